"""Hard case 7 in CI (float32, LLVM): the shadow terminator of a low-polygon sphere with
interpolated normals under grazing light (``evaluation.hard.runners.case_terminator``).

Measured (both routines): no speckle where the facet faces the light; terminator pixels over
the three light angles 362 untreated and 34 with Hanika's point on the 80-face sphere, 202
and 0 on the 320-face sphere."""
from __future__ import annotations

import warnings

import numpy as np
from util_hard import CI, assert_green, rows_of

from evaluation.hard.runners import facing_light, render_image
from evaluation.hard.scenes import terminator_scene
from renderer.effects import EffectSet
from renderer.render import render
from renderer.scene import load_scene


def test_shadow_terminator():
    rows = rows_of("terminator")
    assert_green(rows)
    by = {r.variant: r.info for r in rows}
    for routine in ("moller_trumbore", "watertight"):
        for faces in (80, 320):
            none = by[f"{faces} faces/none/bvh/{routine}/float32"]["terminator_px"]
            hanika = by[f"{faces} faces/hanika/bvh/{routine}/float32"]["terminator_px"]
            assert none > 50, "the untreated terminator must show (the case can fail)"
            assert hanika < none


def _speckles(scene, routine):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        off = render_image(scene, CI, "bvh", routine, "float32",
                      EffectSet.from_scene(scene).without("shadows"))
    on = render_image(scene, CI, "bvh", routine, "float32")
    lost = (off.max(-1) > 0) & (on.max(-1) < 0.5 * off.max(-1))
    return int((lost & facing_light(scene, CI, routine, "float32")).sum())


def test_speckle_count_sees_acne():
    """The speckle criterion can fail: without any offset (``ray_epsilon = 0``) shadow rays
    re-hit their own facet (measured 792 speckle pixels with Möller–Trumbore)."""
    sc = terminator_scene(2, 88.0, 96).with_settings(ray_epsilon=0.0)
    assert _speckles(sc, "moller_trumbore") > 100


def test_hanika_changes_nothing_without_smooth_faces():
    """The treatment only moves shadow rays of smooth faces: a scene of flat faces renders
    bit for bit the same with it."""
    sc = load_scene("scenes/cornell_box.toml").with_size(48, 48)
    a = render(sc, backend="llvm").image
    b = render(sc.with_settings(terminator="hanika"), backend="llvm").image
    assert not any(o.smooth for o in sc.objects)
    assert np.array_equal(a, b)


def test_unknown_treatment_is_one_clear_error():
    import pytest

    from renderer.scene import SceneError
    with pytest.raises(SceneError, match=r"^settings\.terminator: expected one of 'none', "
                                         r"'hanika', got 'pbrt'$"):
        terminator_scene(1, 88.0, 8).with_settings(terminator="pbrt")
