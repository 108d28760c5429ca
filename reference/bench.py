"""The timing study: ours vs Mitsuba 3 on the same device, in one process.

Everything is timed from Dr.Jit's kernel history (``JitFlag.KernelHistory``): the sum of
``execution_time`` of the kernels a step launched, median over repeats after warm-up, so
Python tracing is reported separately and never counted as ray-tracing time.

Parts (each a function returning JSON-ready dicts):
- ``ray_throughput``: identical ray batches (primary rays through pixel centres at 1920×1080,
  shadow rays from the primary hits to the first light) through our accelerator and through
  Mitsuba's ``scene.ray_intersect_preliminary`` / ``scene.ray_test`` (OptiX on CUDA, Embree on
  the CPU), with the fraction of rays on which the two agree.
- ``seed_table``: the thesis's table (three seed scenes × three views at 512², primary rays
  only and with reflection, brute force / per-object boxes / BVH), frozen frames.
- ``whitted_frame``: our frozen Whitted frame vs Mitsuba rendering the same scene with the
  reference harness's integrator, with the image difference.
- ``effects_saving``: the scene's specialised kernel vs the all-effects kernel.
"""
from __future__ import annotations

import json
import os
import platform
import statistics
import subprocess
import time
from dataclasses import replace
from pathlib import Path

import drjit as dr
import numpy as np

# The thesis's GeForce 8800 GT numbers (ms per 512² frame, mean of three views).
THESIS_MS = {
    "cornell_box": {"primary": 5.6, "primary_aabb": 5.5, "reflection": 7.6, "reflection_aabb": 9.8},
    "cornell_sphere": {"primary": 138.2, "primary_aabb": 109.0, "reflection": 295.2, "reflection_aabb": 252.8},
    "platonic_solids": {"primary": 207.5, "primary_aabb": 164.4, "reflection": 362.4, "reflection_aabb": 323.8},
}


# ---- timing helpers ----------------------------------------------------------------------
def kernel_ms(fn, *, warmup: int = 2, repeats: int = 10) -> dict:
    """Run ``fn()`` (which must evaluate its results), and time it from the kernel history.

    Returns median/min kernel milliseconds, the median wall time of the whole call
    (tracing + launch + sync) and the number of kernels per call.
    """
    for _ in range(warmup):
        fn()
        dr.sync_thread()
    dr.kernel_history()  # clear
    kern, wall, launches = [], [], []
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        for _ in range(repeats):
            dr.kernel_history()
            t0 = time.perf_counter()
            fn()
            dr.sync_thread()
            wall.append((time.perf_counter() - t0) * 1e3)
            hist = [h for h in dr.kernel_history() if "execution_time" in h]
            kern.append(sum(h["execution_time"] for h in hist))
            launches.append(len(hist))
    return {"kernel_ms": statistics.median(kern), "kernel_ms_min": min(kern),
            "wall_ms": statistics.median(wall), "kernels": statistics.median(launches),
            "repeats": repeats}


