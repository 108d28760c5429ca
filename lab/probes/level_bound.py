"""The binary trees' level bound (``layout.MAX_LEVELS``) and the traversal's stack
(``layout.STACK_SIZE``) against PLOC's build and the frames: per scene, PLOC's build
without and with cuts (median of ``--repeats`` after a warm-up, with the phases of one
more build, the iterations, the clustered tree's levels and the subtrees rebuilt to fit
the bound), the host SAH build's levels and SAH cost, and the frozen Whitted frame (the
bench's: first view, ``--size``², the backend's accelerator or ``--accel``, median kernel
ms) over the SAH tree and PLOC's, with whether the images are bitwise equal. Both
constants are read at import, so one process measures one setting: run it once per
edited ``layout.py`` and compare the JSON lines. Usage:

    python lab/probes/level_bound.py --backend cuda [--size 512] SCENE...
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
from pathlib import Path

import drjit as dr
import numpy as np

import renderer.accel.layout as layout
from evaluation.bench.frames import frozen_frame_ms
from renderer.accel.bvh_build import build_bvh
from renderer.accel.ploc import build_ploc
from renderer.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]
ap = argparse.ArgumentParser()
ap.add_argument("scenes", nargs="+")
ap.add_argument("--backend", default="cuda")
ap.add_argument("--accel", default=None)
ap.add_argument("--size", type=int, default=512)
ap.add_argument("--frames", type=int, default=20)
ap.add_argument("--repeats", type=int, default=7)
ap.add_argument("--tag", default="")
args = ap.parse_args()
out = {"tag": args.tag, "max_levels": layout.MAX_LEVELS, "stack": layout.STACK_SIZE,
       "backend": args.backend, "load": os.getloadavg()[0]}
for name in args.scenes:
    sc = load_scene(ROOT / "scenes" / f"{name}.toml")
    V, Fc = sc.vertices, sc.faces
    row = {"triangles": int(sc.face_count)}
    for cuts in (False, True):
        build_ploc(V, Fc, args.backend, cuts=cuts)                   # warm-up: compilation
        times = []
        for _ in range(args.repeats):
            dr.sync_thread()
            st = {}
            times.append(build_ploc(V, Fc, args.backend, cuts=cuts, stats=st).build_seconds)
        phases = {}
        build_ploc(V, Fc, args.backend, cuts=cuts, stats={"phases": phases})
        key = "cut" if cuts else "nocut"
        row[f"ploc_{key}_ms"] = 1e3 * statistics.median(times)
        row[f"ploc_{key}_mtris_s"] = sc.face_count / statistics.median(times) / 1e6
        row[f"ploc_{key}_stats"] = {k: st.get(k) for k in ("iterations", "levels", "rebuilt",
                                                            "cut", "fallback")}
        row[f"ploc_{key}_phases_ms"] = {k: round(1e3 * v, 2) for k, v in phases.items()}
    sah = build_bvh(V, Fc)
    row["sah_levels"], row["sah_cost"], row["sah_build_s"] = (sah.levels, sah.sah_cost,
                                                              sah.build_seconds)
    images = {}
    for build in ("sah", "ploc"):
        res = frozen_frame_ms(sc.with_settings(build=build).with_size(args.size, args.size),
                              backend=args.backend, accel=args.accel, frames=args.frames)
        row[f"frame_ms_{build}"] = res["frozen_kernel_ms"]
        images[build] = res["image"]
    row["ploc_frame_ratio"] = row["frame_ms_ploc"] / row["frame_ms_sah"]
    row["same_image"] = bool(np.array_equal(images["sah"], images["ploc"]))
    out[name] = row
    print(name, json.dumps(row), flush=True)
print("RESULT", json.dumps(out), flush=True)
