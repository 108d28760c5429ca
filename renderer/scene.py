"""The scene: one host-side (numpy) description that both renderers consume.

``Scene`` is the single source of truth: ``renderer`` uploads it to Dr.Jit arrays, and
``reference`` translates it into a Mitsuba scene. The meaning of every field (camera model,
shading modes, specular weights) is fixed in ``docs/MODEL.md``.

Geometry is flattened: all objects' triangles in one array, each object owning a contiguous
range of faces and of vertices (vertices are never shared between objects, so per-object
vertex normals are well defined).
"""
from __future__ import annotations

import difflib
import math
import tomllib
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from . import meshio, shapes

SHADING_MODES = ("classic", "physical")
FALLOFFS = ("none", "inverse_square")
COMBINATIONS = ("constant", "fresnel")


class SceneError(ValueError):
    """A scene file or scene description is malformed.

    The message always names the file and the field, and says what was expected.
    """


@dataclass(frozen=True)
class Camera:
    """Pinhole camera (docs/MODEL.md, "Camera and pixels").

    position, target, up: float64 arrays of shape (3,).
    fov_y: vertical field of view in degrees, in (0, 180).
    width, height: image size in pixels, > 0.
    name: label of the view (e.g. "front").
    """

    position: np.ndarray
    target: np.ndarray
    up: np.ndarray
    fov_y: float
    width: int
    height: int
    name: str = "view0"


@dataclass(frozen=True)
class PointLight:
    """position: float64 (3,); intensity: float64 (3,) RGB, >= 0;
    falloff: "none" | "inverse_square"."""

    position: np.ndarray
    intensity: np.ndarray
    falloff: str = "inverse_square"
    name: str = ""


@dataclass(frozen=True)
class Material:
    """Phong-like material with optional mirror reflection and transmission.

    ka, kd, ks: float64 (3,) ambient, diffuse, specular coefficients (>= 0).
    n: Phong exponent (> 0).
    k_refl, k_refr: float64 (3,) reflection and transmission coefficients (>= 0).
    ior: index of refraction of the inside (> 0; used only when k_refr > 0).
    combination: "constant" (thesis eq. 14) or "fresnel" (dielectric Fresnel weights).
    """

    name: str
    ka: np.ndarray
    kd: np.ndarray
    ks: np.ndarray
    n: float = 32.0
    k_refl: np.ndarray = field(default_factory=lambda: np.zeros(3))
    k_refr: np.ndarray = field(default_factory=lambda: np.zeros(3))
    ior: float = 1.5
    combination: str = "constant"

    @property
    def reflective(self) -> bool:
        return bool(np.any(self.k_refl > 0))

    @property
    def transmissive(self) -> bool:
        return bool(np.any(self.k_refr > 0))


@dataclass(frozen=True)
class Settings:
    """Render settings.

    max_depth: deepest specular bounce (camera ray = depth 0); default 5.
    spp: samples per pixel, a perfect square (k x k strata); 1 in exact mode.
    exact: one ray through each pixel centre (pixel-wise comparable with Mitsuba).
    shading: "classic" (thesis eq. 6) or "physical" (see docs/MODEL.md).
    background: float64 (3,) radiance of rays that escape.
    min_weight: prune a branch whose accumulated weight falls under this (thesis: 0.01).
    ray_epsilon: ray-origin offset as a fraction of the scene's bounding-box diagonal.
    seed: seed of the stratified jitter in converged mode.
    """

    max_depth: int = 5
    spp: int = 1
    exact: bool = True
    shading: str = "classic"
    background: np.ndarray = field(default_factory=lambda: np.zeros(3))
    min_weight: float = 0.01
    ray_epsilon: float = 1e-4
    seed: int = 0


@dataclass(frozen=True)
class ObjectInfo:
    """One object of the scene: a contiguous range of faces and of vertices.

    kind: where it came from ("obj", "ply", "quad", "box", "sphere", "tetrahedron", ...).
    smooth: interpolate vertex normals (else the flat geometric normal).
    """

    name: str
    kind: str
    material: int
    first_face: int
    face_count: int
    first_vertex: int
    vertex_count: int
    smooth: bool


