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
    """The loader's own entries (subdivided meshes, objects: ``loader.load_scene``; the
    scene entry over them is ``tests/test_scene_cache.py``'s)."""
    from renderer.scene.loader import load_scene
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


@pytest.mark.parametrize("background", [False, True])
def test_an_entry_that_cannot_be_made_is_one_warning_and_no_file(tmp_path, background):
    """``put_made``: the entry's arrays made by a function (on the writer thread with
    ``background``); one that raises leaves no file and one ``CacheWarning`` naming the
    error, never an exception out of the thread; one that succeeds is written."""
    cache = TreeCache(tmp_path / "c", background=background)

    def broken():
        raise MemoryError("no room for the layout")
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        cache.put_made("layout", "k" * 64, broken)
        cache.flush()
    assert [str(x.message) for x in w if x.category is CacheWarning] == [
        f"{tmp_path / 'c'}: layout cache entry not made (MemoryError: no room for the "
        "layout); working without it"]
    assert not (tmp_path / "c").exists() or not list((tmp_path / "c").iterdir())
    cache.put_made("layout", "k" * 64, lambda: ({"a": np.arange(5)}, {"n": 5}))
    cache.flush()
    got = TreeCache(tmp_path / "c").get("layout", "k" * 64)
    assert np.array_equal(got["a"], np.arange(5)) and got["meta"] == {"n": 5}


# ---- the cached layout: the arrays an accelerator uploads ----------------------------------

def _device_arrays(acc) -> dict:
    """Every array ``acc`` holds on the device, as numpy (an Array3f: its components)."""
    import drjit as dr
    out = {}
    for name in ("nodes", "children", "refs", "tri_data", "tri_trav"):
        v = getattr(acc, name, None)
        if v is not None:
            out[name] = np.asarray(v.numpy())
    for name in ("ng", "n0", "n1", "n2", "material", "smooth", "order"):
        v = getattr(acc.tris, name)
        parts = [v.x, v.y, v.z] if dr.size_v(v) == 3 else [v]
        out[f"tris.{name}"] = [np.asarray(p.numpy()) for p in parts]
    return out


def _same_arrays(a: dict, b: dict):
    assert a.keys() == b.keys()
    for k in a:
        x, y = (a[k], b[k]) if isinstance(a[k], list) else ([a[k]], [b[k]])
        assert all(np.array_equal(p.view(np.uint8), q.view(np.uint8)) for p, q in zip(x, y)), k


@pytest.mark.parametrize("precision", ["float32", "float64"])
@pytest.mark.parametrize("accel", ["bvh", "bvh4", "bvh8"])
def test_layout_hit_uploads_the_built_arrays(tmp_path, accel, precision):
    """A layout hit reads no tree (the tree entry is gone) and uploads, byte for byte, the
    arrays of the accelerator built without a cache (the reference)."""
    from renderer.accel import build_accelerator
    from renderer.device import types
    from renderer.scene import load_scene

    scene = load_scene(_scene_file(tmp_path))          # smooth sphere: vertex normals too
    t = types("llvm", precision)
    ref = _device_arrays(build_accelerator(accel, scene, t, build="device"))
    cache = TreeCache(tmp_path / "c")
    cold = build_accelerator(accel, scene, t, build="device", cache=cache)
    assert not cold.info["layout_cached"]
    _same_arrays(_device_arrays(cold), ref)
    for p in (tmp_path / "c").glob("tree-*.bin"):
        p.unlink()
    warm = build_accelerator(accel, scene, t, build="device", cache=TreeCache(tmp_path / "c"))
    assert warm.info["layout_cached"] and warm.info["tree_cached"]
    assert warm.info["tree_build"] == "device"
    _same_arrays(_device_arrays(warm), ref)
    assert warm.info["sah_cost"] == cold.info["sah_cost"]


def test_layout_key_misses_on_what_the_upload_depends_on(tmp_path):
    """Materials, normals, float64 vertices, precision, routine, accelerator and the
    padding extent each change the layout key; the triangles change the tree's."""
    from dataclasses import replace

    from renderer.accel import BVH, BVH4
    from renderer.accel.builders import LayoutRequest, layout_key, triangles_key
    from renderer.device import types
    from renderer.scene import load_scene

    scene = load_scene(_scene_file(tmp_path))
    f32, f64 = types("llvm", "float32"), types("llvm", "float64")
    tree = tree_key(scene, "device")
    bvh = LayoutRequest("bvh", BVH, 2, "watertight")
    base = layout_key(scene, tree, bvh, f32, 3.0)
    material = scene.face_material.copy()
    material[0] += 1
    normals = scene.normals.copy()
    normals[0, 0] = np.nextafter(normals[0, 0], np.float32(2))
    v64 = scene.vertices64.copy()
    v64[0, 0] = np.nextafter(v64[0, 0], 2.0)
    keys = [base,
            layout_key(replace(scene, face_material=material), tree, bvh, f32, 3.0),
            layout_key(replace(scene, normals=normals), tree, bvh, f32, 3.0),
            layout_key(scene, tree, bvh, f64, 3.0),
            layout_key(replace(scene, vertices64=v64), tree, bvh, f64, 3.0),
            layout_key(scene, tree, replace(bvh, intersection="moller_trumbore"), f32, 3.0),
            layout_key(scene, tree, LayoutRequest("bvh4", BVH4, 4, "watertight"), f32, 3.0),
            layout_key(scene, tree, bvh, f32, float(np.nextafter(3.0, 4.0))),
            layout_key(scene, tree_key(scene, "sah"), bvh, f32, 3.0)]
    assert len(set(keys)) == len(keys)
    # float32 renders do not read the float64 vertices: the same key
    assert layout_key(replace(scene, vertices64=v64), tree, bvh, f32, 3.0) == base
    assert triangles_key(scene) == triangles_key(replace(scene, face_material=material))


