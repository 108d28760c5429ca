"""The watertight ray/triangle test (``renderer.accel.triangle.watertight``): agreement with
Möller–Trumbore away from edges, no ray through a shared edge or vertex missing both
triangles, exact ties on coplanar faces, the packed layout that gives it exact vertices, and
the BVH boxes it needs."""
from __future__ import annotations

from dataclasses import replace

import drjit as dr
import numpy as np
import pytest
from accel_util import assert_same_hits, hits, random_rays, scene_from_arrays, soup

from renderer.accel import ACCELERATORS, Ray, build_accelerator, triangle
from renderer.accel.bvh_build import build_bvh, refit_boxes
from renderer.device import array3, types

PRECISIONS = ("float32", "float64")


def _routine_hits(t, routine, o, d, P):
    """(t, u, v, hit) numpy arrays of ``routine`` on rays (o, d) and triangles P (N, 3, 3),
    packed and loaded as the accelerators do."""
    layout = triangle.layout_of(routine)
    fdt = np.float64 if t.is_double else np.float32
    packed = triangle.pack(P.reshape(-1, 3), np.arange(P.shape[0] * 3).reshape(-1, 3),
                           layout).astype(fdt)
    k = triangle.LAYOUT_VECTORS[layout]
    vecs = [array3(t, packed[:, 3 * j:3 * j + 3]) for j in range(k)]
    out = triangle.ROUTINES[routine](array3(t, o), array3(t, d), *vecs)
    return [np.asarray(x.numpy()) for x in out]


@pytest.mark.parametrize("precision", PRECISIONS)
def test_agrees_with_moller_trumbore_away_from_edges(precision):
    t = types("llvm", precision)
    rng = np.random.default_rng(3)
    n = 20000
    P = rng.normal(size=(n, 3, 3))
    o = rng.normal(size=(n, 3)) * 3
    b = rng.dirichlet([1, 1, 1], n)
    aim = np.einsum("nk,nkj->nj", b, P)
    d = aim - o + rng.normal(size=(n, 3)) * 0.3
    tm, um, vm, hm = _routine_hits(t, "moller_trumbore", o, d, P)
    tw, uw, vw, hw = _routine_hits(t, "watertight", o, d, P)
    # decide the same wherever the barycentrics are not within 1e-4 of an edge
    bm = np.stack([1 - um - vm, um, vm], 1)
    clear = np.all(np.abs(bm) > 1e-4, axis=1) & np.all(np.abs(bm - 1) > 1e-4, axis=1)
    assert hm.sum() > 1000
    assert np.array_equal(hm[clear], hw[clear])
    both = hm & hw
    tol = 1e-3 if precision == "float32" else 1e-9
    assert np.allclose(tw[both], tm[both], rtol=tol, atol=tol)
    assert np.allclose(uw[both], um[both], rtol=tol, atol=tol)
    assert np.allclose(vw[both], vm[both], rtol=tol, atol=tol)


@pytest.mark.parametrize("precision", PRECISIONS)
def test_rays_through_shared_edges_and_vertices_never_leak(precision):
    """A fan of 8 triangles around a vertex far from the origin; rays from origins rounded
    to the precision, aimed at the shared vertex and at points of the shared edges: each
    must hit at least one triangle of the fan (Möller–Trumbore without its edge slack
    misses many of them)."""
    t = types("llvm", precision)
    fdt = np.float64 if t.is_double else np.float32
    rng = np.random.default_rng(5)
    c = np.array([148376.0, 1234.0, -223423.0])
    ang = np.sort(rng.uniform(0, 2 * np.pi, 8))
    # facets tilted by <= 4 degrees, seen from >= 60 degrees elevation: no facet is seen
    # edge-on, so no shared edge is a silhouette (where a rounded aim may miss both; a
    # first version with 20-degree facets had one such legitimate miss)
    ring = c + np.stack([np.cos(ang), np.clip(0.01 * rng.normal(size=8), -0.02, 0.02),
                         np.sin(ang)], 1) * 10
    hub = c + [0.0, 0.5, 0.0]
    P = np.stack([np.repeat(hub[None], 8, 0), ring, np.roll(ring, -1, 0)], 1)
    P = P.astype(fdt).astype(np.float64)
    n = 4000
    o = (c + [0, 50.0, 0] + rng.normal(size=(n, 3)) * 5).astype(fdt).astype(np.float64)
    s = rng.uniform(0, 1, (n, 1))
    e = rng.integers(0, 8, n)
    targets = np.where(np.arange(n)[:, None] < 200, P[0, 0],
                       P[e, 0] * (1 - s) + P[e, 1] * s)       # vertex, then edge points
    d = targets - o
    reps = np.repeat(np.arange(n), 8)
    for routine, slack in (("watertight", None), ("moller_trumbore", 0.0)):
        saved = triangle.edge_slack
        if slack is not None:
            triangle.edge_slack = lambda double: 0.0
        try:
            _, _, _, h = _routine_hits(t, routine, o[reps], d[reps], np.tile(P, (n, 1, 1)))
        finally:
            triangle.edge_slack = saved
        misses = int((~h.reshape(n, 8).any(axis=1)).sum())
        if routine == "watertight":
            assert misses == 0
        else:
            assert misses > 0      # the test can see a leak


