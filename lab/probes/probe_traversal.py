"""Probe: traversal variants against Mitsuba on the GPU (``lab/notes/branches.md``).

    PYTHONPATH=. python lab/probes/probe_traversal.py --mode branches [--backend cuda] [--out DIR]
    PYTHONPATH=. python lab/probes/probe_traversal.py --mode leaf ...    [--size WxH] [--force]
    PYTHONPATH=. python lab/probes/probe_traversal.py --mode setup ...
    PYTHONPATH=. python lab/probes/probe_traversal.py --mode optimize ...
    PYTHONPATH=. python lab/probes/probe_traversal.py --mode refill-count ...

``branches``: the traversal steps written inline with masked updates (what CUDA ran before
``traverse.masked_step`` became a symbolic ``if`` everywhere) against real branches for both
steps (``+br``), for the triangle step only (``+brtri``) or the node step only (``+brnode``);
also leaves of 2 and 8 triangles and Möller–Trumbore, inline. ``refill``: the binary and 4-wide
BVHs whose threads take the next ray when theirs is done (``refill``, rays per thread:
``traverse.refill_traversal``), against the binary and 4-wide BVHs. ``leaf``: with the
branches, leaves of 1, 2, 4 and 8 triangles, the 4-wide BVH from the leaf-2 build, the 8-wide
BVH and Möller–Trumbore. ``optimize``: the binary and 4-wide BVHs built without and with the
insertion-based optimisation (``+reinsert``, ``renderer.accel.optimize``). ``refill-count``:
the 4-wide BVH with 8, 16 and 32 rays per thread (``+refillN``) against the binary and 4-wide
BVHs. (The ``slab`` mode and the ``+tiegather`` variants compared the forms the renderer no
longer has; their results stay in the lab notes.) ``setup``: the watertight test bound to each
traversal's rays (the renderer's, ``triangle.bind_routine``) against the same test doing its
per-ray set-up at every triangle (``+per-test``). Batches as the throughput part's (primary,
incoherent, reflection; closest and any hit; ``setup`` and ``optimize`` also the shadow rays),
every contender timed in turn (``throughput._timed``), and every contender's hits compared with
the binary BVH's (t and face where found). Writes ``OUT/<mode>.json`` and prints one line per
query.
"""
from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path

import drjit as dr
import numpy as np

import renderer.accel.bvh as bvh_module
import renderer.accel.traverse as traverse_module
import renderer.accel.triangle as TR
import renderer.accel.wide as wide_module
from evaluation import wxh
from evaluation.bench import throughput as T
from lab.probes.common import probe_parser, run_probe
from renderer.accel import ACCELERATORS
from renderer.accel.base import Ray
from renderer.accel.bvh_build import build_bvh
from renderer.device import array3, types
from renderer.scene import load_scene

SCENES = ("cornell_sphere", "platonic_solids", "bunny", "sponza", "conference")
#: Which steps branch in the ``branches`` mode (set by each contender while it traces).
BRANCH = {"node": True, "tri": True}


def _switchable(kind: str):
    """A ``masked_step`` that branches when ``BRANCH[kind]`` (or on LLVM), else inline."""
    def masked_step(t, where, step, state):
        if t.backend == "llvm" or BRANCH[kind]:
            return dr.if_stmt(state, where, lambda *s: step(*s, True), lambda *s: s)
        return step(*state, where)
    return masked_step


