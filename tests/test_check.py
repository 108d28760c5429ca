"""The regression gate: ``whitted check`` verdicts and exit codes, golden stores keyed by
content, the bundled store kept read-only, JUnit/JSON/HTML outputs, per-scene thresholds.

One user folder is set up per module: a copy of the analytic quad scene (3 views) and a
golden store rendered into it by ``whitted reference`` at 24 px (6 exact goldens).
"""
from __future__ import annotations

import hashlib
import json
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from evaluation.gate import verdict as vd
from reference import golden
from renderer.film import read_exr_layers, write_exr
from renderer.scene import SceneError, load_scene
from whitted.cli import main

ROOT = Path(__file__).resolve().parents[1]
QUAD = ROOT / "scenes" / "analytic_quad.toml"


@pytest.fixture(scope="module")
def user(tmp_path_factory):
    """(folder, scene copy, store) with the store rendered by ``whitted reference``."""
    base = tmp_path_factory.mktemp("user")
    scenes = base / "my_scenes"
    scenes.mkdir()
    scene = scenes / "quad.toml"
    scene.write_text(QUAD.read_text().split("\n[check]")[0])    # a user's scene: no [check]
    store = base / "my_goldens"
    assert main(["reference", "--goldens", str(store), "--size", "24", "--quiet",
                 str(scene)]) == 0
    return base, scene, store


def _check(*args) -> int:
    return main(["check", *map(str, args), "--backend", "llvm"])


def _tampered_store(store: Path, dest: Path, factor: float = 1.05) -> Path:
    """A copy of ``store`` whose ``top_classic_exact`` golden is ``factor`` times brighter."""
    shutil.copytree(store, dest)
    exr = dest / "quad" / "top_classic_exact.exr"
    write_exr(exr, read_exr_layers(exr)[""] * factor, overwrite=True)
    return dest


