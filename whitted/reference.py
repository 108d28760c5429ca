"""Subcommands of the Mitsuba reference: ``reference`` (render goldens) and ``export``
(write a scene as Mitsuba XML). Mitsuba itself is imported only when they run."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from reference import golden
from reference.mitsuba_scene import export_xml
from renderer.scene import SHADING_MODES, load_scene


def register(subparsers) -> None:
    """Add the ``reference`` and ``export`` subcommands to the main CLI's subparsers."""
    p = subparsers.add_parser(
        "reference", help="render golden images with Mitsuba 3 into a golden store",
        description="Render the goldens of every view x shading mode x mode of each scene "
        "with Mitsuba into a golden store (--goldens DIR, else $WHITTED_GOLDENS, else "
        "[tool.whitted] goldens in the nearest pyproject.toml). Only what is missing or "
        "stale there is rendered; a stale golden is replaced only with --force. The bundled "
        "store is read-only here (its developers use `python -m reference.golden "
        "--bundled`). Modes and shadings default to the scene's [check] table, else exact "
        "mode in both shadings.")
    p.add_argument("scenes", nargs="+", type=Path, help="scene .toml files")
    p.add_argument("--goldens", type=Path, metavar="DIR", help="the golden store to write")
    p.add_argument("--update", action="store_true",
                   help="render what is missing or stale, keep what is up to date (the "
                        "default; stale files still need --force)")
    p.add_argument("--force", action="store_true", help="replace stale goldens")
    p.add_argument("--spp", type=int, default=golden.CONVERGED_SPP,
                   help=f"converged samples per pixel (default {golden.CONVERGED_SPP})")
    p.add_argument("--batches", type=int, default=golden.CONVERGED_BATCHES,
                   help="independent batches of the converged render (variance estimate; "
                        f"default {golden.CONVERGED_BATCHES})")
    p.add_argument("--size", type=int, default=golden.DEFAULT_SIZE,
                   help=f"image height in pixels (default {golden.DEFAULT_SIZE})")
    p.add_argument("--converged-size", type=int, default=golden.CONVERGED_SIZE,
                   help=f"image height of converged goldens (default {golden.CONVERGED_SIZE})")
    p.add_argument("--modes", nargs="+", choices=golden.MODES,
                   help="default: the scene's [check] modes, else exact")
    p.add_argument("--shadings", nargs="+", choices=SHADING_MODES,
                   help="default: the scene's [check] shadings, else both")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_reference)

    p = subparsers.add_parser("export", help="write a scene as a Mitsuba 3 XML file",
                              description="Write a Mitsuba 3 XML scene (meshes as .ply "
                              "beside it); it loads with mi.load_file once the "
                              "harness's plugins (reference/plugins.py) are registered.")
    p.add_argument("scene", type=Path, help="scene .toml file")
    p.add_argument("--mitsuba-xml", type=Path, required=True, help="output .xml path")
    p.add_argument("--view", type=int, default=0)
    p.add_argument("--shading", choices=SHADING_MODES, default=None)
    p.set_defaults(func=cmd_export)


def cmd_reference(args: argparse.Namespace) -> int:
    from evaluation.verdict import plan_for

    store, source = (args.goldens, "--goldens") if args.goldens else \
        golden.configured_store()
    if store is None:
        print("error: no golden store to write: pass --goldens DIR, set $WHITTED_GOLDENS or "
              "add `goldens = \"DIR\"` to [tool.whitted] in pyproject.toml (the bundled store "
              "is read-only)", file=sys.stderr)
        return 4
    written = 0
    try:
        for path in args.scenes:
            modes, shadings = plan_for(load_scene(path), args.modes, args.shadings)
            written += len(golden.render_goldens(
                [path], force=args.force, spp=args.spp, batches=args.batches, size=args.size,
                converged_size=args.converged_size, modes=modes, shadings=shadings,
                progress=not args.quiet, root=store, report=None if args.quiet else print))
    except golden.GoldenError as e:
        print(f"error: {e}", file=sys.stderr)
        return 4
    print(f"wrote {written} golden images into {store}" + (f" (from {source})"
                                                          if source != "--goldens" else ""))
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    scene = load_scene(args.scene, shading=args.shading)
    out = export_xml(scene, args.mitsuba_xml, view=args.view)
    print(f"wrote {out}")
    return 0
