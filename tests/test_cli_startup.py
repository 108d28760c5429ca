"""Start-up of the command line (issue 25): Ctrl-C while the heavy modules import exits
with 130 and one line, no ``KeyboardInterrupt`` traceback (``whitted.entry``)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LINES = {"interrupted: stopped while starting; nothing written",
         "interrupted: stopped; no partial file written"}

#: A child that sends itself SIGINT in the middle of importing the command line (when
#: ``whitted.cli`` imports numpy), then runs the console entry point: deterministic, where
#: a timed Ctrl-C lands wherever the machine's load puts it.
MID_IMPORT = """
import builtins, os, signal, sys
real = builtins.__import__
def hooked(name, *args, **kw):
    if name == "drjit":
        builtins.__import__ = real
        os.kill(os.getpid(), signal.SIGINT)
    return real(name, *args, **kw)
builtins.__import__ = hooked
from importlib.metadata import entry_points
(ep,) = [e for e in entry_points(group="console_scripts") if e.name == "whitted"]
sys.exit(ep.load()(["render", "scenes/cornell_box.toml", "--out", sys.argv[1]]))
"""


def _check(proc_result_code: int, err: str):
    assert proc_result_code == 130, err
    assert "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 1 and err.strip() in LINES, err


def test_sigint_while_importing_exits_130_with_one_line(tmp_path):
    p = subprocess.run([sys.executable, "-c", MID_IMPORT, str(tmp_path / "out")], cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
    _check(p.returncode, p.stderr)



def _interpreter_start() -> float:
    """Seconds this machine takes to start Python up to its first line of user code (the
    ``site`` import): a SIGINT before that is the interpreter's, not ours."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "pass"], check=True)
    return time.perf_counter() - t0


@pytest.mark.parametrize("delay", [0.0, 0.1, 0.25, 0.4, 0.6])
def test_sigint_early_exits_130_with_one_line(tmp_path, delay):
    """Ctrl-C at several moments of the first 0.7 s after Python itself is up."""
    out = tmp_path / "out"
    delay += 1.5 * _interpreter_start()
    proc = subprocess.Popen([sys.executable, "-m", "whitted", "render",
                             "scenes/cornell_box.toml", "--backend", "llvm", "--out", str(out)],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(delay)
    if proc.poll() is not None:
        pytest.skip("the render finished before the signal")
    proc.send_signal(signal.SIGINT)
    try:
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    if proc.returncode == 0 and not err and list(out.glob("*.png")):
        # the signal reached a process already past its last write (exiting: its outputs
        # are whole, as they are written by rename), the same race as the poll above
        pytest.skip("the render finished before the signal")
    _check(proc.returncode, err)


#: libLLVMs the LLVM backend cannot render with: (DRJIT_LIBLLVM_PATH, what the line says).
#: Before the check: a TypeError traceback (none loaded, or 14) or an LLVM abort (15, exit
#: 134 with a DAG dump).
BAD_LLVMS = [("/nonexistent/libLLVM.so", "no usable libLLVM was loaded"),
             ("/usr/lib/x86_64-linux-gnu/libLLVM-14.so", "no usable libLLVM was loaded"),
             ("/usr/lib/x86_64-linux-gnu/libLLVM-15.so", "libLLVM 15")]


@pytest.mark.parametrize("path,says", BAD_LLVMS)
def test_unusable_libllvm_is_one_line_with_the_fix(tmp_path, path, says):
    if not path.startswith("/nonexistent") and not Path(path).exists():
        pytest.skip(f"{path} is not installed here")
    env = {**os.environ, "DRJIT_LIBLLVM_PATH": path}
    p = subprocess.run([sys.executable, "-m", "whitted", "render", "scenes/cornell_box.toml",
                        "--size", "8x8", "--backend", "llvm", "--out", str(tmp_path / "out")],
                       cwd=ROOT, env=env, capture_output=True, text=True, timeout=120)
    err = p.stderr.strip()
    assert p.returncode == 2, err[-2000:]
    assert "Traceback" not in err and len(err.splitlines()) == 1, err[-2000:]
    assert err.startswith("error: backend 'llvm': ") and says in err, err
    assert "apt-get install libllvm19" in err and "DRJIT_LIBLLVM_PATH" in err, err

