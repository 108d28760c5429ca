"""The scene entry (``renderer.scene.scene_cache``): a TOML scene's geometry keyed by its
sources. A hit gives the scene the loader reads without a cache (every array bit for bit,
the objects, the warnings); any change of a mesh file's bytes (its size and time kept), of
the objects or of the materials' order misses; a change elsewhere (a light) hits and reads
the new light; a corrupt or foreign entry is rebuilt with one warning; the facts a scene
carries are those its arrays give, and a copy with other arrays does not use them.

References: ``load_scene(path)`` without a cache, and the facts recomputed on a copy of the
scene without facts."""
import dataclasses
import os
import warnings
from pathlib import Path

import numpy as np
import pytest

from renderer.accel.builders import triangles_key
from renderer.accel.cache import CacheWarning, TreeCache
from renderer.accel.triangle import pad_extent
from renderer.scene import load_scene
from renderer.scene.model import STORED_FACTS, check_ranges

ROOT = Path(__file__).resolve().parents[1]

PLY = """ply
format ascii 1.0
element vertex 5
property float x
property float y
property float z
element face 3
property list uchar int vertex_indices
end_header
0 0 0
1 0 0
0 1 0
0 0 1
2 0 0
3 0 1 2
3 0 1 3
3 0 1 4
"""


def _files(tmp_path, *, light=(1.0, 2.0, 3.0), scale=1.0, ply=PLY, swap=False):
    (tmp_path / "m.ply").write_text(ply)
    mats = ["[materials.a]\nkd = 0.5\n", "[materials.b]\nkd = 0.25\n"]
    if swap:
        mats.reverse()
    path = tmp_path / "s.toml"
    path.write_text(
        "[camera]\nposition = [0, 0, 5]\ntarget = [0, 0, 0]\nresolution = [8, 8]\n"
        f"[[lights]]\nposition = [{light[0]}, {light[1]}, {light[2]}]\nintensity = 1.0\n"
        + "".join(mats)
        + f"[[objects]]\nmesh = \"m.ply\"\nmaterial = \"b\"\nscale = {scale}\nsmooth = true\n"
        "[[objects]]\nshape = \"sphere\"\nmaterial = \"a\"\n")
    return path


def _load(path, cache):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        scene = load_scene(path, cache=cache)
    return scene, [(x.category, str(x.message)) for x in w]


def _same(a, b):
    for f in dataclasses.fields(a):
        if f.name == "facts":
            continue
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray) or x is None:
            assert (x is None) == (y is None), f.name
            if x is not None:
                assert x.dtype == y.dtype and x.shape == y.shape, f.name
                assert x.tobytes() == y.tobytes(), f.name
        else:
            assert repr(x) == repr(y), f.name


def test_hit_is_the_scene_without_a_cache(tmp_path):
    path = _files(tmp_path)
    ref, ref_w = _load(path, None)
    assert [c for c, _ in ref_w] == [UserWarning]          # the zero-area triangle
    cache = TreeCache(tmp_path / "cache")
    cold, cold_w = _load(path, cache)
    hits = cache.hits
    warm, warm_w = _load(path, cache)
    assert cache.hits == hits + 1 and list(cache.folder.glob("scene-*.bin"))
    for s, w in ((cold, cold_w), (warm, warm_w)):
        _same(s, ref)
        assert w == ref_w
        assert not s.vertices.flags.writeable and s.facts


@pytest.mark.parametrize("scene", ["bunny.toml", "cornell_box.toml", "conference.toml"])
def test_bundled_scenes_hit_bit_for_bit(tmp_path, scene):
    path = ROOT / "scenes" / scene
    ref = load_scene(path)
    cache = TreeCache(tmp_path)
    load_scene(path, cache=cache)
    hits = cache.hits
    warm = load_scene(path, cache=cache)
    assert cache.hits == hits + 1
    _same(warm, ref)


