"""The accelerator interface, the shading attributes of its triangles and the gathers its
traversals read records with; the query records (``Ray``, ``ClosestHit``) are
``renderer.accel.query``'s, re-exported here.

An *accelerator* is any object with

    intersect(ray: Ray, active) -> ClosestHit   # closest hit in (0, ray.t_max)
    intersect_p(ray: Ray, active) -> Bool       # any hit in (0, ray.t_max) (shadow rays)
    tris: DeviceTriangles                       # shading attributes, indexed by ClosestHit.prim
    stats() -> dict                             # build time, node count, bytes per triangle, ...

``ray.d`` need not be unit length (``t`` is in units of ``d``); ``active`` is a Bool mask.
Every accelerator holds the same packed triangles (``renderer.accel.triangle``) and calls
the same triangle routine, so brute force, per-object boxes and the BVH return the same hits.

Device structs here and in the accelerators are plain typed dataclasses with no
hand-written Dr.Jit struct field list (with one, Dr.Jit 1.5 rebuilds only the listed
fields). Dr.Jit 1.5 treats a dataclass as a PyTree and rebuilds it (loop state,
``dr.copy``, ``dr.if_stmt``) with ALL its fields, Dr.Jit arrays and host values (str, dict)
alike. A symbolic loop updates such an object in place, so it holds no frozen dataclass:
the accelerators keep ``backend`` and ``precision`` as strings and look ``types`` up from
them.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass

import drjit as dr
import numpy as np

from ..device import Types, host_array, host_view, types
from .query import ClosestHit as ClosestHit
from .query import Ray as Ray
from .query import tie_probe, tie_probe_p


@dataclass
class DeviceTriangles:
    """Shading attributes of the triangles on the device, in the accelerator's order
    (``order``; an accelerator may permute triangles for locality; ``ClosestHit.prim``
    indexes these arrays).

    ng: Array3f (F,) unit geometric normal ``normalize(e1 × e2)``.
    n0, n1, n2: Array3f (F,) vertex normals (only uploaded when some object is smooth,
        else width-1 zeros).
    material: UInt32 (F,) material index; smooth: Bool (F,) interpolate normals.
    order: UInt32 (F,) original face index of each triangle.
    """

    ng: object
    n0: object
    n1: object
    n2: object
    material: object
    smooth: object
    order: object

    @property
    def count(self) -> int:
        return dr.width(self.material)


class Accelerator:
    """What the integrator needs from an accelerator (see the module docstring), and what
    every accelerator shares: ``intersect``/``intersect_p`` are one traversal
    ``_traverse(ray, active, any_hit, probe)`` each subclass writes; ``types`` and
    ``stats()`` come from the ``backend``/``precision``/``info`` fields of the subclass's
    dataclass.

    The tie probe: a subclass's dataclass also has the fields ``tie_break`` (a value of
    ``query.TIE_BREAKS``; "lowest", the renderer's, unless ``build_accelerator`` is told
    otherwise), ``tie_window`` and ``tie_slack`` (world-space distances). With "other"
    ``intersect``/``intersect_p`` run the traversal a second time with a ``query.Probe``
    (``query.tie_probe``/``tie_probe_p``); ``_traverse`` passes the probe to
    ``triangle_step`` and culls and pads its boxes by ``traverse.cull_t``/``probe_pad``."""

    tris: DeviceTriangles
    tie_break: str = "lowest"
    tie_window: float = 0.0
    tie_slack: float = 0.0

    @property
    def types(self) -> Types:
        return types(self.backend, self.precision)

    def stats(self) -> dict:
        return dict(self.info)

    def intersect(self, ray: Ray, active=True) -> ClosestHit:
        """Closest hit in ``(0, ray.t_max)`` (under ``tie_break``)."""
        return tie_probe(lambda r, a, pr: self._traverse(r, a, False, pr), ray, active,
                         self.tie_break, self.tie_window, self.tie_slack)

    def intersect_p(self, ray: Ray, active=True):
        """Any hit in ``(0, ray.t_max)`` (shadow rays); stops at the first hit."""
        return tie_probe_p(lambda r, a, pr: self._traverse(r, a, True, pr), ray, active,
                           self.tie_break, self.tie_slack)

    def _traverse(self, ray: Ray, active, any_hit: bool, probe=None):
        raise NotImplementedError


def array_type(t: Types, name: str) -> type:
    """The Dr.Jit array type ``name`` (e.g. "Array4f") of the module ``t``'s arrays come
    from."""
    return getattr(importlib.import_module(t.Float.__module__), name)


def gather_floats(t: Types, src, index, stride: int, count: int, active=True) -> list:
    """The first ``count`` floats of record ``index`` of ``src`` (records of ``stride``
    floats, a multiple of 4), per lane, with the gather the backend is fastest at: on CUDA
    packet gathers of Array4f (all of the record's quads that ``count`` touches); on LLVM
    one scalar gather per float (a packet gather is emitted there only when numpy's buffer
    happens to be 64-byte aligned, and costs more than scalar gathers on the CPU); where
    ``src`` is a UInt64 view of float32 records (``as_pairs``), one 64-bit gather per two
    floats (``gather_pairs``)."""
    if dr.type_v(src) == dr.VarType.UInt64:
        F32 = array_type(t, "Float32")
        return [t.Float(dr.reinterpret_array(F32, w))
                for w in gather_pairs(t, src, index, stride, count, active)]
    if t.backend == "llvm":
        base = index * stride
        return [dr.gather(t.Float, src, base + k, active) for k in range(count)]
    A4 = array_type(t, "Array4f64" if t.is_double else "Array4f")
    base = index * (stride // 4)
    out = []
    for k in range((count + 3) // 4):
        q = dr.gather(A4, src, base + k if k else base, active)
        out += [q.x, q.y, q.z, q.w]
    return out[:count]


def gather_pairs(t: Types, src, index, stride: int, count: int, active=True) -> list:
    """The first ``count`` 32-bit words (UInt32) of record ``index`` of ``src``, a UInt64
    view of records of ``stride`` 32-bit words (``stride`` even): one 64-bit gather per two
    words, each split into its low and high word (little-endian: word ``2k`` is the low
    half of qword ``k``). Why (LLVM): on the CPU a gather costs about one load per lane
    and element, whatever the element's width (16 scattered dwords cost as much as 16
    scattered qwords), so 64-bit gathers fetch a record with half the loads
    (``lab/notes/accel-decisions.md``)."""
    U32 = array_type(t, "UInt32")
    base = index * (stride // 2)
    out = []
    for k in range((count + 1) // 2):
        q = dr.gather(type(src), src, base + k if k else base, active)
        out += [U32(q), U32(q >> 32)]
    return out[:count]


def as_pairs(t: Types, words: np.ndarray, copy: bool = True):
    """A host array of 32-bit words (last axis even) as the UInt64 device array that
    ``gather_pairs`` reads; ``copy=False``: from ``words``' own memory where it is
    aligned (``device.host_view``: only for words no other device array is made from)."""
    # a fresh copy: ``words`` may be a view of a Dr.Jit array's memory (``.numpy()`` on
    # LLVM), and a second array on the same memory confuses ``dr.freeze``, which tells
    # its inputs apart by address (it then compiled float ops on the UInt64 view)
    # (``host_array``: aligned, so the traced kernel does not depend on the address)
    w = host_array(words, np.uint32) if copy else host_view(words, np.uint32)
    return array_type(t, "UInt64")(w.view(np.uint64).reshape(-1))


def device_pairs(t: Types, x):
    """A 32-bit device array ``x`` (Float or UInt32 of even width) as the UInt64 array that
    ``gather_pairs`` reads, made on the device: word ``2 i`` the low half of pair ``i``
    (``as_pairs`` of the same words on the host)."""
    UInt32, UInt64 = t.UInt32, array_type(t, "UInt64")
    w = x if isinstance(x, UInt32) else dr.reinterpret_array(UInt32, x)
    i = dr.arange(UInt32, dr.width(w) // 2) * 2
    return UInt64(dr.gather(UInt32, w, i)) | (UInt64(dr.gather(UInt32, w, i + 1)) << 32)


def uses_pairs(t: Types) -> bool:
    """Whether the traversals of ``t`` read their float32/UInt32 records through 64-bit
    gathers (``gather_pairs``): on LLVM in float32 (float64 records are 64-bit already;
    CUDA reads quads with packet gathers)."""
    return t.backend == "llvm" and not t.is_double


def traversal_triangles(t: Types, tri_data):
    """The copy of the packed triangles ``tri_data`` that the traversal reads: a UInt64
    view for ``gather_pairs`` where ``uses_pairs(t)``, else None (read ``tri_data``).
    ``tri_data`` itself stays a Float for shading, which gathers one triangle per hit."""
    if not uses_pairs(t):
        return None
    return as_pairs(t, tri_data.numpy().view(np.uint32))
