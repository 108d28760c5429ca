"""No user file is lost: a report path (``check --json`` / ``--junit``) that exists and is
not a report this tool wrote is refused with one line and exit 4 unless ``--force``; a
device, pipe or socket is never replaced by any writer (``renderer.outputs``)."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from evaluation.gate import verdict as vd
from renderer.outputs import OutputError, check_replaceable, write_text
from whitted.cli import main

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "cornell_box.toml"

#: (flag, what stands at the report path); every row must be refused and left untouched.
REFUSED = [
    ("--junit", "scene"), ("--json", "scene"),
    ("--junit", "other_xml"), ("--json", "other_json"),
    ("--junit", "fifo"), ("--json", "fifo"),
]


def _plant(path: Path, kind: str) -> bytes | None:
    if kind == "scene":
        path.write_bytes(SCENE.read_bytes())
    elif kind == "other_xml":
        path.write_text('<testsuites><testsuite name="pytest"/></testsuites>\n')
    elif kind == "other_json":
        path.write_text('{"exit_code": 0, "mine": true}\n')
    elif kind == "fifo":
        os.mkfifo(path)
        return None
    return path.read_bytes()


@pytest.mark.parametrize("flag,kind", REFUSED)
def test_report_path_that_is_not_ours_is_refused(flag, kind, tmp_path, capsys):
    target = tmp_path / "a.toml"
    before = _plant(target, kind)
    assert main(["check", flag, str(target), str(SCENE), "--quiet"]) == 4
    err = capsys.readouterr().err
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"error: {flag} ") and str(target) in last
    if kind == "fifo":
        assert target.is_fifo()
    else:
        assert target.read_bytes() == before
        assert "--force" in last


def test_our_own_reports_are_recognised_and_replaced(tmp_path):
    """A report written by ``write_json`` / ``write_junit`` is replaced without --force;
    a foreign file only with it; a pipe never, not even with it."""
    js, xml = tmp_path / "v.json", tmp_path / "v.xml"
    vd.write_json([], js)
    vd.write_junit([], xml)
    assert vd.is_our_json(js) and vd.is_our_junit(xml)
    assert not vd.is_our_json(xml) and not vd.is_our_junit(js)
    check_replaceable(js, ours=vd.is_our_json)
    check_replaceable(xml, ours=vd.is_our_junit)
    foreign = tmp_path / "scene.toml"
    foreign.write_bytes(SCENE.read_bytes())
    with pytest.raises(FileExistsError):
        check_replaceable(foreign, ours=vd.is_our_json)
    check_replaceable(foreign, ours=vd.is_our_json, force=True)
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with pytest.raises(OutputError, match="not a regular file"):
        check_replaceable(fifo, ours=vd.is_our_json, force=True)


def test_no_writer_replaces_a_pipe(tmp_path):
    """The atomic writer itself refuses a non-regular file even when asked to overwrite."""
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    with pytest.raises(OutputError, match="not a regular file"):
        write_text(fifo, "x", overwrite=True)
    assert fifo.is_fifo()


def test_render_writes_run_together_and_errors_reach_the_command(tmp_path):
    """``whitted.render.write_all``: every write runs (the first ones on threads); an error
    of any is raised in the command once all have ended, and the files the other writes
    created are removed (a file that was there before stays)."""
    import threading

    from whitted.render import write_all
    names = []
    exr, png = tmp_path / "a.exr", tmp_path / "a.png"

    def ok(path):
        def write():
            names.append(threading.current_thread().name)
            path.write_text("new")
        return write

    def bad():
        raise OSError("disk full")

    write_all([(exr, ok(exr)), (png, ok(png))])
    assert exr.read_text() == png.read_text() == "new" and len(set(names)) == 2
    exr.unlink()
    png.unlink()
    with pytest.raises(OSError, match="disk full"):
        write_all([(exr, bad), (png, ok(png))])
    assert not png.exists() and not exr.exists()        # the new PNG went with the EXR
    png.write_text("old")
    with pytest.raises(OSError, match="disk full"):
        write_all([(exr, ok(exr)), (png, bad)])
    assert not exr.exists() and png.read_text() == "old"
    png.unlink()
    with pytest.raises(OSError, match="disk full"):
        write_all([(png, ok(png)), (exr, bad)])
    assert not png.exists()
    exr.write_text("before")                              # there before: replaced, kept
    with pytest.raises(OSError, match="disk full"):
        write_all([(exr, ok(exr)), (png, bad)])
    assert exr.read_text() == "new"
    write_all([])
