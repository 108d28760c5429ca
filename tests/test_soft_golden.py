"""The soft-shadow scene against its converged Mitsuba goldens (scenes/cornell_soft.toml: a
sphere light sampled over its cone by both renderers), judged by the converged rule: it
passes, a null pair of our own renders passes, and a planted wrong cone pdf fails."""
from __future__ import annotations

import drjit as dr
import numpy as np
import pytest

import renderer.lights as lights_module
from evaluation.gate.rules import (
    CONVERGED_THRESHOLDS,
    OUR_SEED,
    check_converged,
    golden_batches,
    matching,
    render_batches,
)
from reference.golden import load_golden
from renderer.scene import load_scene

SCENE = "scenes/cornell_soft.toml"
N = int(CONVERGED_THRESHOLDS["batches"].value)


def _case(shading):
    scene = load_scene(SCENE, shading=shading)
    g = load_golden(scene, view=0, shading=shading, mode="converged")
    return matching(scene, g), g


def _ours(scene, g, first_batch=0):
    return render_batches(scene, 0, batches=N, spp=int(g.meta["batch_spp"]), backend="llvm",
                          seed=OUR_SEED, first_batch=first_batch)


@pytest.mark.parametrize("shading", ["classic", "physical"])
def test_soft_shadows_match_the_converged_golden(shading):
    scene, g = _case(shading)
    res = check_converged(_ours(scene, g), golden_batches(g), CONVERGED_THRESHOLDS)
    assert res["ok"], {k: v for k, v in res.items() if k != "failed"}
    assert float(np.mean(g.image)) > 0.05, "a black golden proves nothing"


def test_null_pair_of_our_renders_passes():
    """Two independent sets of our batches (the same estimator on both sides): the rule's
    false-failure case, which must pass."""
    scene, g = _case("physical")
    a, b = _ours(scene, g), _ours(scene, g, first_batch=N)
    assert check_converged(a, b, CONVERGED_THRESHOLDS)["ok"]


def test_wrong_cone_pdf_is_caught(monkeypatch):
    """A planted bug: the cone's pdf taken as 1/(2π sin²θmax) instead of
    1/(2π (1 - cosθmax)), i.e. the physical sphere estimate 2 I / d_c² instead of
    2 I / (d_c² (1 + cosθmax)). The converged rule must fail it."""
    scene, g = _case("physical")
    good = lights_module._sample_sphere

    def wrong_pdf(lights, i, target, intensity, att, u, t, *, physical):
        ls = good(lights, i, target, intensity, att, u, t, physical=physical)
        r = dr.gather(t.Float, lights.radius, i)
        cos_max = dr.sqrt(1.0 - dr.minimum(r * r / target.dc2, 1.0))
        ls.Li = ls.Li * (1.0 + cos_max)
        return ls
    monkeypatch.setattr(lights_module, "_sample_sphere", wrong_pdf)
    res = check_converged(_ours(scene, g), golden_batches(g), CONVERGED_THRESHOLDS)
    assert not res["ok"], "the converged rule passed a wrong cone pdf"
    assert res["failed_pixels"] > 10
