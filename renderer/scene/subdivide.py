"""Midpoint subdivision of triangle meshes (vectorised numpy).

Each level splits every triangle into four through its edge midpoints; a midpoint shared by
two triangles is created once (edges are deduplicated), so the mesh stays welded and smooth
vertex normals stay continuous. The surface does not move (midpoints lie on the old edges),
only the triangle count grows: 69,451 bunny triangles become 1,111,216 after two levels.
"""
from __future__ import annotations

import numpy as np


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
        nv = V.shape[0]
        F = Fc.shape[0]
        # The three edges of every face (ab, bc, ca), as sorted vertex pairs.
        e = np.stack([Fc[:, [0, 1]], Fc[:, [1, 2]], Fc[:, [2, 0]]], axis=1).reshape(-1, 2)
        key = np.minimum(e[:, 0], e[:, 1]) * nv + np.maximum(e[:, 0], e[:, 1])
        uniq, inverse = np.unique(key, return_inverse=True)
        a, b = uniq // nv, uniq % nv
        mid = ((V[a].astype(np.float64) + V[b].astype(np.float64)) * 0.5).astype(V.dtype)
        m = (nv + inverse).reshape(F, 3)               # midpoint index of ab, bc, ca
        A, B, C = Fc[:, 0], Fc[:, 1], Fc[:, 2]
        ab, bc, ca = m[:, 0], m[:, 1], m[:, 2]
        Fc = np.stack([
            np.stack([A, ab, ca], 1), np.stack([ab, B, bc], 1),
            np.stack([ca, bc, C], 1), np.stack([ab, bc, ca], 1)], axis=1).reshape(-1, 3)
        V = np.concatenate([V, mid], axis=0)
    return V, Fc.astype(np.int32)
