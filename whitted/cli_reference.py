"""Subcommands of the Mitsuba reference: ``reference`` (render goldens) and ``export``
(write a scene as Mitsuba XML)."""
from __future__ import annotations

import argparse
from pathlib import Path


def cmd_reference(args) -> int:
    from reference.golden import (CONVERGED_BATCHES, CONVERGED_SIZE, CONVERGED_SPP,
                                  DEFAULT_SIZE, render_goldens)
    paths = render_goldens(
        args.scenes, force=args.force, spp=args.spp or CONVERGED_SPP,
        batches=args.batches or CONVERGED_BATCHES, size=args.size or DEFAULT_SIZE,
        converged_size=args.converged_size or CONVERGED_SIZE,
        modes=tuple(args.modes), shadings=tuple(args.shadings), progress=not args.quiet)
    print(f"wrote {len(paths)} golden images")
    return 0


def cmd_export(args) -> int:
    from reference.mitsuba_scene import export_xml
    from renderer.scene import load_scene
    scene = load_scene(args.scene, shading=args.shading)
    out = export_xml(scene, args.mitsuba_xml, view=args.view)
    print(f"wrote {out}")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser("reference", help="render golden images with Mitsuba 3",
                              description="Render every view x shading mode x mode of each "
                              "scene with Mitsuba into reference/goldens/.")
    p.add_argument("scenes", nargs="+", type=Path, help="scene .toml files")
    p.add_argument("--force", action="store_true", help="overwrite existing goldens")
    p.add_argument("--spp", type=int, default=None, help="converged samples per pixel")
    p.add_argument("--batches", type=int, default=None,
                   help="independent batches of the converged render (variance estimate)")
    p.add_argument("--size", type=int, default=None, help="image height in pixels")
    p.add_argument("--converged-size", type=int, default=None,
                   help="image height of converged goldens (default 128)")
    p.add_argument("--modes", nargs="+", default=["exact", "converged"],
                   choices=["exact", "converged"])
    p.add_argument("--shadings", nargs="+", default=["classic", "physical"],
                   choices=["classic", "physical"])
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_reference)

    p = subparsers.add_parser("export", help="write a scene as a Mitsuba 3 XML file",
                              description="Write a Mitsuba 3 XML scene (meshes as .ply "
                              "beside it); it loads with mi.load_file after "
                              "`import reference.plugins`.")
    p.add_argument("scene", type=Path, help="scene .toml file")
    p.add_argument("--mitsuba-xml", type=Path, required=True, help="output .xml path")
    p.add_argument("--view", type=int, default=0)
    p.add_argument("--shading", choices=["classic", "physical"], default=None)
    p.set_defaults(func=cmd_export)
