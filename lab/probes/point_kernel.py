"""Point-light scenes compile the same kernel with and without the soft-shadow code.

    PYTHONPATH=<tree> python lab/probes/point_kernel.py OUT.json

For each bundled point-light scene (every view, both shadings, 32² exact, LLVM) it records
the frame's kernel count, IR operation count and the image's sha256 under the tree on
PYTHONPATH; run it under two trees and compare the JSON files (lab/notes/soft-shadows.md).
"""
from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import numpy as np

from renderer.render import Renderer
from renderer.scene import load_scene
from renderer.stats import kernel_operations

SCENES = ("cornell_box", "cornell_sphere", "platonic_solids", "analytic_quad",
          "cases/mirror_background", "cases/fresnel_glass")


def main(out: str) -> None:
    root = Path(__file__).resolve().parents[2] / "scenes"
    rows = {}
    for name in SCENES:
        for shading in ("classic", "physical"):
            sc = load_scene(root / f"{name}.toml", shading=shading).with_size(32)
            for v in range(len(sc.cameras)):
                r = Renderer(sc, backend="llvm")
                ca = r.camera(v)
                k = kernel_operations(lambda r=r, ca=ca: r.frame(ca, 32, 32))
                img = np.ascontiguousarray(k["result"].numpy(), np.float32)
                rows[f"{name}/{shading}/{v}"] = {
                    "kernels": k["kernels"], "operations": k["operations"],
                    "sha256": hashlib.sha256(img.tobytes()).hexdigest()}
                print(name, shading, v, rows[f"{name}/{shading}/{v}"], flush=True)
    Path(out).write_text(json.dumps(rows, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main(sys.argv[1])
