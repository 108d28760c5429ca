"""Export every view of bundled scenes as Mitsuba XML, read the XML back with
``renderer.scene.load_scene`` and render both: are the images bit for bit the same?

    python lab/probes/export_roundtrip.py --size 16 cornell_box bunny sponza conference

Exact mode, the default backend, float32. One line per view: identical, or the number of
pixels that differ and the largest difference."""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))


def main() -> int:
    from reference.mitsuba_scene import export_xml
    from reference.xml_lookat import write_lookat
    from renderer.render import render
    from renderer.scene import load_scene

    p = argparse.ArgumentParser()
    p.add_argument("scenes", nargs="+")
    p.add_argument("--size", type=int, default=16)
    args = p.parse_args()
    warnings.simplefilter("ignore")
    changed = 0
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.scenes:
            t0 = time.time()
            scene = load_scene(ROOT / "scenes" / f"{name}.toml").with_size(args.size)
            for v in range(len(scene.cameras)):
                xml = export_xml(scene, Path(tmp) / f"{name}_{v}.xml", view=v, overwrite=True)
                write_lookat(xml, scene.cameras[v])
                a, b = render(scene, view=v).image, render(load_scene(xml)).image
                d = np.abs(a - b)
                same = np.array_equal(a, b)
                changed += not same
                print(f"{name} view {v}: " + ("identical" if same else
                      f"{int((d > 0).any(-1).sum())} pixels differ, max {d.max():.3g}")
                      + f" ({time.time() - t0:.1f} s)", flush=True)
    return 1 if changed else 0


if __name__ == "__main__":
    raise SystemExit(main())
