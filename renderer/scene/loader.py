"""Reading scene files (TOML; format in docs/scene-format.md) into a ``Scene``.

``load_scene`` reads the file, then one reader per table: ``[render]`` and ``[physical]``
(settings, ambient, background), ``[camera]`` / ``[[views]]``, ``[[lights]]``,
``[materials.<name>]`` and ``[[objects]]`` (meshes and shapes, transformed and assembled
into the flat triangle arrays), and ``[check]`` (what the regression gate checks and its
thresholds: data for ``evaluation``, which the renderer ignores). Every error is a
``SceneError`` that names the file and the dotted field and says what was expected; unknown
keys get the closest valid one suggested.
"""
from __future__ import annotations

import difflib
import math
import os
import tomllib
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .. import parallel
from ..cache_key import code_version, content_key
from . import meshio, shapes
from .model import (
    ARRAY_LIMIT,
    COMBINATIONS,
    FALLOFFS,
    SHADING_MODES,
    SPAWN_RULES,
    TREE_BUILDS,
    Assembly,
    Camera,
    Material,
    ObjectInfo,
    PointLight,
    Scene,
    SceneError,
    Settings,
    validate_image_size,
    validate_settings,
)
from .subdivide import subdivide_midpoint

_TOP_KEYS = ("description", "camera", "views", "render", "ambient", "lights", "materials",
             "objects", "physical", "check")
_VIEW_KEYS = ("name", "position", "target", "up", "fov_y", "resolution")
_RENDER_KEYS = ("max_depth", "spp", "exact", "shading", "background", "min_weight",
                "ray_epsilon", "seed", "spawn", "build", "shadow_samples")
_LIGHT_KEYS = ("name", "position", "intensity", "falloff", "type", "radius", "center",
               "corner", "edge_u", "edge_v", "two_sided")
#: Keys each light type reads besides name, intensity and falloff.
_LIGHT_TYPE_KEYS = {"point": ("position",), "sphere": ("position", "center", "radius"),
                    "rectangle": ("center", "corner", "edge_u", "edge_v", "two_sided")}
_MATERIAL_KEYS = ("ka", "kd", "ks", "n", "k_refl", "k_refr", "ior", "combination")
_OBJECT_KEYS = ("name", "material", "mesh", "shape", "translate", "rotate", "scale",
                "matrix", "smooth", "flip_normals", "subdivide")
_PHYSICAL_KEYS = ("light_scale", "ambient", "background")
_CHECK_KEYS = ("modes", "shadings", "size", "converged_size", "exact", "converged", "warn",
               "reason")
#: Comparison modes a ``[check]`` table may name (``reference.MODES``; the renderer cannot
#: import it).
_CHECK_MODES = ("exact", "converged")
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


def load_scene(path, *, shading: str | None = None, cache=None) -> Scene:
    """Read and validate a scene file (TOML; format in docs/scene-format.md).

    path: the ``.toml`` file; mesh paths inside it are relative to its folder.
    shading: "classic" | "physical" overrides ``render.shading``. In physical mode the
        ``[physical]`` table applies (``light_scale`` multiplies every light's intensity,
        ``ambient`` / ``background`` replace the scene's), and lights default to
        inverse-square falloff (an explicit ``falloff = "none"`` is an error).
    cache: a ``renderer.accel.cache.TreeCache`` (None: none) for the slow arrays of the
        load, keyed by their input arrays and the loader's code: subdivided meshes and
        each object's compacted vertices and averaged normals.

    Raises ``SceneError`` (file, dotted field, what was expected) for any malformed input.
    Zero-area triangles are dropped with a warning.
    """
    path = Path(path)
    r = _Reader(path)
    data = _read_toml(path)
    a = _read_head(r, data, shading)
    objects, sources = _read_objects(r, data, {m.name: i for i, m in enumerate(a.materials)},
                                     cache)
    check = _read_check(r, data)
    scene = _assemble(r, objects, replace(a, sources=[path.resolve(), *sources]), cache)
    return replace(scene, check=check)


def _read_head(r: _Reader, data: dict, shading: str | None) -> Assembly:
    """The tables before the objects, checked in the loader's order: the top-level keys,
    ``description``, ``[render]``, ``[physical]``, the views (their image sizes too), the
    lights and the materials; as an ``Assembly`` whose ``sources`` are still empty (every
    reader of a TOML scene starts with this)."""
    r.keys(data, _TOP_KEYS, "")
    if "description" in data:
        r.string(data["description"], "description")
    settings = _read_render(r, data, shading)
    look = _read_physical(r, data, settings)
    settings = replace(settings, background=look.background)
    cameras = _read_views(r, data)
    for i, cam in enumerate(cameras):
        try:
            validate_image_size(cam.width, cam.height, settings.spp,
                                f"views[{i}]" if "views" in data else "camera")
        except SceneError as e:
            raise SceneError(f"{r.path}: {e}", field=e.field) from None
    lights = _read_lights(r, data, settings.shading, look.light_scale)
    materials = _read_materials(r, data)
    return Assembly(cameras, settings, lights, materials, look.ambient, [])


