"""PLOC's cut large triangles (``renderer.accel.presplit``) give valid trees: every face at
least once (a cut one once per reference, only large ones cut), each leaf's box around its
references' triangles clipped to their cells, the cells of one face's references covering
it, the level bound, the device-summed SAH cost the host's, the unpadded boxes the host
refit; hits bitwise brute force's; a floor under an object stays whole, and a cut tree that
costs more than the uncut one is not kept.

References: direct numpy checks of the structure, ``spatial.clipped_boxes`` and
``bvh_build.raw_boxes`` (the host computations), ``BruteForce`` (the oracle), the uncut
tree for the SAH cost."""
import numpy as np
import pytest
from accel_util import assert_same_hits, hits, random_rays, scene_from_arrays, soup
from test_device_build import child_boxes_nest
from test_ploc import depth

import renderer.accel.presplit as presplit
from renderer.accel import BruteForce, build_accelerator
from renderer.accel.bvh_arrays import sah_cost
from renderer.accel.bvh_build import MAX_LEVELS, check_bvh, raw_boxes
from renderer.accel.ploc import build_ploc
from renderer.device import types


def floors_and_soup():
    """2000 small triangles in the unit cube and 6 large ones across it (two floors, a
    wall and a slanted beam), float32."""
    V, faces = soup(2000, seed=21, size=0.004)
    big = np.array([[0, 0.2, 0], [1, 0.2, 0], [1, 0.2, 1], [0, 0.2, 0], [1, 0.2, 1],
                    [0, 0.2, 1], [0, 0.7, 0], [1, 0.7, 0.1], [0.5, 0.7, 1],
                    [0.3, 0, 0], [0.35, 1, 0], [0.3, 0, 1], [0, 0, 0], [1, 1, 1],
                    [0.05, 0, 0], [0.1, 0.9, 0.1], [0.9, 0.1, 0.9], [0.9, 0.15, 0.85]])
    n = len(V)
    V = np.concatenate([V, big]).astype(np.float32)
    faces = np.concatenate([faces, n + np.arange(len(big)).reshape(-1, 3)])
    return V, faces


def test_large_triangles_are_cut_into_references():
    V, faces = floors_and_soup()
    F = len(faces)
    st = {}
    a = build_ploc(V, faces, "llvm", stats=st)
    assert a.cells is not None and not st["fallback"]
    check_bvh(a)
    child_boxes_nest(a, V, faces)
    seen = np.bincount(a.order, minlength=F)
    tri = V[faces]
    size = (tri.max(1) - tri.min(1)).max(1)
    ext = float((V.max(0) - V.min(0)).max())
    assert np.all(seen[size <= presplit.SPLIT_SIZE * ext] == 1)   # only large ones cut
    assert np.count_nonzero(seen[F - 6:] > 1) >= 4 and seen.min() == 1
    assert a.order.size <= F + presplit.SPLIT_BUDGET * F
    assert a.levels == depth(a) == st["levels"] <= MAX_LEVELS
    assert a.sah_cost == pytest.approx(sah_cost(a), rel=1e-6)
    assert np.array_equal(a.raw, raw_boxes(a, V, faces, np.float32))
    # a reference's cell is finite only where it was cut, and the uncut ones have none
    once = seen[a.order] == 1
    assert np.all(np.isinf(a.cells[0][once])) and np.all(np.isinf(a.cells[1][once]))


def test_cells_of_a_cut_triangle_cover_it():
    V, faces = floors_and_soup()
    a = build_ploc(V, faces, "llvm")
    rng = np.random.default_rng(3)
    cut = np.flatnonzero(np.bincount(a.order) > 1)
    assert cut.size >= 4
    for f in cut:
        pos = np.flatnonzero(a.order == f)
        u = rng.random((500, 2))
        u = np.where(u.sum(1, keepdims=True) > 1, 1 - u, u)
        tri = V[faces[f]].astype(np.float64)
        p = tri[0] + u[:, :1] * (tri[1] - tri[0]) + u[:, 1:] * (tri[2] - tri[0])
        inside = np.zeros(len(p), bool)
        for i in pos:
            inside |= np.all((p >= a.cells[0][i]) & (p <= a.cells[1][i]), axis=1)
        assert inside.all()


