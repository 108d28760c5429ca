"""Part ``throughput``: ray throughput, ours vs Mitsuba 3, on identical ray batches.

Four batches per scene, built on the host once and uploaded to both (``BATCHES``):

- ``primary``: rays through the pixel centres of the scene's first camera at 1920×1080
  (the renderer's own camera, ``renderer.camera``);
- ``shadow``: from the primary hits to the first light (any-hit only);
- ``incoherent``: as many rays with uniformly random origins in the scene's box and
  uniformly random directions (fixed seed ``SEED``);
- ``reflection``: mirror-reflection rays off the primary hits (origin offset along the
  geometric normal on the incoming side).

Each batch goes through every accelerator of ``ACCELS`` (the binary BVH and the wide BVHs
collapsed from that same binary build) and through Mitsuba's
``scene.ray_intersect_preliminary`` (closest hit) / ``scene.ray_test`` (any hit) (OptiX on
CUDA, Embree on the CPU), closest hit and any hit for each batch but ``shadow``. Timing:
kernel time from Dr.Jit's kernel history and the process's CPU time of the evaluation
(``_timed``), every contender timed in turn within each repeat (so a load spike on a
shared machine hits all of them), median of repeats. Reported
per query: M rays/s, the agreement with Mitsuba (hit/miss, same triangle, ``t`` within
1e-4 relative; any hit: same answer), and from the instrumented traversal (``counts``) the
node steps, triangle steps and loop iterations per ray, mean and the mean over SIMD
packets (16 lanes on the CPU, 32-lane warps on CUDA) of the packet's maximum. Build:
the binary SAH build's throughput (triangles/s) and each collapse's time.
"""
from __future__ import annotations

import statistics
import time
from dataclasses import replace

import drjit as dr
import numpy as np

from renderer.accel import ACCELERATORS, Ray, build_accelerator
from renderer.accel.bvh_build import build_bvh
from renderer.accel.order import SortedQueries
from renderer.accel.ploc import build_ploc
from renderer.device import array3, types
from renderer.stats import kernel_launches

from .. import SEED_SCENES
from .part import Context, Part, jsonable, table

SCENES = SEED_SCENES + ("bunny", "sponza", "conference", "bunny_1m")
ACCELS = ("bvh", "bvh4", "bvh8")     # binary, and the wide BVHs collapsed from it
BATCHES = ("primary", "shadow", "incoherent", "reflection")
#: Variants of an accelerator of ``ACCELS``: queries for evaluated batches, the rays sorted
#: first (``renderer.accel.order.SortedQueries``; CPU only: on the GPU the sort costs more
#: than it saves, ``lab/notes/ray-sort.md``) and lanes that take the next ray
#: when theirs is done (``traverse.refill_traversal``, ``REFILL`` rays per lane by
#: backend); and the BVH built without spatial splits (``build_bvh(spatial=0)``; only in
#: scenes where the default build cuts references), to show what the splits gain or cost;
#: and the binary and 4-wide BVHs over the device-built tree (``renderer.accel.ploc``, what
#: ``--build device`` traces), so every row shows both trees.
#: The backends and the batches each kind runs on.
VARIANTS = {"bvh4+sort": ("bvh4", "sort"), "bvh4+refill": ("bvh4", "refill"),
            "bvh-nosplit": ("bvh", "nosplit"), "bvh-ploc": ("bvh", "ploc"),
            "bvh4-ploc": ("bvh4", "ploc")}
VARIANT_BACKENDS = {"sort": ("llvm",), "refill": ("llvm", "cuda"),
                    "nosplit": ("llvm", "cuda"), "ploc": ("llvm", "cuda")}
VARIANT_BATCHES = {"sort": ("incoherent", "reflection"),
                   "refill": ("incoherent", "reflection"), "nosplit": BATCHES,
                   "ploc": BATCHES}
