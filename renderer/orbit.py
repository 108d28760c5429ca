"""The interactive camera, made reproducible: frames on a circle around a view's target.

``orbit_cameras(cam, n)`` places ``n`` cameras evenly on the circle that keeps ``cam``'s
height above its target (measured along ``cam.up``) and its horizontal distance to the
target; camera 0 is ``cam`` itself. ``render_orbit`` renders them with ONE frozen frame
function (``Renderer(..., freeze=True)``): the scene is uploaded and the accelerator built
once, the first frame traces and records the kernels, and every later frame passes only a
new ``CameraArrays`` (opaque device arrays) and replays the recording, so it costs kernel
launches and the read-back of the image. ``write_gif`` stores the frames as an animated GIF
(atomically, through ``renderer.outputs``).
"""
from __future__ import annotations

import importlib.util
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import drjit as dr
import numpy as np

from .film import srgb_encode
from .outputs import atomic_path
from .render import Renderer, RenderOptions, render_options
from .scene import Camera, Scene

# Playback rate of the animations the CLI writes: 25 fps is 4 GIF ticks of 10 ms a frame.
PLAYBACK_FPS = 25


@dataclass
class OrbitResult:
    """frames: ``n`` images (H, W, 3), uint8 sRGB when rendered with ``srgb=True``, else
    float32 linear RGB; cameras: the ``n`` orbit cameras.
    first_frame_ms: wall time of frame 0 (tracing, recording and compiling the kernels,
    running them, reading the image back). frozen_frame_ms: wall time of each later frame
    (replaying the recording with a new camera, reading the image back);
    frozen_frame_ms_median: their median; fps: frames per second over frames 1..n-1
    (``(n - 1) / sum(frozen_frame_ms)``; ``nan`` when ``n == 1``).
    recordings: how many times the frozen function recorded (1 when every replay hit).
    """

    frames: list
    cameras: list
    fps: float
    first_frame_ms: float
    frozen_frame_ms_median: float
    frozen_frame_ms: list = field(default_factory=list)
    recordings: int = 0
    stats: dict = field(default_factory=dict)


def orbit_cameras(cam: Camera, n: int) -> list[Camera]:
    """``n`` cameras on the circle around ``cam.target`` through ``cam.position``.

    The circle's axis is ``cam.up`` through the target: every camera keeps the original
    height ``h = (position - target) · û`` and horizontal radius ``r`` (``û`` = unit up),
    and camera ``k`` sits at angle ``2πk/n`` (counter-clockwise seen from above, i.e. a
    right-handed turn about ``û``). All cameras look at the target with the same up, field
    of view and size; camera 0 is ``cam`` unchanged (positions are float64 (3,)).
    """
    if int(n) != n or n < 1:
        raise ValueError(f"orbit: n: expected an integer >= 1, got {n!r}")
    n = int(n)
    target = np.asarray(cam.target, np.float64)
    up = np.asarray(cam.up, np.float64)
    if np.linalg.norm(up) == 0:
        raise ValueError(f"orbit: camera {cam.name!r}: up is the zero vector")
    u = up / np.linalg.norm(up)
    offset = np.asarray(cam.position, np.float64) - target
    height = float(offset @ u)
    radial = offset - height * u
    radius = float(np.linalg.norm(radial))
    if radius <= 1e-9 * max(float(np.linalg.norm(offset)), 1e-30):
        raise ValueError(f"orbit: camera {cam.name!r}: the camera sits on the up axis through "
                         "its target, so there is no circle to orbit on")
    e1 = radial / radius
    e2 = np.cross(u, e1)        # e1 → e2 is a right-handed quarter turn about u
    cams = [cam]
    for k in range(1, n):
        a = 2.0 * np.pi * k / n
        pos = target + height * u + radius * (np.cos(a) * e1 + np.sin(a) * e2)
        cams.append(replace(cam, position=pos, target=target.copy(), up=up.copy(),
                            name=f"{cam.name}_orbit{k:03d}"))
    return cams


