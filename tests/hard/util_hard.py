"""Shared set-up of the hard-case tests: the CI subset is float32 on LLVM."""
from __future__ import annotations

from evaluation.hard.cases import Config, load_cases
from evaluation.hard.runners import run_suite

CI = Config(backend="llvm", precisions=("float32",))


def rows_of(name: str, cfg: Config = CI, **spec_changes):
    table = load_cases()
    table[name] = {**table[name], **spec_changes}
    return run_suite(cfg, [name], table)


def assert_green(rows) -> None:
    red = [f"{r.case} | {r.variant} | {r.criterion} | {r.measured}" for r in rows
           if not r.passed]
    assert rows and not red, "red rows:\n" + "\n".join(red)
