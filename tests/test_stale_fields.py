"""A STALE verdict says which input changed: the scene field (by its TOML path, with the old
and the new value), the mesh (by file name), the harness file, or the Mitsuba version. The
sidecar records the scene's fields (``scene_fields``); the lookup compares them one by one."""
from __future__ import annotations

import json
import shutil

import pytest

from reference import golden
from renderer.scene import load_scene
from whitted.cli import main

#: A quad and a one-triangle OBJ under one light (goldens: 8 pixels high, a second to render).
SCENE = """\
description = "A quad and a triangle"
ambient = 0.05

[render]
max_depth = 1
shading = "classic"

[camera]
resolution = [12, 8]

[[views]]
name = "front"
position = [0.0, 1.0, 3.0]
target = [0.0, 0.0, 0.0]

[[lights]]
name = "key"
position = [1.0, 2.0, 1.0]
intensity = 1.0

[materials.floor]
kd = 0.5

[materials.paint]
kd = [0.8, 0.2, 0.1]
ks = 0.3
n = 20

[[objects]]
name = "floor"
shape = "quad"
material = "floor"
scale = [2.0, 1.0, 2.0]

[[objects]]
name = "tri"
mesh = "tri.obj"
material = "paint"
"""
OBJ = "v -0.5 0.1 0.0\nv 0.5 0.1 0.0\nv 0.0 0.9 0.0\nf 1 2 3\n"
PICK = ["--modes", "exact", "--shadings", "classic"]


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    """(folder with scene.toml + tri.obj, golden store) rendered once by `whitted reference`."""
    pytest.importorskip("mitsuba")
    base = tmp_path_factory.mktemp("stale")
    (base / "scene.toml").write_text(SCENE)
    (base / "tri.obj").write_text(OBJ)
    assert main(["reference", str(base / "scene.toml"), "--goldens", str(base / "goldens"),
                 "--quiet", *PICK]) == 0
    return base, base / "goldens"


def _changes(store, tmp_path, scene_text=SCENE, obj_text=OBJ) -> list[str]:
    """What the lookup says changed for an edited copy of the scene (same file name)."""
    base, goldens = store
    (tmp_path / "scene.toml").write_text(scene_text)
    (tmp_path / "tri.obj").write_text(obj_text)
    found = golden.find_golden(load_scene(tmp_path / "scene.toml"), view=0, shading="classic",
                               mode="exact", stores=[goldens])
    assert found.status == "stale"
    assert "; ".join(found.changes) in found.message
    return found.changes


def test_the_sidecar_records_the_scene_fields(store):
    _, goldens = store
    meta = json.loads((goldens / "scene" / "front_classic_exact.json").read_text())
    assert meta["scene_fields"]["materials.paint.kd"] == [0.8, 0.2, 0.1]
    assert meta["scene_fields"]["lights[0].position"] == [1.0, 2.0, 1.0]
    assert golden.find_golden(load_scene(store[0] / "scene.toml"), view=0, shading="classic",
                              mode="exact", stores=[goldens]).status == "ok"


def test_a_material_field_is_named(store, tmp_path):
    edited = SCENE.replace("ks = 0.3", "ks = 0.35")
    assert _changes(store, tmp_path, edited) == ["materials.paint.ks 0.3 -> 0.35"]


def test_a_light_field_is_named(store, tmp_path):
    edited = SCENE.replace("position = [1.0, 2.0, 1.0]", "position = [1.0, 2.5, 1.0]")
    assert _changes(store, tmp_path, edited) == \
        ["lights[0].position [1.0, 2.0, 1.0] -> [1.0, 2.5, 1.0]"]


def test_camera_and_settings_fields_are_named_and_added_keys_too(store, tmp_path):
    edited = SCENE.replace("max_depth = 1", "max_depth = 2").replace(
        'target = [0.0, 0.0, 0.0]', 'target = [0.0, 0.0, 0.0]\nfov_y = 35.0')
    assert _changes(store, tmp_path, edited) == ["render.max_depth 1 -> 2",
                                                 "views[0].fov_y added (35.0)"]


def test_many_changed_fields_are_counted(store, tmp_path):
    edited = SCENE.replace("0.5", "0.55").replace("0.8", "0.85").replace("1.0", "1.5")
    changes = _changes(store, tmp_path, edited)
    assert len(changes) == golden.FIELDS_NAMED + 1 and changes[-1].endswith("more scene fields")


def test_a_mesh_file_is_named(store, tmp_path):
    changes = _changes(store, tmp_path, obj_text=OBJ.replace("0.9", "0.95"))
    assert changes == ["mesh tri.obj (its bytes)"]


def test_a_harness_file_is_named(store, tmp_path, monkeypatch):
    real = golden.harness_hashes()
    monkeypatch.setattr(golden, "harness_hashes",
                        lambda: {**real, "renderer/scene/shapes.py": "0" * 64})
    assert _changes(store, tmp_path) == ["harness file renderer/scene/shapes.py"]


def test_the_mitsuba_version_is_named(store, tmp_path, monkeypatch):
    monkeypatch.setattr(golden, "mitsuba_version", lambda: "3.99.0")
    (change,) = _changes(store, tmp_path)
    assert change.startswith("Mitsuba version ") and change.endswith(" -> 3.99.0")


def test_a_sidecar_without_fields_says_scene_file_content(store, tmp_path):
    """Goldens written before sidecars recorded the fields: the change is still found."""
    base, goldens = store
    old = tmp_path / "old_store"
    shutil.copytree(goldens, old)
    side = old / "scene" / "front_classic_exact.json"
    meta = json.loads(side.read_text())
    del meta["scene_fields"]
    side.write_text(json.dumps(meta))
    assert _changes((base, old), tmp_path, SCENE.replace("ks = 0.3", "ks = 0.35")) == \
        ["scene file content"]


def test_the_check_line_names_the_field(store, tmp_path, capsys):
    _, goldens = store
    (tmp_path / "scene.toml").write_text(SCENE.replace("n = 20", "n = 40"))
    (tmp_path / "tri.obj").write_text(OBJ)
    capsys.readouterr()
    assert main(["check", str(tmp_path / "scene.toml"), "--goldens", str(goldens), *PICK,
                 "--backend", "llvm"]) == 4
    (line,) = [x for x in capsys.readouterr().out.splitlines() if x.startswith("STALE")]
    assert "changed since it was rendered: materials.paint.n 20 -> 40" in line
    assert "--force" in line
