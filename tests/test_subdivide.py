"""Midpoint subdivision keeps the surface, its orientation and its closedness."""
import numpy as np

from renderer.scene.subdivide import subdivide_midpoint


def test_subdivision_keeps_surface_and_welds_midpoints():
    # Octahedron: closed, 6 vertices, 12 edges, 8 faces.
    V = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4],
                  [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    V2, F2 = subdivide_midpoint(V, F, 2)
    assert F2.shape == (8 * 16, 3)
    assert V2.shape[0] == 6 + 12 + 48              # one new vertex per edge, per level
    assert np.array_equal(V2[:6], V)
    # Still closed and manifold: every edge shared by exactly two faces.
    e = np.sort(np.concatenate([F2[:, [0, 1]], F2[:, [1, 2]], F2[:, [2, 0]]]), axis=1)
    _, counts = np.unique(e, axis=0, return_counts=True)
    assert np.all(counts == 2)

    def area_normal(V, F):
        return np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])

    a1, a2 = area_normal(V, F), area_normal(V2, F2)
    assert np.isclose(np.linalg.norm(a1, axis=1).sum(), np.linalg.norm(a2, axis=1).sum())
    # Children keep the parent's orientation (winding): same normal direction.
    parent = np.repeat(np.arange(8), 16)
    assert np.all(np.einsum("ij,ij->i", a2, a1[parent]) > 0)
