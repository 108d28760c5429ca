"""Large triangles split into references before PLOC's clustering (``ploc.build_ploc``).

A triangle whose box is longer than ``SPLIT_SIZE`` of the scene box's longest side (a floor,
a wall, a long beam) lies in many Morton cells but sorts into one, and every cluster it
joins grows to its size. Such a triangle is cut into *references* (as the host builder's
spatial splits make them, ``renderer.accel.spatial``): a reference is the triangle within
its *cell*, a box bounded by the planes it was cut at (``-inf``/``+inf`` elsewhere), and
its box is the triangle clipped to the cell (``spatial.clipped_boxes``, rounded outwards to
float32). Each round cuts every reference still longer than ``SPLIT_SIZE`` along its
longest axis at the coarsest plane of the Morton grid (the scene box halved along that axis
again and again) that crosses its box, so the pieces line up with the cells the Morton order
groups; longest references first while the budget of ``SPLIT_BUDGET`` extra references per
triangle lasts, at most ``ROUNDS`` rounds.

The cells of one triangle's references tile space, so boxes recomputed from the vertices
(``bvh_build.raw_boxes``) as ``triangle box ∩ cell`` cover the triangle, and the closest hit
over the references is brute force's (duplicates of a triangle tie at the same ``t`` and
face index): the tree carries the cells as ``BVHArrays.cells`` and ``order`` holds a face
once per reference, as the host builder's tree with spatial splits does.

The large triangles are found and cut on the device (``cut_device``, Dr.Jit: the same code
on CUDA and LLVM): each round is a few kernels over the references to cut and three count
reads, the two pieces' boxes clipped from the triangle in one pass of
``clip_boxes_device``, which does ``spatial.clipped_boxes``'s float64 Sutherland-Hodgman in
fixed corner slots, in the same order, so the references, their cells and boxes are bitwise
the numpy ``cut``'s (which stays as the reference the tests compare with). Only the
references' faces and cells come back to the host, for ``BVHArrays.cells``.
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

from ..device import host_array
from .layout import COUNT_SHIFT
from .spatial import clipped_boxes

#: References longer than this fraction of the scene box's longest side are cut.
SPLIT_SIZE = 0.01
#: At most this many extra references per triangle of the scene.
SPLIT_BUDGET = 0.3
#: Fewer large triangles than this fraction of the scene's are left whole: a handful of
#: them is a floor or a backdrop around objects (the bunny's), whose pieces would join the
#: objects' clusters and grow them.
MIN_LARGE = 1e-3
#: At most this many rounds of cuts (each halves the longest references at most once).
ROUNDS = 12
#: A cut is made only where the two pieces' boxes have less than this fraction of the
#: surface area of the reference's box: 1, every cut that shrinks the boxes. (0.9 gives
#: Sponza a slightly lower SAH cost, 61.65 against 61.73, and a slower frame on the GPU,
#: 1.13 against 1.06 times the SAH tree's; ``lab/notes/device-build.md``.)
GAIN = 1.0
#: Cut pieces of a floor under a small object join that object's clusters and grow them
#: (the bunny on its floor), so ``build_ploc`` also builds the uncut tree when it cut
#: anything (over the triangle boxes it already has) and keeps the one of lower SAH cost.
KEEP_BETTER = True
GRID_LEVELS = 2                  # cuts at the planes of the scene box halved and quartered


@dataclass
class References:
    """The references a scene's triangles are cut into: face int64 (R,), each reference's
    triangle; cell_lo, cell_hi float64 (R, 3), its cell; the first F are the scene's
    triangles in their order (cut ones: their first piece), the rest extra pieces."""

    face: np.ndarray
    cell_lo: np.ndarray
    cell_hi: np.ndarray


def _area(lo, hi):
    d = (hi - lo).astype(np.float64)
    return d[:, 0] * d[:, 1] + d[:, 1] * d[:, 2] + d[:, 2] * d[:, 0]


def _planes(lo, hi, axis, s_lo, s_ext):
    """Per reference, the coarsest Morton-grid plane along ``axis`` strictly inside its box
    ``(lo, hi)`` (float64 (n, 3)); NaN where none of ``GRID_LEVELS`` levels has one."""
    rows = np.arange(lo.shape[0])
    a_lo, a_hi = lo[rows, axis], hi[rows, axis]
    base, ext = s_lo[axis], s_ext[axis]
    plane = np.full(lo.shape[0], np.nan)
    for level in range(1, GRID_LEVELS + 1):
        w = ext / float(1 << level)
        p = base + np.floor((a_hi - base) / w) * w
        p = np.where(p >= a_hi, p - w, p)
        ok = np.isnan(plane) & (p > a_lo) & (p < a_hi)
        plane = np.where(ok, p, plane)
        if not np.isnan(plane).any():
            break
    return plane


def cut(Vn, Fn, big, lo, hi, scene, budget: int):
    """Cut the triangles ``big`` (int64 (B,)) of ``Vn``/``Fn`` with boxes ``lo``/``hi``
    (float32 (B, 3)) in the scene box ``scene`` = (s_lo, s_hi) (float64 (3,) each) into
    references (see the module docstring), at most ``budget`` extra ones. Answers ``(face,
    cell_lo, cell_hi, lo, hi)`` over the references, the first B the triangles' first
    pieces in ``big``'s order."""
    s_lo, s_hi = scene
    s_ext = s_hi - s_lo
    limit = SPLIT_SIZE * float(s_ext.max())
    face = big.astype(np.int64)
    c_lo = np.full((face.size, 3), -np.inf)
    c_hi = np.full((face.size, 3), np.inf)
    lo, hi = lo.astype(np.float32), hi.astype(np.float32)
    done = np.zeros(face.size, bool)      # references whose cut would not pay
    for _ in range(ROUNDS):
        size = (hi - lo).astype(np.float64)
        longest = size.max(axis=1)
        todo = np.flatnonzero((longest > limit) & ~done)
        if not todo.size or budget <= 0:
            break
        todo = todo[np.argsort(-longest[todo], kind="stable")][:budget]
        axis = np.argmax(size[todo], axis=1)
        plane = _planes(lo[todo].astype(np.float64), hi[todo].astype(np.float64), axis,
                        s_lo, s_ext)
        keep = ~np.isnan(plane)
        todo, axis, plane = todo[keep], axis[keep], plane[keep]
        if not todo.size:
            break
        rows = np.arange(todo.size)
        l_hi, r_lo = c_hi[todo].copy(), c_lo[todo].copy()
        l_hi[rows, axis] = plane
        r_lo[rows, axis] = plane
        l_lo, r_hi = c_lo[todo], c_hi[todo]
        f2 = np.concatenate([face[todo], face[todo]])
        b_lo, b_hi = clipped_boxes(Vn, Fn, f2, np.concatenate([l_lo, r_lo]),
                                   np.concatenate([l_hi, r_hi]), np.float32)
        n = todo.size
        area = _area(np.concatenate([b_lo[:n], b_lo[n:]], 1).reshape(2 * n, 3),
                     np.concatenate([b_hi[:n], b_hi[n:]], 1).reshape(2 * n, 3))
        area = area.reshape(n, 2).sum(1)
        pays = area < GAIN * _area(lo[todo], hi[todo])
        done[todo[~pays]] = True
        sel = np.concatenate([pays, pays])
        todo, l_hi, b_lo, b_hi = todo[pays], l_hi[pays], b_lo[sel], b_hi[sel]
        r_lo, r_hi = r_lo[pays], r_hi[pays]
        n = todo.size
        if not n:
            continue
        c_hi[todo], lo[todo], hi[todo] = l_hi, b_lo[:n], b_hi[:n]
        face = np.concatenate([face, face[todo]])
        done = np.concatenate([done, np.zeros(n, bool)])
        c_lo = np.concatenate([c_lo, r_lo])
        c_hi = np.concatenate([c_hi, r_hi])
        lo = np.concatenate([lo, b_lo[n:]])
        hi = np.concatenate([hi, b_hi[n:]])
        budget -= n
    return face, c_lo, c_hi, lo, hi



