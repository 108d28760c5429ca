"""The device BVH build (``renderer.accel.device_build``, LLVM here) gives valid trees that
the traversal reads as it reads the SAH tree: every triangle once, leaves within the leaf
size, each child's box inside its parent's and around its triangles, the level bound; the
hits are bitwise brute force's and the images bitwise the SAH tree's on every bundled
scene and view; the far-origin and closed-mesh hard cases stay green through the new tree.

References: direct numpy checks of the structure, ``BruteForce`` (the oracle), and the
images of the SAH tree (``build="sah"``)."""
from functools import partial
from pathlib import Path

import numpy as np
import pytest
from accel_util import assert_same_hits, hits, random_rays, scene_from_arrays, soup

import evaluation.hard.runners as hard_runners
from evaluation.hard.cases import Config, load_cases
from renderer.accel import ACCELERATORS, BruteForce, build_accelerator
from renderer.accel.bvh_build import MAX_LEVELS, check_bvh
from renderer.accel.device_build import build_device
from renderer.accel.spatial import clipped_boxes
from renderer.accel.traverse import COUNT_SHIFT, FIRST_MASK, LEAF_BIT
from renderer.device import types
from renderer.render import Renderer
from renderer.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
#: Every bundled scene but the 1.1M-triangle bunny (its SAH build alone takes ~20 s here).
SCENES = sorted(p.stem for p in (ROOT / "scenes").glob("*.toml") if p.stem != "bunny_1m")


def child_boxes_nest(a, V, faces):
    """Assert: each leaf's box holds its triangles; each inner child's box holds both of
    its own child boxes; leaf sizes and the parent links (every inner node once). A tree
    with cells (references of cut triangles) holds each reference's triangle clipped to its
    cell (``spatial.clipped_boxes``, the host's computation)."""
    if a.cells is None:
        tri = np.asarray(V, np.float32)[np.asarray(faces)[a.order]]
        tlo, thi = tri.min(axis=1), tri.max(axis=1)
    else:
        tlo, thi = clipped_boxes(V, faces, a.order, a.cells[0], a.cells[1], np.float32)
    for k in range(2):
        ref = a.children[:, k].astype(np.int64)
        box = a.boxes[:, 6 * k:6 * k + 6]
        leaf = (ref & LEAF_BIT) != 0
        first, count = ref[leaf] & FIRST_MASK, ((ref[leaf] >> COUNT_SHIFT) & 15) + 1
        for j in range(int(count.max())):
            m = j < count
            i = first[m] + j
            assert np.all(box[leaf][m, 0:3] <= tlo[i]) and np.all(box[leaf][m, 3:6] >= thi[i])
        c = ref[~leaf]
        inner_box = box[~leaf]
        for side in range(2):
            cb = a.boxes[c, 6 * side:6 * side + 6]
            assert np.all(inner_box[:, 0:3] <= cb[:, 0:3])
            assert np.all(inner_box[:, 3:6] >= cb[:, 3:6])
    parents = a.children.astype(np.int64).reshape(-1)
    parents = parents[(parents & LEAF_BIT) == 0]
    assert np.array_equal(np.sort(parents), np.arange(1, a.node_count))


@pytest.mark.parametrize("leaf_size", [1, 2, 4])
def test_device_tree_is_valid(leaf_size):
    V, faces = soup(3000, seed=3)
    a = build_device(V, faces, "llvm", leaf_size=leaf_size)
    check_bvh(a)
    child_boxes_nest(a, V, faces)
    count = ((a.children.astype(np.int64) >> COUNT_SHIFT) & 15) + 1
    assert count[(a.children & LEAF_BIT) != 0].max() <= leaf_size
    assert a.levels <= MAX_LEVELS and a.sah_cost > 0


def test_device_tree_keeps_the_level_bound_on_degenerate_input():
    # coincident triangles (one Morton code: middle splits) and a chain of nested
    # triangles growing geometrically (radix splits peel one per level near the corner)
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float32)
    V = np.tile(tri, (20000, 1))
    a = build_device(V, np.arange(V.shape[0]).reshape(-1, 3), "llvm")
    check_bvh(a)
    assert a.levels <= MAX_LEVELS
    k = np.arange(400)
    chain = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float64)[None] * (1.1 ** k)[:, None,
                                                                                       None]
    chain[:, :, 2] = k[:, None] * 1e-3
    Vc = chain.reshape(-1, 3)
    fc = np.arange(Vc.shape[0]).reshape(-1, 3)
    a = build_device(Vc, fc, "llvm")
    check_bvh(a)
    child_boxes_nest(a, Vc, fc)
    assert a.levels <= MAX_LEVELS


