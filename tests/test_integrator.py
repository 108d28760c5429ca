"""The integrator's machinery: Fresnel against Mitsuba, camera rays, effect sets, freezing,
converged mode, the film, and the seed scenes."""
from __future__ import annotations

import warnings
from pathlib import Path

import drjit as dr
import numpy as np
import pytest

from renderer.camera import camera_arrays, primary_rays
from renderer.device import types
from renderer.effects import EffectSet
from renderer.film import read_exr, write_exr, write_png
from renderer.render import Renderer, render
from renderer.scene import Settings
from renderer.shade import fresnel
from util import box, camera, light, make_scene, material, pixel_ray, quad

ROOT = Path(__file__).resolve().parents[1]


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


def test_primary_rays_follow_camera_model(backend):
    t = types(backend)
    cam = camera([1, 2, 3], [0, 0.5, -1], fov_y=50, width=7, height=5, up=(0, 1, 0.2))
    o, d = primary_rays(camera_arrays(cam, t), 7, 5, t)
    D = np.stack([c.numpy() for c in d], axis=1)
    want = np.array([pixel_ray(cam, x + 0.5, y + 0.5) for y in range(5) for x in range(7)])
    np.testing.assert_allclose(D, want, atol=2e-6)
    # converged mode: 4 strata per pixel, each inside its quarter of the pixel
    o, d = primary_rays(camera_arrays(cam, t), 7, 5, t, spp=4, exact=False, seed=3)
    D = np.stack([c.numpy() for c in d], axis=1).reshape(5, 7, 4, 3)
    f = cam.target - cam.position; f /= np.linalg.norm(f)
    r = np.cross(f, cam.up); r /= np.linalg.norm(r)
    u = np.cross(r, f)
    ty = np.tan(np.radians(cam.fov_y) / 2); tx = ty * 7 / 5
    px = ((D @ r) / (D @ f) / tx + 1) * 7 / 2          # back to film positions
    py = (1 - (D @ u) / (D @ f) / ty) * 5 / 2
    for s in range(4):
        i, j = s % 2, s // 2
        fx = px[:, :, s] - np.arange(7)[None, :]
        fy = py[:, :, s] - np.arange(5)[:, None]
        assert np.all((fx >= i / 2 - 1e-5) & (fx <= (i + 1) / 2 + 1e-5)), s
        assert np.all((fy >= j / 2 - 1e-5) & (fy <= (j + 1) / 2 + 1e-5)), s
    assert np.std(fx) > 0.05   # jittered, not at the strata centres


def _diffuse_scene(**settings):
    floor = quad([-2, -1, -2], [-2, -1, 2], [2, -1, 2], [2, -1, -2])
    cube = box([-0.5, -1, -0.5], [0.5, 0, 0.5])
    return make_scene([(*floor, 0), (*cube, 1)],
                      materials=[material("floor", kd=0.7, ka=0.2),
                                 material("cube", kd=[0.2, 0.4, 0.8], ks=0.5, n=20, ka=0.1)],
                      lights=[light([1, 2, 1.5], 6.0), light([-1.5, 1, 1], [1, 0.5, 0.2])],
                      camera=camera([0, 1, 4], [0, -0.5, 0], width=32, height=32),
                      ambient=0.3, settings=Settings(**settings))


def _glass_scene(**settings):
    sc = _diffuse_scene(**settings)
    sc.materials.append(material("glass", k_refl=0.2, k_refr=0.8, ks=0.5, n=50,
                                 combination="fresnel"))
    sc.face_material[sc.face_object == 1] = 2
    return sc


def test_effects_follow_scene():
    fx = EffectSet.from_scene(_diffuse_scene())
    assert (fx.shadows, fx.ambient, fx.specular, fx.many_lights) == (True, True, True, True)
    assert not (fx.reflection or fx.refraction or fx.secondary or fx.fresnel or fx.smooth_normals)
    assert fx.depth == 0
    assert "cube" in fx.reasons["specular"]
    fx = EffectSet.from_scene(_glass_scene())
    assert fx.reflection and fx.refraction and fx.fresnel and fx.depth == 5
    assert "glass" in fx.reasons["refraction"]
    assert EffectSet.from_scene(_glass_scene(max_depth=0)).secondary is False
    assert "refraction" in str(fx) and "depth 5" in str(fx)
    with pytest.warns(UserWarning, match="differs from the scene"):
        off = fx.without("refraction")
    assert not off.refraction and off.forced and "forced" in str(off)
    with pytest.raises(ValueError, match="effects.without"):
        fx.without("caustics")