def render_orbit(scene: Scene, n: int, options: RenderOptions | None = None, *,
                 view: int = 0, srgb: bool = True, **settings) -> OrbitResult:
    """Render ``n`` frames orbiting ``scene.cameras[view]`` (see ``orbit_cameras``) with one
    frozen frame function.

    ``options`` and ``settings`` are those of ``render`` (``freeze`` is always on);
    ``srgb`` returns uint8 (H, W, 3) sRGB frames (what an animation stores), else float32
    (H, W, 3) linear RGB. Timing covers the frame function and the read-back of its image,
    not the sRGB encoding or the scene upload.
    """
    cam = scene.cameras[view]
    cams = orbit_cameras(cam, n)
    r = Renderer(scene, render_options(options, **settings), freeze=True)
    frames, times = [], []
    for c in cams:
        ca = r.camera(c)          # upload the camera before the clock starts
        dr.sync_thread()
        t0 = time.perf_counter()
        img = np.asarray(r.frame(ca, c.width, c.height).numpy(), dtype=np.float32)
        times.append(time.perf_counter() - t0)
        frames.append(srgb_encode(img) if srgb else img)
    frozen_ms = [s * 1e3 for s in times[1:]]
    fps = (len(frozen_ms) / (sum(frozen_ms) / 1e3)) if frozen_ms else float("nan")
    stats = dict(r.arrays.accel.stats())
    stats.update(backend=r.t.backend, precision=r.t.precision, spp=r.spp, exact=r.exact,
                 upload_seconds=r.upload_seconds, width=cam.width, height=cam.height,
                 view=cam.name, effects=str(r.effects), frames=n)
    return OrbitResult(frames=frames, cameras=cams, fps=fps, first_frame_ms=times[0] * 1e3,
                       frozen_frame_ms_median=float(np.median(frozen_ms)) if frozen_ms
                       else float("nan"),
                       frozen_frame_ms=frozen_ms, recordings=int(r.frame_fn.n_recordings),
                       stats=stats)


def _as_uint8(frames) -> list[np.ndarray]:
    out = []
    for i, f in enumerate(frames):
        f = np.asarray(f)
        if f.ndim != 3 or f.shape[2] != 3:
            raise ValueError(f"frames[{i}]: expected an image of shape (H, W, 3), got {f.shape}")
        if f.shape != np.shape(frames[0]):
            raise ValueError(f"frames[{i}]: shape {f.shape} differs from frames[0]'s "
                             f"{np.shape(frames[0])}")
        out.append(f if f.dtype == np.uint8 else srgb_encode(f))
    if not out:
        raise ValueError("frames: expected at least one frame")
    return out


def write_gif(path, frames, *, fps: float = PLAYBACK_FPS, overwrite: bool = False) -> Path:
    """Write ``frames`` (uint8 sRGB, or float linear RGB, each (H, W, 3)) as an animated GIF
    that loops forever, shown at ``fps`` frames per second (GIF delays are whole 10 ms
    ticks, so the rate is rounded to the nearest tick). Refuses to replace an existing file
    unless ``overwrite=True``. Note: the GIF writer merges consecutive identical frames."""
    if not fps > 0:
        raise ValueError(f"write_gif: fps: expected > 0, got {fps!r}")
    import imageio.v3 as iio
    imgs = _as_uint8(frames)
    path = Path(path)
    with atomic_path(path, overwrite=overwrite, flag="overwrite=True") as tmp:
        iio.imwrite(tmp, np.stack(imgs), extension=".gif", duration=1000.0 / fps, loop=0)
    return path


def mp4_available() -> bool:
    """Whether imageio can write MP4 here (needs the imageio-ffmpeg or PyAV plugin)."""
    return any(importlib.util.find_spec(m) is not None for m in ("imageio_ffmpeg", "av"))


def write_mp4(path, frames, *, fps: float = PLAYBACK_FPS, overwrite: bool = False) -> Path:
    """Write ``frames`` as an H.264 MP4 through imageio's ffmpeg plugin (only when
    ``mp4_available()``; raises RuntimeError otherwise). Same overwrite rule as
    ``write_gif``."""
    if not mp4_available():
        raise RuntimeError("write_mp4: no ffmpeg plugin for imageio (install imageio-ffmpeg)")
    import imageio.v3 as iio
    imgs = _as_uint8(frames)
    path = Path(path)
    with atomic_path(path, overwrite=overwrite, flag="overwrite=True") as tmp:
        iio.imwrite(tmp, np.stack(imgs), extension=".mp4", fps=fps)
    return path
