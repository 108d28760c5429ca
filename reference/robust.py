"""Mitsuba renders with a choice of Embree's intersection mode, for the hard-case parity
check (``evaluation.hard.runners.case_mitsuba_parity``).

Mitsuba 3's CPU (LLVM) variants trace with Embree, by default in its fast mode, which is not
watertight: a ray through a shared edge or a vertex can pass between the triangles. The
scene parameter ``embree_use_robust_intersections`` switches Embree to its robust
(watertight) mode. ``render_exact_mode`` renders one ray per pixel centre either way, with the
``whitted`` integrator and Mitsuba's own ``spawn_ray`` offsets (the goldens' set-up,
``mitsuba_scene.to_mitsuba_dict``). This module is not one of the golden harness files
(``golden.HARNESS_FILES``): the goldens do not depend on it.
"""
from __future__ import annotations

import numpy as np

from .mitsuba_scene import _mi, render_exact, to_mitsuba_dict


def render_exact_mode(scene, *, robust: bool, view: int = 0) -> np.ndarray:
    """``scene`` rendered by Mitsuba in exact mode, Embree robust (``robust``) or fast.
    Returns float32 (H, W, 3) linear RGB."""
    mi = _mi()
    d = to_mitsuba_dict(scene, view=view, mode="exact")
    d["embree_use_robust_intersections"] = bool(robust)
    return render_exact(mi.load_dict(d))


def closest_t(vertices: np.ndarray, faces: np.ndarray, o: np.ndarray, d: np.ndarray, *,
              robust: bool) -> np.ndarray:
    """Closest-hit ``t`` (inf where missed) of the rays ``(o, d)`` (float (N, 3) each,
    rounded to float32) against one mesh of ``vertices`` (float (V, 3)) and ``faces`` (int
    (F, 3)), Embree robust (``robust``) or fast: ``scene.ray_intersect_preliminary``."""
    from .mitsuba_scene import rays
    mi = _mi()
    mesh = mi.Mesh("all", vertices.shape[0], faces.shape[0])
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(np.asarray(vertices, np.float32).ravel())
    params["faces"] = mi.UInt32(np.asarray(faces, np.uint32).ravel())
    params.update()
    scene = mi.load_dict({"type": "scene", "mesh": mesh,
                          "embree_use_robust_intersections": bool(robust)})
    pi = scene.ray_intersect_preliminary(rays(o, d), coherent=False)
    return np.asarray(pi.t.numpy(), np.float64)
