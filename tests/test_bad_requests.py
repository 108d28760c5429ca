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
