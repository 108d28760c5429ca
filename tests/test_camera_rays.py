"""Primary rays follow the camera model of docs/MODEL.md (checked against the independent
oracle ``util.pixel_ray``); converged-mode samples stay inside their strata."""
from __future__ import annotations

import drjit as dr
import numpy as np
import pytest
from util import camera, pixel_ray

from renderer.camera import RayTile, block_pixel, camera_arrays, primary_rays
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


@pytest.mark.parametrize("width,height,block", [(7, 5, (4, 8)), (37, 13, (4, 8)),
                                                 (32, 8, (8, 4)), (1, 1, (4, 8)),
                                                 (3, 17, (4, 4))])
def test_block_order_is_a_permutation_of_compact_blocks(width, height, block):
    """``block_pixel`` visits every pixel once, and every run of ``bw·bh`` slots that starts
    a full block lies inside one ``bw × bh`` rectangle."""
    t = types("llvm")
    q = dr.arange(t.UInt32, width * height)
    x, y = block_pixel(q, width, height, block)
    xs, ys = x.numpy().astype(np.int64), y.numpy().astype(np.int64)
    assert xs.max() < width and ys.max() < height
    assert len(np.unique(ys * width + xs)) == width * height
    bw, bh = block
    full = 0
    for s in range(0, width * height, bw * bh):
        bx, by = xs[s] // bw, ys[s] // bh
        if (bx + 1) * bw <= width and (by + 1) * bh <= height and xs[s] % bw == 0 \
                and ys[s] % bh == 0:
            run = slice(s, s + bw * bh)
            assert np.all(xs[run] // bw == bx) and np.all(ys[run] // bh == by)
            full += 1
    assert full == (width // bw) * (height // bh)


@pytest.mark.parametrize("spp,exact", [(1, True), (4, False)])
def test_block_order_rays_are_the_row_major_rays(backend, spp, exact):
    """The same rays, bit for bit, in block order: whole image and a band of rows."""
    t = types(backend)
    cam = camera([1, 2, 3], [0, 0.5, -1], fov_y=50, width=13, height=11, up=(0, 1, 0.2))
    ca = camera_arrays(cam, t)

    def dirs(rows, first, block):
        fr = None if first is None else dr.opaque(t.UInt32, first)
        d = primary_rays(ca, 13, 11, t, spp=spp, exact=exact, seed=7,
                         tile=RayTile(first_row=fr, rows=rows, block=block))[1]
        return np.stack([c.numpy() for c in d], axis=1).reshape(-1, spp, 3)

    for rows, first in ((None, None), (6, 3)):
        n_rows = 11 if rows is None else rows
        ref = dirs(rows, first, None)
        got = dirs(rows, first, (4, 8))
        x, y = block_pixel(dr.arange(t.UInt32, 13 * n_rows), 13, n_rows, (4, 8))
        perm = y.numpy().astype(np.int64) * 13 + x.numpy()
        assert got.tobytes() == ref[perm].tobytes()
        assert not np.array_equal(got, ref)          # the order did change
