"""The HTML/PNG report of evaluation/gate/report.py, checked in headless Chromium."""
import html
import json
import os
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from evaluation.gate import metrics
from evaluation.gate.report import ReportEntry, format_metrics_table, write_report
from renderer.film import srgb_encode

CHROMIUM = Path("/usr/bin/chromium")

# sRGB colours of the test image's blocks (linear 1 or 0 per channel encodes exactly).
RED, GREEN, BLUE = (255, 0, 0), (0, 255, 0), (0, 0, 255)


def _images():
    """Reference: red | blue blocks over a grey ramp; ours: the blue block is green."""
    h, w = 36, 48
    ramp = np.linspace(0.05, 0.6, w, dtype=np.float32)
    ref = np.repeat(np.repeat(ramp[None, :, None], h, 0), 3, 2)
    ref[6:30, 4:20] = (1, 0, 0)
    ref[6:30, 28:44] = (0, 0, 1)
    ours = ref.copy()
    ours[6:30, 28:44] = (0, 1, 0)
    ours[0:3, :] *= 1.05  # a faint difference as well
    return ours, ref


def _entry(name="box / front (classic)"):
    ours, ref = _images()
    return ReportEntry(name, ours, ref, ours_seconds=0.0123, ref_seconds=1.5,
                       effects="shadows, reflection", operations="42 ops, 3 kernels",
                       info={"mode": "exact, 1 spp"})


def _screenshot(page: Path, png: Path) -> np.ndarray:
    if not CHROMIUM.exists():
        pytest.fail(f"{CHROMIUM} is missing: install Chromium (apt-get install -y chromium; "
                    "ci/setup.sh does it) to check the report's rendering")
    with tempfile.TemporaryDirectory() as profile:
        cmd = [str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
               "--no-first-run", "--disable-background-networking", "--disable-component-update",
               "--disable-sync", f"--user-data-dir={profile}", "--hide-scrollbars",
               "--force-device-scale-factor=1", f"--screenshot={png}", "--window-size=1400,1000",
               page.resolve().as_uri()]
        run = subprocess.run(cmd, capture_output=True, text=True, timeout=120,
                             env={**os.environ, "HOME": profile})
    assert png.exists(), f"Chromium wrote no screenshot (rc {run.returncode}): {run.stderr[-2000:]}"
    return np.asarray(Image.open(png).convert("RGB"))


def _count(shot: np.ndarray, colour, tol=6) -> int:
    return int((np.abs(shot.astype(int) - colour).max(axis=2) <= tol).sum())


def test_report_files_and_metrics(tmp_path):
    entry = _entry()
    index = write_report(tmp_path / "rep", [entry, _entry("second view")], title="Box scene")
    assert index == tmp_path / "rep" / "index.html"
    text = index.read_text()
    for needle in ("Box scene", "shadows, reflection", "42 ops, 3 kernels", "exact, 1 spp",
                   "12.3 ms", "1.50 s", html.escape(entry.metrics["outlier_rule"])):
        assert needle in text, needle
    ours, ref = _images()
    assert entry.metrics == metrics.metrics(ours, ref)
    folder = tmp_path / "rep" / "box-front-classic"
    for name in ("ours", "mitsuba", "absdiff", "flip", "strip"):
        assert (folder / f"{name}.png").exists(), name
        assert f"box-front-classic/{name}.png" in text
    # the PNGs are the sRGB-encoded images, pixel for pixel
    assert np.array_equal(np.asarray(Image.open(folder / "ours.png")), srgb_encode(ours))
    assert np.array_equal(np.asarray(Image.open(folder / "mitsuba.png")), srgb_encode(ref))
    record = json.loads((folder / "metrics.json").read_text())
    assert record["metrics"]["rmse"] == pytest.approx(entry.metrics["rmse"])
    assert record["absdiff_scale"] == pytest.approx(entry.metrics["max_abs"], rel=1e-5)
    # the strip holds the four panels side by side
    strip = np.asarray(Image.open(folder / "strip.png").convert("RGB"))
    assert strip.shape[1] > 3.5 * strip.shape[0]
    assert _count(strip, RED) > 0 and _count(strip, GREEN) > 0 and _count(strip, BLUE) > 0
    table = format_metrics_table([entry])
    assert "RMSE" in table and "box / front (classic)" in table


def test_report_never_overwrites_without_permission(tmp_path):
    write_report(tmp_path / "rep", [_entry()], title="t")
    with pytest.raises(FileExistsError):
        write_report(tmp_path / "rep", [_entry()], title="t")
    write_report(tmp_path / "rep", [_entry()], title="t", overwrite=True)


def test_report_page_renders_in_chromium(tmp_path):
    index = write_report(tmp_path / "rep", [_entry()], title="Box scene")
    shot = _screenshot(index, tmp_path / "shot.png")
    assert shot.shape[:2] == (1000, 1400)
    colours = np.unique(shot.reshape(-1, 3), axis=0)
    assert len(colours) > 200, f"screenshot looks blank: {len(colours)} distinct colours"
    # Both renders are visible, enlarged: ours shows a green block, Mitsuba a blue one,
    # each 24x16 image pixels, i.e. far more screen pixels than that.
    block = 24 * 16
    assert _count(shot, RED) > 2 * 4 * block      # red block in both panels, enlarged
    assert _count(shot, GREEN) > 4 * block
    assert _count(shot, BLUE) > 4 * block


