"""The scene model: one host-side (numpy) description that both renderers consume.

``Scene`` is the single source of truth: ``renderer`` uploads it to Dr.Jit arrays, and
``reference`` translates it into a Mitsuba scene. The meaning of every field (camera model,
shading modes, specular weights) is fixed in ``docs/MODEL.md``. Scene files are read by
``renderer.scene.loader``; this module never imports it.

Geometry is flattened: all objects' triangles in one array, each object owning a contiguous
range of faces and of vertices (vertices are never shared between objects, so per-object
vertex normals are well defined).

``validate_settings`` is the one host-side check of the render settings (spp, exact,
max_depth, shading); the loader, ``Scene.with_overrides``, the renderer and the command line
all call it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ..cache_key import content_key

SHADING_MODES = ("classic", "physical")
#: Rules for where secondary and shadow rays start (docs/MODEL.md, "Ray offsets"):
#: "scale-free" (the default: each hit point's own rounding error) and "mitsuba" (Mitsuba 3's
#: ``spawn_ray`` / ``spawn_ray_to``, so a comparison with a Mitsuba golden traces the same
#: rays; ``whitted check`` renders with the rule its golden records).
SPAWN_RULES = ("scale-free", "mitsuba")
#: How the BVH is built (``[render] build``; ``renderer.accel.builders``): "device" is the
#: device builder of choice (``builders.DEVICE_BUILD``), "ploc" and "radix" name one.
TREE_BUILDS = ("sah", "device", "ploc", "radix", "auto")
#: Shadow-terminator treatments of smooth (interpolated-normal) faces (docs/MODEL.md,
#: "Ray offsets"): "none" (the default, as Mitsuba 3: shadow rays leave the flat triangle)
#: and "hanika" (Hanika 2021, "Hacking the shadow terminator": a shadow ray starts from the
#: hit point lifted onto the curved surface the vertex normals imply).
TERMINATOR_FIXES = ("none", "hanika")
FALLOFFS = ("none", "inverse_square")
COMBINATIONS = ("constant", "fresnel")

#: Deepest supported Whitted tree: the integrator keeps one stack slot per level, each local
#: array <= 128 bytes (16 entries of float64) because of the LLVM local-array issue
#: (drjit #532).
MAX_DEPTH_LIMIT = 16


class SceneError(ValueError):
    """A scene file or scene description is malformed.

    The message always names the field (and the file, for a scene file) and says what was
    expected; ``field`` holds the dotted field name (e.g. ``"settings.spp"``) when one
    field is at fault, else None.
    """

    def __init__(self, message: str, *, field: str | None = None):
        super().__init__(message)
        self.field = field


def validate_settings(*, spp: int | None = None, exact: bool | None = None,
                      max_depth: int | None = None, shading: str | None = None,
                      spawn: str | None = None, shadow_samples: int | None = None,
                      where: str = "settings") -> None:
    """The one host-side check of the render settings; a None argument is not checked.

    spp: an integer k*k >= 1 (k x k strata); with ``exact`` true it must be 1.
    max_depth: an integer in 0..MAX_DEPTH_LIMIT.
    shading: one of SHADING_MODES.
    spawn: one of SPAWN_RULES.
    shadow_samples: a perfect square k*k >= 1 (shadow rays per light with extent).
    where: prefix of the field names in errors (``"settings"`` gives ``"settings.spp"``;
        the loader passes ``"<file>: render"``, the CLI may pass its own).
    Raises SceneError whose message starts with the field and whose ``field`` names it.
    """
    def fail(name: str, message: str):
        f = f"{where}.{name}"
        raise SceneError(f"{f}: {message}", field=f)

    if spp is not None:
        if isinstance(spp, bool) or int(spp) != spp or spp < 1 \
                or math.isqrt(int(spp)) ** 2 != spp:
            fail("spp", f"expected a perfect square >= 1 (k*k strata), got {spp}")
        if exact and spp != 1:
            fail("exact", f"exact = true renders one ray per pixel centre; it cannot be "
                          f"combined with spp = {spp}")
    if max_depth is not None:
        if isinstance(max_depth, bool) or int(max_depth) != max_depth \
                or not 0 <= max_depth <= MAX_DEPTH_LIMIT:
            fail("max_depth", f"expected an integer in 0..{MAX_DEPTH_LIMIT}, got {max_depth}")
    if shading is not None and shading not in SHADING_MODES:
        fail("shading", f"expected one of {', '.join(map(repr, SHADING_MODES))}, "
                        f"got {shading!r}")
    if spawn is not None and spawn not in SPAWN_RULES:
        fail("spawn", f"expected one of {', '.join(map(repr, SPAWN_RULES))}, got {spawn!r}")
    if shadow_samples is not None:
        ss = shadow_samples
        if isinstance(ss, bool) or int(ss) != ss or ss < 1 or math.isqrt(int(ss)) ** 2 != ss:
            fail("shadow_samples", f"expected a perfect square >= 1 (k*k strata), got {ss}")


#: Dr.Jit arrays hold fewer than 2^32 entries (UInt32 sizes and indices).
ARRAY_LIMIT = 2 ** 32 - 1


def validate_image_size(width: int, height: int, spp: int, where: str = "settings") -> None:
    """A frame of ``width`` x ``height`` pixels at ``spp`` samples must fit Dr.Jit's array
    limit: ``width·height·spp`` rays and ``3·width·height`` film entries, each at most
    ``ARRAY_LIMIT`` (2^32 - 1). Raises SceneError naming ``where`` (the view)."""
    rays, film = int(width) * int(height) * int(spp), 3 * int(width) * int(height)
    if rays > ARRAY_LIMIT or film > ARRAY_LIMIT:
        f = f"{where}.resolution"
        raise SceneError(f"{f}: {width} x {height} pixels at spp = {spp} needs {rays} rays "
                         f"and {film} film entries; Dr.Jit arrays hold at most 2^32 - 1 "
                         f"entries (use fewer pixels or samples, or render in tiles)",
                         field=f)


def precision_limits(double: bool) -> tuple[float, float]:
    """``(coordinate_limit, intensity_limit)`` of the precision: the largest coordinate
    magnitude whose squared distances stay finite (``sqrt(max / 16)``: any two points
    within it are less than ``2·limit`` apart per axis, ``|Δ|² <= 12 limit² < max``) and
    the largest light intensity whose square stays finite. The intensity limit is float32's
    ``sqrt(max)`` in both precisions: the image (``RenderResult.image``, EXR) is float32, so
    a float64 render of a brighter light would overflow there."""
    fmax = float(np.finfo(np.float64 if double else np.float32).max)
    return math.sqrt(fmax / 16.0), math.sqrt(float(np.finfo(np.float32).max))


def size_limit(double: bool) -> float:
    """The smallest extent a scene may have in the precision: ``cbrt(tiny / eps)`` (float32
    4.6e-11, float64 1.0e-97). The intersection routines multiply three lengths of the
    scene (a triple product, an edge function times a distance); below this their product
    is subnormal and loses the precision's relative accuracy (at 1e-18 in float32, 10 % of
    the ray/triangle answers were wrong)."""
    f = np.finfo(np.float64 if double else np.float32)
    return float(np.cbrt(float(f.tiny) / float(f.eps)))


def used_vertices(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The rows of ``vertices`` (V, 3) that ``faces`` (F, 3) index, each once, in vertex
    order (their min and max are those over the faces' corners)."""
    used = np.zeros(vertices.shape[0], bool)
    used[faces.reshape(-1)] = True
    return vertices if used.all() else vertices[used]