def device_info(backend: str) -> dict:
    info = {"backend": backend, "python": platform.python_version(), "drjit": dr.__version__,
            "host": platform.node(), "cpu": platform.processor() or platform.machine(),
            "cores": os.cpu_count()}
    try:
        import mitsuba as mi
        info["mitsuba"] = mi.__version__
    except ImportError:
        pass
    if backend == "cuda":
        try:
            q = subprocess.run(["nvidia-smi", "--query-gpu=name,driver_version,memory.total",
                                "--format=csv,noheader"], capture_output=True, text=True, timeout=30)
            name, driver, mem = (s.strip() for s in q.stdout.strip().split("\n")[0].split(","))
            info.update(device=name, driver=driver, gpu_memory=mem)
        except Exception as e:  # noqa: BLE001 - informational only
            info["device"] = f"unknown GPU ({e})"
    else:
        try:
            model = [l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name")]
            info["device"] = f"{model[0]} ({os.cpu_count()} cores)" if model else "CPU"
        except OSError:
            info["device"] = "CPU"
    return info


# ---- identical ray batches ---------------------------------------------------------------
def primary_rays_np(cam, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre rays of docs/MODEL.md's camera: origins (N,3), unit directions (N,3),
    float32, row-major from the top-left pixel."""
    f = cam.target - cam.position
    f = f / np.linalg.norm(f)
    r = np.cross(f, cam.up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    tan_y = np.tan(np.radians(cam.fov_y) / 2)
    tan_x = tan_y * width / height
    x = (np.arange(width) + 0.5) / width * 2 - 1
    y = 1 - (np.arange(height) + 0.5) / height * 2
    X, Y = np.meshgrid(x, y)
    d = f + (X[..., None] * tan_x) * r + (Y[..., None] * tan_y) * u
    d = (d / np.linalg.norm(d, axis=-1, keepdims=True)).reshape(-1, 3)
    o = np.broadcast_to(cam.position, d.shape)
    return np.ascontiguousarray(o, np.float32), np.ascontiguousarray(d, np.float32)


def shadow_rays_np(scene, o, d, t, prim_face, light_pos) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Shadow rays from the hit points ``o + t d`` (only rays that hit) to ``light_pos``:
    origins offset by ε along the geometric normal on the light's side, unnormalised
    directions to the light, t_max = 1 - 1e-4 (stop just before the light)."""
    hit = np.isfinite(t)
    p = o[hit].astype(np.float64) + t[hit, None] * d[hit].astype(np.float64)
    fa = scene.faces[prim_face[hit]]
    V = scene.vertices.astype(np.float64)
    ng = np.cross(V[fa[:, 1]] - V[fa[:, 0]], V[fa[:, 2]] - V[fa[:, 0]])
    ng /= np.linalg.norm(ng, axis=1, keepdims=True)
    to_l = light_pos[None] - p
    ng *= np.sign(np.sum(ng * to_l, axis=1, keepdims=True) + 1e-30)
    so = p + scene.ray_offset * ng
    sd = light_pos[None] - so
    tmax = np.full(len(so), 1 - 1e-4)
    return so.astype(np.float32), sd.astype(np.float32), tmax.astype(np.float32)


def ray_throughput(scene, *, backend: str, width: int = 1920, height: int = 1080,
                   repeats: int = 10, accel: str = "bvh") -> dict:
    """Closest-hit and shadow-ray throughput, ours vs Mitsuba, on identical ray batches."""
    import mitsuba as mi
    from renderer.device import types
    from renderer.accel import Ray, build_accelerator
    t = types(backend)
    cam = scene.cameras[0]
    o, d = primary_rays_np(cam, width, height)
    n = len(o)

    # -- ours ----------------------------------------------------------------------------
    t0 = time.perf_counter()
    acc = build_accelerator(accel, scene, t)
    dr.eval(acc)
    build_s = time.perf_counter() - t0

    def a3(x, T):
        return T(*(x[:, k].copy() for k in range(3)))

    O, D = a3(o, t.Array3f), a3(d, t.Array3f)
    inf = t.Float(np.full(n, np.inf, np.float32))
    on = dr.full(t.Bool, True, n)
    dr.eval(O, D, inf, on)
    res = {}

    def ours_closest():
        h = acc.intersect(Ray(O, D, inf), on)
        dr.eval(h.t, h.prim, h.found)
        return h

    res["ours_primary"] = kernel_ms(ours_closest, repeats=repeats)
    h = ours_closest()
    valid = h.found.numpy()
    t_ours = np.where(valid, h.t.numpy(), np.inf)
    order = acc.tris.order.numpy().astype(np.int64)
    face_ours = np.where(valid, order[np.minimum(h.prim.numpy(), len(order) - 1)], -1)

    # -- Mitsuba (one mesh holding every triangle, so prim_index is the face index) -----
    variant = "cuda_ad_rgb" if backend == "cuda" else "llvm_ad_rgb"
    mi.set_variant(variant)
    mesh = mi.Mesh("all", scene.vertices.shape[0], scene.faces.shape[0])
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(scene.vertices.astype(np.float32).ravel())
    params["faces"] = mi.UInt32(scene.faces.astype(np.uint32).ravel())
    params.update()
    t0 = time.perf_counter()
    mscene = mi.load_dict({"type": "scene", "mesh": mesh})
    mi_build_s = time.perf_counter() - t0
    ray = mi.Ray3f(mi.Point3f(*(mi.Float(o[:, k].copy()) for k in range(3))),
                   mi.Vector3f(*(mi.Float(d[:, k].copy()) for k in range(3))))
    dr.eval(ray)

    def mi_closest():
        pi = mscene.ray_intersect_preliminary(ray, coherent=True)
        dr.eval(pi.t, pi.prim_index)
        return pi

    res["mitsuba_primary"] = kernel_ms(mi_closest, repeats=repeats)
    pi = mi_closest()
    t_mi = pi.t.numpy()
    face_mi = np.where(np.isfinite(t_mi), pi.prim_index.numpy().astype(np.int64), -1)

    both = np.isfinite(t_ours) & np.isfinite(t_mi)
    res["primary_agreement"] = {
        "hit_miss_agree": float(np.mean(np.isfinite(t_ours) == np.isfinite(t_mi))),
        "same_triangle": float(np.mean(face_ours == face_mi)),
        "t_rel_1e-4": float(np.mean(np.abs(t_ours[both] - t_mi[both]) <= 1e-4 * np.abs(t_mi[both]))) if both.any() else 1.0,
        "hits": int(np.isfinite(t_ours).sum()),
    }

    # -- shadow rays to the first light (from our primary hits) ----------------------------
    if scene.lights:
        so, sd, stmax = shadow_rays_np(scene, o, d, t_ours, np.maximum(face_ours, 0),
                                       scene.lights[0].position)
        m = len(so)
        SO, SD, ST = a3(so, t.Array3f), a3(sd, t.Array3f), t.Float(stmax)
        son = dr.full(t.Bool, True, m)
        dr.eval(SO, SD, ST, son)

        def ours_shadow():
            b = acc.intersect_p(Ray(SO, SD, ST), son)
            dr.eval(b)
            return b

        sray = mi.Ray3f(mi.Point3f(*(mi.Float(so[:, k].copy()) for k in range(3))),
                        mi.Vector3f(*(mi.Float(sd[:, k].copy()) for k in range(3))),
                        mi.Float(stmax), mi.Float(0.0), mi.Color0f())
        dr.eval(sray)

        def mi_shadow():
            b = mscene.ray_test(sray, coherent=False)
            dr.eval(b)
            return b

        res["ours_shadow"] = kernel_ms(ours_shadow, repeats=repeats)
        res["mitsuba_shadow"] = kernel_ms(mi_shadow, repeats=repeats)
        res["shadow_agreement"] = float(np.mean(ours_shadow().numpy() == mi_shadow().numpy()))
        res["shadow_rays"] = m
    res["rays"] = n
    for k in ("primary", "shadow"):
        rays = n if k == "primary" else res.get("shadow_rays", 0)
        for who in ("ours", "mitsuba"):
            if f"{who}_{k}" in res:
                ms = res[f"{who}_{k}"]["kernel_ms"]
                res[f"{who}_{k}"]["mrays_per_s"] = rays / (ms * 1e-3) / 1e6 if ms > 0 else float("nan")
    res.update(triangles=scene.face_count, build_s=build_s, mitsuba_build_s=mi_build_s,
               accel=accel, stats=_jsonable(acc.stats()))
    return res


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.floating,)):
        return float(x)
    if isinstance(x, (int, float, str, bool)) or x is None:
        return x
    return str(x)


