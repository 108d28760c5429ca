"""The cache of built trees (``renderer.accel.cache``, ``builders.binary_tree``): a hit
gives the same tree as the build; any change of triangles or builder misses; a corrupt or
foreign entry is rebuilt with one warning and never trusted; a folder that cannot be
written works without the cache; two processes writing one key leave one valid entry; the
folder stays within its bound; ``whitted render --no-cache`` writes nothing.

References: the trees built without the cache (``binary_tree(cache=None)``)."""
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
from accel_util import scene_from_arrays, soup

from renderer.accel.builders import binary_tree, resolve_build, tree_key
from renderer.accel.cache import CacheWarning, TreeCache

ROOT = Path(__file__).resolve().parents[1]


def _scene(seed=1, F=400):
    V, faces = soup(F, seed=seed)
    return scene_from_arrays(V, faces)


def _same_tree(a, b):
    assert np.array_equal(a.boxes, b.boxes) and np.array_equal(a.children, b.children)
    assert np.array_equal(a.order, b.order) and a.levels == b.levels


@pytest.mark.parametrize("build", ["sah", "device"])
def test_hit_gives_the_built_tree(tmp_path, build):
    scene = _scene()
    cache = TreeCache(tmp_path)
    a, info = binary_tree(scene, "llvm", build=build, cache=cache)
    assert not info.cached and info.build == build
    b, info = binary_tree(scene, "llvm", build=build, cache=cache)
    assert info.cached and cache.hits == 1
    _same_tree(a, b)
    _same_tree(a, binary_tree(scene, "llvm", build=build)[0])
    if build == "sah":
        assert b.cells is None or np.array_equal(a.cells[0], b.cells[0])


def test_any_content_change_misses(tmp_path):
    scene = _scene()
    cache = TreeCache(tmp_path)
    binary_tree(scene, "llvm", build="sah", cache=cache)
    moved = _scene()
    moved.vertices[5, 1] = np.nextafter(moved.vertices[5, 1], np.float32(np.inf))
    keys = {tree_key(scene, "sah"), tree_key(moved, "sah"), tree_key(scene, "device"),
            tree_key(scene, "sah", leaf_size=4)}
    assert len(keys) == 4
    _, info = binary_tree(moved, "llvm", build="sah", cache=cache)
    assert not info.cached
    _, info = binary_tree(scene, "llvm", build="device", cache=cache)
    assert not info.cached


