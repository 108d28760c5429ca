"""The wide traversal's stack size against its frames: the frozen Whitted frame (the
bench's: first view, ``--size``², ``--accel``, median kernel ms of ``--frames``) over
the SAH tree and PLOC's tree (``--builds``), each collapsed for a stack of each
``--stacks`` size, with the collapse's mean fill and most stack entries, and whether the
image is bitwise the first variant's. ``--accel bvh``: the binary traversal with each
stack allocated (its tree needs at most ``MAX_LEVELS``; the fill columns are then the
4-wide collapse's, not used). The variants alternate round by round so drift
shows. Usage:

    python lab/probes/wide_stack.py --backend llvm [--stacks 32,64] [--rounds 3] SCENE...
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np

import renderer.accel.layout as layout
import renderer.accel.traverse as traverse
import renderer.accel.wide as wide
from evaluation.bench.frames import frozen_frame_ms
from renderer.accel import builders
from renderer.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]
ap = argparse.ArgumentParser()
ap.add_argument("scenes", nargs="+")
ap.add_argument("--backend", default="llvm")
ap.add_argument("--accel", default="bvh4")
ap.add_argument("--size", type=int, default=512)
ap.add_argument("--frames", type=int, default=10)
ap.add_argument("--rounds", type=int, default=3)
ap.add_argument("--stacks", default="32,64")
ap.add_argument("--builds", default="sah,ploc")
ap.add_argument("--out", default=None)
args = ap.parse_args()
stacks = [int(s) for s in args.stacks.split(",")]
builds = args.builds.split(",")
out = {"load": os.getloadavg()[0], "size": args.size, "accel": args.accel}
print(f"load average {out['load']:.1f}", flush=True)
original = layout.STACK_SIZE


def set_stack(n: int) -> None:
    """The traversal's stack and the collapse's bound at ``n`` entries."""
    for mod in (layout, traverse, wide):
        mod.STACK_SIZE = n
    wide.collapse.__defaults__ = (4, n)


for name in args.scenes:
    sc = load_scene(ROOT / "scenes" / f"{name}.toml").with_size(args.size, args.size)
    rows, ref = {}, None
    width = int(args.accel[3:] or 2)          # "bvh": the binary traversal, no collapse
    for _round in range(args.rounds):
        for build in builds:
            for n in stacks:
                set_stack(n)
                tree, _ = builders.binary_tree(sc, args.backend, build=build)
                w = wide.collapse(tree, max(width, 4), n)
                res = frozen_frame_ms(sc.with_settings(build=build), backend=args.backend,
                                      accel=args.accel, frames=args.frames)
                ref = res["image"] if ref is None else ref
                r = rows.setdefault(f"{build}-{n}", {
                    "fill": float(np.mean(w.refs != layout.DONE)), "max_stack": w.max_stack,
                    "levels": w.levels, "binary_levels": tree.levels, "frame_ms": [],
                    "same_image": bool(np.array_equal(res["image"], ref))})
                r["frame_ms"].append(res["frozen_kernel_ms"])
    set_stack(original)
    base = np.median(rows[f"{builds[0]}-{stacks[0]}"]["frame_ms"])
    print(f"| {name} | variant | fill | max stack | wide levels | frame ms (rounds) | "
          "median / first's | same |")
    for label, r in rows.items():
        print(f"| {name} | {label} | {r['fill']:.3f} | {r['max_stack']} | {r['levels']} | "
              f"{' / '.join(f'{x:.2f}' for x in r['frame_ms'])} | "
              f"{np.median(r['frame_ms']) / base:.3f} | "
              f"{'yes' if r['same_image'] else 'NO'} |", flush=True)
    out[name] = rows
if args.out:
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / f"wide_stack-{args.backend}.json").write_text(json.dumps(out, indent=1))