EAGER = ("sort", "refill")            # kinds that launch kernels while tracing
#: Variants shown beside the contenders but never "best": other trees than the one the
#: renderer builds by default.
NOT_CONTENDERS = ("bvh-nosplit", "bvh-ploc", "bvh4-ploc")
#: Rays per lane of the refill variant by backend: on CUDA 16 per thread beat 8 on every
#: incoherent batch (``lab/notes/refill-count.md``).
REFILL = {"llvm": 32, "cuda": 16}
SEED = 12                           # the incoherent batch's random generator
#: Offset of the host-side reflection batch's origins (fraction of the scene diagonal): both
#: renderers get the same rays, so any offset that clears the surface will do.
OVERRIDE_EPSILON = 1e-4


# ---- the accelerator seam: the one place that names the accelerator interface -------------
def _build_accelerator(name: str, scene, t, binary=None):
    if binary is None:
        return build_accelerator(name, scene, t)
    return ACCELERATORS[name].build(scene, t, binary=binary)


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


def incoherent_rays_host(scene, n: int, seed: int = SEED) -> tuple[np.ndarray, np.ndarray]:
    """``n`` rays with origins uniform in the box of the scene's vertices and directions
    uniform on the sphere (normalised Gaussians), float32, from ``default_rng(seed)``."""
    rng = np.random.default_rng(seed)
    V = scene.vertices.astype(np.float64)
    lo, hi = V.min(axis=0), V.max(axis=0)
    o = lo + rng.random((n, 3)) * (hi - lo)
    d = rng.standard_normal((n, 3))
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-30)
    return o.astype(np.float32), d.astype(np.float32)


def reflection_rays_host(scene, o, d, t, prim_face) -> tuple[np.ndarray, np.ndarray]:
    """Mirror reflections of the rays ``(o, d)`` at their hits ``o + t d`` (only the rays
    that hit, ``t`` finite) off the geometric normal of face ``prim_face``: origins offset
    by ``scene.ray_offset`` along the normal on the incoming side, unit directions."""
    hit = np.isfinite(t)
    dd = d[hit].astype(np.float64)
    dd /= np.linalg.norm(dd, axis=1, keepdims=True)
    p = o[hit].astype(np.float64) + t[hit, None] * d[hit].astype(np.float64)
    fa = scene.faces[prim_face[hit]]
    V = scene.vertices.astype(np.float64)
    ng = np.cross(V[fa[:, 1]] - V[fa[:, 0]], V[fa[:, 2]] - V[fa[:, 0]])
    ng /= np.maximum(np.linalg.norm(ng, axis=1, keepdims=True), 1e-300)
    cos = np.sum(dd * ng, axis=1, keepdims=True)
    r = dd - 2.0 * cos * ng
    side = -np.where(cos > 0, 1.0, -1.0) * ng                  # the incoming side
    ro = p + OVERRIDE_EPSILON * max(scene.diagonal, 1e-30) * side
    return ro.astype(np.float32), r.astype(np.float32)


def upload_batch(t, bo, bd, btmax=None) -> tuple:
    """The host batch ``(bo, bd, btmax)`` (t_max inf where None) on the device for both
    renderers: ``(ray, on, mitsuba_ray)``, evaluated."""
    from reference.mitsuba_scene import rays
    btmax = np.full(len(bo), np.inf, np.float32) if btmax is None else btmax
    ray = Ray(o=array3(t, bo), d=array3(t, bd), t_max=t.Float(btmax))
    on = dr.full(t.Bool, True, len(bo))
    mray = rays(bo, bd, btmax if np.all(np.isfinite(btmax)) else None)
    dr.eval(ray, on, mray)
    return ray, on, mray


def mitsuba_query(mscene, mray, query: str, coherent: bool):
    """Mitsuba's query of ``mray`` as a function to time: closest hit (``(t, prim_index)``
    of ``ray_intersect_preliminary``) or any hit (``ray_test``)."""
    if query == "closest":
        def closest():
            pi = mscene.ray_intersect_preliminary(mray, coherent=coherent)
            return pi.t, pi.prim_index
        return closest
    return lambda: mscene.ray_test(mray, coherent=coherent)


