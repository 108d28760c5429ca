"""``whitted hard-cases``: run the hard-case stress suite (``evaluation.hard``, cases
in ``evaluation/hard/cases.toml``) and write its table (case, criterion, measured, pass) as
markdown, JSON and an HTML page with each case's image into ``--out``. Exit status 0 only
when every row passes (1 otherwise).

The full device run (10^8 rays in case 1, both precisions, every accelerator and routine):

    whitted hard-cases --backend cuda --rays 100000000 --chunk 16777216 --out DIR
"""
from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

from evaluation import at_least
from renderer.accel import ACCELERATORS, DEFAULT_ROUTINE, ROUTINES
from renderer.device import PRECISIONS

from .options import EXIT, CliError, add_backend_option


def _csv(choices):
    def parse(text: str) -> tuple:
        items = tuple(x for x in text.split(",") if x)
        bad = [x for x in items if x not in choices]
        if bad or not items:
            raise argparse.ArgumentTypeError(
                f"expected a comma-separated subset of {', '.join(choices)}, got {text!r}")
        return items
    return parse


def register(subparsers) -> None:
    """Add the ``hard-cases`` subcommand."""
    from evaluation.hard.runners import CASES
    p = subparsers.add_parser("hard-cases", help="run the hard-case stress suite → table "
                                                 "(markdown, JSON, HTML); exit 0 iff all pass")
    p.add_argument("--out", type=Path, required=True, help="report folder (created)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing report")
    add_backend_option(p)
    p.add_argument("--cases", type=_csv(tuple(CASES)), default=tuple(CASES),
                   help=f"comma-separated cases (default all: {', '.join(CASES)})")
    p.add_argument("--precisions", type=_csv(PRECISIONS), default=PRECISIONS)
    p.add_argument("--accels", type=_csv(tuple(ACCELERATORS)), default=tuple(ACCELERATORS))
    p.add_argument("--intersections", type=_csv(tuple(ROUTINES)), default=tuple(ROUTINES),
                   help=f"triangle routines (default all; the default routine is "
                        f"{DEFAULT_ROUTINE})")
    p.add_argument("--rays", type=at_least(1),
                   help="case 1: random interior rays per BVH variant "
                        "(brute force and boxes trace 1/100)")
    p.add_argument("--chunk", type=at_least(1), default=1 << 20,
                   help="rays per device batch")
    p.add_argument("--seed", type=int, default=1)
    p.set_defaults(func=cmd_hard_cases)


def cmd_hard_cases(args: argparse.Namespace) -> int:
    from evaluation.hard.cases import Config
    from evaluation.hard.report import write_report
    from evaluation.hard.runners import run_suite
    from renderer.device import types
    out = Path(args.out)
    if (out / "hard_cases.json").exists() and not args.overwrite:
        raise CliError(f"{out / 'hard_cases.json'}: exists (pass --overwrite to replace it)",
                       code=EXIT["file"])
    if args.rays is not None and args.rays < 1:
        raise CliError("--rays: expected an integer >= 1", code=EXIT["usage"])
    backend = types(args.backend).backend
    cfg = Config(backend=backend, precisions=args.precisions, accels=args.accels,
                 routines=args.intersections, rays=args.rays, out=out, seed=args.seed,
                 chunk=args.chunk, progress=True)
    t0 = time.perf_counter()
    try:
        rows = run_suite(cfg, args.cases)
    except KeyboardInterrupt:
        print("interrupted: no report written", file=sys.stderr)
        return EXIT["interrupted"]
    meta = {"backend": backend, "device": _device(backend), "cases": ",".join(args.cases),
            "precisions": ",".join(args.precisions), "accels": ",".join(args.accels),
            "intersections": ",".join(args.intersections), "rays": args.rays or "table",
            "seconds": round(time.perf_counter() - t0, 1)}
    paths = write_report(rows, out, meta)
    red = [r for r in rows if not r.passed]
    print(f"{len(rows)} rows, {len(red)} red; wrote {', '.join(str(p) for p in paths.values())}")
    for r in red:
        print(f"RED: {r.case} | {r.variant} | {r.criterion} | {r.measured}")
    return EXIT["fail"] if red else EXIT["ok"]


def _device(backend: str) -> str:
    if backend == "cuda":
        try:
            return subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"],
                                  capture_output=True, text=True, timeout=10).stdout.strip()
        except (OSError, subprocess.SubprocessError):
            return "cuda"
    name = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            name = next((ln.split(":", 1)[1].strip() for ln in f
                         if ln.startswith("model name")), name)
    except OSError:
        pass
    return f"{name}, {os.cpu_count()} cores (LLVM)"