def test_cuts_lower_the_sah_cost_of_large_triangles(monkeypatch):
    V, faces = floors_and_soup()
    cut = build_ploc(V, faces, "llvm")
    monkeypatch.setattr(presplit, "SPLIT_SIZE", 0.0)
    whole = build_ploc(V, faces, "llvm")
    assert whole.cells is None and whole.order.size == len(faces)
    assert cut.sah_cost < whole.sah_cost


@pytest.mark.parametrize("accel", ["bvh", "bvh4"])
def test_cut_tree_matches_brute_force(accel):
    t = types("llvm")
    V, faces = floors_and_soup()
    scene = scene_from_arrays(V, faces)
    ray, active = random_rays(t, 4000, seed=6)
    ref = hits(BruteForce.build(scene, t), ray, active, t)
    acc = build_accelerator(accel, scene, t, build="ploc")
    assert acc.info["tree_build"] == "ploc"
    assert_same_hits(hits(acc, ray, active, t), ref)


def object_on_a_floor():
    """3000 small triangles in a box in the middle of a floor of two triangles, float32."""
    V, faces = soup(3000, seed=8, size=0.004)
    V = 0.4 + 0.2 * V
    floor = np.array([[-4, 0.39, -4], [-4, 0.39, 4], [4, 0.39, 4], [-4, 0.39, -4],
                      [4, 0.39, 4], [4, 0.39, -4]])
    n = len(V)
    V = np.concatenate([V, floor]).astype(np.float32)
    return V, np.concatenate([faces, n + np.arange(6).reshape(2, 3)])


def test_a_floor_under_an_object_is_left_whole(monkeypatch):
    V, faces = object_on_a_floor()
    monkeypatch.setattr(presplit, "KEEP_BETTER", False)
    a = build_ploc(V, faces, "llvm")      # too few large triangles: nothing cut
    assert a.cells is None and np.array_equal(np.sort(a.order), np.arange(len(faces)))
    # the reason: its cut pieces join the object's clusters, and the tree costs more; where
    # the rule lets the cut through, the uncut tree is kept
    monkeypatch.setattr(presplit, "MIN_LARGE", 0.0)
    cut = build_ploc(V, faces, "llvm")
    monkeypatch.setattr(presplit, "KEEP_BETTER", True)
    kept = build_ploc(V, faces, "llvm")
    assert cut.cells is not None and cut.sah_cost > a.sah_cost
    assert kept.cells is None and np.array_equal(kept.children, a.children)


def test_auto_first_image_tree_is_uncut_and_keyed_apart(tmp_path, monkeypatch):
    """"auto" for one frame builds PLOC without the cuts (``cuts=False``: its fastest
    build), "device" with them; the two trees have their own cache entries, so neither
    answers for the other."""
    import renderer.accel.builders as builders
    from renderer.accel.cache import TreeCache
    monkeypatch.setattr(builders, "AUTO_MIN_TRIANGLES", 100)
    V, faces = floors_and_soup()
    scene = scene_from_arrays(V, faces)
    cache = TreeCache(tmp_path)
    a, info = builders.binary_tree(scene, "llvm", build="auto", cache=cache, frames=1)
    assert info.build == "device" and not info.cached
    assert a.cells is None and a.order.size == len(faces)
    d, info = builders.binary_tree(scene, "llvm", build="device", cache=cache)
    assert not info.cached and d.cells is not None and d.order.size > len(faces)
    a2, info = builders.binary_tree(scene, "llvm", build="auto", cache=cache, frames=1)
    assert info.cached and a2.cells is None
    assert np.array_equal(a2.order, a.order) and np.array_equal(a2.boxes, a.boxes)
