"""Every accelerator, on every traversal path, gives bitwise the hits of brute force.

Reference: ``BruteForce`` (every ray against every triangle, same triangle routine).
"""
from dataclasses import replace
from pathlib import Path

import drjit as dr
import numpy as np
import pytest
from accel_util import assert_same_hits, hits, random_rays, scene_from_arrays, soup

from renderer.accel import BVH, BruteForce, ObjectBoxes, Ray
from renderer.accel.bvh_build import build_bvh, check_bvh
from renderer.device import types

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("seed", [0, 1])
def test_bvh_matches_brute_force(backend, seed):
    t = types(backend)
    V, faces = soup(2000, seed=seed)
    sc = scene_from_arrays(V, faces, n_objects=3)
    ray, active = random_rays(t, 4096, seed=10 + seed)
    ref = hits(BruteForce.build(sc, t), ray, active, t)
    assert ref[0].sum() > 500                    # the rays do hit the soup
    assert_same_hits(hits(BVH.build(sc, t), ray, active, t), ref)


BUILD_OPTIONS = [
    dict(),                                                         # the defaults
    dict(sah_leaves=True, leaf_size=8),                             # SAH leaf termination
    dict(all_axes=False, bins=16, root_bins=16, depth_first=False),  # longest axis, BFS order
    dict(sample=64),                                                # sampled three-axis SAH
]


@pytest.mark.parametrize("options", BUILD_OPTIONS, ids=lambda o: ",".join(o) or "defaults")
def test_build_options_keep_hits_identical(options):
    """Every build variant is a valid tree and gives brute force's hits bitwise."""
    t = types("llvm")
    V, faces = soup(2000, seed=3)   # fixed seed: a reproducible soup
    check_bvh(build_bvh(V, faces, **options))
    sc = scene_from_arrays(V, faces, n_objects=2)
    ray, active = random_rays(t, 4096, seed=13)
    ref = hits(BruteForce.build(sc, t), ray, active, t)
    assert ref[0].sum() > 500
    assert_same_hits(hits(BVH.build(sc, t, **options), ray, active, t), ref)


@pytest.mark.parametrize("cls", [BVH, ObjectBoxes, BruteForce])
def test_cuda_path_matches_brute_force_on_llvm(cls):
    """CUDA takes the packet-gather, inline-masked branch of every step; the LLVM backend
    normally takes the scalar-gather, symbolic-if branch. The CUDA branch is
    backend-independent code, so CI (no GPU) runs it here on LLVM arrays."""
    t = types("llvm")
    as_cuda = replace(t, backend="cuda")

    class OnCudaPath(cls):
        types = property(lambda self: as_cuda)

    V, faces = soup(2000, seed=5)   # fixed seed: a reproducible soup
    sc = scene_from_arrays(V, faces, n_objects=2)
    ray, active = random_rays(t, 4096, seed=15)
    ref = hits(BruteForce.build(sc, t), ray, active, t)
    assert ref[0].sum() > 500
    acc = OnCudaPath.build(sc, as_cuda)     # built as for CUDA: no 64-bit views
    assert getattr(acc, "tri_trav", None) is None
    assert_same_hits(hits(acc, ray, active, t), ref)


@pytest.mark.parametrize("count", [1, 2, 5, 12])
def test_gather_pairs_reads_the_words_of_32_bit_gathers(count):
    """``gather_pairs`` (64-bit gathers of a UInt64 view, split into words) returns the
    words and floats that one 32-bit gather per word returns, masked lanes zero."""
    from renderer.accel.base import as_pairs, gather_floats, gather_pairs
    t = types("llvm")
    rng = np.random.default_rng(count)
    words = rng.integers(0, 2**32, (50, 12), dtype=np.uint64).astype(np.uint32)
    idx = t.UInt32(rng.integers(0, 50, 300).astype(np.uint32))
    on = t.Bool(rng.random(300) < 0.7)
    got = gather_pairs(t, as_pairs(t, words), idx, 12, count, on)
    flat = t.UInt32(words.reshape(-1))
    for k in range(count):
        want = dr.gather(t.UInt32, flat, idx * 12 + k, on)
        assert np.array_equal(got[k].numpy(), want.numpy())
    floats = words.view(np.float32)
    got_f = gather_floats(t, as_pairs(t, words), idx, 12, count, on)
    for k in range(count):
        want = dr.gather(t.Float, t.Float(floats.reshape(-1)), idx * 12 + k, on)
        assert np.array_equal(got_f[k].numpy().view(np.uint32), want.numpy().view(np.uint32))


