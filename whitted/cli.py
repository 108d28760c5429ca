"""``whitted``: one entry point, one subcommand per job.

    whitted render  SCENE.toml   render with the Dr.Jit tracer → EXR + PNG
    whitted compare SCENE.toml   ours vs Mitsuba's golden → verdict, HTML side-by-side report
    whitted check   SCENE...     regression gate: one verdict per view, idiff exit codes
    whitted reference SCENE...   (re)render Mitsuba golden images
    whitted export  --mitsuba-xml OUT.xml SCENE.toml
    whitted bench   ...          timing study (kernel times, frozen frames, vs Mitsuba)
    whitted study   ...          accuracy-vs-time study (error vs time, Pareto front)
    whitted hard-cases --out DIR  hard-case stress suite → table; exit 0 iff all pass

Each subcommand lives in its own module (``whitted/render.py``, ``compare.py``,
``check.py``, ``reference.py``, ``bench.py``, ``study.py``, ``hard_cases.py``) with
``register(subparsers)``, which sets ``func``; the options they share are in
``whitted/options.py``. Mitsuba is imported only by the subcommands that run it, when they
run, so ``render`` works with only the core
dependencies installed.

Errors: a bad scene file or override (``SceneError``) and an output that exists
(``FileExistsError``) print one ``error:`` line and return 2; a bad request on the command
line ends through argparse (status 2) or ``options.CliError`` (status 1). ``check`` and
``compare`` exit with their verdict's code (``evaluation.verdict.EXIT_CODES``: 0 pass, 1 warn,
2 fail, 3 size mismatch, 4 missing/stale golden or file error).
"""
from __future__ import annotations

import argparse
import sys

from renderer.scene import SceneError

from . import bench, check, compare, hard_cases, reference, render, study

#: Modules that add subcommands, in the order ``--help`` lists them.
COMMANDS = (render, compare, check, reference, bench, study, hard_cases)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="whitted", description=__doc__.split("\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for module in COMMANDS:
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args) or 0
    except (SceneError, FileExistsError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
