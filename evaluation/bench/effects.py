"""Part ``effects``: the scene's specialised kernel vs the all-effects kernel.

Operations (IR operations of the traced kernels) and frozen-frame time of a frame traced
with the scene's own ``EffectSet`` against one traced with every effect, and whether the two
give the same pixels.
"""
from __future__ import annotations

import numpy as np

from .. import SEED_SCENES
from .frames import frozen_frame_ms
from .part import Context, Part, table

SCENES = SEED_SCENES + ("analytic_quad", "bunny", "glass_bunny")


def effects_saving(scene, *, backend: str, frames: int = 20, accel: str = "bvh") -> dict:
    """The scene's specialised kernel vs the all-effects kernel: operations and time."""
    from renderer.effects import EffectSet
    spec = frozen_frame_ms(scene, backend=backend, accel=accel, frames=frames)
    gen = frozen_frame_ms(scene, backend=backend, accel=accel, frames=frames,
                          effects=EffectSet.all(scene))
    return {"scene": scene.name, "effects": spec["effects"],
            "ops_specialised": spec["operations"], "ops_general": gen["operations"],
            "ms_specialised": spec["frozen_ms"], "ms_general": gen["frozen_ms"],
            "saved_ms": gen["frozen_ms"] - spec["frozen_ms"],
            "same_pixels": bool(np.array_equal(spec["image"], gen["image"])),
            "max_rel_diff": float(np.max(np.abs(spec["image"] - gen["image"])
                                         / np.maximum(np.abs(gen["image"]), 1e-6)))}


def run(ctx: Context) -> list[dict]:
    """Every scene of ``SCENES`` present in the scenes folder, at 512² (quick: 128²)."""
    from renderer.scene import load_scene
    rows = []
    for name in SCENES:
        p = ctx.scene_path(name)
        if not p.exists():
            continue
        sc = load_scene(p).with_size(ctx.frame_size)
        r = effects_saving(sc, backend=ctx.backend, frames=ctx.frames)
        rows.append(r)
        print(f"  effects {name:16s} ops {r['ops_specialised']} vs {r['ops_general']}  "
              f"{r['ms_specialised']:.3f} vs {r['ms_general']:.3f} ms", flush=True)
    return rows


def markdown(rows: list[dict]) -> list[str]:
    cells = [[r["scene"], r["effects"], f"{r['ops_specialised']:,}", f"{r['ops_general']:,}",
              f"{r['ms_specialised']:.3f}", f"{r['ms_general']:.3f}", f"{r['saved_ms']:.3f}",
              "yes" if r["same_pixels"] else "max rel " + format(r["max_rel_diff"], ".1e")]
             for r in rows]
    return table("Effects: the scene's specialised kernel vs all effects",
                 ["scene", "effects on", "ops specialised", "ops general", "ms specialised",
                  "ms general", "saved ms", "same pixels"], "llrrrrrl", cells)


PART = Part(name="effects", key="effects", run=run, markdown=markdown)
