"""``whitted bench``: the timing study (evaluation/bench/), ours vs Mitsuba, one call."""
from __future__ import annotations


def cmd_bench(args) -> int:
    from evaluation.bench import run
    run(args.out, backend=args.backend, scenes_dir=args.scenes, quick=args.quick,
        parts=tuple(args.parts.split(",")))
    return 0


def register(sub) -> None:
    p = sub.add_parser("bench", help="timing study: ray throughput, the thesis's table, "
                                     "Whitted frames and effect savings, vs Mitsuba")
    p.add_argument("--backend", default="auto", choices=("auto", "cuda", "llvm"))
    p.add_argument("--out", default="results", help="folder for bench-<backend>.json/.md")
    p.add_argument("--scenes", default="scenes", help="folder holding the scene files")
    p.add_argument("--quick", action="store_true", help="small sizes (smoke run)")
    p.add_argument("--parts", default="throughput,seed,whitted,effects",
                   help="comma-separated subset of throughput,seed,whitted,effects")
    p.set_defaults(func=cmd_bench)
