"""The pytest plugin (``evaluation/gate/pytest_plugin.py``, entry point ``pytest11``): a user's
folder of scenes and golden store become one test per scene view x shading x mode, with the
verdict as the outcome, and ``--junitxml`` lists them."""
from __future__ import annotations

import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from renderer.film import read_exr_layers, write_exr
from whitted.cli import main

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """my_scenes/ (the analytic quad, classic shading only through [check]) and its goldens,
    rendered once, before pytester snapshots the loaded modules (Mitsuba cannot be loaded
    twice in one process)."""
    base = tmp_path_factory.mktemp("plugin")
    scenes = base / "my_scenes"
    scenes.mkdir()
    text = (ROOT / "scenes/analytic_quad.toml").read_text().split("\n[check]")[0]
    (scenes / "quad.toml").write_text(text + '\n[check]\nshadings = ["classic"]\n')
    store = base / "my_goldens"
    assert main(["reference", str(scenes / "quad.toml"), "--goldens", str(store),
                 "--size", "16", "--quiet"]) == 0
    return base


@pytest.fixture
def user_folder(rendered, pytester):
    """The rendered folder in pytester's, one golden made 5 % too bright, and a copy of the
    scene with another kd and no golden."""
    shutil.copytree(rendered, pytester.path, dirs_exist_ok=True)
    scenes, store = pytester.path / "my_scenes", pytester.path / "my_goldens"
    text = (scenes / "quad.toml").read_text()
    exr = store / "quad" / "oblique_classic_exact.exr"
    write_exr(exr, read_exr_layers(exr)[""] * 1.05, overwrite=True)
    (scenes / "nogolden.toml").write_text(text.replace("\nkd = 0.5", "\nkd = 0.3"))
    return scenes, store


def test_plugin_collects_a_folder_of_scenes(pytester, user_folder):
    scenes, store = user_folder
    junit = pytester.path / "out.xml"
    result = pytester.runpytest_subprocess("--whitted-scenes", str(scenes), "--whitted-goldens",
                                str(store), "--whitted-backend", "llvm",
                                f"--junitxml={junit}", "-p", "no:cacheprovider")
    result.assert_outcomes(passed=2, failed=4)
    result.stdout.fnmatch_lines(["*MISSING*nogolden/top classic exact*whitted reference*",
                                 "*quad.toml::oblique-classic-exact*",
                                 "*FAIL*quad/oblique classic exact*"])
    cases = list(ET.parse(junit).getroot().iter("testcase"))
    assert len(cases) == 6
    assert {c.get("name") for c in cases} == {f"{v}-classic-exact"
                                              for v in ("top", "oblique", "grazing")}
    assert sum(c.find("failure") is not None for c in cases) == 4


def test_plugin_reads_ini_options(pytester, user_folder):
    scenes, store = user_folder
    (scenes / "nogolden.toml").unlink()
    pytester.makeini(f"[pytest]\nwhitted_scenes = my_scenes\nwhitted_goldens = {store.name}\n"
                     "whitted_backend = llvm\n")
    result = pytester.runpytest_subprocess("-p", "no:cacheprovider")
    result.assert_outcomes(passed=2, failed=1)
