"""``whitted bench``: the timing study (``evaluation.bench``), ours vs Mitsuba, one call;
``--parts`` picks study parts by their names in the ``PARTS`` registry. The scenes come from
``--scenes`` (a folder, relative to the current one) or, by default, the bundled scenes
(``whitted.data.scenes_dir``: the repository's ``scenes/`` or the wheel's copy). A run that
measures nothing (no scene of the parts asked for in the folder) writes nothing and exits
with ``EXIT["file"]``."""
from __future__ import annotations

import argparse
import shlex
from pathlib import Path

from evaluation.bench import PARTS, NothingMeasured, run

from .data import scenes_dir
from .options import EXIT, CliError, add_backend_option


def register(subparsers) -> None:
    """Add the ``bench`` subcommand to the main CLI's subparsers."""
    p = subparsers.add_parser("bench", help="timing study: ray throughput, the thesis's table, "
                                            "Whitted frames (vs a fair Mitsuba peer) and "
                                            "effect savings")
    add_backend_option(p)
    p.add_argument("--out", default="results", help="folder for bench-<backend>.json/.md")
    p.add_argument("--scenes", type=Path,
                   help="folder holding the scene files (default: the bundled scenes)")
    p.add_argument("--quick", action="store_true", help="small sizes (smoke run)")
    p.add_argument("--parts", type=part_names, default=tuple(PARTS),
                   help=f"comma-separated subset of {','.join(PARTS)} (default all)")
    p.add_argument("--force", action="store_true",
                   help="replace existing bench-<backend>.json/.md and strips in --out")
    p.set_defaults(func=cmd_bench)


def part_names(text: str) -> tuple[str, ...]:
    """``argparse`` type of ``--parts``: comma-separated names from ``PARTS``."""
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    unknown = [n for n in names if n not in PARTS]
    if unknown or not names:
        raise argparse.ArgumentTypeError(
            f"expected a comma-separated subset of {','.join(PARTS)}, got {text!r}")
    return names


def bench_command(args: argparse.Namespace) -> str:
    """The ``whitted bench`` command line that repeats this run (stored in the result)."""
    words = ["whitted", "bench", "--backend", args.backend, "--parts", ",".join(args.parts),
             "--out", str(args.out)]
    if args.scenes is not None:
        words += ["--scenes", str(args.scenes)]
    words += ["--quick"] * args.quick + ["--force"]
    return shlex.join(words)


def cmd_bench(args: argparse.Namespace) -> int:
    """Run the study; on Ctrl-C (``timeout -s INT``) the partial result is already written
    (``evaluation.bench.run``) and the exit status is 130."""
    folder = scenes_dir() if args.scenes is None else args.scenes
    if not folder.is_dir():
        raise CliError(f"--scenes: {args.scenes}: no such folder", EXIT["file"])
    try:
        run(args.out, backend=args.backend, scenes_dir=folder, quick=args.quick,
            parts=args.parts, overwrite=args.force, command=bench_command(args))
    except NothingMeasured as e:
        raise CliError(f"--scenes: {e}", EXIT["file"]) from None
    except KeyboardInterrupt:
        return EXIT["interrupted"]
    return EXIT["ok"]
