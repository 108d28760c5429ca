"""Frozen Whitted frame (first view, 256², the backend's accelerator, median kernel ms) over
the SAH, radix and PLOC (several radii) trees of bundled scenes, with whether each image is
bitwise the SAH tree's. Each tree is built once per scene (memoised). Usage:
    python lab/probes/ploc_frames.py [--radii 4,8,16] [--size 256] [--frames 5] SCENE...
"""
import argparse
import os
from functools import partial
from pathlib import Path

import numpy as np

import renderer.accel as accel_pkg
import renderer.accel.builders as builders
from evaluation.bench.frames import frozen_frame_ms
from renderer.accel.ploc import build_ploc
from renderer.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]
ap = argparse.ArgumentParser()
ap.add_argument("scenes", nargs="+")
ap.add_argument("--radii", default="4,8,16")
ap.add_argument("--size", type=int, default=256)
ap.add_argument("--frames", type=int, default=5)
ap.add_argument("--backend", default="llvm")
args = ap.parse_args()

memo = {}
plain = builders.binary_tree


def memo_tree(scene, backend, **kw):
    key = (id(scene.faces), kw.get("build"), builders.build_ploc.keywords.get("radius")
           if isinstance(builders.build_ploc, partial) else None)
    if key not in memo:
        memo[key] = plain(scene, backend, **kw)
    return memo[key]


accel_pkg.binary_tree = memo_tree
print(f"load average {os.getloadavg()[0]:.1f}")
print("| scene | tree | SAH cost | frame kernel ms | / SAH | same image |")
print("| --- | --- | ---: | ---: | ---: | --- |")
for name in args.scenes:
    sc = load_scene(ROOT / "scenes" / f"{name}.toml").with_size(args.size, args.size)
    runs = [("sah", "sah", None), ("radix", "radix", None)]
    runs += [(f"ploc r={r}", "ploc", r) for r in map(int, args.radii.split(","))]
    ref = None
    for label, build, r in runs:
        builders.build_ploc = partial(build_ploc, radius=r) if r else build_ploc
        res = frozen_frame_ms(sc.with_settings(build=build), backend=args.backend, accel=None,
                              frames=args.frames)
        tree = memo[(id(sc.faces), build, r)][0]
        if ref is None:
            ref = res
        print(f"| {name} | {label} | {tree.sah_cost:.2f} | {res['frozen_kernel_ms']:.1f} | "
              f"{res['frozen_kernel_ms'] / ref['frozen_kernel_ms']:.2f} | "
              f"{'yes' if np.array_equal(res['image'], ref['image']) else 'NO'} |", flush=True)
    memo.clear()
