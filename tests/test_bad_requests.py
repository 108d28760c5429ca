"""Bad requests of every command as data: each row is one invocation that must end with one
``error:`` line naming the option / file as typed and the documented exit code (2 a bad
request, 4 a file problem), never a traceback, before any work is done, and leave every
file as it was."""
from __future__ import annotations

from pathlib import Path

import pytest

from whitted.cli import main

ROOT = Path(__file__).resolve().parents[1]

#: (name, argv with {tmp} for the test's folder, files to plant {name: bytes}, exit code,
#: text the last line must contain)
ROWS = [
    ("study seeds 0", ["study", "--seeds", "0", "--out", "{tmp}"], {}, 2, "--seeds"),
    ("study size 0", ["study", "--size", "0", "--out", "{tmp}"], {}, 2, "--size"),
    ("study workers -3", ["study", "--workers", "-3", "--out", "{tmp}"], {}, 2, "--workers"),
    ("study max-points -1", ["study", "--max-points", "-1", "--out", "{tmp}"], {}, 2,
     "--max-points"),
    ("study readme alone", ["study", "--readme", "{tmp}/README.md", "--out", "{tmp}"],
     {"README.md": b"# mine\n"}, 2, "--readme"),
    ("study bad offset", ["study", "cornell_box@abc", "--out", "{tmp}"], {}, 2,
     "cornell_box@abc"),
    ("study report-only garbage", ["study", "--report-only", "--out", "{tmp}"],
     {"study.json": b"\x00garbage{"}, 4, "study.json"),
    ("study resume garbage", ["study", "cornell_box", "--out", "{tmp}"],
     {"study.json": b"not json"}, 4, "study.json"),
    ("study resume foreign json", ["study", "cornell_box", "--out", "{tmp}"],
     {"study.json": b'{"mine": [1, 2]}'}, 4, "study.json"),
    ("study report-only array", ["study", "--report-only", "--out", "{tmp}"],
     {"study.json": b"[1, 2]"}, 4, "study.json"),
    ("reference size 0", ["reference", "cornell_box", "--size", "0", "--goldens", "{tmp}"],
     {}, 2, "--size"),
    ("reference spp -4", ["reference", "cornell_box", "--spp", "-4", "--goldens", "{tmp}"],
     {}, 2, "--spp"),
    ("reference batches 0", ["reference", "cornell_box", "--batches", "0", "--goldens",
                             "{tmp}"], {}, 2, "--batches"),
    ("hard-cases chunk 0", ["hard-cases", "--chunk", "0", "--out", "{tmp}"], {}, 2,
     "--chunk"),
    ("check view nope", ["check", "cornell_box", "--view", "nope", "--goldens", "{tmp}"],
     {}, 2, "nope"),
]


@pytest.mark.parametrize("argv,plant,code,needle", [r[1:] for r in ROWS],
                         ids=[r[0].replace(" ", "-") for r in ROWS])
def test_bad_request_is_one_line(argv, plant, code, needle, tmp_path, capsys):
    for name, data in plant.items():
        (tmp_path / name).write_bytes(data)
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    try:
        got = main(argv)
    except SystemExit as e:           # argparse's own usage error
        got = e.code
    err = capsys.readouterr().err
    assert "Traceback" not in err
    last = [line for line in err.strip().splitlines() if line][-1]
    assert got == code, last
    assert "error:" in last and needle in last
    for name, data in plant.items():
        assert (tmp_path / name).read_bytes() == data
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(plant)


GOLDEN = ROOT / "reference" / "goldens" / "analytic_quad" / "grazing_classic_exact"
PNG_BYTES = b"\x89PNG\r\n\x1a\n" + b"\x00" * 64

