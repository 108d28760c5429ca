"""The scene: one host-side (numpy) description that both renderers consume.

``Scene`` is the single source of truth: ``renderer`` uploads it to Dr.Jit arrays, and
``reference`` translates it into a Mitsuba scene. The meaning of every field (camera model,
shading modes, specular weights) is fixed in ``docs/MODEL.md``.

Geometry is flattened: all objects' triangles in one array, each object owning a contiguous
range of faces and of vertices (vertices are never shared between objects, so per-object
vertex normals are well defined).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

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
