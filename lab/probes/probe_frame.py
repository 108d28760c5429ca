"""Probe: where a Whitted frame's time goes, by variants of our frozen frame.

    PYTHONPATH=. python lab/probes/probe_frame.py [--backend cuda] [--size 1024] [--depth 2]
        [--scenes cornell_box,cornell_sphere,platonic_solids,glass_bunny] [--out DIR] [--force]

Per scene (exact mode, the peer part's frame: ``peer._at(scene, depth, size)``), the frozen
frame's median wall and kernel time (``frames.frozen_frame_ms``) for these variants:

- ``bvh``: the renderer's default (the reference row);
- ``rows``, ``block16x2``, ``block4x8``: the rays in row-major order or in other pixel
  blocks than the backend's ``camera.BLOCKS`` (the image must be bitwise the default's);
- ``bvh4``, ``bvh8``: the wide BVHs (the image must be bitwise the default's);
- ``bvh-nosplit``: the BVH built without spatial splits (``build_bvh(spatial=0)``; the
  image must be bitwise the default's);
- ``no-shadows``: the effect set without shadow rays (the shadow rays' share);
- ``depth0``: camera rays only (closest hit and local shading).

Writes ``OUT/frame-variants.json`` (``part.run_probe``: an existing one only with
``--force``).
"""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from lab.probes.common import probe_parser, run_probe
from renderer.scene import load_scene

SCENES = ("cornell_box", "cornell_sphere", "platonic_solids", "glass_bunny")
VARIANTS = ("bvh", "rows", "block16x2", "block4x8", "bvh4", "bvh8", "bvh-nosplit",
            "no-shadows", "depth0")
BLOCK_VARIANTS = {"rows": None, "block16x2": (16, 2), "block4x8": (4, 8)}


def _variant(scene, name: str, backend: str, frames: int) -> dict:
    """frozen_frame_ms of one variant of ``scene``."""
    import renderer.render as R
    from evaluation.bench.frames import frozen_frame_ms
    from renderer.effects import EffectSet
    accel, effects = "bvh", None
    if name in ("bvh4", "bvh8"):
        accel = name
    elif name in BLOCK_VARIANTS:
        default = R.BLOCKS[backend]
        R.BLOCKS[backend] = BLOCK_VARIANTS[name]
        try:
            return frozen_frame_ms(scene, backend=backend, accel=accel, frames=frames)
        finally:
            R.BLOCKS[backend] = default
    elif name == "no-shadows":
        effects = EffectSet.from_scene(scene).without("shadows")
    elif name == "depth0":
        scene = scene.with_settings(max_depth=0)
    if name != "bvh-nosplit":
        return frozen_frame_ms(scene, backend=backend, accel=accel, effects=effects,
                               frames=frames)
    plain = R.build_accelerator

    def nosplit(acc_name, sc, t, **kw):
        from renderer.accel import BVH
        return BVH.build(sc, t, intersection=kw.get("intersection"), spatial=0.0)
    R.build_accelerator = nosplit
    try:
        return frozen_frame_ms(scene, backend=backend, accel=accel, frames=frames)
    finally:
        R.build_accelerator = plain


def probe(name: str, backend: str, size: int, depth: int, frames: int) -> list:
    from evaluation.bench.peer import _at, _no_collection
    scene = _at(load_scene(f"scenes/{name}.toml"), depth, size)
    rows, ref = [], None
    for v in VARIANTS:
        with _no_collection():
            r = _variant(scene, v, backend, frames)
        img = r.pop("image")
        if v == "bvh":
            ref = img
        same = bool(np.array_equal(img, ref)) if img.shape == ref.shape else False
        rows.append({"scene": name, "variant": v, "size": size, "depth": depth,
                     "same_image": same, **{k: r[k] for k in (
                         "frozen_ms", "frozen_kernel_ms", "traced_ms", "operations",
                         "kernels", "frozen_equals_traced")}})
        print(f"{name} {v:12s} frame {r['frozen_ms']:.3f} ms kernel "
              f"{r['frozen_kernel_ms']:.3f} ms  same image {same}", flush=True)
    return rows


def main(argv=None) -> int:
    ap = probe_parser(__doc__, SCENES)
    ap.add_argument("--size", type=int, default=1024)
    ap.add_argument("--depth", type=int, default=2)
    ap.add_argument("--frames", type=int, default=20)
    a = ap.parse_args(argv)
    if a.size < 1 or a.depth < 0 or a.frames < 1:
        ap.error("--size and --frames: at least 1; --depth: at least 0")
    warnings.simplefilter("ignore")
    return run_probe(Path(a.out) / "frame-variants.json", a.force, a.scenes.split(","),
                     lambda name: probe(name, a.backend, a.size, a.depth, a.frames),
                     {"backend": a.backend, "size": a.size, "depth": a.depth})


if __name__ == "__main__":
    raise SystemExit(main())
