"""Safe outputs (renderer/outputs.py and the CLI's use of it): a failed or interrupted write
leaves no file and no temporary, an output that cannot be written is refused before any
rendering with one line and exit code 4, ``--out`` naming an image file writes that file,
and nothing is replaced without ``--overwrite``."""
from __future__ import annotations

import errno
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from renderer.film import read_exr, write_exr, write_png
from renderer.outputs import (
    LIVE_TEMPORARIES,
    OutputError,
    OutputExistsError,
    atomic_path,
    check_output_dir,
    write_text,
)
from whitted.cli import main

ROOT = Path(__file__).resolve().parents[1]
SCENE = str(ROOT / "scenes" / "cornell_box.toml")


def _files(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


# ---- the atomic writer ------------------------------------------------------------------------
def test_a_write_that_fails_half_way_leaves_neither_file_nor_temporary(tmp_path):
    target = tmp_path / "a.bin"
    with pytest.raises(OutputError, match=r"a\.bin: write failed: no space left"):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"x" * 1000)
            raise OSError(errno.ENOSPC, "No space left on device")
    assert _files(tmp_path) == [] and not LIVE_TEMPORARIES


def test_an_interrupted_write_keeps_the_old_file_whole(tmp_path):
    target = write_text(tmp_path / "a.txt", "old")
    with pytest.raises(KeyboardInterrupt):
        with atomic_path(target, overwrite=True) as tmp:
            tmp.write_text("new, but only ha")
            raise KeyboardInterrupt
    assert target.read_text() == "old" and _files(tmp_path) == ["a.txt"]


def test_existing_file_is_kept_unless_overwrite(tmp_path):
    img = np.full((4, 5, 3), 0.25, np.float32)
    p = write_exr(tmp_path / "a.exr", img)
    with pytest.raises(OutputExistsError, match="exists"):
        write_exr(p, img * 2)
    with pytest.raises(FileExistsError):             # still a FileExistsError for callers
        write_png(write_png(tmp_path / "a.png", img), img)
    np.testing.assert_array_equal(read_exr(p), img)
    write_exr(p, img * 2, overwrite=True)
    np.testing.assert_array_equal(read_exr(p), img * 2)
    assert _files(tmp_path) == ["a.exr", "a.png"]
    assert (p.stat().st_mode & 0o777) == 0o666 & ~_umask()   # not mkstemp's 0600


def _umask() -> int:
    m = os.umask(0)
    os.umask(m)
    return m


def test_output_folder_checks_name_the_problem(tmp_path):
    (tmp_path / "file").write_text("")
    with pytest.raises(OutputError, match="is a file, not a folder"):
        check_output_dir(tmp_path / "file" / "sub")
    made = check_output_dir(tmp_path / "new" / "deeper")        # a missing parent is made
    assert made.is_dir() and _files(made) == []                 # the probe is gone


# ---- the CLI: checked before rendering, one line, exit code 4 ---------------------------------
def _render(capsys, *argv):
    code = main(["render", SCENE, "--size", "16x16", "--backend", "llvm", *argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_file_where_a_folder_is_expected_is_refused_before_rendering(tmp_path, capsys):
    (tmp_path / "file").write_text("")
    code, out, err = _render(capsys, "--out", str(tmp_path / "file" / "out"))
    assert code == 4
    assert err.strip().count("\n") == 0 and "is a file, not a folder" in err
    assert "view front" not in out and "effects" not in out         # nothing was rendered


def _read_only_folder(tmp_path) -> Path:
    """A folder this process cannot write: chmod 555 for a normal user; root ignores
    modes, so then a folder on a read-only or permission-checked mount (/sys)."""
    if os.geteuid() != 0:
        d = tmp_path / "ro"
        d.mkdir()
        d.chmod(0o555)
        return d
    d = Path("/sys/kernel")
    if not d.is_dir() or os.access(d, os.W_OK) and _can_create(d):
        pytest.skip("no folder that root cannot write here")
    return d


def _can_create(d: Path) -> bool:
    try:
        (d / ".whitted-test").touch()
    except OSError:
        return False
    (d / ".whitted-test").unlink()
    return True


def test_read_only_folder_is_refused_before_rendering(tmp_path, capsys):
    ro = _read_only_folder(tmp_path)
    code, out, err = _render(capsys, "--out", str(ro / "out"))
    assert code == 4 and "cannot write here" in err and err.strip().count("\n") == 0
    assert "view front" not in out


def test_out_naming_an_exr_or_png_writes_that_file(tmp_path, capsys):
    code, out, _ = _render(capsys, "--out", str(tmp_path / "image.exr"))
    assert code == 0 and _files(tmp_path) == ["image.exr"]
    assert read_exr(tmp_path / "image.exr").shape == (16, 16, 3)
    code, _, _ = _render(capsys, "--out", str(tmp_path / "sub" / "image.png"))
    assert code == 0 and _files(tmp_path / "sub") == ["image.png"]
    # one file cannot hold several views; other image suffixes are not made folders
    code, _, err = _render(capsys, "--view", "all", "--out", str(tmp_path / "all.exr"))
    assert code == 2 and "names one file but 3 views" in err
    code, _, err = _render(capsys, "--out", str(tmp_path / "image.jpg"))
    assert code == 2 and ".jpg files are not written" in err
    assert _files(tmp_path) == ["image.exr", "sub"]


def test_existing_output_needs_overwrite(tmp_path, capsys):
    target = tmp_path / "image.exr"
    assert _render(capsys, "--out", str(target))[0] == 0
    before = target.read_bytes()
    code, out, err = _render(capsys, "--out", str(target), "--shading", "physical")
    assert code == 4 and "--overwrite" in err and "view front" not in out
    assert target.read_bytes() == before
    assert _render(capsys, "--out", str(target), "--shading", "physical", "--overwrite")[0] == 0
    assert target.read_bytes() != before


FULL_DISK = """
import resource, signal, sys
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)     # a write past the limit fails with EFBIG
resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
from whitted.cli import main
sys.exit(main(sys.argv[1:]))
"""


def test_a_full_disk_leaves_no_partial_file(tmp_path):
    """A real failing write: the process may write at most 4 KiB per file (RLIMIT_FSIZE,
    the way a full disk fails a write), so the 64² EXR cannot be finished."""
    out = tmp_path / "out"
    run = subprocess.run([sys.executable, "-c", FULL_DISK, "render", SCENE, "--size", "64x64",
                          "--backend", "llvm", "--out", str(out)],
                         capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert run.returncode == 4, run.stderr[-2000:]
    # (Dr.Jit's own kernel cache may also say it could not write under the limit)
    errors = [line for line in run.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1 and "Traceback" not in run.stderr
    assert "cornell_box_front.exr: write failed" in errors[0]
    assert _files(out) == []                                   # no EXR, no temporary
