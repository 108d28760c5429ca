"""The public entry point: ``render(scene, ...)`` and the reusable ``Renderer``.

``Renderer`` uploads the scene once (accelerator, materials, lights) and exposes
``frame(camera_arrays)``: a pure function of device arrays (``SceneArrays`` +
``CameraArrays``) returning the image tensor, wrapped in ``dr.freeze`` when asked so that a
benchmark can re-run it with a moved camera without re-tracing.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import drjit as dr
import numpy as np

from .accel import DEFAULT_ROUTINE, build_accelerator, default_accel
from .camera import BLOCKS, CameraArrays, RayTile, camera_arrays, primary_rays, ray_keys
from .device import Types, array3, types
from .effects import EffectSet
from .film import develop
from .integrator import trace
from .lights import upload_lights
from .scene import Camera, Scene, check_ranges, validate_image_size
from .shade import SceneArrays, TraceOptions, upload_materials

#: Camera rays per band of ``Renderer.render`` by backend: a band of the LLVM backend takes
#: well under a second for simple scenes on one CPU core, so progress moves and a stop
#: request is honoured between bands; CUDA bands are larger (launch overhead).
TILE_SAMPLES = {"llvm": 1 << 18, "cuda": 1 << 22}


@dataclass
class RenderResult:
    """image: float32 (H, W, 3) linear RGB; effects: the traced EffectSet; seconds: wall
    time of the frame (rays → image on the host, excluding upload/build); stats: accelerator
    and run facts (backend, precision, spp, exact, build_seconds, ...)."""

    image: np.ndarray
    effects: EffectSet
    seconds: float
    stats: dict = field(default_factory=dict)


def make_frame_fn(t: Types, effects: EffectSet, options: TraceOptions, *, spp: int,
                  exact: bool, seed: int):
    """The per-frame work as a function of device arrays only:
    ``frame(cam: CameraArrays, arrays: SceneArrays, width, height) -> TensorXf (H, W, 3)``.

    It closes over host constants only (types, effect set, options), never over a
    ``Renderer``, so wrapping it in ``dr.freeze`` creates no reference cycle (a cycle lets
    Python's collector free device memory in the middle of a later recording, which Dr.Jit
    cannot record). The rays go in the backend's pixel-block order (``camera.BLOCKS``).
    """
    block = BLOCKS[t.backend]

    def frame(cam: CameraArrays, arrays: SceneArrays, width: int, height: int,
              first_row=None, rows: int | None = None):
        tile = RayTile(first_row=first_row, rows=rows, block=block)
        o, d = primary_rays(cam, width, height, t, spp=spp, exact=exact, seed=seed, tile=tile)
        key = ray_keys(width, height, t, spp=spp, seed=seed, tile=tile) \
            if effects.soft_shadows else None
        radiance = trace(arrays, o, d, t, effects, options, key)
        return develop(radiance, width, height if rows is None else rows, spp, t, block)
    return frame


@dataclass
class RenderOptions:
    """How ``Renderer`` (and ``render``, ``orbit.render_orbit``) renders a scene.

    backend: "auto" | "cuda" | "llvm" (default "auto").
    precision: "float32" | "float64" (default "float32").
    accel: a key of ``renderer.accel.ACCELERATORS`` (default None: the backend's,
        ``renderer.accel.default_accel``: the binary BVH on CUDA, the 4-wide BVH on LLVM;
        every accelerator gives the same pixels).
    intersection: triangle routine (default ``renderer.accel.DEFAULT_ROUTINE``).
    effects: EffectSet to trace (default: derived from the scene).
    spp, exact: override ``scene.settings`` as ``Scene.with_overrides`` does (``spp``
        alone sets ``exact = spp == 1``; ``exact`` alone takes spp 1 or the scene's).
    shadow_samples: override ``settings.shadow_samples`` (shadow rays per light with
        extent, k*k).
    freeze: wrap the frame function in ``dr.freeze`` (default False).
    tie_break, tie_window, tie_slack: which hit wins among hits as near as the nearest
        within the distances ``tie_window`` (along the ray) and ``tie_slack`` (off an edge)
        (``renderer.accel.query.tie_probe``): "lowest" original face index (default; the
        renderer's) or "other" (a probe: the golden tests render both and excuse a pixel
        only where they differ).
    """

    backend: str = "auto"
    precision: str = "float32"
    accel: str | None = None
    intersection: str = DEFAULT_ROUTINE
    effects: EffectSet | None = None
    spp: int | None = None
    exact: bool | None = None
    freeze: bool = False
    tie_break: str = "lowest"
    tie_window: float = 0.0
    tie_slack: float = 0.0
    shadow_samples: int | None = None
    build: str | None = None
    cache: object = None
    frames: int | None = None
    build_progress: object = None


def render_options(options: RenderOptions | None = None, **settings) -> RenderOptions:
    """``options`` (default ``RenderOptions()``) with the fields named in ``settings``
    replaced (an unknown name is a TypeError)."""
    return replace(options or RenderOptions(), **settings)


class Renderer:
    """A scene uploaded for repeated frames: ``Renderer(scene, options, **settings)``, the
    ``RenderOptions`` ``options`` with any of its fields given as keywords
    (``Renderer(scene, backend="llvm", accel="bvh")``).

    The settings are checked by ``validate_settings`` (SceneError, a ValueError, names the
    field). ``arrays`` (SceneArrays) holds the uploaded scene, ``frame_fn`` the (frozen)
    per-frame function of ``make_frame_fn``; ``frame(camera(cam), W, H)`` runs it.
    """

    def __init__(self, scene: Scene, options: RenderOptions | None = None, **settings):
        opts = render_options(options, **settings)
        backend, precision, accel = opts.backend, opts.precision, opts.accel
        effects, spp, exact = opts.effects, opts.spp, opts.exact
        if not scene.cameras:
            raise ValueError(f"scene {scene.name!r}: cameras: at least one camera is required")
        scene = scene.with_overrides(spp=spp, exact=exact, shadow_samples=opts.shadow_samples)
        s = scene.settings
        self.scene = scene
        self.t: Types = types(backend, precision)
        check_ranges(scene, precision)
        self.exact = s.exact
        self.spp = s.spp
        self.effects = EffectSet.from_scene(scene) if effects is None else effects
        if self.effects.physical != (s.shading == "physical"):
            raise ValueError("effects.physical: does not match settings.shading "
                             f"{s.shading!r} of scene {scene.name!r}")
        t = self.t
        accel = default_accel(t.backend) if accel is None else accel
        t0 = time.perf_counter()
        acc = build_accelerator(accel, scene, t, intersection=opts.intersection,
                                tie_break=opts.tie_break, tie_window=opts.tie_window,
                                tie_slack=opts.tie_slack,
                                build=s.build if opts.build is None else opts.build,
                                cache=opts.cache, frames=opts.frames,
                                progress=opts.build_progress)
        self.arrays = SceneArrays(
            accel=acc, materials=upload_materials(scene, t), lights=upload_lights(scene, t),
            ambient=array3(t, scene.ambient), background=array3(t, s.background))
        dr.make_opaque(self.arrays.ambient, self.arrays.background)
        self.upload_seconds = time.perf_counter() - t0
        self.options = TraceOptions(n_lights=len(scene.lights), max_depth=int(s.max_depth),
                                    min_weight=float(s.min_weight), eps=scene.ray_offset,
                                    spawn=s.spawn, terminator=s.terminator,
                                    shadow_samples=int(s.shadow_samples))
        self.accel_name = accel
        frame_fn = make_frame_fn(t, self.effects, self.options, spp=self.spp, exact=self.exact,
                                 seed=int(s.seed))
        self.frame_fn = dr.freeze(frame_fn) if opts.freeze else frame_fn

    def camera(self, cam: Camera | int = 0) -> CameraArrays:
        """Device arrays of ``cam`` (a Camera, or an index into ``scene.cameras``)."""
        if isinstance(cam, int):
            cam = self.scene.cameras[cam]
        return camera_arrays(cam, self.t)

    def frame(self, cam: CameraArrays, width: int, height: int):
        """Render one frame: TensorXf (H, W, 3). The kernels are launched (``dr.eval``) but
        not waited for; ``dr.sync_thread()`` or ``.numpy()`` waits."""
        img = self.frame_fn(cam, self.arrays, width, height)
        dr.eval(img)
        return img

    def bands(self, view: int = 0, tile_samples: int | None = None) -> list[tuple[int, int]]:
        """The bands of rows ``render(view)`` launches: ``[(first_row, rows), ...]``, each
        at most ``tile_samples`` camera rays (at least one row); one band when the whole
        image fits (``tile_samples`` None: ``TILE_SAMPLES`` of the backend; 0: one band)."""
        cam = self.scene.cameras[view]
        limit = TILE_SAMPLES[self.t.backend] if tile_samples is None else int(tile_samples)
        per_row = cam.width * self.spp
        if limit <= 0 or per_row * cam.height <= limit:
            return [(0, cam.height)]
        rows = max(1, limit // per_row)
        return [(y, min(rows, cam.height - y)) for y in range(0, cam.height, rows)]

    def render(self, view: int = 0, *, tile_samples: int | None = None, progress=None,
               stop=None) -> RenderResult:
        """Render ``scene.cameras[view]`` → RenderResult (image float32 (H, W, 3)).

        tile_samples: camera rays per band (``bands``); the image is the same bit for bit
            whatever the banding. progress: called as ``progress(rows_done, height)`` after
            each band. stop: called before each band; when it returns True the render ends
            with ``KeyboardInterrupt`` (how the CLI's Ctrl-C reaches a render running in
            its worker thread).
        """
        cam = self.scene.cameras[view]
        validate_image_size(cam.width, cam.height, self.spp, f"views[{view}]")
        ca = self.camera(cam)
        bands = self.bands(view, tile_samples)
        dr.sync_thread()
        t0 = time.perf_counter()
        parts = []
        for y0, rows in bands:
            if stop is not None and stop():
                raise KeyboardInterrupt
            if len(bands) == 1:
                img = self.frame(ca, cam.width, cam.height)
            else:
                img = self.frame_fn(ca, self.arrays, cam.width, cam.height,
                                    dr.opaque(self.t.UInt32, y0), rows)
                dr.eval(img)
            parts.append(np.asarray(img.numpy(), dtype=np.float32))
            if progress is not None:
                progress(y0 + rows, cam.height)
        out = parts[0] if len(parts) == 1 else np.concatenate(parts, axis=0)
        seconds = time.perf_counter() - t0
        stats = dict(self.arrays.accel.stats())
        stats.update(backend=self.t.backend, precision=self.t.precision, spp=self.spp,
                     exact=self.exact, upload_seconds=self.upload_seconds,
                     width=cam.width, height=cam.height, view=cam.name,
                     effects=str(self.effects), bands=len(bands))
        return RenderResult(image=out, effects=self.effects, seconds=seconds, stats=stats)


def render(scene: Scene, options: RenderOptions | None = None, *, view: int = 0,
           **settings) -> RenderResult:
    """Render ``scene`` from ``scene.cameras[view]``.

    Returns a RenderResult whose ``image`` is float32 (H, W, 3) linear RGB (row 0 = top).
    ``options`` and ``settings`` are those of ``Renderer`` (the tie probe's included; the
    backend's accelerator, ``renderer.accel.default_accel``, unless given); ``effects``
    defaults to ``EffectSet.from_scene(scene)``; ``spp``/``exact`` default to
    ``scene.settings``.
    """
    return Renderer(scene, options, **settings).render(view)