def _accelerators(scene, t, mode: str) -> tuple[dict, dict]:
    binary = build_bvh(scene.vertices, scene.faces, leaf_size=4)
    accs = {a: ACCELERATORS[a].build(scene, t, binary=binary) for a in ("bvh", "bvh4")}
    if mode == "leaf":
        for ls in (1, 2, 8):
            b = build_bvh(scene.vertices, scene.faces, leaf_size=ls)
            accs[f"bvh-leaf{ls}"] = ACCELERATORS["bvh"].build(scene, t, binary=b)
            if ls == 2:
                accs["bvh4-leaf2"] = ACCELERATORS["bvh4"].build(scene, t, binary=b)
        accs["bvh8"] = ACCELERATORS["bvh8"].build(scene, t, binary=binary)
    else:
        for ls in (2, 8):
            accs[f"bvh-leaf{ls}"] = ACCELERATORS["bvh"].build(scene, t, leaf_size=ls)
    if mode == "setup":
        b = build_bvh(scene.vertices, scene.faces)
        accs = {"bvh": ACCELERATORS["bvh"].build(scene, t, binary=b)}
        dr.eval(accs)
        accs["bvh+per-test"] = replace(accs["bvh"], intersection="watertight_per_test")
        return accs, {a: (a, True, True) for a in accs}
    if mode == "optimize":
        from renderer.accel.optimize import reinsert
        b = build_bvh(scene.vertices, scene.faces, optimize=0)
        r = reinsert(b)
        accs = {f"{a}{tag}": ACCELERATORS[a].build(scene, t, binary=arrays)
                for tag, arrays in (("", b), ("+reinsert", r)) for a in ("bvh", "bvh4")}
        dr.eval(accs)
        print(f"SAH cost {b.sah_cost:.2f} -> {r.sah_cost:.2f}, levels {b.levels} -> "
              f"{r.levels}", flush=True)
        return accs, {a: (a, True, True) for a in accs}
    if mode == "refill":
        b = build_bvh(scene.vertices, scene.faces, leaf_size=2)
        accs = {"bvh": ACCELERATORS["bvh"].build(scene, t, binary=b),
                "bvh4": ACCELERATORS["bvh4"].build(scene, t, binary=b)}
        dr.eval(accs)
        for r in (2, 4, 8, 16):
            accs[f"bvh+refill{r}"] = replace(accs["bvh"], refill=r)
        for r in (4, 8):
            accs[f"bvh4+refill{r}"] = replace(accs["bvh4"], refill=r)
        return accs, {a: (a, True, True) for a in accs}
    if mode == "refill-count":
        b = build_bvh(scene.vertices, scene.faces)
        accs = {a: ACCELERATORS[a].build(scene, t, binary=b) for a in ("bvh", "bvh4")}
        dr.eval(accs)
        for r in (8, 16, 32):
            accs[f"bvh4+refill{r}"] = replace(accs["bvh4"], refill=r)
        return accs, {a: (a, True, True) for a in accs}
    accs["bvh-mt"] = ACCELERATORS["bvh"].build(scene, t, binary=binary,
                                               intersection="moller_trumbore")
    dr.eval(accs)
    branches = mode == "leaf"
    conts = {a: (a, branches, branches) for a in accs}
    if mode == "branches":
        for a in ("bvh", "bvh4"):
            conts[a + "+br"] = (a, True, True)
            conts[a + "+brtri"] = (a, False, True)
            conts[a + "+brnode"] = (a, True, False)
    return accs, conts


def watertight_per_test(o, d, p0, p1, p2, n, t_min=0.0):
    """``watertight`` without its ``bind``: the per-ray set-up at every triangle test."""
    return TR.watertight(o, d, p0, p1, p2, n, t_min)


watertight_per_test.layout = "vertices"


def _query(t, acc, ray, on, q, node, tri):
    BRANCH["node"], BRANCH["tri"] = node, tri
    try:
        if q == "closest":
            h = acc.intersect(ray, on)
            return h.t, dr.gather(t.UInt32, acc.tris.order, h.prim, h.found), h.found
        return (acc.intersect_p(ray, on),)
    finally:
        BRANCH["node"] = BRANCH["tri"] = True


def same_hits(got, ref, q) -> bool:
    """Whether ``got`` has ``ref``'s hits: the any-hit answers, or found and, where found,
    t and face (the ``(t, face, found)`` of a closest-hit query)."""
    if q != "closest":
        return bool(np.array_equal(got[0], ref[0]))
    f = ref[2]
    return bool(np.array_equal(got[2], f) and np.array_equal(got[0][f], ref[0][f])
                and np.array_equal(got[1][f], ref[1][f]))


