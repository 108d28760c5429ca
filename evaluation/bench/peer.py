"""Part ``peer``: our frozen Whitted frame vs a fair Mitsuba peer, timed side by side.

The peer (``reference.peer``) is the one-kernel, frozen Whitted integrator a competent
Mitsuba 3 user would write, over the same translated scene, at the same depth, resolution
and exact mode (one ray per pixel centre). Both sides are timed the same way: the median
over ``frames`` frozen frames after warm-up of a frame's wall time (launch + wait) and of
its kernel time from Dr.Jit's kernel history. The image difference (peer vs ours) is
reported with the harness's exact-mode rule.

The peer's tree is unrolled at trace time, so deep trees may not compile in reasonable time
(on CUDA, OptiX does not compile depth 5 within 8 minutes). Each depth above 2 is first
probed in a subprocess with a timeout (``peer_compiles``, several at once), and the part
then times, per scene (``plan`` gives the sizes, depths and timeouts per backend):

1. ours vs the peer at depth 2 at 1024² (quick: 256²);
2. ours alone at the scene's own ``max_depth`` (5; 8 for the glass bunny) where the peer
   did not compile there, at 1024² (quick: 128²);
3. ours vs the peer at depth 2 at 512² (quick: 128²);
4. ours vs the peer at the deepest depth the peer compiled (capped at the scene's depth),
   at 1024² (quick: 128²).

Rows are saved after each one (``Context.save_rows``), so a run cut short keeps them; the
order above puts what matters most and costs least first (each peer row pays a compile:
on LLVM the same scene and depth at a second size missed Dr.Jit's kernel cache).

Entry points: ``whitted_frame_peer(scene, ...)`` (one scene, depth, size),
``ours_frame(scene, ...)``, ``peer_compiles(scene, depth, timeout_s)``, ``probe_many``,
``run(ctx)``, ``markdown(rows)``. ``python -m evaluation.bench.peer --probe ...`` is the
probe's subprocess side.
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
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from evaluation.gate.metrics import image_difference
from evaluation.gate.rules import EXACT_THRESHOLDS, check_exact, tie_probe

from .. import SEED_SCENES
from .frames import frozen_frame_ms
from .part import Context, Part, table

ROOT = Path(__file__).resolve().parents[2]
#: The scenes of the peer comparison: the seed scenes and the glass bunny.
PEER_SCENES = SEED_SCENES + ("glass_bunny",)
#: The depth every scene is compared at (the peer compiles it on every backend).
BASE_DEPTH = 2


@dataclass(frozen=True)
class Plan:
    """What the part measures: frame sizes (sides, px), depths probed above ``BASE_DEPTH``,
    the probe timeout (s), probe subprocesses at a time, frozen frames per timing, and the
    size of the rows beyond ``BASE_DEPTH``."""

    sizes: tuple[int, ...]
    probe_depths: tuple[int, ...]
    probe_timeout_s: float
    probe_jobs: int
    frames: int
    deep_size: int


def plan(ctx: Context, n_scenes: int = len(PEER_SCENES)) -> Plan:
    """The part's plan on ``ctx``'s backend. CUDA: probes at depths 3-5, 45 s each, all at
    once (the whole part fits in about 5 minutes on a GPU); LLVM: 3-6, 120 s each, as many at
    once as there are cores; quick: depth 3 only, 60 s, 128²/256² frames at depth 2 and
    128² beyond. Full runs time the deeper rows at 1024²."""
    cores = os.cpu_count() or 1
    if ctx.quick:
        s = ctx.frame_size
        return Plan((s, 2 * s), (3,), 60.0, max(1, min(cores, n_scenes)), ctx.frames, s)
    if ctx.backend == "cuda":
        return Plan((512, 1024), (3, 4, 5), 45.0, 3 * n_scenes, ctx.frames, 1024)
    return Plan((512, 1024), (3, 4, 5, 6), 120.0, cores, ctx.frames, 1024)


# ---- timing ------------------------------------------------------------------------------
def _jit_kernels(history) -> int:
    """Compiled kernels in a kernel history (not memcpy, aggregate or host-function entries)."""
    import drjit as dr
    return sum(1 for h in history if h.get("type") == dr.KernelType.JIT)


@contextlib.contextmanager
def _no_collection():
    """Collect garbage now and not during the block: Python's cycle collector freeing device
    memory while ``dr.freeze`` records a frame makes Dr.Jit abort ("enqueue_host_func():
    this function cannot be recorded"), and Mitsuba scenes left from an earlier row are
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


def peer_frame_ms(scene, *, backend: str, frames: int = 20, warmup: int = 3) -> dict:
    """The peer on ``scene`` (its size and ``settings.max_depth``): traced first frame
    (trace + compile) wall ms, JIT kernels per frame, frozen frame wall/kernel ms (median of
    ``frames`` after ``warmup``), whether the frozen frame equals the traced one, the image."""
    import drjit as dr

    from reference.peer import load_peer
    from renderer.stats import kernel_launches, kernel_ms
    peer = load_peer(scene, backend=backend)
    pos = peer.positions()

    def frame():
        img = peer.frame(pos)
        dr.eval(img)
        return img
    img, hist, traced_ms = kernel_launches(frame)
    traced = np.asarray(img.numpy(), np.float32)
    run_frozen = peer.frozen()
    timing = kernel_ms(lambda: run_frozen(pos), warmup=warmup, repeats=frames)
    frozen = np.asarray(run_frozen(pos).numpy(), np.float32)
    ops = [int(h["operation_count"]) for h in hist if "operation_count" in h]
    return {"frozen_ms": timing["wall_ms"], "frozen_kernel_ms": timing["kernel_ms"],
            "traced_ms": traced_ms, "jit_kernels": _jit_kernels(hist),
            "launches": timing["kernels"], "operations": sum(ops),
            "frozen_equals_traced": bool(np.array_equal(traced, frozen)), "image": traced}


def agreement(ours: np.ndarray, peer: np.ndarray, ties: np.ndarray | None = None) -> dict:
    """Peer vs ours: the bench's image difference, the fraction of pixels whose channels all
    agree within 1e-3 (absolute), and the harness's exact-mode rule (``check_exact``, the
    peer in the golden's place; ``ties``: our tie mask, ``evaluation.gate.rules.tie_probe``,
    without which no pixel is excused)."""
    d = image_difference(ours, peer)
    err = np.abs(np.asarray(ours, np.float64) - np.asarray(peer, np.float64)).max(-1)
    d["within_1e-3"] = float(np.mean(err <= 1e-3))
    ex = check_exact(ours, peer, EXACT_THRESHOLDS, ties)
    d.update(exact_ok=ex["ok"], excused_pixels=ex["excused_pixels"],
             hard_pixels=ex["hard_pixels"], tie_pixels=ex["tie_pixels"],
             mean_rel_held=ex["mean_rel"])
    return d


def tie_mask(scene, backend: str, accel: str | None) -> np.ndarray:
    """Our tie mask of ``scene``'s first view (``evaluation.gate.rules.tie_probe``; untimed)."""
    return tie_probe(scene, 0, backend=backend, accel=accel)[1]


def _at(scene, depth: int, size: int):
    return scene.with_settings(max_depth=int(depth), exact=True).with_size(int(size))


def ours_frame(scene, *, backend: str, depth: int, size: int, frames: int = 20,
               accel: str | None = None) -> dict:
    """Ours alone (frozen ``Renderer``, exact mode) on ``scene`` at ``depth`` and ``size``²:
    a row without the peer's columns."""
    sc = _at(scene, depth, size)
    with _no_collection():
        ours = frozen_frame_ms(sc, backend=backend, accel=accel, frames=frames)
    return {"scene": sc.name, "size": int(size), "depth": int(depth), "backend": backend,
            "frames": frames, "ours_frozen_ms": ours["frozen_ms"],
            "ours_kernel_ms": ours["frozen_kernel_ms"], "ours_traced_ms": ours["traced_ms"],
            "ours_kernels": ours["kernels"],
            "ours_frozen_equals_traced": ours["frozen_equals_traced"], "image": ours["image"]}


def whitted_frame_peer(scene, *, backend: str, depth: int, size: int, frames: int = 20,
                       accel: str | None = None) -> dict:
    """Ours vs the peer on ``scene`` at ``depth`` and ``size``², both timed as frozen frames;
    plus the image difference and the speed-ups (peer ms / ours ms)."""
    row = ours_frame(scene, backend=backend, depth=depth, size=size, frames=frames,
                     accel=accel)
    with _no_collection():
        peer = peer_frame_ms(_at(scene, depth, size), backend=backend, frames=frames)
    row.update(peer_frozen_ms=peer["frozen_ms"], peer_kernel_ms=peer["frozen_kernel_ms"],
               peer_traced_ms=peer["traced_ms"], peer_kernels=peer["jit_kernels"],
               peer_operations=peer["operations"],
               peer_frozen_equals_traced=peer["frozen_equals_traced"],
               difference=agreement(row.pop("image"), peer["image"],
                                    tie_mask(_at(scene, depth, size), backend, accel)))
    row["speedup_frozen"] = row["peer_frozen_ms"] / row["ours_frozen_ms"]
    row["speedup_kernel"] = (row["peer_kernel_ms"] / row["ours_kernel_ms"]
                             if row["ours_kernel_ms"] > 0 else float("nan"))
    return row


# ---- compile probes ------------------------------------------------------------------------
def _probe_cmd(scene, depth: int, backend: str, size: int) -> list[str]:
    path = scene if isinstance(scene, (str, Path)) else scene.path
    if path is None:
        raise ValueError("peer_compiles: the scene needs a file path (scene.path)")
    return [sys.executable, "-m", "evaluation.bench.peer", "--probe", str(path),
            "--depth", str(int(depth)), "--backend", backend, "--size", str(int(size))]


def probe_many(items, timeout_s: float, *, backend: str = "llvm", size: int = 64,
               cold_cache: bool = True, jobs: int = 1) -> list[dict]:
    """``peer_compiles`` for each ``(scene, depth)`` of ``items``, ``jobs`` subprocesses at
    a time, each killed ``timeout_s`` seconds after it started (and all of them on Ctrl-C).
    Results in the order of ``items``."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    items = list(items)
    results: list[dict | None] = [None] * len(items)
    running: dict[int, tuple] = {}
    todo = list(range(len(items)))
    with tempfile.TemporaryDirectory(prefix="peer-probe-") as tmp:
        try:
            while todo or running:
                while todo and len(running) < max(1, jobs):
                    i = todo.pop(0)
                    scene, depth = items[i]
                    e = dict(env)
                    if cold_cache:                 # empty kernel caches per probe
                        e["HOME"] = os.path.join(tmp, str(i))
                        os.makedirs(e["HOME"])
                        e["OPTIX_CACHE_MAXSIZE"] = "0"     # OptiX keeps its own cache
                    out = open(os.path.join(tmp, f"{i}.out"), "w+")
                    err = open(os.path.join(tmp, f"{i}.err"), "w+")
                    proc = subprocess.Popen(_probe_cmd(scene, depth, backend, size), env=e,
                                            cwd=ROOT, stdout=out, stderr=err, text=True)
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
                        results[i] = {"depth": depth, "compiles": False,
                                      "seconds": float(timeout_s),
                                      "error": f"timeout after {timeout_s:g} s"}
                    else:
                        out.seek(0)
                        err.seek(0)
                        lines = out.read().strip().splitlines()
                        if proc.returncode != 0 or not lines:
                            tail = (err.read().strip().splitlines()
                                    or [f"exit {proc.returncode}"])
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
        finally:
            for proc, *_ in running.values():
                proc.kill()
                proc.wait()
    return results


def peer_compiles(scene, depth: int, timeout_s: float, *, backend: str = "llvm",
                  size: int = 64, cold_cache: bool = True) -> dict:
    """Whether the peer at ``depth`` traces, compiles and renders one ``size``² frame within
    ``timeout_s`` seconds (process start and scene load included), in a subprocess killed at
    the timeout, so a runaway compile cannot stop the bench. ``cold_cache``: the subprocess
    gets empty kernel caches (a fresh ``$HOME``, where Dr.Jit and the CUDA driver keep
    theirs, and OptiX's cache off), so the time is a real compile. The scene is read from
    its file (``scene.path``, or a path). Returns {"depth", "compiles", "seconds" (trace +
    compile + first frame, or the timeout), "process_s", "operations", "error"}."""
    return probe_many([(scene, depth)], timeout_s, backend=backend, size=size,
                      cold_cache=cold_cache)[0]


def _probe_main(path: str, depth: int, backend: str, size: int) -> None:
    """Subprocess side of ``peer_compiles``: one traced peer frame; prints one JSON line."""

    from reference.peer import load_peer
    from renderer.scene import load_scene
    from renderer.stats import kernel_launches
    sc = _at(load_scene(path), depth, size)
    peer = load_peer(sc, backend=backend)
    pos = peer.positions()
    _, hist, wall_ms = kernel_launches(lambda: peer.frame(pos))
    ops = sum(int(h.get("operation_count", 0)) for h in hist)
    print(json.dumps({"first_frame_s": wall_ms * 1e-3, "operations": ops}))


def deepest(probes: list[dict]) -> int:
    """The deepest depth up to which every probe compiled (``BASE_DEPTH`` if none did)."""
    best = BASE_DEPTH
    for p in sorted(probes, key=lambda p: p["depth"]):
        if not p["compiles"]:
            break
        best = p["depth"]
    return best


# ---- the part ------------------------------------------------------------------------------
def run(ctx: Context) -> list[dict]:
    """Probe, then time (module docstring); every scene of ``PEER_SCENES`` present."""
    from renderer.scene import load_scene
    names = [n for n in PEER_SCENES if ctx.scene_path(n).exists()]
    p = plan(ctx, len(names))
    scenes = [load_scene(ctx.scene_path(n)) for n in names]
    rows: list[dict] = []

    def add(row: dict) -> None:
        rows.append({k: v for k, v in row.items() if k != "image"})
        ctx.save_rows(rows)

    print(f"  peer: probing depths {list(p.probe_depths)} ({p.probe_timeout_s:g} s each, "
          f"{p.probe_jobs} at a time) on {len(scenes)} scenes", flush=True)
    flat = probe_many([(sc, d) for sc in scenes for d in p.probe_depths], p.probe_timeout_s,
                      backend=ctx.backend, jobs=p.probe_jobs)
    n = len(p.probe_depths)
    probes = {sc.name: flat[i * n:(i + 1) * n] for i, sc in enumerate(scenes)}
    for sc in scenes:
        for pr in probes[sc.name]:
            add(dict(pr, kind="probe", scene=sc.name, backend=ctx.backend))
            print(f"  peer probe {sc.name:16s} depth {pr['depth']}: "
                  + (f"compiles, first frame {pr['seconds']:.1f} s" if pr["compiles"]
                     else f"does not compile ({pr['error']})"), flush=True)

    def timed(sc, depth: int, size: int, with_peer: bool) -> None:
        if with_peer:
            r = whitted_frame_peer(sc, backend=ctx.backend, depth=depth, size=size,
                                   frames=p.frames)
        else:
            r = ours_frame(sc, backend=ctx.backend, depth=depth, size=size, frames=p.frames)
            r["peer_note"] = peer_note(probes[sc.name])
        add(dict(r, kind="frame"))
        line = f"  peer {sc.name:16s} d{depth} {size}²  ours {r['ours_frozen_ms']:.3f} ms"
        if with_peer:
            line += (f"  peer {r['peer_frozen_ms']:.3f} ms  x{r['speedup_frozen']:.2f}  "
                     f"within 1e-3 {r['difference']['within_1e-3']:.4f}")
        else:
            line += f"  (peer {r['peer_note']})"
        print(line, flush=True)

    first, *rest = sorted(p.sizes, reverse=True)
    for sc in scenes:                       # 1. the common depth, the largest size
        timed(sc, BASE_DEPTH, first, True)
    for sc in scenes:                       # 2. ours at the scene's own depth (no peer)
        if sc.settings.max_depth > deepest(probes[sc.name]):
            timed(sc, sc.settings.max_depth, p.deep_size, False)
    for size in rest:                       # 3. the common depth, the other sizes
        for sc in scenes:
            timed(sc, BASE_DEPTH, size, True)
    for sc in scenes:                       # 4. the peer's deepest compiling depth
        deep = min(deepest(probes[sc.name]), sc.settings.max_depth)
        if deep > BASE_DEPTH:
            timed(sc, deep, p.deep_size, True)
    return rows


def peer_note(probes: list[dict]) -> str:
    """Why the peer is not timed beyond ``deepest(probes)``: the first failing probe, or
    that no deeper depth was probed."""
    bad = next((p for p in sorted(probes, key=lambda p: p["depth"]) if not p["compiles"]),
               None)
    if bad is not None:
        return f"does not compile at depth {bad['depth']} ({bad['error']})"
    return f"not probed above depth {deepest(probes)}"


def _peer_cells(r: dict) -> list[str]:
    if "peer_frozen_ms" not in r:
        return [r.get("peer_note", "not timed"), "—", "—", "—", "—", "—", "—"]
    d = r["difference"]
    excused = d.get("excused_pixels", d.get("edge_pixels"))     # older rows: edge_pixels
    rule = ("pass" if d["exact_ok"] else "fail") + f" ({excused} excused px)"
    return [f"{r['peer_frozen_ms']:.3f}", f"{r['peer_kernel_ms']:.3f}",
            f"{r['speedup_frozen']:.2f}×", f"{r['speedup_kernel']:.2f}×",
            f"{d['rmse']:.1e}", f"{d['within_1e-3']:.4f}", rule]


def markdown(rows: list[dict]) -> list[str]:
    order = {n: i for i, n in enumerate(dict.fromkeys(r["scene"] for r in rows))}
    frames = sorted((r for r in rows if r.get("kind") == "frame"),
                    key=lambda r: (order[r["scene"]], r["depth"], r["size"]))
    probes = [r for r in rows if r.get("kind") == "probe"]
    lines = []
    if frames:
        lines += table("Whitted frame, ours vs a fair Mitsuba peer (one kernel, frozen), "
                       "exact mode",
                       ["scene", "depth", "size", "ours ms", "ours kernel ms", "peer ms",
                        "peer kernel ms", "ours faster (frame)", "ours faster (kernel)",
                        "RMSE", "px within 1e-3", "exact rule"], "lrrrrrrrrrrl",
                       [[r["scene"], f"{r['depth']}", f"{r['size']}²",
                         f"{r['ours_frozen_ms']:.3f}", f"{r['ours_kernel_ms']:.3f}"]
                        + _peer_cells(r) for r in frames])
        lines[-1:-1] = ["", "ms: median frozen-frame wall time (launch + wait); kernel ms: "
                        "median kernel time (Dr.Jit's kernel history); ours faster = peer / "
                        "ours; RMSE etc.: peer vs ours. Rows without the peer: ours at the "
                        "scene's own depth, beyond the deepest depth the peer compiled "
                        "in the probes below."]
    if probes:
        lines += table("Peer compile probes (a subprocess per depth, empty kernel caches, "
                       "64² frame; seconds = trace + compile + first frame)",
                       ["scene", "depth", "compiles", "seconds", "IR operations"], "lrlrr",
                       [[p["scene"], f"{p['depth']}",
                         "yes" if p["compiles"] else "no: " + str(p["error"]),
                         f"{p['seconds']:.1f}", f"{p.get('operations') or '—'}"]
                        for p in probes])
    return lines


PART = Part(name="peer", key="peer", run=run, markdown=markdown)


def main(argv=None) -> int:
    """The probe's subprocess side (``peer_compiles``)."""
    ap = argparse.ArgumentParser(description="peer compile probe: one traced peer frame")
    ap.add_argument("--probe", required=True, help="scene file")
    ap.add_argument("--depth", type=int, required=True)
    ap.add_argument("--backend", default="llvm", choices=("llvm", "cuda"))
    ap.add_argument("--size", type=int, default=64)
    a = ap.parse_args(argv)
    _probe_main(a.probe, a.depth, a.backend, a.size)
    return 0


if __name__ == "__main__":
    sys.exit(main())
