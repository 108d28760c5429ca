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


def register(subparsers) -> None:
    """Add the ``compare`` subcommand to the main CLI's subparsers."""
    from whitted.cli import add_scene_options

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
    p.set_defaults(source="golden", func=cmd_compare)


# ───────────────────────────────────────────── our side ──
def render_ours(scene, view: int, args, effects):
    """Render one view with our tracer, recording Dr.Jit's kernel history.

    Returns (RenderResult, {"kernels", "operations", "largest", "kernel_seconds"})."""
    import drjit as dr
    from renderer.render import render

    dr.kernel_history()  # drop older entries
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        res = render(scene, view=view, backend=args.backend, precision=args.precision,
                     accel=args.accel, intersection=args.intersection, effects=effects)
        history = [h for h in dr.kernel_history() if "operation_count" in h]
    ops = [int(h["operation_count"]) for h in history]
    stats = {"kernels": len(ops), "operations": sum(ops), "largest": max(ops, default=0),
             "kernel_seconds": sum(float(h.get("execution_time", 0.0)) for h in history) / 1e3}
    return res, stats


# ───────────────────────────────────────────── Mitsuba's side ──
def mitsuba_live(scene, view: int) -> tuple[np.ndarray, float, dict]:
    """Render ``scene.cameras[view]`` with the reference harness now.

    Returns (float32 (H, W, 3) linear RGB, seconds, info rows)."""
    from reference.mitsuba_scene import render_mitsuba

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
    from reference import golden

    try:
        g = golden.load_golden(scene, view=view, shading=scene.settings.shading, mode="exact")
    except golden.GoldenError as e:
        raise SystemExit(f"error: {e} (or use --live)")
    meta = g.meta
    made = ", ".join(str(meta[k]) for k in ("mitsuba_version", "variant", "date") if k in meta)
    return (np.asarray(g.image, np.float32), meta.get("seconds"),
            {"Mitsuba image": f"golden {g.path}" + (f" ({made})" if made else "")})


# ───────────────────────────────────────────── the command ──
def _default_out(scene) -> Path:
    return Path("out") / "compare" / f"{scene.name}_{scene.settings.shading}"


def cmd_compare(args: argparse.Namespace) -> int:
    from evaluation.report import ReportEntry, format_metrics_table, write_report
    from whitted.cli import effects_for_cli, load_for_cli

    scene, views = load_for_cli(args)
    s = scene.settings
    if args.source == "golden" and not s.exact:
        raise SystemExit("error: goldens are exact-mode images (1 ray per pixel centre); "
                         "use --live to compare a converged (--spp) render")
    out = args.out or _default_out(scene)
    if out.exists() and any(out.iterdir()) and not args.force:
        raise SystemExit(f"error: report folder {out} exists; pass --force to replace it")

    effects = effects_for_cli(scene, args)
    print(f"{scene.name}: {scene.face_count} triangles, {len(scene.lights)} lights, "
          f"shading {s.shading}, {'exact' if s.exact else f'{s.spp} spp'}")
    print(f"effects: {effects}")

    entries = []
    for v in views:
        cam = scene.cameras[v]
        res, ks = render_ours(scene, v, args, effects)
        ref, ref_seconds, ref_info = (mitsuba_golden if args.source == "golden"
                                      else mitsuba_live)(scene, v)
        if ref.shape != res.image.shape:
            raise SystemExit(f"error: view {cam.name!r}: Mitsuba's image is {ref.shape[1]}x"
                             f"{ref.shape[0]}, ours {cam.width}x{cam.height}")
        info = {
            "ours: kernel time": f"{ks['kernel_seconds'] * 1e3:.2f} ms (sum of kernel execution "
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
            operations=f"{ks['operations']:,} IR operations in {ks['kernels']} kernel(s), "
                       f"largest {ks['largest']:,}",
            info=info))

    index = write_report(out, entries, title=f"{scene.name}: ours vs Mitsuba 3 ({s.shading})",
                         overwrite=args.force)
    print(format_metrics_table(entries))
    print(f"report: {index}")
    return 0