def test_specialised_kernel_matches_general_kernel(backend):
    for sc in (_diffuse_scene(), _glass_scene()):
        own = render(sc, backend=backend)
        general = render(sc, backend=backend, effects=EffectSet.all(sc))
        np.testing.assert_allclose(own.image, general.image, rtol=1e-6, atol=1e-7)
        assert own.image.max() > 0.1


def test_effect_forced_off_changes_image(backend):
    sc = _glass_scene()
    fx = EffectSet.from_scene(sc)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        no_shadow = render(sc, backend=backend, effects=fx.without("shadows")).image
    assert np.abs(no_shadow - render(sc, backend=backend).image).max() > 0.05


def test_frozen_frame_matches_traced_frame_with_moved_camera(backend):
    sc = _glass_scene()
    traced = Renderer(sc, backend=backend)
    frozen = Renderer(sc, backend=backend, freeze=True)
    cams = [sc.cameras[0], camera([0.5, 1.2, 3.5], [0, -0.4, 0], width=32, height=32),
            camera([-1, 0.5, 3.8], [0.1, -0.5, 0], width=32, height=32)]
    for cam in cams:
        a = traced.frame(traced.camera(cam), 32, 32).numpy()
        b = frozen.frame(frozen.camera(cam), 32, 32).numpy()
        np.testing.assert_array_equal(a, b)
    assert frozen.frame_fn.n_recordings == 1   # recorded once, replayed for the moved cameras
    assert np.abs(a - traced.frame(traced.camera(cams[0]), 32, 32).numpy()).max() > 0.05


def test_converged_mode_is_seeded_and_close_to_exact(backend):
    sc = _diffuse_scene(exact=False, spp=16, seed=7)
    a = render(sc, backend=backend).image
    b = render(sc, backend=backend).image
    np.testing.assert_array_equal(a, b)
    c = render(sc.with_settings(seed=8), backend=backend).image
    assert np.abs(a - c).max() > 0
    exact = render(sc, backend=backend, exact=True).image
    # antialiasing changes edges only: the median pixel difference is tiny
    assert np.median(np.abs(a - exact)) < 5e-3
    assert np.abs(a - exact).max() > 0.02


def test_max_depth_above_stack_limit_is_an_error():
    with pytest.raises(ValueError, match="max_depth"):
        render(_glass_scene(max_depth=17), backend="llvm")


def test_float64_matches_float32(backend):
    sc = _glass_scene()
    a = render(sc, backend=backend).image
    b = render(sc, backend=backend, precision="float64").image
    assert np.mean(np.abs(a - b)) < 1e-4


def test_film_roundtrip_and_no_overwrite(tmp_path):
    img = np.random.default_rng(0).random((5, 7, 3)).astype(np.float32) * 4  # fixed seed
    p = write_exr(tmp_path / "a.exr", img)
    np.testing.assert_array_equal(read_exr(p), img)
    with pytest.raises(FileExistsError):
        write_exr(p, img)
    write_exr(p, img * 0, overwrite=True)
    assert read_exr(p).max() == 0
    q = write_png(tmp_path / "a.png", img)
    with pytest.raises(FileExistsError):
        write_png(q, img)
    import imageio.v3 as iio
    png = iio.imread(q)
    assert png.shape == (5, 7, 3) and png.dtype == np.uint8
    mid = np.array([[[0.5, 0.0031308, 1.0]]])
    write_png(tmp_path / "m.png", mid)
    np.testing.assert_array_equal(iio.imread(tmp_path / "m.png")[0, 0], [188, 10, 255])


def test_analytic_quad_scene_file_matches_closed_form(backend):
    scene_mod = pytest.importorskip("renderer.scene")
    if not hasattr(scene_mod, "load_scene"):
        pytest.skip("renderer.scene.load_scene not available")
    sc = scene_mod.load_scene(ROOT / "scenes" / "analytic_quad.toml")
    cam = sc.cameras[0]
    img = render(sc, backend=backend).image
    for x, y in [(32, 32), (20, 40), (10, 12)]:
        d = pixel_ray(cam, x + 0.5, y + 0.5)
        p = cam.position + (-cam.position[1] / d[1]) * d
        if max(abs(p[0]), abs(p[2])) > 1:
            np.testing.assert_allclose(img[y, x], 0.0)
            continue
        cos = 1 / np.sqrt(p[0] ** 2 + 1 + p[2] ** 2)
        np.testing.assert_allclose(img[y, x], [0.5 * cos] * 3, rtol=1e-5)


@pytest.mark.parametrize("accel", ["boxes", "bvh"])
def test_accelerators_give_brute_force_pixels(backend, accel):
    pytest.importorskip("renderer.accel.bvh")
    sc = _glass_scene()
    np.testing.assert_array_equal(render(sc, backend=backend, accel=accel).image,
                                  render(sc, backend=backend).image)
