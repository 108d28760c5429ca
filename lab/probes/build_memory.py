"""Peak host memory of the SAH build (``renderer.accel.bvh_build``) per phase, by
tracemalloc (numpy reports its buffers to it), on the Stanford bunny subdivided ``--levels``
times (2: 1.1 M triangles, 3: 4.4 M, 4: 17.8 M). Prints one line per phase: the largest
peak over the levels of the build and the level where it happened, then the whole build's
peak, and writes the hash of the tree (so a change that bounds memory can show the tree is
unchanged). ``PYTHONPATH=. python lab/probes/build_memory.py --levels 3``."""
import argparse
import hashlib
import time
import tracemalloc

import numpy as np

from renderer.accel import bvh_build as bb
from renderer.scene import meshio
from renderer.scene.subdivide import subdivide_midpoint

MESH = "/work/shared/data/meshes/stanford_bunny/bun_zipper.ply"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--levels", type=int, default=2)
    ap.add_argument("--mesh", default=MESH)
    ap.add_argument("--no-spatial", action="store_true")
    ap.add_argument("--optimize", type=int, default=bb.OPTIMIZE)
    a = ap.parse_args()
    v, f = meshio.load_mesh(a.mesh)
    v, f = subdivide_midpoint(v, f, a.levels)[:2]
    print(f"{len(f)} triangles")
    peaks: dict[str, tuple[int, int]] = {}

    def wrap(name):
        fn = getattr(bb, name)

        def run(*args, **kw):
            base = tracemalloc.get_traced_memory()[0]
            tracemalloc.reset_peak()
            out = fn(*args, **kw)
            peak = tracemalloc.get_traced_memory()[1] - base
            if peak > peaks.get(name, (0, 0))[0]:
                peaks[name] = (peak, getattr(args[0], "depth", -1))
            return out
        setattr(bb, name, run)
    for name in ("_layout", "_bin", "_best_split", "_leaf_or_split", "_partition",
                 "_emit_children", "spatial_top", "reinsert", "_depth_first"):
        wrap(name)
    tracemalloc.start()
    t0 = time.perf_counter()
    opts = {"spatial": 0.0} if a.no_spatial else {}
    arr = bb.build_bvh(v, f, optimize=a.optimize, **opts)
    dt = time.perf_counter() - t0
    cur, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    for name, (p, depth) in peaks.items():
        print(f"{name:16s} peak above its input {p / 2**20:9.1f} MiB (level {depth}; -1: once)")
    print(f"build peak {peak / 2**20:.1f} MiB, {dt:.1f} s")
    h = hashlib.sha256()
    for x in (arr.boxes, arr.children, arr.order):
        h.update(np.ascontiguousarray(x).tobytes())
    print("tree", h.hexdigest()[:16])


if __name__ == "__main__":
    main()
