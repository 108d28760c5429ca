"""Our renderer against Mitsuba's golden images, pixel by pixel (cases: evaluation/gate/rules.py),
through the project's pytest plugin (``evaluation/gate/pytest_plugin.py``): one test per scene x
view x shading x mode, judged exactly as ``whitted check`` judges it.

Exact mode: the same rays in both renderers, so only rounding and geometric ties may differ
(rule: ``evaluation.gate.rules.check_exact``; ties found by our tie probe, not by looking at the
images). Converged mode: a per-value Welch t-test of our mean and our own variance (16
renders of ours) against the golden's mean and variance (``check_converged``).
The last tests break our renderer on purpose (wrong ior, reflection forced off, the other
shading mode) or plant a one-pixel crack / a patch 5 % off in a real render, and require the
same checks to fail.
"""
from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pytest

from evaluation.gate.rules import (
    CONVERGED_SCENES,
    CONVERGED_THRESHOLDS,
    EXACT_THRESHOLDS,
    GOLDEN_SCENES,
    ROOT,
    RULES,
    check_exact,
    exact_overlay,
    matching,
    render_batches,
    tie_probe,
)
from reference.golden import load_golden
from renderer.effects import EffectSet
from renderer.scene import load_scene


def _scene_at(path, shading, golden=None, **settings):
    scene = load_scene(path, shading=shading)
    if golden is not None:
        scene = matching(scene, golden)
    return scene.with_settings(**settings) if settings else scene


def _ours_converged(scene, view, golden, **kw):
    return render_batches(scene, view, batches=int(CONVERGED_THRESHOLDS["batches"].value),
                          spp=int(golden.meta["batch_spp"]), backend="llvm", **kw)


def _summary(res: dict) -> dict:
    return {k: v for k, v in res.items() if k not in ("excused", "hard", "failed")}


#: Cases known to fail the exact rule, with the measurement: a strict xfail, so a fix shows.
#: None today. The glass bunny (refraction through the smooth 69K-triangle bunny at 64x64)
#: has 28 / 21 pixels (classic / physical) above max_rel where the tie probe shows no tie,
#: from deep internal bounces: against a live Mitsuba render at max_depth 1-3 no pixel is
#: hard (test_glass_bunny_agrees_to_depth_3). The nudge probe shows each of them
#: ill-conditioned (our own value moves beyond max_rel under a 4-ulp nudge of the primary
#: ray, and the golden lies within the nudged values) and excuses exactly those
#: (tests/test_nudge_probe.py); planted bugs on the bunny still fail
#: (tests/test_rules_must_fail.py).
KNOWN_FAILURES: dict[str, str] = {}
#: No exact case is excused for the offset rule: ours renders with the rule the golden records
#: (Mitsuba's own spawn_ray, evaluation.gate.verdict._ours). Under our default scale-free rule six
#: cases differed at 1-4 glass pixels where the float64 oracle sides with ours
#: (lab/notes/data/issue10-ray-offsets/hard_pixels_vs_oracle.txt); tests/test_oracle.py holds
#: that part.


@pytest.mark.whitted(scenes=[ROOT / s for s in GOLDEN_SCENES], modes=["exact"],
                     shadings=["classic", "physical"], backend="llvm", xfail=KNOWN_FAILURES)
def test_exact_matches_golden(whitted_case):
    print(whitted_case.check())


def test_cornell_box_exact_in_float64():
    """``whitted check cornell_box --precision float64``: every exact case passes. The
    tie probe excuses no shadow ray blocked at its own origin (``query.ORIGIN_OPS``):
    with the walls tilted by an ulp (``cos 90°`` from ``np.radians``, the mutant
    ``right_angles_inexact``) 83 floor pixels went dark and this passed."""
    from evaluation.gate.verdict import check_scene
    from reference.golden import search_stores

    verdicts = check_scene(ROOT / "scenes" / "cornell_box.toml", search_stores(),
                           modes=["exact"], backend="llvm", precision="float64")
    bad = [f"{v.view_name} {v.shading}: {v.status} {v.reason}" for v in verdicts
           if v.status != "PASS"]
    assert len(verdicts) == 6 and not bad, bad


@pytest.mark.parametrize("shading", ["classic", "physical"])
def test_glass_bunny_agrees_to_depth_3(shading):
    """The glass bunny's hard pixels at its full depth are deep-bounce divergence only: cut
    at three bounces, ours and a live Mitsuba render of the same scene (its own spawn rule,
    same size as the golden) agree under the exact rule, with the tie probe alone, with no
    hard pixel."""
    from reference.mitsuba_scene import render_mitsuba

    scene = load_scene("scenes/glass_bunny.toml", shading=shading)
    g = load_golden(scene, view=0, shading=shading, mode="exact")
    sc = matching(scene, g).with_settings(max_depth=3)
    ref = render_mitsuba(sc, view=0, mode="exact")
    ours, ties = tie_probe(sc, 0, backend="llvm")
    res = check_exact(ours, ref, EXACT_THRESHOLDS, ties)
    assert res["ok"], _summary(res)
    assert float(np.mean(ref)) > 0.01, "a black reference proves nothing"


@pytest.mark.slow
@pytest.mark.whitted(scenes=[ROOT / s for s in CONVERGED_SCENES], modes=["converged"],
                     shadings=["classic", "physical"], backend="llvm")
def test_converged_matches_golden(whitted_case):
    print(whitted_case.check())


# ---- the checks can fail ----------------------------------------------------------------
SCENE = "scenes/cornell_sphere.toml"
VIEW = 1          # the "left" view: glass and mirror spheres both in sight


