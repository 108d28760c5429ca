"""``whitted view`` driven in a real browser: headless Chromium through selenium.

The viewer runs as the command a user types (a subprocess on a free port, LLVM, the Cornell
spheres at 64x64). The test waits for the first full-size frame, presses W (the camera
moves forward by one step along its viewing direction and the image changes), switches the
render mode to "primary only" (the effect set shown changes to depth 0 and the mirror
sphere shows its own local colour: the pixels at its centre equal a depth-0 render of the
same camera by the renderer itself and differ from the full Whitted ones), turns on the
Mitsuba side by side and reads the exact rule's verdict. Screenshots of every step go to
``out/test-artifacts/view/`` (or ``$WHITTED_TEST_ARTIFACTS/view``).
"""
from __future__ import annotations

import base64
import io
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "cornell_sphere.toml"
SIZE = (64, 64)
#: The mirror sphere's centre (scenes/cornell_sphere.toml, object "mirror_sphere").
MIRROR_CENTRE, MIRROR_RADIUS = np.array([-0.45, 0.452, -0.35]), 0.45
CHROMIUM, DRIVER = shutil.which("chromium"), shutil.which("chromedriver")
ARTIFACTS = Path(os.environ.get("WHITTED_TEST_ARTIFACTS", ROOT / "out" / "test-artifacts")) / "view"


def _need_browser():
    pytest.importorskip("aiohttp")
    pytest.importorskip("selenium")
    if not (CHROMIUM and DRIVER):
        pytest.fail("chromium and chromedriver are required (bash ci/setup.sh installs "
                    "Debian's chromium and chromium-driver)")


@pytest.fixture
def viewer(tmp_path):
    """The running ``whitted view`` and its URL."""
    _need_browser()
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        [sys.executable, "-m", "whitted", "view", str(SCENE), "--backend", "llvm",
         "--size", f"{SIZE[0]}x{SIZE[1]}", "--port", "0", "--out", str(tmp_path / "saved")],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=ROOT)
    url, lines = None, []
    t0 = time.monotonic()
    while url is None and time.monotonic() - t0 < 60:
        line = proc.stdout.readline()
        if not line:
            break
        lines.append(line)
        m = re.search(r"open (http://\S+/)", line)
        url = m.group(1) if m else None
    if url is None:
        proc.kill()
        pytest.fail("the viewer printed no URL:\n" + "".join(lines))
    yield url
    proc.send_signal(2)           # Ctrl-C
    try:
        proc.wait(timeout=5)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail("the viewer did not stop within 5 s of Ctrl-C")


@pytest.fixture
def browser(tmp_path):
    _need_browser()
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for a in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
              "--no-first-run", f"--user-data-dir={tmp_path / 'chrome'}",
              "--window-size=1000,1000", "--force-device-scale-factor=1"):
        opts.add_argument(a)
    driver = webdriver.Chrome(service=Service(DRIVER), options=opts)
    driver.set_page_load_timeout(30)
    yield driver
    driver.quit()


def _wait(driver, what: str, fn, timeout: float = 40.0):
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        v = fn()
        if v:
            return v
        time.sleep(0.05)
    shot = ARTIFACTS / "timeout.png"
    driver.save_screenshot(str(shot))
    status = driver.find_element("id", "status").text
    pytest.fail(f"timed out waiting for {what} (screenshot {shot}; status: {status!r})")


def _still_frame(driver, after_seq: int = 0):
    """(seq, image uint8 (H, W, 3), camera dict) of the first full-size frame after
    ``after_seq``."""
    def get():
        js = ("const i = document.getElementById('frame'); return [i.dataset.seq || '0', "
              "i.dataset.moving, i.src, document.getElementById('camera').textContent];")
        seq, moving, src, cam = driver.execute_script(js)
        if int(seq) > after_seq and moving == "false" and src.startswith("data:"):
            return int(seq), src, cam
        return None
    seq, src, cam = _wait(driver, f"a still frame after #{after_seq}", get)
    from PIL import Image
    img = np.asarray(Image.open(io.BytesIO(base64.b64decode(src.split(",", 1)[1]))).convert("RGB"))
    return seq, img, json.loads(cam)


