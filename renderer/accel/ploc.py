"""BVH build on the device by locally-ordered clustering (PLOC, Meister & Bittner 2018), in
Dr.Jit: the same code on CUDA and LLVM.

Steps, each a few Dr.Jit kernels over all triangles, clusters or nodes:

1. triangle boxes, large triangles cut into references at coarse planes of the Morton
   grid (``presplit``: the tree then carries their cells, ``BVHArrays.cells``, and
   ``order`` holds a face once per reference; where anything is cut the uncut tree is built
   too, over the triangle boxes already made, their SAH costs compared from one small read
   and only the kept tree copied back), the scene box and 30-bit Morton codes of the
   box centres, sorted by ``dr.argsort``, as ``device_build`` makes them but without its
   large-triangle key (clustering merges a large triangle late by itself: its union boxes
   are large);
2. clustering: the sorted triangles are the first clusters. Each iteration, every cluster
   finds its nearest neighbour among the ``radius`` clusters on either side of it in the
   list (one symbolic loop over the distance; on the CPU, over wide arrays, one loop per run
   of ``WINDOW`` clusters that computes each pair's area once): the one whose union box has
   the smallest surface area (ties ordered by a fixed total order on pairs, so the nearest-
   neighbour graph has no cycles longer than two and the closest pair is always mutual).
   Mutual pairs merge into a new node that takes the lower one's place; the higher one
   leaves the list, until one cluster is left. A node's box is its children's union, its
   count the sum of theirs. The count of nodes made stays on the device: one prefix sum
   numbers the new nodes and compacts the list into arrays as wide as the last count the
   host read (lanes past the count idle), and the host reads the counts every ``READ_EVERY``
   iterations, one transfer for all of them (on the CPU after each, so its arrays shrink
   each time). With ``FREEZE`` the iterations between two reads replay one recording
   (``dr.freeze``) instead of being traced again, compacting within two arrays of one width
   that the host narrows after each read (and step 4's bottom-up pass replays one recording
   per batch);
3. triangle order: a node's first child starts where the node starts, its second after
   the first's triangles, so every subtree is a contiguous run of the triangle order; each
   node's start and depth are sums over its ancestors, taken by pointer jumping;
4. nodes of at most ``leaf_size`` triangles become leaves; the others are the inner nodes,
   numbered latest first (the root is node 0, every child after its parent), their child
   boxes padded on the device by ``pad_boxes``'s rule (the same float32 operations) and
   their SAH cost summed there.

Clustering has no level bound, and the traversal's stack allows ``MAX_LEVELS`` inner
levels. When the clustered tree is deeper, step 4 rebuilds the fewest, deepest subtrees
that make it fit (bottom up: a node whose subtree still reaches too deep is rebuilt when a
balanced tree over its triangles fits below its level, else left to an ancestor): each
such subtree becomes a balanced tree over its contiguous run of triangles (middle splits,
boxes reduced over the run), built top down one level at a time. A clustering that grows a
cluster taller than ``TALL * MAX_LEVELS`` (chains of one-by-one merges, which need one
iteration per merge) stops, and the build returns ``device_build.build_device``'s radix
tree instead.

The output is a ``BVHArrays`` like ``device_build.build_device``'s, so the traversal, the
wide conversion and the refit read it as they read the SAH tree and the hits are the same
bit for bit.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import drjit as dr
import numpy as np

from . import presplit
from .bvh_build import C_TRAV, LEAF_SIZE, MAX_LEVELS, BVHArrays
from .device_build import (
    DeviceTree,
    _levels_needed,
    _module,
    _phase,
    _read_back,
    build_device,
    checked_input,
    host_arrays,
    morton_codes,
    triangle_boxes,
    write_box,
)
from .traverse import COUNT_SHIFT, LEAF_BIT
from .triangle import unit_roundoff

#: Clusters searched on either side of each cluster for its nearest neighbour.
RADIUS = 8
#: Every this many iterations the build reads the tallest cluster's height: one taller than
#: ``TALL * MAX_LEVELS`` (a chain of one-by-one merges, which also costs an iteration per
#: merge) ends the clustering, and the radix tree is returned.
HEIGHT_CHECK = 8
TALL = 3
NODE = 1 << 31                   # a cluster or child reference to a node (else a triangle)
MASK = NODE - 1
#: Iterations between two host reads of the cluster count, per backend (a divisor of
#: ``HEIGHT_CHECK``): the CPU backend reads after every iteration, so its arrays shrink
#: each time; the GPU runs several iterations ahead of the host.
READ_EVERY = {"llvm": 1, "cuda": 8}
#: Whether the ``READ_EVERY`` iterations between two reads replay one recording
#: (``_cluster_blocks``) per backend: on the GPU, whose iterations cost the host's tracing
#: and launches more than their kernels (a replay launches without tracing), not on the
#: CPU, whose iterations cost their kernels and whose arrays shrink every iteration
#: (``lab/notes/device-build.md``). The same tree either way (``test_ploc_reference.py``).
FREEZE = {"llvm": False, "cuda": True}
#: With ``FREEZE``: how many blocks of ``READ_EVERY`` iterations run between the first,
#: second, ... host read of the count (the last repeats). Each read waits for the device
#: and narrows the arrays to the count it read; with one read a block (its counts and
#: tallest height together) reading after every block was as fast as any longer schedule
#: on the GPU (``lab/notes/device-build.md``).
READ_BLOCKS = {"llvm": (1,), "cuda": (1,)}
#: Clusters per lane of the neighbour search, per backend (``_nearest_window``: each pair's
#: area computed once, one box gather per cluster), or 0 for one lane per cluster
#: (``_nearest``). The CPU backend's search costs its gathers; the GPU's costs little
#: beside its iteration's launches and wants a lane per cluster.
WINDOW = {"llvm": 64, "cuda": 0}
#: ... for arrays at least this wide (narrower ones have too few lanes of blocks to fill
#: the CPU's threads, and search faster a cluster per lane), and never in a frozen
#: iteration (its replays run at other widths, which the windowed search's lane count, a
#: fraction of the width, does not follow).
WINDOW_MIN = 1 << 15


def _half_area(lo, hi):
    d = [hi[a] - lo[a] for a in range(3)]
    return d[0] * d[1] + d[1] * d[2] + d[2] * d[0]


@dataclass
class Clusters:
    """What the clustering made: the nodes' child references ``ch`` (2 UInt32), boxes
    ``box`` (6 Floats: lo xyz, hi xyz) and triangle counts ``cnt`` (UInt32), numbered in
    merge order; ``batches``: (first node, node count) of each iteration; ``iterations``;
    ``fallback``: True when a cluster grew taller than ``TALL * MAX_LEVELS``."""

    ch: list
    box: list
    cnt: object
    batches: list
    iterations: int
    fallback: bool


def _nearest(m, c_box, k, radius: int):
    """Each cluster's nearest neighbour among the ``radius`` clusters on either side of it
    (one symbolic loop over the distance; see the module docstring for the pair order):
    UInt32 over the ``dr.width(c_box[0])`` lanes, the lane itself where no candidate lies
    in ``[0, k)`` (``k``: UInt32, the clusters' count, lanes past it idle)."""
    Float, UInt32 = m.Float, m.UInt32
    w = dr.width(c_box[0])
    i = dr.arange(UInt32, w)
    active = i < k

    def body(d, best, best_j, best_t):
        for side in (0, 1):
            if side == 0:
                ok = active & (i >= d)
                j = i - d
                a = j
            else:
                ok = i + d < k
                j = i + d
                a = i
            bl = [dr.minimum(c_box[x], dr.gather(Float, c_box[x], j, ok)) for x in range(3)]
            bh = [dr.maximum(c_box[3 + x], dr.gather(Float, c_box[3 + x], j, ok))
                  for x in range(3)]
            area = _half_area(bl, bh)
            # pairs ordered by (area, distance, parity of the lower index, lower index):
            # for one cluster, candidates of equal area and distance differ in the parity
            # (d odd) or else the lower index is the left one's
            tie = (d << 1) | (a & 1)
            better = ok & ((area < best) | ((area == best) & (tie < best_t)))
            best = dr.select(better, area, best)
            best_j = dr.select(better, j, best_j)
            best_t = dr.select(better, tie, best_t)
        return d + 1, best, best_j, best_t

    state = (dr.full(UInt32, 1, w), dr.full(Float, dr.inf, w), UInt32(i),
             dr.full(UInt32, 0xFFFFFFFF, w))
    state = dr.while_loop(state=state, cond=lambda d, *_: d <= radius, body=body,
                          label="ploc_nearest")
    return state[2]


def _nearest_window(m, c_box, k, radius: int, block: int):
    """``_nearest``'s answer (``k``: here a one-lane UInt32), bit for bit, with each pair's
    area computed once: lane ``b`` walks the clusters ``[b * block - radius, (b + 1) *
    block)`` in order, keeping the boxes of the ``radius + 1`` clusters from the current
    one on and their best candidates so far in its loop state. At cluster ``c`` it
    computes the areas of ``(c, c + d)`` for ``d = 1 .. radius`` and offers each to both
    ends; ``c``'s answer is then final (its left candidates came at earlier steps: the
    walk starts ``radius`` clusters early) and is written where ``c`` lies in the lane's
    block. A cluster gets its left candidates before its right ones and keeps a candidate
    only for a strictly lower (area, tie) key, as ``_nearest`` does, so equal keys keep
    the left candidate there too. One box gather per cluster instead of ``12 * radius``:
    for the CPU backend, whose search kernels cost their gathers."""
    Float, UInt32 = m.Float, m.UInt32
    w = dr.width(c_box[0])
    lanes = (w + block - 1) // block
    blk = dr.opaque(UInt32, block)       # one kernel for every block size
    start = dr.arange(UInt32, lanes) * blk
    end = dr.minimum(start + blk, k)
    first = dr.select(start > radius, start - radius, 0)
    out = dr.arange(UInt32, w)
    n = radius + 1

    def box_at(c):
        ok = c < k
        return [dr.gather(Float, c_box[x], c, ok) for x in range(6)]

    # slot s: the cluster first + s; its box (6 Floats) and best (area, index, tie)
    boxes = []
    for s in range(n):
        boxes += box_at(first + s)
    inf = dr.full(Float, dr.inf, lanes)
    bests = []
    for s in range(n):
        bests += [Float(inf), first + s, dr.full(UInt32, 0xFFFFFFFF, lanes)]

    def body(c, *state):
        bx = [list(state[6 * s:6 * s + 6]) for s in range(n)]
        bt = [list(state[6 * n + 3 * s:6 * n + 3 * s + 3]) for s in range(n)]
        for d in range(1, n):
            ok = c + d < k
            lo = [dr.minimum(bx[0][x], bx[d][x]) for x in range(3)]
            hi = [dr.maximum(bx[0][3 + x], bx[d][3 + x]) for x in range(3)]
            area = _half_area(lo, hi)
            tie = UInt32((d << 1)) | (c & 1)          # the lower index is c for both ends
            for s, j in ((0, c + d), (d, c)):
                best, best_j, best_t = bt[s]
                better = ok & ((area < best) | ((area == best) & (tie < best_t)))
                bt[s] = [dr.select(better, area, best), dr.select(better, j, best_j),
                         dr.select(better, tie, best_t)]
        dr.scatter(out, bt[0][1], c, c >= start)
        nxt = c + n
        new_box = box_at(nxt)
        state = []
        for s in range(1, n):
            state += bx[s]
        state += new_box
        for s in range(1, n):
            state += bt[s]
        state += [Float(inf), nxt, dr.full(UInt32, 0xFFFFFFFF, lanes)]
        return (c + 1, *state)

    dr.while_loop(state=(UInt32(first), *boxes, *bests),
                  cond=lambda c, *_: c < end, body=body, label="ploc_nearest_window")
    return out


def _pairs(m, radius: int, c_box, made_d, f_d, block: int = 0, count: bool = True):
    """The first half of a clustering iteration over the clusters with boxes ``c_box`` (6
    Floats), lanes past the count ``f_d - made_d`` idle (``made_d``: the nodes made so
    far, ``f_d``: the triangles, one-lane UInt32 each): each cluster's nearest neighbour
    ``best_j`` and the exclusive prefix sum ``ex`` (UInt64) of the lanes that merge (high
    word: the lower lane of a mutual pair) and that leave (low word: the higher one);
    answers them with the nodes made after the iteration (one lane: the nodes made before
    plus the scan's total, its sum and flag at the last cluster's lane)."""
    UInt32, UInt64 = m.UInt32, m.UInt64
    i = dr.arange(UInt32, dr.width(c_box[0]))
    k = dr.gather(UInt32, f_d, i & 0) - dr.gather(UInt32, made_d, i & 0)
    best_j = (_nearest_window(m, c_box, f_d - made_d, radius, block) if block else
              _nearest(m, c_box, k, radius))
    dr.eval(best_j)
    mutual = dr.gather(UInt32, best_j, best_j) == i
    merge = mutual & (i < best_j)                   # idle lanes: best_j == i
    gone = mutual & (i > best_j)
    flags = (UInt64(dr.select(merge, UInt32(1), 0)) << 32) | UInt64(dr.select(gone,
                                                                             UInt32(1), 0))
    ex = dr.prefix_reduce(dr.ReduceOp.Add, flags, exclusive=True)
    if not count:                           # (``_merge`` counts: one kernel less)
        dr.eval(best_j, ex)
        return best_j, ex, None
    last = f_d - made_d - 1                 # the last cluster's lane: the scan's total
    made_new = made_d + UInt32((dr.gather(UInt64, ex, last) + dr.gather(UInt64, flags, last))
                               >> 32)
    dr.eval(best_j, ex, made_new)
    return best_j, ex, made_new


def _merge(m, c, pair, made_d, f_d, n, t, count: bool = False):
    """The second half of a clustering iteration: the mutual pairs of ``pair`` = (best_j,
    ex) (``_pairs``) among the clusters ``c`` = (references, 6 boxes, counts, heights)
    merge into new nodes, scattered into ``n`` = (2 child references, 6 boxes, counts)
    from node ``made_d`` on, and the clusters that stay (the merged ones at the lower lane
    of their pair) are compacted into ``t`` (arrays like ``c``, at least as wide as the
    clusters left), one kernel for both. ``count``: the same kernel also answers the nodes
    made after the iteration (a one-lane UInt32, written by the last cluster's lane: the
    node number a merge there would take), which ``_pairs(count=False)`` left out; else
    None."""
    Float, UInt32 = m.Float, m.UInt32
    c_ref, c_box, c_cnt, c_h = c
    n_ch, n_box, n_cnt = n
    best_j, ex = pair
    i = dr.arange(UInt32, dr.width(c_ref))
    made_l = dr.gather(UInt32, made_d, i & 0)
    k = dr.gather(UInt32, f_d, i & 0) - made_l
    mutual = dr.gather(UInt32, best_j, best_j) == i
    merge = mutual & (i < best_j)
    gone = mutual & (i > best_j)
    node = made_l + UInt32(ex >> 32)
    o_ref = dr.gather(UInt32, c_ref, best_j, merge)
    o_cnt = dr.gather(UInt32, c_cnt, best_j, merge)
    o_h = dr.gather(UInt32, c_h, best_j, merge)
    u_box = [dr.minimum(c_box[x], dr.gather(Float, c_box[x], best_j, merge)) for x in range(3)]
    u_box += [dr.maximum(c_box[3 + x], dr.gather(Float, c_box[3 + x], best_j, merge))
              for x in range(3)]
    u_cnt = c_cnt + o_cnt
    dr.scatter(n_ch[0], c_ref, node, merge)
    dr.scatter(n_ch[1], o_ref, node, merge)
    dr.scatter(n_cnt, u_cnt, node, merge)
    for x in range(6):
        dr.scatter(n_box[x], u_box[x], node, merge)
    keep = (i < k) & ~gone
    pos = i - UInt32(ex & 0xFFFFFFFF)
    t_ref, t_box, t_cnt, t_h = t
    dr.scatter(t_ref, dr.select(merge, node | NODE, c_ref), pos, keep)
    for x in range(6):
        dr.scatter(t_box[x], dr.select(merge, u_box[x], c_box[x]), pos, keep)
    dr.scatter(t_cnt, dr.select(merge, u_cnt, c_cnt), pos, keep)
    dr.scatter(t_h, dr.select(merge, dr.maximum(c_h, o_h) + 1, c_h), pos, keep)
    made_new = None
    if count:
        made_new = dr.empty(UInt32, 1)      # (the last cluster never merges as the lower)
        dr.scatter(made_new, node, i & 0, i + 1 == k)
    dr.eval(n_ch, n_box, n_cnt, t, made_new)
    return made_new


def _block(m, radius: int, every: int, c, u, n, made_d, f_d):
    """``every`` clustering iterations at one width: each one's ``_pairs`` and ``_merge``
    over the clusters ``c``, compacted into ``u`` (arrays like ``c``), the two swapping
    roles after each iteration. Answers the clusters after the last iteration (``c`` or
    ``u``, written in place), the nodes made after each iteration (one-lane UInt32 each)
    and the tallest cluster's height after the last (one-lane UInt32). Run through
    ``dr.freeze`` (``_BLOCK``): one recording replayed at every width."""
    made = []
    for _ in range(every):
        best_j, ex, _ = _pairs(m, radius, c[1], made_d, f_d, count=False)
        made_new = _merge(m, c, (best_j, ex), made_d, f_d, n, u, count=True)
        c, u = u, c
        made_d = made_new
        made.append(made_new)
    tallest = dr.max(c[3])
    dr.eval(tallest)
    return c, made, tallest


#: (A block whose replay Dr.Jit's dry run rejects for new inputs is recorded again, at the
#: cost of one trace; a process that builds many trees does so several times, which is
#: no fault, so Dr.Jit's warning about it is off.)
_BLOCK = dr.freeze(_block, warn_after=1 << 30)


def _cluster_blocks(m, slo, shi, radius: int, every: int, progress,
                    reads: tuple = (1,)) -> Clusters:
    """``_cluster`` (the same nodes, batches, stats and progress calls) with its
    ``every`` iterations between two host reads replayed as one recording (``_BLOCK``):
    the clusters are compacted within two arrays of one width, which the host narrows to
    the count it read after each read (one gather kernel). ``reads``: how many blocks run
    between the first, second, ... read (the last repeats; ``READ_BLOCKS``): the blocks
    between two reads run at the width of the last one, and one read brings every
    block's counts and tallest height (``_cluster``'s height check after each block whose
    last iteration is a multiple of ``HEIGHT_CHECK``, in order). For the GPU, whose
    iterations cost their kernels' tracing and launches more than their work, and whose
    reads cost a wait each."""
    Float, UInt32 = m.Float, m.UInt32
    F = dr.width(slo[0])
    n_in = F - 1
    n = (tuple(dr.zeros(UInt32, n_in) for _ in range(2)),
         tuple(dr.zeros(Float, n_in) for _ in range(6)), dr.zeros(UInt32, n_in))
    c = (dr.arange(UInt32, F), tuple(dr.gather(Float, x, dr.arange(UInt32, F))
                                     for x in slo + shi),
         dr.full(UInt32, 1, F), dr.zeros(UInt32, F))
    u = (dr.zeros(UInt32, F), tuple(dr.zeros(Float, F) for _ in range(6)),
         dr.zeros(UInt32, F), dr.zeros(UInt32, F))
    made_d = dr.zeros(UInt32, 1)
    dr.eval(c, u, n, made_d)
    f_d = dr.opaque(UInt32, F, 1)
    batches, made, it = [], 0, 0
    bail = TALL * MAX_LEVELS
    log_f = math.log(F)
    r = 0                                              # reads so far
    while True:
        pending = []                                   # (made after each, tallest) a block
        for _ in range(reads[min(r, len(reads) - 1)]):
            out, made_list, tallest = _BLOCK(m, radius, every, c, u, n, made_d, f_d)
            c, u = (out, u) if every % 2 == 0 else (out, c)    # (written in place)
            made_d = made_list[-1]
            pending.append((made_list, tallest))
        host = _read_back([x for ml, h in pending for x in (*ml, h)])
        for b in range(len(pending)):
            for x in host[b * (every + 1):b * (every + 1) + every]:
                it += 1
                now = int(x[0])
                batches.append((made, now - made))
                made = now
                if progress is not None:
                    progress(round(MAX_LEVELS * (1.0 - math.log(max(F - made, 1)) / log_f)))
                if F - made <= 1:
                    return Clusters(n[0], n[1], n[2], batches, it, False)
            if it % HEIGHT_CHECK == 0 and int(host[b * (every + 1) + every][0]) > bail:
                return Clusters(n[0], n[1], n[2], batches, it, True)
        w_next = max(F - made, 1)
        idx = dr.arange(UInt32, w_next)
        flat = [c[0], *c[1], c[2], c[3]]
        narrow = [dr.gather(type(x), x, idx) for x in flat]
        spare = [dr.gather(type(x), x, idx) for x in flat]    # the other array of the pair
        dr.eval(narrow, spare)
        c = (narrow[0], tuple(narrow[1:7]), narrow[7], narrow[8])
        u = (spare[0], tuple(spare[1:7]), spare[7], spare[8])
        r += 1


def _cluster(m, slo, shi, radius: int, progress, backend: str) -> Clusters:
    """Cluster the sorted triangles (boxes ``slo``, ``shi``: 3 Floats each) until one
    cluster is left (see the module docstring). The cluster count lives on the device (the
    nodes made so far, a one-lane array): each iteration compacts the clusters by a prefix
    sum into arrays as wide as the last count read, lanes past the count idle, and the
    host reads the nodes made every ``READ_EVERY[backend]`` iterations (a divisor of
    ``HEIGHT_CHECK``), with the tallest cluster's height every ``HEIGHT_CHECK``.
    ``progress`` as ``build_ploc``'s, called for each iteration at the next read. With
    ``FREEZE[backend]`` the iterations between two reads replay one recording
    (``_cluster_blocks``), ``READ_BLOCKS[backend]`` of them between two reads; else the
    neighbour search takes ``WINDOW[backend]``'s run of clusters per lane (0: one)."""
    every, window = READ_EVERY[backend], WINDOW[backend]
    if FREEZE[backend]:
        return _cluster_blocks(m, slo, shi, radius, every, progress, READ_BLOCKS[backend])
    Float, UInt32 = m.Float, m.UInt32
    F = dr.width(slo[0])
    n_in = F - 1                                          # inner nodes of the full tree
    n_ch = [dr.zeros(UInt32, n_in) for _ in range(2)]    # child references
    n_box = [dr.zeros(Float, n_in) for _ in range(6)]    # node boxes: lo xyz, hi xyz
    n_cnt = dr.zeros(UInt32, n_in)                        # triangles under each node
    c_ref = dr.arange(UInt32, F)                          # the clusters: references,
    c_box = [dr.gather(Float, x, dr.arange(UInt32, F)) for x in slo + shi]   # boxes,
    c_cnt = dr.full(UInt32, 1, F)                         # triangle counts and heights
    c_h = dr.zeros(UInt32, F)
    made_d = dr.zeros(UInt32, 1)                          # nodes made so far (device)
    dr.eval(c_ref, c_box, c_cnt, c_h, made_d, n_ch, n_box, n_cnt)
    batches = []                                          # (first node, node count)
    pending = []                                          # nodes made after each iteration
    w, made, it = F, 0, 0
    bail = TALL * MAX_LEVELS
    log_f = math.log(F)
    f_d = dr.opaque(UInt32, F, 1)
    while True:
        best_j, ex, made_new = _pairs(m, radius, tuple(c_box), made_d, f_d,
                                      window if w >= WINDOW_MIN else 0)
        pending.append(made_new)
        it_next = it + len(pending)
        done = False
        w_next = w
        if it_next % every == 0:
            host = _read_back(pending)
            for x in range(len(pending)):
                it += 1
                now = int(host[x][0])
                batches.append((made, now - made))
                made = now
                kk = F - made
                if progress is not None:
                    progress(round(MAX_LEVELS * (1.0 - math.log(max(kk, 1)) / log_f)))
                if kk <= 1:
                    done = True
                    break
            pending, w_next = [], max(F - made, 1)
        t = (dr.empty(UInt32, w_next), tuple(dr.empty(Float, w_next) for _ in range(6)),
             dr.empty(UInt32, w_next), dr.empty(UInt32, w_next))
        _merge(m, (c_ref, tuple(c_box), c_cnt, c_h), (best_j, ex), made_d, f_d,
               (tuple(n_ch), tuple(n_box), n_cnt), t)
        if done:
            return Clusters(n_ch, n_box, n_cnt, batches, it, False)
        if (it_next % HEIGHT_CHECK == 0 and it_next % every == 0
                and int(dr.max(t[3])[0]) > bail):
            return Clusters(n_ch, n_box, n_cnt, batches, it, True)
        c_ref, c_box, c_cnt, c_h = t[0], list(t[1]), t[2], t[3]
        made_d, w = made_new, w_next


def _positions(m, cl: Clusters):
    """Where each node's triangles start in the triangle order and its depth (UInt32 over
    the nodes; the root, the last node made, at 0), and each sorted triangle's position
    (UInt32 over the triangles): a node's first child starts where the node starts, its
    second after the first's triangles. Each node's offset from its parent's start, and
    its depth, are summed over its ancestors by pointer jumping (every node adds its
    ancestor's sum and jumps to that ancestor's ancestor): ``ceil(log2(iterations)) + 1``
    rounds, since a node lies at most ``iterations - 1`` levels deep."""
    UInt32 = m.UInt32
    n_in = dr.width(cl.cnt)
    root = n_in - 1
    n = dr.arange(UInt32, n_in)
    ch = cl.ch
    is_node = [(r & NODE) != 0 for r in ch]
    left = dr.select(is_node[0], dr.gather(UInt32, cl.cnt, ch[0] & MASK, is_node[0]), 1)
    up = dr.full(UInt32, root, n_in)          # the jump target: the parent, then further
    acc = dr.zeros(UInt32, n_in)              # offset from the jump target's start
    dep = dr.full(UInt32, 1, n_in)            # levels below the jump target
    for s in range(2):
        dr.scatter(up, n, ch[s] & MASK, is_node[s])
    dr.scatter(acc, left, ch[1] & MASK, is_node[1])
    dr.scatter(dep, UInt32(0), dr.opaque(UInt32, root, 1))
    dr.eval(up, acc, dep, left)
    for _ in range(math.ceil(math.log2(max(cl.iterations, 1))) + 1):
        acc, dep, up = (acc + dr.gather(UInt32, acc, up), dep + dr.gather(UInt32, dep, up),
                        dr.gather(UInt32, up, up))
        dr.eval(acc, dep, up)
    t_pos = dr.zeros(UInt32, n_in + 1)
    for s, start in ((0, acc), (1, acc + left)):
        dr.scatter(t_pos, start, ch[s] & MASK, ~is_node[s])
    dr.eval(t_pos)
    return acc, dep, t_pos


def build_ploc(vertices: np.ndarray, faces: np.ndarray, backend: str = "llvm", *,
               leaf_size: int = LEAF_SIZE, radius: int = RADIUS, cuts: bool = True,
               progress=None, stats: dict | None = None) -> BVHArrays:
    """Build a BVH over ``faces`` (int (F, 3)) of ``vertices`` (float (V, 3)) on ``backend``
    ("cuda" or "llvm"; see the module docstring). ``leaf_size``: most triangles per leaf
    (1..16); ``radius``: the nearest-neighbour search radius (1..64); ``cuts``: False builds
    over the whole triangles (no ``presplit`` step: the fastest build, for a first image
    whose one frame gains less than the cuts cost). ``progress``: called
    after each clustering iteration as ``progress(done)``, ``done`` the clusters merged so
    far on the level-wise builders' scale of ``MAX_LEVELS`` (log of the clusters left).
    ``stats``: None, or a dict that gets ``iterations``, ``levels`` (the clustered tree's,
    before any rebuild), ``rebuilt`` (subtrees rebuilt balanced), ``fallback`` (True when
    the radix tree was returned) and ``cut`` (True when the tree holds cut triangles'
    references); a dict it holds under ``"phases"`` gets the seconds of each phase (the
    build then waits for the device at each phase's end; where ``KEEP_BETTER`` builds the
    uncut tree too, both trees' phases are summed).
    A scene of at most ``leaf_size`` triangles gets ``build_bvh``'s single-leaf tree.
    The tree carries its unpadded child boxes too (``BVHArrays.raw``, what
    ``bvh_build.raw_boxes`` computes on the host), so the traversal pads them for its ray
    origins without a host refit. ``build_ploc_device`` leaves the tree on the device."""
    return _build(vertices, faces, backend,
                  _Options(leaf_size, radius, cuts, progress, stats), False)


def build_ploc_device(vertices: np.ndarray, faces: np.ndarray, backend: str = "llvm",
                      **options) -> BVHArrays | DeviceTree:
    """``build_ploc`` (the same keyword ``options``) leaving a tree of whole triangles on
    the device: a ``DeviceTree``, not copied back, its ``build_seconds`` ending when the
    device has it; the ``BVHArrays`` only where the tree holds cut triangles, is the
    radix fallback or a single leaf."""
    return _build(vertices, faces, backend, _Options(**options), True)


@dataclass
class _Options:
    """``build_ploc``'s keyword options."""

    leaf_size: int = LEAF_SIZE
    radius: int = RADIUS
    cuts: bool = True
    progress: object = None
    stats: dict | None = None


def _build(vertices, faces, backend: str, o: _Options, device: bool):
    """``build_ploc`` (``device``: ``build_ploc_device``) with its options ``o``."""
    leaf_size, radius, cuts, progress, stats = o.leaf_size, o.radius, o.cuts, o.progress, o.stats
    if not 1 <= radius <= 64:
        raise ValueError(f"radius: expected 1..64, got {radius}")
    m = _module(backend)
    t_start = time.perf_counter()
    Vn, Fn, small = checked_input(vertices, faces, leaf_size)
    if small is not None:
        return small
    t_phase = [t_start]
    info = stats if stats is not None else {}
    phases = info.get("phases")
    job = _Job(m, Vn, Fn, leaf_size, radius, progress, phases, t_phase)
    lo, hi = triangle_boxes(m, Vn, Fn)
    cut = presplit.split_references(m, Vn, Fn, lo, hi) if cuts else None   # cut, or None
    if phases is not None:
        _phase(phases, "triangle boxes and cuts", t_phase)
    if cut is None:
        tree, refs = _device_tree(job, lo, hi, info), None
    else:
        c_lo, c_hi, refs = cut
        tree = _device_tree(job, c_lo, c_hi, info)
        del c_lo, c_hi
        if isinstance(tree, BVHArrays):                     # the radix tree: nothing cut
            refs = None
        elif presplit.KEEP_BETTER:       # the uncut tree where it costs less (its boxes kept)
            w_info = {}
            whole = _device_tree(job, lo, hi, w_info)
            if _sah_cost(whole) <= _sah_cost(tree):
                tree, refs = whole, None
                info.update(w_info)
    del lo, hi
    info["cut"] = refs is not None
    # ---- the host arrays ---------------------------------------------------------------------
    if device and refs is None and not isinstance(tree, BVHArrays):
        out = DeviceTree(*tree)
        dr.sync_thread()                 # the tree is there: the build's time ends
        out.build_seconds = time.perf_counter() - t_start
        if phases is not None:
            _phase(phases, "host copy", t_phase)
        return out
    arrays = tree if isinstance(tree, BVHArrays) else host_arrays(*tree)
    if refs is not None:                  # reference positions to faces, with their cells
        arrays.cells = (refs.cell_lo[arrays.order], refs.cell_hi[arrays.order])
        arrays.order = refs.face[arrays.order]
    arrays.build_seconds = time.perf_counter() - t_start
    if phases is not None:
        _phase(phases, "host copy", t_phase)
    return arrays


@dataclass
class _Job:
    """What every tree ``build_ploc`` builds shares: the backend module, the host vertices
    and faces, its options, and the phase clock."""

    m: object
    Vn: np.ndarray
    Fn: np.ndarray
    leaf_size: int
    radius: int
    progress: object
    phases: dict | None
    t_phase: list


def _sah_cost(tree) -> float:
    """The SAH cost of a ``_device_tree`` answer, as ``host_arrays`` computes it (one small
    read instead of the whole tree)."""
    if isinstance(tree, BVHArrays):
        return tree.sah_cost
    (s_lo, s_hi), total = tree[4], tree[5]
    lo = np.array([float(x.numpy()[0]) for x in s_lo], np.float32).astype(np.float64)
    hi = np.array([float(x.numpy()[0]) for x in s_hi], np.float32).astype(np.float64)
    dd = hi - lo
    root = float(dd[0] * dd[1] + dd[1] * dd[2] + dd[2] * dd[0])
    return (C_TRAV * root + float(total.numpy()[0])) / root if root > 0 else 0.0


def _device_tree(job: _Job, lo, hi, info: dict):
    """PLOC's tree over the boxes ``lo``/``hi`` (3 ``m.Float`` each: the triangles', or
    their references'), on the device: ``host_arrays``'s arguments, or the radix tree's
    ``BVHArrays`` where the clustering fell back. ``info`` gets ``build_ploc``'s stats."""
    m, Vn, Fn, leaf_size, radius = job.m, job.Vn, job.Fn, job.leaf_size, job.radius
    progress, phases, t_phase = job.progress, job.phases, job.t_phase
    backend = "cuda" if m.__name__.endswith("cuda") else "llvm"
    Float, UInt32 = m.Float, m.UInt32
    F = dr.width(lo[0])

    # ---- 1. Morton codes, sorted -------------------------------------------------------------
    code, s_lo, s_hi = morton_codes(UInt32, lo, hi)
    perm = dr.argsort(code)
    slo = [dr.gather(Float, x, perm) for x in lo]        # triangle boxes in sorted order
    shi = [dr.gather(Float, x, perm) for x in hi]
    dr.eval(perm, slo, shi)
    del code
    if phases is not None:
        _phase(phases, "Morton codes and sort", t_phase)

    # ---- 2. clustering -----------------------------------------------------------------------
    cl = _cluster(m, slo, shi, radius, progress, backend)
    n_ch, n_box, n_cnt, batches = cl.ch, cl.box, cl.cnt, cl.batches
    info["iterations"] = cl.iterations
    if phases is not None:
        _phase(phases, "clustering", t_phase)
    if cl.fallback:
        info["levels"], info["rebuilt"], info["fallback"] = None, 0, True
        return build_device(Vn, Fn, backend, leaf_size=leaf_size, raw=True)

    # ---- 3. triangle order, top down ---------------------------------------------------------
    n_in = F - 1
    n_first, n_depth, t_pos = _positions(m, cl)
    order_d = dr.zeros(UInt32, F)
    dr.scatter(order_d, perm, t_pos)
    kept = n_cnt > leaf_size
    levels = int(dr.max(dr.select(kept, n_depth, 0))[0]) + 1
    info["levels"] = levels
    if phases is not None:
        _phase(phases, "triangle order", t_phase)

    # ---- 4. subtrees too deep for the traversal, rebuilt balanced ---------------------------
    roots = None
    info["rebuilt"] = 0
    if levels > MAX_LEVELS:
        roots, inside = _deep_subtrees(m, batches, n_ch, n_cnt, n_depth, leaf_size,
                                       FREEZE[backend])
        info["rebuilt"] = int(dr.sum(dr.select(roots, UInt32(1), UInt32(0)))[0])
        kept &= ~inside
        if phases is not None:
            _phase(phases, "deep subtrees", t_phase)

    # ---- 5. inner nodes, padded child boxes, SAH cost -----------------------------------------
    new_id = dr.prefix_sum(dr.select(kept, UInt32(1), UInt32(0)), reverse=True)
    dr.eval(new_id)
    last = dr.opaque(UInt32, n_in - 1)
    src = last - dr.compress(dr.gather(m.Bool, kept, last - dr.arange(UInt32, n_in)))
    N = dr.width(src)
    extent = dr.maximum(dr.maximum(s_hi[0] - s_lo[0], s_hi[1] - s_lo[1]), s_hi[2] - s_lo[2])
    # (``pad``: the padding rule's factor and extent, and where the unpadded boxes go)
    rb_rows, rb_first, rb_count, rb_depth = None, None, None, None
    extra = 0
    if roots is not None:
        is_root = dr.gather(m.Bool, roots, src)
        rb_rows = dr.compress(is_root)
        rb_src = dr.gather(UInt32, src, rb_rows)
        rb_first = dr.gather(UInt32, n_first, rb_src)
        rb_count = dr.gather(UInt32, n_cnt, rb_src)
        rb_depth = dr.gather(UInt32, n_depth, rb_src)
        extra = int(dr.sum(rb_count)[0])
    boxes_d = dr.zeros(Float, 12 * (N + extra))
    raw_d = dr.zeros(Float, 12 * (N + extra))
    pad = float(32 * unit_roundoff(False)), extent, raw_d
    refs_d = dr.zeros(UInt32, 2 * (N + extra))
    n = dr.arange(UInt32, N)
    area = dr.zeros(m.Float64, N)
    for s in range(2):
        r = dr.gather(UInt32, n_ch[s], src)
        is_node = (r & NODE) != 0
        idx = r & MASK
        cnt = dr.select(is_node, dr.gather(UInt32, n_cnt, idx, is_node), 1)
        first = dr.select(is_node, dr.gather(UInt32, n_first, idx, is_node),
                          dr.gather(UInt32, t_pos, idx, ~is_node))
        inner = is_node & (cnt > leaf_size)
        ref = dr.select(inner, dr.gather(UInt32, new_id, idx, inner),
                        LEAF_BIT | ((cnt - 1) << COUNT_SHIFT) | first)
        dr.scatter(refs_d, ref, 2 * n + s)
        lo_c = [dr.select(is_node, dr.gather(Float, n_box[a], idx, is_node),
                          dr.gather(Float, slo[a], idx, ~is_node)) for a in range(3)]
        hi_c = [dr.select(is_node, dr.gather(Float, n_box[3 + a], idx, is_node),
                          dr.gather(Float, shi[a], idx, ~is_node)) for a in range(3)]
        half = write_box(m, boxes_d, 12 * n + 6 * s, lo_c, hi_c, pad)
        area += half * dr.select(inner, 1.0, m.Float64(cnt))
    if roots is not None:                 # their rows are rewritten by the rebuild
        area = dr.select(is_root, 0.0, area)
    total = dr.sum(area)
    dr.eval(boxes_d, refs_d, total, order_d, raw_d)
    if roots is not None:
        p_box = [dr.zeros(Float, F) for _ in range(6)]   # triangle boxes in the final order
        for a in range(6):
            dr.scatter(p_box[a], (slo + shi)[a], t_pos)
        dr.eval(p_box)
        N, levels, rb_area = _rebuild(m, (rb_rows, rb_first, rb_count, rb_depth), p_box,
                                      boxes_d, refs_d, N, leaf_size, pad)
        total += rb_area
        boxes_d = dr.gather(Float, boxes_d, dr.arange(UInt32, 12 * N))
        raw_d = dr.gather(Float, raw_d, dr.arange(UInt32, 12 * N))
        refs_d = dr.gather(UInt32, refs_d, dr.arange(UInt32, 2 * N))
        levels = max(levels, int(dr.max(dr.gather(UInt32, n_depth, src))[0]) + 1)
    info["fallback"] = False
    if phases is not None:
        _phase(phases, "inner nodes", t_phase)
    return boxes_d, refs_d, order_d, raw_d, (s_lo, s_hi), total, levels


def _deep_heights(m, c, ok, tree, height, roots, leaf_size):
    """One batch of ``_deep_subtrees``' bottom-up pass over the nodes ``c`` (UInt32; where
    ``ok``) of ``tree`` = (the 2 child references, counts, depths): each node's height
    (inner levels below it, rebuilds done) and whether it is rebuilt, from its children's
    rows (earlier batches), written to ``height`` and ``roots``."""
    UInt32, Bool = m.UInt32, m.Bool
    n_ch, n_cnt, n_depth = tree
    h = []
    for s in range(2):
        r = dr.gather(UInt32, n_ch[s], c, ok)
        idx = r & MASK
        is_node = ok & ((r & NODE) != 0)
        cc = dr.gather(UInt32, n_cnt, idx, is_node)
        inner = is_node & (cc > leaf_size)
        h.append(dr.select(inner, dr.select(dr.gather(Bool, roots, idx, inner),
                                            _levels_needed(cc, leaf_size),
                                            dr.gather(UInt32, height, idx, inner)), 0))
    n = dr.gather(UInt32, n_cnt, c, ok)
    d = dr.gather(UInt32, n_depth, c, ok)
    hc = dr.maximum(h[0], h[1]) + 1
    big = n > leaf_size
    rebuild = big & (d + hc > MAX_LEVELS) & (d + _levels_needed(n, leaf_size) <= MAX_LEVELS)
    # one kernel per batch: it reads the rows of earlier batches (its children) and
    # writes its own
    dr.scatter(height, dr.select(big, hc, 0), c, ok)
    dr.scatter(roots, rebuild, c, ok)


def _deep_batch(m, bounds, k, tree, height, roots, leaf_size):
    """``_deep_heights`` over batch ``k`` (a one-lane UInt32, incremented here) of
    ``bounds`` (each batch's first node and the next batch's, UInt32 pairs), as one
    kernel over all nodes (those outside the batch idle): replayed by ``_DEEP_BATCH``
    with the same inputs for every batch."""
    UInt32 = m.UInt32
    n = dr.arange(UInt32, dr.width(tree[1]))
    lo = dr.gather(UInt32, bounds, 2 * k)
    hi = dr.gather(UInt32, bounds, 2 * k + 1)
    _deep_heights(m, n, (n >= lo) & (n < hi), tree, height, roots, leaf_size)
    dr.eval(height, roots)
    dr.scatter(k, k + 1, UInt32(0))      # after the batch's kernel has read it
    dr.eval(k)


_DEEP_BATCH = dr.freeze(_deep_batch, warn_after=1 << 30)


def _deep_subtrees(m, batches, n_ch, n_cnt, n_depth, leaf_size, freeze: bool = False):
    """The nodes whose subtrees are rebuilt balanced so that no inner node lies deeper than
    ``MAX_LEVELS`` levels: bottom up (first iteration's nodes first), a node whose subtree,
    with the rebuilds below it, still reaches too deep is rebuilt when a balanced tree over
    its triangles fits below its level (else an ancestor is). Answers the Bool arrays
    (over the nodes) ``roots`` (rebuilt nodes) and ``inside`` (nodes below a root, which
    leave the tree). ``freeze`` (``FREEZE``): each batch's kernel runs over all nodes and
    replays one recording (``_DEEP_BATCH``) instead of being traced."""
    UInt32, Bool = m.UInt32, m.Bool
    n_in = dr.width(n_cnt)
    height = dr.zeros(UInt32, n_in)       # inner levels from the node down, rebuilds done
    roots = dr.zeros(Bool, n_in)
    if freeze:
        bounds = UInt32(np.array([[b0, b0 + cnt] for b0, cnt in batches],
                                 np.uint32).ravel())
        k = dr.opaque(UInt32, 0, 1)
        dr.eval(height, roots, bounds)
        for _ in batches:
            _DEEP_BATCH(m, bounds, k, (tuple(n_ch), n_cnt, n_depth), height, roots,
                        leaf_size)
    else:
        for b0, cnt in batches:
            _deep_heights(m, dr.opaque(UInt32, b0) + dr.arange(UInt32, cnt), True,
                          (n_ch, n_cnt, n_depth), height, roots, leaf_size)
            dr.eval(height, roots)
    inside = _below_any(m, n_ch, roots, len(batches))
    roots &= ~inside
    dr.eval(roots)
    return roots, inside


def _below_any(m, n_ch, flag, iterations: int):
    """Bool over the nodes: whether any strict ancestor has ``flag`` (Bool over the
    nodes; the root is the last node), by pointer jumping as ``_positions`` sums: every
    node ORs its jump target's answer in and jumps to that target's target,
    ``ceil(log2(iterations)) + 1`` rounds (a node lies at most ``iterations - 1`` levels
    deep)."""
    UInt32, Bool = m.UInt32, m.Bool
    n_in = dr.width(flag)
    root = dr.opaque(UInt32, n_in - 1, 1)
    n = dr.arange(UInt32, n_in)
    up = dr.full(UInt32, n_in - 1, n_in)          # the parent (the root's: itself)
    for s in range(2):
        dr.scatter(up, n, n_ch[s] & MASK, (n_ch[s] & NODE) != 0)
    dr.eval(up)
    acc = dr.gather(Bool, flag, up) & (n != root)   # the parent's flag (the root: none)
    dr.eval(acc)
    for _ in range(math.ceil(math.log2(max(iterations, 1))) + 1):
        acc, up = acc | dr.gather(Bool, acc, up), dr.gather(UInt32, up, up)
        dr.eval(acc, up)
    return acc


def _rebuild(m, rb, p_box, boxes_d, refs_d, n_next, leaf_size, pad):
    """Rebuild the subtrees ``rb`` = (rows, first, count, depth) (UInt32 each: the root's
    output row, its triangles' first position and count, its depth) balanced, top down one
    level at a time: a node over ``n`` triangles splits at ``n // 2``, its child boxes
    reduced over their triangles' boxes ``p_box`` (6 Floats over positions). Rows and child
    references go to ``boxes_d`` and ``refs_d``, new nodes from row ``n_next`` on. Answers
    the row count, the deepest node's level and the rows' SAH area (Float64, 1 lane)."""
    Float, UInt32 = m.Float, m.UInt32
    row, first, count, depth = rb
    area = dr.zeros(m.Float64, 1)
    level_max = []
    while dr.width(row):
        k = dr.width(row)
        level_max.append(dr.max(depth))
        lane = dr.arange(UInt32, 2 * k)
        node, side = lane >> 1, lane & 1
        n_row = dr.gather(UInt32, row, node)
        n_first = dr.gather(UInt32, first, node)
        n_count = dr.gather(UInt32, count, node)
        half = n_count >> 1
        c_first = dr.select(side == 0, n_first, n_first + half)
        c_count = dr.select(side == 0, half, n_count - half)
        end = c_first + c_count

        def body(j, lo0, lo1, lo2, hi0, hi1, hi2):
            lo = [dr.minimum(x, dr.gather(Float, p_box[a], j)) for a, x in
                  enumerate((lo0, lo1, lo2))]
            hi = [dr.maximum(x, dr.gather(Float, p_box[3 + a], j)) for a, x in
                  enumerate((hi0, hi1, hi2))]
            return (j + 1, *lo, *hi)

        inf = dr.full(Float, dr.inf, 2 * k)
        state = dr.while_loop(state=(UInt32(c_first), inf, inf, inf, -inf, -inf, -inf),
                              cond=lambda j, *_, end=end: j < end, body=body,
                              label="ploc_rebuild_box")
        leaf = c_count <= leaf_size
        half_area = write_box(m, boxes_d, 12 * n_row + 6 * side, list(state[1:4]),
                               list(state[4:7]), pad)
        area += dr.sum(half_area * dr.select(leaf, m.Float64(c_count), 1.0))
        ref = dr.select(leaf, LEAF_BIT | ((c_count - 1) << COUNT_SHIFT) | c_first, 0)
        dr.eval(ref, c_first, c_count, leaf, boxes_d, area, pad[2])
        pend = dr.compress(~leaf)
        w = dr.width(pend)
        if w:
            dr.scatter(ref, dr.opaque(UInt32, n_next) + dr.arange(UInt32, w), pend)
        dr.scatter(refs_d, ref, 2 * n_row + side)
        if not w:
            dr.eval(refs_d)
            break
        row = dr.opaque(UInt32, n_next) + dr.arange(UInt32, w)
        first = dr.gather(UInt32, c_first, pend)
        count = dr.gather(UInt32, c_count, pend)
        depth = dr.gather(UInt32, dr.gather(UInt32, depth, node) + 1, pend)
        n_next += w
        dr.eval(refs_d, row, first, count, depth)
    levels = max(int(x[0]) for x in level_max) + 1
    return n_next, levels, area
