"""Bench part: our frozen Whitted frame against a fair Mitsuba peer (``reference.peer``).

The peer is the one-kernel, frozen Whitted integrator a competent Mitsuba 3 user would
write (``reference.peer``), over the same translated scene, at the same depth, resolution and
exact mode (one ray per pixel centre). Both sides are timed the same way: the median over
``frames`` frozen frames after warm-up of the wall time of a frame (launch + wait) and of the
kernel time from Dr.Jit's kernel history.

Deep trees of the peer (unrolled at trace time) may not compile in reasonable time, so each
depth is first probed in a subprocess with a timeout (``peer_compiles``); a depth whose probe
fails is reported as such and not timed.

Entry points: ``whitted_frame_peer(scene, ...)`` (one scene, one depth, one size),
``peer_compiles(scene, depth, timeout_s)``, ``run_part(scenes, ...)`` -> rows,
``markdown(rows)``. Command line: ``python evaluation_peer_part.py --help``.
"""
from __future__ import annotations

import argparse
import contextlib
import gc
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

# ---- project imports (one block; renamed at merge) ---------------------------------------
from evaluation.bench import device_info
from evaluation.bench.frames import frozen_frame_ms
from evaluation.metrics import image_difference
from evaluation.rules import EXACT_THRESHOLDS, check_exact
from reference.peer import load_peer
from renderer.scene import Scene, load_scene
from renderer.stats import kernel_ms

# --------------------------------------------------------------------------------------------

ROOT = Path(__file__).resolve().parent
#: The scenes of goal 3: the seed scenes and the glass bunny.
PEER_SCENES = ("cornell_box", "cornell_sphere", "platonic_solids", "glass_bunny")


def _jit_kernels(history) -> int:
    """Compiled kernels in a kernel history (not memcpy, aggregate or host-function entries)."""
    import drjit as dr
    return sum(1 for h in history if h.get("type") == dr.KernelType.JIT)


@contextlib.contextmanager
def _no_collection():
    """Collect garbage now and not during the block: Python's cycle collector freeing device
    memory while ``dr.freeze`` records a frame makes Dr.Jit abort ("enqueue_host_func():
    this function cannot be recorded"), and Mitsuba scenes left from an earlier run are
    such garbage."""
    import drjit as dr
    gc.collect()
    dr.sync_thread()
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def peer_frame_ms(scene: Scene, *, backend: str, frames: int = 20, warmup: int = 3) -> dict:
    """The peer on ``scene`` (its size and ``settings.max_depth``): traced first frame
    (trace + compile) wall ms, JIT kernels per frame, frozen frame wall/kernel ms (median of
    ``frames`` after ``warmup``), whether the frozen frame equals the traced one, and the image."""
    import drjit as dr
    peer = load_peer(scene, backend=backend)
    pos = peer.positions()
    dr.sync_thread()
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        dr.kernel_history()
        t0 = time.perf_counter()
        img = peer.frame(pos)
        dr.sync_thread()
        traced_ms = (time.perf_counter() - t0) * 1e3
        hist = dr.kernel_history()
    traced = np.asarray(img.numpy(), np.float32)
    run = peer.frozen()
    timing = kernel_ms(lambda: run(pos), warmup=warmup, repeats=frames)
    frozen = np.asarray(run(pos).numpy(), np.float32)
    ops = [int(h["operation_count"]) for h in hist if "operation_count" in h]
    return {"frozen_ms": timing["wall_ms"], "frozen_kernel_ms": timing["kernel_ms"],
            "traced_ms": traced_ms, "jit_kernels": _jit_kernels(hist),
            "launches": timing["kernels"], "operations": sum(ops),
            "frozen_equals_traced": bool(np.array_equal(traced, frozen)), "image": traced}


