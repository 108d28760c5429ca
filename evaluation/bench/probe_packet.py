"""Probe (CPU): ray packets inside a lane (``renderer.accel.packet``) against the binary BVH's
own traversal and Mitsuba/Embree, on the throughput part's primary and shadow batches.

    python -m evaluation.bench.probe_packet SCENE WxH K[,K...] [REPEATS]

Prints M rays per CPU s and per kernel second for each contender (``throughput._timed``,
contenders in turn) and whether each packet size gives the BVH's hits (t and original face
where found; any hit).
"""
from __future__ import annotations

import sys
import warnings

import numpy as np

from renderer.accel.bvh import BVH
from renderer.accel.packet import packet_traverse
from renderer.device import types
from renderer.scene import load_scene

from .. import wxh
from . import throughput as T


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    warnings.simplefilter("ignore")
    scene_name, (w, h), ks = argv[0], wxh(argv[1]), [int(k) for k in argv[2].split(",")]
    reps = int(argv[3]) if len(argv) > 3 else 5
    t = types("llvm")
    scene = load_scene(f"scenes/{scene_name}.toml")
    acc = BVH.build(scene, t)
    o, d = T.primary_rays_host(scene, w, h, t)
    n = len(o)
    ray, on, mray = T.upload_batch(t, o, d, np.full(n, np.inf, np.float32))
    ref = acc.intersect(ray, on)
    rt, rp, rf = (x.numpy() for x in (ref.t, ref.prim, ref.found))
    od = acc.tris.order.numpy()
    so, sd, stmax = T.shadow_rays_host(scene, o, d, np.where(rf, rt, np.inf),
                                       np.where(rf, od[rp], 0), scene.lights[0].position)
    sray, son, smray = T.upload_batch(t, so, sd, stmax)
    sref = acc.intersect_p(sray, son).numpy()
    fns = {"bvh": lambda: acc.intersect(ray, on).t,
           "bvh shadow": lambda: acc.intersect_p(sray, son)}
    for k in ks:
        g = packet_traverse(acc, ray, on, False, k)
        gt, gp, gf = (x.numpy() for x in (g.t, g.prim, g.found))
        same = (np.array_equal(rf, gf) and np.array_equal(np.where(rf, rt, 0), np.where(rf, gt, 0))
                and np.array_equal(np.where(rf, od[rp], 0), np.where(rf, od[gp], 0)))
        same_p = np.array_equal(packet_traverse(acc, sray, son, True, k).numpy(), sref)
        print(f"K={k}: closest hits same: {same}, any hits same: {same_p}", flush=True)
        fns[f"K={k}"] = lambda k=k: packet_traverse(acc, ray, on, False, k).t
        fns[f"K={k} shadow"] = lambda k=k: packet_traverse(acc, sray, son, True, k)
    from reference import mitsuba_variant
    from reference.mitsuba_scene import load_triangles
    mitsuba_variant("llvm_ad_rgb")
    ms, _ = load_triangles(scene.vertices, scene.faces)
    fns["embree"] = T.mitsuba_query(ms, mray, "closest", True)
    fns["embree shadow"] = T.mitsuba_query(ms, smray, "any", False)
    timing = T._timed(fns, reps)
    print(f"| {scene_name} {w}x{h} | M rays per CPU s | M rays per kernel s |")
    for name, v in timing.items():
        m = len(so) if name.endswith("shadow") else n
        print(f"| {name} | {m / v['cpu_ms'] / 1e3:.2f} | {m / v['kernel_ms'] / 1e3:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
