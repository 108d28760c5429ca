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
import sys
from pathlib import Path

from evaluation.gate import verdict as vd
from evaluation.gate.imagemeta import format_differences
from reference import MODES
from reference import golden as golden_store
from renderer.accel import ACCELERATORS
from renderer.device import PRECISIONS
from renderer.outputs import check_output_dir, check_replaceable
from renderer.scene import SHADING_MODES, SceneError, load_scene
from renderer.scene.importers import check_defines

from .options import (
    EXIT,
    EXIT_CODE_HELP,
    CliError,
    add_backend_option,
    add_read_options,
    read_options,
    scene_arg,
)
from .progress import render_view


def register(subparsers) -> None:
    """Add the ``check`` subcommand to the main CLI's subparsers."""
    p = subparsers.add_parser(
        "check", help="regression gate: verdict (PASS/WARN/FAIL/MISSING/STALE) and exit code "
                      "per scene view against its golden",
        description=__doc__.split("\n\n")[0].replace("``", ""), epilog=EXIT_CODE_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    add_check_options(p)
    p.add_argument("scenes", nargs="+", type=scene_arg,
                   help="scene files (.toml) or bundled scene names")
    p.add_argument("--modes", nargs="+", choices=MODES,
                   help="comparison modes (default: the scene's [check] modes, else exact)")
    p.add_argument("--shadings", nargs="+", choices=SHADING_MODES,
                   help="shading modes (default: the scene's [check] shadings, else both)")
    p.add_argument("--view", action="append", dest="views", metavar="NAME|INDEX",
                   help="check only this view (repeatable; default every view)")
    p.add_argument("--accel", choices=tuple(ACCELERATORS), help="our acceleration structure")
    p.add_argument("--precision", default=PRECISIONS[0], choices=PRECISIONS)
    add_backend_option(p)
    add_read_options(p)
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
    p.add_argument("--force", action="store_true",
                   help="replace an existing --report folder, or a --json / --junit file "
                        "that is not a report of this tool")
    p.add_argument("--quiet", action="store_true", help="print only the summary line")


def _views(values):
    if not values:
        return None
    return {int(v) if v.isdigit() else v for v in values}


def check_views(scenes, views, read=None) -> None:
    """Every ``--view`` value must name a view (index or name) of at least one of the
    scenes, else a ``CliError`` naming it (exit 2), before anything renders. A scene file
    that cannot be loaded is left to its own ERROR verdict."""
    if not views:
        return
    found: set = set()
    for path in scenes:
        try:
            cams = load_scene(path, **(read or {})).cameras
        except (SceneError, OSError):
            return
        found |= set(range(len(cams))) | {c.name for c in cams}
    missing = [v for v in views if (int(v) if v.isdigit() else v) not in found]
    if missing:
        raise CliError(f"--view {missing[0]}: no such view in "
                       + ", ".join(str(s) for s in scenes)
                       + f" (views: {sorted(str(v) for v in found if isinstance(v, str))})")


def stores_for(args) -> list[Path]:
    """The stores to search: ``--goldens`` (or the configured store), then the bundled one."""
    if args.goldens is not None and args.goldens.exists() and not args.goldens.is_dir():
        raise CliError(f"--goldens {args.goldens}: not a folder", code=EXIT["file"])
    try:
        return golden_store.search_stores(args.goldens)
    except golden_store.GoldenError as e:
        raise CliError(str(e), code=EXIT["file"]) from e


def check_outputs(args) -> None:
    """Before any rendering (``renderer.outputs``'s checks): ``--report`` must not hold a
    report unless ``--force``, and ``--json`` / ``--junit`` must be writable files that are
    missing or hold a report of this tool (a gate's artefacts are rewritten on every run;
    any other file, e.g. a scene named by mistake, only with ``--force``; a device, pipe
    or socket never). Raises ``CliError`` (exit 4, one line)."""
    if args.report is not None:
        out = args.report
        if out.exists() and (not out.is_dir() or any(out.iterdir())) and not args.force:
            raise CliError(f"--report {out}: exists; pass --force to replace it",
                           code=EXIT["file"])
        check_output_dir(out)
    for flag, value, ours, what in (("--json", args.json, vd.is_our_json, "verdict JSON"),
                                    ("--junit", args.junit, vd.is_our_junit, "JUnit report")):
        if value is None or value == "-":
            continue
        try:
            check_replaceable(value, ours=ours, force=args.force, what=what)
        except OSError as e:
            raise CliError(f"{flag} {e}", code=EXIT["file"]) from e


def write_outputs(args, verdicts, title: str) -> None:
    """``--json``, ``--junit`` and ``--report`` of ``verdicts``; raises OSError."""
    if args.json == "-":
        print(json.dumps(vd.to_json(verdicts), indent=1, default=str))
        # (stdout is a stream, not a file: nothing to write atomically)
    elif args.json:
        vd.write_json(verdicts, args.json)
    if args.junit:
        vd.write_junit(verdicts, args.junit)
    if args.report is not None:
        from evaluation.gate.report import write_report

        entries = vd.report_entries(verdicts)
        notes = [(v.status, v.name, v.reason) for v in verdicts if v.ours is None]
        index = write_report(args.report, entries, title=title, overwrite=args.force,
                             notes=notes)
        print(f"report: {index}", file=sys.stderr if args.json == "-" else sys.stdout)


def cmd_check(args: argparse.Namespace) -> int:
    out = sys.stderr if args.json == "-" else sys.stdout
    read = read_options(args)
    for path in args.scenes:            # a usage error (exit 2), as for render, not a verdict
        check_defines(path, read.get("defines"))
    stores = stores_for(args)
    check_outputs(args)
    check_views(args.scenes, args.views, read)
    if not args.quiet:
        print("goldens: " + ", ".join(golden_store._display(s) for s in stores), file=out)

    def show(v):
        if not args.quiet:
            print(vd.format_line(v), file=out, flush=True)
            if v.status != "PASS" and v.differences:
                print(format_differences(v.differences), file=out, flush=True)

    verdicts = vd.check_scenes(args.scenes, stores, modes=args.modes, shadings=args.shadings,
                               views=_views(args.views), backend=args.backend,
                               precision=args.precision, accel=args.accel,
                               keep_images=args.report is not None, progress=show,
                               render=render_view, read=read)
    print(vd.summary_line(verdicts), file=out)
    write_outputs(args, verdicts, title="whitted check: ours vs Mitsuba 3 goldens")
    return vd.exit_code(verdicts)
