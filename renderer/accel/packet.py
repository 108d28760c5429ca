"""Ray packets in a lane: ``K`` rays per SIMD lane share one traversal of the binary BVH.

A Dr.Jit LLVM lane gathers every node and triangle word itself: on the CPU those gathers
and the per-node work (loading a box, ordering the children, the stack) are most of a
traversal step (``results/cpu/profile-llvm.md``). Embree traces coherent rays as packets
that load a node once for many rays. This module does the same inside one lane: lane ``j``
holds rays ``jK .. jK + K - 1`` of the batch (neighbours in the batch, so neighbouring
pixels for primary rays), loads each node and triangle once, tests it against its ``K``
rays, and visits a child where any of its still active rays hits its box (Wald et al.
2001's packet traversal, with a shared stack). Each ray keeps its own closest-hit record
and culls boxes by its own nearest hit, and its triangle tests are the accelerator's
own, so every ray gets the same answer as in ``BVH``'s traversal; what a packet costs
over its rays' own traversals is the union of the nodes they visit.
"""
from __future__ import annotations

import drjit as dr

from .base import ClosestHit, Ray
from .bvh import BVH, load_node
from .traverse import (
    DONE,
    STACK_SIZE,
    TIE_BRANCH_BACKENDS,
    Closest,
    box_ray,
    enter_leaf,
    masked_step,
    pop,
    robust_scale,
    safe_inv,
    slab,
)
from .triangle import bind_routine, layout_of, load, triangle_routine


def _fold(t, order, rec: Closest, hit, i, any_hit: bool) -> Closest:
    """``traverse.triangle_step``'s update of ``rec`` by the test result ``hit`` =
    ``(th, u, v, h)`` of triangle ``i`` (no probe)."""
    th, u, v, h = hit
    if any_hit:
        return Closest(rec.t, rec.u, rec.v, rec.prim, rec.order,
                       rec.found | (h & (th < rec.t)))
    h &= th <= rec.t
    nearer = h & (th < rec.t)
    tie = h & rec.found & (th == rec.t)
    if t.backend in TIE_BRANCH_BACKENDS:
        wins = dr.if_stmt(
            (i, rec.prim, tie), tie,
            lambda i, p, tie: tie & (dr.gather(t.UInt32, order, i, tie)
                                     < dr.gather(t.UInt32, order, p, tie)),
            lambda i, p, tie: tie & False)
        accept = nearer | wins
        i_order = rec.order
    else:
        i_order = dr.gather(t.UInt32, order, i, nearer | tie)
        accept = nearer | (tie & (i_order < rec.order))
        i_order = dr.select(accept, i_order, rec.order)
    return Closest(t=dr.select(accept, th, rec.t), u=dr.select(accept, u, rec.u),
                   v=dr.select(accept, v, rec.v), prim=dr.select(accept, i, rec.prim),
                   order=i_order, found=rec.found | accept)


