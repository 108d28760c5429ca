"""The nudge probe (``evaluation.gate.rules.nudge_probe``): the exact rule excuses a hard
pixel as ill-conditioned only where our own value moves beyond ``max_rel`` under a nudge of
the primary ray by a few float32 ulp, and the golden and ours lie within the values the
nudges span.

The glass bunny's deep internal bounces are such pixels (``whitted check
scenes/glass_bunny.toml`` passes with them listed); planted bugs on the same scene still
fail (``tests/test_rules_must_fail.py``), and so do the mutants that widen the probe
(``evaluation.meta.mutation``: ``nudge_probe_excuses_all``, ``nudge_range_ignored``,
``nudge_ours_not_spanned``).
"""
from __future__ import annotations

import numpy as np
import pytest

from evaluation.gate.rules import (
    EXACT_THRESHOLDS,
    ROOT,
    check_exact,
    exact_overlay,
    matching,
    nudge_probe,
)
from reference.golden import load_golden, search_stores
from renderer.render import Renderer
from renderer.scene import load_scene

TH = EXACT_THRESHOLDS


def test_rule_excuses_only_moving_pixels_that_span_the_golden_and_ours():
    """Five hard pixels of a 2x3 image, golden 1.0 everywhere, ours 1.1: (0, 0) its nudges
    span [0.9, 1.2]: excused; (0, 1) they move as much but span [1.05, 1.3], not the
    golden: hard; (0, 2) they span [0.9, 1.05], the golden but not ours (the image judged is
    not what the probe renders): hard; (1, 0) they do not move: hard; (1, 1) they move by
    less than max_rel: hard. Without ``nudged`` nothing is excused."""
    ref = np.ones((2, 3, 3))
    ours = np.full((2, 3, 3), 1.1)
    nudged = np.repeat(ours[None], 4, axis=0)
    nudged[:, 0, 0] = np.array([0.9, 1.2, 1.1, 1.0])[:, None]
    nudged[:, 0, 1] = np.array([1.05, 1.3, 1.1, 1.2])[:, None]
    nudged[:, 0, 2] = np.array([0.9, 1.0, 1.05, 0.95])[:, None]
    nudged[:, 1, 1] = np.array([1.1, 1.1 * (1 + 0.5 * TH["max_rel"].value), 1.1, 1.1])[:, None]
    nudged[:, 1, 2] = np.array([0.9, 1.2, 1.1, 1.0])[:, None]
    ours[1, 2] = ref[1, 2] = 1.0            # (1, 2) not a hard pixel: never "excused"
    res = check_exact(ours, ref, TH, None, nudged)
    assert res["ill_conditioned"] == [[0, 0]] and res["ill_conditioned_pixels"] == 1
    assert res["hard_pixels"] == 4 and not res["ok"]
    plain = check_exact(ours, ref, TH)
    assert plain["ill_conditioned_pixels"] == 0 and plain["hard_pixels"] == 5
    # the overlay tells them apart: orange for the excused, red for the hard
    img = exact_overlay(ours, ref, TH, None, res["ill_conditioned"])
    assert tuple(img[0, 0]) == (255, 128, 0)
    assert all(tuple(img[y, x]) == (255, 0, 0) for y, x in ((0, 1), (0, 2), (1, 0), (1, 1)))
    # one channel outside the span is enough to hold the pixel
    nudged[:, 0, 0, 2] = np.array([1.05, 1.3, 1.1, 1.2])
    assert check_exact(ours, ref, TH, None, nudged)["ill_conditioned_pixels"] == 0
    with pytest.raises(ValueError, match="nudged"):
        check_exact(ours, ref, TH, None, nudged[:, :1])


def test_a_nudge_of_zero_ulp_is_the_render_itself():
    """The probe's camera upload is the renderer's own: with 0 ulp every nudged render is
    our image bit for bit, so what the probe measures is the nudge alone."""
    sc = load_scene("scenes/cornell_sphere.toml").with_size(24, 24)
    r = Renderer(sc, backend="llvm")
    img = r.render(1).image.astype(np.float64)
    same = nudge_probe(r, 1, ulps=0, nudges=2)
    assert same.shape == (3, *img.shape)
    assert all(np.array_equal(v, img) for v in same)
    moved = nudge_probe(r, 1, ulps=64, nudges=2)
    assert np.array_equal(moved[0], img), "the first render is not nudged"
    assert not np.array_equal(moved[1], img), "64 ulp must move some pixel"


@pytest.mark.parametrize("shading", ["classic", "physical"])
def test_glass_bunny_passes_with_its_ill_conditioned_pixels_listed(shading):
    """``whitted check scenes/glass_bunny.toml``: PASS, excusing a few ill-conditioned
    pixels (measured: 25 classic, 22 physical of 4096), each of which moves beyond
    max_rel under the nudges, recomputed here from the probe's renders, and none of which
    our render gets within max_rel of the golden."""
    from evaluation.gate.verdict import check_scene

    path = ROOT / "scenes" / "glass_bunny.toml"
    (v,) = check_scene(path, search_stores(), modes=["exact"], shadings=[shading],
                       backend="llvm")
    assert v.status == "PASS", v.reason
    ill = v.result["ill_conditioned"]
    assert 0 < len(ill) <= 40, len(ill)
    assert "ill-conditioned" in v.reason
    scene = load_scene(path, shading=shading)
    g = load_golden(scene, view=0, shading=shading, mode="exact")
    r = Renderer(matching(scene, g), backend="llvm")
    img = r.render(0).image.astype(np.float64)
    nudged = nudge_probe(r, 0)
    eps = TH["eps"].value
    for y, x in ill:
        spread = np.ptp(nudged[:, y, x], axis=0) / np.maximum(np.abs(img[y, x]), eps)
        assert spread.max() > TH["max_rel"].value, (y, x)
    # a well-conditioned pixel is never in the list: ours there is within max_rel
    rel = (np.abs(img - g.image) / np.maximum(np.abs(g.image), eps)).max(-1)
    assert all(rel[y, x] > TH["max_rel"].value for y, x in ill)
