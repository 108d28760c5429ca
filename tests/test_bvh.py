"""Acceleration structures: the BVH and per-object boxes give bitwise the hits of brute force.

References: ``BruteForce`` (every ray against every triangle, same triangle routine) and, for
the structure itself, direct numpy checks (every triangle in exactly one leaf, boxes contain
their triangles, level bound).
"""
from dataclasses import replace
from pathlib import Path

import drjit as dr
import numpy as np
import pytest

from renderer.bvh import (BVH, MAX_LEVELS, LEAF_BIT, COUNT_SHIFT, FIRST_MASK, ObjectBoxes,
                          build_bvh, check_bvh)
from renderer.device import types
from renderer.intersect import BruteForce
from renderer.scene import Camera, ObjectInfo, Scene, Settings
from renderer.scene.subdivide import subdivide_midpoint

ROOT = Path(__file__).resolve().parents[1]


# ---- helpers ------------------------------------------------------------------------------
def scene_from_arrays(V, faces, n_objects=1):
    """A Scene holding the triangle soup (V, faces), split into ``n_objects`` face ranges."""
    V = np.asarray(V, np.float32)
    faces = np.asarray(faces, np.int32)
    F = len(faces)
    cuts = np.linspace(0, F, n_objects + 1).astype(int)
    objs = [ObjectInfo(f"o{k}", "soup", 0, int(cuts[k]), int(cuts[k + 1] - cuts[k]), 0,
                       len(V), False) for k in range(n_objects)]
    cam = Camera(np.zeros(3), np.ones(3), np.array([0.0, 1.0, 0.0]), 40.0, 8, 8)
    return Scene([cam], Settings(), [], [], objs, V, np.zeros_like(V), faces,
                 np.zeros(F, np.int32), np.repeat(np.arange(n_objects), np.diff(cuts)).astype(np.int32))


def soup(F, seed, size=0.05):
    """F random triangles of about ``size`` in the unit cube (fixed seed)."""
    rng = np.random.default_rng(seed)
    c = rng.random((F, 3))
    V = (c[:, None, :] + size * rng.standard_normal((F, 3, 3))).reshape(-1, 3)
    return V, np.arange(3 * F).reshape(F, 3)


def random_rays(t, n, seed):
    """Rays from around the unit cube in random directions; half with a finite t_max, some
    inactive, some with exactly-zero direction components (axis-parallel)."""
    rng = np.random.default_rng(seed)
    o = rng.random((n, 3)) * 1.6 - 0.3
    d = rng.standard_normal((n, 3))
    zero = rng.random((n, 3)) < 0.1
    d[zero] = 0.0
    d[np.all(d == 0, axis=1), 1] = 1.0
    t_max = np.where(rng.random(n) < 0.5, np.inf, rng.random(n) * 0.8)
    active = rng.random(n) < 0.9
    a3 = lambda x: t.Array3f(*(t.Float(np.ascontiguousarray(x[:, k])) for k in range(3)))
    return a3(o), a3(d), t.Float(t_max), t.Bool(active)


def hits(acc, o, d, t_max, active, t):
    """(valid, t, original face, u, v, any-hit) as numpy arrays."""
    h = acc.intersect(o, d, t_max, active)
    p = acc.intersect_p(o, d, t_max, active)
    face = dr.gather(t.UInt32, acc.tris.order, h.prim, h.valid)
    return (h.valid.numpy(), h.t.numpy(), face.numpy(), h.u.numpy(), h.v.numpy(), p.numpy())


def assert_same_hits(got, ref):
    valid = ref[0]
    assert np.array_equal(got[0], valid)
    for k in (1, 2, 3, 4):                       # t, face, u, v bitwise where valid
        assert np.array_equal(got[k][valid], ref[k][valid])
    assert np.array_equal(got[5], ref[5])


