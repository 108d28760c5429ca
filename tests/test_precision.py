"""float64 renders agree with float32 renders up to float32 rounding."""
from __future__ import annotations

import numpy as np
from util import glass_scene

from renderer.render import render


def test_float64_matches_float32(backend):
    sc = glass_scene()
    a = render(sc, backend=backend).image
    b = render(sc, backend=backend, precision="float64").image
    assert np.mean(np.abs(a - b)) < 1e-4


def test_float64_is_float64_far_from_the_origin(backend):
    """A lit plane 4096 units from the origin, where float32 spacing is 4.9e-4: float64
    matches the closed form to 1e-5 relative, float32 visibly does not (so a float64
    request that silently runs in float32 fails here)."""
    from test_analytic import expected_local, hit_plane
    from util import camera, light, make_scene, material, pixel_ray, quad

    shift = np.array([4096.0, 0.0, 0.0])
    V, F = quad(*(shift + c for c in ([-20, -20, 0], [20, -20, 0], [20, 20, 0], [-20, 20, 0])))
    kd, lp, I = np.array([0.6, 0.5, 0.4]), shift + [0.3, 0.2, 1.0], np.array([2.0, 3.0, 4.0])
    cam = camera(shift + [0, 0, 3], shift, fov_y=60, width=16, height=16)
    sc = make_scene([(V, F, 0)], materials=[material(kd=kd, ks=0.0, ka=0.0)],
                    lights=[light(lp, I, "none")], camera=cam, ambient=0.0)
    errs = {}
    for precision in ("float32", "float64"):
        img = render(sc, backend=backend, precision=precision).image
        err = 0.0
        for x, y in [(0, 0), (3, 12), (8, 8), (7, 9), (15, 4), (11, 11)]:
            d = pixel_ray(cam, x + 0.5, y + 0.5)
            p = hit_plane(cam.position, d, 0.0)
            want = expected_local(p, np.array([0, 0, 1.0]), -d, lp, I, kd, 0.0, 1.0, 0.0,
                                  0.0, "classic", "none")
            err = max(err, float(np.max(np.abs(img[y, x] - want) / want)))
        errs[precision] = err
    assert errs["float64"] < 1e-5, errs
    assert errs["float32"] > 10 * errs["float64"], errs
