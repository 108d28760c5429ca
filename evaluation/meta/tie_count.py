"""How many pixels the exact rule excuses, per golden case: under the image-space
neighbourhood rule (a 3x3 neighbourhood range +- 0.02 plus a 0.5 % pixel budget,
``old_edge_rule``) and under the tie probe (``evaluation.gate.rules.tie_probe``, no
neighbourhood, no budget), the rule the gate uses.

    python -m evaluation.meta.tie_count [--cases SUBSTR ...] [--out out/rules/exact_ties.json]
                                        [--slack F] [--ray-epsilon E]

``--slack`` tries another tie-probe distance (fraction of the diagonal); ``--ray-epsilon``
renders ours with another ray offset than the golden's, to see what a mismatch of offset
models between the renderers does (a mismatch of offsets is a model difference: its
pixels are no ties, and the rule does not excuse them).

Per case: pixels off by more than max_rel, excused by the neighbourhood rule / the tie
probe, hard under the tie probe, the size of the
tie mask (where a bug could hide now), and the worst relative error of the pixels held.
Writes JSON and a markdown table beside it (atomically); prints the table.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from evaluation import write_result
from evaluation.gate.rules import EXACT_THRESHOLDS, ROOT, cases, check_exact, matching, tie_probe


def old_edge_rule(ours: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """The excused ("edge") pixels of the image-space neighbourhood rule: a pixel off by more than
    max_rel whose golden value lies within our 3x3 neighbourhood's range +- 0.02 (relative
    and absolute), or ours within the golden's."""
    def rng(img):
        p = np.pad(img, ((1, 1), (1, 1), (0, 0)), mode="edge")
        h, w = img.shape[:2]
        st = np.stack([p[dy:dy + h, dx:dx + w] for dy in range(3) for dx in range(3)])
        return st.min(0), st.max(0)
    ours, ref = np.asarray(ours, np.float64), np.asarray(ref, np.float64)
    rel = (np.abs(ours - ref) / np.maximum(np.abs(ref), 1e-2)).max(-1)
    tol = 2e-2 * np.maximum(np.abs(ref), 1.0)
    lo, hi = rng(ours)
    ok = np.all((ref >= lo - tol) & (ref <= hi + tol), axis=-1)
    lo, hi = rng(ref)
    ok |= np.all((ours >= lo - tol) & (ours <= hi + tol), axis=-1)
    return (rel > 5e-3) & ok


def main(argv=None) -> int:
    from reference.golden import load_golden
    from renderer.scene import load_scene

    ap = argparse.ArgumentParser(prog="python -m evaluation.meta.tie_count",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="*", default=[])
    ap.add_argument("--out", default=str(ROOT / "out/rules/exact_ties.json"))
    ap.add_argument("--backend", default="llvm")
    ap.add_argument("--slack", type=float, default=EXACT_THRESHOLDS["tie_slack"].value)
    ap.add_argument("--ray-epsilon", type=float, default=None)
    args = ap.parse_args(argv)
    rows = []
    for c in cases(modes=("exact",)):
        if args.cases and not any(s in c.name for s in args.cases):
            continue
        scene = load_scene(c.scene, shading=c.shading)
        g = load_golden(scene, view=c.view, shading=c.shading, mode=c.mode)
        scene = matching(scene, g)
        if args.ray_epsilon is not None:
            scene = scene.with_settings(ray_epsilon=args.ray_epsilon)
        ours, ties = tie_probe(scene, c.view, backend=args.backend, slack=args.slack)
        res = check_exact(ours, g.image, EXACT_THRESHOLDS, ties)
        off = int(res["excused_pixels"] + res["hard_pixels"])
        rows.append({"case": c.name, "pixels": res["pixels"], "off": off,
                     "excused_before": int(old_edge_rule(ours, g.image).sum()),
                     "excused_now": res["excused_pixels"], "hard_now": res["hard_pixels"],
                     "tie_mask": res["tie_pixels"], "max_rel_held": res["max_rel_held"],
                     "ok": res["ok"]})
        print(rows[-1], flush=True)
    head = ("| case | pixels | off > max_rel | excused before | excused now | hard now | "
            "tie mask | max rel held | ok |\n|---|--:|--:|--:|--:|--:|--:|--:|---|\n")
    md = head + "".join(
        f"| {r['case']} | {r['pixels']} | {r['off']} | {r['excused_before']} | "
        f"{r['excused_now']} | {r['hard_now']} | {r['tie_mask']} | {r['max_rel_held']:.1e} | "
        f"{'pass' if r['ok'] else 'FAIL'} |\n" for r in rows)
    out = Path(args.out)
    write_result(out, json.dumps({"tie_slack": args.slack, "ray_epsilon": args.ray_epsilon,
                                   "cases": rows}, indent=1) + "\n")
    write_result(out.with_suffix(".md"), md)
    print(md)
    return 0 if all(r["ok"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
