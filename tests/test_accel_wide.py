"""The wide BVHs (``bvh4``, ``bvh8``: the binary SAH tree collapsed into 4/8-wide nodes with
8-bit quantised child boxes) give bitwise the hits of brute force on random and adversarial
rays, on both backends' code paths, and the collapse is a valid tree within the stack bound.

Reference: ``BruteForce`` (every ray against every triangle, same triangle routine).
"""
from dataclasses import replace
from pathlib import Path

import drjit as dr
import numpy as np
import pytest
from accel_util import assert_same_hits, hits, random_rays, scene_from_arrays, soup

from renderer.accel import BVH, BruteForce, Ray, WideBVH
from renderer.accel.bvh_build import build_bvh
from renderer.accel.traverse import DONE
from renderer.accel.wide import HEAD, check_wide, collapse, quantize
from renderer.device import array3, types

ROOT = Path(__file__).resolve().parents[1]
LAYOUTS = [(4, True), (8, True), (4, False), (8, False)]
IDS = [f"bvh{w}{'q' if q else 'f'}" for w, q in LAYOUTS]


def grid(n=24):
    """A tessellated unit square at z = 0 (2 n^2 triangles sharing edges and vertices) with
    a second, coincident copy of its first row (exact ties) and a tilted sheet."""
    xs = np.linspace(0.0, 1.0, n + 1)
    X, Y = np.meshgrid(xs, xs, indexing="ij")
    V = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], axis=1)
    idx = lambda i, j: i * (n + 1) + j  # noqa: E731
    faces = []
    for i in range(n):
        for j in range(n):
            faces += [[idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)],
                      [idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)]]
    faces = np.array(faces)
    faces = np.concatenate([faces, faces[:2 * n]])                  # coincident duplicates
    tilt = np.array([[0.1, 0.1, 0.2], [0.9, 0.2, 0.6], [0.2, 0.9, 0.4]])
    V = np.concatenate([V, tilt])
    faces = np.concatenate([faces, [[len(V) - 3, len(V) - 2, len(V) - 1]]])
    return V.astype(np.float32), faces


def adversarial_rays(t, V, faces, seed):
    """Rays aimed exactly at vertices, edge midpoints and centroids of the triangles from
    random origins on both sides, rays in the plane z = 0 (grazing), axis-parallel rays
    through grid vertices, rays starting on the surface, and t_max exactly at a vertex."""
    rng = np.random.default_rng(seed)
    F = faces[rng.integers(0, len(faces), 1500)]
    P = V.astype(np.float64)
    w = rng.integers(0, 3, len(F))
    corner = P[F[np.arange(len(F)), w]]
    mid = 0.5 * (P[F[:, 0]] + P[F[:, 1]])
    cen = P[F].mean(axis=1)
    targets = np.concatenate([corner, mid, cen])
    o = targets + rng.normal(size=targets.shape) * 0.7
    d = targets - o
    t_max = np.where(rng.random(len(o)) < 0.3, 1.0, np.inf)       # ends exactly on target
    # grazing rays in the plane z = 0 and axis-parallel rays down through grid vertices
    g = rng.random((500, 3))
    g[:, 2] = 0.0
    gd = rng.normal(size=(500, 3))
    gd[:, 2] = 0.0
    ax = np.concatenate([corner[:500, :2], np.full((500, 1), 1.0)], axis=1)
    axd = np.tile([0.0, 0.0, -1.0], (500, 1))
    on = cen[:500] + np.array([0.0, 0.0, 0.0])                       # starting on the surface
    ond = rng.normal(size=(500, 3))
    o = np.concatenate([o, g, ax, on])
    d = np.concatenate([d, gd, axd, ond])
    t_max = np.concatenate([t_max, np.full(1500, np.inf)])
    ray = Ray(array3(t, o.astype(np.float32)), array3(t, d.astype(np.float32)),
              t.Float(t_max.astype(np.float32)))
    return ray, t.Bool(True)


@pytest.mark.parametrize("width", [4, 8])
@pytest.mark.parametrize("options", [dict(), dict(sah_leaves=True, leaf_size=8),
                                     dict(depth_first=False, all_axes=False)],
                         ids=["defaults", "sah_leaves", "bfs"])
def test_collapse_is_a_valid_tree_within_the_stack_bound(width, options):
    V, faces = soup(3000, seed=1)
    a = build_bvh(V, faces, **options)
    w = collapse(a, width)
    check_wide(w, a)
    assert w.levels < a.levels and w.node_count < a.node_count
    assert np.sum(w.refs != DONE) / w.node_count > 3   # > 3 children per node on average


@pytest.mark.parametrize("width", [4, 8])
def test_collapse_keeps_a_small_stack_bound(width):
    """With a stack of only as many entries as the binary tree has levels, the collapse
    expands less but still never needs more."""
    V, faces = soup(3000, seed=2)
    a = build_bvh(V, faces)
    w = collapse(a, width, stack_size=a.levels)
    assert w.max_stack <= a.levels
    check_wide(w, a)


