"""renderer/film.py's image files: the one linear -> sRGB encoding and EXR layers."""
import numpy as np
import pytest

from renderer.film import read_exr, read_exr_layers, srgb_encode, write_exr


def test_srgb_encode_known_values():
    lin = np.array([[[0.0, 0.5, 1.0], [0.0031308, 2.0, -1.0]]], np.float32)
    enc = srgb_encode(lin)
    assert enc.dtype == np.uint8
    # 0.5 linear -> 1.055 * 0.5^(1/2.4) - 0.055 = 0.7354 -> 188
    assert enc.tolist() == [[[0, 188, 255], [10, 255, 0]]]


def test_exr_variance_layer_round_trips_exactly(tmp_path):
    rng = np.random.default_rng(3)  # fixed seed: the images are test data
    img = rng.uniform(0, 2, (5, 7, 3)).astype(np.float32)
    var = (rng.uniform(0, 1, (5, 7, 3)) * 1e-9).astype(np.float32)  # far below half's range
    p = write_exr(tmp_path / "a.exr", img, layers={"var": var})
    layers = read_exr_layers(p)
    assert sorted(layers) == ["", "var"]
    np.testing.assert_array_equal(layers[""], img)
    np.testing.assert_array_equal(layers["var"], var)
    np.testing.assert_array_equal(read_exr(p), img)
    assert "var" not in read_exr_layers(write_exr(tmp_path / "b.exr", img))


def test_exr_layer_of_another_shape_is_refused(tmp_path):
    img = np.zeros((4, 4, 3), np.float32)
    with pytest.raises(ValueError, match="layer 'var'"):
        write_exr(tmp_path / "a.exr", img, layers={"var": np.zeros((4, 5, 3))})
    assert not (tmp_path / "a.exr").exists()
