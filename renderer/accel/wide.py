"""The wide BVH: 4 or 8 children per node, built as a conversion of ``bvh_build``'s binary
SAH tree (tinybvh's ``BVH4``/``BVH8_CWBVH::ConvertFrom``).

Conversion (``collapse``): each wide node starts from a binary node's two children and
repeatedly replaces the inner child of largest surface area by its two children (SAH-greedy
expansion) until it has ``width`` children or no inner child may be expanded. Leaves are
the binary tree's leaves unchanged (same triangle order, same packed references of
``renderer.accel.layout``), so the wide tree visits the same triangles in a different
order and the hits are bitwise those of the binary BVH and of brute force.

Stack bound: a closest-hit node step pushes at most ``children - 1`` entries. The
conversion only expands a child when ``pushes so far + (children - 1) + levels still
needed below`` stays within ``STACK_SIZE`` (the binary tree's own bound: a subtree of ``L``
inner levels never needs more than ``L`` entries), so the stack cannot overflow. The
stack holds more than the binary trees' ``MAX_LEVELS``: a stack no deeper than a tree
leaves the nodes on its deepest paths no room for more than 2 children.

Node layout on the device (default, ``quantized``): ``nodes`` UInt32,
``record_words(width)`` per node (12 for 4 children, 16 for 8): the node's origin and the
exponents of its power-of-two scales (one word), then each coordinate of every child box
as one byte, four children per word, SoA (all children's lo.x, then lo.y, lo.z, hi.x,
hi.y, hi.z; CWBVH, Ylitie et al. 2017, rounded outwards by ``quantize``). Unquantised:
``nodes`` Float, ``6 * width`` per node, the same SoA order in float32. ``refs`` UInt32,
``width`` per node (``DONE`` marks an empty slot). One node step reads one contiguous
record and tests one ray against every child box.

Why quantised: on the CPU (LLVM, 16 lanes per SIMD packet) a step's cost is its gathers,
one load per element per lane; quantised boxes need a quarter of the float layout's box
words. On LLVM (float32) the records, the references and the traversal's copy of the
triangles are moreover read as UInt64 views, two words per 64-bit gather
(``base.gather_pairs``): the same bytes with half the loads.

Node steps sort the hit children by entry distance (a sorting network); closest-hit steps
go to the nearest and push the rest far to near, any-hit steps go to the farthest and push
the rest near to far. Any hit ends the query, and the far child tends to hold what a ray
surely meets (the far wall of a room for a primary ray, the geometry around a light for a
shadow ray): the answer is the same in any order, and far first takes fewer loop iterations
than slot order or nearest first (``lab/notes/accel-decisions.md``).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import drjit as dr
import numpy as np

from ..device import Types, host_array, host_view, syntax
from .base import (
    Accelerator,
    DeviceTriangles,
    Ray,
    array_type,
    as_pairs,
    gather_floats,
    gather_pairs,
    traversal_triangles,
    uses_pairs,
)
from .bvh import traversal_boxes
from .bvh_build import BINS, LEAF_SIZE, BVHArrays, build_bvh
from .layout import DONE, LEAF_BIT, STACK_SIZE
from .query import Closest
from .traverse import (
    LeafTriangles,
    Stack,
    TraversalRay,
    cull_t,
    enter_leaf,
    leaf_triangle_step,
    masked_step,
    probe_pad,
    refill_lanes,
    refill_traversal,
    setup,
    slab,
    traversal_result,
)
from .triangle import (
    DEFAULT_ROUTINE,
    STRIDE,
    bind_routine,
    device_triangles,
    origin_reach,
    pad_extent,
    triangle_arrays,
    triangle_routine,
)

WIDTHS = (4, 8)


@dataclass
class WideArrays:
    """A wide BVH on the host.

    width: children per node; boxes: (N, 6, width) SoA child boxes in the binary boxes'
    dtype (lo xyz, hi xyz rows; NaN in empty slots); refs: uint32 (N, width) child
    references (wide-node index or packed leaf; ``DONE`` in empty slots); levels: wide
    levels; max_stack: the most stack entries a closest-hit traversal can hold;
    convert_seconds.
    """

    width: int
    boxes: np.ndarray
    refs: np.ndarray
    levels: int
    max_stack: int
    convert_seconds: float = 0.0

    @property
    def node_count(self) -> int:
        return int(self.refs.shape[0])


def _half_area(box):
    """Half surface area of boxes (..., 6) (lo xyz, hi xyz); 0 for non-finite boxes."""
    with np.errstate(invalid="ignore"):
        d = box[..., 3:6].astype(np.float64) - box[..., 0:3]
        a = d[..., 0] * d[..., 1] + d[..., 1] * d[..., 2] + d[..., 2] * d[..., 0]
    return np.where(np.isfinite(a), a, 0.0)


def _inner_levels(children: np.ndarray) -> np.ndarray:
    """Inner levels of each binary node's subtree (1 for a node whose children are leaves)."""
    ref = children.astype(np.int64)
    inner = (ref & LEAF_BIT) == 0
    levels = [np.zeros(1, np.int64)]
    while True:
        c = ref[levels[-1]][inner[levels[-1]]]
        if not c.size:
            break
        levels.append(c)
    need = np.ones(ref.shape[0], np.int64)
    for nodes in reversed(levels):
        for k in range(2):
            m = inner[nodes, k]
            need[nodes[m]] = np.maximum(need[nodes[m]], need[ref[nodes[m], k]] + 1)
    return need


