"""``whitted render SCENE.toml``: render with the Dr.Jit tracer → EXR + sRGB PNG per view, or
with ``--orbit N`` an animated GIF (and MP4 when imageio has ffmpeg) per view.

``--out`` is a folder (default ``out/``; files ``<scene>_<view>.exr`` and ``.png``), or, for
one view, a file: ``--out image.exr`` writes only that EXR, ``--out image.png`` only that
PNG, ``--out clip.gif`` (with ``--orbit``) only that GIF. Every output is checked before
rendering (``renderer.outputs``: the folder can be made and written, no file there unless
``--overwrite``) and written atomically. Large renders run in bands with a progress bar.
"""
from __future__ import annotations

import argparse
import sys
import threading
import time
from functools import partial
from pathlib import Path

from renderer.device import start_backend
from renderer.film import write_exr, write_png
from renderer.orbit import PLAYBACK_FPS, mp4_available, render_orbit, write_gif, write_mp4
from renderer.outputs import check_output_file
from renderer.render import Renderer
from renderer.stats import format_operations

from .options import (
    CliError,
    add_scene_options,
    cache_for_cli,
    effects_for_cli,
    load_for_cli,
)
from .progress import build_bar, render_view

#: ``--out`` suffixes that name one output file, and what writes them.
FILE_SUFFIXES = {".exr": "EXR image", ".png": "sRGB PNG image", ".gif": "orbit GIF"}
#: Image suffixes that are not written (``--out x.jpg`` is refused, not made a folder).
OTHER_IMAGE_SUFFIXES = (".jpg", ".jpeg", ".tif", ".tiff", ".hdr", ".bmp", ".webp", ".mp4")


def register(subparsers) -> None:
    """Add the ``render`` subcommand to the main CLI's subparsers."""
    p = subparsers.add_parser("render",
                              help="render a scene with the Dr.Jit tracer (EXR + sRGB PNG)")
    add_scene_options(p)
    p.add_argument("--out", default="out",
                   help="output folder (default out/), or for one view a .exr or .png file "
                        "(a .gif file with --orbit)")
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
    """Before rendering: every output path can be written (``outputs.check_output_file``:
    its folder made and writable, no file there unless ``overwrite``). Raises
    ``OutputError`` (``whitted.cli.main`` prints it and returns 4)."""
    for path in paths:
        check_output_file(path, overwrite=overwrite, flag="--overwrite")


def output_files(scene, views: list[int], out: Path, orbit: bool) -> list[dict]:
    """Per view, the files ``--out`` asks for: ``{"exr": path, "png": path}`` (or
    ``{"gif": ..., "mp4": ...}`` for an orbit), only the named one when ``--out`` is a
    file. Raises ``CliError`` (usage) for a file ``--out`` with several views or the wrong
    kind of file."""
    suffix = out.suffix.lower()
    if suffix in OTHER_IMAGE_SUFFIXES:
        raise CliError(f"--out {out}: {suffix} files are not written; name a folder, or a "
                       f"{', '.join(FILE_SUFFIXES)} file")
    if suffix not in FILE_SUFFIXES:
        names = [f"{scene.name}_{scene.cameras[v].name}" for v in views]
        if orbit:
            mp4 = mp4_available()
            return [{"gif": out / f"{n}_orbit.gif",
                     **({"mp4": out / f"{n}_orbit.mp4"} if mp4 else {})} for n in names]
        return [{"exr": out / f"{n}.exr", "png": out / f"{n}.png"} for n in names]
    if (suffix == ".gif") != bool(orbit):
        raise CliError(f"--out {out}: " + ("an orbit is written as a .gif file or into a "
                                           "folder" if orbit else ".gif is written only with "
                                           "--orbit"))
    if len(views) != 1:
        raise CliError(f"--out {out} names one file but {len(views)} views are selected; "
                       "name a folder, or pick one view with --view")
    return [{suffix[1:]: out}]


def write_all(writes: list) -> None:
    """Write a view's files: ``writes`` is a list of ``(path, write)`` (``write`` a
    callable), the first ones run on threads beside the last (the EXR's compression and the
    PNG's run in C without the GIL, so two files take about as long as the slower one).
    When any fails, the files the others created (paths that were not there before) are
    removed, so a failed render leaves none of its new files (each write is atomic: a
    failed one leaves nothing), and the first error is raised once all have ended."""
    errors, made = [], []
    existed = {Path(p): Path(p).exists() for p, _ in writes}

    def run(path, write):
        try:
            write()
            made.append(Path(path))
        except BaseException as e:       # re-raised in the calling thread
            errors.append(e)

    threads = [threading.Thread(target=run, args=w) for w in writes[:-1]]
    for th in threads:
        th.start()
    if writes:
        run(*writes[-1])
    for th in threads:
        th.join()
    if errors:
        for path in made:
            if not existed[path]:
                path.unlink(missing_ok=True)
        raise errors[0]


