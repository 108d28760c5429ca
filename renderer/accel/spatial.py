"""Spatial splits for the top of the BVH (SBVH, Stich, Friedrich & Dietrich 2009).

Large triangles whose boxes overlap much of a scene (the floors, walls and long beams of
Sponza and Conference) make object splits overlap: a ray then visits both children. Near
the root, where such overlap costs every ray, ``spatial_top`` considers besides the binned
object split a *spatial* split: a plane cuts the node's box, references that straddle it go
to both children, each with its box clipped to its side (a "reference" is a triangle with a
box that may be smaller than the triangle's). Per node it takes whichever of the two SAH
costs is lower, the spatial one only where the object split's children overlap (the SBVH's
``alpha``) and while the budget of extra references lasts. Nodes of at most ``min_refs``
references are handed to the level-wise builder of ``bvh_build`` as they are.

Coverage: a straddling reference's two boxes are its box cut at the plane, so they cover
what it covered; every reference also carries its *cell* (the split planes it was cut by,
``-inf``/``+inf`` elsewhere). The cells of one triangle's references tile space, so boxes
recomputed from other vertices (``bvh_build.refit_boxes``: float64, or grown for the
watertight test) as ``triangle box ∩ cell`` still cover the whole triangle. A hit on a
reference's triangle outside the reference's box is still a hit on the triangle, and the
closest hit lies in some reference's box, so the closest hit and any hit are those of brute
force (duplicates of one triangle tie at the same ``t`` and face index).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: SBVH's alpha: try a spatial split only where the object split's children overlap by more
#: than this fraction of the root's surface area.
ALPHA = 1e-5
SPATIAL_BINS = 32
#: When no node in the top ``PROBE_DEPTH`` levels takes a spatial split that lowers its SAH
#: cost by at least ``PROBE_GAIN`` against the best object split, the scene gets none (a
#: mesh of even-sized triangles, like the bunny): the probe costs a few nodes' binning, and
#: spares such a mesh a longer build for no faster ray (``lab/notes/accel-decisions.md``).
PROBE_DEPTH = 3
PROBE_GAIN = 0.02
#: Nodes of more references choose their split from a strided sample of about this many.
SAMPLE = 4096
OBJECT_BINS = 32


def _half_area(lo, hi):
    d = np.maximum(hi - lo, 0.0)
    return d[..., 0] * d[..., 1] + d[..., 1] * d[..., 2] + d[..., 2] * d[..., 0]


@dataclass
class TopSplit:
    """What ``spatial_top`` hands back.

    face: int64 (R,) the triangle of each reference; lo, hi: float32 (R, 3) reference
    boxes; cell_lo, cell_hi: float64 (R, 3) the cells; nodes: float32 (T, 12) the top inner
    nodes' child boxes (unpadded) and children: int64 (T, 2) their children (a top node's
    index, or ``-1 - b`` for bucket ``b``); buckets: list of int64 reference-index arrays,
    each a subtree for the level-wise builder, with depth[b] its inner-node level."""

    face: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    cell_lo: np.ndarray
    cell_hi: np.ndarray
    nodes: np.ndarray
    children: np.ndarray
    buckets: list
    depth: list


def _sweep_cost(cnt_l, cnt_r, blo, bhi):
    """SAH cost of a split after each bin: bins (B, 3) boxes ``blo``/``bhi`` (empty bins
    +inf/-inf), ``cnt_l[k]`` references left of a split after bin k, ``cnt_r[k]`` right."""
    llo = np.minimum.accumulate(blo, axis=0)[:-1]
    lhi = np.maximum.accumulate(bhi, axis=0)[:-1]
    rlo = np.minimum.accumulate(blo[::-1], axis=0)[::-1][1:]
    rhi = np.maximum.accumulate(bhi[::-1], axis=0)[::-1][1:]
    with np.errstate(invalid="ignore"):
        cost = _half_area(llo, lhi) * cnt_l + _half_area(rlo, rhi) * cnt_r
    cost[(cnt_l == 0) | (cnt_r == 0)] = np.inf
    return cost, (llo, lhi, rlo, rhi)


def _bin_boxes(b, lo, hi, bins: int):
    """The union of the boxes ``lo``/``hi`` (R, 3) in each of ``bins`` bins (``b``: the bin
    of each box): (bins, 3) lo and hi, +inf/-inf in empty bins."""
    blo = np.full((bins, 3), np.inf)
    bhi = np.full((bins, 3), -np.inf)
    for j in range(3):
        np.minimum.at(blo[:, j], b, lo[:, j])
        np.maximum.at(bhi[:, j], b, hi[:, j])
    return blo, bhi


def _object_split(lo, hi):
    """The binned object split (centroids, every axis): ``(cost, rule, overlap)`` with
    ``rule = (axis, cmin, scale, k)`` (``object_left``) and the half-area of the two
    children's overlap; cost inf where no plane separates the centroids."""
    c = lo + hi
    cmin, cmax = c.min(axis=0), c.max(axis=0)
    best = (np.inf, None, 0.0)
    for a in range(3):
        ext = cmax[a] - cmin[a]
        if not ext > 0:
            continue
        scale = OBJECT_BINS / ext
        b = np.clip(((c[:, a] - cmin[a]) * scale).astype(np.int64), 0, OBJECT_BINS - 1)
        cnt = np.bincount(b, minlength=OBJECT_BINS)
        blo, bhi = _bin_boxes(b, lo, hi, OBJECT_BINS)
        nl = np.cumsum(cnt)[:-1]
        cost, (llo, lhi, rlo, rhi) = _sweep_cost(nl, len(lo) - nl, blo, bhi)
        k = int(np.argmin(cost))
        if cost[k] < best[0]:
            olo, ohi = np.maximum(llo[k], rlo[k]), np.minimum(lhi[k], rhi[k])
            best = (float(cost[k]), (a, cmin[a], scale, k), float(_half_area(olo, ohi)))
    return best


