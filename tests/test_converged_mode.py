"""Converged mode is reproducible from its seed and differs from exact mode at edges only."""
from __future__ import annotations

import numpy as np
from util import diffuse_scene

from renderer.render import render


def test_converged_mode_is_seeded_and_close_to_exact(backend):
    sc = diffuse_scene(exact=False, spp=16, seed=7)
    a = render(sc, backend=backend).image
    b = render(sc, backend=backend).image
    np.testing.assert_array_equal(a, b)
    c = render(sc.with_settings(seed=8), backend=backend).image
    assert np.abs(a - c).max() > 0
    exact = render(sc, backend=backend, exact=True).image
    # antialiasing changes edges only: the median pixel difference is tiny
    assert np.median(np.abs(a - exact)) < 5e-3
    assert np.abs(a - exact).max() > 0.02
