"""Only the effects a scene calls for are traced, and that is proven with Dr.Jit's numbers.

For every effect flag there is a small scene with it and one without it (the base scene, or
the scene with the one ingredient taken away). The flag follows the scene; the kernel
specialised to the scene (``EffectSet.from_scene``) gives the pixels of the general
all-effects kernel (``EffectSet.all``); and where the scene lacks the effect the specialised
frame has fewer IR operations. Operations are the sum of ``operation_count`` over the
frame's kernels (``renderer.stats.kernel_operations``): a frame is one kernel today, and the
sum also catches work moved into an extra kernel, which the largest kernel alone would miss.
"""
from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from util import box, camera, light, make_scene, material, quad

from renderer.effects import FLAGS, EffectSet, convex_mirror, reachable_depth
from renderer.render import Renderer
from renderer.scene import Settings
from renderer.stats import kernel_operations

ROOT = Path(__file__).resolve().parents[1]
SIZE = 24


def scene_with(*extra, mirror_smooth=False, **settings):
    """A diffuse floor and cube under one light (only ``shadows`` on), plus the named
    ingredients: ambient, specular, reflection, refraction, fresnel, smooth, two_lights,
    no_light."""
    extra = set(extra)
    cube_mat = material("cube", kd=[0.2, 0.4, 0.8], ka=0.1 if "ambient" in extra else 0.0,
                        ks=0.6 if "specular" in extra else 0.0, n=3)
    if "reflection" in extra:
        cube_mat = replace(cube_mat, name="mirror", k_refl=np.full(3, 0.8))
    if "refraction" in extra or "fresnel" in extra:
        cube_mat = replace(cube_mat, name="glass", k_refl=np.full(3, 0.1),
                           k_refr=np.full(3, 0.85),
                           combination="fresnel" if "fresnel" in extra else "constant")
    floor = quad([-2, -1, -2], [-2, -1, 2], [2, -1, 2], [2, -1, -2])
    cube = box([-0.5, -1, -0.5], [0.5, 0, 0.5])
    lights = [light([1, 2, 1.5], 6.0, name="key")]
    if "two_lights" in extra:
        lights.append(light([-1.5, 1, 1], [1, 0.5, 0.2], name="fill"))
    if "sphere_light" in extra:
        lights[0] = replace(lights[0], shape="sphere", radius=0.4)
        settings.setdefault("shadow_samples", 4)
    if "no_light" in extra:
        lights = []
    return make_scene([(*floor, 0), (*cube, 1, "smooth" in extra)],
                      materials=[material("floor", kd=0.7, ka=0.2), cube_mat],
                      lights=lights, ambient=0.3 if "ambient" in extra else 0.0,
                      camera=camera([0, 1, 4], [0, -0.5, 0], width=SIZE, height=SIZE),
                      settings=Settings(**settings))


# flag -> (scene that needs it, scene that does not)
CASES = {
    "shadows": (lambda: scene_with(), lambda: scene_with("no_light", "ambient")),
    "ambient": (lambda: scene_with("ambient"), lambda: scene_with()),
    "reflection": (lambda: scene_with("reflection"), lambda: scene_with()),
    "refraction": (lambda: scene_with("refraction"), lambda: scene_with("reflection")),
    "smooth_normals": (lambda: scene_with("smooth"), lambda: scene_with()),
    "specular": (lambda: scene_with("specular"), lambda: scene_with()),
    "many_lights": (lambda: scene_with("two_lights"), lambda: scene_with()),
    "fresnel": (lambda: scene_with("fresnel"), lambda: scene_with("refraction")),
    "soft_shadows": (lambda: scene_with("sphere_light"), lambda: scene_with()),
    "secondary": (lambda: scene_with("reflection"), lambda: scene_with("reflection", max_depth=0)),
}


def flag(fx: EffectSet, name: str) -> bool:
    return fx.secondary if name == "secondary" else getattr(fx, name)


def frame(sc, backend, effects=None):
    """(kernel_operations dict, image (H, W, 3)) of one frame of ``sc``."""
    r = Renderer(sc, backend=backend, effects=effects)
    ca = r.camera(0)
    k = kernel_operations(lambda: r.frame(ca, SIZE, SIZE))
    return k, k["result"].numpy()


def test_every_flag_has_a_case():
    assert set(CASES) == set(FLAGS) | {"secondary"}


@pytest.mark.parametrize("name", list(CASES))
def test_flag_follows_scene(name):
    with_sc, without_sc = (f() for f in CASES[name])
    on, off = EffectSet.from_scene(with_sc), EffectSet.from_scene(without_sc)
    assert flag(on, name) and not flag(off, name)
    if name != "secondary":
        assert on.reasons[name] and name in " ".join(on.lines())
        assert name not in off.reasons
    # adding the ingredient never switches another effect off (except shadows: the
    # scene without a light has ambient light instead)
    if name != "shadows":
        for k in FLAGS:
            assert getattr(on, k) >= getattr(off, k), (name, k)


