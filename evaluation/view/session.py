"""The viewer's state and work, apart from any transport: camera, settings, frames, the
side-by-side comparison with Mitsuba.

``ViewSession`` holds one scene and the camera the user moves (``CameraState``). It keeps a
``renderer.render.Renderer`` per combination of settings (render mode, effects,
accelerator, triangle routine, precision, spawn rule, spp, shading), built once, and beside
it one ``dr.freeze`` function of the Renderer's frame function followed by the 8-bit sRGB
encoding (``srgb8_frame``: on the device, so the read-back is a quarter of the float
image's bytes); it records once per image size and then only replays with a new
``CameraArrays``, so moving the camera never re-traces Python. ``frame(moving)`` renders at
``moving_size`` while the camera moves and at ``size`` when it is still, and encodes the
image as JPEG (``Frame``). ``needs_compile`` says beforehand
whether the next frame records (a new setting or size), so the caller can say so.

``side_by_side()`` renders the current camera in exact mode with the golden's spawn rule
(``reference.golden.GOLDEN_SPAWN``) with ours and with the reference harness, and judges it
with the exact rule (``evaluation.gate.verdict.judge``, the tie mask from a second render with
the other tie-break, as ``whitted compare`` does): ours | Mitsuba | a heat map of the
per-pixel relative error. The render mode's depth goes to both renderers, so "primary only"
compares primary shading. Mitsuba is imported only then; without it the call raises
``MitsubaMissing`` with one line and the session goes on.
"""
from __future__ import annotations

import io
import time
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import drjit as dr
import numpy as np

from renderer.accel import ACCELERATORS, DEFAULT_ROUTINE, ROUTINES, default_accel
from renderer.camera import camera_frame
from renderer.device import PRECISIONS
from renderer.effects import FLAGS, EffectSet
from renderer.film import srgb_encode, write_exr, write_png
from renderer.outputs import write_text
from renderer.render import Renderer
from renderer.scene import SHADING_MODES, SPAWN_RULES, Camera, Scene, load_scene

#: Render modes of the menu: key -> (label, max_depth; None: the scene's own).
RENDER_MODES = {
    "primary": ("primary only", 0),
    "depth1": ("reflection depth 1", 1),
    "depth2": ("reflection depth 2", 2),
    "depth3": ("reflection depth 3", 3),
    "full": ("full Whitted (the scene's depth)", None),
}
#: Samples per pixel of the menu (1: exact mode, one ray per pixel centre).
SPP_CHOICES = (1, 4, 16)
#: Keys that move the camera: W/S forward/back, A/D left/right, Q/E down/up (along the
#: camera's up); the arrows turn it (left/right about the up axis, up/down tilt).
MOVE_KEYS = {"w": (0, 0, 1), "s": (0, 0, -1), "a": (-1, 0, 0), "d": (1, 0, 0),
             "q": (0, -1, 0), "e": (0, 1, 0)}
TURN_KEYS = {"arrowleft": (1, 0), "arrowright": (-1, 0), "arrowup": (0, 1), "arrowdown": (0, -1)}
#: A key press moves the camera by this fraction of the scene's bounding-box diagonal and
#: turns it by TURN_DEGREES; a mouse drag turns by DRAG_DEGREES a pixel.
STEP_FRACTION = 0.02
TURN_DEGREES = 3.0
DRAG_DEGREES = 0.3
JPEG_QUALITY = 88


def srgb8_frame(frame_fn, t):
    """``dr.freeze`` of ``frame_fn`` (``renderer.render.make_frame_fn``'s function) followed
    by ``film.srgb_encode``'s mapping on the device: ``f(cam, arrays, width, height)`` ->
    UInt8 of ``height·width·3`` sRGB values, row-major (within one level of
    ``srgb_encode`` of the float image: float32 rounding)."""
    UInt8 = getattr(dr, t.backend).UInt8

    def frame(cam, arrays, width: int, height: int):
        v = frame_fn(cam, arrays, width, height).array
        v = dr.clip(dr.select(dr.isnan(v), 0.0, v), 0.0, 1.0)
        y = dr.select(v <= 0.0031308, 12.92 * v, 1.055 * dr.power(v, 1 / 2.4) - 0.055)
        return UInt8(dr.round(y * 255.0))
    return dr.freeze(frame)


