"""The top of a PLOC tree (``ploc.build_ploc``) built by a full-sweep SAH over its last
clusters, on the host.

When at most ``TOP`` clusters are left, the clustering stops and this module builds the
tree above them: the clusters' boxes, triangle counts and references are copied to the host
(one read), and a top-down build splits every node's clusters where the sum of the two
sides' surface areas, each weighted by its triangle count, is least, over every position of
the clusters sorted by box centre along each axis (a full sweep; ties go to the lower axis,
then the lower position). All nodes of one level are split at once with segmented numpy
operations. A node over one cluster is that cluster (its subtree a leaf of the top tree).

The top nodes are numbered as ``build_ploc``'s clustering numbers its nodes: after the
clustered ones, deepest level first, so every node's children come before it and each level
is one batch of ``build_ploc``'s list (the root last). Their boxes are the float32 unions of
their children's boxes, their counts the sums: the same arrays the clustering fills, written
on the device with one scatter each.
"""
from __future__ import annotations

import drjit as dr
import numpy as np

#: Clusters left when the clustering stops and the top tree is built over them (0: the
#: clustering runs to the root). Off: on Sponza and Conference the swept top costs more
#: than PLOC's own merges (``lab/notes/device-build.md``).
TOP = 0
#: What weights a side's area in the split cost: "clusters" (each cluster 1: the top nodes
#: below a side grow with its clusters, the subtrees' own cost is fixed) or "triangles".
WEIGHT = "clusters"


def _seg_cummin(x, seg, span):
    """Cumulative minimum of float64 ``x`` (K,) restarted at every segment (``seg``: int
    segment id of each element, non-decreasing; ``span``: more than the range of ``x``)."""
    off = seg * span
    return np.minimum.accumulate(x - off) + off


def _splits(cen, lo, hi, w, seg, start, size):
    """The best split of every segment of at least two clusters: for each cluster (in the
    current order) its segment ``seg``; segments begin at ``start`` and hold ``size``
    clusters. Answers, per segment, the axis and the number of clusters on the left of the
    cheapest split, and per axis the order of the clusters sorted by centre within their
    segments (``orders[a]``, positions into the current order)."""
    n_seg = start.shape[0]
    span = 4.0 * float(np.max(hi) - np.min(lo)) + 1.0
    best = np.full(n_seg, np.inf)
    axis = np.zeros(n_seg, np.int64)
    left = np.ones(n_seg, np.int64)
    orders = []
    pos = np.arange(seg.shape[0])
    rel = pos - start[seg]                    # position within the segment
    last = rel == size[seg] - 1
    for a in range(3):
        o = np.lexsort((pos, cen[:, a], seg))   # stable: by segment, centre, position
        orders.append(o)
        blo, bhi, bw = lo[o], hi[o], w[o]
        # prefix boxes (clusters 0..i of the segment) and suffix boxes (i+1..end)
        plo = np.stack([_seg_cummin(blo[:, k], seg, span) for k in range(3)], 1)
        phi = -np.stack([_seg_cummin(-bhi[:, k], seg, span) for k in range(3)], 1)
        rseg = (n_seg - 1) - seg[::-1]
        slo = np.stack([_seg_cummin(blo[::-1, k], rseg, span) for k in range(3)], 1)[::-1]
        shi = -np.stack([_seg_cummin(-bhi[::-1, k], rseg, span) for k in range(3)], 1)[::-1]
        cw = np.cumsum(bw)
        base = cw[start] - bw[start]              # weight before each segment
        wl = cw - base[seg]
        wr = (base + np.add.reduceat(bw, start))[seg] - cw
        dl, dr_ = phi - plo, np.empty_like(plo)
        dr_[:-1] = shi[1:] - slo[1:]
        dr_[-1] = 0.0
        al = dl[:, 0] * dl[:, 1] + dl[:, 1] * dl[:, 2] + dl[:, 2] * dl[:, 0]
        ar = dr_[:, 0] * dr_[:, 1] + dr_[:, 1] * dr_[:, 2] + dr_[:, 2] * dr_[:, 0]
        cost = np.where(last, np.inf, al * wl + ar * wr)
        # cheapest position per segment, the first of equal costs
        k = np.lexsort((rel, cost, seg))
        first = k[start]
        c = cost[first]
        take = c < best
        best = np.where(take, c, best)
        axis = np.where(take, a, axis)
        left = np.where(take, rel[first] + 1, left)
    return axis, left, orders


