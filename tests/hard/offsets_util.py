"""Helpers of the ray-offset stress cases (tests/hard/test_offsets_*.py): moving a scene
rigidly, comparing two renders pixel by pixel with the exact rule's edge allowance."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from evaluation.gate.agreement import EDGE_TOL
from evaluation.gate.agreement import neighbour_range as _neighbour_range

#: float32 unit roundoff.
U32 = 2.0 ** -24


def transformed(scene, scale: float = 1.0, shift=(0.0, 0.0, 0.0)):
    """``scene`` with every position mapped to ``scale · x + shift`` (geometry from its
    float32 vertices, cameras, lights), light intensities times ``scale²`` where they fall
    off as 1/dist², so the image is the same in exact arithmetic. Vertices are rounded to
    float32 once, as the loader does; the float64 positions (``Scene.positions(True)``, the
    loader's unrounded vertices) are mapped too and kept as ``vertices64``, so a float64
    render of the moved scene sees its exact geometry (without them ``Scene.__post_init__``
    drops the stale float64 array and float64 renders widen the float32 vertices, rounded
    to 1/128 at 1e5 and to 1 at 1e7)."""
    shift = np.asarray(shift, np.float64)
    V64 = scene.positions(True) * scale + shift
    V = V64.astype(np.float32)
    cams = [replace(c, position=c.position * scale + shift, target=c.target * scale + shift)
            for c in scene.cameras]
    lights = [replace(li, position=li.position * scale + shift,
                      intensity=li.intensity * (scale ** 2 if li.falloff == "inverse_square"
                                                else 1.0))
              for li in scene.lights]
    return replace(scene, vertices=V, vertices64=V64, cameras=cams, lights=lights)


def quantized_at_origin(scene, shift):
    """``scene`` with the vertices ``transformed(scene, shift=shift)`` has (rounded to
    float32 at ``shift``) moved back by ``-shift`` (exact: the differences are multiples of
    the ulp at ``shift``), so it has exactly the moved scene's geometry, near the origin."""
    shift = np.asarray(shift, np.float64)
    V = ((scene.positions(True) + shift).astype(np.float32).astype(np.float64) - shift)
    assert np.array_equal(V.astype(np.float32).astype(np.float64), V)
    return replace(scene, vertices=V.astype(np.float32))


def compare(ours: np.ndarray, ref: np.ndarray, *, bad_rel: float = 0.05) -> dict:
    """Pixel comparison of two renders of the same scene (H, W, 3).

    bad pixels: some channel off by more than ``bad_rel`` relative (floor 0.1 on |ref|) and
    not explained as an edge (a 3x3 neighbourhood allowance, either way
    round): acne, leaks, black glass. relMSE: mean over pixels and channels of
    ``(a - r)² / (r² + 1e-2)``. Non-finite pixels are bad."""
    a = np.nan_to_num(np.asarray(ours, np.float64), nan=1e30, posinf=1e30, neginf=-1e30)
    r = np.asarray(ref, np.float64)
    rel = (np.abs(a - r) / np.maximum(np.abs(r), 0.1)).max(-1)
    tol = EDGE_TOL * np.maximum(np.abs(r), 1.0)
    lo, hi = _neighbour_range(a)
    explained = np.all((r >= lo - tol) & (r <= hi + tol), -1)
    lo, hi = _neighbour_range(r)
    explained |= np.all((a >= lo - tol) & (a <= hi + tol), -1)
    bad = (rel > bad_rel) & ~explained
    rel_mse = float(np.mean((a - r) ** 2 / (r ** 2 + 1e-2)))
    diff = np.abs(a - r).max(-1)
    edge = (rel > bad_rel) & explained
    return dict(bad=int(bad.sum()), edge=int(edge.sum()), rel_mse=rel_mse,
                max_abs=float(diff.max()), max_abs_not_edge=float(diff[~edge].max(initial=0)),
                pixels=int(bad.size))


def snapped(scene, shift):
    """``scene`` moved by ``shift`` with its vertices snapped to float32's grid there, as a
    float32 render sees them: ``transformed``'s cameras and lights, and the float32
    vertices as the float64 ones too, so a float64 render sees the same snapped geometry."""
    moved = transformed(scene, shift=shift)
    return replace(moved, vertices64=moved.vertices.astype(np.float64), normals64=None)


def far_from_origin_criterion(scene, shift, precision: str, *, view: int = 0,
                              bad_rel: float = 0.05) -> dict:
    """The honest far-from-the-origin check (issue 25): our render in ``precision`` of the
    scene moved by ``shift`` (``snapped``) against our float64 render of the *same snapped
    vertices*, so the geometry's own snapping to float32's grid is not counted against
    float32's arithmetic. Returns ``compare``'s dict plus ``shadow_pixels`` (pixels the
    reference's shadow rays darken: lit without shadows, more than ``bad_rel`` darker
    with them) and ``lost_shadow`` (of those, pixels ours leaves lit, off any edge the
    3x3 allowance explains): a shadow must survive wherever the snapped geometry still
    casts it."""
    from renderer.effects import EffectSet
    from renderer.render import render

    sc = snapped(scene, shift)
    fx = EffectSet.from_scene(sc)
    ref = render(sc, view=view, backend="llvm", precision="float64").image.astype(np.float64)
    lit = render(sc, view=view, backend="llvm", precision="float64",
                 effects=fx.without("shadows")).image.astype(np.float64)
    ours = render(sc, view=view, backend="llvm", precision=precision).image.astype(np.float64)
    res = compare(ours, ref, bad_rel=bad_rel)
    floor = np.maximum(np.abs(lit), 0.1)
    shadow = ((lit - ref) / floor).max(-1) > bad_rel
    ours_dark = ((lit - ours) / floor).max(-1) > bad_rel
    tol = EDGE_TOL * np.maximum(np.abs(ref), 1.0)
    lo, hi = _neighbour_range(ours)
    explained = np.all((ref >= lo - tol) & (ref <= hi + tol), -1)
    res.update(shadow_pixels=int(shadow.sum()),
               lost_shadow=int((shadow & ~ours_dark & ~explained).sum()))
    return res
