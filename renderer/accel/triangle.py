"""Ray/triangle intersection routines and the one packed triangle layout.

Routines (one function each, same signature) take the ray (origin ``o``, direction ``d``:
Array3f) and the triangle as its first vertex ``v0`` and the edge vectors ``e1 = v1 - v0``,
``e2 = v2 - v0`` (precomputed on the host at load, as in the thesis), and return
``(t, u, v, hit)``: the ray parameter, the barycentrics of ``v1`` and ``v2``, and a Bool
mask. ``hit`` already includes ``t > t_min``; callers compare ``t`` against their own
``t_max``. The types follow the inputs, so float64 works unchanged.

Packed layout (``pack`` on the host, ``load`` on the device): 12 floats per triangle,
``v0.xyz, e1.xyz, e2.xyz`` and 3 floats of padding, so a triangle is three aligned quads.
"""
from __future__ import annotations

import drjit as dr
import numpy as np

from ..device import Types, array3
from .base import DeviceTriangles, gather_floats

#: Floats per packed triangle.
STRIDE = 12


def unit_roundoff(double: bool) -> float:
    """Unit roundoff of float64 (``double``) or float32: half the distance from 1 to the
    next float."""
    return 2.0 ** -53 if double else 2.0 ** -24


def edge_slack(double: bool) -> float:
    """Barycentric slack of Möller–Trumbore's inside test: 16 units of roundoff (2^-20 in
    float32). The test is not watertight: a ray through a shared edge can miss both
    triangles by a rounding error (seen on CUDA, where products are contracted into FMAs, as
    black pixels along a quad's diagonal). Accepting ``u, v >= -slack`` and
    ``u + v <= 1 + slack`` closes those cracks; the closest-hit tie-break (lowest original
    face index) keeps the choice deterministic, and the boxes of the accelerators are padded
    far more than this (``renderer.accel.bvh_build.pad_boxes``)."""
    return 16.0 * unit_roundoff(double)


def moller_trumbore(o, d, v0, e1, e2, t_min=0.0):
    """Möller–Trumbore (thesis eqs. 1-5), with ``edge_slack`` on the inside test.
    Two-sided; parallel rays never hit."""
    slack = edge_slack(dr.type_v(o) == dr.VarType.Float64)
    p = dr.cross(d, e2)
    det = dr.dot(e1, p)
    inv_det = dr.rcp(det)
    s = o - v0
    u = dr.dot(s, p) * inv_det
    q = dr.cross(s, e1)
    v = dr.dot(d, q) * inv_det
    t = dr.dot(e2, q) * inv_det
    hit = ((det != 0) & (u >= -slack) & (v >= -slack) & (u + v <= 1 + slack)
           & (t > t_min))
    return t, u, v, hit


#: Routines by name, so the intersection test is a render parameter.
ROUTINES = {"moller_trumbore": moller_trumbore}


def triangle_routine(name: str):
    """The routine registered as ``name`` in ``ROUTINES``; ValueError listing the choices."""
    try:
        return ROUTINES[name]
    except KeyError:
        raise ValueError(f"intersection: expected one of {sorted(ROUTINES)}, "
                         f"got {name!r}") from None


def pack(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """float64 (F, STRIDE) packed rows of the triangles ``faces`` (int (F, 3)) of
    ``vertices`` (float (V, 3)); the caller casts to the precision in use. The edges are
    differences of float64 vertices, rounded once by that cast."""
    V = np.asarray(vertices).astype(np.float64)
    p0, p1, p2 = (V[faces[:, k]] for k in range(3))
    packed = np.zeros((faces.shape[0], STRIDE), np.float64)
    packed[:, 0:3] = p0
    packed[:, 3:6] = p1 - p0
    packed[:, 6:9] = p2 - p0
    return packed


def load(t, data, i, active=True):
    """``(v0, e1, e2)`` (Array3f) of packed triangle(s) ``i`` (UInt32) of ``data``."""
    f = gather_floats(t, data, i, STRIDE, 9, active)
    return (t.Array3f(f[0], f[1], f[2]), t.Array3f(f[3], f[4], f[5]),
            t.Array3f(f[6], f[7], f[8]))


def upload_triangles(scene, t: Types, order: np.ndarray | None = None,
                     with_normals: bool | None = None):
    """Upload ``scene``'s triangles, optionally permuted by ``order`` (int (F,)): returns
    ``(tri_data, tris)``, the packed geometry of ``pack`` as a Float and the
    ``DeviceTriangles``. Normals are uploaded when ``with_normals`` (default: when any
    object is smooth)."""
    F = scene.face_count
    order = np.arange(F, dtype=np.int64) if order is None else np.asarray(order, np.int64)
    faces = scene.faces[order]
    packed = pack(scene.vertices, faces)
    ng = np.cross(packed[:, 3:6], packed[:, 6:9])
    ng /= np.maximum(np.linalg.norm(ng, axis=1, keepdims=True), 1e-300)
    smooth = scene.face_smooth[order]
    if with_normals is None:
        with_normals = bool(smooth.any())
    if with_normals:
        N = scene.normals.astype(np.float64)
        n0, n1, n2 = (array3(t, N[faces[:, k]]) for k in range(3))
    else:
        n0 = n1 = n2 = t.Array3f(0, 0, 0)
    fdt = np.float64 if t.is_double else np.float32
    tri_data = t.Float(packed.astype(fdt).reshape(-1))
    tris = DeviceTriangles(
        ng=array3(t, ng), n0=n0, n1=n1, n2=n2,
        material=t.UInt32(scene.face_material[order].astype(np.uint32)),
        smooth=t.Bool(smooth), order=t.UInt32(order.astype(np.uint32)))
    return tri_data, tris