def collapse(a: BVHArrays, width: int = 4, stack_size: int = STACK_SIZE) -> WideArrays:
    """Collapse the binary tree ``a`` into ``width``-wide nodes (SAH-greedy expansion of the
    largest-area inner child), one wide level at a time, vectorised over its nodes."""
    if width not in WIDTHS:
        raise ValueError(f"width: expected one of {WIDTHS}, got {width}")
    t0 = time.perf_counter()
    ch = a.children.astype(np.int64)
    bx = a.boxes.reshape(-1, 2, 6)
    need = _inner_levels(a.children)
    is_inner = lambda r: (r != DONE) & ((r & LEAF_BIT) == 0)  # noqa: E731
    frontier = np.zeros(1, np.int64)              # binary node of each new wide node
    budget = np.array([stack_size], np.int64)     # stack entries left to its subtree
    out_boxes, out_refs = [], []
    next_index, levels, max_stack = 1, 0, 0
    while frontier.size:
        M = frontier.size
        refs = np.full((M, width), DONE, np.int64)
        boxes = np.full((M, width, 6), np.nan, a.boxes.dtype)
        refs[:, :2] = ch[frontier]
        boxes[:, :2] = bx[frontier]
        # a box at infinity (the binary tree's never-hit child of a single-leaf root)
        refs[~np.all(np.isfinite(boxes), axis=2)] = DONE
        count = np.full(M, 2, np.int64)
        rows = np.arange(M)
        for _ in range(width - 2):
            inner = is_inner(refs)
            r = np.where(inner, refs, 0)
            slot_need = np.where(inner, need[r], 0)
            # the most levels any other slot still needs, for each slot j (top two)
            top = np.sort(slot_need, axis=1)
            others = np.where(slot_need == top[:, -1:], top[:, -2:-1], top[:, -1:])
            new_max = np.maximum(others, slot_need - 1)
            ok = inner & ((count[:, None] + new_max) <= budget[:, None])
            score = np.where(ok, _half_area(boxes), -1.0)
            j = np.argmax(score, axis=1)
            do = ok[rows, j] & (count < width)
            if not do.any():
                break
            rr, jj = rows[do], j[do]
            rb = refs[rr, jj]
            cc = count[do]
            refs[rr, cc] = ch[rb, 1]
            boxes[rr, cc] = bx[rb, 1]
            refs[rr, jj] = ch[rb, 0]
            boxes[rr, jj] = bx[rb, 0]
            count[do] += 1
        inner = is_inner(refs)
        rows_in, slots_in = np.nonzero(inner)
        child_bin = refs[rows_in, slots_in]
        refs[rows_in, slots_in] = next_index + np.arange(child_bin.size)
        next_index += child_bin.size
        used = stack_size - budget + (count - 1)
        max_stack = max(max_stack, int(used.max()))
        out_refs.append(refs.astype(np.uint32))
        out_boxes.append(np.ascontiguousarray(boxes.transpose(0, 2, 1)))   # (M, 6, W)
        frontier = child_bin
        budget = (budget - (count - 1))[rows_in]
        levels += 1
    return WideArrays(width, np.concatenate(out_boxes), np.concatenate(out_refs), levels,
                      max_stack, time.perf_counter() - t0)