def object_left(lo, hi, rule):
    """Which references of boxes ``lo``/``hi`` go to the left child under ``rule``."""
    a, cmin, scale, k = rule
    b = np.clip(((lo[:, a] + hi[:, a] - cmin) * scale).astype(np.int64), 0, OBJECT_BINS - 1)
    return b <= k


def _spatial_split(lo, hi, nlo, nhi):
    """The best spatial split of boxes ``lo``/``hi`` (R, 3) in the node box ``nlo``/``nhi``:
    ``(cost, axis, plane)`` (plane: float32); reference boxes are clipped to each bin's slab
    (tight along the split axis, the box's own extent along the others)."""
    best = (np.inf, -1, 0.0)
    B = SPATIAL_BINS
    for a in range(3):
        ext = float(nhi[a]) - float(nlo[a])
        if not ext > 0:
            continue
        w = ext / B
        b0 = np.clip(((lo[:, a] - nlo[a]) / w).astype(np.int64), 0, B - 1)
        b1 = np.clip(((hi[:, a] - nlo[a]) / w).astype(np.int64), b0, B - 1)
        enter = np.bincount(b0, minlength=B)
        leave = np.bincount(b1, minlength=B)
        span = b1 - b0 + 1
        ref = np.repeat(np.arange(len(lo)), span)
        k = np.arange(span.sum()) - np.repeat(np.cumsum(span) - span, span)
        b = b0[ref] + k
        clo, chi = lo[ref].astype(np.float64), hi[ref].astype(np.float64)
        clo[:, a] = np.maximum(clo[:, a], nlo[a] + b * w)
        chi[:, a] = np.minimum(chi[:, a], nlo[a] + (b + 1) * w)
        blo, bhi = _bin_boxes(b, clo, chi, B)
        nl = np.cumsum(enter)[:-1]
        nr = len(lo) - np.cumsum(leave)[:-1]
        cost, _ = _sweep_cost(nl, nr, blo, bhi)
        k = int(np.argmin(cost))
        if cost[k] < best[0]:
            plane = np.float32(nlo[a] + (k + 1) * w)
            best = (float(cost[k]), a, plane)
    return best


