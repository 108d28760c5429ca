"""Traversal steps shared by every accelerator and backend.

A traversal is one symbolic loop per query whose body is made of these steps: the ray
set-up (``setup``, which builds the ``TraversalRay`` record), the slab test of a box
(``slab``), the triangle step that folds one candidate triangle into the closest-hit record
(``triangle_step``), the leaf entry (``enter_leaf``) and the node stack (``Stack``). Where a
backend needs different code for the same step (the slab test's min/max on the CPU, the
gathers), the branch is inside the step.

Node references and the stack bound are those of ``renderer.accel.layout``; the query
records (``Ray``, ``ClosestHit``, ``Closest``, ``Probe``) and the tie probe are
``renderer.accel.query``'s, re-exported here.
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr

from ..device import Types, syntax
from .layout import COUNT_SHIFT as COUNT_SHIFT
from .layout import DONE, FIRST_MASK, LEAF_BIT, STACK_SIZE
from .layout import MAX_LEAF as MAX_LEAF
from .query import TIE_BREAKS as TIE_BREAKS
from .query import Closest, ClosestHit, Probe, Ray
from .query import tie_probe as tie_probe
from .query import tie_probe_p as tie_probe_p
from .triangle import layout_of, load, unit_roundoff


@dataclass
class TraversalRay:
    """The rays as a traversal loop reads them (``setup``), every array of the batch width.

    o, d: Array3f origin and direction; inv: ``safe_inv(d)``; box_o, box_inv: the ray as
    the slab test reads it (``box_ray``; None for a traversal without boxes); t_max: the
    end of the ray interval, as the query gave it; robust: ``robust_scale`` (float), the
    slab test's growth of ``t_far``."""

    o: object
    d: object
    inv: object
    box_o: object
    box_inv: object
    t_max: object
    robust: float


@dataclass
class Stack:
    """A traversal's node stack: ``data`` the ``dr.alloc_local`` UInt32 buffer of
    ``STACK_SIZE`` entries (allocated before the loop, carried in its state), ``sp`` the
    depth (UInt32) and ``cur`` the node being visited (UInt32 node reference, ``DONE`` when
    the traversal is over). ``push`` and ``pop`` update the record in place, as the loop
    and ``dr.if_stmt`` state it travels in expect."""

    data: object
    sp: object
    cur: object

    @classmethod
    def start(cls, t: Types, active, n: int) -> "Stack":
        """An empty stack at the root (node 0) where ``active``, else ``DONE``."""
        return cls(data=dr.alloc_local(t.UInt32, STACK_SIZE), sp=dr.zeros(t.UInt32, n),
                   cur=dr.select(active, dr.zeros(t.UInt32, n), DONE))

    def push(self, ref, where) -> None:
        """Push node reference ``ref`` where ``where``."""
        self.data.write(ref, self.sp, where)
        self.sp = dr.select(where, self.sp + 1, self.sp)

    def pop(self, where) -> None:
        """Where ``where``: the next node is the top of the stack, or DONE when it is
        empty."""
        can_pop = where & (self.sp > 0)
        self.sp = dr.select(can_pop, self.sp - 1, self.sp)
        popped = self.data.read(self.sp, can_pop)
        self.cur = dr.select(where, dr.select(can_pop, popped, DONE), self.cur)


@dataclass
class LeafTriangles:
    """What a triangle step reads: ``t`` the types, ``routine`` the triangle routine (bound
    to the loop's rays by ``triangle.bind_routine`` where the lanes keep their rays),
    ``data`` the packed triangles as the traversal reads them, ``order`` the original face
    index of each (UInt32, the tie-break). Excluded from loop state (it holds ``Types``)."""

    t: Types
    routine: object
    data: object
    order: object


def robust_scale(t: Types) -> float:
    """``1 + 2 gamma(3)`` of the precision in use (pbrt): the slab test's growth of t_far."""
    eps = unit_roundoff(t.is_double)
    gamma3 = 3 * eps / (1 - 3 * eps)
    return 1.0 + 2.0 * gamma3


def safe_inv(t: Types, d):
    """1/d per component, clamped to a huge finite value so that ``(lo - o) * inv`` is never
    0 * inf = NaN for axis-parallel rays (a zero component then means "the slab never ends")."""
    big = 2.0 ** 900 if t.is_double else 2.0 ** 100
    return dr.clip(1.0 / d, -big, big)


