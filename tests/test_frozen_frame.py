"""A frame function wrapped in ``dr.freeze`` records once and replays with a moved camera,
giving the pixels of a traced frame."""
from __future__ import annotations

import numpy as np
from util import camera, glass_scene

from renderer.render import Renderer


def test_frozen_frame_matches_traced_frame_with_moved_camera(backend):
    sc = glass_scene()
    traced = Renderer(sc, backend=backend)
    frozen = Renderer(sc, backend=backend, freeze=True)
    cams = [sc.cameras[0], camera([0.5, 1.2, 3.5], [0, -0.4, 0], width=32, height=32),
            camera([-1, 0.5, 3.8], [0.1, -0.5, 0], width=32, height=32)]
    for cam in cams:
        a = traced.frame(traced.camera(cam), 32, 32).numpy()
        b = frozen.frame(frozen.camera(cam), 32, 32).numpy()
        np.testing.assert_array_equal(a, b)
    assert frozen.frame_fn.n_recordings == 1   # recorded once, replayed for the moved cameras
    assert np.abs(a - traced.frame(traced.camera(cams[0]), 32, 32).numpy()).max() > 0.05
