"""Progress of long work, and the stop request that Ctrl-C sets.

``bar(total, label)`` is a tqdm bar on stderr (with ETA) when stderr is a terminal, and
plain lines (``label: 3/16 (19%), 4.1 s, ETA 17.5 s``) at most every few seconds
otherwise, so a CI log stays readable. ``STOP`` is the event ``whitted.cli.main`` sets on
Ctrl-C; long loops pass ``stop=STOP.is_set`` to ``Renderer.render`` so that the worker
thread ends at the next band.
"""
from __future__ import annotations

import contextlib
import sys
import threading
import time

from renderer.stats import kernel_operations

#: Set by ``whitted.cli.main`` on Ctrl-C; work in the worker thread stops at the next band.
STOP = threading.Event()

#: Seconds between two plain progress lines when stderr is not a terminal.
PLAIN_INTERVAL = 5.0


class _PlainBar:
    """tqdm's ``update``/``close`` as plain lines, for logs."""

    def __init__(self, total: int, label: str, file):
        self.total, self.label, self.file = total, label, file
        self.n = 0
        self.t0 = self.last = time.perf_counter()

    def update(self, k: int = 1) -> None:
        self.n += k
        now = time.perf_counter()
        if now - self.last >= PLAIN_INTERVAL or self.n >= self.total:
            self.last = now
            el = now - self.t0
            eta = el / self.n * (self.total - self.n) if self.n else float("nan")
            print(f"{self.label}: {self.n}/{self.total} ({100 * self.n / self.total:.0f}%), "
                  f"{el:.1f} s, ETA {eta:.1f} s", file=self.file, flush=True)

    def close(self) -> None:
        pass


def bar(total: int, label: str, *, unit: str = "row", file=None):
    """A progress bar for ``total`` steps: tqdm on a terminal, plain lines otherwise."""
    file = sys.stderr if file is None else file
    if file.isatty():
        from tqdm import tqdm
        return tqdm(total=total, desc=label, unit=unit, file=file, leave=False,
                    dynamic_ncols=True)
    return _PlainBar(total, label, file)


@contextlib.contextmanager
def build_bar(scene, min_triangles: int = 100_000):
    """A bar over the levels of a BVH build (at most ``MAX_LEVELS``) for scenes of at least
    ``min_triangles`` triangles; yields the ``build_progress`` callback (None for smaller
    scenes, whose build is quick)."""
    from renderer.accel.bvh_build import MAX_LEVELS
    if scene.face_count < min_triangles:
        yield None
        return
    state = {}

    def step(build: str, levels: int) -> None:
        if "bar" not in state:
            state["bar"] = bar(MAX_LEVELS, f"{scene.name}: {build} BVH build", unit="level")
            state["n"] = 0
        if levels > state["n"]:
            state["bar"].update(levels - state["n"])
            state["n"] = levels
    try:
        yield step
    finally:
        if "bar" in state:
            state["bar"].close()


def render_view(renderer, view: int, label: str) -> dict:
    """``renderer.render(view)`` with a bar over its bands and the ``STOP`` request
    honoured between bands. Returns ``renderer.stats.kernel_operations``'s dict (the
    RenderResult under ``"result"``) for a one-band render; a banded render runs without
    Dr.Jit's kernel history (with it on, the main thread waits for the interpreter lock
    during a band, which delays Ctrl-C), so its dict holds only ``"result"``."""
    if len(renderer.bands(view)) == 1:
        return kernel_operations(lambda: renderer.render(view, stop=STOP.is_set))
    return {"result": _render_bands(renderer, view, label)}


def _render_bands(renderer, view: int, label: str):
    height = renderer.scene.cameras[view].height
    b = bar(height, label)
    done = [0]

    def step(rows_done: int, _total: int) -> None:
        b.update(rows_done - done[0])
        done[0] = rows_done
    try:
        return renderer.render(view, progress=step, stop=STOP.is_set)
    finally:
        b.close()
