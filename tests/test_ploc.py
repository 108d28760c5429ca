"""The PLOC device build (``renderer.accel.ploc``, LLVM here) gives valid trees that the
traversal reads as it reads the SAH tree: every triangle once, leaves within the leaf size,
each child's box inside its parent's and around its triangles, parent links, the recorded
level count the tree's real depth and within the traversal's bound (a build that would
exceed it returns the radix tree); hits bitwise brute force's. Images over the PLOC tree
against the SAH tree's on every bundled scene and the hard cases are in
``test_device_build.py`` (``build="device"`` runs PLOC, ``builders.DEVICE_BUILD``).

References: direct numpy checks of the structure, ``BruteForce`` (the oracle), the radix
builder's tree (``device_build.build_device``) for the SAH-cost comparison and the
fallback, ``bvh_arrays.sah_cost`` (the host's sum) for the device-summed SAH cost."""
import math

import drjit as dr
import numpy as np
import pytest
from accel_util import assert_same_hits, hits, random_rays, scene_from_arrays, soup
from test_device_build import child_boxes_nest, morton_chain

import renderer.accel.ploc as ploc
from renderer.accel import BruteForce, build_accelerator
from renderer.accel.builders import DEVICE_BUILD, binary_tree, builder, tree_key
from renderer.accel.bvh_arrays import sah_cost
from renderer.accel.bvh_build import MAX_LEVELS, check_bvh
from renderer.accel.device_build import build_device
from renderer.accel.ploc import build_ploc
from renderer.accel.traverse import COUNT_SHIFT, LEAF_BIT
from renderer.device import types


def depth(a):
    """Inner-node levels of ``a`` (root at level 1), walked from the root on the host."""
    level = np.zeros(a.node_count, np.int64)
    level[0] = 1
    for n in range(a.node_count):          # children are numbered after their parents
        for k in range(2):
            r = int(a.children[n, k])
            if not r & LEAF_BIT:
                assert r > n
                level[r] = level[n] + 1
    return int(level.max())


@pytest.mark.parametrize("leaf_size,radius", [(1, 8), (2, 1), (2, 8), (4, 16)])
def test_ploc_tree_is_valid(leaf_size, radius):
    V, faces = soup(3000, seed=3)
    st = {}
    a = build_ploc(V, faces, "llvm", leaf_size=leaf_size, radius=radius, stats=st)
    assert not st["fallback"]
    check_bvh(a)
    child_boxes_nest(a, V, faces)
    count = ((a.children.astype(np.int64) >> COUNT_SHIFT) & 15) + 1
    assert count[(a.children & LEAF_BIT) != 0].max() <= leaf_size
    assert a.levels == depth(a) == st["levels"] <= MAX_LEVELS
    assert a.sah_cost == pytest.approx(sah_cost(a), rel=1e-6)


def test_ploc_tree_is_better_than_the_radix_tree():
    V, faces = soup(3000, seed=3)
    assert build_ploc(V, faces, "llvm").sah_cost < 0.95 * build_device(V, faces,
                                                                         "llvm").sah_cost


def test_coincident_triangles_halve_each_iteration():
    # all union areas tie: the pair order (distance, then the lower index's parity) makes
    # the pairs (0 1) (2 3) ... mutual, so the clusters halve each iteration
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    V = np.tile(tri, (20000, 1))
    faces = np.arange(V.shape[0]).reshape(-1, 3)
    st = {}
    a = build_ploc(V, faces, "llvm", stats=st)
    check_bvh(a)
    child_boxes_nest(a, V, faces)
    assert st["iterations"] <= math.ceil(math.log2(20000)) + 1 and not st["fallback"]
    assert a.levels <= MAX_LEVELS


def test_a_tree_over_the_level_bound_falls_back_to_the_radix_tree():
    # nested triangles growing geometrically: each clusters with its smaller neighbour, one
    # merge per iteration, a chain 400 deep
    V = nested_chain(400)
    faces = np.arange(V.shape[0]).reshape(-1, 3)
    st = {}
    a = build_ploc(V, faces, "llvm", stats=st)
    assert st["fallback"] and st["iterations"] < ploc.TALL * MAX_LEVELS + 24
    check_bvh(a)
    child_boxes_nest(a, V, faces)
    b = build_device(V, faces, "llvm")
    assert np.array_equal(a.children, b.children) and np.array_equal(a.order, b.order)