# ---- structure ----------------------------------------------------------------------------
@pytest.mark.parametrize("leaf_size", [1, 4, 8])
def test_bvh_structure_is_valid(leaf_size):
    V, faces = soup(3000, seed=1)   # fixed seed: a reproducible soup
    a = build_bvh(V, faces, leaf_size=leaf_size)
    check_bvh(a)
    # Every leaf's box contains its triangles (and leaves respect leaf_size).
    tri = np.asarray(V, np.float32)[faces[a.order]]
    tlo, thi = tri.min(axis=1), tri.max(axis=1)
    for k in range(2):
        ref = a.children[:, k].astype(np.int64)
        leaf = (ref & LEAF_BIT) != 0
        first = ref[leaf] & FIRST_MASK
        count = ((ref[leaf] >> COUNT_SHIFT) & 15) + 1
        assert count.max() <= leaf_size
        box = a.boxes[leaf, 6 * k:6 * k + 6]
        for j in range(count.max()):
            m = j < count
            i = first[m] + j
            assert np.all(box[m, 0:3] <= tlo[i]) and np.all(box[m, 3:6] >= thi[i])
    assert a.levels <= MAX_LEVELS and a.sah_cost > 0


def test_stack_bound_on_degenerate_input():
    # 20,000 coincident triangles: no SAH split exists; median splits keep the tree shallow.
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    V = np.tile(tri, (20000, 1))
    faces = np.arange(V.shape[0]).reshape(-1, 3)
    a = build_bvh(V, faces)
    check_bvh(a)
    assert a.levels <= MAX_LEVELS
    # A chain of nested triangles of geometrically growing size: SAH peels one triangle per
    # level, so only the depth limit (median splits near MAX_LEVELS) keeps it within bounds.
    k = np.arange(400)
    s = (1.1 ** k)[:, None, None]
    chain = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float64)[None] * s
    chain[:, :, 2] = k[:, None] * 1e-3
    Vc = chain.reshape(-1, 3)
    fc = np.arange(Vc.shape[0]).reshape(-1, 3)
    b = build_bvh(Vc, fc, leaf_size=1)
    check_bvh(b)
    assert b.levels <= MAX_LEVELS

    # Traversal on the coincident stack: every ray through it hits, ties -> face 0.
    t = types("llvm")
    sc = scene_from_arrays(V[:3 * 2000], faces[:2000])
    acc = BVH.build(sc, t)
    n = 64
    xs = np.linspace(0.05, 0.4, n)
    o = t.Array3f(t.Float(xs), t.Float(xs[::-1]), t.Float(np.full(n, 1.0)))
    d = t.Array3f(0.0, 0.0, -1.0)
    h = acc.intersect(o, d, t.Float(dr.inf), t.Bool(True))
    face = dr.gather(t.UInt32, acc.tris.order, h.prim)
    assert np.all(h.valid.numpy()) and np.all(face.numpy() == 0)

    # The chain scene: deepest tree we can make, still bitwise brute force.
    sc = scene_from_arrays(Vc, fc)
    rays = random_rays(t, 1024, seed=3)
    assert_same_hits(hits(BVH.build(sc, t, leaf_size=1), *rays, t),
                     hits(BruteForce.build(sc, t), *rays, t))


# ---- hits agree with brute force -----------------------------------------------------------
@pytest.mark.parametrize("seed", [0, 1])
def test_bvh_matches_brute_force(backend, seed):
    t = types(backend)
    V, faces = soup(2000, seed=seed)
    sc = scene_from_arrays(V, faces, n_objects=3)
    rays = random_rays(t, 4096, seed=10 + seed)
    ref = hits(BruteForce.build(sc, t), *rays, t)
    assert ref[0].sum() > 500                    # the rays do hit the soup
    assert_same_hits(hits(BVH.build(sc, t), *rays, t), ref)


BUILD_OPTIONS = [
    dict(),                                                         # the defaults
    dict(sah_leaves=True, leaf_size=8),                             # SAH leaf termination
    dict(all_axes=False, bins=16, root_bins=16, depth_first=False),  # longest axis, BFS order
    dict(sample=64),                                                # sampled three-axis SAH
]


