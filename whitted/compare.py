"""``whitted compare SCENE.toml``: our render against Mitsuba's, as an HTML report.

    whitted compare SCENE.toml [--view N|NAME|all] [--shading classic|physical]
                               [--out DIR] [--golden | --live] [--force]

Mitsuba's image comes from the stored golden (``--golden``, the default; exact mode) or is
rendered now through the reference harness (``--live``, needs Mitsuba). The report folder
(default ``out/compare/<scene>_<shading>``) is never replaced unless ``--force`` is given.
Prints the effect set, the metrics table and the report's path.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from evaluation.report import ReportEntry, format_metrics_table, write_report
from reference import golden
from reference.mitsuba_scene import render_mitsuba
from renderer.render import Renderer
from renderer.stats import format_operations, kernel_operations

from .options import CliError, add_scene_options, effects_for_cli, load_for_cli


def register(subparsers) -> None:
    """Add the ``compare`` subcommand to the main CLI's subparsers."""
    p = subparsers.add_parser(
        "compare", help="render ours and compare with Mitsuba 3 → HTML side-by-side report",
        description=__doc__.split("\n")[0])
    add_scene_options(p)
    p.add_argument("--out", type=Path,
                   help="report folder (default out/compare/<scene>_<shading>)")
    source = p.add_mutually_exclusive_group()
    source.add_argument("--golden", dest="source", action="store_const", const="golden",
                        help="take Mitsuba's image from the stored golden (default)")
    source.add_argument("--live", dest="source", action="store_const", const="live",
                        help="render Mitsuba's image now with the reference harness")
    p.add_argument("--force", action="store_true", help="replace an existing report folder")
    p.add_argument("--study", type=Path, action="append",
                   help="accuracy-vs-time study folder (whitted study --out, e.g. "
                        "results/study/cpu) to carry as the report's 'Accuracy vs time' page "
                        "(repeatable)")
    p.set_defaults(source="golden", func=cmd_compare)


# ---- Mitsuba's side ------------------------------------------------------------------------------
def mitsuba_live(scene, view: int) -> tuple[np.ndarray, float, dict]:
    """Render ``scene.cameras[view]`` with the reference harness now.

    Returns (float32 (H, W, 3) linear RGB, seconds, info rows)."""
    s = scene.settings
    mode = "exact" if s.exact else "converged"
    t0 = time.perf_counter()
    img = render_mitsuba(scene, view=view, mode=mode, spp=1 if s.exact else s.spp, seed=s.seed)
    seconds = time.perf_counter() - t0
    return np.asarray(img, np.float32), seconds, {"Mitsuba image": f"rendered live ({mode})"}


def mitsuba_golden(scene, view: int) -> tuple[np.ndarray, float | None, dict]:
    """Mitsuba's stored exact-mode golden of ``scene.cameras[view]`` in the scene's shading
    mode (``reference.golden.load_golden``).

    Returns (float32 (H, W, 3) linear RGB, render seconds if the sidecar records them else
    None, info rows). A missing or stale golden ends the command with the golden module's
    message, which names the command that regenerates it."""
    try:
        g = golden.load_golden(scene, view=view, shading=scene.settings.shading, mode="exact")
    except golden.GoldenError as e:
        raise CliError(f"{e} (or use --live)") from e
    meta = g.meta
    made = ", ".join(str(meta[k]) for k in ("mitsuba_version", "variant", "date") if k in meta)
    return (np.asarray(g.image, np.float32), meta.get("seconds"),
            {"Mitsuba image": f"golden {g.path}" + (f" ({made})" if made else "")})


# ---- the command ---------------------------------------------------------------------------------
def _default_out(scene) -> Path:
    return Path("out") / "compare" / f"{scene.name}_{scene.settings.shading}"


def cmd_compare(args: argparse.Namespace) -> int:
    scene, views = load_for_cli(args)
    s = scene.settings
    if args.source == "golden" and not s.exact:
        raise CliError("goldens are exact-mode images (1 ray per pixel centre); "
                       "use --live to compare a converged (--spp) render")
    out = args.out or _default_out(scene)
    if out.exists() and any(out.iterdir()) and not args.force:
        raise CliError(f"report folder {out} exists; pass --force to replace it")

    effects = effects_for_cli(scene, args)
    print(f"{scene.name}: {scene.face_count} triangles, {len(scene.lights)} lights, "
          f"shading {s.shading}, {'exact' if s.exact else f'{s.spp} spp'}")
    print(f"effects: {effects}")

    # one upload / accelerator build for every view
    renderer = Renderer(scene, backend=args.backend, precision=args.precision,
                        accel=args.accel, intersection=args.intersection, effects=effects)
    mitsuba_image = mitsuba_golden if args.source == "golden" else mitsuba_live
    entries = []
    for v in views:
        cam = scene.cameras[v]
        ks = kernel_operations(lambda v=v: renderer.render(v))
        res = ks["result"]
        ref, ref_seconds, ref_info = mitsuba_image(scene, v)
        if ref.shape != res.image.shape:
            raise CliError(f"view {cam.name!r}: Mitsuba's image is {ref.shape[1]}x"
                           f"{ref.shape[0]}, ours {cam.width}x{cam.height}")
        info = {
            "ours: kernel time": f"{ks['kernel_ms']:.2f} ms (sum of kernel execution "
                                 "times; the wall time above includes tracing and compilation)",
            "settings": f"{s.shading}, max_depth {s.max_depth}, min_weight {s.min_weight:g}, "
                        f"{'exact, 1 ray per pixel centre' if s.exact else f'{s.spp} spp'}",
            "ours: backend": f"{res.stats.get('backend', args.backend)}, {args.precision}, "
                             f"accel {args.accel}",
            **ref_info,
        }
        entries.append(ReportEntry(
            name=f"{scene.name} / {cam.name} ({s.shading})", ours=res.image, ref=ref,
            ours_seconds=res.seconds, ref_seconds=ref_seconds, effects=str(effects),
            operations=format_operations(ks), info=info))

    index = write_report(out, entries, title=f"{scene.name}: ours vs Mitsuba 3 ({s.shading})",
                         overwrite=args.force, studies=getattr(args, "study", None) or ())
    print(format_metrics_table(entries))
    print(f"report: {index}")
    return 0
