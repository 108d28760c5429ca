"""What a traversal step's operations cost on the CPU (LLVM backend): microbenchmarks.

A traversal step on LLVM is a handful of gathers (node record, child references, triangle)
plus stack writes and reads (``dr.alloc_local``) plus arithmetic, for a SIMD packet of
rays at once. This module times those operations alone, in CPU ns per 32-bit word fetched
(or per entry written), over 2 M lanes, median of repeats:

- ``gather32``: 16 words of a 64-byte record, one 32-bit gather each;
- ``gather64``: the same 16 words as 8 64-bit gathers of a UInt64 view (``gather_pairs``);
- ``packet4``: the same 16 words as 4 packet gathers of Array4u (per-lane 16-byte loads
  and a transpose: what CUDA uses);
- ``stack_push`` / ``stack_pop``: one masked write / read of a 32-entry local array at a
  per-lane index inside a symbolic loop (the traversal stack).

Records are drawn from a table that fits in L1 (300 records, 19 KB) or not (20 000,
1.3 MB). Run: ``PYTHONPATH=. python lab/probes/cpu_costs.py`` (prints a markdown table).

``step_fit(rows)`` / ``... cpu_costs.py --fit bench-llvm-throughput.json``:
the per-step costs of a throughput run, by least squares over its (scene, batch, query)
rows, per accelerator: CPU ns per 16-ray packet = a * node steps + b * triangle steps + c,
the steps being those of each packet's slowest ray (``_steps``'s ``*_packet_max``).
"""
from __future__ import annotations

import os
import statistics
import time

import drjit as dr
import numpy as np

LANES = 2_000_000


def _cpu_ms(make, repeats: int = 7) -> float:
    ts = []
    for _ in range(repeats + 1):
        out = make()
        dr.sync_thread()
        c0 = time.process_time()
        dr.eval(out)
        dr.sync_thread()
        ts.append((time.process_time() - c0) * 1e3)
    return statistics.median(ts[1:])


def gathers(records: int, seed: int = 0) -> dict:
    """CPU ns per 32-bit word fetched by each gather form (see the module docstring)."""
    from drjit.llvm import Array4u, UInt32, UInt64
    rng = np.random.default_rng(seed)
    raw = rng.integers(0, 1 << 30, records * 16, dtype=np.uint32)
    b32, b64 = UInt32(raw), UInt64(raw.view(np.uint64))
    idx = UInt32(rng.integers(0, records, LANES, dtype=np.uint32))
    dr.eval(b32, b64, idx)

    def g32():
        s = UInt32(0)
        for k in range(16):
            s += dr.gather(UInt32, b32, idx * 16 + k)
        return s

    def g64():
        s = UInt64(0)
        for k in range(8):
            s += dr.gather(UInt64, b64, idx * 8 + k)
        return UInt32(s) + UInt32(s >> 32)

    def p4():
        s = UInt32(0)
        for k in range(4):
            q = dr.gather(Array4u, b32, idx * 4 + k)
            s += q.x + q.y + q.z + q.w
        return s

    words = LANES * 16
    return {name: _cpu_ms(fn) * 1e6 / words
            for name, fn in (("gather32", g32), ("gather64", g64), ("packet4", p4))}


def stack_ops(iterations: int = 40) -> dict:
    """CPU ns per entry of a masked local-array write (push) and read (pop) at per-lane
    indices inside a symbolic loop, from the difference of loops with and without them."""
    from drjit.llvm import UInt32

    @dr.syntax
    def loop(pushes: int, pops: int, UInt32=UInt32, iterations=iterations):
        i = dr.zeros(UInt32, LANES)
        x = dr.arange(UInt32, LANES)
        acc = dr.zeros(UInt32, LANES)
        stack = dr.alloc_local(UInt32, 32)
        sp = (x * 7) & 7
        while dr.hint(i < iterations, exclude=[UInt32]):
            for k in range(pushes):
                m = ((x >> k) & 1) == 1
                stack.write(x + k, sp, m)
                sp = dr.select(m, sp + 1, sp)
            for _ in range(pops):
                can = sp > 0
                sp = dr.select(can, sp - 1, sp)
                acc += stack.read(sp, can)
            x = x * 1664525 + 1013904223
            sp = sp & 15
            i += 1
        return acc + sp

    n = LANES * iterations
    base = _cpu_ms(lambda: loop(0, 0))
    pop1 = _cpu_ms(lambda: loop(0, 1))
    push3 = _cpu_ms(lambda: loop(3, 1))
    return {"stack_pop": (pop1 - base) * 1e6 / n, "stack_push": (push3 - pop1) * 1e6 / n / 3}


