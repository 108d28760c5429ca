"""Insertion-based optimisation of a binary BVH (Bittner, Hapala & Havran 2013).

The level-wise binned build decides every split from its node alone; the tree it makes can
still hold subtrees in the wrong place (a small node high up under a large box, a sliver
whose box spans a room). ``reinsert`` takes the nodes that cost most for their size, cuts
each out of the tree (its parent goes, its sibling takes the parent's place) and puts it
back where the SAH cost grows least: as the sibling of the node ``x`` that minimises
``area(x ∪ n)`` plus the growth of every ancestor of ``x``, found by a branch-and-bound
search from the root (a priority queue on the growth so far; a subtree is skipped once its
lower bound, growth so far + ``area(n)``, cannot beat the best). A move is kept only where
it lowers the cost.

Leaves are kept as they are (the same triangle ranges, references and cells), so the
optimised tree visits the same triangles under different boxes and the hits stay those of
brute force; only inner nodes move. A move is allowed only where the tree keeps at most
``MAX_LEVELS`` inner levels (the traversal stack's bound).
"""
from __future__ import annotations

import heapq
import time
from array import array
from dataclasses import replace

import numpy as np

from .bvh_arrays import BVHArrays, sah_cost
from .layout import LEAF_BIT, MAX_LEVELS

#: Default rounds of ``reinsert`` (``build_bvh(optimize=...)``); each moves the
#: ``FRACTION`` of nodes that cost most for their size. Rounds stop early once one lowers the
#: inner nodes' cost (their summed surface area) by less than ``MIN_GAIN`` of it.
ROUNDS = 4
FRACTION = 0.01
MIN_GAIN = 0.005


def _area(b) -> float:
    dx, dy, dz = b[3] - b[0], b[4] - b[1], b[5] - b[2]
    return dx * dy + dy * dz + dz * dx


def _union(a, b) -> tuple:
    # conditional expressions, not min/max calls (a third faster in CPython); the same
    # values: min(x, y) is ``y if y < x else x``, max(x, y) ``y if y > x else x``
    return (b[0] if b[0] < a[0] else a[0], b[1] if b[1] < a[1] else a[1],
            b[2] if b[2] < a[2] else a[2], b[3] if b[3] > a[3] else a[3],
            b[4] if b[4] > a[4] else a[4], b[5] if b[5] > a[5] else a[5])


def _union_area(a, b) -> float:
    """``_area(_union(a, b))`` without the tuple (the search's inner step)."""
    dx = (b[3] if b[3] > a[3] else a[3]) - (b[0] if b[0] < a[0] else a[0])
    dy = (b[4] if b[4] > a[4] else a[4]) - (b[1] if b[1] < a[1] else a[1])
    dz = (b[5] if b[5] > a[5] else a[5]) - (b[2] if b[2] < a[2] else a[2])
    return dx * dy + dy * dz + dz * dx


