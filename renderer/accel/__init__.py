"""Closest-hit and any-hit queries behind one interface (``renderer.accel.base``).

``ACCELERATORS`` maps the names used on the command line to accelerator classes, each
built by ``cls.build(scene, t, intersection=...)``; ``build_accelerator(name, scene, t)``
validates both names. Where to add:

- a triangle routine: a function in ``triangle.py``, registered in ``ROUTINES``;
- an accelerator: a module with a plain dataclass answering ``intersect`` / ``intersect_p``
  / ``stats`` / ``tris`` from the steps of ``traverse.py``, registered in ``ACCELERATORS``.

``DEFAULT_ROUTINE`` is the watertight test (``triangle.watertight``), chosen from the
hard-case suite (``whitted hard-cases``, LLVM on this 2-core CPU): both routines miss 0 of
10^6 rays from inside a closed sphere at (148376, 1234, -223423) and 0 of the rays aimed
exactly at its vertices and edges (Möller–Trumbore only thanks to its 16-ulp edge slack;
without it, 341 of 26k vertex/edge rays miss), but from 10^6 rays spawned off 1000 random
triangles (coordinates over 10^±8) Möller–Trumbore re-hits its own triangle 105 times in
float32 and the watertight test 0 times (its conservative ``t > deltaT``). Its cost per
closest-hit ray is within the noise of this shared machine, 0–15 % above
Möller–Trumbore (BVH, 512² primary rays: bunny 428–601 vs 442–578 ns, Cornell box 170 vs
150 ns in float32), as the paper claims (Blender measured ~10 %). Images change only at
ties on shared edges and in glass paths that a different ``t`` rounding sends elsewhere;
the golden regression tests pass with either. ``--intersection moller_trumbore`` keeps the
old images bit for bit.
"""
from __future__ import annotations

from ..device import Types
from .base import Accelerator, ClosestHit, DeviceTriangles, Ray
from .boxes import ObjectBoxes
from .brute import BruteForce
from .bvh import BVH
from .triangle import DEFAULT_ROUTINE, ROUTINES, triangle_routine

ACCELERATORS = {"brute": BruteForce, "boxes": ObjectBoxes, "bvh": BVH}
DEFAULT_ACCEL = "bvh"

__all__ = ["ACCELERATORS", "BVH", "DEFAULT_ACCEL", "DEFAULT_ROUTINE", "ROUTINES", "Accelerator",
           "BruteForce", "ClosestHit", "DeviceTriangles", "ObjectBoxes", "Ray", "build_accelerator",
           "triangle_routine"]


def build_accelerator(name: str, scene, t: Types, *,
                      intersection: str = DEFAULT_ROUTINE) -> Accelerator:
    """Build the accelerator ``name`` (a key of ``ACCELERATORS``) for ``scene`` with the
    triangle routine ``intersection`` (a key of ``ROUTINES``)."""
    if name not in ACCELERATORS:
        raise ValueError(f"accel: expected one of {sorted(ACCELERATORS)}, got {name!r}")
    triangle_routine(intersection)
    return ACCELERATORS[name].build(scene, t, intersection=intersection)
