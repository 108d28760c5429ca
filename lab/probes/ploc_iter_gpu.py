"""Where a PLOC build's time goes on a backend, per part: the clustering iterations' host
time (tracing and launching ``_pairs`` and ``_merge``, clocked around each call, which does
not wait for the device) against the device's own kernel time (``dr.kernel_history``'s
``execution_time``), with ``FREEZE`` off and on; the bare cost of one traced and launched
kernel (a loop of tiny kernels, traced and frozen); and the build's transfers (the
vertex/face upload and the tree's copy back, as bytes and ms). Medians of ``--repeats``
builds after a warm-up, ``dr.sync_thread`` around each. Usage:

    python lab/probes/ploc_iter_gpu.py --backend cuda [--repeats 5] [--out DIR] SCENE...
"""
from __future__ import annotations

import argparse
import collections
import json
import os
import statistics
import time
from pathlib import Path

import drjit as dr
import numpy as np

import renderer.accel.ploc as ploc
from renderer.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]
ap = argparse.ArgumentParser()
ap.add_argument("scenes", nargs="+")
ap.add_argument("--backend", default="cuda")
ap.add_argument("--repeats", type=int, default=5)
ap.add_argument("--out", default=None)
args = ap.parse_args()
m = ploc._module(args.backend)
out = {"load": os.getloadavg()[0], "backend": args.backend}
clock = collections.defaultdict(float)


def timed(name, fn):
    def run(*a, **k):
        t = time.perf_counter()
        r = fn(*a, **k)
        clock[name] += time.perf_counter() - t
        clock[name + " calls"] += 1
        return r
    return run


ploc._pairs, ploc._merge = timed("pairs", ploc._pairs), timed("merge", ploc._merge)
ploc._BLOCK = timed("block", ploc._BLOCK)


def launch_cost(n_kernels=200, width=1000):
    """ms of host time per traced + launched tiny kernel, and per frozen replay of one."""
    x = dr.opaque(m.Float, 0, width)         # evaluated (a literal would fold away)
    dr.sync_thread()
    t = time.perf_counter()
    for _ in range(n_kernels):
        x = x + 1
        dr.eval(x)
    host = time.perf_counter() - t
    dr.sync_thread()
    wall = time.perf_counter() - t

    @dr.freeze
    def step(y):
        return y * 1.0001 + 1

    for _ in range(3):
        x = step(x)
    dr.sync_thread()
    t = time.perf_counter()
    for _ in range(n_kernels):
        x = step(x)
    fhost = time.perf_counter() - t
    dr.sync_thread()
    fwall = time.perf_counter() - t
    return {"traced_host_ms": 1e3 * host / n_kernels, "traced_wall_ms": 1e3 * wall / n_kernels,
            "frozen_host_ms": 1e3 * fhost / n_kernels, "frozen_wall_ms": 1e3 * fwall / n_kernels}


def transfers(V, F):
    """ms to upload the vertices and faces as ``build_ploc`` does, and to copy back 62 MB."""
    ts_up, ts_down = [], []
    big = dr.zeros(m.UInt32, 62 * (1 << 20) // 4)
    dr.eval(big)
    for _ in range(args.repeats):
        dr.sync_thread()
        t = time.perf_counter()
        v = [m.Float(np.ascontiguousarray(V[:, a])) for a in range(3)]
        f = m.UInt32(np.ascontiguousarray(F.astype(np.uint32)).ravel())
        dr.eval(v, f)
        dr.sync_thread()
        ts_up.append(time.perf_counter() - t)
        t = time.perf_counter()
        big.numpy()
        ts_down.append(time.perf_counter() - t)
    return {"upload_bytes": V.nbytes // 2 + F.size * 4, "upload_ms": 1e3 * statistics.median(ts_up),
            "copy_back_62MB_ms": 1e3 * statistics.median(ts_down)}


def one_build(V, F, freeze):
    ploc.FREEZE[args.backend] = freeze
    ph = {}
    clock.clear()
    dr.kernel_history()
    dr.sync_thread()
    t = time.perf_counter()
    ploc.build_ploc(V, F, args.backend, cuts=False, stats={"phases": ph})
    dr.sync_thread()
    wall = time.perf_counter() - t
    hist = dr.kernel_history()
    by = collections.Counter(str(k.get("type")).split(".")[-1] for k in hist)
    return {"wall_ms": 1e3 * wall, "phases_ms": {k: 1e3 * v for k, v in ph.items()},
            "host_pairs_ms": 1e3 * clock["pairs"], "host_merge_ms": 1e3 * clock["merge"],
            "host_block_ms": 1e3 * clock["block"], "iterations": clock["pairs calls"],
            "blocks": clock["block calls"],
            "kernel_exec_ms": sum(k.get("execution_time", 0) for k in hist),
            "kernels": len(hist), "kernel_types": dict(by)}


def plain_build(V, F, freeze, every=None):
    ploc.FREEZE[args.backend] = freeze
    ploc.READ_EVERY[args.backend] = every or EVERY
    dr.sync_thread()
    t = time.perf_counter()
    a = ploc.build_ploc(V, F, args.backend, cuts=False)
    dr.sync_thread()
    ms = 1e3 * (time.perf_counter() - t)
    ploc.READ_EVERY[args.backend] = EVERY
    trees.add(hash(a.boxes.tobytes() + a.children.tobytes() + a.order.tobytes()))
    return ms


EVERY = ploc.READ_EVERY[args.backend]


out["launch"] = launch_cost()
print("launch", json.dumps(out["launch"]), flush=True)
for name in args.scenes:
    s = load_scene(ROOT / "scenes" / f"{name}.toml")
    V, F = np.asarray(s.vertices, np.float32), np.asarray(s.faces)
    row = {"triangles": len(F)}
    trees = set()
    # a fresh process's first build (the recording included), then the warm builds,
    # the variants interleaved round by round
    variants = [(False, None), (True, None), (True, 8), (False, 8)]
    for freeze, every in variants:
        row[f"freeze={freeze} every={every} first_ms"] = plain_build(V, F, freeze, every)
    samples = {v: [] for v in variants}
    for _ in range(args.repeats):
        for v in variants:
            samples[v].append(plain_build(V, F, *v))
    for (freeze, every), ts in samples.items():
        row[f"freeze={freeze} every={every} median_ms"] = statistics.median(ts)
        row[f"freeze={freeze} every={every} all_ms"] = ts
    row["same_tree"] = len(trees) == 1
    for freeze in (False, True):
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        row[f"freeze={freeze} profile"] = one_build(V, F, freeze)
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    row["transfers"] = transfers(V, F)
    ploc.FREEZE[args.backend] = False
    out[name] = row
    print(name, json.dumps(row), flush=True)
if args.out:
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / f"ploc_iter-{args.backend}.json").write_text(json.dumps(out, indent=1))
