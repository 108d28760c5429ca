"""Primary rays follow the camera model of docs/MODEL.md (checked against the independent
oracle ``util.pixel_ray``); converged-mode samples stay inside their strata."""
from __future__ import annotations

import numpy as np
from util import camera, pixel_ray

from renderer.camera import camera_arrays, primary_rays
from renderer.device import types


def test_primary_rays_follow_camera_model(backend):
    t = types(backend)
    cam = camera([1, 2, 3], [0, 0.5, -1], fov_y=50, width=7, height=5, up=(0, 1, 0.2))
    o, d = primary_rays(camera_arrays(cam, t), 7, 5, t)
    D = np.stack([c.numpy() for c in d], axis=1)
    want = np.array([pixel_ray(cam, x + 0.5, y + 0.5) for y in range(5) for x in range(7)])
    np.testing.assert_allclose(D, want, atol=2e-6)
    # converged mode: 4 strata per pixel, each inside its quarter of the pixel
    o, d = primary_rays(camera_arrays(cam, t), 7, 5, t, spp=4, exact=False, seed=3)
    D = np.stack([c.numpy() for c in d], axis=1).reshape(5, 7, 4, 3)
    f = cam.target - cam.position
    f /= np.linalg.norm(f)
    r = np.cross(f, cam.up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    ty = np.tan(np.radians(cam.fov_y) / 2)
    tx = ty * 7 / 5
    px = ((D @ r) / (D @ f) / tx + 1) * 7 / 2          # back to film positions
    py = (1 - (D @ u) / (D @ f) / ty) * 5 / 2
    for s in range(4):
        i, j = s % 2, s // 2
        fx = px[:, :, s] - np.arange(7)[None, :]
        fy = py[:, :, s] - np.arange(5)[:, None]
        assert np.all((fx >= i / 2 - 1e-5) & (fx <= (i + 1) / 2 + 1e-5)), s
        assert np.all((fy >= j / 2 - 1e-5) & (fy <= (j + 1) / 2 + 1e-5)), s
    assert np.std(fx) > 0.05   # jittered, not at the strata centres