@pytest.mark.parametrize("precision", PRECISIONS)
def test_coplanar_faces_on_an_axis_plane_tie_exactly(precision):
    """Two different triangles of the plane y = 0.5: the same t for every ray that hits
    both, so the closest-hit tie-break (lowest face index) decides, not rounding."""
    t = types("llvm", precision)
    rng = np.random.default_rng(8)
    n = 5000
    A = np.array([[-1, 0.5, -1.0], [1, 0.5, -1], [0, 0.5, 1.3]])
    B = np.array([[-0.9, 0.5, 0.8], [0.1, 0.5, -1.2], [1.1, 0.5, 0.9]])
    o = rng.normal(size=(n, 3)) + [0, 3, 0]
    d = np.concatenate([rng.uniform(-0.3, 0.3, (n, 1)), -np.ones((n, 1)),
                        rng.uniform(-0.3, 0.3, (n, 1))], 1)
    d[: n // 2, 1] = -0.2                       # half the rays with x or z the major axis
    ta, *_, ha = _routine_hits(t, "watertight", o, d, np.repeat(A[None], n, 0))
    tb, *_, hb = _routine_hits(t, "watertight", o, d, np.repeat(B[None], n, 0))
    both = ha & hb
    assert both.sum() > 500
    assert np.array_equal(ta[both], tb[both])


@pytest.mark.parametrize("half", [2e3, 2e4, 2e5])
@pytest.mark.parametrize("precision", PRECISIONS)
def test_near_hits_on_a_huge_triangle_are_kept(precision, half):
    """Hits close to the ray origin on a triangle far larger than the distance (a floor of
    side 2·``half`` under small objects): every ray from 0.01 ... 1 above the floor aimed
    down at it, grazing ones included, hits at the exact ``t`` (float64 of the same ray, rel
    1e-6), and rays leaving the floor from 0 ... 1 ulp above it never hit it. The
    conservative ``t > 0`` test bounds the error of the routine's own plane ``t``; pbrt-v4's
    deltaT (for a ``t`` interpolated from the vertices' depths along the ray) grows with the
    triangle's extent along the ray and rejected these hits up to t ≈ 2 at ``half`` 2e5."""
    t = types("llvm", precision)
    fdt = np.float64 if t.is_double else np.float32
    rng = np.random.default_rng(11)
    n = 4000
    P = np.array([[-half, 0, -half], [half, 0, -half], [0, 0, 2 * half]])
    h = 10.0 ** rng.uniform(-2, 0, n)
    o = np.stack([rng.uniform(-1, 1, n), h, rng.uniform(-1, 1, n)], 1).astype(fdt)
    az = rng.uniform(0, 2 * np.pi, n)
    dy = -10.0 ** rng.uniform(-1.5, 0, n)           # down, grazing down to ~2 degrees
    d = np.stack([np.cos(az), dy, np.sin(az)], 1).astype(fdt)
    d64 = d.astype(np.float64)
    t_true = -o[:, 1].astype(np.float64) / d64[:, 1]
    tw, _, _, hw = _routine_hits(t, "watertight", o.astype(np.float64), d64,
                                 np.repeat(P[None], n, 0))
    assert hw.all(), f"{(~hw).sum()} of {n} near hits dropped (t up to {t_true[~hw].max()})"
    assert np.allclose(tw, t_true, rtol=1e-6, atol=0)
    # leaving the floor: origins on it or one ulp above, directions up
    o_up = o.copy()
    o_up[:, 1] = np.where(np.arange(n) % 2 == 0, 0.0, np.nextafter(fdt(0), fdt(1)))
    d_up = d64 * [1, -1, 1]
    *_, h_up = _routine_hits(t, "watertight", o_up.astype(np.float64), d_up,
                             np.repeat(P[None], n, 0))
    assert not h_up.any()


def test_vertices_layout_keeps_the_shared_vertices_exact():
    """In float32, v0 + (v1 - v0) is often not v1 (vertices of different magnitudes); the
    vertices layout stores v1 itself (and the unit normal in the padding)."""
    rng = np.random.default_rng(2)
    V = (10.0 ** rng.uniform(-3, 5, (3000, 3)) * rng.choice([-1, 1], (3000, 3)))
    V32 = V.astype(np.float32).astype(np.float64)
    F = np.arange(3000).reshape(-1, 3)
    edges = triangle.pack(V32, F, "edges").astype(np.float32)
    verts = triangle.pack(V32, F, "vertices").astype(np.float32)
    v1 = V32[F[:, 1]].astype(np.float32)
    assert np.any(edges[:, 0:3] + edges[:, 3:6] != v1)
    assert np.array_equal(verts[:, 3:6], v1)
    assert np.array_equal(verts[:, 6:9], V32[F[:, 2]].astype(np.float32))
    assert np.allclose(np.linalg.norm(verts[:, 9:12].astype(np.float64), axis=1), 1, atol=1e-6)
    with pytest.raises(ValueError, match="layout"):
        triangle.pack(V32, F, "strips")


def test_boxes_are_refit_in_float64_and_widened_for_the_origins():
    V, F = soup(300, seed=4)
    V = V + [1e5, 0, 0]
    a = build_bvh(V.astype(np.float32), F)
    b64 = refit_boxes(a, V, F, np.float64, 1.0)
    assert b64.dtype == np.float64
    # every triangle lies inside its leaf boxes, exactly (float64 vertices)
    ref = a.children.astype(np.int64)
    for node in range(a.node_count):
        for k in range(2):
            r = ref[node, k]
            if r & (1 << 31):
                first, count = r & ((1 << 27) - 1), ((r >> 27) & 15) + 1
                p = V[F[a.order[first:first + count]]].reshape(-1, 3)
                assert np.all(p >= b64[node, 6 * k:6 * k + 3])
                assert np.all(p <= b64[node, 6 * k + 3:6 * k + 6])
    sc = scene_from_arrays(V, F)
    for routine in ("moller_trumbore", "watertight"):     # both: the slab test's FMA form
        assert triangle.box_reach(sc, routine) >= 1e5
        assert triangle.pad_extent(sc, routine) >= 1e5 + np.max(np.ptp(V, axis=0)) - 1e-6


@pytest.mark.parametrize("precision", PRECISIONS)
def test_every_accelerator_gives_brute_force_hits(precision):
    t = types("llvm", precision)
    V, F = soup(400, seed=9)
    sc = scene_from_arrays(V, F, n_objects=4)
    ray, active = random_rays(t, 3000, seed=2)
    out = {}
    for name in ACCELERATORS:
        acc = build_accelerator(name, sc, t, intersection="watertight")
        h = acc.intersect(ray, active)
        order = dr.gather(t.UInt32, acc.tris.order, h.prim, h.found)
        out[name] = (h.found.numpy(), np.where(h.found.numpy(), order.numpy(), 0),
                     np.where(h.found.numpy(), h.t.numpy(), 0))
    for name in ACCELERATORS:
        for x, y in zip(out[name], out["brute"]):
            assert np.array_equal(x, y), name


@pytest.mark.parametrize("precision", PRECISIONS)
def test_origins_beyond_the_reach_keep_brute_force_hits(precision):
    """Rays from 10^3 and 10^5 scene sizes away, aimed at triangle vertices (box faces):
    the boxes' padding does not cover the rounding of origins that far
    (``traverse.box_ray``), so such rays enter every box and every accelerator gives
    brute force's hits, also through the refill traversal. Without that (``reach`` = inf),
    the BVHs lose some in float32."""
    t = types("llvm", precision)
    V, F = soup(300, seed=11)
    sc = scene_from_arrays(V, F, n_objects=3)
    rng = np.random.default_rng(3)
    n = 20000
    tgt = V.astype(np.float64)[rng.integers(0, len(V), n)]
    u = rng.standard_normal((n, 3))
    o = tgt + u / np.linalg.norm(u, axis=1)[:, None] * np.where(
        rng.random(n) < 0.5, 1e3, 1e5)[:, None]
    ray = Ray(array3(t, o), array3(t, tgt - o), t.Float(np.full(n, np.inf)))
    on = dr.full(t.Bool, True, n)
    lost = 0
    for routine in ("watertight", "moller_trumbore"):
        ref = hits(build_accelerator("brute", sc, t, intersection=routine), ray, on, t)
        assert ref[0].sum() > n // 3
        for name in ACCELERATORS:
            acc = build_accelerator(name, sc, t, intersection=routine)
            assert_same_hits(hits(acc, ray, on, t), ref)
            if name in ("bvh", "bvh4"):         # lanes that take the next ray take its rule
                assert_same_hits(hits(replace(acc, refill=4), ray, on, t), ref)
            if name == "bvh" and precision == "float32":
                blind = hits(replace(acc, reach=float("inf")), ray, on, t)
                lost += int(np.sum(blind[0] != ref[0]) + np.sum(blind[5] != ref[5]))
    if precision == "float32":
        assert lost > 0                 # the test can see the boxes' blind spot


def _indexed_watertight(o, d, p0, p1, p2, n):
    """Reference for the rotation: the shear and edge functions with the axes chosen by
    integer indices (``kz`` the largest ``|d|`` component, the first of equal ones in the
    order x, y, z by pbrt-v4's ``MaxComponentIndex``-style test; ``kx = kz + 1``,
    ``ky = kz + 2`` mod 3), then the routine's own tail."""
    UInt32 = dr.uint32_array_t(type(o.x))
    a0, a1, a2 = p0 - o, p1 - o, p2 - o
    ad = dr.abs(d)
    kz = dr.select(ad.x > ad.y, dr.select(ad.x > ad.z, UInt32(0), UInt32(2)),
                   dr.select(ad.y > ad.z, UInt32(1), UInt32(2)))
    kx = dr.select(kz == 2, UInt32(0), kz + 1)
    ky = dr.select(kx == 2, UInt32(0), kx + 1)

    def pick(v, k):
        return dr.select(k == 0, v.x, dr.select(k == 1, v.y, v.z))
    dx, dy, dz = pick(d, kx), pick(d, ky), pick(d, kz)
    sx, sy = -dx * (1.0 / dz), -dy * (1.0 / dz)
    xy = [(dr.fma(sx, pick(a, kz), pick(a, kx)), dr.fma(sy, pick(a, kz), pick(a, ky)))
          for a in (a0, a1, a2)]
    double = dr.type_v(o) == dr.VarType.Float64
    return triangle._watertight_tail((a0, a1, a2), n, d, (*xy[0], *xy[1], *xy[2]), double,
                                     0.0)


@pytest.mark.parametrize("precision", PRECISIONS)
def test_bound_rotation_is_the_indexed_permutation(precision):
    """``watertight`` bound to its rays (``bind_routine``, as every traversal calls it)
    returns bitwise what the per-lane index permutation returns, on rays whose largest
    direction component is each axis in turn and on rays with equal components (ties)."""
    t = types("llvm", precision)
    rng = np.random.default_rng(11)
    n = 30000
    P = rng.normal(size=(n, 3, 3))
    o = rng.normal(size=(n, 3)) * 3
    aim = np.einsum("nk,nkj->nj", rng.dirichlet([1, 1, 1], n), P)
    d = aim - o
    # a third of the rays with tied components: |dx| = |dy|, |dy| = |dz|, all three
    tie = rng.integers(0, 4, n)
    d[tie == 1, 1] = -d[tie == 1, 0]
    d[tie == 2, 2] = d[tie == 2, 1]
    d[tie == 3, 1:] = d[tie == 3, :1]
    fdt = np.float64 if t.is_double else np.float32
    packed = triangle.pack(P.reshape(-1, 3), np.arange(n * 3).reshape(-1, 3),
                           "vertices").astype(fdt)
    vecs = [array3(t, packed[:, 3 * j:3 * j + 3]) for j in range(4)]
    O, D = array3(t, o), array3(t, d)
    bound = triangle.bind_routine(triangle.watertight, O, D)
    assert bound is not triangle.watertight
    assert triangle.bind_routine(triangle.moller_trumbore, O, D) is triangle.moller_trumbore
    got = [np.asarray(x.numpy()) for x in bound(O, D, *vecs)]
    ref = [np.asarray(x.numpy()) for x in _indexed_watertight(O, D, *vecs)]
    assert ref[3].sum() > n // 4                       # enough hits to compare
    axes = np.argmax(np.abs(d), axis=1)
    assert all(np.sum(ref[3] & (axes == k)) > 100 for k in range(3))
    for g, r in zip(got, ref):
        assert np.array_equal(g[ref[3]], r[ref[3]]) if g.dtype != bool else \
            np.array_equal(g, r)
