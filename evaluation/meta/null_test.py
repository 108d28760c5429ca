"""Null test of the converged rule: how often does it fail a correct renderer?

Two independent converged renders of OURS (16 batches each, batches 0-15 and 16-31 of
``render_batches``, at the golden's size and batch spp) are compared with
``evaluation.gate.rules.check_converged``, exactly as ours is compared with a golden: the same
expectation on both sides, so every failure is a false failure. Also run: ours against the
golden (the real check), for the record.

    python -m evaluation.meta.null_test [--cases SUBSTR ...] [--out out/null_test/null.json]

Writes a JSON record (per case: failed values/pixels and max |t| of the null pair and of
ours vs golden; totals: false-failure rate over cases) atomically, and prints one line per
case. Ctrl-C stops after the current case and writes what was measured.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from evaluation import write_result
from evaluation.gate.rules import (
    CONVERGED_THRESHOLDS,
    OUR_SEED,
    ROOT,
    cases,
    check_converged,
    golden_batches,
    matching,
    render_batches,
)

KEYS = ("failed_values", "failed_pixels", "max_t", "ok")


def main(argv=None) -> int:
    from reference.golden import load_golden
    from renderer.scene import load_scene

    ap = argparse.ArgumentParser(prog="python -m evaluation.meta.null_test",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("--cases", nargs="*", default=[], help="substrings of case names")
    ap.add_argument("--out", default=str(ROOT / "out/null_test/null.json"))
    ap.add_argument("--backend", default="llvm")
    args = ap.parse_args(argv)
    batches = int(CONVERGED_THRESHOLDS["batches"].value)
    todo = [c for c in cases(modes=("converged",))
            if not args.cases or any(s in c.name for s in args.cases)]
    rows = []
    t0 = time.time()
    try:
        for i, c in enumerate(todo):
            scene = load_scene(c.scene, shading=c.shading)
            g = load_golden(scene, view=c.view, shading=c.shading, mode=c.mode)
            scene = matching(scene, g)
            spp = int(g.meta["batch_spp"])
            a = render_batches(scene, c.view, batches=batches, spp=spp, seed=OUR_SEED,
                               backend=args.backend)
            b = render_batches(scene, c.view, batches=batches, spp=spp, seed=OUR_SEED,
                               first_batch=batches, backend=args.backend)
            null = check_converged(a, b, CONVERGED_THRESHOLDS)
            real = check_converged(a, golden_batches(g), CONVERGED_THRESHOLDS)
            row = {"case": c.name, "null": {k: null[k] for k in KEYS},
                   "golden": {k: real[k] for k in KEYS}, "null_failed": null["failed"][:10],
                   "golden_failed": real["failed"][:10]}
            rows.append(row)
            print(f"[{i + 1}/{len(todo)} {time.time() - t0:.0f}s] {c.name}: null "
                  f"{row['null']} | golden {row['golden']}", flush=True)
    except KeyboardInterrupt:
        print("interrupted: writing the cases measured so far", file=sys.stderr)
    n = len(rows)
    summary = {
        "cases": n, "batches_per_side": batches,
        "alpha": CONVERGED_THRESHOLDS["alpha"].value,
        "null_failed_cases": sum(not r["null"]["ok"] for r in rows),
        "null_false_failure_rate": (sum(not r["null"]["ok"] for r in rows) / n) if n else None,
        "golden_failed_cases": sum(not r["golden"]["ok"] for r in rows),
        "seconds": round(time.time() - t0, 1),
    }
    write_result(Path(args.out), json.dumps({"summary": summary, "cases": rows}, indent=1)
                  + "\n")
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