# ---- the same cut on the device ---------------------------------------------------------
MAX_CORNERS = 9                  # a triangle clipped by six planes has at most 9 corners


def _unfused(m, x):
    """``x`` (a float64 product) through a select on an opaque true mask, so that the sum
    it feeds keeps two roundings: on CUDA, ptxas may fuse an ``add.f64`` with the
    ``mul.f64`` feeding it into an FMA (Dr.Jit emits neither with ``.rn``), which numpy's
    ``a + b * c`` does not; it cannot fuse across the ``selp``."""
    return dr.select(dr.opaque(m.Bool, True), x, 0.0)


def _next_down(m, x):
    """The float32 just below ``x`` (``m.Float``), as ``np.nextafter(x, -inf)``."""
    UInt32 = m.UInt32
    b = dr.reinterpret_array(UInt32, x)
    neg = (b & 0x80000000) != 0
    zero = (b & 0x7FFFFFFF) == 0
    b = dr.select(zero, UInt32(0x80000001), dr.select(neg, b + 1, b - 1))
    return dr.reinterpret_array(m.Float, b)


def _next_up(m, x):
    """The float32 just above ``x`` (``m.Float``), as ``np.nextafter(x, inf)``."""
    return -_next_down(m, -x)


def _put(out, k, val, mask, bound):
    """``out[k] = val`` where ``mask`` (corner slots: lists of 3 arrays; ``k`` < ``bound``)."""
    for j in range(min(MAX_CORNERS, bound)):
        w = mask & (k == j)
        out[j] = [dr.select(w, val[c], out[j][c]) for c in range(3)]


