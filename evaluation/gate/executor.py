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

GPUs (CUDA): nothing here assumes one GPU. ``DaskExecutor(workers=N, gpus="auto")`` (what
``whitted study --backend cuda --workers N`` uses) gives worker rank ``i`` the GPU
``gpus[i % len(gpus)]`` through ``CUDA_VISIBLE_DEVICES``, set in the worker process by its
Nanny (``env``) before the task code imports Dr.Jit, which initialises CUDA lazily at its
first CUDA array; inside a worker the GPU is then device 0. ``gpus="auto"`` means the GPUs
this process may use: ``CUDA_VISIBLE_DEVICES`` when set, else one per line of
``nvidia-smi -L``. With ``dask-cuda`` installed and ``N`` at most the GPU count, its
``LocalCUDACluster`` is used instead (the same assignment, plus CPU affinity per GPU); more
workers than GPUs share GPUs round-robin. A scheduler address leaves placement to the
cluster that owns the workers (``dask-cuda-worker`` per GPU, or Slurm's GPU binding).

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
                 env: dict | None = None, dashboard: bool = False, gpus=None):
        try:
            from dask.distributed import Client, LocalCluster
        except ImportError as e:  # pragma: no cover - depends on the extra
            raise RuntimeError("the Dask executor needs the 'study' extra: "
                               "pip install 'dask[distributed]'") from e
        if scheduler is None and (workers is None or workers < 1):
            raise ValueError(f"workers: expected >= 1 (or a scheduler address), got {workers}")
        self.cluster = None
        self.gpus = None
        if scheduler is None:
            if env:
                os.environ.update({k: str(v) for k, v in env.items()})
            kw = dict(n_workers=int(workers), threads_per_worker=1, processes=True,
                      dashboard_address=":0" if dashboard else None)
            if gpus is not None:
                self.gpus = visible_gpus() if gpus == "auto" else [str(g) for g in gpus]
                if not self.gpus:
                    raise RuntimeError("--workers with CUDA: no GPU visible (nvidia-smi -L "
                                       "lists none and CUDA_VISIBLE_DEVICES is unset)")
                self.cluster = _gpu_cluster(self.gpus, kw)
            else:
                self.cluster = LocalCluster(**kw)
            self.client = Client(self.cluster)
        else:
            self.client = Client(scheduler)
        self.scheduler = scheduler
        self.workers = len(self.client.scheduler_info().get("workers", {})) or workers

    def describe(self) -> dict:
        out = {"executor": self.name, "workers": self.workers,
               "scheduler": self.scheduler or type(self.cluster).__name__}
        if self.gpus:
            out["gpus"] = list(self.gpus)
        return out

    def worker_env(self, name: str = "CUDA_VISIBLE_DEVICES") -> dict:
        """``{worker name: os.environ[name]}`` as each worker process sees it."""
        info = self.client.scheduler_info()["workers"]
        got = self.client.run(os.getenv, name)     # (os.environ.get would pickle ours)
        return {info[a].get("name", a): v for a, v in got.items()}

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


def visible_gpus(environ=None, smi_output: str | None = None) -> list[str]:
    """The GPUs this process may hand to workers: the entries of ``CUDA_VISIBLE_DEVICES``
    when it is set (empty: none), else ``0 .. n-1`` for the ``n`` lines ``nvidia-smi -L``
    prints (none when it is missing). ``environ`` / ``smi_output`` replace the real ones
    (tests fake a GPU count with them)."""
    environ = os.environ if environ is None else environ
    if "CUDA_VISIBLE_DEVICES" in environ:
        return [g.strip() for g in environ["CUDA_VISIBLE_DEVICES"].split(",") if g.strip()]
    if smi_output is None:
        import subprocess
        try:
            smi_output = subprocess.run(["nvidia-smi", "-L"], capture_output=True, text=True,
                                        timeout=30).stdout
        except (OSError, subprocess.SubprocessError):
            smi_output = ""
    n = sum(1 for ln in smi_output.splitlines() if ln.startswith("GPU "))
    return [str(i) for i in range(n)]


def gpu_for_worker(rank: int, gpus: list[str]) -> str:
    """``CUDA_VISIBLE_DEVICES`` of worker ``rank``: one GPU, round-robin over ``gpus``."""
    if not gpus:
        raise ValueError("no GPUs to assign")
    return str(gpus[int(rank) % len(gpus)])


def _gpu_cluster(gpus: list[str], kw: dict):
    """A local cluster whose worker ``i`` sees only GPU ``gpu_for_worker(i, gpus)``."""
    try:
        from dask_cuda import LocalCUDACluster
    except ImportError:
        LocalCUDACluster = None
    if LocalCUDACluster is not None and kw["n_workers"] <= len(gpus):  # pragma: no cover
        return LocalCUDACluster(CUDA_VISIBLE_DEVICES=",".join(gpus), **kw)
    import copy

    from dask.distributed import LocalCluster

    class GPULocalCluster(LocalCluster):
        """``LocalCluster`` with ``CUDA_VISIBLE_DEVICES`` per worker (Nanny ``env``, set in
        the worker process before any task runs)."""

        def new_worker_spec(self):
            ((name, spec),) = super().new_worker_spec().items()
            spec = copy.deepcopy(spec)
            opts = spec.setdefault("options", {})
            rank = name if isinstance(name, int) else self._i
            opts["env"] = {**(opts.get("env") or {}),
                           "CUDA_VISIBLE_DEVICES": gpu_for_worker(rank, gpus)}
            return {name: spec}

    # LocalCluster builds its first workers without new_worker_spec: start none, then scale.
    n = kw.pop("n_workers")
    cluster = GPULocalCluster(n_workers=0, **kw)
    cluster.scale(n)
    cluster.wait_for_workers(n)
    return cluster


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