def quantize(w: WideArrays) -> np.ndarray:
    """The child boxes of ``w`` quantised to 8 bits per coordinate (CWBVH, Ylitie et al.
    2017), conservatively: uint32 (N, ``record_words(width)``) words per node,
    ``origin xyz`` (float32 bits) and one word holding the biased float32 exponents of the
    three power-of-two scales (a byte each), then the bytes ``q`` of lo.x, lo.y, lo.z,
    hi.x, hi.y, hi.z of every child, four children per word (child ``k`` in bits
    ``8 (k % 4)``). The device decodes ``origin + q * scale``; ``q`` is rounded down for
    lo and up for hi, then moved outwards until the decoded value lies outside the float
    box both in float32 and exactly (float64 traversals decode exactly), so a decoded box
    always contains the float box: it can only cost box tests, never a hit."""
    W = w.width
    N = w.node_count
    bx = w.boxes.astype(np.float64)                      # (N, 6, W)
    real = (w.refs != DONE)[:, None, :] & np.isfinite(bx)
    lo, hi = bx[:, 0:3], bx[:, 3:6]                      # (N, 3, W)
    rl = real[:, 0:3]
    org = np.where(rl, lo, np.inf).min(axis=2)           # (N, 3)
    top = np.where(rl, hi, -np.inf).max(axis=2)
    org = np.where(np.isfinite(org), org, 0.0).astype(np.float32)
    ext = np.maximum(np.where(np.isfinite(top), top, 0.0) - org, 0.0)
    e = np.clip(np.ceil(np.log2(np.maximum(ext / 254.0, 2.0 ** -120))), -120, 120)
    scale = np.exp2(e).astype(np.float32)                # (N, 3)
    o3 = np.broadcast_to(org[..., None], lo.shape)                  # float32 (N, 3, W)
    s3 = np.broadcast_to(scale[..., None], lo.shape)
    with np.errstate(invalid="ignore"):
        qlo = np.clip(np.floor((np.where(rl, lo, o3) - o3) / s3), 0, 255)
        qhi = np.clip(np.ceil((np.where(rl, hi, o3) - o3) / s3), 0, 255)
    qlo = _outward(qlo, o3, s3, lo, rl, -1)
    qhi = _outward(qhi, o3, s3, hi, rl, +1)
    q = np.concatenate([qlo, qhi], axis=1).astype(np.uint32)        # (N, 6, W)
    words = (q.reshape(N, 6, W // 4, 4) << np.array([0, 8, 16, 24], np.uint32)).sum(
        axis=3, dtype=np.uint32)                                    # (N, 6, W/4)
    biased = (scale.view(np.uint32) >> np.uint32(23)) & np.uint32(255)     # (N, 3)
    exps = biased[:, 0] | (biased[:, 1] << np.uint32(8)) | (biased[:, 2] << np.uint32(16))
    rec = np.concatenate([org.view(np.uint32), exps[:, None], words.reshape(N, -1)], axis=1)
    pad = record_words(W) - rec.shape[1]
    return np.concatenate([rec, np.zeros((N, pad), np.uint32)], axis=1) if pad else rec


def _decoded(q, o, s):
    """``o + q s`` (q float64 integers, o and s float32) as the device computes it: exactly
    (float64 traversals) and rounded once to float32. Returns both, float64."""
    exact = o.astype(np.float64) + q * s.astype(np.float64)
    return exact, exact.astype(np.float32).astype(np.float64)


def _outward(q, o, s, bound, real, step: int):
    """``q`` moved by ``step`` (-1 for lo, +1 for hi) where the decoded value does not yet
    lie outside ``bound`` (both decodings) for ``real`` entries; raises if one is left
    inside after 4 moves. The first test runs over the whole arrays, the later ones over
    the entries moved."""
    q = q.copy()
    ex, f = _decoded(q, o, s)
    with np.errstate(invalid="ignore"):
        bad = real & (((ex > bound) | (f > bound)) if step < 0 else
                      ((ex < bound) | (f < bound)))
    idx = np.nonzero(bad)
    for k in range(5):
        if not idx[0].size:
            return q
        q[idx] = np.clip(q[idx] + step, 0, 255)
        if k == 4:
            break
        ex, f = _decoded(q[idx], o[idx], s[idx])
        b = bound[idx]
        bad = (ex > b) | (f > b) if step < 0 else (ex < b) | (f < b)
        idx = tuple(i[bad] for i in idx)
    raise AssertionError("quantize: a decoded box does not contain its float box")


def record_words(width: int) -> int:
    """UInt32 words of a quantised node record: ``HEAD + 6 width / 4``, rounded up to whole
    quads (12 for 4 children, 16 for 8) so that CUDA reads it with packet gathers."""
    return (HEAD + 6 * width // 4 + 3) // 4 * 4


#: Header words of a quantised record: origin xyz (float32 bits) and the three biased
#: float32 exponents of the power-of-two scales, one byte each.
HEAD = 4


def gather_words(t: Types, src, index, stride: int, count: int, active=True) -> list:
    """The first ``count`` UInt32 of record ``index`` of ``src`` (records of ``stride``
    words, a multiple of 4): packet gathers of Array4u on CUDA, one scalar gather per word
    on LLVM, one 64-bit gather per two words where ``src`` is a UInt64 view
    (``base.gather_pairs``, LLVM float32)."""
    if dr.type_v(src) == dr.VarType.UInt64:
        return gather_pairs(t, src, index, stride, count, active)
    if t.backend == "llvm":
        base = index * stride
        return [dr.gather(t.UInt32, src, base + k, active) for k in range(count)]
    A4 = array_type(t, "Array4u")
    base = index * (stride // 4)
    out = []
    for k in range((count + 3) // 4):
        q = dr.gather(A4, src, base + k if k else base, active)
        out += [q.x, q.y, q.z, q.w]
    return out[:count]


def check_wide(w: WideArrays, a: BVHArrays) -> None:
    """Validate a collapse (tests): every binary leaf appears exactly once, every wide node
    but the root is referenced once, the stack bound holds. Raises AssertionError."""
    ref = w.refs.astype(np.int64).reshape(-1)
    real = ref != DONE
    leaf = real & ((ref & LEAF_BIT) != 0)
    inner = ref[real & ~leaf]
    assert np.array_equal(np.sort(inner), np.arange(1, w.node_count))
    b = a.children.astype(np.int64).reshape(-1)
    finite = np.all(np.isfinite(a.boxes.reshape(-1, 6)), axis=1)
    assert np.array_equal(np.sort(ref[leaf]), np.sort(b[((b & LEAF_BIT) != 0) & finite]))
    assert w.max_stack <= STACK_SIZE


def wide_node_step(wide: "WideBVH", ray: TraversalRay, t_max, stack: Stack, to_pop,
                   any_hit: bool, active=True, pad: float = 0.0):
    """One wide node ``stack.cur`` of ``wide`` where ``active``: test the ray against every
    child box (grown by ``pad``) at once (``(0, t_max)``), go to the nearest hit child and
    push the other hit children far to near (any hit: the farthest, pushing the rest near
    to far). Returns ``(stack, to_pop)``, ``to_pop`` grown by the lanes where no child was
    hit."""
    t, W, cur = wide.types, wide.width, stack.cur
    boxes = child_boxes(t, W, wide.nodes, cur, active)
    child = gather_words(t, wide.refs, cur, W, W, active)
    key, ref = [], []
    for k in range(W):
        lo, hi = boxes[k]
        if pad:         # the tie probe's slack reaches beyond the padded boxes
            lo, hi = lo - pad, hi + pad
        r = child[k]
        hit, tn = slab(t, ray, lo, hi, t_max)
        hit &= r != DONE
        if active is not True:
            hit &= active
        ref.append(dr.select(hit, r, DONE))
        key.append(dr.select(hit, tn, dr.inf))
    if any_hit:             # farthest first: the ascending network on negated distances
        key = [dr.select(r != DONE, -k, dr.inf) for k, r in zip(key, ref)]
    for i, j in _network(W):
        swap = key[j] < key[i]
        key[i], key[j] = dr.select(swap, key[j], key[i]), dr.select(swap, key[i], key[j])
        ref[i], ref[j] = dr.select(swap, ref[j], ref[i]), dr.select(swap, ref[i], ref[j])
    for k in range(W - 1, 0, -1):
        stack.push(ref[k], ref[k] != DONE)
    nxt = ref[0]
    missed = nxt == DONE
    if active is not True:
        missed &= active
        nxt = dr.select(active, nxt, cur)
    stack.cur = dr.select(missed, cur, nxt)
    return stack, to_pop | missed


def child_boxes(t: Types, W: int, nodes, cur, active=True) -> list:
    """``[(lo, hi)]`` (Array3f) of the ``W`` children of node(s) ``cur``: ``nodes`` is
    a Float of SoA float boxes (``6 W`` per node) or a UInt32 of quantised records
    (``quantize``: ``record_words(W)`` words per node, decoded as ``origin + q * scale``)."""
    if dr.type_v(nodes) not in (dr.VarType.UInt32, dr.VarType.UInt64):
        f = gather_floats(t, nodes, cur, 6 * W, 6 * W, active)
        return [(t.Array3f(f[k], f[W + k], f[2 * W + k]),
                 t.Array3f(f[3 * W + k], f[4 * W + k], f[5 * W + k])) for k in range(W)]
    rec = gather_words(t, nodes, cur, record_words(W), HEAD + 6 * W // 4, active)
    F32 = array_type(t, "Float32")
    org = [t.Float(dr.reinterpret_array(F32, h)) for h in rec[:3]]
    scale = [t.Float(dr.reinterpret_array(F32, ((rec[3] >> (8 * a)) & 255) << 23))
             for a in range(3)]
    words = rec[HEAD:]
    q = [[t.Float((words[c * (W // 4) + k // 4] >> (8 * (k % 4))) & 255) for c in range(6)]
         for k in range(W)]
    return [(t.Array3f(*(dr.fma(q[k][a], scale[a], org[a]) for a in range(3))),
             t.Array3f(*(dr.fma(q[k][3 + a], scale[a], org[a]) for a in range(3))))
            for k in range(W)]


def _network(n: int) -> list[tuple[int, int]]:
    """Compare-exchange pairs of an ascending sorting network on ``n`` in (4, 8) keys
    (optimal networks: 5 and 19 comparators)."""
    if n == 4:
        return [(0, 1), (2, 3), (0, 2), (1, 3), (1, 2)]
    return [(0, 2), (1, 3), (4, 6), (5, 7), (0, 4), (1, 5), (2, 6), (3, 7), (0, 1), (2, 3),
            (4, 5), (6, 7), (2, 4), (3, 5), (1, 4), (3, 6), (1, 2), (3, 4), (5, 6)]


@dataclass
class WideBVH(Accelerator):
    """Wide BVH accelerator (see the module docstring).

    Build with ``WideBVH.build(scene, t, width=4, intersection=..., leaf_size=2, bins=32)``
    (``leaf_size``, ``bins`` and the other ``build_bvh`` keywords build the binary tree).
    nodes: Float (6 width N) SoA child boxes; refs: UInt32 (width N) child references;
    tri_data, tris: as ``BVH``; width: 4 or 8; backend, precision, intersection, info.
    """

    nodes: object
    refs: object
    tri_data: object
    tris: DeviceTriangles
    width: int = 4
    backend: str = "llvm"
    precision: str = "float32"
    intersection: str = DEFAULT_ROUTINE
    tie_break: str = "lowest"          # query.TIE_BREAKS; "other" only probes ties
    tie_window: float = 0.0            # t window (world units) of tie_break "other"
    tie_slack: float = 0.0             # edge slack (world units) of tie_break "other"
    info: dict = field(default_factory=dict, repr=False)
    tri_trav: object = None
    refill: int = 0
    reach: float = 0.0                 # origins the box padding covers (``traverse.box_ray``)

    @classmethod
    def build(cls, scene, t: Types, *, width: int = 4, quantized: bool | None = None,
              intersection: str = DEFAULT_ROUTINE, binary: BVHArrays | None = None,
              **build_options) -> "WideBVH":
        """``binary``: a binary build of ``scene`` to convert (else one is built with
        ``build_options``, ``build_bvh``'s keywords); ``quantized``: 8-bit child boxes
        (``quantize``; default for float32), else SoA boxes of the precision (default for
        float64). The host arrays of ``host_layout``, uploaded by ``from_layout``."""
        triangle_routine(intersection)
        a = binary if binary is not None else build_bvh(
            scene.vertices, scene.faces, **build_options)
        arrays, info = cls.host_layout(scene, t, a, width=width, quantized=quantized,
                                       intersection=intersection)
        info.update(leaf_size=build_options.get("leaf_size", LEAF_SIZE),
                    bins=build_options.get("bins", BINS))
        t0 = time.perf_counter()
        acc = cls.from_layout(t, arrays, info)
        acc.info["upload_seconds"] += time.perf_counter() - t0
        return acc

    @classmethod
    def host_layout(cls, scene, t: Types, a: BVHArrays, *, width: int = 4,
                    quantized: bool | None = None, intersection: str = DEFAULT_ROUTINE,
                    extent: float | None = None, triangles: dict | None = None
                    ) -> tuple[dict, dict]:
        """Everything the ``width``-wide accelerator of the binary tree ``a`` uploads, as
        host arrays in their device dtypes (``triangle_arrays``' and ``nodes``: uint32
        (N, ``record_words(width)``) quantised records, or (N, 6, width) SoA boxes of the
        precision; ``refs`` uint32 (N, width)), and its ``info`` (JSON-able; ``reach`` and
        ``width`` included). ``extent``, ``triangles``: as ``BVH.host_layout``."""
        triangle_routine(intersection)
        extent = pad_extent(scene, intersection) if extent is None else extent
        if quantized is None:  # 8-bit boxes are fitted to float32 boxes: float64 keeps floats
            quantized = not t.is_double
        a = replace(a, boxes=traversal_boxes(a, scene, t, intersection, extent))
        w = collapse(a, width)
        tq = time.perf_counter()
        fdt = np.float64 if t.is_double else np.float32
        nodes = quantize(w) if quantized else np.ascontiguousarray(w.boxes, fdt)
        quantize_seconds = time.perf_counter() - tq if quantized else 0.0
        t0 = time.perf_counter()
        arrays = dict(triangles or triangle_arrays(scene, t.is_double, a.order,
                                                   routine=intersection))
        arrays["nodes"] = nodes
        arrays["refs"] = np.ascontiguousarray(w.refs, np.uint32)
        fsize = 8 if t.is_double else 4
        F = max(scene.face_count, 1)
        info = {
            "accel": f"bvh{width}", "intersection": intersection,
            "build_seconds": a.build_seconds + w.convert_seconds + quantize_seconds,
            "binary_build_seconds": a.build_seconds,
            "convert_seconds": w.convert_seconds + quantize_seconds, "quantized": quantized,
            "upload_seconds": time.perf_counter() - t0, "triangles": scene.face_count,
            "nodes": w.node_count, "binary_nodes": a.node_count, "leaves": a.leaf_count,
            "levels": w.levels, "binary_levels": a.levels, "max_stack": w.max_stack,
            "sah_cost": a.sah_cost, "leaf_size": LEAF_SIZE, "bins": BINS, "width": width,
            "fill": float(np.mean(w.refs != DONE)),
            "node_bytes_per_triangle": w.node_count * (
                (4 * record_words(width) if quantized else 6 * fsize * width)
                + 4 * width) / F,
            "traversal_triangle_bytes_per_triangle": STRIDE * fsize,
            "reach": origin_reach(scene, intersection),
        }
        return arrays, info

    @classmethod
    def from_layout(cls, t: Types, arrays: dict, info: dict, own: bool = False
                    ) -> "WideBVH":
        """The accelerator on the device from ``host_layout``'s ``arrays`` and ``info``
        (uploads only: no host work beyond aligned copies; ``own``: the arrays are this
        call's to hand over, as ``device_triangles``)."""
        tri_data, tris = device_triangles(t, arrays, own)
        qwords, wrefs = arrays["nodes"], arrays["refs"]
        pairs = uses_pairs(t)
        put = host_view if own else host_array
        if info["quantized"]:
            nodes = (as_pairs(t, qwords, copy=not own) if pairs
                     else t.UInt32(put(qwords.reshape(-1))))
        else:
            fdt = np.float64 if t.is_double else np.float32
            nodes = t.Float(put(qwords.reshape(-1), fdt))
        refs = (as_pairs(t, wrefs, copy=not own) if pairs
                else t.UInt32(put(wrefs.reshape(-1))))
        tri_trav = traversal_triangles(t, tri_data)
        dr.eval(nodes, refs, tri_data, tri_trav, tris)
        info = dict(info)
        return cls(nodes, refs, tri_data, tris, width=int(info["width"]), backend=t.backend,
                   precision=t.precision, intersection=info["intersection"], info=info,
                   tri_trav=tri_trav, reach=float(info["reach"]))

    def counts(self, ray: Ray, active=True, any_hit: bool = False):
        """The instrumented traversal (profiling): ``(node_steps, triangle_steps,
        iterations)`` UInt32 per ray, the same traversal as the query with counters."""
        return self._traverse(ray, active, any_hit, counting=True)

    def _leaf_triangles(self, routine) -> LeafTriangles:
        """The triangles as the traversal reads them (``tri_trav`` where the backend has
        one), with ``routine``."""
        return LeafTriangles(t=self.types, routine=routine, order=self.tris.order,
                             data=self.tri_data if self.tri_trav is None else self.tri_trav)

    def _traverse(self, ray: Ray, active, any_hit: bool, probe=None, counting: bool = False):
        if self.refill and not counting and probe is None:
            n = dr.width(ray.o, ray.d, ray.t_max, active)
            lanes = refill_lanes(n, self.refill)
            if lanes < n:
                return refill_traversal(
                    self._leaf_triangles(triangle_routine(self.intersection)),
                    lambda r, best_t, stack, to_pop: wide_node_step(
                        self, r, best_t, stack, to_pop, any_hit, True),
                    ray, active, any_hit, lanes, f"bvh{self.width}_refill", self.reach)
        return self._traverse_lanes(ray, active, any_hit, probe, counting)

    @syntax
    def _traverse_lanes(self, ray: Ray, active, any_hit: bool, probe=None,
                        counting: bool = False):
        t, W = self.types, self.width
        r, active, n = setup(t, ray, active, self.reach)
        tris = self._leaf_triangles(bind_routine(triangle_routine(self.intersection),
                                                 r.o, r.d))
        stack = Stack.start(t, active, n)
        first = dr.zeros(t.UInt32, n)
        end = dr.zeros(t.UInt32, n)
        rec = Closest.empty(t, r.t_max, n)
        n_node = dr.zeros(t.UInt32, n)
        n_tri = dr.zeros(t.UInt32, n)
        n_iter = dr.zeros(t.UInt32, n)

        while dr.hint(active, max_iterations=-1, label=f"bvh{W}",
                      exclude=[self, t, tris, any_hit, probe, counting, W]):
            is_leaf, is_inner, first, end = enter_leaf(stack.cur, first, end)
            if dr.hint(counting, mode="scalar"):
                n_node += dr.select(is_inner, 1, 0)
                n_tri += dr.select(first < end, 1, 0)
                n_iter += 1
            cull = cull_t(rec, r.t_max, probe)   # boxes beyond it are skipped
            stack, to_pop = masked_step(
                t, is_inner,
                lambda stack, to_pop, on, best_t=cull: wide_node_step(
                    self, r, best_t, stack, to_pop, any_hit, on, probe_pad(probe)),
                (stack, is_leaf | False))
            stack.pop(to_pop)

            rec, first = leaf_triangle_step(tris, r, first, end, rec, any_hit, probe)
            if dr.hint(any_hit, mode="scalar"):
                active &= ~rec.found

            active &= (first < end) | (stack.cur != DONE)

        return traversal_result(rec, any_hit, (n_node, n_tri, n_iter) if counting else None)


class BVH4(WideBVH):
    """``WideBVH`` with 4 children per node (registered as ``bvh4``)."""

    @classmethod
    def build(cls, scene, t: Types, **kw) -> "WideBVH":
        kw.setdefault("width", 4)
        return super().build(scene, t, **kw)


class BVH8(WideBVH):
    """``WideBVH`` with 8 children per node (registered as ``bvh8``)."""

    @classmethod
    def build(cls, scene, t: Types, **kw) -> "WideBVH":
        kw.setdefault("width", 8)
        return super().build(scene, t, **kw)