# ---- the measurement ----------------------------------------------------------------------
def _timed(fns: dict, repeats: int, warmup: int = 2, eager=()) -> dict:
    """Time each ``fns[name]()``, which traces a query and returns the variables to
    evaluate: kernel time as ``renderer.stats.kernel_ms`` reports it, and the process's CPU
    time of the evaluation alone (``time.process_time`` around ``dr.eval`` + sync: every
    thread of this process, Dr.Jit's workers and Embree's alike, no Python tracing). The
    contenders are timed in turn within every repeat (round robin). Why CPU time: on a
    shared, oversubscribed CPU the scheduler time-slices a long kernel with the other
    processes while a short one may finish within one slice, so wall-clock kernel time
    penalises the slower contender more than its work; CPU time counts the work.
    ``eager``: names of contenders that launch kernels while tracing (the sorted queries
    sort and gather the batch first): their CPU time includes the call itself, Python
    tracing and all (conservative); kernel time includes those kernels for everyone."""
    def once(fn, whole=False):
        c0 = time.process_time()
        out = fn()
        if not whole:
            c0 = time.process_time()
        dr.eval(out)
        dr.sync_thread()
        return time.process_time() - c0

    for k, fn in fns.items():
        for _ in range(warmup):
            once(fn, k in eager)
    kern = {k: [] for k in fns}
    wall = {k: [] for k in fns}
    cpu = {k: [] for k in fns}
    for _ in range(repeats):
        for k, fn in fns.items():
            cpu_s, hist, ms = kernel_launches(lambda fn=fn, k=k: once(fn, k in eager))
            cpu[k].append(cpu_s * 1e3)
            wall[k].append(ms)
            kern[k].append(sum(h["execution_time"] for h in hist if "execution_time" in h))
    return {k: {"kernel_ms": statistics.median(kern[k]), "kernel_ms_min": min(kern[k]),
                "cpu_ms": statistics.median(cpu[k]), "cpu_ms_min": min(cpu[k]),
                "wall_ms": statistics.median(wall[k]), "repeats": repeats} for k in fns}


def _rate(timing: dict, n: int) -> dict:
    ms, cpu = timing["kernel_ms"], timing["cpu_ms"]
    return dict(timing, mrays_per_s=n / (ms * 1e-3) / 1e6 if ms > 0 else float("nan"),
                mrays_per_cpu_s=n / (cpu * 1e-3) / 1e6 if cpu > 0 else float("nan"))


def _steps(acc, ray, on, any_hit: bool, lanes: int) -> dict | None:
    """Node steps, triangle steps and loop iterations per ray of ``acc``'s instrumented
    traversal (None when it has none): mean, and mean over packets of ``lanes`` rays of
    the packet's maximum (what a SIMD packet or warp executes)."""
    if not hasattr(acc, "counts"):
        return None
    out = {}
    for name, c in zip(("node", "triangle", "iterations"), acc.counts(ray, on, any_hit)):
        x = c.numpy().astype(np.int64)
        m = len(x) // lanes * lanes
        out[name] = float(x.mean()) if len(x) else 0.0
        out[name + "_packet_max"] = (float(x[:m].reshape(-1, lanes).max(axis=1).mean())
                                     if m else out[name])
    return out


def _agreement_closest(t_ours, face_ours, t_mi, face_mi) -> dict:
    both = np.isfinite(t_ours) & np.isfinite(t_mi)
    return {
        "hit_miss_agree": float(np.mean(np.isfinite(t_ours) == np.isfinite(t_mi))),
        "same_triangle": float(np.mean(face_ours == face_mi)),
        "t_rel_1e-4": float(np.mean(np.abs(t_ours[both] - t_mi[both])
                                    <= 1e-4 * np.abs(t_mi[both]))) if both.any() else 1.0,
        "hits": int(np.isfinite(t_ours).sum()),
    }


