"""The timing study: ours vs Mitsuba 3 on the same device, in one process.

Everything is timed from Dr.Jit's kernel history (``renderer.stats.kernel_ms``: the sum of
``execution_time`` of the kernels a step launched, median over repeats after warm-up), so
Python tracing is reported separately and never counted as ray-tracing time.

The study is a registry of parts (``PARTS``, name -> ``Part``), run in registry order, each
a module of this package:

- ``throughput`` (``throughput.py``): identical ray batches through our accelerator and
  through Mitsuba's (OptiX on CUDA, Embree on the CPU), with the fraction of rays on which
  the two agree.
- ``seed`` (``seed_table.py``): the thesis's table (three seed scenes × three views at 512²,
  primary rays only and with reflection, brute force / per-object boxes / BVH), frozen frames.
- ``whitted`` (``whitted_frame.py``): our Whitted frame at the scene's own depth against
  the reference harness's Mitsuba render (the image difference and a PNG strip); the
  harness's integrator is a reference, not a speed peer, so it is not timed.
- ``peer`` (``peer.py``): the Whitted-frame speed comparison: our frozen frame vs a fair
  Mitsuba peer (``reference.peer``: one kernel, frozen) at equal depth, 512² and 1024², with
  the depth at which the peer's unrolled tree stops compiling (probed in subprocesses).
- ``effects`` (``effects.py``): the scene's specialised kernel vs the all-effects kernel.
- ``build`` (``build.py``): the device BVH build vs the host SAH build vs Mitsuba's scene
  build, the two trees' SAH cost and frames, and a process's time to its first image.

A new part is one module defining ``PART = Part(name, key, run, markdown)`` (``part.py``)
and one entry in ``PARTS`` below.
"""
from __future__ import annotations

import json
import os
import platform
import subprocess
import time
from pathlib import Path

from renderer.outputs import check_output_file

from . import build, effects, peer, seed_table, throughput, whitted_frame
from .part import Context, Part, jsonable, write_atomic

__all__ = ["PARTS", "Context", "NothingMeasured", "Part", "device_info", "markdown", "run"]

#: The study's parts by name, in the order they run and appear in the markdown.
PARTS: dict[str, Part] = {p.name: p for p in (throughput.PART, seed_table.PART,
                                               whitted_frame.PART, peer.PART, effects.PART,
                                               build.PART)}


class NothingMeasured(Exception):
    """No part asked for found a scene of its own in the scenes folder: the run measured
    nothing and wrote no result."""


def device_info(backend: str) -> dict:
    """The machine a result was measured on: backend, versions, host, device name."""
    from importlib.metadata import PackageNotFoundError, version

    import drjit as dr
    info = {"backend": backend, "python": platform.python_version(), "drjit": dr.__version__,
            "host": platform.node(), "cpu": platform.processor() or platform.machine(),
            "cores": os.cpu_count()}
    try:
        info["mitsuba"] = version("mitsuba")
    except PackageNotFoundError:
        pass
    if backend == "cuda":
        try:
            q = subprocess.run(["nvidia-smi", "--query-gpu=name,driver_version,memory.total",
                                "--format=csv,noheader"], capture_output=True, text=True,
                               timeout=30)
            name, driver, mem = (s.strip() for s in q.stdout.strip().split("\n")[0].split(","))
            info.update(device=name, driver=driver, gpu_memory=mem)
        except Exception as e:  # noqa: BLE001 - informational only
            info["device"] = f"unknown GPU ({e})"
    else:
        try:
            with open("/proc/cpuinfo") as f:
                model = [line.split(":", 1)[1].strip() for line in f
                         if line.startswith("model name")]
            info["device"] = f"{model[0]} ({os.cpu_count()} cores)" if model else "CPU"
        except OSError:
            info["device"] = "CPU"
    return info


