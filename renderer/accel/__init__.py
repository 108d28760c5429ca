"""TEMPORARY SHIM (branch house-scene only; replaced by the ACCEL engineer's package at merge).

Presents the new accelerator interface over the old ``renderer.intersect`` API so the scene
and shading code can be written against it:

    accel.intersect(Ray(o, d, t_max), active) -> ClosestHit(t, u, v, prim, found)
    accel.intersect_p(Ray(o, d, t_max), active) -> Bool
"""
from __future__ import annotations

from dataclasses import dataclass

from ..intersect import build_accelerator as _build_old

DEFAULT_ACCEL = "bvh"
ACCELERATORS = ("brute", "boxes", "bvh")


@dataclass
class Ray:
    """o, d: Array3f; t_max: Float."""

    o: object = None
    d: object = None
    t_max: object = None


@dataclass
class ClosestHit:
    """t, u, v: Float; prim: UInt32; found: Bool."""

    t: object = None
    u: object = None
    v: object = None
    prim: object = None
    found: object = None


@dataclass
class _Adapter:
    inner: object = None

    @property
    def tris(self):
        return self.inner.tris

    def stats(self) -> dict:
        return self.inner.stats()

    def intersect(self, ray: Ray, active) -> ClosestHit:
        h = self.inner.intersect(ray.o, ray.d, ray.t_max, active)
        return ClosestHit(t=h.t, u=h.u, v=h.v, prim=h.prim, found=h.valid)

    def intersect_p(self, ray: Ray, active):
        return self.inner.intersect_p(ray.o, ray.d, ray.t_max, active)


def build_accelerator(name: str, scene, t, *, intersection: str = "moller_trumbore"):
    return _Adapter(_build_old(name, scene, t, intersection=intersection))
