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

The large triangles are found on the device (a compress: one count read) and only they are
copied to the host and cut there (numpy); their references' boxes go back in one upload.
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

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
#: surface area of the reference's box (1: every cut).
GAIN = 0.9
#: Cut pieces of a floor under a small object join that object's clusters and grow them
#: (the bunny on its floor), so ``build_ploc`` also builds the uncut tree when it cut
#: anything and keeps the one of lower SAH cost.
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
    big = np.asarray(big_d.numpy(), np.int64)
    b_lo = np.stack([np.asarray(dr.gather(Float, x, big_d).numpy()) for x in lo], 1)
    b_hi = np.stack([np.asarray(dr.gather(Float, x, big_d).numpy()) for x in hi], 1)
    face, c_lo, c_hi, r_lo, r_hi = cut(Vn, Fn, big, b_lo, b_hi, scene, budget)
    B, R = big.size, F + face.size - big.size
    if R == F:
        return None
    out_lo, out_hi = [], []
    for a in range(3):
        for src, new, out in ((lo, r_lo, out_lo), (hi, r_hi, out_hi)):
            x = dr.gather(Float, src[a], dr.arange(UInt32, R) % F)   # extra slots: any value
            dr.scatter(x, Float(np.ascontiguousarray(new[:B, a])), big_d)
            dr.scatter(x, Float(np.ascontiguousarray(new[B:, a])),
                       dr.arange(UInt32, F, R))
            out.append(x)
    dr.eval(out_lo, out_hi)
    all_face = np.concatenate([np.arange(F, dtype=np.int64), face[B:]])
    cell_lo = np.full((R, 3), -np.inf)
    cell_hi = np.full((R, 3), np.inf)
    cell_lo[big], cell_hi[big] = c_lo[:B], c_hi[:B]
    cell_lo[F:], cell_hi[F:] = c_lo[B:], c_hi[B:]
    return out_lo, out_hi, References(all_face, cell_lo, cell_hi)