def clipped_boxes(vertices, faces, face, cell_lo, cell_hi, dtype=np.float32):
    """The boxes of triangles ``face`` (R,) of ``vertices``/``faces`` clipped to their
    cells ``cell_lo``/``cell_hi`` (R, 3; infinite where uncut): Sutherland-Hodgman against
    each finite cell plane in float64 (a triangle cut by six planes has at most 9 corners),
    the box of what remains rounded outwards to ``dtype``. Returns ``(lo, hi)`` (R, 3)."""
    V = np.asarray(vertices, np.float64)
    tri = np.asarray(faces, np.int64)[face]
    R = len(face)
    poly = np.zeros((R, 9, 3))
    poly[:, :3] = V[tri]
    n = np.full(R, 3)
    for a in range(3):
        for plane, sign in ((cell_lo[:, a], -1.0), (cell_hi[:, a], 1.0)):
            cut = np.flatnonzero(np.isfinite(plane) & (n > 0))
            if not cut.size:
                continue
            P, m, pl = poly[cut], n[cut], plane[cut]
            out = np.zeros_like(P)
            k = np.zeros(len(cut), np.int64)
            rows = np.arange(len(cut))
            for i in range(9):
                live = i < m
                if not live.any():
                    break
                cur = P[rows, i]
                nxt = P[rows, (i + 1) % np.maximum(m, 1)]
                cin = sign * (cur[:, a] - pl) <= 0
                nin = sign * (nxt[:, a] - pl) <= 0
                keep = live & cin
                out[rows[keep], k[keep]] = cur[keep]
                k += keep
                cross = live & (cin != nin)
                if cross.any():
                    c, x = cur[cross], nxt[cross]
                    tt = (pl[cross] - c[:, a]) / (x[:, a] - c[:, a])
                    q = c + tt[:, None] * (x - c)
                    q[:, a] = pl[cross]
                    out[rows[cross], k[cross]] = q
                    k += cross
            poly[cut], n[cut] = out, k
    valid = np.arange(9)[None, :] < n[:, None]
    lo = np.where(valid[..., None], poly, np.inf).min(axis=1)
    hi = np.where(valid[..., None], poly, -np.inf).max(axis=1)
    # nothing left (a sliver that rounding moved out of the cell, with vertices other than
    # the build's): the triangle's box within the cell, else the triangle's box; never an
    # empty box, whose padding would be NaN
    empty = n == 0
    if empty.any():
        t_lo, t_hi = V[tri[empty]].min(axis=1), V[tri[empty]].max(axis=1)
        c_lo, c_hi = np.maximum(t_lo, cell_lo[empty]), np.minimum(t_hi, cell_hi[empty])
        ok = np.all(c_lo <= c_hi, axis=1, keepdims=True)
        lo[empty], hi[empty] = np.where(ok, c_lo, t_lo), np.where(ok, c_hi, t_hi)
    if np.dtype(dtype) == np.float64:
        return lo, hi
    dt = np.dtype(dtype).type
    lo_d, hi_d = lo.astype(dtype), hi.astype(dtype)
    lo_d = np.where(lo_d > lo, np.nextafter(lo_d, dt(-np.inf)), lo_d)
    hi_d = np.where(hi_d < hi, np.nextafter(hi_d, dt(np.inf)), hi_d)
    return lo_d, hi_d


def _bucket(buckets: list, depth: list, idx, d: int) -> int:
    """Record ``idx`` as a bucket at depth ``d``; its child reference ``-1 - b``."""
    buckets.append(idx)
    depth.append(d)
    return -len(buckets)


