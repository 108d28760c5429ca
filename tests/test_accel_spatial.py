"""Spatial splits (``renderer.accel.spatial``): references that straddle a split plane are
duplicated with clipped boxes, so the tree must still find brute force's hits bitwise, in
both precisions and with both triangle routines (the watertight and float64 traversals
refit the boxes from each reference's cell), and every triangle must stay covered by its
references' boxes."""
import numpy as np
import pytest
from accel_util import assert_same_hits, hits, random_rays, scene_from_arrays, soup
from test_accel_wide import adversarial_rays, grid

import renderer.accel.bvh_build as bvh_build
import renderer.accel.spatial as spatial
from renderer.accel import BVH, BruteForce, WideBVH
from renderer.accel.bvh import traversal_boxes
from renderer.accel.bvh_build import LEAF_BIT, SPATIAL, build_bvh, check_bvh
from renderer.device import types


@pytest.fixture
def small_scenes_split(monkeypatch):
    """Spatial splits in test-sized scenes (the defaults start at 16384 triangles)."""
    monkeypatch.setattr(bvh_build, "SPATIAL_MIN_TRIANGLES", 64)
    monkeypatch.setattr(bvh_build, "SPATIAL_MIN_REFS", 32)
    monkeypatch.setattr(spatial, "PROBE_DEPTH", 12)


def floor_and_clutter(seed=3):
    """Small triangles over two large ones crossing the whole scene diagonally (a floor
    and a tilted wall): the case spatial splits are for."""
    V, faces = soup(3000, seed, size=0.03)
    big = np.array([[-0.1, -0.1, 0.3], [1.1, -0.1, 0.5], [-0.1, 1.1, 0.45],
                    [0.2, -0.1, -0.1], [0.9, 1.1, 1.1], [0.1, 1.1, 0.0]], np.float32)
    V = np.concatenate([V, big])
    n = len(V)
    faces = np.concatenate([faces, [[n - 6, n - 5, n - 4], [n - 3, n - 2, n - 1]]])
    return V.astype(np.float32), faces


def test_spatial_splits_duplicate_the_large_triangles_and_lower_the_sah(small_scenes_split):
    V, faces = floor_and_clutter()
    plain = build_bvh(V, faces, spatial=0.0)
    a = build_bvh(V, faces, spatial=SPATIAL)
    check_bvh(a)
    assert a.cells is not None and a.order.size > len(faces)       # references were cut
    counts = np.bincount(a.order, minlength=len(faces))
    assert counts[-2:].min() > 1                  # the two large triangles, several times
    assert a.sah_cost < plain.sah_cost


@pytest.mark.parametrize("precision", ["float32", "float64"])
@pytest.mark.parametrize("intersection", ["watertight", "moller_trumbore"])
def test_spatial_bvh_matches_brute_force(small_scenes_split, precision, intersection):
    t = types("llvm", precision)
    V, faces = floor_and_clutter()
    sc = scene_from_arrays(V, faces, n_objects=2)
    ray, active = random_rays(t, 6000, seed=23)
    ref = hits(BruteForce.build(sc, t, intersection=intersection), ray, active, t)
    acc = BVH.build(sc, t, intersection=intersection, spatial=SPATIAL)
    assert acc.tris.order.numpy().size > len(faces)
    assert_same_hits(hits(acc, ray, active, t), ref)
    for width in (4, 8):
        assert_same_hits(hits(WideBVH.build(sc, t, width=width, intersection=intersection,
                                            spatial=SPATIAL), ray, active, t), ref)


def test_spatial_bvh_matches_brute_force_on_adversarial_rays(small_scenes_split):
    """Shared edges, coincident faces, grazing and axis-parallel rays (the grid of
    ``test_accel_wide``) in a scene whose two large triangles are cut by the splits."""
    t = types("llvm")
    Vg, fg = grid(32)
    Vc, fc = floor_and_clutter(seed=11)
    V = np.concatenate([Vg, Vc])
    faces = np.concatenate([fg, fc + len(Vg)])
    sc = scene_from_arrays(V, faces, n_objects=2)
    ray, active = adversarial_rays(t, V, faces, seed=8)
    ref = hits(BruteForce.build(sc, t), ray, active, t)
    acc = BVH.build(sc, t, spatial=SPATIAL)
    assert acc.tris.order.numpy().size > len(faces)
    assert_same_hits(hits(acc, ray, active, t), ref)


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_every_triangle_is_covered_by_its_references_boxes(small_scenes_split, precision):
    """Points spread over each triangle (in the traversal's precision) lie inside the box of
    at least one leaf that holds a reference to it: the boxes the traversal reads, refitted
    from the cells for the watertight routine."""
    t = types("llvm", precision)
    V, faces = floor_and_clutter(seed=5)
    sc = scene_from_arrays(V, faces)
    a = build_bvh(sc.vertices, sc.faces, spatial=SPATIAL)
    assert a.cells is not None
    boxes = traversal_boxes(a, sc, t, "watertight").reshape(-1, 2, 6)
    # the box of every leaf position
    pos_lo = np.full((a.order.size, 3), np.inf)
    pos_hi = np.full((a.order.size, 3), -np.inf)
    ref = a.children.astype(np.int64)
    for node, k in zip(*np.nonzero((ref & LEAF_BIT) != 0)):
        first = int(ref[node, k] & bvh_build.FIRST_MASK)
        count = int((ref[node, k] >> bvh_build.COUNT_SHIFT) & 15) + 1
        pos_lo[first:first + count] = boxes[node, k, 0:3]
        pos_hi[first:first + count] = boxes[node, k, 3:6]
    rng = np.random.default_rng(2)
    P = sc.positions(t.is_double).astype(np.float64)
    for f in (len(faces) - 2, len(faces) - 1, 0, 17):      # the large ones and two small
        b = rng.dirichlet([1.0, 1.0, 1.0], 4000)
        b = np.concatenate([b, np.eye(3), [[0.5, 0.5, 0], [0, 0.5, 0.5], [0.5, 0, 0.5]]])
        pts = b @ P[faces[f]]
        mine = np.flatnonzero(a.order == f)
        inside = np.zeros(len(pts), bool)
        for p in mine:
            inside |= np.all((pts >= pos_lo[p]) & (pts <= pos_hi[p]), axis=1)
        assert inside.all(), f


def test_default_build_cuts_only_where_the_cut_pays():
    """Spatial splits are on by default, but a mesh of even-sized triangles (the Stanford
    bunny, 69K triangles: its best spatial split near the root gains 0.7 % of a node's SAH
    cost) builds without them, while a floor among clutter (its large triangles overlap
    everything) takes them."""
    from pathlib import Path

    from renderer.scene import load_scene
    root = Path(__file__).resolve().parents[1]
    sc = load_scene(root / "scenes/bunny.toml")
    assert sc.face_count > bvh_build.SPATIAL_MIN_TRIANGLES
    a = build_bvh(sc.vertices, sc.faces)
    assert a.cells is None and a.order.size == sc.face_count
    V, faces = floor_and_clutter()
    reps = bvh_build.SPATIAL_MIN_TRIANGLES // len(faces) + 1    # above the size threshold
    V = np.concatenate([V + [0.0, 0.01 * k, 0.0] for k in range(reps)]).astype(np.float32)
    faces = np.concatenate([faces + k * (faces.max() + 1) for k in range(reps)])
    b = build_bvh(V, faces)
    assert b.cells is not None and b.order.size > len(faces)
