"""The PLOC clustering (``ploc._cluster``: the cluster count kept on the device, one symbolic
loop for the neighbour search, several iterations between host reads) and triangle order
(``ploc._positions``: pointer jumping) build the tree that the plain loops build, bit for
bit: every ``BVHArrays`` field, the stats and the progress calls.

Reference: ``_cluster_reference`` and ``_positions_reference`` below, the clustering loop
(one ``dr.compress`` and its count read per iteration, the 2 x radius candidates unrolled
in Python) and the top-down triangle order (one pair of kernels per iteration) as
``build_ploc`` ran them before, frozen here; ``build_ploc`` runs them in place of
``_cluster`` and ``_positions`` for the reference tree. Each case runs with the host
reading the count after every iteration and after 4 and 8 (``ploc.READ_EVERY``, the GPU's
setting), each traced every time and replayed (``ploc.FREEZE``, the GPU's setting), so the
device-side count and the frozen iteration are tested on LLVM. The whole build (one upload, one
read back, the inner nodes) is checked against main's on every bundled scene by
``lab/probes/ploc_hashes.py``."""
import math

import drjit as dr
import numpy as np
import pytest
from accel_util import soup
from test_ploc import nested_chain

import renderer.accel.ploc as ploc
from renderer.accel.bvh_build import MAX_LEVELS
from renderer.accel.ploc import NODE, TALL, Clusters, _half_area, build_ploc

CLUSTER = ploc._cluster                   # the clustering under test
POSITIONS = ploc._positions               # and the triangle order
_REFERENCE = {}                           # case -> the reference build


def _cluster_reference(m, slo, shi, radius, progress, backend):
    """The clustering loop of ``build_ploc`` before the device-side count (the backend's
    schedule unused): one ``dr.compress`` count read per iteration."""
    Float, UInt32 = m.Float, m.UInt32
    F = dr.width(slo[0])
    n_in = F - 1
    n_ch = [dr.zeros(UInt32, n_in) for _ in range(2)]
    n_box = [dr.zeros(Float, n_in) for _ in range(6)]
    n_cnt = dr.zeros(UInt32, n_in)
    c_ref = dr.arange(UInt32, F)
    c_box = [dr.gather(Float, x, dr.arange(UInt32, F)) for x in slo + shi]
    c_cnt = dr.full(UInt32, 1, F)
    c_h = dr.zeros(UInt32, F)
    dr.eval(c_box)
    batches = []
    k, made, it = F, 0, 0
    bail = TALL * MAX_LEVELS
    while k > 1:
        i = dr.arange(UInt32, k)
        best = dr.full(Float, dr.inf, k)
        best_j = UInt32(i)
        best_t = dr.full(UInt32, 0xFFFFFFFF, k)
        for d in range(1, min(radius, k - 1) + 1):
            for side in (0, 1):
                if side == 0:
                    ok = i >= d
                    j = i - d
                    a = j
                else:
                    ok = i + d < k
                    j = i + d
                    a = i
                bl = [dr.minimum(c_box[x], dr.gather(Float, c_box[x], j, ok))
                      for x in range(3)]
                bh = [dr.maximum(c_box[3 + x], dr.gather(Float, c_box[3 + x], j, ok))
                      for x in range(3)]
                area = _half_area(bl, bh)
                tie = UInt32(2 * d) | (a & 1)
                better = ok & ((area < best) | ((area == best) & (tie < best_t)))
                best = dr.select(better, area, best)
                best_j = dr.select(better, j, best_j)
                best_t = dr.select(better, tie, best_t)
        dr.eval(best_j)
        mutual = dr.gather(UInt32, best_j, best_j) == i
        merge = mutual & (i < best_j)
        slot = dr.prefix_sum(dr.select(merge, UInt32(1), UInt32(0)))
        node = dr.opaque(UInt32, made) + slot
        o_ref = dr.gather(UInt32, c_ref, best_j, merge)
        o_cnt = dr.gather(UInt32, c_cnt, best_j, merge)
        o_h = dr.gather(UInt32, c_h, best_j, merge)
        u_box = [dr.minimum(c_box[x], dr.gather(Float, c_box[x], best_j, merge))
                 for x in range(3)]
        u_box += [dr.maximum(c_box[3 + x], dr.gather(Float, c_box[3 + x], best_j, merge))
                  for x in range(3)]
        u_cnt = c_cnt + o_cnt
        dr.scatter(n_ch[0], c_ref, node, merge)
        dr.scatter(n_ch[1], o_ref, node, merge)
        dr.scatter(n_cnt, u_cnt, node, merge)
        for x in range(6):
            dr.scatter(n_box[x], u_box[x], node, merge)
        new_ref = dr.select(merge, node | NODE, c_ref)
        new_box = [dr.select(merge, u_box[x], c_box[x]) for x in range(6)]
        new_cnt = dr.select(merge, u_cnt, c_cnt)
        new_h = dr.select(merge, dr.maximum(c_h, o_h) + 1, c_h)
        dr.eval(n_ch, n_cnt, n_box, new_ref, new_box, new_cnt, new_h)
        keep = dr.compress(~(mutual & (i > best_j)))
        k_new = dr.width(keep)
        c_ref = dr.gather(UInt32, new_ref, keep)
        c_box = [dr.gather(Float, x, keep) for x in new_box]
        c_cnt = dr.gather(UInt32, new_cnt, keep)
        c_h = dr.gather(UInt32, new_h, keep)
        dr.eval(c_ref, c_box, c_cnt, c_h)
        batches.append((made, k - k_new))
        made += k - k_new
        k = k_new
        it += 1
        if progress is not None:
            progress(round(MAX_LEVELS * (1.0 - math.log(max(k, 1)) / math.log(F))))
        if it % ploc.HEIGHT_CHECK == 0 and k > 1 and dr.max(c_h)[0] > bail:
            return Clusters(n_ch, n_box, n_cnt, batches, it, True)
    return Clusters(n_ch, n_box, n_cnt, batches, it, False)


