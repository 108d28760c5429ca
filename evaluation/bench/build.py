"""Part ``build``: how fast the BVH is built, how good the tree is, and how soon the first
image comes.

Per scene (``SCENES``; quick: ``QUICK_SCENES``), in one process on the same triangles:

- the device builds, each after one warm-up build (kernel compilation), median of
  ``REPEATS``: seconds, M triangles/s: the radix tree (``renderer.accel.device_build``,
  the ``device_*`` columns) and PLOC (``renderer.accel.ploc``, ``ploc_*``; what
  ``--build device`` runs, with whether it cut large triangles, and without the cuts,
  ``ploc_nocut_*``: "auto"'s tree for a first image), all on the backend's Dr.Jit, from
  the host's vertex and face arrays to the host's ``BVHArrays`` (the triangles' upload
  and the tree's copy back
  included, as Mitsuba's build below includes its mesh upload); PLOC without cuts also
  to the tree left on the device (``build_ploc_device``, ``ploc_device_*``: the tree the
  binary BVH's accelerator is made from, as Mitsuba's build leaves its structure on the
  device: the upload included, no copy back; the accelerator's own steps after it, the
  boxes padded for the traversal's extent and the packed triangles gathered into the
  tree's order, are in the process rows, not here); the radix tree also with
  ``raw=True`` (also copying back the unpadded boxes, what ``whitted render`` asks for so
  the traversal pads them without a host refit);
- the host SAH build (``bvh_build.build_bvh``, one build): seconds, M triangles/s;
- Mitsuba's own scene build (``reference.mitsuba_scene.load_triangles``: OptiX on CUDA,
  Embree on the CPU, forced by a first trace: ``_mitsuba_build``), first and second build;
- the SAH cost of the three trees, and a Whitted frame (the scene's first view at
  ``Context.frame_size``², the backend's accelerator, frozen: median kernel ms) over each,
  the three timed in turn for ``FRAME_ROUNDS`` rounds (the median of the rounds' medians,
  so a drifting machine's drift falls on the three trees alike), with whether the images
  are bitwise the SAH tree's;
- the process start-to-first-image: ``whitted render SCENE --size N×N`` (``PROCESS_SIZE``)
  with the SAH build and no cache (the tool before the device build and the cache, once),
  with ``--build auto`` and an empty cache (cold), then again (from the cache), the median
  of ``PROCESS_REPEATS`` processes each. The processes read compiled Python bytecode (as
  an installed package has; written by an untimed first process into a folder of the
  part's own, ``PYTHONPYCACHEPREFIX``, also where the environment turns bytecode off).

Each row carries the 1-minute load average before it ran (a shared CPU's numbers depend
on it). Run on a GPU host with one command:
``python -m whitted bench --backend cuda --parts build --out DIR``.
"""
from __future__ import annotations

import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .part import Context, Part, table

SCENES = ("bunny", "sponza", "conference", "bunny_1m")
QUICK_SCENES = ("cornell_box", "bunny")
REPEATS = 5
PROCESS_SIZE = 1024
#: Cold and cached processes per scene (medians); the SAH process without a cache runs once.
PROCESS_REPEATS = 3
#: Rounds of the three trees' frames, taken in turn (``frames.interleaved_frame_ms``).
FRAME_ROUNDS = 3


def _load(ctx: Context, name: str):
    from renderer.scene import load_scene
    t0 = time.perf_counter()
    scene = load_scene(ctx.scene_path(name))
    return scene, time.perf_counter() - t0


TIMING = re.compile(r"timing: imports ([\d.]+) s, load ([\d.]+) s, tree ([\d.]+) s, "
                    r"upload ([-\d.]+) s, first image at ([\d.]+) s")


def _process_env(cache: Path, pycache: Path) -> dict:
    """The environment of a timed ``whitted render`` process: its own tree cache, and Python
    bytecode written to and read from ``pycache`` (``PYTHONPYCACHEPREFIX``) even where the
    caller's environment turns bytecode off, as an installed package has it compiled."""
    env = dict(os.environ, WHITTED_CACHE=str(cache), PYTHONPYCACHEPREFIX=str(pycache))
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