@pytest.mark.parametrize("width", [4, 8])
def test_collapse_fills_the_room_of_a_larger_stack(width):
    """A tree at its stack bound (the binary tree's levels) leaves the deep paths' nodes no
    room for more than 2 children; the traversal's stack of twice that fills them, still
    within the bound it was given."""
    V, faces = soup(3000, seed=2)
    a = build_bvh(V, faces)
    tight = collapse(a, width, stack_size=a.levels)
    roomy = collapse(a, width, stack_size=2 * a.levels)
    check_wide(roomy, a)
    assert tight.max_stack <= a.levels < roomy.max_stack <= 2 * a.levels
    assert roomy.node_count < tight.node_count
    assert np.mean(roomy.refs != DONE) > np.mean(tight.refs != DONE)


@pytest.mark.parametrize("width", [4, 8])
def test_quantised_boxes_contain_the_float_boxes(width):
    V, faces = grid(16)
    V = V * np.float32(1000.0) + np.float32(12345.0)        # large offsets: float rounding
    a = build_bvh(V, faces)
    w = collapse(a, width)
    q = quantize(w)
    N, W = w.node_count, width
    org = q[:, 0:3].view(np.float32)
    shifts = np.array([0, 8, 16, 24], np.uint32)
    scale = (((q[:, 3:4] >> shifts[:3]) & 255) << 23).astype(np.uint32).view(np.float32)
    assert np.all((scale > 0) & np.isfinite(scale))                  # normal powers of two
    b = (q[:, HEAD:HEAD + 6 * W // 4].reshape(N, 6, W // 4, 1) >> shifts) & 255
    b = b.reshape(N, 6, W).astype(np.float32)
    for axis in range(3):
        dec_lo = org[:, axis, None] + b[:, axis] * scale[:, axis, None]
        dec_hi = org[:, axis, None] + b[:, 3 + axis] * scale[:, axis, None]
        real = w.refs != DONE
        assert np.all((dec_lo <= w.boxes[:, axis])[real])
        assert np.all((dec_hi >= w.boxes[:, 3 + axis])[real])


@pytest.mark.parametrize("layout", LAYOUTS, ids=IDS)
@pytest.mark.parametrize("seed", [0, 1])
def test_wide_bvh_matches_brute_force_on_random_rays(layout, seed):
    width, quantized = layout
    t = types("llvm")
    V, faces = soup(2000, seed=seed)
    sc = scene_from_arrays(V, faces, n_objects=3)
    ray, active = random_rays(t, 4096, seed=10 + seed)
    ref = hits(BruteForce.build(sc, t), ray, active, t)
    assert ref[0].sum() > 500
    assert_same_hits(hits(WideBVH.build(sc, t, width=width, quantized=quantized), ray,
                          active, t), ref)


@pytest.mark.parametrize("layout", LAYOUTS, ids=IDS)
def test_wide_bvh_matches_brute_force_on_adversarial_rays(layout):
    width, quantized = layout
    t = types("llvm")
    V, faces = grid()
    sc = scene_from_arrays(V, faces, n_objects=2)
    ray, active = adversarial_rays(t, V, faces, seed=3)
    ref = hits(BruteForce.build(sc, t), ray, active, t)
    assert ref[0].sum() > 2000
    assert_same_hits(hits(WideBVH.build(sc, t, width=width, quantized=quantized), ray,
                          active, t), ref)


@pytest.mark.parametrize("width", [4, 8])
def test_cuda_path_matches_brute_force_on_llvm(width):
    """The CUDA branch (packet gathers, inline masks) on LLVM arrays, as in
    ``test_accel_traversal``."""
    t = types("llvm")
    as_cuda = replace(t, backend="cuda")

    class OnCudaPath(WideBVH):
        types = property(lambda self: as_cuda)

    V, faces = soup(2000, seed=5)
    sc = scene_from_arrays(V, faces, n_objects=2)
    ray, active = random_rays(t, 4096, seed=15)
    ref = hits(BruteForce.build(sc, t), ray, active, t)
    acc = OnCudaPath.build(sc, as_cuda, width=width)   # built as for CUDA: UInt32 records
    assert dr.type_v(acc.nodes) == dr.VarType.UInt32 and acc.tri_trav is None
    assert_same_hits(hits(acc, ray, active, t), ref)


@pytest.mark.parametrize("width", [4, 8])
def test_llvm_reads_records_through_64_bit_gathers(width):
    """On LLVM (float32) the node records, child references and the traversal's copy of
    the triangles are UInt64 views (``gather_pairs``), holding bitwise the words of the
    32-bit layout that CUDA reads; the hits are brute force's (random rays above)."""
    t = types("llvm")
    V, faces = soup(500, seed=2)
    sc = scene_from_arrays(V, faces, n_objects=1)
    acc = WideBVH.build(sc, t, width=width, leaf_size=4)
    as_cuda = replace(t, backend="cuda")          # the same tree (each backend has its
    ref = WideBVH.build(sc, as_cuda, width=width, leaf_size=4)   # default leaf size)
    assert dr.type_v(acc.nodes) == dr.VarType.UInt64
    assert dr.type_v(acc.refs) == dr.VarType.UInt64
    assert np.array_equal(acc.nodes.numpy().view(np.uint32), ref.nodes.numpy())
    assert np.array_equal(acc.refs.numpy().view(np.uint32), ref.refs.numpy())
    assert np.array_equal(acc.tri_trav.numpy().view(np.float32), acc.tri_data.numpy())


def test_double_precision_matches_brute_force():
    t = types("llvm", "float64")
    V, faces = soup(800, seed=9)
    sc = scene_from_arrays(V, faces, n_objects=2)
    ray, active = random_rays(t, 2048, seed=19)
    ref = hits(BruteForce.build(sc, t), ray, active, t)
    for width in (4, 8):
        assert_same_hits(hits(WideBVH.build(sc, t, width=width), ray, active, t), ref)


def test_single_triangle_scene():
    t = types("llvm")
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    o = t.Array3f(t.Float([0.2, 2.0]), t.Float([0.2, 2.0]), t.Float([1.0, 1.0]))
    ray = Ray(o, t.Array3f(0.0, 0.0, -1.0), t.Float(dr.inf))
    for width in (4, 8):
        h = WideBVH.build(scene_from_arrays(tri, [[0, 1, 2]]), t, width=width).intersect(
            ray, t.Bool(True))
        assert h.found.numpy().tolist() == [True, False]
        assert np.allclose(h.t.numpy()[0], 1.0)


def test_wide_nodes_take_fewer_steps_than_binary():
    """The instrumented traversals: the same rays need fewer node steps in the wide trees,
    and exactly as many candidate triangles as leaves they enter."""
    t = types("llvm")
    V, faces = soup(4000, seed=4)
    sc = scene_from_arrays(V, faces)
    ray, active = random_rays(t, 4096, seed=24)
    a = build_bvh(sc.vertices, sc.faces)
    nodes = {}
    for name, acc in (("bvh", BVH.build(sc, t, binary=a)),
                      ("bvh4", WideBVH.build(sc, t, width=4, binary=a)),
                      ("bvh8", WideBVH.build(sc, t, width=8, binary=a))):
        n, tri, it = (x.numpy() for x in acc.counts(ray, active))
        assert np.all(it >= n) and np.all(it <= n + tri)
        nodes[name] = n.mean()
    assert nodes["bvh4"] < 0.7 * nodes["bvh"]
    assert nodes["bvh8"] < nodes["bvh4"]


def test_render_identical_across_accelerators():
    from renderer.render import render
    from renderer.scene import load_scene
    path = ROOT / "scenes" / "cornell_sphere.toml"
    if not path.exists():
        pytest.skip("scenes/cornell_sphere.toml not present")
    scene = load_scene(path).with_size(48, 48)
    images = {a: render(scene, backend="llvm", accel=a).image
              for a in ("brute", "bvh", "bvh4", "bvh8")}
    assert images["brute"].max() > 0
    for a in ("bvh", "bvh4", "bvh8"):
        assert np.array_equal(images[a], images["brute"]), a


@pytest.mark.parametrize("width", [0, 4, 8])
@pytest.mark.parametrize("rays", ["random", "adversarial"])
def test_refill_traversal_matches_brute_force(width, rays, monkeypatch):
    """``refill`` (lanes take the next ray when theirs is done) gives bitwise brute force's
    hits, for the wide BVHs (``width``) and the binary one (0); few lanes, so that every
    lane traces several rays."""
    import renderer.accel.traverse as traverse
    monkeypatch.setattr(traverse, "REFILL_MIN_LANES", 64)
    t = types("llvm")
    if rays == "random":
        V, faces = soup(2000, seed=7)
        ray, active = random_rays(t, 4096, seed=17)
    else:
        V, faces = grid()
        ray, active = adversarial_rays(t, V, faces, seed=5)
    sc = scene_from_arrays(V, faces, n_objects=2)
    ref = hits(BruteForce.build(sc, t), ray, active, t)
    acc = replace(WideBVH.build(sc, t, width=width) if width else BVH.build(sc, t), refill=8)
    assert_same_hits(hits(acc, ray, active, t), ref)
    occluded = acc.intersect_p(ray, active).numpy()
    assert np.array_equal(occluded, BruteForce.build(sc, t).intersect_p(ray, active).numpy())
    assert np.array_equal(acc.counts(ray, active)[0].numpy(),      # counts: lane traversal
                          replace(acc, refill=0).counts(ray, active)[0].numpy())
