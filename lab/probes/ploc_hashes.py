"""Hashes of every field of the ``BVHArrays`` that ``build_ploc`` gives (boxes, children,
order, raw boxes, levels, leaf count, SAH cost, bounds) and of its ``stats``, for every
bundled scene (default leaf size and radius; the bunny also at leaf size 1 / radius 4 and
leaf size 4 / radius 16): the evidence that a faster PLOC build builds the same tree bit
for bit.

    python lab/probes/ploc_hashes.py --out a.json [--backend llvm] [SCENE.toml ...]
    python lab/probes/ploc_hashes.py --against a.json [SCENE.toml ...]   # exit 1 on a change
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from renderer.accel.ploc import build_ploc  # noqa: E402
from renderer.scene import load_scene  # noqa: E402

VARIANTS = {"bunny": ((1, 4), (4, 16))}      # extra (leaf_size, radius) per scene


def tree_hashes(a, st: dict) -> dict:
    out = {}
    for f in ("boxes", "children", "order", "raw"):
        x = getattr(a, f)
        x = np.zeros(0) if x is None else np.ascontiguousarray(x)
        out[f] = f"{x.dtype} {x.shape} " + hashlib.sha256(x.tobytes()).hexdigest()[:20]
    out["scalars"] = repr((a.levels, a.leaf_count, a.sah_cost,
                           [np.asarray(b).tolist() for b in a.bounds]))
    out["stats"] = repr(sorted(st.items()))
    return out


def hashes(paths, backend: str) -> dict:
    out = {}
    for p in paths:
        scene = load_scene(p)
        name = Path(p).stem
        for leaf, radius in ((None, None),) + VARIANTS.get(name, ()):
            kw = {} if leaf is None else {"leaf_size": leaf, "radius": radius}
            st = {}
            t0 = time.perf_counter()
            a = build_ploc(scene.vertices, scene.faces, backend, stats=st, **kw)
            dt = time.perf_counter() - t0
            key = name if leaf is None else f"{name}@leaf{leaf}r{radius}"
            for f, h in tree_hashes(a, st).items():
                out[f"{key}/{f}"] = h
            print(f"{key}: {scene.face_count} triangles, {st} in {dt:.2f} s", flush=True)
    return out


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("scenes", nargs="*")
    ap.add_argument("--backend", default="llvm")
    ap.add_argument("--out")
    ap.add_argument("--against")
    args = ap.parse_args()
    paths = args.scenes or sorted(str(p) for p in (ROOT / "scenes").glob("*.toml")) + sorted(
        str(p) for p in (ROOT / "scenes" / "cases").glob("*.toml"))
    h = hashes(paths, args.backend)
    if args.out:
        Path(args.out).write_text(json.dumps(h, indent=1, sort_keys=True) + "\n")
    if args.against:
        ref = json.loads(Path(args.against).read_text())
        bad = [k for k in h if ref.get(k) != h[k]]
        for k in bad:
            print(f"changed: {k}: {ref.get(k)} -> {h[k]}")
        print(f"{len(h) - len(bad)} of {len(h)} equal")
        return 1 if bad else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
