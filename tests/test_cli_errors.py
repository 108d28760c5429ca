"""Every bad request ends with one clear line and a documented exit code (whitted/cli.py):
2 for a bad option or scene, 4 for a file or golden problem; warnings are one line; and
``--version`` answers."""
from __future__ import annotations

import subprocess
import sys
import warnings
from pathlib import Path

import drjit as dr
import pytest

from whitted.cli import main

ROOT = Path(__file__).resolve().parents[1]
SCENE = str(ROOT / "scenes" / "cornell_box.toml")


def _one_error_line(err: str) -> str:
    lines = [line for line in err.strip().splitlines() if line]
    assert "Traceback" not in err
    return lines[-1]


@pytest.mark.parametrize("option,value", [("--intersection", "foo"), ("--effect-off", "foo"),
                                          ("--accel", "foo"), ("--size", "0x3")])
def test_bad_option_value_is_a_usage_error(option, value, capsys):
    with pytest.raises(SystemExit) as e:
        main(["render", SCENE, option, value])
    assert e.value.code == 2
    last = _one_error_line(capsys.readouterr().err)
    assert f"argument {option}" in last and value in last


#: Overrides the parser accepts and the scene refuses: (command, the one error line's start).
BAD_OVERRIDES = [
    (["render", SCENE, "--spp", "2"], "error: --spp: expected a perfect square >= 1"),
    (["render", SCENE, "--spp", "0"], "error: --spp: expected a perfect square >= 1"),
    (["render", SCENE, "--max-depth", "-1"], "error: --max-depth: expected an integer in 0.."),
    (["render", SCENE, "--max-depth", "99"], "error: --max-depth: expected an integer in 0.."),
    (["export", SCENE, "--spp", "3"], "error: --spp: expected a perfect square >= 1"),
]


@pytest.mark.parametrize("argv,line", BAD_OVERRIDES)
def test_bad_override_names_the_option_as_typed(tmp_path, capsys, argv, line):
    out = ["--mitsuba-xml", str(tmp_path / "x.xml")] if argv[0] == "export" else \
        ["--out", str(tmp_path / "out")]
    assert main([*argv, *out]) == 2
    last = _one_error_line(capsys.readouterr().err)
    assert last.startswith(line), last
    assert "settings." not in last


#: -D and --approximate on every command that reads a scene: the same one line, exit 2.
XML = ROOT / "tests" / "data" / "imports" / "teapot_direct.xml"
READ_COMMANDS = ["render", "check", "reference", "view"]
BAD_READS = [
    (["-D", "res"], "error: -D res: expected NAME=VALUE"),
    (["-D", "9x=1"], "error: -D 9x=1: expected NAME=VALUE"),
    (["-D", "res=24"], f"error: {SCENE}: -D res=...: parameters are for Mitsuba XML scenes only"),
]


@pytest.mark.parametrize("command", READ_COMMANDS)
@pytest.mark.parametrize("extra,line", BAD_READS, ids=["no-value", "bad-name", "not-xml"])
def test_bad_define_is_the_same_line_on_every_command(tmp_path, capsys, command, extra, line):
    out = {"render": ["--out", str(tmp_path / "out")], "check": [],
           "reference": ["--goldens", str(tmp_path / "g")], "view": ["--port", "0"]}[command]
    assert main([command, SCENE, *extra, *out]) == 2
    assert _one_error_line(capsys.readouterr().err) == line
    assert not (tmp_path / "g").exists() and not (tmp_path / "out").exists()


@pytest.mark.parametrize("command", READ_COMMANDS)
def test_every_reading_command_takes_D_and_approximate(command):
    from whitted.cli import build_parser
    args = build_parser().parse_args([command, str(XML), "-D", "res=8", "--approximate"])
    assert args.defines == ["res=8"] and args.approximate is True


