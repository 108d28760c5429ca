"""Generated shapes in object space.

Every generator returns ``(vertices, faces)``: float64 (V, 3) positions and int64 (F, 3)
triangles, wound counter-clockwise seen from outside (``(v1 - v0) × (v2 - v0)`` points
outward), with vertices shared between the triangles of a shape (welded).

Conventions (object space, y up):

============  ===========================================================  =========
shape         geometry                                                     triangles
============  ===========================================================  =========
quad          unit square [-0.5, 0.5]² in the xz-plane (y = 0), facing +y  2
box           unit cube [-0.5, 0.5]³ (edge 1)                              12
sphere        geodesic sphere of radius 1: an icosahedron whose faces are  20·f²
              split into f² triangles (``frequency`` f, default 4) and
              projected onto the sphere; ``subdivisions`` s means f = 2^s
tetrahedron   regular, circumradius 1, centred at the origin               4
cube          regular, circumradius 1 (edge 2/√3)                          12
octahedron    regular, circumradius 1 (vertices ±x, ±y, ±z)                8
dodecahedron  regular, circumradius 1; 12 pentagons as 3-triangle fans     36
icosahedron   regular, circumradius 1                                      20
============  ===========================================================  =========
"""
from __future__ import annotations

import itertools

import numpy as np

__all__ = ["quad", "box", "sphere", "tetrahedron", "cube", "octahedron", "dodecahedron",
           "icosahedron", "SHAPES", "SHAPE_PARAMETERS", "make_shape"]

PHI = (1.0 + 5.0 ** 0.5) / 2.0


def _orient_outward(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """For a convex shape around the origin: flip triangles whose normal points inward."""
    v0, v1, v2 = (vertices[faces[:, i]] for i in range(3))
    n = np.cross(v1 - v0, v2 - v0)
    inward = np.einsum("ij,ij->i", n, v0 + v1 + v2) < 0
    faces = faces.copy()
    faces[inward] = faces[inward][:, [0, 2, 1]]
    return faces


def _convex_polygons(vertices: np.ndarray, polygons) -> tuple[np.ndarray, np.ndarray]:
    """Fan convex polygons (vertex lists in cyclic order) and orient them outward."""
    tris = [(p[0], p[i], p[i + 1]) for p in polygons for i in range(1, len(p) - 1)]
    faces = np.asarray(tris, dtype=np.int64)
    return vertices, _orient_outward(vertices, faces)


def quad() -> tuple[np.ndarray, np.ndarray]:
    """Unit square in the xz-plane, centred, facing +y: 4 vertices, 2 triangles."""
    v = np.array([[-0.5, 0, -0.5], [-0.5, 0, 0.5], [0.5, 0, 0.5], [0.5, 0, -0.5]], float)
    return v, np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int64)


def _cube_polygons():
    v = np.array(list(itertools.product((-1.0, 1.0), repeat=3)))   # index = 4x + 2y + z
    polys = []
    for axis in range(3):
        for sign in (0, 1):
            ids = [i for i in range(8) if (i >> (2 - axis)) & 1 == sign]
            # cyclic order around the face: sort by angle in the face plane
            a, b = [k for k in range(3) if k != axis]
            c = v[ids].mean(axis=0)
            ang = np.arctan2(v[ids, b] - c[b], v[ids, a] - c[a])
            polys.append([ids[i] for i in np.argsort(ang)])
    return v, polys


def box() -> tuple[np.ndarray, np.ndarray]:
    """Unit cube [-0.5, 0.5]³: 8 vertices, 12 triangles."""
    v, polys = _cube_polygons()
    return _convex_polygons(v * 0.5, polys)


def cube() -> tuple[np.ndarray, np.ndarray]:
    """Regular hexahedron with circumradius 1: 8 vertices, 12 triangles."""
    v, polys = _cube_polygons()
    return _convex_polygons(v / np.sqrt(3.0), polys)


def tetrahedron() -> tuple[np.ndarray, np.ndarray]:
    """Regular tetrahedron with circumradius 1: 4 vertices, 4 triangles."""
    v = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], float) / np.sqrt(3.0)
    return _convex_polygons(v, list(itertools.combinations(range(4), 3)))


def octahedron() -> tuple[np.ndarray, np.ndarray]:
    """Regular octahedron with circumradius 1: 6 vertices, 8 triangles."""
    v = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    polys = [(x, y, z) for x in (0, 1) for y in (2, 3) for z in (4, 5)]
    return _convex_polygons(v, polys)


