"""Running the study: render a point's seeds (``render_seeds``), measure its error against
the references (``error_metrics``), and the resumable loop over the sweep (``run_study``)
through ``evaluation.gate.executor`` (in-process, or Dask workers)."""

from __future__ import annotations

import hashlib
import json
import math
import os
import platform
import statistics
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from evaluation.gate.executor import make_executor, progress
from evaluation.gate.metrics import delta_e2000, flip_error
from reference.golden import GoldenError, load_golden
from renderer.effects import EffectSet
from renderer.outputs import atomic_path, write_text
from renderer.render import Renderer, make_frame_fn
from renderer.scene import Scene
from renderer.stats import kernel_launches, kernel_ms

from .points import (
    METRICS,
    OPTIONAL_METRICS,
    OPTIONAL_SETTINGS,
    PROFILES,
    REL_EPS,
    ROOT,
    SCHEMA,
    SETTING_KEYS,
    TRIM,
    Profile,
    build_sweep,
    prepare_scene,
)
from .report import write_outputs


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
            def frame(fn=fn, arrays=r.arrays):
                img = fn(ca, arrays, W, H)
                dr.eval(img)
                return img
            img, hist, wall = kernel_launches(frame)
            hist = [h for h in hist if "operation_count" in h]
            compile_ms = sum(float(h.get("codegen_time", 0)) + float(h.get("backend_time", 0))
                             for h in hist)
            exec_ms = sum(float(h.get("execution_time", 0)) for h in hist)
            facts.update(first_frame_ms=wall, compile_ms=compile_ms,
                         trace_ms=max(wall - compile_ms - exec_ms, 0.0),
                         kernels=len(hist),
                         operations=sum(int(h["operation_count"]) for h in hist),
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
class StudyFileError(ValueError):
    """A study.json that cannot be resumed (not JSON, not UTF-8, not a study of this
    schema); the message is one line naming the file."""


def load_results(path: Path) -> dict:
    """The study saved at ``path``, or an empty one when there is none. A file that is there
    but is not a study of ``SCHEMA`` raises ``StudyFileError`` (it is never replaced by a
    fresh study)."""
    path = Path(path)
    if not path.exists():
        return {"schema": SCHEMA, "meta": {}, "scenes": {}, "points": {}}
    try:
        data = json.loads(path.read_bytes().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise StudyFileError(f"{path}: not a study JSON file ({type(e).__name__}: "
                             f"{' '.join(str(e).split())[:120]}); move it away or pick "
                             "another --out") from None
    except IsADirectoryError:
        raise StudyFileError(f"{path}: is a folder, expected study.json") from None
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        found = data.get("schema") if isinstance(data, dict) else type(data).__name__
        raise StudyFileError(f"{path}: not a study of schema {SCHEMA!r} (found {found!r}); "
                             "move it away or pick another --out")
    for key in ("meta", "scenes", "points"):
        if not isinstance(data.get(key, {}), dict):
            raise StudyFileError(f"{path}: field {key!r} is not an object")
        data.setdefault(key, {})
    return data


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
    # CUDA on a local cluster: one GPU per worker (evaluation.gate.executor); a scheduler's own
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