def _clip_plane(m, poly, n, plane, side):
    """One Sutherland-Hodgman pass of ``clip_boxes_device``: the polygons ``poly`` (corner
    slots) of ``n`` corners clipped against ``plane`` (where finite) on the side
    ``(axis, sign)`` (opaque ``m.UInt32`` and ``m.Float64``) ``sign * (x - plane) <= 0``."""
    F64, UInt32 = m.Float64, m.UInt32
    ax, sign = side

    def along(p):
        return dr.select(ax == 0, p[0], dr.select(ax == 1, p[1], p[2]))

    on = dr.isfinite(plane) & (n > 0)
    out = [[F64(0.0)] * 3 for _ in range(MAX_CORNERS)]
    k = dr.zeros(UInt32, dr.width(n))
    for i in range(MAX_CORNERS):
        live = on & (n > i)
        cur = poly[i]
        if i + 1 < MAX_CORNERS:
            nxt = [dr.select(n > i + 1, poly[i + 1][c], poly[0][c]) for c in range(3)]
        else:
            nxt = poly[0]
        c_a, x_a = along(cur), along(nxt)
        cin = sign * (c_a - plane) <= 0
        nin = sign * (x_a - plane) <= 0
        keep = live & cin
        _put(out, k, cur, keep, 2 * i + 1)
        k += dr.select(keep, UInt32(1), UInt32(0))
        cross = live & (cin != nin)
        tt = (plane - c_a) / (x_a - c_a)
        q = [dr.select(ax == c, plane, cur[c] + _unfused(m, tt * (nxt[c] - cur[c])))
             for c in range(3)]
        _put(out, k, q, cross, 2 * i + 2)
        k += dr.select(cross, UInt32(1), UInt32(0))
    poly = [[dr.select(on, out[j][c], poly[j][c]) for c in range(3)]
            for j in range(MAX_CORNERS)]
    return poly, dr.select(on, k, n)


