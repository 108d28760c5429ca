"""Scene parts from mesh files and their assembly into a scene, shared by the readers of
other tools' files (``importers`` for OBJ, PLY and TOML import objects, ``mitsuba_xml``).

``obj_parts`` / ``ply_part`` read a mesh file's parts (``loader._Part``, zero-area
triangles dropped by ``_clean``) with their file normals; ``assemble`` makes the scene of
parts through the TOML loader's assembly (``loader._assemble``, an ``Assembly`` for the
rest), file normals in place of the averaged ones; ``auto_camera`` / ``default_light``
frame and light a scene that has no camera or light (``_frame_and_light``).
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from . import loader, objmtl
from .model import Assembly, Camera, Material, PointLight, Scene, SceneError
from .plyattrs import read_ply

#: Material of OBJ faces without ``usemtl`` and of PLY meshes.
DEFAULT_MATERIAL = Material(name="default", ka=np.full(3, 0.8), kd=np.full(3, 0.8),
                            ks=np.zeros(3))
#: Image size and vertical field of view of a framed camera.
AUTO_SIZE, AUTO_FOV = (256, 256), 40.0


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


def assemble(path: Path, parts: list, normals: list, rest: Assembly, *,
             cache=None) -> Scene:
    """The scene of ``parts`` (``loader._Part``, already ``_clean``) and ``rest`` (cameras,
    lights, materials, ...) with ``normals[k]`` (float64 (V, 3) world-space file normals of
    part k, or None: averaged) in place of the averaged normals. Unit-length; a zero file
    normal falls back to the averaged one."""
    r = loader._Reader(path)
    for part in parts:
        if len(part.faces) == 0:
            raise SceneError(f"{path}: object {part.name!r} has no triangles left (all "
                             "zero-area or empty)")
    scene = loader._assemble(r, parts, rest, cache=cache)
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
@dataclass
class ObjOptions:
    """How ``obj_parts`` makes parts of an OBJ's groups. normals: "file" (``vn`` where
    every face vertex of a group has one) or "averaged". smooth: force smooth shading on
    (True) or off (False); None: smooth where the group has ``vn`` normals or a smoothing
    group (``s`` != 0). taken: object names already used (the parts' names are added;
    None: a fresh set). kind: the parts' object kind. flat: every group flat (Mitsuba's
    ``face_normals``). prefix: object names are ``<prefix>.<group name>`` (a scene file's
    object name)."""

    normals: str = "file"
    smooth: bool | None = None
    taken: set | None = None
    kind: str = "obj"
    flat: bool = False
    prefix: str | None = None


def obj_parts(path: Path, materials: list[Material], m: np.ndarray | None = None,
              options: ObjOptions | None = None, **keywords):
    """The parts of an OBJ file: one per group (``objmtl.read_obj``), its MTL materials
    appended to ``materials`` (faces without ``usemtl`` get ``DEFAULT_MATERIAL``; a name
    already in ``materials`` is reused).

    m: 4x4 object-to-world transform (default identity). options: an ``ObjOptions``
    (its fields may also be given as ``keywords``, which override it).
    Returns (parts, file normals per part, files read: the OBJ and its MTLs). Warnings name
    file and line for everything ignored. Raises MeshError / SceneError."""
    o = replace(options or ObjOptions(), **keywords)
    normals, smooth, kind, flat, prefix = o.normals, o.smooth, o.kind, o.flat, o.prefix
    m = np.eye(4) if m is None else m
    taken = set() if o.taken is None else o.taken
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


def ply_part(path: Path, m: np.ndarray | None = None, *, material: int = 0,
             normals: str = "file", name: str | None = None, flat: bool = False):
    """(part, file normals or None, ``PlyMesh``) of a PLY file: smooth with the file's
    normals when it has them and ``normals`` is "file", else smooth with averaged normals
    (flat when ``flat``)."""
    m = np.eye(4) if m is None else m
    ply = read_ply(path)
    fn = world_normals(ply.normals, m) if (normals == "file" and ply.normals is not None
                                           and not flat) else None
    name = name or Path(path).stem
    world, faces, fn = _clean(path, name, _transform(m, ply.vertices), ply.faces, fn)
    if np.linalg.det(m[:3, :3]) < 0:
        faces = faces[:, [0, 2, 1]]
    return loader._Part(name, "ply", material, not flat, world, faces), fn, ply