@pytest.mark.parametrize("options", BUILD_OPTIONS, ids=lambda o: ",".join(o) or "defaults")
def test_build_options_keep_hits_identical(options):
    """Every build variant is a valid tree and gives brute force's hits bitwise."""
    t = types("llvm")
    V, faces = soup(2000, seed=3)   # fixed seed: a reproducible soup
    check_bvh(build_bvh(V, faces, **options))
    sc = scene_from_arrays(V, faces, n_objects=2)
    rays = random_rays(t, 4096, seed=13)
    ref = hits(BruteForce.build(sc, t), *rays, t)
    assert ref[0].sum() > 500
    assert_same_hits(hits(BVH.build(sc, t, **options), *rays, t), ref)


def test_sah_options_lower_the_cost():
    """Three-axis binning and SAH leaves give a cheaper tree than longest-axis splits
    (the point of having them; on this soup 107.4 and 99.7 vs 108.2)."""
    V, faces = soup(4000, seed=4)   # fixed seed
    plain = build_bvh(V, faces, all_axes=False, bins=16, root_bins=16)
    assert build_bvh(V, faces).sah_cost < plain.sah_cost
    assert build_bvh(V, faces, sah_leaves=True, leaf_size=8).sah_cost < plain.sah_cost


def test_cuda_traversal_matches_brute_force_on_llvm():
    """CUDA runs ``BVH._traverse``; the LLVM backend normally takes ``_traverse_llvm``.
    The generic loop is backend-independent code, so CI (no GPU) runs it here directly."""
    t = types("llvm")
    V, faces = soup(2000, seed=5)   # fixed seed: a reproducible soup
    sc = scene_from_arrays(V, faces, n_objects=2)
    o, d, t_max, active = random_rays(t, 4096, seed=15)
    ref = hits(BruteForce.build(sc, t), o, d, t_max, active, t)
    acc = BVH.build(sc, t)
    h = acc._traverse(o, d, t_max, active, False)
    p = acc._traverse(o, d, t_max, active, True)
    face = dr.gather(t.UInt32, acc.tris.order, h.prim, h.valid)
    got = (h.valid.numpy(), h.t.numpy(), face.numpy(), h.u.numpy(), h.v.numpy(), p.numpy())
    assert ref[0].sum() > 500
    assert_same_hits(got, ref)


def test_object_boxes_match_brute_force(backend):
    t = types(backend)
    V, faces = soup(1500, seed=7)
    sc = scene_from_arrays(V, faces, n_objects=5)
    rays = random_rays(t, 4096, seed=17)
    ref = hits(BruteForce.build(sc, t), *rays, t)
    assert_same_hits(hits(ObjectBoxes.build(sc, t), *rays, t), ref)


def test_ties_break_by_smallest_face_index():
    # Duplicated triangles in shuffled order: all three accelerators report the same face.
    t = types("llvm")
    V, faces = soup(300, seed=4, size=0.1)
    rng = np.random.default_rng(4)   # fixed seed: reproducible shuffle
    faces = np.concatenate([faces, faces, faces])[rng.permutation(900)]
    sc = scene_from_arrays(V, faces, n_objects=2)
    rays = random_rays(t, 2048, seed=5)
    ref = hits(BruteForce.build(sc, t), *rays, t)
    for cls in (BVH, ObjectBoxes):
        assert_same_hits(hits(cls.build(sc, t), *rays, t), ref)


def test_any_hit_agrees_with_closest_hit(backend):
    t = types(backend)
    V, faces = soup(1000, seed=2)
    sc = scene_from_arrays(V, faces, n_objects=2)
    o, d, t_max, active = random_rays(t, 4096, seed=22)
    for cls in (BVH, ObjectBoxes):
        acc = cls.build(sc, t)
        h = acc.intersect(o, d, t_max, active)
        p = acc.intersect_p(o, d, t_max, active)
        assert np.array_equal(p.numpy(), h.valid.numpy())
        # Shortening t_max to just the hit distance leaves no hit in (0, t): open interval.
        p2 = acc.intersect_p(o, d, h.t, active & h.valid)
        h2 = acc.intersect(o, d, h.t, active & h.valid)
        assert not np.any(h2.valid.numpy())
        assert not np.any(p2.numpy() & ~np.isfinite(h.t.numpy()))