def _mirror_disc(cam: dict) -> np.ndarray:
    """bool (H, W): the pixels well inside the mirror sphere's outline as the viewer's
    camera ``cam`` sees it at SIZE (70 % of its projected radius)."""
    from renderer.camera import camera_frame
    from renderer.scene import Camera
    c = Camera(position=np.array(cam["position"]), target=np.array(cam["target"]),
               up=np.array(cam["up"]), fov_y=cam["fov_y"], width=SIZE[0], height=SIZE[1])
    fr = camera_frame(c)
    p = MIRROR_CENTRE - fr["position"]
    z = p @ fr["forward"]
    sx, sy = (p @ fr["right"]) / z / fr["tan_x"], (p @ fr["up"]) / z / fr["tan_y"]
    x, y = (sx + 1) / 2 * SIZE[0], (1 - sy) / 2 * SIZE[1]
    radius = MIRROR_RADIUS / z / fr["tan_y"] * SIZE[1] / 2
    yy, xx = np.mgrid[0:SIZE[1], 0:SIZE[0]] + 0.5
    return (xx - x) ** 2 + (yy - y) ** 2 < (0.7 * radius) ** 2


def _ours(cam: dict, max_depth: int | None) -> np.ndarray:
    """The renderer's own sRGB image of ``cam`` at SIZE (``max_depth`` None: the scene's)."""
    from renderer.film import srgb_encode
    from renderer.render import Renderer
    from renderer.scene import Camera, load_scene
    scene = load_scene(SCENE).with_overrides(max_depth=max_depth)
    c = Camera(position=np.array(cam["position"]), target=np.array(cam["target"]),
               up=np.array(cam["up"]), fov_y=cam["fov_y"], width=SIZE[0], height=SIZE[1])
    r = Renderer(scene, backend="llvm")
    return srgb_encode(r.frame(r.camera(c), *SIZE).numpy())


def _shot(driver, name: str) -> Path:
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    path = ARTIFACTS / name
    driver.save_screenshot(str(path))
    return path


def test_viewer_in_headless_chromium(viewer, browser):
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.support.ui import Select
    d = browser
    d.get(viewer)

    # 1. the first frame, at full size
    seq, first, cam0 = _still_frame(d)
    assert first.shape == (SIZE[1], SIZE[0], 3)
    assert len(np.unique(first.reshape(-1, 3), axis=0)) > 50, "the first frame looks blank"
    _shot(d, "1_first_frame.png")
    effects_full = d.find_element("id", "overlay").get_attribute("data-effects")
    assert "depth 5" in effects_full and "reflection" in effects_full

    # 2. W: the camera moves forward along its view and the image changes
    ActionChains(d).send_keys("w").perform()
    seq, moved, cam1 = _still_frame(d, seq)
    p0, p1 = np.array(cam0["position"]), np.array(cam1["position"])
    forward = np.array(cam0["target"]) - p0
    forward /= np.linalg.norm(forward)
    step = p1 - p0
    assert step @ forward > 0, f"W did not move the camera forward: {p0} -> {p1}"
    assert np.linalg.norm(step - (step @ forward) * forward) < 1e-9, "W moved sideways"
    assert np.abs(moved.astype(int) - first).mean() > 1.0, "the image did not change after W"
    _shot(d, "2_after_w.png")

    # 3. render mode "primary only": the effect set changes, the mirror shows its local colour
    Select(d.find_element("id", "mode")).select_by_value("primary")
    _wait(d, "the overlay's effect set to change",
          lambda: "depth 0" in (d.find_element("id", "overlay").get_attribute("data-effects")
                                or ""))
    seq, primary, cam2 = _still_frame(d, seq)
    effects_primary = d.find_element("id", "overlay").get_attribute("data-effects")
    assert effects_primary != effects_full and "reflection" not in effects_primary
    disc = _mirror_disc(cam2)
    assert disc.sum() > 20
    local, whitted = _ours(cam2, 0)[disc].astype(int), _ours(cam2, None)[disc].astype(int)
    assert np.abs(local - whitted).mean() > 10, "the test's mirror pixels reflect nothing"
    got = primary[disc].astype(int)
    # JPEG: a few levels of difference, more at the highlight's edge
    assert np.abs(got - local).mean() <= 3 and np.abs(got - local).max() <= 24, (
        f"mirror: the viewer shows mean {got.mean(0)}, the depth-0 render {local.mean(0)}")
    assert np.abs(got - whitted).mean() > 8, "the mirror still shows its reflection"
    _shot(d, "3_primary_only.png")

    # 4. Mitsuba side by side: the exact rule's verdict for this view
    pytest.importorskip("mitsuba")
    d.find_element("id", "sbs").click()
    status = _wait(d, "the side-by-side verdict", lambda: d.find_element(
        "id", "verdict").get_attribute("data-status"), timeout=60)
    text = d.find_element("id", "verdict").text
    assert status == "PASS", text
    assert re.search(r"excused \d+, failing 0 of 4096 pixels", text), text
    _shot(d, "4_side_by_side.png")