def test_click_swaps_ours_and_mitsuba_in_place(tmp_path):
    index = write_report(tmp_path / "rep", [_entry()], title="Box scene")
    before = _screenshot(index, tmp_path / "before.png")
    # Same page with a click on the "ours" panel: it pins Mitsuba's image in its place.
    clicked = index.with_name("clicked.html")
    clicked.write_text(index.read_text().replace(
        "</body>", "<script>document.querySelector('figure.swap').click();</script></body>"))
    after = _screenshot(clicked, tmp_path / "after.png")
    green_before, blue_before = _count(before, GREEN), _count(before, BLUE)
    assert _count(after, GREEN) < 0.05 * green_before
    assert _count(after, BLUE) > 1.8 * blue_before


SCENES = Path(__file__).resolve().parents[1] / "scenes"


def test_compare_cli_writes_report_and_never_overwrites(tmp_path, capsys):
    from whitted.cli import main

    out = tmp_path / "cmp"
    argv = ["compare", str(SCENES / "analytic_quad.toml"), "--view", "all", "--size", "16x16",
            "--accel", "brute",
            "--live", "--out", str(out)]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert f"report: {out / 'index.html'}" in printed
    assert "RMSE" in printed and "effects:" in printed
    folders = sorted(p.name for p in out.iterdir() if p.is_dir())
    from renderer.scene import load_scene
    assert len(folders) == len(load_scene(SCENES / "analytic_quad.toml").cameras)  # every view
    for name in folders:
        record = json.loads((out / name / "metrics.json").read_text())
        assert record["metrics"]["pixels"] == 16 * 16
        assert "IR operations" in record["operations"] and record["effects"]
        assert record["ref_seconds"] is not None and record["ours_seconds"] > 0
    stamp = (out / "index.html").stat().st_mtime_ns
    assert main(argv) == 4                          # exists, no --force: file error
    assert "--force" in capsys.readouterr().err
    assert (out / "index.html").stat().st_mtime_ns == stamp
    assert main(argv + ["--force"]) == 0


def test_compare_cli_takes_mitsuba_image_from_golden(tmp_path, capsys):
    from reference import golden
    from renderer.film import read_exr
    from renderer.scene import load_scene
    from whitted.cli import main

    scene_path = SCENES / "analytic_quad.toml"
    root = tmp_path / "goldens"
    golden.render_goldens([scene_path], size=16, modes=("exact",), shadings=("classic",),
                          progress=False, root=root)
    out = tmp_path / "cmp"
    assert main(["compare", str(scene_path), "--view", "top", "--size", "16x16",
                 "--accel", "brute", "--out", str(out), "--goldens", str(root)]) == 0
    assert "golden" in (out / "index.html").read_text()
    (folder,) = [p for p in out.iterdir() if p.is_dir()]
    stored = golden.load_golden(load_scene(scene_path),
                                view=0, shading="classic", mode="exact", root=root)
    assert np.array_equal(read_exr(folder / "mitsuba.exr"), stored.image)
    # a golden of another size is refused, not compared: verdict SIZE, exit code 3
    capsys.readouterr()
    assert main(["compare", str(scene_path), "--view", "top", "--size", "8x8", "--accel",
                 "brute", "--out", str(tmp_path / "cmp8"), "--goldens", str(root)]) == 3
    assert "SIZE" in capsys.readouterr().out and "image is 16x16, ours 8x8" in \
        (tmp_path / "cmp8" / "index.html").read_text()


def test_report_carries_notes_and_the_study_page_together(tmp_path):
    """write_report(notes=, studies=): the verdict notes first, the committed CPU study as
    the "Accuracy vs time" section, its files copied byte for byte (atomically: no
    temporary file left), a folder that is not a study skipped."""
    study_dir = Path(__file__).resolve().parents[1] / "results" / "study" / "cpu"
    out = tmp_path / "report"
    index = write_report(out, [_entry()], title="t",
                         notes=[("STALE", "box / side (classic)", "golden is stale")],
                         studies=[study_dir, tmp_path / "not_a_study"])
    page = index.read_text()
    assert page.index("golden is stale") < page.index("Accuracy vs time")
    assert 'href="study/cpu/index.html"' in page and 'href="study/cpu/study.json"' in page
    copied = sorted(p.name for p in (out / "study" / "cpu").iterdir())
    assert "index.html" in copied and "study.json" in copied and "cornell_box.png" in copied
    for name in copied:
        assert not name.startswith("."), name
        assert (out / "study" / "cpu" / name).read_bytes() == (study_dir / name).read_bytes()
    assert not (out / "study" / "not_a_study").exists()
    plain = write_report(tmp_path / "plain", [_entry()], title="t").read_text()
    assert "Accuracy vs time" not in plain


def test_compare_cli_refuses_a_study_folder_that_is_not_one(tmp_path, capsys):
    from whitted.cli import main
    out = tmp_path / "cmp"
    assert main(["compare", str(SCENES / "analytic_quad.toml"), "--view", "top", "--size",
                 "16x16", "--accel", "brute", "--out", str(out), "--live",
                 "--study", str(tmp_path / "nothing")]) == 4
    err = capsys.readouterr().err
    assert "--study" in err and "nothing" in err and len(err.strip().splitlines()) == 1
    assert not (out / "index.html").exists()
