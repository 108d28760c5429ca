"""Dr.Jit's own numbers for the kernels a call launches: how many, how big, how long.

Every timing reads Dr.Jit's kernel history (``dr.JitFlag.KernelHistory``) through one
function, ``kernel_launches(fn)`` (one call of ``fn`` under the history: its result, the
history entries of the kernels it launched, its wall time), so Python tracing and compilation
are never counted as kernel time. The renderer, the bench, the study and the tests take their
kernel numbers from it or from the two summaries built on it:

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


def kernel_launches(fn) -> tuple[object, list[dict], float]:
    """Run ``fn()`` once under Dr.Jit's kernel history, older entries dropped first.

    Returns ``(result, history, wall_ms)``: what ``fn`` returned, the history entries of the
    kernels launched during the call (dicts with ``execution_time``, ``operation_count``,
    ``codegen_time``, ``backend_time``, ``type``, ... where Dr.Jit records them) and the
    call's wall time in ms until its kernels finished. ``fn`` must evaluate its results."""
    dr.sync_thread()
    dr.kernel_history()  # drop older entries
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        t0 = time.perf_counter()
        result = fn()
        dr.sync_thread()
        wall_ms = (time.perf_counter() - t0) * 1e3
        history = dr.kernel_history()
    return result, history, wall_ms


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
    result, history, _ = kernel_launches(fn)
    history = [h for h in history if "operation_count" in h]
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
    kern, wall, launches = [], [], []
    for _ in range(repeats):
        _, hist, ms = kernel_launches(fn)
        hist = [h for h in hist if "execution_time" in h]
        wall.append(ms)
        kern.append(sum(h["execution_time"] for h in hist))
        launches.append(len(hist))
    return {"kernel_ms": statistics.median(kern), "kernel_ms_min": min(kern),
            "wall_ms": statistics.median(wall), "kernels": statistics.median(launches),
            "repeats": repeats}


def format_operations(k: dict) -> str:
    """One line for logs and reports: ``"1,234 IR operations in 2 kernel(s), largest 1,200"``."""
    return (f"{k['operations']:,} IR operations in {k['kernels']} kernel(s), "
            f"largest {k['largest']:,}")