def ray_throughput(scene, *, backend: str, width: int = 1920, height: int = 1080,
                   repeats: int = 10, accels=ACCELS, batches=BATCHES,
                   steps: bool = True) -> dict:
    """Closest-hit and any-hit throughput of ``accels`` vs Mitsuba on the identical
    ``batches`` (see the module docstring) of ``width``×``height`` rays. ``steps``: also
    run the instrumented traversals. The legacy keys (``ours_primary``, ``ours_shadow``,
    ``primary_agreement`` ...) hold the first accelerator's primary and shadow rows."""
    from reference import mitsuba_variant
    from reference.mitsuba_scene import load_triangles
    t = types(backend)
    lanes = 32 if t.backend == "cuda" else 16
    o, d = primary_rays_host(scene, width, height, t)
    n = len(o)

    # ---- builds: one binary SAH build, uploaded as is and collapsed to the wide BVHs -------
    t0, c0 = time.perf_counter(), time.process_time()
    binary = build_bvh(scene.vertices, scene.faces)
    binary_s, binary_cpu = time.perf_counter() - t0, time.process_time() - c0
    accs, build = {}, {"triangles": scene.face_count, "binary_build_s": binary.build_seconds,
                       "optimize_s": binary.optimize_seconds,
                       "binary_build_cpu_s": binary_cpu, "references": int(binary.order.size),
                       "triangles_per_s": scene.face_count / max(binary.build_seconds, 1e-9),
                       "triangles_per_cpu_s": scene.face_count / max(binary_cpu, 1e-9)}
    for name in accels:
        t0 = time.perf_counter()
        accs[name] = _build_accelerator(name, scene, t, binary=binary)
        dr.eval(accs[name])
        build[name] = {"seconds": binary_s + time.perf_counter() - t0,
                       "stats": jsonable(accs[name].stats())}
    mitsuba_variant("cuda_ad_rgb" if backend == "cuda" else "llvm_ad_rgb")
    mscene, mi_build_s = load_triangles(scene.vertices, scene.faces)
    build["mitsuba_build_s"] = mi_build_s
    first = accels[0]

    sorted_q, kinds = {}, {}
    ploc = None
    for s, (a, kind) in VARIANTS.items():
        if a not in accs or t.backend not in VARIANT_BACKENDS[kind]:
            continue
        if kind == "ploc":
            if ploc is None:
                ploc = build_ploc(scene.vertices, scene.faces, t.backend)
                build["ploc"] = {"binary_build_s": ploc.build_seconds,
                                 "sah_cost": ploc.sah_cost, "sah_cost_sah": binary.sah_cost}
            sorted_q[s] = _build_accelerator(a, scene, t, binary=ploc)
            dr.eval(sorted_q[s])
        elif kind == "sort":
            sorted_q[s] = SortedQueries.for_scene(accs[a], scene)
        elif kind == "refill":
            sorted_q[s] = replace(accs[a], refill=REFILL[t.backend])
        else:
            if binary.cells is None:      # the default build cut no reference: same tree
                continue
            sb = build_bvh(scene.vertices, scene.faces, spatial=0.0)
            build[s] = {"binary_build_s": sb.build_seconds, "references": int(sb.order.size),
                        "sah_cost": sb.sah_cost}
            sorted_q[s] = _build_accelerator(a, scene, t, binary=sb)
            dr.eval(sorted_q[s])
        kinds[s] = kind
    eager = tuple(s for s in sorted_q if kinds[s] in EAGER)

    def variants_for(batch: str) -> dict:
        return {s: v for s, v in sorted_q.items() if batch in VARIANT_BATCHES[kinds[s]]}

    def measure(name, bo, bd, btmax, queries, coherent):
        m = len(bo)
        ray, on, mray = upload_batch(t, bo, bd, btmax)
        out = {"rays": m}
        contenders = dict(accs, **variants_for(name))
        for q in queries:
            fns = {}
            for a, acc in contenders.items():
                if q == "closest":
                    fns[a] = lambda acc=acc: _closest(acc, ray.o, ray.d, ray.t_max, on)
                else:
                    fns[a] = lambda acc=acc: _occluded(acc, ray.o, ray.d, ray.t_max, on)
            mi_trace = mitsuba_query(mscene, mray, q, coherent)

            def mi_fn(mi_trace=mi_trace):
                out = mi_trace()
                dr.eval(out)
                return out
            fns["mitsuba"] = mi_trace
            timing = _timed(fns, repeats, eager=eager) if m else {}
            res = {"ms": {k: _rate(v, m) for k, v in timing.items()}}
            if m and q == "closest":
                ht, hp, hf = _closest(accs[first], ray.o, ray.d, ray.t_max, on)
                valid = hf.numpy()
                t_ours = np.where(valid, ht.numpy(), np.inf)
                order = accs[first].tris.order.numpy().astype(np.int64)
                face = np.where(valid, order[np.minimum(hp.numpy(), len(order) - 1)], -1)
                mt, mp = mi_fn()
                t_mi = mt.numpy()
                face_mi = np.where(np.isfinite(t_mi), mp.numpy().astype(np.int64), -1)
                res["agreement"] = _agreement_closest(t_ours, face, t_mi, face_mi)
                res["_hits"] = (t_ours, face)
            elif m:
                ours = _occluded(accs[first], ray.o, ray.d, ray.t_max, on).numpy()
                res["agreement"] = {"same_answer": float(np.mean(ours == mi_fn().numpy())),
                                    "hits": int(ours.sum())}
            for sname, sq in (variants_for(name).items() if m else ()):
                if q == "closest":           # t, original face, found
                    a_, b_ = (_closest(x, ray.o, ray.d, ray.t_max, on) for x in (accs[first], sq))
                    a_, b_ = ((h[0], dr.gather(t.UInt32, x.tris.order, h[1], h[2]), h[2])
                              for h, x in ((a_, accs[first]), (b_, sq)))
                    same = all(np.array_equal(x.numpy(), y.numpy()) for x, y in zip(a_, b_))
                else:
                    same = np.array_equal(_occluded(accs[first], ray.o, ray.d, ray.t_max,
                                                    on).numpy(),
                                          _occluded(sq, ray.o, ray.d, ray.t_max, on).numpy())
                res.setdefault("variants_bitwise_equal", {})[sname] = bool(same)
            if steps and m:
                res["steps"] = {a: _steps(acc, ray, on, q == "any", lanes)
                                for a, acc in accs.items() if hasattr(acc, "counts")}
            out[q] = res
        return out

    res = {"scene_triangles": scene.face_count, "batches": {}}
    inf = np.full(n, np.inf, np.float32)
    prim = measure("primary", o, d, inf, ("closest", "any"), True)
    t_ours, face_ours = prim["closest"].pop("_hits")
    if "primary" in batches:
        res["batches"]["primary"] = prim
    if "shadow" in batches and scene.lights:
        so, sd, stmax = shadow_rays_host(scene, o, d, t_ours, np.maximum(face_ours, 0),
                                         scene.lights[0].position)
        res["batches"]["shadow"] = measure("shadow", so, sd, stmax, ("any",), False)
    if "incoherent" in batches:
        io, idir = incoherent_rays_host(scene, n)
        b = measure("incoherent", io, idir, inf, ("closest", "any"), False)
        b["closest"].pop("_hits", None)
        res["batches"]["incoherent"] = b
    if "reflection" in batches:
        ro, rd = reflection_rays_host(scene, o, d, t_ours, np.maximum(face_ours, 0))
        b = measure("reflection", ro, rd, np.full(len(ro), np.inf, np.float32),
                    ("closest", "any"), False)
        b["closest"].pop("_hits", None)
        res["batches"]["reflection"] = b

    # ---- the legacy keys: the first accelerator's primary and shadow rows ------------------
    res["rays"] = n
    res["ours_primary"] = prim["closest"]["ms"][first]
    res["mitsuba_primary"] = prim["closest"]["ms"]["mitsuba"]
    res["primary_agreement"] = prim["closest"]["agreement"]
    sh = res["batches"].get("shadow")
    if sh:
        res["ours_shadow"] = sh["any"]["ms"][first]
        res["mitsuba_shadow"] = sh["any"]["ms"]["mitsuba"]
        res["shadow_agreement"] = sh["any"]["agreement"]["same_answer"]
        res["shadow_rays"] = sh["rays"]
    res.update(backend=t.backend, triangles=scene.face_count, build_s=build[first]["seconds"],
               mitsuba_build_s=mi_build_s, accel=first, accels=list(accels),
               variants=[s for s, (a, k) in VARIANTS.items()
                         if a in accs and t.backend in VARIANT_BACKENDS[k]], build=build,
               stats=build[first]["stats"])
    return res


