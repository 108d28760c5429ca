"""Closest-hit and any-hit queries behind one interface (``renderer.accel.base``).

``ACCELERATORS`` maps the names used on the command line to accelerator classes, each
built by ``cls.build(scene, t, intersection=...)``; ``build_accelerator(name, scene, t)``
validates both names. Where to add:

- a triangle routine: a function in ``triangle.py``, registered in ``ROUTINES``;
- an accelerator: a module with a plain dataclass answering ``intersect`` / ``intersect_p``
  / ``stats`` / ``tris`` from the steps of ``traverse.py``, registered in ``ACCELERATORS``
  (subclass ``base.Accelerator`` and give ``_traverse`` a ``probe`` argument, with the
  ``tie_break``/``tie_window``/``tie_slack`` fields, and the tie probe works unchanged).

Modules, from the bottom up: ``layout`` (node references, the stack bound), ``query``
(``Ray``, ``ClosestHit``, the closest-hit record, the tie probe), ``base`` (the interface,
the gathers), ``triangle`` (the routines and the packed triangles), ``traverse`` (the steps
every traversal is made of), ``bvh_arrays``, ``spatial``, ``optimize`` and ``bvh_build``
(the host build), then the accelerators ``brute``, ``boxes``, ``bvh`` and ``wide``, and
``order`` (sorted queries).

Defaults: ``DEFAULT_ROUTINE`` is the watertight test (``triangle.watertight``): no ray
leaks through the shared edges and vertices of a closed mesh without a tuned slack, no ray
spawned off a triangle re-hits it, and coplanar faces tie exactly;
``--intersection moller_trumbore`` selects the other routine. ``DEFAULT_ACCELS`` names the
fastest accelerator for Whitted frames on each backend (every accelerator gives the same
pixels): the binary BVH on CUDA, the 4-wide BVH on LLVM. The measurements behind both:
``lab/notes/accel-decisions.md``.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

from ..device import Types
from .base import Accelerator, ClosestHit, DeviceTriangles, Ray
from .boxes import ObjectBoxes
from .brute import BruteForce
from .builders import BUILDS, LayoutRequest, check_build, tree_accelerator
from .bvh import BVH
from .query import TIE_BREAKS
from .triangle import DEFAULT_ROUTINE, ROUTINES, triangle_routine
from .wide import BVH4, BVH8, WideBVH

ACCELERATORS = {"brute": BruteForce, "boxes": ObjectBoxes, "bvh": BVH, "bvh4": BVH4,
                "bvh8": BVH8}
#: The renderer's accelerator per backend (``default_accel``): the fastest for Whitted
#: frames there (see the module docstring).
DEFAULT_ACCELS = {"cuda": "bvh", "llvm": "bvh4"}

__all__ = ["ACCELERATORS", "BUILDS", "BVH", "BVH4", "BVH8", "DEFAULT_ACCELS", "DEFAULT_ROUTINE",
           "ROUTINES", "TIE_BREAKS", "TREE_ACCELS", "Accelerator", "BruteForce", "BuildRequest",
           "ClosestHit", "DeviceTriangles",
           "ObjectBoxes", "Ray", "WideBVH", "build_accelerator", "default_accel",
           "triangle_routine"]


def default_accel(backend: str) -> str:
    """The renderer's accelerator on ``backend`` ("cuda" or "llvm"): ``DEFAULT_ACCELS``."""
    if backend not in DEFAULT_ACCELS:
        raise ValueError(f"backend: expected one of {sorted(DEFAULT_ACCELS)}, got {backend!r}")
    return DEFAULT_ACCELS[backend]


#: The accelerators built over ``bvh_build``'s binary tree (``builders.binary_tree``).
TREE_ACCELS = ("bvh", "bvh4", "bvh8")


@dataclass(frozen=True)
class BuildRequest:
    """How ``build_accelerator`` builds: the triangle routine ``intersection`` (a key of
    ``ROUTINES``); ``tie_break`` (a value of ``TIE_BREAKS``), ``tie_window`` and
    ``tie_slack`` (world-space distances) choose the closest hit among near-equal ones
    (``query.tie_probe``); the default, "lowest", is the renderer's (window and slack
    unused). ``build`` (``builders.BUILDS``), ``cache`` (a ``cache.TreeCache`` or None) and
    ``frames`` (frames the caller renders, None: unknown) choose how the tree of a
    ``TREE_ACCELS`` accelerator is got (``builders.binary_tree``, which calls
    ``progress(build, levels_done)`` during a build), and with a cache the arrays it
    uploads (``builders.tree_accelerator``)."""

    intersection: str = DEFAULT_ROUTINE
    tie_break: str = "lowest"
    tie_window: float = 0.0
    tie_slack: float = 0.0
    build: str = "sah"
    cache: object = None
    frames: int | None = None
    progress: object = None


def build_accelerator(name: str, scene, t: Types, request: BuildRequest | None = None,
                      **keywords) -> Accelerator:
    """Build the accelerator ``name`` (a key of ``ACCELERATORS``) for ``scene`` as
    ``request`` says (a ``BuildRequest``; its fields may also be given as ``keywords``,
    which override it). ``acc.info`` then names how the tree was got (``tree_build``,
    ``tree_cached``, ``tree_seconds``)."""
    req = replace(request or BuildRequest(), **keywords)
    intersection, tie_break = req.intersection, req.tie_break
    tie_window, tie_slack, build = req.tie_window, req.tie_slack, req.build
    if name not in ACCELERATORS:
        raise ValueError(f"accel: expected one of {sorted(ACCELERATORS)}, got {name!r}")
    if tie_break not in TIE_BREAKS:
        raise ValueError(f"tie_break: expected one of {list(TIE_BREAKS)}, got {tie_break!r}")
    if not tie_window >= 0.0:
        raise ValueError(f"tie_window: expected a distance >= 0, got {tie_window!r}")
    if not tie_slack >= 0.0:
        raise ValueError(f"tie_slack: expected a distance >= 0, got {tie_slack!r}")
    triangle_routine(intersection)
    check_build(build)
    if name in TREE_ACCELS:
        cls = ACCELERATORS[name]
        width = {"bvh": 2, "bvh4": 4, "bvh8": 8}[name]
        acc = tree_accelerator(scene, t, LayoutRequest(name, cls, width, intersection), req)
    else:
        acc = ACCELERATORS[name].build(scene, t, intersection=intersection)
    if tie_break == "lowest":
        return acc
    return replace(acc, tie_break=tie_break, tie_window=float(tie_window),
                   tie_slack=float(tie_slack))