def _positions_reference(m, cl):
    """The triangle order of ``build_ploc`` before the pointer jumping: top down, one pair
    of kernels per clustering iteration."""
    UInt32 = m.UInt32
    n_in = dr.width(cl.cnt)
    n_ch, n_cnt = cl.ch, cl.cnt
    n_first = dr.zeros(UInt32, n_in)
    n_depth = dr.zeros(UInt32, n_in)
    t_pos = dr.zeros(UInt32, n_in + 1)
    for b0, cnt in reversed(cl.batches):
        c = dr.opaque(UInt32, b0) + dr.arange(UInt32, cnt)
        first = dr.gather(UInt32, n_first, c)
        depth = dr.gather(UInt32, n_depth, c)
        ch = [dr.gather(UInt32, n_ch[s], c) for s in range(2)]
        is_node = [(r & NODE) != 0 for r in ch]
        left = dr.select(is_node[0], dr.gather(UInt32, n_cnt, ch[0] & ploc.MASK, is_node[0]),
                         1)
        dr.eval(first, depth, ch, left)
        for s, start in ((0, first), (1, first + left)):
            idx = ch[s] & ploc.MASK
            dr.scatter(n_first, start, idx, is_node[s])
            dr.scatter(n_depth, depth + 1, idx, is_node[s])
            dr.scatter(t_pos, start, idx, ~is_node[s])
        dr.eval(n_first, n_depth, t_pos)
    return n_first, n_depth, t_pos


def _build(monkeypatch, V, faces, cluster, every, freeze=False, reads=(1,), **kw):
    monkeypatch.setattr(ploc, "_cluster", cluster)
    monkeypatch.setattr(ploc, "_positions", POSITIONS if cluster is CLUSTER else
                        _positions_reference)
    monkeypatch.setitem(ploc.READ_EVERY, "llvm", every)
    monkeypatch.setitem(ploc.FREEZE, "llvm", freeze)
    monkeypatch.setitem(ploc.READ_BLOCKS, "llvm", reads)
    st, prog = {}, []
    a = build_ploc(V, faces, "llvm", stats=st, progress=prog.append, **kw)
    return a, st, prog


