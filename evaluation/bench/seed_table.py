"""Part ``seed``: the thesis's table, frozen frames of the seed scenes.

Each seed scene × its three views at 512², primary rays only (depth 0: local light and
shadows) and with reflection (the scene's full Whitted tree), for brute force, per-object
boxes and the BVH; ms per frame = mean over the views of the median of the frozen frames,
beside the thesis's GeForce 8800 GT numbers.
"""
from __future__ import annotations

import numpy as np

from .. import SEED_SCENES
from .frames import frozen_frame_ms
from .part import Context, Part, table

#: The thesis's GeForce 8800 GT numbers (ms per 512² frame, mean of three views).
THESIS_MS = {
    "cornell_box": {"primary": 5.6, "primary_aabb": 5.5, "reflection": 7.6,
                    "reflection_aabb": 9.8},
    "cornell_sphere": {"primary": 138.2, "primary_aabb": 109.0, "reflection": 295.2,
                       "reflection_aabb": 252.8},
    "platonic_solids": {"primary": 207.5, "primary_aabb": 164.4, "reflection": 362.4,
                        "reflection_aabb": 323.8},
}


def seed_table(scene_paths, *, backend: str, frames: int = 20, size=(512, 512)) -> list[dict]:
    """The table's rows for ``scene_paths``: one per scene × test × accelerator."""
    from renderer.scene import load_scene
    rows = []
    for path in scene_paths:
        scene = load_scene(path)
        for test, depth in (("primary", 0), ("reflection", scene.settings.max_depth)):
            sc = scene.with_settings(max_depth=depth)
            for accel in ("brute", "boxes", "bvh"):
                per_view = [frozen_frame_ms(sc, backend=backend, accel=accel, view=v,
                                            frames=frames, size=size)
                            for v in range(len(sc.cameras))]
                ms = float(np.mean([p["frozen_ms"] for p in per_view]))
                kms = float(np.mean([p["frozen_kernel_ms"] for p in per_view]))
                key = test + ("_aabb" if accel == "boxes" else "")
                thesis = THESIS_MS.get(scene.name, {}).get(key if accel != "bvh" else test)
                rows.append({"scene": scene.name, "test": test, "accel": accel, "ms": ms,
                             "kernel_ms": kms, "views": len(per_view),
                             "frozen_equals_traced": all(p["frozen_equals_traced"]
                                                         for p in per_view),
                             "thesis_ms": thesis,
                             "speedup_vs_thesis": thesis / ms if thesis and ms > 0 else None})
                print(f"  seed {scene.name:16s} {test:10s} {accel:5s} {ms:9.3f} ms"
                      + (f"  (thesis {thesis} ms, {thesis / ms:,.0f}x)" if thesis else ""),
                      flush=True)
    return rows


def run(ctx: Context) -> list[dict]:
    """The seed scenes at 512² (quick: 128²)."""
    n = ctx.frame_size
    return seed_table([ctx.scene_path(name) for name in SEED_SCENES], backend=ctx.backend,
                      frames=ctx.frames, size=(n, n))


def markdown(rows: list[dict]) -> list[str]:
    cells = [[r["scene"], r["test"], r["accel"], f"{r['ms']:.3f}", f"{r['kernel_ms']:.3f}",
              f"{r['thesis_ms']}" if r["thesis_ms"] else "—",
              f"{r['speedup_vs_thesis']:,.0f}×" if r["speedup_vs_thesis"] else "—"]
             for r in rows]
    return table("The thesis's table (ms per frame, mean of three views, median of frozen "
                 "frames)", ["scene", "test", "accel", "ms", "kernel ms", "thesis 8800 GT ms",
                             "speed-up"], "lllrrrr", cells)


PART = Part(name="seed", key="seed_table", run=run, markdown=markdown)
