"""PLOC build time of two source trees, interleaved: for each scene, a process per tree
builds ``build_ploc(cuts=False)`` (``auto``'s tree) once to compile, then ``--repeats``
times (``dr.sync_thread`` around each), trees alternating ``--rounds`` times; prints each
process's median and the kernels one build launched, and whether both trees built the same
tree (field hashes).

    python lab/probes/ploc_ab.py --backend cuda OLD_ROOT NEW_ROOT bunny conference bunny_1m
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

CHILD = r"""
import hashlib, json, statistics, sys, time, warnings
warnings.simplefilter("ignore")
root, backend, scene, repeats = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
sys.path.insert(0, root)
import drjit as dr
from renderer.accel.ploc import build_ploc
from renderer.scene import load_scene
s = load_scene(scene)
build_ploc(s.vertices, s.faces, backend, cuts=False)
dr.sync_thread()
ts = []
for _ in range(repeats):
    t = time.perf_counter()
    a = build_ploc(s.vertices, s.faces, backend, cuts=False)
    dr.sync_thread()
    ts.append(time.perf_counter() - t)
dr.set_flag(dr.JitFlag.KernelHistory, True); dr.kernel_history()
build_ploc(s.vertices, s.faces, backend, cuts=False)
kernels = len(dr.kernel_history())
h = hashlib.sha256()
for f in ("boxes", "children", "order", "raw"):
    h.update(getattr(a, f).tobytes())
print(json.dumps({"median_ms": 1e3 * statistics.median(ts), "all_ms": [1e3 * t for t in ts],
                  "kernels": kernels, "tree": h.hexdigest()[:16], "triangles": len(s.faces)}))
"""


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("old")
    ap.add_argument("new")
    ap.add_argument("scenes", nargs="+")
    ap.add_argument("--backend", default="llvm")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()
    here = Path(__file__).resolve().parents[2]
    out = {}
    for name in args.scenes:
        scene = str(here / "scenes" / f"{name}.toml")
        for r in range(args.rounds):
            for label, root in (("old", args.old), ("new", args.new)):
                env = dict(os.environ, PYTHONPATH=os.pathsep.join(
                    [str(Path(root).resolve())] + os.environ.get("PYTHONPATH", "").split(
                        os.pathsep)))
                p = subprocess.run([sys.executable, "-c", CHILD, str(Path(root).resolve()),
                                    args.backend, scene, str(args.repeats)],
                                   capture_output=True, text=True, env=env)
                if p.returncode:
                    print(p.stderr[-2000:], file=sys.stderr)
                    return 1
                row = json.loads(p.stdout.strip().splitlines()[-1])
                out.setdefault(name, {}).setdefault(label, []).append(row)
                print(f"{name:12s} round {r} {label}: {row['median_ms']:7.2f} ms "
                      f"({row['triangles'] / row['median_ms'] / 1e3:6.2f} M/s), "
                      f"{row['kernels']} kernels, tree {row['tree']}", flush=True)
        same = len({x["tree"] for v in out[name].values() for x in v}) == 1
        print(f"{name:12s} same tree in both: {same}", flush=True)
    print(json.dumps(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
