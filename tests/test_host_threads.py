"""The host thread pool (``renderer.parallel``) changes no bit: the loader's object arrays,
the subdivision, the accelerators' packed triangles, their permutation and the padded
boxes are the same with one thread as with many (spans cut small, so a 69K-triangle mesh
is split into many), and the same as the plain numpy forms they replace (``np.cross``,
``np.linalg.norm``, row gathers: references written out here). The pool itself returns
results in order, raises a call's error and does not deadlock when a step splits again
inside another step."""
import warnings
from pathlib import Path

import numpy as np
import pytest

from renderer import parallel
from renderer.accel import bvh_build, triangle
from renderer.scene import load_scene, loader
from renderer.scene.meshio import load_mesh
from renderer.scene.subdivide import subdivide_midpoint

ROOT = Path(__file__).resolve().parents[1]
MANY = 7


@pytest.fixture(scope="module")
def bunny():
    V, F = load_mesh(ROOT / "scenes" / "meshes" / "stanford_bunny" / "bun_zipper.ply")
    return np.asarray(V, np.float64) * 10.0 + 1e3, np.asarray(F, np.int64)


@pytest.fixture(scope="module")
def scene():
    return load_scene(ROOT / "scenes" / "bunny.toml")


@pytest.fixture
def small_spans(monkeypatch):
    monkeypatch.setattr(parallel, "GRAIN", 97)


def _same(a, b, where=""):
    """Bitwise equality of two arrays, or of two dicts / lists / tuples of them."""
    if isinstance(a, dict):
        assert sorted(a) == sorted(b), where
        for k in a:
            _same(a[k], b[k], f"{where}/{k}")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for k, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{where}[{k}]")
    else:
        a, b = np.asarray(a), np.asarray(b)
        assert a.dtype == b.dtype and a.shape == b.shape, where
        assert a.tobytes() == b.tobytes(), where


def _both(fn):
    """``fn()`` with one thread and with ``MANY``."""
    with parallel.threads(1):
        one = fn()
    with parallel.threads(MANY):
        many = fn()
    return one, many


def _degenerate(V, F):
    """The bunny with zero-area faces (a repeated corner), unused vertices, duplicate
    positions (a seam) and a pair of cancelling faces."""
    F = F.copy()
    F[::11, 2] = F[::11, 1]
    V = np.concatenate([V, V[:300]])
    F = np.concatenate([F[:-5], F[:200] % 300 + len(V) - 300, F[:1], F[:1][:, [0, 2, 1]]])
    return V, F


def test_pool_runs_in_order_raises_and_nests():
    with parallel.threads(4):
        assert parallel.run(lambda x: x * x, range(50)) == [x * x for x in range(50)]
        assert parallel.together(lambda: 1, lambda: 2, lambda: 3) == [1, 2, 3]

        def fails(x):
            if x in (3, 7):
                raise KeyError(x)
            return x
        with pytest.raises(KeyError) as e:
            parallel.run(fails, range(10))
        assert e.value.args == (3,)

        def nested(x):          # every pool thread waits on its own inner split
            out = np.zeros(1000)
            parallel.for_spans(1000, lambda lo, hi: out.__setitem__(slice(lo, hi), x),
                               grain=10)
            return out.sum()
        assert parallel.run(nested, range(16)) == [1000.0 * x for x in range(16)]
        cut = parallel.spans(1001, grain=10)
        assert len(cut) == 4 and cut[0][0] == 0 and cut[-1][1] == 1001
        assert all(a[1] == b[0] for a, b in zip(cut, cut[1:]))
    with pytest.raises(ValueError):
        with parallel.threads(0):
            pass


def test_unique_inverse_is_numpy_unique(small_spans):
    rng = np.random.default_rng(2)
    for x in (rng.integers(0, 2**40, 20000), rng.integers(-5, 5, 9000),
              np.zeros(5000, np.int64), np.arange(7000)[::-1].copy(),
              rng.integers(0, 2**64 - 1, 12000, dtype=np.uint64)):
        ref_v, ref_i = np.unique(x, return_inverse=True)
        for n in (1, 2, MANY, 300):
            with parallel.threads(n):
                v, i = parallel.unique_inverse(x)
            _same(v, ref_v)
            _same(i, ref_i.reshape(-1))


def test_part_arrays_same_for_any_thread_count(bunny, small_spans):
    V, F = _degenerate(*bunny)
    one, many = _both(lambda: loader._part_arrays(V, F))
    assert not one["keep"].all()                     # the zero-area faces went
    _same(one, many)


