"""The README's results table is generated from results/ (``evaluation.bench.readme_table``):
the README holds exactly what the generator prints, and the generator's numbers are the
stored results' own (checked against the markdown tables the bench wrote beside them)."""
from __future__ import annotations

import json
import shlex
import shutil
import statistics
from pathlib import Path

import pytest

from evaluation.bench import readme_table as rt

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"


def md_column(md: Path, column: str) -> list[tuple[list[str], str]]:
    """Rows of the first markdown table in ``md`` that has ``column``: (cells, that cell)."""
    rows, head = [], None
    for line in md.read_text().splitlines():
        if not line.startswith("| "):
            if head is not None and rows:
                break
            head = None
            continue
        cells = [c.strip() for c in line.strip("|").split("|")]
        if head is None:
            head = cells if column in cells else None
        elif not cells[0].startswith("---"):
            rows.append((cells, cells[head.index(column)]))
    return rows


def test_readme_block_is_the_generators_output():
    """A stale README (results/ changed, the table not regenerated) fails here: run
    ``python -m evaluation.bench.readme_table --write README.md``."""
    readme = (ROOT / "README.md").read_text()
    assert rt.BEGIN in readme and rt.END in readme
    assert rt.block_of(readme) == rt.table(RESULTS)


def row(name: str) -> rt.Row:
    return next(r for r in rt.load_rows(RESULTS) if r.name == name)


def test_throughput_rows_are_the_stored_tables_best_over_mitsuba():
    for path, name in (("h200/throughput/bench-cuda.json", "Ray throughput"),
                       ("cpu/bench-llvm-throughput.json", "Ray throughput, CPU")):
        r = row(name)
        assert r.file == path and r.kind == "throughput"
        stored = [float(cell.split()[0]) for _, cell in
                  md_column((RESULTS / path).with_suffix(".md"), "best / Mitsuba")]
        assert len(stored) >= 7 * 7
        cell = rt.read_row(r, RESULTS)
        lo, hi, mid = min(stored), max(stored), statistics.median(stored)
        assert cell.result.startswith(f"{lo:.2f}–{hi:.2f}× (median {mid:.2f}×)"), cell.result
    gpu = rt.read_row(row("Ray throughput"), RESULTS)
    assert gpu.device == "NVIDIA H200" and "49 of 49 rows ≥ 1.5×" in gpu.result


def test_build_rows_are_the_stored_tables_device_build_against_mitsuba():
    for path, name in (("h100/build/bench-cuda.json", "BVH build, GPU"),
                       ("cpu/build/bench-llvm.json", "BVH build, CPU")):
        r = row(name)
        assert r.file == path and r.kind == "build"
        ours = md_column((RESULTS / path).with_suffix(".md"), "on device M/s")
        theirs = {cells[0]: v for cells, v in
                  md_column((RESULTS / path).with_suffix(".md"), "Mitsuba M/s")}
        assert len(ours) == 4
        cell = rt.read_row(r, RESULTS)
        for cells, rate in ours:
            assert f"{cells[0]} {rate} vs {theirs[cells[0]]}" in cell.result, cell.result
        assert "4 scenes" in cell.conditions


def test_peer_row_is_the_stored_tables_frame_ratio_at_depth_2():
    rows = md_column(RESULTS / "h200/peer/bench-cuda.md", "ours faster (frame)")
    frame = [float(c.rstrip("×")) for cells, c in rows if cells[1] == "2" and cells[2] == "1024²"]
    assert len(frame) == 4
    cell = rt.read_row(row("Whitted frame"), RESULTS)
    assert cell.result.startswith(f"{min(frame):.2f}–{max(frame):.2f}×"), cell.result
    assert "depth 2" in cell.conditions and "4 scenes" in cell.conditions


def test_a_missing_result_says_not_measured(tmp_path):
    shutil.copy(RESULTS / rt.ROWS_FILE, tmp_path)
    (tmp_path / "h200/throughput").mkdir(parents=True)
    shutil.copy(RESULTS / "h200/throughput/bench-cuda.json", tmp_path / "h200/throughput")
    text = rt.table(tmp_path)
    lines = {line.split(" | ")[0].lstrip("| "): line for line in text.splitlines()
             if line.startswith("| ") and not line.startswith("| ---")}
    assert "not measured" not in lines["Ray throughput"]
    for name in ("Whitted frame", "Ray throughput, CPU", "Time to first image, GPU",
                 "Time to first image, CPU"):
        assert "not measured" in lines[name]
    assert "NVIDIA H200 (2026-" in text and "EPYC" not in text.split("\n")[0]