def top_tree(boxes: np.ndarray, counts: np.ndarray):
    """The topology of the top tree over K >= 2 clusters (``boxes``: float32 (K, 6), lo xyz
    and hi xyz; ``counts``: their triangle counts). Answers ``(children, levels)``:
    ``children`` int64 (K - 1, 2), each child a cluster ``c`` (as ``c``) or a top node
    ``t`` (as ``K + t``), nodes numbered top down level by level (node 0 the root), and
    ``levels``, the first node of each level followed by K - 1."""
    K = boxes.shape[0]
    lo = boxes[:, :3].astype(np.float64)
    hi = boxes[:, 3:].astype(np.float64)
    cen = lo + hi
    w = np.ones(K) if WEIGHT == "clusters" else counts.astype(np.float64)
    cur = np.arange(K)                         # clusters in segment order
    seg = np.zeros(K, np.int64)
    start = np.zeros(1, np.int64)
    size = np.array([K], np.int64)
    node = np.zeros(1, np.int64)               # top node of each segment
    children = np.zeros((K - 1, 2), np.int64)
    levels = [0]
    made = 1
    while start.shape[0]:
        axis, left, orders = _splits(cen[cur], lo[cur], hi[cur], w[cur], seg, start, size)
        pick = np.stack(orders, 0)[axis[seg], np.arange(K if seg.shape[0] == K else
                                                        seg.shape[0])]
        cur = cur[pick]
        rel = np.arange(cur.shape[0]) - start[seg]
        side = (rel >= left[seg]).astype(np.int64)
        # child segments: (start, size) of each side of each segment
        c_start = np.stack([start, start + left], 1).reshape(-1)
        c_size = np.stack([left, size - left], 1).reshape(-1)
        inner = c_size > 1
        n_new = int(np.count_nonzero(inner))
        c_node = np.full(c_start.shape[0], -1, np.int64)
        c_node[inner] = made + np.arange(n_new)
        ref = np.where(inner, K + c_node, cur[c_start])
        children[node] = ref.reshape(-1, 2)
        made += n_new
        # the next level: the clusters of the inner child segments, in order
        keep = inner[2 * seg + side]
        if not n_new:
            break
        levels.append(made - n_new)
        new_seg = np.cumsum(inner) - 1              # index among the inner child segments
        seg = new_seg[(2 * seg + side)[keep]]
        cur = cur[keep]
        start = np.concatenate([[0], np.cumsum(c_size[inner])[:-1]]).astype(np.int64)
        size = c_size[inner]
        node = c_node[inner]
    levels.append(K - 1)
    return children, levels


def build_top(m, clusters, nodes, made: int) -> list:
    """Build the top tree over the clusters ``(c_ref, c_box, c_cnt)`` (UInt32, 6 Floats,
    UInt32 on the device, at least two) into the node arrays ``(n_ch, n_box, n_cnt)`` (two
    UInt32, six Floats, one UInt32) from node ``made`` on. Answers the batches ``[(first
    node, node count), ...]`` of its levels, deepest first (see the module docstring)."""
    c_ref, c_box, c_cnt = clusters
    n_ch, n_box, n_cnt = nodes
    Float, UInt32 = m.Float, m.UInt32
    K = dr.width(c_ref)
    boxes = np.stack([np.asarray(x.numpy(), np.float32) for x in c_box], 1)
    counts = np.asarray(c_cnt.numpy(), np.int64)
    refs = np.asarray(c_ref.numpy(), np.uint32)
    children, levels = top_tree(boxes, counts)
    T = K - 1
    # top nodes numbered deepest level first: level l's nodes keep their order
    new = np.empty(T, np.int64)
    batches = []
    at = made
    for a, b in reversed(list(zip(levels[:-1], levels[1:]))):
        new[a:b] = at + np.arange(b - a)
        batches.append((at, b - a))
        at += b - a
    # boxes and counts bottom up (float32 unions: exactly what the clustering computes)
    t_box = np.zeros((T, 6), np.float32)
    t_cnt = np.zeros(T, np.int64)
    for a, b in reversed(list(zip(levels[:-1], levels[1:]))):
        ch = children[a:b]
        parts = []
        for s in range(2):
            c = ch[:, s]
            top = c >= K
            bx = np.where(top[:, None], t_box[np.where(top, c - K, 0)],
                          boxes[np.where(top, 0, c)])
            ct = np.where(top, t_cnt[np.where(top, c - K, 0)], counts[np.where(top, 0, c)])
            parts.append((bx, ct))
        t_box[a:b, :3] = np.minimum(parts[0][0][:, :3], parts[1][0][:, :3])
        t_box[a:b, 3:] = np.maximum(parts[0][0][:, 3:], parts[1][0][:, 3:])
        t_cnt[a:b] = parts[0][1] + parts[1][1]
    ref = np.where(children >= K, (new[np.maximum(children - K, 0)] | (1 << 31)),
                   refs[np.minimum(children, K - 1)].astype(np.int64)).astype(np.uint32)
    at = UInt32(new.astype(np.uint32))
    for s in range(2):
        dr.scatter(n_ch[s], UInt32(np.ascontiguousarray(ref[:, s])), at)
    for x in range(6):
        dr.scatter(n_box[x], Float(np.ascontiguousarray(t_box[:, x])), at)
    dr.scatter(n_cnt, UInt32(t_cnt.astype(np.uint32)), at)
    dr.eval(n_ch, n_box, n_cnt)
    return batches