def object_reach(scene: "Scene", double: bool) -> list:
    """Per object, the largest coordinate magnitude of its vertices in the precision
    (``positions(double)``), a float, or None for an object without vertices."""
    V = scene.positions(double)
    out = []
    for obj in scene.objects:
        v = V[obj.first_vertex:obj.first_vertex + obj.vertex_count]
        out.append(float(np.max(np.abs(v))) if v.size else None)
    return out


def extent_of(vertices: np.ndarray, faces: np.ndarray) -> float:
    """The largest side of the bounding box of the vertices ``faces`` use."""
    used = used_vertices(vertices, faces)
    return float(np.max(used.max(axis=0) - used.min(axis=0)))


def _bounds(vertices: np.ndarray, faces: np.ndarray) -> list[list]:
    """``[lo, hi]`` (lists of floats: a cache entry stores them) of the used vertices."""
    used = used_vertices(vertices, faces)
    return [used.min(axis=0).astype(np.float64).tolist(),
            used.max(axis=0).astype(np.float64).tolist()]


#: The fields of a ``Scene`` whose values ``Scene.facts`` describes (by identity).
FACT_FIELDS = ("vertices", "normals", "faces", "face_material", "face_object", "vertices64",
               "normals64", "objects")


def _facts_hold(scene: "Scene") -> bool:
    f = scene.facts
    return bool(f) and all(getattr(scene, k) is v for k, v in zip(FACT_FIELDS, f["_of"]))