def setup(t: Types, ray: Ray, active, reach: float | None = None):
    """The ray as a traversal loop reads it: ``(TraversalRay, active, n)``, every array of
    the batch width ``n``; ``reach``: the accelerator's (``box_ray``), None for a
    traversal without boxes."""
    n = dr.width(ray.o, ray.d, ray.t_max, active)
    o, d = t.Array3f(ray.o), t.Array3f(ray.d)
    inv = safe_inv(t, d)
    box_o, box_inv = (None, None) if reach is None else box_ray(t, o, inv, reach)
    return (TraversalRay(o=o, d=d, inv=inv, box_o=box_o, box_inv=box_inv, t_max=ray.t_max,
                         robust=robust_scale(t)),
            t.Bool(active) & dr.full(t.Bool, True, n), n)


def box_ray(t: Types, o, inv, reach: float):
    """The ray(s) ``(o, inv)`` as ``slab`` reads them, for boxes padded for origins of
    coordinates up to ``reach`` in magnitude (the accelerator's ``reach``,
    ``triangle.pad_extent``): ``(-(o * inv), inv)``, so that the slab test is one FMA per
    plane, ``lo * inv - o * inv``, with ``o * inv`` computed once per ray.

    The boxes are padded (``bvh_build.pad_boxes``: 32 ``u`` (coordinate + reach), ``u`` the
    unit roundoff) so that a triangle's computed hit lies inside them although the triangle
    test rounds in proportion to ``|p - o|``. The FMA form rounds ``o * inv`` once, which
    moves each slab plane by up to ``u |o_a|`` in world units: a 32nd of that padding where
    ``|o_a| <= reach``, which the triangle test leaves room for. From farther away the
    padding covers neither the FMA form nor ``(lo - o) * inv``; such rays get ``(0, 0)``,
    for which every slab value is 0, so they enter every box with ``t_near = 0``: brute
    force's hits at brute force's cost, and no extra work per box for the others. A
    render's rays start at cameras, lights and surfaces, which lie within the reach
    (``triangle.box_reach``)."""
    mag = dr.maximum(dr.maximum(dr.abs(o.x), dr.abs(o.y)), dr.abs(o.z))
    far = ~(mag <= reach)
    return dr.select(far, 0.0, -(o * inv)), dr.select(far, 0.0, inv)


def slab(t: Types, ray: TraversalRay, lo, hi, t_max):
    """Williams et al. ray/box slab test of ``ray`` (its ``box_o``, ``box_inv``) against
    the box ``(lo, hi)`` and ``(0, t_max)``; t_far grown by ``ray.robust`` (pbrt) so that
    the float test never misses a box the exact ray hits. Returns ``(hit, t_near)``.

    On LLVM min/max are written as compare + select: Dr.Jit emits ``dr.minimum`` /
    ``dr.maximum`` as LLVM's NaN-propagating ``llvm.minimum``/``maximum``, which x86 has no
    instruction for; compare + select is two instructions. The values differ only where a
    slab value is NaN, which needs a NaN ray (``safe_inv`` never returns 0 or inf) or a
    box at infinity: the triangle test never hits such a ray, and such a box holds no
    triangle but the first one, so the hits stay the same."""
    o, inv, robust = ray.box_o, ray.box_inv, ray.robust
    t0, t1 = dr.fma(lo, inv, o), dr.fma(hi, inv, o)
    if t.backend == "llvm":
        c = t0 < t1
        tn = dr.select(c, t0, t1)
        tf = dr.select(c, t1, t0)
        a = dr.select(tn.x > tn.y, tn.x, tn.y)
        b = dr.select(tn.z > 0.0, tn.z, 0.0)
        t_near = dr.select(a > b, a, b)
        a = dr.select(tf.x < tf.y, tf.x, tf.y)
        t_far = dr.select(a < tf.z, a, tf.z) * robust
        return (t_near <= t_far) & (t_near <= t_max), t_near
    tn = dr.minimum(t0, t1)
    tf = dr.maximum(t0, t1)
    t_near = dr.maximum(dr.maximum(tn.x, tn.y), dr.maximum(tn.z, 0.0))
    t_far = dr.minimum(dr.minimum(tf.x, tf.y), tf.z) * robust
    return t_near <= dr.minimum(t_far, t_max), t_near


