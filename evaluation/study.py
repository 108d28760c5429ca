"""What accuracy costs in time: the accuracy-vs-time study.

Per scene, one factor at a time around a default setting, plus the spp × depth grid:

======================  ==============================================================
factor                  values
======================  ==============================================================
``spp``                 samples per pixel (stratified jitter): 1, 4, 16, 64, 256
``max_depth``           0 … 8
``min_weight``          weight cut-off: 0, 0.001, 0.01, 0.1
``precision``           float32, float64
``combination``         constant, fresnel (a model change: plotted apart, off the front)
``intersection``        every routine of the triangle-routine registry
``accel``               every accelerator of the registry (brute, boxes, bvh): same image
``effects``             auto (the scene's effect set) vs all (the general kernel)
``shadow_samples``      shadow rays per light with extent: 1, 4, 16, 64 (only scenes with a
                        sphere or rectangle light)
``grid``                spp × max_depth
======================  ==============================================================

The default of each scene is its own file's ``max_depth``, ``min_weight`` and combination,
float32, the first triangle routine, the BVH, auto effects and ``Profile.default_spp``.

Every point is rendered in converged mode (stratified jitter, ``spp`` samples per pixel) with
``len(seeds)`` seeds (>= 5), and each image is compared against two references:

- ``golden``: the converged Mitsuba golden of the scene (``reference/goldens``, 128 × 128,
  box-averaged when the study runs at a divisor of that size);
- ``own``: our own render of the scene's *default* setting at ``Profile.ref_spp`` (same model
  variant, i.e. the same ``combination``), so error against ``own`` is our sampling error
  plus what the factor changes, and error against ``golden`` adds the model difference to
  Mitsuba.

Metrics per image (``error_metrics``): RMSE, relMSE (``(a-r)^2 / (r^2 + eps)``, eps 0.01)
and relMSE trimmed at 0.1 % (the worst 0.1 % of pixels dropped), mean and 95th percentile
HDR-FLIP, mean CIEDE2000 (only where colour-science is installed; else skipped with a note in
the results). A point stores the per-seed values and mean / std / min / max.

Time per point (one seed): the first traced frame's wall time with Dr.Jit's compile time
(codegen + backend, from the kernel history) reported apart; then the frame wrapped in
``dr.freeze`` (as ``Renderer(freeze=True)`` does), recorded once and replayed: kernel time
(median of the kernel history's ``execution_time`` over repeats after warm-up) and frozen
frame wall time. Device, backend and versions go with every point.

Points run through ``evaluation.executor`` (in-process, or Dask workers); the results JSON
is rewritten (temp file + rename) after every point, so a run can stop anywhere and resume.
``write_outputs`` turns the JSON into markdown, PNG + SVG plots and an HTML page.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import platform
import statistics
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

# ---- project imports (the one block to rename at merge) ------------------------------------
from evaluation.metrics import delta_e2000, flip_error
from reference.golden import GoldenError, load_golden
from renderer.accel import ACCELERATORS, ROUTINES
from renderer.effects import EffectSet
from renderer.outputs import atomic_path, check_output_dir, write_text
from renderer.render import Renderer, make_frame_fn
from renderer.scene import Scene, load_scene
from renderer.stats import kernel_ms

from .executor import make_executor, progress

ROOT = Path(__file__).resolve().parent.parent
SCHEMA = 1
#: Denominator floor of relMSE (as in evaluation.metrics / reference.compare).
REL_EPS = 1e-2
#: Fraction of the worst pixels dropped by the trimmed relMSE.
TRIM = 1e-3
METRICS = ("rmse", "relmse", "relmse_trim", "flip_mean", "flip_p95", "de2000_mean")
#: Metrics that need an optional package, and the package (skipped, with a note, without it:
#: the GPU hosts have no network and colour-science is not among the wheels carried there).
OPTIONAL_METRICS = {"de2000_mean": "colour"}
REFS = ("golden", "own")
FACTORS = ("spp", "max_depth", "min_weight", "precision", "combination", "intersection",
           "accel", "effects", "shadow_samples")
#: Order in which factor lines are measured (a run stopped by its budget has the first ones).
PRIORITY = ("spp", "accel", "precision", "effects", "min_weight", "combination", "max_depth",
            "intersection", "shadow_samples")
#: Factors that change what is rendered (the model), not how well: off the Pareto front.
MODEL_FACTORS = ("combination",)
SEED_SCENES = ("scenes/cornell_box.toml", "scenes/cornell_sphere.toml",
               "scenes/platonic_solids.toml", "scenes/glass_bunny.toml")


# =========================================================================================
# The sweep
# =========================================================================================
@dataclass(frozen=True)
class Profile:
    """How big a sweep is: values swept, seeds, size, repeats and the own reference's spp."""

    spp: tuple = (1, 4, 16, 64, 256)
    grid_spp: tuple = (1, 4, 16, 64, 256)
    depths: tuple = tuple(range(9))
    min_weights: tuple = (0.0, 0.001, 0.01, 0.1)
    precisions: tuple = ("float32", "float64")
    combinations: tuple = ("constant", "fresnel")
    effects: tuple = ("auto", "all")
    #: Shadow rays per light with extent (scenes with a sphere or rectangle light only).
    shadow_samples: tuple = (1, 4, 16, 64)
    default_spp: int = 16
    seeds: tuple = (0, 1, 2, 3, 4)
    size: int = 128
    ref_spp: int = 4096
    ref_seed: int = 10_000
    warmup: int = 2
    repeats: int = 10
    factors: tuple = FACTORS
    grid: bool = True
    #: Brute force only on scenes with at most this many triangles (it tests them all).
    brute_max_faces: int = 200_000
    #: Per-object boxes only on scenes whose largest object has at most this many triangles
    #: (inside a box every triangle is tested: brute force per object); None: no limit.
    boxes_max_object_faces: int | None = None
    #: Factor points with more spp than this run after every other factor point.
    defer_spp: int = 64


PROFILES = {
    # The GPU run: the full study.
    "gpu": Profile(brute_max_faces=5000),
    # The 2-core CPU run: same factors, the grid stops at 64 spp, fewer repeats.
    "cpu": Profile(grid_spp=(1, 4, 16), ref_spp=256, warmup=0, repeats=3,
                   brute_max_faces=2000, boxes_max_object_faces=20_000),
    # CI: tiny images, three spp values, a short depth range.
    "tiny": Profile(spp=(1, 4, 16), grid_spp=(1, 4), depths=(0, 1, 2, 6), default_spp=4,
                    size=16, ref_spp=256, warmup=0, repeats=1),
}


def parse_scene_arg(text: str) -> tuple[str, float]:
    """``PATH`` or ``PATH@OFFSET`` (the scene translated by OFFSET along x, y and z: a hard
    scene for float32) -> (path, offset). A bare name means ``scenes/NAME.toml``."""
    path, _, off = str(text).partition("@")
    if not path.endswith(".toml") and "/" not in path:
        path = f"scenes/{path}.toml"
    return path, float(off) if off else 0.0


def scene_label(path: str, offset: float = 0.0) -> str:
    return Path(path).stem + (f"@{offset:g}" if offset else "")


def translated(scene: Scene, offset) -> Scene:
    """``scene`` moved by ``offset`` (float or (3,)): vertices, cameras and lights. The image
    is the same in exact arithmetic; in float32 the ray offset then falls below the spacing
    of representable positions far from the origin."""
    o = np.broadcast_to(np.asarray(offset, np.float64), (3,))
    cams = [replace(c, position=np.asarray(c.position) + o, target=np.asarray(c.target) + o)
            for c in scene.cameras]
    lights = [replace(l, position=np.asarray(l.position) + o) for l in scene.lights]
    verts = (scene.vertices.astype(np.float64) + o).astype(np.float32)
    return replace(scene, vertices=verts, cameras=cams, lights=lights)