def clip_boxes_device(m, tri, c_lo, c_hi):
    """``spatial.clipped_boxes`` on the device, the same float64 operations in the same
    order: the triangles ``tri`` (3 corners of 3 ``m.Float64`` each) clipped to the cells
    ``c_lo``/``c_hi`` (3 ``m.Float64`` each, infinite where uncut) by Sutherland-Hodgman in
    ``MAX_CORNERS`` fixed corner slots, the box of what remains rounded outwards to float32.
    Answers ``(lo, hi)``, 3 ``m.Float`` each."""
    F64, UInt32 = m.Float64, m.UInt32
    w = dr.width(c_lo[0])
    # every pass's inputs evaluated (no literal or gather folded into the first), so the
    # passes of every round are one kernel
    poly = [list(c) for c in tri] + [[dr.zeros(F64, w) for _ in range(3)]
                                     for _ in range(MAX_CORNERS - 3)]
    n = dr.full(UInt32, 3, w)
    dr.make_opaque(poly, n, c_lo, c_hi)
    for a in range(3):
        for plane, sign in ((c_lo[a], -1.0), (c_hi[a], 1.0)):
            # the axis and side are opaque: the six passes are one kernel, compiled once
            poly, n = _clip_plane(m, poly, n, plane, (dr.opaque(UInt32, a),
                                                     dr.opaque(F64, sign)))
            dr.eval(poly, n)
    lo64, hi64 = [], []
    for c in range(3):
        lo_c, hi_c = F64(np.inf), F64(-np.inf)
        for j in range(MAX_CORNERS):
            ok = n > j
            lo_c = dr.minimum(lo_c, dr.select(ok, poly[j][c], np.inf))
            hi_c = dr.maximum(hi_c, dr.select(ok, poly[j][c], -np.inf))
        lo64.append(lo_c)
        hi64.append(hi_c)
    # nothing left (a sliver rounding moved out of its cell): the triangle's box within
    # the cell, else the triangle's box
    empty = n == 0
    t_lo = [dr.minimum(dr.minimum(tri[0][c], tri[1][c]), tri[2][c]) for c in range(3)]
    t_hi = [dr.maximum(dr.maximum(tri[0][c], tri[1][c]), tri[2][c]) for c in range(3)]
    e_lo = [dr.maximum(t_lo[c], c_lo[c]) for c in range(3)]
    e_hi = [dr.minimum(t_hi[c], c_hi[c]) for c in range(3)]
    inside = (e_lo[0] <= e_hi[0]) & (e_lo[1] <= e_hi[1]) & (e_lo[2] <= e_hi[2])
    lo, hi = [], []
    for c in range(3):
        l64 = dr.select(empty, dr.select(inside, e_lo[c], t_lo[c]), lo64[c])
        h64 = dr.select(empty, dr.select(inside, e_hi[c], t_hi[c]), hi64[c])
        l32, h32 = m.Float(l64), m.Float(h64)
        lo.append(dr.select(F64(l32) > l64, _next_down(m, l32), l32))
        hi.append(dr.select(F64(h32) < h64, _next_up(m, h32), h32))
    return lo, hi


def _area_device(m, lo, hi):
    d = [m.Float64(hi[a] - lo[a]) for a in range(3)]
    u = [_unfused(m, d[0] * d[1]), _unfused(m, d[1] * d[2]), _unfused(m, d[2] * d[0])]
    return u[0] + u[1] + u[2]


def _grow(m, arrays, new):
    """Each of ``arrays`` (device arrays) followed by the matching one of ``new``."""
    out = []
    for x, y in zip(arrays, new):
        R, n = dr.width(x), dr.width(y)
        z = dr.zeros(type(x), R + n)
        dr.scatter(z, x, dr.arange(m.UInt32, R))
        dr.scatter(z, y, dr.arange(m.UInt32, R, R + n))
        out.append(z)
    return out