def _read_toml(path: Path) -> dict:
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SceneError(f"{path}: file not found") from None
    except tomllib.TOMLDecodeError as e:
        raise SceneError(f"{path}: TOML syntax error: {e}") from None
    except (OSError, UnicodeDecodeError) as e:
        raise SceneError(f"{path}: cannot read: {e}") from None


# ---- [render] --------------------------------------------------------------------------------
def _read_render(r: _Reader, data: dict, shading: str | None) -> Settings:
    """``[render]`` with the caller's shading override; background as the table gives it
    (``[physical]`` may replace it)."""
    rt = r.table(data.get("render", {}), "render")
    r.keys(rt, _RENDER_KEYS, "render")
    default_shading = r.string(rt.get("shading", "classic"), "render.shading", SHADING_MODES)
    if shading is not None and shading not in SHADING_MODES:
        raise SceneError(f"{r.path}: shading override: expected one of {SHADING_MODES}, "
                         f"got {shading!r}")
    spp = r.integer(rt.get("spp", 1), "render.spp", lo=1)
    exact = r.boolean(rt["exact"], "render.exact") if "exact" in rt else spp == 1
    max_depth = r.integer(rt.get("max_depth", 5), "render.max_depth", lo=0)
    spawn = r.string(rt.get("spawn", "scale-free"), "render.spawn", SPAWN_RULES)
    if "spawn" in rt and "ray_epsilon" in rt:     # either rule, named or the default's
        raise SceneError(f"{r.path}: render.spawn: {spawn!r} and render.ray_epsilon (an "
                         "absolute offset) exclude each other", field="render.spawn")
    try:
        validate_settings(spp=spp, exact=exact, max_depth=max_depth, where="render")
    except SceneError as e:
        raise SceneError(f"{r.path}: {e}", field=e.field) from None
    return Settings(
        max_depth=max_depth, spp=spp, exact=exact, shading=shading or default_shading,
        background=r.color(rt.get("background", 0.0), "render.background"),
        min_weight=r.number(rt.get("min_weight", 0.01), "render.min_weight", lo=0.0),
        ray_epsilon=(r.number(rt["ray_epsilon"], "render.ray_epsilon", lo=0.0, lo_open=True)
                     if "ray_epsilon" in rt else None),
        seed=r.integer(rt.get("seed", 0), "render.seed", lo=0),
        spawn=spawn, shadow_samples=_shadow_samples(r, rt),
        build=r.string(rt.get("build", "auto"), "render.build", TREE_BUILDS),
    )


def _shadow_samples(r: _Reader, rt: dict) -> int:
    """``render.shadow_samples``: a perfect square >= 1 (default 1)."""
    n = r.integer(rt.get("shadow_samples", 1), "render.shadow_samples", lo=1)
    try:
        validate_settings(shadow_samples=n, where="render")
    except SceneError as e:
        raise SceneError(f"{r.path}: {e}", field=e.field) from None
    return n


# ---- ambient and [physical] ------------------------------------------------------------------
@dataclass
class _Look:
    """Ambient and background radiance (float64 (3,)) and the factor on every light's
    intensity, for the shading mode in use."""

    ambient: np.ndarray
    background: np.ndarray
    light_scale: np.ndarray


def _read_physical(r: _Reader, data: dict, settings: Settings) -> _Look:
    """Top-level ``ambient`` and the ``[physical]`` table, which applies in physical mode."""
    pt = r.table(data.get("physical", {}), "physical")
    r.keys(pt, _PHYSICAL_KEYS, "physical")
    ambient = r.color(data.get("ambient", 0.0), "ambient")
    light_scale = r.color(pt.get("light_scale", 1.0), "physical.light_scale")
    p_ambient = r.color(pt.get("ambient", 0.0), "physical.ambient")
    p_background = r.color(pt.get("background", 0.0), "physical.background")
    look = _Look(ambient=ambient, background=settings.background, light_scale=light_scale)
    if settings.shading == "physical":
        if "ambient" in pt:
            look.ambient = p_ambient
        if "background" in pt:
            look.background = p_background
    return look


# ---- [camera] and [[views]] ------------------------------------------------------------------
def _read_views(r: _Reader, data: dict) -> list[Camera]:
    """One camera per ``[[views]]`` entry (``[camera]`` holds their defaults), or the
    ``[camera]`` table alone."""
    cam_defaults = r.table(data.get("camera", {}), "camera")
    r.keys(cam_defaults, _VIEW_KEYS, "camera")
    in_views = "views" in data
    views = r.array_of_tables(data["views"], "views") if in_views else []
    if not views:
        views = [{}]
    cameras, names = [], set()
    for i, view in enumerate(views):
        where = f"views[{i}]" if in_views else "camera"
        r.keys(view, _VIEW_KEYS, where)
        cam = _camera(r, {**_VIEW_DEFAULTS, **cam_defaults}, view, where, i, in_views)
        if cam.name in names:
            raise r.error(f"{where}.name", f"duplicate view name {cam.name!r}")
        names.add(cam.name)
        cameras.append(cam)
    return cameras


