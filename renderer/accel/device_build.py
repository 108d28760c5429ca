"""BVH build on the device (Dr.Jit, the same code on CUDA and LLVM): a Morton-code radix tree.

Steps, each a few Dr.Jit kernels over all triangles or all nodes of one level:

1. triangle boxes and the scene box (device reductions);
2. 30-bit Morton codes of the box centres in the scene box, large triangles
   (``BIG_TRIANGLE``) keyed after all others, sorted by ``dr.argsort`` (a radix sort);
3. the tree top down, one inner-node level at a time: a node over the sorted range
   ``[s, e]`` splits where the highest bit in which ``code[s]`` and ``code[e]`` differ
   flips (a binary search over the range: the Karras radix-tree split), at the range's
   middle where the codes are equal or where the radix split would need more than
   ``MAX_LEVELS`` levels (so the traversal stack never overflows). Children of at most
   ``leaf_size`` triangles are leaves; the others are the next level's nodes, compacted by
   ``dr.compress`` (one count read per level, the only host round trips of the build);
4. the child boxes bottom up, deepest level first: a leaf's box reduced over its (at most
   ``leaf_size``) triangles, an inner child's the union of its own two child boxes.

The result is a ``BVHArrays`` like ``bvh_build.build_bvh``'s (inner nodes numbered level
by level, so every level is one contiguous run of nodes), its boxes padded on the device by
``pad_boxes``'s rule (the same float32 operations) and its SAH cost summed there, so the
traversal, the wide conversion and the refit read it as they read the SAH tree, and the
hits are the same bit for bit. With ``raw=True`` it also carries the unpadded child boxes
(``BVHArrays.raw``), which the traversal pads for its ray origins instead of refitting on
the host. The interface to any other device builder is the same ``BVHArrays`` (boxes
padded by ``pad_boxes``'s rule, children, order, levels, SAH cost, optionally ``raw``).
"""
from __future__ import annotations

import importlib
import math
import time
from dataclasses import dataclass, field

import drjit as dr
import numpy as np

from .. import parallel
from ..device import host_array
from .bvh_build import C_TRAV, LEAF_SIZE, MAX_LEVELS, BVHArrays, build_bvh
from .traverse import COUNT_SHIFT, LEAF_BIT, MAX_LEAF
from .triangle import unit_roundoff

MORTON_BITS = 10                 # bits per axis: 30-bit codes
#: Triangles whose box is larger than this fraction of the scene box's longest side (along
#: their own longest side) sort after all others (bit 30 of the key), so the root splits
#: them off and the small triangles' subtrees keep tight boxes (a floor or wall triangle in
#: a Morton cell of small ones would grow every box above it). Of 1/4, 1/8, 1/16, 1/32, 1/64
#: and none, 1/4 gives the lowest SAH cost on the bunny, Sponza and Conference
#: (``lab/notes/device-build.md``).
BIG_TRIANGLE = 0.25


def _module(backend: str):
    if backend not in ("cuda", "llvm"):
        raise ValueError(f"backend: expected 'cuda' or 'llvm', got {backend!r}")
    return importlib.import_module(f"drjit.{backend}")


def _spread(x):
    """The 10 low bits of UInt32 ``x`` spread to every third bit (Morton interleave)."""
    x = (x | (x << 16)) & 0x030000FF
    x = (x | (x << 8)) & 0x0300F00F
    x = (x | (x << 4)) & 0x030C30C3
    x = (x | (x << 2)) & 0x09249249
    return x


def _levels_needed(count, leaf_size: int):
    """UInt32: inner-node levels a median-split subtree over ``count`` (UInt32) triangles
    needs: ``ceil(log2(ceil(count / leaf_size)))``, 0 for a leaf."""
    leaves = (count + (leaf_size - 1)) // leaf_size
    return dr.select(leaves > 1, 32 - dr.lzcnt(dr.maximum(leaves, 1) - 1), 0)


