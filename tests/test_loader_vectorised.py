"""The loader's vectorised steps give the bytes of the plain numpy forms they replace:
``_compact`` is ``np.unique(faces, return_inverse=True)``, ``_weld`` groups rows as
``np.unique(verts, axis=0)`` does (-0.0 equal to 0.0, a hash collision caught), and
``_vertex_normals`` sums in ``np.add.at``'s order (references: those numpy calls, on the
bundled bunny mesh and on made-up rows)."""
from pathlib import Path

import numpy as np
import pytest

from renderer.scene import loader
from renderer.scene.meshio import load_mesh

ROOT = Path(__file__).resolve().parents[1]


def _groups(labels):
    """The partition a labelling makes, as a canonical array (first index of each row's
    group)."""
    labels = np.asarray(labels).reshape(-1)
    first = {}
    return np.array([first.setdefault(int(x), i) for i, x in enumerate(labels)])


def _reference_normals(verts, faces, face_n):
    _, weld = np.unique(verts, axis=0, return_inverse=True)
    weld = weld.reshape(-1)
    acc = np.zeros((weld.max() + 1, 3))
    for c in range(3):
        np.add.at(acc, weld[faces[:, c]], face_n)
    n = acc[weld]
    length = np.linalg.norm(n, axis=1)
    fallback = np.zeros_like(n)
    fallback[faces.reshape(-1)] = np.repeat(face_n, 3, axis=0)
    bad = length < 1e-12
    n[bad] = fallback[bad]
    length[bad] = 1.0
    return n / length[:, None]


@pytest.fixture(scope="module")
def bunny():
    V, F = load_mesh(ROOT / "scenes" / "meshes" / "stanford_bunny" / "bun_zipper.ply")
    return np.asarray(V, np.float64), np.asarray(F, np.int64)


def test_compact_is_unique_with_inverse(bunny):
    V, F = bunny
    F = F[::3]                                    # leaves some vertices unused
    used, faces = loader._compact(F, V.shape[0])
    ref_used, ref_inv = np.unique(F, return_inverse=True)
    assert np.array_equal(used, ref_used)
    assert np.array_equal(faces, ref_inv.reshape(-1, 3)) and faces.dtype == np.int64


def test_weld_groups_rows_as_unique_does(monkeypatch):
    rng = np.random.default_rng(3)
    rows = rng.integers(-2, 3, size=(500, 3)).astype(np.float64) * 0.5
    rows[::7, 1] = -0.0                           # -0.0 welds with 0.0
    rows[1::7, 1] = 0.0
    ref = np.unique(rows, axis=0, return_inverse=True)[1]
    assert np.array_equal(_groups(loader._weld(rows)), _groups(ref))
    monkeypatch.setattr(loader, "_row_hash",            # every row collides: the row sort
                        lambda bits: np.zeros(bits.shape[0], np.uint64))
    assert np.array_equal(_groups(loader._weld(rows)), _groups(ref))


def test_vertex_normals_are_add_at_bytes(bunny):
    V, F = bunny
    V = np.concatenate([V, V[:50]])               # a seam: coincident copies of vertices
    F = np.concatenate([F, F[:40] % 50 + V.shape[0] - 50])
    cross = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    face_n = loader._unit_rows(cross, np.linalg.norm(cross, axis=1))
    face_n[5] = -face_n[4]                        # cancelling neighbours: the fallback
    got = loader._vertex_normals(V, F, face_n)
    assert np.array_equal(got, _reference_normals(V, F, face_n))