def probe(scene_name: str, t, mode: str, width: int, height: int, repeats: int) -> list:
    from reference import mitsuba_variant
    from reference.mitsuba_scene import load_triangles
    scene = load_scene(f"scenes/{scene_name}.toml")
    accs, conts = _accelerators(scene, t, mode)
    mitsuba_variant("cuda_ad_rgb" if t.backend == "cuda" else "llvm_ad_rgb")
    mscene, _ = load_triangles(scene.vertices, scene.faces)
    o, d = T.primary_rays_host(scene, width, height, t)
    n = len(o)
    ray = Ray(o=array3(t, o), d=array3(t, d), t_max=t.Float(np.full(n, np.inf, np.float32)))
    ht, face, hf = (x.numpy() for x in _query(t, accs["bvh"], ray, dr.full(t.Bool, True, n),
                                              "closest", True, True))
    t_h = np.where(hf, ht, np.inf)
    face = np.where(hf, face, 0).astype(np.int64)
    so, sd, stmax = T.shadow_rays_host(scene, o, d, t_h, face,
                                       scene.lights[0].position)
    batches = {"primary": (o, d, True),
               "shadow": (so, sd, False, stmax),
               "incoherent": T.incoherent_rays_host(scene, n) + (False,),
               "reflection": T.reflection_rays_host(scene, o, d, t_h, face) + (False,)}
    rows = []
    for bname, (bo, bd, coherent, *btmax) in batches.items():
        if bname == "shadow" and mode not in ("setup", "optimize"):
            continue
        m = len(bo)
        ray, on, mray = T.upload_batch(t, bo, bd, *btmax)
        for q in (("any",) if bname == "shadow" else ("closest", "any")):
            fns = {k: (lambda a=a, nb=nb, tb=tb, q=q, ray=ray, on=on:
                        _query(t, accs[a], ray, on, q, nb, tb))
                   for k, (a, nb, tb) in conts.items()}
            fns["mitsuba"] = T.mitsuba_query(mscene, mray, q, coherent)
            ref = [x.numpy() for x in fns["bvh"]()]
            same = {k: same_hits([x.numpy() for x in fns[k]()], ref, q) for k in conts}
            timing = T._timed(fns, repeats)
            rows.append({"scene": scene_name, "batch": bname, "query": q, "rays": m,
                         "same": same, "ms": timing})
            base = timing["mitsuba"]["kernel_ms"]
            line = "  ".join(f"{k} {base / v['kernel_ms']:.2f}"
                             for k, v in timing.items() if k != "mitsuba")
            differ = [k for k, v in same.items() if not v]
            print(f"{scene_name} {bname} {q} mitsuba {m / base / 1e3:.0f} Mrays/s | "
                  f"x mitsuba: {line}" + (f"  DIFFER: {differ}" if differ else ""), flush=True)
    return rows


def main(argv=None) -> int:
    ap = probe_parser(__doc__, SCENES)
    ap.add_argument("--mode", choices=("branches", "leaf", "refill", "refill-count", "setup",
                                       "optimize"),
                    default="branches")
    ap.add_argument("--size", type=wxh, default=None,
                    help="batch WxH (default 1920x1080 on CUDA, 160x90 on the CPU)")
    a = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    t = types(a.backend)
    size = a.size or ((1920, 1080) if a.backend == "cuda" else (160, 90))
    if a.mode == "setup":
        TR.ROUTINES["watertight_per_test"] = watertight_per_test
    if a.mode == "branches":
        bvh_module.masked_step = wide_module.masked_step = _switchable("node")
        traverse_module.masked_step = _switchable("tri")
    return run_probe(Path(a.out) / f"{a.mode}.json", a.force, a.scenes.split(","),
                     lambda name: probe(name, t, a.mode, *size,
                                        7 if a.backend == "cuda" else 3),
                     {"backend": a.backend})


if __name__ == "__main__":
    raise SystemExit(main())
