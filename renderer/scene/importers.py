"""Scenes from other tools' files, and the one entry point that reads any scene file.

``load_scene(path, ...)`` dispatches on the suffix (``SCENE_FORMATS``): ``.toml`` (the
project's format, ``loader``), ``.obj`` (+ its MTL files), ``.ply`` and ``.xml`` (Mitsuba 3,
``mitsuba_xml``). A mesh file becomes a scene with one object per OBJ group (``o``/``g``
name, ``usemtl`` material, smoothing group), a camera framed on its bounding box
(``auto_camera``) and, when it has no light, one point light at the camera
(``default_light``), each said in one warning line. ``camera="auto"`` frames any scene.

Geometry goes through the TOML loader's assembly (``loader._assemble``), so every format
gets the same zero-area check, per-object vertex ranges and float64 copies; file normals
(OBJ ``vn``, PLY ``nx ny nz``) replace the averaged ones of their objects.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np

from . import loader, meshio, objmtl
from .model import (
    Camera,
    Material,
    PointLight,
    Scene,
    SceneError,
    Settings,
    validate_image_size,
)

__all__ = ["SCENE_FORMATS", "DEFAULT_MATERIAL", "auto_camera", "default_light",
           "load_scene", "obj_parts", "load_obj_scene", "load_ply_scene"]

#: Scene-file suffixes ``load_scene`` reads.
SCENE_FORMATS = (".toml", ".obj", ".ply", ".xml")
#: Material of OBJ faces without ``usemtl`` and of PLY meshes.
DEFAULT_MATERIAL = Material(name="default", ka=np.full(3, 0.8), kd=np.full(3, 0.8),
                            ks=np.zeros(3))
#: Image size and vertical field of view of a framed camera.
AUTO_SIZE, AUTO_FOV = (256, 256), 40.0


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
    if defines and suffix != ".xml":
        raise SceneError(f"{path}: -D {next(iter(defines))}=...: parameters are for Mitsuba "
                         "XML scenes only")
    if suffix == ".toml":
        scene = load_toml(path, shading=shading, cache=cache)
    elif suffix == ".obj":
        scene = load_obj_scene(path, shading=shading, cache=cache)
    elif suffix == ".ply":
        scene = load_ply_scene(path, shading=shading, cache=cache)
    elif suffix == ".xml":
        from .mitsuba_xml import load_xml
        scene = load_xml(path, shading=shading, defines=defines or {},
                         approximate=approximate, cache=cache)
    else:
        raise SceneError(f"{path}: unsupported scene format {path.suffix!r}, expected one of "
                         f"{', '.join(SCENE_FORMATS)}")
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
        return loader.load_scene(path, shading=shading, cache=cache)
    r = loader._Reader(path)
    r.keys(data, loader._TOP_KEYS, "")
    if "description" in data:
        r.string(data["description"], "description")
    settings = loader._read_render(r, data, shading)
    look = loader._read_physical(r, data, settings)
    settings = replace(settings, background=look.background)
    cameras = loader._read_views(r, data)
    for i, cam in enumerate(cameras):
        try:
            validate_image_size(cam.width, cam.height, settings.spp,
                                f"views[{i}]" if "views" in data else "camera")
        except SceneError as e:
            raise SceneError(f"{r.path}: {e}", field=e.field) from None
    lights = loader._read_lights(r, data, settings.shading, look.light_scale)
    materials = loader._read_materials(r, data)
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
    scene = assemble(path, out, normals, cameras=cameras, settings=settings, lights=lights,
                     materials=materials, ambient=look.ambient,
                     sources=[path.resolve(), *sources], cache=cache)
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


# ---- framing ---------------------------------------------------------------------------------
def auto_camera(scene: Scene, size: tuple[int, int] = AUTO_SIZE, fov_y: float = AUTO_FOV,
                name: str = "auto") -> Camera:
    """A view of the whole scene: looking along -z (from +z) or +z (from -z) at the centre
    of the bounding box, y up, as close as lets every corner of the bounding box lie in the
    image with a 5% margin. The side is the one that sees more front-facing triangle area
    (an open box is seen through its opening); +z on a tie."""
    lo, hi = scene.bounds()
    centre = (lo + hi) / 2
    w, h = size
    tan_y = math.tan(math.radians(fov_y) / 2) / 1.05
    tan_x = tan_y * w / h
    side = 1.0
    if scene.face_count:
        v = scene.vertices.astype(np.float64)
        f = scene.faces
        cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        toward_plus, toward_minus = cross[:, 2].clip(0).sum(), (-cross[:, 2]).clip(0).sum()
        side = -1.0 if toward_minus > toward_plus * (1 + 1e-9) else 1.0
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])]) - centre
    near = side * corners[:, 2]              # how far each corner sits towards the camera
    dist = float(np.max(np.maximum(np.abs(corners[:, 0]) / tan_x,
                                   np.abs(corners[:, 1]) / tan_y) + near))
    dist = max(dist, float(np.max(near)) * 1.01, 1e-6 * max(float(np.abs(hi - lo).max()),
                                                             1e-30))
    position = centre + np.array([0.0, 0.0, side * dist])
    return Camera(position=position, target=centre, up=np.array([0.0, 1.0, 0.0]),
                  fov_y=fov_y, width=int(w), height=int(h), name=name)


def default_light(scene: Scene) -> PointLight:
    """The light of a scene that has none: a point light at the first camera. Classic:
    intensity 1 without falloff; physical: inverse-square with intensity pi·d² (d the
    camera's distance to its target), so a white diffuse surface at the target is about
    as bright as in classic mode."""
    cam = scene.cameras[0]
    if scene.settings.shading == "physical":
        d2 = float(np.sum((cam.target - cam.position) ** 2))
        return PointLight(position=cam.position.copy(), intensity=np.full(3, math.pi * d2),
                          falloff="inverse_square", name="camera_light")
    return PointLight(position=cam.position.copy(), intensity=np.ones(3), falloff="none",
                      name="camera_light")


def _frame_and_light(scene: Scene, path: Path) -> Scene:
    if not scene.cameras:
        scene = replace(scene, cameras=[auto_camera(scene)])
        warnings.warn(f"{path}: no camera: one framed on the bounding box (--camera auto)",
                      stacklevel=3)
    if not scene.lights:
        light = default_light(scene)
        scene = replace(scene, lights=[light])
        warnings.warn(f"{path}: no light: a point light at the camera "
                      f"(intensity {light.intensity[0]:.4g}, falloff {light.falloff})",
                      stacklevel=3)
    return scene


# ---- assembly --------------------------------------------------------------------------------
def _clean(path: Path, name: str, world: np.ndarray, faces: np.ndarray,
           normals: np.ndarray | None):
    """Faces without the zero-area triangles (the loader's float32 test, one warning) and
    vertices compacted to those used, in their order, so that ``loader._assemble`` keeps
    the vertex order and file normals line up with its output."""
    p = world.astype(np.float32).astype(np.float64)
    cross = np.cross(p[faces[:, 1]] - p[faces[:, 0]], p[faces[:, 2]] - p[faces[:, 0]])
    keep = np.linalg.norm(cross, axis=1) > 0
    if not keep.all():
        n = int((~keep).sum())
        warnings.warn(f"{path}: object {name!r}: dropped {n} zero-area "
                      f"triangle{'s' if n > 1 else ''} of {len(faces)}", stacklevel=4)
    faces = faces[keep]
    used, inv = np.unique(faces.reshape(-1), return_inverse=True)
    return world[used], inv.reshape(-1, 3), None if normals is None else normals[used]


def assemble(path: Path, parts: list, normals: list, *, cameras, settings, lights,
             materials, ambient, sources, cache=None) -> Scene:
    """The scene of ``parts`` (``loader._Part``, already ``_clean``) with ``normals[k]``
    (float64 (V, 3) world-space file normals of part k, or None: averaged) in place of the
    averaged normals. Unit-length; a zero file normal falls back to the averaged one."""
    r = loader._Reader(path)
    for part in parts:
        if len(part.faces) == 0:
            raise SceneError(f"{path}: object {part.name!r} has no triangles left (all "
                             "zero-area or empty)")
    scene = loader._assemble(r, parts, cameras, settings, lights, materials, ambient,
                             sources, cache=cache)
    n64, n32 = scene.normals64.copy(), scene.normals.copy()
    for obj, fn in zip(scene.objects, normals):
        if fn is None:
            continue
        length = np.linalg.norm(fn, axis=1, keepdims=True)
        sl = slice(obj.first_vertex, obj.first_vertex + obj.vertex_count)
        ok = (length[:, 0] > 1e-12) & np.all(np.isfinite(fn), axis=1)
        unit = fn / np.where(length > 1e-12, length, 1.0)
        n64[sl][ok] = unit[ok]
        # A float32 file normal that is unit to float32 precision is kept as it is (an
        # exported scene read back keeps its normals bit for bit).
        exact = ok & (np.abs(length[:, 0] - 1) < 1e-6) & (fn.astype(np.float32) == fn).all(1)
        n32[sl][ok] = np.where(exact[ok, None], fn[ok], unit[ok]).astype(np.float32)
    return replace(scene, normals=n32, normals64=n64)


def world_normals(n: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Object-space normals float64 (V, 3) under the 4x4 transform ``m`` (inverse
    transpose of its linear part)."""
    return n @ np.linalg.inv(m[:3, :3])


def _transform(m: np.ndarray, verts: np.ndarray) -> np.ndarray:
    return verts @ m[:3, :3].T + m[:3, 3]


# ---- OBJ + MTL -------------------------------------------------------------------------------
def obj_parts(path: Path, materials: list[Material], m: np.ndarray | None = None, *,
              normals: str = "file", smooth: bool | None = None, taken: set | None = None,
              kind: str = "obj", flat: bool = False, prefix: str | None = None):
    """The parts of an OBJ file: one per group (``objmtl.read_obj``), its MTL materials
    appended to ``materials`` (faces without ``usemtl`` get ``DEFAULT_MATERIAL``; a name
    already in ``materials`` is reused).

    m: 4x4 object-to-world transform (default identity). normals: "file" (``vn`` where
    every face vertex of a group has one) or "averaged". smooth: force smooth shading on
    (True) or off (False); None: smooth where the group has ``vn`` normals or a smoothing
    group (``s`` != 0). flat: every group flat (Mitsuba's ``face_normals``). prefix:
    object names are ``<prefix>.<group name>`` (a scene file's object name).
    Returns (parts, file normals per part, files read: the OBJ and its MTLs). Warnings name
    file and line for everything ignored. Raises MeshError / SceneError."""
    m = np.eye(4) if m is None else m
    taken = set() if taken is None else taken
    obj = objmtl.read_obj(path)
    files = [Path(path).resolve()]
    for line in obj.warnings:
        warnings.warn(line, stacklevel=3)
    by_name = {mat.name: i for i, mat in enumerate(materials)}
    for lib, lineno in obj.mtllibs:
        mtl = Path(path).parent / lib
        if not mtl.is_file():
            raise SceneError(f"{path}:{lineno}: mtllib {lib}: file not found ({mtl})")
        mats, notes = objmtl.read_mtl(mtl)
        files.append(mtl.resolve())
        for line in notes:
            warnings.warn(line, stacklevel=3)
        for name, mat in mats.items():
            if name not in by_name:
                by_name[name] = len(materials)
                materials.append(mat)
    mirror = np.linalg.det(m[:3, :3]) < 0
    parts, part_normals = [], []
    for g in obj.groups:
        if len(g.faces) == 0:
            continue
        if g.material is None:
            mat = _default_index(materials, by_name)
        elif g.material in by_name:
            mat = by_name[g.material]
        else:
            warnings.warn(f"{path}:{g.material_line}: usemtl {g.material!r}: no such "
                          f"material in {[lib for lib, _ in obj.mtllibs] or 'any mtllib'}; "
                          "the default grey is used", stacklevel=3)
            mat = _default_index(materials, by_name)
        has_vn = bool(np.all(g.normals >= 0))
        if normals == "file" and has_vn and not flat:
            pairs = np.stack([g.faces, g.normals], -1).reshape(-1, 2)
            uniq, inv = np.unique(pairs, axis=0, return_inverse=True)
            verts, faces = obj.positions[uniq[:, 0]], inv.reshape(-1, 3)
            fn = world_normals(obj.normals[uniq[:, 1]], m)
        else:
            verts, faces, fn = obj.positions, g.faces, None
        is_smooth = (has_vn or g.smoothing != 0) if smooth is None else smooth
        if flat:
            is_smooth = False
        base = g.name or Path(path).stem
        name = _unique_name(base if prefix is None else f"{prefix}.{base}", g, taken)
        world, faces, fn = _clean(path, name, _transform(m, verts), faces, fn)
        if mirror:
            faces = faces[:, [0, 2, 1]]
        parts.append(loader._Part(name, kind, mat, is_smooth, world, faces))
        part_normals.append(fn)
    if not parts:
        raise SceneError(f"{path}: no faces")
    return parts, part_normals, files


def _default_index(materials: list[Material], by_name: dict) -> int:
    if DEFAULT_MATERIAL.name not in by_name:
        by_name[DEFAULT_MATERIAL.name] = len(materials)
        materials.append(DEFAULT_MATERIAL)
    return by_name[DEFAULT_MATERIAL.name]


def _unique_name(base: str, g, taken: set) -> str:
    name = base
    for suffix in (f".{g.material}", f".s{g.smoothing}"):
        if name not in taken:
            break
        name += suffix
    k = 1
    while name in taken:
        k += 1
        name = f"{base}.{k}"
    taken.add(name)
    return name


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
    scene = assemble(path, parts, normals, cameras=[], settings=_settings(shading),
                     lights=[], materials=materials, ambient=np.zeros(3), sources=files,
                     cache=cache)
    return _frame_and_light(scene, path)


def ply_part(path: Path, m: np.ndarray | None = None, *, material: int = 0,
             normals: str = "file", name: str | None = None, flat: bool = False):
    """(part, file normals or None, ``PlyMesh``) of a PLY file: smooth with the file's
    normals when it has them and ``normals`` is "file", else smooth with averaged normals
    (flat when ``flat``)."""
    from .plyattrs import read_ply
    m = np.eye(4) if m is None else m
    ply = read_ply(path)
    fn = world_normals(ply.normals, m) if (normals == "file" and ply.normals is not None
                                           and not flat) else None
    name = name or Path(path).stem
    world, faces, fn = _clean(path, name, _transform(m, ply.vertices), ply.faces, fn)
    if np.linalg.det(m[:3, :3]) < 0:
        faces = faces[:, [0, 2, 1]]
    return loader._Part(name, "ply", material, not flat, world, faces), fn, ply


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
    scene = assemble(path, [part], [fn], cameras=[], settings=_settings(shading), lights=[],
                     materials=[material], ambient=np.zeros(3), sources=[path.resolve()],
                     cache=cache)
    return _frame_and_light(scene, path)