def scene_fact(scene: "Scene", name: str, compute):
    """``scene.facts[name]`` where ``scene.facts`` describes ``scene``'s own arrays (the
    very objects of ``FACT_FIELDS``: a copy with other arrays computes), else
    ``compute()``, remembered in those facts where they hold."""
    if not _facts_hold(scene):
        return compute()
    f = scene.facts
    if name not in f:
        value = compute()
        if isinstance(value, np.ndarray):
            value.flags.writeable = False
        f[name] = value
    return f[name]


def with_facts(scene: "Scene", facts: dict | None = None) -> "Scene":
    """``scene`` with its arrays read-only and ``facts`` (a dict of ``scene_fact`` values,
    None: none yet) describing them: the values derived from the arrays are then computed
    once (``scene_fact``), or come with the facts."""
    for k in FACT_FIELDS[:-1]:
        a = getattr(scene, k)
        if isinstance(a, np.ndarray):
            a.flags.writeable = False
    facts = dict(facts or {})
    facts["_of"] = tuple(getattr(scene, k) for k in FACT_FIELDS)
    return replace(scene, facts=facts)


def triangles_digest(scene: "Scene") -> str:
    """The content hash of ``scene``'s triangles (float32 vertices, faces): the key the
    accelerators' trees are stored under (``accel.builders.triangles_key``)."""
    return scene_fact(scene, "triangles", lambda: content_key(
        np.asarray(scene.vertices, np.float32), np.asarray(scene.faces)))


def any_smooth(scene: "Scene") -> bool:
    """Whether any face of ``scene`` interpolates vertex normals."""
    return scene_fact(scene, "smooth", lambda: bool(scene.face_smooth.any()))


def layout_inputs(scene: "Scene", double: bool) -> str:
    """The content hash of the scene arrays an accelerator's layout holds beyond its
    triangles: the face materials and smooth flags, the vertex normals of the precision
    (where any face is smooth) and the float64 vertices (``double``, where the scene has
    them)."""
    def compute():
        parts = [np.asarray(scene.face_material), np.asarray(scene.face_smooth)]
        if any_smooth(scene):
            parts.append(np.asarray(scene.normals_of(double)))
        if double and scene.vertices64 is not None:
            parts.append(np.asarray(scene.vertices64))
        return content_key("layout inputs", *parts)
    return scene_fact(scene, f"layout inputs {'float64' if double else 'float32'}", compute)


def vertex_reach(scene: "Scene") -> float:
    """The largest coordinate magnitude of the vertices (float64 where the scene has them;
    0 without triangles)."""
    if not scene.face_count:
        return 0.0
    V = scene.vertices64 if scene.vertices64 is not None else scene.vertices
    return scene_fact(scene, "vertex reach", lambda: float(np.max(np.abs(V))))


def used_materials(scene: "Scene") -> list[int]:
    """The material indices the faces use, ascending."""
    return scene_fact(scene, "materials", lambda: sorted(
        set(int(m) for m in np.unique(scene.face_material))) if scene.face_count else [])


#: The ``scene_fact`` values ``store_facts`` computes (JSON-able: a cache entry holds them).
STORED_FACTS = ("triangles", "smooth", "layout inputs float32", "vertex reach", "materials",
                "bounds", "object_reach float32", "extent float32")


