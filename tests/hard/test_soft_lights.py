"""Hard cases of the lights with extent (issue 28): a sphere light shrinking to a point, a
sphere light touching the floor, a rectangle light seen edge-on, a light larger than the
scene. Each is held to a closed form or to the point light, never to "looks fine"."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
from test_soft_shadows import floor_scene, sphere
from util import light

from renderer.render import render


def test_shrinking_sphere_converges_to_the_point_image(backend):
    """Radius 1e-2 .. 1e-6 over a cube's shadow: the image error against the point light
    falls with the radius (penumbra width ∝ r) and is at rounding level at 1e-6."""
    pt = render(floor_scene([light([0.5, 2, 0.5], 6.0)]), backend=backend).image
    errs = []
    for r in (1e-2, 1e-4, 1e-6):
        img = render(floor_scene([sphere([0.5, 2, 0.5], 6.0, r)], shadow_samples=4),
                     backend=backend).image
        errs.append(float(np.abs(img - pt).mean()))
    assert errs[0] > errs[1] >= errs[2] and errs[2] < 1e-6, errs


def test_sphere_touching_the_floor(backend):
    """A sphere light resting on the floor (tangent at one point): finite everywhere, the
    physical image still the point light's (shell theorem; every floor point sees the whole
    sphere above its horizon, the contact point a hemisphere)."""
    c = [0.2, 0.5, -0.1]
    pt = render(floor_scene([light(c, 2.0)], cube=False), backend=backend).image
    img = render(floor_scene([sphere(c, 2.0, 0.5)], cube=False, shadow_samples=256),
                 backend=backend).image
    assert np.isfinite(img).all() and img.max() > 0
    rel = np.abs(img - pt) / np.maximum(pt, 1e-3)
    assert np.median(rel) < 5e-3, np.median(rel)


def test_rectangle_seen_edge_on(backend):
    """A rectangle light in the floor's own plane lights it with g = 0: exactly black, no
    NaN; raised by a hair it lights the floor one-sidedly only from its front."""
    rect = replace(light([0, 0, 0], 4.0), shape="rectangle", edge_u=np.array([1.0, 0, 0]),
                   edge_v=np.array([0, 0, -1.0]))                 # normal +y, in the plane
    img = render(floor_scene([rect], cube=False, shadow_samples=4), backend=backend).image
    assert np.isfinite(img).all() and img.max() == 0
    up = replace(rect, position=np.array([0, 1e-3, 0]))           # faces up: floor dark
    assert render(floor_scene([up], cube=False, shadow_samples=4),
                  backend=backend).image.max() == 0
    down = replace(up, edge_u=up.edge_v, edge_v=up.edge_u)       # faces the floor
    img = render(floor_scene([down], cube=False, shadow_samples=4), backend=backend).image
    assert np.isfinite(img).all() and img.max() > 0


def test_light_larger_than_the_scene(backend):
    """A sphere light of radius 50 far above a 6-wide floor: every point sees a cone of
    half-angle ~30°; physical shading still meets the shell theorem, classic stays finite."""
    c, I = [0.0, 100.0, 0.0], 4e4
    pt = render(floor_scene([light(c, I)], cube=False), backend=backend).image
    img = render(floor_scene([sphere(c, I, 50.0)], cube=False, shadow_samples=64),
                 backend=backend).image
    np.testing.assert_allclose(img, pt, rtol=5e-3)
    cl = render(floor_scene([sphere(c, I, 50.0)], cube=False, shading="classic",
                            shadow_samples=4), backend=backend).image
    assert np.isfinite(cl).all() and cl.max() > 0