def test_any_source_change_misses(tmp_path):
    path = _files(tmp_path)
    cache = TreeCache(tmp_path / "cache")
    load_scene(path, cache=cache)
    # the mesh file's bytes change, its size and times do not
    mesh = tmp_path / "m.ply"
    st = os.stat(mesh)
    edited = PLY.replace("0 1 0\n", "0 2 0\n")
    assert len(edited) == len(PLY)
    mesh.write_text(edited)
    os.utime(mesh, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert os.stat(mesh).st_size == st.st_size and os.stat(mesh).st_mtime_ns == st.st_mtime_ns
    got = load_scene(path, cache=cache)
    _same(got, load_scene(path))
    assert got.vertices[:, 1].max() == 2.0
    # an object's transform; the materials' order (the faces' indices change)
    for kw in ({"scale": 2.0, "ply": edited}, {"swap": True, "ply": edited}):
        p = _files(tmp_path, **kw)
        misses = cache.misses
        got = load_scene(p, cache=cache)
        assert cache.misses > misses, kw
        _same(got, load_scene(p))


def test_a_light_change_hits_and_reads_the_new_light(tmp_path):
    cache = TreeCache(tmp_path / "cache")
    load_scene(_files(tmp_path), cache=cache)
    path = _files(tmp_path, light=(4.0, 5.0, 6.0))
    hits = cache.hits
    got = load_scene(path, cache=cache)
    assert cache.hits == hits + 1
    _same(got, load_scene(path))


@pytest.mark.parametrize("damage", ["flip", "truncate", "foreign"])
def test_corrupt_or_foreign_entry_is_rebuilt_with_one_warning(tmp_path, damage):
    cache = TreeCache(tmp_path / "cache")
    path = _files(tmp_path)
    ref, ref_w = _load(path, None)
    load_scene(path, cache=cache)
    (entry,) = cache.folder.glob("scene-*.bin")
    data = bytearray(entry.read_bytes())
    if damage == "flip":
        data[-200] ^= 0x10                     # inside the arrays
    elif damage == "truncate":
        data = data[: len(data) // 2]
    else:                                      # another scene's entry under this key
        other = tmp_path / "other"
        other.mkdir()
        c2 = TreeCache(tmp_path / "cache2")
        load_scene(_files(other, scale=3.0), cache=c2)
        (e2,) = c2.folder.glob("scene-*.bin")
        data = bytearray(e2.read_bytes())
        _files(tmp_path)
    entry.write_bytes(bytes(data))
    got, w = _load(path, TreeCache(tmp_path / "cache"))
    assert [c for c, _ in w].count(CacheWarning) == 1, w
    assert [x for x in w if x[0] is not CacheWarning] == ref_w
    _same(got, ref)
    c3 = TreeCache(tmp_path / "cache")               # the rebuilt entry replaced it
    _load(path, c3)
    assert c3.hits >= 1 and c3.rejected == 0


def test_facts_are_those_of_the_arrays(tmp_path):
    """Each fact a loaded scene carries equals the value computed on a copy of its arrays
    (no facts), in both precisions' checks; a copy with one changed vertex computes its
    own values."""
    cache = TreeCache(tmp_path / "cache")
    path = _files(tmp_path)
    load_scene(path, cache=cache)
    warm = load_scene(path, cache=cache)
    assert set(STORED_FACTS) <= set(warm.facts)
    bare = dataclasses.replace(warm, vertices=warm.vertices.copy(),
                               vertices64=warm.vertices64.copy())
    assert not bare.facts or bare.facts["_of"][0] is not bare.vertices
    assert triangles_key(warm) == triangles_key(bare)
    assert [x.tolist() for x in warm.bounds()] == [x.tolist() for x in bare.bounds()]
    assert pad_extent(warm, "watertight") == pad_extent(bare, "watertight")
    assert np.array_equal(warm.face_smooth, bare.face_smooth)
    for precision in ("float32", "float64"):
        check_ranges(warm, precision)
    for k in STORED_FACTS:
        bare2 = dataclasses.replace(warm, vertices=warm.vertices.copy())
        from renderer.scene.model import stored_facts, with_facts
        assert stored_facts(with_facts(bare2))[k] == warm.facts[k], k
    moved = dataclasses.replace(warm, vertices=warm.vertices + np.float32(1.0))
    assert triangles_key(moved) != triangles_key(warm)
    assert moved.bounds()[0].tolist() != warm.bounds()[0].tolist()


def test_unwritable_folder_loads_without_the_entry(tmp_path):
    """A cache folder that cannot be made: the scene loads as without a cache, with one
    ``CacheWarning`` for the cache (not one per entry or load)."""
    path = _files(tmp_path)
    ref, ref_w = _load(path, None)
    blocker = tmp_path / "file"
    blocker.write_text("a file where the cache folder would go")
    cache = TreeCache(blocker / "cache")
    first, w1 = _load(path, cache)
    second, w2 = _load(path, cache)
    assert [c for c, _ in w1 + w2].count(CacheWarning) == 1, w1 + w2
    for s, w in ((first, w1), (second, w2)):
        _same(s, ref)
        assert [x for x in w if x[0] is not CacheWarning] == ref_w
