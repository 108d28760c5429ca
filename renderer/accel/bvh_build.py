"""Host-side BVH build (numpy): binned SAH, built level by level.

All nodes of one level are split at once with segmented numpy operations, no
per-triangle Python loop. The result (``BVHArrays``) is a flat array of *inner* nodes; each
node stores the boxes of BOTH children (so one fetch gives everything a traversal step
needs) and two child references (an inner-node index or a packed leaf, see
``renderer.accel.traverse``). Triangles are reordered so that each leaf is a contiguous
range; ``BVHArrays.order`` maps positions back to original face indices.

Boxes are computed in float32 from the float32 vertices, whatever the precision of the
traversal, and padded by ``pad_boxes``. The number of inner-node levels is bounded by
``MAX_LEVELS`` (= the traversal's ``STACK_SIZE``, switching to median splits near the
limit), so the traversal stack cannot overflow.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from .traverse import COUNT_SHIFT, FIRST_MASK, LEAF_BIT, MAX_LEAF, STACK_SIZE
from .triangle import unit_roundoff

MAX_LEVELS = STACK_SIZE      # levels of inner nodes; the stack never holds more entries
C_TRAV, C_TRI = 1.0, 1.0     # SAH costs of one node visit and one triangle test
LEAF_SIZE = 4                # default most triangles per leaf
BINS = 32                    # default SAH bins per axis
BIG_NODE = 1024              # nodes larger than this (level average) get root_bins bins
AXES_MIN = 1024              # three-axis SAH only in levels whose nodes average more triangles
BIN_DIV = 4                  # bins per node: at most (triangles per node, rounded up to 2^k) / BIN_DIV
SAMPLE = 1024                # larger nodes are binned from a sample of about this many


def pad_boxes(lo: np.ndarray, hi: np.ndarray, extent: float):
    """Boxes ``(lo, hi)`` grown by 32 units of roundoff of their dtype (2^-19 in float32)
    times their coordinates' magnitude plus the scene's ``extent``, so a triangle's computed
    hit (with its rounding error) always lies inside its boxes. Returns ``(lo, hi)``."""
    dt = lo.dtype.type
    e = ((np.maximum(np.abs(lo), np.abs(hi)) + dt(extent))
         * dt(32 * unit_roundoff(lo.dtype == np.float64)))
    return lo - e, hi + e


@dataclass
class BVHArrays:
    """A BVH on the host.

    boxes: float32 (N, 12) per inner node: child A lo xyz, hi xyz, child B lo xyz, hi xyz
        (padded by a few ulps so the float32 triangle test never hits outside its box).
    children: uint32 (N, 2) child references (inner index or packed leaf).
    order: int64 (F,) original face index of each reordered triangle.
    levels: number of inner-node levels (<= MAX_LEVELS); leaf_count; sah_cost (relative to
        the root's surface area, C_trav = C_tri = 1); build_seconds.
    """

    boxes: np.ndarray
    children: np.ndarray
    order: np.ndarray
    levels: int
    leaf_count: int
    sah_cost: float
    build_seconds: float
    bounds: tuple = (np.zeros(3), np.zeros(3))

    @property
    def node_count(self) -> int:
        return int(self.boxes.shape[0])


def leaf_ref(first, count):
    """Packed leaf reference(s): uint32."""
    first = np.asarray(first, np.uint64)
    count = np.asarray(count, np.uint64)
    return (np.uint64(LEAF_BIT) | ((count - np.uint64(1)) << np.uint64(COUNT_SHIFT))
            | first).astype(np.uint32)


def _half_area(lo, hi):
    d = hi - lo
    return d[0] * d[1] + d[1] * d[2] + d[2] * d[0]


def _sweep(x, op, reverse=False):
    """Running ``op`` (np.minimum / np.maximum) over axis -2 (the bins) of x (..., B, nseg);
    a Python loop over the B bins, each step vectorised over all nodes and axes (much faster
    than ufunc.accumulate along a short axis)."""
    out = np.empty_like(x)
    ks = range(x.shape[-2] - 1, -1, -1) if reverse else range(x.shape[-2])
    prev = None
    for k in ks:
        if prev is None:
            out[..., k, :] = x[..., k, :]
        else:
            op(out[..., prev, :], x[..., k, :], out=out[..., k, :])
        prev = k
    return out


def _levels_needed(n, leaf_size):
    """Inner-node levels a median-split subtree over n triangles needs (n > leaf_size)."""
    leaves = np.ceil(n / leaf_size)
    return np.ceil(np.log2(np.maximum(leaves, 1))).astype(np.int64)


def build_bvh(vertices: np.ndarray, faces: np.ndarray, *, leaf_size: int = LEAF_SIZE,
              bins: int = BINS, root_bins: int = BINS, all_axes: bool = True,
              sah_leaves: bool = False, depth_first: bool = True,
              sample: int = SAMPLE) -> BVHArrays:
    """Build a BVH over the triangles ``faces`` (int (F, 3)) of ``vertices`` (float (V, 3)).

    leaf_size: most triangles per leaf (1..16); a node with more is always split.
    bins: SAH bins per axis of each node (>= 2; default ``BINS`` = 32); root_bins: bins for the large
        nodes near the root (more than ``BIG_NODE`` triangles on average in their level).
    all_axes: evaluate the binned SAH along all three axes and take the cheapest split
        (False: only along the node's longest centroid axis).
    sah_leaves: a node of at most ``leaf_size`` triangles becomes a leaf when intersecting
        its triangles is no dearer than the best split (SAH with C_TRAV, C_TRI); False: every
        node of more than ``leaf_size`` triangles is split, every smaller one is a leaf.
    depth_first: number the inner nodes in depth-first order (a node's first child directly
        follows it); False keeps the level-by-level order of the build.
    A node whose centroids coincide, or one too deep to finish with SAH splits inside
    MAX_LEVELS levels, is split at the median instead.
    """
    if not 1 <= leaf_size <= MAX_LEAF:
        raise ValueError(f"leaf_size: expected 1..{MAX_LEAF}, got {leaf_size}")
    if bins < 2 or root_bins < 2:
        raise ValueError(f"bins: expected >= 2, got {bins}, {root_bins}")
    t_start = time.perf_counter()
    V = np.asarray(vertices, np.float32)
    Fi = np.asarray(faces, np.int64)
    F = int(Fi.shape[0])
    if F >= 1 << COUNT_SHIFT:
        raise ValueError(f"faces: at most {1 << COUNT_SHIFT} triangles, got {F}")
    if F and MAX_LEVELS < int(_levels_needed(np.array([F]), leaf_size)[0]) + 1:
        raise ValueError(f"faces: {F} triangles need more than {MAX_LEVELS} BVH levels")

    p = [V[Fi[:, k]] for k in range(3)]
    lo = np.minimum(np.minimum(p[0], p[1]), p[2]).T.copy()        # (3, F) float32
    hi = np.maximum(np.maximum(p[0], p[1]), p[2]).T.copy()
    del p
    if F:
        s_lo, s_hi = lo.min(axis=1), hi.max(axis=1)
    else:
        s_lo = s_hi = np.zeros(3, np.float32)
    extent = float(np.max(s_hi - s_lo)) if F else 0.0

    n_max = max(F, 1)
    boxes = np.empty((n_max, 12), np.float32)
    children = np.empty((n_max, 2), np.uint32)
    order = np.empty(F, np.int64)

    if F <= leaf_size:                        # one inner node over a single leaf
        boxes[0, 0:3], boxes[0, 3:6] = pad_boxes(s_lo, s_hi, extent)
        boxes[0, 6:12] = np.inf               # a box at infinity: never hit
        children[0] = [leaf_ref(0, max(F, 1)), leaf_ref(0, 1)] if F else [leaf_ref(0, 1)] * 2
        if F == 0:
            boxes[0, 0:6] = np.inf
        order[:] = np.arange(F)
        arrays = BVHArrays(boxes[:1].copy(), children[:1].copy(), order, 1, 1,
                           0.0, 0.0, (s_lo.astype(np.float64), s_hi.astype(np.float64)))
        arrays.sah_cost = _sah_cost(arrays)
        arrays.build_seconds = time.perf_counter() - t_start
        return arrays

    # Children of at most `imm` triangles become leaves at once; larger ones are "pending"
    # nodes of the next level, which decide there (SAH) whether they are a leaf or split.
    imm = 1 if sah_leaves else leaf_size
    child_flat = children.reshape(-1)         # slot 2 i + k: child k of node i
    # ---- working set: the triangles of the pending nodes of this level, grouped by node ---
    # lo/hi rows: 3 float32 arrays each (1-D rows keep numpy's gathers fast).
    w_idx = np.arange(F, dtype=np.int64)
    w_lo, w_hi = list(lo), list(hi)
    seg_n = np.array([F], np.int64)           # triangles per pending node
    seg_g = np.array([0], np.int64)           # first position in the final triangle order
    seg_slot = np.array([-1], np.int64)       # its reference's slot in the parent (root: -1)
    n_nodes, leaf_count, level, levels = 0, 0, 0, 0

    while seg_n.size:
        nseg = seg_n.size
        n = w_idx.size
        seg_start = np.zeros(nseg, np.int64)
        np.cumsum(seg_n[:-1], out=seg_start[1:])
        es = np.repeat(np.arange(nseg, dtype=np.int32), seg_n)   # node of each element
        # Fewer bins once the nodes are small (a bin per triangle is enough), more while
        # they are large.
        nb = root_bins if n / nseg > BIG_NODE else bins
        B = int(min(nb, max(4, (1 << int(math.ceil(math.log2(max(n / nseg, 2))))) // BIN_DIV)))

        # ---- binning along each axis (or the longest) of the centroid bounds ------------
        cen = [w_lo[j] + w_hi[j] for j in range(3)]                # 2 x box centre
        cmin = np.stack([np.minimum.reduceat(cen[j], seg_start) for j in range(3)])
        cmax = np.stack([np.maximum.reduceat(cen[j], seg_start) for j in range(3)])
        ext = cmax - cmin
        long_axis = np.argmax(ext, axis=0)
        sidx = np.arange(nseg)
        with np.errstate(divide="ignore"):
            scale = np.where(ext > 0, np.float32(B) / ext, np.float32(0)).astype(np.float32)
        seg_first = seg_start.astype(np.int32)[es]
        k_in = np.arange(n, dtype=np.int32) - seg_first                   # index in node
        # Large nodes are binned from a strided sample of about `sample` of their triangles
        # (the split plane is chosen on the sample, the partition and the child boxes are
        # then computed exactly over all triangles).
        stride = np.maximum(seg_n // sample, 1)
        sampled = stride > 1
        if sampled.any():
            sm = np.flatnonzero(k_in % stride.astype(np.int32)[es] == 0)
            s_es = es[sm]
            s_cen = [c[sm] for c in cen]
            sp_lo = [r[sm] for r in w_lo]
            sp_hi = [r[sm] for r in w_hi]
            s_n = np.bincount(s_es, minlength=nseg)
        else:
            sm, s_es, s_cen, sp_lo, sp_hi, s_n = None, es, cen, w_lo, w_hi, seg_n
        if all_axes and n / nseg > AXES_MIN:
            axes = [(s_cen[a], cmin[a], scale[a]) for a in range(3)]
        else:
            ax = long_axis[s_es]
            cl = np.where(ax == 0, s_cen[0], np.where(ax == 1, s_cen[1], s_cen[2]))
            axes = [(cl, cmin[long_axis, sidx], scale[long_axis, sidx])]
        A = len(axes)
        cnt = np.empty((A, B, nseg), np.int64)
        bmin = np.full((3, A, B * nseg), np.inf, np.float32)
        bmax = np.full((3, A, B * nseg), -np.inf, np.float32)
        bs = []
        for i, (c, c0, sc) in enumerate(axes):
            b = ((c - c0[s_es]) * sc[s_es]).astype(np.int32)
            np.clip(b, 0, B - 1, out=b)
            bs.append(b)
            key = b * nseg + s_es                # bin-major: the sweeps below run over bins
            cnt[i] = np.bincount(key, minlength=nseg * B).reshape(B, nseg)
            for j in range(3):
                np.minimum.at(bmin[j, i], key, sp_lo[j])
                np.maximum.at(bmax[j, i], key, sp_hi[j])
        bmin = bmin.reshape(3, A, B, nseg)
        bmax = bmax.reshape(3, A, B, nseg)
        Lmin, Lmax = _sweep(bmin, np.minimum), _sweep(bmax, np.maximum)   # bins 0..k
        Rmin, Rmax = (_sweep(bmin, np.minimum, reverse=True),                # bins k..B-1
                      _sweep(bmax, np.maximum, reverse=True))
        nL = np.cumsum(cnt, axis=1)[:, :-1]                    # (A, B-1, nseg): split after k
        nR = s_n - nL
        with np.errstate(invalid="ignore", over="ignore"):
            cost = (_half_area(Lmin[:, :, :-1], Lmax[:, :, :-1]) * nL.astype(np.float32)
                    + _half_area(Rmin[:, :, 1:], Rmax[:, :, 1:]) * nR.astype(np.float32))
        cost[(nL == 0) | (nR == 0)] = np.inf
        cost = cost.reshape(A * (B - 1), nseg)
        bi = np.argmin(cost, axis=0)
        best_cost = cost[bi, sidx]
        best_a, best = bi // (B - 1), bi % (B - 1)
        node_area = _half_area(Lmin[:, 0, B - 1], Lmax[:, 0, B - 1])          # (nseg,)

        # ---- leaf or split: SAH decides for small nodes; median where SAH cannot split or
        # the depth runs out ------------------------------------------------------------
        can_sah = np.isfinite(best_cost)
        small = seg_n <= leaf_size
        if sah_leaves:
            with np.errstate(invalid="ignore"):
                cheaper = (np.float32(C_TRI) * seg_n * node_area
                           <= np.float32(C_TRAV) * node_area + np.float32(C_TRI) * best_cost)
            make_leaf = small & (~can_sah | cheaper | (level >= MAX_LEVELS))
        else:
            make_leaf = small
        if level == 0:
            make_leaf[:] = False
        inner = ~make_leaf
        forced = inner & (~can_sah | (level + 1 + _levels_needed(seg_n, leaf_size) > MAX_LEVELS))
        lf = np.flatnonzero(make_leaf)
        if lf.size:
            child_flat[seg_slot[lf]] = leaf_ref(seg_g[lf], seg_n[lf])
            leaf_count += int(lf.size)
            el = np.flatnonzero(make_leaf[es])
            order[seg_g[es[el]] + k_in[el]] = w_idx[el]
        node_id = n_nodes + np.cumsum(inner) - inner
        nonroot = inner & (seg_slot >= 0)
        child_flat[seg_slot[nonroot]] = node_id[nonroot].astype(np.uint32)

        # ---- partition ---------------------------------------------------------------------
        if sm is not None:                    # bins of every triangle along the chosen axis
            ax = best_a[es] if A > 1 else long_axis[es]
            c = np.where(ax == 0, cen[0], np.where(ax == 1, cen[1], cen[2]))
            sa = best_a if A > 1 else long_axis
            bsel = ((c - cmin[sa, sidx][es]) * scale[sa, sidx][es]).astype(np.int32)
            np.clip(bsel, 0, B - 1, out=bsel)
        elif A == 1:
            bsel = bs[0]
        else:
            ax = best_a[es]
            bsel = np.where(ax == 0, bs[0], np.where(ax == 1, bs[1], bs[2]))
        right = bsel > best[es]
        lx = np.cumsum(~right) - ~right                           # lefts before, globally
        l_in = lx - lx[seg_start][es]                             # lefts before, in node
        rank = np.where(right, k_in - l_in, l_in)                 # stable rank in its child
        n_left = nL[best_a, best, sidx]
        if sm is not None:
            last = seg_start + seg_n - 1
            n_left = np.where(sampled, l_in[last] + ~right[last], n_left)
        n_left = np.where(forced, seg_n // 2, n_left)
        bl = np.stack([Lmin[:, best_a, best, sidx].T, Lmax[:, best_a, best, sidx].T], 1)
        br = np.stack([Rmin[:, best_a, best + 1, sidx].T, Rmax[:, best_a, best + 1, sidx].T], 1)
        if forced.any():
            m = np.flatnonzero(forced[es])
            la = long_axis[es[m]]
            cval = np.where(la == 0, cen[0][m], np.where(la == 1, cen[1][m], cen[2][m]))
            srt = m[np.lexsort((cval, es[m]))]                    # by node, then centroid
            rank_in = k_in[m]
            right[srt] = rank_in >= n_left[es[srt]]
            rank[srt] = np.where(right[srt], rank_in - n_left[es[srt]], rank_in)
        exact = forced | (sampled & inner)
        if exact.any():
            # child boxes of median and sampled splits: reduced over their triangles
            m = np.flatnonzero(exact[es])
            ck = (es[m] * 2 + right[m]).astype(np.int64)
            fmin = np.full((3, 2 * nseg), np.inf, np.float32)
            fmax = np.full((3, 2 * nseg), -np.inf, np.float32)
            for j in range(3):
                np.minimum.at(fmin[j], ck, w_lo[j][m])
                np.maximum.at(fmax[j], ck, w_hi[j][m])
            fs = np.flatnonzero(exact)
            bl[fs, 0], bl[fs, 1] = fmin[:, 2 * fs].T, fmax[:, 2 * fs].T
            br[fs, 0], br[fs, 1] = fmin[:, 2 * fs + 1].T, fmax[:, 2 * fs + 1].T

        # ---- children of the split nodes: tiny ones are leaves now, the rest pending ------
        ins = np.flatnonzero(inner)
        a_lo, a_hi = pad_boxes(bl[ins, 0], bl[ins, 1], extent)
        b_lo, b_hi = pad_boxes(br[ins, 0], br[ins, 1], extent)
        boxes[node_id[ins]] = np.concatenate([a_lo, a_hi, b_lo, b_hi], axis=1)
        c_n = np.stack([n_left, seg_n - n_left], 1).reshape(-1)            # (2 nseg,)
        c_g = np.stack([seg_g, seg_g + n_left], 1).reshape(-1)
        c_slot = (2 * node_id[:, None] + np.arange(2)).reshape(-1)
        c_exists = np.repeat(inner, 2)
        c_leaf = c_exists & (c_n <= imm)
        c_pend = c_exists & ~c_leaf
        child_flat[c_slot[c_leaf]] = leaf_ref(c_g[c_leaf], c_n[c_leaf])
        leaf_count += int(c_leaf.sum())

        ci = 2 * es + right                                                # child of element
        el_leaf = c_leaf[ci]
        order[c_g[ci[el_leaf]] + rank[el_leaf]] = w_idx[el_leaf]

        c_next = np.cumsum(c_pend) - c_pend                               # next-level index
        nn_n = c_n[c_pend]
        nn_start = np.zeros(nn_n.size, np.int64)
        np.cumsum(nn_n[:-1], out=nn_start[1:])
        keep = np.flatnonzero(c_pend[ci])
        src = np.empty(keep.size, np.int64)                  # gather index of the next level
        src[nn_start[c_next[ci[keep]]] + rank[keep]] = keep
        w_idx = w_idx[src]
        w_lo = [r[src] for r in w_lo]
        w_hi = [r[src] for r in w_hi]
        seg_n, seg_g, seg_slot = nn_n, c_g[c_pend], c_slot[c_pend]
        if ins.size:
            levels = level + 1
        n_nodes += int(ins.size)
        level += 1

    boxes, children = boxes[:n_nodes], children[:n_nodes]
    if depth_first:
        boxes, children = _depth_first(boxes, children)
    arrays = BVHArrays(boxes.copy(), children.copy(), order, levels,
                       leaf_count, 0.0, 0.0,
                       (s_lo.astype(np.float64), s_hi.astype(np.float64)))
    arrays.build_seconds = time.perf_counter() - t_start
    arrays.sah_cost = _sah_cost(arrays)
    return arrays


def _depth_first(boxes, children):
    """Renumber the inner nodes in depth-first (pre-)order: child A of a node directly follows
    it, child B follows A's subtree, so a subtree is one contiguous run of nodes. Vectorised
    over the nodes of one level at a time."""
    N = boxes.shape[0]
    ref = children.astype(np.int64)
    inner = (ref & LEAF_BIT) == 0                                  # (N, 2)
    lv = [np.zeros(1, np.int64)]                                   # nodes of each level
    while True:
        c = ref[lv[-1]][inner[lv[-1]]]
        if not c.size:
            break
        lv.append(c)
    size = np.ones(N, np.int64)                                    # inner nodes in subtree
    for nodes in reversed(lv):
        for k in range(2):
            m = inner[nodes, k]
            size[nodes[m]] += size[ref[nodes[m], k]]
    pre = np.zeros(N, np.int64)
    for nodes in lv:
        a_in = inner[nodes, 0]
        pre[ref[nodes[a_in], 0]] = pre[nodes[a_in]] + 1
        b_in = inner[nodes, 1]
        nb = nodes[b_in]
        pre[ref[nb, 1]] = pre[nb] + 1 + np.where(inner[nb, 0], size[np.where(inner[nb, 0], ref[nb, 0], 0)], 0)
    new_boxes = np.empty_like(boxes)
    new_boxes[pre] = boxes
    new_ref = np.where(inner, pre[np.where(inner, ref, 0)], ref).astype(np.uint32)
    new_children = np.empty_like(children)
    new_children[pre] = new_ref
    return new_boxes, new_children


def _sah_cost(a: BVHArrays) -> float:
    """SAH cost relative to the root box: C_trav per inner node + C_tri per leaf triangle,
    each weighted by its box's surface area."""
    lo, hi = a.bounds
    root = float(_half_area(np.asarray(lo, np.float64), np.asarray(hi, np.float64)))
    if root <= 0 or a.node_count == 0:
        return 0.0
    bx = a.boxes.astype(np.float64)
    total = C_TRAV * root
    for k in range(2):
        box = bx[:, 6 * k:6 * k + 6]
        with np.errstate(invalid="ignore"):
            area = _half_area(box[:, 0:3].T, box[:, 3:6].T)
        area = np.where(np.isfinite(area), area, 0.0)
        ref = a.children[:, k].astype(np.int64)
        is_leaf = (ref & LEAF_BIT) != 0
        count = ((ref >> COUNT_SHIFT) & 15) + 1
        total += float(np.sum(np.where(is_leaf, C_TRI * count * area, C_TRAV * area)))
    return total / root


def check_bvh(a: BVHArrays) -> None:
    """Validate the structure (tests and debugging): every triangle in exactly one leaf,
    children inside the tree, levels within MAX_LEVELS. Raises AssertionError."""
    F = a.order.size
    seen = np.zeros(F, np.int64)
    ref = a.children.astype(np.int64).reshape(-1)
    leaf = (ref & LEAF_BIT) != 0
    inner = ref[~leaf]
    assert np.all(inner < a.node_count) and np.all(inner > 0)
    assert np.unique(inner).size == inner.size == a.node_count - 1
    first = ref[leaf] & FIRST_MASK
    count = ((ref[leaf] >> COUNT_SHIFT) & 15) + 1
    real = np.isfinite(a.boxes.reshape(-1, 2, 6)[:, :, 0].reshape(-1))[leaf]
    for f, c in zip(first[real], count[real]):
        seen[f:f + c] += 1
    assert F == 0 or np.all(seen == 1)
    assert np.array_equal(np.sort(a.order), np.arange(F))
    assert a.levels <= MAX_LEVELS