# ---- [[lights]] ------------------------------------------------------------------------------
def _read_lights(r: _Reader, data: dict, mode: str, light_scale: np.ndarray
                 ) -> list[PointLight]:
    """Lights (``type`` "point", the default, "sphere" or "rectangle"; docs/MODEL.md); in
    physical mode inverse-square only, intensities times ``light_scale``. A sphere of
    ``radius = 0`` is a point light."""
    lights = []
    for i, lt in enumerate(r.array_of_tables(data.get("lights", []), "lights")):
        where = f"lights[{i}]"
        r.keys(lt, _LIGHT_KEYS, where)
        kind = r.string(lt.get("type", "point"), f"{where}.type", tuple(_LIGHT_TYPE_KEYS))
        for key in lt:
            if key not in ("name", "intensity", "falloff", "type") \
                    and key not in _LIGHT_TYPE_KEYS[kind]:
                raise r.error(f"{where}.{key}", f"not a key of a {kind!r} light (keys: "
                              f"{', '.join(_LIGHT_TYPE_KEYS[kind])})")
        if "intensity" not in lt:
            raise r.error(f"{where}.intensity", "missing (required)")
        falloff_default = "none" if mode == "classic" else "inverse_square"
        falloff = r.string(lt.get("falloff", falloff_default), f"{where}.falloff", FALLOFFS)
        if mode == "physical" and falloff != "inverse_square":
            raise r.error(f"{where}.falloff", "physical shading needs 'inverse_square' "
                          "lights (Mitsuba's point and area emitters); remove the key or use "
                          "classic shading")
        intensity = r.color(lt["intensity"], f"{where}.intensity")
        if mode == "physical":
            intensity = intensity * light_scale
        name = r.string(lt.get("name", f"light{i}"), f"{where}.name")
        common = dict(intensity=intensity, falloff=falloff, name=name)
        if kind == "rectangle":
            lights.append(_read_rectangle(r, lt, where, common))
            continue
        if kind == "sphere" and "position" in lt and "center" in lt:
            raise r.error(f"{where}.center", "give the centre once (center or position)")
        pos_key = "center" if "center" in lt else "position"
        if pos_key not in lt:
            raise r.error(f"{where}.position", "missing (required)")
        position = r.vector(lt[pos_key], f"{where}.{pos_key}")
        radius = r.number(lt.get("radius", 0.0), f"{where}.radius", lo=0.0) \
            if kind == "sphere" else 0.0
        if kind == "sphere" and "radius" not in lt:
            raise r.error(f"{where}.radius", "missing (required for a sphere light)")
        if radius > 0:
            lights.append(PointLight(position=position, shape="sphere", radius=radius,
                                     **common))
        else:
            lights.append(PointLight(position=position, **common))
    return lights


def _read_rectangle(r: _Reader, lt: dict, where: str, common: dict) -> PointLight:
    """A rectangle light: ``edge_u``, ``edge_v`` and its ``center`` or ``corner`` (one of
    them), ``two_sided`` (false)."""
    for req in ("edge_u", "edge_v"):
        if req not in lt:
            raise r.error(f"{where}.{req}", "missing (required for a rectangle light)")
    eu = r.vector(lt["edge_u"], f"{where}.edge_u")
    ev = r.vector(lt["edge_v"], f"{where}.edge_v")
    if ("center" in lt) == ("corner" in lt):
        raise r.error(f"{where}.center", "give exactly one of center and corner")
    if "center" in lt:
        centre = r.vector(lt["center"], f"{where}.center")
    else:
        centre = r.vector(lt["corner"], f"{where}.corner") + 0.5 * (eu + ev)
    if not np.linalg.norm(np.cross(eu, ev)) > 0:
        raise r.error(f"{where}.edge_v", "parallel to edge_u (the rectangle has no area)")
    two = r.boolean(lt.get("two_sided", False), f"{where}.two_sided")
    return PointLight(position=centre, shape="rectangle", edge_u=eu, edge_v=ev,
                      two_sided=two, **common)


# ---- [materials.<name>] ----------------------------------------------------------------------
def _read_materials(r: _Reader, data: dict) -> list[Material]:
    """Materials in file order (``ka`` defaults to ``kd``)."""
    materials = []
    for name, mt in r.table(data.get("materials", {}), "materials").items():
        where = f"materials.{name}"
        r.table(mt, where)
        r.keys(mt, _MATERIAL_KEYS, where)
        kd = r.color(mt.get("kd", 0.0), f"{where}.kd")
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
    return materials


