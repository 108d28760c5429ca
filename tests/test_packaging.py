"""The wheel is usable on its own: built from the tree (``pip wheel . --no-deps``),
installed into a fresh virtual environment, ``whitted render`` of a bundled scene by its
name works from another folder, reading the scene and mesh files the wheel carries (not
the repository's), and ``whitted data`` copies them out. The dependencies come from the
project's environment (PYTHONPATH), so nothing is downloaded but the build backend."""
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
    assert not any(n.startswith(("tests/", "scenes/")) for n in names)


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