@dataclass
class Scene:
    """Everything needed to render, on the host.

    vertices: float32 (V, 3) world-space positions.
    normals: float32 (V, 3) unit vertex normals (average of adjacent face normals within
        the object); present for every vertex, used only for smooth objects.
    faces: int32 (F, 3) global vertex indices; no zero-area triangles (dropped at load).
    face_material: int32 (F,) index into ``materials``.
    face_object: int32 (F,) index into ``objects``.
    cameras: the views; ``cameras[0]`` is the default.
    """

    cameras: list[Camera]
    settings: Settings
    lights: list[PointLight]
    materials: list[Material]
    objects: list[ObjectInfo]
    vertices: np.ndarray
    normals: np.ndarray
    faces: np.ndarray
    face_material: np.ndarray
    face_object: np.ndarray
    ambient: np.ndarray = field(default_factory=lambda: np.zeros(3))
    name: str = "scene"
    path: Path | None = None
    # Files the scene was built from (scene file + meshes), for golden-image hashes.
    source_files: list[Path] = field(default_factory=list)

    # ---- derived facts -------------------------------------------------------------------
    @property
    def face_count(self) -> int:
        return int(self.faces.shape[0])

    @property
    def face_smooth(self) -> np.ndarray:
        """bool (F,): whether each face interpolates vertex normals."""
        smooth = np.array([o.smooth for o in self.objects], dtype=bool)
        return smooth[self.face_object] if len(smooth) else np.zeros(0, bool)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) float64 (3,) of all vertices used by faces."""
        if self.face_count == 0:
            return np.zeros(3), np.zeros(3)
        used = self.vertices[self.faces.reshape(-1)].astype(np.float64)
        return used.min(axis=0), used.max(axis=0)

    @property
    def diagonal(self) -> float:
        lo, hi = self.bounds()
        return float(np.linalg.norm(hi - lo))

    @property
    def ray_offset(self) -> float:
        """Absolute ray-origin offset ε (docs/MODEL.md, "Ray offsets")."""
        return self.settings.ray_epsilon * max(self.diagonal, 1e-30)

    def with_camera(self, index: int) -> "Scene":
        """The same scene with ``cameras[index]`` moved to the front."""
        cams = list(self.cameras)
        cams.insert(0, cams.pop(index))
        return replace(self, cameras=cams)

    def with_settings(self, **changes) -> "Scene":
        return replace(self, settings=replace(self.settings, **changes))

    def with_size(self, width: int, height: int | None = None) -> "Scene":
        """The same scene with every view resized to ``width`` x ``height`` pixels
        (``height`` defaults to ``width``); the field of view is kept."""
        height = width if height is None else height
        return replace(self, cameras=[replace(c, width=int(width), height=int(height))
                                      for c in self.cameras])


# =========================================================================================
# Loading scene files (docs/scene-format.md)
# =========================================================================================

_TOP_KEYS = ("description", "camera", "views", "render", "ambient", "lights", "materials",
             "objects", "physical")
_VIEW_KEYS = ("name", "position", "target", "up", "fov_y", "resolution")
_RENDER_KEYS = ("max_depth", "spp", "exact", "shading", "background", "min_weight",
                "ray_epsilon", "seed")
_LIGHT_KEYS = ("name", "position", "intensity", "falloff")
_MATERIAL_KEYS = ("ka", "kd", "ks", "n", "k_refl", "k_refr", "ior", "combination")
_OBJECT_KEYS = ("name", "material", "mesh", "shape", "translate", "rotate", "scale",
                "matrix", "smooth", "flip_normals", "subdivide")
_PHYSICAL_KEYS = ("light_scale", "ambient", "background")
_VIEW_DEFAULTS = {"up": [0.0, 1.0, 0.0], "fov_y": 40.0, "resolution": [256, 256]}


class _Reader:
    """Typed access to the parsed TOML with errors that name the file and the field."""

    def __init__(self, path: Path):
        self.path = path

    def error(self, field: str, message: str) -> SceneError:
        return SceneError(f"{self.path}: {field}: {message}")

    @staticmethod
    def join(where: str, key: str) -> str:
        return f"{where}.{key}" if where else key

    def keys(self, table: dict, allowed, where: str) -> None:
        for key in table:
            if key not in allowed:
                close = difflib.get_close_matches(key, allowed, n=1, cutoff=0.5)
                hint = f"; did you mean {close[0]!r}?" if close else ""
                raise self.error(self.join(where, key),
                                 f"unknown key (valid keys: {', '.join(allowed)}){hint}")

    def table(self, value, field: str) -> dict:
        if not isinstance(value, dict):
            raise self.error(field, f"expected a table, got {_describe(value)}")
        return value

    def array_of_tables(self, value, field: str) -> list:
        if not isinstance(value, list) or not all(isinstance(x, dict) for x in value):
            raise self.error(field, f"expected an array of tables ([[{field}]]), "
                                    f"got {_describe(value)}")
        return value

    def number(self, value, field: str, *, lo=None, lo_open=False, hi=None, hi_open=False
               ) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(field, f"expected a number, got {_describe(value)}")
        x = float(value)
        if not math.isfinite(x):
            raise self.error(field, f"expected a finite number, got {value}")
        if lo is not None and (x < lo or (lo_open and x == lo)):
            raise self.error(field, f"expected a number {'>' if lo_open else '>='} {lo}, "
                                    f"got {value}")
        if hi is not None and (x > hi or (hi_open and x == hi)):
            raise self.error(field, f"expected a number {'<' if hi_open else '<='} {hi}, "
                                    f"got {value}")
        return x

    def integer(self, value, field: str, *, lo=None) -> int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(field, f"expected an integer, got {_describe(value)}")
        if lo is not None and value < lo:
            raise self.error(field, f"expected an integer >= {lo}, got {value}")
        return int(value)

    def boolean(self, value, field: str) -> bool:
        if not isinstance(value, bool):
            raise self.error(field, f"expected true or false, got {_describe(value)}")
        return value

    def string(self, value, field: str, choices=None) -> str:
        if not isinstance(value, str):
            raise self.error(field, f"expected a string, got {_describe(value)}")
        if choices is not None and value not in choices:
            close = difflib.get_close_matches(value, choices, n=1, cutoff=0.5)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise self.error(field, f"expected one of {', '.join(map(repr, choices))}, "
                                    f"got {value!r}{hint}")
        return value

    def vector(self, value, field: str, n: int = 3) -> np.ndarray:
        if not isinstance(value, list) or len(value) != n:
            raise self.error(field, f"expected an array of {n} numbers, got "
                                    f"{_describe(value)}")
        return np.array([self.number(x, f"{field}[{i}]") for i, x in enumerate(value)])

    def color(self, value, field: str) -> np.ndarray:
        """RGB triple or one number for all three channels; >= 0."""
        if isinstance(value, list):
            c = self.vector(value, field)
        elif isinstance(value, (int, float)) and not isinstance(value, bool):
            c = np.full(3, self.number(value, field))
        else:
            raise self.error(field, "expected a number or an array of 3 numbers (RGB), "
                                    f"got {_describe(value)}")
        if np.any(c < 0):
            raise self.error(field, f"expected non-negative values, got {value}")
        return c


def _describe(value) -> str:
    kind = {bool: "boolean", int: "integer", float: "number", str: "string", list: "array",
            dict: "table"}.get(type(value), type(value).__name__)
    text = repr(value)
    return f"{kind} {text if len(text) <= 40 else text[:37] + '...'}"


def load_scene(path, *, shading: str | None = None) -> Scene:
    """Read and validate a scene file (TOML; format in docs/scene-format.md).

    path: the ``.toml`` file; mesh paths inside it are relative to its folder.
    shading: "classic" | "physical" overrides ``render.shading``. In physical mode the
        ``[physical]`` table applies (``light_scale`` multiplies every light's intensity,
        ``ambient`` / ``background`` replace the scene's), and lights default to
        inverse-square falloff (an explicit ``falloff = "none"`` is an error).

    Raises ``SceneError`` (file, dotted field, what was expected) for any malformed input.
    Zero-area triangles are dropped with a warning.
    """
    path = Path(path)
    r = _Reader(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SceneError(f"{path}: file not found") from None
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"{path}: TOML syntax error: {e}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise SceneError(f"{path}: cannot read: {e}") from None
    r.keys(data, _TOP_KEYS, "")
    if "description" in data:
        r.string(data["description"], "description")

    # ---- render settings ------------------------------------------------------------------
    rt = r.table(data.get("render", {}), "render")
    r.keys(rt, _RENDER_KEYS, "render")
    default_shading = r.string(rt.get("shading", "classic"), "render.shading", SHADING_MODES)
    if shading is not None and shading not in SHADING_MODES:
        raise SceneError(f"{path}: shading override: expected one of {SHADING_MODES}, "
                         f"got {shading!r}")
    mode = shading or default_shading
    spp = r.integer(rt.get("spp", 1), "render.spp", lo=1)
    if math.isqrt(spp) ** 2 != spp:
        raise r.error("render.spp", f"expected a perfect square (k*k strata), got {spp}")
    exact = r.boolean(rt["exact"], "render.exact") if "exact" in rt else spp == 1
    if exact and spp > 1:
        raise r.error("render.exact", f"exact = true renders one ray per pixel centre; "
                                      f"it cannot be combined with spp = {spp}")
    physical_t = r.table(data.get("physical", {}), "physical")
    r.keys(physical_t, _PHYSICAL_KEYS, "physical")
    background = r.color(rt.get("background", 0.0), "render.background")
    ambient = r.color(data.get("ambient", 0.0), "ambient")
    light_scale = r.color(physical_t.get("light_scale", 1.0), "physical.light_scale")
    p_ambient = r.color(physical_t.get("ambient", 0.0), "physical.ambient")
    p_background = r.color(physical_t.get("background", 0.0), "physical.background")
    if mode == "physical":
        if "ambient" in physical_t:
            ambient = p_ambient
        if "background" in physical_t:
            background = p_background
    settings = Settings(
        max_depth=r.integer(rt.get("max_depth", 5), "render.max_depth", lo=0),
        spp=spp, exact=exact, shading=mode, background=background,
        min_weight=r.number(rt.get("min_weight", 0.01), "render.min_weight", lo=0.0),
        ray_epsilon=r.number(rt.get("ray_epsilon", 1e-4), "render.ray_epsilon", lo=0.0,
                             lo_open=True),
        seed=r.integer(rt.get("seed", 0), "render.seed", lo=0),
    )

    # ---- cameras --------------------------------------------------------------------------
    cam_defaults = r.table(data.get("camera", {}), "camera")
    r.keys(cam_defaults, _VIEW_KEYS, "camera")
    views = r.array_of_tables(data.get("views", []), "views") if "views" in data else []
    if not views:
        views = [{}]
    cameras, view_names = [], set()
    for i, view in enumerate(views):
        where = f"views[{i}]" if "views" in data else "camera"
        r.keys(view, _VIEW_KEYS, where)
        cameras.append(_camera(r, {**_VIEW_DEFAULTS, **cam_defaults}, view, where, i,
                               "views" in data))
        if cameras[-1].name in view_names:
            raise r.error(f"{where}.name", f"duplicate view name {cameras[-1].name!r}")
        view_names.add(cameras[-1].name)

    # ---- lights ---------------------------------------------------------------------------
    lights = []
    for i, lt in enumerate(r.array_of_tables(data.get("lights", []), "lights")):
        where = f"lights[{i}]"
        r.keys(lt, _LIGHT_KEYS, where)
        for req in ("position", "intensity"):
            if req not in lt:
                raise r.error(f"{where}.{req}", "missing (required)")
        falloff_default = "none" if mode == "classic" else "inverse_square"
        falloff = r.string(lt.get("falloff", falloff_default), f"{where}.falloff", FALLOFFS)
        if mode == "physical" and falloff != "inverse_square":
            raise r.error(f"{where}.falloff", "physical shading needs 'inverse_square' "
                          "point lights (Mitsuba's point emitter); remove the key or use "
                          "classic shading")
        intensity = r.color(lt["intensity"], f"{where}.intensity")
        if mode == "physical":
            intensity = intensity * light_scale
        lights.append(PointLight(position=r.vector(lt["position"], f"{where}.position"),
                                 intensity=intensity, falloff=falloff,
                                 name=r.string(lt.get("name", f"light{i}"), f"{where}.name")))

    # ---- materials ------------------------------------------------------------------------
    materials, material_index = [], {}
    for name, mt in r.table(data.get("materials", {}), "materials").items():
        where = f"materials.{name}"
        r.table(mt, where)
        r.keys(mt, _MATERIAL_KEYS, where)
        kd = r.color(mt.get("kd", 0.0), f"{where}.kd")
        material_index[name] = len(materials)
        materials.append(Material(
            name=name,
            ka=r.color(mt["ka"], f"{where}.ka") if "ka" in mt else kd.copy(),
            kd=kd,
            ks=r.color(mt.get("ks", 0.0), f"{where}.ks"),
            n=r.number(mt.get("n", 32.0), f"{where}.n", lo=0.0, lo_open=True),
            k_refl=r.color(mt.get("k_refl", 0.0), f"{where}.k_refl"),
            k_refr=r.color(mt.get("k_refr", 0.0), f"{where}.k_refr"),
            ior=r.number(mt.get("ior", 1.5), f"{where}.ior", lo=0.0, lo_open=True),
            combination=r.string(mt.get("combination", "constant"), f"{where}.combination",
                                 COMBINATIONS),
        ))

    # ---- objects --------------------------------------------------------------------------
    sources = [path.resolve()]
    parts = []          # (ObjectInfo fields, world vertices float64, faces int64)
    object_names = set()
    for i, ot in enumerate(r.array_of_tables(data.get("objects", []), "objects")):
        where = f"objects[{i}]"
        shape_name = ot.get("shape")
        extra = shapes.SHAPE_PARAMETERS.get(shape_name, ()) if isinstance(shape_name, str) \
            else ()
        r.keys(ot, _OBJECT_KEYS + tuple(extra), where)
        if "material" not in ot:
            raise r.error(f"{where}.material", "missing (required): the name of a "
                                               "[materials.<name>] table")
        mname = r.string(ot["material"], f"{where}.material")
        if mname not in material_index:
            known = ", ".join(material_index) or "none defined"
            close = difflib.get_close_matches(mname, list(material_index), n=1, cutoff=0.5)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise r.error(f"{where}.material", f"unknown material {mname!r} "
                                               f"(defined: {known}){hint}")
        if ("mesh" in ot) == ("shape" in ot):
            raise r.error(where, "expected exactly one of 'mesh' (a file) or 'shape'")
        if "mesh" in ot:
            rel = r.string(ot["mesh"], f"{where}.mesh")
            mesh_path = (path.parent / rel)
            if mesh_path.suffix.lower() not in meshio.MESH_FORMATS:
                raise r.error(f"{where}.mesh", f"unsupported mesh format "
                              f"{mesh_path.suffix!r}, expected one of "
                              f"{sorted(meshio.MESH_FORMATS)}")
            if not mesh_path.is_file():
                raise r.error(f"{where}.mesh", f"mesh file not found: {mesh_path}")
            try:
                verts, faces = meshio.load_mesh(mesh_path)
            except meshio.MeshError as e:
                raise r.error(f"{where}.mesh", str(e)) from None
            sources.append(mesh_path.resolve())
            kind, default_name = mesh_path.suffix.lower()[1:], mesh_path.stem
        else:
            kind = r.string(ot["shape"], f"{where}.shape", tuple(shapes.SHAPES))
            params = {}
            for key in shapes.SHAPE_PARAMETERS[kind]:
                if key in ot:
                    params[key] = r.integer(ot[key], f"{where}.{key}",
                                            lo=1 if key == "frequency" else 0)
            if len(params) > 1:
                raise r.error(f"{where}.{'.'.join(params)}", "give either 'frequency' or "
                                                          "'subdivisions', not both")
            verts, faces = shapes.make_shape(kind, **params)
            default_name = kind
        if "subdivide" in ot:           # midpoint subdivision, each level: triangles x 4
            levels = r.integer(ot["subdivide"], f"{where}.subdivide", lo=0)
            if levels > 4:
                raise r.error(f"{where}.subdivide", f"expected 0..4 levels, got {levels}")
            from .subdivide import subdivide_midpoint
            verts, faces = subdivide_midpoint(verts, faces, levels)
            faces = faces.astype(np.int64)
        name = r.string(ot.get("name", f"{default_name}{i}"), f"{where}.name")
        if name in object_names:
            raise r.error(f"{where}.name", f"duplicate object name {name!r}")
        object_names.add(name)
        m = _transform(r, ot, where)
        world = verts @ m[:3, :3].T + m[:3, 3]
        if not np.all(np.isfinite(world)):
            raise r.error(where, "transform produces non-finite vertex positions")
        flip = (np.linalg.det(m[:3, :3]) < 0) != r.boolean(ot.get("flip_normals", False),
                                                            f"{where}.flip_normals")
        if flip:                        # mirroring transforms keep the winding outward
            faces = faces[:, [0, 2, 1]]
        smooth = r.boolean(ot.get("smooth", kind == "sphere"), f"{where}.smooth")
        parts.append((name, kind, material_index[mname], smooth, world, faces))
    return _assemble(r, data, parts, cameras, settings, lights, materials, ambient, sources)


def _camera(r: _Reader, defaults: dict, view: dict, where: str, i: int, in_views: bool
            ) -> Camera:
    merged = {**defaults, **view}

    def field(key):   # the table the value came from, for error messages
        return f"{where}.{key}" if key in view or not in_views else f"camera.{key}"

    for req in ("position", "target"):
        if req not in merged:
            raise r.error(f"{where}.{req}", "missing (required, here or in [camera])")
    pos = r.vector(merged["position"], field("position"))
    target = r.vector(merged["target"], field("target"))
    up = r.vector(merged["up"], field("up"))
    fov = r.number(merged["fov_y"], field("fov_y"), lo=0.0, lo_open=True, hi=180.0,
                   hi_open=True)
    res = merged["resolution"]
    if isinstance(res, tuple):
        res = list(res)
    if not isinstance(res, list) or len(res) != 2:
        raise r.error(field("resolution"), f"expected [width, height], got {_describe(res)}")
    w = r.integer(res[0], field("resolution") + "[0]", lo=1)
    h = r.integer(res[1], field("resolution") + "[1]", lo=1)
    forward = target - pos
    if np.linalg.norm(forward) == 0:
        raise r.error(field("target"), "target coincides with position")
    if np.linalg.norm(np.cross(forward, up)) <= 1e-9 * np.linalg.norm(forward) * \
            max(np.linalg.norm(up), 1e-300):
        raise r.error(field("up"), "up is zero or parallel to the viewing direction")
    name = r.string(merged.get("name", f"view{i}"), field("name"))
    return Camera(position=pos, target=target, up=up, fov_y=fov, width=w, height=h, name=name)


def _rotation(deg: np.ndarray) -> np.ndarray:
    """Rotation by deg[0] about x, then deg[1] about y, then deg[2] about z."""
    cx, cy, cz = np.cos(np.radians(deg))
    sx, sy, sz = np.sin(np.radians(deg))
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return rz @ ry @ rx


def _transform(r: _Reader, ot: dict, where: str) -> np.ndarray:
    """The object's 4x4 object-to-world matrix: ``matrix``, or translate·rotate·scale."""
    m = np.eye(4)
    if "matrix" in ot:
        others = [k for k in ("translate", "rotate", "scale") if k in ot]
        if others:
            raise r.error(f"{where}.matrix", f"give either 'matrix' or "
                          f"translate/rotate/scale, not both (also found {others[0]!r})")
        rows = ot["matrix"]
        if not isinstance(rows, list) or len(rows) != 4:
            raise r.error(f"{where}.matrix", f"expected 4 rows of 4 numbers, got "
                                             f"{_describe(rows)}")
        m = np.stack([r.vector(row, f"{where}.matrix[{k}]", 4) for k, row in enumerate(rows)])
        if not np.array_equal(m[3], [0, 0, 0, 1]):
            raise r.error(f"{where}.matrix[3]", f"expected [0, 0, 0, 1] (affine transform), "
                                                f"got {m[3].tolist()}")
        field = f"{where}.matrix"
    else:
        scale = ot.get("scale", 1.0)
        s = (r.vector(scale, f"{where}.scale") if isinstance(scale, list)
             else np.full(3, r.number(scale, f"{where}.scale")))
        rot = _rotation(r.vector(ot["rotate"], f"{where}.rotate")) if "rotate" in ot \
            else np.eye(3)
        m[:3, :3] = rot @ np.diag(s)
        if "translate" in ot:
            m[:3, 3] = r.vector(ot["translate"], f"{where}.translate")
        field = f"{where}.scale"
    a = m[:3, :3]
    if abs(np.linalg.det(a)) <= 1e-12 * max(np.abs(a).max(), 1e-300) ** 3:
        raise r.error(field, "singular transform (zero volume scale)")
    return m


def _assemble(r, data, parts, cameras, settings, lights, materials, ambient, sources) -> Scene:
    objects, all_v, all_n, all_f, f_mat, f_obj = [], [], [], [], [], []
    v_base = f_base = 0
    for k, (name, kind, mat, smooth, world, faces) in enumerate(parts):
        where = f"objects[{k}]"
        # Zero-area test on the float32 positions the renderer will see (float64 arithmetic).
        p = world.astype(np.float32).astype(np.float64)
        cross = np.cross(p[faces[:, 1]] - p[faces[:, 0]], p[faces[:, 2]] - p[faces[:, 0]])
        area2 = np.linalg.norm(cross, axis=1)
        keep = area2 > 0
        dropped = int((~keep).sum())
        if dropped:
            warnings.warn(f"{r.path}: {where} ({name!r}): dropped {dropped} zero-area "
                          f"triangle{'s' if dropped > 1 else ''} of {len(faces)}", stacklevel=3)
        faces, cross, area2 = faces[keep], cross[keep], area2[keep]
        if len(faces) == 0:
            raise r.error(where, f"object {name!r} has no triangles left (all zero-area or "
                                 "empty mesh)")
        used, faces = np.unique(faces, return_inverse=True)   # compact to used vertices
        faces = faces.reshape(-1, 3)
        verts = world[used]
        normals = _vertex_normals(verts, faces, cross / area2[:, None])
        objects.append(ObjectInfo(name=name, kind=kind, material=mat, first_face=f_base,
                                  face_count=len(faces), first_vertex=v_base,
                                  vertex_count=len(verts), smooth=smooth))
        all_v.append(verts)
        all_n.append(normals)
        all_f.append(faces + v_base)
        f_mat.append(np.full(len(faces), mat, np.int32))
        f_obj.append(np.full(len(faces), k, np.int32))
        v_base += len(verts)
        f_base += len(faces)

    def cat(xs, shape, dtype):
        return np.concatenate(xs).astype(dtype) if xs else np.zeros(shape, dtype)

    return Scene(
        cameras=cameras, settings=settings, lights=lights, materials=materials,
        objects=objects,
        vertices=cat(all_v, (0, 3), np.float32),
        normals=cat(all_n, (0, 3), np.float32),
        faces=cat(all_f, (0, 3), np.int32),
        face_material=cat(f_mat, (0,), np.int32),
        face_object=cat(f_obj, (0,), np.int32),
        ambient=ambient, name=r.path.stem, path=r.path, source_files=sources,
    )


def _vertex_normals(verts: np.ndarray, faces: np.ndarray, face_n: np.ndarray) -> np.ndarray:
    """Normalised plain average of the unit normals of the faces sharing each vertex;
    coincident positions are welded for the average (smooth across mesh seams)."""
    _, weld = np.unique(verts, axis=0, return_inverse=True)
    weld = weld.reshape(-1)
    acc = np.zeros((weld.max() + 1, 3))
    for c in range(3):
        np.add.at(acc, weld[faces[:, c]], face_n)
    n = acc[weld]
    length = np.linalg.norm(n, axis=1)
    # Opposing faces can cancel: fall back to the normal of one adjacent face.
    fallback = np.zeros_like(n)
    fallback[faces.reshape(-1)] = np.repeat(face_n, 3, axis=0)
    bad = length < 1e-12
    n[bad] = fallback[bad]
    length[bad] = 1.0
    return n / length[:, None]