# ---- [check] ---------------------------------------------------------------------------------
def _read_check(r: _Reader, data: dict) -> dict:
    """The ``[check]`` table as plain data: ``modes`` and ``shadings`` (lists of names),
    ``size`` and ``converged_size`` (the goldens' ``(width, height)``), the threshold
    overrides ``exact`` / ``converged`` and the ``warn`` levels (tables of name -> number;
    ``evaluation.rules`` checks the names), and ``reason`` (why they differ from the
    defaults). Absent keys are absent from the result."""
    ct = r.table(data.get("check", {}), "check")
    r.keys(ct, _CHECK_KEYS, "check")
    out: dict = {}
    for key, choices in (("modes", _CHECK_MODES), ("shadings", SHADING_MODES)):
        if key in ct:
            values = ct[key]
            if not isinstance(values, list) or not values:
                raise r.error(f"check.{key}", f"expected a non-empty array of names from "
                                              f"{', '.join(map(repr, choices))}, got "
                                              f"{_describe(values)}")
            out[key] = [r.string(v, f"check.{key}[{i}]", choices) for i, v in enumerate(values)]
    for key in ("size", "converged_size"):
        if key in ct:
            size = ct[key]
            if not isinstance(size, list) or len(size) != 2:
                raise r.error(f"check.{key}", f"expected [width, height], got {_describe(size)}")
            w = r.integer(size[0], f"check.{key}[0]", lo=1)
            h = r.integer(size[1], f"check.{key}[1]", lo=1)
            if 3 * w * h > ARRAY_LIMIT:
                raise r.error(f"check.{key}", f"{w} x {h} pixels need {3 * w * h} film "
                                              "entries; Dr.Jit arrays hold at most 2^32 - 1")
            out[key] = (w, h)
    for key in ("exact", "converged", "warn"):
        if key in ct:
            table = r.table(ct[key], f"check.{key}")
            out[key] = {name: r.number(v, f"check.{key}.{name}", lo=0.0)
                        for name, v in table.items()}
    if "reason" in ct:
        out["reason"] = r.string(ct["reason"], "check.reason")
    return out


# ---- [[objects]] -----------------------------------------------------------------------------
@dataclass
class _Part:
    """One object before assembly: world-space vertices float64 (V, 3), faces int (F, 3)."""

    name: str
    kind: str
    material: int
    smooth: bool
    world: np.ndarray
    faces: np.ndarray


def _read_objects(r: _Reader, data: dict, material_index: dict[str, int], cache=None
                  ) -> tuple[list[_Part], list[Path]]:
    """Every object, transformed to world space, and the mesh files read."""
    parts, names, sources = [], set(), []
    for i, ot in enumerate(r.array_of_tables(data.get("objects", []), "objects")):
        where = f"objects[{i}]"
        shape_name = ot.get("shape")
        extra = shapes.SHAPE_PARAMETERS.get(shape_name, ()) if isinstance(shape_name, str) \
            else ()
        r.keys(ot, _OBJECT_KEYS + tuple(extra), where)
        material = _object_material(r, ot, where, material_index)
        if ("mesh" in ot) == ("shape" in ot):
            raise r.error(where, "expected exactly one of 'mesh' (a file) or 'shape'")
        if "mesh" in ot:
            verts, faces, kind, default_name, mesh_path = _object_mesh(r, ot, where)
            sources.append(mesh_path.resolve())
        else:
            verts, faces, kind = _object_shape(r, ot, where)
            default_name = kind
        if "subdivide" in ot:           # midpoint subdivision, each level: triangles x 4
            levels = r.integer(ot["subdivide"], f"{where}.subdivide", lo=0)
            if levels > 4:
                raise r.error(f"{where}.subdivide", f"expected 0..4 levels, got {levels}")
            _check_size(r, f"{where}.subdivide", len(faces) * 4 ** levels,
                        f"subdivide = {levels} of {len(faces):,} triangles")
            out = _cached(cache, "mesh", (verts, faces, levels), lambda v=verts, f=faces,
                          n=levels: dict(zip(("v", "f"), subdivide_midpoint(v, f, n))))
            verts, faces = out["v"], out["f"].astype(np.int64)
        name = r.string(ot.get("name", f"{default_name}{i}"), f"{where}.name")
        if name in names:
            raise r.error(f"{where}.name", f"duplicate object name {name!r}")
        names.add(name)
        m = _transform(r, ot, where)
        world = verts @ m[:3, :3].T + m[:3, 3]
        if not np.all(np.isfinite(world)):
            raise r.error(where, "transform produces non-finite vertex positions")
        flip = (np.linalg.det(m[:3, :3]) < 0) != r.boolean(ot.get("flip_normals", False),
                                                            f"{where}.flip_normals")
        if flip:                        # mirroring transforms keep the winding outward
            faces = faces[:, [0, 2, 1]]
        smooth = r.boolean(ot.get("smooth", kind == "sphere"), f"{where}.smooth")
        parts.append(_Part(name, kind, material, smooth, world, faces))
    return parts, sources


def _object_material(r: _Reader, ot: dict, where: str, material_index: dict[str, int]
                     ) -> int:
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
    return material_index[mname]


def _object_mesh(r: _Reader, ot: dict, where: str):
    """(vertices, faces, kind, default name, path) of ``mesh = "<file>"``."""
    rel = r.string(ot["mesh"], f"{where}.mesh")
    mesh_path = r.path.parent / rel
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
    return verts, faces, mesh_path.suffix.lower()[1:], mesh_path.stem, mesh_path


