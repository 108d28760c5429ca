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
    from renderer.render import Renderer
    if size:
        scene = scene.with_size(*size)
    cam = scene.cameras[view]
    traced = Renderer(scene, backend=backend, accel=accel, effects=effects)
    ca = traced.camera(view)
    dr.sync_thread()
    t0 = time.perf_counter()
    k = kernel_operations(lambda: traced.frame(ca, cam.width, cam.height))
    traced_ms = (time.perf_counter() - t0) * 1e3
    img = k["result"]
    frozen = Renderer(scene, backend=backend, accel=accel, effects=effects, freeze=True)
    fca = frozen.camera(view)
    timing = kernel_ms(lambda: frozen.frame(fca, cam.width, cam.height), warmup=warmup,
                       repeats=frames)
    same = bool(np.array_equal(img.numpy(), frozen.frame(fca, cam.width, cam.height).numpy()))
    return {"frozen_ms": timing["wall_ms"], "frozen_kernel_ms": timing["kernel_ms"],
            "traced_ms": traced_ms, "operations": k["operations"],
            "largest_kernel_ops": k["largest"], "kernels": k["kernels"],
            "frozen_equals_traced": same, "frames": frames,
            "effects": str(traced.effects), "image": img.numpy()}
