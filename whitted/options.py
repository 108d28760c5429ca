"""Options and helpers shared by the subcommands that render a scene with our tracer.

Every ``choices`` list comes from the constant that defines it (``renderer.device``,
``renderer.scene``, ``renderer.accel``, ``renderer.effects``), so a new backend, shading
mode, accelerator, triangle routine or effect shows up on the command line without an edit
here. ``--spp``, ``--max-depth`` and ``--size`` go through ``Scene.with_overrides``, the one
place that validates them (``--spp`` alone also sets exact mode to ``spp == 1``); a bad value
there is a ``SceneError`` naming the option as typed (``overrides_for_cli``), which
``whitted.cli.main`` prints as one ``error:`` line (exit code 2). ``EXIT`` is the table of
exit codes (``whitted.cli``).
"""
from __future__ import annotations

import argparse

from evaluation import wxh
from evaluation.gate.exit_codes import EXIT_CODES
from renderer.accel import ACCELERATORS, BUILDS, DEFAULT_ACCELS, DEFAULT_ROUTINE, ROUTINES
from renderer.device import BACKENDS, PRECISIONS
from renderer.effects import FLAGS, EffectSet
from renderer.scene import SHADING_MODES, Scene, SceneError, load_scene

from .data import scene_arg

#: Exit codes of every subcommand: the verdict codes of ``evaluation.gate.verdict.EXIT_CODES``
#: (OpenImageIO ``idiff``'s: 0 pass, 1 warn, 2 fail, 3 size, 4 missing/stale golden or file
#: error), a bad request sharing FAIL's 2 (argparse's own usage code), and 130 for Ctrl-C.
EXIT = {"ok": EXIT_CODES["PASS"], "warn": EXIT_CODES["WARN"], "fail": EXIT_CODES["FAIL"],
        "usage": EXIT_CODES["FAIL"], "size": EXIT_CODES["SIZE"], "file": EXIT_CODES["MISSING"],
        "interrupted": 130}


#: The exit-code table of ``whitted --help`` (and ``check --help``), from ``EXIT``.
EXIT_CODE_HELP = f"""exit codes (idiff's style; check, compare, diff: the largest verdict's):
  {EXIT["ok"]}    PASS: done, or every comparison passed
  {EXIT["warn"]}    WARN: passed, but a [check.warn] level of a scene file was exceeded
  {EXIT["fail"]}    FAIL: an image differs from its golden; or a bad request (usage, option
       value, scene file, view, backend)
  {EXIT["size"]}    SIZE: an image and its golden differ in size
  {EXIT["file"]}    MISSING / STALE / ERROR: a golden is missing, out of date or unreadable (the
       line names the command that fixes it); a file error (an output that exists or
       cannot be written, a missing input)
  {EXIT["interrupted"]}  interrupted (Ctrl-C); no partial file is left"""

class CliError(Exception):
    """A command-line request that cannot be carried out (a view that does not exist, an
    output that would be replaced, a golden that cannot be compared). ``whitted.cli.main``
    prints the one line ``error: <message>`` on stderr and returns ``code`` (default
    ``EXIT["usage"]``; ``EXIT["file"]`` for files, ``EXIT["size"]`` for a size mismatch)."""

    def __init__(self, message: str, code: int = EXIT["usage"]):
        super().__init__(message)
        self.code = code


def add_backend_option(p: argparse.ArgumentParser) -> None:
    """``--backend``, one of ``renderer.device.BACKENDS`` (default auto)."""
    p.add_argument("--backend", default="auto", choices=BACKENDS)


def add_scene_options(p: argparse.ArgumentParser) -> None:
    """Options shared by every subcommand that renders a scene with our tracer."""
    p.add_argument("scene", type=scene_arg,
                   help="scene file (.toml, .obj with its .mtl, .ply, Mitsuba .xml), or a "
                        "bundled scene's name (whitted data)")
    add_import_options(p)
    p.add_argument("--view", default="0", help="view index, view name, or 'all' (default 0)")
    p.add_argument("--size", type=wxh, help="override the resolution, e.g. 512x512")
    p.add_argument("--shading", choices=SHADING_MODES, help="override the shading mode")
    p.add_argument("--spp", type=int,
                   help="samples per pixel (a perfect square; implies converged mode)")
    p.add_argument("--max-depth", type=int, help="override the specular depth limit")
    p.add_argument("--shadow-samples", type=int,
                   help="shadow rays per light with extent per hit (a perfect square)")
    add_backend_option(p)
    p.add_argument("--precision", default=PRECISIONS[0], choices=PRECISIONS)
    p.add_argument("--accel", choices=tuple(ACCELERATORS),
                   help="acceleration structure (default: the backend's, "
                        + ", ".join(f"{a} on {b}" for b, a in DEFAULT_ACCELS.items())
                        + "; every one gives the same pixels)")
    p.add_argument("--intersection", default=DEFAULT_ROUTINE, choices=tuple(ROUTINES),
                   help=f"ray/triangle routine (default {DEFAULT_ROUTINE})")
    p.add_argument("--build", choices=BUILDS,
                   help="how the BVH is built: 'sah' (host SAH: the faster tree), 'device' "
                        "(Dr.Jit on the backend: the faster build; PLOC), 'ploc' "
                        "(locally-ordered clustering), 'radix' (Morton radix tree: the "
                        "fastest build), 'auto' (default, or the scene's [render] build: a "
                        "cached SAH tree, else the device build for a few frames of a large "
                        "scene)")
    p.add_argument("--no-cache", action="store_true",
                   help="neither read nor write the cache of built trees ($WHITTED_CACHE, "
                        "else the user cache folder)")
    p.add_argument("--effects", default="auto", choices=("auto", "all"),
                   help="'auto': trace only the effects the scene calls for; 'all': every effect")
    p.add_argument("--effect-off", action="append", default=[], metavar="EFFECT",
                   choices=FLAGS,
                   help="force one effect off for debugging (the image then differs from the "
                        f"scene's truth); one of {', '.join(FLAGS)}")


