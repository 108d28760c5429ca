"""Helpers of the ray-offset stress cases (tests/hard/test_offsets_*.py): moving a scene
rigidly, comparing two renders pixel by pixel with the exact rule's edge allowance (the
parts of ``evaluation.hard.far``, case 16's criterion)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from evaluation.hard.far import (  # noqa: F401  (the tests import them from here)
    compare,
    far_from_origin_criterion,
    snapped,
    transformed,
)

#: float32 unit roundoff.
U32 = 2.0 ** -24


def quantized_at_origin(scene, shift):
    """``scene`` with the vertices ``transformed(scene, shift=shift)`` has (rounded to
    float32 at ``shift``) moved back by ``-shift`` (exact: the differences are multiples of
    the ulp at ``shift``), so it has exactly the moved scene's geometry, near the origin."""
    shift = np.asarray(shift, np.float64)
    V = ((scene.positions(True) + shift).astype(np.float32).astype(np.float64) - shift)
    assert np.array_equal(V.astype(np.float32).astype(np.float64), V)
    return replace(scene, vertices=V.astype(np.float32))
