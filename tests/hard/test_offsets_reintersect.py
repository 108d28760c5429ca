"""Rays spawned by ``offset_origin`` never re-hit the triangle they leave (the offset's
error bound is enough for the intersection routine in use).

pbrt-v4's ``Triangle.Reintersect`` set-up: random triangles whose coordinates are
log-uniform over 10^±8 (size and position independently, so a triangle can sit 1e4 of its
own sizes from the origin or straddle it), one hit per triangle from a random ray, then
rays spawned from the hit in random directions over the whole sphere (``offset_origin``
picks the side); each is tested against the very triangle it leaves with the renderer's
routine and ``t_min = 0``. Any hit is a self-hit.

Measured (float32, LLVM, Möller–Trumbore, 1000 triangles x 1000 rays): the bound's margin
``POINT_ERROR_OPS`` of 7 gives 0 self-hits; ``test_offset_is_needed`` shows the check can
fail (no offset at all: thousands of self-hits), and the numbers at smaller margins are in
``self_hits``'s printout (``python tests/hard/test_offsets_reintersect.py``).
"""
from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace

import drjit as dr
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from renderer import shade  # noqa: E402
from renderer.accel.base import ClosestHit, DeviceTriangles, Ray  # noqa: E402
from renderer.accel.triangle import load, moller_trumbore, pack  # noqa: E402
from renderer.device import array3, types  # noqa: E402

SEED = 10      # fixed: the count is a property of the routine and the bound, not of luck


def _triangles(rng, n):
    """float64 (V, 3) vertices and (n, 3) faces of ``n`` random non-degenerate float32
    triangles: size 10^U(-8, 8), centre that size times 10^U(-4, 4) from the origin."""
    size = 10.0 ** rng.uniform(-8, 8, n)
    far = 10.0 ** rng.uniform(-4, 4, n)
    dirc = rng.normal(size=(n, 3))
    dirc /= np.linalg.norm(dirc, axis=1, keepdims=True)
    centre = dirc * (size * far)[:, None]
    V = (centre[:, None, :] + size[:, None, None] * rng.normal(size=(n, 3, 3)))
    V = V.astype(np.float32).astype(np.float64)
    area = np.linalg.norm(np.cross(V[:, 1] - V[:, 0], V[:, 2] - V[:, 0]), axis=1)
    keep = area > 1e-3 * size ** 2
    V = V[keep]
    return V.reshape(-1, 3), np.arange(V.shape[0] * 3).reshape(-1, 3), size[keep]


def self_hits(n_tris=1000, n_rays=1000, scale=1.0, seed=SEED, precision="float32"):
    """(self-hits, spawned rays) for ``n_tris`` random triangles x ``n_rays`` spawned rays
    each; ``scale`` multiplies the offset (1: the renderer's; 0: no offset)."""
    t = types("llvm", precision)
    rng = np.random.default_rng(seed)
    V, F, size = _triangles(rng, n_tris)
    nt = F.shape[0]
    packed = pack(V, F)
    fdt = np.float64 if t.is_double else np.float32
    tri_data = t.Float(packed.astype(fdt).reshape(-1))
    ng = np.cross(packed[:, 3:6], packed[:, 6:9])
    ng /= np.linalg.norm(ng, axis=1, keepdims=True)
    tris = DeviceTriangles(ng=array3(t, ng), n0=None, n1=None, n2=None,
                           material=t.UInt32(np.zeros(nt, np.uint32)), smooth=None,
                           order=t.UInt32(np.arange(nt, dtype=np.uint32)))
    accel = SimpleNamespace(tri_data=tri_data, tris=tris, intersection="moller_trumbore")
    # ---- one camera-like ray per triangle, towards a random point inside it ---------------
    b = rng.dirichlet([1, 1, 1], nt)
    q = np.einsum("nk,nkd->nd", b, V[F])
    away = rng.normal(size=(nt, 3))
    away /= np.linalg.norm(away, axis=1, keepdims=True)
    o = q + away * (size * 10.0 ** rng.uniform(-2, 2, nt))[:, None]
    d = (q - o) / np.linalg.norm(q - o, axis=1, keepdims=True)
    prim = t.UInt32(np.repeat(np.arange(nt, dtype=np.uint32), n_rays))
    idx = np.repeat(np.arange(nt), n_rays)
    O, D = array3(t, o[idx]), array3(t, d[idx])
    v0, e1, e2 = load(t, tri_data, prim)
    th, u, v, found = moller_trumbore(O, D, v0, e1, e2)
    hit = ClosestHit(t=th, u=u, v=v, prim=prim, found=found)
    sp = shade.surface_point(accel, Ray(o=O, d=D, t_max=t.Float(dr.inf)), hit, t,
                             SimpleNamespace(smooth_normals=False))
    sp.p_err = sp.p_err * scale
    # ---- spawned rays over the whole sphere ----------------------------------------------
    w = rng.normal(size=(nt * n_rays, 3))
    w /= np.linalg.norm(w, axis=1, keepdims=True)
    W = array3(t, w)
    so = shade.offset_origin(sp, W)
    _, _, _, again = moller_trumbore(so, W, v0, e1, e2)
    spawned = found & (dr.abs(dr.dot(W, sp.ng)) > 0)
    return int(dr.count(again & spawned)[0]), int(dr.count(spawned)[0])


def test_spawned_rays_never_rehit_their_triangle():
    hits, n = self_hits()
    assert n > 900_000, f"only {n} spawned rays: the set-up lost its hits"
    assert hits == 0, f"{hits} of {n} spawned rays hit the triangle they leave"


@pytest.mark.parametrize("precision", ["float64"])
def test_spawned_rays_never_rehit_their_triangle_float64(precision):
    hits, n = self_hits(n_tris=300, n_rays=300, precision=precision)
    assert n > 80_000
    assert hits == 0, f"{precision}: {hits} of {n} spawned rays re-hit their triangle"


def test_offset_is_needed():
    """The check can fail: spawned from the bare hit point, rays re-hit their triangle."""
    hits, n = self_hits(n_tris=300, n_rays=300, scale=0.0)
    assert hits > 0.01 * n, f"only {hits} of {n} self-hits without an offset"


if __name__ == "__main__":
    for s in (0.0, 1 / 7, 2 / 7, 3 / 7, 1.0):
        h, n = self_hits(scale=s)
        print(f"margin {7 * s:.0f} roundings: {h} self-hits of {n} spawned rays")


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_next_float_away(precision):
    """One float up or down from ±0, ±1 and ±tiny values, against numpy's nextafter."""
    t = types("llvm", precision)
    dt = np.float64 if t.is_double else np.float32
    x = np.array([0.0, -0.0, 1.0, -1.0, 1e-30, -1e-30, 3e5, -3e5], dt)
    for up in (True, False):
        got = np.array(shade._next_float_away(t.Float(x), t.Bool(np.full(len(x), up))))
        want = np.nextafter(x, dt(np.inf if up else -np.inf))
        assert np.all(np.isfinite(got)), got
        np.testing.assert_array_equal(got, want)
