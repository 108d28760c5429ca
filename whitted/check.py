"""``whitted check SCENE...``: the regression gate. Renders ours, compares every view with its
golden under the case's rule and prints one verdict line per scene/view/shading/mode.

    whitted check SCENE... [--goldens DIR] [--modes exact converged] [--shadings ...]
                           [--view NAME|INDEX]... [--json FILE|-] [--junit FILE]
                           [--report DIR [--force]]

Goldens are looked up by content in ``--goldens DIR`` (else ``$WHITTED_GOLDENS``, else
``goldens`` of ``[tool.whitted]`` in the nearest pyproject.toml), then in the bundled store.
What is checked: the options, else the scene file's ``[check]`` table, else exact mode in both
shading modes.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from evaluation import verdict as vd
from reference import MODES
from reference import golden as golden_store
from renderer.accel import ACCELERATORS
from renderer.device import PRECISIONS
from renderer.scene import SHADING_MODES

from .options import add_backend_option

EXIT_CODE_HELP = """exit codes (OpenImageIO idiff's convention; the largest over all verdicts):
  0  PASS     every image passed its rule
  1  WARN     passed, but a [check.warn] level of a scene file was exceeded
  2  FAIL     an image differs from its golden beyond the rule
  3  SIZE     an image and its golden differ in size
  4  MISSING / STALE / ERROR: a golden is missing or out of date, or a scene, threshold
              or golden file could not be read (the line says the command that fixes it)"""


def register(subparsers) -> None:
    """Add the ``check`` subcommand to the main CLI's subparsers."""
    p = subparsers.add_parser(
        "check", help="regression gate: verdict (PASS/WARN/FAIL/MISSING/STALE) and exit code "
                      "per scene view against its golden",
        description=__doc__.split("\n\n")[0].replace("``", ""), epilog=EXIT_CODE_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    add_check_options(p)
    p.add_argument("scenes", nargs="+", type=Path, help="scene files (.toml)")
    p.add_argument("--modes", nargs="+", choices=MODES,
                   help="comparison modes (default: the scene's [check] modes, else exact)")
    p.add_argument("--shadings", nargs="+", choices=SHADING_MODES,
                   help="shading modes (default: the scene's [check] shadings, else both)")
    p.add_argument("--view", action="append", dest="views", metavar="NAME|INDEX",
                   help="check only this view (repeatable; default every view)")
    p.add_argument("--accel", choices=tuple(ACCELERATORS), help="our acceleration structure")
    p.add_argument("--precision", default=PRECISIONS[0], choices=PRECISIONS)
    add_backend_option(p)
    p.set_defaults(func=cmd_check)


def add_check_options(p: argparse.ArgumentParser) -> None:
    """``--goldens``, ``--json``, ``--junit``, ``--report``, ``--force``, ``--quiet`` (shared
    with ``compare``)."""
    p.add_argument("--goldens", type=Path, metavar="DIR",
                   help="golden store searched first (default $WHITTED_GOLDENS or "
                        "[tool.whitted] goldens in pyproject.toml); the bundled store follows")
    p.add_argument("--json", metavar="FILE|-", help="write the verdicts as JSON ('-': stdout)")
    p.add_argument("--junit", type=Path, metavar="FILE",
                   help="write JUnit XML, one testcase per scene/view/shading/mode")
    p.add_argument("--report", type=Path, metavar="DIR",
                   help="write the HTML report (failures first) into DIR")
    p.add_argument("--force", action="store_true", help="replace an existing --report folder")
    p.add_argument("--quiet", action="store_true", help="print only the summary line")


def _views(values):
    if not values:
        return None
    return {int(v) if v.isdigit() else v for v in values}


def stores_for(args) -> list[Path]:
    """The stores to search: ``--goldens`` (or the configured store), then the bundled one."""
    if args.goldens is not None and args.goldens.exists() and not args.goldens.is_dir():
        raise golden_store.GoldenError(f"--goldens {args.goldens}: not a folder")
    return golden_store.search_stores(args.goldens)


def check_outputs(args) -> None:
    """Before any rendering: ``--report`` must not hold a report unless ``--force``, and the
    folders of ``--json`` / ``--junit`` must be writable. Raises OSError."""
    if args.report is not None:
        out = args.report
        if out.exists() and (not out.is_dir() or any(out.iterdir())) and not args.force:
            raise FileExistsError(f"--report {out}: exists; pass --force to replace it")
    for flag, value in (("--json", args.json), ("--junit", args.junit)):
        if value is None or value == "-":
            continue
        path = Path(value)
        if path.is_dir():
            raise IsADirectoryError(f"{flag} {path}: is a folder, expected a file name")
        folder = path.parent
        while not folder.exists() and folder != folder.parent:
            folder = folder.parent
        if not folder.is_dir() or not os.access(folder, os.W_OK):
            raise PermissionError(f"{flag} {path}: {folder} is not a writable folder")


def write_outputs(args, verdicts, title: str) -> None:
    """``--json``, ``--junit`` and ``--report`` of ``verdicts``; raises OSError."""
    if args.json == "-":
        print(json.dumps(vd.to_json(verdicts), indent=1, default=str))
    elif args.json:
        vd.write_json(verdicts, args.json)
    if args.junit:
        vd.write_junit(verdicts, args.junit)
    if args.report is not None:
        from evaluation.report import write_report

        entries = vd.report_entries(verdicts)
        notes = [(v.status, v.name, v.reason) for v in verdicts if v.ours is None]
        index = write_report(args.report, entries, title=title, overwrite=args.force,
                             notes=notes)
        print(f"report: {index}", file=sys.stderr if args.json == "-" else sys.stdout)


def cmd_check(args: argparse.Namespace) -> int:
    out = sys.stderr if args.json == "-" else sys.stdout
    try:
        stores = stores_for(args)
        check_outputs(args)
    except (golden_store.GoldenError, OSError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 4
    if not args.quiet:
        print("goldens: " + ", ".join(golden_store._display(s) for s in stores), file=out)

    def show(v):
        if not args.quiet:
            print(vd.format_line(v), file=out, flush=True)

    verdicts = vd.check_scenes(args.scenes, stores, modes=args.modes, shadings=args.shadings,
                               views=_views(args.views), backend=args.backend,
                               precision=args.precision, accel=args.accel,
                               keep_images=args.report is not None, progress=show)
    print(vd.summary_line(verdicts), file=out)
    try:
        write_outputs(args, verdicts, title="whitted check: ours vs Mitsuba 3 goldens")
    except OSError as e:
        print(f"error: {e}", file=sys.stderr)
        return 4
    return vd.exit_code(verdicts)
