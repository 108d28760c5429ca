"""SAH cost, levels and build seconds of the radix, PLOC (several radii) and host SAH trees
of bundled scenes (LLVM backend). Usage:
    python lab/probes/ploc_quality.py [--sah] [--radii 4,8,16] SCENE...
"""
import argparse
import time
from pathlib import Path

from renderer.accel.bvh_build import build_bvh, check_bvh
from renderer.accel.device_build import build_device
from renderer.accel.ploc import build_ploc
from renderer.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]

ap = argparse.ArgumentParser()
ap.add_argument("scenes", nargs="+")
ap.add_argument("--sah", action="store_true")
ap.add_argument("--radii", default="4,8,16")
ap.add_argument("--backend", default="llvm")
args = ap.parse_args()
print("| scene | triangles | tree | SAH cost | levels | iterations | build s |")
print("| --- | ---: | --- | ---: | ---: | ---: | ---: |")
for name in args.scenes:
    sc = load_scene(ROOT / "scenes" / f"{name}.toml")
    V, Fa = sc.vertices, sc.faces
    rows = []
    build_device(V, Fa, args.backend)                      # warm the kernel cache
    t = time.perf_counter()
    a = build_device(V, Fa, args.backend)
    rows.append(("radix", a, time.perf_counter() - t, ""))
    for r in [int(x) for x in args.radii.split(",")]:
        st = {}
        build_ploc(V, Fa, args.backend, radius=r)
        t = time.perf_counter()
        a = build_ploc(V, Fa, args.backend, radius=r, stats=st)
        rows.append((f"ploc r={r}" + (" (fallback)" if st["fallback"] else "")
                     + (f" ({st['rebuilt']} rebuilt)" if st["rebuilt"] else ""), a,
                     time.perf_counter() - t, st["iterations"]))
    if args.sah:
        t = time.perf_counter()
        a = build_bvh(V, Fa)
        rows.append(("sah", a, time.perf_counter() - t, ""))
    for tree, a, s, it in rows:
        check_bvh(a)
        print(f"| {name} | {sc.face_count} | {tree} | {a.sah_cost:.2f} | {a.levels} | {it} | "
              f"{s:.3f} |", flush=True)
