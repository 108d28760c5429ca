"""Scenes from other tools' files, and the one entry point that reads any scene file.

``load_scene(path, ...)`` dispatches on the suffix (``SCENE_FORMATS``): ``.toml`` (the
project's format, ``loader``), ``.obj`` (+ its MTL files), ``.ply`` and ``.xml`` (Mitsuba 3,
``mitsuba_xml``). A mesh file becomes a scene with one object per OBJ group (``o``/``g``
name, ``usemtl`` material, smoothing group), a camera framed on its bounding box
(``auto_camera``) and, when it has no light, one point light at the camera
(``default_light``), each said in one warning line. ``camera="auto"`` frames any scene.

Geometry goes through the TOML loader's assembly (``loader._assemble``, by
``parts.assemble``), so every format gets the same zero-area check, per-object vertex
ranges and float64 copies; file normals (OBJ ``vn``, PLY ``nx ny nz``) replace the averaged
ones of their objects.
"""
from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from . import loader, meshio, scene_cache
from .mitsuba_xml import load_xml
from .model import Assembly, Material, Scene, SceneError, Settings
from .parts import (
    AUTO_FOV,
    AUTO_SIZE,
    DEFAULT_MATERIAL,
    ObjOptions,
    _frame_and_light,
    assemble,
    auto_camera,
    default_light,
    obj_parts,
    ply_part,
    world_normals,
)

__all__ = ["AUTO_FOV", "AUTO_SIZE", "SCENE_FORMATS", "DEFAULT_MATERIAL", "ObjOptions",
           "assemble", "auto_camera", "check_defines", "default_light", "load_scene", "obj_parts",
           "load_obj_scene", "load_ply_scene", "ply_part", "world_normals"]

#: Scene-file suffixes ``load_scene`` reads.
SCENE_FORMATS = (".toml", ".obj", ".ply", ".xml")
def check_defines(path, defines) -> None:
    """``-D`` parameters are for a Mitsuba XML scene only: SceneError for any other file."""
    if defines and Path(path).suffix.lower() != ".xml":
        raise SceneError(f"{path}: -D {next(iter(defines))}=...: parameters are for Mitsuba "
                         "XML scenes only")