@pytest.mark.parametrize("name", list(CASES))
def test_specialised_kernel_is_smaller_and_gives_general_pixels(backend, name):
    for sc, lacks in zip((f() for f in CASES[name]), (False, True)):
        own_k, own = frame(sc, backend)
        gen_k, gen = frame(sc, backend, EffectSet.all(sc))
        # same arithmetic in the same order: equal pixels (1e-6 relative allows for a
        # backend that contracts or reorders differently between the two kernels)
        np.testing.assert_allclose(own, gen, rtol=1e-6, atol=1e-7, err_msg=name)
        assert own.max() > 0.05, name
        assert own_k["kernels"] >= 1
        if lacks:
            assert own_k["operations"] < gen_k["operations"], (name, own_k["ops"], gen_k["ops"])
        else:
            assert own_k["operations"] <= gen_k["operations"], name


@pytest.mark.parametrize("name", [n for n in CASES if n != "shadows"])
def test_each_flag_alone_costs_operations(backend, name):
    """Against the general kernel every missing effect counts together; here the scene's own
    set gets just this one flag switched on: more operations, the same pixels. (shadows is
    left out: it is off only without lights, and then there is no light to shade at all.)"""
    sc = CASES[name][1]()
    fx = EffectSet.from_scene(sc)
    if name in ("reflection", "secondary"):
        forced = replace(fx, reflection=True, depth=max(sc.settings.max_depth, 1))
    else:
        forced = replace(fx, **{name: True})
    assert flag(forced, name) and not flag(fx, name)
    own_k, own = frame(sc, backend, fx)
    more_k, more = frame(sc, backend, forced)
    np.testing.assert_allclose(own, more, rtol=1e-6, atol=1e-7, err_msg=name)
    assert own_k["operations"] < more_k["operations"], (name, own_k["ops"], more_k["ops"])


@pytest.mark.parametrize("name", [n for n in CASES if n != "secondary"])
def test_needed_effect_changes_the_image(backend, name):
    """The scene that calls for an effect looks different without it: the effect is real
    work, not decoration, and the derived set must keep it."""
    sc = CASES[name][0]()
    fx = EffectSet.from_scene(sc)
    with pytest.warns(UserWarning, match="differs from the scene"):
        off = fx.without(name)
    _, a = frame(sc, backend)
    _, b = frame(sc, backend, off)
    assert np.abs(a - b).max() > 1e-3, name


def test_adding_ingredients_switches_effects_on():
    base = scene_with()
    fx = EffectSet.from_scene(base)
    assert [k for k in FLAGS if getattr(fx, k)] == ["shadows"] and fx.depth == 0
    glass = EffectSet.from_scene(scene_with("refraction"))
    assert glass.refraction and glass.reflection and "glass" in glass.reasons["refraction"]
    clear = scene_with("refraction")                    # k_refl = 0: reflects only by TIR
    clear.materials[1] = replace(clear.materials[1], k_refl=np.zeros(3))
    tir = EffectSet.from_scene(clear)
    assert tir.reflection and "total internal reflection" in tir.reasons["reflection"]
    two = EffectSet.from_scene(scene_with("two_lights"))
    assert two.many_lights and two.reasons["many_lights"] == "2 lights"
    mirror = scene_with("reflection", max_depth=3)
    assert EffectSet.from_scene(mirror).depth == 1      # the cube is a convex mirror
    assert EffectSet.from_scene(scene_with("refraction", max_depth=3)).depth == 3
    assert EffectSet.from_scene(mirror.with_settings(max_depth=0)).secondary is False
    assert EffectSet.from_scene(scene_with("no_light")).shadows is False
    fx = EffectSet.from_scene(scene_with("fresnel", max_depth=5))
    assert "refraction" in str(fx) and "depth 5" in str(fx)
    with pytest.raises(ValueError, match="effects.without"):
        fx.without("caustics")


