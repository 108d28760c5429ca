"""Midpoint subdivision of triangle meshes (vectorised numpy).

Each level splits every triangle into four through its edge midpoints; a midpoint shared by
two triangles is created once (edges are deduplicated), so the mesh stays welded and smooth
vertex normals stay continuous. The surface does not move (midpoints lie on the old edges),
only the triangle count grows: 69,451 bunny triangles become 1,111,216 after two levels.
"""
from __future__ import annotations

import numpy as np

from .. import parallel


def subdivide_midpoint(vertices: np.ndarray, faces: np.ndarray, levels: int = 1
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Subdivide ``levels`` times.

    vertices: float (V, 3); faces: int (F, 3).
    Returns (vertices (V', 3) of the input dtype, faces int32 (F * 4**levels, 3)): the
    original vertices first (same indices), then one new vertex per distinct edge.
    Child triangles keep the winding of their parent: for parent (a, b, c) with midpoints
    ab, bc, ca the children are (a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca).
    """
    if levels < 0:
        raise ValueError(f"levels: expected >= 0, got {levels}")
    V = np.asarray(vertices)
    Fc = np.asarray(faces, np.int64)
    for _ in range(levels):
        V, Fc = _level(V, Fc)
    return V, Fc.astype(np.int32)


def _level(V: np.ndarray, Fc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One level of ``subdivide_midpoint`` (faces int64): the edge keys, midpoints and
    child faces elementwise over spans of faces (``renderer.parallel``), one sort of the
    keys (``np.unique``) in between."""
    nv, F = V.shape[0], Fc.shape[0]
    cols = [np.ascontiguousarray(Fc[:, c]) for c in range(3)]
    # The three edges of every face (ab, bc, ca), as sorted vertex pairs, face by face.
    key = np.empty((F, 3), np.int64)

    def key_span(lo, hi):
        for j in range(3):
            p, q = cols[j][lo:hi], cols[(j + 1) % 3][lo:hi]
            np.add(np.minimum(p, q) * nv, np.maximum(p, q), out=key[lo:hi, j])
    parallel.for_spans(F, key_span)
    uniq, inverse = parallel.unique_inverse(key.reshape(-1))
    E = uniq.shape[0]
    out_v = np.empty((nv + E,) + V.shape[1:], V.dtype)
    out_v[:nv] = V

    def mid_span(lo, hi):
        u = uniq[lo:hi]
        a, b = u // nv, u % nv
        out_v[nv + lo:nv + hi] = ((np.take(V, a, axis=0, mode="clip").astype(np.float64)
                                   + np.take(V, b, axis=0, mode="clip").astype(np.float64)) * 0.5)
    m = (nv + inverse).reshape(F, 3)               # midpoint index of ab, bc, ca
    out_f = np.empty((F, 4, 3), np.int64)

    def face_span(lo, hi):
        A, B, C = (c[lo:hi] for c in cols)
        ab, bc, ca = m[lo:hi, 0], m[lo:hi, 1], m[lo:hi, 2]
        # children (a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca)
        for child, corners in enumerate(((A, ab, ca), (ab, B, bc), (ca, bc, C),
                                         (ab, bc, ca))):
            for k, x in enumerate(corners):
                out_f[lo:hi, child, k] = x
    parallel.together(lambda: parallel.for_spans(E, mid_span),
                      lambda: parallel.for_spans(F, face_span))
    return out_v, out_f.reshape(-1, 3)
