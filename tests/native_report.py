"""Ours against native Mitsuba 3 on one scene at a chosen size, per spawn rule, with the
float64 oracle as the judge on sampled pixels.

Usage: ``python tests/native_report.py [--scene glass_bunny] [--size 256]
[--shading classic,physical] [--pixels 200] [--seed 0]``

For each shading mode: Mitsuba's exact-mode render with its own ``spawn_ray`` /
``spawn_ray_to`` (``reference.mitsuba_scene.render_mitsuba``, the goldens' set-up, Embree in
its default mode; and in its robust mode, ``reference.robust``) at ``size`` x ``size``, and
ours (LLVM, float32, BVH, default routine) with each spawn rule
(``renderer.scene.SPAWN_RULES``). Printed: the share of pixels within 1e-3 (max over RGB) of
Mitsuba, the same with the exact rule's edge ties set aside
(``evaluation.gate.agreement.edge_mask``), the number of pixels over 1e-3 that are not edge ties;
then, on ``--pixels`` sampled pixels (``oracle.sample_pixels``), the share within 1e-3 of the
float64 oracle (offsets -> 0) of each image, on all of them and on those whose tree touches
glass. (The measurement behind
lab/notes/data/issue10-ray-offsets/glass_bunny_vs_mitsuba_native*.txt.)
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for p in (ROOT, ROOT / "tests"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

import oracle  # noqa: E402

TOL = 1e-3


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="glass_bunny")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--shading", default="classic,physical")
    ap.add_argument("--pixels", type=int, default=200)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    from evaluation.gate.agreement import edge_mask
    from reference import mitsuba_variant
    from reference.mitsuba_scene import render_mitsuba
    from reference.robust import render_exact_mode
    from renderer.render import render
    from renderer.scene import SPAWN_RULES, load_scene
    mitsuba_variant("llvm_ad_rgb")
    for shading in args.shading.split(","):
        path = ROOT / "scenes" / f"{args.scene}.toml"
        scene = load_scene(path, shading=shading).with_size(args.size, args.size)
        t0 = time.perf_counter()
        mit = np.asarray(render_mitsuba(scene, mode="exact", spawn="mitsuba"), np.float64)
        t_mi = time.perf_counter() - t0
        robust = np.asarray(render_exact_mode(scene, robust=True), np.float64)
        images = {"mitsuba": mit}
        for rule in SPAWN_RULES:
            images[f"ours {rule}"] = np.asarray(
                render(scene.with_settings(spawn=rule), backend="llvm").image, np.float64)
        pairs = [(f"ours spawn={rule}", images[f"ours {rule}"], "Mitsuba-native", mit)
                 for rule in SPAWN_RULES]
        pairs += [("ours spawn=mitsuba", images["ours mitsuba"], "Mitsuba-native robust "
                   "Embree", robust), ("Mitsuba-native", mit, "Mitsuba-native robust Embree",
                                       robust)]
        for la, a, lb, b in pairs:
            over = ~(np.abs(a - b).max(-1) <= TOL)
            edge = over & edge_mask(a, b, TOL)
            print(f"{args.scene} {shading} {args.size}²: {la} vs {lb} "
                  f"within 1e-3: {1 - over.mean():.4f}; edges aside "
                  f"{1 - (over & ~edge).sum() / max(1, (~edge).sum()):.4f}; "
                  f"{int(over.sum())} px over 1e-3 ({int((over & ~edge).sum())} not edge "
                  f"ties)", flush=True)
        osc = oracle.load(path, shading).with_size(args.size, args.size)
        pix = oracle.sample_pixels(osc, 0, args.pixels, args.seed)
        ref, info = oracle.render_pixels(osc, 0, pix, with_info=True)
        g = info["glass"]
        x, y = pix[:, 0], pix[:, 1]
        parts = []
        for label, img in images.items():
            e = np.abs(img[y, x] - ref).max(1)
            e = np.where(np.isfinite(e), e, np.inf)
            parts.append(f"{label} {np.mean(e <= TOL):.3f} (glass "
                         f"{np.mean(e[g] <= TOL) if g.any() else float('nan'):.3f})")
        print(f"  oracle ({len(pix)} px, {int(g.sum())} glass): within 1e-3 "
              + "; ".join(parts) + f"; mitsuba {t_mi:.0f}s", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