# ---- the part -----------------------------------------------------------------------------
def run(ctx: Context) -> list[dict]:
    """Every scene of ``SCENES`` present in the scenes folder, at 1920×1080 (quick: 320×180),
    one progress line per batch and query."""
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
        for batch, b in r["batches"].items():
            for q in ("closest", "any"):
                if q not in b:
                    continue
                ms = b[q]["ms"]
                ours = "  ".join(f"{a} {ms[a]['mrays_per_s']:8.1f}"
                                 for a in r["accels"] + r.get("variants", []) if a in ms)
                print(f"  rays {name:16s} {batch:10s} {q:7s} {ours}  mitsuba "
                      f"{ms['mitsuba']['mrays_per_s']:8.1f} Mrays/s", flush=True)
    return rows


def _legacy_markdown(rows: list[dict]) -> list[str]:
    """The table of results stored before the batches existed (primary and shadow only)."""
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


def _fmt(x: float) -> str:
    return f"{x:,.0f}" if x >= 100 else f"{x:.1f}" if x >= 10 else f"{x:.2f}"


def markdown(rows: list[dict]) -> list[str]:
    if not rows or "batches" not in rows[0]:
        return _legacy_markdown(rows)
    accels = rows[0]["accels"]
    sorted_ = rows[0].get("variants", [])
    by_kernel = rows[0].get("backend") == "cuda"    # the variants' column: kernel time on
    cells, steps = [], []
    for r in rows:
        for batch, b in r["batches"].items():
            for q in ("closest", "any"):
                if q not in b:
                    continue
                x = b[q]
                ms = x["ms"]
                rate = {k: v["mrays_per_s"] for k, v in ms.items()}
                ours = accels + [a for a in sorted_ if a in ms and a not in NOT_CONTENDERS]
                best = max(ours, key=lambda a: rate[a])
                crate = {k: v.get("mrays_per_cpu_s", float("nan")) for k, v in ms.items()}
                cbest = max(ours, key=lambda a: crate[a])
                ag = x.get("agreement", {})
                agree = (f"{ag['same_triangle']:.4f}" if "same_triangle" in ag
                         else f"{ag.get('same_answer', float('nan')):.4f}")
                cells.append([r["scene"], batch, q, f"{b['rays']:,}"]
                             + [_fmt(rate[a]) for a in accels]
                             + [_fmt((rate if by_kernel else crate)[a]) if a in ms else "–"
                                for a in sorted_]
                             + [_fmt(rate["mitsuba"]),
                                f"{rate[best] / rate['mitsuba']:.2f} ({best})",
                                f"{crate[cbest] / crate['mitsuba']:.2f} ({cbest})", agree])
                st = x.get("steps") or {}
                steps.append([r["scene"], batch, q]
                             + [f"{st[a]['node']:.1f} / {st[a]['triangle']:.1f} / "
                                f"{st[a]['iterations_packet_max']:.1f}" if st.get(a) else "–"
                                for a in accels])
    # results from before the insertion-based optimisation have no "optimize_s"
    optimized = any("optimize_s" in r["build"] for r in rows)
    build = [[r["scene"], f"{r['triangles']:,}", f"{r['build']['binary_build_s']:.3f}"]
             + ([f"{r['build'].get('optimize_s', 0.0):.3f}"] if optimized else [])
             + [f"{r['build']['triangles_per_s'] / 1e6:.2f}",
                f"{r['build'].get('triangles_per_cpu_s', float('nan')) / 1e6:.2f}"]
             + [f"{r['build'][a]['stats'].get('convert_seconds', 0.0):.3f}" for a in accels]
             + [f"{r['build']['mitsuba_build_s']:.3f}"] for r in rows]
    build_title = ("BVH build (CPU, numpy): binary SAH build"
                   + (" (with its insertion-based optimisation, ``renderer.accel.optimize``)"
                      if optimized else "")
                   + ", its throughput, and each accelerator's extra time (the wide BVHs' "
                   "collapse and quantisation)")
    build_head = (["scene", "triangles", "binary SAH build s"]
                  + (["of which optimisation s"] if optimized else [])
                  + ["M triangles/s", "M triangles/CPU s"] + [f"{a} extra s" for a in accels]
                  + ["Mitsuba build s"])
    n = len(accels)
    title = ("Ray throughput (identical batches; M rays/s from kernel time, median of "
             "repeats, contenders timed in turn)")
    if sorted_ and by_kernel:
        title = title[:-1] + ("; the query variant +refill (threads take the next ray, "
                              "``traverse.refill_traversal``, evaluated batches only)"
                              + (" and bvh-nosplit (the BVH built without the default "
                                 "spatial splits, where those cut references)"
                                 if "bvh-nosplit" in sorted_ else "")
                              + (" and bvh+spatial (the BVH built with spatial splits, "
                                 "where they cut references)" if "bvh+spatial" in sorted_
                                 else "")
                              + (" and bvh-ploc / bvh4-ploc (the BVHs over the device-built "
                                 "PLOC tree, ``--build device``)" if "bvh-ploc" in sorted_
                                 else "")
                              + ": M rays/s from kernel time like the others)")
    elif sorted_:
        title = title[:-1] + ("; the query variants (+sort: rays sorted first, "
                              "``renderer.accel.order``; +refill: lanes take the next ray, "
                              "``WideBVH.refill``"
                              + ("; -nosplit: the BVH built without the default spatial "
                                 "splits, where those cut references"
                                 if "bvh-nosplit" in sorted_ else "")
                              + ("; +spatial: the BVH built with spatial splits, where they "
                                 "cut references" if "bvh+spatial" in sorted_ else "")
                              + ("; -ploc: the BVHs over the device-built PLOC tree, "
                                 "``--build device``" if "bvh-ploc" in sorted_ else "")
                              + "): M rays per CPU s, the call itself "
                              "(sort, ray copy, Python tracing) included)")
    unit = "Mrays/s" if by_kernel else "Mrays/CPU s"
    return (table(title,
                  ["scene", "batch", "query", "rays"] + [f"{a} Mrays/s" for a in accels]
                  + [f"{a} {unit}" for a in sorted_]
                  + ["Mitsuba", "best / Mitsuba", "best / Mitsuba by CPU time", "agreement"],
                  "lllr" + "r" * (n + len(sorted_) + 4), cells)
            + table("Traversal steps per ray (instrumented traversal): node steps / triangle "
                    "steps / loop iterations of the slowest ray of each SIMD packet or warp",
                    ["scene", "batch", "query"] + accels, "lll" + "r" * n, steps)
            + table(build_title, build_head, "lrrrr" + "r" * (len(build_head) - 5), build)
            + _trees_markdown(rows, by_kernel))


