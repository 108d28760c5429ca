"""Shared helpers of the accelerator tests: triangle soups as scenes, random ray batches,
and the hit tuple compared bitwise against brute force."""
import drjit as dr
import numpy as np

from renderer.accel import Ray
from renderer.device import array3
from renderer.scene import Camera, ObjectInfo, Scene, Settings


def scene_from_arrays(V, faces, n_objects=1):
    """A Scene holding the triangle soup (V, faces), split into ``n_objects`` face ranges."""
    V = np.asarray(V, np.float32)
    faces = np.asarray(faces, np.int32)
    F = len(faces)
    cuts = np.linspace(0, F, n_objects + 1).astype(int)
    objs = [ObjectInfo(f"o{k}", "soup", 0, int(cuts[k]), int(cuts[k + 1] - cuts[k]), 0,
                       len(V), False) for k in range(n_objects)]
    cam = Camera(np.zeros(3), np.ones(3), np.array([0.0, 1.0, 0.0]), 40.0, 8, 8)
    return Scene([cam], Settings(), [], [], objs, V, np.zeros_like(V), faces,
                 np.zeros(F, np.int32),
                 np.repeat(np.arange(n_objects), np.diff(cuts)).astype(np.int32))


def soup(F, seed, size=0.05):
    """F random triangles of about ``size`` in the unit cube (fixed seed)."""
    rng = np.random.default_rng(seed)
    c = rng.random((F, 3))
    V = (c[:, None, :] + size * rng.standard_normal((F, 3, 3))).reshape(-1, 3)
    return V, np.arange(3 * F).reshape(F, 3)


def random_rays(t, n, seed):
    """``(Ray, active)``: rays from around the unit cube in random directions; half with a
    finite t_max, some inactive, some with exactly-zero direction components
    (axis-parallel)."""
    rng = np.random.default_rng(seed)
    o = rng.random((n, 3)) * 1.6 - 0.3
    d = rng.standard_normal((n, 3))
    zero = rng.random((n, 3)) < 0.1
    d[zero] = 0.0
    d[np.all(d == 0, axis=1), 1] = 1.0
    t_max = np.where(rng.random(n) < 0.5, np.inf, rng.random(n) * 0.8)
    active = rng.random(n) < 0.9
    return Ray(array3(t, o), array3(t, d), t.Float(t_max)), t.Bool(active)


def hits(acc, ray, active, t):
    """(found, t, original face, u, v, any-hit) as numpy arrays."""
    h = acc.intersect(ray, active)
    p = acc.intersect_p(ray, active)
    face = dr.gather(t.UInt32, acc.tris.order, h.prim, h.found)
    return (h.found.numpy(), h.t.numpy(), face.numpy(), h.u.numpy(), h.v.numpy(), p.numpy())


def assert_same_hits(got, ref):
    found = ref[0]
    assert np.array_equal(got[0], found)
    for k in (1, 2, 3, 4):                       # t, face, u, v bitwise where found
        assert np.array_equal(got[k][found], ref[k][found])
    assert np.array_equal(got[5], ref[5])
