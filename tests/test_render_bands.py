"""Large renders run in bands of rows (``Renderer.render``, ``camera.primary_rays`` with
``first_row``/``rows``); the bands hold the same rays as one batch, so the image is the
one-batch image bit for bit, in exact and in converged (jittered) mode."""
from __future__ import annotations

from pathlib import Path

import drjit as dr
import numpy as np
import pytest

from renderer.render import Renderer
from renderer.scene import load_scene

SCENES = Path(__file__).resolve().parents[1] / "scenes"


BACKENDS = ["llvm", pytest.param("cuda", marks=pytest.mark.skipif(
    not dr.has_backend(dr.JitBackend.CUDA), reason="no CUDA device"))]


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("name,spp", [("cornell_sphere", None), ("cornell_box", 4)])
def test_banded_image_is_bitwise_the_one_batch_image(name, spp, backend):
    scene = load_scene(SCENES / f"{name}.toml").with_overrides(size=(40, 23), spp=spp)
    r = Renderer(scene, backend=backend)
    whole = r.render(1, tile_samples=0)
    per_row = 40 * (spp or 1)
    done = []
    banded = r.render(1, tile_samples=7 * per_row, progress=lambda a, b: done.append((a, b)))
    assert whole.stats["bands"] == 1 and banded.stats["bands"] == 4   # 7+7+7+2 rows
    assert done == [(7, 23), (14, 23), (21, 23), (23, 23)]
    assert whole.image.mean() > 0.01
    assert whole.image.tobytes() == banded.image.tobytes()


def test_bands_of_other_rays_would_be_caught():
    """The property can fail: a converged render with another seed differs."""
    scene = load_scene(SCENES / "cornell_box.toml").with_overrides(size=(16, 16), spp=4)
    a = Renderer(scene, backend="llvm").render(0, tile_samples=16 * 4 * 5).image
    b = Renderer(scene.with_settings(seed=1), backend="llvm").render(0, tile_samples=0).image
    assert not np.array_equal(a, b)


def test_stop_request_ends_a_banded_render_between_bands():
    scene = load_scene(SCENES / "cornell_sphere.toml").with_size(16, 16)
    r = Renderer(scene, backend="llvm")
    calls = []

    def stop():
        calls.append(1)
        return len(calls) > 2
    with pytest.raises(KeyboardInterrupt):
        r.render(0, tile_samples=16 * 4, stop=stop)
    assert len(calls) == 3


class _Terminal:
    """A stand-in for stderr on a terminal."""

    def __init__(self):
        self.text = ""

    def isatty(self):
        return True

    def write(self, s):
        self.text += s

    def flush(self):
        pass


def test_progress_is_a_tqdm_bar_on_a_terminal_and_plain_lines_in_a_log():
    import io

    from whitted.progress import bar
    term = _Terminal()
    b = bar(10, "scene/view", file=term)
    b.update(4)
    b.refresh()                        # tqdm redraws at most every 0.1 s on its own
    b.close()
    assert "scene/view" in term.text and "4/10" in term.text and "<" in term.text  # ETA
    log = io.StringIO()
    b = bar(10, "scene/view", file=log)
    for _ in range(10):
        b.update(1)
    lines = log.getvalue().splitlines()
    assert lines[-1].startswith("scene/view: 10/10 (100%)") and "ETA" in lines[-1]
    assert "\r" not in log.getvalue()


def test_cli_render_in_bands_reports_them(tmp_path, capsys):
    from whitted.cli import main
    # 700 x 500 = 350,000 camera rays > 2^18: two bands on LLVM
    assert main(["render", str(SCENES / "cornell_box.toml"), "--size", "700x500",
                 "--backend", "llvm", "--out", str(tmp_path / "a.png")]) == 0
    out, err = capsys.readouterr()
    assert "in 2 bands" in out and "cornell_box/front: 500/500 (100%)" in err


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("name,spp", [("glass_bunny", None), ("cornell_sphere", 4)])
def test_block_order_image_is_bitwise_the_row_major_image(name, spp, backend, monkeypatch):
    """Frames trace their rays in pixel blocks (``camera.BLOCKS``); the image is the
    row-major frame's bit for bit, whole and in bands whose height is no multiple of the
    block's, in exact and converged mode."""
    import renderer.render as R
    scene = load_scene(SCENES / f"{name}.toml").with_overrides(size=(37, 19), spp=spp)
    per_row = 37 * (spp or 1)
    assert R.BLOCKS[backend] is not None
    blocked = Renderer(scene, backend=backend)
    images = [blocked.render(0, tile_samples=0).image,
              blocked.render(0, tile_samples=5 * per_row).image]
    monkeypatch.setitem(R.BLOCKS, backend, None)
    rows = Renderer(scene, backend=backend).render(0, tile_samples=0).image
    assert rows.mean() > 0.01
    for img in images:
        assert img.tobytes() == rows.tobytes()