def triangle_step(tris: LeafTriangles, ray: TraversalRay, i, rec: Closest, any_hit: bool,
                  active=True, probe: Probe | None = None) -> Closest:
    """Test packed triangle ``i`` where ``active`` and fold it into ``rec``: accept a hit
    that is nearer, or (once something was found) equally near with a smaller original face
    index (``tris.order``), so ties resolve the same in every accelerator. For ``any_hit``
    only ``found`` (a hit in (0, ray.t_max)) is updated. ``active`` is True where the
    caller's symbolic ``if`` already masks the lanes.

    An exact tie reads both original face indices in a symbolic branch, taken only when
    some lane of the packet or warp has one (exact ties are rare, and a masked gather costs
    its loads on the CPU even for masked-off lanes); ``rec.order`` is therefore not kept
    by the renderer's pass.

    With a ``probe`` (pass two of ``tie_probe``) ``ray.t_max`` is the end of the tie window
    (inclusive), the inside test takes the probe's slack (``probe_inside``, for either
    layout), and the hit in ``(0, t_max]`` with the largest original face index, other than
    triangle ``probe.nearest``, wins, however near; the caller culls boxes by ``t_max``,
    not ``rec.t`` (``cull_t``)."""
    t, order, t_max = tris.t, tris.order, ray.t_max
    layout = layout_of(tris.routine)
    tri = load(t, tris.data, i, active, layout)
    th, u, v, h = tris.routine(ray.o, ray.d, *tri)
    if probe is not None:
        e1, e2 = edges_of(tri, layout)
        inside = probe_inside(th, u, v, e1, e2, probe.slack)
        near = th <= probe.origin
        # at the origin the routine's answer stands: a narrowed test keeps its hit, a
        # widened one adds none (a re-hit of the surface the ray left is no tie)
        h = dr.select(near, h, inside) if probe.slack < 0 else inside & ~near
    if active is not True:
        h &= active
    if any_hit:
        return Closest(rec.t, rec.u, rec.v, rec.prim, rec.order, rec.found | (h & (th < t_max)))
    if probe is not None:
        h &= th <= t_max
        i_order = dr.gather(t.UInt32, order, i, h)
        accept = h & (i != probe.nearest) & (~rec.found | (i_order > rec.order))
        return Closest(t=dr.select(accept, th, rec.t), u=dr.select(accept, u, rec.u),
                       v=dr.select(accept, v, rec.v), prim=dr.select(accept, i, rec.prim),
                       order=dr.select(accept, i_order, rec.order), found=rec.found | accept)
    h &= th <= rec.t
    nearer = h & (th < rec.t)
    tie = h & rec.found & (th == rec.t)
    wins = dr.if_stmt(
        (i, rec.prim, tie), tie,
        lambda i, p, tie: tie & (dr.gather(t.UInt32, order, i, tie)
                                 < dr.gather(t.UInt32, order, p, tie)),
        lambda i, p, tie: tie & False)
    accept = nearer | wins
    return Closest(t=dr.select(accept, th, rec.t), u=dr.select(accept, u, rec.u),
                   v=dr.select(accept, v, rec.v), prim=dr.select(accept, i, rec.prim),
                   order=rec.order, found=rec.found | accept)


def edges_of(tri, layout: str):
    """The edge vectors ``(e1, e2) = (p1 - p0, p2 - p0)`` of a triangle as ``load`` returns
    it in ``layout``: stored in "edges", differences of the vertices in "vertices"."""
    if layout == "edges":
        return tri[1], tri[2]
    return tri[1] - tri[0], tri[2] - tri[0]


def probe_inside(th, u, v, e1, e2, slack: float):
    """The probe's inside test of a hit ``(th, u, v)`` on the triangle with edges ``e1``,
    ``e2``: within the world-space distance ``slack`` of the triangle (outside it by less
    than ``slack`` when ``slack > 0``; inside by more than ``-slack`` when ``slack < 0``).
    A barycentric coordinate times the triangle's altitude over the opposite edge is the
    distance from that edge, so the slack of each coordinate is ``slack * edge / (2 area)``."""
    two_area = dr.norm(dr.cross(e1, e2))
    s = slack / two_area
    w = 1.0 - u - v
    return ((two_area > 0) & (th > 0) & (u >= -s * dr.norm(e2)) & (v >= -s * dr.norm(e1))
            & (w >= -s * dr.norm(e2 - e1)))


def cull_t(rec: Closest, t_max, probe):
    """The distance beyond which a traversal skips boxes: the closest hit so far, or in
    pass two of ``tie_probe`` the end of the tie window ``t_max``."""
    return rec.t if probe is None else t_max


def probe_pad(probe) -> float:
    """How far a traversal grows its boxes: the probe's slack (0 without a probe)."""
    return 0.0 if probe is None else abs(float(probe.slack))


