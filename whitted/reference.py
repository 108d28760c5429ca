"""Subcommands of the Mitsuba reference: ``reference`` (render goldens) and ``export``
(write a scene as Mitsuba XML). Mitsuba itself is imported only when they run."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from evaluation import at_least
from reference import golden
from reference.mitsuba_scene import (
    check_export,
    export_paths,
    export_xml,
    portable_integrator,
    portable_problems,
)
from reference.xml_lookat import write_lookat
from renderer.outputs import check_output_dir
from renderer.scene import SHADING_MODES, load_scene
from renderer.scene.importers import check_defines

from .data import scene_arg
from .options import (
    EXIT,
    CliError,
    add_read_options,
    overrides_for_cli,
    read_options,
    select_views,
)


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
    p.add_argument("scenes", nargs="+", type=scene_arg,
                   help="scene .toml files (or bundled scene names)")
    p.add_argument("--goldens", type=Path, metavar="DIR", help="the golden store to write")
    p.add_argument("--update", action="store_true",
                   help="render what is missing or stale, keep what is up to date (the "
                        "default; stale files still need --force)")
    p.add_argument("--force", action="store_true", help="replace stale goldens")
    p.add_argument("--spp", type=at_least(1), default=golden.CONVERGED_SPP,
                   help=f"converged samples per pixel (default {golden.CONVERGED_SPP})")
    p.add_argument("--batches", type=at_least(1), default=golden.CONVERGED_BATCHES,
                   help="independent batches of the converged render (variance estimate; "
                        f"default {golden.CONVERGED_BATCHES})")
    p.add_argument("--size", type=at_least(1), default=None,
                   help="image height in pixels, the width following the view's aspect "
                        "(default: the scene's [check] size, else its own resolution)")
    p.add_argument("--converged-size", type=at_least(1), default=None,
                   help="image height of converged goldens (default: --size, else the "
                        "scene's [check] converged_size or size, else its own resolution)")
    p.add_argument("--modes", nargs="+", choices=golden.MODES,
                   help="default: the scene's [check] modes, else exact")
    p.add_argument("--shadings", nargs="+", choices=SHADING_MODES,
                   help="default: the scene's [check] shadings, else both")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--workers", type=at_least(0), default=0,
                   help="render the goldens on a Dask LocalCluster of N worker processes "
                        "(one GPU each where there are GPUs; default: in this process)")
    p.add_argument("--scheduler", help="render the goldens on an existing Dask scheduler")
    add_read_options(p)
    p.set_defaults(func=cmd_reference)

    p = subparsers.add_parser(
        "export", help="write a scene as a Mitsuba 3 XML file (meshes in a folder of its own)",
        description="Write a Mitsuba 3 XML scene, its meshes as .ply files in "
        "<xml stem>_meshes/ beside it. By default it loads with mi.load_file once the "
        "harness's plugins (reference/plugins.py) are registered; --portable writes stock "
        "plugins only (plain Mitsuba loads it) or says which parts need ours. Nothing is "
        "replaced without --force.")
    p.add_argument("scene", type=scene_arg, help="scene .toml file or bundled scene name")
    p.add_argument("--mitsuba-xml", type=Path, required=True, help="output .xml path")
    p.add_argument("--view", default="0", help="view index or name (default 0)")
    p.add_argument("--shading", choices=SHADING_MODES, default=None)
    p.add_argument("--portable", action="store_true",
                   help="stock Mitsuba plugins only (diffuse, conductor, dielectric, point, "
                        "direct/path): physical shading, no ambient or background")
    p.add_argument("--spp", type=at_least(1), default=None,
                   help="samples per pixel of the exported sampler (a perfect square; "
                        "default: the scene's, 16 with --portable)")
    p.add_argument("--force", action="store_true",
                   help="replace an existing export (the XML and its mesh folder)")
    p.set_defaults(func=cmd_export)


def cmd_reference(args: argparse.Namespace) -> int:
    from evaluation.gate.executor import make_executor, visible_gpus
    from evaluation.gate.verdict import plan_for

    read = read_options(args)
    for path in args.scenes:            # before the store is made: exit 2, as for render
        check_defines(path, read.get("defines"))
    store, source = (args.goldens, "--goldens") if args.goldens else \
        golden.configured_store()
    if store is None:
        raise CliError("no golden store to write: pass --goldens DIR, set $WHITTED_GOLDENS or "
                       "add `goldens = \"DIR\"` to [tool.whitted] in pyproject.toml (the "
                       "bundled store is read-only)", code=EXIT["file"])
    workers, scheduler = getattr(args, "workers", 0) or 0, getattr(args, "scheduler", None)
    if workers < 0:
        raise CliError(f"--workers: expected 0 (this process) or more, got {workers}")
    check_output_dir(store)                 # before any rendering: the store can be written
    written = 0
    try:
        # plan every scene first: a stale golden without --force (or a bundled store) is
        # refused before any worker starts or anything renders
        plans = []
        for path in args.scenes:
            modes, shadings = plan_for(load_scene(path, **read), args.modes, args.shadings)
            plans.append((path, modes, shadings))
            golden.golden_jobs([path], size=args.size, converged_size=args.converged_size,
                               modes=modes, shadings=shadings, root=store, force=args.force,
                               read=read)
        # Same executor as `whitted study`: each job (scene, shading, mode, view) is a
        # picklable spec rendered by reference.golden.render_golden_job wherever it runs.
        kw = {"gpus": "auto"} if workers and not scheduler and visible_gpus() else {}
        try:
            ex = make_executor(workers, scheduler, **kw)
        except (RuntimeError, ValueError, OSError) as e:
            where = "--scheduler" if scheduler else "--workers"
            raise CliError(f"{where}: {e}") from e
        with ex:
            for path, modes, shadings in plans:
                written += len(golden.render_goldens(
                    [path], force=args.force, spp=args.spp, batches=args.batches,
                    size=args.size, converged_size=args.converged_size, modes=modes,
                    shadings=shadings, progress=not args.quiet, root=store,
                    report=None if args.quiet else print,
                    executor=None if ex.name == "in-process" else ex, read=read))
    except golden.GoldenError as e:
        raise CliError(str(e), code=EXIT["file"]) from e
    print(f"wrote {written} golden images into {store}" + (f" (from {source})"
                                                          if source != "--goldens" else ""))
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    scene = load_scene(args.scene, shading=args.shading)
    if args.spp is not None:
        scene = overrides_for_cli(scene, spp=args.spp)
    views = select_views(scene, args.view)
    if len(views) != 1:
        raise CliError("--view: export writes one view; name one index or view name")
    check_export(args.mitsuba_xml, overwrite=args.force)
    if args.portable:
        problems = portable_problems(scene)
        if problems:
            raise CliError(f"{args.scene}: --portable: these parts need the project's "
                           "Mitsuba plugins (reference/plugins.py):\n  "
                           + "\n  ".join(problems) + "\nexport without --portable to keep "
                           "them")
    s = scene.settings
    spp = s.spp if not s.exact else (16 if args.portable else 1)
    mode = "converged" if args.portable or not s.exact else "exact"
    out = export_xml(scene, args.mitsuba_xml, view=views[0], spp=spp, mode=mode,
                     portable=args.portable, overwrite=args.force)
    write_lookat(out, scene.cameras[views[0]])     # the view exactly, for a read back
    print(f"wrote {out} and its meshes in {export_paths(out)[1]}/")
    if args.portable:
        note = portable_integrator(scene)[1]
        print("portable: stock Mitsuba plugins only (mi.load_file needs no plugin of ours)")
        if note:
            print(f"warning: {note}", file=sys.stderr)
    else:
        print("note: loads in Mitsuba once reference.plugins.register() has run "
              "(whitted integrator, whitted_material, whitted_phong)")
    return 0
