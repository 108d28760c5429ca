"""Hashes of the images of every view of the smaller bundled scenes, for every accelerator
and triangle routine: the evidence that a restructuring changed no pixel.

    python lab/probes/image_hashes.py --out hashes.json          # write
    python lab/probes/image_hashes.py --against hashes.json      # compare, exit 1 on a change

Exact mode, LLVM, 48x48, float32 (the issue's protocol)."""
from __future__ import annotations

import argparse
import hashlib
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from renderer.accel import ACCELERATORS, ROUTINES  # noqa: E402
from renderer.render import render  # noqa: E402
from renderer.scene import load_scene  # noqa: E402

SCENES = ["analytic_quad", "bunny", "cornell_box", "cornell_sphere", "glass_bunny",
          "platonic_solids", "cases/fresnel_glass", "cases/mirror_background"]


def hashes(size: int = 48) -> dict:
    out = {}
    for name in SCENES:
        scene = load_scene(ROOT / "scenes" / f"{name}.toml").with_overrides(
            spp=1, exact=True, size=(size, size))
        for accel in sorted(ACCELERATORS):
            for routine in sorted(r for r in ROUTINES if not r.startswith("_")):
                for v, cam in enumerate(scene.cameras):
                    img = render(scene, view=v, backend="llvm", accel=accel,
                                 intersection=routine).image
                    key = f"{name}/{cam.name}/{accel}/{routine}"
                    out[key] = hashlib.sha256(np.ascontiguousarray(img).tobytes()).hexdigest()
                    print(key, out[key][:16], flush=True)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out")
    ap.add_argument("--against")
    a = ap.parse_args()
    h = hashes()
    if a.out:
        Path(a.out).write_text(json.dumps(h, indent=1, sort_keys=True) + "\n")
    if a.against:
        ref = json.loads(Path(a.against).read_text())
        diff = sorted(k for k in ref if h.get(k) != ref[k])
        extra = sorted(set(h) - set(ref))
        print(f"{len(h)} images, {len(diff)} differ, {len(extra)} new")
        for k in diff:
            print("DIFFERS", k)
        return 1 if diff else 0
    print(f"{len(h)} images")
    return 0


if __name__ == "__main__":
    sys.exit(main())
