"""Host-side BVH build (numpy): binned SAH, built level by level.

All nodes of one level are split at once with segmented numpy operations, no
per-triangle Python loop. The result (``BVHArrays``) is a flat array of *inner* nodes; each
node stores the boxes of BOTH children (so one fetch gives everything a traversal step
needs) and two child references (an inner-node index or a packed leaf, see
``renderer.accel.layout``). Triangles are reordered so that each leaf is a contiguous
range; ``BVHArrays.order`` maps positions back to original face indices.

After the build, ``renderer.accel.optimize.reinsert`` moves the costliest nodes to where
the SAH cost grows least (``build_bvh(optimize=...)``, on by default); leaves stay as built.

Boxes are computed in float32 from the float32 vertices and padded by ``pad_boxes``; the
traversal recomputes them over the same tree with ``refit_boxes`` (float64 from the float64
vertices for float64 renders), padded for the reach of the scene's ray origins
(``triangle.pad_extent``: the watertight test and the slab test's FMA form need it). The
number of inner-node levels is bounded by ``MAX_LEVELS`` (the most entries the binary
traversal pushes; median splits near the limit; the optimisation keeps the bound), so the
traversal stack cannot overflow.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np

from .. import parallel
from .bvh_arrays import C_TRAV, C_TRI, BVHArrays, half_area, sah_cost
from .layout import COUNT_SHIFT, FIRST_MASK, LEAF_BIT, MAX_LEAF, MAX_LEVELS, leaf_ref
from .optimize import reinsert
from .spatial import clipped_boxes, spatial_top
from .triangle import unit_roundoff

#: Default most triangles per leaf. Every traversal step is a real branch, which a warp
#: (CUDA) or SIMD packet (LLVM) takes only when one of its lanes needs it, so small leaves
#: pay: leaves of at most 2 triangles trace faster than leaves of 4 on both backends, hits
#: bitwise the same (``lab/notes/accel-decisions.md``).
LEAF_SIZE = 2
BINS = 32                    # default SAH bins per axis
#: Spatial splits (``build_bvh(spatial=...)``, on by default): the budget of extra
#: references, and where they are tried: scenes of more triangles than
#: ``SPATIAL_MIN_TRIANGLES``, nodes of more references than ``SPATIAL_MIN_REFS``, the top
#: ``SPATIAL_DEPTH`` inner levels. Of the bench scenes only Sponza and Conference get cuts.
#: They speed up closest-hit and shadow rays on both backends; only any-hit rays that stop
#: near the root (Conference's walls and floor move down the tree) slow down, and a
#: renderer's any-hit rays are shadow rays (``lab/notes/accel-decisions.md``).
SPATIAL = 0.3
SPATIAL_MIN_TRIANGLES = 16384
SPATIAL_MIN_REFS = 512
SPATIAL_DEPTH = 12
#: Rounds of insertion-based optimisation after the build (``renderer.accel.optimize``): each
#: moves the 1 % of nodes that cost most for their size to where the SAH cost grows least.
#: It lowers the SAH cost of every bench scene and speeds up the traversal of most, any-hit
#: rays most, hits bitwise the same; it costs up to about the build's own time again
#: (``lab/notes/accel-decisions.md``).
OPTIMIZE = 4
BIG_NODE = 1024              # nodes larger than this (level average) get root_bins bins
AXES_MIN = 1024              # three-axis SAH only in levels whose nodes average more triangles
BIN_DIV = 4                  # bins per node: at most (triangles per node, rounded up to
                             # 2^k) / BIN_DIV
SAMPLE = 1024                # larger nodes are binned from a sample of about this many


def pad_boxes(lo: np.ndarray, hi: np.ndarray, extent: float):
    """Boxes ``(lo, hi)`` grown by 32 units of roundoff of their dtype (2^-19 in float32)
    times their coordinates' magnitude plus the scene's ``extent``, so a triangle's computed
    hit (with its rounding error) always lies inside its boxes. Returns ``(lo, hi)``."""
    dt = lo.dtype.type
    e = ((np.maximum(np.abs(lo), np.abs(hi)) + dt(extent))
         * dt(32 * unit_roundoff(lo.dtype == np.float64)))
    return lo - e, hi + e


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


@dataclass
class BuildOptions:
    """The settings of one build (``build_bvh``), validated.

    leaf_size: most triangles per leaf (1..16); a node with more is always split.
    bins: SAH bins per axis of each node (>= 2; default ``BINS`` = 32); root_bins: bins for
        the large nodes near the root (more than ``BIG_NODE`` triangles on average in their
        level).
    all_axes: evaluate the binned SAH along all three axes and take the cheapest split
        (False: only along the node's longest centroid axis).
    sah_leaves: a node of at most ``leaf_size`` triangles becomes a leaf when intersecting
        its triangles is no dearer than the best split (SAH with C_TRAV, C_TRI); False: every
        node of more than ``leaf_size`` triangles is split, every smaller one is a leaf.
    sample: nodes of more triangles are binned from a strided sample of about this many.
    depth_first: number the inner nodes in depth-first order (a node's first child directly
        follows it); False keeps the level-by-level order of the build.
    spatial: spatial splits near the root (``renderer.accel.spatial``) with at most
        ``spatial * F`` extra references (``SPATIAL``: 0.3), in scenes of more than
        ``SPATIAL_MIN_TRIANGLES`` triangles (the default); 0: object splits only.
    optimize: rounds of insertion-based optimisation after the build
        (``renderer.accel.optimize.reinsert``; default ``OPTIMIZE``); 0: none.
    """

    leaf_size: int = LEAF_SIZE
    bins: int = BINS
    root_bins: int = BINS
    all_axes: bool = True
    sah_leaves: bool = False
    sample: int = SAMPLE
    depth_first: bool = True
    spatial: float = SPATIAL
    optimize: int = OPTIMIZE

    def __post_init__(self):
        if not 1 <= self.leaf_size <= MAX_LEAF:
            raise ValueError(f"leaf_size: expected 1..{MAX_LEAF}, got {self.leaf_size}")
        if self.bins < 2 or self.root_bins < 2:
            raise ValueError(f"bins: expected >= 2, got {self.bins}, {self.root_bins}")

    @property
    def immediate_leaf(self) -> int:
        """Children of at most this many triangles become leaves at once; larger ones are
        pending nodes of the next level, which decide there (SAH) whether they are a leaf."""
        return 1 if self.sah_leaves else self.leaf_size


@dataclass
class _Tree:
    """The output being filled level by level: ``boxes`` (N, 12) and ``children`` (N, 2)
    of the inner nodes (slot ``2 i + k`` of ``children.reshape(-1)`` is child k of node i),
    ``order`` (F,) the original face at each leaf position, and counters."""

    boxes: np.ndarray
    children: np.ndarray
    order: np.ndarray
    extent: float                 # scene size, for pad_boxes
    n_nodes: int = 0
    leaf_count: int = 0
    levels: int = 0

    @property
    def child_flat(self) -> np.ndarray:
        return self.children.reshape(-1)


@dataclass
class _Level:
    """The pending nodes of one level and their triangles ("elements"), grouped by node in
    node order. Set on creation: the working set. Set by the phases of ``build_bvh``, in
    order: the layout (``_layout``), the bins (``_bin``), the best split (``_best_split``),
    the leaf-or-split decision (``_leaf_or_split``), the partition (``_partition``)."""

    depth: int                    # inner-node level of these nodes (root: 0)
    idx: np.ndarray               # int64 (n,) original face index of each element
    lo: list                      # 3 float32 rows (n,): element box lo (1-D rows keep
    hi: list                      #   numpy's gathers fast); hi likewise
    count: np.ndarray             # int64 (nseg,) triangles per node
    first: np.ndarray             # int64 (nseg,) first position in the final triangle order
    slot: np.ndarray              # int64 (nseg,) its reference's slot in the parent (root -1)
    # ---- _layout
    start: np.ndarray = None      # (nseg,) first element of each node
    node: np.ndarray = None       # int32 (n,) node of each element
    k_in: np.ndarray = None       # int32 (n,) index of each element in its node
    sidx: np.ndarray = None       # arange(nseg)
    nbins: int = 0                # bins per axis in this level
    cen: list = None              # 3 rows (n,): 2 x box centre
    cmin: np.ndarray = None       # (3, nseg) centroid bounds lo
    long_axis: np.ndarray = None  # (nseg,) longest centroid axis
    scale: np.ndarray = None      # (3, nseg) bins per unit of (2 x) centroid
    # ---- _bin
    sm: np.ndarray = None         # elements of the sample (None: all elements)
    sampled: np.ndarray = None    # (nseg,) node binned from a sample
    s_n: np.ndarray = None        # (nseg,) binned triangles per node
    n_axes: int = 0               # 3 (all axes) or 1 (the longest)
    cnt: np.ndarray = None        # (A, B, nseg) triangles per bin
    bmin: np.ndarray = None       # (3, A, B, nseg) bounds of each bin
    bmax: np.ndarray = None
    bs: list = None               # per axis: bin of each binned element
    # ---- _best_split
    Lmin: np.ndarray = None       # (3, A, B, nseg) bounds of bins 0..k
    Lmax: np.ndarray = None
    Rmin: np.ndarray = None       # bounds of bins k..B-1
    Rmax: np.ndarray = None
    nL: np.ndarray = None         # (A, B-1, nseg) triangles left of a split after bin k
    best_a: np.ndarray = None     # (nseg,) axis (index into the binned axes) of the best split
    best: np.ndarray = None       # (nseg,) its bin: split after it
    best_cost: np.ndarray = None  # (nseg,) its SAH cost (inf: no split separates the node)
    node_area: np.ndarray = None  # (nseg,) half area of the node's box
    # ---- _leaf_or_split
    inner: np.ndarray = None      # (nseg,) node is split
    forced: np.ndarray = None     # (nseg,) split at the median instead of by SAH
    node_id: np.ndarray = None    # (nseg,) inner-node index of each split node
    # ---- _partition
    right: np.ndarray = None      # (n,) element goes to child B
    rank: np.ndarray = None       # (n,) stable rank of the element in its child
    n_left: np.ndarray = None     # (nseg,) triangles in child A
    bl: np.ndarray = None         # (nseg, 2, 3) child A box lo, hi (unpadded)
    br: np.ndarray = None         # child B box

    @property
    def nseg(self) -> int:
        return self.count.size

    @property
    def size(self) -> int:
        return self.idx.size


def build_bvh(vertices: np.ndarray, faces: np.ndarray, options: BuildOptions | None = None,
              *, progress=None, **settings) -> BVHArrays:
    """Build a BVH over the triangles ``faces`` (int (F, 3)) of ``vertices`` (float (V, 3))
    with ``options`` (a ``BuildOptions``; default ``BuildOptions()``), any of its fields
    overridden by the keywords ``settings`` (``build_bvh(V, F, leaf_size=4)``; an unknown
    name is a TypeError). ``progress``: None, or called as ``progress(levels_done)`` after
    each level of the build (and once more, ``MAX_LEVELS``, when the build is done but the
    optimisation). A node whose centroids coincide, or one too deep to finish with SAH
    splits inside MAX_LEVELS levels, is split at the median instead.
    """
    opt = replace(options or BuildOptions(), **settings)
    leaf_size = opt.leaf_size
    t_start = time.perf_counter()
    V = np.asarray(vertices, np.float32)
    Fi = np.asarray(faces, np.int64)
    F = int(Fi.shape[0])
    if F >= 1 << COUNT_SHIFT:
        raise ValueError(f"faces: at most {1 << COUNT_SHIFT} triangles, got {F}")
    if F and MAX_LEVELS < int(_levels_needed(np.array([F]), leaf_size)[0]) + 1:
        raise ValueError(f"faces: {F} triangles need more than {MAX_LEVELS} BVH levels")

    # ---- triangle boxes and the scene's bounds --------------------------------------------
    p = [V[Fi[:, k]] for k in range(3)]
    lo = np.minimum(np.minimum(p[0], p[1]), p[2]).T.copy()        # (3, F) float32
    hi = np.maximum(np.maximum(p[0], p[1]), p[2]).T.copy()
    del p
    if F:
        s_lo, s_hi = lo.min(axis=1), hi.max(axis=1)
    else:
        s_lo = s_hi = np.zeros(3, np.float32)
    bounds = (s_lo.astype(np.float64), s_hi.astype(np.float64))
    top = None
    if opt.spatial > 0 and F > max(leaf_size, SPATIAL_MIN_TRIANGLES):
        top = spatial_top(V, Fi, lo.T, hi.T, int(opt.spatial * F), SPATIAL_MIN_REFS,
                          SPATIAL_DEPTH)
        if top is not None and not len(top.nodes):
            top = None
    R = F if top is None else int(top.face.size)          # references
    if top is not None:
        lo, hi = top.lo.T.copy(), top.hi.T.copy()
    n_max = max(R, 1) + (0 if top is None else len(top.nodes))
    tree = _Tree(np.empty((n_max, 12), np.float32), np.empty((n_max, 2), np.uint32),
                 np.empty(R, np.int64), float(np.max(s_hi - s_lo)) if F else 0.0)

    if F <= leaf_size:
        _single_leaf(tree, s_lo, s_hi)
    else:
        # ---- level by level: bin, choose splits, partition, emit children ---------------
        if top is None:
            lv = _Level(0, np.arange(F, dtype=np.int64), list(lo), list(hi),
                        np.array([F], np.int64), np.array([0], np.int64),
                        np.array([-1], np.int64))
        else:
            lv = _top_nodes(top, tree, lo, hi)
        while lv.nseg:
            _layout(lv, opt)
            _bin(lv, opt)
            _best_split(lv)
            _leaf_or_split(lv, tree, opt)
            _partition(lv)
            lv = _emit_children(lv, tree, opt)
            if progress is not None:
                progress(lv.depth)

    boxes, children = tree.boxes[:tree.n_nodes], tree.children[:tree.n_nodes]
    if opt.depth_first and F > leaf_size:
        boxes, children = _depth_first(boxes, children)
    order, cells = tree.order, None
    if top is not None:                   # leaf positions hold references: their faces
        order = top.face[tree.order]
        cells = (top.cell_lo[tree.order], top.cell_hi[tree.order])
    arrays = BVHArrays(boxes.copy(), children.copy(), order, tree.levels,
                       tree.leaf_count, 0.0, 0.0, bounds, cells)
    arrays.sah_cost = sah_cost(arrays)
    if progress is not None:
        progress(MAX_LEVELS)
    if opt.optimize > 0 and F > leaf_size:
        arrays = reinsert(arrays, rounds=opt.optimize)
    arrays.build_seconds = time.perf_counter() - t_start
    return arrays


def _top_nodes(top, tree: _Tree, lo, hi) -> _Level:
    """Write ``spatial_top``'s top nodes into ``tree`` (padded child boxes; top children
    linked, bucket children linked later by the level-wise build) and return the buckets as
    the first pending level of that build (at the deepest bucket's depth, so its
    ``MAX_LEVELS`` bound holds for every bucket)."""
    T = len(top.nodes)
    for k in range(2):
        blo, bhi = pad_boxes(top.nodes[:, 6 * k:6 * k + 3], top.nodes[:, 6 * k + 3:6 * k + 6],
                             tree.extent)
        tree.boxes[:T, 6 * k:6 * k + 3], tree.boxes[:T, 6 * k + 3:6 * k + 6] = blo, bhi
    ch = top.children
    tree.children[:T] = np.where(ch >= 0, ch, 0).astype(np.uint32)
    slot = np.empty(len(top.buckets), np.int64)
    node, k = np.nonzero(ch < 0)
    slot[-1 - ch[node, k]] = 2 * node + k
    tree.n_nodes = T
    tree.levels = max(top.depth)
    counts = np.array([b.size for b in top.buckets], np.int64)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]]).astype(np.int64)
    el = np.concatenate(top.buckets)
    return _Level(max(top.depth), el, [r[el] for r in lo], [r[el] for r in hi], counts,
                  first, slot)


def _single_leaf(tree: _Tree, s_lo, s_hi) -> None:
    """At most ``leaf_size`` triangles: one inner node whose child A is a single leaf and
    child B a box at infinity (never hit); with no triangles both boxes are at infinity."""
    F = tree.order.size
    tree.boxes[0, 0:3], tree.boxes[0, 3:6] = pad_boxes(s_lo, s_hi, tree.extent)
    tree.boxes[0, 6:12] = np.inf
    tree.children[0] = ([leaf_ref(0, max(F, 1)), leaf_ref(0, 1)] if F
                        else [leaf_ref(0, 1)] * 2)
    if F == 0:
        tree.boxes[0, 0:6] = np.inf
    tree.order[:] = np.arange(F)
    tree.n_nodes, tree.leaf_count, tree.levels = 1, 1, 1


def _layout(lv: _Level, opt: BuildOptions) -> None:
    """Where each node's elements lie, how many bins the level gets, and the centroid
    bounds the bins divide."""
    nseg, n, seg_n = lv.nseg, lv.size, lv.count
    seg_start = np.zeros(nseg, np.int64)
    np.cumsum(seg_n[:-1], out=seg_start[1:])
    es = np.repeat(np.arange(nseg, dtype=np.int32), seg_n)   # node of each element
    # Fewer bins once the nodes are small (a bin per triangle is enough), more while
    # they are large.
    nb = opt.root_bins if n / nseg > BIG_NODE else opt.bins
    B = int(min(nb, max(4, (1 << int(math.ceil(math.log2(max(n / nseg, 2))))) // BIN_DIV)))
    cen = [lv.lo[j] + lv.hi[j] for j in range(3)]                # 2 x box centre
    cmin = np.stack([np.minimum.reduceat(cen[j], seg_start) for j in range(3)])
    cmax = np.stack([np.maximum.reduceat(cen[j], seg_start) for j in range(3)])
    ext = cmax - cmin
    with np.errstate(divide="ignore"):
        scale = np.where(ext > 0, np.float32(B) / ext, np.float32(0)).astype(np.float32)
    seg_first = seg_start.astype(np.int32)[es]
    lv.start, lv.node, lv.sidx, lv.nbins = seg_start, es, np.arange(nseg), B
    lv.k_in = np.arange(n, dtype=np.int32) - seg_first
    lv.cen, lv.cmin, lv.long_axis, lv.scale = cen, cmin, np.argmax(ext, axis=0), scale


def _bin(lv: _Level, opt: BuildOptions) -> None:
    """Count the triangles and bound their boxes in each bin, along each axis (levels of
    large nodes with ``all_axes``) or the longest. Large nodes are binned from a strided
    sample of about ``opt.sample`` of their triangles (the split plane is chosen on the
    sample; the partition and the child boxes are then computed exactly over all
    triangles)."""
    nseg, n, es, B = lv.nseg, lv.size, lv.node, lv.nbins
    cmin, scale, long_axis, sidx = lv.cmin, lv.scale, lv.long_axis, lv.sidx
    stride = np.maximum(lv.count // opt.sample, 1)
    sampled = stride > 1
    if sampled.any():
        sm = np.flatnonzero(lv.k_in % stride.astype(np.int32)[es] == 0)
        s_es = es[sm]
        s_cen = [c[sm] for c in lv.cen]
        sp_lo = [r[sm] for r in lv.lo]
        sp_hi = [r[sm] for r in lv.hi]
        s_n = np.bincount(s_es, minlength=nseg)
    else:
        sm, s_es, s_cen, sp_lo, sp_hi, s_n = None, es, lv.cen, lv.lo, lv.hi, lv.count
    if opt.all_axes and n / nseg > AXES_MIN:
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
        key = b * nseg + s_es                # bin-major: the sweeps run over bins
        cnt[i] = np.bincount(key, minlength=nseg * B).reshape(B, nseg)
        for j in range(3):
            np.minimum.at(bmin[j, i], key, sp_lo[j])
            np.maximum.at(bmax[j, i], key, sp_hi[j])
    lv.sm, lv.sampled, lv.s_n, lv.n_axes, lv.cnt, lv.bs = sm, sampled, s_n, A, cnt, bs
    lv.bmin = bmin.reshape(3, A, B, nseg)
    lv.bmax = bmax.reshape(3, A, B, nseg)


def _best_split(lv: _Level) -> None:
    """Compute the SAH cost of splitting after each bin (sweeps of the bin bounds from
    both ends), and find the split that minimizes it for each node."""
    A, B, nseg = lv.n_axes, lv.nbins, lv.nseg
    Lmin, Lmax = _sweep(lv.bmin, np.minimum), _sweep(lv.bmax, np.maximum)   # bins 0..k
    Rmin, Rmax = (_sweep(lv.bmin, np.minimum, reverse=True),                 # bins k..B-1
                  _sweep(lv.bmax, np.maximum, reverse=True))
    nL = np.cumsum(lv.cnt, axis=1)[:, :-1]                 # (A, B-1, nseg): split after k
    nR = lv.s_n - nL
    with np.errstate(invalid="ignore", over="ignore"):
        cost = (half_area(Lmin[:, :, :-1], Lmax[:, :, :-1]) * nL.astype(np.float32)
                + half_area(Rmin[:, :, 1:], Rmax[:, :, 1:]) * nR.astype(np.float32))
    cost[(nL == 0) | (nR == 0)] = np.inf
    cost = cost.reshape(A * (B - 1), nseg)
    bi = np.argmin(cost, axis=0)
    lv.best_cost = cost[bi, lv.sidx]
    lv.best_a, lv.best = bi // (B - 1), bi % (B - 1)
    lv.node_area = half_area(Lmin[:, 0, B - 1], Lmax[:, 0, B - 1])          # (nseg,)
    lv.Lmin, lv.Lmax, lv.Rmin, lv.Rmax, lv.nL = Lmin, Lmax, Rmin, Rmax, nL


def _leaf_or_split(lv: _Level, tree: _Tree, opt: BuildOptions) -> None:
    """Decide leaf or split for each node: SAH decides for small nodes (``sah_leaves``);
    the median where SAH cannot split or the depth runs out. Leaves are written to the
    tree now, split nodes get their inner-node index and are linked to their parents."""
    seg_n, level, es = lv.count, lv.depth, lv.node
    can_sah = np.isfinite(lv.best_cost)
    small = seg_n <= opt.leaf_size
    if opt.sah_leaves:
        with np.errstate(invalid="ignore"):
            cheaper = (np.float32(C_TRI) * seg_n * lv.node_area
                       <= np.float32(C_TRAV) * lv.node_area + np.float32(C_TRI) * lv.best_cost)
        make_leaf = small & (~can_sah | cheaper | (level >= MAX_LEVELS))
    else:
        make_leaf = small
    if level == 0:
        make_leaf[:] = False
    inner = ~make_leaf
    lv.forced = inner & (~can_sah
                         | (level + 1 + _levels_needed(seg_n, opt.leaf_size) > MAX_LEVELS))
    lf = np.flatnonzero(make_leaf)
    if lf.size:
        tree.child_flat[lv.slot[lf]] = leaf_ref(lv.first[lf], seg_n[lf])
        tree.leaf_count += int(lf.size)
        el = np.flatnonzero(make_leaf[es])
        tree.order[lv.first[es[el]] + lv.k_in[el]] = lv.idx[el]
    node_id = tree.n_nodes + np.cumsum(inner) - inner
    nonroot = inner & (lv.slot >= 0)
    tree.child_flat[lv.slot[nonroot]] = node_id[nonroot].astype(np.uint32)
    lv.inner, lv.node_id = inner, node_id


def _partition(lv: _Level) -> None:
    """Send each element to child A or B of its node (its bin along the chosen axis, or
    its rank by centroid for median splits), rank it stably in its child, and compute the
    child boxes (from the bin sweeps; reduced over the triangles for median and sampled
    splits)."""
    es, k_in, sidx, seg_n, B = lv.node, lv.k_in, lv.sidx, lv.count, lv.nbins
    cen, best_a, best, forced, sampled = lv.cen, lv.best_a, lv.best, lv.forced, lv.sampled
    if lv.sm is not None:                 # bins of every triangle along the chosen axis
        ax = best_a[es] if lv.n_axes > 1 else lv.long_axis[es]
        c = np.where(ax == 0, cen[0], np.where(ax == 1, cen[1], cen[2]))
        sa = best_a if lv.n_axes > 1 else lv.long_axis
        bsel = ((c - lv.cmin[sa, sidx][es]) * lv.scale[sa, sidx][es]).astype(np.int32)
        np.clip(bsel, 0, B - 1, out=bsel)
    elif lv.n_axes == 1:
        bsel = lv.bs[0]
    else:
        ax = best_a[es]
        bsel = np.where(ax == 0, lv.bs[0], np.where(ax == 1, lv.bs[1], lv.bs[2]))
    right = bsel > best[es]
    lx = np.cumsum(~right) - ~right                           # lefts before, globally
    l_in = lx - lx[lv.start][es]                              # lefts before, in node
    rank = np.where(right, k_in - l_in, l_in)                 # stable rank in its child
    n_left = lv.nL[best_a, best, sidx]
    if lv.sm is not None:
        last = lv.start + seg_n - 1
        n_left = np.where(sampled, l_in[last] + ~right[last], n_left)
    n_left = np.where(forced, seg_n // 2, n_left)
    bl = np.stack([lv.Lmin[:, best_a, best, sidx].T, lv.Lmax[:, best_a, best, sidx].T], 1)
    br = np.stack([lv.Rmin[:, best_a, best + 1, sidx].T,
                   lv.Rmax[:, best_a, best + 1, sidx].T], 1)
    if forced.any():                      # median split by centroid along the longest axis
        m = np.flatnonzero(forced[es])
        la = lv.long_axis[es[m]]
        cval = np.where(la == 0, cen[0][m], np.where(la == 1, cen[1][m], cen[2][m]))
        srt = m[np.lexsort((cval, es[m]))]                    # by node, then centroid
        rank_in = k_in[m]
        right[srt] = rank_in >= n_left[es[srt]]
        rank[srt] = np.where(right[srt], rank_in - n_left[es[srt]], rank_in)
    exact = forced | (sampled & lv.inner)
    if exact.any():
        # child boxes of median and sampled splits: reduced over their triangles
        m = np.flatnonzero(exact[es])
        ck = (es[m] * 2 + right[m]).astype(np.int64)
        fmin = np.full((3, 2 * lv.nseg), np.inf, np.float32)
        fmax = np.full((3, 2 * lv.nseg), -np.inf, np.float32)
        for j in range(3):
            np.minimum.at(fmin[j], ck, lv.lo[j][m])
            np.maximum.at(fmax[j], ck, lv.hi[j][m])
        fs = np.flatnonzero(exact)
        bl[fs, 0], bl[fs, 1] = fmin[:, 2 * fs].T, fmax[:, 2 * fs].T
        br[fs, 0], br[fs, 1] = fmin[:, 2 * fs + 1].T, fmax[:, 2 * fs + 1].T
    lv.right, lv.rank, lv.n_left, lv.bl, lv.br = right, rank, n_left, bl, br


def _emit_children(lv: _Level, tree: _Tree, opt: BuildOptions) -> _Level:
    """Write the split nodes' padded child boxes; children of at most
    ``opt.immediate_leaf`` triangles become leaves now, the rest are the pending nodes of
    the next level, returned with their elements gathered in node order."""
    inner, node_id, n_left, seg_n, seg_g = lv.inner, lv.node_id, lv.n_left, lv.count, lv.first
    ins = np.flatnonzero(inner)
    a_lo, a_hi = pad_boxes(lv.bl[ins, 0], lv.bl[ins, 1], tree.extent)
    b_lo, b_hi = pad_boxes(lv.br[ins, 0], lv.br[ins, 1], tree.extent)
    tree.boxes[node_id[ins]] = np.concatenate([a_lo, a_hi, b_lo, b_hi], axis=1)
    c_n = np.stack([n_left, seg_n - n_left], 1).reshape(-1)            # (2 nseg,)
    c_g = np.stack([seg_g, seg_g + n_left], 1).reshape(-1)
    c_slot = (2 * node_id[:, None] + np.arange(2)).reshape(-1)
    c_exists = np.repeat(inner, 2)
    c_leaf = c_exists & (c_n <= opt.immediate_leaf)
    c_pend = c_exists & ~c_leaf
    tree.child_flat[c_slot[c_leaf]] = leaf_ref(c_g[c_leaf], c_n[c_leaf])
    tree.leaf_count += int(c_leaf.sum())

    ci = 2 * lv.node + lv.right                                        # child of element
    el_leaf = c_leaf[ci]
    tree.order[c_g[ci[el_leaf]] + lv.rank[el_leaf]] = lv.idx[el_leaf]

    c_next = np.cumsum(c_pend) - c_pend                               # next-level index
    nn_n = c_n[c_pend]
    nn_start = np.zeros(nn_n.size, np.int64)
    np.cumsum(nn_n[:-1], out=nn_start[1:])
    keep = np.flatnonzero(c_pend[ci])
    src = np.empty(keep.size, np.int64)                  # gather index of the next level
    src[nn_start[c_next[ci[keep]]] + lv.rank[keep]] = keep
    if ins.size:
        tree.levels = lv.depth + 1
    tree.n_nodes += int(ins.size)
    return _Level(lv.depth + 1, lv.idx[src], [r[src] for r in lv.lo], [r[src] for r in lv.hi],
                  nn_n, c_g[c_pend], c_slot[c_pend])


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
        a_size = size[np.where(inner[nb, 0], ref[nb, 0], 0)]
        pre[ref[nb, 1]] = pre[nb] + 1 + np.where(inner[nb, 0], a_size, 0)
    new_boxes = np.empty_like(boxes)
    new_boxes[pre] = boxes
    new_ref = np.where(inner, pre[np.where(inner, ref, 0)], ref).astype(np.uint32)
    new_children = np.empty_like(children)
    new_children[pre] = new_ref
    return new_boxes, new_children


def refit_boxes(a: BVHArrays, vertices: np.ndarray, faces: np.ndarray, dtype, extent: float
                ) -> np.ndarray:
    """The boxes of ``a``'s tree recomputed from ``vertices`` (float (V, 3)) in ``dtype``
    (np.float32 or np.float64) and padded by ``pad_boxes(.., extent)``: (N, 12) of
    ``dtype``. The tree (children, order) is unchanged; boxes at infinity (the empty
    child of a single-leaf tree) stay at infinity. Vectorised per tree level.
    ``pad_refit(a, raw_boxes(a, ...), extent)`` is the same in two steps."""
    if a.order.size == 0:
        return np.array(a.boxes, np.dtype(dtype).type)
    return pad_refit(a, raw_boxes(a, vertices, faces, dtype), extent)


def raw_boxes(a: BVHArrays, vertices: np.ndarray, faces: np.ndarray, dtype) -> np.ndarray:
    """``refit_boxes`` before its padding: the exact bounds of each child's triangles
    (cells) in ``dtype``, (N, 12) like ``a.boxes`` (lo xyz, hi xyz of child A, then B);
    +-inf where a child holds nothing. They depend on the tree and the vertices only, so a
    cached tree keeps them (``BVHArrays.raw``) and the traversal's padding for any ray
    origins is one elementwise step (``pad_refit``)."""
    dt = np.dtype(dtype).type
    N = a.node_count
    F = a.order.size
    lo = np.full((N, 2, 3), np.inf, dt)                            # unpadded child boxes
    hi = np.full((N, 2, 3), -np.inf, dt)
    if F == 0:
        return np.concatenate([lo[:, 0], hi[:, 0], lo[:, 1], hi[:, 1]], axis=1)
    V = np.asarray(vertices, dt)
    Fi = np.asarray(faces, np.int64)[a.order]
    p = [V[Fi[:, k]] for k in range(3)]
    t_lo = np.minimum(np.minimum(p[0], p[1]), p[2])                  # (F, 3) in BVH order
    t_hi = np.maximum(np.maximum(p[0], p[1]), p[2])
    if a.cells is not None:               # each reference: its triangle clipped to its cell
        t_lo, t_hi = clipped_boxes(vertices, faces, a.order, a.cells[0], a.cells[1], dt)
    ref = a.children.astype(np.int64)
    is_leaf = (ref & LEAF_BIT) != 0
    real = np.isfinite(a.boxes.reshape(N, 2, 6)[:, :, 0])          # (N, 2)
    # leaves: reduce over their contiguous triangle ranges
    lf = is_leaf & real
    first = (ref[lf] & FIRST_MASK)
    count = ((ref[lf] >> COUNT_SHIFT) & 15) + 1
    srt = np.argsort(first, kind="stable")
    starts = first[srt]
    red_lo = np.minimum.reduceat(t_lo, starts, axis=0)
    red_hi = np.maximum.reduceat(t_hi, starts, axis=0)
    ends = starts + count[srt]
    assert np.all(ends[:-1] <= starts[1:]) and ends[-1] <= F
    # reduceat over [start_k, start_{k+1}): leaves tile [0, F) with no gaps in a valid tree
    leaf_lo = np.empty_like(red_lo)
    leaf_hi = np.empty_like(red_hi)
    leaf_lo[srt], leaf_hi[srt] = red_lo, red_hi
    lo[lf], hi[lf] = leaf_lo, leaf_hi
    # inner nodes: deepest level first
    levels = [np.zeros(1, np.int64)]
    while True:
        nodes = levels[-1]
        c = ref[nodes][~is_leaf[nodes]]
        if not c.size:
            break
        levels.append(c)
    for nodes in reversed(levels):
        for k in range(2):
            m = ~is_leaf[nodes, k]
            par, child = nodes[m], ref[nodes[m], k]
            lo[par, k] = np.minimum(lo[child, 0], lo[child, 1])
            hi[par, k] = np.maximum(hi[child, 0], hi[child, 1])
    return np.concatenate([lo[:, 0], hi[:, 0], lo[:, 1], hi[:, 1]], axis=1)


def pad_refit(a: BVHArrays, raw: np.ndarray, extent: float) -> np.ndarray:
    """``raw`` (``raw_boxes``, (N, 12)) padded by ``pad_boxes(.., extent)`` in its dtype,
    at infinity where ``a``'s own child box is (the empty child of a single-leaf tree);
    elementwise over spans of nodes (``renderer.parallel``)."""
    N = a.node_count
    real = np.isfinite(a.boxes.reshape(N, 2, 6)[:, :, 0])          # (N, 2)
    boxes = np.empty_like(raw)

    def span(lo, hi):
        for k in range(2):
            with np.errstate(invalid="ignore"):
                plo, phi = pad_boxes(raw[lo:hi, 6 * k:6 * k + 3],
                                     raw[lo:hi, 6 * k + 3:6 * k + 6], extent)
            r = real[lo:hi, k, None]
            boxes[lo:hi, 6 * k:6 * k + 3] = np.where(r, plo, np.inf)
            boxes[lo:hi, 6 * k + 3:6 * k + 6] = np.where(r, phi, np.inf)
    parallel.for_spans(N, span)
    return boxes


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
    if a.cells is None:
        assert np.array_equal(np.sort(a.order), np.arange(F))
    else:                                 # every face at least once
        assert np.array_equal(np.unique(a.order), np.arange(int(a.order.max()) + 1))
    assert a.levels <= MAX_LEVELS
