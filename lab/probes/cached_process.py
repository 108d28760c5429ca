"""Time whole cached ``whitted render`` processes (issue 24, time to first image).

``python lab/probes/cached_process.py [--backend B] [--runs N] [--size WxH] [--accel A]
SCENE.toml ...`` (from the repository root, PYTHONPATH set to it): per scene, one cold
process (empty cache folder), then N (default 5) cached ones; each runs with Python bytecode
allowed (PYTHONDONTWRITEBYTECODE unset, PYTHONPYCACHEPREFIX a temporary folder, as an
installed package has). Prints the medians of the wall time, of the ``timing:`` line's parts
(imports, load, tree, upload, frame+writes = first image - the others, outside = wall -
first image) and a finer split of the frame+writes part, measured in the child by wrapping
the functions ``whitted render`` calls after the upload (the first frame, the EXR metadata,
the EXR and PNG writes, the cache flush, and the end from the command's return to the
process's exit); ``start`` is the parent's start of the child to the child's first line.

The child is this file with ``--child``: it wraps those functions with timers, runs
``whitted.entry.main`` as the console script does, and prints one ``split:`` JSON line.
"""
from __future__ import annotations

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
ROOT = Path(__file__).resolve().parents[2]


def child(argv: list[str]) -> int:
    """Run ``whitted`` with ``argv`` as the console script does (``whitted.entry.main``),
    the steps after the upload timed."""
    t_enter = time.time()
    import whitted.render as wr
    from renderer import film
    from renderer.accel.cache import TreeCache
    from renderer.render import Renderer

    spent: dict[str, float] = {}

    stamps: dict[str, float] = {}

    def timed(name, fn):
        def run(*a, **k):
            t0 = time.perf_counter()
            stamps.setdefault(name + " start", t0)
            try:
                return fn(*a, **k)
            finally:
                stamps[name + " end"] = time.perf_counter()
                spent[name] = spent.get(name, 0.0) + time.perf_counter() - t0
        return run

    Renderer.render = timed("frame", Renderer.render)
    TreeCache.flush = timed("flush", TreeCache.flush)
    wr.write_all = timed("writes", wr.write_all)
    wr.write_exr = timed("exr", film.write_exr)
    wr.write_png = timed("png", film.write_png)
    wr.render_view = timed("render_view", wr.render_view)
    real_exit = os._exit

    def report(code=0):
        if "writes start" in stamps:      # the EXR metadata (its imports included)
            spent["metadata"] = stamps["writes start"] - stamps["render_view end"]
        sys.stdout.flush()
        print("split: " + json.dumps({"enter": t_enter, "main_end": time.time(), **spent}),
              file=sys.stderr, flush=True)
        return code

    # ``whitted.entry.main`` ends a render with ``os._exit`` (QUICK_EXIT): report first
    os._exit = lambda code: real_exit(report(code))
    import whitted.entry as entry
    sys.argv = ["whitted", *argv]
    return report(entry.main())


def run_once(scene: str, args, cache: Path, out: Path, env: dict) -> dict:
    cmd = [sys.executable, str(Path(__file__).resolve()), "--child", "render", scene,
           "--backend", args.backend, "--size", args.size, "--out", str(out), "--overwrite"]
    if args.accel:
        cmd += ["--accel", args.accel]
    t0 = time.time()
    p = subprocess.run(cmd, env={**env, "WHITTED_CACHE": str(cache)}, capture_output=True,
                       text=True, cwd=ROOT)
    t1 = time.time()
    if p.returncode != 0:
        raise SystemExit(f"{scene}: exit {p.returncode}\n{p.stdout}\n{p.stderr}")
    m = TIMING.search(p.stdout)
    split = json.loads(next(line for line in p.stderr.splitlines()
                            if line.startswith("split: "))[7:])
    imports, load, tree, upload, first = map(float, m.groups())
    row = {"wall": t1 - t0, "imports": imports, "load": load, "tree": tree,
           "upload": upload, "frame+writes": first - imports - load - tree - upload,
           "outside": (t1 - t0) - first}
    row.update({k: split.get(k, 0.0) for k in ("frame", "metadata", "exr", "png",
                                                  "writes", "flush")})
    row["view rest"] = split.get("render_view", 0.0) - split.get("frame", 0.0)
    row["start"] = split["enter"] - t0
    row["end"] = t1 - split["main_end"]
    return row


def main(argv: list[str]) -> int:
    if argv[:1] == ["--child"]:
        return child(argv[1:])
    import argparse
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="+")
    ap.add_argument("--backend", default="llvm")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--size", default="1024x1024")
    ap.add_argument("--accel", default=None)
    args = ap.parse_args(argv)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    with tempfile.TemporaryDirectory(prefix="cached-process-") as tmp:
        tmp = Path(tmp)
        env["PYTHONPYCACHEPREFIX"] = str(tmp / "pycache")
        env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
        print(f"backend {args.backend}, size {args.size}, {args.runs} cached runs; "
              f"load {os.getloadavg()[0]:.2f}")
        for scene in args.scenes:
            cache, out = tmp / f"cache-{Path(scene).stem}", tmp / "out"
            cold = run_once(scene, args, cache, out, env)
            rows = [run_once(scene, args, cache, out, env) for _ in range(args.runs)]
            keys = list(cold)
            med = {k: statistics.median(r[k] for r in rows) for k in keys}
            print(f"\n{scene}")
            print("| run | " + " | ".join(keys) + " |")
            print("| --- |" + " ---: |" * len(keys))
            for name, r in (("cold", cold), (f"cached (median of {len(rows)})", med)):
                print(f"| {name} | " + " | ".join(f"{r[k]:.3f}" for k in keys) + " |")
        print(f"\nload {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
