"""The bundled scenes: where they are, names that find them, and ``whitted data DIR``.

The scene files and their meshes live in ``scenes/`` at the repository root (tests, README
commands and the goldens' sidecars name them there). A wheel carries a copy as package
data, ``whitted/bundled/scenes/`` (copied by ``setup.py``'s ``build_py`` at build time), so
an installed ``whitted`` has them too:

- ``scenes_dir()`` is the repository's ``scenes/`` in a checkout (also an editable
  install), else the wheel's copy;
- a scene argument that is not an existing file but a bundled scene's name
  (``cornell_box`` or ``cornell_box.toml``) means that bundled scene (``scene_arg``, the
  ``argparse`` type of every SCENE argument), so ``whitted render cornell_box`` works from
  any folder;
- ``whitted data DIR`` copies the bundled scenes and meshes (with ``meshes/SOURCES.md``,
  their terms) into DIR to edit or to point ``--goldens`` users at; files there are not
  replaced without ``--force``.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from renderer.outputs import check_output_file, write_bytes

_HERE = Path(__file__).resolve().parent


def scenes_dir() -> Path:
    """The folder of the bundled scene files (``meshes/`` inside it)."""
    repo = _HERE.parent / "scenes"
    if repo.is_dir():
        return repo
    return _HERE / "bundled" / "scenes"


def bundled_scenes() -> dict[str, Path]:
    """Bundled scene files by name (the file's stem), sorted."""
    d = scenes_dir()
    return {p.stem: p for p in sorted(d.glob("*.toml"))} if d.is_dir() else {}


def scene_arg(text: str) -> Path:
    """``argparse`` type of a SCENE argument: an existing path as given; otherwise a
    bundled scene's name (``cornell_box`` or ``cornell_box.toml``, no folder part); otherwise
    the path as given (the loader then says the file is missing)."""
    p = Path(text)
    if p.exists() or len(p.parts) != 1:
        return p
    stem = p.stem if p.suffix == ".toml" else p.name
    return bundled_scenes().get(stem, p)


def register(subparsers) -> None:
    """Add the ``data`` subcommand to the main CLI's subparsers."""
    p = subparsers.add_parser(
        "data", help="copy the bundled scenes and meshes into a folder (or list them)",
        description="Copy the bundled scene files and their meshes into DIR (scenes/*.toml "
                    "and meshes/...). Without DIR, list the bundled scenes.")
    p.add_argument("dir", type=Path, nargs="?", help="destination folder")
    p.add_argument("--force", action="store_true", help="replace files that exist in DIR")
    p.set_defaults(func=cmd_data)


def bundled_files() -> list[Path]:
    """Every bundled file (scenes and meshes), relative to ``scenes_dir()``."""
    root = scenes_dir()
    return sorted(p.relative_to(root) for p in root.rglob("*")
                  if p.is_file() and "__pycache__" not in p.parts)


def cmd_data(args: argparse.Namespace) -> int:
    if args.dir is None:
        print(f"bundled scenes in {scenes_dir()}:")
        for name, path in bundled_scenes().items():
            print(f"  {name:20s} {path.name}")
        return 0
    files = bundled_files()
    for rel in files:                   # every check before the first copy
        check_output_file(args.dir / rel, overwrite=args.force, flag="--force")
    for rel in files:
        write_bytes(args.dir / rel, (scenes_dir() / rel).read_bytes(), overwrite=args.force,
                    flag="--force")
    print(f"copied {len(files)} files ({len(bundled_scenes())} scenes) into {args.dir}")
    return 0