@pytest.mark.parametrize("damage", ["flip", "truncate", "foreign", "garbage"])
def test_corrupt_or_foreign_entry_is_rebuilt_with_one_warning(tmp_path, damage):
    scene, other = _scene(1), _scene(2)
    cache = TreeCache(tmp_path)
    ref, _ = binary_tree(scene, "llvm", build="sah", cache=cache)
    binary_tree(other, "llvm", build="sah", cache=cache)
    path = cache.path("tree", tree_key(scene, "sah"))
    data = bytearray(path.read_bytes())
    if damage == "flip":
        data[len(data) // 2] ^= 0x40
    elif damage == "truncate":
        data = data[: len(data) // 3]
    elif damage == "foreign":            # a valid entry of another scene under this key
        data = bytearray(cache.path("tree", tree_key(other, "sah")).read_bytes())
    else:
        data = bytearray(b"not a cache file at all")
    path.write_bytes(bytes(data))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        got, info = binary_tree(scene, "llvm", build="sah", cache=TreeCache(tmp_path))
    assert [x.category for x in w] == [CacheWarning], [str(x.message) for x in w]
    assert not info.cached
    _same_tree(got, ref)
    # the rebuilt tree replaced the bad entry
    _, info = binary_tree(scene, "llvm", build="sah", cache=TreeCache(tmp_path))
    assert info.cached


def test_unwritable_folder_works_without_the_cache(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("a file where the cache folder would go")
    cache = TreeCache(blocker / "cache")
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        a, info = binary_tree(_scene(), "llvm", build="sah", cache=cache)
        b, info2 = binary_tree(_scene(), "llvm", build="sah", cache=cache)
    assert not info.cached and not info2.cached
    assert [x.category for x in w] == [CacheWarning]     # one warning, not one per write
    _same_tree(a, b)


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0,
                    reason="root writes into read-only folders")
def test_read_only_folder_reads_and_does_not_write(tmp_path):
    scene = _scene()
    binary_tree(scene, "llvm", build="sah", cache=TreeCache(tmp_path))
    os.chmod(tmp_path, 0o555)
    try:
        _, info = binary_tree(scene, "llvm", build="sah", cache=TreeCache(tmp_path))
        assert info.cached
        with warnings.catch_warnings(record=True):
            warnings.simplefilter("always")
            _, info = binary_tree(_scene(3), "llvm", build="sah", cache=TreeCache(tmp_path))
        assert not info.cached
    finally:
        os.chmod(tmp_path, 0o755)


def test_two_processes_writing_one_key(tmp_path):
    code = (
        "import sys; sys.path.insert(0, sys.argv[2]); sys.path.insert(0, sys.argv[3])\n"
        "from accel_util import scene_from_arrays, soup\n"
        "from renderer.accel.cache import TreeCache\n"
        "from renderer.accel.builders import binary_tree, tree_key, _to_entry\n"
        "V, f = soup(400, seed=1); s = scene_from_arrays(V, f)\n"
        "a, _ = binary_tree(s, 'llvm', build='device')\n"
        "c = TreeCache(sys.argv[1]); k = tree_key(s, 'device')\n"
        "for _ in range(30):\n"
        "    c.put('tree', k, *_to_entry(a))\n"
    )
    env = dict(os.environ, WHITTED_CACHE=str(tmp_path))
    procs = [subprocess.Popen([sys.executable, "-c", code, str(tmp_path), str(ROOT / "tests"),
                               str(ROOT)], env=env) for _ in range(2)]
    assert [p.wait(timeout=300) for p in procs] == [0, 0]
    entries = sorted(p.name for p in tmp_path.iterdir())
    assert len(entries) == 1 and not entries[0].startswith(".")      # no temporaries left
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got, info = binary_tree(_scene(), "llvm", build="device", cache=TreeCache(tmp_path))
    assert info.cached
    _same_tree(got, binary_tree(_scene(), "llvm", build="device")[0])


def test_folder_stays_within_its_bound(tmp_path):
    cache = TreeCache(tmp_path)
    binary_tree(_scene(1), "llvm", build="sah", cache=cache)
    size = sum(p.stat().st_size for p in tmp_path.iterdir())
    small = TreeCache(tmp_path, max_bytes=int(size * 2.5))
    for seed in (2, 3, 4, 5):
        binary_tree(_scene(seed), "llvm", build="sah", cache=small)
    assert sum(p.stat().st_size for p in tmp_path.iterdir()) <= small.max_bytes
    # the newest entry is kept
    _, info = binary_tree(_scene(5), "llvm", build="sah", cache=small)
    assert info.cached


def test_auto_rule():
    assert resolve_build("auto", 10**6, 1, sah_cached=True) == "sah"
    assert resolve_build("auto", 10**6, 1, sah_cached=False) == "device"
    assert resolve_build("auto", 10**6, None, sah_cached=False) == "sah"
    assert resolve_build("auto", 100, 1, sah_cached=False) == "sah"
    assert resolve_build("device", 100, None, sah_cached=True) == "device"
    with pytest.raises(ValueError, match="build"):
        resolve_build("fast", 1, 1, False)


def test_auto_takes_a_cached_sah_tree(tmp_path):
    scene = _scene(F=30000)
    cache = TreeCache(tmp_path)
    _, info = binary_tree(scene, "llvm", build="auto", cache=cache, frames=1)
    assert info.build == "device" and not info.cached
    binary_tree(scene, "llvm", build="sah", cache=cache)
    _, info = binary_tree(scene, "llvm", build="auto", cache=cache, frames=1)
    assert info.build == "sah" and info.cached


def test_cli_no_cache_writes_nothing(tmp_path):
    env = dict(os.environ, WHITTED_CACHE=str(tmp_path / "c"))
    base = [sys.executable, "-m", "whitted", "render", "cornell_box", "--backend", "llvm",
            "--size", "16x16"]
    r = subprocess.run(base + ["--out", str(tmp_path / "a"), "--no-cache"], env=env,
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert not (tmp_path / "c").exists()
    r = subprocess.run(base + ["--out", str(tmp_path / "b")], env=env, capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert len(list((tmp_path / "c").glob("tree-*.bin"))) == 1
    r = subprocess.run(base + ["--out", str(tmp_path / "d")], env=env, capture_output=True,
                       text=True, timeout=300)
    assert "read from the cache" in r.stdout


def _scene_file(tmp_path, levels=2):
    path = tmp_path / "s.toml"
    path.write_text(
        "[camera]\nresolution = [8, 8]\nposition = [0, 0, 5]\ntarget = [0, 0, 0]\n"
        "fov_y = 40.0\n[materials.m]\nkd = [0.5, 0.5, 0.5]\n"
        f"[[objects]]\nshape = \"cube\"\nmaterial = \"m\"\nsubdivide = {levels}\n"
        "[[objects]]\nshape = \"sphere\"\nmaterial = \"m\"\n")
    return path


def test_scene_load_through_the_cache_gives_the_same_scene(tmp_path):
    from renderer.scene import load_scene
    path = _scene_file(tmp_path)
    ref = load_scene(path)
    cache = TreeCache(tmp_path / "cache")
    cold = load_scene(path, cache=cache)
    warm = load_scene(path, cache=cache)
    assert cache.hits >= 2 and cache.misses >= 2
    for s in (cold, warm):
        for f in ("vertices", "normals", "faces", "vertices64", "normals64", "face_material",
                  "face_object"):
            assert np.array_equal(getattr(s, f), getattr(ref, f)), f
        assert s.objects == ref.objects
    # a change of the cube's subdivision misses its entries (the sphere's still hits)
    hits, misses = cache.hits, cache.misses
    load_scene(_scene_file(tmp_path, levels=1), cache=cache)
    assert (cache.hits, cache.misses) == (hits + 1, misses + 2)


@pytest.mark.parametrize("build", ["sah", "device"])
@pytest.mark.parametrize("accel", ["bvh", "bvh4"])
def test_cached_unpadded_boxes_upload_the_refitted_boxes(tmp_path, build, accel):
    """A tree from the cache carries its unpadded boxes (``BVHArrays.raw``), and the
    accelerator uploads from them exactly the node records a refit of the tree uploads
    (reference: the same tree without ``raw``, padded by ``refit_boxes``)."""
    from dataclasses import replace

    from renderer.accel import build_accelerator
    from renderer.device import types
    from renderer.scene import load_scene

    scene = load_scene(ROOT / "scenes" / "bunny.toml")
    cache = TreeCache(tmp_path)
    binary_tree(scene, "llvm", build=build, cache=cache)
    hit, info = binary_tree(scene, "llvm", build=build, cache=cache)
    assert info.cached and hit.raw is not None and hit.raw.dtype == np.float32
    t = types("llvm", "float32")
    cls = build_accelerator(accel, scene, t, build="sah").__class__
    got = cls.build(scene, t, binary=hit)
    ref = cls.build(scene, t, binary=replace(hit, raw=None))
    assert np.array_equal(got.nodes.numpy(), ref.nodes.numpy())


def test_entry_whose_unpadded_boxes_leave_the_tree_is_rebuilt(tmp_path):
    """Unpadded boxes outside their padded boxes are not a tree's: the entry is rebuilt."""
    from renderer.accel.builders import _to_entry

    scene = _scene()
    cache = TreeCache(tmp_path)
    a, _ = binary_tree(scene, "llvm", build="sah", cache=cache)
    arrays, meta = _to_entry(a)
    arrays["raw"] = arrays["raw"] + np.float32(1.0)
    cache.put("tree", tree_key(scene, "sah"), arrays, meta)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        b, info = binary_tree(scene, "llvm", build="sah", cache=cache)
    assert not info.cached
    assert sum(issubclass(x.category, CacheWarning) for x in w) == 1
    _same_tree(a, b)


def test_background_writes_are_whole_entries_after_flush(tmp_path):
    """``TreeCache(background=True)``: ``put`` returns at once, ``flush`` waits, and the
    entry then reads back as the synchronous cache's (reference: the tree built without a
    cache)."""
    scene = _scene()
    cache = TreeCache(tmp_path, background=True)
    a, _ = binary_tree(scene, "llvm", build="device", cache=cache)
    cache.flush()
    assert not cache._pending
    b, info = binary_tree(scene, "llvm", build="device", cache=TreeCache(tmp_path))
    assert info.cached
    _same_tree(a, b)
    _same_tree(b, binary_tree(scene, "llvm", build="device")[0])
