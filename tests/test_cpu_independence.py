"""The LLVM backend renders the same bits on every x86 CPU: a render at AVX-512's 16 lanes
equals one at AVX2's 8 lanes (the same process's kernels compiled for a Haswell-class
target), so a golden check's verdict does not depend on the machine that runs it.
``renderer.device.rsqrt`` is what this needs: Dr.Jit's float32 ``dr.rsqrt`` starts from
each ISA's own estimate instruction."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

SCRIPT = r"""
import ctypes, hashlib, json, os, sys
import drjit as dr
import drjit.llvm
import numpy as np
lib = ctypes.CDLL(os.path.join(os.path.dirname(dr.__file__), "libdrjit-core.so"))
lib._Z24jit_llvm_target_featuresv.restype = ctypes.c_char_p
_ = drjit.llvm.Float(1) + 1
feats = lib._Z24jit_llvm_target_featuresv().decode()
if sys.argv[1] == "avx2":
    f2 = ",".join("-" + f[1:] if f.startswith("+avx512") else f for f in feats.split(","))
    lib._Z19jit_llvm_set_targetPKcS0_j(b"haswell", f2.encode(), 8)
from renderer.render import Renderer
from renderer.scene import load_scene
out = {"lanes": int(lib._Z21jit_llvm_vector_widthv())}
for name in ("glass_bunny", "cornell_sphere"):
    sc = load_scene(f"scenes/{name}.toml").with_size(48, 48)
    img = np.asarray(Renderer(sc, backend="llvm").render(0).image, np.float32)
    assert np.isfinite(img).all() and img.max() > 0.05, name
    out[name] = hashlib.sha256(img.tobytes()).hexdigest()
print(json.dumps(out))
"""


def _avx512() -> bool:
    try:
        return "avx512f" in Path("/proc/cpuinfo").read_text()
    except OSError:
        return False


def _render(target: str) -> dict:
    p = subprocess.run([sys.executable, "-c", SCRIPT, target], cwd=ROOT, text=True,
                       capture_output=True, timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    return json.loads(p.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(not _avx512(), reason="needs a CPU with AVX-512 (two estimate ISAs)")
def test_avx512_and_avx2_render_the_same_bits():
    wide, narrow = _render("native"), _render("avx2")
    assert (wide["lanes"], narrow["lanes"]) == (16, 8)
    for name in ("glass_bunny", "cornell_sphere"):
        assert wide[name] == narrow[name], name