def enter_leaf(cur, first, end):
    """When no leaf triangles are pending (``first >= end``), classify node reference
    ``cur``; a leaf's triangle range becomes ``[first, end)``. Returns
    ``(is_leaf, is_inner, first, end)``."""
    node_step = first >= end
    is_leaf = node_step & ((cur & LEAF_BIT) != 0) & (cur != DONE)
    is_inner = node_step & ((cur & LEAF_BIT) == 0)
    first = dr.select(is_leaf, cur & FIRST_MASK, first)
    end = dr.select(is_leaf, (cur & FIRST_MASK) + ((cur >> COUNT_SHIFT) & 15) + 1, end)
    return is_leaf, is_inner, first, end


def leaf_triangle_step(tris: LeafTriangles, ray: TraversalRay, first, end, rec: Closest,
                       any_hit: bool, probe=None) -> tuple:
    """The triangle half of a traversal iteration, shared by every accelerator: where a
    leaf triangle is pending (``first < end``), test triangle ``first`` (``triangle_step``)
    and move on to the next. Returns ``(rec, first)``."""
    return masked_step(
        tris.t, first < end,
        lambda rec, first, on: (
            triangle_step(tris, ray, first, rec, any_hit, on, probe),
            first + 1 if on is True else dr.select(on, first + 1, first)),
        (rec, first))


def traversal_result(rec: Closest, any_hit: bool, counts=None):
    """What a traversal returns: the counters ``(node_steps, triangle_steps, iterations)``
    where it counted (``counts``), else ``rec.found`` for an any-hit query, else the
    closest hit (``rec.result()``)."""
    if counts is not None:
        return counts
    return rec.found if any_hit else rec.result()


def masked_step(t: Types, where, step, state: tuple) -> tuple:
    """``step(*state, True)`` applied to the lanes ``where``, inside a symbolic ``if``;
    returns the new state. The ``if`` is a real branch, taken only when some lane of the
    16-lane SIMD packet (LLVM) or of the 32-thread warp (CUDA) needs it; written inline
    with masked updates instead, every lane pays for every instruction of the loop body
    on every iteration, so the branch is the faster form, with bitwise the same hits
    (``lab/notes/accel-decisions.md``). Inside the ``if`` Dr.Jit masks the step's gathers
    and stack writes itself."""
    return dr.if_stmt(state, where, lambda *s: step(*s, True), lambda *s: s)


#: Fewest lanes a refill traversal runs on (``refill_lanes``): on the CPU enough blocks of
#: work for every thread; batches no larger run the ordinary traversal.
REFILL_MIN_LANES = 4096


