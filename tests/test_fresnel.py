"""The dielectric Fresnel term equals Mitsuba's ``fresnel()``, total internal reflection
included."""
from __future__ import annotations

import numpy as np
import pytest

from renderer.device import types
from renderer.shade import fresnel


def test_fresnel_matches_mitsuba():
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    t = types("llvm")
    cos = np.concatenate([np.linspace(-1, 1, 101), [0.0, 1e-6, -1e-6]])
    for eta in (1.5, 1 / 1.33, 1.0, 2.42, 1.0001):
        F, ct, eit, eti = fresnel(t.Float(cos), t.Float(eta))
        ref = np.array([[float(v) for v in mi.fresnel(float(c), float(eta))] for c in cos])
        np.testing.assert_allclose(F.numpy(), ref[:, 0], atol=2e-6, err_msg=f"F, eta {eta}")
        np.testing.assert_allclose(ct.numpy(), ref[:, 1], atol=2e-6, err_msg=f"cos_t, eta {eta}")
        np.testing.assert_allclose(eit.numpy(), ref[:, 2], rtol=1e-6)
        np.testing.assert_allclose(eti.numpy(), ref[:, 3], rtol=1e-6)
    # total internal reflection from inside glass beyond the critical angle
    F = fresnel(t.Float(-np.cos(np.radians(45.0))), t.Float(1.5))[0]
    assert F.numpy()[0] == 1.0
