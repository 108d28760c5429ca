"""``whitted render SCENE.toml``: render with the Dr.Jit tracer → EXR + sRGB PNG per view, or
with ``--orbit N`` an animated GIF (and MP4 when imageio has ffmpeg) per view."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from renderer.film import write_exr, write_png
from renderer.orbit import PLAYBACK_FPS, mp4_available, render_orbit, write_gif, write_mp4
from renderer.render import Renderer
from renderer.stats import format_operations, kernel_operations

from .options import add_scene_options, effects_for_cli, load_for_cli


def register(subparsers) -> None:
    """Add the ``render`` subcommand to the main CLI's subparsers."""
    p = subparsers.add_parser("render",
                              help="render a scene with the Dr.Jit tracer (EXR + sRGB PNG)")
    add_scene_options(p)
    p.add_argument("--out", default="out", help="output folder (default out/)")
    p.add_argument("--overwrite", action="store_true", help="replace existing output files")
    p.add_argument("--orbit", type=orbit_count, metavar="N",
                   help="render N frames on a circle around the view's target with one frozen "
                        "frame function → animated GIF, and report frames per second")
    p.set_defaults(func=cmd_render)


def orbit_count(text: str) -> int:
    """``argparse`` type of ``--orbit``: an integer >= 2."""
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 2:
        raise argparse.ArgumentTypeError(
            f"expected an integer >= 2 (frames on the orbit), got {text!r}")
    return n


def refuse_existing(paths, overwrite: bool) -> None:
    """Raise ``FileExistsError`` before rendering if an output exists and ``overwrite`` is
    off (``whitted.cli.main`` prints it and returns 2)."""
    for path in paths:
        if path.exists() and not overwrite:
            raise FileExistsError(f"{path}: exists (pass --overwrite to replace it)")


def cmd_render(args: argparse.Namespace) -> int:
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
    if args.orbit:
        return render_orbit_views(scene, views, effects, args, out)
    stems = [out / f"{scene.name}_{scene.cameras[v].name}" for v in views]
    refuse_existing((s.with_suffix(ext) for s in stems for ext in (".exr", ".png")),
                    args.overwrite)
    # one upload / accelerator build for every view
    renderer = Renderer(scene, backend=args.backend, precision=args.precision,
                        accel=args.accel, intersection=args.intersection, effects=effects)
    for v, stem in zip(views, stems):
        cam = scene.cameras[v]
        ks = kernel_operations(lambda v=v: renderer.render(v))
        res = ks["result"]
        write_exr(stem.with_suffix(".exr"), res.image, overwrite=args.overwrite)
        write_png(stem.with_suffix(".png"), res.image, overwrite=args.overwrite)
        print(f"  view {cam.name}: {cam.width}x{cam.height}, {res.seconds * 1e3:.1f} ms "
              f"→ {stem}.exr, {stem}.png")
        print(f"    kernels: {format_operations(ks)}, {ks['kernel_ms']:.2f} ms kernel time")
    return 0


def render_orbit_views(scene, views, effects, args: argparse.Namespace, out: Path) -> int:
    """``render --orbit N``: per view, N frames on a circle around its target from one frozen
    frame function (renderer/orbit.py) → an animated GIF (and MP4 when imageio has ffmpeg)."""
    for v in views:
        cam = scene.cameras[v]
        stem = out / f"{scene.name}_{cam.name}_orbit"
        paths = [stem.with_suffix(".gif")] + ([stem.with_suffix(".mp4")] if mp4_available() else [])
        refuse_existing(paths, args.overwrite)
        res = render_orbit(scene, args.orbit, view=v, backend=args.backend,
                           precision=args.precision, accel=args.accel,
                           intersection=args.intersection, effects=effects)
        write_gif(paths[0], res.frames, fps=PLAYBACK_FPS, overwrite=args.overwrite)
        if len(paths) > 1:
            write_mp4(paths[1], res.frames, fps=PLAYBACK_FPS, overwrite=args.overwrite)
        print(f"  view {cam.name}: orbit of {args.orbit} frames at {cam.width}x{cam.height}: "
              f"first (traced) frame {res.first_frame_ms:.1f} ms, frozen frames median "
              f"{res.frozen_frame_ms_median:.2f} ms, {res.fps:.1f} frames/s over frames "
              f"1..{args.orbit - 1} (recordings: {res.recordings}) → "
              f"{', '.join(map(str, paths))}")
    return 0