# ---- frozen frames -------------------------------------------------------------------------
def frozen_frame_ms(scene, *, backend: str, accel: str, view: int = 0, effects=None,
                    frames: int = 20, warmup: int = 3, size: tuple[int, int] | None = None) -> dict:
    """Median time of ``frames`` frozen frames of ``scene`` (after ``warmup``), plus the
    traced (first) frame's wall time and the kernels' operation counts."""
    from renderer.render import Renderer
    if size:
        scene = replace(scene, cameras=[replace(c, width=size[0], height=size[1]) for c in scene.cameras])
    cam = scene.cameras[view]
    traced = Renderer(scene, backend=backend, accel=accel, effects=effects)
    ca = traced.camera(view)
    dr.sync_thread()
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        dr.kernel_history()
        t0 = time.perf_counter()
        img = traced.frame(ca, cam.width, cam.height)
        dr.sync_thread()
        traced_ms = (time.perf_counter() - t0) * 1e3
        hist = [h for h in dr.kernel_history() if "operation_count" in h]
    ops = [int(h["operation_count"]) for h in hist]
    frozen = Renderer(scene, backend=backend, accel=accel, effects=effects, freeze=True)
    fca = frozen.camera(view)
    timing = kernel_ms(lambda: frozen.frame(fca, cam.width, cam.height), warmup=warmup, repeats=frames)
    same = bool(np.array_equal(img.numpy(), frozen.frame(fca, cam.width, cam.height).numpy()))
    return {"frozen_ms": timing["wall_ms"], "frozen_kernel_ms": timing["kernel_ms"],
            "traced_ms": traced_ms, "operations": sum(ops), "largest_kernel_ops": max(ops, default=0),
            "kernels": len(ops), "frozen_equals_traced": same, "frames": frames,
            "effects": str(traced.effects), "image": img.numpy()}


