"""Backend and precision: which Dr.Jit array types the kernels are built from.

Every kernel module takes its types from a ``Types`` bundle instead of hard-coding
``drjit.cuda`` or ``drjit.llvm``: ``types()`` gives ``drjit.auto``'s choice (CUDA when a GPU
is present, LLVM otherwise); ``types("llvm")`` forces the CPU backend. ``precision`` selects
float32 (default) or float64 for every floating-point array, so the same code renders in
double precision. The LLVM backend is refused before any kernel where the libLLVM Dr.Jit
loaded cannot run it (``llvm_problem``: one line with the fix). The renderer takes its
reciprocals from here (``rcp``, ``rsqrt``, ``normalize``): Dr.Jit's own are float32-accurate
for float64 arrays on CUDA, and its float32 ``rsqrt`` on LLVM depends on the CPU. Its
``syntax`` is ``dr.syntax`` applied at a function's first call, so a process pays the
source transformation only for the kernels it traces.
"""
from __future__ import annotations

import importlib
import os
from dataclasses import dataclass
from functools import lru_cache, wraps

import drjit as dr
import numpy as np

BACKENDS = ("auto", "cuda", "llvm")
PRECISIONS = ("float32", "float64")


class DeviceError(RuntimeError):
    """A backend that this machine cannot run (``--backend cuda`` without a CUDA device,
    the LLVM backend without a usable libLLVM)."""


def syntax(f):
    """``@dr.syntax`` (Python control flow on Dr.Jit values as symbolic loops and
    conditionals), transformed at the first call of ``f`` rather than at its definition:
    the transformation reads and recompiles the function's source (milliseconds each), and
    a render calls only some of the kernels the renderer defines."""
    done = []

    @wraps(f)
    def call(*args, **kwargs):
        if not done:
            done.append(dr.syntax(f))
        return done[0](*args, **kwargs)
    return call


#: The oldest libLLVM major version the LLVM backend renders with: Dr.Jit 1.5 refuses 14
#: (no opaque pointers) and LLVM 15 aborts while compiling the render kernel (a DAG dump,
#: exit 134); 19 is the version ``ci/setup.sh`` installs.
MIN_LLVM = 16
LLVM_FIX = ("install libLLVM 19 (`apt-get install libllvm19`) or point DRJIT_LIBLLVM_PATH "
            "at a libLLVM.so of version {min} or newer")


def llvm_problem() -> str | None:
    """Why the LLVM backend cannot run here, with the fix, in one line; None where it can
    (a libLLVM of version ``MIN_LLVM`` or newer is loaded). Decided from what Dr.Jit
    found when it was imported, before any kernel."""
    version = tuple(dr.detail.llvm_version())
    fix = LLVM_FIX.format(min=MIN_LLVM)
    path = os.environ.get("DRJIT_LIBLLVM_PATH")
    where = f" (DRJIT_LIBLLVM_PATH={path})" if path else ""
    if not dr.has_backend(dr.JitBackend.LLVM) and version[0] < 0:
        return f"backend 'llvm': no usable libLLVM was loaded{where}; {fix}"
    if version[0] < MIN_LLVM:
        found = ".".join(map(str, version))
        return f"backend 'llvm': libLLVM {found}{where} is too old (it cannot compile " \
               f"the render kernels); {fix}"
    return None


@dataclass(frozen=True)
class Types:
    backend: str            # "cuda" | "llvm" (resolved, never "auto")
    precision: str          # "float32" | "float64"
    Float: type
    UInt32: type
    Int32: type
    Bool: type
    Array2f: type
    Array3f: type
    Array3u: type
    TensorXf: type
    PCG32: type

    @property
    def is_double(self) -> bool:
        return self.precision == "float64"


@lru_cache(maxsize=None)
def types(backend: str = "auto", precision: str = "float32") -> Types:
    """The array types for ``backend`` ("auto" | "cuda" | "llvm") and ``precision``."""
    if backend not in BACKENDS:
        raise ValueError(f"backend: expected one of {BACKENDS}, got {backend!r}")
    if precision not in PRECISIONS:
        raise ValueError(f"precision: expected one of {PRECISIONS}, got {precision!r}")
    if backend == "auto":
        import drjit.auto as auto
        backend = "cuda" if dr.backend_v(auto.Float) == dr.JitBackend.CUDA else "llvm"
    if backend == "cuda" and not dr.has_backend(dr.JitBackend.CUDA):
        raise DeviceError("backend 'cuda' requested but no CUDA device is available "
                          "(backend 'llvm' or 'auto' runs on the CPU)")
    if backend == "llvm" and (problem := llvm_problem()) is not None:
        raise DeviceError(problem)
    m = importlib.import_module(f"drjit.{backend}")
    s = "64" if precision == "float64" else ""
    return Types(
        backend=backend, precision=precision,
        Float=getattr(m, "Float" + s), UInt32=m.UInt32, Int32=m.Int32, Bool=m.Bool,
        Array2f=getattr(m, "Array2f" + s), Array3f=getattr(m, "Array3f" + s),
        Array3u=m.Array3u, TensorXf=getattr(m, "TensorXf" + s), PCG32=m.PCG32,
    )