def _icosahedron_vertices() -> np.ndarray:
    v = []
    for a in (-1.0, 1.0):
        for b in (-PHI, PHI):
            v += [(0, a, b), (a, b, 0), (b, 0, a)]
    v = np.array(v)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def icosahedron() -> tuple[np.ndarray, np.ndarray]:
    """Regular icosahedron with circumradius 1: 12 vertices, 20 triangles."""
    v = _icosahedron_vertices()
    d = np.linalg.norm(v[:, None] - v[None], axis=2)
    edge = d[d > 1e-9].min()
    near = np.abs(d - edge) < 1e-9
    polys = [t for t in itertools.combinations(range(12), 3)
             if near[t[0], t[1]] and near[t[1], t[2]] and near[t[0], t[2]]]
    return _convex_polygons(v, polys)


def dodecahedron() -> tuple[np.ndarray, np.ndarray]:
    """Regular dodecahedron with circumradius 1: 20 vertices, 12 pentagons = 36 triangles.

    Built as the dual of the icosahedron: one vertex per icosahedron face (its centroid,
    projected to the unit sphere), one pentagon per icosahedron vertex.
    """
    iv, ifaces = icosahedron()
    v = iv[ifaces].mean(axis=1)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    polys = []
    for k, axis in enumerate(iv):
        ids = np.flatnonzero(np.any(ifaces == k, axis=1))       # the 5 faces around k
        c = v[ids].mean(axis=0)
        e1 = v[ids[0]] - c
        e2 = np.cross(axis, e1)
        ang = np.arctan2((v[ids] - c) @ e2, (v[ids] - c) @ e1)
        polys.append([int(ids[i]) for i in np.argsort(ang)])
    return _convex_polygons(v, polys)


def sphere(frequency: int | None = None, subdivisions: int | None = None
           ) -> tuple[np.ndarray, np.ndarray]:
    """Geodesic unit sphere: each icosahedron face split into ``frequency²`` triangles
    (``subdivisions`` s is the same as frequency 2^s; default frequency 4 = 320 triangles).
    20·f² triangles, 10·f² + 2 welded vertices.
    """
    if frequency is not None and subdivisions is not None:
        raise ValueError("give either frequency or subdivisions, not both")
    f = 4 if frequency is None and subdivisions is None else (
        frequency if frequency is not None else 2 ** subdivisions)
    if f < 1:
        raise ValueError(f"frequency must be >= 1, got {f}")
    iv, ifaces = icosahedron()
    pts, tris = [], []
    grid = [(i, j) for i in range(f + 1) for j in range(f + 1 - i)]
    index = {ij: k for k, ij in enumerate(grid)}
    local = []
    for i in range(f):
        for j in range(f - i):
            local.append((index[i, j], index[i + 1, j], index[i, j + 1]))
            if i + j < f - 1:
                local.append((index[i + 1, j], index[i + 1, j + 1], index[i, j + 1]))
    local = np.array(local, dtype=np.int64)
    ij = np.array(grid, float) / f
    for n, (a, b, c) in enumerate(ifaces):
        A, B, C = iv[a], iv[b], iv[c]
        p = A + ij[:, :1] * (B - A) + ij[:, 1:] * (C - A)
        pts.append(p / np.linalg.norm(p, axis=1, keepdims=True))
        tris.append(local + n * len(grid))
    pts, tris = np.concatenate(pts), np.concatenate(tris)
    # Weld the copies of points on shared icosahedron edges.
    key = np.round(pts * 2 ** 30).astype(np.int64)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    vertices = pts[first]
    faces = inverse.reshape(-1)[tris]
    return vertices, _orient_outward(vertices, faces)


#: Shape name -> generator.
SHAPES = {"quad": quad, "box": box, "sphere": sphere, "tetrahedron": tetrahedron,
          "cube": cube, "octahedron": octahedron, "dodecahedron": dodecahedron,
          "icosahedron": icosahedron}

#: Shape name -> accepted keyword parameters.
SHAPE_PARAMETERS = {name: () for name in SHAPES}
SHAPE_PARAMETERS["sphere"] = ("frequency", "subdivisions")


def make_shape(name: str, **params) -> tuple[np.ndarray, np.ndarray]:
    """``SHAPES[name](**params)``."""
    return SHAPES[name](**params)
