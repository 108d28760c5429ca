"""``SortedQueries`` (rays sorted by octant and origin cell before tracing, results
scattered back) gives bitwise the hits of the accelerator it wraps and of brute force, on
random and adversarial rays, closest and any hit, with inactive lanes."""
import drjit as dr
import numpy as np
import pytest
from accel_util import assert_same_hits, hits, random_rays, scene_from_arrays, soup
from test_accel_wide import adversarial_rays, grid

from renderer.accel import BVH, BruteForce, Ray, WideBVH
from renderer.accel.order import SortedQueries, ray_key, ray_order
from renderer.device import types


@pytest.mark.parametrize("width", [2, 4, 8])
def test_sorted_queries_match_brute_force_on_random_rays(width):
    t = types("llvm")
    V, faces = soup(1500, seed=width)
    sc = scene_from_arrays(V, faces, n_objects=2)
    ray, active = random_rays(t, 5000, seed=20 + width)
    acc = BVH.build(sc, t) if width == 2 else WideBVH.build(sc, t, width=width)
    ref = hits(BruteForce.build(sc, t), ray, active, t)
    assert ref[0].sum() > 500
    assert_same_hits(hits(SortedQueries.for_scene(acc, sc), ray, active, t), ref)


def test_sorted_queries_match_brute_force_on_adversarial_rays():
    t = types("llvm")
    V, faces = grid()
    sc = scene_from_arrays(V, faces, n_objects=2)
    ray, active = adversarial_rays(t, V, faces, seed=4)
    ref = hits(BruteForce.build(sc, t), ray, active, t)
    acc = WideBVH.build(sc, t, width=4)
    assert_same_hits(hits(SortedQueries.for_scene(acc, sc), ray, active, t), ref)


def test_ray_order_is_a_stable_sort_by_key():
    t = types("llvm")
    rng = np.random.default_rng(1)
    o = rng.uniform(-2, 3, (3000, 3)).astype(np.float32)
    d = rng.standard_normal((3000, 3)).astype(np.float32)
    ray = Ray(o=t.Array3f(*o.T), d=t.Array3f(*d.T), t_max=t.Float(np.inf))
    lo, hi = (-1.0, -1.0, -1.0), (2.0, 2.0, 2.0)      # origins outside clamp to the border
    key = ray_key(t, ray, lo, hi)[0].numpy()
    perm = ray_order(t, ray, lo, hi).numpy()
    assert np.array_equal(perm, np.argsort(key, kind="stable"))
    assert key.max() < 1 << 15
    octant = (d[:, 0] > 0) * 4 + (d[:, 1] > 0) * 2 + (d[:, 2] > 0) * 1
    assert np.array_equal(key >> 12, octant)
    dr.eval()