def test_face_cross_is_numpy_cross_and_norm(bunny, small_spans):
    V, F = _degenerate(*bunny)
    P = V[F]
    ref = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    for n in (1, MANY):
        with parallel.threads(n):
            cross, length = loader._face_cross_columns(loader._columns(V, np.float64),
                                                       loader._columns(F, np.intp))
        _same(np.stack(cross, axis=1), ref)
        _same(length, np.linalg.norm(ref, axis=1))


def test_subdivision_same_for_any_thread_count(bunny, small_spans):
    V, F = bunny
    one, many = _both(lambda: subdivide_midpoint(V, F, 2))
    _same(one, many)
    one32, many32 = _both(lambda: subdivide_midpoint(V.astype(np.float32), F, 1))
    _same(one32, many32)


def _reference_triangle_arrays(scene, double, order, layout):
    """The plain numpy form of ``triangle_arrays`` (row gathers, ``np.cross``,
    ``np.linalg.norm``, whole-array ``np.where``)."""
    fdt = np.float64 if double else np.float32
    faces = scene.faces[order]
    V = np.asarray(scene.positions(double)).astype(np.float64)
    p0, p1, p2 = (V[faces[:, k]] for k in range(3))
    n = np.cross(p1 - p0, p2 - p0)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    packed = np.zeros((len(faces), triangle.STRIDE), fdt)
    packed[:, 0:3] = p0
    if layout == "edges":
        packed[:, 3:6] = np.where(length == 0, 0.0, p1 - p0)
        packed[:, 6:9] = np.where(length == 0, 0.0, p2 - p0)
    else:
        packed[:, 3:6], packed[:, 6:9] = p1, p2
        packed[:, 9:12] = np.where(length > 0, n / np.where(length > 0, length, 1.0), 0.0)
    out = {"tri_data": packed,
           "ng": np.ascontiguousarray((n / np.maximum(length, 1e-300)).T, fdt)}
    N = scene.normals_of(double)
    for k in range(3):
        out[f"n{k}"] = np.ascontiguousarray(N[faces[:, k]].T, fdt)
    out["material"] = np.asarray(scene.face_material[order], np.uint32)
    out["smooth"] = np.asarray(scene.face_smooth[order], bool)
    out["order"] = order.astype(np.uint32)
    return out


@pytest.mark.parametrize("double", [False, True])
@pytest.mark.parametrize("routine", ["watertight", "moller_trumbore"])
def test_triangle_arrays_same_for_any_thread_count(scene, small_spans, double, routine):
    order = np.random.default_rng(1).permutation(scene.face_count)
    order = np.concatenate([order, order[:500]])     # references: faces more than once
    ref = _reference_triangle_arrays(scene, double, order, triangle.layout_of(routine))
    face, _ = _both(lambda: triangle.triangle_arrays(scene, double, None, True,
                                                     routine=routine))
    one, many = _both(lambda: triangle.triangle_arrays(scene, double, order, True,
                                                       routine=routine))
    _same(one, ref)
    _same(many, ref)
    p_one, p_many = _both(lambda: triangle.permuted(face, order))
    _same(p_one, ref)
    _same(p_many, ref)


def test_padded_boxes_same_for_any_thread_count(scene, small_spans):
    tree = bvh_build.build_bvh(scene.vertices, scene.faces)
    raw = bvh_build.raw_boxes(tree, scene.vertices, scene.faces, np.float32)
    one, many = _both(lambda: bvh_build.pad_refit(tree, raw, 3.5))
    real = np.isfinite(tree.boxes.reshape(-1, 2, 6)[:, :, 0])
    ref = np.empty_like(raw)
    for k in range(2):
        with np.errstate(invalid="ignore"):
            lo, hi = bvh_build.pad_boxes(raw[:, 6 * k:6 * k + 3], raw[:, 6 * k + 3:6 * k + 6],
                                         3.5)
        ref[:, 6 * k:6 * k + 3] = np.where(real[:, k, None], lo, np.inf)
        ref[:, 6 * k + 3:6 * k + 6] = np.where(real[:, k, None], hi, np.inf)
    _same(one, ref)
    _same(many, ref)


def test_host_threads_variable_is_read_and_a_bad_value_warns_once(monkeypatch):
    from renderer import parallel
    monkeypatch.setenv("WHITTED_HOST_THREADS", "3")
    assert parallel.thread_count() == 3
    monkeypatch.setenv("WHITTED_HOST_THREADS", "three")
    monkeypatch.setattr(parallel, "_warned", set())
    with pytest.warns(UserWarning, match=r"WHITTED_HOST_THREADS='three': expected a positive"):
        n = parallel.thread_count()
    assert 1 <= n <= parallel.MAX_THREADS
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert parallel.thread_count() == n          # warned once