def morton_chain(cluster=64):
    """Clusters of ``cluster`` coincident tiny triangles whose Morton codes are 2^j, j =
    0..29 (one bit each), plus one at the far corner: radix splits peel one cluster per
    level (30 levels), then each cluster needs log2(cluster / 2) more: over MAX_LEVELS."""
    tri = np.array([[0, 0, 0], [1e-5, 0, 0], [0, 1e-5, 0]])
    pts = []
    for j in range(30):
        p = np.zeros(3)
        p[2 - j % 3] = (2 ** (j // 3) + 0.5) / 1024
        pts.append(p)
    pts.append(np.ones(3) - 2e-5)
    V = np.concatenate([np.tile(tri + p, (cluster, 1)) for p in pts])
    return V, np.arange(V.shape[0]).reshape(-1, 3)


def test_device_tree_keeps_the_level_bound_on_a_morton_chain():
    V, faces = morton_chain()
    a = build_device(V, faces, "llvm")
    check_bvh(a)
    child_boxes_nest(a, V, faces)
    assert a.levels <= MAX_LEVELS


def test_tiny_scenes():
    for F in (1, 2, 3):
        V, faces = soup(F, seed=F)
        a = build_device(V, faces, "llvm")
        check_bvh(a)


@pytest.mark.parametrize("accel", ["bvh", "bvh4", "bvh8"])
def test_device_tree_matches_brute_force(accel):
    t = types("llvm")
    V, faces = soup(2000, seed=4)
    scene = scene_from_arrays(V, faces)
    ray, active = random_rays(t, 4000, seed=5)
    ref = hits(BruteForce.build(scene, t), ray, active, t)
    acc = build_accelerator(accel, scene, t, build="device")
    assert acc.info["tree_build"] == "device"
    assert_same_hits(hits(acc, ray, active, t), ref)


@pytest.mark.parametrize("name", SCENES)
def test_images_equal_the_sah_trees_on_every_scene_and_view(name):
    # "device" is the PLOC tree (builders.DEVICE_BUILD), "radix" the Morton radix tree
    scene = load_scene(ROOT / "scenes" / f"{name}.toml").with_overrides(size=(24, 24))
    sah = Renderer(scene, backend="llvm", build="sah")
    for build in ("device", "radix"):
        dev = Renderer(scene, backend="llvm", build=build)
        assert dev.arrays.accel.info["tree_build"] == build
        for v in range(len(scene.cameras)):
            a, b = sah.render(v).image, dev.render(v).image
            assert np.array_equal(a, b), (name, build, scene.cameras[v].name)


@pytest.mark.parametrize("build", ["ploc", "radix"])
@pytest.mark.parametrize("case", ["closed_mesh", "far_origin"])
def test_hard_cases_through_the_device_tree(monkeypatch, case, build):
    built = []

    def device_accel(name, scene, t, **kw):
        acc = build_accelerator(name, scene, t, **{**kw, "build": build})
        built.append(acc.info.get("tree_build"))
        return acc

    monkeypatch.setattr(hard_runners, "build_accelerator", device_accel)
    cfg = Config(backend="llvm", precisions=("float32",), accels=("bvh", "bvh4"), rays=4000)
    rows = hard_runners.run_suite(cfg, [case], load_cases())
    red = [f"{r.case} | {r.variant} | {r.criterion} | {r.measured}" for r in rows
           if not r.passed]
    assert rows and not red, "red rows:\n" + "\n".join(red)
    assert build in built


def test_every_tree_accelerator_takes_the_device_tree():
    assert set(ACCELERATORS) >= {"bvh", "bvh4", "bvh8"}
    t = types("llvm")
    V, faces = soup(300, seed=6)
    scene = scene_from_arrays(V, faces)
    for name in ("bvh", "bvh4", "bvh8"):
        acc = partial(build_accelerator, name, scene, t)(build="device")
        assert acc.info["tree_build"] == "device"


@pytest.mark.skipif(not __import__("drjit").has_backend(__import__("drjit").JitBackend.CUDA),
                    reason="no CUDA device")
def test_cuda_device_tree_is_valid_and_matches_brute_force():
    V, faces = soup(3000, seed=7)
    a = build_device(V, faces, "cuda")
    check_bvh(a)
    child_boxes_nest(a, V, faces)
    t = types("cuda")
    scene = scene_from_arrays(V, faces)
    ray, active = random_rays(t, 4000, seed=8)
    ref = hits(BruteForce.build(scene, t), ray, active, t)
    for name in ("bvh", "bvh4"):
        acc = build_accelerator(name, scene, t, build="device")
        assert_same_hits(hits(acc, ray, active, t), ref)


@pytest.mark.parametrize("leaf_size", [1, 2])
def test_device_raw_boxes_are_the_host_refit(leaf_size):
    """``build_device(raw=True)``'s unpadded boxes are those ``bvh_build.raw_boxes`` computes
    on the host over the same tree (reference), and padding them gives ``refit_boxes``'s
    bytes; without ``raw`` the tree is the same and carries none."""
    from renderer.accel.bvh_build import pad_refit, raw_boxes, refit_boxes

    V, faces = soup(3000, seed=7)
    a = build_device(V, faces, "llvm", leaf_size=leaf_size, raw=True)
    ref = raw_boxes(a, V, faces, np.float32)
    assert a.raw is not None and a.raw.dtype == np.float32
    assert np.array_equal(a.raw, ref)
    assert np.array_equal(pad_refit(a, a.raw, 7.5),
                          refit_boxes(a, V, faces, np.float32, 7.5))
    b = build_device(V, faces, "llvm", leaf_size=leaf_size)
    assert b.raw is None and np.array_equal(a.boxes, b.boxes)
    assert np.array_equal(a.children, b.children) and np.array_equal(a.order, b.order)