# ---- the reachable depth ---------------------------------------------------------------------
def mirror_scene(*objects_extra, cam=(0, 1, 4), smooth=False, max_depth=5):
    """Floor, a diffuse wall, and a closed flat mirror box (object 2) seen from ``cam``;
    ``objects_extra``: further (V, F, material) objects."""
    floor = quad([-3, -1, -3], [-3, -1, 3], [3, -1, 3], [3, -1, -3])
    wall = quad([-3, -1, -2], [3, -1, -2], [3, 2, -2], [-3, 2, -2])
    mirror = box([-0.6, -1, -0.6], [0.6, 0.2, 0.6])
    return make_scene([(*floor, 0), (*wall, 1), (*mirror, 2, smooth), *objects_extra],
                      materials=[material("floor", kd=0.7), material("wall", kd=[0.8, 0.3, 0.2]),
                                 material("mirror", k_refl=0.9, kd=0.05)],
                      lights=[light([1, 2.5, 2], 8.0)],
                      camera=camera(cam, [0, -0.3, 0], width=SIZE, height=SIZE),
                      settings=Settings(max_depth=max_depth))


def test_depth_capped_for_a_single_convex_mirror(backend):
    sc = mirror_scene()
    fx = EffectSet.from_scene(sc)
    assert fx.depth == 1 and "convex" in fx.reasons["depth"]
    assert "capped at 1" in " ".join(fx.lines())
    _, capped = frame(sc, backend)
    _, full = frame(sc, backend, replace(fx, depth=5))
    np.testing.assert_array_equal(capped, full)
    assert capped.max() > 0.05


def test_depth_not_capped_when_a_mirror_can_see_itself(backend):
    # two mirror boxes in one object: not convex
    V1, F1 = box([-0.6, -1, -0.6], [0.6, 0.2, 0.6])
    V2, F2 = box([0.9, -1, -0.9], [1.5, 0.8, 0.3])
    pair = make_scene([(np.concatenate([V1, V2]), np.concatenate([F1, F2 + len(V1)]), 0)],
                      materials=[material("mirror", k_refl=0.9)])
    assert convex_mirror(pair, 0) is None
    # a second mirror (a plane in front of the wall): the box and the plane see each other
    sc2 = mirror_scene((*quad([-3, -1, -1.9], [3, -1, -1.9], [3, 2, -1.9], [-3, 2, -1.9]), 2))
    assert reachable_depth(sc2)[0] == 5
    # with the cap forced anyway the image changes: the cap is not free
    fx = EffectSet.from_scene(sc2)
    _, full = frame(sc2, backend)
    _, capped = frame(sc2, backend, replace(fx, depth=1))
    assert np.abs(full - capped).max() > 1e-3


def test_depth_cap_conditions():
    assert reachable_depth(mirror_scene())[0] == 1
    assert reachable_depth(mirror_scene(smooth=True))[0] == 5         # smooth normals
    assert reachable_depth(mirror_scene(cam=(0, -0.4, 0)))[0] == 5    # camera inside
    assert reachable_depth(mirror_scene(max_depth=1))[0] == 1
    glass = scene_with("refraction", max_depth=4)
    assert EffectSet.from_scene(glass).depth == 4                     # something transmits
    plane = make_scene([(*quad([-1, 0, -1], [-1, 0, 1], [1, 0, 1], [1, 0, -1]), 0)],
                       materials=[material("mirror", k_refl=0.9)])
    assert "planar" in convex_mirror(plane, 0)
    bv, bf = box([-1, -1, -1], [1, 1, 1])
    open_box = make_scene([(bv, bf[2:], 0)],
                          materials=[material("mirror", k_refl=0.9)])
    assert convex_mirror(open_box, 0) is None                          # not closed


# ---- visible: CLI and report -----------------------------------------------------------------
def test_cli_render_prints_effects_reasons_and_operations(tmp_path):
    import contextlib
    import io

    from whitted.cli import main
    out = io.StringIO()
    err = io.StringIO()
    with (contextlib.redirect_stdout(out), contextlib.redirect_stderr(err),
          warnings.catch_warnings()):
        warnings.simplefilter("ignore")
        assert main(["render", str(ROOT / "scenes" / "cornell_box.toml"), "--size", "16x16",
                     "--backend", "llvm", "--accel", "brute", "--out", str(tmp_path),
                     "--effect-off", "shadows"]) == 0
    text = out.getvalue()
    assert "refraction — material 'glass'" in text
    assert "reflection — material 'mirror'" in text
    assert "shadows —" not in text                     # forced off
    assert "IR operations in 1 kernel" in text
    assert "differs from the scene's truth" in err.getvalue()


def test_compare_report_shows_effects_and_operations(tmp_path):
    pytest.importorskip("mitsuba")
    from whitted.cli import main
    out = tmp_path / "report"
    assert main(["compare", str(ROOT / "scenes" / "analytic_quad.toml"), "--size", "16x16",
                 "--backend", "llvm", "--live", "--out", str(out)]) == 0
    html = (out / "index.html").read_text()
    from renderer.scene import load_scene
    fx = EffectSet.from_scene(load_scene(ROOT / "scenes" / "analytic_quad.toml"))
    assert str(fx) in html
    assert "IR operations in" in html
