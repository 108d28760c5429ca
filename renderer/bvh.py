"""Acceleration structures: per-object bounding boxes (the thesis's scheme) and a BVH.

``build_bvh`` builds a bounding volume hierarchy on the host (numpy, binned SAH, built level
by level: all nodes of one level are split at once with segmented numpy operations, no
per-triangle Python loop). The result is a flat array of *inner* nodes; each node stores the
boxes of BOTH children (so one fetch gives everything a traversal step needs) and two child
references. A reference is either an inner-node index or a packed leaf (``LEAF_BIT`` | count-1
in bits 27..30 | first triangle in bits 0..26). Triangles are reordered so that each leaf is a
contiguous range; ``BVHArrays.order`` maps positions back to original face indices.

``BVH`` and ``ObjectBoxes`` are accelerators in the sense of ``renderer.intersect``: they are
built with ``cls.build(scene, t, intersection=...)`` and answer ``intersect`` (closest hit)
and ``intersect_p`` (any hit). All accelerators call the same triangle routine on the same
triangle data and break ties between equal ``t`` by the smallest original face index, so
they return bitwise identical hits.

Traversal is one symbolic loop per query with a per-ray stack of ``STACK_SIZE`` UInt32
(``dr.alloc_local``). The stack is kept at 32 entries = 128 bytes because larger local arrays
crash Dr.Jit 1.5.0's LLVM backend (drjit issue #532); the builder bounds the number of inner
node levels by the same number (switching to median splits near the limit), so the stack
cannot overflow.
"""
from __future__ import annotations

import importlib
import math
import time
from dataclasses import dataclass, field

import drjit as dr
import numpy as np

from .device import Types
from .intersect import DeviceTriangles, Hit, triangle_routine, upload_triangles
from .scene import Scene

LEAF_BIT = 1 << 31
COUNT_SHIFT = 27
FIRST_MASK = (1 << COUNT_SHIFT) - 1
MAX_LEAF = 16                # leaf size limit of the packed reference (4 count bits)
STACK_SIZE = 32              # UInt32 entries per ray: 128 bytes (drjit #532 limit)
MAX_LEVELS = STACK_SIZE      # levels of inner nodes; the stack never holds more entries
DONE = 0xFFFFFFFF            # "no node left" sentinel of the traversal
C_TRAV, C_TRI = 1.0, 1.0     # SAH costs of one node visit and one triangle test
LEAF_SIZE = 4                # default most triangles per leaf
BIG_NODE = 1024              # nodes larger than this (level average) get root_bins bins
AXES_MIN = 1024              # three-axis SAH only in levels whose nodes average more triangles
BIN_DIV = 4                  # bins per node: at most (triangles per node, rounded up to 2^k) / BIN_DIV
SAMPLE = 1024                # larger nodes are binned from a sample of about this many


