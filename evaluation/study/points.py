"""The study's plan: profiles, factors, the default setting of a scene and the sweep of
points around it (``build_sweep``), each point a spec with its key."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from renderer.accel import ACCELERATORS, ROUTINES
from renderer.scene import Scene, load_scene

ROOT = Path(__file__).resolve().parents[2]
SCHEMA = 1
#: Denominator floor of relMSE (as in evaluation.gate.metrics / reference.compare).
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


def scene_file(path: str) -> Path:
    """A spec's scene path as a file: absolute as given; relative, from the current folder
    when the file is there, else from the repository root (``ROOT``, a checkout)."""
    p = Path(path)
    return p if p.is_absolute() or p.exists() else ROOT / p


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
    sc = load_scene(scene_file(spec["scene"]), shading=spec.get("shading"))
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


#: Settings only some scenes have (in their default only then): lights with extent.
OPTIONAL_SETTINGS = ("shadow_samples",)
SETTING_KEYS = ("spp", "max_depth", "min_weight", "precision", "combination", "intersection",
                "accel", "effects")


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
        sc = load_scene(scene_file(path), shading=shading)
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


def busy_load(cores: int) -> float:
    """The 1-minute load average above which a CPU run counts as shared with other work:
    the study's own render threads keep the load near the core count, so up to half a
    core more is its own."""
    return cores + 0.5