def stored_facts(scene: "Scene") -> dict:
    """``STORED_FACTS`` of ``scene`` (which must carry facts: ``with_facts``), computed
    where not yet known: what a cache entry of the scene stores beside its arrays."""
    triangles_digest(scene)
    layout_inputs(scene, False)
    vertex_reach(scene)
    used_materials(scene)
    scene.bounds()
    scene_fact(scene, "object_reach float32", lambda: object_reach(scene, False))
    if scene.face_count:
        scene_fact(scene, "extent float32", lambda: extent_of(scene.vertices, scene.faces))
    return {k: scene.facts[k] for k in STORED_FACTS if k in scene.facts}


def check_ranges(scene: "Scene", precision: str = "float32") -> None:
    """Numerical guard before upload: every vertex, camera and light position within the
    precision's coordinate limit and every light intensity within its intensity limit
    (``precision_limits``; float32: 4.6e18 and 1.8e19; float64: 3.4e153 and 1.8e19), and
    a scene with triangles at least ``size_limit`` across (float32: 4.6e-11). Raises
    SceneError naming the file and the field (a float32 1e39 intensity would otherwise
    become inf and NaN pixels)."""
    double = precision == "float64"
    c_lim, i_lim = precision_limits(double)
    src = f"{scene.path}: " if scene.path is not None else f"scene {scene.name!r}: "
    hint = "" if double else "; render with --precision float64 or rescale the scene"

    def fail(field: str, what: str, value: float, lim: float):
        kind = "float32 image" if what == "intensity" else precision
        tail = "; rescale the light intensities" if what == "intensity" else hint
        raise SceneError(f"{src}{field}: {what} {value:.6g} exceeds the {kind} limit "
                         f"{lim:.3g} (its square overflows){tail}", field=field)

    for i, light in enumerate(scene.lights):
        if np.max(np.abs(light.position)) > c_lim:
            fail(f"lights[{i}].position", "coordinate", np.max(np.abs(light.position)), c_lim)
        if np.max(light.intensity) > i_lim:
            fail(f"lights[{i}].intensity", "intensity", np.max(light.intensity), i_lim)
        size = max([float(light.radius)] + [float(np.max(np.abs(e)))
                                             for e in (light.edge_u, light.edge_v)
                                             if e is not None])
        if size > c_lim:
            fail(f"lights[{i}] size", "coordinate", size, c_lim)
    for i, cam in enumerate(scene.cameras):
        if np.max(np.abs(cam.position)) > c_lim:
            fail(f"views[{i}].position", "coordinate", np.max(np.abs(cam.position)), c_lim)
    for k, (obj, mag) in enumerate(zip(scene.objects, scene_fact(
            scene, f"object_reach {precision}", lambda: object_reach(scene, double)))):
        if mag is not None and mag > c_lim:
            fail(f"objects[{k}] ({obj.name!r}) vertices", "coordinate", mag, c_lim)
    if scene.face_count:
        extent = scene_fact(scene, f"extent {precision}", lambda: extent_of(
            scene.positions(double), scene.faces))
        s_lim = size_limit(double)
        if extent < s_lim:
            f = "objects vertices"
            raise SceneError(f"{src}{f}: the scene is {extent:.3g} across, under the "
                             f"{precision} limit {s_lim:.3g} (products of its lengths "
                             f"underflow){hint}", field=f)


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


#: Light shapes (docs/MODEL.md, "Lights with extent"): a point, a sphere of radius > 0, a
#: rectangle (parallelogram) of edges ``edge_u``, ``edge_v``.
LIGHT_SHAPES = ("point", "sphere", "rectangle")


