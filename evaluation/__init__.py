"""How well and how fast: our renderer measured against Mitsuba 3, one sub-package per job.

- ``gate``: where a verdict is made: rules and thresholds, metrics, verdicts and exit codes,
  the HTML report, the pytest plugin, the executor;
- ``bench``: where a timing is taken: the timing study as a registry of parts;
- ``study``: accuracy against time, factor by factor (points, run, report, README block);
- ``hard``: the hard-case stress suite (case table, scenes, rays, runners, report);
- ``meta``: the checks of the rules (mutation, null test, tie count, speckles).

``evaluation`` may import ``renderer`` and ``reference``; neither imports ``evaluation``.
No module here imports ``mitsuba`` when it is imported: functions that need the Mitsuba peer
reach it through ``reference`` when they run. Experiments are not here: they live in ``lab/``
at the repository root, which no package imports.
"""
from __future__ import annotations

#: The thesis's three seed scenes (file stems under ``scenes/``), in its table's order.
SEED_SCENES = ("cornell_box", "cornell_sphere", "platonic_solids")


def write_result(path, text: str) -> None:
    """Write a results file (JSON, markdown) atomically through the project's one writer
    (``renderer.outputs.write_text``), replacing an older one and making its folder."""
    from pathlib import Path

    from renderer.outputs import write_text

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    write_text(path, text, overwrite=True)


def at_least(minimum: int):
    """``argparse`` type of every count option (``--spp``, ``--batches``, ``--seeds``,
    ``--chunk``, ...): an integer ``>= minimum``; bad input is argparse's one-line error
    naming the option, exit 2."""
    import argparse

    def count(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected an integer >= {minimum}, got {text!r}")
        return value
    return count


def wxh(text: str) -> tuple[int, int]:
    """``argparse`` type of every ``--size`` (the CLI's and the evaluation scripts'):
    ``"WIDTHxHEIGHT"`` -> (width, height), both > 0; bad input is argparse's one-line error,
    exit 2. Here, in the package's light top module, so that ``whitted`` reaches it without
    importing the bench."""
    import argparse
    try:
        w, h = (int(v) for v in text.lower().split("x"))
        if w <= 0 or h <= 0:
            raise ValueError
        return w, h
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected WIDTHxHEIGHT with positive integers, got {text!r}") from None
