"""The pytest plugin (``evaluation/gate/pytest_plugin.py``, entry point ``pytest11``): a user's
folder of scenes and golden store become one test per scene view x shading x mode, with the
verdict as the outcome, and ``--junitxml`` lists them."""
from __future__ import annotations

import re
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from renderer.film import read_exr, read_exr_layers, read_exr_metadata, write_exr
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
                                 "*oblique-classic-exact (quad.toml)*",
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


def _run(pytester, *args):
    return pytester.runpytest_subprocess("--whitted-backend", "llvm", "-p", "no:cacheprovider",
                                         *args)


def test_a_scene_file_argument_runs_only_that_files_cases(pytester, user_folder):
    scenes, store = user_folder
    for extra in (("--whitted-scenes", str(scenes)), ()):
        result = _run(pytester, *extra, "--whitted-goldens", str(store), "-v",
                      "my_scenes/quad.toml")
        result.assert_outcomes(passed=2, failed=1)
        assert "nogolden" not in result.stdout.str()


def test_a_node_id_as_verbose_prints_it_runs_that_one_case(pytester, user_folder):
    scenes, store = user_folder
    listed = _run(pytester, "--whitted-scenes", str(scenes), "--whitted-goldens", str(store),
                  "-v")
    ids = [line.split()[0] for line in listed.stdout.lines
           if line.split() and line.split()[-2:-1] and line.split()[1] in ("PASSED", "FAILED")]
    assert "my_scenes/quad.toml::oblique-classic-exact" in ids, listed.stdout.str()
    assert len(ids) == 6
    for node in ("my_scenes/quad.toml::oblique-classic-exact",
                 "my_scenes/nogolden.toml::grazing-classic-exact"):
        again = _run(pytester, "--whitted-scenes", str(scenes), "--whitted-goldens",
                     str(store), "-v", node)
        again.assert_outcomes(failed=1)
        again.stdout.fnmatch_lines([f"{node} FAILED*"])


def test_k_selects_cases_by_file_and_case_name(pytester, user_folder):
    scenes, store = user_folder
    result = _run(pytester, "--whitted-scenes", str(scenes), "--whitted-goldens", str(store),
                  "-k", "quad and not oblique")
    result.assert_outcomes(passed=2)


def test_a_failing_case_writes_ours_the_golden_and_their_difference(pytester, user_folder):
    """The planted 5 % golden fails and writes its images (the paths in the report); the
    passing cases and the cases without a golden write none; once it passes again its
    images are gone."""
    scenes, store = user_folder
    results = pytester.path / "results"
    result = _run(pytester, "--whitted-scenes", str(scenes), "--whitted-goldens", str(store),
                  "--whitted-results", str(results))
    result.assert_outcomes(passed=2, failed=4)
    case = results / "my_scenes" / "quad" / "oblique-classic-exact"
    names = {"ours.exr", "ours.png", "golden.exr", "golden.png", "diff.exr", "diff.png",
             "rule.png"}
    written = sorted(p.relative_to(results) for p in results.rglob("*") if p.is_file())
    assert written == sorted(Path("my_scenes/quad/oblique-classic-exact") / n for n in names)
    for n in names:
        result.stdout.fnmatch_lines([f"*{case / n}"])
    ours, golden = read_exr(case / "ours.exr"), read_exr(case / "golden.exr")
    planted = read_exr(store / "quad" / "oblique_classic_exact.exr")
    assert np.array_equal(golden, planted)
    assert np.allclose(read_exr(case / "diff.exr"), np.abs(ours - golden), atol=1e-7)
    assert np.abs(ours - golden).max() > 0.01
    meta = read_exr_metadata(case / "ours.exr")
    assert meta["renderer"].startswith("whitted ") and meta["backend"] == "llvm"
    assert meta["view"] == "oblique" and meta["mode"] == "exact" and meta["spp"] == "1"
    assert read_exr_metadata(case / "golden.exr")["renderer"].startswith("mitsuba ")
    from PIL import Image
    for n in ("ours.png", "golden.png", "diff.png", "rule.png"):
        assert Image.open(case / n).size == (ours.shape[1], ours.shape[0])
    rule = np.asarray(Image.open(case / "rule.png").convert("RGB"))
    hard = int(re.search(r"FAIL .*oblique classic exact: ([\d,]+) pixels above",
                         result.stdout.str()).group(1).replace(",", ""))
    assert hard > 0 and (rule == (255, 0, 0)).all(-1).sum() == hard    # hard pixels in red

    # the golden put right: the case passes and its images are removed
    exr = store / "quad" / "oblique_classic_exact.exr"
    write_exr(exr, planted / 1.05, overwrite=True)
    again = _run(pytester, "--whitted-scenes", str(scenes), "--whitted-goldens", str(store),
                 "--whitted-results", str(results), "my_scenes/quad.toml")
    again.assert_outcomes(passed=3)
    assert not [p for p in results.rglob("*") if p.is_file()]


def test_the_default_results_folder_is_out_whitted_results(pytester, user_folder):
    scenes, store = user_folder
    _run(pytester, "--whitted-goldens", str(store),
         "my_scenes/quad.toml::oblique-classic-exact").assert_outcomes(failed=1)
    folder = pytester.path / "out" / "whitted-results" / "my_scenes" / "quad"
    assert (folder / "oblique-classic-exact" / "diff.png").is_file()
