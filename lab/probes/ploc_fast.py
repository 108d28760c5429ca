"""PLOC build time, main's build (``ploc_main.py``, frozen at cd4f323) against today's
``renderer.accel.ploc.build_ploc``: median of ``--repeats`` builds after a warm-up build,
the two interleaved (``dr.sync_thread`` before each clock read; a build is triangles in as
numpy arrays, tree out as host ``BVHArrays``), each build's phases (one build that waits at
each phase's end), the kernels one build launches (``dr.kernel_history``), ``dr.argsort``
alone over as many Morton codes, and whether the two trees are equal bit for bit; with
``--every``, ``--freeze``, ``--unrolled`` also today's build with other ``READ_EVERY``, the
other ``FREEZE`` or the neighbour search unrolled. Writes ``OUT/ploc_fast-BACKEND.json``.
Usage:
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

import renderer.accel.ploc as ploc  # noqa: E402
from renderer.accel.device_build import morton_codes, triangle_boxes  # noqa: E402
from renderer.accel.ploc import build_ploc  # noqa: E402
from renderer.scene import load_scene  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("scenes", nargs="+")
ap.add_argument("--backend", default="llvm")
ap.add_argument("--out", default=".")
ap.add_argument("--repeats", type=int, default=5)
ap.add_argument("--every", default="", help="also time READ_EVERY = these (comma list)")
ap.add_argument("--unrolled", action="store_true",
                help="also time the neighbour search unrolled in Python")
ap.add_argument("--freeze", action="store_true",
                help="also time the iteration the other way (dr.freeze on / off)")
args = ap.parse_args()
m = __import__(f"drjit.{args.backend}", fromlist=["UInt32"])


def same(a, b) -> bool:
    return all(getattr(a, f).tobytes() == getattr(b, f).tobytes()
               for f in ("boxes", "children", "order", "raw")) and (
        (a.levels, a.leaf_count, a.sah_cost) == (b.levels, b.leaf_count, b.sah_cost))


def nearest_unrolled(m, c_box, k, radius):
    """``ploc._nearest`` with the 2 x radius candidates unrolled in Python."""
    Float, UInt32 = m.Float, m.UInt32
    w = dr.width(c_box[0])
    i = dr.arange(UInt32, w)
    active = i < k
    best = dr.full(Float, dr.inf, w)
    best_j = UInt32(i)
    best_t = dr.full(UInt32, 0xFFFFFFFF, w)
    for d in range(1, radius + 1):
        for side in (0, 1):
            ok = (active & (i >= d)) if side == 0 else (i + d < k)
            j = i - d if side == 0 else i + d
            a = j if side == 0 else i
            bl = [dr.minimum(c_box[x], dr.gather(Float, c_box[x], j, ok)) for x in range(3)]
            bh = [dr.maximum(c_box[3 + x], dr.gather(Float, c_box[3 + x], j, ok))
                  for x in range(3)]
            area = ploc._half_area(bl, bh)
            tie = UInt32(2 * d) | (a & 1)
            better = ok & ((area < best) | ((area == best) & (tie < best_t)))
            best = dr.select(better, area, best)
            best_j = dr.select(better, j, best_j)
            best_t = dr.select(better, tie, best_t)
    return best_j


def first_phase(V, Fa) -> dict:
    """Milliseconds of the first phase's steps, waiting after each (median of repeats)."""
    out, t = {}, []

    def mark(name):
        dr.sync_thread()
        t.append(time.perf_counter())
        out.setdefault(name, []).append((t[-1] - t[-2]) * 1e3)
    for _ in range(args.repeats + 1):
        t[:] = [time.perf_counter()]
        Vn = np.ascontiguousarray(np.asarray(V, np.float32))
        Fn = np.asarray(Fa)
        mark("host arrays")
        lo, hi = triangle_boxes(m, Vn, Fn)
        mark("upload and boxes")
        code, s_lo, s_hi = morton_codes(m.UInt32, lo, hi)
        dr.eval(code, s_lo, s_hi)
        mark("Morton codes")
        perm = dr.argsort(code)
        dr.eval(perm)
        mark("argsort")
        slo = [dr.gather(m.Float, x, perm) for x in lo + hi]
        dr.eval(slo)
        mark("sorted boxes")
    return {k: statistics.median(v[1:]) for k, v in out.items()}


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
    builds = {"main": ploc_main.build_ploc, "new": build_ploc}
    st = {tag: {} for tag in builds}
    trees = {tag: b(V, Fa, args.backend, stats=st[tag]) for tag, b in builds.items()}
    ts = {tag: [] for tag in builds}
    for _ in range(args.repeats):             # interleaved: load drift hits both alike
        for tag, b in builds.items():
            dr.sync_thread()
            t = time.perf_counter()
            b(V, Fa, args.backend)
            dr.sync_thread()
            ts[tag].append(time.perf_counter() - t)
    for tag, b in builds.items():
        ph = {}
        b(V, Fa, args.backend, **({"phases": ph} if tag == "main" else {"stats": {"phases": ph}}))
        s = statistics.median(ts[tag])
        row[tag] = {"s": s, "all_s": ts[tag], "mtri_s": F / s / 1e6, "phases_ms":
                    {k: v * 1e3 for k, v in ph.items()}, "stats": st[tag],
                    "kernels": kernels(lambda b=b: b(V, Fa, args.backend))}
    be = args.backend
    # (tag, READ_EVERY, FREEZE, neighbour search); a frozen variant gets its own recordings
    variants = [(f"every{e}", int(e), ploc.FREEZE[be], ploc._nearest)
                for e in args.every.split(",") if e]
    if args.unrolled:
        variants.append(("unrolled", ploc.READ_EVERY[be], True, nearest_unrolled))
    if args.freeze:
        variants.append(("frozen" if not ploc.FREEZE[be] else "traced", ploc.READ_EVERY[be],
                         not ploc.FREEZE[be], ploc._nearest))
    for tag, every, freeze, nearest in variants:
        keep = (ploc.READ_EVERY[be], ploc.FREEZE[be], ploc._nearest, ploc._BLOCK)
        ploc.READ_EVERY[be], ploc.FREEZE[be], ploc._nearest = every, freeze, nearest
        ploc._BLOCK = dr.freeze(ploc._block, warn_after=1 << 30)
        a, s, ts = timed(lambda: build_ploc(V, Fa, args.backend))
        ph = {}
        build_ploc(V, Fa, args.backend, stats={"phases": ph})
        ploc.READ_EVERY[be], ploc.FREEZE[be], ploc._nearest, ploc._BLOCK = keep
        row[tag] = {"s": s, "mtri_s": F / s / 1e6, "same_tree": same(a, trees["new"]),
                    "phases_ms": {k: v * 1e3 for k, v in ph.items()}}
        print(f"    {tag:9s} {s * 1e3:7.1f} ms same={row[tag]['same_tree']} " + ", ".join(
            f"{k} {v:.1f}" for k, v in row[tag]["phases_ms"].items()), flush=True)
    row["first_phase_ms"] = first_phase(V, Fa)
    print("    first phase: " + ", ".join(f"{k} {v:.2f}" for k, v in
                                         row["first_phase_ms"].items()), flush=True)
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
