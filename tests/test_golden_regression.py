"""Our renderer against Mitsuba's golden images, pixel by pixel (cases: evaluation/rules.py),
through the project's pytest plugin (``evaluation/pytest_plugin.py``): one test per scene x
view x shading x mode, judged exactly as ``whitted check`` judges it.

Exact mode: the same rays in both renderers, so only rounding and ties at shared edges may
differ (rule: ``evaluation.rules.check_exact``). Converged mode: a per-pixel Z-test of our
k x k stratified render against the golden's mean and variance (``check_converged``).
The last tests break our renderer on purpose (wrong ior, reflection forced off, the other
shading mode) and require the same checks to fail.
"""
from __future__ import annotations

import warnings
from dataclasses import replace

import pytest

from evaluation.rules import (
    CONVERGED_SCENES,
    CONVERGED_THRESHOLDS,
    EXACT_THRESHOLDS,
    GOLDEN_SCENES,
    ROOT,
    RULES,
    check_exact,
)
from reference.golden import load_golden
from renderer.effects import EffectSet
from renderer.render import render
from renderer.scene import load_scene

OUR_SEED = 20240611   # fixed: ours must be independent of the golden's Mitsuba seeds


def _scene_at(path, shading, golden=None, **settings):
    scene = load_scene(path, shading=shading)
    if golden is not None:
        scene = scene.with_size(*golden.meta["resolution"])
    return scene.with_settings(**settings) if settings else scene


def _ours_converged(scene, view, golden, **kw):
    spp = int(golden.meta["batch_spp"])
    return render(scene.with_settings(seed=OUR_SEED), view=view, backend="llvm",
                  exact=False, spp=spp, **kw).image


#: Cases known to fail the exact rule, with the measurement: a strict xfail, so a fix shows.
KNOWN_FAILURES = {
    "glass_bunny": "refraction through the 69K-triangle bunny: 43 / 36 tie pixels (classic / "
                   "physical, 1.05 % / 0.88 % of 64x64) exceed edge_fraction 0.5 %; at 128 px "
                   "163 / 161 and at 256 px 625 / 577 tie pixels plus 2-7 hard pixels (measured "
                   "with whitted check on LLVM); see issue 11's tie detection by tracing",
}
#: No exact case is excused for the offset rule: ours renders with the rule the golden records
#: (Mitsuba's own spawn_ray, evaluation.verdict._ours). Under our default scale-free rule six
#: cases differed at 1-4 glass pixels where the float64 oracle sides with ours
#: (results/offsets/hard_pixels_vs_oracle.txt); tests/test_oracle.py holds that part.


@pytest.mark.whitted(scenes=[ROOT / s for s in GOLDEN_SCENES], modes=["exact"],
                     shadings=["classic", "physical"], backend="llvm", xfail=KNOWN_FAILURES)
def test_exact_matches_golden(whitted_case):
    print(whitted_case.check())


@pytest.mark.slow
@pytest.mark.whitted(scenes=[ROOT / s for s in CONVERGED_SCENES], modes=["converged"],
                     shadings=["classic", "physical"], backend="llvm")
def test_converged_matches_golden(whitted_case):
    print(whitted_case.check())


# ---- the checks can fail ----------------------------------------------------------------
SCENE = "scenes/cornell_sphere.toml"
VIEW = 1          # the "left" view: glass and mirror spheres both in sight


def _broken_render(shading, golden, breakage):
    """Our renderer with one deliberate error, exact mode."""
    scene = _scene_at(SCENE, shading, golden)
    if breakage == "wrong_ior":
        assert any(m.transmissive for m in scene.materials), f"{SCENE}: no glass to break"
        mats = [replace(m, ior=1.3) if m.transmissive else m for m in scene.materials]
        return render(replace(scene, materials=mats), view=VIEW, backend="llvm").image
    if breakage == "reflection_off":
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fx = EffectSet.from_scene(scene).without("reflection")
        return render(scene, view=VIEW, backend="llvm", effects=fx).image
    other = "physical" if shading == "classic" else "classic"
    return render(_scene_at(SCENE, other, golden), view=VIEW, backend="llvm").image


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
    good = render(_scene_at(SCENE, shading, g), view=VIEW, backend="llvm").image
    assert check_exact(good, g.image, EXACT_THRESHOLDS)["ok"]
    res = check_exact(_broken_render(shading, g, breakage), g.image, EXACT_THRESHOLDS)
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
    assert not res["ok"], f"the Z-test passed a render with the wrong ior: {res}"