def agreement(ours: np.ndarray, peer: np.ndarray) -> dict:
    """Peer vs ours: the bench's image difference, the fraction of pixels whose channels all
    agree within 1e-3 (absolute), and the harness's exact-mode rule (``check_exact``, the
    peer in the golden's place)."""
    d = image_difference(ours, peer)
    err = np.abs(np.asarray(ours, np.float64) - np.asarray(peer, np.float64)).max(-1)
    d["within_1e-3"] = float(np.mean(err <= 1e-3))
    ex = check_exact(ours, peer, EXACT_THRESHOLDS)
    d.update(exact_ok=ex["ok"], edge_pixels=ex["edge_pixels"], hard_pixels=ex["hard_pixels"],
             mean_rel_nonedge=ex["mean_rel"])
    return d


def whitted_frame_peer(scene: Scene, *, backend: str, depth: int, size: int,
                       frames: int = 20, accel: str = "bvh") -> dict:
    """Ours (frozen ``Renderer``, exact mode) vs the peer on ``scene`` at ``depth`` and
    ``size``², both timed as frozen frames; plus the image difference."""
    sc = scene.with_settings(max_depth=int(depth), exact=True).with_size(int(size))
    with _no_collection():
        ours = frozen_frame_ms(sc, backend=backend, accel=accel, frames=frames)
    with _no_collection():
        peer = peer_frame_ms(sc, backend=backend, frames=frames)
    row = {"scene": sc.name, "size": int(size), "depth": int(depth), "backend": backend,
           "frames": frames,
           "ours_frozen_ms": ours["frozen_ms"], "ours_kernel_ms": ours["frozen_kernel_ms"],
           "ours_traced_ms": ours["traced_ms"], "ours_kernels": ours["kernels"],
           "ours_frozen_equals_traced": ours["frozen_equals_traced"],
           "peer_frozen_ms": peer["frozen_ms"], "peer_kernel_ms": peer["frozen_kernel_ms"],
           "peer_traced_ms": peer["traced_ms"], "peer_kernels": peer["jit_kernels"],
           "peer_operations": peer["operations"],
           "peer_frozen_equals_traced": peer["frozen_equals_traced"],
           "difference": agreement(ours["image"], peer["image"])}
    row["speedup_frozen"] = row["peer_frozen_ms"] / row["ours_frozen_ms"]
    row["speedup_kernel"] = (row["peer_kernel_ms"] / row["ours_kernel_ms"]
                             if row["ours_kernel_ms"] > 0 else float("nan"))
    return row


# ---- compile probe ---------------------------------------------------------------------------
def _probe_cmd(scene, depth: int, backend: str, size: int) -> list[str]:
    path = scene if isinstance(scene, (str, Path)) else scene.path
    if path is None:
        raise ValueError("peer_compiles: the scene needs a file path (scene.path)")
    return [sys.executable, str(Path(__file__).resolve()), "--probe", str(path),
            "--probe-depth", str(int(depth)), "--backend", backend,
            "--probe-size", str(int(size))]