def seed_table(scene_paths, *, backend: str, frames: int = 20, size=(512, 512)) -> list[dict]:
    """The thesis's table: each seed scene × its three views, primary rays only (depth 0:
    local light and shadows) and with reflection (the scene's full Whitted tree), for brute
    force, per-object boxes and the BVH; ms per frame = mean over the views of the median of
    ``frames`` frozen frames."""
    from renderer.scene import load_scene
    rows = []
    for path in scene_paths:
        scene = load_scene(path)
        for test, depth in (("primary", 0), ("reflection", scene.settings.max_depth)):
            sc = scene.with_settings(max_depth=depth)
            for accel in ("brute", "boxes", "bvh"):
                per_view = [frozen_frame_ms(sc, backend=backend, accel=accel, view=v,
                                            frames=frames, size=size)
                            for v in range(len(sc.cameras))]
                ms = float(np.mean([p["frozen_ms"] for p in per_view]))
                kms = float(np.mean([p["frozen_kernel_ms"] for p in per_view]))
                key = test + ("_aabb" if accel == "boxes" else "")
                thesis = THESIS_MS.get(scene.name, {}).get(key if accel != "bvh" else test)
                rows.append({"scene": scene.name, "test": test, "accel": accel, "ms": ms,
                             "kernel_ms": kms, "views": len(per_view),
                             "frozen_equals_traced": all(p["frozen_equals_traced"] for p in per_view),
                             "thesis_ms": thesis,
                             "speedup_vs_thesis": thesis / ms if thesis and ms > 0 else None})
                print(f"  seed {scene.name:16s} {test:10s} {accel:5s} {ms:9.3f} ms"
                      + (f"  (thesis {thesis} ms, {thesis / ms:,.0f}x)" if thesis else ""), flush=True)
    return rows


