"""Dr.Jit's own numbers for the kernels a call launches: how many, how big, how long.

Both functions read Dr.Jit's kernel history (``dr.JitFlag.KernelHistory``), so Python tracing
and compilation are never counted as kernel time.

``kernel_operations(fn)`` runs ``fn`` once and sums the ``operation_count`` (IR operations of
each compiled kernel) and ``execution_time`` entries: this is how the renderer proves that a
kernel specialised to a scene's ``EffectSet`` is smaller than the all-effects kernel.
``kernel_ms(fn)`` is the timing rule of every benchmark: warm-up calls, then the median over
repeats of the summed kernel execution time.
"""
from __future__ import annotations

import statistics
import time

import drjit as dr


def kernel_operations(fn) -> dict:
    """Run ``fn()`` (e.g. one frame, which must evaluate its result) under kernel history.

    Returns a dict:
      kernels: number of kernels launched (entries with an ``operation_count``);
      operations: sum of their operation counts (IR operations, whole frame);
      largest: operation count of the largest kernel (the traced Whitted kernel);
      ops: list of the per-kernel counts, launch order;
      kernel_ms: sum of their execution times (ms; waits for the kernels to finish);
      result: what ``fn`` returned.
    """
    dr.sync_thread()
    dr.kernel_history()  # drop older entries
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        result = fn()
        dr.sync_thread()
        history = [h for h in dr.kernel_history() if "operation_count" in h]
    ops = [int(h["operation_count"]) for h in history]
    return {"kernels": len(ops), "operations": sum(ops), "largest": max(ops, default=0),
            "ops": ops,
            "kernel_ms": sum(float(h.get("execution_time", 0.0)) for h in history),
            "result": result}


def kernel_ms(fn, *, warmup: int = 2, repeats: int = 10) -> dict:
    """Time ``fn()`` (which must evaluate its results) from the kernel history.

    ``warmup`` calls first (tracing, compilation, caches), then ``repeats`` timed calls.
    Returns a dict:
      kernel_ms: median over the repeats of the summed kernel execution time (ms);
      kernel_ms_min: the smallest of those sums;
      wall_ms: median wall time of a whole call (tracing + launch + sync), ms;
      kernels: median number of kernels launched per call;
      repeats: ``repeats``.
    """
    for _ in range(warmup):
        fn()
        dr.sync_thread()
    dr.kernel_history()  # drop older entries
    kern, wall, launches = [], [], []
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        for _ in range(repeats):
            dr.kernel_history()
            t0 = time.perf_counter()
            fn()
            dr.sync_thread()
            wall.append((time.perf_counter() - t0) * 1e3)
            hist = [h for h in dr.kernel_history() if "execution_time" in h]
            kern.append(sum(h["execution_time"] for h in hist))
            launches.append(len(hist))
    return {"kernel_ms": statistics.median(kern), "kernel_ms_min": min(kern),
            "wall_ms": statistics.median(wall), "kernels": statistics.median(launches),
            "repeats": repeats}


def format_operations(k: dict) -> str:
    """One line for logs and reports: ``"1,234 IR operations in 2 kernel(s), largest 1,200"``."""
    return (f"{k['operations']:,} IR operations in {k['kernels']} kernel(s), "
            f"largest {k['largest']:,}")