def add_import_options(p: argparse.ArgumentParser) -> None:
    """``--camera auto``, ``-D NAME=VALUE`` and ``--approximate``: how a scene file is read
    (``renderer.scene.load_scene``)."""
    p.add_argument("--camera", choices=("auto",),
                   help="'auto': one view framed on the scene's bounding box, replacing the "
                        "file's views (a mesh file without views gets it anyway)")
    add_read_options(p)


def add_read_options(p: argparse.ArgumentParser) -> None:
    """``-D NAME=VALUE`` and ``--approximate`` (``read_options``)."""
    p.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE",
                   help="Mitsuba XML: set a $NAME parameter (overrides its <default>)")
    p.add_argument("--approximate", action="store_true",
                   help="Mitsuba XML: render elements outside the model's subset (path "
                        "integrator, rough or plastic BSDFs, named conductors) by their "
                        "documented approximation instead of refusing them")


def read_options(args: argparse.Namespace) -> dict:
    """``load_scene``'s ``defines`` and ``approximate`` from ``-D`` and ``--approximate``,
    only those given (``Scene.read``); a bad ``-D`` is a SceneError (exit 2)."""
    from renderer.scene.mitsuba_xml import parse_defines
    defines = parse_defines(getattr(args, "defines", []))
    return {**({"defines": defines} if defines else {}),
            **({"approximate": True} if getattr(args, "approximate", False) else {})}


def read_scene(args: argparse.Namespace, path=None, *, cache=None) -> Scene:
    """``load_scene`` of ``path`` (default ``args.scene``) with the options of
    ``add_import_options``, ``--shading`` and the tree cache ``cache``."""
    items = getattr(args, "defines", [])
    if items:                        # the XML reader is imported only where -D is given
        from renderer.scene.mitsuba_xml import parse_defines
        defines = parse_defines(items)
    else:
        defines = {}
    return load_scene(args.scene if path is None else path,
                      shading=getattr(args, "shading", None),
                      camera=getattr(args, "camera", None),
                      defines=defines,
                      approximate=getattr(args, "approximate", False), cache=cache)


def cache_for_cli(args: argparse.Namespace):
    """The tree cache the command line asks for: None with ``--no-cache``; one per command
    (kept on ``args``), writing in the background (the command calls its ``flush``)."""
    from renderer.accel.cache import TreeCache
    if getattr(args, "no_cache", False):
        return None
    if getattr(args, "_cache", None) is None:
        args._cache = TreeCache(background=True)
    return args._cache


#: The option (and ``Scene.with_overrides`` argument) each settings field comes from on the
#: command line.
OVERRIDE_OPTIONS = {"settings.spp": ("--spp", "spp"), "settings.exact": ("--spp", "spp"),
                    "settings.max_depth": ("--max-depth", "max_depth"),
                    "size": ("--size", "size"), "settings.seed": ("--seed", "seed"),
                    "settings.shadow_samples": ("--shadow-samples", "shadow_samples")}


def overrides_for_cli(scene: Scene, **overrides) -> Scene:
    """``scene.with_overrides(**overrides)`` (None keeps the scene's value) for options of
    the command line: an error about a value the command line gave names the option as
    typed (``--spp: ...``), not the settings field (``settings.spp``)."""
    try:
        return scene.with_overrides(**overrides)
    except SceneError as e:
        option, key = OVERRIDE_OPTIONS.get(e.field or "", (None, None))
        if option is None or overrides.get(key) is None:
            raise
        text, head = str(e), f"{e.field}: "
        body = text[len(head):] if text.startswith(head) else text
        raise SceneError(f"{option}: {body}", field=option) from None


def load_for_cli(args: argparse.Namespace) -> tuple[Scene, list[int]]:
    """The scene with the command line's overrides applied, and the selected view indices.

    Raises ``SceneError`` for a bad scene file or override (naming the option as typed),
    ``CliError`` for a bad view."""
    scene = read_scene(args, cache=cache_for_cli(args))
    scene = overrides_for_cli(scene, spp=args.spp, max_depth=args.max_depth, size=args.size,
                              shadow_samples=getattr(args, "shadow_samples", None))
    return scene, select_views(scene, args.view)


def select_views(scene: Scene, view: str) -> list[int]:
    """Indices of the views ``--view`` names: an index, a view name, or ``all``."""
    names = [c.name for c in scene.cameras]
    if view == "all":
        return list(range(len(names)))
    if view.isdigit() and int(view) < len(names):
        return [int(view)]
    if view in names:
        return [names.index(view)]
    raise CliError(f"--view: expected an index < {len(names)}, a name in {names} or 'all', "
                   f"got {view!r}")


def effects_for_cli(scene: Scene, args: argparse.Namespace) -> EffectSet:
    """The effect set ``--effects`` and ``--effect-off`` ask for."""
    eff = EffectSet.all(scene) if args.effects == "all" else EffectSet.from_scene(scene)
    for name in args.effect_off:
        eff = eff.without(name)
    return eff