class _Tree:
    """The BVH as nodes with parent links: inner nodes ``0..N-1`` (0 the root), leaves
    after them (``ref``: the packed leaf reference); boxes as six float64 columns ``c``
    (lo xyz, hi xyz) and their ``area`` (``_area``); ``height``: inner levels of the
    subtree (0 for a leaf). Every field is a typed ``array.array`` (8 bytes a value, read as
    a Python number by the scalar search), not a list of Python objects, so a tree of tens
    of millions of nodes stays a few bytes per value."""

    def __init__(self, a: BVHArrays):
        N = a.node_count
        ch = a.children.astype(np.int64)                          # (N, 2)
        leaf = (ch & LEAF_BIT) != 0
        ids = np.where(leaf, 0, ch)
        ids[leaf] = N + np.arange(int(leaf.sum()))                  # leaves after the nodes
        M = N + int(leaf.sum())
        parent = np.full(M, -1, np.int64)
        parent[ids.reshape(-1)] = np.repeat(np.arange(N), 2)
        root = np.concatenate([np.asarray(a.bounds[0], np.float64),
                               np.asarray(a.bounds[1], np.float64)])
        flat, child_boxes = ids.reshape(-1), a.boxes.reshape(-1, 6)
        self.c = []
        for k in range(6):                  # one float64 column at a time
            col = np.empty(M, np.float64)
            col[flat] = child_boxes[:, k]
            col[0] = root[k]
            self.c.append(_col("d", col))
            del col
        ref = np.zeros(M, np.int64)
        ref[ids[leaf]] = ch[leaf]
        self.N = N
        self.left, self.right = _col("q", ids[:, 0]), _col("q", ids[:, 1])
        self.parent, self.ref = _col("q", parent), _col("q", ref)
        c = [np.frombuffer(x, np.float64) for x in self.c]
        dx, dy, dz = c[3] - c[0], c[4] - c[1], c[5] - c[2]
        self.area = _col("d", dx * dy + dy * dz + dz * dx)
        del c, dx, dy, dz
        height = np.zeros(M, np.int64)
        for nodes in reversed(_levels(ids, leaf)):
            height[nodes] = 1 + np.maximum(height[ids[nodes, 0]], height[ids[nodes, 1]])
        self.height = _col("q", height)
        self.max_levels = MAX_LEVELS

    def _box(self, i) -> tuple:
        return tuple(c[i] for c in self.c)

    def _refit(self, i) -> None:
        """Box and area of inner node ``i`` from its children's (``_union``, ``_area``)."""
        a, b = self.left[i], self.right[i]
        c0, c1, c2, c3, c4, c5 = self.c
        x0 = c0[b] if c0[b] < c0[a] else c0[a]
        y0 = c1[b] if c1[b] < c1[a] else c1[a]
        z0 = c2[b] if c2[b] < c2[a] else c2[a]
        x1 = c3[b] if c3[b] > c3[a] else c3[a]
        y1 = c4[b] if c4[b] > c4[a] else c4[a]
        z1 = c5[b] if c5[b] > c5[a] else c5[a]
        c0[i], c1[i], c2[i], c3[i], c4[i], c5[i] = x0, y0, z0, x1, y1, z1
        dx, dy, dz = x1 - x0, y1 - y0, z1 - z0
        self.area[i] = dx * dy + dy * dz + dz * dx

    def _preorder(self) -> list:
        out, st = [], [0]
        while st:
            i = st.pop()
            if i < self.N:
                out.append(i)
                st += [self.right[i], self.left[i]]
        return out

    def _up(self, i) -> None:
        """Refit the boxes and heights from inner node ``i`` up to the root."""
        while i != -1:
            self._refit(i)
            self.height[i] = 1 + max(self.height[self.left[i]], self.height[self.right[i]])
            i = self.parent[i]

    def _replace_child(self, q, old, new) -> None:
        if self.left[q] == old:
            self.left[q] = new
        else:
            self.right[q] = new
        self.parent[new] = q

    def reinsert(self, n) -> float:
        """Move node ``n`` to where the SAH cost grows least; returns the cost saved
        (unnormalised surface area; 0 where ``n`` stays)."""
        p = self.parent[n]
        if p <= 0:                         # the root or a child of the root
            return 0.0
        g = self.parent[p]
        s = self.right[p] if self.left[p] == n else self.left[p]
        b0, b1, b2, b3, b4, b5 = self._box(n)
        hn = self.height[n]
        area, height, left, right = self.area, self.height, self.left, self.right
        an = area[n]
        saved = area[p]
        self._replace_child(g, p, s)       # cut n and p out; s takes p's place
        i = g
        while i != -1:
            old = area[i]
            self._refit(i)
            saved += old - area[i]
            height[i] = 1 + max(height[left[i]], height[right[i]])
            i = self.parent[i]
        c0, c1, c2, c3, c4, c5 = self.c
        N, max_levels = self.N, self.max_levels
        best, best_x = np.inf, s
        heap = [(0.0, 1, 0)]               # (growth of the ancestors, level of the slot, x)
        while heap:
            grown, lv, x = heapq.heappop(heap)
            if grown + an >= best:
                break
            # _union_area(box[x], box[n])
            dx = (b3 if b3 > c3[x] else c3[x]) - (b0 if b0 < c0[x] else c0[x])
            dy = (b4 if b4 > c4[x] else c4[x]) - (b1 if b1 < c1[x] else c1[x])
            dz = (b5 if b5 > c5[x] else c5[x]) - (b2 if b2 < c2[x] else c2[x])
            ux = dx * dy + dy * dz + dz * dx
            if grown + ux < best and lv + height[x] <= max_levels and x != 0:
                best, best_x = grown + ux, x
            if x < N and lv + 1 + hn <= max_levels:
                below = grown + ux - area[x]
                if below + an < best:
                    heapq.heappush(heap, (below, lv + 1, left[x]))
                    heapq.heappush(heap, (below, lv + 1, right[x]))
        x = best_x if saved - best > 0 else s
        q = self.parent[x]
        self._replace_child(q, x, p)       # p becomes the parent of x and n
        left[p], right[p] = x, n
        self.parent[x] = self.parent[n] = p
        self._up(p)
        return saved - best if x != s else 0.0

    def cost(self) -> float:
        return sum(self.area[:self.N])

    def worst(self, fraction: float) -> list:
        """The inner nodes and leaves (not the root, not its children) that cost most for
        their size: area^2 / mean child area for inner nodes, area for leaves."""
        ar = np.frombuffer(self.area, np.float64)
        N = self.N
        kids = 0.5 * (ar[np.frombuffer(self.left, np.int64)]
                      + ar[np.frombuffer(self.right, np.int64)])
        score = ar.copy()
        with np.errstate(divide="ignore", invalid="ignore"):
            score[:N] = ar[:N] * ar[:N] / kids
        parent = np.frombuffer(self.parent, np.int64)
        ok = (parent > 0) & np.isfinite(score)
        cand = np.flatnonzero(ok)
        k = max(1, int(cand.size * fraction))
        if k < cand.size:
            cand = cand[np.argpartition(-score[cand], k - 1)[:k]]
        return cand[np.argsort(-score[cand], kind="stable")].tolist()

    def arrays(self, a: BVHArrays) -> BVHArrays:
        """The tree back as ``BVHArrays``: children boxes and references, the inner nodes in
        depth-first pre-order (``bvh_build._depth_first``'s)."""
        pre = np.array(self._preorder(), np.int64)
        index = np.zeros(len(self.parent), np.int64)
        index[pre] = np.arange(self.N)
        kids = np.stack([np.frombuffer(self.left, np.int64)[pre],
                         np.frombuffer(self.right, np.int64)[pre]], 1)  # (N, 2)
        boxes = np.empty((self.N, 12), np.float32)
        for k in range(2):
            for j, c in enumerate(self.c):
                boxes[:, 6 * k + j] = np.frombuffer(c, np.float64)[kids[:, k]]
        ref = np.frombuffer(self.ref, np.int64)
        children = np.where(kids >= self.N, ref[kids], index[kids]).astype(np.uint32)
        out = replace(a, boxes=boxes, children=children, levels=self.height[0])
        out.sah_cost = sah_cost(out)
        return out