@dataclass(frozen=True)
class PointLight:
    """A light (docs/MODEL.md): a point light unless ``shape`` says otherwise.

    position: float64 (3,), the point, or the centre of a sphere or rectangle light;
    intensity: float64 (3,) RGB, >= 0 (W/sr in physical shading; for a rectangle along its
    normal); falloff: "none" | "inverse_square".
    shape: one of LIGHT_SHAPES; radius: the sphere's radius (> 0 for "sphere", 0 else);
    edge_u, edge_v: float64 (3,) full edges of a rectangle (None else), its normal
    ``normalize(edge_u × edge_v)``; two_sided: a rectangle emits on both sides.
    """

    position: np.ndarray
    intensity: np.ndarray
    falloff: str = "inverse_square"
    name: str = ""
    shape: str = "point"
    radius: float = 0.0
    edge_u: np.ndarray | None = None
    edge_v: np.ndarray | None = None
    two_sided: bool = False

    def __post_init__(self):
        if self.shape not in LIGHT_SHAPES:
            raise SceneError(f"light {self.name!r}: shape: expected one of "
                             f"{', '.join(map(repr, LIGHT_SHAPES))}, got {self.shape!r}",
                             field="shape")
        if self.shape == "sphere" and not self.radius > 0:
            raise SceneError(f"light {self.name!r}: radius: a sphere light needs radius > 0 "
                             f"(radius 0 is a point light), got {self.radius}", field="radius")
        if self.shape == "rectangle":
            if self.edge_u is None or self.edge_v is None or not np.linalg.norm(
                    np.cross(self.edge_u, self.edge_v)) > 0:
                raise SceneError(f"light {self.name!r}: edge_u, edge_v: a rectangle light "
                                 "needs two non-parallel edges", field="edge_u")

    @property
    def extent(self) -> bool:
        """The light has extent (a sphere or a rectangle): its shadows are soft."""
        return self.shape != "point"

    @property
    def area(self) -> float:
        """Emitting area of one side (0 for a point light)."""
        if self.shape == "sphere":
            return 4.0 * math.pi * self.radius ** 2
        if self.shape == "rectangle":
            return float(np.linalg.norm(np.cross(self.edge_u, self.edge_v)))
        return 0.0

    @property
    def radiance(self) -> np.ndarray:
        """Emitted radiance ``L_e`` of a light with extent (``I / (π r²)`` for a sphere,
        ``I / A`` for a rectangle; docs/MODEL.md)."""
        if self.shape == "sphere":
            return self.intensity / (math.pi * self.radius ** 2)
        return self.intensity / self.area