def refill_lanes(n: int, refill: int) -> int:
    """Lanes of a refill traversal of ``n`` rays with about ``refill`` rays per lane
    (``refill_traversal``); ``n`` (no refill) where that leaves no lane a second ray."""
    return min(n, max(-(-n // refill), REFILL_MIN_LANES)) if refill else n


@syntax
def refill_traversal(tris: LeafTriangles, node_fn, ray: Ray, active, any_hit: bool,
                     lanes: int, label: str, reach: float):
    """A traversal whose ``lanes`` lanes take a new ray when theirs is done: they start on
    the first ``lanes`` rays of the batch; a lane whose ray has finished writes its result
    and takes the next untraced ray from an atomic counter (``dr.scatter_inc``), so a SIMD
    packet (LLVM) or warp (CUDA) stops paying for its slowest ray until the batch runs out
    (Aila & Laine 2009's persistent threads with dynamic fetch). The rays are evaluated
    first and gathered by index, so this is a query for evaluated batches, not for a
    caller's megakernel. ``tris.routine`` is unbound (the lanes change rays).
    ``node_fn(ray, best_t, stack, to_pop)`` is the accelerator's node step (``ray`` a
    ``TraversalRay`` for the accelerator's ``reach``) under ``masked_step`` (returns
    ``(stack, to_pop)``); each ray's steps are those of the accelerator's own loop, in the
    same order, so the hits are bitwise the same. Returns what the accelerator's query
    returns (``found`` for any hit, else a ``ClosestHit``)."""
    t = tris.t
    n = dr.width(ray.o, ray.d, ray.t_max, active)
    O, D = (v if dr.width(v) == n else v + dr.zeros(t.Array3f, n)
            for v in (t.Array3f(ray.o), t.Array3f(ray.d)))
    TM = t.Float(ray.t_max)
    TM = TM if dr.width(TM) == n else TM + dr.zeros(t.Float, n)
    ACT = t.Bool(active)
    ACT = ACT if dr.width(ACT) == n else ACT & dr.full(t.Bool, True, n)
    dr.eval(O, D, TM, ACT)              # gathered by ray index in the loop
    counter = dr.full(t.UInt32, lanes, 1)          # the next ray nobody has taken
    out_t, out_u, out_v = (dr.zeros(t.Float, n) for _ in range(3))
    out_prim = dr.zeros(t.UInt32, n)
    out_found = dr.zeros(t.Bool, n)
    ray_id = dr.arange(t.UInt32, lanes)
    valid = dr.full(t.Bool, True, lanes)
    o = dr.gather(t.Array3f, O, ray_id)
    d = dr.gather(t.Array3f, D, ray_id)
    inv = safe_inv(t, d)
    b_o, b_inv = box_ray(t, o, inv, reach)
    r = TraversalRay(o=o, d=d, inv=inv, box_o=b_o, box_inv=b_inv,
                     t_max=dr.gather(t.Float, TM, ray_id), robust=robust_scale(t))
    stack = Stack(data=dr.alloc_local(t.UInt32, STACK_SIZE), sp=dr.zeros(t.UInt32, lanes),
                  cur=dr.select(dr.gather(t.Bool, ACT, ray_id), t.UInt32(0), t.UInt32(DONE)))
    first = dr.zeros(t.UInt32, lanes)
    end = dr.zeros(t.UInt32, lanes)
    rec = Closest.empty(t, r.t_max, lanes)

    while dr.hint(valid, max_iterations=-1, label=label,
                  exclude=[t, tris, node_fn, any_hit, n, O, D, TM, ACT,
                           counter, out_t, out_u, out_v, out_prim, out_found]):
        is_leaf, is_inner, first, end = enter_leaf(stack.cur, first, end)
        stack, to_pop = masked_step(
            t, is_inner,
            lambda stack, to_pop, on, best_t=rec.t, r=r: node_fn(r, best_t, stack, to_pop),
            (stack, is_leaf | False))
        stack.pop(to_pop)
        rec, first = leaf_triangle_step(tris, r, first, end, rec, any_hit)
        busy = (first < end) | (stack.cur != DONE)
        if dr.hint(any_hit, mode="scalar"):
            busy &= ~rec.found
        finish = valid & ~busy
        # the finished rays' results, then each finished lane takes the next ray
        if dr.hint(any_hit, mode="scalar"):
            dr.scatter(out_found, rec.found, ray_id, finish)
        else:
            dr.scatter(out_t, rec.t, ray_id, finish)
            dr.scatter(out_u, rec.u, ray_id, finish)
            dr.scatter(out_v, rec.v, ray_id, finish)
            dr.scatter(out_prim, rec.prim, ray_id, finish)
            dr.scatter(out_found, rec.found, ray_id, finish)
        nid = dr.scatter_inc(counter, t.UInt32(0), finish)
        ray_id = dr.select(finish, nid, ray_id)
        valid = dr.select(finish, nid < n, valid)
        take = finish & valid
        o = dr.select(take, dr.gather(t.Array3f, O, nid, take), r.o)
        d = dr.select(take, dr.gather(t.Array3f, D, nid, take), r.d)
        inv = dr.select(take, safe_inv(t, d), r.inv)
        n_o, n_inv = box_ray(t, o, inv, reach)
        t_max = dr.select(take, dr.gather(t.Float, TM, nid, take), r.t_max)
        r = TraversalRay(o=o, d=d, inv=inv, box_o=dr.select(take, n_o, r.box_o),
                         box_inv=dr.select(take, n_inv, r.box_inv), t_max=t_max,
                         robust=r.robust)
        on = dr.gather(t.Bool, ACT, nid, take)
        stack.cur = dr.select(take, dr.select(on, t.UInt32(0), t.UInt32(DONE)), stack.cur)
        stack.sp = dr.select(take, 0, stack.sp)
        first = dr.select(take, 0, first)
        end = dr.select(take, 0, end)
        rec = Closest(t=dr.select(take, t_max, rec.t), u=dr.select(take, 0.0, rec.u),
                      v=dr.select(take, 0.0, rec.v), prim=dr.select(take, 0, rec.prim),
                      order=dr.select(take, DONE, rec.order), found=rec.found & ~take)
    if dr.hint(any_hit, mode="scalar"):
        return out_found
    return ClosestHit(t=out_t, u=out_u, v=out_v, prim=out_prim, found=out_found)
