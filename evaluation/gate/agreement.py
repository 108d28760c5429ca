"""Pixel agreement of our exact-mode renders with a set of Mitsuba goldens, per case.

Usage: ``python -m evaluation.gate.agreement [--goldens DIR] [--scenes a,b] [--json PATH]
[--ray-epsilon E] [--spawn RULE]``

For every exact-mode regression case (``evaluation.gate.rules.cases``) it renders ours on LLVM
(float32, the BVH) at the golden's size with the golden's spawn rule (``rules.matching``)
and prints: the fraction of pixels within 1e-3 (max over RGB, absolute) of the golden; the
same fraction with the tie-probe pixels set aside (``rules.tie_probe``: the pixels whose
value depends on how a geometric tie is broken, found by tracing); the size of the tie
mask; the exact rule's excused and hard pixel counts and its verdict. The goal is
>= 99.5 % on every bundled scene in the second column.

``--goldens`` reads another golden folder (e.g. the goldens of an older commit, extracted
with ``git archive``), ``--ray-epsilon`` renders ours with that explicit offset override,
``--spawn`` with that offset rule instead of the golden's (``renderer.scene.SPAWN_RULES``;
"scale-free" shows what our default rule does against Mitsuba's).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from evaluation.gate.rules import GOLDEN_SCENES, cases, matching, tie_probe
from reference.golden import GOLDEN_DIR, load_golden
from renderer.scene import SPAWN_RULES, load_scene

TOL = 1e-3
#: Relative (and absolute) widening of a pixel's 3x3 range in ``edge_mask``.
EDGE_TOL = 0.02


def neighbour_range(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Channel-wise min and max over each pixel's 3x3 neighbourhood (edge-clamped)."""
    p = np.pad(img, ((1, 1), (1, 1), (0, 0)), mode="edge")
    h, w = img.shape[:2]
    stack = np.stack([p[dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3)])
    return stack.min(0), stack.max(0)


def edge_mask(a: np.ndarray, b: np.ndarray, tol: float = EDGE_TOL) -> np.ndarray:
    """Pixels whose value one image has one pixel away in the other, (H, W) bool: the
    image-space explanation of ties on shared edges and silhouettes, for comparisons where
    neither side can be traced again (two Mitsuba renders, or a render against a moved copy
    of its scene). The exact rule does not use it: it excuses only what the tie probe
    traces (``rules.tie_probe``)."""
    lo, hi = neighbour_range(a)
    t = tol * np.maximum(np.abs(b), 1.0)
    ex = np.all((b >= lo - t) & (b <= hi + t), axis=-1)
    lo, hi = neighbour_range(b)
    ex |= np.all((a >= lo - t) & (a <= hi + t), axis=-1)
    return ex


def measure(case, goldens: Path, ray_epsilon: float | None = None,
            spawn: str | None = None) -> dict:
    """One case's numbers (see the module docstring)."""
    scene = load_scene(case.scene, shading=case.shading)
    g = load_golden(scene, view=case.view, shading=case.shading, mode="exact", root=goldens)
    scene = matching(scene, g)
    if ray_epsilon is not None:
        scene = scene.with_settings(spawn="scale-free", ray_epsilon=ray_epsilon)
    elif spawn is not None:
        scene = scene.with_settings(spawn=spawn)
    ours, ties = tie_probe(scene, case.view, backend="llvm")
    ours = np.asarray(ours, np.float64)
    ref = np.asarray(g.image, np.float64)
    err = np.abs(ours - ref).max(-1)
    err = np.where(np.isfinite(err), err, np.inf)
    close = err <= TOL
    res = case.check(ours, g, ties)
    return dict(case=case.name, pixels=int(err.size), within=float(close.mean()),
                within_ties_aside=float((close & ~ties).sum() / max(1, (~ties).sum())),
                differ=int((~close).sum()), differ_not_tie=int((~close & ~ties).sum()),
                tie_pixels=int(ties.sum()), rule_excused=res["excused_pixels"],
                rule_hard=res["hard_pixels"], mean_rel=res["mean_rel"], ok=bool(res["ok"]),
                spawn=scene.settings.spawn, ray_epsilon=scene.settings.ray_epsilon)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--goldens", type=Path, default=GOLDEN_DIR)
    ap.add_argument("--scenes", default=None, help="comma-separated scene stems")
    ap.add_argument("--ray-epsilon", type=float, default=None)
    ap.add_argument("--spawn", choices=SPAWN_RULES, default=None)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    scenes = GOLDEN_SCENES if args.scenes is None else tuple(
        f"scenes/{s}.toml" for s in args.scenes.split(","))
    print(f"goldens: {args.goldens}; ray_epsilon: {args.ray_epsilon}; spawn: {args.spawn}")
    print("| case | within 1e-3 | ties aside | differ (not tie) | tie mask | rule excused / "
          "hard | mean_rel | rule |")
    print("|---|---|---|---|---|---|---|---|")
    rows = []
    t0 = time.perf_counter()
    for case in cases(scenes, modes=("exact",)):
        r = measure(case, args.goldens, args.ray_epsilon, args.spawn)
        rows.append(r)
        print(f"| {r['case']} | {100 * r['within']:.2f} % | {100 * r['within_ties_aside']:.2f} % "
              f"| {r['differ']} ({r['differ_not_tie']}) | {r['tie_pixels']} | "
              f"{r['rule_excused']} / {r['rule_hard']} | {r['mean_rel']:.1e} | "
              f"{'pass' if r['ok'] else 'FAIL'} |", flush=True)
    worst = min(r["within_ties_aside"] for r in rows)
    print(f"\nworst ties-aside agreement {100 * worst:.2f} %; {sum(r['ok'] for r in rows)}"
          f"/{len(rows)} cases pass the exact rule; {time.perf_counter() - t0:.0f} s")
    if args.json:
        tmp = args.json.with_suffix(".tmp")
        tmp.write_text(json.dumps(rows, indent=1) + "\n")
        tmp.replace(args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
