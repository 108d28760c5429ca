"""Where a CUDA PLOC build (``build_ploc(cuts=False)``, ``auto``'s first-image tree) of a large
scene spends its time outside the kernels: the host's input check, the vertex/face upload,
the tree's copy back to the host, against the same build left on the device
(``build_ploc_device``); kernels per build and their summed device time
(``dr.kernel_history``); the device build with several schedules of count reads
(``ploc.READ_BLOCKS``); Mitsuba's scene build (OptiX) on the same triangles.
Medians of ``--repeats`` after two warm-up builds, ``dr.sync_thread`` around each. Usage:

    python lab/probes/device_tree.py --backend cuda [--repeats 9] [--mitsuba] [--out DIR]
        [--scenes bunny_1m,conference,sponza,bunny]
"""
from __future__ import annotations

import json
import os
import statistics
import time
from pathlib import Path

import drjit as dr
import numpy as np
from common import probe_parser

import renderer.accel.device_build as db
import renderer.accel.ploc as ploc
from renderer.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]
ap = probe_parser(__doc__, ["bunny_1m", "conference", "sponza", "bunny"])
ap.add_argument("--repeats", type=int, default=9)
ap.add_argument("--mitsuba", action="store_true", help="also time Mitsuba's scene build")
args = ap.parse_args()
args.scenes = args.scenes.split(",")
missing = [n for n in args.scenes if not (ROOT / "scenes" / f"{n}.toml").is_file()]
if missing:
    raise SystemExit(f"error: --scenes: no scenes/{missing[0]}.toml")
m = ploc._module(args.backend)


def med(fn, n=args.repeats):
    ts = []
    for _ in range(n):
        dr.sync_thread()
        t = time.perf_counter()
        fn()
        dr.sync_thread()
        ts.append(time.perf_counter() - t)
    return round(statistics.median(ts) * 1e3, 3), round(min(ts) * 1e3, 3)


def upload(V, F):
    v = m.Float(np.ascontiguousarray(V, np.float32).reshape(-1))
    f = m.UInt32(np.ascontiguousarray(F).reshape(-1).view(np.uint32))
    dr.eval(v, f)


def probe(name: str) -> dict:
    scene = load_scene(ROOT / "scenes" / f"{name}.toml")
    V, F = scene.vertices, scene.faces
    row = {"scene": name, "triangles": int(F.shape[0]), "load": os.getloadavg()[0]}
    host = lambda: ploc.build_ploc(V, F, args.backend, cuts=False)  # noqa: E731
    dev = lambda: ploc.build_ploc_device(V, F, args.backend, cuts=False)  # noqa: E731
    for _ in range(2):
        host()
        dev()
    variants = {"host": host, "device": dev}
    schedules = {"reads 1": (1,), "reads 1,1,2,4": (1, 1, 2, 4), "reads 1,2,4,8": (1, 2, 4, 8),
                 "reads 1,1,1,2": (1, 1, 1, 2)}
    keep = ploc.READ_BLOCKS[args.backend]
    for tag, sched in schedules.items():
        ploc.READ_BLOCKS[args.backend] = sched
        dev()
        row[f"device_{tag}_ms"] = med(dev)
    ploc.READ_BLOCKS[args.backend] = keep
    for tag, fn in variants.items():          # the kept schedule, last: the bench's view
        row[f"{tag}_ms"] = med(fn)
    row["build_seconds_device_ms"] = statistics.median(dev().build_seconds * 1e3
                                                       for _ in range(args.repeats))
    row["checked_input_ms"] = med(lambda: db.checked_input(V, F, 2))
    row["upload_ms"] = med(lambda: upload(V, F))
    Vn, Fn, _ = db.checked_input(V, F, 2)
    row["boxes_ms"] = med(lambda: db.triangle_boxes(m, Vn, Fn))
    tree = dev()
    row["host_copy_ms"] = med(lambda: db.host_arrays(tree.boxes, tree.children, tree.order,
                                                     tree.raw, tree.scene_box, tree.area,
                                                     tree.levels))
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()
    dev()
    dr.sync_thread()
    hist = dr.kernel_history()
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    row["kernels"] = len(hist)
    row["kernel_ms"] = round(sum(h.get("execution_time", 0.0) for h in hist), 3)
    stats = {}
    ploc.build_ploc(V, F, args.backend, cuts=False, stats=stats)
    row["iterations"] = stats.get("iterations")
    if args.mitsuba:
        from evaluation.bench.build import _mitsuba_build
        from reference import mitsuba_variant
        mitsuba_variant("cuda_ad_rgb" if args.backend == "cuda" else "llvm_ad_rgb")
        _mitsuba_build(scene)
        row["mitsuba_ms"] = sorted(round(_mitsuba_build(scene) * 1e3, 3) for _ in range(5))
    print(json.dumps(row), flush=True)
    return row


rows = [probe(name) for name in args.scenes]
if args.out:
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / f"device_tree-{args.backend}.json").write_text(json.dumps(rows, indent=1))