def _process_seconds(ctx: Context, name: str, size: int, extra: list[str], env: dict
                     ) -> tuple[float, dict]:
    """Wall seconds of one ``whitted render`` process (start to exit, one image) in ``env``
    (``_process_env``), and the breakdown its ``timing:`` line gives (imports, load, tree,
    upload, first_image_at: from the command's imports; outside: the rest of the wall time,
    interpreter start, Dr.Jit's import and exit)."""
    with tempfile.TemporaryDirectory() as out:
        cmd = [sys.executable, "-m", "whitted", "render", str(ctx.scene_path(name)),
               "--backend", ctx.backend, "--size", f"{size}x{size}", "--out", out] + extra
        t0 = time.perf_counter()
        r = subprocess.run(cmd, env=env, capture_output=True, text=True)
        seconds = time.perf_counter() - t0
        if r.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)}: exit {r.returncode}: "
                               f"{r.stderr.strip().splitlines()[-1:]}")
        m = TIMING.search(r.stdout)
        parts = {}
        if m:
            parts = dict(zip(("imports", "load", "tree", "upload", "first_image_at"),
                             map(float, m.groups())))
            parts["outside"] = seconds - parts["first_image_at"]
        return seconds, parts


def _median_process(runs: list[tuple[float, dict]]) -> tuple[float, dict]:
    """The run of median wall time (its own breakdown with it)."""
    return sorted(runs, key=lambda r: r[0])[len(runs) // 2]


def process_rows(ctx: Context, name: str, size: int, pycache: Path) -> dict:
    """Time to first image of scene ``name``: one process with the SAH build and no cache,
    ``PROCESS_REPEATS`` cold processes (``--build auto``, each with an empty cache) and
    ``PROCESS_REPEATS`` cached ones (the last cold process's cache), medians."""
    row = {}
    with tempfile.TemporaryDirectory() as tmp:
        env = _process_env(Path(tmp) / "none", pycache)
        row["process_sah_nocache_s"], row["process_sah_nocache_parts"] = _process_seconds(
            ctx, name, size, ["--build", "sah", "--no-cache"], env)
        cold = []
        for i in range(PROCESS_REPEATS):
            env = _process_env(Path(tmp) / f"cache{i}", pycache)
            cold.append(_process_seconds(ctx, name, size, [], env))
        cached = [_process_seconds(ctx, name, size, [], env) for _ in range(PROCESS_REPEATS)]
    row["process_cold_s"], row["process_cold_parts"] = _median_process(cold)
    row["process_cached_s"], row["process_cached_parts"] = _median_process(cached)
    row["process_repeats"] = PROCESS_REPEATS
    return row


def _median_build(build) -> tuple[float, object]:
    """The median ``build_seconds`` of ``REPEATS`` calls of ``build`` (a device build, after
    its warm-up; the device idle before each), and the last tree."""
    import drjit as dr
    times = []
    for _ in range(REPEATS):
        dr.sync_thread()
        tree = build()
        times.append(tree.build_seconds)
    return statistics.median(times), tree


def _mitsuba_build(scene) -> float:
    """Seconds of Mitsuba's scene build on ``scene``'s triangles: ``mi.load_dict`` plus the
    first ``ray_test`` of one ray (OptiX builds its acceleration structure lazily, at the
    first trace), minus a second, warm ``ray_test`` of the same ray."""
    import drjit as dr

    from reference.mitsuba_scene import load_triangles, rays
    c = np.asarray(scene.vertices, np.float64).mean(axis=0)
    ray = rays(c[None] + [0.0, 0.0, 1e3], np.array([[0.0, 0.0, -1.0]]))
    dr.sync_thread()
    t0 = time.perf_counter()
    mscene, _ = load_triangles(scene.vertices, scene.faces)
    hit = mscene.ray_test(ray)
    dr.eval(hit)
    dr.sync_thread()
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    hit = mscene.ray_test(ray)
    dr.eval(hit)
    dr.sync_thread()
    return max(first - (time.perf_counter() - t0), 0.0)


def build_row(ctx: Context, name: str, pycache: Path) -> dict:
    """The measurements of one scene (see the module docstring)."""

    from reference import mitsuba_variant
    from renderer.accel.bvh_build import build_bvh
    from renderer.accel.device_build import build_device
    from renderer.accel.ploc import build_ploc, build_ploc_device

    from .frames import interleaved_frame_ms
    row = {"scene": name, "load_avg_1min": os.getloadavg()[0]}
    scene, row["load_s"] = _load(ctx, name)
    F = scene.face_count
    row["triangles"] = F
    build_device(scene.vertices, scene.faces, ctx.backend)          # warm-up: compilation
    row["device_s"], dev = _median_build(lambda: build_device(scene.vertices, scene.faces,
                                                              ctx.backend))
    row["device_mtris_s"] = F / row["device_s"] / 1e6
    row["device_sah_cost"], row["device_levels"] = dev.sah_cost, dev.levels
    row["device_raw_s"], _ = _median_build(lambda: build_device(
        scene.vertices, scene.faces, ctx.backend, raw=True))
    phases = {}
    build_device(scene.vertices, scene.faces, ctx.backend, phases=phases)
    row["device_phases_s"] = phases          # one more build, waiting at each phase's end
    build_ploc(scene.vertices, scene.faces, ctx.backend)            # warm-up: compilation
    pl_stats = {}
    row["ploc_s"], pl = _median_build(lambda: build_ploc(scene.vertices, scene.faces,
                                                         ctx.backend, stats=pl_stats))
    row["ploc_mtris_s"] = F / row["ploc_s"] / 1e6
    row["ploc_sah_cost"], row["ploc_levels"] = pl.sah_cost, pl.levels
    phases = {}
    build_ploc(scene.vertices, scene.faces, ctx.backend, stats={"phases": phases})
    row["ploc_phases_s"] = phases
    build_ploc(scene.vertices, scene.faces, ctx.backend, cuts=False)             # warm-up
    row["ploc_cut"] = bool(pl_stats.get("cut"))
    row["ploc_nocut_s"], whole = _median_build(lambda: build_ploc(
        scene.vertices, scene.faces, ctx.backend, cuts=False))
    row["ploc_nocut_mtris_s"] = F / row["ploc_nocut_s"] / 1e6
    row["ploc_device_s"], _ = _median_build(lambda: build_ploc_device(
        scene.vertices, scene.faces, ctx.backend, cuts=False))
    row["ploc_device_mtris_s"] = F / row["ploc_device_s"] / 1e6
    row["ploc_nocut_sah_cost"] = whole.sah_cost
    sah = build_bvh(scene.vertices, scene.faces)
    row["sah_s"] = sah.build_seconds
    row["sah_mtris_s"] = F / sah.build_seconds / 1e6
    row["sah_sah_cost"], row["sah_levels"] = sah.sah_cost, sah.levels
    mitsuba_variant("cuda_ad_rgb" if ctx.backend == "cuda" else "llvm_ad_rgb")
    row["mitsuba_build_s"] = _mitsuba_build(scene)
    row["mitsuba_build_again_s"] = _mitsuba_build(scene)
    row["mitsuba_mtris_s"] = F / row["mitsuba_build_again_s"] / 1e6
    row["speedup_vs_sah"] = row["sah_s"] / row["device_s"]
    row["vs_mitsuba"] = row["mitsuba_build_again_s"] / row["device_s"]
    # a Whitted frame over each tree: the builder is picked through the scene's settings
    frames = interleaved_frame_ms(
        {b: scene.with_settings(build=b).with_size(ctx.frame_size)
         for b in ("sah", "radix", "ploc")},
        backend=ctx.backend, accel=None, frames=ctx.frames, rounds=FRAME_ROUNDS)
    row["frame_rounds_kernel_ms"] = {b: f["rounds_kernel_ms"] for b, f in frames.items()}
    row["frame_ms_sah"] = frames["sah"]["frozen_kernel_ms"]
    row["frame_ms_device"] = frames["radix"]["frozen_kernel_ms"]
    row["frame_ms_ploc"] = frames["ploc"]["frozen_kernel_ms"]
    row["frame_ratio"] = row["frame_ms_device"] / max(row["frame_ms_sah"], 1e-9)
    row["ploc_frame_ratio"] = row["frame_ms_ploc"] / max(row["frame_ms_sah"], 1e-9)
    row["frames_bitwise_equal"] = all(bool(np.array_equal(frames["sah"]["image"],
                                                          frames[b]["image"]))
                                      for b in ("radix", "ploc"))
    size = 64 if ctx.quick else PROCESS_SIZE
    row["process_size"] = size
    row.update(process_rows(ctx, name, size, pycache))
    return row


def run(ctx: Context) -> list[dict]:
    rows = []
    names = [n for n in (QUICK_SCENES if ctx.quick else SCENES) if ctx.scene_path(n).exists()]
    with tempfile.TemporaryDirectory() as pycache:
        if names:                       # compiles the bytecode the timed processes read
            with tempfile.TemporaryDirectory() as cache:
                _process_seconds(ctx, names[0], 64, ["--no-cache"],
                                 _process_env(Path(cache), Path(pycache)))
        for name in names:
            rows.append(_build_row_printed(ctx, name, Path(pycache)))
            ctx.save_rows(rows)
    return rows


def _build_row_printed(ctx: Context, name: str, pycache: Path) -> dict:
    r = build_row(ctx, name, pycache)
    print(f"  build {name:12s} {r['triangles']:>8d} tris: radix {r['device_s']:.3f} s "
          f"({r['device_mtris_s']:.2f} M/s), PLOC {r['ploc_s']:.3f} s "
          f"({r['ploc_mtris_s']:.2f} M/s, frame x{r['ploc_frame_ratio']:.2f}), "
          f"SAH {r['sah_s']:.2f} s, Mitsuba "
          f"{r['mitsuba_build_again_s']:.3f} s; SAH cost {r['device_sah_cost']:.1f} vs "
          f"{r['sah_sah_cost']:.1f}; frame x{r['frame_ratio']:.2f}; process "
          f"{r['process_sah_nocache_s']:.1f} -> {r['process_cold_s']:.1f} cold, "
          f"{r['process_cached_s']:.1f} cached", flush=True)
    return r


def markdown(rows: list[dict]) -> list[str]:
    cells = [[r["scene"], f"{r['triangles']:,}", f"{r['device_s']:.3f}",
              f"{r['device_mtris_s']:.2f}",
              f"{r['device_raw_s']:.3f}" if "device_raw_s" in r else "",
              _get(r, "ploc_s", ".3f"),
              _get(r, "ploc_mtris_s", ".2f"),
              ("yes" if r["ploc_cut"] else "no") if "ploc_cut" in r else "-",
              _get(r, "ploc_nocut_s", ".3f"), _get(r, "ploc_nocut_mtris_s", ".2f"),
              _get(r, "ploc_device_s", ".4f"), _get(r, "ploc_device_mtris_s", ".2f"),
              f"{r['sah_s']:.2f}", f"{r['sah_mtris_s']:.3f}",
              f"{r['mitsuba_build_s']:.3f} / {r['mitsuba_build_again_s']:.3f}",
              f"{r['mitsuba_mtris_s']:.2f}", f"{r['load_avg_1min']:.1f}"] for r in rows]
    out = table("Build: device (Dr.Jit: radix, PLOC) vs host SAH vs Mitsuba's scene build, "
                "one process",
                ["scene", "triangles", "radix s", "radix M/s", "radix + raw boxes s", "PLOC s",
                 "PLOC M/s", "PLOC cut", "PLOC no cuts s", "PLOC no cuts M/s",
                 "PLOC no cuts, on device s", "on device M/s", "SAH s",
                 "SAH M/s", "Mitsuba s (1st / 2nd)", "Mitsuba M/s", "load avg"],
                "lrrrrrrlrrrrrrrrr", cells)
    names = list(rows[0].get("device_phases_s", {})) if rows else []
    cells = [[r["scene"]] + [f"{1e3 * r['device_phases_s'].get(n, 0.0):.1f}" for n in names]
             for r in rows if r.get("device_phases_s")]
    out += table("Radix build by phase (ms; one build that waits at each phase's end)",
                 ["scene"] + names, "l" + "r" * len(names), cells)
    names = _phase_names(rows, "ploc_phases_s")      # (deep subtrees: some scenes only)
    cells = [[r["scene"]] + [_get(r["ploc_phases_s"], n, ".1f", 1e3) for n in names]
             for r in rows if r.get("ploc_phases_s")]
    if cells:
        out += table("PLOC build by phase (ms; one build that waits at each phase's end)",
                     ["scene"] + names, "l" + "r" * len(names), cells)
    cells = [[r["scene"], f"{r['device_sah_cost']:.2f}", _get(r, "ploc_sah_cost", ".2f"),
              f"{r['sah_sah_cost']:.2f}",
              f"{r['device_levels']} / {r.get('ploc_levels', '-')} / {r['sah_levels']}",
              f"{r['frame_ms_device']:.3f}", _get(r, "frame_ms_ploc", ".3f"),
              f"{r['frame_ms_sah']:.3f}", f"{r['frame_ratio']:.2f}",
              _get(r, "ploc_frame_ratio", ".2f"),
              "yes" if r["frames_bitwise_equal"] else "NO"] for r in rows]
    out += table("Trees: SAH cost and a frozen Whitted frame (kernel ms) over each",
                 ["scene", "SAH cost radix", "SAH cost PLOC", "SAH cost SAH",
                  "levels radix / PLOC / SAH", "frame ms radix", "frame ms PLOC",
                  "frame ms SAH", "radix / SAH", "PLOC / SAH", "same image"],
                 "lrrrrrrrrrl", cells)
    cells = [[r["scene"], f"{r['process_size']}²", f"{r['process_sah_nocache_s']:.2f}",
              f"{r['process_cold_s']:.2f}", f"{r['process_cached_s']:.2f}"] for r in rows]
    n = rows[0].get("process_repeats", 1) if rows else 1
    out += table("Time to first image: one `whitted render` process, start to exit"
                 + (f" (cold and cached: median of {n} processes)" if n > 1 else ""),
                 ["scene", "size", "SAH, no cache s", "auto, cold cache s",
                  "auto, cached s"], "lrrrr", cells)
    cells = []
    for r in rows:
        for key, label in (("sah_nocache", "SAH, no cache"), ("cold", "auto, cold"),
                           ("cached", "auto, cached")):
            p = r.get(f"process_{key}_parts") or {}
            if p:
                frame = (p["first_image_at"] - p["imports"] - p["load"] - p["tree"]
                         - p["upload"])
                cells.append([r["scene"], label, f"{r[f'process_{key}_s']:.2f}"]
                             + [f"{p[k]:.2f}" for k in ("outside", "imports", "load", "tree",
                                                         "upload")] + [f"{frame:.2f}"])
    out += table("Where a `whitted render` process spends its time (s; `outside`: interpreter "
                 "start, Dr.Jit's import and exit, `frame`: the rest up to the first image, "
                 "compilation "
                 "included)", ["scene", "run", "wall", "outside", "imports", "load", "tree",
                               "upload", "frame"], "llrrrrrrr", cells)
    return out


def _get(row: dict, key: str, fmt: str, scale: float = 1.0) -> str:
    """``row[key]`` (times ``scale``) formatted, or "-" (rows written before the PLOC
    columns, a phase a build did not run)."""
    return "-" if row.get(key) is None else format(scale * row[key], fmt)


def _phase_names(rows: list, key: str) -> list:
    """The phase names of ``rows[i][key]`` (dicts) in build order: every row's phases, one
    that only some rows ran placed after the phase it follows there."""
    names = []
    for r in rows:
        prev = None
        for n in r.get(key) or {}:
            if n not in names:
                names.insert(names.index(prev) + 1 if prev is not None else 0, n)
            prev = n
    return names


PART = Part(name="build", key="build", run=run, markdown=markdown)