def _phase(phases: dict, name: str, t_phase: list) -> None:
    """Wait for the device, add the seconds since ``t_phase[0]`` to ``phases[name]``."""
    dr.sync_thread()
    now = time.perf_counter()
    phases[name] = phases.get(name, 0.0) + now - t_phase[0]
    t_phase[0] = now


def _bisect(UInt32, code, bit, a, b):
    """One bisection step of the split search: ``(a, b)`` halved towards the first code
    in ``(a, b]`` with ``bit`` set."""
    mid = (a + b) >> 1
    has = (dr.gather(UInt32, code, mid) & bit) != 0
    return dr.select(has, a, mid), dr.select(has, mid, b)


def triangle_boxes(m, Vn: np.ndarray, Fn: np.ndarray):
    """The float32 box ``(lo, hi)`` (3 ``m.Float`` each) of every face ``Fn`` (int (F, 3))
    of ``Vn`` (float32 (V, 3), contiguous), evaluated: one upload of each array as it lies
    in memory (no per-column copies on the host; on LLVM through ``host_array``: aligned,
    so the LLVM kernels do not depend on numpy's addresses), the kernel gathering corner
    k's axis a at ``3 * face[3 f + k] + a``."""
    Float, UInt32 = m.Float, m.UInt32
    f_h = np.ascontiguousarray(Fn).reshape(-1)
    if m.__name__.endswith("cuda"):           # a copy to the device: alignment moot
        v_flat = Float(Vn.reshape(-1))
        f_flat = UInt32(f_h.view(np.uint32) if f_h.dtype in (np.int32, np.uint32) else
                        f_h.astype(np.uint32))
    else:
        v_flat = Float(host_array(Vn.reshape(-1)))
        f_flat = UInt32(host_array(f_h, np.uint32))
    i3 = dr.arange(UInt32, int(Fn.shape[0])) * 3
    fi = [dr.gather(UInt32, f_flat, i3 + k) * 3 for k in range(3)]
    lo, hi = [], []
    for a in range(3):
        p = [dr.gather(Float, v_flat, fi[k] + a) for k in range(3)]
        lo.append(dr.minimum(dr.minimum(p[0], p[1]), p[2]))
        hi.append(dr.maximum(dr.maximum(p[0], p[1]), p[2]))
    dr.eval(lo, hi)
    return lo, hi


def morton_codes(UInt32, lo, hi):
    """``(code, s_lo, s_hi)``: the ``3 * MORTON_BITS``-bit Morton code of each box centre
    (``lo``, ``hi``: 3 arrays each), normalised per axis in the boxes' scene box
    ``(s_lo, s_hi)`` (3 floats each, evaluated on the device)."""
    s_lo = [dr.min(x) for x in lo]
    s_hi = [dr.max(x) for x in hi]
    scale = float(1 << MORTON_BITS)
    code = dr.zeros(UInt32, dr.width(lo[0]))
    for k in range(3):
        ext = s_hi[k] - s_lo[k]
        inv = dr.select(ext > 0, scale / dr.maximum(ext, 1e-30), 0.0)
        c = (lo[k] + hi[k]) * 0.5
        q = UInt32(dr.clip((c - s_lo[k]) * inv, 0.0, scale - 1.0))
        code |= _spread(q) << (2 - k)
    return code, s_lo, s_hi


def _read_back(parts):
    """The host copies (numpy) of the evaluated 32-bit device arrays ``parts`` (Float or
    UInt32 of one backend). On CUDA they travel as one buffer: one device-to-host copy and
    one wait instead of one each; on LLVM each is read where it lies (no copy)."""
    if dr.backend_v(parts[0]) != dr.JitBackend.CUDA:
        return [x.numpy() for x in parts]
    m = _module("cuda")
    UInt32 = m.UInt32
    widths = [dr.width(x) for x in parts]
    buf = dr.empty(UInt32, sum(widths))
    at = 0
    for x, w in zip(parts, widths):
        bits = x if isinstance(x, UInt32) else dr.reinterpret_array(UInt32, x)
        dr.scatter(buf, bits, dr.opaque(UInt32, at) + dr.arange(UInt32, w))
        at += w
    host = buf.numpy()
    out, at = [], 0
    for x, w in zip(parts, widths):
        out.append(host[at:at + w] if isinstance(x, UInt32) else host[at:at + w].view(
            np.float32))
        at += w
    return out


