"""Probe: rays sorted before tracing, on the GPU (``lab/notes/ray-sort.md``).

    PYTHONPATH=. python lab/probes/probe_sort.py [--backend cuda] [--out DIR] [--force]

For the incoherent and reflection batches of the throughput part, the binary and 4-wide
BVHs plain and wrapped in sorted queries with several keys (``KeyedSort``), against
Mitsuba, every contender timed in turn with the sort's kernels included
(``throughput._timed``). Each sorted variant's hits are compared bitwise with its plain
BVH's, and one sorted call's kernel history (kernel kinds and times) is recorded. Writes
``OUT/ray-sort.json`` (``part.run_probe``: an existing one only with ``--force``).
"""
from __future__ import annotations

import warnings
from pathlib import Path

import drjit as dr
import numpy as np

from evaluation.bench import throughput as T
from lab.probes.common import probe_parser, run_probe
from renderer.accel import ACCELERATORS
from renderer.accel.base import Ray
from renderer.accel.bvh_build import build_bvh
from renderer.accel.order import SortedQueries, _spread3
from renderer.device import array3, types
from renderer.scene import load_scene
from renderer.stats import kernel_launches

SCENES = ("cornell_sphere", "platonic_solids", "bunny", "sponza", "conference")
#: (accelerator, key mode, origin bits per axis, direction bits per axis)
VARIANTS = [("bvh", "oct", 3, 0), ("bvh", "oct", 4, 0), ("bvh", "oct", 5, 0),
            ("bvh", "oct+axis", 4, 0), ("bvh", "dir", 4, 2), ("bvh", "dir", 3, 3),
            ("bvh", "dir-low", 4, 2), ("bvh4", "oct", 4, 0), ("bvh4", "dir", 4, 2)]


class KeyedSort(SortedQueries):
    """``SortedQueries`` with a choice of key (``mode``): "oct" (``order.ray_key``: the
    direction's octant above the origin's Morton code), "oct+axis" (the major axis too),
    "dir" (an octahedral direction cell of ``dbits`` per axis above the origin code),
    "dir-low" (below it)."""

    def __init__(self, accel, lo, hi, bits, mode, dbits=2):
        super().__init__(accel, lo, hi, bits)
        self.mode, self.dbits = mode, dbits

    def _key(self, ray):
        t = self.accel.types
        cells = 1 << self.bits
        q = []
        for a in range(3):
            scale = cells / max(self.hi[a] - self.lo[a], 1e-30)
            c = t.Int32((ray.o[a] - self.lo[a]) * scale)
            q.append(t.UInt32(dr.clip(c, 0, cells - 1)))
        morton = _spread3(q[0]) | (_spread3(q[1]) << 1) | (_spread3(q[2]) << 2)
        d = ray.d
        octant = t.UInt32(dr.select(d.x > 0, 4, 0) | dr.select(d.y > 0, 2, 0)
                          | dr.select(d.z > 0, 1, 0))
        ob = 3 * self.bits
        if self.mode == "oct":
            return (octant << ob) | morton, 3 + ob
        if self.mode == "oct+axis":
            ad = dr.abs(d)
            ax = t.UInt32(dr.select((ad.x >= ad.y) & (ad.x >= ad.z), 0,
                                    dr.select(ad.y >= ad.z, 1, 2)))
            return (((octant << 2) | ax) << ob) | morton, 5 + ob
        # octahedral map of the direction, dbits per axis
        s = dr.abs(d.x) + dr.abs(d.y) + dr.abs(d.z)
        px, py = d.x / s, d.y / s
        neg = d.z < 0
        qx = dr.select(neg, (1 - dr.abs(py)) * dr.sign(px), px)
        qy = dr.select(neg, (1 - dr.abs(px)) * dr.sign(py), py)
        n = 1 << self.dbits
        ix = t.UInt32(dr.clip(t.Int32((qx * 0.5 + 0.5) * n), 0, n - 1))
        iy = t.UInt32(dr.clip(t.Int32((qy * 0.5 + 0.5) * n), 0, n - 1))
        dk = (ix << self.dbits) | iy
        if self.mode == "dir-low":
            return (morton << (2 * self.dbits)) | dk, 2 * self.dbits + ob
        return (dk << ob) | morton, 2 * self.dbits + ob

    def _sorted(self, ray, active):
        t = self.accel.types
        n = dr.width(ray.o, ray.d, ray.t_max, active)
        ray = Ray(o=t.Array3f(ray.o) + dr.zeros(t.Array3f, n),
                  d=t.Array3f(ray.d) + dr.zeros(t.Array3f, n),
                  t_max=t.Float(ray.t_max) + dr.zeros(t.Float, n))
        key, kb = self._key(ray)
        dr.eval(key)
        perm = dr.detail.block_mkperm(key, n, 1 << kb)
        g = lambda v: dr.gather(type(v), v, perm)  # noqa: E731
        sray = Ray(o=g(ray.o), d=g(ray.d), t_max=g(ray.t_max))
        son = g(t.Bool(active) & dr.full(t.Bool, True, n))
        dr.eval(sray, son)
        return t, n, perm, sray, son


