"""Closest-hit and any-hit queries behind one interface (``renderer.accel.base``).

``ACCELERATORS`` maps the names used on the command line to accelerator classes, each
built by ``cls.build(scene, t, intersection=...)``; ``build_accelerator(name, scene, t)``
validates both names. Where to add:

- a triangle routine: a function in ``triangle.py``, registered in ``ROUTINES``;
- an accelerator: a module with a plain dataclass answering ``intersect`` / ``intersect_p``
  / ``stats`` / ``tris`` from the steps of ``traverse.py``, registered in ``ACCELERATORS``.
"""
from __future__ import annotations

from dataclasses import replace

from ..device import Types
from .base import Accelerator, ClosestHit, DeviceTriangles, Ray
from .boxes import ObjectBoxes
from .brute import BruteForce
from .bvh import BVH
from .traverse import TIE_BREAKS
from .triangle import ROUTINES, triangle_routine

ACCELERATORS = {"brute": BruteForce, "boxes": ObjectBoxes, "bvh": BVH}
DEFAULT_ACCEL = "bvh"
DEFAULT_ROUTINE = "moller_trumbore"

__all__ = ["ACCELERATORS", "BVH", "DEFAULT_ACCEL", "DEFAULT_ROUTINE", "ROUTINES", "Accelerator",
           "BruteForce", "ClosestHit", "DeviceTriangles", "ObjectBoxes", "Ray", "TIE_BREAKS",
           "build_accelerator", "triangle_routine"]


def build_accelerator(name: str, scene, t: Types, *, intersection: str = DEFAULT_ROUTINE,
                      tie_break: str = "lowest", tie_window: float = 0.0,
                      tie_slack: float = 0.0) -> Accelerator:
    """Build the accelerator ``name`` (a key of ``ACCELERATORS``) for ``scene`` with the
    triangle routine ``intersection`` (a key of ``ROUTINES``). ``tie_break`` (a value of
    ``TIE_BREAKS``), ``tie_window`` and ``tie_slack`` (world-space distances) choose the
    closest hit among near-equal ones (``traverse.tie_probe``); the default, "lowest", is
    the renderer's (window and slack unused)."""
    if name not in ACCELERATORS:
        raise ValueError(f"accel: expected one of {sorted(ACCELERATORS)}, got {name!r}")
    if tie_break not in TIE_BREAKS:
        raise ValueError(f"tie_break: expected one of {list(TIE_BREAKS)}, got {tie_break!r}")
    if not tie_window >= 0.0:
        raise ValueError(f"tie_window: expected a distance >= 0, got {tie_window!r}")
    if not tie_slack >= 0.0:
        raise ValueError(f"tie_slack: expected a distance >= 0, got {tie_slack!r}")
    triangle_routine(intersection)
    acc = ACCELERATORS[name].build(scene, t, intersection=intersection)
    if tie_break == "lowest":
        return acc
    return replace(acc, tie_break=tie_break, tie_window=float(tie_window),
                   tie_slack=float(tie_slack))