def test_a_material_change_misses_the_layout_but_not_the_tree(tmp_path):
    from dataclasses import replace

    from renderer.accel import build_accelerator
    from renderer.device import types
    from renderer.scene import load_scene

    scene = load_scene(_scene_file(tmp_path))
    t = types("llvm", "float32")
    cache = TreeCache(tmp_path / "c")
    build_accelerator("bvh4", scene, t, build="sah", cache=cache)
    material = scene.face_material.copy()
    material[: len(material) // 2] = 1                   # a second material
    other = replace(scene, face_material=material, materials=scene.materials * 2)
    acc = build_accelerator("bvh4", other, t, build="sah", cache=cache)
    assert acc.info["tree_cached"] and not acc.info["layout_cached"]
    assert np.array_equal(acc.tris.material.numpy(), material[acc.tris.order.numpy()])


@pytest.mark.parametrize("damage", ["flip", "truncate", "foreign", "references"])
def test_corrupt_or_foreign_layout_is_rebuilt_with_one_warning(tmp_path, damage):
    """A layout entry that is damaged, another scene's, or whose (checksummed) references
    leave the tree is never uploaded: one ``CacheWarning``, the arrays of the build
    without a cache (the reference), and the entry replaced."""
    from renderer.accel import BVH4, build_accelerator
    from renderer.accel.builders import LayoutRequest, layout_key
    from renderer.accel.triangle import pad_extent
    from renderer.device import types
    from renderer.scene import load_scene

    scene = load_scene(_scene_file(tmp_path))
    other = load_scene(_scene_file(tmp_path, levels=1))
    t = types("llvm", "float32")
    ref = _device_arrays(build_accelerator("bvh4", scene, t, build="sah"))
    cache = TreeCache(tmp_path / "c")
    build_accelerator("bvh4", scene, t, build="sah", cache=cache)
    build_accelerator("bvh4", other, t, build="sah", cache=cache)
    req = LayoutRequest("bvh4", BVH4, 4, "watertight")

    def key(s):
        return layout_key(s, tree_key(s, "sah"), req, t, pad_extent(s, "watertight"))
    path = cache.path("layout", key(scene))
    if damage == "references":          # a well-formed entry whose references are wrong
        e = cache.get("layout", key(scene))
        arrays = {k: np.array(v) for k, v in e.items() if k != "meta"}
        arrays["refs"][0, 0] = np.uint32(arrays["nodes"].shape[0] + 5)
        cache.put("layout", key(scene), arrays, e["meta"])
    else:
        data = bytearray(path.read_bytes())
        if damage == "flip":
            data[len(data) // 2] ^= 0x08
        elif damage == "truncate":
            data = data[: len(data) - 100]
        else:
            data = bytearray(cache.path("layout", key(other)).read_bytes())
        path.write_bytes(bytes(data))
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        acc = build_accelerator("bvh4", scene, t, build="sah", cache=TreeCache(tmp_path / "c"))
    assert [x.category for x in w] == [CacheWarning], [str(x.message) for x in w]
    assert not acc.info["layout_cached"] and acc.info["tree_cached"]
    _same_arrays(_device_arrays(acc), ref)
    acc = build_accelerator("bvh4", scene, t, build="sah", cache=TreeCache(tmp_path / "c"))
    assert acc.info["layout_cached"]


def test_checksum_changes_with_any_word():
    """``checksum`` against the arrays' bytes: every single-bit flip of a small array;
    in a large one a zeroed block, the top bit of two words of one block flipped, and two
    swapped words; the same bytes in another dtype or shape give the same checksum."""
    from renderer.accel.cache import BLOCK, checksum

    rng = np.random.default_rng(3)
    small = rng.integers(0, 2**63, 7, dtype=np.uint64).view(np.uint8)[:53].copy()
    ref = checksum(small)
    for i in range(small.size):
        for bit in range(8):
            x = small.copy()
            x[i] ^= np.uint8(1 << bit)
            assert checksum(x) != ref, (i, bit)
    big = rng.integers(0, 2**63, 5 * BLOCK + 17, dtype=np.uint64)
    ref = checksum(big)
    x = big.copy()
    x[BLOCK:2 * BLOCK] = 0
    assert checksum(x) != ref
    top = np.uint64(1 << 63)
    for i, j in ((3, 5), (3, 4), (3, 3 + BLOCK // 2), (7, 7 + 2 * BLOCK)):
        x = big.copy()
        x[i] ^= top
        x[j] ^= top
        assert checksum(x) != ref, (i, j)
    x = big.copy()
    x[[10, 10 + BLOCK]] = x[[10 + BLOCK, 10]]
    assert checksum(x) != ref
    assert checksum(big.view(np.float64).reshape(-1)) == ref


def test_packing_in_face_order_then_permuting_is_the_ordered_packing():
    """``permuted(triangle_arrays(order=None), order)`` (the packing that overlaps the
    device build) against ``triangle_arrays(order)``: the same bytes in both layouts and
    precisions."""
    from renderer.accel.triangle import permuted, triangle_arrays
    from renderer.scene import load_scene

    scene = load_scene(ROOT / "scenes" / "glass_bunny.toml")
    order = np.random.default_rng(0).permutation(scene.face_count)
    for double in (False, True):
        for routine in ("watertight", "moller_trumbore"):
            ref = triangle_arrays(scene, double, order, True, routine=routine)
            got = permuted(triangle_arrays(scene, double, None, True, routine=routine), order)
            assert ref.keys() == got.keys()
            for k in ref:
                assert ref[k].dtype == got[k].dtype and ref[k].shape == got[k].shape, k
                assert ref[k].tobytes() == got[k].tobytes(), (k, double, routine)
