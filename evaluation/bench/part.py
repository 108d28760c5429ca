"""The shape every study part shares: what it is given (``Context``) and what it is (``Part``).

A part is a function from the context to JSON-ready rows plus a function from those rows to
markdown lines; ``evaluation.bench`` runs the parts asked for and writes the rows under the
part's ``key`` in ``bench-<backend>.json`` and the lines in ``bench-<backend>.md``.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from renderer.outputs import write_text


@dataclass(frozen=True)
class Context:
    """What every part is given.

    backend: "cuda" | "llvm" (resolved, never "auto"); scenes_dir: the folder holding the
    scene files; out_dir: the output folder (exists when a part runs); quick: smoke sizes;
    checkpoint: ``checkpoint(rows)`` saves a part's rows so far (``save_rows``);
    overwrite: a part may replace its existing output files (``whitted bench --force``).
    """

    backend: str
    scenes_dir: Path
    out_dir: Path
    quick: bool = False
    checkpoint: Callable[[list[dict]], None] | None = None
    overwrite: bool = False

    def save_rows(self, rows: list[dict]) -> None:
        """Write the running part's rows so far with the result (a long part calls this
        after each row, so a run cut short keeps them); nothing without a checkpoint."""
        if self.checkpoint is not None:
            self.checkpoint(rows)

    @property
    def frames(self) -> int:
        """Frozen frames timed per measurement (after warm-up)."""
        return 5 if self.quick else 20

    @property
    def frame_size(self) -> int:
        """Side of the square frames of the frame parts, pixels."""
        return 128 if self.quick else 512

    def scene_path(self, name: str) -> Path:
        """``scenes_dir / <name>.toml``."""
        return self.scenes_dir / f"{name}.toml"


@dataclass(frozen=True)
class Part:
    """One part of the study.

    name: its name on the command line (``whitted bench --parts``); key: the key of its rows
    in the result; run: ``run(ctx) -> list[dict]`` (JSON-ready rows, printing one progress
    line per row); markdown: ``markdown(rows) -> list[str]`` (its section of the report).
    """

    name: str
    key: str
    run: Callable[[Context], list[dict]]
    markdown: Callable[[list[dict]], list[str]]


def jsonable(x):
    """``x`` with numpy scalars as Python numbers and anything unknown as its ``str``."""
    if isinstance(x, dict):
        return {k: jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.floating,)):
        return float(x)
    if isinstance(x, (int, float, str, bool)) or x is None:
        return x
    return str(x)


def write_atomic(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through the project's atomic writer
    (``renderer.outputs``: a temporary file in the same folder, fsync, rename), so a reader
    (or a run cut off mid-write) never sees half a file. Replaces ``path``: the callers
    checked before the run that they may (``evaluation.bench.run``)."""
    write_text(path, text, overwrite=True)


def table(title: str, columns: list[str], align: str, rows: list[list[str]]) -> list[str]:
    """A markdown section: ``## title``, a blank line, the table, a blank line.

    columns: the header cells; align: one letter per column, "l" (left) or "r" (right);
    rows: the cells of each row, as text.
    """
    rule = {"l": "---", "r": "---:"}
    lines = [f"## {title}", "", "| " + " | ".join(columns) + " |",
             "| " + " | ".join(rule[a] for a in align) + " |"]
    lines += ["| " + " | ".join(cells) + " |" for cells in rows]
    return lines + [""]