def probe_many(items, timeout_s: float, *, backend: str = "llvm", size: int = 64,
               cold_cache: bool = True, jobs: int = 1) -> list[dict]:
    """``peer_compiles`` for each ``(scene, depth)`` of ``items``, ``jobs`` subprocesses at
    a time, each killed ``timeout_s`` seconds after it started. Results in the order of
    ``items``."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    items = list(items)
    results: list[dict | None] = [None] * len(items)
    running: dict[int, tuple] = {}
    todo = list(range(len(items)))
    with tempfile.TemporaryDirectory(prefix="peer-probe-") as tmp:
        while todo or running:
            while todo and len(running) < max(1, jobs):
                i = todo.pop(0)
                scene, depth = items[i]
                e = dict(env)
                if cold_cache:                 # empty kernel caches per probe
                    e["HOME"] = os.path.join(tmp, str(i))
                    os.makedirs(e["HOME"])
                    e["OPTIX_CACHE_MAXSIZE"] = "0"     # OptiX keeps its own, outside $HOME
                out = open(os.path.join(tmp, f"{i}.out"), "w+")
                err = open(os.path.join(tmp, f"{i}.err"), "w+")
                proc = subprocess.Popen(_probe_cmd(scene, depth, backend, size), env=e,
                                        stdout=out, stderr=err, text=True)
                running[i] = (proc, time.perf_counter(), out, err)
            time.sleep(0.05)
            for i, (proc, t0, out, err) in list(running.items()):
                depth = int(items[i][1])
                wall = time.perf_counter() - t0
                if proc.poll() is None:
                    if wall < timeout_s:
                        continue
                    proc.kill()
                    proc.wait()
                    results[i] = {"depth": depth, "compiles": False, "seconds": float(timeout_s),
                                  "error": f"timeout after {timeout_s:g} s"}
                else:
                    out.seek(0)
                    err.seek(0)
                    lines = out.read().strip().splitlines()
                    if proc.returncode != 0 or not lines:
                        tail = err.read().strip().splitlines() or [f"exit {proc.returncode}"]
                        results[i] = {"depth": depth, "compiles": False, "seconds": wall,
                                      "error": tail[-1]}
                    else:
                        o = json.loads(lines[-1])
                        results[i] = {"depth": depth, "compiles": True,
                                      "seconds": o["first_frame_s"], "process_s": wall,
                                      "operations": o["operations"], "error": None}
                out.close()
                err.close()
                del running[i]
    return results


def peer_compiles(scene: Scene | str | Path, depth: int, timeout_s: float, *,
                  backend: str = "llvm", size: int = 64, cold_cache: bool = True) -> dict:
    """Whether the peer at ``depth`` traces, compiles and renders one ``size``² frame within
    ``timeout_s`` seconds (process start and scene load included), run in a subprocess that
    is killed at the timeout, so a hang or a runaway compile cannot stop the bench.
    ``cold_cache``: the subprocess gets empty kernel caches (a fresh ``$HOME``, where Dr.Jit
    and the CUDA driver keep theirs, and OptiX's cache off), so the time is a real compile. The scene is read from its file
    (``scene.path``, or a path). Returns {"depth", "compiles", "seconds" (trace + compile +
    first frame, or the timeout), "process_s", "operations", "error"}."""
    return probe_many([(scene, depth)], timeout_s, backend=backend, size=size,
                      cold_cache=cold_cache)[0]


def _probe_main(path: str, depth: int, backend: str, size: int) -> None:
    """Subprocess side of ``peer_compiles``: one traced peer frame; prints one JSON line."""
    import drjit as dr
    sc = load_scene(path).with_settings(max_depth=depth, exact=True).with_size(size)
    peer = load_peer(sc, backend=backend)
    pos = peer.positions()
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        dr.kernel_history()
        t0 = time.perf_counter()
        peer.frame(pos)
        dr.sync_thread()
        first = time.perf_counter() - t0
        ops = sum(int(h.get("operation_count", 0)) for h in dr.kernel_history())
    print(json.dumps({"first_frame_s": first, "operations": ops}))


def peer_depth_limit(scene, depths, timeout_s: float, *, jobs: int = 1, **kw) -> list[dict]:
    """``peer_compiles`` for ``depths`` in increasing order; with ``jobs == 1`` it stops at
    the first depth that does not compile (a deeper tree only grows), with more it probes
    them all at once."""
    depths = sorted(depths)
    if jobs > 1:
        return probe_many([(scene, d) for d in depths], timeout_s, jobs=jobs, **kw)
    probes = []
    for d in depths:
        probes.append(peer_compiles(scene, d, timeout_s, **kw))
        if not probes[-1]["compiles"]:
            break
    return probes


# ---- the part ------------------------------------------------------------------------------------
def _scene(s) -> Scene:
    if isinstance(s, Scene):
        return s
    p = Path(s)
    if not p.suffix:
        p = ROOT / "scenes" / f"{s}.toml"
    return load_scene(p)


def run_part(scenes, *, backend: str, sizes=(512, 1024), depths=(2, 5), frames: int = 20,
             probe_depths=None, probe_timeout_s: float = 120.0, probe_jobs: int = 1,
             log=None, on_row=None) -> list[dict]:
    """Probe, then time. Probes: for each scene (Scene, name or path) the peer's compile at
    ``probe_depths`` (default: the ``depths`` above 2), ``probe_jobs`` subprocesses at a
    time, each bounded by ``probe_timeout_s``; one row per probe (``"kind": "probe"``).
    Frames: ours vs the peer at each depth of ``depths`` and size of ``sizes``, skipped (a
    row with ``"compiles": False``) where a probe at that depth or below failed; one row per
    (scene, depth, size) (``"kind": "frame"``). ``on_row(rows)`` is called after each
    frame row (the command line writes its files there, so a run cut short keeps its rows)."""
    log = log or (lambda msg: print(msg, flush=True))
    scs = [_scene(s) for s in scenes]
    to_probe = sorted(set(probe_depths if probe_depths is not None
                          else [d for d in depths if d > 2]))
    if probe_jobs > 1:       # every (scene, depth) at once
        flat = probe_many([(sc, d) for sc in scs for d in to_probe], probe_timeout_s,
                          backend=backend, jobs=probe_jobs)
        per_scene = [flat[i * len(to_probe):(i + 1) * len(to_probe)] for i in range(len(scs))]
    else:                    # one at a time, each scene up to its first failing depth
        per_scene = [peer_depth_limit(sc, to_probe, probe_timeout_s, backend=backend)
                     if to_probe else [] for sc in scs]
    rows = []
    for sc, probes in zip(scs, per_scene):
        for p in probes:
            rows.append(dict(p, kind="probe", scene=sc.name, backend=backend))
            log(f"  probe {sc.name:16s} depth {p['depth']}: "
                + (f"compiles, first frame {p['seconds']:.1f} s" if p["compiles"]
                   else f"does not compile ({p['error']})"))
    for sc in scs:
        mine = [r for r in rows if r["kind"] == "probe" and r["scene"] == sc.name]
        limit = min((r["depth"] for r in mine if not r["compiles"]), default=None)
        for depth in depths:
            if limit is not None and depth >= limit:
                rows.append({"kind": "frame", "scene": sc.name, "depth": int(depth),
                             "backend": backend, "compiles": False,
                             "probe": next(r for r in mine if r["depth"] == limit)})
                if on_row:
                    on_row(rows)
                continue
            for size in sizes:
                r = whitted_frame_peer(sc, backend=backend, depth=depth, size=size,
                                       frames=frames)
                r.update(kind="frame", compiles=True,
                         probe=next((p for p in mine if p["depth"] == depth), None))
                rows.append(r)
                if on_row:
                    on_row(rows)
                d = r["difference"]
                log(f"  peer {sc.name:16s} d{depth} {size}²  ours {r['ours_frozen_ms']:.3f} ms "
                    f"(kernel {r['ours_kernel_ms']:.3f})  peer {r['peer_frozen_ms']:.3f} ms "
                    f"(kernel {r['peer_kernel_ms']:.3f})  x{r['speedup_frozen']:.2f}  "
                    f"rmse {d['rmse']:.1e}  within 1e-3 {d['within_1e-3']:.4f}")
    return rows


def markdown(rows: list[dict], device: dict | None = None) -> str:
    """The rows of ``run_part`` as markdown: the frame table, then the compile probes."""
    lines = []
    if device:
        lines += [f"## Whitted frame: ours vs a fair Mitsuba peer on {device.get('device')} "
                  f"({device.get('backend')})", ""]
    if any(r.get("kind") != "probe" for r in rows):
        lines += ["Both frozen (`dr.freeze`), exact mode, same scene, depth and size; ms = median "
                  "frame wall time (launch + wait), kernel ms = median kernel time from Dr.Jit's "
                  "kernel history, warm-up excluded. Difference = peer vs ours.", "",
                  "| scene | depth | size | ours ms | ours kernel ms | peer ms | peer kernel ms | "
                  "ours faster (frame, peer/ours) | ours faster (kernel) | peer kernels | RMSE | "
                  "px within 1e-3 | exact rule |",
                  "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: "
                  "| ---: | --- |"]
    for r in rows:
        if r.get("kind") == "probe":
            continue
        if not r.get("compiles", True):
            p = r.get("probe") or {}
            lines.append(f"| {r['scene']} | {r['depth']} | — | — | — | peer does not compile "
                         f"({p.get('error', '')}) | — | — | — | — | — | — | — |")
            continue
        d = r["difference"]
        rule = ("pass" if d["exact_ok"] else "fail") + f" ({d['edge_pixels']} edge px)"
        lines.append(f"| {r['scene']} | {r['depth']} | {r['size']}² | {r['ours_frozen_ms']:.3f} | "
                     f"{r['ours_kernel_ms']:.3f} | {r['peer_frozen_ms']:.3f} | "
                     f"{r['peer_kernel_ms']:.3f} | {r['speedup_frozen']:.2f}× | "
                     f"{r['speedup_kernel']:.2f}× | {r['peer_kernels']} | "
                     f"{d['rmse']:.1e} | {d['within_1e-3']:.4f} | {rule} |")
    probes = [r for r in rows if r.get("kind") == "probe"]
    if probes:
        lines += ["", "Peer compile probes (a subprocess per depth, empty kernel cache, 64² "
                  "frame; seconds = trace + compile + first frame):", "",
                  "| scene | depth | compiles | seconds | IR operations |",
                  "| --- | ---: | --- | ---: | ---: |"]
        for p in probes:
            lines.append(f"| {p['scene']} | {p['depth']} | "
                         f"{'yes' if p['compiles'] else 'no: ' + str(p['error'])} | "
                         f"{p['seconds']:.1f} | {p.get('operations', '—')} |")
    lines.append("")
    return "\n".join(lines)


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items() if k != "image"}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    return x


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--backend", default="llvm", choices=("llvm", "cuda"))
    ap.add_argument("--scenes", nargs="+", default=list(PEER_SCENES))
    ap.add_argument("--sizes", nargs="+", type=int, default=[512, 1024])
    ap.add_argument("--depths", nargs="+", type=int, default=[2, 5])
    ap.add_argument("--probe-depths", nargs="*", type=int, default=None,
                    help="depths to probe for compiling (default: the depths above 2)")
    ap.add_argument("--probe-timeout", type=float, default=120.0)
    ap.add_argument("--probe-jobs", type=int, default=1,
                    help="probe subprocesses at a time (>1: every scene and depth at once)")
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--probe-only", action="store_true",
                    help="only the compile probes, no frames (file suffix -probes)")
    ap.add_argument("--out", default=None, help="folder for peer-<backend>.json and .md")
    ap.add_argument("--probe", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--probe-depth", type=int, default=2, help=argparse.SUPPRESS)
    ap.add_argument("--probe-size", type=int, default=64, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.probe:
        _probe_main(a.probe, a.probe_depth, a.backend, a.probe_size)
        return 0
    info = device_info(a.backend)
    print(f"peer bench on {info.get('device')} ({a.backend})", flush=True)
    date = time.strftime("%Y-%m-%d %H:%M:%S")

    def write(rows):
        if not a.out:
            return
        out = Path(a.out)
        out.mkdir(parents=True, exist_ok=True)
        tag = a.backend + ("-probes" if a.probe_only else "")
        (out / f"peer-{tag}.json").write_text(json.dumps(
            _jsonable({"device": info, "date": date, "argv": sys.argv[1:], "rows": rows}),
            indent=1))
        (out / f"peer-{tag}.md").write_text(markdown(rows, info))

    rows = run_part(a.scenes, backend=a.backend, sizes=a.sizes,
                    depths=[] if a.probe_only else a.depths,
                    frames=a.frames, probe_depths=a.probe_depths,
                    probe_timeout_s=a.probe_timeout, probe_jobs=a.probe_jobs, on_row=write)
    write(rows)
    print(markdown(rows, info))
    return 0


if __name__ == "__main__":
    sys.exit(main())
