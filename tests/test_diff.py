"""``whitted diff A B``: two image files judged by check's own rules, with check's verdict
line, exit codes and report refusals; bad inputs are one error line with their exit code.

The images are small synthetic EXRs and PNGs (no rendering), except the metadata test,
which renders the analytic quad twice at 16 px with different settings."""
from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from evaluation.gate.rules import THRESHOLDS, check_exact
from renderer.film import read_exr, read_png, srgb_encode, write_exr, write_png
from whitted.cli import main
from whitted.options import EXIT


def _image(seed: int = 7, shape=(12, 16)) -> np.ndarray:
    """A fixed smooth-ish positive image (values 0.05..0.95)."""
    rng = np.random.default_rng(seed)
    return (0.05 + 0.9 * rng.random((*shape, 3))).astype(np.float32)


@pytest.fixture
def pair(tmp_path):
    """b.exr (the reference) and a.exr, a copy of it."""
    b = _image()
    write_exr(tmp_path / "b.exr", b)
    write_exr(tmp_path / "a.exr", b)
    return tmp_path, b


def _diff(*args, capsys=None):
    code = main(["diff", *map(str, args)])
    if capsys is None:
        return code
    out = capsys.readouterr()
    return code, out.out, out.err


def test_identical_images_pass_and_one_pixel_fails_at_check_s_max_rel(pair, capsys):
    """The exact rule's own thresholds decide: one pixel 0.4 % brighter passes (max_rel
    5e-3), 0.6 % fails with check's FAIL line, and --threshold max_rel=0.01 lets it pass
    again; the whole image 0.4 % brighter fails by mean_rel (1e-4)."""
    folder, b = pair
    assert THRESHOLDS["exact"]["max_rel"].value == 5e-3
    code, out, _ = _diff(folder / "a.exr", folder / "b.exr", capsys=capsys)
    assert code == EXIT["ok"] and out.startswith("PASS    ")
    for factor, expected in ((1.004, EXIT["ok"]), (1.006, EXIT["fail"])):
        a = b.copy()
        a[3, 4] *= factor
        write_exr(folder / "a.exr", a, overwrite=True)
        code, out, _ = _diff(folder / "a.exr", folder / "b.exr", capsys=capsys)
        assert code == expected, out
    assert out.startswith("FAIL    ") and "1 pixels above max_rel 0.005 (no tie probe)" in out
    assert "1 checked: 1 FAIL; exit code 2" in out
    assert _diff(folder / "a.exr", folder / "b.exr", "--threshold", "max_rel=0.01") == 0
    write_exr(folder / "a.exr", b * 1.004, overwrite=True)
    code, out, _ = _diff(folder / "a.exr", folder / "b.exr", capsys=capsys)
    assert code == EXIT["fail"] and "mean rel 0.004 > 0.0001" in out


def test_the_json_verdict_holds_the_numbers_of_check_s_exact_rule(pair, capsys):
    folder, b = pair
    a = b.copy()
    a[3, 4] *= 1.02
    write_exr(folder / "a.exr", a, overwrite=True)
    code, out, _ = _diff(folder / "a.exr", folder / "b.exr", "--json", "-", "--quiet",
                         capsys=capsys)
    assert code == EXIT["fail"]
    v = json.loads(out)["verdicts"][0]
    ref = check_exact(read_exr(folder / "a.exr"), b, THRESHOLDS["exact"])
    for key in ("mean_rel", "max_rel", "hard_pixels", "hard", "ok"):
        assert v["result"][key] == ref[key], key
    assert v["result"]["hard"] == [[3, 4]] and v["excused"] == {}
    assert v["status"] == "FAIL" and v["exit_code"] == EXIT["fail"]


def test_warn_levels_give_exit_1(pair):
    folder, b = pair
    a = b.copy()
    a[3, 4] *= 1.001
    write_exr(folder / "a.exr", a, overwrite=True)
    assert _diff(folder / "a.exr", folder / "b.exr") == EXIT["ok"]
    assert _diff(folder / "a.exr", folder / "b.exr", "--warn", "mean_rel=1e-6") == EXIT["warn"]