class MitsubaMissing(RuntimeError):
    """The reference harness cannot run here (Mitsuba is not installed)."""


@dataclass
class ViewSettings:
    """What the menus choose. mode: a key of RENDER_MODES; effects_off: effects forced off
    (``EffectSet.without``); accel: a key of ``ACCELERATORS`` (None: the backend's);
    intersection: a key of ``ROUTINES``; precision; spawn: one of ``SPAWN_RULES``; spp: one
    of SPP_CHOICES; shading: one of ``SHADING_MODES``."""

    mode: str = "full"
    effects_off: tuple = ()
    accel: str | None = None
    intersection: str = DEFAULT_ROUTINE
    precision: str = PRECISIONS[0]
    spawn: str = "scale-free"
    spp: int = 1
    shading: str = "classic"

    def key(self) -> tuple:
        return (self.mode, tuple(sorted(self.effects_off)), self.accel, self.intersection,
                self.precision, self.spawn, self.spp, self.shading)


@dataclass
class CameraState:
    """The moving camera: position, target, up (float64 (3,)), fov_y in degrees."""

    position: np.ndarray
    target: np.ndarray
    up: np.ndarray
    fov_y: float

    @classmethod
    def of(cls, cam: Camera) -> "CameraState":
        return cls(np.array(cam.position, np.float64), np.array(cam.target, np.float64),
                   np.array(cam.up, np.float64), float(cam.fov_y))

    def camera(self, width: int, height: int, name: str = "viewer") -> Camera:
        return Camera(position=self.position.copy(), target=self.target.copy(),
                      up=self.up.copy(), fov_y=self.fov_y, width=int(width),
                      height=int(height), name=name)

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(right, up, forward) unit vectors of the camera (``camera.camera_frame``)."""
        fr = camera_frame(self.camera(1, 1))
        return fr["right"], fr["up"], fr["forward"]

    def as_dict(self) -> dict:
        return {"position": self.position.tolist(), "target": self.target.tolist(),
                "up": self.up.tolist(), "fov_y": self.fov_y}


def _rotate(v: np.ndarray, axis: np.ndarray, degrees: float) -> np.ndarray:
    """``v`` turned by ``degrees`` about the unit ``axis`` (Rodrigues)."""
    a = np.radians(degrees)
    k = axis / np.linalg.norm(axis)
    return v * np.cos(a) + np.cross(k, v) * np.sin(a) + k * (k @ v) * (1 - np.cos(a))


@dataclass
class Frame:
    """One encoded frame: jpeg (bytes), width, height; render_ms (the frozen frame with
    its sRGB encoding, and the read-back), encode_ms (JPEG); rays (camera rays traced);
    effects (the set's text); moving (rendered at the moving size); recorded (this frame
    recorded kernels); image: uint8 (H, W, 3) sRGB."""

    jpeg: bytes
    width: int
    height: int
    render_ms: float
    encode_ms: float
    rays: int
    effects: str
    moving: bool
    recorded: bool
    image: np.ndarray = field(repr=False, default=None)

    @property
    def rays_per_s(self) -> float:
        return self.rays / max(self.render_ms / 1e3, 1e-9)


@dataclass
class SideBySide:
    """The comparison of the current view: jpeg of ours | Mitsuba | heat map; status
    (PASS / WARN / FAIL / SIZE), reason, excused and failing pixel counts, seconds of
    Mitsuba's render, and a note when ours is not the scene's truth (effects forced)."""

    jpeg: bytes
    status: str
    reason: str
    excused: int
    failing: int
    pixels: int
    mitsuba_seconds: float
    note: str = ""


def encode_jpeg(image_u8: np.ndarray, quality: int = JPEG_QUALITY) -> bytes:
    from PIL import Image
    buf = io.BytesIO()
    Image.fromarray(image_u8).save(buf, format="JPEG", quality=quality)
    return buf.getvalue()


def heat_map(rel: np.ndarray) -> np.ndarray:
    """uint8 (H, W, 3) of a relative error ``rel`` (H, W) on a log scale from 1e-6 (black)
    through red (1e-3) to yellow and white (>= 1e-1)."""
    x = np.clip((np.log10(np.maximum(rel, 1e-12)) + 6.0) / 5.0, 0.0, 1.0)
    r = np.clip(x * 2.0, 0, 1)
    g = np.clip(x * 2.0 - 1.0, 0, 1)
    b = np.clip(x * 4.0 - 3.0, 0, 1)
    return np.round(np.stack([r, g, b], -1) * 255).astype(np.uint8)


class ViewSession:
    """One scene in the viewer (see the module's docstring).

    scene_path: the scene file (re-read when the shading mode changes); backend: as
    ``Renderer``; size: (width, height) when the camera is still (default: view 0's);
    moving_size: while it moves (default: ``size`` halved); settings: the first
    ``ViewSettings`` (default: the scene's spawn rule and shading)."""

    def __init__(self, scene_path, *, backend: str = "auto", size=None, moving_size=None,
                 settings: ViewSettings | None = None, scene: Scene | None = None):
        self.scene_path = Path(scene_path)
        self.backend = backend
        self.base = scene if scene is not None else load_scene(self.scene_path)
        s = self.base.settings
        self.settings = settings or ViewSettings(spawn=s.spawn, shading=s.shading,
                                                 spp=1 if s.exact else s.spp)
        cam0 = self.base.cameras[0]
        self.size = tuple(size) if size else (cam0.width, cam0.height)
        self.moving_size = tuple(moving_size) if moving_size else (
            max(1, self.size[0] // 2), max(1, self.size[1] // 2))
        self.camera = CameraState.of(cam0)
        self.view_name = cam0.name
        self._scenes: dict[str, Scene] = {s.shading: self.base}
        self._renderers: dict[tuple, Renderer] = {}
        self._frozen: dict[tuple, object] = {}
        self._recorded: set[tuple] = set()
        self.saved = 0
        self.renderer()      # fail now (bad backend, no GPU) rather than in the first frame

    # ---- scene and renderer of the settings -----------------------------------------------
    @property
    def presets(self) -> list[str]:
        return [c.name for c in self.base.cameras]

    @property
    def step(self) -> float:
        return STEP_FRACTION * max(self.base.diagonal, 1e-9)

    def scene_for(self, st: ViewSettings) -> Scene:
        """The scene as the settings ask for it: shading (the file re-read), the mode's
        depth, spp (exact when 1) and the spawn rule."""
        if st.shading not in self._scenes:
            self._scenes[st.shading] = load_scene(self.scene_path, shading=st.shading,
                                                  **self.base.read)
        scene = self._scenes[st.shading]
        depth = RENDER_MODES[st.mode][1]
        scene = scene.with_overrides(spp=st.spp, max_depth=depth)
        if st.spawn != scene.settings.spawn:
            scene = scene.with_settings(spawn=st.spawn, ray_epsilon=None)
        return scene

    def effects_for(self, scene: Scene, st: ViewSettings) -> EffectSet:
        eff = EffectSet.from_scene(scene)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")      # the overlay marks the set "(forced)"
            for name in st.effects_off:
                if getattr(eff, name):
                    eff = eff.without(name)
        return eff

    def renderer(self, st: ViewSettings | None = None) -> Renderer:
        st = st or self.settings
        key = st.key()
        if key not in self._renderers:
            scene = self.scene_for(st)
            r = Renderer(scene, backend=self.backend, precision=st.precision,
                         accel=st.accel, intersection=st.intersection,
                         effects=self.effects_for(scene, st))
            self._frozen[key] = srgb8_frame(r.frame_fn, r.t)
            self._renderers[key] = r
        return self._renderers[key]

    def scene_effects(self) -> EffectSet:
        """The effect set the scene itself calls for at the current mode (no toggles)."""
        return EffectSet.from_scene(self.scene_for(self.settings))

    def options(self) -> dict:
        """The menus' choices and the current values (for the page)."""
        st = self.settings
        r = self.renderer()
        return {
            "scene": self.base.name, "backend": r.t.backend,
            "size": list(self.size), "moving_size": list(self.moving_size),
            "modes": [[k, v[0]] for k, v in RENDER_MODES.items()],
            "effects": [k for k in FLAGS if getattr(self.scene_effects(), k)],
            "accels": list(ACCELERATORS), "routines": list(ROUTINES),
            "precisions": list(PRECISIONS), "spawns": list(SPAWN_RULES),
            "spps": list(SPP_CHOICES), "shadings": list(SHADING_MODES),
            "presets": self.presets, "view": self.view_name,
            "values": {"mode": st.mode, "accel": st.accel or default_accel(r.t.backend),
                       "intersection": st.intersection, "precision": st.precision,
                       "spawn": st.spawn, "spp": st.spp, "shading": st.shading,
                       "effects_off": list(st.effects_off)},
        }

    # ---- input --------------------------------------------------------------------------
    def set_option(self, name: str, value) -> None:
        """Change one setting (``ViewSettings`` field; ``spp`` as text or int). Raises
        ValueError with one line for a value that is not a choice; the settings are left
        as they were when the new ones cannot render (e.g. physical shading of a scene
        whose lights do not fall off)."""
        choices = {"mode": list(RENDER_MODES), "accel": list(ACCELERATORS),
                   "intersection": list(ROUTINES), "precision": list(PRECISIONS),
                   "spawn": list(SPAWN_RULES), "spp": list(SPP_CHOICES),
                   "shading": list(SHADING_MODES)}
        if name not in choices:
            raise ValueError(f"option {name!r}: expected one of {', '.join(choices)}")
        if name == "spp":
            value = int(value)
        if value not in choices[name]:
            raise ValueError(f"{name}: expected one of {choices[name]}, got {value!r}")
        new = replace(self.settings, **{name: value})
        self.renderer(new)           # raises (SceneError, DeviceError) before switching
        self.settings = new

    def set_effect(self, name: str, on: bool) -> None:
        if name not in FLAGS:
            raise ValueError(f"effect {name!r}: expected one of {', '.join(FLAGS)}")
        off = set(self.settings.effects_off)
        off.discard(name) if on else off.add(name)
        new = replace(self.settings, effects_off=tuple(sorted(off)))
        self.renderer(new)
        self.settings = new

    def key(self, key: str, repeat: int = 1) -> bool:
        """Apply a key press (``MOVE_KEYS``, ``TURN_KEYS``; case-insensitive). Returns
        whether the camera changed."""
        k = key.lower()
        c = self.camera
        if k in MOVE_KEYS:
            r, u, f = c.basis()
            mx, my, mz = MOVE_KEYS[k]
            up = c.up / np.linalg.norm(c.up)
            delta = (mx * r + my * up + mz * f) * self.step * repeat
            c.position = c.position + delta
            c.target = c.target + delta
            return True
        if k in TURN_KEYS:
            yaw, pitch = TURN_KEYS[k]
            self._turn_view(yaw * TURN_DEGREES * repeat, pitch * TURN_DEGREES * repeat)
            return True
        return False

    def _turn_view(self, yaw: float, pitch: float) -> None:
        """Turn the viewing direction about the camera (the target moves)."""
        c = self.camera
        r, _, _ = c.basis()
        v = c.target - c.position
        v = _rotate(v, c.up, yaw)
        w = _rotate(v, r, pitch)
        if abs(np.dot(w / np.linalg.norm(w), c.up / np.linalg.norm(c.up))) < 0.995:
            v = w
        c.target = c.position + v

    def orbit(self, dx: float, dy: float) -> None:
        """Mouse drag: the camera circles its target (``dx``, ``dy`` in pixels)."""
        c = self.camera
        r, _, _ = c.basis()
        v = c.position - c.target
        v = _rotate(v, c.up, -dx * DRAG_DEGREES)
        w = _rotate(v, r, -dy * DRAG_DEGREES)
        if abs(np.dot(w / np.linalg.norm(w), c.up / np.linalg.norm(c.up))) < 0.995:
            v = w
        c.position = c.target + v

    def pan(self, dx: float, dy: float) -> None:
        """Mouse drag with the right button or Shift: camera and target slide in the image
        plane so that the point at the target follows the mouse (pixels of ``size``)."""
        c = self.camera
        r, u, _ = c.basis()
        dist = float(np.linalg.norm(c.target - c.position))
        per_px = 2 * dist * np.tan(np.radians(c.fov_y) / 2) / self.size[1]
        delta = (-dx * r + dy * u) * per_px
        c.position = c.position + delta
        c.target = c.target + delta

    def zoom(self, wheel: float) -> None:
        """Mouse wheel: the camera moves towards (``wheel`` < 0) or away from its target,
        by a factor ``exp(wheel / 500)`` of the distance; it stops short of the target."""
        c = self.camera
        v = c.position - c.target
        dist = float(np.linalg.norm(v))
        new = max(dist * float(np.exp(wheel / 500.0)), 1e-3 * self.base.diagonal)
        c.position = c.target + v * (new / dist)

    def preset(self, name_or_index) -> None:
        """Jump to one of the scene's own views (name or index)."""
        names = self.presets
        i = names.index(name_or_index) if name_or_index in names else int(name_or_index)
        self.camera = CameraState.of(self.base.cameras[i])
        self.view_name = names[i]

    # ---- frames -------------------------------------------------------------------------
    def _size(self, moving: bool) -> tuple[int, int]:
        return self.moving_size if moving else self.size

    def needs_compile(self, moving: bool) -> bool:
        """Whether the next frame at this size records kernels (new settings or size)."""
        return (self.settings.key(), self._size(moving)) not in self._recorded

    def frame(self, moving: bool = False) -> Frame:
        """Render the current camera (at ``moving_size`` when ``moving``) and encode it."""
        w, h = self._size(moving)
        r = self.renderer()
        fn = self._frozen[self.settings.key()]
        ca = r.camera(self.camera.camera(w, h))
        dr.sync_thread()
        t0 = time.perf_counter()
        u8 = fn(ca, r.arrays, w, h)
        dr.eval(u8)
        img = np.asarray(u8.numpy()).reshape(h, w, 3)
        t1 = time.perf_counter()
        jpeg = encode_jpeg(img)
        t2 = time.perf_counter()
        k = (self.settings.key(), (w, h))
        recorded = k not in self._recorded
        self._recorded.add(k)
        return Frame(jpeg=jpeg, width=w, height=h, render_ms=(t1 - t0) * 1e3,
                     encode_ms=(t2 - t1) * 1e3, rays=w * h * r.spp, effects=str(r.effects),
                     moving=moving, recorded=recorded, image=img)

    # ---- outputs ------------------------------------------------------------------------
    def save_view(self, out_dir) -> tuple[Path, Path]:
        """Render the current view at ``size`` and write it as EXR + PNG into ``out_dir``
        (``<scene>_view<N>.exr/.png``, the first N whose files do not exist; atomic
        writes, nothing replaced). Returns both paths."""
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        w, h = self.size
        r = self.renderer()
        img = np.asarray(r.frame(r.camera(self.camera.camera(w, h)), w, h).numpy(),
                         np.float32)
        n = self.saved + 1
        while (out / f"{self.base.name}_view{n}.exr").exists() or \
                (out / f"{self.base.name}_view{n}.png").exists():
            n += 1
        self.saved = n
        stem = out / f"{self.base.name}_view{n}"
        return (write_exr(stem.with_suffix(".exr"), img),
                write_png(stem.with_suffix(".png"), img))

    def view_table(self, name: str = "viewer") -> str:
        """The current camera as a ``[[views]]`` table of the scene file format."""
        c = self.camera

        def vec(v):
            return "[" + ", ".join(f"{float(x):.6g}" for x in v) + "]"
        w, h = self.size
        return (f'[[views]]\nname = "{name}"\nposition = {vec(c.position)}\n'
                f"target = {vec(c.target)}\nup = {vec(c.up)}\nfov_y = {c.fov_y:.6g}\n"
                f"resolution = [{w}, {h}]\n")

    def save_view_table(self, out_dir, name: str = "viewer") -> Path:
        """Write ``view_table(name)`` to ``out_dir/<scene>_<name>.toml`` (atomic; a file
        that exists gets the next free number)."""
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        path = out / f"{self.base.name}_{name}.toml"
        n = 1
        while path.exists():
            n += 1
            path = out / f"{self.base.name}_{name}{n}.toml"
        return write_text(path, self.view_table(name))

    # ---- Mitsuba side by side -----------------------------------------------------------
    def side_by_side(self) -> SideBySide:
        """Ours | Mitsuba | heat map of the current view at ``size`` (see the module's
        docstring). Raises MitsubaMissing when Mitsuba cannot be imported."""
        try:
            import mitsuba  # noqa: F401

            from reference.golden import GOLDEN_SPAWN, Golden
            from reference.mitsuba_scene import render_mitsuba
        except ImportError as e:
            raise MitsubaMissing(f"side by side: Mitsuba is not installed ({e}); install "
                                 "the project's 'reference' extra") from None
        from evaluation.gate import verdict as vd
        st = replace(self.settings, spp=1, spawn=GOLDEN_SPAWN)
        w, h = self.size
        scene = self.scene_for(st)
        scene = replace(scene, cameras=[self.camera.camera(w, h)])
        ours_r = self.renderer(st)
        th = vd.thresholds_for(scene, "exact")
        d = float(th["tie_slack"].value) * scene.diagonal
        probe = Renderer(scene, backend=self.backend, precision=st.precision, accel=st.accel,
                         intersection=st.intersection, effects=ours_r.effects,
                         tie_break="other", tie_window=d, tie_slack=d)
        ca = ours_r.camera(scene.cameras[0])
        ours = np.asarray(ours_r.frame(ca, w, h).numpy(), np.float32)
        other = probe.render(0).image
        ties = np.any(other != ours, axis=-1)
        t0 = time.perf_counter()
        ref = np.asarray(render_mitsuba(scene, view=0, mode="exact"), np.float32)
        mi_seconds = time.perf_counter() - t0
        status, reason, _, res = vd.judge(ours, Golden(ref, None, {}, Path()), "exact", th,
                                          scene.check.get("warn"), scene, ties)
        eps = th["eps"].value
        rel = (np.abs(ours.astype(np.float64) - ref) / np.maximum(np.abs(ref), eps)).max(-1)
        strip = np.concatenate([srgb_encode(ours), srgb_encode(ref), heat_map(rel)], axis=1)
        note = ("effects forced off: ours is not the scene's truth, so it may fail"
                if ours_r.effects.forced else "")
        return SideBySide(jpeg=encode_jpeg(strip, 92), status=status, reason=reason,
                          excused=int(res.get("excused_pixels", 0)),
                          failing=int(res.get("hard_pixels", 0)),
                          pixels=int(res.get("pixels", rel.size)),
                          mitsuba_seconds=mi_seconds, note=note)
