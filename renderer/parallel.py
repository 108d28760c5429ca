"""A small thread pool for the host's elementwise numpy work (the scene loader's face and
vertex arrays, the accelerators' packed triangles and boxes).

numpy releases the GIL inside its elementwise loops, gathers, sorts and ``np.bincount``, so
splitting such work over threads uses every core. The helpers here only ever split work
whose results do not depend on the split: elementwise operations and gathers over spans of
rows (each row computed alone, in the same operations as without threads), independent
steps run side by side, and the sort of integers by value ranges (``unique_inverse``). No
floating-point reduction is split: the results are the same bit for bit for any number of
threads.

The pool's size is ``thread_count()``: the cores this process may run on (at most
``MAX_THREADS``), or the ``WHITTED_HOST_THREADS`` environment variable, or the ``threads``
context manager (tests and probes). The calling thread takes part in its own work, so a
step split inside another step (a span split inside one of ``together``'s steps) never
waits for a pool thread that is busy waiting itself.
"""
from __future__ import annotations

import os
import queue
import threading
import warnings
from contextlib import contextmanager

import numpy as np

#: The most threads the pool uses (memory bandwidth, not cores, bounds these steps).
MAX_THREADS = 16
#: The fewest rows a span of ``spans`` holds: smaller steps run on the calling thread alone
#: (a thread hand-over costs about what numpy does to a few thousand rows).
GRAIN = 32768

_override: list[int] = []
_jobs: queue.SimpleQueue = queue.SimpleQueue()
_started = 0
_start_lock = threading.Lock()
_warned: set[str] = set()                 # the bad WHITTED_HOST_THREADS values warned of


def thread_count() -> int:
    """Threads the helpers use: ``threads(n)``'s ``n`` inside that context, else a valid
    ``WHITTED_HOST_THREADS`` (a positive integer), else the cores this process may run on;
    at most ``MAX_THREADS`` unless set explicitly."""
    if _override:
        return _override[-1]
    env = os.environ.get("WHITTED_HOST_THREADS", "").strip()
    if env.isdigit() and int(env) > 0:
        return int(env)
    if env and env not in _warned:
        _warned.add(env)
        warnings.warn(f"WHITTED_HOST_THREADS={env!r}: expected a positive integer; using "
                      "the cores this process may run on", stacklevel=2)
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:                  # not on Linux
        cores = os.cpu_count() or 1
    return max(1, min(cores, MAX_THREADS))


@contextmanager
def threads(n: int):
    """Use ``n`` (>= 1) threads inside the context (tests and probes)."""
    if int(n) < 1:
        raise ValueError(f"threads: expected at least 1, got {n}")
    _override.append(int(n))
    try:
        yield
    finally:
        _override.pop()


def _worker() -> None:
    while True:
        _jobs.get()()


def _ensure_workers(n: int) -> None:
    """At least ``n`` pool threads (daemons: they never hold up the interpreter's exit)."""
    global _started
    with _start_lock:
        while _started < n:
            threading.Thread(target=_worker, name=f"whitted host {_started}",
                             daemon=True).start()
            _started += 1


def _after_fork() -> None:
    """A forked child has none of the parent's pool threads: start afresh."""
    global _jobs, _started, _start_lock
    _jobs, _started, _start_lock = queue.SimpleQueue(), 0, threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork)


class _Batch:
    """Items handed out one at a time to whichever thread asks next; ``wait`` returns
    once every item is done."""

    def __init__(self, fn, items):
        self.fn, self.items = fn, items
        self.results = [None] * len(items)
        self.errors: dict[int, BaseException] = {}
        self.next = self.done = 0
        self.cond = threading.Condition()

    def work(self) -> None:
        while True:
            with self.cond:
                i = self.next
                if i >= len(self.items):
                    return
                self.next += 1
            try:
                self.results[i] = self.fn(self.items[i])
            except BaseException as e:          # raised by ``wait``, first item first
                self.errors[i] = e
            with self.cond:
                self.done += 1
                if self.done == len(self.items):
                    self.cond.notify_all()

    def wait(self) -> list:
        with self.cond:
            while self.done < len(self.items):
                self.cond.wait()
        if self.errors:
            raise self.errors[min(self.errors)]
        return self.results


def run(fn, items) -> list:
    """``[fn(x) for x in items]``, the calls spread over ``thread_count()`` threads (the
    caller's among them); the results in the order of ``items``. An exception raised by a
    call is raised here (that of the first such item) once every call has ended."""
    items = list(items)
    k = min(thread_count(), len(items))
    if k <= 1:
        return [fn(x) for x in items]
    batch = _Batch(fn, items)
    _ensure_workers(k - 1)
    for _ in range(k - 1):
        _jobs.put(batch.work)
    batch.work()
    return batch.wait()


def together(*steps) -> list:
    """The results of the independent zero-argument callables ``steps``, run side by side
    (``run``)."""
    return run(lambda step: step(), steps)


def spans(n: int, grain: int | None = None) -> list[tuple[int, int]]:
    """``range(n)`` cut into at most ``thread_count()`` contiguous ``(lo, hi)`` spans of
    at least ``grain`` (default ``GRAIN``) rows each (one span when ``n`` is small)."""
    grain = GRAIN if grain is None else grain
    k = max(1, min(thread_count(), n // max(grain, 1)))
    cuts = [n * j // k for j in range(k + 1)]
    return list(zip(cuts[:-1], cuts[1:]))


def for_spans(n: int, fn, grain: int | None = None) -> None:
    """``fn(lo, hi)`` for the ``spans(n, grain)`` of ``range(n)``, side by side (``run``);
    ``fn`` writes its rows into arrays the caller made."""
    run(lambda s: fn(*s), spans(n, grain))


def unique_inverse(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(x, return_inverse=True)`` of a 1-D integer array ``x`` (the sorted
    distinct values and each element's index among them), the same arrays, with the sort
    split over threads: ``x`` is cut by value at splitters drawn from a regular sample,
    each value range is made unique on its own thread, and the ranges' results are
    joined in value order (integers: no rounding anywhere)."""
    x = np.asarray(x)
    n = x.size
    k = min(thread_count(), n // (4 * GRAIN), 255)       # ranges numbered in uint8
    if k <= 1:
        values, inverse = np.unique(x, return_inverse=True)
        return values, inverse.reshape(-1)
    sample = np.sort(x[::max(1, n // (64 * k))])
    splitters = np.unique(sample[[len(sample) * j // k for j in range(1, k)]])
    bucket = np.zeros(n, np.uint8)             # the value range of each element

    def find(lo, hi):
        for s in splitters:
            bucket[lo:hi] += x[lo:hi] >= s
    for_spans(n, find)

    def part(j):
        members = np.flatnonzero(bucket == j)
        values, inverse = np.unique(x[members], return_inverse=True)
        return members, values, inverse.reshape(-1)
    parts = run(part, range(len(splitters) + 1))
    offsets = np.cumsum([0] + [len(v) for _, v, _ in parts])
    inverse = np.empty(n, np.intp)

    def place(j):
        members, _, inv = parts[j]
        inverse[members] = inv + offsets[j]
    run(place, range(len(parts)))
    return np.concatenate([v for _, v, _ in parts]), inverse