def test_png_and_exr_in_either_order(pair, capsys):
    """A PNG is decoded from sRGB to linear: a PNG against itself passes, the PNG of an EXR
    fails against it by its 8-bit rounding (not by a gamma mistake: within 1 % of linear),
    in either order; a PNG named .exr is read as the PNG it is."""
    folder, b = pair
    write_png(folder / "b.png", b)
    assert _diff(folder / "b.png", folder / "b.png") == EXIT["ok"]
    decoded = read_png(folder / "b.png")
    assert (np.abs(decoded - b) / b).max() < 0.03
    assert np.array_equal(srgb_encode(decoded), srgb_encode(b))
    assert _diff(folder / "b.png", folder / "b.exr") == EXIT["fail"]
    assert _diff(folder / "b.exr", folder / "b.png") == EXIT["fail"]
    assert _diff(folder / "b.png", folder / "b.exr", "--threshold", "max_rel=0.05",
                 "--threshold", "mean_rel=0.05") == EXIT["ok"]
    (folder / "png.exr").write_bytes((folder / "b.png").read_bytes())
    assert _diff(folder / "png.exr", folder / "b.png") == EXIT["ok"]


def _truncated(folder: Path) -> Path:
    p = folder / "trunc.exr"
    p.write_bytes((folder / "b.exr").read_bytes()[:40])
    return p


def _file(name: str, data: bytes):
    def make(folder: Path) -> Path:
        (folder / name).write_bytes(data)
        return folder / name
    return make


def _nan(folder: Path) -> Path:
    img = read_exr(folder / "b.exr")
    img[2, 5] = np.nan
    img[7, 1] = np.inf
    return write_exr(folder / "nan.exr", img)


def _small(folder: Path) -> Path:
    return write_exr(folder / "small.exr", read_exr(folder / "b.exr")[:6])


def _folder(folder: Path) -> Path:
    (folder / "dir.exr").mkdir()
    return folder / "dir.exr"


#: (which side, how to make the input, exit code, words of the one error line; None: a
#: verdict line instead)
BAD_INPUTS = [
    ("A", lambda f: f / "missing.exr", EXIT["file"], "no such file"),
    ("B", lambda f: f / "missing.png", EXIT["file"], "no such file"),
    ("A", _truncated, EXIT["file"], "truncated or damaged OpenEXR"),
    ("B", _file("empty.exr", b""), EXIT["file"], "not an EXR or PNG image (empty)"),
    ("A", _file("text.png", b"hello, world\n"), EXIT["file"], "not an EXR or PNG image"),
    ("B", _file("bad.png", b"\x89PNG\r\n\x1a\n" + b"\0" * 30), EXIT["file"],
     "damaged PNG"),
    ("A", _folder, EXIT["file"], "is a folder"),
    ("B", _nan, EXIT["file"], "2 pixels are NaN or infinite (first at (2, 5))"),
    ("A", _nan, EXIT["fail"], None),
    ("A", _small, EXIT["size"], None),
]


@pytest.mark.parametrize("side, make, code, words", BAD_INPUTS,
                         ids=[f"{s}-{c}-{(w or 'verdict').split()[0]}"
                              for s, _, c, w in BAD_INPUTS])
def test_a_bad_input_is_one_line_with_its_exit_code(pair, capsys, side, make, code, words):
    folder, _ = pair
    bad = make(folder)
    args = (bad, folder / "b.exr") if side == "A" else (folder / "a.exr", bad)
    got, out, err = _diff(*args, capsys=capsys)
    assert got == code
    if words is None:
        line = out.splitlines()[0]
        status = {EXIT["fail"]: "FAIL", EXIT["size"]: "SIZE"}[code]
        assert line.startswith(status)
        if code == EXIT["fail"]:
            assert "2 pixels of A are NaN or infinite ((2,5), (7,1))" in line
        else:
            assert "A is 16x6, B 16x12" in line
        assert err == ""
    else:
        assert out == "" and len(err.splitlines()) == 1, err
        assert err.startswith(f"error: {side} {bad}") and words in err, err


#: Bad options: (arguments after A B, exit code, words of the error line)
BAD_OPTIONS = [
    (["--threshold", "max_rell=1"], EXIT["usage"], "--threshold max_rell: unknown threshold"),
    (["--threshold", "max_rel=-1"], EXIT["usage"], "--threshold max_rel: expected a number"),
    (["--threshold", "max_rel"], EXIT["usage"], "expected NAME=VALUE"),
    (["--threshold", "max_rel=abc"], EXIT["usage"], "'abc' is not a number"),
    (["--rule", "converged"], EXIT["usage"], "the converged rule needs a converged golden"),
    (["--warn", "nope=1"], EXIT["usage"], "check.warn.nope: not a number the exact rule"),
    (["--diff", "d.jpg"], EXIT["usage"], "expected a .exr or .png file name"),
]


@pytest.mark.parametrize("extra, code, words", BAD_OPTIONS,
                         ids=[e[0] + "-" + e[1].split("=")[0] for e, _, _ in BAD_OPTIONS])