def test_defines_reach_the_golden_and_its_key(tmp_path, capsys):
    """``reference -D res=16`` renders the XML's goldens at 16 x 16 (the scene's own
    resolution, set by -D); ``check`` with the same -D finds them, without it they are
    stale and the line says how the file was read."""
    pytest.importorskip("mitsuba")
    teapot = ROOT.parent / "shared" / "data" / "meshes" / "utah_teapot" / "teapot.obj"
    if not teapot.exists():
        pytest.skip("the shared teapot mesh is not here")
    store = tmp_path / "g"
    defines = ["-D", f"teapot={teapot}", "-D", "res=16"]
    pick = ["--modes", "exact", "--shadings", "physical"]
    assert main(["reference", str(XML), "--goldens", str(store), "--quiet", *pick,
                 *defines]) == 0
    (side,) = store.rglob("*.json")
    import json
    meta = json.loads(side.read_text())
    assert meta["resolution"] == [16, 16] and meta["inputs"]["read"]["defines"]["res"] == "16"
    capsys.readouterr()
    check = ["check", str(XML), "--goldens", str(store), *pick, "--backend", "llvm"]
    assert main([*check, *defines]) in (0, 1)
    assert main([*check, "-D", f"teapot={teapot}", "-D", "res=20"]) == 4
    (line,) = [x for x in capsys.readouterr().out.splitlines() if x.startswith("STALE")]
    assert f"-D res=16 -D teapot={teapot} -> -D res=20 -D teapot={teapot}" in line


@pytest.mark.skipif(dr.has_backend(dr.JitBackend.CUDA), reason="this machine has CUDA")
def test_cuda_backend_without_a_gpu_is_one_line(tmp_path, capsys):
    assert main(["render", SCENE, "--backend", "cuda", "--out", str(tmp_path)]) == 2
    assert _one_error_line(capsys.readouterr().err) == (
        "error: backend 'cuda' requested but no CUDA device is available (backend 'llvm' "
        "or 'auto' runs on the CPU)")


def test_view_that_does_not_exist_is_a_usage_error(tmp_path, capsys):
    assert main(["render", SCENE, "--view", "99", "--out", str(tmp_path)]) == 2
    assert _one_error_line(capsys.readouterr().err).startswith("error: --view: expected")


def test_missing_scene_file_is_one_line(tmp_path, capsys):
    assert main(["render", str(tmp_path / "nope.toml"), "--out", str(tmp_path)]) == 2
    last = _one_error_line(capsys.readouterr().err)
    assert last.startswith("error: ") and "nope.toml" in last


def test_reference_replaces_a_stale_golden_only_with_force(tmp_path, capsys):
    """The golden store keeps what is up to date (exit 0, nothing rewritten) and refuses to
    replace a stale golden without --force: exit 4, one line naming --force, files kept."""
    pytest.importorskip("mitsuba")
    root = tmp_path / "goldens"
    scene = tmp_path / "analytic_quad.toml"
    text = (ROOT / "scenes" / "analytic_quad.toml").read_text()
    scene.write_text(text)
    argv = ["reference", str(scene), "--goldens", str(root), "--size", "8",
            "--modes", "exact", "--shadings", "classic", "--quiet"]
    assert main(argv) == 0
    stored = {p: p.read_bytes() for p in root.rglob("*.*")}
    assert len([p for p in stored if p.suffix == ".exr"]) == 3
    assert main(argv) == 0                              # up to date: kept as it is
    assert {p: p.read_bytes() for p in root.rglob("*.*")} == stored
    scene.write_text(text.replace("ambient = 0.0", "ambient = 0.1"))   # now stale
    capsys.readouterr()
    assert main(argv) == 4
    last = _one_error_line(capsys.readouterr().err)
    assert last.startswith("error: ") and "stale" in last and "--force" in last
    assert {p: p.read_bytes() for p in root.rglob("*.*")} == stored


