"""The viewer's session and command without a browser (``tests/test_view_browser.py`` drives
the page): camera keys, frozen frames that replay for a moved camera, the saved view and the
``[[views]]`` table read back, the side-by-side verdict, Mitsuba missing, the command's
one-line errors and Ctrl-C, and the frame-rate benchmark at a tiny size."""
from __future__ import annotations

import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from evaluation.view.session import (
    STEP_FRACTION,
    TURN_DEGREES,
    MitsubaMissing,
    ViewSession,
)
from renderer.film import read_exr, srgb_encode
from renderer.render import Renderer
from renderer.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "cornell_sphere.toml"


@pytest.fixture(scope="module")
def session():
    return ViewSession(SCENE, backend="llvm", size=(32, 24))


def _ours(session, max_depth=None, effects=None) -> np.ndarray:
    """The renderer's own float image of the session's camera at its still size."""
    scene = load_scene(SCENE).with_overrides(max_depth=max_depth)
    r = Renderer(scene, backend="llvm", effects=effects)
    w, h = session.size
    return r.frame(r.camera(session.camera.camera(w, h)), w, h).numpy()


def test_keys_move_and_turn_the_camera(session):
    session.preset(0)
    c = session.camera
    p0, t0 = c.position.copy(), c.target.copy()
    f = (t0 - p0) / np.linalg.norm(t0 - p0)
    step = STEP_FRACTION * session.base.diagonal
    session.key("w")
    assert np.allclose(c.position - p0, step * f) and np.allclose(c.target - t0, step * f)
    session.key("S")
    assert np.allclose(c.position, p0)
    session.key("d")
    right = c.position - p0
    assert np.isclose(np.linalg.norm(right), step) and abs(right @ f) < 1e-12
    assert np.cross(f, c.up) @ right > 0, "D moved left"
    session.key("a")
    session.key("e")
    assert np.allclose(c.position - p0, step * c.up / np.linalg.norm(c.up))
    session.key("q")
    session.key("ArrowLeft")
    assert np.allclose(c.position, p0)
    g = (c.target - c.position) / np.linalg.norm(c.target - c.position)
    assert np.isclose(np.degrees(np.arccos(np.clip(g @ f, -1, 1))), TURN_DEGREES)
    assert np.cross(f, g) @ c.up > 0, "ArrowLeft turned right"
    assert not session.key("x")
    session.preset(0)


def test_frozen_frame_replays_for_a_moved_camera(session):
    session.preset(0)
    first = session.frame()
    session.key("w")
    session.orbit(25, 10)
    moved = session.frame()
    assert first.recorded and not moved.recorded
    fn = session._frozen[session.settings.key()]
    assert fn.n_recordings == 1, "moving the camera recorded the frame again"
    want = srgb_encode(_ours(session))
    assert np.abs(moved.image.astype(int) - want).max() <= 1
    assert np.abs(first.image.astype(int) - moved.image).mean() > 2
    session.preset(0)


def test_render_mode_primary_only(session):
    session.preset(0)
    session.set_option("mode", "primary")
    try:
        f = session.frame()
        assert "depth 0" in f.effects and "reflection" not in f.effects
        assert np.abs(f.image.astype(int) - srgb_encode(_ours(session, 0))).max() <= 1
    finally:
        session.set_option("mode", "full")
    with pytest.raises(ValueError, match="mode: expected one of"):
        session.set_option("mode", "depth9")
    assert session.settings.mode == "full"


def test_menus_accelerator_and_routine(session):
    session.preset(0)
    base = session.frame().image
    try:
        session.set_option("accel", "brute")          # every accelerator: the same pixels
        brute = session.frame()
        assert brute.recorded and np.array_equal(brute.image, base)
        session.set_option("intersection", "moller_trumbore")
        mt = session.frame()
        assert mt.recorded and np.abs(mt.image.astype(int) - base).mean() < 0.5
    finally:
        session.set_option("accel", "bvh4")
        session.set_option("intersection", "watertight")


