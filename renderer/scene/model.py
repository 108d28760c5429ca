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

SHADING_MODES = ("classic", "physical")
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
                      where: str = "settings") -> None:
    """The one host-side check of the render settings; a None argument is not checked.

    spp: an integer k*k >= 1 (k x k strata); with ``exact`` true it must be 1.
    max_depth: an integer in 0..MAX_DEPTH_LIMIT.
    shading: one of SHADING_MODES.
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
    ray_epsilon: None (default): scale-free ray offsets from each hit point's own rounding
        error (docs/MODEL.md, "Ray offsets"); a number: explicit override, an absolute
        offset of ``ray_epsilon`` × the scene's bounding-box diagonal.
    seed: seed of the stratified jitter in converged mode.
    """

    max_depth: int = 5
    spp: int = 1
    exact: bool = True
    shading: str = "classic"
    background: np.ndarray = field(default_factory=lambda: np.zeros(3))
    min_weight: float = 0.01
    ray_epsilon: float | None = None
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

    # ---- derived facts -----------------------------------------------------------------------
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
                       size: tuple[int, int] | None = None, seed: int | None = None
                       ) -> "Scene":
        """The same scene with the given overrides (None keeps the scene's value), checked
        by ``validate_settings``: the entry point of the command line and the harnesses.

        spp: samples per pixel (k*k); ``spp`` without ``exact`` sets ``exact = spp == 1``.
        exact: one ray per pixel centre (then spp must be 1).
        max_depth: 0..MAX_DEPTH_LIMIT. seed: converged-mode jitter seed (>= 0).
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
        scene = replace(self, settings=replace(s, **changes))
        if size is not None:
            w, h = size
            if int(w) != w or int(h) != h or w < 1 or h < 1:
                raise SceneError(f"size: expected positive integers (width, height), "
                                 f"got {size!r}", field="size")
            scene = scene.with_size(w, h)
        return scene

    def with_size(self, width: int, height: int | None = None) -> "Scene":
        """The same scene with every view resized to ``width`` x ``height`` pixels
        (``height`` defaults to ``width``); the field of view is kept."""
        height = width if height is None else height
        return replace(self, cameras=[replace(c, width=int(width), height=int(height))
                                      for c in self.cameras])

