"""``whitted compare SCENE.toml``: our render against Mitsuba's: a verdict per view and an
HTML report.

    whitted compare SCENE.toml [--view N|NAME|all] [--shading classic|physical]
                               [--out DIR] [--golden | --live] [--goldens DIR] [--force]

Mitsuba's image comes from the stored golden (``--golden``, the default; exact mode; looked
up by content in ``--goldens DIR`` or the configured store, then the bundled one) or is
rendered now through the reference harness (``--live``, needs Mitsuba). Each view gets the
verdict of ``whitted check`` (the exact rule with the scene's thresholds: our image and its
tie mask from a second render with ``tie_break="other"``, ``evaluation.gate.rules.tie_probe``) and
the command
exits with its code (0 pass, 1 warn, 2 fail, 3 size mismatch, 4 missing or stale golden); a
converged ``--live`` render has no variance to test against and gets no verdict. The report
folder (default ``out/compare/<scene>_<shading>``) is never replaced unless ``--force`` is
given. Prints the effect set, the verdicts, the metrics table and the report's path.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from evaluation.gate import verdict as vd
from evaluation.gate.report import ReportEntry, format_metrics_table, write_report
from reference import golden
from reference.mitsuba_scene import render_mitsuba
from renderer.outputs import check_output_dir
from renderer.render import Renderer
from renderer.stats import format_operations

from .options import (
    EXIT,
    CliError,
    add_scene_options,
    cache_for_cli,
    effects_for_cli,
    load_for_cli,
)
from .progress import render_view


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
    p.add_argument("--goldens", type=Path, metavar="DIR",
                   help="golden store searched before the bundled one (default "
                        "$WHITTED_GOLDENS or [tool.whitted] goldens in pyproject.toml)")
    p.add_argument("--force", action="store_true", help="replace an existing report folder")
    p.add_argument("--study", type=Path, action="append",
                   help="accuracy-vs-time study folder (whitted study --out) to carry as the "
                        "report's 'Accuracy vs time' page "
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


def mitsuba_golden(scene, view: int, stores=None) -> tuple[np.ndarray, float | None, dict]:
    """Mitsuba's stored exact-mode golden of ``scene.cameras[view]`` in the scene's shading
    mode, looked up by content in ``stores`` (default: the bundled store).

    Returns (float32 (H, W, 3) linear RGB, render seconds if the sidecar records them else
    None, info rows). Raises ``reference.golden.GoldenError`` for a missing or stale golden,
    with the message that names the command that renders it."""
    g = golden.load_golden(scene, view=view, shading=scene.settings.shading, mode="exact",
                           stores=stores)
    meta = g.meta
    made = ", ".join(str(meta[k]) for k in ("mitsuba_version", "variant", "date") if k in meta)
    return (np.asarray(g.image, np.float32), meta.get("seconds"),
            {"Mitsuba image": f"golden {golden._display(g.path)}"
             + (f" ({made})" if made else "")})


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
    if out.exists() and out.is_dir() and any(out.iterdir()) and not args.force:
        raise CliError(f"report folder {out} exists; pass --force to replace it",
                       code=EXIT["file"])
    check_output_dir(out)
    for d in getattr(args, "study", None) or ():
        if not (Path(d) / "index.html").is_file():
            raise CliError(f"--study {d}: not a study folder (no index.html; `whitted study "
                           "--out DIR` makes one)", code=EXIT["file"])

    effects = effects_for_cli(scene, args)
    # ours spawns secondary and shadow rays as the reference does (the harness's goldens and
    # a --live render both use Mitsuba's own spawn_ray), so both trace the same rays
    scene = scene.with_settings(spawn=golden.GOLDEN_SPAWN, ray_epsilon=None)
    print(f"{scene.name}: {scene.face_count} triangles, {len(scene.lights)} lights, "
          f"shading {s.shading}, {'exact' if s.exact else f'{s.spp} spp'}; ours spawns "
          f"rays as the reference does (spawn = {golden.GOLDEN_SPAWN!r})")
    print(f"effects: {effects}")

    # one upload / accelerator build for every view
    cache = cache_for_cli(args)
    renderer = Renderer(scene, backend=args.backend, precision=args.precision,
                        accel=args.accel, intersection=args.intersection, effects=effects,
                        build=args.build, cache=cache, frames=len(views))
    stores = golden.search_stores(args.goldens)
    th = vd.thresholds_for(scene, "exact")
    # the tie probe (exact mode): the same scene with the other tie-break, for the tie mask
    d = float(th["tie_slack"].value) * scene.diagonal
    probe = Renderer(scene, backend=args.backend, precision=args.precision,
                     accel=args.accel, intersection=args.intersection, effects=effects,
                     tie_break="other", tie_window=d, tie_slack=d, build=args.build,
                     cache=cache, frames=len(views)) if s.exact else None
    entries, verdicts = [], []
    for v in views:
        cam = scene.cameras[v]
        verdict = vd.Verdict(scene.name, str(args.scene), v, cam.name, s.shading,
                             "exact" if s.exact else "converged", "ERROR", "")
        verdicts.append(verdict)
        if args.source == "golden":
            try:
                ref, ref_seconds, ref_info = mitsuba_golden(scene, v, stores)
            except golden.GoldenError as e:
                found = golden.find_golden(scene, view=v, shading=s.shading, mode="exact",
                                           stores=stores)
                verdict.status = found.status.upper() if found.status != "ok" else "ERROR"
                verdict.reason = f"{e} (or use --live)"
                print(vd.format_line(verdict))
                continue
        else:
            ref, ref_seconds, ref_info = mitsuba_live(scene, v)
        ks = render_view(renderer, v, f"{scene.name}/{cam.name}")
        res = ks["result"]
        if ref.shape != res.image.shape:
            verdict.status = "SIZE"
            verdict.reason = (f"Mitsuba's image is {ref.shape[1]}x{ref.shape[0]}, ours "
                              f"{cam.width}x{cam.height}")
            print(vd.format_line(verdict))
            continue
        if s.exact:
            other = render_view(probe, v, f"{scene.name}/{cam.name} (tie probe)")["result"]
            ties = np.any(other.image != res.image, axis=-1)
            (verdict.status, verdict.reason, verdict.excused,
             verdict.result) = vd.judge(res.image, golden.Golden(ref, None, {}, Path()),
                                        "exact", th, scene.check.get("warn"), scene, ties)
            print(vd.format_line(verdict))
        else:
            verdicts.remove(verdict)
            print(f"{scene.name}/{cam.name}: no verdict (a converged --live render has no "
                  "variance to test against; use `whitted check --modes converged`)")
        info = {
            "ours: kernel time": "not recorded (banded render)" if "kernel_ms" not in ks
            else f"{ks['kernel_ms']:.2f} ms (sum of kernel execution "
                                 "times; the wall time above includes tracing and compilation)",
            "settings": f"{s.shading}, max_depth {s.max_depth}, min_weight {s.min_weight:g}, "
                        f"{'exact, 1 ray per pixel centre' if s.exact else f'{s.spp} spp'}",
            "ours: backend": f"{res.stats.get('backend', args.backend)}, {args.precision}, "
                             f"accel {res.stats.get('accel', args.accel)}",
            **ref_info,
        }
        entries.append(ReportEntry(
            name=f"{scene.name} / {cam.name} ({s.shading})", ours=res.image, ref=ref,
            ours_seconds=res.seconds, ref_seconds=ref_seconds, effects=str(effects),
            operations=format_operations(ks) if "operations" in ks else "", info=info,
            verdict=verdict.status if s.exact else None, verdict_reason=verdict.reason,
            thresholds={k: (t.value, t.why) for k, t in th.items()} if s.exact else {}))

    notes = [(x.status, x.name, x.reason) for x in verdicts
             if x.status in ("MISSING", "STALE", "ERROR", "SIZE")]
    entries.sort(key=lambda e: -vd.EXIT_CODES.get(e.verdict or "PASS", 0))
    index = write_report(out, entries, title=f"{scene.name}: ours vs Mitsuba 3 ({s.shading})",
                         overwrite=args.force, notes=notes,
                         studies=getattr(args, "study", None) or ())
    if entries:
        print(format_metrics_table(entries))
    print(f"report: {index}")
    if verdicts:
        print(vd.summary_line(verdicts))
    return vd.exit_code(verdicts) if verdicts else 0