def whitted_frame(scene, *, backend: str, frames: int = 20, accel: str = "bvh",
                  mitsuba_repeats: int = 5, strip_path=None) -> dict:
    """Our frozen Whitted frame vs Mitsuba rendering the same scene (exact mode, same
    resolution and depth) with the reference harness's integrator; plus the image
    difference between the two."""
    from reference import mitsuba_variant
    from reference.mitsuba_scene import load, render_exact
    import mitsuba as mi
    ours = frozen_frame_ms(scene, backend=backend, accel=accel, frames=frames)
    mi.set_variant(mitsuba_variant("cuda_ad_rgb" if backend == "cuda" else "llvm_ad_rgb"))
    msc = load(scene, view=0, mode="exact", spp=1)
    mt = kernel_ms(lambda: render_exact(msc), warmup=1, repeats=mitsuba_repeats)
    ref = render_exact(msc)
    m = image_difference(ours["image"], ref)
    if strip_path is not None:
        write_strip(strip_path, ours["image"], ref)
    cam = scene.cameras[0]
    return {"scene": scene.name, "size": [cam.width, cam.height], "depth": scene.settings.max_depth,
            "ours_frozen_ms": ours["frozen_ms"], "ours_kernel_ms": ours["frozen_kernel_ms"],
            "ours_traced_ms": ours["traced_ms"], "effects": ours["effects"],
            "mitsuba_kernel_ms": mt["kernel_ms"], "mitsuba_wall_ms": mt["wall_ms"],
            "mitsuba_kernels": mt["kernels"],
            "difference": m}


def write_strip(path, ours, ref) -> None:
    """PNG: ours | Mitsuba | outlier pixels (white), sRGB."""
    import imageio.v3 as iio
    from renderer.film import srgb_encode
    a, r = np.asarray(ours, np.float64), np.asarray(ref, np.float64)
    err = np.abs(a - r)
    bad = np.any((err / np.maximum(np.abs(r), 1e-2) > 0.1) & (err > 0.01), axis=-1)
    mask = np.repeat(bad[..., None], 3, -1).astype(np.uint8) * 255
    iio.imwrite(path, np.concatenate([srgb_encode(a), srgb_encode(r), mask], 1))


def image_difference(ours, ref) -> dict:
    """RMSE, max abs, mean relative error and outlier pixels (reference.compare's rule:
    some channel with relative error > 0.1 and absolute error > 0.01), numpy only so the
    benchmark runs where colour-science and FLIP are not installed."""
    a, r = np.asarray(ours, np.float64), np.asarray(ref, np.float64)
    err = np.abs(a - r)
    rel = err / np.maximum(np.abs(r), 1e-2)
    return {"rmse": float(np.sqrt(np.mean(err ** 2))), "max_abs": float(err.max()),
            "mean_rel": float(rel.max(axis=-1).mean()),
            "outliers": int(np.sum(np.any((rel > 0.1) & (err > 0.01), axis=-1)))}


def effects_saving(scene, *, backend: str, frames: int = 20, accel: str = "bvh") -> dict:
    """The scene's specialised kernel vs the all-effects kernel: operations and time."""
    from renderer.effects import EffectSet
    spec = frozen_frame_ms(scene, backend=backend, accel=accel, frames=frames)
    gen = frozen_frame_ms(scene, backend=backend, accel=accel, frames=frames,
                          effects=EffectSet.all(scene))
    return {"scene": scene.name, "effects": spec["effects"],
            "ops_specialised": spec["operations"], "ops_general": gen["operations"],
            "ms_specialised": spec["frozen_ms"], "ms_general": gen["frozen_ms"],
            "saved_ms": gen["frozen_ms"] - spec["frozen_ms"],
            "same_pixels": bool(np.array_equal(spec["image"], gen["image"])),
            "max_rel_diff": float(np.max(np.abs(spec["image"] - gen["image"])
                                         / np.maximum(np.abs(gen["image"]), 1e-6)))}


