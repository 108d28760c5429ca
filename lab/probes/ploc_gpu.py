"""Build time (median of 5 after a warm-up build, ``dr.sync_thread`` before each clock read)
of the radix and PLOC trees (radii 4, 8, 16), the host SAH build, and a frozen Whitted
frame (first view, the backend's accelerator, median kernel ms) over the SAH, radix and
PLOC (r = 8) trees, images compared bitwise. Writes ``OUT/ploc_gpu.json``. Usage:
    python lab/probes/ploc_gpu.py --backend cuda --size 1024 --out DIR SCENE...
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
from evaluation.bench.frames import frozen_frame_ms
from renderer.accel.builders import binary_tree
from renderer.accel.bvh_build import build_bvh, check_bvh
from renderer.accel.device_build import build_device
from renderer.accel.ploc import build_ploc
from renderer.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]
ap = argparse.ArgumentParser()
ap.add_argument("scenes", nargs="+")
ap.add_argument("--backend", default="cuda")
ap.add_argument("--size", type=int, default=1024)
ap.add_argument("--out", default=".")
ap.add_argument("--repeats", type=int, default=5)
args = ap.parse_args()
memo = {}


def memo_tree(scene, backend, **kw):
    key = (id(scene.faces), kw.get("build"))
    if key not in memo:
        memo[key] = binary_tree(scene, backend, **kw)
    return memo[key]


accel_pkg.binary_tree = memo_tree
try:
    from evaluation.bench import device_info
    dev = device_info(args.backend)
except Exception as e:                        # no Mitsuba or the like on the device host
    dev = {"backend": args.backend, "device": f"unknown ({e})"}
print(f"device: {dev.get('device')} ({args.backend}), load {os.getloadavg()[0]:.1f}", flush=True)
rows = []


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


for name in args.scenes:
    sc = load_scene(ROOT / "scenes" / f"{name}.toml")
    V, Fa, F = sc.vertices, sc.faces, sc.face_count
    row = {"scene": name, "triangles": F, "builds": {}}
    a, s = timed(partial(build_device, V, Fa, args.backend))
    row["builds"]["radix"] = {"s": s, "sah_cost": a.sah_cost, "levels": a.levels}
    for r in (4, 8, 16):
        st = {}
        a, s = timed(partial(build_ploc, V, Fa, args.backend, radius=r, stats=st))
        check_bvh(a)
        row["builds"][f"ploc{r}"] = {"s": s, "sah_cost": a.sah_cost, "levels": a.levels, **st}
    ph = {}
    build_ploc(V, Fa, args.backend, stats={"phases": ph})
    row["ploc8_phases_s"] = ph
    t = time.perf_counter()
    a = build_bvh(V, Fa)
    row["builds"]["sah"] = {"s": time.perf_counter() - t, "sah_cost": a.sah_cost,
                            "levels": a.levels}
    for b, v in row["builds"].items():
        print(f"  {name:11s} {b:7s} {v['s'] * 1e3:9.2f} ms {F / v['s'] / 1e6:8.2f} M/s "
              f"SAH {v['sah_cost']:6.2f} levels {v['levels']}", flush=True)
    print(f"  {name:11s} ploc8 phases (ms): "
          + ", ".join(f"{k} {1e3 * x:.2f}" for k, x in ph.items()), flush=True)
    frames, ref = {}, None
    scs = sc.with_size(args.size, args.size)
    for b in ("sah", "radix", "ploc"):
        res = frozen_frame_ms(scs.with_settings(build=b), backend=args.backend, accel=None,
                              frames=20)
        ref = ref if ref is not None else res["image"]
        frames[b] = {"kernel_ms": res["frozen_kernel_ms"],
                     "same_image": bool(np.array_equal(ref, res["image"]))}
        print(f"  {name:11s} frame {b:6s} {res['frozen_kernel_ms']:8.3f} ms "
              f"x{res['frozen_kernel_ms'] / frames['sah']['kernel_ms']:.3f} "
              f"same={frames[b]['same_image']}", flush=True)
    row["frames"] = frames
    rows.append(row)
    memo.clear()
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / "ploc_gpu.json").write_text(json.dumps({"device": dev, "rows": rows},
                                                             indent=1))