def start_backend(backend: str):
    """Start initialising the CUDA backend (driver, context) on a background thread, so it
    overlaps with work that needs no device (reading the scene): ``types`` then finds it
    ready. Returns the thread, or None for a backend other than "cuda" (the LLVM backend is
    checked first by ``types``, and "auto" probes CUDA itself)."""
    if backend != "cuda":
        return None
    import threading
    th = threading.Thread(target=dr.has_backend, args=(dr.JitBackend.CUDA,), daemon=True,
                          name="start cuda")
    th.start()
    return th


#: Byte alignment of the host buffers device arrays are made from (``host_array``).
HOST_ALIGN = 64


def host_array(x, dtype=None) -> np.ndarray:
    """A C-contiguous copy of ``x`` (as ``dtype``) starting at a ``HOST_ALIGN``-byte
    boundary, for ``t.Float(...)``-style uploads. On LLVM Dr.Jit reads a numpy array's own
    memory and marks a kernel input whose address is not aligned to the vector width
    (``align 1`` instead of ``align 4``/``32`` in the IR): the traced kernel, and its
    hash, then depended on where numpy's allocator put the array (it moved with
    ``PYTHONHASHSEED``), so a warm run could compile again. Aligned, the kernel is the
    same in every run."""
    x = np.asarray(x, dtype=dtype)
    buf = np.empty(x.nbytes + HOST_ALIGN, np.uint8)
    start = (-buf.ctypes.data) % HOST_ALIGN
    out = buf[start:start + x.nbytes].view(x.dtype).reshape(x.shape)
    out[...] = x
    return out


def host_view(x: np.ndarray, dtype=None) -> np.ndarray:
    """``x`` itself where it is a C-contiguous array of ``dtype`` (default its own) that
    starts at a ``HOST_ALIGN``-byte boundary (a cache entry's arrays), else
    ``host_array(x, dtype)``. Only for arrays no other device array is made from: on LLVM
    the device array is then ``x``'s memory (``base.as_pairs`` on why two device arrays
    must not share it)."""
    dt = x.dtype if dtype is None else np.dtype(dtype)
    if (isinstance(x, np.ndarray) and x.dtype == dt and x.flags.c_contiguous
            and x.ctypes.data % HOST_ALIGN == 0):
        return x
    return host_array(x, dtype)


def array3(t: Types, rows) -> object:
    """``t.Array3f`` of width N from host rows (anything numpy reads as (N, 3) or (3,))."""
    x = np.asarray(rows, np.float64).reshape(-1, 3)
    fdt = np.float64 if t.is_double else np.float32
    return t.Array3f(*(t.Float(host_array(x[:, k], fdt)) for k in range(3)))


# ---- reciprocals that keep float64 float64 on CUDA --------------------------------------
# Under Dr.Jit 1.5's default ``JitFlag.FastMath`` the CUDA backend emits ``dr.rcp`` as
# ``rcp.approx.ftz`` for float64 as well as float32 (the flag's other approximations are
# float32-only), and ``dr.rsqrt`` and ``dr.normalize`` of float64 go through that
# reciprocal: about float32's accuracy in a float64 render (Möller–Trumbore's distances on
# rays from 10^4 radii away came out 2e-7 too short, so a BVH that culled by its padded
# boxes disagreed with brute force). These helpers divide instead for float64
# (``div.rn.f64``, correctly rounded) and keep Dr.Jit's own operations for float32 on
# CUDA. The LLVM backend already divides for ``dr.rcp``; its float32 ``dr.rsqrt`` starts
# from the CPU's estimate instruction (``vrsqrtps`` with AVX2, ``vrsqrt14ps`` with
# AVX-512) and refines it, so its last bits, and an ill-conditioned pixel of a glass
# bunny, depended on the CPU. On LLVM ``rsqrt`` is ``1 / sqrt(x)``, two correctly rounded
# operations: the same image on every CPU (the bundled scenes' renders are bitwise equal
# at 8 and 16 lanes).
def _double(x) -> bool:
    return dr.type_v(x) == dr.VarType.Float64


def _llvm(x) -> bool:
    return dr.backend_v(x) == dr.JitBackend.LLVM


def rcp(x):
    """``1 / x``: correctly rounded in float64 on every backend; ``dr.rcp`` in float32."""
    return 1.0 / x if _double(x) else dr.rcp(x)


def rsqrt(x):
    """``1 / sqrt(x)``: in float64 ``sqrt(1 / x)`` (Dr.Jit's own float64 formula, with an
    exact reciprocal); in float32 ``1 / sqrt(x)`` on LLVM (the same bits on every CPU),
    ``dr.rsqrt`` on CUDA."""
    if _double(x):
        return dr.sqrt(1.0 / x)
    return 1.0 / dr.sqrt(x) if _llvm(x) else dr.rsqrt(x)


def normalize(v):
    """``v / |v|`` as ``dr.normalize`` computes it (``v * rsqrt(|v|²)``), with ``rsqrt``'s
    float64 accuracy."""
    return v * rsqrt(dr.squared_norm(v))


def unit_roundoff(double: bool) -> float:
    """Unit roundoff of float64 (``double``) or float32: half the distance from 1 to the
    next float."""
    return 2.0 ** -53 if double else 2.0 ** -24
