"""Closest-hit and any-hit queries behind one interface (``renderer.accel.base``).

``ACCELERATORS`` maps the names used on the command line to accelerator classes, each
built by ``cls.build(scene, t, intersection=...)``; ``build_accelerator(name, scene, t)``
validates both names. Where to add:

- a triangle routine: a function in ``triangle.py``, registered in ``ROUTINES``;
- an accelerator: a module with a plain dataclass answering ``intersect`` / ``intersect_p``
  / ``stats`` / ``tris`` from the steps of ``traverse.py``, registered in ``ACCELERATORS``.
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