#: (name, what replaces the golden's EXR or sidecar JSON, or a pyproject.toml above the
#: folder check runs in); each must be one error line naming the file, exit 4.
BAD_STORES = [
    ("exr truncated", "exr", lambda b: b[:40]),
    ("exr empty", "exr", lambda b: b""),
    ("exr garbage", "exr", lambda b: b"garbage" * 30),
    ("exr is a png", "exr", lambda b: PNG_BYTES),
    ("exr mode 000", "exr", None),
    ("json not utf8", "json", lambda b: b"\xff\xfe\x00{"),
    ("json array", "json", lambda b: b"[1, 2, 3]"),
    ("json wrong types", "json", lambda b: b'{"content_key": 7, "inputs": []}'),
    ("json inputs not object", "json",
     lambda b: b.replace(b'"inputs": {', b'"inputs": 3, "x": {', 1)),
    ("pyproject binary", "pyproject", lambda b: b"\xff\xfe\x00\x81binary"),
]


@pytest.mark.parametrize("kind,damage", [r[1:] for r in BAD_STORES],
                         ids=[r[0].replace(" ", "-") for r in BAD_STORES])
def test_bad_golden_store_is_one_line(kind, damage, tmp_path, capsys, monkeypatch):
    import os
    store = tmp_path / "store"
    (store / "analytic_quad").mkdir(parents=True)
    for ext in ("exr", "json"):
        src = GOLDEN.with_suffix(f".{ext}")
        (store / "analytic_quad" / src.name).write_bytes(src.read_bytes())
    target = store / "analytic_quad" / f"{GOLDEN.name}.{kind}"
    argv = ["check", str(ROOT / "scenes" / "analytic_quad.toml"), "--view", "grazing",
            "--shadings", "classic", "--modes", "exact"]
    if kind == "pyproject":
        (tmp_path / "pyproject.toml").write_bytes(damage(b""))
        work = tmp_path / "work"
        work.mkdir()
        monkeypatch.chdir(work)
        monkeypatch.delenv("WHITTED_GOLDENS", raising=False)
    else:
        argv += ["--goldens", str(store)]
        if damage is None:
            if os.geteuid() == 0:
                pytest.skip("root reads a mode-000 file")
            target.chmod(0)
        else:
            target.write_bytes(damage(target.read_bytes()))
    code = main(argv)
    err = capsys.readouterr()
    text = err.out + err.err
    assert "Traceback" not in text
    assert code == 4, text
    name = "pyproject.toml" if kind == "pyproject" else target.name
    assert name in text


#: (name, a [check.<mode>] table appended to a copy of analytic_quad.toml, the field the
#: error line must name); each is exit 2 with one line, before any render.
BAD_CHECK_TABLES = [
    ("batches 0", "[check.converged]\nbatches = 0\n", "check.converged.batches"),
    ("batches 1.5", "[check.converged]\nbatches = 1.5\n", "check.converged.batches"),
    ("alpha 2", "[check.converged]\nalpha = 2\n", "check.converged.alpha"),
    ("alpha 0", "[check.converged]\nalpha = 0.0\n", "check.converged.alpha"),
    ("var_floor text", '[check.converged]\nvar_floor = "big"\n', "check.converged.var_floor"),
    ("max_rel negative", "[check.exact]\nmax_rel = -1.0\n", "check.exact.max_rel"),
]


@pytest.mark.parametrize("table,field", [r[1:] for r in BAD_CHECK_TABLES],
                         ids=[r[0].replace(" ", "-") for r in BAD_CHECK_TABLES])
def test_bad_check_threshold_is_one_line(table, field, tmp_path, capsys):
    scene = tmp_path / "analytic_quad.toml"
    scene.write_text((ROOT / "scenes" / "analytic_quad.toml").read_text() + "\n" + table)
    mode = field.split(".")[1]
    code = main(["check", str(scene), "--modes", mode, "--goldens", str(tmp_path / "g")])
    out = capsys.readouterr()
    text = out.out + out.err
    assert "Traceback" not in text
    assert code in (2, 4), text
    assert field in text and scene.name in text
