"""Frozen Whitted frame (the bench's: first view, ``--size``², the backend's accelerator,
median kernel ms of ``--frames``) over the SAH tree and PLOC trees built with other
parameters (the search radius, ``presplit``'s cut constants), with each tree's SAH cost,
build ms and whether its image is bitwise the SAH tree's. No cache (the variants share
cache keys). Rounds alternate the trees so drift shows. Usage:

    python lab/probes/ploc_variants.py --backend cuda [--size 512] [--rounds 2] SCENE...
"""
from __future__ import annotations

import argparse
import json
import os
import time
from functools import partial
from pathlib import Path

import numpy as np

import renderer.accel.builders as builders
import renderer.accel.presplit as presplit
from evaluation.bench.frames import frozen_frame_ms
from renderer.accel.ploc import build_ploc
from renderer.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]
VARIANTS = {                      # name: (radius, presplit overrides)
    "ploc": (8, {}),
    "r16": (16, {}),
    "r32": (32, {}),
    "split0.005": (8, {"SPLIT_SIZE": 0.005}),
    "budget0.6": (8, {"SPLIT_BUDGET": 0.6}),
    "grid3": (8, {"GRID_LEVELS": 3}),
    "gain1": (8, {"GAIN": 1.0}),
    "r16-split0.005-budget0.6": (16, {"SPLIT_SIZE": 0.005, "SPLIT_BUDGET": 0.6}),
}
ap = argparse.ArgumentParser()
ap.add_argument("scenes", nargs="+")
ap.add_argument("--backend", default="cuda")
ap.add_argument("--size", type=int, default=512)
ap.add_argument("--frames", type=int, default=20)
ap.add_argument("--rounds", type=int, default=2)
ap.add_argument("--variants", default=",".join(VARIANTS))
ap.add_argument("--accel", default=None, help="the accelerator (default: the backend's)")
ap.add_argument("--out", default=None)
args = ap.parse_args()
names = args.variants.split(",")
defaults = {k: getattr(presplit, k) for k in ("SPLIT_SIZE", "SPLIT_BUDGET", "GRID_LEVELS", "GAIN")}
out = {"load": os.getloadavg()[0], "size": args.size}
print(f"load average {out['load']:.1f}", flush=True)
for name in args.scenes:
    sc = load_scene(ROOT / "scenes" / f"{name}.toml").with_size(args.size, args.size)
    rows = {}
    ref = None
    for _round in range(args.rounds):
        for label in ["sah"] + names:
            if label == "sah":
                build = "sah"
                builders.build_ploc = build_ploc
            else:
                build = "ploc"
                radius, over = VARIANTS[label]
                for k, v in defaults.items():
                    setattr(presplit, k, over.get(k, v))
                builders.build_ploc = partial(build_ploc, radius=radius)
            t = time.perf_counter()
            tree, _ = builders.binary_tree(sc, args.backend, build=build)
            build_ms = 1e3 * (time.perf_counter() - t)
            res = frozen_frame_ms(sc.with_settings(build=build), backend=args.backend,
                                  accel=args.accel, frames=args.frames)
            if ref is None:
                ref = res["image"]
            r = rows.setdefault(label, {"sah_cost": tree.sah_cost, "levels": tree.levels,
                                        "frame_ms": [], "build_ms": [],
                                        "same_image": bool(np.array_equal(res["image"], ref))})
            r["frame_ms"].append(res["frozen_kernel_ms"])
            r["build_ms"].append(build_ms)
    for k, v in defaults.items():
        setattr(presplit, k, v)
    base = min(rows["sah"]["frame_ms"])
    print(f"| {name} | tree | SAH cost | levels | frame ms (rounds) | best / SAH best | "
          "build ms | same |")
    for label, r in rows.items():
        print(f"| {name} | {label} | {r['sah_cost']:.2f} | {r['levels']} | "
              f"{' / '.join(f'{x:.3f}' for x in r['frame_ms'])} | "
              f"{min(r['frame_ms']) / base:.3f} | "
              f"{min(r['build_ms']):.0f} | {'yes' if r['same_image'] else 'NO'} |", flush=True)
    out[name] = rows
if args.out:
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / f"ploc_variants-{args.backend}.json").write_text(json.dumps(out, indent=1))