def cut_device(m, geom, big, lo, hi, scene, budget: int):
    """``cut`` on the device, bitwise the same references in the same order: ``geom`` =
    ``(v_flat, f_flat)`` the vertices (``m.Float``, 3 per vertex) and faces (``m.UInt32``,
    3 per face) on the device, ``big`` (``m.UInt32`` (B,)) the faces cut, ``lo``/``hi`` their
    boxes (3 ``m.Float`` each), ``scene`` = (s_lo, s_hi) float64 (3,) each. Answers
    ``(face, cell_lo, cell_hi, lo, hi)`` on the device (``m.UInt32``; 3 ``m.Float64``;
    3 ``m.Float64``; 3 ``m.Float``; 3 ``m.Float``), the first B the triangles' first pieces.
    Each round reads three counts (the references to cut, those with a plane, those whose
    cut pays)."""
    F64, UInt32, Float = m.Float64, m.UInt32, m.Float
    v_flat, f_flat = geom
    s_lo, s_hi = scene
    s_ext = s_hi - s_lo
    limit = SPLIT_SIZE * float(s_ext.max())
    B = dr.width(big)
    face = UInt32(big)
    c_lo = [dr.full(F64, -np.inf, B) for _ in range(3)]
    c_hi = [dr.full(F64, np.inf, B) for _ in range(3)]
    lo, hi = list(lo), list(hi)
    done = dr.zeros(m.Bool, B)
    for _ in range(ROUNDS):
        size = [F64(hi[a] - lo[a]) for a in range(3)]
        longest = dr.maximum(dr.maximum(size[0], size[1]), size[2])
        todo = dr.compress((longest > limit) & ~done)
        if not dr.width(todo) or budget <= 0:
            break
        # longest first (a stable sort: ties keep their order), within the budget
        key = 0xFFFFFFFF - dr.reinterpret_array(UInt32, Float(dr.gather(F64, longest, todo)))
        todo = dr.gather(UInt32, todo, dr.argsort(key))
        if dr.width(todo) > budget:
            todo = dr.gather(UInt32, todo, dr.arange(UInt32, budget))
        sz = [dr.gather(F64, size[a], todo) for a in range(3)]
        axis = dr.select((sz[0] >= sz[1]) & (sz[0] >= sz[2]), UInt32(0),
                         dr.select(sz[1] >= sz[2], UInt32(1), UInt32(2)))
        a_lo = F64(0.0)
        a_hi = F64(0.0)
        base = F64(0.0)
        ext = F64(0.0)
        for a in range(3):
            on = axis == a
            a_lo = dr.select(on, F64(dr.gather(Float, lo[a], todo)), a_lo)
            a_hi = dr.select(on, F64(dr.gather(Float, hi[a], todo)), a_hi)
            base = dr.select(on, float(s_lo[a]), base)
            ext = dr.select(on, float(s_ext[a]), ext)
        plane = dr.full(F64, np.nan, dr.width(todo))
        for level in range(1, GRID_LEVELS + 1):
            w = ext / float(1 << level)
            p = base + _unfused(m, dr.floor((a_hi - base) / w) * w)
            p = dr.select(p >= a_hi, p - w, p)
            ok = dr.isnan(plane) & (p > a_lo) & (p < a_hi)
            plane = dr.select(ok, p, plane)
        has = dr.compress(~dr.isnan(plane))
        if not dr.width(has):
            break
        todo, axis, plane = (dr.gather(UInt32, todo, has), dr.gather(UInt32, axis, has),
                             dr.gather(F64, plane, has))
        n = dr.width(todo)
        # both pieces in one pass: lanes [0, n) the left ones, [n, 2n) the right ones
        j = dr.arange(UInt32, 2 * n)
        row = j % n
        right = j >= n
        t2, ax2, pl2 = (dr.gather(UInt32, todo, row), dr.gather(UInt32, axis, row),
                        dr.gather(F64, plane, row))
        p_lo = [dr.gather(F64, c_lo[a], t2) for a in range(3)]
        p_hi = [dr.gather(F64, c_hi[a], t2) for a in range(3)]
        p_lo = [dr.select(right & (ax2 == a), pl2, p_lo[a]) for a in range(3)]
        p_hi = [dr.select(~right & (ax2 == a), pl2, p_hi[a]) for a in range(3)]
        fid = dr.gather(UInt32, face, t2)
        tri = [[F64(dr.gather(Float, v_flat, 3 * dr.gather(UInt32, f_flat, 3 * fid + k) + c))
                for c in range(3)] for k in range(3)]
        b_lo, b_hi = clip_boxes_device(m, tri, p_lo, p_hi)
        area2 = _area_device(m, b_lo, b_hi)
        area = dr.gather(F64, area2, dr.arange(UInt32, n)) + \
            dr.gather(F64, area2, dr.arange(UInt32, n, 2 * n))
        own = _area_device(m, [dr.gather(Float, lo[a], todo) for a in range(3)],
                           [dr.gather(Float, hi[a], todo) for a in range(3)])
        pays = area < GAIN * own
        dr.scatter(done, True, todo, ~pays)
        keep = dr.compress(pays)
        n = dr.width(keep)
        if not n:
            dr.eval(done)
            continue
        left, rgt = keep, keep + dr.width(todo)
        dst = dr.gather(UInt32, todo, keep)
        for a in range(3):
            dr.scatter(c_hi[a], dr.gather(F64, p_hi[a], left), dst)
            dr.scatter(lo[a], dr.gather(Float, b_lo[a], left), dst)
            dr.scatter(hi[a], dr.gather(Float, b_hi[a], left), dst)
        new = ([dr.gather(UInt32, face, dst), dr.zeros(m.Bool, n)]
               + [dr.gather(F64, p_lo[a], rgt) for a in range(3)]
               + [dr.gather(F64, p_hi[a], rgt) for a in range(3)]
               + [dr.gather(Float, b_lo[a], rgt) for a in range(3)]
               + [dr.gather(Float, b_hi[a], rgt) for a in range(3)])
        grown = _grow(m, [face, done] + c_lo + c_hi + lo + hi, new)
        face, done = grown[0], grown[1]
        c_lo, c_hi, lo, hi = grown[2:5], grown[5:8], grown[8:11], grown[11:14]
        dr.eval(face, done, c_lo, c_hi, lo, hi)
        budget -= n
    return face, c_lo, c_hi, lo, hi