# ---- the whole study ---------------------------------------------------------------------------
SEED_SCENES = ("cornell_box", "cornell_sphere", "platonic_solids")
THROUGHPUT_SCENES = SEED_SCENES + ("bunny", "conference", "bunny_1m")
EFFECT_SCENES = SEED_SCENES + ("analytic_quad", "bunny", "glass_bunny")


def run(out_dir, *, backend: str = "auto", scenes_dir="scenes", quick: bool = False,
        parts=("throughput", "seed", "whitted", "effects")) -> dict:
    """Run the benchmark parts and write ``bench-<backend>.json`` and ``.md`` in ``out_dir``.

    ``quick`` shrinks every size (for a smoke run on a CPU): 1920×1080 → 320×180,
    512² → 128², 20 frozen frames → 5.
    """
    from renderer.device import types
    from renderer.scene import load_scene
    backend = types(backend).backend
    sd = Path(scenes_dir)
    frames = 5 if quick else 20
    info = device_info(backend)
    print(f"bench on {info.get('device')} ({backend})", flush=True)
    result = {"device": info, "quick": quick, "date": time.strftime("%Y-%m-%d %H:%M:%S")}
    if "throughput" in parts:
        result["throughput"] = []
        w, h = (320, 180) if quick else (1920, 1080)
        for name in THROUGHPUT_SCENES:
            p = sd / f"{name}.toml"
            if not p.exists():
                continue
            r = ray_throughput(load_scene(p), backend=backend, width=w, height=h,
                               repeats=5 if quick else 10)
            r["scene"] = name
            result["throughput"].append(r)
            print(f"  rays {name:16s} ours {r['ours_primary']['mrays_per_s']:9.1f} Mrays/s"
                  f"  mitsuba {r['mitsuba_primary']['mrays_per_s']:9.1f}"
                  f"  same tri {r['primary_agreement']['same_triangle']:.4f}", flush=True)
    if "seed" in parts:
        result["seed_table"] = seed_table([sd / f"{n}.toml" for n in SEED_SCENES], backend=backend,
                                          frames=frames, size=(128, 128) if quick else (512, 512))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if "whitted" in parts:
        result["whitted"] = []
        for name in SEED_SCENES:
            sc = load_scene(sd / f"{name}.toml")
            n = 128 if quick else 512
            sc = replace(sc, cameras=[replace(c, width=n, height=n) for c in sc.cameras])
            r = whitted_frame(sc, backend=backend, frames=frames,
                              strip_path=out / f"whitted-{name}-{backend}.png")
            result["whitted"].append(r)
            print(f"  whitted {name:16s} ours {r['ours_frozen_ms']:.3f} ms  mitsuba kernels "
                  f"{r['mitsuba_kernel_ms']:.3f} ms  rmse {r['difference']['rmse']:.2e}", flush=True)
    if "effects" in parts:
        result["effects"] = []
        for name in EFFECT_SCENES:
            p = sd / f"{name}.toml"
            if not p.exists():
                continue
            sc = load_scene(p)
            n = 128 if quick else 512
            sc = replace(sc, cameras=[replace(c, width=n, height=n) for c in sc.cameras])
            r = effects_saving(sc, backend=backend, frames=frames)
            result["effects"].append(r)
            print(f"  effects {name:16s} ops {r['ops_specialised']} vs {r['ops_general']}  "
                  f"{r['ms_specialised']:.3f} vs {r['ms_general']:.3f} ms", flush=True)
    tag = backend + ("-quick" if quick else "")
    (out / f"bench-{tag}.json").write_text(json.dumps(_jsonable(result), indent=1))
    (out / f"bench-{tag}.md").write_text(markdown(result))
    print(f"wrote {out / f'bench-{tag}.json'} and .md", flush=True)
    return result


