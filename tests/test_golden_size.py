"""Goldens are rendered at the scene's own resolution unless its ``[check]`` table (``size``,
``converged_size``) or the command line says otherwise, and ``check`` reports pixels in that
resolution; the bundled goldens have the size their scene files name."""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from reference import golden
from renderer.film import read_exr_layers, write_exr
from renderer.scene import SceneError, load_scene
from whitted.cli import main

ROOT = Path(__file__).resolve().parents[1]

#: One diffuse quad under one light, 320 x 240, one view (exact goldens take a second).
SCENE = """\
description = "A quad at 320 x 240"
ambient = 0.05

[render]
max_depth = 0
shading = "classic"

[camera]
resolution = [320, 240]
up = [0.0, 0.0, -1.0]

[[views]]
name = "top"
position = [0.0, 3.0, 0.0]
target = [0.0, 0.0, 0.0]
fov_y = 45.0

[[lights]]
name = "point"
position = [0.3, 1.0, 0.2]
intensity = 1.0

[materials.diffuse]
kd = 0.5

[[objects]]
name = "quad"
shape = "quad"
material = "diffuse"
scale = [2.0, 1.0, 2.0]
"""
PICK = ["--modes", "exact", "--shadings", "classic"]


def _reference(scene, store, *extra) -> int:
    return main(["reference", str(scene), "--goldens", str(store), "--quiet", *PICK, *extra])


def _golden(store, name="quad", view="top", mode="exact"):
    exr = Path(store) / name / f"{view}_classic_{mode}.exr"
    return read_exr_layers(exr)[""], json.loads(exr.with_suffix(".json").read_text())


def test_a_320x240_scene_gets_320x240_goldens_and_pixels_in_that_size(tmp_path, capsys):
    pytest.importorskip("mitsuba")
    scene, store = tmp_path / "quad.toml", tmp_path / "goldens"
    scene.write_text(SCENE)
    assert _reference(scene, store) == 0
    image, meta = _golden(store)
    assert image.shape == (240, 320, 3) and meta["resolution"] == [320, 240]
    # a pixel planted far down and right (outside any 256-high image): the verdict names it
    exr = store / "quad" / "top_classic_exact.exr"
    image[230, 310] += 0.25
    write_exr(exr, image, overwrite=True)
    capsys.readouterr()
    assert main(["check", str(scene), "--goldens", str(store), *PICK, "--backend", "llvm",
                 "--json", "-"]) == 2
    (v,) = json.loads(capsys.readouterr().out)["verdicts"]
    assert v["status"] == "FAIL" and v["result"]["hard"] == [[230, 310]]


def test_check_size_wins_over_the_resolution_and_the_command_line_over_both(tmp_path):
    pytest.importorskip("mitsuba")
    scene = tmp_path / "quad.toml"
    scene.write_text(SCENE + "\n[check]\nsize = [40, 30]\nconverged_size = [16, 12]\n")
    assert _reference(scene, tmp_path / "a") == 0
    assert _golden(tmp_path / "a")[0].shape == (30, 40, 3)
    assert _reference(scene, tmp_path / "b", "--size", "24") == 0      # height; 4:3 kept
    assert _golden(tmp_path / "b")[1]["resolution"] == [32, 24]
    s = load_scene(scene)
    assert golden.golden_size(s, "converged") == (16, 12)
    assert golden.golden_size(s, "converged", size=24) == (32, 24)
    assert golden.golden_size(s, "converged", size=24, converged_size=12) == (16, 12)


def test_converged_size_sets_the_converged_goldens(tmp_path):
    pytest.importorskip("mitsuba")
    scene = tmp_path / "quad.toml"
    scene.write_text(SCENE + "\n[check]\nsize = [40, 30]\nconverged_size = [8, 6]\n")
    jobs = golden.golden_jobs([scene], modes=("exact", "converged"), shadings=("classic",),
                              root=tmp_path / "g")
    assert {j["mode"]: (j["width"], j["height"]) for j in jobs} == \
        {"exact": (40, 30), "converged": (8, 6)}
    plain = tmp_path / "plain" / "quad.toml"
    plain.parent.mkdir()
    plain.write_text(SCENE)
    jobs = golden.golden_jobs([plain], modes=("exact", "converged"), shadings=("classic",),
                              root=tmp_path / "g")
    assert {j["mode"]: (j["width"], j["height"]) for j in jobs} == \
        {"exact": (0, 0), "converged": (0, 0)}          # 0: each view's own resolution


def test_a_golden_of_another_size_is_stale_for_reference_and_replaced_with_force(tmp_path,
                                                                                  capsys):
    pytest.importorskip("mitsuba")
    scene, store = tmp_path / "quad.toml", tmp_path / "goldens"
    scene.write_text(SCENE + "\n[check]\nsize = [40, 30]\n")
    assert _reference(scene, store) == 0
    before = (store / "quad" / "top_classic_exact.exr").read_bytes()
    scene.write_text(SCENE + "\n[check]\nsize = [48, 36]\n")
    # check still finds it (the [check] table is not in the key) ...
    assert golden.find_golden(load_scene(scene), view=0, shading="classic", mode="exact",
                              stores=[store]).status == "ok"
    # ... but reference says the size changed and replaces it only with --force
    capsys.readouterr()
    assert _reference(scene, store) == 4
    err = capsys.readouterr().err
    assert "size 40x30 -> 48x36" in err and "--force" in err
    assert (store / "quad" / "top_classic_exact.exr").read_bytes() == before
    assert _reference(scene, store, "--force") == 0
    assert _golden(store)[1]["resolution"] == [48, 36]


@pytest.mark.parametrize("table,field", [
    ("size = [0, 30]", "check.size[0]"),
    ("size = [40]", "check.size"),
    ("size = 40", "check.size"),
    ("converged_size = [8, 2.5]", "check.converged_size[1]"),
    ("size = [100000, 100000]", "check.size"),
])
def test_a_bad_check_size_names_the_field(table, field, tmp_path):
    scene = tmp_path / "quad.toml"
    scene.write_text(SCENE + f"\n[check]\n{table}\n")
    with pytest.raises(SceneError, match=rf"quad\.toml: {re.escape(field)}: "):
        load_scene(scene)


def test_every_bundled_golden_has_the_size_its_scene_names():
    """Every view of every bundled scene has goldens, and each bundled golden's resolution is
    what the harness renders now (the scene's ``[check]`` size, else the view's resolution),
    so re-rendering keeps its size."""
    paths = [*ROOT.glob("scenes/*.toml"), *ROOT.glob("scenes/cases/*.toml")]
    scenes = {(p.stem, sh): load_scene(p, shading=sh) for p in paths
              for sh in ("classic", "physical")}
    seen = set()
    for side in sorted(golden.BUNDLED_STORE.glob("*/*.json")):
        meta = json.loads(side.read_text())
        scene = scenes[meta["scene_name"], meta["shading"]]
        cam = scene.cameras[meta["view"]]
        want = golden.golden_size(scene, meta["mode"]) or (cam.width, cam.height)
        assert meta["resolution"] == list(want), side.name
        seen.add((meta["scene_name"], meta["view_name"]))
    # every bundled scene has goldens, of every view (`whitted check scenes/*.toml` finds them)
    want = {(name, cam.name) for (name, _), s in scenes.items() for cam in s.cameras}
    assert want <= seen, sorted(want - seen)
