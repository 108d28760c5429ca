"""Closest-hit and any-hit queries behind one interface.

An *accelerator* is any object with

    intersect(o, d, t_max, active) -> Hit       # closest hit in (t_min, t_max)
    intersect_p(o, d, t_max, active) -> Bool    # any hit in (t_min, t_max) (shadow rays)

where ``o, d`` are Array3f (``d`` need not be unit length; ``t`` is in units of ``d``),
``t_max`` a Float and ``active`` a Bool mask. Every accelerator holds the same
``DeviceTriangles`` (uploaded once) and calls the same triangle routine
(``renderer.triangle.ROUTINES``), so brute force, per-object boxes and the BVH return the
same hits. ``ACCELERATORS`` maps the names used on the command line to builders:
``build_accelerator(name, scene, tris, t)``.
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import numpy as np

from .device import Types
from .scene import Scene
from .triangle import ROUTINES


@dataclass
class DeviceTriangles:
    """Triangle data on the device, in the order of ``order`` (an accelerator may permute
    triangles for locality; ``prim`` ids in ``Hit`` index these arrays).

    v0, e1, e2: Array3f (F,) first vertex and edge vectors (Möller–Trumbore).
    n0, n1, n2: Array3f (F,) vertex normals (only uploaded when some object is smooth,
        else width-1 zeros).
    ng: Array3f (F,) unit geometric normal ``normalize(e1 × e2)``.
    material: UInt32 (F,) material index; smooth: Bool (F,) interpolate normals.
    order: UInt32 (F,) original face index of each triangle.
    """

    v0: object = None
    e1: object = None
    e2: object = None
    n0: object = None
    n1: object = None
    n2: object = None
    ng: object = None
    material: object = None
    smooth: object = None
    order: object = None
    DRJIT_STRUCT = {"v0": object, "e1": object, "e2": object, "n0": object, "n1": object,
                    "n2": object, "ng": object, "material": object, "smooth": object,
                    "order": object}

    @property
    def count(self) -> int:
        return dr.width(self.material)


def upload_triangles(scene: Scene, t: Types, order: np.ndarray | None = None,
                     with_normals: bool | None = None) -> DeviceTriangles:
    """Upload ``scene``'s triangles (optionally permuted by ``order``, int (F,)) as
    ``DeviceTriangles`` of types ``t``. Normals are uploaded when ``with_normals`` (default:
    when any object is smooth)."""
    F = scene.face_count
    order = np.arange(F, dtype=np.int64) if order is None else np.asarray(order, np.int64)
    fdt = np.float64 if t.is_double else np.float32
    faces = scene.faces[order]
    V = scene.vertices.astype(np.float64)
    p0, p1, p2 = V[faces[:, 0]], V[faces[:, 1]], V[faces[:, 2]]
    e1, e2 = p1 - p0, p2 - p0
    ng = np.cross(e1, e2)
    ng /= np.maximum(np.linalg.norm(ng, axis=1, keepdims=True), 1e-300)

    def a3(x):
        x = np.ascontiguousarray(x, dtype=fdt)
        return t.Array3f(t.Float(x[:, 0]), t.Float(x[:, 1]), t.Float(x[:, 2]))

    smooth = scene.face_smooth[order]
    if with_normals is None:
        with_normals = bool(smooth.any())
    if with_normals:
        N = scene.normals.astype(np.float64)
        n0, n1, n2 = (a3(N[faces[:, k]]) for k in range(3))
    else:
        n0 = n1 = n2 = t.Array3f(0, 0, 0)
    return DeviceTriangles(
        v0=a3(p0), e1=a3(e1), e2=a3(e2), n0=n0, n1=n1, n2=n2, ng=a3(ng),
        material=t.UInt32(scene.face_material[order].astype(np.uint32)),
        smooth=t.Bool(smooth), order=t.UInt32(order.astype(np.uint32)))


@dataclass
class Hit:
    """Result of a closest-hit query (all arrays of the ray batch's width).

    valid: Bool; t: Float ray parameter; u, v: Float barycentrics of v1, v2;
    prim: UInt32 index into DeviceTriangles (undefined where not valid).
    """

    valid: object = None
    t: object = None
    u: object = None
    v: object = None
    prim: object = None
    DRJIT_STRUCT = {"valid": object, "t": object, "u": object, "v": object, "prim": object}


def triangle_routine(name: str):
    try:
        return ROUTINES[name]
    except KeyError:
        raise ValueError(f"intersection: expected one of {sorted(ROUTINES)}, got {name!r}") from None


# ---- the accelerator registry -----------------------------------------------------------
# Each accelerator is a dataclass carrying DRJIT_STRUCT over its device arrays (so symbolic
# loops and dr.freeze see them), built by ``cls.build(scene, t, intersection=...)``, with
# ``intersect``/``intersect_p`` as described at the top of this module and a ``stats()`` dict
# (build time, node count, bytes per triangle, ...).
ACCELERATORS = {
    "brute": ("renderer.intersect", "BruteForce"),
    "boxes": ("renderer.bvh", "ObjectBoxes"),
    "bvh": ("renderer.bvh", "BVH"),
}


def build_accelerator(name: str, scene: Scene, t: Types, *, intersection: str = "moller_trumbore"):
    """Build the accelerator ``name`` ("brute" | "boxes" | "bvh") for ``scene``."""
    import importlib
    if name not in ACCELERATORS:
        raise ValueError(f"accel: expected one of {sorted(ACCELERATORS)}, got {name!r}")
    triangle_routine(intersection)  # validate early
    module, cls = ACCELERATORS[name]
    return getattr(importlib.import_module(module), cls).build(scene, t, intersection=intersection)


# ---- brute force ------------------------------------------------------------------------
@dataclass
class BruteForce:
    """Every ray tests every triangle (the reference accelerator).

    tris: DeviceTriangles, in scene order.
    intersection: name of the triangle routine (``renderer.triangle.ROUTINES``).
    build_seconds: host time of the upload.

    The candidate loop is a symbolic loop over triangle indices; per candidate it gathers
    ``v0, e1, e2`` only, and the closest hit keeps ``(t, u, v, prim)``. Rays start at their
    offset origin, so ``t_min = 0``.
    """

    tris: DeviceTriangles = None
    intersection: str = "moller_trumbore"
    build_seconds: float = 0.0
    DRJIT_STRUCT = {"tris": DeviceTriangles}

    @classmethod
    def build(cls, scene: Scene, t: Types, *, intersection: str = "moller_trumbore") -> "BruteForce":
        import time
        triangle_routine(intersection)
        t0 = time.perf_counter()
        tris = upload_triangles(scene, t)
        dr.eval(tris)
        return cls(tris=tris, intersection=intersection,
                   build_seconds=time.perf_counter() - t0)

    def _candidate(self, i, o, d):
        """Test triangle ``i`` (UInt32, same type as the ray batch) against the rays."""
        tr = self.tris
        A3 = type(o)
        v0 = dr.gather(A3, tr.v0, i)
        e1 = dr.gather(A3, tr.e1, i)
        e2 = dr.gather(A3, tr.e2, i)
        return triangle_routine(self.intersection)(o, d, v0, e1, e2)

    @dr.syntax
    def intersect(self, o, d, t_max, active) -> Hit:
        """Closest hit in ``(0, t_max)``. o, d: Array3f (N,); t_max: Float; active: Bool."""
        Float = type(t_max)
        UInt32 = type(self.tris.material)
        n = self.tris.count
        best_t = Float(t_max)
        best_u = Float(0)
        best_v = Float(0)
        best_prim = UInt32(0)
        found = dr.zeros(type(active), dr.width(o))
        i = UInt32(0)
        while dr.hint(active & (i < n), max_iterations=-1, label="brute_force_closest",
                      exclude=[self, o, d, n, Float, UInt32]):
            tt, u, v, hit = self._candidate(i, o, d)
            closer = hit & (tt < best_t)
            best_t = dr.select(closer, tt, best_t)
            best_u = dr.select(closer, u, best_u)
            best_v = dr.select(closer, v, best_v)
            best_prim = dr.select(closer, i, best_prim)
            found |= closer
            i += 1
        return Hit(valid=found & active, t=best_t, u=best_u, v=best_v, prim=best_prim)

    @dr.syntax
    def intersect_p(self, o, d, t_max, active):
        """Any hit in ``(0, t_max)`` (shadow rays); stops at the first hit."""
        UInt32 = type(self.tris.material)
        n = self.tris.count
        blocked = dr.zeros(type(active), dr.width(o))
        i = UInt32(0)
        while dr.hint(active & ~blocked & (i < n), max_iterations=-1, label="brute_force_any",
                      exclude=[self, o, d, t_max, n, UInt32]):
            tt, u, v, hit = self._candidate(i, o, d)
            blocked |= hit & (tt < t_max)
            i += 1
        return blocked & active

    def stats(self) -> dict:
        return {"accel": "brute", "triangles": self.tris.count, "nodes": 0,
                "build_seconds": self.build_seconds,
                "intersection": self.intersection}
