"""``whitted``: one entry point, one subcommand per job.

    whitted render  SCENE.toml   render with the Dr.Jit tracer → EXR + PNG
    whitted compare SCENE.toml   ours vs Mitsuba's golden → HTML side-by-side report
    whitted reference SCENE...   (re)render Mitsuba golden images
    whitted export  --mitsuba-xml OUT.xml SCENE.toml
    whitted bench   ...          timing study (kernel times, frozen frames, vs Mitsuba)

Subcommands that need Mitsuba live in modules that import it lazily, so ``render`` works
with only the core dependencies installed.
"""
from __future__ import annotations

import argparse
import importlib
import sys
from dataclasses import replace
from pathlib import Path

# Modules that add subcommands with ``register(subparsers)``; each sets ``func``.
_SUBCOMMAND_MODULES = ("whitted.cli_compare", "whitted.cli_reference", "whitted.cli_bench")


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
        if w <= 0 or h <= 0:
            raise ValueError
        return w, h
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT with positive integers, got {text!r}")


def add_scene_options(p: argparse.ArgumentParser) -> None:
    """Options shared by every subcommand that renders a scene with our tracer."""
    p.add_argument("scene", type=Path, help="scene file (.toml)")
    p.add_argument("--view", default="0", help="view index, view name, or 'all' (default 0)")
    p.add_argument("--size", type=_size, help="override the resolution, e.g. 512x512")
    p.add_argument("--shading", choices=("classic", "physical"), help="override the shading mode")
    p.add_argument("--spp", type=int, help="samples per pixel (a perfect square; implies converged mode)")
    p.add_argument("--max-depth", type=int, help="override the specular depth limit")
    p.add_argument("--backend", default="auto", choices=("auto", "cuda", "llvm"))
    p.add_argument("--precision", default="float32", choices=("float32", "float64"))
    p.add_argument("--accel", default="bvh", choices=("brute", "boxes", "bvh"),
                   help="acceleration structure (default bvh)")
    p.add_argument("--intersection", default="moller_trumbore", help="ray/triangle routine")
    p.add_argument("--effects", default="auto", choices=("auto", "all"),
                   help="'auto': trace only the effects the scene calls for; 'all': every effect")
    p.add_argument("--effect-off", action="append", default=[], metavar="EFFECT",
                   help="force one effect off for debugging (the image then differs from the scene's truth)")


def load_for_cli(args):
    """The scene with the command line's overrides applied, and the selected view indices."""
    from renderer.scene import load_scene
    scene = load_scene(args.scene, shading=args.shading)
    if args.size:
        w, h = args.size
        scene = replace(scene, cameras=[replace(c, width=w, height=h) for c in scene.cameras])
    changes = {}
    if args.spp is not None:
        changes.update(spp=args.spp, exact=args.spp == 1)
    if args.max_depth is not None:
        changes.update(max_depth=args.max_depth)
    if args.spp is not None and (args.spp < 1 or round(args.spp ** 0.5) ** 2 != args.spp):
        raise SystemExit(f"error: --spp: expected a perfect square >= 1 (k x k strata), got {args.spp}")
    if args.max_depth is not None and args.max_depth < 0:
        raise SystemExit(f"error: --max-depth: expected >= 0, got {args.max_depth}")
    if changes:
        scene = scene.with_settings(**changes)
    return scene, select_views(scene, args.view)


def select_views(scene, view: str) -> list[int]:
    names = [c.name for c in scene.cameras]
    if view == "all":
        return list(range(len(names)))
    if view.isdigit() and int(view) < len(names):
        return [int(view)]
    if view in names:
        return [names.index(view)]
    raise SystemExit(f"error: --view: expected an index < {len(names)}, a name in {names} or 'all', got {view!r}")


def effects_for_cli(scene, args):
    from renderer.effects import EffectSet
    eff = EffectSet.all(scene) if args.effects == "all" else EffectSet.from_scene(scene)
    for name in args.effect_off:
        eff = eff.without(name)
    return eff


