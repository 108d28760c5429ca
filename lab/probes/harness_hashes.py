"""Hashes of Mitsuba's renders of the golden scenes through the reference harness of one
tree: the evidence that a harness change leaves the goldens valid.

    PYTHONPATH=ROOT python lab/probes/harness_hashes.py ROOT OUT.json

Every view of the golden scenes, both shadings, exact and converged (4 spp), 48x48, Mitsuba
LLVM. Run it for the old and the new tree on one machine and compare the JSON files."""
from __future__ import annotations

import hashlib
import json
import sys
import warnings
from pathlib import Path

import numpy as np

SCENES = ["analytic_quad", "bunny", "cornell_box", "cornell_sphere", "glass_bunny",
          "platonic_solids", "cases/fresnel_glass", "cases/mirror_background", "sponza",
          "conference"]


def main() -> int:
    root, out = Path(sys.argv[1]), sys.argv[2]
    sys.path.insert(0, str(root))
    warnings.simplefilter("ignore")
    from reference.mitsuba_scene import render_mitsuba
    from renderer.scene import load_scene
    res = {}
    for name in SCENES:
        for shading in ("classic", "physical"):
            sc = load_scene(root / "scenes" / f"{name}.toml", shading=shading).with_size(48, 48)
            for v, cam in enumerate(sc.cameras):
                for mode, spp in (("exact", 1), ("converged", 4)):
                    img = np.ascontiguousarray(render_mitsuba(sc, view=v, mode=mode, spp=spp),
                                               dtype=np.float32)
                    key = f"{name}/{cam.name}/{shading}/{mode}"
                    res[key] = hashlib.sha256(img.tobytes()).hexdigest()
                    print(key, res[key][:12], flush=True)
    Path(out).write_text(json.dumps(res, indent=1, sort_keys=True) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
