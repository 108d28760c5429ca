"""The orbit camera (renderer/orbit.py) and ``whitted render --orbit``: cameras on the
circle, one frozen frame function whose frames equal traced renders, the animated GIF."""
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from renderer.orbit import orbit_cameras, render_orbit, write_gif
from renderer.render import Renderer, render
from renderer.scene import Camera, load_scene

SCENES = Path(__file__).resolve().parents[1] / "scenes"
SIZE = 24          # tiny frames: the properties do not depend on the resolution


def _cornell(size=SIZE):
    return load_scene(SCENES / "cornell_box.toml").with_size(size)


def _tilted_camera():
    # An up axis off the coordinate axes, so height and radius are not plain y and xz.
    return Camera(position=np.array([1.0, 2.0, 3.0]), target=np.array([0.2, -0.1, 0.4]),
                  up=np.array([0.3, 1.0, -0.2]), fov_y=40.0, width=8, height=6, name="tilted")


@pytest.mark.parametrize("n", [2, 5, 12])
@pytest.mark.parametrize("which", ["front", "left", "close", "tilted"])
def test_orbit_cameras_keep_distance_height_and_are_evenly_spaced(which, n):
    cam = _tilted_camera() if which == "tilted" else \
        next(c for c in _cornell().cameras if c.name == which)
    cams = orbit_cameras(cam, n)
    assert len(cams) == n and cams[0] is cam
    u = cam.up / np.linalg.norm(cam.up)
    off0 = cam.position - cam.target
    h0 = off0 @ u
    radial = []
    for c in cams:
        np.testing.assert_array_equal(c.target, cam.target)
        np.testing.assert_array_equal(c.up, cam.up)
        assert (c.fov_y, c.width, c.height) == (cam.fov_y, cam.width, cam.height)
        off = c.position - c.target
        assert np.linalg.norm(off) == pytest.approx(np.linalg.norm(off0), rel=1e-12)
        assert off @ u == pytest.approx(h0, rel=1e-12, abs=1e-12)
        radial.append(off - (off @ u) * u)
    # Consecutive cameras (cyclically) are 2π/n apart, all turning the same way about up.
    r = np.linalg.norm(radial[0])
    for a, b in zip(radial, radial[1:] + radial[:1]):
        ang = np.arctan2(np.cross(a, b) @ u, a @ b)
        if n == 2:
            ang = abs(ang)          # half a turn: the sign of sin(π) is rounding noise
        assert ang == pytest.approx(2 * np.pi / n, rel=1e-9)
        assert np.linalg.norm(b) == pytest.approx(r, rel=1e-12)
    # Evenly spaced around the full circle: the horizontal offsets sum to zero.
    assert np.linalg.norm(np.sum(radial, axis=0)) < 1e-9 * r
    assert len({c.name for c in cams}) == n


def test_orbit_refuses_camera_on_its_up_axis():
    cam = Camera(position=np.array([0.0, 3.0, 0.0]), target=np.zeros(3),
                 up=np.array([0.0, 1.0, 0.0]), fov_y=40.0, width=8, height=8, name="top")
    with pytest.raises(ValueError, match="up axis"):
        orbit_cameras(cam, 4)
    with pytest.raises(ValueError, match="n"):
        orbit_cameras(_tilted_camera(), 0)


def test_first_orbit_frame_equals_render_bitwise(backend):
    sc = _cornell()
    for view in (0, 2):
        orbit = render_orbit(sc, 3, view=view, backend=backend, accel="bvh", srgb=False)
        ref = render(sc, view=view, backend=backend, accel="bvh").image
        assert orbit.frames[0].dtype == np.float32 and orbit.frames[0].shape == ref.shape
        np.testing.assert_array_equal(orbit.frames[0], ref)


