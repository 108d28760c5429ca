"""Ray reordering for incoherent batches on the CPU: queries that sort the rays first.

On LLVM a traversal runs 16 rays per SIMD packet and a packet loops until its slowest ray
is done, so a packet of unrelated rays (random origins and directions, diffuse or glossy
bounces) pays for its longest ray 16 times, and every lane gathers from a different part
of the tree. ``SortedQueries`` groups the rays before tracing them: one bucket pass
(``dr.detail.block_mkperm``, a stable counting sort) over a 15-bit key made of the
direction's octant (3 bits) and the Morton code of the origin in a 16³ grid over the
scene's box (12 bits); then the rays are gathered into that order (evaluated), traced with
the wrapped accelerator, and the results scattered back to the callers' order. The hits
are the wrapped accelerator's, bit for bit: a ray's hit does not depend on its neighbours.

Cost and use: the sort evaluates the ray batch (it cannot be fused into a caller's
megakernel), so it is a query for evaluated batches (``evaluation.bench.throughput``'s
``+sort`` contender), not the renderer's default. On the CPU it pays on uniformly random
rays and not on mirror-reflection rays off primary hits, which arrive in pixel order and
are already coherent (``lab/notes/accel-decisions.md``).
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

from .base import ClosestHit, Ray

#: Bits of the origin's grid coordinate per axis (the key has 3 + 3 * ORIGIN_BITS bits).
ORIGIN_BITS = 4


def _spread3(x):
    """The low 5 bits of UInt32 ``x`` spread to every third bit (Morton interleave)."""
    x = (x | (x << 8)) & 0x0300F00F
    x = (x | (x << 4)) & 0x030C30C3
    return (x | (x << 2)) & 0x09249249


def ray_key(t, ray: Ray, lo, hi, bits: int = ORIGIN_BITS):
    """UInt32 sort key of each ray: the direction's octant (sign bits of x, y, z) above the
    Morton code of the origin's cell in a ``2^bits``-per-axis grid over ``[lo, hi]``
    (origins outside are clamped to the border cells). Returns ``(key, key_bits)``."""
    cells = 1 << bits
    q = []
    for a in range(3):
        scale = cells / max(float(hi[a]) - float(lo[a]), 1e-30)
        c = t.Int32((ray.o[a] - float(lo[a])) * scale)
        q.append(t.UInt32(dr.clip(c, 0, cells - 1)))
    morton = _spread3(q[0]) | (_spread3(q[1]) << 1) | (_spread3(q[2]) << 2)
    d = ray.d
    octant = (dr.select(d.x > 0, 4, 0) | dr.select(d.y > 0, 2, 0)
              | dr.select(d.z > 0, 1, 0))
    return (t.UInt32(octant) << (3 * bits)) | morton, 3 + 3 * bits


def ray_order(t, ray: Ray, lo, hi, bits: int = ORIGIN_BITS):
    """The permutation (UInt32, evaluated) that sorts ``ray`` by ``ray_key``, stable."""
    key, key_bits = ray_key(t, ray, lo, hi, bits)
    dr.eval(key)
    n = dr.width(key)
    mkperm = getattr(getattr(dr, "detail", None), "block_mkperm", None)
    if mkperm is None or n == 0:     # older Dr.Jit: the radix sort (several passes)
        return dr.argsort(key) if n else t.UInt32()
    return mkperm(key, n, 1 << key_bits)


@dataclass
class SortedQueries:
    """``intersect`` / ``intersect_p`` of ``accel`` on rays sorted by ``ray_order`` (see
    the module docstring). ``lo``, ``hi``: the box of the scene (host xyz) the origin grid
    spans; ``bits``: grid bits per axis."""

    accel: object
    lo: tuple
    hi: tuple
    bits: int = ORIGIN_BITS

    @classmethod
    def for_scene(cls, accel, scene, bits: int = ORIGIN_BITS) -> SortedQueries:
        V = np.asarray(scene.vertices, np.float64)
        lo, hi = (V.min(axis=0), V.max(axis=0)) if len(V) else (np.zeros(3), np.ones(3))
        return cls(accel, tuple(map(float, lo)), tuple(map(float, hi)), bits)

    @property
    def tris(self):
        return self.accel.tris

    def _sorted(self, ray: Ray, active):
        t = self.accel.types
        n = dr.width(ray.o, ray.d, ray.t_max, active)
        ray = Ray(o=t.Array3f(ray.o) + dr.zeros(t.Array3f, n),
                  d=t.Array3f(ray.d) + dr.zeros(t.Array3f, n),
                  t_max=t.Float(ray.t_max) + dr.zeros(t.Float, n))
        perm = ray_order(t, ray, self.lo, self.hi, self.bits)
        g = lambda v: dr.gather(type(v), v, perm)  # noqa: E731
        sray = Ray(o=g(ray.o), d=g(ray.d), t_max=g(ray.t_max))
        son = g(t.Bool(active) & dr.full(t.Bool, True, n))
        dr.eval(sray, son)              # the traversal kernel reads contiguous sorted rays
        return t, n, perm, sray, son

    @staticmethod
    def _unsort(v, perm, n):
        out = dr.zeros(type(v), n)
        dr.scatter(out, v, perm)
        return out

    def intersect(self, ray: Ray, active=True) -> ClosestHit:
        t, n, perm, sray, son = self._sorted(ray, active)
        h = self.accel.intersect(sray, son)
        return ClosestHit(*(self._unsort(v, perm, n) for v in (h.t, h.u, h.v, h.prim,
                                                                h.found)))

    def intersect_p(self, ray: Ray, active=True):
        t, n, perm, sray, son = self._sorted(ray, active)
        return self._unsort(self.accel.intersect_p(sray, son), perm, n)

    def stats(self) -> dict:
        return dict(self.accel.stats(), ray_order=f"octant + origin Morton {self.bits} bits")