def run(out_dir, *, backend: str = "auto", scenes_dir="scenes", quick: bool = False,
        parts=tuple(PARTS), overwrite: bool = False, command: str | None = None) -> dict:
    """Run the parts named in ``parts`` (in ``PARTS`` order) and write
    ``bench-<backend>.json`` and ``.md`` (``-quick`` appended to the tag when ``quick``)
    in ``out_dir``. Existing files there are replaced only when ``overwrite``, checked before
    the study runs (``OutputExistsError``). Returns the result: the ``command`` that
    regenerates it (when given), device, quick, date and each part's rows under its key.

    The files are rewritten (atomically) after each part and at each part's checkpoints
    (``Context.save_rows``); on Ctrl-C (or ``timeout -s INT``) they are written with what
    was measured and ``"interrupted"`` naming the part, and the interrupt is re-raised.
    Nothing is written until a part has rows; when no part finds a scene of its own in
    ``scenes_dir``, ``NothingMeasured`` is raised and no file is written.

    ``quick`` shrinks every size (for a smoke run on a CPU): 1920×1080 → 320×180,
    512² → 128², 20 frozen frames → 5.
    """
    from renderer.device import types
    unknown = [p for p in parts if p not in PARTS]
    if unknown:
        raise ValueError(f"parts: unknown {unknown}; expected some of {list(PARTS)}")
    backend = types(backend).backend
    out = Path(out_dir)
    tag = backend + ("-quick" if quick else "")
    for ext in (".json", ".md"):        # before the study, not after its minutes of work
        check_output_file(out / f"bench-{tag}{ext}", overwrite=overwrite, flag="--force")
    info = device_info(backend)
    print(f"bench on {info.get('device')} ({backend})", flush=True)
    result = {"command": command} if command else {}
    result.update(device=info, quick=quick, date=time.strftime("%Y-%m-%d %H:%M:%S"))

    def save() -> None:
        write_atomic(out / f"bench-{tag}.json", json.dumps(jsonable(result), indent=1))
        write_atomic(out / f"bench-{tag}.md", markdown(result))

    def measured() -> bool:
        return any(result.get(p.key) for p in PARTS.values())

    def checkpoint(key: str):
        def keep(rows: list[dict]) -> None:
            result[key] = list(rows)
            if measured():
                save()
        return keep

    part = None
    try:
        for part in PARTS.values():
            if part.name in parts:
                ctx = Context(backend=backend, scenes_dir=Path(scenes_dir), out_dir=out,
                              quick=quick, checkpoint=checkpoint(part.key),
                              overwrite=overwrite)
                result[part.key] = part.run(ctx)
                if measured():
                    save()
    except KeyboardInterrupt:
        result["interrupted"] = f"in part {part.name}" if part else "before the first part"
        save()
        print(f"interrupted {result['interrupted']}: wrote what was measured to "
              f"{out / f'bench-{tag}.json'} and .md", flush=True)
        raise
    if not measured():
        raise NothingMeasured(f"no scene of the parts {', '.join(parts)} in {scenes_dir}: "
                              "nothing measured, nothing written")
    save()
    print(f"wrote {out / f'bench-{tag}.json'} and .md", flush=True)
    return result


def markdown(result: dict) -> str:
    """The result of ``run`` as markdown: the command that regenerates it as a comment line
    (when the result names one), a header, then each part's tables."""
    dev = result["device"]
    lines = [f"<!-- command: {result['command']} -->"] if result.get("command") else []
    lines += [f"# Benchmark on {dev.get('device')} ({dev['backend']})", "",
             f"{result['date']}; drjit {dev.get('drjit')}, mitsuba {dev.get('mitsuba')}"
             + (f", driver {dev['driver']}" if dev.get("driver") else "")
             + ("; QUICK smoke sizes" if result.get("quick") else ""), ""]
    if result.get("note"):
        lines += [result["note"], ""]
    if result.get("interrupted"):
        lines += [f"**Interrupted {result['interrupted']}: partial results.**", ""]
    for part in PARTS.values():
        if result.get(part.key):
            lines += part.markdown(result[part.key])
    return "\n".join(lines)
