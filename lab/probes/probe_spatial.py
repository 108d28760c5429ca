"""Probe: the BVH with and without spatial splits (``renderer.accel.spatial``) against
Mitsuba, on the throughput part's batches.

    PYTHONPATH=. python lab/probes/probe_spatial.py [--backend llvm] [--size 640x360]
        [--scenes sponza,conference] [--out DIR] [--force]

Per scene: one build with ``spatial=0`` and one with the default, each as the binary and
the 4-wide BVH; per batch and query the kernel time of every contender (timed in turn,
``throughput._timed``), the hits compared with the plain build's (t and face where found),
and the instrumented traversal's steps. Writes ``OUT/spatial.json`` (``part.run_probe``:
an existing one only with ``--force``).
"""
from __future__ import annotations

import warnings
from pathlib import Path

import drjit as dr
import numpy as np

from evaluation import wxh
from evaluation.bench import throughput as T
from lab.probes.common import probe_parser, run_probe
from lab.probes.probe_traversal import same_hits
from renderer.accel import ACCELERATORS
from renderer.accel.bvh_build import SPATIAL, build_bvh
from renderer.device import types
from renderer.scene import load_scene

SCENES = ("sponza", "conference")


def probe(name: str, t, width: int, height: int, repeats: int) -> list:
    from reference import mitsuba_variant
    from reference.mitsuba_scene import load_triangles
    scene = load_scene(f"scenes/{name}.toml")
    builds = {"plain": build_bvh(scene.vertices, scene.faces, spatial=0.0),
              "spatial": build_bvh(scene.vertices, scene.faces, spatial=SPATIAL)}
    accs = {f"{a}-{b}": ACCELERATORS[a].build(scene, t, binary=arrays)
            for b, arrays in builds.items() for a in ("bvh", "bvh4")}
    dr.eval(accs)
    mitsuba_variant("cuda_ad_rgb" if t.backend == "cuda" else "llvm_ad_rgb")
    mscene, _ = load_triangles(scene.vertices, scene.faces)
    o, d = T.primary_rays_host(scene, width, height, t)
    ray, on, _ = T.upload_batch(t, o, d)
    ht, hp, hf = T._closest(accs["bvh-plain"], ray.o, ray.d, ray.t_max, on)
    valid = hf.numpy()
    order = accs["bvh-plain"].tris.order.numpy().astype(np.int64)
    t_h = np.where(valid, ht.numpy(), np.inf)
    face = np.where(valid, order[np.minimum(hp.numpy(), len(order) - 1)], 0)
    batches = {"primary": (o, d, True),
               "incoherent": T.incoherent_rays_host(scene, len(o)) + (False,),
               "reflection": T.reflection_rays_host(scene, o, d, t_h, face) + (False,)}
    rows = []
    for bname, (bo, bd, coherent) in batches.items():
        ray, on, mray = T.upload_batch(t, bo, bd)
        for q in ("closest", "any"):
            def ours(acc, q=q, ray=ray, on=on):
                if q == "closest":
                    h = acc.intersect(ray, on)
                    return h.t, dr.gather(t.UInt32, acc.tris.order, h.prim, h.found), h.found
                return (acc.intersect_p(ray, on),)
            fns = {k: (lambda acc=acc, ours=ours: ours(acc)) for k, acc in accs.items()}
            fns["mitsuba"] = T.mitsuba_query(mscene, mray, q, coherent)
            ref = [x.numpy() for x in fns["bvh-plain"]()]
            same = {k: same_hits([x.numpy() for x in fns[k]()], ref, q) for k in accs}
            steps = {k: [float(x.numpy().mean()) for x in accs[k].counts(ray, on, q == "any")]
                     for k in accs}
            timing = T._timed(fns, repeats)
            rows.append({"scene": name, "batch": bname, "query": q, "rays": len(bo),
                         "same": same, "steps": steps, "ms": timing,
                         "references": {b: int(a.order.size) for b, a in builds.items()},
                         "build_s": {b: a.build_seconds for b, a in builds.items()},
                         "sah": {b: a.sah_cost for b, a in builds.items()}})
            base = timing["mitsuba"]["kernel_ms"]
            line = "  ".join(f"{k} {base / v['kernel_ms']:.3f}"
                             for k, v in timing.items() if k != "mitsuba")
            print(f"{name} {bname} {q} | x mitsuba: {line} | same {all(same.values())}",
                  flush=True)
    return rows


def main(argv=None) -> int:
    ap = probe_parser(__doc__, SCENES, backend='llvm')
    ap.add_argument("--size", type=wxh, default=(640, 360), help="batch WxH")
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args(argv)
    if a.repeats < 1:
        ap.error(f"--repeats: expected at least 1, got {a.repeats}")
    warnings.simplefilter("ignore")
    t = types(a.backend)
    return run_probe(Path(a.out) / "spatial.json", a.force, a.scenes.split(","),
                     lambda name: probe(name, t, *a.size, a.repeats),
                     {"backend": a.backend, "size": list(a.size)})


if __name__ == "__main__":
    raise SystemExit(main())
