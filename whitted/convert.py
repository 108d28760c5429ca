"""``whitted convert IN OUT.toml``: an OBJ + MTL, PLY or Mitsuba XML scene (or a TOML one)
written as the project's TOML scene file, its meshes as PLY files in ``OUT_meshes/``
(``renderer.scene.writer``). Nothing is replaced without ``--force``; every file is written
atomically, the TOML last. Reading ``OUT.toml`` back renders the same image."""
from __future__ import annotations

import argparse
from pathlib import Path

from renderer.outputs import check_output_file, write_bytes
from renderer.scene.writer import scene_files

from .data import scene_arg
from .options import CliError, add_import_options, read_scene


def register(subparsers) -> None:
    """Add the ``convert`` subcommand to the main CLI's subparsers."""
    p = subparsers.add_parser("convert", help="write an OBJ/PLY/Mitsuba XML scene as a TOML "
                                               "scene file (meshes as PLY beside it)")
    p.add_argument("scene", type=scene_arg, help="scene file (.obj, .ply, .xml or .toml)")
    p.add_argument("out", type=Path, help="the TOML file to write (OUT.toml; meshes in "
                                          "OUT_meshes/)")
    add_import_options(p)
    p.add_argument("--force", action="store_true", help="replace existing files")
    p.set_defaults(func=cmd_convert, shading=None)


def cmd_convert(args: argparse.Namespace) -> int:
    if args.out.suffix.lower() != ".toml":
        raise CliError(f"{args.out}: the output is a .toml scene file")
    scene = read_scene(args)
    try:
        files = scene_files(scene, args.out, source=Path(args.scene).name)
    except ValueError as e:
        raise CliError(f"{args.scene}: {e}") from None
    for path in files:                      # every check before the first write
        check_output_file(path, overwrite=args.force, flag="--force")
    for path, data in files.items():
        write_bytes(path, data, overwrite=args.force, flag="--force")
    print(f"wrote {args.out} ({len(scene.objects)} objects, {len(scene.materials)} "
          f"materials, {len(scene.cameras)} views, {len(scene.lights)} lights) and "
          f"{len(files) - 1} meshes")
    return 0
