"""The kernels a render traces are the same in every run (issue 25: three hashes seen for
``whitted render`` on LLVM, so a warm run sometimes compiled again). The cause was the
addresses of numpy buffers Dr.Jit reads in place: an input not aligned to the vector width
is loaded with ``align 1`` (``renderer.device.host_array``). Python's hash seed moves those
addresses, so runs under different ``PYTHONHASHSEED`` values must trace the same kernels."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = """
import sys, drjit as dr
dr.set_flag(dr.JitFlag.KernelHistory, True)
from renderer.render import render
from renderer.scene import load_scene
for precision in ("float32", "float64"):
    render(load_scene("scenes/cornell_box.toml").with_size(12, 12), backend="llvm",
           precision=precision)
print(" ".join(str(h["hash"]) for h in dr.kernel_history()
               if h["type"] == dr.KernelType.JIT))
"""


def _hashes(seed: int) -> str:
    env = {**os.environ, "PYTHONHASHSEED": str(seed)}
    p = subprocess.run([sys.executable, "-c", CHILD], cwd=ROOT, env=env, capture_output=True,
                       text=True, timeout=300, check=True)
    return p.stdout.strip()


def test_traced_kernels_do_not_depend_on_the_run():
    runs = {seed: _hashes(seed) for seed in (1, 2, 3, 4)}
    assert runs[1], "no kernel traced"
    assert len(set(runs.values())) == 1, runs