def cmd_render(args) -> int:
    from renderer.film import write_exr, write_png
    from renderer.render import Renderer
    from renderer.stats import format_operations, kernel_operations
    scene, views = load_for_cli(args)
    effects = effects_for_cli(scene, args)
    print(f"{scene.name}: {scene.face_count} triangles, {len(scene.objects)} objects, "
          f"{len(scene.lights)} lights, shading {scene.settings.shading}")
    print(f"effects: {effects}")
    for line in effects.lines():
        print(f"  {line}")
    if args.effect_off:
        print(f"warning: effect(s) {', '.join(args.effect_off)} forced off: the image differs "
              "from the scene's truth", file=sys.stderr)
    elif args.effects == "all":
        print("note: --effects all traces every effect (the general kernel): same image, "
              "more work")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if getattr(args, "orbit", None):
        return render_orbit_views(scene, views, effects, args, out)
    stems = [out / f"{scene.name}_{scene.cameras[v].name}" for v in views]
    if not args.overwrite:
        for p in (s.with_suffix(ext) for s in stems for ext in (".exr", ".png")):
            if p.exists():
                raise FileExistsError(f"{p}: exists")
    # one upload / BVH build for every view
    renderer = Renderer(scene, backend=args.backend, precision=args.precision,
                        accel=args.accel, intersection=args.intersection, effects=effects)
    for v, stem in zip(views, stems):
        cam = scene.cameras[v]
        ks = kernel_operations(lambda: renderer.render(v))
        res = ks["result"]
        write_exr(stem.with_suffix(".exr"), res.image, overwrite=args.overwrite)
        write_png(stem.with_suffix(".png"), res.image, overwrite=args.overwrite)
        print(f"  view {cam.name}: {cam.width}x{cam.height}, {res.seconds * 1e3:.1f} ms "
              f"→ {stem}.exr, {stem}.png")
        print(f"    kernels: {format_operations(ks)}, {ks['kernel_ms']:.2f} ms kernel time")
    return 0


def _orbit_count(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 2:
        raise argparse.ArgumentTypeError(f"expected an integer >= 2 (frames on the orbit), got {text!r}")
    return n


def render_orbit_views(scene, views, effects, args, out: Path) -> int:
    """``render --orbit N``: per view, N frames on a circle around its target from one frozen
    frame function (renderer/orbit.py) → an animated GIF (and MP4 when imageio has ffmpeg)."""
    from renderer.orbit import PLAYBACK_FPS, mp4_available, render_orbit, write_gif, write_mp4
    for v in views:
        cam = scene.cameras[v]
        stem = out / f"{scene.name}_{cam.name}_orbit"
        paths = [stem.with_suffix(".gif")] + ([stem.with_suffix(".mp4")] if mp4_available() else [])
        for path in paths:      # refuse before rendering, not after
            if path.exists() and not args.overwrite:
                raise FileExistsError(f"{path}: exists")
        res = render_orbit(scene, args.orbit, view=v, backend=args.backend,
                           precision=args.precision, accel=args.accel,
                           intersection=args.intersection, effects=effects)
        write_gif(paths[0], res.frames, fps=PLAYBACK_FPS, overwrite=args.overwrite)
        if len(paths) > 1:
            write_mp4(paths[1], res.frames, fps=PLAYBACK_FPS, overwrite=args.overwrite)
        print(f"  view {cam.name}: orbit of {args.orbit} frames at {cam.width}x{cam.height}: "
              f"first (traced) frame {res.first_frame_ms:.1f} ms, frozen frames median "
              f"{res.frozen_frame_ms_median:.2f} ms, {res.fps:.1f} frames/s over frames 1..{args.orbit - 1} "
              f"(recordings: {res.recordings}) → {', '.join(map(str, paths))}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="whitted", description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("render", help="render a scene with the Dr.Jit tracer (EXR + sRGB PNG)")
    add_scene_options(p)
    p.add_argument("--out", default="out", help="output folder (default out/)")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument("--orbit", type=_orbit_count, metavar="N",
                   help="render N frames on a circle around the view's target with one frozen "
                        "frame function → animated GIF, and report frames per second")
    p.set_defaults(func=cmd_render)
    for name in _SUBCOMMAND_MODULES:
        try:
            module = importlib.import_module(name)
        except ModuleNotFoundError as e:
            if e.name != name:
                raise
            continue
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from renderer.scene import SceneError
    try:
        return args.func(args) or 0
    except SceneError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except FileExistsError as e:
        print(f"error: {str(e).split(' (pass')[0]} (pass --overwrite, or --force for reports, "
              "to replace it)", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
