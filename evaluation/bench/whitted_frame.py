"""Part ``whitted``: our frozen Whitted frame at the scene's own depth vs Mitsuba's image.

Mitsuba renders with the reference harness's integrator (exact mode, same resolution and
depth); the two images' difference is reported (``evaluation.gate.metrics.image_difference``)
and a PNG strip ours | Mitsuba | outlier pixels is written per scene. Ours is timed (frozen
and traced); the harness's integrator is not: it is a wavefront reference (a kernel per
tree level, host syncs), not a speed peer. The speed comparison is the ``peer`` part
(``peer.py``: a one-kernel, frozen Mitsuba integrator at equal depth).

Results stored before this split carry the harness's time (``mitsuba_kernel_ms``); their
rows render in the table they were published with (``_markdown_timed``).
"""
from __future__ import annotations

import numpy as np

from evaluation.gate.metrics import image_difference, outlier_mask

from .. import SEED_SCENES
from .frames import frozen_frame_ms
from .part import Context, Part, table


def whitted_frame(scene, *, backend: str, frames: int = 20, accel: str | None = None,
                  strip_path=None, overwrite: bool = False) -> dict:
    """Our frozen Whitted frame (timed) vs Mitsuba's exact render of ``scene`` through the
    harness's integrator (not timed), with the image difference; ``strip_path``: where to
    write the PNG strip (None: none; an existing one is replaced only when ``overwrite``)."""
    from reference import mitsuba_variant
    from reference.mitsuba_scene import load, render_exact
    ours = frozen_frame_ms(scene, backend=backend, accel=accel, frames=frames)
    mitsuba_variant("cuda_ad_rgb" if backend == "cuda" else "llvm_ad_rgb")
    ref = render_exact(load(scene, view=0, mode="exact", spp=1))
    m = image_difference(ours["image"], ref)
    if strip_path is not None:
        write_strip(strip_path, ours["image"], ref, overwrite=overwrite)
    cam = scene.cameras[0]
    return {"scene": scene.name, "size": [cam.width, cam.height],
            "depth": scene.settings.max_depth,
            "ours_frozen_ms": ours["frozen_ms"], "ours_kernel_ms": ours["frozen_kernel_ms"],
            "ours_traced_ms": ours["traced_ms"], "effects": ours["effects"],
            "difference": m}


def write_strip(path, ours, ref, *, overwrite: bool = False) -> None:
    """PNG: ours | Mitsuba | outlier pixels (white), sRGB (atomic; an existing file is
    replaced only when ``overwrite``)."""
    import imageio.v3 as iio

    from renderer.film import srgb_encode
    from renderer.outputs import atomic_path
    mask = np.repeat(outlier_mask(ours, ref)[..., None], 3, -1).astype(np.uint8) * 255
    with atomic_path(path, overwrite=overwrite, flag="--force") as tmp:
        iio.imwrite(tmp, np.concatenate([srgb_encode(ours), srgb_encode(ref), mask], 1),
                    extension=".png")


def run(ctx: Context) -> list[dict]:
    """The seed scenes at 512² (quick: 128²); strips ``whitted-<scene>-<backend>.png``."""
    from renderer.scene import load_scene
    rows = []
    for name in SEED_SCENES:
        sc = load_scene(ctx.scene_path(name)).with_size(ctx.frame_size)
        r = whitted_frame(sc, backend=ctx.backend, frames=ctx.frames,
                          strip_path=ctx.out_dir / f"whitted-{name}-{ctx.backend}.png",
                          overwrite=ctx.overwrite)
        rows.append(r)
        print(f"  whitted {name:16s} ours {r['ours_frozen_ms']:.3f} ms  rmse vs Mitsuba "
              f"{r['difference']['rmse']:.2e}", flush=True)
    return rows


def markdown(rows: list[dict]) -> list[str]:
    if any("mitsuba_kernel_ms" in r for r in rows):
        return _markdown_timed(rows)
    cells = [[r["scene"], f"{r['size'][0]}×{r['size'][1]}", f"{r['depth']}",
              f"{r['ours_traced_ms']:.2f}", f"{r['ours_frozen_ms']:.3f}",
              f"{r['ours_kernel_ms']:.3f}", f"{r['difference']['rmse']:.2e}",
              f"{r['difference']['outliers']}", f"{r['difference']['mean_rel']:.2e}"]
             for r in rows]
    return table("Whitted frame at the scene's depth, ours (frozen) vs Mitsuba's image "
                 "(reference integrator, not timed: see the peer part), exact mode",
                 ["scene", "size", "depth", "ours traced ms", "ours frozen ms",
                  "ours kernel ms", "RMSE", "outlier px", "mean rel"], "llrrrrrrr", cells)


def _markdown_timed(rows: list[dict]) -> list[str]:
    """The table of results stored before the ``peer`` part, with the harness's time."""
    cells = [[r["scene"], f"{r['size'][0]}×{r['size'][1]}", f"{r['depth']}",
              f"{r['ours_traced_ms']:.2f}", f"{r['ours_frozen_ms']:.3f}",
              f"{r['ours_kernel_ms']:.3f}", f"{r['mitsuba_kernel_ms']:.3f}",
              f"{r['mitsuba_wall_ms']:.1f}", f"{r['difference']['rmse']:.2e}",
              f"{r['difference']['outliers']}", f"{r['difference']['mean_rel']:.2e}"]
             for r in rows]
    return table("Whitted frame, ours (frozen) vs Mitsuba (reference integrator), exact mode",
                 ["scene", "size", "depth", "ours traced ms", "ours frozen ms",
                  "ours kernel ms", "Mitsuba kernel ms", "Mitsuba wall ms", "RMSE",
                  "outlier px", "mean rel"], "llrrrrrrrrr", cells)


PART = Part(name="whitted", key="whitted", run=run, markdown=markdown)