#: Memory a render takes per triangle at its peak (the loader's arrays, the upload and the
#: accelerator's build; measured on the subdivided bunny: 1.37 KB at 278K triangles, 1.08 KB
#: at 1.1M): what a mesh that would not fit is refused with (``_check_size``).
BYTES_PER_TRIANGLE = 1100
#: The most triangles one scene may have: 12 packed floats each in one Dr.Jit array (fewer
#: than 2^32 entries).
MAX_TRIANGLES = (2 ** 32 - 1) // 12


def _physical_memory() -> int | None:
    try:
        return int(os.sysconf("SC_PAGE_SIZE")) * int(os.sysconf("SC_PHYS_PAGES"))
    except (AttributeError, OSError, ValueError):
        return None


def _check_size(r: _Reader, field: str, count: int, what: str) -> None:
    """Refuse, before anything is built, an object of ``count`` triangles that cannot be
    rendered: more than ``MAX_TRIANGLES``, or an estimated peak (``BYTES_PER_TRIANGLE``)
    beyond this machine's physical memory."""
    need = count * BYTES_PER_TRIANGLE
    mem = _physical_memory()
    if count > MAX_TRIANGLES or (mem is not None and need > mem):
        have = f"this machine has {mem / 1e9:.3g} GB" if mem is not None else "too much"
        limit = f"; at most {MAX_TRIANGLES:,} triangles fit the device arrays" \
            if count > MAX_TRIANGLES else ""
        raise r.error(field, f"{what} makes {count:.3g} triangles, about {need / 1e9:.3g} GB "
                             f"to render ({have}{limit}); use a smaller value")


def _object_shape(r: _Reader, ot: dict, where: str):
    """(vertices, faces, kind) of ``shape = "<name>"`` with its parameters."""
    kind = r.string(ot["shape"], f"{where}.shape", tuple(shapes.SHAPES))
    params = {}
    for key in shapes.SHAPE_PARAMETERS[kind]:
        if key in ot:
            params[key] = r.integer(ot[key], f"{where}.{key}",
                                    lo=1 if key == "frequency" else 0)
    if len(params) > 1:
        raise r.error(f"{where}.{'.'.join(params)}", "give either 'frequency' or "
                                                  "'subdivisions', not both")
    for key, value in params.items():            # sphere: 20·f² triangles, f = 2^s
        f = value if key == "frequency" else 2 ** min(value, 64)
        _check_size(r, f"{where}.{key}", 20 * f * f, f"{key} = {value}")
    verts, faces = shapes.make_shape(kind, **params)
    return verts, faces, kind


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