def markdown() -> list[str]:
    from evaluation.bench.part import table
    rows = []
    for records in (300, 20_000):
        g = gathers(records)
        rows.append([f"{records:,} records ({records * 64 / 1024:,.0f} KB)"]
                    + [f"{g[k]:.2f}" for k in ("gather32", "gather64", "packet4")]
                    + [f"{g['gather32'] / g['gather64']:.2f}x"])
    s = stack_ops()
    head = (f"CPU ns per 32-bit word fetched ({LANES:,} lanes, 16 words each; load average "
            f"{os.getloadavg()[0]:.1f})")
    return (table(head, ["table", "32-bit gathers", "64-bit gathers", "Array4u packets",
                         "64-bit speed-up"], "lrrrr", rows)
            + table("CPU ns per traversal-stack entry (masked local-array write / read at a "
                    "per-lane index, in a symbolic loop)", ["push", "pop"], "rr",
                    [[f"{s['stack_push']:.2f}", f"{s['stack_pop']:.2f}"]]))


def step_fit(rows: list[dict], lanes: int = 16) -> dict:
    """``{accel: {"node_ns", "triangle_ns", "const_ns", "r2", "rows", "iteration_ns"}}``
    from throughput rows (see the module docstring); ``iteration_ns``: the median over
    rows of CPU ns per packet per loop iteration of the slowest ray."""
    acc: dict = {}
    for r in rows:
        for b in r["batches"].values():
            for q in ("closest", "any"):
                x = b.get(q)
                if not x or not x.get("steps"):
                    continue
                for a, st in x["steps"].items():
                    if not st or a not in x["ms"]:
                        continue
                    ns = x["ms"][a]["cpu_ms"] * 1e6 / (b["rays"] / lanes)
                    acc.setdefault(a, []).append((st["node_packet_max"],
                                                  st["triangle_packet_max"],
                                                  st["iterations_packet_max"], ns))
    out = {}
    for a, v in acc.items():
        m = np.array(v, np.float64)
        X = np.stack([m[:, 0], m[:, 1], np.ones(len(m))], axis=1)
        coef, *_ = np.linalg.lstsq(X, m[:, 3], rcond=None)
        pred = X @ coef
        r2 = 1 - np.sum((m[:, 3] - pred) ** 2) / max(np.sum((m[:, 3] - m[:, 3].mean()) ** 2),
                                                     1e-30)
        out[a] = {"node_ns": float(coef[0]), "triangle_ns": float(coef[1]),
                  "const_ns": float(coef[2]), "r2": float(r2), "rows": len(m),
                  "iteration_ns": float(np.median(m[:, 3] / np.maximum(m[:, 2], 1e-9)))}
    return out


def step_fit_markdown(rows: list[dict]) -> list[str]:
    from evaluation.bench.part import table
    fit = step_fit(rows)
    cells = [[f"`{a}`", f"{f['node_ns']:.0f}", f"{f['triangle_ns']:.0f}",
              f"{f['const_ns']:.0f}", f"{f['iteration_ns']:.0f}", f"{f['r2']:.2f}",
              str(f["rows"])] for a, f in fit.items()]
    return table("Cost per traversal step (least squares over the rows: CPU ns per 16-ray "
                 "packet = a node steps + b triangle steps + c, steps of the packet's "
                 "slowest ray)", ["accelerator", "a: ns per node step",
                                  "b: ns per triangle step", "c: ns", "ns per loop iteration "
                                  "(median)", "R²", "rows"], "lrrrrrr", cells)


if __name__ == "__main__":
    import argparse
    import json
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--fit", help="a bench-<backend>-throughput.json to fit step costs on")
    args = ap.parse_args()
    if args.fit:
        with open(args.fit) as f:
            print("\n".join(step_fit_markdown(json.load(f)["throughput"])))
    else:
        print("\n".join(markdown()))
