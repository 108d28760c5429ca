"""Every command works from the wheel: built from the tree (``pip wheel . --no-deps``),
installed into a fresh virtual environment outside the repository, and run from another
folder on a tiny bundled case, reading the scene, mesh, golden and hard-case files the wheel
carries (not the repository's): ``render``, ``data``, ``check``, ``hard-cases`` (one small
case), ``bench --quick`` (one part on one scene, and a folder with no scene of the part:
one error line, no file), ``study`` (one point, then ``--report-only``). The dependencies
come from the project's environment (PYTHONPATH), so nothing is downloaded but the build
backend. ``lab/`` (the experiments) is not in the wheel."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(cmd, **kw):
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=600, **kw)
    assert run.returncode == 0, f"{cmd}: {run.stdout[-2000:]}{run.stderr[-3000:]}"
    return run


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("wheel")
    _run([sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "-q", "-w",
          str(tmp / "dist")], cwd=tmp)
    (wheel,) = (tmp / "dist").glob("whitted-*.whl")
    venv = tmp / "venv"
    _run([getattr(sys, "_base_executable", sys.executable), "-m", "venv", "--without-pip",
          str(venv)])
    py = venv / "bin" / "python"
    _run([sys.executable, "-m", "pip", "--python", str(py), "install", "--no-deps", "-q",
          str(wheel)])
    env = dict(os.environ)
    # the project's dependencies, as a plain path (its .pth files, among them the editable
    # install of this checkout, are not read from PYTHONPATH)
    env["PYTHONPATH"] = sysconfig.get_paths()["purelib"]
    env.pop("PYTHONHOME", None)
    work = tmp / "elsewhere"
    work.mkdir()
    return {"wheel": wheel, "bin": venv / "bin", "env": env, "work": work}


def test_wheel_carries_scenes_meshes_goldens_and_licence(installed):
    names = zipfile.ZipFile(installed["wheel"]).namelist()
    assert "whitted/bundled/scenes/cornell_box.toml" in names
    assert "whitted/bundled/scenes/meshes/stanford_bunny/bun_zipper.ply" in names
    assert "whitted/bundled/scenes/meshes/SOURCES.md" in names
    assert any(n.startswith("reference/goldens/cornell_box/") and n.endswith(".exr")
               for n in names)
    assert any(n.endswith("dist-info/licenses/LICENSE") for n in names)
    assert "evaluation/hard/cases.toml" in names
    assert "evaluation/gate/pytest_plugin.py" in names
    assert not any(n.startswith(("tests/", "scenes/", "lab/")) for n in names)
    entry = next(n for n in names if n.endswith("dist-info/entry_points.txt"))
    points = zipfile.ZipFile(installed["wheel"]).read(entry).decode()
    assert "whitted = evaluation.gate.pytest_plugin" in points


def test_installed_whitted_renders_a_bundled_scene_from_another_folder(installed):
    env, work, bin_ = installed["env"], installed["work"], installed["bin"]
    where = _run([str(bin_ / "python"), "-c", "import whitted, whitted.data as d; "
                  "print(whitted.__file__); print(d.scenes_dir())"], cwd=work, env=env)
    module, scenes = where.stdout.split()
    assert module.startswith(str(bin_.parent)) and scenes.startswith(str(bin_.parent))
    run = _run([str(bin_ / "whitted"), "render", "bunny", "--size", "24x16", "--backend",
                "llvm", "--out", "bunny.png"], cwd=work, env=env)
    assert "69453 triangles" in run.stdout          # the bunny mesh + the floor
    assert (work / "bunny.png").stat().st_size > 100
    _run([str(bin_ / "whitted"), "data", "mine"], cwd=work, env=env)
    assert (work / "mine" / "cornell_box.toml").read_bytes() == (
        ROOT / "scenes" / "cornell_box.toml").read_bytes()
    assert (work / "mine" / "meshes" / "conference" / "conference.ply").exists()
    version = _run([str(bin_ / "whitted"), "--version"], cwd=work, env=env)
    assert version.stdout.strip() == "whitted 0.1.0"


def test_installed_whitted_checks_a_bundled_scene_against_the_bundled_golden(installed):
    """``whitted check bunny`` from a folder with no project in it: the scene by its name
    from the wheel's ``whitted/bundled/scenes``, its goldens found by content in the wheel's
    bundled store (``reference/goldens`` inside the package), every verdict PASS, exit 0."""
    env, work, bin_ = installed["env"], installed["work"], installed["bin"]
    env = {k: v for k, v in env.items() if k != "WHITTED_GOLDENS"}
    run = subprocess.run([str(bin_ / "whitted"), "check", "bunny", "--backend", "llvm",
                          "--json", "verdicts.json"], cwd=work, env=env, capture_output=True,
                         text=True, timeout=600)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    lines = [line for line in run.stdout.splitlines() if line.startswith(("PASS", "WARN",
                                                                          "FAIL", "SIZE",
                                                                          "MISSING", "STALE",
                                                                          "ERROR"))]
    assert len(lines) == 4 and all(line.startswith("PASS") for line in lines), run.stdout
    assert run.stdout.splitlines()[0] == "goldens: the bundled store"
    store = _run([str(bin_ / "python"), "-c", "from reference import golden; "
                  "print(golden.BUNDLED_STORE)"], cwd=work, env=env).stdout.strip()
    assert store.startswith(str(bin_.parent)) and (Path(store) / "bunny").is_dir()
    verdicts = json.loads((work / "verdicts.json").read_text())
    assert verdicts["exit_code"] == 0 and verdicts["counts"]["PASS"] == 4


def _whitted(installed, *args):
    return subprocess.run([str(installed["bin"] / "whitted"), *args], cwd=installed["work"],
                          env=installed["env"], capture_output=True, text=True, timeout=600)


def test_installed_hard_cases_reads_the_case_table_from_the_wheel(installed):
    run = _whitted(installed, "hard-cases", "--cases", "degenerate", "--backend", "llvm",
                   "--precisions", "float32", "--accels", "brute,bvh",
                   "--intersections", "watertight", "--out", "hard")
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    report = json.loads((installed["work"] / "hard" / "hard_cases.json").read_text())
    assert report["passed"] and report["rows"]
    assert {r["case"] for r in report["rows"]} == {"11 degenerate input"}


def test_installed_bench_quick_measures_one_part_or_says_why_not(installed):
    work = installed["work"]
    scenes = Path(_run([str(installed["bin"] / "python"), "-c",
                        "import whitted.data as d; print(d.scenes_dir())"], cwd=work,
                       env=installed["env"]).stdout.strip())
    (work / "one").mkdir()
    (work / "one" / "cornell_box.toml").write_bytes((scenes / "cornell_box.toml").read_bytes())
    run = _whitted(installed, "bench", "--quick", "--backend", "llvm", "--parts", "effects",
                   "--scenes", "one", "--out", "bench")
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    result = json.loads((work / "bench" / "bench-llvm-quick.json").read_text())
    assert [r["scene"] for r in result["effects"]] == ["cornell_box"]
    assert result["effects"][0]["same_pixels"]
    (work / "none").mkdir()
    run = _whitted(installed, "bench", "--quick", "--backend", "llvm", "--parts", "effects",
                   "--scenes", "none", "--out", "bench-none")
    assert run.returncode == 4, run.stdout[-3000:] + run.stderr[-3000:]
    assert run.stderr.count("\n") == 1 and run.stderr.startswith("error: --scenes: ")
    assert not (work / "bench-none").exists() or not any((work / "bench-none").iterdir())


def test_installed_study_runs_a_bundled_scene_by_name(installed):
    work = installed["work"]
    run = _whitted(installed, "study", "cornell_box", "--profile", "tiny", "--size", "8",
                   "--factors", "spp", "--no-grid", "--max-points", "1", "--backend", "llvm",
                   "--no-progress", "--out", "study")
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    data = json.loads((work / "study" / "study.json").read_text())
    assert len(data["points"]) == 1
    (point,) = data["points"].values()
    assert point["scene"] == "cornell_box" and point["errors"]["own"]
    run = _whitted(installed, "study", "--report-only", "--out", "study")
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    assert (work / "study" / "study.md").is_file()
    run = _whitted(installed, "study", "no_such_scene", "--profile", "tiny", "--out", "s2")
    assert run.returncode == 4 and run.stderr.startswith("error: no_such_scene: ")