def test_object_boxes_match_brute_force(backend):
    t = types(backend)
    V, faces = soup(1500, seed=7)
    sc = scene_from_arrays(V, faces, n_objects=5)
    ray, active = random_rays(t, 4096, seed=17)
    ref = hits(BruteForce.build(sc, t), ray, active, t)
    assert_same_hits(hits(ObjectBoxes.build(sc, t), ray, active, t), ref)


def test_ties_break_by_smallest_face_index():
    # Duplicated triangles in shuffled order: all three accelerators report the same face.
    t = types("llvm")
    V, faces = soup(300, seed=4, size=0.1)
    rng = np.random.default_rng(4)   # fixed seed: reproducible shuffle
    faces = np.concatenate([faces, faces, faces])[rng.permutation(900)]
    sc = scene_from_arrays(V, faces, n_objects=2)
    ray, active = random_rays(t, 2048, seed=5)
    ref = hits(BruteForce.build(sc, t), ray, active, t)
    for cls in (BVH, ObjectBoxes):
        assert_same_hits(hits(cls.build(sc, t), ray, active, t), ref)


def test_coincident_triangles_resolve_to_the_first_face():
    # 2,000 coincident triangles: every ray through the stack hits, ties -> face 0.
    t = types("llvm")
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    V = np.tile(tri, (2000, 1))
    sc = scene_from_arrays(V, np.arange(V.shape[0]).reshape(-1, 3))
    n = 64
    xs = np.linspace(0.05, 0.4, n)
    o = t.Array3f(t.Float(xs), t.Float(xs[::-1]), t.Float(np.full(n, 1.0)))
    for cls in (BVH, ObjectBoxes, BruteForce):
        acc = cls.build(sc, t)
        h = acc.intersect(Ray(o, t.Array3f(0.0, 0.0, -1.0), t.Float(dr.inf)), t.Bool(True))
        face = dr.gather(t.UInt32, acc.tris.order, h.prim)
        assert np.all(h.found.numpy()) and np.all(face.numpy() == 0)


def test_any_hit_agrees_with_closest_hit(backend):
    t = types(backend)
    V, faces = soup(1000, seed=2)
    sc = scene_from_arrays(V, faces, n_objects=2)
    ray, active = random_rays(t, 4096, seed=22)
    for cls in (BVH, ObjectBoxes, BruteForce):
        acc = cls.build(sc, t)
        h = acc.intersect(ray, active)
        p = acc.intersect_p(ray, active)
        assert np.array_equal(p.numpy(), h.found.numpy())
        # Shortening t_max to just the hit distance leaves no hit in (0, t): open interval.
        short = Ray(ray.o, ray.d, h.t)
        p2 = acc.intersect_p(short, active & h.found)
        h2 = acc.intersect(short, active & h.found)
        assert not np.any(h2.found.numpy())
        assert not np.any(p2.numpy() & ~np.isfinite(h.t.numpy()))


def test_double_precision_matches_brute_force():
    t = types("llvm", "float64")
    V, faces = soup(800, seed=9)
    sc = scene_from_arrays(V, faces, n_objects=2)
    ray, active = random_rays(t, 2048, seed=19)
    ref = hits(BruteForce.build(sc, t), ray, active, t)
    assert_same_hits(hits(BVH.build(sc, t), ray, active, t), ref)
    assert_same_hits(hits(ObjectBoxes.build(sc, t), ray, active, t), ref)


