"""The device cut (``presplit.cut_device``) against the host cut (``presplit.cut``) on
each scene's large triangles: references bitwise equal, warm time of each (median of
``--repeats``), and what decides whether the cuts pay: the SAH cost of the uncut and the
cut PLOC tree beside cheap predictors (the references' summed box area before and after
the cut, over the scene's, and the large triangles' share of it). Usage:
    python lab/probes/presplit_device.py --backend llvm SCENE...
"""
import argparse
import os
import statistics
import time
from pathlib import Path

import drjit as dr
import numpy as np

import renderer.accel.presplit as presplit
from renderer.accel.device_build import triangle_boxes
from renderer.accel.ploc import _module, build_ploc
from renderer.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]
ap = argparse.ArgumentParser()
ap.add_argument("scenes", nargs="+")
ap.add_argument("--backend", default="llvm")
ap.add_argument("--repeats", type=int, default=3)
args = ap.parse_args()
m = _module(args.backend)
print(f"backend {args.backend}, load {os.getloadavg()[0]:.1f}", flush=True)


def med(fn):
    fn()
    ts = []
    for _ in range(args.repeats):
        dr.sync_thread()
        t = time.perf_counter()
        out = fn()
        dr.sync_thread()
        ts.append(time.perf_counter() - t)
    return out, statistics.median(ts)


def area(lo, hi):
    d = (hi - lo).astype(np.float64)
    return d[:, 0] * d[:, 1] + d[:, 1] * d[:, 2] + d[:, 2] * d[:, 0]


def scene_row(name):
    sc = load_scene(ROOT / "scenes" / f"{name}.toml")
    V = np.ascontiguousarray(np.asarray(sc.vertices, np.float32))
    Fn = np.asarray(sc.faces)
    lo, hi = triangle_boxes(m, V, Fn)
    L = np.stack([np.asarray(x.numpy()) for x in lo], 1)
    H = np.stack([np.asarray(x.numpy()) for x in hi], 1)
    s_lo, s_hi = L.min(0).astype(np.float64), H.max(0).astype(np.float64)
    F = len(Fn)
    big = np.flatnonzero((H - L).max(1) > presplit.SPLIT_SIZE * (s_hi - s_lo).max())
    budget = int(presplit.SPLIT_BUDGET * F)
    row = f"{name}: {F} triangles, {big.size} large"
    if big.size < presplit.MIN_LARGE * F or not big.size:
        print(row + " (below MIN_LARGE: nothing cut)", flush=True)
        return
    host, t_host = med(lambda: presplit.cut(V, Fn, big, L[big], H[big], (s_lo, s_hi),
                                            budget))
    geom = presplit._geometry(m, V, Fn)
    big_d = m.UInt32(big.astype(np.uint32))

    def dev():
        out = presplit.cut_device(m, geom, big_d, [m.Float(L[big, a]) for a in range(3)],
                                  [m.Float(H[big, a]) for a in range(3)], (s_lo, s_hi),
                                  budget)
        dr.eval(out)
        return out

    d, t_dev = med(dev)
    d_np = (np.asarray(d[0].numpy(), np.int64),) + tuple(
        np.stack([np.asarray(x.numpy()) for x in part], 1) for part in d[1:])
    same = all(a.shape == b.shape and np.array_equal(a, b) for a, b in zip(host, d_np))
    s_area = area(s_lo[None], s_hi[None])[0]
    a_all = area(L, H).sum()
    a_big = area(L[big], H[big]).sum()
    a_cut = a_all - a_big + area(host[3], host[4]).sum()
    t_uncut = build_ploc(V, Fn, args.backend, cuts=False)
    presplit.KEEP_BETTER = False
    t_cut = build_ploc(V, Fn, args.backend)
    presplit.KEEP_BETTER = True
    print(f"{row}, {len(host[0]) - big.size} extra references; bitwise {same}; "
          f"host cut {1e3 * t_host:.1f} ms, device cut {1e3 * t_dev:.1f} ms; "
          f"SAH uncut {t_uncut.sah_cost:.3f}, cut {t_cut.sah_cost:.3f}; "
          f"box area / scene's: all {a_all / s_area:.1f}, large {a_big / s_area:.1f}, "
          f"after cut {a_cut / s_area:.1f} (ratio {a_cut / a_all:.3f}, "
          f"large share {a_big / a_all:.3f})", flush=True)


for name in args.scenes:
    scene_row(name)