def _trees_markdown(rows: list[dict], by_kernel: bool) -> list[str]:
    """Each row's rate over the device-built PLOC tree against the SAH tree's, per
    accelerator (binary and 4-wide), with the two trees' SAH costs; [] before the PLOC
    variants existed."""
    pairs = [(a, f"{a}-ploc") for a in ("bvh", "bvh4")]
    key = "mrays_per_s" if by_kernel else "mrays_per_cpu_s"
    cells = []
    for r in rows:
        cost = r["build"].get("ploc")
        if not cost:
            continue
        for batch, b in r["batches"].items():
            for q in ("closest", "any"):
                ms = b.get(q, {}).get("ms", {})
                row = [r["scene"], batch, q]
                for a, p in pairs:
                    if a in ms and p in ms:
                        x, y = ms[a][key], ms[p][key]
                        row += [_fmt(x), _fmt(y), f"{y / x:.2f}"]
                    else:
                        row += ["–"] * 3
                if q in b:
                    row.append(f"{cost['sah_cost_sah']:.2f} / {cost['sah_cost']:.2f}")
                    cells.append(row)
    if not cells:
        return []
    unit = "Mrays/s" if by_kernel else "Mrays/CPU s"
    return table(f"Both trees, every row ({unit}): the SAH tree (the default) and the "
                 "device-built PLOC tree (``--build device``), and PLOC / SAH",
                 ["scene", "batch", "query", "bvh SAH", "bvh PLOC", "PLOC / SAH", "bvh4 SAH",
                  "bvh4 PLOC", "PLOC / SAH", "SAH cost SAH / PLOC"], "lll" + "r" * 7, cells)


PART = Part(name="throughput", key="throughput", run=run, markdown=markdown)
