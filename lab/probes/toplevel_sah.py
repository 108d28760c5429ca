"""SAH cost, levels and build seconds of PLOC trees whose top is a full-sweep SAH tree over
the last K clusters (``renderer.accel.toplevel``), for several K (0: PLOC alone), with
phases. Usage:
    python lab/probes/toplevel_sah.py [--tops 0,256,1024,2048,4096,8192] [--backend llvm]
        SCENE...
"""
import argparse
import os
import time
from pathlib import Path

import renderer.accel.toplevel as toplevel
from renderer.accel.bvh_build import check_bvh
from renderer.accel.ploc import build_ploc
from renderer.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]
ap = argparse.ArgumentParser()
ap.add_argument("scenes", nargs="+")
ap.add_argument("--tops", default="0,256,1024,2048,4096,8192")
ap.add_argument("--backend", default="llvm")
ap.add_argument("--repeats", type=int, default=1)
args = ap.parse_args()
print(f"load average {os.getloadavg()[0]:.1f}")
print("| scene | K | clusters | SAH cost | levels | iterations | build ms | top ms |")
print("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |")
for name in args.scenes:
    sc = load_scene(ROOT / "scenes" / f"{name}.toml")
    V, Fa = sc.vertices, sc.faces
    for K in map(int, args.tops.split(",")):
        toplevel.TOP = K
        build_ploc(V, Fa, args.backend)                       # warm-up
        times = []
        for _ in range(args.repeats):
            t = time.perf_counter()
            a = build_ploc(V, Fa, args.backend)
            times.append(time.perf_counter() - t)
        st, ph = {}, {}
        build_ploc(V, Fa, args.backend, stats=st, phases=ph)
        check_bvh(a)
        times.sort()
        print(f"| {name} | {K} | {st['top']} | {a.sah_cost:.2f} | {a.levels} | "
              f"{st['iterations']} | {1e3 * times[len(times) // 2]:.1f} | "
              f"{1e3 * ph.get('top tree', 0.0):.1f} |", flush=True)
