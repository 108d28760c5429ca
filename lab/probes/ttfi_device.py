"""Time to first image, process by process, for two source trees side by side (issue 24):
``whitted render SCENE --backend B --size 1024x1024`` with an empty cache (cold) and again
(cached), each tree's ``timing:`` line parsed; then the device build's phases of the tree
this file lives in. Run from the repository root of the baseline tree:

    python lab/probes/ttfi_device.py --backend cuda --trees .,.hcopy-ttfi [--scenes a,b]
        [--repeats 2] [--json OUT.json]
"""
from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TIMING = re.compile(r"timing: imports ([\d.]+) s, load ([\d.]+) s, tree ([\d.]+) s, "
                    r"upload ([-\d.]+) s, first image at ([\d.]+) s")
KEYS = ("imports", "load", "tree", "upload", "first")


def process(tree: Path, scene: str, backend: str, size: int, cache: Path) -> dict:
    with tempfile.TemporaryDirectory() as out:
        env = dict(os.environ, WHITTED_CACHE=str(cache))
        env["PYTHONPATH"] = os.pathsep.join([str(tree.resolve())] + [
            p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p and p != os.getcwd()])
        cmd = [sys.executable, "-m", "whitted", "render", f"scenes/{scene}.toml", "--backend",
               backend, "--size", f"{size}x{size}", "--out", out, "--view", "0"]
        t0 = time.perf_counter()
        r = subprocess.run(cmd, env=env, cwd=tree, capture_output=True, text=True)
        wall = time.perf_counter() - t0
    if r.returncode:
        return {"wall": wall, "error": r.stderr.strip().splitlines()[-1:]}
    m = TIMING.search(r.stdout)
    row = {"wall": wall}
    if m:
        row.update(zip(KEYS, map(float, m.groups())))
        row["frame"] = row["first"] - row["imports"] - row["load"] - row["tree"] - row["upload"]
    return row


def phases(scene_name: str, backend: str) -> dict:
    import drjit as dr

    from renderer.accel.device_build import build_device
    from renderer.scene import load_scene
    s = load_scene(f"scenes/{scene_name}.toml")
    build_device(s.vertices, s.faces, backend)
    times, ph = [], {}
    for _ in range(5):
        dr.sync_thread()
        times.append(build_device(s.vertices, s.faces, backend).build_seconds)
    build_device(s.vertices, s.faces, backend, phases=ph)
    t = statistics.median(times)
    return {"median_s": t, "mtris_s": s.face_count / t / 1e6,
            "phases_ms": {k: round(v * 1e3, 2) for k, v in ph.items()}}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--backend", default="cuda")
    ap.add_argument("--trees", default=".")
    ap.add_argument("--scenes", default="bunny_1m,conference")
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--json")
    a = ap.parse_args()
    rows = []
    print(f"load average {os.getloadavg()[0]:.2f}")
    print("| tree | scene | run | wall | imports | load | tree | upload | frame |")
    for scene in a.scenes.split(","):
        for rep in range(a.repeats):
            for tree in a.trees.split(","):
                with tempfile.TemporaryDirectory() as cache:
                    for run in ("cold", "cached"):
                        r = process(Path(tree), scene, a.backend, a.size, Path(cache))
                        r.update(src=tree, scene=scene, run=run, repeat=rep)
                        rows.append(r)
                        cells = " | ".join(f"{r.get(k, float('nan')):.2f}" for k in
                                           ("wall", "imports", "load", "tree", "upload",
                                            "frame"))
                        print(f"| {tree} | {scene} | {run} | {cells} |{r.get('error', '')}",
                              flush=True)
    build = {s: phases(s, a.backend) for s in a.scenes.split(",")}
    for s, b in build.items():
        print(f"device build {s}: {b['median_s'] * 1e3:.1f} ms ({b['mtris_s']:.1f} M tri/s) "
              f"{b['phases_ms']}")
    if a.json:
        Path(a.json).write_text(json.dumps({"rows": rows, "build": build}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