def _col(code: str, x: np.ndarray) -> array:
    """A typed ``array.array`` (``"q"`` int64, ``"d"`` float64) holding ``x``."""
    out = array(code)
    out.frombytes(np.ascontiguousarray(x, np.int64 if code == "q" else np.float64).tobytes())
    return out


def _levels(ids: np.ndarray, leaf: np.ndarray) -> list:
    """The inner nodes of each level, root first (``ids``: (N, 2) child node ids)."""
    levels = [np.zeros(1, np.int64)]
    while True:
        nodes = levels[-1]
        c = ids[nodes][~leaf[nodes]]
        if not c.size:
            return levels
        levels.append(c)


def reinsert(a: BVHArrays, rounds: int = ROUNDS, fraction: float = FRACTION,
             min_gain: float = MIN_GAIN, max_levels: int = MAX_LEVELS) -> BVHArrays:
    """``a`` optimised by up to ``rounds`` rounds of reinsertion (see the module
    docstring), each of the ``fraction`` of nodes that cost most for their size; stops once a
    round saves less than ``min_gain`` of the inner nodes' cost. No move makes the tree
    deeper than ``max_levels`` inner levels (``MAX_LEVELS`` at most; a tree already deeper
    keeps its depth). Returns new arrays (``a`` unchanged); ``build_seconds`` and
    ``optimize_seconds`` grow by the time taken."""
    if a.node_count < 3 or rounds <= 0:
        return a
    t0 = time.perf_counter()
    tree = _Tree(a)
    tree.max_levels = max(min(max_levels, MAX_LEVELS), tree.height[0])
    for _ in range(rounds):
        total = tree.cost()
        saved = sum(tree.reinsert(n) for n in tree.worst(fraction))
        if saved < min_gain * total:
            break
    out = tree.arrays(a)
    dt = time.perf_counter() - t0
    out.build_seconds = a.build_seconds + dt
    out.optimize_seconds = a.optimize_seconds + dt
    return out
