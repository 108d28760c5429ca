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


def _device_cut(V, faces):
    """The large triangles of ``V``/``faces`` cut by ``presplit.cut`` (numpy) and by
    ``presplit.cut_device`` (Dr.Jit, LLVM), both answers in numpy."""
    from renderer.accel.ploc import _module
    m = _module("llvm")
    tri = V[faces]
    lo, hi = tri.min(1), tri.max(1)
    s_lo, s_hi = lo.min(0).astype(np.float64), hi.max(0).astype(np.float64)
    big = np.flatnonzero((hi - lo).max(1) > presplit.SPLIT_SIZE * (s_hi - s_lo).max())
    budget = int(presplit.SPLIT_BUDGET * len(faces))
    host = presplit.cut(V, faces, big, lo[big], hi[big], (s_lo, s_hi), budget)
    dev = presplit.cut_device(m, presplit._geometry(m, V, faces),
                              m.UInt32(big.astype(np.uint32)),
                              [m.Float(np.ascontiguousarray(lo[big, a])) for a in range(3)],
                              [m.Float(np.ascontiguousarray(hi[big, a])) for a in range(3)],
                              (s_lo, s_hi), budget)
    dev = (np.asarray(dev[0].numpy(), np.int64),) + tuple(
        np.stack([np.asarray(x.numpy()) for x in part], 1) for part in dev[1:])
    return host, dev


@pytest.mark.parametrize("scene", ["floors", "walls"])
def test_device_cut_is_the_host_cut_bitwise(scene):
    """The device cut makes the host cut's references in its order: the same faces, cells
    and float32 boxes, bit for bit (the tree over them is then the host-cut tree)."""
    if scene == "floors":
        V, faces = floors_and_soup()
    else:                                 # a box room: every triangle large, slanted ones too
        rng = np.random.default_rng(5)
        V = rng.random((90, 3)).astype(np.float32)
        faces = rng.integers(0, 90, (30, 3))
        faces = faces[np.array([len(set(f)) == 3 for f in faces])]
    host, dev = _device_cut(V, faces)
    assert len(host[0]) > len(set(host[0].tolist()))          # something was cut
    for h, d, what in zip(host, dev, ("face", "cell_lo", "cell_hi", "lo", "hi")):
        assert h.shape == d.shape, what
        assert np.array_equal(h.view(np.uint8), d.astype(h.dtype).view(np.uint8)), what


def test_device_clip_is_the_host_clip_bitwise():
    """``clip_boxes_device`` against ``spatial.clipped_boxes`` on random triangles and random
    cells bounded by up to six planes (many of them crossing the triangle, some missing it,
    some through a corner; slivers): the same float32 boxes bit for bit."""
    from renderer.accel.ploc import _module
    from renderer.accel.spatial import clipped_boxes
    m = _module("llvm")
    rng = np.random.default_rng(11)
    R = 3000
    V = rng.random((3 * R, 3)).astype(np.float32)
    V[:R // 10] = V[R // 10: 2 * (R // 10)] + 1e-6             # some slivers
    faces = np.arange(3 * R).reshape(R, 3)
    a, b = rng.random((R, 3)), rng.random((R, 3))
    c_lo, c_hi = np.minimum(a, b), np.maximum(a, b)
    c_lo[rng.random((R, 3)) < 0.4] = -np.inf
    c_hi[rng.random((R, 3)) < 0.4] = np.inf
    on = rng.random(R) < 0.2                                    # planes through corners
    c_lo[on, 0] = V[faces[on, 1], 0]
    c_hi[on, 1] = V[faces[on, 2], 1]
    face = np.arange(R)
    lo, hi = clipped_boxes(V, faces, face, c_lo, c_hi, np.float32)
    tri = [[m.Float64(np.ascontiguousarray(V[faces[:, k], c].astype(np.float64)))
            for c in range(3)] for k in range(3)]
    d_lo, d_hi = presplit.clip_boxes_device(
        m, tri, [m.Float64(np.ascontiguousarray(c_lo[:, c])) for c in range(3)],
        [m.Float64(np.ascontiguousarray(c_hi[:, c])) for c in range(3)])
    d_lo = np.stack([np.asarray(x.numpy()) for x in d_lo], 1)
    d_hi = np.stack([np.asarray(x.numpy()) for x in d_hi], 1)
    assert np.array_equal(lo.view(np.uint32), d_lo.view(np.uint32))
    assert np.array_equal(hi.view(np.uint32), d_hi.view(np.uint32))
