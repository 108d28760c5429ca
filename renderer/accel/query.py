"""The records of a query: the rays asked about, the hits answered, and the closest-hit
record a traversal carries, with the tie-break every accelerator applies.

``Ray`` and ``ClosestHit`` are what the integrator passes to and gets from an accelerator
(``renderer.accel.base``); ``Closest`` is the record a traversal folds candidate triangles
into (``traverse.triangle_step``); ``tie_probe`` / ``tie_probe_p`` run an accelerator's
traversal once (the renderer's tie-break, "lowest") or twice (the golden tests' probe of
geometric ties, "other").
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import drjit as dr

from ..device import Types, unit_roundoff
from .layout import DONE

#: Closest-hit tie-breaks: "lowest" (the renderer's: nearest ``t``, then the smallest
#: original face index) and "other" (a probe for the golden tests, ``tie_probe``: another
#: triangle as near as the nearest one within the precision, where there is one).
TIE_BREAKS = ("lowest", "other")


@dataclass
class Ray:
    """A batch of rays. o, d: Array3f (N,) origin and direction; t_max: Float, the end of
    the ray interval (0, t_max) in units of ``d``."""

    o: object
    d: object
    t_max: object


@dataclass
class ClosestHit:
    """Result of a closest-hit query (arrays of the ray batch's width).

    t: Float ray parameter; u, v: Float barycentrics of v1, v2; prim: UInt32 index into
    the accelerator's ``DeviceTriangles`` (undefined where not found); found: Bool.
    """

    t: object
    u: object
    v: object
    prim: object
    found: object


#: A probe's hit at ``t <= ORIGIN_OPS · u · max|o|`` (``u`` the unit roundoff, ``o`` the
#: ray's origin) lies at the ray's origin within the rounding of the point the ray left:
#: a spawned ray re-hitting its own surface, or a surface through its origin. That is no
#: tie: the probe leaves the renderer's answer there (``at_origin``).
ORIGIN_OPS = 64


class Probe(NamedTuple):
    """A pass of ``tie_probe`` / ``tie_probe_p``: the nearest hit's triangle (UInt32 per
    ray, an index in the accelerator's order like ``ClosestHit.prim``; None for any-hit),
    the slack (float, a world-space distance; negative narrows) of the inside test, and
    ``origin`` (Float per ray, ``at_origin``): hits at ``t <= origin`` keep the routine's
    own inside test when the slack narrows and do not count when it widens."""

    nearest: object
    slack: float
    origin: object = 0.0


def at_origin(o):
    """``ORIGIN_OPS · u · max|o|`` per ray: the distance along a ray from ``o`` within
    which a hit is at the origin for the tie probe (``Probe.origin``)."""
    mag = dr.maximum(dr.maximum(dr.abs(o.x), dr.abs(o.y)), dr.abs(o.z))
    return mag * (ORIGIN_OPS * unit_roundoff(dr.type_v(mag) == dr.VarType.Float64))


@dataclass
class Closest:
    """The closest-hit record a traversal carries: ``t`` starts at ``t_max`` and shrinks
    to the nearest hit; ``prim`` is the triangle in the accelerator's order and ``order``
    its original face index (the tie-break); u, v: barycentrics; found: Bool."""

    t: object
    u: object
    v: object
    prim: object
    order: object
    found: object

    @classmethod
    def empty(cls, t: Types, t_max, n: int) -> "Closest":
        return cls(t=t.Float(t_max) + dr.zeros(t.Float, n), u=dr.zeros(t.Float, n),
                   v=dr.zeros(t.Float, n), prim=dr.zeros(t.UInt32, n),
                   order=dr.full(t.UInt32, DONE, n), found=dr.zeros(t.Bool, n))

    def result(self) -> ClosestHit:
        return ClosestHit(t=self.t, u=self.u, v=self.v, prim=self.prim, found=self.found)


def tie_probe(traverse, ray: Ray, active, tie_break: str, window: float,
              slack: float) -> ClosestHit:
    """The closest hit under ``tie_break`` (``TIE_BREAKS``) through ``traverse(ray, active,
    probe)``, an accelerator's closest-hit traversal (``probe``: None or a ``Probe``).

    "lowest" is one pass, the renderer's. "other" is two: the nearest hit at ``t*`` (pass
    one, the renderer's hit), then every triangle hit in ``(0, t* + window]`` with the
    inside test widened by the distance ``slack`` (``traverse.probe_inside``; pass two): the one
    with the largest original face index other than the nearest wins; where there is none,
    the nearest stays. ``window`` and ``slack`` are world-space distances (``ray.d`` unit
    length, as the integrator's rays are). So the
    closest hit changes exactly where another triangle is as near as the nearest within
    the precision (a shared edge, a corner, coplanar faces): a geometric tie, which two
    renderers may resolve either way. Where pass one finds nothing, pass two does not run
    (a crack stays a crack). A window reaching ``ray.t_max`` shrinks to ``t*``."""
    if tie_break not in TIE_BREAKS:
        raise ValueError(f"tie_break: expected one of {list(TIE_BREAKS)}, got {tie_break!r}")
    first = traverse(ray, active, None)
    if tie_break == "lowest":
        return first
    limit = first.t + window
    limit = dr.select(first.found & (limit < ray.t_max), limit, first.t)
    origin = at_origin(ray.o)
    other = traverse(Ray(o=ray.o, d=ray.d, t_max=limit),
                     first.found & (first.t > origin) & active,
                     Probe(nearest=first.prim, slack=slack, origin=origin))
    keep = ~other.found
    return ClosestHit(t=dr.select(keep, first.t, other.t), u=dr.select(keep, first.u, other.u),
                      v=dr.select(keep, first.v, other.v),
                      prim=dr.select(keep, first.prim, other.prim), found=first.found)


def tie_probe_p(traverse, ray: Ray, active, tie_break: str, slack: float):
    """Any hit (shadow rays) under ``tie_break`` through ``traverse(ray, active, probe)``,
    an accelerator's any-hit traversal. "lowest": the renderer's answer. "other": the
    answer flipped where the inside test decides it within ``slack`` (the ray grazes an
    occluder's edge): a blocked ray stays blocked only if it is blocked with the inside
    test narrowed by ``slack``, an unblocked one becomes blocked if it is blocked with the
    test widened by ``slack``."""
    found = traverse(ray, active, None)
    if tie_break == "lowest":
        return found
    origin = at_origin(ray.o)
    narrow = traverse(ray, active & found, Probe(nearest=None, slack=-slack, origin=origin))
    wide = traverse(ray, active & ~found, Probe(nearest=None, slack=slack, origin=origin))
    return dr.select(found, narrow, wide)
