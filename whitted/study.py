"""``whitted study``: the accuracy-vs-time study (``evaluation.study``).

    whitted study [SCENE ...] --out results/study/cpu --profile cpu --backend llvm
    whitted study --profile gpu --backend cuda --out results/study/h200 --budget-minutes 7
    whitted study --workers 4 ...            # Dask LocalCluster of 4 worker processes
    whitted study --scheduler tcp://host:8786 ...
    whitted study --report-only --out DIR    # re-write markdown, plots, HTML from DIR/study.json
    whitted study --check-executor --workers 1 --profile tiny --out DIR   # Dask == in-process

Also runnable without the CLI as ``python -m whitted.study ...``. A SCENE is a path, a
name under ``scenes/`` or ``PATH@OFFSET`` (the scene translated far from the origin).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    from evaluation.study import PROFILES, SEED_SCENES
    p.add_argument("scenes", nargs="*", default=list(SEED_SCENES),
                   help="scene files, names or PATH@OFFSET (default: the seed scenes and "
                        "the glass bunny)")
    p.add_argument("--out", type=Path, default=Path("results/study/run"),
                   help="results folder (study.json is resumed if present)")
    p.add_argument("--profile", default="cpu", choices=sorted(PROFILES),
                   help="sweep size: gpu (full), cpu (grid to 64 spp, 3 repeats), tiny (CI)")
    p.add_argument("--backend", default="llvm", choices=("llvm", "cuda"))
    p.add_argument("--shading", choices=("classic", "physical"),
                   help="shading mode (default: each scene's own)")
    p.add_argument("--size", type=int, help="image height in pixels (default: the profile's)")
    p.add_argument("--seeds", type=int, help="seeds per point (default: the profile's, 5)")
    p.add_argument("--factors", help="comma-separated factors to sweep (default: all)")
    p.add_argument("--no-grid", action="store_true", help="skip the spp x depth grid")
    p.add_argument("--workers", type=int, default=0,
                   help="run points on a Dask LocalCluster of N worker processes")
    p.add_argument("--scheduler", help="run points on an existing Dask scheduler (address)")
    p.add_argument("--budget-minutes", type=float,
                   help="stop taking new points after this many minutes (resume later)")
    p.add_argument("--max-points", type=int, help="stop after this many new points")
    p.add_argument("--report-only", action="store_true",
                   help="only write markdown, plots and HTML from OUT/study.json")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--check-executor", action="store_true",
                   help="run the sweep in-process and on --workers Dask workers (default 1) "
                        "into OUT/in-process and OUT/dask; exit 1 unless the JSON agrees "
                        "minus timings")


def run(args) -> int:
    from dataclasses import replace

    from evaluation import study
    if args.report_only:
        data = study.load_results(args.out / "study.json")
        if not data["points"]:
            print(f"error: no points in {args.out / 'study.json'}", file=sys.stderr)
            return 2
        for path in study.write_outputs(data, args.out):
            print(path)
        return 0
    prof = study.PROFILES[args.profile]
    changes = {"name": args.profile}
    if args.size:
        changes["size"] = args.size
    if args.seeds:
        changes["seeds"] = tuple(range(args.seeds))
    if args.factors:
        fs = tuple(f.strip() for f in args.factors.split(",") if f.strip())
        bad = [f for f in fs if f not in study.FACTORS]
        if bad:
            print(f"error: --factors: unknown {bad}; expected some of {study.FACTORS}",
                  file=sys.stderr)
            return 2
        changes["factors"] = fs
    if args.no_grid:
        changes["grid"] = False
    changes.pop("name")
    profile = replace(prof, **changes) if changes else args.profile
    if args.check_executor:
        ok = study.executor_check(args.scenes, args.out, profile=profile, backend=args.backend,
                                  workers=args.workers or 1)
        return 0 if ok else 1
    study.run_study(args.scenes, args.out, profile=profile, backend=args.backend,
                    shading=args.shading, workers=args.workers, scheduler=args.scheduler,
                    budget_s=args.budget_minutes * 60 if args.budget_minutes else None,
                    max_points=args.max_points, show_progress=not args.no_progress)
    print(f"results: {args.out}/study.json, study.md, index.html")
    return 0


def register(subparsers) -> None:
    """Add ``study`` to the ``whitted`` command's subparsers."""
    p = subparsers.add_parser("study", help="accuracy-vs-time study (error vs kernel time, "
                                            "Pareto front, tables, plots)",
                              description=__doc__,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(p)
    p.set_defaults(func=run)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="whitted study", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(p)
    return run(p.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
