"""Hashes of every array an accelerator uploads (node boxes, children, packed triangles,
normals, materials, order) for the bvh and bvh4 accelerators of a few scenes in float32 and
float64, both trees: the evidence that a faster upload path uploads the same bytes.

    python lab/probes/upload_hashes.py --out a.json [SCENE ...]
    python lab/probes/upload_hashes.py --against a.json [SCENE ...]   # exit 1 on a change
    python lab/probes/upload_hashes.py --cache --against a.json      # through a fresh cache

``--cache``: every accelerator is built twice through a fresh ``TreeCache`` (a miss that
writes the tree and layout entries, then a hit that uploads the cached layout); the hit's
arrays are compared, and any array where the miss and the hit differ is listed as
``KEY/cold``.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tempfile
from pathlib import Path

import drjit as dr
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from renderer.accel import build_accelerator  # noqa: E402
from renderer.accel.cache import TreeCache  # noqa: E402
from renderer.device import types  # noqa: E402
from renderer.scene import load_scene  # noqa: E402

SCENES = ["bunny", "cornell_box", "glass_bunny", "platonic_solids", "cases/fresnel_glass"]


def digest(x) -> str:
    """SHA-256 prefix of a Dr.Jit array's bytes (an Array3f: its three components)."""
    if not dr.is_array_v(x):
        return repr(x)
    parts = [x.x, x.y, x.z] if dr.size_v(x) == 3 else [x]
    return hashlib.sha256(b"".join(np.ascontiguousarray(np.asarray(p.numpy())).tobytes()
                                   for p in parts)).hexdigest()[:20]


def hashes(names, cache: bool = False) -> dict:
    out = {}
    tmp = tempfile.TemporaryDirectory() if cache else None
    for name in names:
        scene = load_scene(ROOT / "scenes" / f"{name}.toml")
        for precision in ("float32", "float64"):
            t = types("llvm", precision)
            for build in ("sah", "device"):
                for accel in ("bvh", "bvh4"):
                    key = f"{name}/{precision}/{build}/{accel}"
                    if tmp is None:
                        out.update(arrays(build_accelerator(accel, scene, t, build=build),
                                          key))
                    else:
                        c = TreeCache(tmp.name)
                        cold = arrays(build_accelerator(accel, scene, t, build=build,
                                                        cache=c), key)
                        acc = build_accelerator(accel, scene, t, build=build, cache=c)
                        assert acc.info["layout_cached"], key
                        out.update(arrays(acc, key))
                        out.update({f"{k}/cold": v for k, v in cold.items() if out[k] != v})
                    print(key, flush=True)
    return out


def arrays(acc, key: str) -> dict:
    out = {}
    for field in ("nodes", "children", "refs", "tri_data", "tri_trav"):
        v = getattr(acc, field, None)
        if v is not None:
            out[f"{key}/{field}"] = digest(v)
    for field in ("ng", "n0", "n1", "n2", "material", "smooth", "order"):
        out[f"{key}/tris.{field}"] = digest(getattr(acc.tris, field))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("scenes", nargs="*", default=SCENES)
    ap.add_argument("--out")
    ap.add_argument("--against")
    ap.add_argument("--cache", action="store_true")
    a = ap.parse_args()
    h = hashes(a.scenes, a.cache)
    if a.out:
        Path(a.out).write_text(json.dumps(h, indent=1, sort_keys=True) + "\n")
    if a.against:
        ref = json.loads(Path(a.against).read_text())
        diff = sorted(k for k in ref if k in h and h[k] != ref[k])
        diff += sorted(k for k in h if k.endswith("/cold"))
        print(f"{len(h)} arrays, {len(diff)} differ")
        for k in diff:
            print("DIFFERS", k)
        return 1 if diff else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
