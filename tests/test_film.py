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