def _summary_words(m, scene_box, area):
    """The scene box ``(s_lo, s_hi)`` (3 one-lane Floats each) and the SAH area (one-lane
    Float64) as 8 UInt32 words (lo, hi, the area's two words), evaluated."""
    bits = dr.reinterpret_array(m.UInt64, area)
    small = dr.zeros(m.UInt32, 8)
    for k, x in enumerate(list(scene_box[0]) + list(scene_box[1])):
        dr.scatter(small, dr.reinterpret_array(m.UInt32, x), k)
    dr.scatter(small, m.UInt32(bits & 0xFFFFFFFF), 6)
    dr.scatter(small, m.UInt32(bits >> 32), 7)
    dr.eval(small)
    return small


def _summary(small_h: np.ndarray) -> tuple:
    """``(bounds, sah_cost)`` from ``_summary_words``' host copy."""
    small_h = np.ascontiguousarray(small_h, np.uint32)
    b_lo, b_hi = small_h[:3].view(np.float32), small_h[3:6].view(np.float32)
    area_h = float(small_h[6:8].view(np.float64)[0])
    bounds = (b_lo.astype(np.float64), b_hi.astype(np.float64))
    dd = bounds[1] - bounds[0]
    root = float(dd[0] * dd[1] + dd[1] * dd[2] + dd[2] * dd[0])
    return bounds, ((C_TRAV * root + area_h) / root if root > 0 else 0.0)


def host_arrays(boxes_d, refs_d, order_d, raw_d, scene_box, area, levels: int) -> BVHArrays:
    """The host ``BVHArrays`` of a tree built on the device: its padded node boxes
    (``boxes_d``, 12 Floats a node), child references (``refs_d``, 2 UInt32 a node),
    triangle order, unpadded boxes (``raw_d``, or None), the scene box ``(s_lo, s_hi)`` (3
    one-lane Floats each), the sum of the nodes' weighted half areas (``area``, one-lane
    Float64) that gives the SAH cost, and the number of levels. One read back
    (``_read_back``) brings all of them."""
    n = dr.width(refs_d) // 2
    m = _module("cuda" if dr.backend_v(boxes_d) == dr.JitBackend.CUDA else "llvm")
    small = _summary_words(m, scene_box, area)
    host = _read_back([boxes_d, refs_d, order_d, small]
                      + ([raw_d] if raw_d is not None else []))
    boxes = np.asarray(host[0], np.float32).reshape(n, 12)
    ch = np.asarray(host[1], np.uint32).reshape(n, 2)
    order = np.asarray(host[2], np.int64)
    bounds, sah = _summary(host[3])
    leaf_count = int(np.count_nonzero(ch & np.uint32(LEAF_BIT)))
    raw_h = np.asarray(host[4], np.float32).reshape(n, 12) if raw_d is not None else None
    return BVHArrays(boxes, ch, order, levels, leaf_count, sah, 0.0, bounds, raw=raw_h)


