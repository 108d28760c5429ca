"""PLOC with and without cut large triangles (``renderer.accel.presplit``) against the host
SAH tree: build time (median of ``--repeats`` after a warm-up, ``dr.sync_thread`` before
each clock read), phases, SAH cost, references, and a frozen Whitted frame (first view, the
backend's accelerator, median kernel ms) over each tree, images compared bitwise with the
SAH tree's. Writes ``OUT/presplit_gpu.json``. Usage:
    python lab/probes/presplit_gpu.py --backend cuda --size 1024 --out DIR SCENE...
"""
import argparse
import json
import os
import statistics
import time
from functools import partial
from pathlib import Path

import drjit as dr
import numpy as np

import renderer.accel as accel_pkg
import renderer.accel.presplit as presplit
from evaluation.bench.frames import frozen_frame_ms
from renderer.accel.builders import binary_tree
from renderer.accel.bvh_build import check_bvh
from renderer.accel.ploc import build_ploc
from renderer.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]
ap = argparse.ArgumentParser()
ap.add_argument("scenes", nargs="+")
ap.add_argument("--backend", default="cuda")
ap.add_argument("--size", type=int, default=1024)
ap.add_argument("--out", default=".")
ap.add_argument("--repeats", type=int, default=5)
ap.add_argument("--frames", type=int, default=20)
args = ap.parse_args()
SIZE = presplit.SPLIT_SIZE
memo = {}


def memo_tree(scene, backend, **kw):
    key = (id(scene.faces), kw.get("build"), presplit.SPLIT_SIZE)
    if key not in memo:
        memo[key] = binary_tree(scene, backend, **kw)
    return memo[key]


accel_pkg.binary_tree = memo_tree
name = getattr(dr, "device_name", None)
print(f"backend {args.backend}, load {os.getloadavg()[0]:.1f}", flush=True)
try:
    import subprocess
    print(subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"],
                         capture_output=True, text=True).stdout.strip(), flush=True)
except Exception:
    pass


def timed(fn):
    fn()                                      # warm-up: kernel compilation
    ts = []
    for _ in range(args.repeats):
        dr.sync_thread()
        t = time.perf_counter()
        a = fn()
        dr.sync_thread()
        ts.append(time.perf_counter() - t)
    return a, statistics.median(ts)


rows = []
for scene in args.scenes:
    sc = load_scene(ROOT / "scenes" / f"{scene}.toml")
    V, Fa, F = sc.vertices, sc.faces, sc.face_count
    row = {"scene": scene, "triangles": F, "builds": {}, "frames": {}}
    for label, size in (("ploc", 0.0), ("ploc+cuts", SIZE)):
        presplit.SPLIT_SIZE = size
        st, ph = {}, {}
        a, s = timed(partial(build_ploc, V, Fa, args.backend, stats=st))
        check_bvh(a)
        build_ploc(V, Fa, args.backend, stats={"phases": ph})
        row["builds"][label] = {"ms": 1e3 * s, "sah_cost": a.sah_cost, "levels": a.levels,
                                "references": int(a.order.size), "phases_ms":
                                {k: 1e3 * x for k, x in ph.items()}, **st}
        print(f"  {scene:11s} {label:10s} {1e3 * s:8.2f} ms SAH {a.sah_cost:6.2f} "
              f"refs {a.order.size} levels {a.levels} phases "
              + ", ".join(f"{k} {1e3 * x:.2f}" for k, x in ph.items()), flush=True)
    scs = sc.with_size(args.size, args.size)
    ref = None
    for label, build, size in (("sah", "sah", SIZE), ("ploc", "ploc", 0.0),
                               ("ploc+cuts", "ploc", SIZE)):
        presplit.SPLIT_SIZE = size
        res = frozen_frame_ms(scs.with_settings(build=build), backend=args.backend,
                              accel=None, frames=args.frames)
        ref = ref if ref is not None else res
        same = bool(np.array_equal(ref["image"], res["image"]))
        row["frames"][label] = {"kernel_ms": res["frozen_kernel_ms"], "same_image": same}
        tree = memo[(id(scs.faces), build, size)][0]
        print(f"  {scene:11s} frame {label:10s} {res['frozen_kernel_ms']:8.3f} ms "
              f"x{res['frozen_kernel_ms'] / ref['frozen_kernel_ms']:.3f} SAH "
              f"{tree.sah_cost:6.2f} same={same}", flush=True)
    presplit.SPLIT_SIZE = SIZE
    rows.append(row)
    memo.clear()
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / "presplit_gpu.json").write_text(json.dumps(rows, indent=1))
