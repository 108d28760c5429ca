"""A tree left on the device by its builder (``ploc.build_ploc_device``, a
``device_build.DeviceTree``) is the tree the host build answers, and the accelerator made
from it on the device (``BVH.from_device_tree``) holds the arrays the host path uploads
(``BVH.host_layout`` of the copied-back tree, then ``from_layout``), bit for bit, with and
without the 64-bit pair records (``uses_pairs``); the render path takes it where it can
(``builders.tree_accelerator``) and draws the same image with and without a cache.

References: ``build_ploc``'s host output, and the host layout of ``DeviceTree.host()``."""
from __future__ import annotations

import numpy as np
import pytest
from accel_util import soup

import renderer.accel.bvh as bvh_mod
from renderer.accel import BVH
from renderer.accel.device_build import DeviceTree
from renderer.accel.ploc import build_ploc, build_ploc_device
from renderer.device import types
from renderer.scene import load_scene

ROOT = __import__("pathlib").Path(__file__).resolve().parents[1]


def _same(x, y, what):
    u = x if isinstance(x, np.ndarray) else np.asarray(x.numpy())
    v = y if isinstance(y, np.ndarray) else np.asarray(y.numpy())
    assert u.dtype == v.dtype and u.shape == v.shape, what
    assert u.tobytes() == v.tobytes(), what


@pytest.mark.parametrize("name", ["bunny", "sponza"])
def test_device_output_is_the_host_tree(backend, name):
    sc = load_scene(ROOT / "scenes" / f"{name}.toml")
    host = build_ploc(sc.vertices, sc.faces, backend, cuts=False)
    dev = build_ploc_device(sc.vertices, sc.faces, backend, cuts=False)
    assert isinstance(dev, DeviceTree) and dev.build_seconds > 0
    leaves, sah, bounds = dev.summary()          # before any copy back
    back = dev.host()
    for f in ("boxes", "children", "order", "raw"):
        _same(getattr(back, f), getattr(host, f), f)
    assert (back.levels, back.leaf_count, back.sah_cost) == (host.levels, host.leaf_count,
                                                             host.sah_cost)
    assert (leaves, sah) == (host.leaf_count, host.sah_cost)
    assert all(np.array_equal(u, v) for u, v in zip(bounds, host.bounds))


def test_device_output_falls_back_to_host_arrays():
    V, faces = soup(2, seed=1)                   # a single leaf: the host's tree
    assert not isinstance(build_ploc_device(V, faces, "llvm"), DeviceTree)
    with pytest.raises(TypeError):
        build_ploc_device(V, faces, "llvm", output="gpu")


@pytest.mark.parametrize("pairs", [True, False])
@pytest.mark.parametrize("name", ["bunny", "cornell_sphere"])
def test_accelerator_from_the_device_tree_is_the_host_layouts(monkeypatch, backend, name,
                                                                pairs):
    if pairs and backend != "llvm":
        pytest.skip("64-bit pair records are the LLVM backend's")
    monkeypatch.setattr(bvh_mod, "uses_pairs", lambda t: pairs)
    import renderer.accel.base as base
    monkeypatch.setattr(base, "uses_pairs", lambda t: pairs)
    sc = load_scene(ROOT / "scenes" / f"{name}.toml")
    t = types(backend, "float32")
    dev = build_ploc_device(sc.vertices, sc.faces, backend, cuts=False)
    acc = BVH.from_device_tree(sc, t, dev)
    arrays, info = BVH.host_layout(sc, t, dev.host())
    ref = BVH.from_layout(t, arrays, info)
    for f in ("nodes", "children", "tri_data", "tri_trav"):
        x, y = getattr(acc, f), getattr(ref, f)
        assert (x is None) == (y is None), f
        if x is not None:
            _same(x, y, f)
    for f in ("ng", "n0", "n1", "n2"):
        for k in range(3):
            _same(getattr(acc.tris, f)[k], getattr(ref.tris, f)[k], f)
    for f in ("material", "smooth", "order"):
        _same(getattr(acc.tris, f), getattr(ref.tris, f), f)
    assert acc.info == info


def test_float64_is_refused():
    sc = load_scene(ROOT / "scenes" / "bunny.toml")
    dev = build_ploc_device(sc.vertices, sc.faces, "llvm", cuts=False)
    with pytest.raises(ValueError, match="float32"):
        BVH.from_device_tree(sc, types("llvm", "float64"), dev)


@pytest.mark.parametrize("background", [False, True])
def test_render_path_takes_the_device_tree(tmp_path, monkeypatch, background):
    """``Renderer`` with a PLOC tree and the binary BVH makes the accelerator from the
    device tree (no ``host_layout`` on its path), draws the SAH tree's image, and leaves
    a tree and a layout entry that a second renderer reads back into the same image."""
    import renderer.accel.builders as builders
    from renderer.accel.cache import TreeCache
    from renderer.render import Renderer, RenderOptions
    sc = load_scene(ROOT / "scenes" / "bunny.toml").with_size(48)
    sah = Renderer(sc, RenderOptions(backend="llvm", accel="bvh"), build="sah").render()
    made = []
    real = BVH.from_device_tree.__func__
    monkeypatch.setattr(BVH, "from_device_tree", classmethod(
        lambda cls, *a, **k: made.append(1) or real(cls, *a, **k)))
    for cache in (None, TreeCache(tmp_path / "cache", background=background)):
        made.clear()
        r = Renderer(sc, RenderOptions(backend="llvm", accel="bvh", cache=cache),
                     build="device")
        assert made == [1] and r.arrays.accel.info["tree_build"] == "device"
        np.testing.assert_array_equal(r.render().image, sah.image)
    cache.flush()
    kinds = sorted(p.name.split("-")[0] for p in (tmp_path / "cache").iterdir())
    assert kinds == ["layout", "tree"]
    made.clear()
    hit = Renderer(sc, RenderOptions(backend="llvm", accel="bvh", cache=cache),
                   build="device")
    assert made == [] and hit.arrays.accel.info["layout_cached"]
    np.testing.assert_array_equal(hit.render().image, sah.image)
    assert builders.on_device(builders.LayoutRequest("bvh", BVH, 2, "watertight"),
                              types("llvm", "float32"))
    assert not builders.on_device(builders.LayoutRequest("bvh", BVH, 2, "watertight"),
                                  types("llvm", "float64"))
