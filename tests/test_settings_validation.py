"""Render settings are checked in one place (``validate_settings``): every entry point
(``Scene.with_overrides``, ``Renderer``, the camera) refuses the same bad values with a
``SceneError`` that names the field."""
from __future__ import annotations

from dataclasses import replace

import pytest
from util import diffuse_scene, glass_scene, light

from renderer.camera import camera_arrays, primary_rays
from renderer.device import types
from renderer.render import render
from renderer.scene import MAX_DEPTH_LIMIT, SceneError, validate_settings


@pytest.mark.parametrize("kwargs, field, text", [
    (dict(spp=8), "settings.spp", "perfect square"),
    (dict(spp=0), "settings.spp", "perfect square"),
    (dict(spp=4, exact=True), "settings.exact", "spp = 4"),
    (dict(max_depth=-1), "settings.max_depth", f"0..{MAX_DEPTH_LIMIT}"),
    (dict(max_depth=MAX_DEPTH_LIMIT + 1), "settings.max_depth", f"0..{MAX_DEPTH_LIMIT}"),
    (dict(shading="phong"), "settings.shading", "'classic'"),
])
def test_bad_settings_name_the_field(kwargs, field, text):
    with pytest.raises(SceneError, match=text) as e:
        validate_settings(**kwargs)
    assert e.value.field == field and str(e.value).startswith(field)
    with pytest.raises(SceneError) as e:
        diffuse_scene().with_overrides(**kwargs)
    assert e.value.field == field


def test_good_settings_pass():
    validate_settings(spp=16, exact=False, max_depth=MAX_DEPTH_LIMIT, shading="physical")
    validate_settings()


def test_max_depth_above_stack_limit_is_an_error():
    with pytest.raises(ValueError, match="max_depth"):
        render(glass_scene(max_depth=MAX_DEPTH_LIMIT + 1), backend="llvm")


def test_exact_camera_rays_refuse_several_samples():
    t = types("llvm")
    with pytest.raises(SceneError, match="settings.exact"):
        primary_rays(camera_arrays(diffuse_scene().cameras[0], t), 4, 4, t, spp=4, exact=True)


def test_with_overrides_applies_each_override():
    sc = diffuse_scene()
    s = sc.with_overrides(spp=16).settings
    assert (s.spp, s.exact) == (16, False)               # spp alone implies converged mode
    s = sc.with_overrides(spp=16).with_overrides(exact=True).settings
    assert (s.spp, s.exact) == (1, True)                 # exact alone takes one sample
    s = sc.with_overrides(max_depth=3, seed=9).settings
    assert (s.max_depth, s.seed) == (3, 9)
    resized = sc.with_overrides(size=(20, 10))
    assert [(c.width, c.height) for c in resized.cameras] == [(20, 10)]
    assert sc.settings.spp == 1 and sc.cameras[0].width == 32   # the original is unchanged
    with pytest.raises(SceneError, match="size"):
        sc.with_overrides(size=(0, 10))
    with pytest.raises(SceneError, match="seed"):
        sc.with_overrides(seed=-1)


def test_shading_override_keeps_the_light_model_valid():
    sc = diffuse_scene()                                 # inverse-square lights, built in code
    assert sc.with_overrides(shading="physical").settings.shading == "physical"
    classic_lights = replace(sc, lights=[light([1, 2, 1.5], 6.0, falloff="none")])
    with pytest.raises(SceneError, match="inverse_square"):
        classic_lights.with_overrides(shading="physical")
    from_file = replace(sc, path="scene.toml")           # the file's [physical] table applies
    with pytest.raises(SceneError, match="load_scene"):  # only when it is read
        from_file.with_overrides(shading="physical")
    assert from_file.with_overrides(shading="classic") is not None
