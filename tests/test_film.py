"""The film's files: EXR round trip, PNG sRGB encoding, no silent overwrite."""
from __future__ import annotations

import numpy as np
import pytest

from renderer.film import read_exr, write_exr, write_png


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


def test_png_decodes_to_the_srgb_encoding(tmp_path):
    """Every pixel of the written PNG is ``srgb_encode``'s byte (reference: the encoding
    itself, read back by imageio)."""
    import imageio.v3 as iio

    from renderer.film import srgb_encode
    img = np.random.default_rng(5).random((33, 47, 3)).astype(np.float32) * 1.2
    write_png(tmp_path / "r.png", img)
    np.testing.assert_array_equal(iio.imread(tmp_path / "r.png"), srgb_encode(img))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_srgb_encode_by_table_is_the_curve_byte_for_byte(dtype):
    """``srgb_encode``'s table lookup gives ``srgb_curve``'s bytes (the float64 curve
    itself, the reference) on random values in and around [0, 1], tiny and huge values,
    the special values, and the values at and next to every step of the byte."""
    from renderer.film import _srgb_steps, srgb_curve, srgb_encode
    rng = np.random.default_rng(5)
    steps = _srgb_steps(dtype)
    near = [steps]
    down, up = steps.copy(), steps.copy()
    for _ in range(3):
        down, up = np.nextafter(down, dtype(0)), np.nextafter(up, dtype(2))
        near += [down, up]
    info = np.finfo(dtype)
    x = np.concatenate([rng.random(200_000), rng.normal(0.5, 1.0, 50_000),
                        rng.random(50_000) ** 12,
                        [np.nan, -np.nan, np.inf, -np.inf, 0.0, -0.0, 1.0, 2.0,
                         float(info.tiny), float(info.smallest_subnormal), float(info.max),
                         -float(info.max)]]).astype(dtype)
    x = np.concatenate([x] + near)
    assert np.array_equal(srgb_encode(x), srgb_curve(x))
    assert np.array_equal(srgb_encode(x.reshape(-1, 1, 1)), srgb_curve(x).reshape(-1, 1, 1))
    assert srgb_encode(steps).tolist() == list(range(1, 256))      # one byte per step
    h = x[:1000].astype(np.float16)                               # other dtypes: the curve
    assert np.array_equal(srgb_encode(h), srgb_curve(h))
    swapped = x[:1000].astype(np.dtype(dtype).newbyteorder())     # and other byte orders
    assert np.array_equal(srgb_encode(swapped), srgb_curve(x[:1000]))
