"""Frozen-frame timing shared by the frame parts (seed table, Whitted frame, effects)."""
from __future__ import annotations

import time

import drjit as dr
import numpy as np

from renderer.stats import kernel_ms, kernel_operations


def frozen_frame_ms(scene, *, backend: str, accel: str | None, view: int = 0, effects=None,
                    frames: int = 20, warmup: int = 3, size: tuple[int, int] | None = None) -> dict:
    """Median time of ``frames`` frozen frames of ``scene`` (after ``warmup``), plus the
    traced (first) frame's wall time and the kernels' operation counts.

    size: (width, height) to render at (None: the scene's). Returns a dict: frozen_ms
    (median wall ms of a frozen frame), frozen_kernel_ms (median kernel ms), traced_ms,
    operations, largest_kernel_ops, kernels (of the traced frame), frozen_equals_traced,
    frames, effects (text) and image (the traced frame, float32 (H, W, 3)).
    """
    run = _FrozenFrame(scene, backend, accel, view, effects, size)
    timing = run.time(warmup, frames)
    return run.result(timing["wall_ms"], timing["kernel_ms"], frames)


def interleaved_frame_ms(scenes: dict, *, backend: str, accel: str | None, view: int = 0,
                         frames: int = 20, warmup: int = 3, rounds: int = 3) -> dict:
    """``frozen_frame_ms`` of each scene of ``scenes`` (label -> scene), timed in
    ``rounds`` rounds that take the scenes in turn (``frames`` frames each after
    ``warmup``), so a drifting machine's drift falls on every scene alike: label -> the
    ``frozen_frame_ms`` dict, its ``frozen_ms`` / ``frozen_kernel_ms`` the medians of the
    rounds' medians, with ``rounds_kernel_ms`` (each round's). The renderers stay alive
    for the rounds (one tree and one recording per scene)."""
    runs = {k: _FrozenFrame(sc, backend, accel, view, None, None) for k, sc in scenes.items()}
    walls = {k: [] for k in runs}
    kernels = {k: [] for k in runs}
    for _ in range(rounds):
        for k, run in runs.items():
            timing = run.time(warmup, frames)
            walls[k].append(timing["wall_ms"])
            kernels[k].append(timing["kernel_ms"])
    out = {}
    for k, run in runs.items():
        out[k] = run.result(float(np.median(walls[k])), float(np.median(kernels[k])), frames)
        out[k]["rounds_kernel_ms"] = kernels[k]
    return out


class _FrozenFrame:
    """One scene's traced frame (its image and operation counts) and frozen renderer."""

    def __init__(self, scene, backend, accel, view, effects, size):
        from renderer.render import Renderer
        if size:
            scene = scene.with_size(*size)
        self.cam = cam = scene.cameras[view]
        traced = Renderer(scene, backend=backend, accel=accel, effects=effects)
        ca = traced.camera(view)
        dr.sync_thread()
        t0 = time.perf_counter()
        self.k = kernel_operations(lambda: traced.frame(ca, cam.width, cam.height))
        self.traced_ms = (time.perf_counter() - t0) * 1e3
        self.effects = str(traced.effects)
        self.frozen = Renderer(scene, backend=backend, accel=accel, effects=effects,
                               freeze=True)
        self.fca = self.frozen.camera(view)

    def frame(self):
        return self.frozen.frame(self.fca, self.cam.width, self.cam.height)

    def time(self, warmup: int, frames: int) -> dict:
        return kernel_ms(self.frame, warmup=warmup, repeats=frames)

    def result(self, wall_ms: float, kern_ms: float, frames: int) -> dict:
        img = self.k["result"]
        same = bool(np.array_equal(img.numpy(), self.frame().numpy()))
        return {"frozen_ms": wall_ms, "frozen_kernel_ms": kern_ms,
                "traced_ms": self.traced_ms, "operations": self.k["operations"],
                "largest_kernel_ops": self.k["largest"], "kernels": self.k["kernels"],
                "frozen_equals_traced": same, "frames": frames,
                "effects": self.effects, "image": img.numpy()}