def spatial_top(vertices, faces, lo: np.ndarray, hi: np.ndarray, budget: int,
                min_refs: int, max_depth: int) -> TopSplit | None:
    """Split the references of float32 boxes ``lo``/``hi`` (F, 3) (one per triangle of
    ``vertices``/``faces``; a cut reference's boxes are ``clipped_boxes``) from
    the root down, with spatial splits where they pay (module docstring), until nodes hold
    at most ``min_refs`` references or reach ``max_depth`` inner levels; at most ``budget``
    extra references in all. Returns a ``TopSplit``, or None where no node of the top
    ``PROBE_DEPTH`` levels takes a spatial split that gains ``PROBE_GAIN`` of its SAH
    cost."""
    F = len(lo)
    cap = F + max(int(budget), 0)
    FACE = np.zeros(cap, np.int64)
    FACE[:F] = np.arange(F)
    LO, HI = np.zeros((cap, 3), np.float32), np.zeros((cap, 3), np.float32)
    LO[:F], HI[:F] = lo, hi
    CLO, CHI = np.full((cap, 3), -np.inf), np.full((cap, 3), np.inf)
    n_refs = F
    root_area = float(_half_area(lo.min(axis=0).astype(np.float64),
                                 hi.max(axis=0).astype(np.float64)))
    nodes, children, buckets, depth = [], [], [], []
    # work items: (reference indices, parent node, child slot k, depth)
    work = [(np.arange(F, dtype=np.int64), -1, 0, 0)]
    paid = False                  # a spatial split near the root gained PROBE_GAIN
    while work:
        idx, parent, k, d = work.pop()
        if d > PROBE_DEPTH and not paid:
            return None               # no spatial split pays near the root: none at all
        lo_n, hi_n = LO[idx].astype(np.float64), HI[idx].astype(np.float64)
        if len(idx) <= min_refs or d >= max_depth:
            ref = _bucket(buckets, depth, idx, d)
        else:
            nlo, nhi = lo_n.min(axis=0), hi_n.max(axis=0)
            # large nodes choose their split on a strided sample (the partition is exact)
            sm = slice(None, None, max(len(idx) // SAMPLE, 1))
            o_cost, o_rule, overlap = _object_split(lo_n[sm], hi_n[sm])
            s_cost, s_axis, plane = np.inf, -1, 0.0
            if n_refs < cap and overlap > ALPHA * root_area:
                s_cost, s_axis, plane = _spatial_split(lo_n[sm], hi_n[sm], nlo, nhi)
            if not (s_cost < o_cost or (overlap > ALPHA * root_area and o_cost < np.inf)):
                # object splits without overlap from here: the level-wise builder's work
                ref = _bucket(buckets, depth, idx, d)
            elif not (o_cost < np.inf or s_cost < np.inf):
                ref = _bucket(buckets, depth, idx, d)
            else:
                if s_cost < o_cost:
                    paid |= d <= PROBE_DEPTH and s_cost < (1.0 - PROBE_GAIN) * o_cost
                    a = s_axis
                    left = lo_n[:, a] < plane
                    right = hi_n[:, a] > plane
                    left |= ~left & ~right          # a flat reference on the plane
                    both = left & right
                    if n_refs + int(both.sum()) > cap:
                        both[:] = False
                        right = ~left
                    dup = idx[both]
                    if dup.size:                    # the right halves become new refs
                        new = np.arange(n_refs, n_refs + dup.size, dtype=np.int64)
                        FACE[new] = FACE[dup]
                        CLO[new], CHI[new] = CLO[dup], CHI[dup]
                        CLO[new, a] = np.maximum(CLO[new, a], float(plane))
                        CHI[dup, a] = np.minimum(CHI[dup, a], float(plane))  # left halves
                        both_ids = np.concatenate([dup, new])
                        LO[both_ids], HI[both_ids] = clipped_boxes(
                            vertices, faces, FACE[both_ids], CLO[both_ids], CHI[both_ids])
                        n_refs += dup.size
                        right_idx = np.concatenate([idx[right & ~both], new])
                    else:
                        right_idx = idx[right & ~left]
                    left_idx = idx[left]
                else:
                    o_left = object_left(lo_n, hi_n, o_rule)
                    left_idx, right_idx = idx[o_left], idx[~o_left]
                if not (left_idx.size and right_idx.size):
                    ref = _bucket(buckets, depth, idx, d)
                else:
                    node = len(nodes)
                    nodes.append(None)
                    children.append([0, 0])
                    work.append((right_idx, node, 1, d + 1))
                    work.append((left_idx, node, 0, d + 1))
                    ref = node
        if parent >= 0:
            children[parent][k] = ref
    face, LO, HI, CLO, CHI = (x[:n_refs] for x in (FACE, LO, HI, CLO, CHI))
    # the top nodes' child boxes: unions over the references below each child
    box = {}

    def bounds(ref):
        if ref < 0:
            ids = buckets[-1 - ref]
            return LO[ids].min(axis=0), HI[ids].max(axis=0)
        if ref not in box:
            (al, ah), (bl, bh) = bounds(children[ref][0]), bounds(children[ref][1])
            nodes[ref] = np.concatenate([al, ah, bl, bh]).astype(np.float32)
            box[ref] = (np.minimum(al, bl), np.maximum(ah, bh))
        return box[ref]

    for i in range(len(nodes) - 1, -1, -1):      # children before parents
        bounds(i)
    return TopSplit(face, LO, HI, CLO, CHI,
                    np.array(nodes, np.float32).reshape(-1, 12),
                    np.array(children, np.int64).reshape(-1, 2), buckets, depth)
