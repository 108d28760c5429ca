"""The point executor: map a picklable function over picklable items, results as they complete.

One interface, three places to run:

- ``InProcess()`` (the default): the items run one after another in this process, in order.
- ``DaskExecutor(workers=N)``: a Dask distributed ``LocalCluster`` of ``N`` worker processes
  with one thread each, so every worker owns its own Dr.Jit state (its own JIT, kernel cache
  and device context). Workers are spawned processes: they inherit this process's
  environment (``DRJIT_LIBLLVM_PATH`` from ``ci/env.sh``, ``PYTHONPATH``) and ``sys.path``.
- ``DaskExecutor(scheduler="tcp://host:8786")``: an existing Dask scheduler (e.g. started by
  ``dask-jobqueue`` on Slurm, or ``dask-cuda``'s ``LocalCUDACluster`` for one worker per GPU).
  Its workers must be able to import the mapped function (same repository on their path).

``executor.map(fn, items)`` yields ``(index, result)`` pairs as results arrive (in order for
``InProcess``, completion order for Dask); an exception in ``fn`` is raised in the caller at
the item that failed, after the executor cancelled the rest. ``progress(...)`` wraps any such
iterator in a tqdm bar with an ETA. Both executors are context managers; leaving the ``with``
block (also by Ctrl-C) cancels pending work and shuts a local cluster down.

Nothing here knows about rendering: the study maps its points through it, and golden
rendering can map its (scene, view, shading, mode) jobs through the same object.
"""
from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator
from typing import Any


class InProcess:
    """Run the items in this process, one after another, in order."""

    name = "in-process"
    workers = 1

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[tuple[int, Any]]:
        for i, item in enumerate(items):
            yield i, fn(item)

    def describe(self) -> dict:
        return {"executor": self.name, "workers": 1}

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


class DaskExecutor:
    """Run the items on Dask distributed workers.

    workers: start a ``LocalCluster`` of this many worker processes (one thread each).
    scheduler: address of a running scheduler instead (``workers`` is then ignored).
    env: extra environment variables for local worker processes (they also inherit ours).
    dashboard: serve Dask's dashboard for a local cluster (default off: port clashes in CI).
    """

    name = "dask"

    def __init__(self, workers: int | None = None, scheduler: str | None = None, *,
                 env: dict | None = None, dashboard: bool = False):
        try:
            from dask.distributed import Client, LocalCluster
        except ImportError as e:  # pragma: no cover - depends on the extra
            raise RuntimeError("the Dask executor needs the 'study' extra: "
                               "pip install 'dask[distributed]'") from e
        if scheduler is None and (workers is None or workers < 1):
            raise ValueError(f"workers: expected >= 1 (or a scheduler address), got {workers}")
        self.cluster = None
        if scheduler is None:
            if env:
                os.environ.update({k: str(v) for k, v in env.items()})
            self.cluster = LocalCluster(n_workers=int(workers), threads_per_worker=1,
                                        processes=True,
                                        dashboard_address=":0" if dashboard else None)
            self.client = Client(self.cluster)
        else:
            self.client = Client(scheduler)
        self.scheduler = scheduler
        self.workers = len(self.client.scheduler_info().get("workers", {})) or workers

    def describe(self) -> dict:
        return {"executor": self.name, "workers": self.workers,
                "scheduler": self.scheduler or "LocalCluster"}

    def map(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[tuple[int, Any]]:
        from dask.distributed import as_completed
        items = list(items)
        if not items:
            return
        futures = self.client.map(fn, items, pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        try:
            for fut in as_completed(futures):
                yield index[fut.key], fut.result()
        finally:
            pending = [f for f in futures if not f.done()]
            if pending:
                self.client.cancel(pending)

    def close(self) -> None:
        try:
            self.client.close()
        finally:
            if self.cluster is not None:
                self.cluster.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False


def make_executor(workers: int = 0, scheduler: str | None = None, **kw):
    """``InProcess()`` when neither ``workers`` (> 0) nor ``scheduler`` is given, else a
    ``DaskExecutor``."""
    if scheduler:
        return DaskExecutor(scheduler=scheduler, **kw)
    if workers and workers > 0:
        return DaskExecutor(workers=workers, **kw)
    return InProcess()


def progress(pairs: Iterator[tuple[int, Any]], total: int, *, desc: str = "",
             enabled: bool = True) -> Iterator[tuple[int, Any]]:
    """``pairs`` with a tqdm progress bar (count, rate, ETA) on stderr; plain when tqdm is
    missing or ``enabled`` is False."""
    if not enabled:
        yield from pairs
        return
    try:
        from tqdm import tqdm
    except ImportError:
        yield from pairs
        return
    with tqdm(total=total, desc=desc, unit="pt", dynamic_ncols=True) as bar:
        for pair in pairs:
            yield pair
            bar.update(1)
