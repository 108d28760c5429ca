"""Guards against input the kernels cannot represent: each is one clear error naming the
file and the field (or a numerical guard), checked here on the exact inputs that broke."""
from __future__ import annotations

import drjit as dr
import numpy as np
import pytest

from renderer.render import Renderer, render
from renderer.scene import SceneError, load_scene, precision_limits
from renderer.shade import phong_power

QUAD = """
[render]
max_depth = {max_depth}
spp = {spp}

[camera]
position = [0.0, 3.0, 0.0]
target = [0.0, 0.0, 0.0]
up = [0.0, 0.0, -1.0]
resolution = [{w}, {h}]

[[lights]]
position = [0.0, 1.0, {lz}]
intensity = {intensity}

[materials.m]
kd = 0.5
ks = 0.5
n = 300

[[objects]]
shape = "quad"
material = "m"
scale = [{sc}, {sc}, {sc}]
translate = [0.0, 0.0, {tz}]
"""


def write(tmp_path, **kw):
    p = tmp_path / "guard.toml"
    v = dict(max_depth=2, spp=1, w=16, h=16, lz=0.0, intensity=1.0, tz=0.0, sc=2.0)
    v.update(kw)
    p.write_text(QUAD.format(**v))
    return p


def test_intensity_whose_square_overflows_float32_is_an_error(tmp_path):
    p = write(tmp_path, intensity="1e39")
    sc = load_scene(p)
    with pytest.raises(SceneError, match=r"guard\.toml: lights\[0\]\.intensity: "
                                         r"intensity 1e\+39 exceeds the float32 image limit"):
        Renderer(sc, backend="llvm")
    # the image is float32 whatever the precision, so float64 refuses it too
    with pytest.raises(SceneError, match=r"lights\[0\]\.intensity"):
        Renderer(sc, backend="llvm", precision="float64")


def test_intensity_at_the_float32_limit_renders_finite(tmp_path):
    _, i_lim = precision_limits(False)
    img = render(load_scene(write(tmp_path, intensity=repr(i_lim * 0.999))),
                 backend="llvm").image
    assert np.all(np.isfinite(img)) and img.max() > 0


def test_coordinates_whose_squares_overflow_are_an_error(tmp_path):
    with pytest.raises(SceneError, match=r"lights\[0\]\.position: coordinate .*float32"):
        Renderer(load_scene(write(tmp_path, lz="1e19")), backend="llvm")
    Renderer(load_scene(write(tmp_path, lz="1e19")), backend="llvm", precision="float64")
    with pytest.raises(SceneError, match=r"objects\[0\] \('quad0'\) vertices: coordinate"):
        Renderer(load_scene(write(tmp_path, tz="1e19", sc="1e19")), backend="llvm")


def test_max_depth_beyond_the_kernel_stack_is_rejected_at_load(tmp_path):
    with pytest.raises(SceneError, match=r"guard\.toml: render\.max_depth: expected an "
                                         r"integer in 0\.\.16, got 17"):
        load_scene(write(tmp_path, max_depth=17))


def test_image_beyond_the_array_limit_is_rejected(tmp_path):
    with pytest.raises(SceneError, match=r"guard\.toml: camera\.resolution: 65536 x 65536 "
                                         r"pixels .* 2\^32 - 1"):
        load_scene(write(tmp_path, w=65536, h=65536))
    with pytest.raises(SceneError, match=r"camera\.resolution: 30000 x 30000 pixels at "
                                         r"spp = 16"):
        load_scene(write(tmp_path, w=30000, h=30000, spp=16))
    sc = load_scene(write(tmp_path))
    with pytest.raises(SceneError, match=r"size\.resolution"):
        sc.with_overrides(size=(70000, 70000))
    with pytest.raises(SceneError, match=r"views\[0\]\.resolution"):
        sc.with_overrides(spp=65536 * 4, exact=False).with_size(1024, 1024).with_overrides(
            spp=65536 * 4)


def test_phong_power_float64_guard_on_the_input_that_gave_minus_inf():
    import drjit.llvm as L
    x = L.Float64([0.09386617626859929, 0.5, 0.0, 1.0])
    n = L.Float64([300.0, 2.0, 5.0, 1e4])
    dr.make_opaque(x, n)
    raw = dr.power(x, n).numpy()
    got = phong_power(x, n).numpy()
    assert np.all(np.isfinite(got)) and np.all(got >= 0)
    # the guarded value is 0 where Dr.Jit's pow is wrong (true 5.7e-309 < 2^-1000),
    # and bitwise Dr.Jit's elsewhere
    assert got[0] == 0.0
    assert np.array_equal(got[1:], np.where(x.numpy()[1:] > 0, raw[1:], 0.0))
    assert got[1] == 0.25 and got[3] == 1.0
    # the whole broken band [-1024, -1023.5) of exp2 arguments
    e = np.linspace(-1030, -990, 40001)
    X = L.Float64(2.0 ** (e / 300))
    N = L.Float64(np.full_like(e, 300.0))
    dr.make_opaque(X, N)
    g = phong_power(X, N).numpy()
    assert np.all(np.isfinite(g)) and np.all(g >= 0)
    ref = 2.0 ** e
    keep = e > -1000 + 1e-9
    assert np.allclose(g[keep], ref[keep], rtol=1e-12, atol=0)


def test_phong_power_float32_is_untouched():
    import drjit.llvm as L
    x = L.Float(np.linspace(0, 1, 1001))
    n = L.Float(np.full(1001, 300.0))
    dr.make_opaque(x, n)
    assert np.array_equal(phong_power(x, n).numpy(),
                          np.where(x.numpy() > 0, dr.power(x, n).numpy(), 0.0))


@pytest.mark.slow
def test_glass_bunny_float64_has_no_non_finite_pixel():
    """The shipped glass bunny at 512² in float64 had 7 -inf pixels (Dr.Jit's float64
    pow); with ``phong_power`` none."""
    sc = load_scene("scenes/glass_bunny.toml").with_size(512, 512)
    img = render(sc, backend="llvm", precision="float64").image
    assert np.all(np.isfinite(img))


#: Tiny scenes, refused like huge ones: (quad scale, precision, refused).
TINY = [("1e-18", "float32", True), ("1e-12", "float32", True), ("1e-9", "float32", False),
        ("1e-18", "float64", False), ("1e-60", "float64", False)]


@pytest.mark.parametrize("scale,precision,refused", TINY)
def test_scenes_whose_length_products_underflow_are_an_error(tmp_path, scale, precision,
                                                             refused):
    sc = load_scene(write(tmp_path, sc=scale))
    if refused:
        with pytest.raises(SceneError, match=r"guard\.toml: objects vertices: the scene is "
                                             rf".* across, under the {precision} limit"):
            Renderer(sc, backend="llvm", precision=precision)
    else:
        Renderer(sc, backend="llvm", precision=precision)