def _assert_same(a, b):
    for f in ("boxes", "children", "order", "raw"):
        x, y = getattr(a, f), getattr(b, f)
        assert x.dtype == y.dtype and x.shape == y.shape, f
        assert x.tobytes() == y.tobytes(), f
    assert (a.levels, a.leaf_count, a.sah_cost) == (b.levels, b.leaf_count, b.sah_cost)
    for u, v in zip(a.bounds, b.bounds):
        assert np.array_equal(u, v)


def _coincident():
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    V = np.tile(tri, (5000, 1))
    return V, np.arange(V.shape[0]).reshape(-1, 3)


def _chain_and_soup():
    Vs, fs = soup(1000, seed=11)
    Vc = nested_chain(60) + 0.3
    V = np.concatenate([Vs, Vc])
    return V, np.concatenate([fs, len(Vs) + np.arange(len(Vc)).reshape(-1, 3)])


CASES = {
    "soup": (lambda: soup(3000, seed=3), {}),
    "soup leaf 1 radius 3": (lambda: soup(2000, seed=5), {"leaf_size": 1, "radius": 3}),
    "soup leaf 4 radius 16": (lambda: soup(2000, seed=6, size=0.2),
                              {"leaf_size": 4, "radius": 16}),
    "coincident triangles": (_coincident, {}),
    "deep subtrees rebuilt": (_chain_and_soup, {}),
    "fallback to the radix tree": (lambda: (nested_chain(400),
                                            np.arange(1200).reshape(-1, 3)), {}),
}


@pytest.mark.parametrize("every,freeze,reads", [
    (1, False, (1,)), (4, False, (1,)), (8, False, (1,)), (1, True, (1,)), (4, True, (1,)),
    (8, True, (1,)), (4, True, (1, 3, 2)), (8, True, (1, 1, 2, 4))])
@pytest.mark.parametrize("case", list(CASES))
def test_clustering_builds_the_reference_tree(monkeypatch, case, every, freeze, reads):
    make, kw = CASES[case]
    V, faces = make()
    if case not in _REFERENCE:
        _REFERENCE[case] = _build(monkeypatch, V, faces, _cluster_reference, 1, **kw)
    ref, st_ref, prog_ref = _REFERENCE[case]
    new, st_new, prog_new = _build(monkeypatch, V, faces, CLUSTER, every, freeze, reads,
                                   **kw)
    _assert_same(new, ref)
    assert st_new == st_ref
    assert prog_new == prog_ref
    if case.startswith("fallback"):
        assert st_ref["fallback"]


@pytest.mark.parametrize("window", [3, 64])
@pytest.mark.parametrize("every,freeze", [(1, False), (4, False)])
@pytest.mark.parametrize("case", list(CASES))
def test_windowed_search_builds_the_reference_tree(monkeypatch, case, every, freeze, window):
    """The CPU backend's neighbour search (``ploc.WINDOW``: a lane per run of clusters,
    each pair's area once) at every width, against the reference loop."""
    make, kw = CASES[case]
    V, faces = make()
    if case not in _REFERENCE:
        _REFERENCE[case] = _build(monkeypatch, V, faces, _cluster_reference, 1, **kw)
    ref, st_ref, prog_ref = _REFERENCE[case]
    monkeypatch.setitem(ploc.WINDOW, "llvm", window)
    monkeypatch.setattr(ploc, "WINDOW_MIN", 1)
    new, st_new, prog_new = _build(monkeypatch, V, faces, CLUSTER, every, freeze, **kw)
    _assert_same(new, ref)
    assert (st_new, prog_new) == (st_ref, prog_ref)
