"""Closest-hit and any-hit queries behind one interface (``renderer.accel.base``).

``ACCELERATORS`` maps the names used on the command line to accelerator classes, each
built by ``cls.build(scene, t, intersection=...)``; ``build_accelerator(name, scene, t)``
validates both names. Where to add:

- a triangle routine: a function in ``triangle.py``, registered in ``ROUTINES``;
- an accelerator: a module with a plain dataclass answering ``intersect`` / ``intersect_p``
  / ``stats`` / ``tris`` from the steps of ``traverse.py``, registered in ``ACCELERATORS``
  (subclass ``base.Accelerator`` and give ``_traverse`` a ``probe`` argument, with the
  ``tie_break``/``tie_window``/``tie_slack`` fields, and the tie probe works unchanged).

``DEFAULT_ROUTINE`` is the watertight test (``triangle.watertight``), chosen from the
hard-case suite (``whitted hard-cases``; LLVM on this shared 2-core AMD EPYC,
``results/hard-cases/llvm-cpu``):

- leaks: both routines miss 0 of 10^6 rays from inside a closed sphere at (148376, 1234,
  -223423) and 0 of the rays aimed exactly at its vertices and edge midpoints, but
  Möller–Trumbore only thanks to its 16-ulp edge slack (without it 341 of 26 098
  vertex/edge rays miss); the watertight test needs no tuned slack;
- self-hits: from 10^6 rays spawned off 1000 random triangles (coordinates over 10^±8)
  Möller–Trumbore re-hits its own triangle 105 times in float32, the watertight test 0
  times (its ``t > 0`` trusted only beyond the rounding of its own plane ``t``; pbrt-v4's
  deltaT, used before, also held 0 but grew with a triangle's extent along the ray and
  dropped true hits near huge triangles: tests/test_watertight.py);
- coplanar faces: on an axis-aligned plane the watertight ``t`` is the plane's, so
  overlapping faces tie exactly (0 speckle pixels against Möller–Trumbore's 244 of 4096);
- cost per closest-hit ray (512² primary rays, best of 7, interleaved): BVH 1.24x on the
  Cornell box (134 → 167 ns float32), 0.99x on the bunny (276 → 273 ns); the test alone
  (brute force) 1.38x float32, 1.60x float64. The paper claims the same speed, Blender
  measured ~10 %; on the H200 the watertight test keeps 0.73–0.85x of Möller–Trumbore's
  closest-hit throughput (``results/h200/routine/``). float64 costs 1.08–1.21x float32
  (Möller–Trumbore), 1.17–1.40x (watertight).

Images change only where a glass path's ``t`` rounds differently (glass bunny at 128²: 138
pixels over 1e-3, every other bundled scene 0); the golden regression tests pass with
either routine, and ``--intersection moller_trumbore`` gives the old images bit for bit.
"""
from __future__ import annotations

from dataclasses import replace

from ..device import Types
from .base import Accelerator, ClosestHit, DeviceTriangles, Ray
from .boxes import ObjectBoxes
from .brute import BruteForce
from .builders import BUILDS, binary_tree, check_build
from .bvh import BVH
from .traverse import TIE_BREAKS
from .triangle import DEFAULT_ROUTINE, ROUTINES, triangle_routine
from .wide import BVH4, BVH8, WideBVH

ACCELERATORS = {"brute": BruteForce, "boxes": ObjectBoxes, "bvh": BVH, "bvh4": BVH4,
                "bvh8": BVH8}
#: The renderer's accelerator per backend (``default_accel``): every one gives the same
#: pixels, so the fastest is the default. Whitted frames, frozen, kernel time: on the H200
#: the binary BVH (the wide BVHs 1.06-1.83x slower at depth 2, 1024²:
#: ``results/h200/peer/experiments/pixel-blocks.md``); on this project's 2-core EPYC (LLVM,
#: AVX-512) the 4-wide BVH, 1.06-1.20x faster than the binary one at depth 2, 512², on the
#: Cornell box, Cornell spheres, Platonic solids and glass bunny, and 1.08-1.33x at the
#: scenes' own depth, 384² (glass bunny, bunny, Sponza, Conference, Cornell spheres); the
#: 8-wide BVH 0.69-1.12x.
DEFAULT_ACCELS = {"cuda": "bvh", "llvm": "bvh4"}

__all__ = ["ACCELERATORS", "BUILDS", "BVH", "BVH4", "BVH8", "DEFAULT_ACCELS", "DEFAULT_ROUTINE",
           "ROUTINES", "TIE_BREAKS", "TREE_ACCELS", "Accelerator", "BruteForce", "ClosestHit",
           "DeviceTriangles",
           "ObjectBoxes", "Ray", "WideBVH", "build_accelerator", "default_accel",
           "triangle_routine"]


def default_accel(backend: str) -> str:
    """The renderer's accelerator on ``backend`` ("cuda" or "llvm"): ``DEFAULT_ACCELS``."""
    if backend not in DEFAULT_ACCELS:
        raise ValueError(f"backend: expected one of {sorted(DEFAULT_ACCELS)}, got {backend!r}")
    return DEFAULT_ACCELS[backend]


#: The accelerators built over ``bvh_build``'s binary tree (``builders.binary_tree``).
TREE_ACCELS = ("bvh", "bvh4", "bvh8")


def build_accelerator(name: str, scene, t: Types, *, intersection: str = DEFAULT_ROUTINE,
                      tie_break: str = "lowest", tie_window: float = 0.0,
                      tie_slack: float = 0.0, build: str = "sah", cache=None,
                      frames: int | None = None, progress=None) -> Accelerator:
    """Build the accelerator ``name`` (a key of ``ACCELERATORS``) for ``scene`` with the
    triangle routine ``intersection`` (a key of ``ROUTINES``). ``tie_break`` (a value of
    ``TIE_BREAKS``), ``tie_window`` and ``tie_slack`` (world-space distances) choose the
    closest hit among near-equal ones (``traverse.tie_probe``); the default, "lowest", is
    the renderer's (window and slack unused). ``build`` (``builders.BUILDS``), ``cache`` (a
    ``cache.TreeCache`` or None) and ``frames`` (frames the caller renders, None: unknown)
    choose how the tree of a ``TREE_ACCELS`` accelerator is got (``builders.binary_tree``,
    which calls ``progress(build, levels_done)`` during a build);
    ``acc.info`` then names it (``tree_build``, ``tree_cached``, ``tree_seconds``)."""
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
        tree, how = binary_tree(scene, t.backend, build=build, cache=cache, frames=frames,
                                progress=progress)
        acc = ACCELERATORS[name].build(scene, t, intersection=intersection, binary=tree)
        acc.info.update(tree_build=how.build, tree_cached=how.cached,
                        tree_seconds=how.seconds)
    else:
        acc = ACCELERATORS[name].build(scene, t, intersection=intersection)
    if tie_break == "lowest":
        return acc
    return replace(acc, tie_break=tie_break, tie_window=float(tie_window),
                   tie_slack=float(tie_slack))
