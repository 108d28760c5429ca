"""Every accelerator gives the pixels of brute force (the oracle), and ``render`` uses the
backend's accelerator unless told otherwise (the binary BVH on CUDA, the 4-wide BVH on
LLVM)."""
from __future__ import annotations

import numpy as np
import pytest
from util import glass_scene

from renderer.accel import DEFAULT_ACCELS
from renderer.render import Renderer, render


@pytest.mark.parametrize("accel", ["boxes", "bvh", "bvh4", "bvh8"])
def test_accelerators_give_brute_force_pixels(backend, accel):
    sc = glass_scene()
    np.testing.assert_array_equal(render(sc, backend=backend, accel=accel).image,
                                  render(sc, backend=backend, accel="brute").image)


def test_default_accelerator_is_the_backends():
    assert DEFAULT_ACCELS == {"cuda": "bvh", "llvm": "bvh4"}
    r = Renderer(glass_scene(), backend="llvm")
    assert r.accel_name == "bvh4" and type(r.arrays.accel).__name__ == "BVH4"
    assert r.render().stats["accel"] == "bvh4"