def test_write_replaces_only_the_block(tmp_path, capsys):
    readme = tmp_path / "README.md"
    readme.write_text(f"# title\n\nbefore\n{rt.BEGIN}\nold table\n{rt.END}\nafter\n")
    assert rt.main(["--results", str(RESULTS), "--write", str(readme)]) == 0
    text = readme.read_text()
    assert "old table" not in text and text.startswith("# title\n\nbefore\n")
    assert text.endswith(f"{rt.END}\nafter\n") and rt.block_of(text) == rt.table(RESULTS)
    assert rt.main(["--results", str(RESULTS), "--write", str(readme)]) == 0
    assert readme.read_text() == text                      # idempotent
    assert not [p for p in tmp_path.iterdir() if p.name != "README.md"]   # no temporaries


def test_write_without_markers_is_one_error_line_and_leaves_the_file(tmp_path, capsys):
    readme = tmp_path / "README.md"
    readme.write_text("# no markers\n")
    assert rt.main(["--results", str(RESULTS), "--write", str(readme)]) == 4
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {readme}: ") and "Traceback" not in err[0]
    assert readme.read_text() == "# no markers\n"


@pytest.mark.parametrize("broken", ["{", '{"device": {}, "throughput": [{"accels": []}]}'])
def test_an_unreadable_result_names_its_file(tmp_path, broken):
    shutil.copy(RESULTS / rt.ROWS_FILE, tmp_path)
    (tmp_path / "h200/throughput").mkdir(parents=True)
    (tmp_path / "h200/throughput/bench-cuda.json").write_text(broken)
    with pytest.raises(ValueError, match="bench-cuda.json"):
        rt.table(tmp_path)


def test_every_current_result_names_the_command_that_regenerates_it():
    """results/ holds current results only, each beginning with its command: the bench's
    JSON in a "command" key (its markdown's first line repeats it), other markdown results
    in a comment line; results/README.md lists every one."""
    listing = (RESULTS / "README.md").read_text()
    mds = sorted(p for p in RESULTS.rglob("*.md") if p.name != "README.md")
    assert len(mds) >= 10
    for md in mds:
        first = md.read_text().split("\n", 1)[0]
        assert first.startswith("<!-- command: ") and first.endswith(" -->"), md
        command = first.removeprefix("<!-- command: ").removesuffix(" -->")
        assert command.split("   #")[0] in listing, md
        if md.with_suffix(".json").is_file() and md.name.startswith("bench-"):
            assert json.loads(md.with_suffix(".json").read_text())["command"] == command


def test_bench_records_a_command_that_parses_back_to_the_same_run():
    from whitted.bench import bench_command
    from whitted.cli import build_parser
    parser = build_parser()
    args = parser.parse_args(["bench", "--backend", "llvm", "--parts", "peer,throughput",
                              "--out", "x y", "--quick"])
    words = shlex.split(bench_command(args))
    assert words[0] == "whitted"
    again = parser.parse_args(words[1:])
    for key in ("backend", "parts", "out", "scenes", "quick"):
        assert getattr(again, key) == getattr(args, key), key
    assert again.force      # the stored command replaces the result it made


def test_the_rows_file_is_checked_field_by_field(tmp_path):
    with pytest.raises(ValueError, match="readme_table.toml"):
        rt.table(tmp_path)                                  # no rows file
    (tmp_path / rt.ROWS_FILE).write_text('[[row]]\nname = "x"\nagainst = "y"\nfile = ""\n')
    with pytest.raises(ValueError, match="row 1: kind missing"):
        rt.table(tmp_path)
    (tmp_path / rt.ROWS_FILE).write_text('[[row]]\nname = "x"\nagainst = "y"\nkind = "new"\n'
                                         'file = "new.json"\n')
    (tmp_path / "new.json").write_text("{}")           # a kind with no reader yet
    assert "| x | y | – | not measured |" in rt.table(tmp_path)
