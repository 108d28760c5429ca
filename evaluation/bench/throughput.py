"""Part ``throughput``: ray throughput, ours vs Mitsuba 3, on identical ray batches.

Primary rays through the pixel centres of the scene's first camera at 1920×1080 (the
renderer's own camera, ``renderer.camera``), and shadow rays from the primary hits to the
first light, go through our accelerator and through Mitsuba's
``scene.ray_intersect_preliminary`` / ``scene.ray_test`` (OptiX on CUDA, Embree on the CPU).
Reports kernel time (``renderer.stats.kernel_ms``), M rays/s and the fraction of rays on
which the two agree.
"""
from __future__ import annotations

import time

import drjit as dr
import numpy as np

from renderer.accel import Ray, build_accelerator
from renderer.device import array3, types
from renderer.stats import kernel_ms

from .. import SEED_SCENES
from .part import Context, Part, jsonable, table

SCENES = SEED_SCENES + ("bunny", "conference", "bunny_1m")


# ---- the accelerator seam: the one place that names the accelerator interface -------------
def _build_accelerator(name: str, scene, t):
    return build_accelerator(name, scene, t)


def _closest(acc, o, d, t_max, active):
    """Closest hit of each ray: (t, prim, found)."""
    h = acc.intersect(Ray(o=o, d=d, t_max=t_max), active)
    return h.t, h.prim, h.found


def _occluded(acc, o, d, t_max, active):
    """Whether anything lies on each ray within t_max: Bool."""
    return acc.intersect_p(Ray(o=o, d=d, t_max=t_max), active)