def test_saved_view_and_view_table_read_back(session, tmp_path):
    session.preset(1)
    session.orbit(-30, 5)
    exr, png = session.save_view(tmp_path)
    exr2, _ = session.save_view(tmp_path)
    assert exr != exr2 and png.exists(), "a second save replaced the first"
    assert np.array_equal(read_exr(exr), _ours(session))
    table = session.save_view_table(tmp_path, "mine").read_text()
    copy = tmp_path / "scene.toml"
    copy.write_text(SCENE.read_text() + "\n" + table)
    cam = load_scene(copy).cameras[-1]
    c = session.camera
    assert cam.name == "mine" and (cam.width, cam.height) == session.size
    assert np.allclose(cam.position, c.position, atol=1e-5)
    assert np.allclose(cam.target, c.target, atol=1e-5) and cam.fov_y == c.fov_y
    session.preset(0)


def test_side_by_side_verdict():
    pytest.importorskip("mitsuba")
    s = ViewSession(SCENE, backend="llvm", size=(24, 24))
    s.orbit(20, 0)
    sb = s.side_by_side()
    assert sb.status == "PASS" and sb.failing == 0 and sb.pixels == 24 * 24, sb.reason
    # ours without shadows is not the scene: the exact rule must see it
    s.set_effect("shadows", False)
    bad = s.side_by_side()
    assert bad.status == "FAIL" and bad.failing > 0 and "forced" in bad.note


def test_side_by_side_without_mitsuba_keeps_the_session(monkeypatch):
    s = ViewSession(SCENE, backend="llvm", size=(16, 16))
    monkeypatch.setitem(sys.modules, "mitsuba", None)
    with pytest.raises(MitsubaMissing, match="Mitsuba is not installed") as e:
        s.side_by_side()
    assert "\n" not in str(e.value)
    assert s.frame().image.shape == (16, 16, 3)


def _start_view(*extra):
    proc = subprocess.Popen(
        [sys.executable, "-m", "whitted", "view", str(SCENE), "--backend", "llvm",
         "--size", "16x16", *extra], cwd=ROOT, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True)
    line = ""
    while "open http" not in line:
        line = proc.stdout.readline()
        if not line:
            proc.wait(10)
            pytest.fail(f"the viewer did not start: {proc.stderr.read()}")
    return proc, int(re.search(r":(\d+)/", line).group(1))


def test_view_errors_are_one_line_and_ctrl_c_stops_it():
    proc, port = _start_view("--port", "0")
    try:
        busy = subprocess.run([sys.executable, "-m", "whitted", "view", str(SCENE),
                               "--backend", "llvm", "--size", "16x16", "--port", str(port)],
                              cwd=ROOT, capture_output=True, text=True, timeout=120)
        assert busy.returncode == 2
        assert busy.stderr.strip().splitlines() == [busy.stderr.strip()]
        assert busy.stderr.startswith(f"error: --port {port}: cannot listen")
        with socket.create_connection(("127.0.0.1", port), timeout=5):
            pass                                   # the first viewer still serves
        proc.send_signal(signal.SIGINT)
        t0 = time.perf_counter()
        _, err = proc.communicate(timeout=10)
        seconds = time.perf_counter() - t0
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert seconds < 1.0, f"took {seconds:.2f} s to stop"
    assert "Traceback" not in err
    unknown = subprocess.run([sys.executable, "-m", "whitted", "view", "no_such_scene"],
                             cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert unknown.returncode == 2 and unknown.stderr.strip().count("\n") == 0
    assert "no_such_scene" in unknown.stderr and "Traceback" not in unknown.stderr


def test_frame_rate_bench_at_a_tiny_size():
    pytest.importorskip("aiohttp")
    from evaluation.bench.viewer import bench_scene, markdown
    row = bench_scene(SCENE, backend="llvm", size=(16, 8), frames=3, warmup=1)
    assert row["frames"] == 3 and row["recorded_after_first"] == 0
    assert row["message_to_sent_ms"] >= row["render_ms"] + row["encode_ms"] > 0
    assert 0 < row["encode_share"] < 1 and row["fps"] > 0
    md = markdown({"device": {"backend": "llvm", "device": "CPU"}, "date": "now",
                   "rows": [row]})
    assert "| cornell_sphere | 970 | 16x8 | 3 |" in md