def nested_chain(n, scale=1.1):
    """``n`` nested triangles growing geometrically (each clusters with its smaller
    neighbour: a chain ``n - 1`` deep), in the unit cube."""
    k = np.arange(n)
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float64)[None] * (scale ** k)[:, None,
                                                                                     None]
    tri[:, :, 2] = k[:, None] * 1e-3
    return tri.reshape(-1, 3) / scale ** n


def test_deep_subtrees_are_rebuilt_within_the_level_bound():
    # a 60-deep chain beside a soup: the clustered tree is too deep, the chain's subtree
    # is rebuilt balanced, the rest stays clustered
    Vs, fs = soup(1000, seed=11)
    Vc = nested_chain(60) + 0.3
    V = np.concatenate([Vs, Vc])
    faces = np.concatenate([fs, len(Vs) + np.arange(len(Vc)).reshape(-1, 3)])
    st = {}
    a = build_ploc(V, faces, "llvm", stats=st)
    assert st["levels"] > MAX_LEVELS and st["rebuilt"] >= 1 and not st["fallback"]
    check_bvh(a)
    child_boxes_nest(a, V, faces)
    assert a.levels == depth(a) <= MAX_LEVELS
    assert a.sah_cost == pytest.approx(sah_cost(a), rel=1e-6)
    t = types("llvm")
    scene = scene_from_arrays(V, faces)
    ray, active = random_rays(t, 3000, seed=12)
    ref = hits(BruteForce.build(scene, t), ray, active, t)
    acc = build_accelerator("bvh4", scene, t, build="ploc")
    assert_same_hits(hits(acc, ray, active, t), ref)


def test_morton_chain_and_tiny_scenes():
    V, faces = morton_chain()
    a = build_ploc(V, faces, "llvm")
    check_bvh(a)
    child_boxes_nest(a, V, faces)
    assert a.levels == depth(a) <= MAX_LEVELS
    for F in (1, 2, 3, 4):
        V, faces = soup(F, seed=F)
        a = build_ploc(V, faces, "llvm", leaf_size=1)
        check_bvh(a)


@pytest.mark.parametrize("accel", ["bvh", "bvh4", "bvh8"])
def test_ploc_tree_matches_brute_force(accel):
    t = types("llvm")
    V, faces = soup(2000, seed=4)
    scene = scene_from_arrays(V, faces)
    ray, active = random_rays(t, 4000, seed=5)
    ref = hits(BruteForce.build(scene, t), ray, active, t)
    acc = build_accelerator(accel, scene, t, build="ploc")
    assert acc.info["tree_build"] == "ploc"
    assert_same_hits(hits(acc, ray, active, t), ref)


def test_device_names_the_ploc_builder():
    V, faces = soup(500, seed=9)
    scene = scene_from_arrays(V, faces)
    assert DEVICE_BUILD == "ploc" and builder("device") == "ploc"
    assert tree_key(scene, "device") == tree_key(scene, "ploc") != tree_key(scene, "radix")
    a, _ = binary_tree(scene, "llvm", build="device")
    b = build_ploc(V, faces, "llvm")
    assert np.array_equal(a.children, b.children) and np.array_equal(a.boxes, b.boxes)


@pytest.mark.skipif(not __import__("drjit").has_backend(__import__("drjit").JitBackend.CUDA),
                    reason="no CUDA device")
def test_cuda_ploc_tree_is_valid_and_matches_brute_force():
    V, faces = soup(3000, seed=7)
    a = build_ploc(V, faces, "cuda")
    check_bvh(a)
    child_boxes_nest(a, V, faces)
    assert a.levels == depth(a) <= MAX_LEVELS
    t = types("cuda")
    scene = scene_from_arrays(V, faces)
    ray, active = random_rays(t, 4000, seed=8)
    ref = hits(BruteForce.build(scene, t), ray, active, t)
    for name in ("bvh", "bvh4"):
        acc = build_accelerator(name, scene, t, build="ploc")
        assert_same_hits(hits(acc, ray, active, t), ref)