def _specular_combinations(scene: Scene) -> set:
    return {m.combination for m in scene.materials if m.reflective or m.transmissive}


def prepare_scene(spec: dict) -> Scene:
    """The scene a point spec describes: loaded with its shading, translated, resized
    (height ``size``, width by the camera's aspect), its view first, settings and
    combination applied (converged mode, ``spp``; the seed is set per render)."""
    sc = load_scene(ROOT / spec["scene"] if not Path(spec["scene"]).is_absolute()
                    else spec["scene"], shading=spec.get("shading"))
    if spec.get("offset"):
        sc = translated(sc, spec["offset"])
    if spec.get("view", 0):
        sc = sc.with_camera(int(spec["view"]))
    cam = sc.cameras[0]
    h = int(spec["size"])
    w = max(1, int(round(h * cam.width / cam.height)))
    sc = sc.with_size(w, h)
    comb = spec.get("combination", "scene")
    if comb != "scene":
        sc = replace(sc, materials=[replace(m, combination=comb)
                                    if (m.reflective or m.transmissive) else m
                                    for m in sc.materials])
    s = sc.settings
    settings = replace(s, spp=int(spec["spp"]), exact=False,
                       max_depth=int(spec.get("max_depth", s.max_depth)),
                       min_weight=float(spec.get("min_weight", s.min_weight)),
                       shadow_samples=int(spec.get("shadow_samples", s.shadow_samples)))
    return replace(sc, settings=settings)


SETTING_KEYS = ("spp", "max_depth", "min_weight", "precision", "combination", "intersection",
                "accel", "effects")

#: Settings only some scenes have (in their default only then): lights with extent.
OPTIONAL_SETTINGS = ("shadow_samples",)


def point_key(spec: dict) -> str:
    """Identity of a point: the scene and its settings (not seeds, repeats or device)."""
    s = " ".join(f"{k}={spec[k]}" for k in SETTING_KEYS)
    if "shadow_samples" in spec:          # scenes with a light of extent only
        s += f" shadow_samples={spec['shadow_samples']}"
    return f"{spec['label']} | {s}"


def default_settings(scene: Scene, profile: Profile) -> dict:
    s = scene.settings
    d = {"spp": profile.default_spp, "max_depth": int(s.max_depth),
         "min_weight": float(s.min_weight), "precision": "float32", "combination": "scene",
         "intersection": next(iter(ROUTINES)), "accel": "bvh" if "bvh" in ACCELERATORS
         else next(iter(ACCELERATORS)), "effects": "auto"}
    if any(light.extent for light in scene.lights):
        d["shadow_samples"] = int(s.shadow_samples)
    return d


def build_sweep(scene_args, profile: Profile, *, backend: str = "llvm",
                shading: str | None = None) -> tuple[list[dict], dict]:
    """Point specs of the sweep (deduplicated, in priority order: every scene's default, then
    factor by factor across the scenes, the grid last) and per-scene facts (defaults,
    own-reference specs)."""
    scenes = {}
    for arg in scene_args:
        path, offset = parse_scene_arg(arg)
        label = scene_label(path, offset)
        sc = load_scene(ROOT / path if not Path(path).is_absolute() else path, shading=shading)
        scenes[label] = {"path": path, "offset": offset, "label": label,
                         "shading": sc.settings.shading,
                         "default": default_settings(sc, profile),
                         "combinations": sorted(_specular_combinations(sc)),
                         "faces": int(sc.face_count),
                         "max_object_faces": max((int(o.face_count) for o in sc.objects),
                                                 default=0)}
    values = {"spp": profile.spp, "max_depth": profile.depths,
              "min_weight": profile.min_weights, "precision": profile.precisions,
              "combination": profile.combinations, "intersection": tuple(ROUTINES),
              "accel": tuple(ACCELERATORS), "effects": profile.effects,
              "shadow_samples": profile.shadow_samples}
    specs, seen = [], set()

    def add(info, to=specs, **changes):
        st = dict(info["default"], **changes)
        if st["combination"] != "scene" and set(info["combinations"]) <= {st["combination"]}:
            st["combination"] = "scene"          # the scene's own model (or no mirrors)
        spec = {"scene": info["path"], "offset": info["offset"], "label": info["label"],
                "shading": info["shading"], "view": 0, "size": profile.size,
                "backend": backend, **st, "seeds": list(profile.seeds),
                "warmup": profile.warmup, "repeats": profile.repeats}
        spec["key"] = point_key(spec)
        if spec["key"] not in seen:
            seen.add(spec["key"])
            to.append(spec)

    for info in scenes.values():
        add(info)
    deferred = []
    for f in sorted(profile.factors, key=PRIORITY.index):
        for info in scenes.values():
            for v in values[f]:
                if f == "shadow_samples" and f not in info["default"]:
                    break                         # point lights only: nothing to sweep
                if f == "accel" and v == "brute" and info["faces"] > profile.brute_max_faces:
                    info.setdefault("skipped", []).append(
                        f"accel=brute ({info['faces']} triangles > brute_max_faces "
                        f"{profile.brute_max_faces})")
                    continue
                big = info["max_object_faces"]
                if (f == "accel" and v == "boxes" and profile.boxes_max_object_faces is not None
                        and big > profile.boxes_max_object_faces):
                    info.setdefault("skipped", []).append(
                        f"accel=boxes (an object of {big} triangles > boxes_max_object_faces "
                        f"{profile.boxes_max_object_faces})")
                    continue
                late = f == "spp" and v > profile.defer_spp
                add(info, to=deferred if late else specs, **{f: v})
    specs += deferred
    if profile.grid:
        for info in scenes.values():
            for d in profile.depths:
                for n in profile.grid_spp:
                    add(info, spp=n, max_depth=d)
    for info in scenes.values():
        combs = sorted({s["combination"] for s in specs if s["label"] == info["label"]})
        info["refs"] = {c: ref_spec(info, profile, c, backend) for c in combs}
    return specs, scenes


def ref_spec(info: dict, profile: Profile, combination: str, backend: str) -> dict:
    spec = {"scene": info["path"], "offset": info["offset"], "label": info["label"],
            "shading": info["shading"], "view": 0, "size": profile.size, "backend": backend,
            **dict(info["default"], spp=profile.ref_spp, combination=combination),
            "seeds": [profile.ref_seed]}
    spec["key"] = "ref " + point_key(spec)
    return spec


# =========================================================================================
# Error metrics
# =========================================================================================
def metrics_available() -> tuple[tuple, list[str]]:
    """The metrics this process can compute and a note for each one skipped."""
    import importlib.util
    have, notes = [], []
    for m in METRICS:
        mod = OPTIONAL_METRICS.get(m)
        if mod and importlib.util.find_spec(mod) is None:
            notes.append(f"{m} skipped: the Python package {mod!r} (colour-science) is not "
                         "installed")
        else:
            have.append(m)
    return tuple(have), notes