def test_warnings_are_one_line_without_source(tmp_path, monkeypatch, capsys):
    import whitted.render as cmd
    original = cmd.load_for_cli

    def warn_then_load(args):
        warnings.warn("something odd\n  about this scene", UserWarning, stacklevel=1)
        return original(args)
    monkeypatch.setattr(cmd, "load_for_cli", warn_then_load)
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        assert main(["render", SCENE, "--size", "8x8", "--backend", "llvm",
                     "--out", str(tmp_path)]) == 0
    err = capsys.readouterr().err
    assert err.strip().splitlines() == ["warning: something odd about this scene (UserWarning)"]


def test_version():
    run = subprocess.run([sys.executable, "-m", "whitted", "--version"], cwd=ROOT,
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 0 and run.stdout.startswith("whitted 0.")


def test_one_exit_code_table():
    """``options.EXIT`` (every command) and ``evaluation.gate.verdict.EXIT_CODES`` (check and
    compare's verdicts) agree, and ``whitted --help`` shows every code."""
    from evaluation.gate.verdict import EXIT_CODES
    from whitted.cli import build_parser
    from whitted.options import EXIT
    assert (EXIT["ok"], EXIT["warn"], EXIT["fail"], EXIT["size"]) == tuple(
        EXIT_CODES[s] for s in ("PASS", "WARN", "FAIL", "SIZE"))
    assert EXIT["file"] == EXIT_CODES["MISSING"] == EXIT_CODES["STALE"] == EXIT_CODES["ERROR"]
    assert EXIT["usage"] == 2 and EXIT["interrupted"] == 130     # argparse's, the shell's
    text = build_parser().format_help()
    for status, code in EXIT_CODES.items():
        assert f"\n  {code} " in text and status in text
    assert "\n  130 " in text


# Bad imported scenes (OBJ + MTL, Mitsuba XML): (file name, content, what the line says).
BAD_IMPORTS = [
    ("a.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nmtllib gone.mtl\nf 1 2 3\n",
     "a.obj:4: mtllib gone.mtl: file not found"),
    ("b.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n", "b.obj:4: face vertex index 7"),
    ("c.xml", "<scene version=\"3.0.0\">\n<shape type=\"cube\">\n</scene>\n",
     "c.xml:3: XML syntax error"),
    ("d.xml", "<scene version=\"3.0.0\">\n<integrator type=\"direct\"/>\n"
              "<shape type=\"obj\">\n<string name=\"filename\" value=\"nope.obj\"/>\n"
              "</shape>\n</scene>\n", "d.xml:4: filename: file not found"),
    ("e.xml", "<scene version=\"3.0.0\">\n<integrator type=\"direct\"/>\n"
              "<shape type=\"cube\">\n<float name=\"x\" value=\"$size\"/>\n</shape>\n"
              "</scene>\n", "e.xml:4: $size: parameter has no value"),
    ("f.xml", "<scene version=\"3.0.0\">\n<integrator type=\"direct\"/>\n"
              "<bsdf type=\"twosided\" id=\"a\"><ref id=\"b\"/></bsdf>\n"
              "<bsdf type=\"twosided\" id=\"b\"><ref id=\"a\"/></bsdf>\n"
              "<shape type=\"cube\"><ref id=\"a\"/></shape>\n</scene>\n",
     "a cycle of references (a -> b -> a)"),
    ("g.xml", "<scene version=\"3.0.0\">\n<integrator type=\"direct\"/>\n"
              "<emitter type=\"area\"/>\n<shape type=\"cube\"/>\n</scene>\n",
     "g.xml:3: <emitter type=\"area\">: an area emitter belongs inside a <shape>"),
]


@pytest.mark.parametrize("name,text,says", BAD_IMPORTS, ids=[b[0] for b in BAD_IMPORTS])
def test_bad_imported_scene_is_one_line_exit_2_nothing_written(tmp_path, capsys, name, text,
                                                               says):
    scene = tmp_path / name
    scene.write_text(text)
    out = tmp_path / "out"
    assert main(["render", str(scene), "--out", str(out)]) == 2
    last = _one_error_line(capsys.readouterr().err)
    assert last.startswith(f"error: {scene.parent}/") and says in last, last
    assert not out.exists()
