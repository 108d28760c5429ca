"""A TOML scene's geometry as one cache entry, keyed by its source bytes.

``load_toml(path, data, shading, cache)`` reads a scene file as ``loader.load_scene`` does
(the same table readers, in its order), with its geometry (the flat arrays of
``loader._assemble``, the objects, the warnings the reading gave and the ``facts`` the
upload derives from the arrays) as the ``"scene"`` entry of ``cache``
(``renderer.accel.cache.TreeCache``). The entry's key (``entry_key``) hashes what the
geometry is made of: the scene file's path as given (it names the warnings), its
``[[objects]]`` table and material names, the bytes of every mesh file the table names,
the source text of the modules that read and assemble them (``SCENE_MODULES``) and
numpy's version; so any change of a mesh file's bytes (whatever its size or time), of an
object, of a material's place or of the code misses. A hit reads the arrays without
parsing a mesh; a miss reads the file as ``loader.load_scene`` and stores the entry.

The scene of either has its arrays read-only and carries their facts (``model.with_facts``:
the triangles' content key, bounds, reaches, used materials, the layout's input key),
which the renderer then reads instead of recomputing them. An entry that does not hold a
scene of this shape (array names, dtypes, shapes, object ranges) is rebuilt with one
``CacheWarning``, as a corrupt one (``TreeCache.get``).
"""
from __future__ import annotations

import builtins
import hashlib
import json
import warnings
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from ..cache_key import CacheWarning, code_version, content_key
from . import loader
from .model import (
    FACT_FIELDS,
    ObjectInfo,
    Scene,
    stored_facts,
    with_facts,
)

#: Source files (relative to the ``renderer`` package) whose text keys a scene entry.
SCENE_MODULES = ("scene/loader.py", "scene/meshio.py", "scene/shapes.py",
                 "scene/subdivide.py", "scene/model.py", "scene/scene_cache.py",
                 "cache_key.py", "parallel.py")
#: The arrays of an entry: name -> (dtype, columns; 0: one axis), all of one length per
#: row kind (vertices or faces); the float64 pair is optional.
ARRAYS = {"vertices": (np.float32, 3), "normals": (np.float32, 3),
          "vertices64": (np.float64, 3), "normals64": (np.float64, 3),
          "faces": (np.int32, 3), "face_material": (np.int32, 0),
          "face_object": (np.int32, 0)}


def _mesh_paths(path: Path, data: dict) -> list[Path] | None:
    """The mesh files ``[[objects]]`` names, in order; None where the table is not as
    the loader reads it (the loader then says why)."""
    objs = data.get("objects", [])
    if not isinstance(objs, list):
        return None
    out = []
    for ot in objs:
        if not isinstance(ot, dict):
            return None
        if "mesh" in ot:
            if not isinstance(ot["mesh"], str):
                return None
            out.append(path.parent / ot["mesh"])
    return out


def entry_key(path: Path, data: dict, material_index: dict) -> str | None:
    """The scene entry's key (module docstring), or None where a mesh file cannot be read
    (no entry: the loader reports it)."""
    meshes = _mesh_paths(path, data)
    if meshes is None:
        return None
    digests = []
    for m in meshes:
        try:
            digests.append(hashlib.sha256(m.read_bytes()).hexdigest())
        except OSError:
            return None
    objects = json.dumps(data.get("objects", []), sort_keys=True, default=repr)
    return content_key("scene", str(path), objects, material_index, digests,
                       np.__version__, code_version(SCENE_MODULES))


def load_toml(path: Path, data: dict, shading: str | None, cache) -> Scene:
    """``loader.load_scene(path, shading=shading, cache=cache)`` of the parsed file ``data``
    with its geometry through the scene entry (module docstring)."""
    r = loader._Reader(path)
    a = loader._read_head(r, data, shading)
    index = {m.name: i for i, m in enumerate(a.materials)}
    key = entry_key(path, data, index)
    got = cache.get("scene", key) if key is not None else None
    scene = _from_entry(got, r, data, a) if got is not None else None
    if scene is None:
        scene, caught = _read_geometry(r, data, index, a, cache)
        scene = with_facts(scene)
        if key is not None and caught is not None:
            arrays = {k: getattr(scene, k) for k in ARRAYS if getattr(scene, k) is not None}
            cache.put("scene", key, arrays, {
                "objects": [asdict(o) for o in scene.objects], "warnings": caught,
                "facts": stored_facts(scene)})
    return replace(scene, check=loader._read_check(r, data))


def _read_geometry(r, data: dict, index: dict, a, cache):
    """The loader's objects and assembly, with the warnings they gave (re-given here) as
    ``(category name, message)``; None for the warnings where one is not a built-in
    category (the scene is then not stored: its warnings could not be given again)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        objects, sources = loader._read_objects(r, data, index, cache)
        scene = loader._assemble(r, objects, replace(a, sources=[r.path.resolve(), *sources]),
                                 cache)
    kept = []
    for w in caught:
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        name = w.category.__name__
        if getattr(builtins, name, None) is not w.category:
            kept = None
        elif kept is not None:
            kept.append([name, str(w.message)])
    return scene, kept


def _from_entry(e: dict, r, data: dict, a) -> Scene | None:
    """The scene of the entry ``e`` (with ``a``'s cameras, settings, lights, materials),
    its warnings given again; None (one ``CacheWarning``) where ``e`` does not hold a
    scene of this shape."""
    try:
        meta = e["meta"]
        objects = [ObjectInfo(**o) for o in meta["objects"]]
        V, F = e["vertices"].shape[0], e["faces"].shape[0]
        ok = bool(objects) or V == F == 0
        for name, (dt, cols) in ARRAYS.items():
            if name not in e:
                ok = ok and name in ("vertices64", "normals64")
                continue
            rows = V if name in ("vertices", "normals", "vertices64", "normals64") else F
            ok = ok and e[name].dtype == dt and e[name].shape == ((rows, cols) if cols
                                                                  else (rows,))
        ok = ok and ("normals64" not in e or "vertices64" in e)
        f_end = v_end = 0
        for o in objects:
            ok = ok and o.first_face == f_end and o.first_vertex == v_end
            f_end, v_end = f_end + o.face_count, v_end + o.vertex_count
        ok = ok and f_end == F and v_end == V
        warned = [(getattr(builtins, c), str(m)) for c, m in meta["warnings"]]
        ok = ok and all(isinstance(c, type) and issubclass(c, Warning) for c, _ in warned)
        facts = dict(meta["facts"])
    except (KeyError, TypeError, ValueError, AttributeError):
        ok = False
    if not ok:
        warnings.warn("cache entry does not hold a scene of this file; rebuilding",
                      CacheWarning, stacklevel=3)
        return None
    for category, message in warned:
        warnings.warn(message, category, stacklevel=4)
    arrays = {k: e.get(k) for k in ARRAYS}
    sources = [r.path.resolve()] + [p.resolve() for p in _mesh_paths(r.path, data)]
    # the facts hold for these arrays from the start: the entry was checked when written
    # (the float64 vertices round to the float32 ones), so the scene need not check again
    facts["_of"] = tuple(objects if k == "objects" else arrays[k] for k in FACT_FIELDS)
    scene = Scene(cameras=a.cameras, settings=a.settings, lights=a.lights,
                  materials=a.materials, objects=objects, ambient=a.ambient, name=r.path.stem,
                  path=r.path, source_files=sources, facts=facts, **arrays)
    return with_facts(scene, facts)
