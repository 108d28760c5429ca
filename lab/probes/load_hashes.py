"""Hashes of every array ``load_scene`` gives (vertices, normals in both precisions, faces,
materials, objects) for the bundled scenes: the evidence that a faster loader (PLY read,
subdivision, compaction, vertex normals) loads the same bytes.

    python lab/probes/load_hashes.py --out a.json [SCENE.toml ...]
    python lab/probes/load_hashes.py --against a.json [SCENE.toml ...]   # exit 1 on a change
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

from renderer.scene import load_scene  # noqa: E402

FIELDS = ("vertices", "normals", "vertices64", "normals64", "faces", "face_material",
          "face_object")


def hashes(paths) -> dict:
    out = {}
    for p in paths:
        t0 = time.perf_counter()
        scene = load_scene(p)
        dt = time.perf_counter() - t0
        for f in FIELDS:
            a = getattr(scene, f)
            a = np.zeros(0) if a is None else np.ascontiguousarray(a)
            out[f"{Path(p).stem}/{f}"] = (f"{a.dtype} {a.shape} "
                                         + hashlib.sha256(a.tobytes()).hexdigest()[:20])
        print(f"{p}: {scene.face_count} triangles in {dt:.2f} s", flush=True)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("scenes", nargs="*")
    ap.add_argument("--out")
    ap.add_argument("--against")
    a = ap.parse_args()
    paths = a.scenes or sorted(map(str, (ROOT / "scenes").glob("*.toml"))) + sorted(
        map(str, (ROOT / "scenes" / "cases").glob("*.toml")))
    h = hashes(paths)
    if a.out:
        Path(a.out).write_text(json.dumps(h, indent=1, sort_keys=True) + "\n")
    if a.against:
        ref = json.loads(Path(a.against).read_text())
        diff = sorted(k for k in ref if k in h and h[k] != ref[k])
        print(f"{len(h)} arrays, {len(diff)} differ")
        for k in diff:
            print("DIFFERS", k)
        return 1 if diff else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