@dr.syntax
def packet_traverse(acc: BVH, ray: Ray, active, any_hit: bool, K: int):
    """Closest hit (``ClosestHit``) or any hit (Bool) of the rays of ``ray`` through
    ``acc`` (a ``BVH``), ``K`` consecutive rays per lane (see the module docstring)."""
    t = acc.types
    routine = triangle_routine(acc.intersection)
    layout = layout_of(routine)
    robust = robust_scale(t)
    nodes, children, order = acc.nodes, acc.children, acc.tris.order
    tri_data = acc.tri_data if acc.tri_trav is None else acc.tri_trav
    n = dr.width(ray.o, ray.d, ray.t_max, active)
    O, D = (v if dr.width(v) == n else v + dr.zeros(t.Array3f, n)
            for v in (t.Array3f(ray.o), t.Array3f(ray.d)))
    TM = t.Float(ray.t_max)
    TM = TM if dr.width(TM) == n else TM + dr.zeros(t.Float, n)
    ACT = t.Bool(active)
    ACT = ACT if dr.width(ACT) == n else ACT & dr.full(t.Bool, True, n)
    m = -(-n // K)
    lane = dr.arange(t.UInt32, m)
    ids, os_, ds, obs, ibs, routines, recs, acts = [], [], [], [], [], [], [], []
    for k in range(K):
        idx = lane * K + k
        ok = idx < n
        o = dr.gather(t.Array3f, O, idx, ok)
        d = dr.gather(t.Array3f, D, idx, ok)
        ob, ib = box_ray(t, o, safe_inv(t, d), acc.reach)
        ids.append(idx)
        os_.append(o)
        ds.append(d)
        obs.append(ob)
        ibs.append(ib)
        routines.append(bind_routine(routine, o, d))
        recs.append(Closest.empty(t, dr.gather(t.Float, TM, idx, ok), m))
        acts.append(dr.gather(t.Bool, ACT, idx, ok) & ok)
    recs, acts = tuple(recs), tuple(acts)
    stack = dr.alloc_local(t.UInt32, STACK_SIZE)
    sp = dr.zeros(t.UInt32, m)
    alive = acts[0]
    for k in range(1, K):
        alive |= acts[k]
    cur = dr.select(alive, dr.zeros(t.UInt32, m), DONE)
    first = dr.zeros(t.UInt32, m)
    end = dr.zeros(t.UInt32, m)

    def node(sp, cur, to_pop, on, recs, acts):
        a_lo, a_hi, b_lo, b_hi, ref_a, ref_b = load_node(t, nodes, children, cur, on)
        hit_a = hit_b = None
        score = dr.zeros(t.Float, m)
        for k in range(K):
            ha, ta = slab(t, obs[k], ibs[k], a_lo, a_hi, recs[k].t, robust)
            hb, tb = slab(t, obs[k], ibs[k], b_lo, b_hi, recs[k].t, robust)
            ha &= acts[k]
            hb &= acts[k]
            hit_a = ha if hit_a is None else hit_a | ha
            hit_b = hb if hit_b is None else hit_b | hb
            score += dr.select(ha & hb, tb - ta, 0.0)
        both = hit_a & hit_b
        b_first = (score > 0) if any_hit else (score < 0)
        near = dr.select(hit_a & ~(hit_b & b_first), ref_a, ref_b)
        far = dr.select(b_first, ref_a, ref_b)
        stack.write(far, sp, both)
        sp = dr.select(both, sp + 1, sp)
        return sp, dr.select(hit_a | hit_b, near, cur), to_pop | ~(hit_a | hit_b)

    def leaf(recs, first, on, acts):
        tri = load(t, tri_data, first, on, layout)
        out = []
        for k in range(K):
            th, u, v, h = routines[k](os_[k], ds[k], *tri)
            out.append(_fold(t, order, recs[k], (th, u, v, h & acts[k]), first, any_hit))
        return tuple(out), first + 1

    while dr.hint(alive, max_iterations=-1, label=f"bvh_packet{K}",
                  exclude=[acc, t, routine, robust, any_hit, K]):
        is_leaf, is_inner, first, end = enter_leaf(cur, first, end)
        sp, cur, to_pop = masked_step(
            t, is_inner,
            lambda sp, cur, to_pop, on, recs=recs, acts=acts: node(sp, cur, to_pop, on, recs,
                                                                   acts),
            (sp, cur, is_leaf | False))
        sp, cur = pop(stack, sp, cur, to_pop)
        recs, first = masked_step(
            t, first < end, lambda recs, first, on, acts=acts: leaf(recs, first, on, acts),
            (recs, first))
        if dr.hint(any_hit, mode="scalar"):
            acts = tuple(acts[k] & ~recs[k].found for k in range(K))
        alive = acts[0]
        for k in range(1, K):
            alive |= acts[k]
        alive &= (first < end) | (cur != DONE)

    return _scatter_results(t, recs, ids, n, any_hit)


def _scatter_results(t, recs, ids, n: int, any_hit: bool):
    """The per-ray records of the lanes in the batch's ray order. The records are evaluated
    together first (one traversal kernel), then gathered: ray ``i`` is ray ``i % K`` of
    lane ``i // K``. (Scattering each ray's record into shared output arrays instead makes
    Dr.Jit evaluate the whole traversal once per scatter into the same array.)"""
    K = len(recs)
    fields = ("found",) if any_hit else ("t", "u", "v", "prim", "found")
    dr.eval(*(getattr(r, f) for r in recs for f in fields))
    i = dr.arange(t.UInt32, n)
    lane, k = i // K, i % K
    out = {}
    for f in fields:
        v = dr.gather(type(getattr(recs[0], f)), getattr(recs[0], f), lane)
        for j in range(1, K):
            v = dr.select(k == j, dr.gather(type(getattr(recs[j], f)), getattr(recs[j], f),
                                            lane, k == j), v)
        out[f] = v
    if any_hit:
        return out["found"]
    return ClosestHit(**out)