def _broken_render(shading, golden, breakage):
    """Our renderer with one deliberate error, exact mode: (image, its tie mask), the
    mask from the broken renderer itself, as the gate would compute it."""
    scene = _scene_at(SCENE, shading, golden)
    if breakage == "wrong_ior":
        assert any(m.transmissive for m in scene.materials), f"{SCENE}: no glass to break"
        mats = [replace(m, ior=1.3) if m.transmissive else m for m in scene.materials]
        return tie_probe(replace(scene, materials=mats), VIEW, backend="llvm")
    if breakage == "reflection_off":
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fx = EffectSet.from_scene(scene).without("reflection")
        return tie_probe(scene, VIEW, backend="llvm", effects=fx)
    other = "physical" if shading == "classic" else "classic"
    return tie_probe(_scene_at(SCENE, other, golden), VIEW, backend="llvm")


BREAKAGES = [
    "wrong_ior",
    "reflection_off",
    "other_shading",
]


@pytest.mark.parametrize("breakage", BREAKAGES)
@pytest.mark.parametrize("shading", ["classic", "physical"])
def test_exact_check_fails_on_broken_renderer(shading, breakage):
    g = load_golden(load_scene(SCENE, shading=shading), view=VIEW, shading=shading,
                    mode="exact")
    good, ties = tie_probe(_scene_at(SCENE, shading, g), VIEW, backend="llvm")
    assert check_exact(good, g.image, EXACT_THRESHOLDS, ties)["ok"]
    broken, broken_ties = _broken_render(shading, g, breakage)
    res = check_exact(broken, g.image, EXACT_THRESHOLDS, broken_ties)
    assert not res["ok"], f"{breakage}: the exact check passed a broken render: {res}"


@pytest.mark.slow
def test_converged_check_fails_on_wrong_ior():
    shading = "physical"
    g = load_golden(load_scene(SCENE, shading=shading), view=VIEW, shading=shading,
                    mode="converged")
    scene = _scene_at(SCENE, shading, g)
    mats = [replace(m, ior=1.3) if m.transmissive else m for m in scene.materials]
    ours = _ours_converged(replace(scene, materials=mats), VIEW, g)
    res = RULES["converged"](ours, g, CONVERGED_THRESHOLDS)
    assert not res["ok"], f"the t-test passed a render with the wrong ior: {_summary(res)}"


# ---- planted defects on a real render: the rule must see them -----------------------------
PLANT_SCENE = "scenes/cornell_box.toml"   # front view: 203 corner-seam tie pixels


@pytest.fixture(scope="module")
def planted_base():
    """The Cornell box front view (classic): golden, our render and our tie mask."""
    g = load_golden(load_scene(PLANT_SCENE, shading="classic"), view=0, shading="classic",
                    mode="exact")
    ours, ties = tie_probe(_scene_at(PLANT_SCENE, "classic", g), 0, backend="llvm")
    res = check_exact(ours, g.image, EXACT_THRESHOLDS, ties)
    assert res["ok"] and res["excused_pixels"] > 100, _summary(res)
    return g, ours, ties


def _crack_sites(ties: np.ndarray) -> list[tuple[int, int]]:
    """Pixels next to an excused seam pixel but not ties themselves: where a crack hides
    best from an image-space rule (its 3x3 neighbourhood holds the seam's dark values)."""
    near = np.zeros_like(ties)
    h, w = ties.shape
    near[1:-1, 1:-1] = np.any([ties[1 + dy:h - 1 + dy, 1 + dx:w - 1 + dx]
                               for dy in (-1, 0, 1) for dx in (-1, 0, 1)], axis=0)
    return [tuple(p) for p in np.argwhere(near & ~ties)]


def test_one_pixel_crack_fails(planted_base):
    g, ours, ties = planted_base
    sites = _crack_sites(ties)
    assert len(sites) > 50
    for y, x in sites[:: max(1, len(sites) // 8)]:
        cracked = ours.copy()
        cracked[y, x] = 0.0        # the background: the ray fell through an edge
        res = check_exact(cracked, g.image, EXACT_THRESHOLDS, ties)
        assert not res["ok"] and res["hard"] == [[y, x]], (y, x, _summary(res))


def test_overlay_draws_excused_and_hard_pixels(planted_base):
    g, ours, ties = planted_base
    y, x = _crack_sites(ties)[0]
    cracked = ours.copy()
    cracked[y, x] = 0.0
    res = check_exact(cracked, g.image, EXACT_THRESHOLDS, ties)
    img = exact_overlay(cracked, g.image, EXACT_THRESHOLDS, ties)
    assert img.shape == ours.shape and img.dtype == np.uint8
    assert tuple(img[y, x]) == (255, 0, 0)
    yellow = np.all(img == (255, 230, 0), axis=-1)
    assert yellow.sum() == res["excused_pixels"] and [list(p) for p in np.argwhere(yellow)] \
        == res["excused"]


@pytest.mark.parametrize("factor", [1.05, 0.95, 1.27])
def test_patch_off_by_5_percent_fails(planted_base, factor):
    g, ours, ties = planted_base
    h, w = ours.shape[:2]
    for y0, x0 in [(h // 2 - 8, w // 2 - 8), (h - 17, 0), (0, w - 17)]:
        patched = ours.copy()
        patched[y0:y0 + 17, x0:x0 + 17] *= factor
        res = check_exact(patched, g.image, EXACT_THRESHOLDS, ties)
        assert not res["ok"], (factor, y0, x0, _summary(res))
