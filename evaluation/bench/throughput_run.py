"""The throughput part alone at a chosen batch size: ``python -m
evaluation.bench.throughput_run --size 640x360 --repeats 5 --out out/throughput``.

Writes ``bench-<backend>-throughput.json`` / ``.md`` in the format of ``evaluation.bench.run``
(so ``markdown(json)`` reproduces the ``.md``), each row with the load average measured
before its scene (``load_average``: 1, 5, 15 minutes), and prints one line per batch and
query. For a shared CPU, where the full 1920×1080 batches of ``whitted bench`` take too
long per repeat to time every contender several times.
"""
from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
import time
from pathlib import Path

from renderer.outputs import OutputError, check_output_file

from .. import wxh
from . import device_info, markdown
from .part import jsonable, write_atomic
from .throughput import SCENES, ray_throughput


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=wxh, default=(640, 360),
                    help="batch size WxH (pixels of the camera)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--backend", default="llvm")
    ap.add_argument("--scenes", default="scenes")
    ap.add_argument("--only", default="", help="comma-separated scene names (default all)")
    ap.add_argument("--out", default="out/throughput")
    ap.add_argument("--note", default="")
    ap.add_argument("--force", action="store_true")
    args = ap.parse_args(argv)
    from renderer.device import types
    from renderer.scene import load_scene
    try:
        backend = types(args.backend).backend
    except (ValueError, RuntimeError) as e:
        ap.error(f"--backend: {e}")
    w, h = args.size
    names = [n for n in (args.only.split(",") if args.only else SCENES) if n]
    missing = [n for n in names if not (Path(args.scenes) / f"{n}.toml").exists()]
    if missing:
        ap.error(f"--only: no scene {', '.join(missing)} in {args.scenes}/")
    out = Path(args.out)
    stem = out / f"bench-{backend}-throughput"
    try:
        for ext in (".json", ".md"):
            check_output_file(stem.with_suffix(ext), overwrite=args.force, flag="--force")
    except OutputError as e:
        print(f"throughput_run: {e}", file=sys.stderr)
        return 2
    command = shlex.join(["python", "-m", "evaluation.bench.throughput_run", "--size",
                          f"{w}x{h}", "--repeats", str(args.repeats), "--backend", backend]
                         + (["--scenes", args.scenes] if args.scenes != "scenes" else [])
                         + (["--only", args.only] if args.only else [])
                         + ["--out", args.out, "--force"])
    result = {"command": command, "device": device_info(backend), "quick": False,
              "date": time.strftime("%Y-%m-%d %H:%M:%S"), "throughput": [],
              "note": (f"throughput part alone at {w}x{h}, repeats {args.repeats}"
                       + (f"; {args.note}" if args.note else ""))}

    def save():
        write_atomic(stem.with_suffix(".json"), json.dumps(jsonable(result), indent=1))
        write_atomic(stem.with_suffix(".md"), markdown(result))

    for name in names:
        p = Path(args.scenes) / f"{name}.toml"
        load = os.getloadavg()
        t0 = time.perf_counter()
        r = ray_throughput(load_scene(p), backend=backend, width=w, height=h,
                           repeats=args.repeats)
        r.update(scene=name, load_average=list(load), seconds=time.perf_counter() - t0)
        result["throughput"].append(r)
        save()
        for batch, b in r["batches"].items():
            for q in ("closest", "any"):
                if q not in b:
                    continue
                ms = b[q]["ms"]
                line = "  ".join(f"{a} {v['mrays_per_cpu_s']:7.2f}" for a, v in ms.items())
                print(f"{name:16s} {batch:10s} {q:7s} M rays/CPU s: {line}  "
                      f"(load {load[0]:.1f})", flush=True)
    loads = [r["load_average"][0] for r in result["throughput"]]
    if loads:
        result["note"] += (f"; load average (1 min) before each scene {min(loads):.1f}–"
                           f"{max(loads):.1f} (per row in the JSON's ``load_average``)")
    save()
    print(f"wrote {stem}.json and .md", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
