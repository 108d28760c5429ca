"""Dr.Jit's own numbers for one frame: how many kernels it launched and how big they are.

``kernel_operations(fn)`` runs ``fn`` under ``dr.JitFlag.KernelHistory`` and sums the
``operation_count`` (IR operations of each compiled kernel) and ``execution_time`` entries of
the kernel history. This is how the renderer proves that a kernel specialised to a scene's
``EffectSet`` is smaller than the all-effects kernel.
"""
from __future__ import annotations

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


def format_operations(k: dict) -> str:
    """One line for logs and reports: ``"1,234 IR operations in 2 kernel(s), largest 1,200"``."""
    return (f"{k['operations']:,} IR operations in {k['kernels']} kernel(s), "
            f"largest {k['largest']:,}")