@pytest.mark.parametrize("case", ["soup", "rebuilt", "fallback"])
def test_ploc_raw_boxes_are_the_host_refit(case):
    """``build_ploc``'s unpadded boxes are ``bvh_build.raw_boxes`` over the same tree
    (reference: the host computation), in the clustered tree, with rebuilt deep subtrees
    and in the radix fallback."""
    from renderer.accel.bvh_build import raw_boxes

    if case == "soup":
        V, faces = soup(2000, seed=13)
    elif case == "rebuilt":
        Vs, fs = soup(1000, seed=11)
        Vc = nested_chain(60) + 0.3
        V = np.concatenate([Vs, Vc])
        faces = np.concatenate([fs, len(Vs) + np.arange(len(Vc)).reshape(-1, 3)])
    else:
        V = nested_chain(400)
        faces = np.arange(len(V)).reshape(-1, 3)
    V = V.astype(np.float32)       # as a scene's (cut triangles are clipped in float32's)
    st = {}
    a = build_ploc(V, faces, "llvm", stats=st)
    assert st["fallback"] == (case == "fallback")
    assert (st["rebuilt"] >= 1) == (case == "rebuilt")
    assert a.raw is not None and np.array_equal(a.raw, raw_boxes(a, V, faces, np.float32))


@pytest.mark.parametrize("build", [build_ploc, build_device])
def test_device_builders_refuse_bad_input_in_one_error(build):
    """Both device builders check their input alike (``device_build.checked_input``): face
    indices outside the vertices, a leaf size out of range; PLOC also its radius."""
    V, faces = soup(100, seed=3)
    bad = faces.copy()
    bad[7, 1] = len(V)
    with pytest.raises(ValueError, match=r"faces: indices must lie in \[0, "):
        build(V, bad, "llvm")
    bad[7, 1] = -1
    with pytest.raises(ValueError, match="faces: indices"):
        build(V, bad, "llvm")
    with pytest.raises(ValueError, match="leaf_size: expected 1..16"):
        build(V, faces, "llvm", leaf_size=17)
    if build is build_ploc:
        with pytest.raises(ValueError, match="radius"):
            build(V, faces, "llvm", radius=0)


@pytest.mark.parametrize("w,k,radius,block,steps", [
    (1000, 1000, 8, 64, 4), (1000, 613, 8, 64, 2), (257, 250, 3, 5, 2), (50, 50, 16, 64, 1),
    (3000, 2999, 8, 1, 3), (3, 2, 8, 64, 1), (1200, 1200, 1, 7, 2), (640, 640, 8, 64, 0)])
def test_windowed_search_is_the_per_cluster_search(w, k, radius, block, steps):
    """``ploc._nearest_window`` answers ``ploc._nearest``'s neighbours bit for bit, lanes past
    the count included, on boxes on a coarse grid (``steps`` per unit: many equal areas,
    so the pair order's ties decide) and on random ones (``steps`` 0)."""
    m = ploc._module("llvm")
    rng = np.random.default_rng(w + k + radius)
    lo = rng.random((w, 3))
    ext = rng.random((w, 3))
    if steps:
        lo, ext = np.round(lo * steps) / steps, np.round(ext * steps) / steps
    lo, hi = lo.astype(np.float32), (lo + ext).astype(np.float32)
    c_box = [m.Float(np.ascontiguousarray(x[:, a])) for x in (lo, hi) for a in range(3)]
    kk = dr.opaque(m.UInt32, k, 1)
    per_cluster = ploc._nearest(m, c_box, kk, radius).numpy()
    windowed = ploc._nearest_window(m, c_box, kk, radius, block).numpy()
    assert np.array_equal(windowed, per_cluster)
    assert np.array_equal(per_cluster[k:], np.arange(k, w))
    assert (per_cluster[:k] != np.arange(k)).all()      # every cluster found a neighbour