def _tree_hashes(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


# ---- verdicts and exit codes ----------------------------------------------------------------
def test_check_exits_0_on_the_real_renderer_and_2_on_a_broken_one(user, monkeypatch, capsys):
    _, scene, store = user
    assert _check(scene, "--goldens", store) == 0
    lines = capsys.readouterr().out.splitlines()
    assert sum(line.startswith("PASS") for line in lines) == 6

    from renderer.render import Renderer
    real = Renderer.render

    def five_percent_bright(self, view=0, **kw):     # kw: the CLI's progress / stop
        res = real(self, view, **kw)
        res.image = np.asarray(res.image) * 1.05
        return res
    monkeypatch.setattr(Renderer, "render", five_percent_bright)
    assert _check(scene, "--goldens", store) == 2
    out = capsys.readouterr().out
    assert out.count("\nFAIL") == 6


def test_check_exits_2_on_a_one_pixel_crack(user, monkeypatch, capsys):
    """A crack of one pixel fails: the exact rule excuses only pixels the tie probe shows
    to depend on a tie (the crack is in both of the gate's renders, as a renderer's crack
    would be: the probe's second pass never runs where the first found nothing), or that
    the nudge probe shows ill-conditioned (the crack is not in the probe's renders, so ours
    lies outside their range)."""
    _, scene, store = user
    from renderer.render import Renderer
    real = Renderer.render

    def one_black_pixel(self, view=0, **kw):    # a crack of one pixel in the lit quad
        res = real(self, view, **kw)
        img = np.array(res.image)
        h, w, _ = img.shape
        img[h // 2, w // 2] = 0
        res.image = img
        return res
    monkeypatch.setattr(Renderer, "render", one_black_pixel)
    assert _check(scene, "--goldens", store, "--view", "top", "--shadings", "classic",
                  "--json", "-") == 2
    v = json.loads(capsys.readouterr().out)["verdicts"][0]
    assert v["status"] == "FAIL" and v["result"]["hard_pixels"] == 1
    assert v["result"]["hard"] == [[12, 12]]
    assert "where neither the tie probe nor the nudge probe excuses" in v["reason"]


def test_edited_material_is_stale_and_says_what_changed(user, tmp_path, capsys):
    _, scene, store = user
    edited = tmp_path / "quad.toml"
    edited.write_text(scene.read_text().replace("\nkd = 0.5", "\nkd = 0.4"))
    assert _check(edited, "--goldens", store) == 4
    out = capsys.readouterr().out
    stale = [line for line in out.splitlines() if line.startswith("STALE")]
    assert len(stale) == 6
    assert "changed since it was rendered: materials.diffuse.kd 0.5 -> 0.4)" in stale[0]
    assert f"whitted reference --goldens {golden._display(store)} --force" in stale[0]
    # the store's file is kept without --force, replaced with it
    private = tmp_path / "store"
    shutil.copytree(store, private)
    before = _tree_hashes(private)
    assert main(["reference", "--goldens", str(private), "--size", "24", "--quiet",
                 str(edited)]) == 4
    assert "pass --force" in capsys.readouterr().err
    assert _tree_hashes(private) == before
    assert main(["reference", "--goldens", str(private), "--size", "24", "--quiet", "--force",
                 str(edited)]) == 0
    assert _check(edited, "--goldens", private) == 0


def test_missing_golden_exits_4_and_names_the_command(user, tmp_path, capsys):
    _, scene, _ = user
    empty = tmp_path / "empty_store"
    edited = tmp_path / "new.toml"
    edited.write_text(scene.read_text().replace("\nkd = 0.5", "\nkd = 0.3"))
    assert _check(edited, "--goldens", empty, "--view", "top", "--shadings", "classic") == 4
    line = capsys.readouterr().out.splitlines()[1]
    assert line.startswith("MISSING") and "whitted reference --goldens" in line


def test_a_pass_a_fail_and_a_missing_golden_in_one_run(user, tmp_path, capsys):
    """The done-means run: JUnit parses with one testcase per verdict, JSON and the exit code
    agree, the HTML report puts the failure first and shows the thresholds."""
    _, scene, store = user
    tampered = _tampered_store(store, tmp_path / "goldens")
    other = tmp_path / "other.toml"
    other.write_text(scene.read_text().replace("\nkd = 0.5", "\nkd = 0.3"))
    junit, js, rep = tmp_path / "out.xml", tmp_path / "out.json", tmp_path / "report"
    code = _check(scene, other, "--goldens", tampered, "--shadings", "classic",
                  "--junit", junit, "--json", js, "--report", rep)
    assert code == 4
    data = json.loads(js.read_text())
    statuses = [v["status"] for v in data["verdicts"]]
    assert statuses == ["FAIL", "PASS", "PASS", "MISSING", "MISSING", "MISSING"]
    assert data["exit_code"] == 4 and data["counts"]["FAIL"] == 1
    suite = ET.parse(junit).getroot().find("testsuite")
    cases = suite.findall("testcase")
    assert len(cases) == 6 and suite.get("failures") == "1" and suite.get("errors") == "3"
    assert cases[0].find("failure").get("type") == "FAIL"
    assert cases[3].find("error").get("message").startswith("MISSING")
    assert {c.get("classname") for c in cases} == {"whitted.quad", "whitted.other"}
    page = (rep / "index.html").read_text()
    assert page.index('class="verdict v-FAIL"') < page.index('class="verdict v-PASS"')
    assert "max_rel" in page and "tie_slack" in page
    # the failing exact case shows the rule's verdict drawn over the golden: all red (the
    # tampered golden is 5 % off everywhere the quad is lit), the passing ones do not
    drawn = list(rep.glob("*/rule.png"))
    assert len(drawn) == 1 and "exact rule" in page
    from PIL import Image
    img = np.asarray(Image.open(drawn[0]))
    assert (np.all(img == (255, 0, 0), axis=-1)).sum() == data["verdicts"][0]["result"][
        "hard_pixels"] > 0


def test_size_mismatch_exits_3_in_compare(user, capsys):
    _, scene, store = user
    assert main(["compare", str(scene), "--goldens", str(store), "--backend", "llvm",
                 "--size", "32x24", "--out", str(store.parent / "cmp_size")]) == 3
    assert "SIZE" in capsys.readouterr().out


def test_compare_gives_the_same_verdict_and_exit_code(user, tmp_path, capsys):
    _, scene, store = user
    assert main(["compare", str(scene), "--goldens", str(store), "--backend", "llvm",
                 "--size", "24x24", "--out", str(tmp_path / "ok")]) == 0
    assert capsys.readouterr().out.count("PASS") >= 1
    tampered = _tampered_store(store, tmp_path / "goldens")
    assert main(["compare", str(scene), "--goldens", str(tampered), "--backend", "llvm",
                 "--size", "24x24", "--out", str(tmp_path / "bad")]) == 2
    assert "FAIL" in capsys.readouterr().out


def test_compare_passes_the_bundled_cornell_box(tmp_path, capsys):
    """The main job's comparison (ci/main.sh): mirror and glass in sight, so ours must trace
    the reference's rays (its spawn rule) for the exact rule to pass."""
    assert main(["compare", str(ROOT / "scenes/cornell_box.toml"), "--view", "all",
                 "--backend", "llvm", "--out", str(tmp_path / "cmp")]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert sum(ln.startswith("PASS") for ln in lines) == 3, out
    assert not any(ln.startswith("FAIL") for ln in lines), out


# ---- stores ---------------------------------------------------------------------------------
def test_bundled_store_is_untouched_by_reference_on_a_copy(tmp_path, monkeypatch, capsys):
    before = _tree_hashes(golden.BUNDLED_STORE)
    copy = tmp_path / "cornell_box.toml"
    text = (ROOT / "scenes/cornell_box.toml").read_text()
    copy.write_text(text.replace("max_depth = 5", "max_depth = 4", 1))   # an edited copy
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv(golden.STORE_ENV, raising=False)
    assert main(["reference", "--force", "--quiet", str(copy)]) == 4     # no store: refused
    assert "read-only" in capsys.readouterr().err
    monkeypatch.setenv(golden.STORE_ENV, str(golden.BUNDLED_STORE))
    assert main(["reference", "--force", "--quiet", str(copy)]) == 4     # bundled: refused
    assert "read-only" in capsys.readouterr().err
    monkeypatch.delenv(golden.STORE_ENV)
    assert main(["reference", str(copy), "--goldens", str(tmp_path / "g"), "--force",
                 "--quiet", "--size", "16", "--shadings", "classic"]) == 0
    assert (tmp_path / "g" / "cornell_box" / "front_classic_exact.exr").is_file()
    assert _tree_hashes(golden.BUNDLED_STORE) == before


def test_identical_copy_of_a_bundled_scene_finds_its_bundled_golden(tmp_path):
    for name, meshes in (("analytic_quad", None), ("bunny", "stanford_bunny")):
        copy = tmp_path / name / f"{name}.toml"
        copy.parent.mkdir()
        shutil.copy(ROOT / "scenes" / f"{name}.toml", copy)
        if meshes:
            shutil.copytree(ROOT / "scenes/meshes" / meshes, copy.parent / "meshes" / meshes)
        found = golden.find_golden(load_scene(copy), view=0, shading="classic", mode="exact",
                                   stores=golden.search_stores(tmp_path / "none"))
        assert found.status == "ok", found.message
        assert found.path.parent.parent == golden.BUNDLED_STORE


def test_sidecars_store_no_absolute_paths(user):
    def strings(x):
        if isinstance(x, dict):
            for k, v in x.items():
                yield k
                yield from strings(v)
        elif isinstance(x, list):
            for v in x:
                yield from strings(v)
        elif isinstance(x, str):
            yield x

    sides = list(golden.BUNDLED_STORE.glob("*/*.json")) + list(user[2].glob("*/*.json"))
    assert len(sides) > 50
    for side in sides:
        meta = json.loads(side.read_text())
        assert meta["format"] == golden.FORMAT and meta["key"] and meta["content_key"]
        assert not any(s.startswith("/") or "\\" in s for s in strings(meta)), side


def test_configured_store_from_pyproject_and_environment(tmp_path, monkeypatch):
    monkeypatch.delenv(golden.STORE_ENV, raising=False)
    (tmp_path / "pyproject.toml").write_text('[tool.whitted]\ngoldens = "ci/goldens"\n')
    sub = tmp_path / "a" / "b"
    sub.mkdir(parents=True)
    store, where = golden.configured_store(sub)
    assert store == tmp_path / "ci/goldens" and "pyproject.toml" in where
    assert golden.search_stores(cwd=sub) == [tmp_path / "ci/goldens", golden.BUNDLED_STORE]
    monkeypatch.setenv(golden.STORE_ENV, str(tmp_path / "env"))
    assert golden.configured_store(sub)[0] == tmp_path / "env"


def test_a_harness_change_makes_goldens_stale(user, monkeypatch):
    _, scene, store = user
    real = golden.harness_hashes()
    monkeypatch.setattr(golden, "harness_hashes",
                        lambda: {**real, "reference/plugins.py": "0" * 64})
    found = golden.find_golden(load_scene(scene), view=0, shading="classic", mode="exact",
                               stores=[store])
    assert found.status == "stale" and found.changes == ["harness file reference/plugins.py"]


def test_code_hash_is_the_files_bytes_whatever_the_interpreter(tmp_path):
    """The key of a harness file is the sha256 of its bytes (CRLF read as LF): the same under
    every Python version (a token hash differed between 3.11 here and 3.12 on the GPU host,
    where every bundled golden read STALE), and any change to the code changes it."""
    import hashlib
    a, b, c = tmp_path / "a.py", tmp_path / "b.py", tmp_path / "c.py"
    a.write_bytes(b'x = f"{1}"\ndef f(x):\n    return x + 1\n')
    b.write_bytes(b'x = f"{1}"\r\ndef f(x):\r\n    return x + 1\r\n')
    c.write_bytes(b'x = f"{1}"\ndef f(x):\n    return x + 2\n')
    assert golden.code_hash(a) == hashlib.sha256(a.read_bytes()).hexdigest()
    assert golden.code_hash(a) == golden.code_hash(b) != golden.code_hash(c)


def test_check_table_thresholds_reach_the_verdict_and_bad_ones_are_named(user, tmp_path):
    _, scene, store = user
    text = scene.read_text()
    ok = tmp_path / "quad.toml"
    ok.write_text(text + '\n[check]\nmodes = ["exact"]\nshadings = ["classic"]\n'
                         'reason = "measured"\n[check.exact]\nmax_rel = 0.004\n')
    verdicts = vd.check_scene(ok, [store], backend="llvm")
    assert [v.status for v in verdicts] == ["PASS"] * 3        # the [check] key is not hashed
    th = verdicts[0].thresholds["max_rel"]
    assert th["value"] == 0.004 and th["source"] == "scene" and "measured" in th["why"]
    assert verdicts[0].thresholds["eps"]["source"] == "default"
    typo = tmp_path / "typo.toml"
    typo.write_text(text + "\n[check.exact]\nmax_rell = 0.01\n")
    (v,) = vd.check_scene(typo, [store], backend="llvm")
    assert v.status == "ERROR" and "check.exact.max_rell" in v.reason
    assert "did you mean 'max_rel'" in v.reason
    bad = tmp_path / "bad.toml"
    bad.write_text(text + '\n[check]\nmodes = ["fast"]\n')
    with pytest.raises(SceneError, match=r"bad\.toml: check\.modes\[0\]: expected one of"):
        load_scene(bad)


def test_warn_level_exceeded_exits_1_and_json_goes_to_stdout(user, tmp_path, capsys):
    _, scene, store = user
    warn = tmp_path / "quad.toml"
    warn.write_text(scene.read_text() + '\n[check]\nshadings = ["classic"]\n'
                                        "[check.warn]\nmean_rel = 1e-12\n")
    assert _check(warn, "--goldens", store, "--view", "top", "--json", "-") == 1
    captured = capsys.readouterr()
    data = json.loads(captured.out)                  # stdout holds only the JSON
    assert data["exit_code"] == 1 and data["verdicts"][0]["status"] == "WARN"
    assert "mean_rel" in data["verdicts"][0]["reason"] and "WARN" in captured.err
    typo = tmp_path / "typo.toml"
    typo.write_text(scene.read_text() + "\n[check.warn]\nmean_rell = 1\n")
    assert _check(typo, "--goldens", store, "--view", "top") == 4
    assert "check.warn.mean_rell" in capsys.readouterr().out


def test_outputs_are_checked_before_rendering(user, tmp_path, monkeypatch, capsys):
    _, scene, store = user
    from renderer.render import Renderer

    def no_render(self, view=0):
        raise AssertionError("rendered before the outputs were checked")
    monkeypatch.setattr(Renderer, "render", no_render)
    (tmp_path / "rep").mkdir()
    (tmp_path / "rep" / "index.html").write_text("x")
    assert _check(scene, "--goldens", store, "--report", tmp_path / "rep") == 4
    assert "pass --force" in capsys.readouterr().err
    (tmp_path / "file").write_text("")
    assert _check(scene, "--goldens", store, "--junit", tmp_path / "file" / "out.xml") == 4
    assert "--junit" in capsys.readouterr().err


def test_mitsuba_version_is_part_of_the_key_when_installed(user, monkeypatch):
    _, scene, store = user
    s = load_scene(scene)
    monkeypatch.setattr(golden, "mitsuba_version", lambda: "3.99.0")
    found = golden.find_golden(s, view=0, shading="classic", mode="exact", stores=[store])
    assert found.status == "stale" and found.changes[-1].endswith("-> 3.99.0")
    monkeypatch.setattr(golden, "mitsuba_version", lambda: None)   # not installed: not checked
    assert golden.find_golden(s, view=0, shading="classic", mode="exact",
                              stores=[store]).status == "ok"


def test_reference_on_dask_workers_writes_the_same_store(user, tmp_path, capsys):
    """`whitted reference --workers N` goes through the same store logic: the files equal
    the in-process store's, an up-to-date store renders nothing, a stale golden is refused
    without --force before a worker starts, and the bundled store stays read-only."""
    pytest.importorskip("dask.distributed")
    _, scene, store = user
    mine = tmp_path / "dask_store"
    args = ["reference", "--goldens", str(mine), "--size", "24", "--quiet", str(scene)]
    assert main(args + ["--workers", "2"]) == 0
    capsys.readouterr()
    ours, theirs = _tree_hashes(store), _tree_hashes(mine)
    exrs = {k: v for k, v in ours.items() if k.endswith(".exr")}
    assert exrs and exrs == {k: v for k, v in theirs.items() if k.endswith(".exr")}
    for side in mine.rglob("*.json"):           # the same format-2 sidecars but the date
        a = json.loads(side.read_text())
        b = json.loads((store / side.relative_to(mine)).read_text())
        a.pop("date"), b.pop("date")
        assert a == b and a["format"] == 2
    assert _check(scene, "--goldens", mine) == 0
    assert main(args + ["--workers", "2"]) == 0
    assert "wrote 0 golden images" in capsys.readouterr().out
    edited = tmp_path / "quad.toml"
    edited.write_text(scene.read_text().replace("\nkd = 0.5", "\nkd = 0.4"))
    before = _tree_hashes(mine)
    assert main(args[:-1] + [str(edited), "--workers", "2"]) == 4
    assert "pass --force" in capsys.readouterr().err
    assert _tree_hashes(mine) == before
    with pytest.raises(SystemExit) as bad:         # argparse's one line, exit 2
        main(args + ["--workers", "-1"])
    assert bad.value.code == 2
    assert "--workers" in capsys.readouterr().err