def cmd_render(args: argparse.Namespace) -> int:
    from . import STARTED
    t_imports = time.perf_counter() - STARTED
    start_backend(args.backend)          # overlaps the device's start with the scene load
    t_load = time.perf_counter()
    scene, views = load_for_cli(args)
    t_load = time.perf_counter() - t_load
    effects = effects_for_cli(scene, args)
    files = output_files(scene, views, Path(args.out), bool(args.orbit))
    refuse_existing((p for f in files for p in f.values()), args.overwrite)
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
    if args.orbit:
        return render_orbit_views(scene, views, effects, args, files)
    # one upload / accelerator build for every view
    with build_bar(scene) as step:
        renderer = Renderer(scene, backend=args.backend, precision=args.precision,
                            accel=args.accel, intersection=args.intersection,
                            effects=effects, build=args.build, cache=cache_for_cli(args),
                            frames=len(views), build_progress=step)
    info = renderer.arrays.accel.stats()
    if "tree_build" in info:
        print(f"bvh: {info['tree_build']} tree of {scene.face_count} triangles "
              f"{'read from the cache' if info['tree_cached'] else 'built'}"
              f"{' with its uploaded layout' if info.get('layout_cached') else ''} in "
              f"{info['tree_seconds']:.2f} s")
    first = None
    for v, f in zip(views, files):
        cam = scene.cameras[v]
        ks = render_view(renderer, v, f"{scene.name}/{cam.name}")
        res = ks["result"]
        writes = []
        if "exr" in f:
            # the metadata's scene key comes from the golden store's code: imported only
            # when an EXR is written, so a PNG render does not pay for the gate's imports
            from evaluation.gate.imagemeta import ours_metadata
            meta = ours_metadata(scene, v, backend=renderer.t.backend,
                                 precision=renderer.t.precision)
            writes.append((f["exr"], partial(write_exr, f["exr"], res.image,
                                             overwrite=args.overwrite, metadata=meta)))
        if "png" in f:
            writes.append((f["png"], partial(write_png, f["png"], res.image,
                                             overwrite=args.overwrite)))
        write_all(writes)
        bands = res.stats.get("bands", 1)
        print(f"  view {cam.name}: {cam.width}x{cam.height}, {res.seconds * 1e3:.1f} ms"
              f"{f' in {bands} bands' if bands > 1 else ''} → "
              f"{', '.join(map(str, f.values()))}")
        if "operations" in ks:
            print(f"    kernels: {format_operations(ks)}, {ks['kernel_ms']:.2f} ms kernel time")
        first = first if first is not None else time.perf_counter() - STARTED
    tree = float(info.get("tree_seconds", 0.0))
    print(f"timing: imports {t_imports:.2f} s, load {t_load:.2f} s, tree {tree:.2f} s, "
          f"upload {renderer.upload_seconds - tree:.2f} s, first image at {first:.2f} s "
          "since the command's imports began")
    return 0


def render_orbit_views(scene, views, effects, args: argparse.Namespace, files) -> int:
    """``render --orbit N``: per view, N frames on a circle around its target from one frozen
    frame function (renderer/orbit.py) → an animated GIF (and MP4 when imageio has ffmpeg)."""
    for v, f in zip(views, files):
        cam = scene.cameras[v]
        sc = scene if args.build is None else scene.with_settings(build=args.build)
        res = render_orbit(sc, args.orbit, view=v, backend=args.backend,
                           precision=args.precision, accel=args.accel,
                           intersection=args.intersection, effects=effects)
        write_gif(f["gif"], res.frames, fps=PLAYBACK_FPS, overwrite=args.overwrite)
        if "mp4" in f:
            write_mp4(f["mp4"], res.frames, fps=PLAYBACK_FPS, overwrite=args.overwrite)
        print(f"  view {cam.name}: orbit of {args.orbit} frames at {cam.width}x{cam.height}: "
              f"first (traced) frame {res.first_frame_ms:.1f} ms, frozen frames median "
              f"{res.frozen_frame_ms_median:.2f} ms, {res.fps:.1f} frames/s over frames "
              f"1..{args.orbit - 1} (recordings: {res.recordings}) → "
              f"{', '.join(map(str, f.values()))}")
    return 0