# =========================================================================================
# Host-side build
# =========================================================================================
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
              bins: int = 32, root_bins: int = 32, all_axes: bool = True,
              sah_leaves: bool = False, depth_first: bool = True,
              sample: int = SAMPLE) -> BVHArrays:
    """Build a BVH over the triangles ``faces`` (int (F, 3)) of ``vertices`` (float (V, 3)).

    leaf_size: most triangles per leaf (1..16); a node with more is always split.
    bins: SAH bins per axis of each node (>= 2; default 16); root_bins: bins for the large
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

    def pad(blo, bhi):
        # Grow boxes by a few float32 ulps of their coordinates and of the scene's size, so a
        # triangle's computed hit (with its rounding error) always lies inside its boxes.
        e = (np.maximum(np.abs(blo), np.abs(bhi)) + np.float32(extent)) * np.float32(2.0 ** -19)
        return blo - e, bhi + e

    n_max = max(F, 1)
    boxes = np.empty((n_max, 12), np.float32)
    children = np.empty((n_max, 2), np.uint32)
    order = np.empty(F, np.int64)

    if F <= leaf_size:                        # one inner node over a single leaf
        boxes[0, 0:3], boxes[0, 3:6] = pad(s_lo, s_hi)
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
        a_lo, a_hi = pad(bl[ins, 0], bl[ins, 1])
        b_lo, b_hi = pad(br[ins, 0], br[ins, 1])
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


# =========================================================================================
# Device side
# =========================================================================================
def _types_of(t: Types | None, arr) -> Types:
    """The Types bundle (kept on the accelerator; re-derived from its arrays when Dr.Jit
    rebuilt the object from its DRJIT_STRUCT fields alone)."""
    if t is not None:
        return t
    from .device import types
    backend = "cuda" if dr.backend_v(arr) == dr.JitBackend.CUDA else "llvm"
    return types(backend, "float64" if dr.type_v(arr) == dr.VarType.Float64 else "float32")


def _wide_types(t: Types):
    m = importlib.import_module(f"drjit.{t.backend}")
    return (getattr(m, "Array4f64" if t.is_double else "Array4f"), m.Array2u)


def _upload_packed_triangles(scene: Scene, order: np.ndarray, t: Types):
    """v0, e1, e2 of each (reordered) triangle packed as 12 floats (3 Array4f), computed
    exactly as ``upload_triangles`` computes them (so the triangle test sees equal values)."""
    fdt = np.float64 if t.is_double else np.float32
    faces = scene.faces[order]
    V = scene.vertices.astype(np.float64)
    p0, p1, p2 = V[faces[:, 0]], V[faces[:, 1]], V[faces[:, 2]]
    packed = np.zeros((faces.shape[0], 12), fdt)
    packed[:, 0:3] = p0
    packed[:, 3:6] = p1 - p0
    packed[:, 6:9] = p2 - p0
    return t.Float(packed.reshape(-1))


def _robust_scale(t: Types) -> float:
    eps = 2.0 ** -53 if t.is_double else 2.0 ** -24
    gamma3 = 3 * eps / (1 - 3 * eps)
    return 1.0 + 2.0 * gamma3


def _ray_setup(t: Types, o, d, t_max, active):
    """The ray as a traversal loop reads it: ``(o, d, 1/d, active, n)``, every array of the
    batch width ``n``."""
    n = dr.width(o, d, t_max, active)
    o, d = t.Array3f(o), t.Array3f(d)
    return o, d, _safe_inv(d, t), t.Bool(active) & dr.full(t.Bool, True, n), n


def _closest_record(t: Types, t_max, n: int):
    """The empty closest-hit record: ``(best_t, prim, prim_order, hit_u, hit_v, found)``;
    ``best_t`` starts at ``t_max`` and shrinks to the nearest hit, ``prim`` is the triangle
    in traversal order and ``prim_order`` its original face index (the tie-break)."""
    return (t.Float(t_max) + dr.zeros(t.Float, n), dr.zeros(t.UInt32, n),
            dr.full(t.UInt32, DONE, n), dr.zeros(t.Float, n), dr.zeros(t.Float, n),
            dr.zeros(t.Bool, n))


def _enter_leaf(cur, first, end):
    """When no leaf triangles are pending, classify node reference ``cur``; a leaf's
    triangle range becomes ``[first, end)``. Returns ``(is_leaf, is_inner, first, end)``."""
    node_step = first >= end
    is_leaf = node_step & ((cur & LEAF_BIT) != 0) & (cur != DONE)
    is_inner = node_step & ((cur & LEAF_BIT) == 0)
    first = dr.select(is_leaf, cur & FIRST_MASK, first)
    end = dr.select(is_leaf, (cur & FIRST_MASK) + ((cur >> COUNT_SHIFT) & 15) + 1, end)
    return is_leaf, is_inner, first, end


def _pop(stack, sp, cur, pop):
    """Where ``pop``: the next node is the top of the stack, or DONE when it is empty.
    Returns ``(sp, cur)``."""
    can_pop = pop & (sp > 0)
    sp = dr.select(can_pop, sp - 1, sp)
    popped = stack.read(sp, can_pop)
    return sp, dr.select(pop, dr.select(can_pop, popped, DONE), cur)


def _safe_inv(d, t: Types):
    """1/d per component, clamped to a huge finite value so that ``(lo - o) * inv`` is never
    0 * inf = NaN for axis-parallel rays (a zero component then means "the slab never ends")."""
    big = 2.0 ** 900 if t.is_double else 2.0 ** 100
    return dr.clip(1.0 / d, -big, big)


def _slab(o, inv, lo, hi, t_max, robust):
    """Williams et al. ray/box slab test; t_far grown by 1 + 2 gamma(3) (pbrt) so that the
    float test never misses a box the exact ray hits. Returns (hit, t_near)."""
    t0 = (lo - o) * inv
    t1 = (hi - o) * inv
    tn = dr.minimum(t0, t1)
    tf = dr.maximum(t0, t1)
    t_near = dr.maximum(dr.maximum(tn.x, tn.y), dr.maximum(tn.z, 0.0))
    t_far = dr.minimum(dr.minimum(tf.x, tf.y), tf.z) * robust
    return t_near <= dr.minimum(t_far, t_max), t_near


def _triangle_step(routine, A4, t, o, d, tri_data, order, i, active, t_max,
                   best_t, prim, prim_order, hit_u, hit_v, found, any_hit):
    """Test triangle ``i`` (packed ``tri_data``) where ``active`` and fold it into the
    closest-hit state: accept a hit that is nearer, or (once something was found) equally
    near with a smaller original face index, so ties resolve the same in every accelerator.
    For ``any_hit`` only ``found`` (a hit in (0, t_max)) matters."""
    a = dr.gather(A4, tri_data, i * 3, active)
    b = dr.gather(A4, tri_data, i * 3 + 1, active)
    c = dr.gather(A4, tri_data, i * 3 + 2, active)
    v0 = t.Array3f(a.x, a.y, a.z)
    e1 = t.Array3f(a.w, b.x, b.y)
    e2 = t.Array3f(b.z, b.w, c.x)
    th, u, v, h = routine(o, d, v0, e1, e2)
    if any_hit:
        return best_t, prim, prim_order, hit_u, hit_v, found | (active & h & (th < t_max))
    h &= active & (th <= best_t)
    nearer = h & (th < best_t)
    tie = h & found & (th == best_t)
    i_order = dr.gather(t.UInt32, order, i, nearer | tie)
    accept = nearer | (tie & (i_order < prim_order))
    return (dr.select(accept, th, best_t), dr.select(accept, i, prim),
            dr.select(accept, i_order, prim_order), dr.select(accept, u, hit_u),
            dr.select(accept, v, hit_v), found | accept)


# ---- the LLVM (CPU) path ------------------------------------------------------------------
# Dr.Jit's LLVM backend runs 16 lanes per SIMD packet with masked execution, so it pays for
# every instruction of the loop body on every iteration, whichever lanes need it. The CPU
# traversal therefore (a) wraps the node step and the triangle step in symbolic ``if``s,
# which the LLVM backend compiles to real branches taken only when some lane of the packet
# needs that step, and (b) gathers one float per lane at a time: a packet gather of four
# floats (``Array4f``) is emitted only when the source happens to be 64-byte aligned (arrays
# made from numpy are mapped as they lie), and on the CPU it is slower than four scalar
# gathers, so the old code's speed depended on where numpy's buffer landed. The CUDA path
# above is unchanged. Both give the same hits: traversal order and culling never change
# which triangle wins (nearest t, then smallest original face index).
def _gather_floats(t: Types, src, base, count: int, active=True):
    """``count`` consecutive floats ``src[base + k]`` per lane, as scalar gathers."""
    return [dr.gather(t.Float, src, base + k, active) for k in range(count)]


def _slab_select(o, inv, lo, hi, t_max, robust):
    """``_slab`` with min/max written as compare + select (LLVM path). Dr.Jit emits
    ``dr.minimum``/``dr.maximum`` as LLVM's NaN-propagating ``llvm.minimum``/``maximum``,
    which x86 has no instruction for; compare + select is two instructions. The values
    differ only where a slab value is NaN, which needs a NaN ray (origin or direction, as
    ``_safe_inv`` never returns 0 or inf): the triangle test never hits such a ray, so the
    hits stay the same."""
    t0 = (lo - o) * inv
    t1 = (hi - o) * inv
    c = t0 < t1
    tn = dr.select(c, t0, t1)
    tf = dr.select(c, t1, t0)
    a = dr.select(tn.x > tn.y, tn.x, tn.y)
    b = dr.select(tn.z > 0.0, tn.z, 0.0)
    t_near = dr.select(a > b, a, b)
    a = dr.select(tf.x < tf.y, tf.x, tf.y)
    t_far = dr.select(a < tf.z, a, tf.z) * robust
    return (t_near <= t_far) & (t_near <= t_max), t_near


def _node_step_llvm(t, nodes, children, o, inv, best_t, robust, stack, sp, cur):
    """One inner node (LLVM path): test both child boxes, push the far hit child, go to the
    near one. Returns (sp, cur, pop): ``pop`` where neither child was hit."""
    f = _gather_floats(t, nodes, cur * 12, 12)
    ref_a = dr.gather(t.UInt32, children, cur * 2)
    ref_b = dr.gather(t.UInt32, children, cur * 2 + 1)
    hit_a, tn_a = _slab_select(o, inv, t.Array3f(f[0], f[1], f[2]),
                               t.Array3f(f[3], f[4], f[5]), best_t, robust)
    hit_b, tn_b = _slab_select(o, inv, t.Array3f(f[6], f[7], f[8]),
                               t.Array3f(f[9], f[10], f[11]), best_t, robust)
    both = hit_a & hit_b
    b_first = tn_b < tn_a
    near = dr.select(hit_a & ~(hit_b & b_first), ref_a, ref_b)
    far = dr.select(b_first, ref_a, ref_b)
    stack.write(far, sp, both)
    sp = dr.select(both, sp + 1, sp)
    pop = ~(hit_a | hit_b)
    return sp, dr.select(pop, cur, near), pop


def _triangle_step_llvm(routine, t, o, d, tri_data, order, i, t_max,
                        best_t, prim, prim_order, hit_u, hit_v, found, any_hit):
    """``_triangle_step`` with scalar gathers (LLVM path; the caller's ``if`` masks lanes)."""
    f = _gather_floats(t, tri_data, i * 12, 9)
    th, u, v, h = routine(o, d, t.Array3f(f[0], f[1], f[2]), t.Array3f(f[3], f[4], f[5]),
                          t.Array3f(f[6], f[7], f[8]))
    if any_hit:
        return best_t, prim, prim_order, hit_u, hit_v, found | (h & (th < t_max))
    h &= th <= best_t
    nearer = h & (th < best_t)
    tie = h & found & (th == best_t)
    i_order = dr.gather(t.UInt32, order, i, nearer | tie)
    accept = nearer | (tie & (i_order < prim_order))
    return (dr.select(accept, th, best_t), dr.select(accept, i, prim),
            dr.select(accept, i_order, prim_order), dr.select(accept, u, hit_u),
            dr.select(accept, v, hit_v), found | accept)


@dataclass
class BVH:
    """Bounding volume hierarchy accelerator (see module docstring).

    Build with ``BVH.build(scene, t, intersection="moller_trumbore", leaf_size=4, bins=16)``.
    Device arrays: ``nodes`` Float (12 N) child boxes, ``children`` UInt32 (2 N) child refs,
    ``tri_data`` Float (12 F) packed v0/e1/e2, ``tris`` DeviceTriangles in BVH order.
    """

    nodes: object = None
    children: object = None
    tri_data: object = None
    tris: DeviceTriangles = None
    DRJIT_STRUCT = {"nodes": object, "children": object, "tri_data": object,
                    "tris": DeviceTriangles}
    # Static (host) facts, not traced.
    types: Types = field(default=None, repr=False)
    intersection: str = "moller_trumbore"
    info: dict = field(default_factory=dict, repr=False)

    @classmethod
    def build(cls, scene: Scene, t: Types, *, intersection: str = "moller_trumbore",
              leaf_size: int = LEAF_SIZE, bins: int = 32, **build_options) -> "BVH":
        """``build_options`` go to ``build_bvh`` (root_bins, all_axes, sah_leaves,
        depth_first, sample)."""
        triangle_routine(intersection)
        a = build_bvh(scene.vertices, scene.faces, leaf_size=leaf_size, bins=bins, **build_options)
        t0 = time.perf_counter()
        tris = upload_triangles(scene, t, order=a.order)
        fdt = np.float64 if t.is_double else np.float32
        nodes = t.Float(a.boxes.astype(fdt).reshape(-1))
        children = t.UInt32(a.children.reshape(-1))
        tri_data = _upload_packed_triangles(scene, a.order, t)
        dr.eval(nodes, children, tri_data, tris)
        fsize = 8 if t.is_double else 4
        F = max(scene.face_count, 1)
        info = {
            "accel": "bvh", "intersection": intersection, "build_seconds": a.build_seconds,
            "upload_seconds": time.perf_counter() - t0, "triangles": scene.face_count,
            "nodes": a.node_count, "leaves": a.leaf_count, "levels": a.levels,
            "sah_cost": a.sah_cost, "leaf_size": leaf_size, "bins": bins,
            "node_bytes_per_triangle": a.node_count * (12 * fsize + 8) / F,
            "traversal_triangle_bytes_per_triangle": 12 * fsize,
        }
        return cls(nodes, children, tri_data, tris, types=t, intersection=intersection,
                   info=info)

    def stats(self) -> dict:
        return dict(self.info)

    def intersect(self, o, d, t_max, active=True) -> Hit:
        return self._trace(o, d, t_max, active, False)

    def intersect_p(self, o, d, t_max, active=True):
        return self._trace(o, d, t_max, active, True)

    def _trace(self, o, d, t_max, active, any_hit: bool):
        # A plain Python branch at trace time: the CPU gets its own loop (see
        # ``_traverse_llvm``), CUDA keeps ``_traverse``.
        if _types_of(self.types, self.nodes).backend == "llvm":
            return self._traverse_llvm(o, d, t_max, active, any_hit)
        return self._traverse(o, d, t_max, active, any_hit)

    @dr.syntax
    def _traverse(self, o, d, t_max, active, any_hit: bool):
        t = _types_of(self.types, self.nodes)
        A4, A2u = _wide_types(t)
        routine = triangle_routine(self.intersection)
        robust = _robust_scale(t)
        nodes, children, tri_data, order = self.nodes, self.children, self.tri_data, self.tris.order
        o, d, inv, active, n = _ray_setup(t, o, d, t_max, active)
        stack = dr.alloc_local(t.UInt32, STACK_SIZE)
        sp = dr.zeros(t.UInt32, n)                  # stack depth
        cur = dr.select(active, dr.zeros(t.UInt32, n), DONE)   # next node (root = 0)
        first = dr.zeros(t.UInt32, n)               # pending leaf triangles [first, end)
        end = dr.zeros(t.UInt32, n)
        best_t, prim, prim_order, hit_u, hit_v, found = _closest_record(t, t_max, n)

        while dr.hint(active, max_iterations=-1, label="bvh",
                      exclude=[self, t, A4, A2u, routine, robust, any_hit]):
            # ---- node step: only when no leaf triangles are pending ---------------------
            is_leaf, is_inner, first, end = _enter_leaf(cur, first, end)

            q0 = dr.gather(A4, nodes, cur * 3, is_inner)
            q1 = dr.gather(A4, nodes, cur * 3 + 1, is_inner)
            q2 = dr.gather(A4, nodes, cur * 3 + 2, is_inner)
            refs = dr.gather(A2u, children, cur, is_inner)
            a_lo = t.Array3f(q0.x, q0.y, q0.z)
            a_hi = t.Array3f(q0.w, q1.x, q1.y)
            b_lo = t.Array3f(q1.z, q1.w, q2.x)
            b_hi = t.Array3f(q2.y, q2.z, q2.w)
            hit_a, tn_a = _slab(o, inv, a_lo, a_hi, best_t, robust)
            hit_b, tn_b = _slab(o, inv, b_lo, b_hi, best_t, robust)
            hit_a &= is_inner
            hit_b &= is_inner
            both = hit_a & hit_b
            b_first = tn_b < tn_a
            near = dr.select(hit_a & ~(hit_b & b_first), refs.x, refs.y)
            far = dr.select(b_first, refs.x, refs.y)
            stack.write(far, sp, both)
            sp = dr.select(both, sp + 1, sp)
            cur = dr.select(hit_a | hit_b, near, cur)

            pop = is_leaf | (is_inner & ~(hit_a | hit_b))
            sp, cur = _pop(stack, sp, cur, pop)

            # ---- triangle step: one pending leaf triangle ---------------------------------
            tri_step = first < end
            best_t, prim, prim_order, hit_u, hit_v, found = _triangle_step(
                routine, A4, t, o, d, tri_data, order, first, tri_step, t_max,
                best_t, prim, prim_order, hit_u, hit_v, found, any_hit)
            if dr.hint(any_hit, mode="scalar"):
                active &= ~found
            first = dr.select(tri_step, first + 1, first)

            active &= (first < end) | (cur != DONE)

        if dr.hint(any_hit, mode="scalar"):
            return found
        return Hit(valid=found, t=best_t, u=hit_u, v=hit_v, prim=prim)


    @dr.syntax
    def _traverse_llvm(self, o, d, t_max, active, any_hit: bool):
        """``_traverse`` for the LLVM backend: the same loop, with the node step and the
        triangle step each behind a symbolic ``if`` (a branch skipped when no lane of the
        SIMD packet needs it) and scalar gathers (see the note above ``_gather_floats``)."""
        t = _types_of(self.types, self.nodes)
        routine = triangle_routine(self.intersection)
        robust = _robust_scale(t)
        nodes, children, tri_data, order = self.nodes, self.children, self.tri_data, self.tris.order
        o, d, inv, active, n = _ray_setup(t, o, d, t_max, active)
        stack = dr.alloc_local(t.UInt32, STACK_SIZE)
        sp = dr.zeros(t.UInt32, n)                  # stack depth
        cur = dr.select(active, dr.zeros(t.UInt32, n), DONE)   # next node (root = 0)
        first = dr.zeros(t.UInt32, n)               # pending leaf triangles [first, end)
        end = dr.zeros(t.UInt32, n)
        best_t, prim, prim_order, hit_u, hit_v, found = _closest_record(t, t_max, n)

        while dr.hint(active, max_iterations=-1, label="bvh_llvm",
                      exclude=[self, t, routine, robust, any_hit]):
            # ---- node step: only when no leaf triangles are pending ---------------------
            is_leaf, is_inner, first, end = _enter_leaf(cur, first, end)
            pop = is_leaf | False
            # (explicit dr.if_stmt with lambdas made here, so they see this iteration's
            # best_t and stack)
            sp, cur, pop = dr.if_stmt(
                (sp, cur, pop), is_inner,
                lambda sp, cur, pop: _node_step_llvm(t, nodes, children, o, inv, best_t, robust,
                                                     stack, sp, cur),
                lambda sp, cur, pop: (sp, cur, pop))

            sp, cur = _pop(stack, sp, cur, pop)

            # ---- triangle step: one pending leaf triangle ---------------------------------
            best_t, prim, prim_order, hit_u, hit_v, found, first = dr.if_stmt(
                (best_t, prim, prim_order, hit_u, hit_v, found, first), first < end,
                lambda best_t, prim, prim_order, hit_u, hit_v, found, first: _triangle_step_llvm(
                    routine, t, o, d, tri_data, order, first, t_max, best_t, prim, prim_order,
                    hit_u, hit_v, found, any_hit) + (first + 1,),
                lambda *state: state)
            if dr.hint(any_hit, mode="scalar"):
                active &= ~found

            active &= (first < end) | (cur != DONE)

        if dr.hint(any_hit, mode="scalar"):
            return found
        return Hit(valid=found, t=best_t, u=hit_u, v=hit_v, prim=prim)


@dataclass
class ObjectBoxes:
    """The thesis's scheme: one axis-aligned box per scene object (``Scene.objects`` face
    ranges); a ray tests each object's box (Williams et al.) and, if it hits, the object's
    triangles. Triangles stay in scene order (``tris.order`` is the identity).

    Build with ``ObjectBoxes.build(scene, t, intersection="moller_trumbore")``.
    Device arrays: ``boxes`` Float (8 n_objects) lo xyz, pad, hi xyz, pad; ``ranges`` UInt32
    (2 n_objects) first face, face count; ``tri_data`` packed v0/e1/e2; ``tris``.
    """

    boxes: object = None
    ranges: object = None
    tri_data: object = None
    tris: DeviceTriangles = None
    DRJIT_STRUCT = {"boxes": object, "ranges": object, "tri_data": object,
                    "tris": DeviceTriangles}
    types: Types = field(default=None, repr=False)
    intersection: str = "moller_trumbore"
    info: dict = field(default_factory=dict, repr=False)

    @classmethod
    def build(cls, scene: Scene, t: Types, *, intersection: str = "moller_trumbore") -> "ObjectBoxes":
        triangle_routine(intersection)
        t0 = time.perf_counter()
        F = scene.face_count
        objs = [(o.first_face, o.face_count) for o in scene.objects if o.face_count > 0]
        if not objs and F:
            objs = [(0, F)]
        fdt = np.float64 if t.is_double else np.float32
        boxes = np.full((max(len(objs), 1), 8), np.inf, fdt)
        ranges = np.zeros((max(len(objs), 1), 2), np.uint32)
        V = scene.vertices.astype(np.float32)
        ext = 0.0
        if F:
            lo_s, hi_s = scene.bounds()
            ext = float(np.max(hi_s - lo_s))
        for k, (f0, fc) in enumerate(objs):      # a loop over objects, not triangles
            p = V[scene.faces[f0:f0 + fc].reshape(-1)]
            lo, hi = p.min(axis=0), p.max(axis=0)
            e = (np.maximum(np.abs(lo), np.abs(hi)) + np.float32(ext)) * np.float32(2.0 ** -19)
            boxes[k, 0:3], boxes[k, 4:7] = lo - e, hi + e
            ranges[k] = (f0, fc)
        order = np.arange(F, dtype=np.int64)
        tris = upload_triangles(scene, t, order=order)
        tri_data = _upload_packed_triangles(scene, order, t)
        out = cls(t.Float(boxes.reshape(-1)), t.UInt32(ranges.reshape(-1)), tri_data, tris,
                  types=t, intersection=intersection)
        dr.eval(out.boxes, out.ranges, out.tri_data, out.tris)
        out.info = {"accel": "boxes", "intersection": intersection, "build_seconds": time.perf_counter() - t0,
                    "triangles": F, "objects": len(objs),
                    "box_bytes_per_triangle": len(objs) * 8 * (8 if t.is_double else 4) / max(F, 1)}
        return out

    def stats(self) -> dict:
        return dict(self.info)

    def intersect(self, o, d, t_max, active=True) -> Hit:
        return self._traverse(o, d, t_max, active, False)

    def intersect_p(self, o, d, t_max, active=True):
        return self._traverse(o, d, t_max, active, True)

    @dr.syntax
    def _traverse(self, o, d, t_max, active, any_hit: bool):
        t = _types_of(self.types, self.boxes)
        A4, A2u = _wide_types(t)
        routine = triangle_routine(self.intersection)
        robust = _robust_scale(t)
        boxes, ranges, tri_data, order = self.boxes, self.ranges, self.tri_data, self.tris.order
        n_obj = dr.width(self.ranges) // 2
        o, d, inv, active, n = _ray_setup(t, o, d, t_max, active)
        active &= n_obj > 0
        obj = dr.zeros(t.UInt32, n)                 # next object to test
        first = dr.zeros(t.UInt32, n)               # pending triangles [first, end)
        end = dr.zeros(t.UInt32, n)
        best_t, prim, prim_order, hit_u, hit_v, found = _closest_record(t, t_max, n)

        while dr.hint(active, max_iterations=-1, label="boxes",
                      exclude=[self, t, A4, A2u, routine, robust, any_hit]):
            # ---- box step: the next object's box, when no triangles are pending ---------
            box_step = (first >= end) & (obj < n_obj)
            q0 = dr.gather(A4, boxes, obj * 2, box_step)
            q1 = dr.gather(A4, boxes, obj * 2 + 1, box_step)
            rng = dr.gather(A2u, ranges, obj, box_step)
            hit, _ = _slab(o, inv, t.Array3f(q0.x, q0.y, q0.z), t.Array3f(q1.x, q1.y, q1.z),
                           best_t, robust)
            hit &= box_step
            first = dr.select(hit, rng.x, first)
            end = dr.select(hit, rng.x + rng.y, end)
            obj = dr.select(box_step, obj + 1, obj)

            # ---- triangle step -----------------------------------------------------------
            tri_step = first < end
            best_t, prim, prim_order, hit_u, hit_v, found = _triangle_step(
                routine, A4, t, o, d, tri_data, order, first, tri_step, t_max,
                best_t, prim, prim_order, hit_u, hit_v, found, any_hit)
            if dr.hint(any_hit, mode="scalar"):
                active &= ~found
            first = dr.select(tri_step, first + 1, first)

            active &= (first < end) | (obj < n_obj)

        if dr.hint(any_hit, mode="scalar"):
            return found
        return Hit(valid=found, t=best_t, u=hit_u, v=hit_v, prim=prim)