def split_references(m, Vn, Fn, lo, hi):
    """PLOC's references (see the module docstring) of the faces ``Fn`` of ``Vn`` with
    triangle boxes ``lo``/``hi`` (3 ``m.Float`` each, on the device). Answers None when no
    triangle is cut, else ``(lo, hi, refs)``: the references' boxes (3 ``m.Float`` each,
    the F triangles' slots first, then the extra pieces) and their ``References``."""
    Float, UInt32 = m.Float, m.UInt32
    F = dr.width(lo[0])
    budget = min(int(SPLIT_BUDGET * F), (1 << COUNT_SHIFT) - 1 - F)   # references' bound
    if budget <= 0 or SPLIT_SIZE <= 0:
        return None
    s_lo = [dr.min(x) for x in lo]
    s_hi = [dr.max(x) for x in hi]
    size = dr.maximum(dr.maximum(hi[0] - lo[0], hi[1] - lo[1]), hi[2] - lo[2])
    ext = dr.maximum(dr.maximum(s_hi[0] - s_lo[0], s_hi[1] - s_lo[1]), s_hi[2] - s_lo[2])
    big_d = dr.compress(size > ext * SPLIT_SIZE)
    if not dr.width(big_d) or dr.width(big_d) < MIN_LARGE * F:
        return None
    scene = (np.array([float(x.numpy()[0]) for x in s_lo]),
             np.array([float(x.numpy()[0]) for x in s_hi]))
    b_lo = [dr.gather(Float, x, big_d) for x in lo]
    b_hi = [dr.gather(Float, x, big_d) for x in hi]
    face, c_lo, c_hi, r_lo, r_hi = cut_device(m, _geometry(m, Vn, Fn), big_d, b_lo, b_hi,
                                              scene, budget)
    B = dr.width(big_d)
    R = F + dr.width(face) - B
    if R == F:
        return None
    first, extra = dr.arange(UInt32, B), dr.arange(UInt32, B, R - F + B)
    out_lo, out_hi = [], []
    for a in range(3):
        for src, new, out in ((lo, r_lo, out_lo), (hi, r_hi, out_hi)):
            x = dr.gather(Float, src[a], dr.arange(UInt32, R) % F)   # extra slots: any value
            dr.scatter(x, dr.gather(Float, new[a], first), big_d)
            dr.scatter(x, dr.gather(Float, new[a], extra), dr.arange(UInt32, F, R))
            out.append(x)
    dr.eval(out_lo, out_hi)
    big = np.asarray(big_d.numpy(), np.int64)
    face = np.asarray(face.numpy(), np.int64)
    c_lo = np.stack([np.asarray(x.numpy()) for x in c_lo], 1)
    c_hi = np.stack([np.asarray(x.numpy()) for x in c_hi], 1)
    all_face = np.concatenate([np.arange(F, dtype=np.int64), face[B:]])
    cell_lo = np.full((R, 3), -np.inf)
    cell_hi = np.full((R, 3), np.inf)
    cell_lo[big], cell_hi[big] = c_lo[:B], c_hi[:B]
    cell_lo[F:], cell_hi[F:] = c_lo[B:], c_hi[B:]
    return out_lo, out_hi, References(all_face, cell_lo, cell_hi)


def _geometry(m, Vn, Fn):
    """The vertices (``m.Float``, 3 per vertex) and faces (``m.UInt32``, 3 per face) on the
    device, uploaded as ``device_build.triangle_boxes`` uploads them."""
    f_h = np.ascontiguousarray(Fn).reshape(-1)
    if m.__name__.endswith("cuda"):
        return (m.Float(Vn.reshape(-1)),
                m.UInt32(f_h.view(np.uint32) if f_h.dtype in (np.int32, np.uint32) else
                         f_h.astype(np.uint32)))
    return m.Float(host_array(Vn.reshape(-1))), m.UInt32(host_array(f_h, np.uint32))
