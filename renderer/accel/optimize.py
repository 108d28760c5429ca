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
    after them (``ref``: the packed leaf reference); ``box`` tuples (lo xyz, hi xyz) and
    their ``area`` (``_area``); ``height``: inner levels of the subtree (0 for a leaf)."""

    def __init__(self, a: BVHArrays):
        N = a.node_count
        ch = a.children.astype(np.int64)                          # (N, 2)
        leaf = (ch & LEAF_BIT) != 0
        ids = np.where(leaf, 0, ch)
        ids[leaf] = N + np.arange(int(leaf.sum()))                  # leaves after the nodes
        M = N + int(leaf.sum())
        parent = np.full(M, -1, np.int64)
        parent[ids.reshape(-1)] = np.repeat(np.arange(N), 2)
        box = np.empty((M, 6), np.float64)
        box[ids.reshape(-1)] = a.boxes.astype(np.float64).reshape(-1, 6)
        lo, hi = a.bounds
        box[0] = np.concatenate([np.asarray(lo, np.float64), np.asarray(hi, np.float64)])
        ref = np.zeros(M, np.int64)
        ref[ids[leaf]] = ch[leaf]
        self.N = N
        self.left, self.right = ids[:, 0].tolist(), ids[:, 1].tolist()
        self.parent, self.ref = parent.tolist(), ref.tolist()
        self.box = [tuple(r) for r in box.tolist()]
        self.area = [_area(b) for b in self.box]
        height = np.zeros(M, np.int64)
        for nodes in reversed(_levels(ids, leaf)):
            height[nodes] = 1 + np.maximum(height[ids[nodes, 0]], height[ids[nodes, 1]])
        self.height = height.tolist()
        self.max_levels = MAX_LEVELS

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
            lf, rt = self.left[i], self.right[i]
            self.box[i] = b = _union(self.box[lf], self.box[rt])
            self.area[i] = _area(b)
            self.height[i] = 1 + max(self.height[lf], self.height[rt])
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
        bn, hn = self.box[n], self.height[n]
        an = self.area[n]
        saved = self.area[p]
        self._replace_child(g, p, s)       # cut n and p out; s takes p's place
        i = g
        while i != -1:
            nb = _union(self.box[self.left[i]], self.box[self.right[i]])
            na = _area(nb)
            saved += self.area[i] - na
            self.box[i], self.area[i] = nb, na
            self.height[i] = 1 + max(self.height[self.left[i]], self.height[self.right[i]])
            i = self.parent[i]
        best, best_x = np.inf, s
        heap = [(0.0, 1, 0)]               # (growth of the ancestors, level of the slot, x)
        while heap:
            grown, lv, x = heapq.heappop(heap)
            if grown + an >= best:
                break
            ux = _union_area(self.box[x], bn)
            if grown + ux < best and lv + self.height[x] <= self.max_levels and x != 0:
                best, best_x = grown + ux, x
            if x < self.N and lv + 1 + hn <= self.max_levels:
                below = grown + ux - self.area[x]
                if below + an < best:
                    heapq.heappush(heap, (below, lv + 1, self.left[x]))
                    heapq.heappush(heap, (below, lv + 1, self.right[x]))
        x = best_x if saved - best > 0 else s
        q = self.parent[x]
        self._replace_child(q, x, p)       # p becomes the parent of x and n
        self.left[p], self.right[p] = x, n
        self.parent[x] = self.parent[n] = p
        self._up(p)
        return saved - best if x != s else 0.0

    def cost(self) -> float:
        return sum(self.area[:self.N])

    def worst(self, fraction: float) -> list:
        """The inner nodes and leaves (not the root, not its children) that cost most for
        their size: area^2 / mean child area for inner nodes, area for leaves."""
        ar = np.array(self.area)
        N = self.N
        kids = 0.5 * (ar[np.array(self.left)] + ar[np.array(self.right)])
        score = ar.copy()
        with np.errstate(divide="ignore", invalid="ignore"):
            score[:N] = ar[:N] * ar[:N] / kids
        parent = np.array(self.parent)
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
        kids = np.stack([np.array(self.left)[pre], np.array(self.right)[pre]], 1)  # (N, 2)
        box = np.array(self.box)
        boxes = box[kids].reshape(self.N, 12).astype(np.float32)
        ref = np.array(self.ref, np.int64)
        children = np.where(kids >= self.N, ref[kids], index[kids]).astype(np.uint32)
        out = replace(a, boxes=boxes, children=children, levels=self.height[0])
        out.sah_cost = sah_cost(out)
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
