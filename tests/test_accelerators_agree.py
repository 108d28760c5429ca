"""Every accelerator gives the pixels of brute force (the oracle), and ``render`` uses the
BVH unless told otherwise."""
from __future__ import annotations

import numpy as np
import pytest
from util import glass_scene

from renderer.accel import DEFAULT_ACCEL
from renderer.render import Renderer, render


@pytest.mark.parametrize("accel", ["boxes", "bvh"])
def test_accelerators_give_brute_force_pixels(backend, accel):
    sc = glass_scene()
    np.testing.assert_array_equal(render(sc, backend=backend, accel=accel).image,
                                  render(sc, backend=backend, accel="brute").image)


def test_default_accelerator_is_the_bvh():
    assert DEFAULT_ACCEL == "bvh"
    assert Renderer(glass_scene(), backend="llvm").accel_name == "bvh"
