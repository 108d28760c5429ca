"""The host BVH build gives valid trees: every triangle in exactly one leaf, boxes that
contain their triangles, the level bound, and cheaper trees from the SAH options.

Reference: direct numpy checks of the structure (``check_bvh`` and the ones below).
"""
from pathlib import Path

import numpy as np
import pytest
from accel_util import assert_same_hits, hits, random_rays, scene_from_arrays, soup

from renderer.accel import BVH, BruteForce
from renderer.accel.bvh_build import MAX_LEVELS, build_bvh, check_bvh, pad_boxes
from renderer.accel.optimize import reinsert
from renderer.accel.traverse import COUNT_SHIFT, FIRST_MASK, LEAF_BIT
from renderer.accel.triangle import edge_slack
from renderer.device import types
from renderer.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]


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
    # The chain scene: deepest tree we can make, still bitwise brute force.
    t = types("llvm")
    sc = scene_from_arrays(Vc, fc)
    ray, active = random_rays(t, 1024, seed=3)
    assert_same_hits(hits(BVH.build(sc, t, leaf_size=1), ray, active, t),
                     hits(BruteForce.build(sc, t), ray, active, t))


def test_sah_options_lower_the_cost():
    """Three-axis binning and SAH leaves give a cheaper tree than longest-axis splits
    (the point of having them; on this soup 107.4 and 99.7 vs 108.2)."""
    V, faces = soup(4000, seed=4)   # fixed seed
    plain = build_bvh(V, faces, all_axes=False, bins=16, root_bins=16)
    assert build_bvh(V, faces).sah_cost < plain.sah_cost
    assert build_bvh(V, faces, sah_leaves=True, leaf_size=8).sah_cost < plain.sah_cost


def _leaf_refs(a):
    ref = a.children.astype(np.int64).reshape(-1)
    return np.sort(ref[(ref & LEAF_BIT) != 0])


def _height(a):
    ref = a.children.astype(np.int64)
    h = np.zeros(a.node_count, np.int64)
    for i in range(a.node_count - 1, -1, -1):     # depth-first order: children after parents
        kids = [h[r] for r in ref[i] if not r & LEAF_BIT]
        h[i] = 1 + max(kids, default=0)
    return int(h[0])


def test_reinsertion_lowers_the_cost_and_keeps_the_leaves():
    """``optimize.reinsert`` moves inner nodes only: the same leaves (triangle ranges), every
    child box inside its parent's box, a valid tree of at most ``MAX_LEVELS`` levels, and a
    lower SAH cost (Platonic solids: 12.64 -> 11.66; a random soup's binned build leaves
    nothing to gain); ``levels`` is the tree's real height."""
    sc = load_scene(ROOT / "scenes/platonic_solids.toml")
    V, faces = sc.vertices, sc.faces
    a = build_bvh(V, faces, optimize=0)
    b = reinsert(a)
    check_bvh(b)
    assert b.sah_cost < 0.95 * a.sah_cost
    assert build_bvh(V, faces).sah_cost == b.sah_cost          # the default build's
    assert np.array_equal(_leaf_refs(a), _leaf_refs(b))
    assert np.array_equal(a.order, b.order) and b.levels == _height(b) <= MAX_LEVELS
    bx = b.boxes.reshape(-1, 2, 6)
    ref = b.children.astype(np.int64)
    inner = (ref & LEAF_BIT) == 0
    for k in range(2):
        node = ref[inner[:, k], k]
        outer = bx[inner[:, k], k]
        for j in range(2):
            assert np.all(bx[node, j, 0:3] >= outer[:, 0:3])
            assert np.all(bx[node, j, 3:6] <= outer[:, 3:6])


def test_reinsertion_keeps_the_level_bound():
    """A move that would make the tree deeper than ``max_levels`` is not made: with the
    build's own height as the bound the tree keeps it, without it the same scene's tree
    grows deeper (Platonic solids: 13 -> 18 levels; so the bound is what holds it)."""
    sc = load_scene(ROOT / "scenes/platonic_solids.toml")
    a = build_bvh(sc.vertices, sc.faces, optimize=0)
    h = _height(a)
    free = reinsert(a)
    held = reinsert(a, max_levels=h)
    assert free.levels > h >= held.levels == _height(held)
    check_bvh(held)


def test_precision_constants_follow_the_precision():
    """Edge slack and box padding are multiples of the unit roundoff of the precision in
    use, with the float32 values the renderer has always used."""
    assert edge_slack(False) == 2.0 ** -20 and edge_slack(True) == 2.0 ** -49
    for dt, scale in ((np.float32, 2.0 ** -19), (np.float64, 2.0 ** -48)):
        lo, hi = pad_boxes(np.array([1.0, -2.0, 0.0], dt), np.array([2.0, -1.0, 0.0], dt), 4.0)
        assert lo.dtype == dt
        assert np.array_equal(lo, np.array([1 - 6 * scale, -2 - 6 * scale, -4 * scale], dt))
        assert np.array_equal(hi, np.array([2 + 6 * scale, -1 + 6 * scale, 4 * scale], dt))


def test_reinsertion_memory_is_a_few_values_per_node():
    """The optimisation's tree is typed arrays (8 bytes a value), not Python objects: its
    peak allocation (tracemalloc, output included) stays under 300 bytes per node, where a
    tree of lists and box tuples takes about 570 (for the bunny subdivided four times,
    17.8 M triangles, about 10 GB)."""
    import tracemalloc
    V, faces = soup(20000, seed=3)
    a = build_bvh(V, faces, optimize=0)
    nodes = 2 * a.node_count + 1                 # inner nodes and leaves
    tracemalloc.start()
    try:
        out = reinsert(a, rounds=1)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    check_bvh(out)
    assert peak / nodes < 300, peak / nodes