def write_box(m, boxes_d, at, lo, hi, pad):
    """Scatter the box ``(lo, hi)`` (3 Floats each) padded by ``pad_boxes``'s rule (``pad``:
    32 units of roundoff, the scene extent, and None or the Float that gets the unpadded
    box at the same place) to ``boxes_d[at .. at + 5]``; answers its half surface area
    (Float64)."""
    u32, extent, raw_d = pad
    d = []
    for a in range(3):                    # pad_boxes: 32 roundoff x (magnitude + extent)
        e = (dr.maximum(abs(lo[a]), abs(hi[a])) + extent) * u32
        lo_a, hi_a = lo[a] - e, hi[a] + e
        dr.scatter(boxes_d, lo_a, at + a)
        dr.scatter(boxes_d, hi_a, at + 3 + a)
        if raw_d is not None:
            dr.scatter(raw_d, lo[a], at + a)
            dr.scatter(raw_d, hi[a], at + 3 + a)
        d.append(m.Float64(hi_a - lo_a))
    return d[0] * d[1] + d[1] * d[2] + d[2] * d[0]


@dataclass
class DeviceTree:
    """A tree built on the device and left there: ``host_arrays``' arguments (padded node
    boxes ``boxes``, 12 Floats a node; child references ``children``, 2 UInt32 a node;
    the triangle order ``order``, UInt32; the unpadded boxes ``raw``; the scene box and
    the SAH area on the device; ``levels``) and the build's seconds. An accelerator is
    made from it on the device (``bvh.BVH.from_device_tree``); ``host()`` copies it back
    once (one read) for a cache entry or a host consumer."""

    boxes: object
    children: object
    order: object
    raw: object
    scene_box: tuple
    area: object
    levels: int
    build_seconds: float = 0.0
    _host: BVHArrays | None = field(default=None, repr=False)

    @property
    def node_count(self) -> int:
        return dr.width(self.children) // 2

    def summary(self) -> tuple:
        """``(leaf_count, sah_cost, bounds)`` (as ``BVHArrays``') from one small read; the
        tree stays on the device."""
        if self._host is not None:
            return self._host.leaf_count, self._host.sah_cost, self._host.bounds
        m = _module("cuda" if dr.backend_v(self.children) == dr.JitBackend.CUDA else "llvm")
        leaves = dr.sum(dr.select((self.children & LEAF_BIT) != 0, m.UInt32(1), 0))
        dr.eval(leaves)
        small, leaves = _read_back([_summary_words(m, self.scene_box, self.area), leaves])
        bounds, sah = _summary(small)
        return int(leaves[0]), sah, bounds

    def padded(self, extent: float):
        """The node boxes the traversal reads for a scene of padding extent ``extent``
        (``triangle.pad_extent``): the unpadded boxes grown by ``write_box``, the device
        form of ``bvh_build.pad_boxes``' float32 rule (the same operations as ``pad_refit``
        on the host; a device tree has two leaves at least, so no empty child box); a
        Float of 12 per node, evaluated."""
        m = _module("cuda" if dr.backend_v(self.raw) == dr.JitBackend.CUDA else "llvm")
        Float, UInt32 = m.Float, m.UInt32
        i = dr.arange(UInt32, dr.width(self.raw) // 6) * 6      # a child box each
        lo = [dr.gather(Float, self.raw, i + a) for a in range(3)]
        hi = [dr.gather(Float, self.raw, i + 3 + a) for a in range(3)]
        out = dr.empty(Float, dr.width(self.raw))
        write_box(m, out, i, lo, hi, (float(32 * unit_roundoff(False)), extent, None))
        dr.eval(out)
        return out

    def host(self) -> BVHArrays:
        """The ``BVHArrays`` of this tree (copied back at the first call)."""
        if self._host is None:
            self._host = host_arrays(self.boxes, self.children, self.order, self.raw,
                                     self.scene_box, self.area, self.levels)
            self._host.build_seconds = self.build_seconds
        return self._host


def _indices_within(Fn: np.ndarray, V: int) -> bool:
    """Whether every index of ``Fn`` lies in ``[0, V)``: the rows' minimum and maximum
    over spans on the host threads (``renderer.parallel``)."""
    flat = Fn.reshape(-1)
    bad = []

    def span(lo, hi):
        part = flat[lo:hi]
        if int(part.min()) < 0 or int(part.max()) >= V:
            bad.append((lo, hi))
    parallel.for_spans(flat.size, span)
    return not bad


def checked_input(vertices, faces, leaf_size: int) -> tuple:
    """What a device builder starts from: ``(Vn, Fn, small)``, the vertices as contiguous
    float32 and the faces as given; ``small`` is ``build_bvh``'s single-leaf tree for a
    scene of at most ``leaf_size`` triangles, else None. ValueError for a leaf size out of
    1..``MAX_LEAF``, more triangles than a leaf reference can count, face indices outside
    the vertices, or a scene needing more than ``MAX_LEVELS`` levels."""
    if not 1 <= leaf_size <= MAX_LEAF:
        raise ValueError(f"leaf_size: expected 1..{MAX_LEAF}, got {leaf_size}")
    Vn = np.ascontiguousarray(np.asarray(vertices, np.float32))
    Fn = np.asarray(faces)
    F = int(Fn.shape[0])
    if F >= 1 << COUNT_SHIFT:
        raise ValueError(f"faces: at most {1 << COUNT_SHIFT} triangles, got {F}")
    if F <= leaf_size:
        return Vn, Fn, build_bvh(Vn, Fn.astype(np.int64), leaf_size=leaf_size, spatial=0.0,
                                 optimize=0)
    if Fn.size and not _indices_within(Fn, Vn.shape[0]):
        raise ValueError(f"faces: indices must lie in [0, {Vn.shape[0]})")
    if MAX_LEVELS < math.ceil(math.log2(math.ceil(F / leaf_size))) + 1:
        raise ValueError(f"faces: {F} triangles need more than {MAX_LEVELS} BVH levels")
    return Vn, Fn, None


def build_device(vertices: np.ndarray, faces: np.ndarray, backend: str = "llvm", *,
                 leaf_size: int = LEAF_SIZE, progress=None,
                 phases: dict | None = None, raw: bool = False) -> BVHArrays:
    """Build a BVH over ``faces`` (int (F, 3)) of ``vertices`` (float (V, 3)) on ``backend``
    ("cuda" or "llvm"; see the module docstring). ``leaf_size``: most triangles per leaf
    (1..16). ``progress``: called as ``progress(levels_done)`` after each level.
    ``phases``: None, or a dict that gets the seconds of each phase (the build then waits
    for the device at each phase's end, which costs a little). A scene of at most
    ``leaf_size`` triangles gets ``build_bvh``'s single-leaf tree. ``raw``: also copy back
    the unpadded child boxes (``BVHArrays.raw``, what ``bvh_build.raw_boxes`` computes on
    the host), so the traversal pads them for its ray origins without a host refit."""
    m = _module(backend)
    t_start = time.perf_counter()
    Vn, Fn, small = checked_input(vertices, faces, leaf_size)
    if small is not None:
        return small
    F = int(Fn.shape[0])
    Float, UInt32 = m.Float, m.UInt32
    t_phase = [t_start]

    # ---- 1. triangle boxes and the scene box -----------------------------------------------
    # one upload of each array as it lies in memory (no per-column copies on the host);
    # the kernel gathers corner k's axis a at 3 * face[3 f + k] + a
    # (``host_array``: aligned, so the LLVM kernels do not depend on numpy's addresses)
    lo, hi = triangle_boxes(m, Vn, Fn)
    if phases is not None:
        _phase(phases, "triangle boxes", t_phase)

    # ---- 2. Morton codes of the box centres, sorted ---------------------------------------
    code, s_lo, s_hi = morton_codes(UInt32, lo, hi)
    size = dr.maximum(dr.maximum(hi[0] - lo[0], hi[1] - lo[1]), hi[2] - lo[2])
    ext = dr.maximum(dr.maximum(s_hi[0] - s_lo[0], s_hi[1] - s_lo[1]), s_hi[2] - s_lo[2])
    code |= dr.select(size > ext * BIG_TRIANGLE, UInt32(1 << 30), 0)
    perm = dr.argsort(code)
    code = dr.gather(UInt32, code, perm)
    slo = [dr.gather(Float, x, perm) for x in lo]        # triangle boxes in sorted order
    shi = [dr.gather(Float, x, perm) for x in hi]
    dr.eval(code, perm, slo, shi)
    del lo, hi
    if phases is not None:
        _phase(phases, "Morton codes and sort", t_phase)

    # ---- 3. topology, top down ------------------------------------------------------------
    first, count = dr.opaque(UInt32, 0, 1), dr.opaque(UInt32, F, 1)   # the root level
    level_base, level_size, level_refs = [], [], []
    n_nodes, k = 0, 1
    while k:
        depth = len(level_base)
        level_base.append(n_nodes)
        level_size.append(k)
        n_nodes += k
        s, e = first, first + count - 1
        cs, ce = dr.gather(UInt32, code, s), dr.gather(UInt32, code, e)
        diff = cs ^ ce
        bit = UInt32(1) << (31 - dr.lzcnt(dr.maximum(diff, 1)))
        # code[a] lacks the bit, code[b] has it: bisect to the first index that has it
        a, b = dr.while_loop(
            state=(UInt32(s), UInt32(e)),
            cond=lambda a, b: b - a > 1,
            body=lambda a, b, bit=bit: _bisect(UInt32, code, bit, a, b),
            label="device_build_split")
        left = dr.select(diff != 0, b - s, count >> 1)
        big = dr.maximum(left, count - left)
        over = dr.opaque(UInt32, depth + 1) + _levels_needed(big, leaf_size) > MAX_LEVELS
        left = dr.select(over, count >> 1, left)
        dr.eval(left)
        # children: lane 2 i + side is child ``side`` of this level's node i
        lane = dr.arange(UInt32, 2 * k)
        node = lane >> 1
        side = lane & 1
        n_first = dr.gather(UInt32, first, node)
        n_count = dr.gather(UInt32, count, node)
        n_left = dr.gather(UInt32, left, node)
        c_first = dr.select(side == 0, n_first, n_first + n_left)
        c_count = dr.select(side == 0, n_left, n_count - n_left)
        leaf = c_count <= leaf_size
        ref = dr.select(leaf, LEAF_BIT | ((c_count - 1) << COUNT_SHIFT) | c_first, 0)
        dr.eval(ref, c_first, c_count, leaf)
        pend = dr.compress(~leaf)                          # the next level's nodes
        k = dr.width(pend)
        if k:           # inner children: the next level's nodes, numbered in lane order
            dr.scatter(ref, dr.opaque(UInt32, n_nodes) + dr.arange(UInt32, k), pend)
            first = dr.gather(UInt32, c_first, pend)
            count = dr.gather(UInt32, c_count, pend)
            dr.eval(ref, first, count)
        level_refs.append(ref)
        if progress is not None:
            progress(len(level_base))
    levels = len(level_base)
    if phases is not None:
        _phase(phases, "topology", t_phase)

    # ---- 4. child boxes, bottom up ---------------------------------------------------------
    # (unpadded, as BVHArrays.boxes; every inner child of a level's node is in the next level)
    below, level_boxes = None, []
    for depth in reversed(range(levels)):
        size, refs = level_size[depth], level_refs[depth]
        i = dr.arange(UInt32, size)
        out = []
        for side in range(2):
            ref = dr.gather(UInt32, refs, 2 * i + side)
            is_leaf = (ref & LEAF_BIT) != 0
            inner = ~is_leaf
            lo_c, hi_c = [dr.full(Float, dr.inf, size) for _ in range(3)], \
                [dr.full(Float, -dr.inf, size) for _ in range(3)]
            if below is not None:
                j = ref - dr.opaque(UInt32, level_base[depth + 1])
                for a in range(3):
                    lo_c[a] = dr.select(inner, dr.minimum(dr.gather(Float, below[a], j, inner),
                                                          dr.gather(Float, below[6 + a], j,
                                                                    inner)), lo_c[a])
                    hi_c[a] = dr.select(inner, dr.maximum(dr.gather(Float, below[3 + a], j,
                                                                    inner),
                                                          dr.gather(Float, below[9 + a], j,
                                                                    inner)), hi_c[a])
            f0 = ref & ((1 << COUNT_SHIFT) - 1)
            cnt = ((ref >> COUNT_SHIFT) & 15) + 1
            for jj in range(leaf_size):
                on = is_leaf & (cnt > jj)
                for a in range(3):
                    lo_c[a] = dr.select(on, dr.minimum(lo_c[a],
                                                       dr.gather(Float, slo[a], f0 + jj, on)),
                                        lo_c[a])
                    hi_c[a] = dr.select(on, dr.maximum(hi_c[a],
                                                       dr.gather(Float, shi[a], f0 + jj, on)),
                                        hi_c[a])
            out += lo_c + hi_c
        dr.eval(out)
        level_boxes.append(out)
        below = out
    level_boxes.reverse()

    if phases is not None:
        _phase(phases, "boxes bottom up", t_phase)

    # ---- 5. padded boxes and references in the host layout, on the device -----------------
    N = n_nodes
    extent = dr.maximum(dr.maximum(s_hi[0] - s_lo[0], s_hi[1] - s_lo[1]), s_hi[2] - s_lo[2])
    u32 = float(32 * unit_roundoff(False))
    boxes_d = dr.zeros(Float, 12 * N)
    raw_d = dr.zeros(Float, 12 * N) if raw else None
    refs_d = dr.zeros(UInt32, 2 * N)
    area = dr.zeros(m.Float64, 1)
    for depth in range(levels):
        base, size = dr.opaque(UInt32, level_base[depth]), level_size[depth]
        i = dr.arange(UInt32, size)
        ids = base + i
        lb, refs = level_boxes[depth], level_refs[depth]
        for side in range(2):
            ref = dr.gather(UInt32, refs, 2 * i + side)
            padded = []
            for a in range(3):             # pad_boxes: 32 roundoff x (magnitude + extent)
                lo_a, hi_a = lb[6 * side + a], lb[6 * side + 3 + a]
                e = (dr.maximum(abs(lo_a), abs(hi_a)) + extent) * u32
                padded.append((lo_a - e, hi_a + e))
            for a in range(3):
                dr.scatter(boxes_d, padded[a][0], 12 * ids + 6 * side + a)
                dr.scatter(boxes_d, padded[a][1], 12 * ids + 6 * side + 3 + a)
                if raw:
                    dr.scatter(raw_d, lb[6 * side + a], 12 * ids + 6 * side + a)
                    dr.scatter(raw_d, lb[6 * side + 3 + a], 12 * ids + 6 * side + 3 + a)
            d = [m.Float64(padded[a][1] - padded[a][0]) for a in range(3)]
            half = d[0] * d[1] + d[1] * d[2] + d[2] * d[0]
            weight = dr.select((ref & LEAF_BIT) != 0,
                               m.Float64(((ref >> COUNT_SHIFT) & 15) + 1), 1.0)
            area += dr.sum(half * weight)
        dr.scatter(refs_d, refs, 2 * base + dr.arange(UInt32, 2 * size))
    dr.eval(boxes_d, refs_d, area, raw_d)

    # ---- the host arrays ------------------------------------------------------------------
    arrays = host_arrays(boxes_d, refs_d, perm, raw_d if raw else None, (s_lo, s_hi), area,
                         levels)
    arrays.build_seconds = time.perf_counter() - t_start
    if phases is not None:
        _phase(phases, "host layout and copy", t_phase)
    return arrays