def test_empty_and_tiny_scenes():
    t = types("llvm")
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    sc = scene_from_arrays(tri, [[0, 1, 2]])
    o = t.Array3f(t.Float([0.2, 2.0]), t.Float([0.2, 2.0]), t.Float([1.0, 1.0]))
    ray = Ray(o, t.Array3f(0.0, 0.0, -1.0), t.Float(dr.inf))
    for cls in (BVH, ObjectBoxes, BruteForce):
        h = cls.build(sc, t).intersect(ray, t.Bool(True))
        assert h.found.numpy().tolist() == [True, False]
        assert np.allclose(h.t.numpy()[0], 1.0)


# ---- inside other kernels -------------------------------------------------------------------
@dr.syntax
def count_layers(acc, o, d, t):
    """March through the geometry, re-shooting from each hit until nothing is hit (an
    accelerator query inside an outer symbolic loop, like the integrator's)."""
    n = dr.zeros(t.UInt32, dr.width(o))
    active = t.Bool(True)
    while dr.hint(active, max_iterations=-1, label="march", exclude=[acc, t]):
        h = acc.intersect(Ray(o, d, t.Float(dr.inf)), active)
        active &= h.found & (n < 50)
        o = dr.select(active, o + d * (h.t * 1.0001), o)
        n = dr.select(active, n + 1, n)
    return n


def test_callable_in_outer_loop_and_frozen():
    t = types("llvm")
    V, faces = soup(500, seed=6)
    sc = scene_from_arrays(V, faces)
    acc = BVH.build(sc, t)
    ray, _ = random_rays(t, 1024, seed=8)
    o, d = ray.o, ray.d

    ref = count_layers(acc, o, d, t).numpy()
    assert ref.max() >= 2
    frozen = dr.freeze(lambda acc, o, d: acc.intersect(Ray(o, d, t.Float(dr.inf))).t)
    plain = acc.intersect(Ray(o, d, t.Float(dr.inf))).t.numpy()
    for _ in range(3):
        assert np.array_equal(frozen(acc, o, d).numpy(), plain)


# ---- a seed scene, end to end ---------------------------------------------------------------
def test_render_identical_across_accelerators():
    from renderer.render import render
    from renderer.scene import load_scene
    path = ROOT / "scenes" / "cornell_box.toml"
    if not path.exists():
        pytest.skip("scenes/cornell_box.toml not present")
    scene = load_scene(path).with_size(48, 48)
    images = {a: render(scene, backend="llvm", accel=a).image for a in ("brute", "boxes", "bvh")}
    assert images["brute"].max() > 0
    assert np.array_equal(images["boxes"], images["brute"])
    assert np.array_equal(images["bvh"], images["brute"])


def test_any_hit_far_child_first_gives_brute_force_answers():
    """Any-hit node steps visit the farthest hit child first (``accel.wide``'s module
    text): on random rays through a box room with clutter, where many children are hit at
    once and every ray hits, every BVH's any-hit answer is brute force's (why far first:
    its iteration counts against nearest first and slot order are in
    ``lab/notes/accel-decisions.md``)."""
    from renderer.accel import BVH4, BVH8
    t = types("llvm")
    rng = np.random.default_rng(5)
    Vc, fc = soup(600, seed=5, size=0.04)
    room = np.array([[x, y, z] for x in (-0.5, 1.5) for y in (-0.5, 1.5) for z in (-0.5, 1.5)])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    walls = [(a, b, c) for a, b, c, d in quads] + [(a, c, d) for a, b, c, d in quads]
    V = np.concatenate([Vc, room])
    faces = np.concatenate([fc, np.asarray(walls) + len(Vc)])
    sc = scene_from_arrays(V, faces)
    o = rng.random((4096, 3))
    d = rng.standard_normal((4096, 3))
    ray = Ray(o=t.Array3f(*o.T.astype(np.float32)), d=t.Array3f(*d.T.astype(np.float32)),
              t_max=t.Float(np.full(4096, np.inf, np.float32)))
    active = dr.full(t.Bool, True, 4096)
    ref = BruteForce.build(sc, t).intersect_p(ray, active).numpy()
    assert ref.all()                                  # the room closes every ray
    for cls in (BVH, BVH4, BVH8):
        acc = cls.build(sc, t)
        assert np.array_equal(acc.intersect_p(ray, active).numpy(), ref), cls