def error_metrics(img: np.ndarray, ref: np.ndarray) -> dict:
    """The study's metrics of ``img`` against ``ref`` (float (H, W, 3) linear RGB); the
    optional ones (``OPTIONAL_METRICS``) only where their package is installed."""
    a = np.nan_to_num(np.asarray(img, np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    r = np.asarray(ref, np.float64)
    d2 = (a - r) ** 2
    rel = (d2 / (r * r + REL_EPS)).mean(axis=2).ravel()
    drop = int(math.ceil(TRIM * rel.size))
    kept = np.sort(rel)[: rel.size - drop] if drop < rel.size else rel
    fmap, fmean = flip_error(a.astype(np.float32), r.astype(np.float32))
    out = {"rmse": float(np.sqrt(d2.mean())), "relmse": float(rel.mean()),
           "relmse_trim": float(kept.mean()), "flip_mean": float(fmean),
           "flip_p95": float(np.percentile(fmap, 95))}
    if "de2000_mean" in metrics_available()[0]:
        out["de2000_mean"] = float(delta_e2000(a, r).mean())
    return out


def summarize(values: list[float]) -> dict:
    v = [float(x) for x in values]
    return {"mean": statistics.fmean(v), "std": statistics.pstdev(v) if len(v) > 1 else 0.0,
            "min": min(v), "max": max(v), "values": v}


def block_mean(img: np.ndarray, h: int, w: int) -> np.ndarray:
    """``img`` (H, W, 3) averaged over k × k blocks down to (h, w, 3) (H = k h, W = k w): the
    box-filtered image at the lower resolution."""
    H, W, _ = img.shape
    if (H, W) == (h, w):
        return img
    if H % h or W % w or H // h != W // w:
        raise ValueError(f"golden of {W}x{H} cannot be box-reduced to {w}x{h}")
    k = H // h
    return img.reshape(h, k, w, k, 3).mean(axis=(1, 3))


def golden_for(spec: dict) -> tuple[np.ndarray | None, dict]:
    """The converged golden of the spec's scene (box-reduced to the study's size), and facts
    about it (path, spp, noise floor: the RMSE its own Monte Carlo noise contributes)."""
    sc = prepare_scene(dict(spec, spp=1))
    cam = sc.cameras[0]
    try:
        g = load_golden(sc, view=int(spec.get("view", 0)), shading=spec["shading"],
                        mode="converged")
    except GoldenError as e:
        return None, {"missing": str(e)}
    img = block_mean(g.image, cam.height, cam.width)
    info = {"path": str(Path(g.path).relative_to(ROOT)) if ROOT in Path(g.path).parents
            else str(g.path), "spp": g.meta.get("spp"), "mitsuba": g.meta.get("mitsuba_version"),
            "resolution": g.meta.get("resolution")}
    if g.var is not None:
        k = g.image.shape[0] // cam.height
        var_mean = g.var / max(int(g.meta.get("batches", 1)), 1) / (k * k)
        info["noise_rmse"] = float(np.sqrt(block_mean(var_mean, cam.height, cam.width).mean()))
    return img, info


# =========================================================================================
# Running one point (in whichever process the executor chose)
# =========================================================================================
_DEVICE: dict = {}


def device_info(backend: str) -> dict:
    """Device, backend and versions of this process (``evaluation.bench.device_info`` plus
    numpy, the platform and the GPU this worker sees; cached)."""
    if backend in _DEVICE:
        return _DEVICE[backend]
    from evaluation.bench import device_info as bench_device_info
    info = dict(bench_device_info(backend), numpy=np.__version__,
                platform=platform.platform())
    if backend == "cuda":
        info["cuda_visible_devices"] = os.environ.get("CUDA_VISIBLE_DEVICES")
    _DEVICE[backend] = info
    return info


def _renderer(spec: dict) -> tuple[Renderer, Scene]:
    sc = prepare_scene(spec)
    effects = EffectSet.all(sc) if spec["effects"] == "all" else None
    r = Renderer(sc, backend=spec["backend"], precision=spec["precision"], accel=spec["accel"],
                 intersection=spec["intersection"], effects=effects, spp=int(spec["spp"]),
                 exact=False)
    return r, sc


def render_seeds(spec: dict, seeds=None, *, timing: bool = False) -> tuple[list, dict]:
    """Images (float32 (H, W, 3)) of ``spec`` for each seed, one upload and one compiled
    kernel for all seeds (the seed is an opaque Dr.Jit value with the meaning of
    ``Settings.seed``). With ``timing``, also the first frame's wall and compile time and the
    frozen frame's kernel and wall times (the first seed's frame function wrapped in
    ``dr.freeze``, as ``Renderer(freeze=True)`` does; recorded once, then replayed)."""
    import drjit as dr
    seeds = spec["seeds"] if seeds is None else seeds
    r, sc = _renderer(spec)
    cam = sc.cameras[0]
    W, H = cam.width, cam.height
    ca = r.camera(0)
    u64 = __import__(f"drjit.{r.t.backend}", fromlist=["UInt64"]).UInt64
    fn0 = None
    images, facts = [], {"effects": str(r.effects), "reachable_depth": int(r.effects.depth),
                         "upload_s": float(r.upload_seconds), "rays_per_frame": W * H * r.spp}
    for i, s in enumerate(seeds):
        seed_var = dr.opaque(u64, int(s))
        fn = make_frame_fn(r.t, r.effects, r.options, spp=r.spp, exact=False, seed=seed_var)
        fn0 = fn0 or fn
        dr.sync_thread()
        first = i == 0 and timing
        if first:
            dr.kernel_history()
            with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
                t0 = time.perf_counter()
                img = fn(ca, r.arrays, W, H)
                dr.eval(img)
                dr.sync_thread()
                wall = (time.perf_counter() - t0) * 1e3
                hist = [h for h in dr.kernel_history() if "operation_count" in h]
            compile_ms = sum(float(h.get("codegen_time", 0)) + float(h.get("backend_time", 0))
                             for h in hist)
            exec_ms = sum(float(h.get("execution_time", 0)) for h in hist)
            facts.update(first_frame_ms=wall, compile_ms=compile_ms,
                         trace_ms=max(wall - compile_ms - exec_ms, 0.0),
                         kernels=len(hist), operations=sum(int(h["operation_count"]) for h in hist),
                         cache_hits=sum(bool(h.get("cache_hit")) for h in hist))
        else:
            img = fn(ca, r.arrays, W, H)
        images.append(np.asarray(img.numpy(), np.float32))
    if timing:
        frozen = dr.freeze(fn0)
        dr.sync_thread()
        t0 = time.perf_counter()
        out = frozen(ca, r.arrays, W, H)
        dr.eval(out)
        dr.sync_thread()
        facts["freeze_record_ms"] = (time.perf_counter() - t0) * 1e3
        cpu0 = time.process_time()
        tm = kernel_ms(lambda arrays=r.arrays: dr.eval(frozen(ca, arrays, W, H)),
                       warmup=int(spec.get("warmup", 1)), repeats=int(spec.get("repeats", 3)))
        # CPU time of this process per frame (all threads): on a CPU backend shared with other
        # work it does not grow while the process waits for a core, unlike the kernel time.
        facts["frozen_cpu_ms"] = ((time.process_time() - cpu0) * 1e3
                                  / (int(spec.get("warmup", 1)) + int(spec.get("repeats", 3))))
        facts.update(kernel_ms=float(tm["kernel_ms"]), kernel_ms_min=float(tm["kernel_ms_min"]),
                     frozen_wall_ms=float(tm["wall_ms"]), repeats=int(tm["repeats"]),
                     warmup=int(spec.get("warmup", 1)))
        facts["frozen_equals_traced"] = bool(np.array_equal(np.asarray(out.numpy(), np.float32),
                                                            images[0]))
        del frozen, out
    del fn, fn0, r
    return images, facts


def busy_load(cores: int) -> float:
    """The 1-minute load average above which a CPU run counts as shared with other work:
    the study's own render threads keep the load near the core count, so up to half a
    core more is its own."""
    return cores + 0.5


def image_hash(img: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(img, np.float32).tobytes()).hexdigest()[:16]


def run_reference(spec: dict) -> dict:
    """Executor task: the own reference image of a scene (one seed at ``ref_spp``)."""
    t0 = time.perf_counter()
    images, facts = render_seeds(spec)
    return {"key": spec["key"], "image": images[0], "seconds": time.perf_counter() - t0,
            "device": device_info(spec["backend"]), "pid": os.getpid(), **facts}


def run_point(item) -> dict:
    """Executor task: ``item = (spec, golden image or None, own reference image)``; renders
    every seed, measures time and returns the JSON record of the point."""
    spec, golden, own = item
    t0 = time.perf_counter()
    images, facts = render_seeds(spec, timing=True)
    errors = {}
    for name, ref in (("golden", golden), ("own", own)):
        if ref is None:
            errors[name] = None
            continue
        per = [error_metrics(img, ref) for img in images]
        errors[name] = {m: summarize([p[m] for p in per]) for m in METRICS if m in per[0]}
    timing = {k: facts.pop(k) for k in list(facts) if k in (
        "first_frame_ms", "compile_ms", "trace_ms", "freeze_record_ms", "kernel_ms",
        "kernel_ms_min", "frozen_wall_ms", "frozen_cpu_ms", "repeats", "warmup", "cache_hits",
        "kernels",
        "operations")}
    if hasattr(os, "getloadavg"):
        timing["loadavg_1m"] = os.getloadavg()[0]      # other work on the machine
    settings = {k: spec[k] for k in SETTING_KEYS + OPTIONAL_SETTINGS if k in spec}
    return {"key": spec["key"], "scene": spec["label"], "settings": settings,
            "seeds": list(spec["seeds"]), "size": spec["size"], "errors": errors,
            "image_sha256": [image_hash(i) for i in images], "timing": timing,
            "facts": facts, "device": device_info(spec["backend"]),
            "seconds": time.perf_counter() - t0, "pid": os.getpid()}


# =========================================================================================
# The results file (atomic rewrites; resumable)
# =========================================================================================
def load_results(path: Path) -> dict:
    path = Path(path)
    if path.exists():
        data = json.loads(path.read_text())
        if data.get("schema") == SCHEMA:
            return data
    return {"schema": SCHEMA, "meta": {}, "scenes": {}, "points": {}}


def save_results(path: Path, data: dict) -> None:
    """Write ``data`` to ``path`` through a temporary file and a rename: an interrupted run
    leaves the previous complete file or the new one, never half of one."""
    write_text(path, json.dumps(data, indent=1, sort_keys=True) + "\n", overwrite=True)


def _ref_cache(out: Path, key: str) -> Path:
    return Path(out) / "cache" / (hashlib.sha256(key.encode()).hexdigest()[:20] + ".npy")


def run_study(scene_args, out, *, profile: Profile | str = "cpu", backend: str = "llvm",
              shading: str | None = None, workers: int = 0, scheduler: str | None = None,
              budget_s: float | None = None, max_points: int | None = None,
              show_progress: bool = True, outputs: bool = True, log=print) -> dict:
    """Run (or resume) the study into folder ``out``: ``out/study.json`` after every point,
    then the markdown, plots and HTML page (``outputs``). ``budget_s`` stops taking new
    points after that many seconds (the rest stays for a resumed run); ``max_points`` stops
    after that many new points. Returns the results dict."""
    prof = PROFILES[profile] if isinstance(profile, str) else profile
    out = Path(out)
    jpath = out / "study.json"
    data = load_results(jpath)
    specs, scenes = build_sweep(scene_args, prof, backend=backend, shading=shading)
    data["meta"].update(profile=asdict(prof) | {"name": profile if isinstance(profile, str)
                                                else "custom"},
                        backend=backend, metrics=list(metrics_available()[0]),
                        metric_notes=metrics_available()[1], rel_eps=REL_EPS, trim=TRIM)
    t_start = time.perf_counter()
    # CUDA on a local cluster: one GPU per worker (evaluation.executor); a scheduler's own
    # workers already have their placement.
    gpu_kw = {"gpus": "auto"} if backend == "cuda" and workers and not scheduler else {}
    with make_executor(workers, scheduler, **gpu_kw) as ex:
        data["meta"]["executor"] = ex.describe()
        # ---- references: goldens (here) and own high-spp renders (executor, cached) -------
        goldens, owns, todo = {}, {}, []
        for label, info in scenes.items():
            img, ginfo = golden_for({"scene": info["path"], "offset": info["offset"],
                                     "shading": info["shading"], "size": prof.size,
                                     "view": 0, **info["default"]})
            goldens[label] = img
            info["golden"] = ginfo
            for comb, rs in info["refs"].items():
                cache = _ref_cache(out, rs["key"])
                if cache.exists():
                    owns[(label, comb)] = np.load(cache)
                else:
                    todo.append(((label, comb), rs))
        if todo:
            log(f"study: {len(todo)} own reference render(s) at {prof.ref_spp} spp")
            pairs = ex.map(run_reference, [rs for _, rs in todo])
            for i, res in progress(pairs, len(todo), desc="references",
                                   enabled=show_progress):
                (label, comb), rs = todo[i]
                cache = _ref_cache(out, rs["key"])
                with atomic_path(cache, overwrite=True) as tmp, open(tmp, "wb") as f:
                    np.save(f, res["image"])
                owns[(label, comb)] = res["image"]
                scenes[label].setdefault("ref_info", {})[comb] = {
                    "spp": prof.ref_spp, "seconds": res["seconds"],
                    "device": res["device"]["device"]}
                if budget_s is not None and time.perf_counter() - t_start > budget_s:
                    raise SystemExit("study: budget spent on the own references; run again "
                                     "to resume (finished references are cached)")
        for label, info in scenes.items():
            old = data["scenes"].get(label, {})
            info["ref_info"] = {**old.get("ref_info", {}), **info.get("ref_info", {})}
            data["scenes"][label] = {k: v for k, v in info.items()}
        data["meta"]["device"] = device_info(backend) if not (workers or scheduler) else \
            data["meta"].get("device")
        save_results(jpath, data)

        # ---- points -------------------------------------------------------------------------
        todo = [s for s in specs if s["key"] not in data["points"]]
        if max_points is not None:
            todo = todo[:max_points]
        have = sum(s["key"] in data["points"] for s in specs)
        log(f"study: {len(specs)} points, {have} already measured, "
            f"{len(todo)} to run now ({ex.describe()['executor']})")
        items = [(s, goldens[s["label"]], owns[(s["label"], s["combination"])]) for s in todo]
        done = 0
        stopped = False
        try:
            for _i, rec in progress(ex.map(run_point, items), len(items), desc="study",
                                   enabled=show_progress):
                data["points"][rec["key"]] = rec
                if data["meta"].get("device") is None:
                    data["meta"]["device"] = rec["device"]
                save_results(jpath, data)
                done += 1
                if budget_s is not None and time.perf_counter() - t_start > budget_s:
                    stopped = True
                    break
        finally:
            wall = time.perf_counter() - t_start
            data["meta"].setdefault("runs", []).append(
                {"date": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                 "points": done, "wall_s": round(wall, 1), "stopped_by_budget": stopped})
            data["meta"]["missing"] = [s["key"] for s in specs if s["key"] not in data["points"]]
            save_results(jpath, data)
    log(f"study: {done} point(s) in {wall:.0f} s; {len(data['meta']['missing'])} missing")
    if outputs:
        write_outputs(data, out)
    return data


# =========================================================================================
# Analysis: factor lines, Pareto front, tables, sentences
# =========================================================================================
def differs(settings: dict, default: dict) -> list[str]:
    return [k for k in SETTING_KEYS + OPTIONAL_SETTINGS if settings.get(k) != default.get(k)]


def point_label(settings: dict, default: dict) -> str:
    d = differs(settings, default)
    return ", ".join(f"{k}={settings[k]}" for k in d) or "default"


def time_of(p: dict) -> float:
    return float(p["timing"]["kernel_ms"])


def err_of(p: dict, ref: str, metric: str = "relmse") -> float | None:
    e = p["errors"].get(ref)
    return None if e is None or metric not in e else float(e[metric]["mean"])


def scene_points(data: dict, label: str) -> list[dict]:
    return [p for p in data["points"].values() if p["scene"] == label]


def factor_line(data: dict, label: str, factor: str) -> list[dict]:
    """Points of ``label`` that differ from its default in ``factor`` only (and the default),
    in the order of the factor's values."""
    default = data["scenes"][label]["default"]
    if factor not in default:
        return []                     # an optional setting this scene does not have
    pts = [p for p in scene_points(data, label)
           if set(differs(p["settings"], default)) <= {factor}]
    order = {"precision": ["float32", "float64"], "effects": ["auto", "all"],
             "combination": ["scene", "constant", "fresnel"]}
    if factor in order:
        return sorted(pts, key=lambda p: order[factor].index(p["settings"][factor]))
    if factor in ("accel", "intersection"):
        return sorted(pts, key=lambda p: str(p["settings"][factor]))
    return sorted(pts, key=lambda p: p["settings"][factor])


def pareto(points: list[dict], ref: str, metric: str = "relmse") -> list[dict]:
    """Points not beaten in both time and error (model changes excluded), by time."""
    cand = [p for p in points if p["settings"]["combination"] == "scene"
            and err_of(p, ref, metric) is not None]
    cand.sort(key=lambda p: (time_of(p), err_of(p, ref, metric)))
    front, best = [], math.inf
    for p in cand:
        e = err_of(p, ref, metric)
        if e < best:
            front.append(p)
            best = e
    return front


def _fmt(x, digits=3) -> str:
    if x is None:
        return "–"
    if x == 0:
        return "0"
    return f"{x:.{digits}g}" if 1e-3 <= abs(x) < 1e4 else f"{x:.{digits - 1}e}"


def budgets(lo: float, hi: float) -> list[float]:
    """1-2-5 steps from ``lo`` to ``hi``."""
    out = []
    k = math.floor(math.log10(max(lo, 1e-9)))
    while True:
        for m in (1, 2, 5):
            b = m * 10.0 ** k
            if b >= lo * 0.999:
                out.append(b)
            if b >= hi:
                return out
        k += 1


def equal_time_rows(points: list[dict], default: dict, ref: str) -> list[dict]:
    pts = [p for p in points if p["settings"]["combination"] == "scene"
           and err_of(p, ref) is not None]
    if not pts:
        return []
    rows = []
    for b in budgets(min(map(time_of, pts)), max(map(time_of, pts))):
        ok = [p for p in pts if time_of(p) <= b]
        if not ok:
            continue
        best = min(ok, key=lambda p: err_of(p, ref))
        rows.append({"budget_ms": b, "setting": point_label(best["settings"], default),
                     "kernel_ms": time_of(best), "relmse": err_of(best, ref),
                     "relmse_std": best["errors"][ref]["relmse"]["std"],
                     "rmse": err_of(best, ref, "rmse"), "flip": err_of(best, ref, "flip_mean")})
    return rows


def equal_error_rows(points: list[dict], default: dict, ref: str) -> list[dict]:
    pts = [p for p in points if p["settings"]["combination"] == "scene"
           and err_of(p, ref) is not None and err_of(p, ref) > 0]
    if not pts:
        return []
    lo = min(err_of(p, ref) for p in pts)
    hi = max(err_of(p, ref) for p in pts)
    rows = []
    k = math.ceil(math.log10(hi))
    while 10.0 ** k >= lo * 0.999 and len(rows) < 8:
        target = 10.0 ** k
        ok = [p for p in pts if err_of(p, ref) <= target]
        if ok:
            best = min(ok, key=time_of)
            rows.append({"target": target, "setting": point_label(best["settings"], default),
                         "kernel_ms": time_of(best), "relmse": err_of(best, ref)})
        k -= 1
    return rows


def _find(line: list[dict], factor: str, value) -> dict | None:
    for p in line:
        if p["settings"][factor] == value:
            return p
    return None


def _ratio(a, b):
    return None if a is None or b is None or b == 0 else a / b


def factor_sentences(data: dict, label: str) -> dict:
    """One sentence per factor of what it buys on scene ``label`` (from the data)."""
    default = data["scenes"][label]["default"]
    ref = "golden" if data["scenes"][label].get("golden", {}).get("path") else "own"
    out = {}
    base = _find(factor_line(data, label, "spp"), "spp", default["spp"])
    if base is None:
        return out

    def cmp(p, q, metric="rmse", r="own"):
        return _ratio(err_of(p, r, metric), err_of(q, r, metric)), _ratio(time_of(p), time_of(q))

    line = factor_line(data, label, "spp")
    steps = [(a, b) for a, b in zip(line, line[1:])]
    if steps:
        parts = []
        for a, b in steps:
            e, t = cmp(b, a)
            if e and t:
                parts.append(f"{a['settings']['spp']}→{b['settings']['spp']}: RMSE ÷{1 / e:.2f} "
                             f"at {t:.2f}× time")
        out["spp"] = ("4× spp (vs own reference) " + "; ".join(parts) + ".") if parts else None
    line = factor_line(data, label, "max_depth")
    if len(line) > 1:
        dd = default["max_depth"]
        # the shallowest depth from which every depth up to the default gives its image
        same_from = None
        for p in sorted((p for p in line if p["settings"]["max_depth"] <= dd),
                        key=lambda p: -p["settings"]["max_depth"]):
            if p["image_sha256"] != base["image_sha256"]:
                break
            same_from = p["settings"]["max_depth"]
        deeper = [p for p in line if p["settings"]["max_depth"] > dd]
        d0 = _find(line, "max_depth", 0)
        e, t = cmp(base, d0, "relmse", ref) if d0 else (None, None)
        s = (f"depth 0→{dd}: relMSE vs {ref} ×{_fmt(e)} at {_fmt(t)}× time"
             if e and t else "")
        if same_from is not None and same_from < dd:
            shallow = _find(line, "max_depth", same_from)
            s += (f"; from depth {same_from} to {dd} the image is bitwise the default's "
                  f"(depth {same_from} costs {_fmt(_ratio(time_of(shallow), time_of(base)))}× "
                  "the default's time)")
        if deeper and all(p["image_sha256"] == base["image_sha256"] for p in deeper):
            s += (f"; deeper than {dd} the image is bitwise the default's (depth "
                  f"{deeper[-1]['settings']['max_depth']} costs "
                  f"{_fmt(_ratio(time_of(deeper[-1]), time_of(base)))}× time for nothing)")
        elif deeper:
            e2, t2 = cmp(deeper[-1], base, "relmse", ref)
            s += (f"; deeper than {dd} changes the image (more bounces than the scene's "
                  f"depth, which the golden and the own reference stop at): depth "
                  f"{deeper[-1]['settings']['max_depth']} relMSE vs {ref} ×{_fmt(e2)} at "
                  f"{_fmt(t2)}× time")
        out["max_depth"] = s.lstrip("; ") + "."
    line = factor_line(data, label, "min_weight")
    if len(line) > 1:
        parts = []
        for p in line:
            if p is base:
                continue
            e, t = cmp(p, base, "relmse", "own")
            same = p["image_sha256"] == base["image_sha256"]
            parts.append(f"cut-off {p['settings']['min_weight']:g}: "
                         + ("same image" if same else f"relMSE vs own ×{_fmt(e)}")
                         + f" at {_fmt(t)}× time")
        out["min_weight"] = (f"vs cut-off {default['min_weight']:g}: " + "; ".join(parts) + ".")
    for factor, label_of in (("precision", "float64"), ("effects", "all")):
        p = _find(factor_line(data, label, factor), factor, label_of)
        if p:
            e, t = cmp(p, base, "rmse", ref)
            same = p["image_sha256"] == base["image_sha256"]
            out[factor] = (f"{factor}={label_of}: "
                           + ("the same image" if same else f"RMSE vs {ref} ×{_fmt(e)}")
                           + f" at {_fmt(t)}× time.")
    line = factor_line(data, label, "accel")
    if len(line) > 1:
        fastest = min(line, key=time_of)
        same = len({tuple(p["image_sha256"]) for p in line}) == 1
        slow = max(line, key=time_of)
        ratio = time_of(slow) / time_of(fastest)
        out["accel"] = (f"{'same image from every accelerator' if same else 'IMAGES DIFFER'}; "
                        f"{fastest['settings']['accel']} is {ratio:.1f}× "
                        f"faster than {slow['settings']['accel']}.")
    line = factor_line(data, label, "intersection")
    if len(line) == 1:
        out["intersection"] = (f"only {line[0]['settings']['intersection']} is registered: "
                               "nothing to compare yet.")
    elif line:
        out["intersection"] = "; ".join(
            f"{p['settings']['intersection']}: {_fmt(time_of(p))} ms, RMSE vs {ref} "
            f"{_fmt(err_of(p, ref, 'rmse'))}" for p in line) + "."
    line = factor_line(data, label, "combination")
    if len(line) > 1:
        out["combination"] = "model change: " + "; ".join(
            f"{p['settings']['combination']}: relMSE vs {ref} {_fmt(err_of(p, ref))}, "
            f"{_fmt(time_of(p))} ms" for p in line) + "." + (
            "" if ref == "golden" else " (no golden: each model is compared with its own "
            "high-spp render, so this is sampling error, not the model difference)")
    return out


def _median(xs):
    xs = [x for x in xs if x is not None and math.isfinite(x)]
    return statistics.median(xs) if xs else None


def p_cpu_time(p: dict) -> bool:
    """Whether cost ratios of ``p`` use the process's CPU time per frozen frame instead of
    the kernel time: on the LLVM backend, where a shared machine makes kernel (wall) times
    include waiting for a core while CPU time does not."""
    return p.get("device", {}).get("backend") == "llvm"


def summary_sentences(data: dict) -> list[str]:
    """What each factor costs, one sentence per factor: the median over scenes of the error
    and time ratios of one step away from the default (the README's section). On the LLVM
    backend the time ratio is of CPU time per frame where both points have it."""
    rows = {}

    def step(name, factor, value_of, metric="rmse", ref="own"):
        for label, info in data["scenes"].items():
            d = info.get("default")
            if not d:
                continue
            line = factor_line(data, label, factor)
            base = _find(line, factor, d[factor])
            other = _find(line, factor, value_of(d))
            if base is None or other is None or other is base:
                continue
            r = "golden" if ref == "golden" and base["errors"].get("golden") else "own"
            cpu = [p["timing"].get("frozen_cpu_ms") for p in (other, base)]
            if p_cpu_time(base) and all(cpu):
                t, unit = _ratio(cpu[0], cpu[1]), "CPU time"
            else:
                t, unit = _ratio(time_of(other), time_of(base)), "time"
            rows.setdefault(name, []).append(
                (_ratio(err_of(other, r, metric), err_of(base, r, metric)), t,
                 other["image_sha256"] == base["image_sha256"], r, unit))

    step("4× spp", "spp", lambda d: d["spp"] * 4)
    step("¼ spp", "spp", lambda d: d["spp"] // 4)
    step("one bounce less (max depth − 1)", "max_depth", lambda d: d["max_depth"] - 1,
         "relmse", "golden")
    step("no secondary rays (max depth 0)", "max_depth", lambda d: 0, "relmse", "golden")
    step("cut-off 0 (trace every branch)", "min_weight", lambda d: 0.0, "relmse")
    step("cut-off 0.1", "min_weight", lambda d: 0.1, "relmse")
    step("float64", "precision", lambda d: "float64", "rmse", "golden")
    step("brute force instead of the BVH", "accel", lambda d: "brute")
    step("per-object boxes instead of the BVH", "accel", lambda d: "boxes")
    step("the all-effects kernel", "effects", lambda d: "all")
    out = []
    for name, rs in rows.items():
        e = _median([r[0] for r in rs])
        t = _median([r[1] for r in rs])
        same = all(r[2] for r in rs)
        metric = "relMSE" if "depth" in name or "cut-off" in name else "RMSE"
        ref = rs[0][3]
        if same:
            what = "the same image (bitwise)"
        elif e is None:
            what = "error n/a"
        elif e < 1:
            what = f"{metric} vs {ref} ÷{1 / e:.2f}"
        else:
            what = f"{metric} vs {ref} ×{e:.2f}"
        units = {r[4] for r in rs}
        unit = units.pop() if len(units) == 1 else "time (CPU time where measured)"
        out.append(f"{name}: {what} at {_fmt(t)}× {unit} (median of {len(rs)} scene"
                   f"{'s' if len(rs) > 1 else ''})")
    return out


def readme_section(data: dict, folder: str) -> str:
    """The README's "What each factor costs" block for the run in ``data`` (committed in
    ``folder``): the device named, one sentence per factor (``summary_sentences``)."""
    meta = data["meta"]
    dev = meta.get("device") or {}
    prof = meta.get("profile", {})
    pts = list(data["points"].values())
    loads = [p["timing"].get("loadavg_1m") for p in pts if p["timing"].get("loadavg_1m")]
    total = len(pts) + len(meta.get("missing", []))
    head = (f"On the **{dev.get('device', '?')}** ({meta.get('backend')} backend, Dr.Jit "
            f"{dev.get('drjit')}; {', '.join(data['scenes'])} at {prof.get('size')} px high, "
            f"{len(prof.get('seeds', []))} seeds; {len(pts)} of {total} points measured), "
            f"one step away from each scene's default ({prof.get('default_spp')} spp, the "
            "scene's depth and cut-off, "
            "float32, BVH), median over the scenes of the error and time ratios"
            + (" (on LLVM: CPU time per frame where measured)" if meta.get("backend") == "llvm"
               else " (kernel time)"))
    if loads and max(loads) > busy_load(dev.get("cores") or 1):
        head += (f"; the machine was shared (load average {min(loads):.1f}–{max(loads):.1f} "
                 f"on {dev.get('cores')} cores): ratios of kernel time (marked \"time\") "
                 "are uncertain by a factor of ~2–3, those of CPU time much less; the errors "
                 "do not depend on it")
    import textwrap
    wrap = textwrap.TextWrapper(width=100, break_long_words=False, break_on_hyphens=False)
    lines = wrap.wrap(head + f" (tables and plots: `{folder}/study.md`):") + [""]
    wrap.subsequent_indent = "  "
    for x in summary_sentences(data):
        lines += wrap.wrap(f"- {x}.")
    return "\n".join(lines) + "\n"


def readme_marker(folder: str) -> str:
    """The comment line that heads the generated block of ``folder`` in the README."""
    return f"<!-- generated by evaluation.study.readme_section from {folder}/study.json -->"


def update_readme(text: str, data: dict, folder: str) -> str:
    """``text`` (a README) with the block under ``readme_marker(folder)`` replaced by
    ``readme_section(data, folder)``: the block is the marker, its paragraph, a blank line
    and the list after it (lines starting "- " or "  "). Raises ``ValueError`` when the
    marker is missing; any other text stays as it was."""
    lines = text.split("\n")
    mark = readme_marker(folder)
    if mark not in lines:
        raise ValueError(f"no line {mark!r} in the README")
    i = j = lines.index(mark) + 1
    while j < len(lines) and lines[j].strip():            # the paragraph
        j += 1
    j += 1                                                 # the blank line
    while j < len(lines) and lines[j].startswith(("- ", "  ")):   # the list
        j += 1
    block = readme_section(data, folder).rstrip("\n").split("\n")
    return "\n".join(lines[:i] + block + lines[j:])


# =========================================================================================
# Outputs: markdown, plots, HTML
# =========================================================================================
def _md_table(header: list[str], rows: list[list]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def markdown(data: dict) -> str:
    meta = data["meta"]
    dev = meta.get("device") or {}
    out = [f"# Accuracy vs time: {dev.get('device', '?')} ({meta.get('backend')})", ""]
    prof = meta.get("profile", {})
    out.append(f"Dr.Jit {dev.get('drjit')}, Python {dev.get('python')}; profile "
               f"`{prof.get('name')}`: {prof.get('size')} px high, seeds "
               f"{prof.get('seeds')}, own reference {prof.get('ref_spp')} spp; time = kernel "
               f"time of the frozen frame (median of {prof.get('repeats')} after "
               f"{prof.get('warmup')} warm-up). Executor: {meta.get('executor')}.")
    for note in meta.get("metric_notes", []):
        out.append(f"Note: {note}.")
    runs = meta.get("runs", [])
    if runs:
        out.append("Runs: " + "; ".join(f"{r['date']} {r['points']} points in {r['wall_s']} s"
                                         + (" (stopped by budget)" if r.get('stopped_by_budget')
                                            else "") + (f" ({r['note']})" if r.get("note") else "")
                                         for r in runs) + ".")
    lines = summary_sentences(data)
    if lines:
        out += ["", "## What each factor costs", "",
                "One step away from each scene's default; ratios are the median over scenes of "
                "(error, kernel time; on LLVM the process's CPU time per frame where measured, "
                "which waiting for a core on a shared machine does not inflate) relative to the "
                "default.", ""]
        out += [f"- {x}." for x in lines]
        out.append("")
    loads = [p["timing"].get("loadavg_1m") for p in data["points"].values()]
    loads = [x for x in loads if x is not None]
    cores = dev.get("cores") or 1
    if loads and max(loads) > busy_load(cores):
        out.append(f"**Measured under load**: the 1-minute load average was {min(loads):.1f}–"
                   f"{max(loads):.1f} on {cores} cores while points were timed (other work on "
                   "the machine), so kernel times include waiting for a core and time ratios "
                   "between points are uncertain by a factor of a few; the errors are not "
                   "affected (renders are deterministic).")
        out.append("")
    if meta.get("missing"):
        out.append(f"**{len(meta['missing'])} points of the sweep not measured yet** "
                   "(resume the run to add them).")
    out.append("")
    for label, info in data["scenes"].items():
        pts = scene_points(data, label)
        if not pts:
            continue
        default = info["default"]
        g = info.get("golden", {})
        out.append(f"## {label}")
        out.append("")
        out.append(f"Default: {', '.join(f'{k}={v}' for k, v in default.items())}. Golden: "
                   + (f"`{g['path']}` ({g.get('spp')} spp, its own noise RMSE "
                      f"{_fmt(g.get('noise_rmse'))})" if g.get("path") else
                      "**missing** (errors vs golden not available)") + ".")
        if info.get("skipped"):
            out.append("Skipped: " + "; ".join(info["skipped"]) + ".")
        out.append("")
        out.append("What each factor buys:")
        out.append("")
        for f, s in factor_sentences(data, label).items():
            if s:
                out.append(f"- **{f}**: {s}")
        out.append("")
        out.append(f"![{label}]({label}.png) ([SVG]({label}.svg))")
        out.append("")
        for ref in REFS:
            rows = equal_time_rows(pts, default, ref)
            if rows:
                out.append(f"Equal time (vs {ref}): the best setting within each "
                           "kernel-time budget")
                out.append("")
                out.append(_md_table(["budget ms", "best setting", "kernel ms", "relMSE (± std)",
                                      "RMSE", "mean FLIP"],
                                     [[_fmt(r["budget_ms"]), r["setting"], _fmt(r["kernel_ms"]),
                                       f"{_fmt(r['relmse'])} ± {_fmt(r['relmse_std'], 2)}",
                                       _fmt(r["rmse"]), _fmt(r["flip"])] for r in rows]))
                out.append("")
            rows = equal_error_rows(pts, default, ref)
            if rows:
                out.append(f"Equal error (vs {ref}): the cheapest setting reaching each relMSE")
                out.append("")
                out.append(_md_table(["relMSE ≤", "cheapest setting", "kernel ms", "relMSE"],
                                     [[_fmt(r["target"]), r["setting"], _fmt(r["kernel_ms"]),
                                       _fmt(r["relmse"])] for r in rows]))
                out.append("")
        out.append("All points (mean over seeds; ± = std over seeds):")
        out.append("")
        rows = []
        front = {p["key"] for p in pareto(pts, "golden" if g.get("path") else "own")}
        for p in sorted(pts, key=time_of):
            t = p["timing"]
            rows.append([point_label(p["settings"], default) + (" ★" if p["key"] in front else ""),
                         _fmt(t["kernel_ms"]), _fmt(t["frozen_wall_ms"]),
                         _fmt(t["compile_ms"]), _fmt(t.get("trace_ms")),
                         *[f"{_fmt(err_of(p, r))} ± {_fmt(p['errors'][r]['relmse']['std'], 2)}"
                           if p["errors"].get(r) else "–" for r in REFS],
                         *[_fmt(err_of(p, r, "rmse")) for r in REFS],
                         _fmt(err_of(p, "golden", "flip_mean")),
                         _fmt(err_of(p, "golden", "flip_p95")),
                         _fmt(err_of(p, "golden", "de2000_mean"))])
        out.append(_md_table(["setting (★ Pareto)", "kernel ms", "frozen wall ms", "compile ms",
                              "trace ms", "relMSE golden", "relMSE own", "RMSE golden",
                              "RMSE own", "FLIP golden", "FLIP p95 golden", "ΔE00 golden"], rows))
        out.append("")
    return "\n".join(out) + "\n"


_STYLE = {"spp": ("tab:blue", "o"), "max_depth": ("tab:orange", "s"),
          "min_weight": ("tab:green", "^"), "precision": ("tab:red", "D"),
          "intersection": ("tab:purple", "v"), "accel": ("tab:brown", "P"),
          "effects": ("tab:pink", "X"), "combination": ("tab:gray", "*"),
          "shadow_samples": ("tab:olive", "h")}


def plot_scene(data: dict, label: str, out: Path, metric: str = "relmse") -> list[Path]:
    """Log-log error vs kernel time of one scene: one panel per reference (lines per factor,
    the grid as grey dots, the Pareto front in black), and the model change apart."""
    import matplotlib
    matplotlib.use("Agg")
    matplotlib.rcParams["svg.hashsalt"] = "whitted-study"     # same plot, same file
    import matplotlib.pyplot as plt
    pts = scene_points(data, label)
    refs = [r for r in REFS if any(p["errors"].get(r) for p in pts)]
    fig, axes = plt.subplots(1, len(refs) + 1, figsize=(5.2 * (len(refs) + 1), 4.4),
                             squeeze=False)
    axes = axes[0]
    default = data["scenes"][label]["default"]
    for ax, ref in zip(axes, refs):
        def ys(points, ref=ref):
            return [max(err_of(p, ref, metric), 1e-12) for p in points]
        grid = [p for p in pts if len(differs(p["settings"], default)) > 1]
        if grid:
            ax.scatter([time_of(p) for p in grid], ys(grid),
                       s=9, color="0.75", label="spp × depth grid", zorder=1)
        for f in FACTORS:
            if f in MODEL_FACTORS:
                continue
            line = factor_line(data, label, f)
            if len(line) < 2:
                continue
            c, m = _STYLE[f]
            x = [time_of(p) for p in line]
            y = [max(err_of(p, ref, metric), 1e-12) for p in line]
            lo = [max(p["errors"][ref][metric]["min"], 1e-12) for p in line]
            hi = [p["errors"][ref][metric]["max"] for p in line]
            ax.errorbar(x, y, yerr=[np.subtract(y, lo), np.subtract(hi, y)], color=c, marker=m,
                        ms=4, lw=1.2, capsize=2, label=f, zorder=3)
            if f in ("spp", "max_depth", "min_weight"):
                for p, xi, yi in zip(line, x, y):
                    ax.annotate(f"{p['settings'][f]:g}", (xi, yi), fontsize=6, color=c,
                                xytext=(3, 3), textcoords="offset points")
        front = pareto(pts, ref, metric)
        if front:
            ax.step([time_of(p) for p in front], ys(front),
                    where="post", color="k", lw=1, ls="--", zorder=4, label="Pareto front")
            ax.scatter([time_of(p) for p in front], ys(front),
                       s=40, facecolors="none", edgecolors="k", zorder=5)
        g = data["scenes"][label].get("golden", {})
        if ref == "golden" and g.get("noise_rmse") and metric == "rmse":
            ax.axhline(g["noise_rmse"], color="k", lw=0.6, ls=":", label="golden's own noise")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("kernel time per frame (ms)")
        ax.set_ylabel(f"{metric} vs {ref} (mean over seeds; bars: min–max)")
        ax.set_title(f"{label}: vs {'Mitsuba golden' if ref == 'golden' else 'own high-spp'}")
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
        ax.legend(fontsize=7)
    ax = axes[-1]
    line = factor_line(data, label, "combination")
    for ref, c in (("golden", "k"), ("own", "tab:gray")):
        sel = [p for p in line if p["errors"].get(ref)]
        if sel:
            yv = [max(err_of(p, ref, metric), 1e-12) for p in sel]
            ax.scatter([time_of(p) for p in sel], yv, color=c, marker="*", s=60,
                       label=f"vs {ref}")
            for p, y in zip(sel, yv):
                ax.annotate(p["settings"]["combination"], (time_of(p), y),
                            fontsize=7, xytext=(3, 3), textcoords="offset points")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_title(f"{label}: combination (a model change)")
    ax.set_xlabel("kernel time per frame (ms)")
    ax.set_ylabel(metric)
    ax.grid(True, which="both", lw=0.3, alpha=0.5)
    if line:
        ax.legend(fontsize=7)
    fig.tight_layout()
    paths = []
    for ext in ("png", "svg"):
        p = Path(out) / f"{label}.{ext}"
        with atomic_path(p, overwrite=True) as tmp:
            fig.savefig(tmp, format=ext, dpi=110,
                        metadata={"Date": None} if ext == "svg" else None)
        paths.append(p)
    plt.close(fig)
    return paths


def _md_to_html(md: str) -> str:
    """The small markdown subset ``markdown()`` writes (headings, lists, tables, images)."""
    import html
    import re
    out, table = [], []

    def inline(s):
        s = html.escape(s)
        s = re.sub(r"!\[([^\]]*)\]\(([^)]+)\)", r'<img src="\2" alt="\1">', s)
        s = re.sub(r"\[([^\]]+)\]\(([^)]+)\)", r'<a href="\2">\1</a>', s)
        s = re.sub(r"\*\*([^*]+)\*\*", r"<b>\1</b>", s)
        return re.sub(r"`([^`]+)`", r"<code>\1</code>", s)

    def flush():
        if table:
            rows = [r for r in table if not set(r.replace("|", "").strip()) <= {"-"}]
            cells = [[c.strip() for c in r.strip().strip("|").split("|")] for r in rows]
            out.append("<table><tr>" + "".join(f"<th>{inline(c)}</th>" for c in cells[0])
                       + "</tr>" + "".join("<tr>" + "".join(f"<td>{inline(c)}</td>" for c in r)
                                           + "</tr>" for r in cells[1:]) + "</table>")
            table.clear()

    for line in md.splitlines():
        if line.startswith("|"):
            table.append(line)
            continue
        flush()
        if line.startswith("## "):
            out.append(f"<h2>{inline(line[3:])}</h2>")
        elif line.startswith("# "):
            out.append(f"<h1>{inline(line[2:])}</h1>")
        elif line.startswith("- "):
            out.append(f"<li>{inline(line[2:])}</li>")
        elif line.strip():
            out.append(f"<p>{inline(line)}</p>")
    flush()
    return "\n".join(out)


def write_outputs(data: dict, out) -> list[Path]:
    """study.md, <scene>.png/.svg and index.html in ``out`` from the results ``data``."""
    out = check_output_dir(out)
    written = []
    for label in data["scenes"]:
        if scene_points(data, label):
            try:
                written += plot_scene(data, label, out)
            except ImportError:
                break
    md = markdown(data)
    write_text(out / "study.md", md, overwrite=True)
    written.append(out / "study.md")
    page = ("<!doctype html><html><head><meta charset='utf-8'><title>Accuracy vs time</title>"
            "<style>body{font-family:sans-serif;max-width:1400px;margin:auto;padding:1em}"
            "table{border-collapse:collapse;font-size:12px;margin:0.5em 0}"
            "td,th{border:1px solid #ccc;padding:2px 6px}img{max-width:100%}</style></head>"
            f"<body>{_md_to_html(md)}<p><a href='study.json'>study.json</a> (all points)</p>"
            "</body></html>\n")
    write_text(out / "index.html", page, overwrite=True)
    written.append(out / "index.html")
    return written


def strip_timings(data: dict) -> dict:
    """The results without what depends on the run (times, process, device, dates): what
    two runs of the same sweep must agree on."""
    pts = {}
    for k, p in data["points"].items():
        pts[k] = {kk: v for kk, v in p.items()
                  if kk not in ("timing", "seconds", "pid", "device")}
        pts[k]["facts"] = {kk: v for kk, v in p["facts"].items() if kk != "upload_s"}
    return pts


def diff_runs(a: dict, b: dict) -> list[str]:
    """What differs between two runs of the same sweep, timings aside (``strip_timings``):
    one line per differing point and field; [] when they agree."""
    sa, sb = strip_timings(a), strip_timings(b)
    out = [f"only in the first run: {k}" for k in sorted(set(sa) - set(sb))]
    out += [f"only in the second run: {k}" for k in sorted(set(sb) - set(sa))]
    for k in sorted(set(sa) & set(sb)):
        for f in sorted(set(sa[k]) | set(sb[k])):
            if sa[k].get(f) != sb[k].get(f):
                out.append(f"{k}: {f} differs")
    return out


def executor_check(scene_args, out, *, profile="tiny", backend: str = "llvm",
                   workers: int = 1, log=print) -> bool:
    """Run the same sweep in-process and on ``workers`` Dask workers (one GPU each on
    CUDA) into ``out/in-process`` and ``out/dask``; print and return whether the JSON
    agrees minus timings (the executor changes where points run, never what they are)."""
    kw = dict(profile=profile, backend=backend, show_progress=False, outputs=False,
              log=lambda *a: None)
    here = run_study(scene_args, Path(out) / "in-process", **kw)
    there = run_study(scene_args, Path(out) / "dask", workers=workers, **kw)
    diffs = diff_runs(here, there)
    ex = there["meta"].get("executor", {})
    log(f"executor check ({backend}, {len(here['points'])} points, Dask {ex}): "
        + ("JSON minus timings EQUAL to in-process" if not diffs
           else f"{len(diffs)} DIFFERENCES:\n  " + "\n  ".join(diffs[:20])))
    return not diffs


if __name__ == "__main__":  # pragma: no cover
    sys.exit("run the study with `whitted study` or `python -m whitted.study`")