def test_a_bad_option_is_one_line_with_its_exit_code(pair, capsys, extra, code, words):
    folder, _ = pair
    got, _, err = _diff(folder / "a.exr", folder / "b.exr", *extra, capsys=capsys)
    assert got == code and len(err.splitlines()) == 1 and words in err, err


def test_reports_are_written_and_files_not_ours_are_refused(pair, capsys):
    """--json / --junit are replaced only when they hold a report of this tool, --diff and
    --report never without --force; the difference image is |A - B| (EXR) and the same
    scaled to white (PNG)."""
    folder, b = pair
    a = b.copy()
    a[1, 2] += 0.25
    write_exr(folder / "a.exr", a, overwrite=True)
    scene = folder / "scene.toml"
    scene.write_text("[settings]\n")
    for flag in ("--json", "--junit"):
        assert _diff(folder / "a.exr", folder / "b.exr", flag, scene) == EXIT["file"]
        assert scene.read_text() == "[settings]\n"
    args = [folder / "a.exr", folder / "b.exr", "--json", folder / "v.json", "--junit",
            folder / "v.xml", "--diff", folder / "d.exr", "--report", folder / "rep"]
    assert _diff(*args) == EXIT["fail"]
    assert json.loads((folder / "v.json").read_text())["exit_code"] == EXIT["fail"]
    case = ET.parse(folder / "v.xml").getroot().find("testsuite/testcase")
    assert case.find("failure") is not None and "vs" in case.get("name")
    d = read_exr(folder / "d.exr")
    assert np.allclose(d, np.abs(a - b), atol=1e-7) and d[1, 2].max() > 0.2
    assert (folder / "rep" / "index.html").is_file()
    capsys.readouterr()
    code, _, err = _diff(*args, capsys=capsys)          # d.exr and rep/ exist now
    assert code == EXIT["file"] and "--report" in err and "--force" in err
    code, _, err = _diff(folder / "a.exr", folder / "b.exr", "--diff", folder / "d.exr",
                         capsys=capsys)
    assert code == EXIT["file"] and err.startswith("error: --diff") and "--force" in err
    assert _diff(*args, "--force") == EXIT["fail"]      # the JSON and JUnit are ours
    assert _diff(folder / "a.exr", folder / "b.exr", "--diff", folder / "d.png") == 2
    png = np.asarray(Image.open(folder / "d.png").convert("RGB"))
    assert png.max() == 255 and png[1, 2].max() == 255 and png[0, 0].max() == 0


def test_the_converged_rule_judges_two_converged_goldens(capsys):
    """Converged goldens carry a var layer and their batch count (sidecar): a golden
    against itself passes the t-test, against another view's it fails, and the line below
    names the view."""
    from reference.golden import BUNDLED_STORE

    g = BUNDLED_STORE / "analytic_quad"
    top, oblique = g / "top_classic_converged.exr", g / "oblique_classic_converged.exr"
    assert _diff(top, top, "--rule", "converged", capsys=capsys)[0] == EXIT["ok"]
    code, out, _ = _diff(top, oblique, "--rule", "converged", capsys=capsys)
    assert code == EXIT["fail"] and out.startswith("FAIL ") and "t-test:" in out
    assert "metadata differs: view top (A) vs oblique (B); content_key " in out


def test_images_from_different_settings_print_the_fields_that_differ(tmp_path, capsys):
    """Two of our renders of one scene, one at 1 spp (exact) and one at 4 spp in float64:
    diff prints the metadata fields that differ (mode, spp, precision), not the ones that
    agree (scene key, view, resolution)."""
    for name, extra in (("one", []), ("four", ["--spp", "4", "--precision", "float64"])):
        assert main(["render", "analytic_quad", "--size", "16x16", "--view", "oblique",
                     "--backend", "llvm", "--out", str(tmp_path / name), *extra]) == 0
    a = tmp_path / "four" / "analytic_quad_oblique.exr"
    b = tmp_path / "one" / "analytic_quad_oblique.exr"
    capsys.readouterr()
    code, out, _ = _diff(a, b, capsys=capsys)
    assert code == EXIT["fail"]
    line = [x for x in out.splitlines() if "metadata differs" in x]
    assert line == ["        metadata differs: mode converged (A) vs exact (B); spp 4 (A) vs "
                    "1 (B); precision float64 (A) vs float32 (B)"], out
    assert _diff(b, b, capsys=capsys)[1].count("metadata") == 0      # nothing on a PASS
