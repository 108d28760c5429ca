"""The Mitsuba reference on CUDA against itself on LLVM, for each way of spawning rays.

Usage (one GPU job, about a minute):
``python -m evaluation.meta.speckles --out DIR [--size 256] [--scenes platonic_solids,glass_bunny]
[--variants cuda_ad_rgb,llvm_ad_rgb] [--shading classic]``

Mitsuba's CUDA renders can show speckles inside glass that the LLVM goldens lack. This
renders every view of each scene with the reference harness
(``reference.mitsuba_scene.render_mitsuba``, exact mode) on both variants, once with the
fixed offset rule (``spawn="fixed"``: an absolute 1e-4 x diagonal
along N_g) and once with Mitsuba's own ``si.spawn_ray`` / ``si.spawn_ray_to``
(``spawn="mitsuba"``), and counts the pixels where CUDA and LLVM differ by more than 1e-2
(max over RGB, absolute). The rule whose count drops to the level of the diffuse scenes (a
few edge pixels) is the one that fixes it.

Writes ``DIR/speckles.json`` and ``DIR/speckles.md`` (a row per scene x view x spawn) and
``DIR/<scene>-<view>-<spawn>.png`` (CUDA | LLVM | pixels over 1e-2 in white).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

TOL = 1e-2
SPAWNS = ("fixed", "mitsuba")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, required=True, help="output folder (created)")
    ap.add_argument("--size", type=int, default=256, help="image height (default 256)")
    ap.add_argument("--scenes", default="platonic_solids,glass_bunny")
    ap.add_argument("--variants", default="cuda_ad_rgb,llvm_ad_rgb",
                    help="the two Mitsuba variants compared (first against second)")
    ap.add_argument("--shading", default="classic", choices=("classic", "physical"))
    args = ap.parse_args(argv)

    from reference import mitsuba_variant
    from reference.mitsuba_scene import render_mitsuba
    from renderer.film import write_png
    from renderer.scene import load_scene

    variants = args.variants.split(",")
    if len(variants) != 2:
        ap.error("--variants: give exactly two, e.g. cuda_ad_rgb,llvm_ad_rgb")
    args.out.mkdir(parents=True, exist_ok=True)
    jobs = []
    for name in args.scenes.split(","):
        scene = load_scene(Path("scenes") / f"{name}.toml", shading=args.shading)
        cam = scene.cameras[0]
        scene = scene.with_size(max(1, round(args.size * cam.width / cam.height)), args.size)
        for v in range(len(scene.cameras)):
            for spawn in SPAWNS:
                jobs.append((name, scene, v, spawn))
    images: dict = {}
    t0 = time.perf_counter()
    for variant in variants:                 # one variant at a time: set it once
        mitsuba_variant(variant)
        for k, (name, scene, v, spawn) in enumerate(jobs):
            images[(variant, name, v, spawn)] = render_mitsuba(scene, view=v, mode="exact",
                                                               spawn=spawn)
            print(f"[{variant}] {k + 1}/{len(jobs)} {name} view {v} spawn={spawn} "
                  f"({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)
    rows = []
    a_var, b_var = variants
    for name, scene, v, spawn in jobs:
        a, b = images[(a_var, name, v, spawn)], images[(b_var, name, v, spawn)]
        err = np.abs(a.astype(np.float64) - b).max(-1)
        err = np.where(np.isfinite(err), err, np.inf)
        over = err > TOL
        view = scene.cameras[v].name
        rows.append(dict(scene=name, view=view, spawn=spawn, pixels=int(err.size),
                         over=int(over.sum()), max_abs=float(err.max())))
        mask = np.repeat(over[..., None].astype(np.float32), 3, -1)
        write_png(args.out / f"{name}-{view}-{spawn}.png",
                  np.concatenate([a, b, mask], 1), overwrite=True)
    lines = [f"# Mitsuba {a_var} against {b_var} (exact mode, {args.size} rows, "
             f"{args.shading}): pixels differing by > {TOL:g}", "",
             "| scene | view | spawn | pixels > 1e-2 | share | max abs |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['view']} | {r['spawn']} | {r['over']} "
                     f"| {100 * r['over'] / r['pixels']:.3f} % | {r['max_abs']:.3g} |")
    lines.append(f"\n{time.perf_counter() - t0:.0f} s")
    text = "\n".join(lines) + "\n"
    print(text)
    for fname, body in (("speckles.md", text), ("speckles.json", json.dumps(rows, indent=1))):
        tmp = args.out / (fname + ".tmp")
        tmp.write_text(body)
        tmp.replace(args.out / fname)
    return 0


if __name__ == "__main__":
    sys.exit(main())