def test_double_precision_matches_brute_force():
    t = types("llvm", "float64")
    V, faces = soup(800, seed=9)
    sc = scene_from_arrays(V, faces, n_objects=2)
    rays = random_rays(t, 2048, seed=19)
    ref = hits(BruteForce.build(sc, t), *rays, t)
    assert_same_hits(hits(BVH.build(sc, t), *rays, t), ref)
    assert_same_hits(hits(ObjectBoxes.build(sc, t), *rays, t), ref)


def test_empty_and_tiny_scenes():
    t = types("llvm")
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    sc = scene_from_arrays(tri, [[0, 1, 2]])
    o = t.Array3f(t.Float([0.2, 2.0]), t.Float([0.2, 2.0]), t.Float([1.0, 1.0]))
    d = t.Array3f(0.0, 0.0, -1.0)
    for cls in (BVH, ObjectBoxes):
        h = cls.build(sc, t).intersect(o, d, t.Float(dr.inf), t.Bool(True))
        assert h.valid.numpy().tolist() == [True, False]
        assert np.allclose(h.t.numpy()[0], 1.0)


# ---- inside other kernels -------------------------------------------------------------------
@dr.syntax
def count_layers(acc, o, d, t):
    """March through the geometry, re-shooting from each hit until nothing is hit (an
    accelerator query inside an outer symbolic loop, like the integrator's)."""
    n = dr.zeros(t.UInt32, dr.width(o))
    active = t.Bool(True)
    while dr.hint(active, max_iterations=-1, label="march", exclude=[acc, t]):
        h = acc.intersect(o, d, t.Float(dr.inf), active)
        active &= h.valid & (n < 50)
        o = dr.select(active, o + d * (h.t * 1.0001), o)
        n = dr.select(active, n + 1, n)
    return n


def test_callable_in_outer_loop_and_frozen():
    t = types("llvm")
    V, faces = soup(500, seed=6)
    sc = scene_from_arrays(V, faces)
    acc = BVH.build(sc, t)
    o, d, _, _ = random_rays(t, 1024, seed=8)

    ref = count_layers(acc, o, d, t).numpy()
    assert ref.max() >= 2
    frozen = dr.freeze(lambda acc, o, d: acc.intersect(o, d, t.Float(dr.inf), t.Bool(True)).t)
    plain = acc.intersect(o, d, t.Float(dr.inf), t.Bool(True)).t.numpy()
    for _ in range(3):
        assert np.array_equal(frozen(acc, o, d).numpy(), plain)


# ---- subdivision ---------------------------------------------------------------------------
def test_subdivision_keeps_surface_and_welds_midpoints():
    # Octahedron: closed, 6 vertices, 12 edges, 8 faces.
    V = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4],
                  [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    V2, F2 = subdivide_midpoint(V, F, 2)
    assert F2.shape == (8 * 16, 3)
    assert V2.shape[0] == 6 + 12 + 48              # one new vertex per edge, per level
    assert np.array_equal(V2[:6], V)
    # Still closed and manifold: every edge shared by exactly two faces.
    e = np.sort(np.concatenate([F2[:, [0, 1]], F2[:, [1, 2]], F2[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    assert np.all(counts == 2)

    def area_normal(V, F):
        c = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
        return c

    a1, a2 = area_normal(V, F), area_normal(V2, F2)
    assert np.isclose(np.linalg.norm(a1, axis=1).sum(), np.linalg.norm(a2, axis=1).sum())
    # Children keep the parent's orientation (winding): same normal direction.
    parent = np.repeat(np.arange(8), 16)
    assert np.all(np.einsum("ij,ij->i", a2, a1[parent]) > 0)


# ---- a seed scene, end to end ---------------------------------------------------------------
def test_render_identical_across_accelerators():
    from renderer.render import render
    from renderer.scene import load_scene
    path = ROOT / "scenes" / "cornell_box.toml"
    if not path.exists():
        pytest.skip("scenes/cornell_box.toml not present")
    scene = load_scene(path)
    cams = [replace(c, width=48, height=48) for c in scene.cameras]
    scene = replace(scene, cameras=cams)
    images = {a: render(scene, backend="llvm", accel=a).image for a in ("brute", "boxes", "bvh")}
    assert images["brute"].max() > 0
    assert np.array_equal(images["boxes"], images["brute"])
    assert np.array_equal(images["bvh"], images["brute"])
