"""Subcommands of the Mitsuba reference: ``reference`` (render goldens) and ``export``
(write a scene as Mitsuba XML). Mitsuba itself is imported only when they run."""
from __future__ import annotations

import argparse
from pathlib import Path

from reference import golden
from reference.mitsuba_scene import export_xml
from renderer.scene import SHADING_MODES, load_scene


def register(subparsers) -> None:
    """Add the ``reference`` and ``export`` subcommands to the main CLI's subparsers."""
    p = subparsers.add_parser("reference", help="render golden images with Mitsuba 3",
                              description="Render every view x shading mode x mode of each "
                              "scene with Mitsuba into reference/goldens/.")
    p.add_argument("scenes", nargs="+", type=Path, help="scene .toml files")
    p.add_argument("--force", action="store_true", help="overwrite existing goldens")
    p.add_argument("--spp", type=int, default=golden.CONVERGED_SPP,
                   help=f"converged samples per pixel (default {golden.CONVERGED_SPP})")
    p.add_argument("--batches", type=int, default=golden.CONVERGED_BATCHES,
                   help="independent batches of the converged render (variance estimate; "
                        f"default {golden.CONVERGED_BATCHES})")
    p.add_argument("--size", type=int, default=golden.DEFAULT_SIZE,
                   help=f"image height in pixels (default {golden.DEFAULT_SIZE})")
    p.add_argument("--converged-size", type=int, default=golden.CONVERGED_SIZE,
                   help=f"image height of converged goldens (default {golden.CONVERGED_SIZE})")
    p.add_argument("--modes", nargs="+", default=list(golden.MODES), choices=golden.MODES)
    p.add_argument("--shadings", nargs="+", default=list(SHADING_MODES),
                   choices=SHADING_MODES)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--workers", type=int, default=0,
                   help="render the goldens on a Dask LocalCluster of N worker processes "
                        "(one GPU each where there are GPUs; default: in this process)")
    p.add_argument("--scheduler", help="render the goldens on an existing Dask scheduler")
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
    # Same executor as `whitted study`: each job (scene, shading, mode, view) is a picklable
    # spec rendered by reference.golden.render_golden_job in whichever process runs it.
    from evaluation.executor import make_executor, visible_gpus
    workers, scheduler = getattr(args, "workers", 0), getattr(args, "scheduler", None)
    kw = {"gpus": "auto"} if workers and not scheduler and visible_gpus() else {}
    with make_executor(workers, scheduler, **kw) as ex:
        paths = golden.render_goldens(
            args.scenes, force=args.force, spp=args.spp, batches=args.batches, size=args.size,
            converged_size=args.converged_size, modes=tuple(args.modes),
            shadings=tuple(args.shadings), progress=not args.quiet,
            executor=None if ex.name == "in-process" else ex)
    print(f"wrote {len(paths)} golden images")
    return 0


def cmd_export(args: argparse.Namespace) -> int:
    scene = load_scene(args.scene, shading=args.shading)
    out = export_xml(scene, args.mitsuba_xml, view=args.view)
    print(f"wrote {out}")
    return 0