def _sin_cos_degrees(deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(sin, cos)`` of angles in degrees, exact (0, ±1) at multiples of 90°: ``cos(90°)``
    computed from ``np.radians`` is 6e-17, which tilts a wall rotated upright by a float64
    ulp, so the floor it stands on pokes through it and a float64 shadow ray from the
    floor's edge is blocked by the wall. Other angles are ``np.sin``/``np.cos`` as given."""
    deg = np.asarray(deg, np.float64)
    s, c = np.sin(np.radians(deg)), np.cos(np.radians(deg))
    quarter = np.mod(deg, 360.0) / 90.0
    right = quarter == np.round(quarter)
    k = np.mod(np.round(quarter), 4).astype(int)
    s = np.where(right, np.array([0.0, 1.0, 0.0, -1.0])[k], s)
    c = np.where(right, np.array([1.0, 0.0, -1.0, 0.0])[k], c)
    return s, c


def _rotation(deg: np.ndarray) -> np.ndarray:
    """Rotation by deg[0] about x, then deg[1] about y, then deg[2] about z
    (``_sin_cos_degrees``: right angles exact)."""
    (sx, sy, sz), (cx, cy, cz) = _sin_cos_degrees(deg)
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


def _cached(cache, kind: str, inputs: tuple, fn) -> dict:
    """``fn()`` (a dict of arrays and an optional JSON-able ``meta``), through ``cache``
    (None: ``fn()``) under a key of ``inputs`` and the loader's code."""
    if cache is None:
        return fn()
    key = content_key(kind, *inputs, code_version(("scene/loader.py", "scene/subdivide.py")))
    got = cache.get(kind, key)
    if got is not None:
        return got
    out = fn()
    cache.put(kind, key, {k: v for k, v in out.items() if k != "meta"}, out.get("meta"))
    return out


def _part_arrays(world: np.ndarray, faces: np.ndarray) -> dict:
    """One object's arrays: ``keep`` (faces with area), ``faces`` (those faces over the
    compacted vertices), ``verts`` and their averaged ``normals`` (float32's positions) and
    ``normals64`` (float64's).

    The zero-area test is made on the positions each precision renders (float64
    arithmetic): a triangle is dropped only where it has no area in either, so a float64
    render far from the origin keeps the small triangles that float32's grid collapses
    (those never hit in float32: ``triangle.pack`` stores them degenerate). The vertex
    normals of each precision come from its own face normals (a face without area in one
    precision does not count there). The work is elementwise over spans of faces and
    vertices on ``renderer.parallel``'s threads, both precisions side by side; the normal
    sums keep their order (``_vertex_normals``)."""
    world = np.asarray(world, np.float64)
    V = world.shape[0]
    fc = _columns(faces, np.intp)
    w64 = _columns(world, np.float64)
    w32 = [None] * 3

    def rounded(k):                  # the float32 grid's positions, in float64
        w32[k] = w64[k].astype(np.float32).astype(np.float64)
    parallel.run(rounded, range(3))
    (cross32, area32), (cross, area2) = parallel.together(
        lambda: _face_cross_columns(w32, fc), lambda: _face_cross_columns(w64, fc))
    keep = (area32 > 0) | (area2 > 0)
    if not keep.all():
        fc = [c[keep] for c in fc]
        cross32, cross = [c[keep] for c in cross32], [c[keep] for c in cross]
        area32, area2 = area32[keep], area2[keep]
    if len(fc[0]) == 0:
        return {"keep": keep, "faces": np.asarray(faces)[keep], "verts": world[:0],
                "normals": world[:0], "normals64": world[:0]}
    used, faces_c = _compact_columns(fc, V)              # compact to used vertices
    if used is None:
        verts, vc = world.copy(), w64
    else:
        verts = np.take(world, used, axis=0, mode="clip")
        vc = parallel.run(lambda k: np.take(w64[k], used, mode="clip"), range(3))
    faces = np.empty((len(faces_c[0]), 3), np.int64)

    def put_faces(lo, hi):
        for c in range(3):
            faces[lo:hi, c] = faces_c[c][lo:hi]
    parallel.for_spans(len(faces), put_faces)
    F = len(faces)
    weights = [[np.empty(3 * F) for _ in range(3)] for _ in range(2)]
    weld, _, _ = parallel.together(lambda: _weld_columns(vc),
                                   lambda: _unit_columns(cross32, area32, weights[0]),
                                   lambda: _unit_columns(cross, area2, weights[1]))
    normals, normals64 = _normals_columns(weld, faces_c, weights)
    return {"keep": keep, "faces": faces, "verts": verts, "normals": normals,
            "normals64": normals64}


def _columns(a: np.ndarray, dtype) -> list[np.ndarray]:
    """The three columns of ``a`` (N, 3) as contiguous ``dtype`` arrays (threads)."""
    return parallel.run(lambda k: np.ascontiguousarray(a[:, k], dtype), range(3))


def _face_cross_columns(pc: list, fc: list) -> tuple[list, np.ndarray]:
    """The cross products ``(p1 - p0) x (p2 - p0)`` of faces ``fc`` (three index columns)
    over points ``pc`` (three float64 columns), as three columns, and their lengths
    (``np.linalg.norm``'s ``sqrt((x² + y²) + z²)``). Each component is ``np.cross``'s
    ``a1 b2 - a2 b1`` (cyclic) of the edges ``a = p1 - p0``, ``b = p2 - p0``: the same
    operations in the same order, so the same bits; elementwise over spans of faces."""
    F = len(fc[0])
    cross = [np.empty(F) for _ in range(3)]
    length = np.empty(F)

    def span(lo, hi):
        f0, f1, f2 = (c[lo:hi] for c in fc)
        a, b = [], []
        for k in range(3):
            p0 = np.take(pc[k], f0, mode="clip")
            a.append(np.take(pc[k], f1, mode="clip") - p0)
            b.append(np.subtract(np.take(pc[k], f2, mode="clip"), p0, out=p0))
        tmp = np.empty(hi - lo)
        for k in range(3):
            i, j = (k + 1) % 3, (k + 2) % 3
            out = cross[k][lo:hi]
            np.multiply(a[i], b[j], out=out)
            np.subtract(out, np.multiply(a[j], b[i], out=tmp), out=out)
        sq = np.multiply(cross[0][lo:hi], cross[0][lo:hi], out=length[lo:hi])
        sq += np.multiply(cross[1][lo:hi], cross[1][lo:hi], out=tmp)
        sq += np.multiply(cross[2][lo:hi], cross[2][lo:hi], out=tmp)
        np.sqrt(sq, out=sq)
    parallel.for_spans(F, span)
    return cross, length


def _compact(faces: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(faces, return_inverse=True)`` for indices below ``n``: the used indices
    in ascending order and the faces (F, 3) renumbered over them, by a mask (no sort)."""
    used, cols = _compact_columns(_columns(faces, np.intp), n)
    used = np.arange(n) if used is None else used
    return used, np.stack(cols, axis=1).astype(np.int64, copy=False)


def _compact_columns(fc: list, n: int) -> tuple[np.ndarray | None, list]:
    """``_compact`` of faces as three index columns: the used indices (None: all ``n``
    are used) and the renumbered columns (int64; the same columns where all are used)."""
    mask = np.zeros(n, bool)
    parallel.run(lambda c: mask.__setitem__(c, True), fc)   # every write stores True
    if mask.all():
        return None, [c.astype(np.int64, copy=False) for c in fc]
    used = np.flatnonzero(mask)
    remap = np.cumsum(mask, dtype=np.int64) - 1
    return used, parallel.run(lambda c: np.take(remap, c, mode="clip"), fc)


def _mix(x: np.ndarray) -> np.ndarray:
    """SplitMix64's finaliser of uint64 ``x`` (every input bit moves every output bit)."""
    x = x ^ (x >> np.uint64(30))
    x *= np.uint64(0xBF58476D1CE4E5B9)
    x ^= x >> np.uint64(27)
    x *= np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def _row_hash(bits: np.ndarray) -> np.ndarray:
    """A uint64 hash of each row of ``bits`` (V, 3) uint64."""
    return _mix(_mix(_mix(bits[:, 0]) ^ bits[:, 1]) ^ bits[:, 2])


def _weld(verts: np.ndarray) -> np.ndarray:
    """A label per row of ``verts`` (V, 3), equal for equal rows (floats compared as
    numbers: -0.0 equals 0.0) and different otherwise: the grouping of
    ``np.unique(verts, axis=0, return_inverse=True)``, from a hash of each row's bits (one
    1-D sort instead of a row sort), checked row by row; a collision, or a NaN, falls back
    to the row sort's labels (``_weld_columns``). A hash grouping labels each row with the
    index of one row of its group: most rows are their own, so the normal sums over the
    labels read and write memory nearly in vertex order (any labelling of the same
    grouping gives the same sums)."""
    return _weld_columns(_columns(np.asarray(verts), np.float64))


def _weld_columns(vc: list) -> np.ndarray:
    """``_weld`` of the rows whose three float64 columns are ``vc``; the hashes and the
    check elementwise over spans of rows."""
    V = len(vc[0])
    h = np.empty(V, np.uint64)
    bits = np.empty((V, 3), np.uint64)

    def hash_span(lo, hi):
        for k in range(3):
            np.add(vc[k][lo:hi], 0.0, out=bits[lo:hi, k].view(np.float64))  # -0.0 -> 0.0
        h[lo:hi] = _row_hash(bits[lo:hi])
    parallel.for_spans(V, hash_span)
    _, label = parallel.unique_inverse(h)
    rep = np.empty(int(label.max()) + 1 if label.size else 0, np.int64)
    rep[label] = np.arange(label.size)
    src = np.take(rep, label, mode="clip")
    same = parallel.run(lambda s: all(np.array_equal(
        np.take(vc[k], src[s[0]:s[1]], mode="clip"), vc[k][s[0]:s[1]]) for k in range(3)),
        parallel.spans(V))
    if all(same):
        return src
    rows = np.stack(vc, axis=1)
    return np.unique(rows, axis=0, return_inverse=True)[1].reshape(-1)


def _assemble(r: _Reader, parts: list[_Part], a: Assembly, cache=None) -> Scene:
    """The flat scene arrays: zero-area triangles dropped, vertices compacted per object,
    vertex normals averaged; the rest of the scene from ``a``."""
    cameras, settings, lights, materials = a.cameras, a.settings, a.lights, a.materials
    ambient, sources = a.ambient, a.sources
    objects, all_v, all_n, all_n64, all_f, f_mat, f_obj = [], [], [], [], [], [], []
    v_base = f_base = 0
    for k, part in enumerate(parts):
        name, kind, mat, smooth, world, faces = (part.name, part.kind, part.material,
                                                 part.smooth, part.world, part.faces)
        where = f"objects[{k}]"
        arr = _cached(cache, "object", (world, faces), lambda w=world, f=faces:
                      _part_arrays(w, f))
        keep = arr["keep"]
        dropped = int((~keep).sum())
        if dropped:
            warnings.warn(f"{r.path}: {where} ({name!r}): dropped {dropped} zero-area "
                          f"triangle{'s' if dropped > 1 else ''} of {len(faces)}", stacklevel=3)
        if len(arr["faces"]) == 0:
            raise r.error(where, f"object {name!r} has no triangles left (all zero-area or "
                                 "empty mesh)")
        faces, verts = arr["faces"], arr["verts"]
        normals, normals64 = arr["normals"], arr["normals64"]
        objects.append(ObjectInfo(name=name, kind=kind, material=mat, first_face=f_base,
                                  face_count=len(faces), first_vertex=v_base,
                                  vertex_count=len(verts), smooth=smooth))
        all_v.append(verts)
        all_n.append(normals)
        all_n64.append(normals64)
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
        vertices64=cat(all_v, (0, 3), np.float64),
        normals64=cat(all_n64, (0, 3), np.float64),
        faces=cat(all_f, (0, 3), np.int32),
        face_material=cat(f_mat, (0,), np.int32),
        face_object=cat(f_obj, (0,), np.int32),
        ambient=ambient, name=r.path.stem, path=r.path, source_files=sources,
    )


def _unit_rows(v: np.ndarray, length: np.ndarray) -> np.ndarray:
    """Rows of ``v`` divided by ``length`` (0 where the length is 0)."""
    return np.stack(_unit_columns([v[:, k] for k in range(3)], length), axis=1)


def _unit_columns(vc: list, length: np.ndarray, out: list | None = None
                  ) -> list[np.ndarray]:
    """``_unit_rows`` of the rows whose three columns are ``vc``, as three columns
    (elementwise over spans): written into the first ``len(length)`` values of the three
    float64 arrays ``out`` where given (returned)."""
    n = len(length)
    out = [np.empty(n) for _ in range(3)] if out is None else out

    def span(lo, hi):
        ln = length[lo:hi]
        flat = ~(ln > 0)
        safe = np.where(flat, 1.0, ln)
        for k in range(3):
            np.divide(vc[k][lo:hi], safe, out=out[k][lo:hi])
            out[k][lo:hi][flat] = 0.0
    parallel.for_spans(n, span)
    return out


def _vertex_normals(verts: np.ndarray, faces: np.ndarray, face_n: np.ndarray,
                    weld: np.ndarray | None = None) -> np.ndarray:
    """Normalised plain average of the unit normals of the faces sharing each vertex;
    coincident positions are welded for the average (smooth across mesh seams; ``weld``:
    ``_weld(verts)``, computed when None). Each vertex's sum adds its faces' normals in the
    order corner 0 of every face, then corner 1, then corner 2 (``np.bincount`` adds in
    input order; ``_normals_columns``)."""
    weld = _weld(verts) if weld is None else weld
    face_n = np.asarray(face_n, np.float64)
    weights = [np.empty(3 * face_n.shape[0]) for _ in range(3)]
    for k in range(3):
        weights[k][:face_n.shape[0]] = face_n[:, k]
    return _normals_columns(np.asarray(weld), _columns(faces, np.intp), [weights])[0]


def _normals_columns(weld: np.ndarray, fc: list, weights: list) -> list[np.ndarray]:
    """``_vertex_normals`` for each face normal set of ``weights`` over the faces ``fc``
    (three index columns), the vertices labelled by ``weld``: one (V, 3) float64 array per
    set. A set is three float64 arrays (3 F,), one per component, whose first F values are
    the unit face normals; the other two copies (``np.tile``'s) are made here. The sums are
    ``np.bincount`` passes (one per set and component, side by side, each adding in the
    order corner 0 of every face, then corner 1, then corner 2); the gathers and divisions
    are elementwise over spans."""
    F = len(fc[0])
    L = int(weld.max()) + 1
    idx = np.empty(3 * F, np.intp)

    def gather_span(lo, hi):
        for c in range(3):
            np.take(weld, fc[c][lo:hi], out=idx[c * F + lo:c * F + hi], mode="clip")
        for w in (w for ws in weights for w in ws):
            w[F + lo:F + hi] = w[lo:hi]
            w[2 * F + lo:2 * F + hi] = w[lo:hi]
    parallel.for_spans(F, gather_span)
    jobs = [(s, k) for s in range(len(weights)) for k in range(3)]
    sums = parallel.run(lambda j: np.bincount(idx, weights=weights[j[0]][j[1]], minlength=L),
                        jobs)
    return parallel.run(lambda s: _normalised(weld, sums[3 * s:3 * s + 3], fc,
                                              [w[:F] for w in weights[s]]),
                        range(len(weights)))


def _normalised(weld: np.ndarray, acc: list, fc: list, unit: list) -> np.ndarray:
    """The (V, 3) unit vertex normals from the welded sums ``acc`` (three columns over the
    weld labels) of the face normals ``unit`` (three columns over the faces ``fc``); a
    vertex whose sum cancels takes the normal of one adjacent face. Elementwise over spans
    of vertices (``np.linalg.norm``'s ``sqrt((x² + y²) + z²)``, then one division)."""
    V = len(weld)
    n = [np.empty(V) for _ in range(3)]
    length = np.empty(V)

    def length_span(lo, hi):
        w = weld[lo:hi]
        for k in range(3):
            np.take(acc[k], w, out=n[k][lo:hi], mode="clip")
        sq = np.multiply(n[0][lo:hi], n[0][lo:hi], out=length[lo:hi])
        sq += n[1][lo:hi] * n[1][lo:hi]
        sq += n[2][lo:hi] * n[2][lo:hi]
        np.sqrt(sq, out=sq)
    parallel.for_spans(V, length_span)
    bad = length < 1e-12             # opposing faces cancel: one adjacent face's normal
    if bad.any():
        length[bad] = 1.0
    res = np.empty((V, 3))

    def divide_span(lo, hi):
        for k in range(3):
            np.divide(n[k][lo:hi], length[lo:hi], out=res[lo:hi, k])
    parallel.for_spans(V, divide_span)
    if bad.any():
        fallback = np.zeros((V, 3))
        fallback[np.stack(fc, axis=1).reshape(-1)] = np.repeat(np.stack(unit, axis=1), 3,
                                                               axis=0)
        res[bad] = fallback[bad]
    return res
