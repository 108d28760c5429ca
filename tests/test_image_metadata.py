"""Image metadata (``evaluation.gate.imagemeta``): EXR header attributes ``whitted:<field>``
that our renders, check's images and goldens carry, and the fields ``check`` prints when ours
and the golden disagree.

One store per module: the analytic quad (classic shading, exact mode, 3 views) rendered by
``whitted reference`` at 8 px."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from evaluation.gate.imagemeta import differences, image_metadata, ours_metadata
from reference import golden
from renderer.film import read_exr, read_exr_layers, read_exr_metadata, write_exr
from renderer.scene import load_scene
from whitted.cli import main
from whitted.options import EXIT

ROOT = Path(__file__).resolve().parents[1]
QUAD = ROOT / "scenes" / "analytic_quad.toml"


def test_metadata_round_trips_through_the_exr_header(tmp_path):
    img = np.linspace(0, 1, 2 * 3 * 3, dtype=np.float32).reshape(2, 3, 3)
    meta = {"spp": 4, "scene_key": "ab" * 32, "view": "front (left)", "note": "ü, = ; x"}
    p = write_exr(tmp_path / "m.exr", img, layers={"var": img * 0.5}, metadata=meta)
    assert read_exr_metadata(p) == {k: str(v) for k, v in meta.items()}
    layers = read_exr_layers(p)
    assert np.array_equal(layers[""], img) and np.array_equal(layers["var"], img * 0.5)
    assert read_exr_metadata(write_exr(tmp_path / "plain.exr", img)) == {}
    with pytest.raises(ValueError, match="not an OpenEXR file"):
        (tmp_path / "x.exr").write_bytes(b"hello")
        read_exr_metadata(tmp_path / "x.exr")


def with_check(text: str, lines: str) -> str:
    """The scene text with ``lines`` in its ``[check]`` table (added when it has none)."""
    if "\n[check]\n" in text:
        return text.replace("\n[check]\n", "\n[check]\n" + lines, 1)
    return text + "\n[check]\n" + lines


def test_our_scene_key_is_the_golden_s_for_the_same_content(tmp_path):
    """ours_metadata's scene_key equals the bundled golden's (its sidecar) for the bundled
    scene and for a copy with another [check] table, and differs for an edited material."""
    side = json.loads((golden.BUNDLED_STORE / "analytic_quad" /
                       "top_classic_exact.json").read_text())
    theirs = golden.golden_metadata(side)
    ours = ours_metadata(load_scene(QUAD), 0, backend="llvm", precision="float32")
    assert ours["scene_key"] == theirs["scene_key"] and len(ours["scene_key"]) == 64
    copy = tmp_path / "copy.toml"
    copy.write_text(with_check(QUAD.read_text(), 'shadings = ["classic"]\n'))
    assert ours_metadata(load_scene(copy), 0, backend="llvm",
                         precision="float32")["scene_key"] == theirs["scene_key"]
    edited = tmp_path / "edited.toml"
    edited.write_text(QUAD.read_text().replace("\nkd = 0.5", "\nkd = 0.3"))
    assert "kd = 0.3" in edited.read_text()
    other = ours_metadata(load_scene(edited), 0, backend="llvm", precision="float32")
    assert other["scene_key"] != theirs["scene_key"]
    skip = ("renderer", "resolution")     # the golden's size is the store's choice
    diff = differences(other, theirs, names=("ours", "golden"), ignore=skip)
    assert diff[0] == "scene edited (ours) vs analytic_quad (golden)"
    assert diff[1].startswith("scene_key ") and len(diff) == 2     # the settings agree
    # the same content under another file name: the name alone is not a difference
    assert differences(ours_metadata(load_scene(copy), 0, backend="llvm",
                                     precision="float32"), theirs, ignore=skip) == []


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    base = tmp_path_factory.mktemp("meta")
    scene = base / "quad.toml"
    scene.write_text(with_check(QUAD.read_text(), 'shadings = ["classic"]\nmodes = ["exact"]\n'))
    store = base / "goldens"
    assert main(["reference", str(scene), "--goldens", str(store), "--size", "8",
                 "--quiet"]) == 0
    return base, scene, store


def test_a_golden_written_now_carries_its_metadata_in_the_header(store):
    _, _, root = store
    exrs = sorted((root / "quad").glob("*.exr"))
    assert len(exrs) == 3
    for exr in exrs:
        side = json.loads(exr.with_suffix(".json").read_text())
        head = read_exr_metadata(exr)
        assert head == golden.golden_metadata(side)
        assert head["content_key"] == side["content_key"]
        assert head["renderer"] == f"mitsuba {side['mitsuba_version']} ({side['variant']})"
        assert head["mode"] == "exact" and head["spp"] == "1" and head["resolution"] == "8x8"
        assert head["view"] == side["view_name"] and head["shading"] == "classic"


def test_a_golden_without_header_metadata_is_described_by_its_sidecar(store, tmp_path):
    _, _, root = store
    exr = tmp_path / "top_classic_exact.exr"
    write_exr(exr, read_exr(root / "quad" / exr.name))
    shutil.copy(root / "quad" / exr.with_suffix(".json").name, tmp_path)
    assert read_exr_metadata(exr) == {}
    assert image_metadata(exr) == read_exr_metadata(root / "quad" / exr.name)
    exr.with_suffix(".json").write_text("[1, 2]")
    assert image_metadata(exr) == {}


def test_check_prints_the_fields_that_differ_when_ours_and_the_golden_disagree(
        store, tmp_path, capsys):
    """A golden made 5 % brighter fails; checked in float64 the line below the verdict
    names the precision (ours float64, the golden float32); in float32 nothing differs but
    the renderer, and no metadata line is printed. The report's EXRs carry both sides'."""
    _, scene, root = store
    tampered = tmp_path / "goldens"
    shutil.copytree(root, tampered)
    exr = tampered / "quad" / "top_classic_exact.exr"
    write_exr(exr, read_exr(exr) * 1.05, overwrite=True)
    capsys.readouterr()
    args = ["check", str(scene), "--goldens", str(tampered), "--backend", "llvm",
            "--view", "top"]
    assert main([*args, "--precision", "float64", "--report", str(tmp_path / "rep"),
                 "--json", str(tmp_path / "v.json")]) == EXIT["fail"]
    lines = capsys.readouterr().out.splitlines()
    at = next(i for i, x in enumerate(lines) if x.startswith("FAIL "))
    assert lines[at + 1] == ("        metadata differs: precision float64 (ours) vs "
                             "float32 (golden)")
    v = json.loads((tmp_path / "v.json").read_text())["verdicts"][0]
    assert v["differences"] == ["precision float64 (ours) vs float32 (golden)"]
    assert v["metadata"]["ours"]["precision"] == "float64"
    ours_exr = next((tmp_path / "rep").rglob("ours.exr"))
    assert read_exr_metadata(ours_exr)["precision"] == "float64"
    assert read_exr_metadata(ours_exr.parent / "mitsuba.exr")["renderer"].startswith("mitsuba")
    assert main(args) == EXIT["fail"]
    out = capsys.readouterr().out
    assert "FAIL " in out and "metadata differs" not in out