#: The light record's plain name (every light is a ``PointLight`` with a ``shape``).
Light = PointLight


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
    ray_epsilon: None (default): scale-free ray offsets from each hit point's own rounding
        error (docs/MODEL.md, "Ray offsets"); a number: explicit override, an absolute
        offset of ``ray_epsilon`` × the scene's bounding-box diagonal.
    spawn: one of SPAWN_RULES, the offset rule when ``ray_epsilon`` is None ("scale-free",
        the default; "mitsuba": Mitsuba 3's own rule, for comparisons with its goldens).
    seed: seed of the stratified jitter in converged mode (and of the shadow samples).
    shadow_samples: shadow rays per light with extent per shading point, a perfect square
        ``k²`` (k × k strata; docs/MODEL.md, "Lights with extent"); point lights take one.
    terminator: one of TERMINATOR_FIXES, the shadow-terminator treatment of smooth faces
        ("none", the default; "hanika": shadow rays from the lifted hit point). Set in code
        (``Scene.with_settings``); scene files do not read it.
    build: one of TREE_BUILDS, how the BVH is built ("auto", the default:
        ``renderer.accel.builders.resolve_build``).
    """

    max_depth: int = 5
    spp: int = 1
    exact: bool = True
    shading: str = "classic"
    background: np.ndarray = field(default_factory=lambda: np.zeros(3))
    min_weight: float = 0.01
    ray_epsilon: float | None = None
    seed: int = 0
    spawn: str = "scale-free"
    terminator: str = "none"
    shadow_samples: int = 1
    build: str = "auto"

    def __post_init__(self):
        validate_settings(spawn=self.spawn, shadow_samples=self.shadow_samples)
        if self.terminator not in TERMINATOR_FIXES:
            raise SceneError(f"settings.terminator: expected one of "
                             f"{', '.join(map(repr, TERMINATOR_FIXES))}, got "
                             f"{self.terminator!r}", field="settings.terminator")
        if self.spawn != "scale-free" and self.ray_epsilon is not None:
            raise SceneError(f"settings.spawn: {self.spawn!r} and ray_epsilon (an absolute "
                             "offset) exclude each other", field="settings.spawn")


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
class Assembly:
    """What a scene holds besides its geometry, as a reader hands it to the assembly of its
    parts (``loader._assemble``, ``parts.assemble``): ``cameras``, ``settings``,
    ``lights``, ``materials``, ``ambient`` (RGB) and ``sources`` (the files read)."""

    cameras: list
    settings: Settings
    lights: list
    materials: list
    ambient: np.ndarray
    sources: list


@dataclass
class Scene:
    """Everything needed to render, on the host.

    vertices: float32 (V, 3) world-space positions (what float32 renders, the Mitsuba
        reference and the BVH's binning read).
    normals: float32 (V, 3) unit vertex normals (average of adjacent face normals within
        the object); present for every vertex, used only for smooth objects.
    vertices64, normals64: float64 (V, 3) the positions before rounding to float32 and the
        normals averaged from their faces (the loader keeps them, so a float64 render sees
        the exact transformed geometry), or None
        (then ``positions(True)`` is ``vertices`` widened). Read both through
        ``positions(double)`` / ``normals_of(double)``.
    faces: int32 (F, 3) global vertex indices; no triangle without area in both precisions
        (dropped at load; one with area in float64 only never hits in float32).
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
    vertices64: np.ndarray | None = None
    normals64: np.ndarray | None = None
    name: str = "scene"
    path: Path | None = None
    # Files the scene was built from (scene file + meshes), for golden-image hashes.
    source_files: list[Path] = field(default_factory=list)
    # The file's [check] table (what the regression gate checks, thresholds): evaluation's
    # data, ignored by the renderer.
    check: dict = field(default_factory=dict)
    # How the file was read beyond its bytes: ``load_scene``'s ``defines`` and
    # ``approximate`` where given (keyword arguments, so the file can be read again the same
    # way: ``load_scene(path, shading=..., **scene.read)``); part of a golden's key.
    read: dict = field(default_factory=dict)
    # Values derived from the arrays (``scene_fact``): given by the loader with a cache
    # (stored in its scene entry), for these very arrays, which it makes read-only.
    facts: dict | None = field(default=None, compare=False, repr=False)

    def __post_init__(self):
        # A copy made with ``replace(scene, vertices=...)`` (moved, scaled) keeps the old
        # float64 arrays: they no longer round to the new float32 ones, so drop them (float64
        # renders then widen the float32 positions) rather than render stale geometry.
        # The float64 normals go with the float64 vertices: they are averaged from the
        # float64 face normals, so they need not round to the float32 ones (far from the
        # origin a face can have area in float64 only).
        v64 = self.vertices64
        if v64 is not None and not _facts_hold(self) and (
                v64.shape != np.shape(self.vertices) or not np.array_equal(
                v64.astype(np.float32), np.asarray(self.vertices, np.float32))):
            self.vertices64 = None
        if self.vertices64 is None or (self.normals64 is not None
                                       and self.normals64.shape != np.shape(self.normals)):
            self.normals64 = None

    # ---- derived facts -----------------------------------------------------------------------
    @property
    def face_count(self) -> int:
        return int(self.faces.shape[0])

    @property
    def face_smooth(self) -> np.ndarray:
        """bool (F,): whether each face interpolates vertex normals."""
        def compute():
            smooth = np.array([o.smooth for o in self.objects], dtype=bool)
            return smooth[self.face_object] if len(smooth) else np.zeros(0, bool)
        return scene_fact(self, "face_smooth", compute)

    def positions(self, double: bool = False) -> np.ndarray:
        """Vertex positions of the precision in use: float64 (V, 3) ``vertices64`` for a
        float64 render (``double``), else the float32 ``vertices``."""
        if double and self.vertices64 is not None:
            return self.vertices64
        return self.vertices.astype(np.float64) if double else self.vertices

    def normals_of(self, double: bool = False) -> np.ndarray:
        """Vertex normals of the precision in use (as ``positions``)."""
        if double and self.normals64 is not None:
            return self.normals64
        return self.normals.astype(np.float64) if double else self.normals

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) float64 (3,) of all vertices used by faces."""
        if self.face_count == 0:
            return np.zeros(3), np.zeros(3)
        lo, hi = scene_fact(self, "bounds", lambda: _bounds(self.vertices, self.faces))
        return np.array(lo, np.float64), np.array(hi, np.float64)

    @property
    def diagonal(self) -> float:
        lo, hi = self.bounds()
        return float(np.linalg.norm(hi - lo))

    @property
    def ray_offset(self) -> float | None:
        """The explicit absolute ray-origin offset ε = ``ray_epsilon`` × diagonal, or None
        when the scene uses scale-free offsets (the default; docs/MODEL.md, "Ray
        offsets")."""
        if self.settings.ray_epsilon is None:
            return None
        return self.settings.ray_epsilon * max(self.diagonal, 1e-30)

    def with_camera(self, index: int) -> "Scene":
        """The same scene with ``cameras[index]`` moved to the front."""
        cams = list(self.cameras)
        cams.insert(0, cams.pop(index))
        return replace(self, cameras=cams)

    def with_settings(self, **changes) -> "Scene":
        """The same scene with ``settings`` fields replaced (checked by
        ``validate_settings``)."""
        settings = replace(self.settings, **changes)
        validate_settings(spp=settings.spp, exact=settings.exact,
                          max_depth=settings.max_depth, shading=settings.shading)
        return replace(self, settings=settings)

    def with_overrides(self, *, spp: int | None = None, exact: bool | None = None,
                       max_depth: int | None = None, shading: str | None = None,
                       size: tuple[int, int] | None = None, seed: int | None = None,
                       shadow_samples: int | None = None) -> "Scene":
        """The same scene with the given overrides (None keeps the scene's value), checked
        by ``validate_settings``: the entry point of the command line and the harnesses.

        spp: samples per pixel (k*k); ``spp`` without ``exact`` sets ``exact = spp == 1``.
        exact: one ray per pixel centre (then spp must be 1).
        max_depth: 0..MAX_DEPTH_LIMIT. seed: converged-mode jitter seed (>= 0).
        shadow_samples: shadow rays per light with extent (k*k).
        size: (width, height) of every view (``with_size``).
        shading: must equal the scene's mode for a scene read from a file (the file's
            ``[physical]`` table and light falloffs are applied when it is read: use
            ``load_scene(path, shading=...)``); a scene built in code switches mode, and
            physical shading then needs every light to fall off as ``inverse_square``.
        Raises SceneError naming the field.
        """
        s = self.settings
        if exact is None:
            exact = s.exact if spp is None else spp == 1
        if spp is None:
            spp = 1 if exact else s.spp
        max_depth = s.max_depth if max_depth is None else max_depth
        validate_settings(spp=spp, exact=exact, max_depth=max_depth,
                          shading=s.shading if shading is None else shading)
        if seed is not None and (isinstance(seed, bool) or int(seed) != seed or seed < 0):
            raise SceneError(f"settings.seed: expected an integer >= 0, got {seed}",
                             field="settings.seed")
        if shading is not None and shading != s.shading:
            if self.path is not None:
                raise SceneError(
                    f"settings.shading: {self.path} was read with {s.shading!r} shading; "
                    f"the mode is chosen when the file is read: load_scene(path, "
                    f"shading={shading!r})", field="settings.shading")
            bad = [light.name for light in self.lights if light.falloff != "inverse_square"]
            if shading == "physical" and bad:
                raise SceneError(f"settings.shading: physical shading needs "
                                 f"'inverse_square' point lights; light {bad[0]!r} has "
                                 f"falloff 'none'", field="settings.shading")
        changes = dict(spp=int(spp), exact=bool(exact), max_depth=int(max_depth))
        if shading is not None:
            changes["shading"] = shading
        if seed is not None:
            changes["seed"] = int(seed)
        if shadow_samples is not None:
            validate_settings(shadow_samples=shadow_samples)
            changes["shadow_samples"] = int(shadow_samples)
        scene = replace(self, settings=replace(s, **changes))
        if size is not None:
            w, h = size
            if int(w) != w or int(h) != h or w < 1 or h < 1:
                raise SceneError(f"size: expected positive integers (width, height), "
                                 f"got {size!r}", field="size")
            scene = scene.with_size(w, h)
        for i, cam in enumerate(scene.cameras):
            validate_image_size(cam.width, cam.height, scene.settings.spp,
                                "size" if size is not None else f"views[{i}]")
        return scene

    def with_size(self, width: int, height: int | None = None) -> "Scene":
        """The same scene with every view resized to ``width`` x ``height`` pixels
        (``height`` defaults to ``width``); the field of view is kept."""
        height = width if height is None else height
        return replace(self, cameras=[replace(c, width=int(width), height=int(height))
                                      for c in self.cameras])

