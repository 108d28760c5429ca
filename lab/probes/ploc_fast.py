"""PLOC build time, main's build (``ploc_main.py``, frozen at cd4f323) against today's
``renderer.accel.ploc.build_ploc``: median of ``--repeats`` builds after a warm-up build
(``dr.sync_thread`` before each clock read; a build is triangles in as numpy arrays, tree
out as host ``BVHArrays``), each build's phases (one build that waits at each phase's end),
the kernels one build launches (``dr.kernel_history``), ``dr.argsort`` alone over as many
Morton codes, and whether the two trees are equal bit for bit. Writes
``OUT/ploc_fast-BACKEND.json``. Usage:
    python lab/probes/ploc_fast.py --backend cuda --out DIR SCENE...
"""
import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import drjit as dr
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "lab" / "probes"))

import ploc_main  # noqa: E402

from renderer.accel.ploc import build_ploc  # noqa: E402
from renderer.scene import load_scene  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("scenes", nargs="+")
ap.add_argument("--backend", default="llvm")
ap.add_argument("--out", default=".")
ap.add_argument("--repeats", type=int, default=5)
args = ap.parse_args()
m = __import__(f"drjit.{args.backend}", fromlist=["UInt32"])


def same(a, b) -> bool:
    return all(getattr(a, f).tobytes() == getattr(b, f).tobytes()
               for f in ("boxes", "children", "order", "raw")) and (
        (a.levels, a.leaf_count, a.sah_cost) == (b.levels, b.leaf_count, b.sah_cost))


def timed(fn):
    a = fn()                                  # warm-up: kernel compilation
    ts = []
    for _ in range(args.repeats):
        dr.sync_thread()
        t = time.perf_counter()
        a = fn()
        dr.sync_thread()
        ts.append(time.perf_counter() - t)
    return a, statistics.median(ts), ts


def kernels(fn) -> int:
    dr.kernel_history()                       # clears it
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    fn()
    dr.sync_thread()
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    return len(dr.kernel_history())


print(f"backend {args.backend}, load {os.getloadavg()[0]:.1f}, drjit {dr.__version__}",
      flush=True)


def scene_row(name: str) -> dict:
    sc = load_scene(ROOT / "scenes" / f"{name}.toml")
    V, Fa, F = sc.vertices, sc.faces, sc.face_count
    row = {"scene": name, "triangles": F}
    trees = {}
    for tag, build in (("main", ploc_main.build_ploc), ("new", build_ploc)):
        st = {}
        a, s, ts = timed(lambda b=build, st=st: b(V, Fa, args.backend, stats=st))
        ph = {}
        build(V, Fa, args.backend, phases=ph)
        trees[tag] = a
        row[tag] = {"s": s, "all_s": ts, "mtri_s": F / s / 1e6, "phases_ms":
                    {k: v * 1e3 for k, v in ph.items()}, "stats": st,
                    "kernels": kernels(lambda b=build: b(V, Fa, args.backend))}
    row["same_tree"] = same(trees["main"], trees["new"])
    codes = m.UInt32(np.random.default_rng(1).integers(0, 1 << 30, F, dtype=np.uint32))
    dr.eval(codes)
    _, row["argsort_ms"], _ = timed(lambda: dr.eval(dr.argsort(codes)))
    row["argsort_ms"] *= 1e3
    o, n = row["main"], row["new"]
    print(f"{name:11s} {F:>9,d} main {o['s'] * 1e3:7.1f} ms ({o['mtri_s']:6.1f} M/s, "
          f"{o['kernels']} kernels) new {n['s'] * 1e3:7.1f} ms ({n['mtri_s']:6.1f} M/s, "
          f"{n['kernels']} kernels) same={row['same_tree']} argsort "
          f"{row['argsort_ms']:.2f} ms", flush=True)
    for tag in ("main", "new"):
        print(f"    {tag:4s} " + ", ".join(f"{k} {v:.1f}" for k, v in
                                       row[tag]["phases_ms"].items()), flush=True)
    return row


rows = [scene_row(name) for name in args.scenes]
out = Path(args.out)
out.mkdir(parents=True, exist_ok=True)
(out / f"ploc_fast-{args.backend}.json").write_text(json.dumps(
    {"backend": args.backend, "load": os.getloadavg(), "rows": rows}, indent=1) + "\n")
