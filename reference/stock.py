"""Stock Mitsuba 3 rendering a scene file as it is: ``mi.load_file`` of the *same* XML that
``renderer.scene.load_scene`` reads, no plugin of ours, no translation of our ``Scene``.

``render_file_exact(path, defines)`` traces one ray through each pixel centre with the
file's own integrator (``Integrator.sample``), the film positions of exact mode
(``mitsuba_scene.film_positions``; docs/MODEL.md), so the image compares with ours under the
exact rule. It is deterministic for the integrators and emitters that map exactly onto the
model (``direct`` with point emitters: the emitter sample does not depend on the random
numbers, and BSDF samples never hit a point light).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .mitsuba_scene import film_positions


def render_file_exact(path, defines: dict[str, str] | None = None, *, seed: int = 0
                      ) -> np.ndarray:
    """Stock Mitsuba's render of the XML file ``path`` (``-D`` parameters ``defines``): one
    ray through each pixel centre. Returns float32 (H, W, 3) linear RGB, row 0 the top."""
    import drjit as dr
    import mitsuba as mi

    from . import mitsuba_variant
    mitsuba_variant()
    scene = mi.load_file(str(Path(path)), **(defines or {}))
    sensor = scene.sensors()[0]
    w, h = (int(v) for v in sensor.film().size())
    xy = film_positions(w, h)
    n = xy.shape[0]
    sampler = sensor.sampler().fork()
    sampler.seed(seed, n)
    pos = mi.Point2f(mi.Float(xy[:, 0].astype(np.float32)), mi.Float(xy[:, 1].astype(np.float32)))
    ray, _ = sensor.sample_ray(0.0, dr.full(mi.Float, 0.5, n), pos, dr.full(mi.Point2f, 0.5, n))
    L, _, _ = scene.integrator().sample(scene, sampler, ray, None, dr.full(mi.Bool, True, n))
    return np.ascontiguousarray(np.array(L, dtype=np.float32).reshape(3, n).T).reshape(h, w, 3)
