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