def test_frozen_orbit_frames_differ_and_equal_traced_renders(backend):
    sc = _cornell()
    n = 4
    orbit = render_orbit(sc, n, view=1, backend=backend, accel="bvh", srgb=False)
    assert orbit.recordings == 1            # one recording, replayed for frames 1..n-1
    assert len(orbit.frames) == n and len(orbit.frozen_frame_ms) == n - 1
    assert orbit.fps > 0 and orbit.first_frame_ms > 0 and orbit.frozen_frame_ms_median > 0
    traced = Renderer(sc, backend=backend, accel="bvh")          # not frozen: traced per call
    for cam, frame in zip(orbit.cameras, orbit.frames):
        ref = traced.frame(traced.camera(cam), cam.width, cam.height).numpy()
        np.testing.assert_array_equal(frame, ref)
    for i in range(n):
        for j in range(i + 1, n):
            assert np.abs(orbit.frames[i] - orbit.frames[j]).max() > 0.05, (i, j)


def test_orbit_srgb_frames_are_uint8_encoding_of_linear_frames(backend):
    from renderer.film import srgb_encode
    sc = _cornell(16)
    lin = render_orbit(sc, 2, backend=backend, srgb=False).frames
    enc = render_orbit(sc, 2, backend=backend, srgb=True).frames
    for a, b in zip(lin, enc):
        assert b.dtype == np.uint8 and b.shape == (16, 16, 3)
        np.testing.assert_array_equal(b, srgb_encode(a))


def test_gif_has_n_frames_of_frame_size(tmp_path, backend):
    sc = _cornell().with_size(20, 12)
    n = 5
    orbit = render_orbit(sc, n, backend=backend)
    path = write_gif(tmp_path / "sub" / "orbit.gif", orbit.frames, fps=25)
    gif = iio.imread(path, index=None)
    assert gif.shape[:3] == (n, 12, 20)
    # A palette per frame: close to the rendered sRGB frames, not bit-exact.
    err = np.abs(gif[..., :3].astype(int) - np.stack(orbit.frames).astype(int))
    assert err.mean() < 4.0
    meta = iio.immeta(path, index=0)
    assert meta.get("duration") == 40 and meta.get("loop") == 0


def test_write_gif_refuses_to_overwrite_without_permission(tmp_path):
    rng = np.random.default_rng(3)                  # fixed seed: two distinct 2-frame clips
    a = [rng.integers(0, 256, (8, 8, 3), dtype=np.uint8) for _ in range(2)]
    b = [rng.integers(0, 256, (8, 8, 3), dtype=np.uint8) for _ in range(3)]
    path = write_gif(tmp_path / "x.gif", a, fps=10)
    before = path.read_bytes()
    with pytest.raises(FileExistsError):
        write_gif(path, b, fps=10)
    assert path.read_bytes() == before
    write_gif(path, b, fps=10, overwrite=True)
    assert iio.imread(path, index=None).shape[0] == 3


def test_write_gif_rejects_mismatched_frames(tmp_path):
    with pytest.raises(ValueError, match=r"frames\[1\]"):
        write_gif(tmp_path / "y.gif",
                  [np.zeros((4, 4, 3), np.uint8), np.zeros((4, 5, 3), np.uint8)])
    assert not (tmp_path / "y.gif").exists()


def test_cli_render_orbit_writes_gif_and_reports_fps(tmp_path, capsys):
    from whitted.cli import main
    argv = ["render", str(SCENES / "cornell_box.toml"), "--size", "16x16", "--orbit", "3",
            "--backend", "llvm", "--out", str(tmp_path)]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert "frames/s" in out and "first (traced) frame" in out and "recordings: 1" in out
    gif = tmp_path / "cornell_box_front_orbit.gif"
    assert iio.imread(gif, index=None).shape[:3] == (3, 16, 16)
    before = gif.read_bytes()
    assert main(argv) == 4                          # exists, no --overwrite: file error
    assert gif.read_bytes() == before
    assert main(argv + ["--overwrite"]) == 0
    with pytest.raises(SystemExit):
        main(argv[:-4] + ["--orbit", "1", "--out", str(tmp_path)])