def load_scene(path, *, shading: str | None = None, camera: str | None = None,
               defines: dict[str, str] | None = None, approximate: bool = False,
               cache=None) -> Scene:
    """Read any scene file by its suffix (``SCENE_FORMATS``).

    shading: "classic" | "physical" overrides the file's mode (``loader.load_scene``).
    camera: None (the file's views; a mesh file gets a framed one) or "auto" (one view
        framed on the bounding box, ``auto_camera``, replacing the file's views).
    defines: Mitsuba XML parameters (``-D name=value``) overriding ``<default>`` values.
    approximate: Mitsuba XML only: render elements outside the model's subset by their
        documented approximation (one warning each) instead of refusing them.
    cache: a ``renderer.accel.cache.TreeCache`` (None: none), as ``loader.load_scene``.
    Raises ``SceneError`` (file, field or line, what was expected) for malformed input.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if camera not in (None, "auto"):
        raise SceneError(f"camera: expected 'auto', got {camera!r}", field="camera")
    check_defines(path, defines)
    if suffix == ".toml":
        scene = load_toml(path, shading=shading, cache=cache)
    elif suffix == ".obj":
        scene = load_obj_scene(path, shading=shading, cache=cache)
    elif suffix == ".ply":
        scene = load_ply_scene(path, shading=shading, cache=cache)
    elif suffix == ".xml":
        scene = load_xml(path, shading=shading, defines=defines or {},
                         approximate=approximate, cache=cache)
    else:
        raise SceneError(f"{path}: unsupported scene format {path.suffix!r}, expected one of "
                         f"{', '.join(SCENE_FORMATS)}")
    if suffix == ".xml" and (defines or approximate):     # recorded where they matter
        scene = replace(scene, read={**({"defines": dict(defines)} if defines else {}),
                                     **({"approximate": True} if approximate else {})})
    if camera == "auto":
        scene = replace(scene, cameras=[auto_camera(scene)])
    return scene


# ---- TOML objects that read more of a mesh file ----------------------------------------------
#: ``[[objects]]`` keys read here rather than by ``loader``: ``materials = "mtl"`` (an OBJ's
#: groups with their MTL materials) and ``normals = "file" | "averaged"`` (a mesh's own
#: vertex normals, or the averaged ones: the default).
OBJECT_IMPORT_KEYS = ("materials", "normals")
NORMAL_SOURCES = ("averaged", "file")
#: Object kinds of parts built from those keys (goldens of such scenes are keyed by the
#: importers' code too: ``reference.golden``).
IMPORT_KINDS = ("obj+mtl", "obj+normals", "ply+normals")


def load_toml(path, *, shading: str | None = None, cache=None) -> Scene:
    """``loader.load_scene``; for a file whose objects use ``OBJECT_IMPORT_KEYS``, the same
    reading (the loader's table readers, in its order) with those objects built here
    (``_import_object``)."""
    path = Path(path)
    data = loader._read_toml(path)
    objs = data.get("objects")
    if not isinstance(objs, list) or not any(
            isinstance(o, dict) and set(o) & set(OBJECT_IMPORT_KEYS) for o in objs):
        if cache is not None:          # the geometry as one entry, keyed by its sources
            return scene_cache.load_toml(path, data, shading, cache)
        return loader.load_scene(path, shading=shading, cache=cache)
    r = loader._Reader(path)
    head = loader._read_head(r, data, shading)
    materials = head.materials
    index = {m.name: i for i, m in enumerate(materials)}
    # The import objects stand in as plain mesh objects of a placeholder material, so the
    # loader checks their common keys (name, mesh, transform, smooth) and names them.
    placeholder = len(materials)
    plain = []
    for ot in objs:
        if isinstance(ot, dict) and set(ot) & set(OBJECT_IMPORT_KEYS):
            ot = {k: v for k, v in ot.items() if k not in OBJECT_IMPORT_KEYS}
            ot.setdefault("material", _PLACEHOLDER)
        plain.append(ot)
    parts, sources = loader._read_objects(r, {"objects": plain},
                                          {**index, _PLACEHOLDER: placeholder}, cache)
    check = loader._read_check(r, data)
    out, normals, names = [], [], {p.name for p in parts}
    for i, (ot, part) in enumerate(zip(objs, parts)):
        if isinstance(ot, dict) and set(ot) & set(OBJECT_IMPORT_KEYS):
            more, fns, files = _import_object(r, ot, f"objects[{i}]", part, materials,
                                              index, names)
            out += more
            normals += fns
            sources += [f for f in files if f not in sources]
        else:
            out.append(part)
            normals.append(None)
    scene = assemble(path, out, normals, replace(head, sources=[path.resolve(), *sources]),
                     cache=cache)
    return replace(scene, check=check)


_PLACEHOLDER = "\x00import"


def _import_object(r, ot: dict, where: str, part, materials: list[Material], index: dict,
                   names: set):
    """The parts of one ``[[objects]]`` entry with ``materials = "mtl"`` and/or ``normals``
    (``part`` is the loader's reading of it as a plain mesh object: its name, world-space
    positions and smooth flag). Returns (parts, file normals per part, files read)."""
    source = r.string(ot.get("normals", "averaged"), f"{where}.normals", NORMAL_SOURCES)
    if "mesh" not in ot:
        raise r.error(f"{where}.{'materials' if 'materials' in ot else 'normals'}",
                      "needs a mesh file (mesh = \"...\")")
    mesh = r.path.parent / ot["mesh"]
    suffix = mesh.suffix.lower()
    m = loader._transform(r, ot, where)
    flip = (np.linalg.det(m[:3, :3]) < 0) != bool(ot.get("flip_normals", False))
    if "subdivide" in ot and (source == "file" or "materials" in ot):
        raise r.error(f"{where}.subdivide", "not available with materials = \"mtl\" or "
                                            "normals = \"file\"")
    try:
        if "materials" in ot:
            r.string(ot["materials"], f"{where}.materials", ("mtl",))
            if "material" in ot:
                raise r.error(f"{where}.materials", "give either 'material' or materials = "
                                                    "\"mtl\", not both")
            if suffix != ".obj":
                raise r.error(f"{where}.materials", "materials = \"mtl\" needs an .obj mesh")
            smooth = ot.get("smooth")
            names.discard(part.name)
            parts, fns, files = obj_parts(mesh, materials, m, normals=source,
                                          smooth=smooth, taken=names, kind="obj+mtl",
                                          prefix=part.name)
            index.update({mt.name: k for k, mt in enumerate(materials)})
        elif suffix == ".ply":
            p, fn, ply = ply_part(mesh, m, material=part.material, normals=source,
                                  name=part.name)
            if source == "file" and ply.normals is None:
                raise r.error(f"{where}.normals", f"{mesh} has no vertex normals (nx, ny, "
                                                  "nz); use normals = \"averaged\"")
            p.kind, p.smooth = "ply+normals", bool(ot.get("smooth", fn is not None))
            parts, fns, files = [p], [fn], []
        else:
            mats: list[Material] = []
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")     # its MTL is not asked for
                groups, gfns, _ = obj_parts(mesh, mats, m, normals=source, taken=set())
            if source == "file" and any(fn is None for fn in gfns):
                raise r.error(f"{where}.normals", f"{mesh}: not every face vertex has a "
                                                  "'vn' normal; use normals = \"averaged\"")
            parts, fns, files = _merge(groups, gfns, part, "obj+normals")
            parts[0].smooth = bool(ot.get("smooth", fns[0] is not None or part.smooth))
    except meshio.MeshError as e:
        raise r.error(f"{where}.mesh", str(e)) from None
    except SceneError as e:
        if str(e).startswith(str(r.path)):
            raise
        raise r.error(f"{where}.mesh", str(e)) from None
    if flip != (np.linalg.det(m[:3, :3]) < 0):          # flip_normals on top of a mirror
        for p in parts:
            p.faces = p.faces[:, [0, 2, 1]]
    return parts, fns, files


def _merge(groups, normals, part, kind):
    """One part (the loader's name and material) of an OBJ's groups."""
    world = np.concatenate([g.world for g in groups])
    offsets = np.cumsum([0] + [len(g.world) for g in groups])
    faces = np.concatenate([g.faces + o for g, o in zip(groups, offsets)])
    fn = np.concatenate(normals) if all(n is not None for n in normals) else None
    return [loader._Part(part.name, kind, part.material, part.smooth, world, faces)], [fn], []


def _settings(shading: str | None) -> Settings:
    if shading is not None and shading not in ("classic", "physical"):
        raise SceneError(f"shading override: expected 'classic' or 'physical', got "
                         f"{shading!r}")
    return Settings(shading=shading or "classic")


def load_obj_scene(path, *, shading: str | None = None, cache=None) -> Scene:
    """An OBJ file (+ MTL) as a scene: its groups as objects (``obj_parts``), a framed
    camera and a default light (module docstring). Classic shading unless ``shading``."""
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"{path}: file not found")
    materials: list[Material] = []
    try:
        parts, normals, files = obj_parts(path, materials)
    except meshio.MeshError as e:
        raise SceneError(str(e)) from None
    scene = assemble(path, parts, normals,
                     Assembly(cameras=[], settings=_settings(shading), lights=[],
                              materials=materials, ambient=np.zeros(3), sources=files),
                     cache=cache)
    return _frame_and_light(scene, path)


def load_ply_scene(path, *, shading: str | None = None, cache=None) -> Scene:
    """A PLY file as a scene of one smooth object (file normals when present, else
    averaged), a framed camera and a default light. Vertex colours, which the model cannot
    vary across a surface, become the material's kd as their mean (one warning)."""
    path = Path(path)
    if not path.is_file():
        raise SceneError(f"{path}: file not found")
    try:
        part, fn, ply = ply_part(path)
    except meshio.MeshError as e:
        raise SceneError(str(e)) from None
    material = DEFAULT_MATERIAL
    if ply.colors is not None:
        mean = ply.colors.mean(axis=0)
        material = replace(DEFAULT_MATERIAL, name="vertex_colours", ka=mean, kd=mean)
        warnings.warn(f"{path}: vertex colours averaged into one material (kd = "
                      f"{np.round(mean, 3).tolist()}): the model has no per-vertex colour",
                      stacklevel=2)
    scene = assemble(path, [part], [fn],
                     Assembly(cameras=[], settings=_settings(shading), lights=[],
                              materials=[material], ambient=np.zeros(3),
                              sources=[path.resolve()]), cache=cache)
    return _frame_and_light(scene, path)
