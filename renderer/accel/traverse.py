"""Traversal steps shared by every accelerator and backend.

A traversal is one symbolic loop per query whose body is made of these steps: the ray
set-up (``setup``), the slab test of a box (``slab``), the triangle step that folds one
candidate triangle into the closest-hit record (``triangle_step``), the leaf entry
(``enter_leaf``) and the stack pop (``pop``). Where a backend needs different code for the
same step (the slab test's min/max on the CPU, the gathers), the branch is inside the step.

Node references (the BVH's children, the traversal's ``cur`` and stack entries) are UInt32:
an inner-node index, or a packed leaf ``LEAF_BIT | (count - 1) << COUNT_SHIFT | first``
(``count`` triangles from position ``first``), or ``DONE``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import drjit as dr

from ..device import Types
from .base import ClosestHit, Ray
from .triangle import layout_of, load, unit_roundoff

LEAF_BIT = 1 << 31
COUNT_SHIFT = 27
FIRST_MASK = (1 << COUNT_SHIFT) - 1
MAX_LEAF = 16                # leaf size limit of the packed reference (4 count bits)
DONE = 0xFFFFFFFF            # "no node left" sentinel of the traversal
STACK_SIZE = 32              # UInt32 entries per ray: 128 bytes (drjit #532 limit)
#: Closest-hit tie-breaks: "lowest" (the renderer's: nearest ``t``, then the smallest
#: original face index) and "other" (a probe for the golden tests, ``tie_probe``: another
#: triangle as near as the nearest one within the precision, where there is one).
TIE_BREAKS = ("lowest", "other")
#: Backends whose closest-hit step reads the original face indices of an exact tie in a
#: symbolic branch (``triangle_step``); elsewhere a masked gather on every nearer hit (kept
#: for the probes, which measure it). Both backends: on the CPU it saves a median 5 % of the
#: CPU time; on an H200 closest-hit rays are 1.00-1.05x faster (median 1.01x binary, 1.02x
#: 4-wide; none slower in 15 rows each; ``results/h200/throughput/refill-count.md``).
TIE_BRANCH_BACKENDS = ("llvm", "cuda")
#: Any-hit node steps go to the farthest hit child first and push the others far to near
#: (closest hit: nearest first). Any hit ends the query, and the far child tends to hold
#: what a ray surely meets (the far wall of a room for a primary ray, the geometry around a
#: light for a shadow ray); the answer is the same in any order. Loop iterations per ray
#: against nearest first (binary BVH, LLVM counts on the bench's 480x270 batches): shadow
#: rays 1-7 % fewer, primary, incoherent and reflection any-hit rays 3-55 % fewer (Sponza
#: primary 32.5 -> 16.0); the wide BVHs, against slot order: up to 54 % fewer. CPU time
#: (2-core EPYC): 0.97-1.23x on shadow rays, up to 2.7x on Sponza's and Conference's other
#: any-hit rays.
FAR_FIRST = True


#: A probe's hit at ``t <= ORIGIN_OPS · u · max|o|`` (``u`` the unit roundoff, ``o`` the
#: ray's origin) lies at the ray's origin within the rounding of the point the ray left:
#: a spawned ray re-hitting its own surface, or a surface through its origin. That is no
#: tie: the probe leaves the renderer's answer there (``at_origin``).
ORIGIN_OPS = 64


class Probe(NamedTuple):
    """A pass of ``tie_probe`` / ``tie_probe_p``: the nearest hit's triangle (UInt32 per
    ray, an index in the accelerator's order like ``ClosestHit.prim``; None for any-hit),
    the slack (float, a world-space distance; negative narrows) of the inside test, and
    ``origin`` (Float per ray, ``at_origin``): hits at ``t <= origin`` keep the routine's
    own inside test when the slack narrows and do not count when it widens."""

    nearest: object
    slack: float
    origin: object = 0.0


def at_origin(o):
    """``ORIGIN_OPS · u · max|o|`` per ray: the distance along a ray from ``o`` within
    which a hit is at the origin for the tie probe (``Probe.origin``)."""
    mag = dr.maximum(dr.maximum(dr.abs(o.x), dr.abs(o.y)), dr.abs(o.z))
    return mag * (ORIGIN_OPS * unit_roundoff(dr.type_v(mag) == dr.VarType.Float64))


@dataclass
class Closest:
    """The closest-hit record a traversal carries: ``t`` starts at ``t_max`` and shrinks
    to the nearest hit; ``prim`` is the triangle in the accelerator's order and ``order``
    its original face index (the tie-break); u, v: barycentrics; found: Bool."""

    t: object
    u: object
    v: object
    prim: object
    order: object
    found: object

    @classmethod
    def empty(cls, t: Types, t_max, n: int) -> "Closest":
        return cls(t=t.Float(t_max) + dr.zeros(t.Float, n), u=dr.zeros(t.Float, n),
                   v=dr.zeros(t.Float, n), prim=dr.zeros(t.UInt32, n),
                   order=dr.full(t.UInt32, DONE, n), found=dr.zeros(t.Bool, n))

    def result(self) -> ClosestHit:
        return ClosestHit(t=self.t, u=self.u, v=self.v, prim=self.prim, found=self.found)


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


def setup(t: Types, ray: Ray, active):
    """The ray as a traversal loop reads it: ``(o, d, inv, active, n)``, every array of
    the batch width ``n``; ``inv = safe_inv(d)``."""
    n = dr.width(ray.o, ray.d, ray.t_max, active)
    o, d = t.Array3f(ray.o), t.Array3f(ray.d)
    return o, d, safe_inv(t, d), t.Bool(active) & dr.full(t.Bool, True, n), n


#: Backends whose slab test is one FMA per plane, ``lo * inv - o * inv`` with ``o * inv``
#: computed once per ray (``box_ray``), instead of ``(lo - o) * inv`` (a subtraction and
#: a product). H200: 0.99-1.05x faster traversal, median 1.02x over 35 batches, bitwise the
#: same hits (``results/h200/throughput/slab.md``). The probes set it to compare both forms.
SLAB_FMA_BACKENDS: tuple = ("llvm", "cuda")


def box_ray(t: Types, o, inv, reach: float):
    """The ray(s) ``(o, inv)`` as ``slab`` reads them, for boxes padded for origins of
    coordinates up to ``reach`` in magnitude (the accelerator's ``reach``,
    ``triangle.pad_extent``): ``(-(o * inv), inv)`` for the FMA form
    (``SLAB_FMA_BACKENDS``), else ``(o, inv)``.

    The boxes are padded (``bvh_build.pad_boxes``: 32 ``u`` (coordinate + reach), ``u`` the
    unit roundoff) so that a triangle's computed hit lies inside them although the triangle
    test rounds in proportion to ``|p - o|``. The FMA form rounds ``o * inv`` once, which
    moves each slab plane by up to ``u |o_a|`` in world units: a 32nd of that padding where
    ``|o_a| <= reach``, which the triangle test leaves room for. From farther away the
    padding covers neither (of 2 10^4 rays from 10^3-10^5 scene sizes away, 2-11 lost their
    hit in float32, in either form); such rays get ``(0, 0)``, for which every slab value is
    0, so they enter every box with ``t_near = 0``: brute force's hits at brute force's
    cost, and no extra work per box for the others. A render's rays start at cameras,
    lights and surfaces, which lie within the reach (``triangle.box_reach``)."""
    if t.backend not in SLAB_FMA_BACKENDS:
        return o, inv
    mag = dr.maximum(dr.maximum(dr.abs(o.x), dr.abs(o.y)), dr.abs(o.z))
    far = ~(mag <= reach)
    return dr.select(far, 0.0, -(o * inv)), dr.select(far, 0.0, inv)


def slab(t: Types, o, inv, lo, hi, t_max, robust):
    """Williams et al. ray/box slab test; t_far grown by ``robust_scale`` (pbrt) so that
    the float test never misses a box the exact ray hits. ``(o, inv)``: ``box_ray``'s.
    Returns ``(hit, t_near)``.

    On LLVM min/max are written as compare + select: Dr.Jit emits ``dr.minimum`` /
    ``dr.maximum`` as LLVM's NaN-propagating ``llvm.minimum``/``maximum``, which x86 has no
    instruction for; compare + select is two instructions. The values differ only where a
    slab value is NaN, which needs a NaN ray (``safe_inv`` never returns 0 or inf) or a
    box at infinity: the triangle test never hits such a ray, and such a box holds no
    triangle but the first one, so the hits stay the same."""
    if t.backend in SLAB_FMA_BACKENDS:
        t0, t1 = dr.fma(lo, inv, o), dr.fma(hi, inv, o)
    else:
        t0, t1 = (lo - o) * inv, (hi - o) * inv
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


def triangle_step(t: Types, routine, o, d, tri_data, order, i, t_max, rec: Closest,
                  any_hit: bool, active=True, probe: Probe | None = None) -> Closest:
    """Test packed triangle ``i`` where ``active`` and fold it into ``rec``: accept a hit
    that is nearer, or (once something was found) equally near with a smaller original face
    index (``order``), so ties resolve the same in every accelerator. For ``any_hit`` only
    ``found`` (a hit in (0, t_max)) is updated. ``active`` is True where the caller's
    symbolic ``if`` already masks the lanes.

    With a ``probe`` (pass two of ``tie_probe``) ``t_max`` is the end of the tie window
    (inclusive), the inside test takes the probe's slack (``probe_inside``, for either
    layout), and the hit in ``(0, t_max]`` with the largest original face index, other than
    triangle ``probe.nearest``, wins, however near; the caller culls boxes by ``t_max``,
    not ``rec.t`` (``cull_t``)."""
    layout = layout_of(routine)
    tri = load(t, tri_data, i, active, layout)
    th, u, v, h = routine(o, d, *tri)
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
    if t.backend in TIE_BRANCH_BACKENDS:
        # exact ties are rare: read both original face indices only in a symbolic branch
        # taken when some lane of the packet has one (a masked gather costs its loads on
        # the CPU even for masked-off lanes); ``rec.order`` is not kept on this path
        wins = dr.if_stmt(
            (i, rec.prim, tie), tie,
            lambda i, p, tie: tie & (dr.gather(t.UInt32, order, i, tie)
                                     < dr.gather(t.UInt32, order, p, tie)),
            lambda i, p, tie: tie & False)
        accept = nearer | wins
        return Closest(t=dr.select(accept, th, rec.t), u=dr.select(accept, u, rec.u),
                       v=dr.select(accept, v, rec.v), prim=dr.select(accept, i, rec.prim),
                       order=rec.order, found=rec.found | accept)
    i_order = dr.gather(t.UInt32, order, i, nearer | tie)
    accept = nearer | (tie & (i_order < rec.order))
    return Closest(t=dr.select(accept, th, rec.t), u=dr.select(accept, u, rec.u),
                   v=dr.select(accept, v, rec.v), prim=dr.select(accept, i, rec.prim),
                   order=dr.select(accept, i_order, rec.order), found=rec.found | accept)


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


def tie_probe(traverse, ray: Ray, active, tie_break: str, window: float,
              slack: float) -> ClosestHit:
    """The closest hit under ``tie_break`` (``TIE_BREAKS``) through ``traverse(ray, active,
    probe)``, an accelerator's closest-hit traversal (``probe``: None or a ``Probe``).

    "lowest" is one pass, the renderer's. "other" is two: the nearest hit at ``t*`` (pass
    one, the renderer's hit), then every triangle hit in ``(0, t* + window]`` with the
    inside test widened by the distance ``slack`` (``probe_inside``; pass two): the one
    with the largest original face index other than the nearest wins; where there is none,
    the nearest stays. ``window`` and ``slack`` are world-space distances (``ray.d`` unit
    length, as the integrator's rays are). So the
    closest hit changes exactly where another triangle is as near as the nearest within
    the precision (a shared edge, a corner, coplanar faces): a geometric tie, which two
    renderers may resolve either way. Where pass one finds nothing, pass two does not run
    (a crack stays a crack). A window reaching ``ray.t_max`` shrinks to ``t*``."""
    if tie_break not in TIE_BREAKS:
        raise ValueError(f"tie_break: expected one of {list(TIE_BREAKS)}, got {tie_break!r}")
    first = traverse(ray, active, None)
    if tie_break == "lowest":
        return first
    limit = first.t + window
    limit = dr.select(first.found & (limit < ray.t_max), limit, first.t)
    origin = at_origin(ray.o)
    other = traverse(Ray(o=ray.o, d=ray.d, t_max=limit),
                     first.found & (first.t > origin) & active,
                     Probe(nearest=first.prim, slack=slack, origin=origin))
    keep = ~other.found
    return ClosestHit(t=dr.select(keep, first.t, other.t), u=dr.select(keep, first.u, other.u),
                      v=dr.select(keep, first.v, other.v),
                      prim=dr.select(keep, first.prim, other.prim), found=first.found)


def tie_probe_p(traverse, ray: Ray, active, tie_break: str, slack: float):
    """Any hit (shadow rays) under ``tie_break`` through ``traverse(ray, active, probe)``,
    an accelerator's any-hit traversal. "lowest": the renderer's answer. "other": the
    answer flipped where the inside test decides it within ``slack`` (the ray grazes an
    occluder's edge): a blocked ray stays blocked only if it is blocked with the inside
    test narrowed by ``slack``, an unblocked one becomes blocked if it is blocked with the
    test widened by ``slack``."""
    found = traverse(ray, active, None)
    if tie_break == "lowest":
        return found
    origin = at_origin(ray.o)
    narrow = traverse(ray, active & found, Probe(nearest=None, slack=-slack, origin=origin))
    wide = traverse(ray, active & ~found, Probe(nearest=None, slack=slack, origin=origin))
    return dr.select(found, narrow, wide)


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


def pop(stack, sp, cur, where):
    """Where ``where``: the next node is the top of the stack, or DONE when it is empty.
    Returns ``(sp, cur)``."""
    can_pop = where & (sp > 0)
    sp = dr.select(can_pop, sp - 1, sp)
    popped = stack.read(sp, can_pop)
    return sp, dr.select(where, dr.select(can_pop, popped, DONE), cur)


def leaf_triangle_step(t: Types, routine, o, d, tri_data, order, first, end, t_max,
                       rec: Closest, any_hit: bool, probe=None) -> tuple:
    """The triangle half of a traversal iteration, shared by every accelerator: where a
    leaf triangle is pending (``first < end``), test triangle ``first`` (``triangle_step``)
    and move on to the next. Returns ``(rec, first)``."""
    return masked_step(
        t, first < end,
        lambda rec, first, on: (
            triangle_step(t, routine, o, d, tri_data, order, first, t_max, rec, any_hit,
                          on, probe),
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
    on every iteration. Measured on an H200 (``results/h200/throughput/branches.md``):
    the branches make the binary BVH's traversal 1.35-2.05x faster (median 1.65x), with
    bitwise the same hits. Inside the ``if`` Dr.Jit masks the step's gathers and stack
    writes itself."""
    return dr.if_stmt(state, where, lambda *s: step(*s, True), lambda *s: s)


#: Fewest lanes a refill traversal runs on (``refill_lanes``): on the CPU enough blocks of
#: work for every thread; batches no larger run the ordinary traversal.
REFILL_MIN_LANES = 4096


def refill_lanes(n: int, refill: int) -> int:
    """Lanes of a refill traversal of ``n`` rays with about ``refill`` rays per lane
    (``refill_traversal``); ``n`` (no refill) where that leaves no lane a second ray."""
    return min(n, max(-(-n // refill), REFILL_MIN_LANES)) if refill else n


@dr.syntax
def refill_traversal(t: Types, routine, tri_data, order, node_fn, ray: Ray, active,
                     any_hit: bool, n: int, lanes: int, label: str, reach: float):
    """A traversal whose ``lanes`` lanes take a new ray when theirs is done: they start on
    the first ``lanes`` rays of the batch; a lane whose ray has finished writes its result
    and takes the next untraced ray from an atomic counter (``dr.scatter_inc``), so a SIMD
    packet (LLVM) or warp (CUDA) stops paying for its slowest ray until the batch runs out
    (Aila & Laine 2009's persistent threads with dynamic fetch). The rays are evaluated
    first and gathered by index, so this is a query for evaluated batches, not for a
    caller's megakernel. ``node_fn(sp, cur, to_pop, best_t, o, inv, stack)`` is the
    accelerator's node step (``o``, ``inv``: ``box_ray``'s, for the accelerator's
    ``reach``) under ``masked_step`` (returns ``(sp, cur, to_pop)``); each ray's steps are
    those of the accelerator's own loop, in the same order, so the hits are bitwise the
    same. Returns what the accelerator's query returns (``found`` for any hit, else a
    ``ClosestHit``)."""
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
    t_max = dr.gather(t.Float, TM, ray_id)
    inv = safe_inv(t, d)
    b_o, b_inv = box_ray(t, o, inv, reach)
    stack = dr.alloc_local(t.UInt32, STACK_SIZE)
    sp = dr.zeros(t.UInt32, lanes)
    cur = dr.select(dr.gather(t.Bool, ACT, ray_id), t.UInt32(0), t.UInt32(DONE))
    first = dr.zeros(t.UInt32, lanes)
    end = dr.zeros(t.UInt32, lanes)
    rec = Closest.empty(t, t_max, lanes)

    while dr.hint(valid, max_iterations=-1, label=label,
                  exclude=[t, routine, tri_data, order, node_fn, any_hit, n, O, D, TM, ACT,
                           counter, out_t, out_u, out_v, out_prim, out_found]):
        is_leaf, is_inner, first, end = enter_leaf(cur, first, end)
        sp, cur, to_pop = masked_step(
            t, is_inner,
            lambda sp, cur, to_pop, on, best_t=rec.t, b_o=b_o, b_inv=b_inv: node_fn(
                sp, cur, to_pop, best_t, b_o, b_inv, stack),
            (sp, cur, is_leaf | False))
        sp, cur = pop(stack, sp, cur, to_pop)
        rec, first = leaf_triangle_step(t, routine, o, d, tri_data, order, first, end,
                                        t_max, rec, any_hit)
        busy = (first < end) | (cur != DONE)
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
        o = dr.select(take, dr.gather(t.Array3f, O, nid, take), o)
        d = dr.select(take, dr.gather(t.Array3f, D, nid, take), d)
        inv = dr.select(take, safe_inv(t, d), inv)
        n_o, n_inv = box_ray(t, o, inv, reach)
        b_o, b_inv = dr.select(take, n_o, b_o), dr.select(take, n_inv, b_inv)
        t_max = dr.select(take, dr.gather(t.Float, TM, nid, take), t_max)
        on = dr.gather(t.Bool, ACT, nid, take)
        cur = dr.select(take, dr.select(on, t.UInt32(0), t.UInt32(DONE)), cur)
        sp = dr.select(take, 0, sp)
        first = dr.select(take, 0, first)
        end = dr.select(take, 0, end)
        rec = Closest(t=dr.select(take, t_max, rec.t), u=dr.select(take, 0.0, rec.u),
                      v=dr.select(take, 0.0, rec.v), prim=dr.select(take, 0, rec.prim),
                      order=dr.select(take, DONE, rec.order), found=rec.found & ~take)
    if dr.hint(any_hit, mode="scalar"):
        return out_found
    return ClosestHit(t=out_t, u=out_u, v=out_v, prim=out_prim, found=out_found)