# ---- identical ray batches ----------------------------------------------------------------
def primary_rays_host(scene, width: int, height: int, t) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre rays of the scene's first camera at ``width``×``height``, from
    ``renderer.camera``: origins (N, 3) and unit directions (N, 3), float32, row-major from
    the top-left pixel."""
    from renderer.camera import camera_arrays, primary_rays
    cam = scene.with_size(width, height).cameras[0]
    o, d = primary_rays(camera_arrays(cam, t), width, height, t)
    d = np.ascontiguousarray(d.numpy().T, np.float32)
    o = np.ascontiguousarray(np.broadcast_to(o.numpy().T, d.shape), np.float32)
    return o, d


def shadow_rays_host(scene, o, d, t, prim_face, light_pos) -> tuple[np.ndarray, np.ndarray,
                                                                   np.ndarray]:
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
    # the same batch for both peers: the scene's override, else the old 1e-4 x diagonal
    eps = scene.ray_offset if scene.ray_offset is not None else 1e-4 * scene.diagonal
    so = p + eps * ng
    sd = light_pos[None] - so
    tmax = np.full(len(so), 1 - 1e-4)
    return so.astype(np.float32), sd.astype(np.float32), tmax.astype(np.float32)


# ---- the measurement ----------------------------------------------------------------------
def ray_throughput(scene, *, backend: str, width: int = 1920, height: int = 1080,
                   repeats: int = 10, accel: str = "bvh") -> dict:
    """Closest-hit and shadow-ray throughput, ours vs Mitsuba, on identical ray batches."""
    from reference import mitsuba_variant
    from reference.mitsuba_scene import load_triangles, rays
    t = types(backend)
    o, d = primary_rays_host(scene, width, height, t)
    n = len(o)

    # ---- ours -----------------------------------------------------------------------------
    t0 = time.perf_counter()
    acc = _build_accelerator(accel, scene, t)
    dr.eval(acc)
    build_s = time.perf_counter() - t0

    o_dev, d_dev = array3(t, o), array3(t, d)
    inf = t.Float(np.full(n, np.inf, np.float32))
    on = dr.full(t.Bool, True, n)
    dr.eval(o_dev, d_dev, inf, on)
    res = {}

    def ours_closest():
        h = _closest(acc, o_dev, d_dev, inf, on)
        dr.eval(*h)
        return h

    res["ours_primary"] = kernel_ms(ours_closest, repeats=repeats)
    h_t, h_prim, h_found = ours_closest()
    valid = h_found.numpy()
    t_ours = np.where(valid, h_t.numpy(), np.inf)
    order = acc.tris.order.numpy().astype(np.int64)
    face_ours = np.where(valid, order[np.minimum(h_prim.numpy(), len(order) - 1)], -1)

    # ---- Mitsuba (one mesh holding every triangle, so prim_index is the face index) -------
    mitsuba_variant("cuda_ad_rgb" if backend == "cuda" else "llvm_ad_rgb")
    mscene, mi_build_s = load_triangles(scene.vertices, scene.faces)
    ray = rays(o, d)
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
        "t_rel_1e-4": float(np.mean(np.abs(t_ours[both] - t_mi[both])
                                    <= 1e-4 * np.abs(t_mi[both]))) if both.any() else 1.0,
        "hits": int(np.isfinite(t_ours).sum()),
    }

    # ---- shadow rays to the first light (from our primary hits) ---------------------------
    if scene.lights:
        so, sd, stmax = shadow_rays_host(scene, o, d, t_ours, np.maximum(face_ours, 0),
                                         scene.lights[0].position)
        m = len(so)
        so_dev, sd_dev, st_dev = array3(t, so), array3(t, sd), t.Float(stmax)
        son = dr.full(t.Bool, True, m)
        dr.eval(so_dev, sd_dev, st_dev, son)

        def ours_shadow():
            b = _occluded(acc, so_dev, sd_dev, st_dev, son)
            dr.eval(b)
            return b

        sray = rays(so, sd, stmax)
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
        count = n if k == "primary" else res.get("shadow_rays", 0)
        for who in ("ours", "mitsuba"):
            if f"{who}_{k}" in res:
                ms = res[f"{who}_{k}"]["kernel_ms"]
                res[f"{who}_{k}"]["mrays_per_s"] = (count / (ms * 1e-3) / 1e6 if ms > 0
                                                    else float("nan"))
    res.update(triangles=scene.face_count, build_s=build_s, mitsuba_build_s=mi_build_s,
               accel=accel, stats=jsonable(acc.stats()))
    return res


# ---- the part -----------------------------------------------------------------------------
def run(ctx: Context) -> list[dict]:
    """Every scene of ``SCENES`` present in the scenes folder, at 1920×1080 (quick: 320×180)."""
    from renderer.scene import load_scene
    w, h = (320, 180) if ctx.quick else (1920, 1080)
    rows = []
    for name in SCENES:
        p = ctx.scene_path(name)
        if not p.exists():
            continue
        r = ray_throughput(load_scene(p), backend=ctx.backend, width=w, height=h,
                           repeats=5 if ctx.quick else 10)
        r["scene"] = name
        rows.append(r)
        print(f"  rays {name:16s} ours {r['ours_primary']['mrays_per_s']:9.1f} Mrays/s"
              f"  mitsuba {r['mitsuba_primary']['mrays_per_s']:9.1f}"
              f"  same tri {r['primary_agreement']['same_triangle']:.4f}", flush=True)
    return rows


def markdown(rows: list[dict]) -> list[str]:
    cells = []
    for r in rows:
        op, mp = r["ours_primary"]["mrays_per_s"], r["mitsuba_primary"]["mrays_per_s"]
        os_ = r.get("ours_shadow", {}).get("mrays_per_s", float("nan"))
        ms_ = r.get("mitsuba_shadow", {}).get("mrays_per_s", float("nan"))
        cells.append([r["scene"], f"{r['triangles']:,}", f"{r['rays']:,}", f"{op:,.0f}",
                      f"{mp:,.0f}", f"{op / mp:.2f}",
                      f"{r['primary_agreement']['same_triangle']:.4f}", f"{os_:,.0f}",
                      f"{ms_:,.0f}", f"{os_ / ms_:.2f}",
                      f"{r.get('shadow_agreement', float('nan')):.4f}", f"{r['build_s']:.2f}"])
    return table("Ray throughput (identical rays; kernel time, median of repeats)",
                 ["scene", "triangles", "rays", "ours primary Mrays/s", "Mitsuba primary",
                  "ratio", "same triangle", "ours shadow Mrays/s", "Mitsuba shadow", "ratio",
                  "shadow agree", "BVH build s"], "lrrrrrrrrrrr", cells)


PART = Part(name="throughput", key="throughput", run=run, markdown=markdown)