def _results(fn) -> list:
    out = fn()
    return [x.numpy() for x in (out if isinstance(out, tuple) else (out,))]


def probe(name: str, t, width: int, height: int, repeats: int) -> list:
    from reference import mitsuba_variant
    from reference.mitsuba_scene import load_triangles
    scene = load_scene(f"scenes/{name}.toml")
    binary = build_bvh(scene.vertices, scene.faces, leaf_size=4)
    accs = {a: ACCELERATORS[a].build(scene, t, binary=binary) for a in ("bvh", "bvh4")}
    dr.eval(accs)
    V = scene.vertices.astype(np.float64)
    lo, hi = tuple(map(float, V.min(0))), tuple(map(float, V.max(0)))
    variants = {f"{a}+{mode}{bits}" + (f"d{db}" if db else ""):
                (a, KeyedSort(accs[a], lo, hi, bits, mode, db))
                for a, mode, bits, db in VARIANTS}
    mitsuba_variant("cuda_ad_rgb" if t.backend == "cuda" else "llvm_ad_rgb")
    mscene, _ = load_triangles(scene.vertices, scene.faces)
    o, d = T.primary_rays_host(scene, width, height, t)
    n = len(o)
    ray = Ray(o=array3(t, o), d=array3(t, d), t_max=t.Float(np.full(n, np.inf, np.float32)))
    ht, hp, hf = T._closest(accs["bvh"], ray.o, ray.d, ray.t_max, dr.full(t.Bool, True, n))
    valid = hf.numpy()
    order = accs["bvh"].tris.order.numpy().astype(np.int64)
    t_h = np.where(valid, ht.numpy(), np.inf)
    face = np.where(valid, order[np.minimum(hp.numpy(), len(order) - 1)], 0)
    batches = {"incoherent": T.incoherent_rays_host(scene, n),
               "reflection": T.reflection_rays_host(scene, o, d, t_h, face)}
    rows = []
    for bname, (bo, bd) in batches.items():
        m = len(bo)
        ray, on, mray = T.upload_batch(t, bo, bd)
        for q in ("closest", "any"):
            query = T._closest if q == "closest" else T._occluded
            conts = dict(accs, **{k: v for k, (_, v) in variants.items()})
            fns = {k: (lambda acc=acc, query=query, ray=ray, on=on:
                        query(acc, ray.o, ray.d, ray.t_max, on))
                   for k, acc in conts.items()}
            fns["mitsuba"] = T.mitsuba_query(mscene, mray, q, False)
            same = {k: all(np.array_equal(x, y) for x, y in
                           zip(_results(fns[a]), _results(fns[k])))
                    for k, (a, _) in variants.items()}
            _, launched, _ = kernel_launches(lambda f=fns["bvh+oct4"]: dr.eval(f()))
            hist = [(str(h.get("type")), h.get("size"), round(h.get("execution_time", -1), 4))
                    for h in launched]
            timing = T._timed(fns, repeats, eager=tuple(variants))
            rows.append({"scene": name, "batch": bname, "query": q, "rays": m,
                         "bitwise": same, "hist_sorted_call": hist, "ms": timing})
            base = timing["mitsuba"]["kernel_ms"]
            line = "  ".join(f"{k} {base / v['kernel_ms']:.2f}"
                             for k, v in timing.items() if k != "mitsuba")
            print(f"{name} {bname} {q} mitsuba {m / base / 1e3:.0f} Mrays/s | x mitsuba: "
                  f"{line} | bitwise {all(same.values())}", flush=True)
    return rows


def main(argv=None) -> int:
    ap = probe_parser(__doc__, SCENES)
    a = ap.parse_args(argv)
    warnings.simplefilter("ignore")
    t = types(a.backend)
    size = (1920, 1080) if a.backend == "cuda" else (160, 90)
    return run_probe(Path(a.out) / "ray-sort.json", a.force, a.scenes.split(","),
                     lambda name: probe(name, t, *size, 7 if a.backend == "cuda" else 3),
                     {"backend": a.backend})


if __name__ == "__main__":
    raise SystemExit(main())
