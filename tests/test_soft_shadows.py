"""Sphere and rectangle lights (docs/MODEL.md, "Lights with extent"): radius 0 is the point
light bit for bit, the shadow samples are deterministic per seed and independent of the
batching, and the estimates meet closed forms (a fully visible uniform sphere lights a
diffuse plane exactly as a point light at its centre; a rectangle's irradiance is its
form factor)."""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from util import box, camera, light, make_scene, material, quad

from renderer.effects import EffectSet
from renderer.render import Renderer, render
from renderer.scene import SceneError, Settings, load_scene

ROOT = Path(__file__).resolve().parents[1]


def floor_scene(lights, *, shading="physical", cube=True, size=24, **settings):
    """A diffuse floor (kd 0.6) at y = 0, optionally a cube on it, seen from above."""
    objs = [(*quad([-3, 0, -3], [-3, 0, 3], [3, 0, 3], [3, 0, -3]), 0)]
    if cube:
        objs.append((*box([-0.4, 0, -0.4], [0.4, 0.8, 0.4]), 1))
    return make_scene(objs, materials=[material("floor", kd=0.6),
                                       material("cube", kd=[0.3, 0.5, 0.7])],
                      lights=lights,
                      camera=camera([0, 4, 3], [0, 0, 0], width=size, height=size),
                      settings=Settings(shading=shading, **settings))


def sphere(pos, intensity, radius, **kw):
    return replace(light(pos, intensity, **kw), shape="sphere", radius=radius)


def test_radius_zero_in_a_file_is_the_point_light(tmp_path):
    src = (ROOT / "scenes/cornell_soft.toml").read_text()
    f = tmp_path / "zero.toml"
    f.write_text(src.replace("radius = 0.15", "radius = 0.0"))
    sc = load_scene(f)
    assert sc.lights[0].shape == "point" and not EffectSet.from_scene(sc).soft_shadows
    soft = load_scene(ROOT / "scenes/cornell_soft.toml")
    assert soft.lights[0].shape == "sphere" and soft.lights[0].radius == 0.15
    assert EffectSet.from_scene(soft).soft_shadows


def test_point_light_in_a_soft_kernel_is_bitwise_the_point_light(backend):
    """A point light shaded by the soft-shadow kernel (beside a light of extent that adds
    exactly 0) gives the point-light kernel's pixels bit for bit."""
    key = light([1, 2.5, 1.5], 6.0, name="key")
    dark = sphere([-1, 2, 0], 0.0, 0.3, name="dark")
    for shading in ("classic", "physical"):
        a = render(floor_scene([key], shading=shading), backend=backend).image
        sc = floor_scene([key, dark], shading=shading, shadow_samples=4)
        fx = EffectSet.from_scene(sc)
        assert fx.soft_shadows and fx.many_lights
        b = render(sc, backend=backend).image
        np.testing.assert_array_equal(a, b)
        assert a.max() > 0.05


def test_shadow_samples_deterministic_per_seed_and_batching(backend):
    sc = floor_scene([sphere([0.5, 2, 0.5], 8.0, 0.5)], shadow_samples=4, seed=3)
    a = Renderer(sc, backend=backend).render(0).image
    b = Renderer(sc, backend=backend).render(0, tile_samples=5 * 24).image
    np.testing.assert_array_equal(a, b)
    c = Renderer(sc.with_settings(seed=4), backend=backend).render(0).image
    assert np.abs(a - c).max() > 1e-3                # the penumbra moves with the seed
    hard = render(floor_scene([light([0.5, 2, 0.5], 8.0)]), backend=backend).image
    assert np.abs(a - hard).max() > 0.05             # and it is not the hard shadow


def test_uniform_sphere_lights_a_plane_as_its_centre_point(backend):
    """Physical shading, no occluder: a uniform sphere wholly above a diffuse plane gives
    the irradiance of a point light of the same intensity at its centre (Newton's shell
    theorem for 1/r²-weighted cosines), so the converged image is the point light's."""
    centre, I = [0.3, 1.5, -0.2], 5.0
    point = render(floor_scene([light(centre, I)], cube=False), backend=backend).image
    sc = floor_scene([sphere(centre, I, 0.6)], cube=False, shadow_samples=256)
    soft = render(sc, backend=backend).image
    rel = np.abs(soft - point) / np.maximum(point, 1e-3)
    assert point.min() > 0.01
    assert rel.mean() < 2e-3 and rel.max() < 8e-3, (rel.mean(), rel.max())   # 1/N: stratified


def test_rectangle_irradiance_is_its_form_factor(backend):
    """A one-sided rectangle light facing down at height h over the camera's centre pixel:
    physical diffuse radiance ``kd/π · π L_e F`` with the closed-form form factor of a
    parallel rectangle (the sum over its four corner sub-rectangles)."""
    h, a, b, I = 1.2, 1.6, 1.0, 3.0
    rect = replace(light([0, h, 0], I), shape="rectangle", edge_u=np.array([a, 0, 0]),
                   edge_v=np.array([0, 0, b]))                  # normal (0, -1, 0)
    sc = floor_scene([rect], cube=False, shadow_samples=1024, size=1)
    sc = replace(sc, cameras=[replace(sc.cameras[0], position=np.array([0, 3.0, 1e-3]),
                                      target=np.zeros(3), fov_y=1.0)])
    v = render(sc, backend=backend).image[0, 0, 0]

    def corner(x, y):                                            # point below a corner
        A, B = x / h, y / h
        sa, sb = math.sqrt(1 + A * A), math.sqrt(1 + B * B)
        return (A / sa * math.atan(B / sa) + B / sb * math.atan(A / sb)) / (2 * math.pi)
    F = 4 * corner(a / 2, b / 2)
    L_e = I / (a * b)
    expect = 0.6 / math.pi * math.pi * L_e * F
    assert abs(v - expect) / expect < 3e-3, (v, expect)
    back = replace(rect, edge_u=rect.edge_v, edge_v=rect.edge_u)   # faces up: dark
    assert render(replace(sc, lights=[back]), backend=backend).image.max() == 0
    two = replace(back, two_sided=True)
    v2 = render(replace(sc, lights=[two]), backend=backend).image[0, 0, 0]
    assert abs(v2 - expect) / expect < 3e-3, (v2, expect)


def test_tiny_sphere_converges_to_the_point_light(backend):
    for shading in ("classic", "physical"):
        pt = render(floor_scene([light([0.5, 2, 0.5], 6.0)], shading=shading),
                    backend=backend).image
        tiny = render(floor_scene([sphere([0.5, 2, 0.5], 6.0, 1e-6)], shading=shading,
                                  shadow_samples=4), backend=backend).image
        np.testing.assert_allclose(tiny, pt, rtol=1e-4, atol=1e-6)


def test_bad_light_fields_name_the_field(tmp_path):
    src = (ROOT / "scenes/cornell_soft.toml").read_text()
    for old, new, field in (("radius = 0.15", "radius = -1.0", "lights[0].radius"),
                            ("shadow_samples = 4", "shadow_samples = 5",
                             "render.shadow_samples"),
                            ('type = "sphere"', 'type = "disk"', "lights[0].type"),
                            ("radius = 0.15", "radius = 0.15\nedge_u = [1, 0, 0]",
                             "lights[0].edge_u")):
        f = tmp_path / "bad.toml"
        f.write_text(src.replace(old, new))
        with pytest.raises(SceneError, match=field.replace("[", r"\[").replace("]", r"\]")):
            load_scene(f)