def markdown(r: dict) -> str:
    """The results as markdown tables."""
    dev = r["device"]
    lines = [f"# Benchmark on {dev.get('device')} ({dev['backend']})", "",
             f"{r['date']}; drjit {dev.get('drjit')}, mitsuba {dev.get('mitsuba')}"
             + (f", driver {dev['driver']}" if dev.get("driver") else "")
             + ("; QUICK smoke sizes" if r.get("quick") else ""), ""]
    if r.get("throughput"):
        lines += ["## Ray throughput (identical rays; kernel time, median of repeats)", "",
                  "| scene | triangles | rays | ours primary Mrays/s | Mitsuba primary | ratio | same triangle | ours shadow Mrays/s | Mitsuba shadow | ratio | shadow agree | BVH build s |",
                  "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
        for t in r["throughput"]:
            op, mp = t["ours_primary"]["mrays_per_s"], t["mitsuba_primary"]["mrays_per_s"]
            os_ = t.get("ours_shadow", {}).get("mrays_per_s", float("nan"))
            ms_ = t.get("mitsuba_shadow", {}).get("mrays_per_s", float("nan"))
            lines.append(f"| {t['scene']} | {t['triangles']:,} | {t['rays']:,} | {op:,.0f} | {mp:,.0f} | "
                         f"{op / mp:.2f} | {t['primary_agreement']['same_triangle']:.4f} | {os_:,.0f} | "
                         f"{ms_:,.0f} | {os_ / ms_:.2f} | {t.get('shadow_agreement', float('nan')):.4f} | "
                         f"{t['build_s']:.2f} |")
        lines.append("")
    if r.get("seed_table"):
        lines += ["## The thesis's table (ms per frame, mean of three views, median of frozen frames)", "",
                  "| scene | test | accel | ms | kernel ms | thesis 8800 GT ms | speed-up |",
                  "| --- | --- | --- | ---: | ---: | ---: | ---: |"]
        for s in r["seed_table"]:
            th = f"{s['thesis_ms']}" if s["thesis_ms"] else "—"
            sp = f"{s['speedup_vs_thesis']:,.0f}×" if s["speedup_vs_thesis"] else "—"
            lines.append(f"| {s['scene']} | {s['test']} | {s['accel']} | {s['ms']:.3f} | "
                         f"{s['kernel_ms']:.3f} | {th} | {sp} |")
        lines.append("")
    if r.get("whitted"):
        lines += ["## Whitted frame, ours (frozen) vs Mitsuba (reference integrator), exact mode", "",
                  "| scene | size | depth | ours traced ms | ours frozen ms | ours kernel ms | Mitsuba kernel ms | Mitsuba wall ms | RMSE | outlier px | mean rel |",
                  "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
        for w in r["whitted"]:
            d = w["difference"]
            lines.append(f"| {w['scene']} | {w['size'][0]}×{w['size'][1]} | {w['depth']} | "
                         f"{w['ours_traced_ms']:.2f} | {w['ours_frozen_ms']:.3f} | {w['ours_kernel_ms']:.3f} | {w['mitsuba_kernel_ms']:.3f} | "
                         f"{w['mitsuba_wall_ms']:.1f} | {d['rmse']:.2e} | {d['outliers']} | {d['mean_rel']:.2e} |")
        lines.append("")
    if r.get("effects"):
        lines += ["## Effects: the scene's specialised kernel vs all effects", "",
                  "| scene | effects on | ops specialised | ops general | ms specialised | ms general | saved ms | same pixels |",
                  "| --- | --- | ---: | ---: | ---: | ---: | ---: | --- |"]
        for e in r["effects"]:
            lines.append(f"| {e['scene']} | {e['effects']} | {e['ops_specialised']:,} | {e['ops_general']:,} | "
                         f"{e['ms_specialised']:.3f} | {e['ms_general']:.3f} | {e['saved_ms']:.3f} | "
                         f"{'yes' if e['same_pixels'] else 'max rel ' + format(e['max_rel_diff'], '.1e')} |")
        lines.append("")
    return "\n".join(lines)
