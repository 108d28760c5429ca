"""Generated shapes: outward winding, closedness, and the solids' closed-form geometry."""

import numpy as np
import pytest

from renderer.scene.shapes import SHAPES, sphere

PHI = (1 + 5 ** 0.5) / 2
# name: (triangles, vertices, edge length for circumradius 1)
SOLIDS = {
    "tetrahedron": (4, 4, np.sqrt(8 / 3)),
    "cube": (12, 8, 2 / np.sqrt(3)),
    "octahedron": (8, 6, np.sqrt(2)),
    "dodecahedron": (36, 20, 4 / (np.sqrt(3) * (1 + np.sqrt(5)))),
    "icosahedron": (20, 12, 1 / np.sin(2 * np.pi / 5)),
}
CLOSED = ["box", "sphere", *SOLIDS]


def signed_volume(v, f):
    return np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() / 6


def edges(f):
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    return np.unique(e, axis=0, return_counts=True)


@pytest.mark.parametrize("name", CLOSED)
def test_closed_shapes_are_watertight_with_outward_normals(name):
    v, f = SHAPES[name]()
    assert v.dtype == np.float64 and f.dtype == np.int64 and f.shape[1] == 3
    uniq, counts = edges(f)
    assert np.all(counts == 2), "every edge shared by exactly two triangles"
    assert len(v) - len(uniq) + len(f) == 2, "Euler characteristic of a sphere"
    assert signed_volume(v, f) > 0
    # Each triangle's normal points away from the centre (all shapes are convex).
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert np.all(np.einsum("ij,ij->i", n, v[f].mean(axis=1)) > 0)
    # Consistent orientation: each directed edge appears once.
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    assert len(np.unique(directed, axis=0)) == len(directed)


@pytest.mark.parametrize("name", SOLIDS)
def test_platonic_solids_are_regular(name):
    tris, verts, edge = SOLIDS[name]
    v, f = SHAPES[name]()
    assert f.shape == (tris, 3) and v.shape == (verts, 3)
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-12)  # circumradius
    d = np.linalg.norm(v[:, None] - v[None], axis=2)
    nearest = np.sort(d, axis=1)[:, 1]
    np.testing.assert_allclose(nearest, edge, rtol=1e-9)
    # Every polyhedron edge length is the shortest distance; fan diagonals are longer.
    uniq, _ = edges(f)
    lengths = np.linalg.norm(v[uniq[:, 0]] - v[uniq[:, 1]], axis=1)
    n_edges = {"tetrahedron": 6, "cube": 12, "octahedron": 12, "dodecahedron": 30,
               "icosahedron": 30}[name]
    assert np.isclose(lengths, edge).sum() == n_edges


def test_closed_form_volumes():
    # Unit-edge box; octahedron of circumradius 1: 4/3; tetrahedron: 8/(9 sqrt 3).
    assert np.isclose(signed_volume(*SHAPES["box"]()), 1.0)
    assert np.isclose(signed_volume(*SHAPES["octahedron"]()), 4 / 3)
    assert np.isclose(signed_volume(*SHAPES["tetrahedron"]()), 8 / (9 * np.sqrt(3)))
    a = SOLIDS["icosahedron"][2]
    assert np.isclose(signed_volume(*SHAPES["icosahedron"]()), 5 / 12 * (3 + np.sqrt(5)) * a**3)


def test_quad_faces_up_with_unit_area():
    v, f = SHAPES["quad"]()
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert np.allclose(n / np.linalg.norm(n, axis=1, keepdims=True), [0, 1, 0])
    assert np.isclose(np.linalg.norm(n, axis=1).sum() / 2, 1.0)
    assert np.allclose(v[:, 1], 0) and np.allclose(np.abs(v[:, [0, 2]]), 0.5)


@pytest.mark.parametrize("frequency", [1, 2, 3, 4, 5, 7])
def test_geodesic_sphere_counts_and_radius(frequency):
    v, f = sphere(frequency)
    assert f.shape == (20 * frequency**2, 3)
    assert len(v) == 10 * frequency**2 + 2
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-12)
    # Volume approaches the ball's from below.
    assert signed_volume(v, f) < 4 / 3 * np.pi


def test_sphere_subdivisions_is_frequency_power_of_two():
    for s in range(4):
        np.testing.assert_array_equal(sphere(subdivisions=s)[1], sphere(2 ** s)[1])
    assert sphere()[1].shape == (320, 3)
