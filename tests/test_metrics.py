"""Metrics of evaluation/gate/metrics.py on synthetic images with known answers."""
import numpy as np
import pytest

from evaluation.gate import metrics


def _image(seed=0, h=16, w=24, lo=0.05, hi=0.9):
    rng = np.random.default_rng(seed)  # fixed seed: the images are test data, not noise
    return rng.uniform(lo, hi, (h, w, 3)).astype(np.float32)


def test_identical_images_have_zero_error():
    img = _image()
    m = metrics.metrics(img, img.copy())
    for key in ("rmse", "relmse", "max_abs", "mean_rel", "max_rel", "flip_mean",
                "de2000_mean", "de2000_p99", "de2000_max"):
        assert m[key] == pytest.approx(0.0, abs=1e-6), key
    assert m["outliers"] == 0
    assert m["nonfinite_pixels"] == 0
    assert m["pixels"] == 16 * 24


def test_constant_shift_gives_known_errors():
    ref = _image()
    shift = 0.05
    m = metrics.metrics(ref + shift, ref, eps=1e-2)
    r = ref.astype(np.float64)
    assert m["rmse"] == pytest.approx(shift, rel=1e-5)
    assert m["max_abs"] == pytest.approx(shift, rel=1e-5)
    assert m["relmse"] == pytest.approx(np.mean(shift**2 / (r**2 + 1e-2)), rel=1e-4)
    # per-pixel relative error = shift / (smallest channel of the pixel, floored at eps)
    rel_pixel = shift / np.maximum(r.min(axis=2), 1e-2)
    assert m["mean_rel"] == pytest.approx(rel_pixel.mean(), rel=1e-4)
    assert m["max_rel"] == pytest.approx(rel_pixel.max(), rel=1e-4)
    assert m["flip_mean"] > 0
    assert m["de2000_mean"] > 0


def test_outlier_rule_needs_both_relative_and_absolute_error():
    ref = np.full((8, 8, 3), 0.2, np.float32)
    ours = ref.copy()
    ours[1, 1, 0] += 0.05   # rel 0.25, abs 0.05: outlier
    ours[2, 2, 1] += 0.005  # rel 0.025, abs 0.005: not
    ours[3, 3] = 0.0        # rel 1.0, abs 0.2 in every channel: one outlier pixel
    ref[4, 4] = 0.001
    ours[4, 4] = 0.006      # rel 0.5 (eps floor 1e-2), abs 0.005: not
    ref[5, 5] = 10.0
    ours[5, 5] = 10.5       # abs 0.5, rel 0.05: not
    assert metrics.metrics(ours, ref)["outliers"] == 2
    assert metrics.outlier_mask(ours, ref).sum() == 2
    assert metrics.image_difference(ours, ref)["outliers"] == 2


def test_delta_e_white_against_black_is_100():
    # CIEDE2000 with a* = b* = 0 and mean L* = 50 reduces to |ΔL*| = 100.
    white = np.ones((4, 4, 3), np.float32)
    black = np.zeros((4, 4, 3), np.float32)
    de = metrics.delta_e2000(white, black)
    assert de.shape == (4, 4)
    np.testing.assert_allclose(de, 100.0, atol=0.05)


def test_delta_e_separates_close_and_different_colours():
    red = np.zeros((4, 4, 3), np.float32)
    red[..., 0] = 0.8
    green = np.zeros((4, 4, 3), np.float32)
    green[..., 1] = 0.8
    assert metrics.delta_e2000(red, red).max() == 0.0
    assert metrics.delta_e2000(red, green).min() > 50.0
    assert metrics.delta_e2000(red * 1.001, red).max() < 0.5


def test_flip_map_matches_mean_and_locates_the_error():
    ref = _image(1)
    ours = ref.copy()
    ours[4:8, 4:8] = 0.0
    fmap, mean = metrics.flip_error(ours, ref)
    assert fmap.shape == ref.shape[:2] and fmap.dtype == np.float32
    assert mean == pytest.approx(fmap.mean(), rel=1e-5)
    assert 0.0 <= fmap.min() and fmap.max() <= 1.0
    assert fmap[4:8, 4:8].mean() > 5 * fmap[12:, 16:].mean()
    assert metrics.metrics(ours, ref, flip_map=fmap)["flip_mean"] == pytest.approx(mean)


def test_flip_handles_black_reference():
    # FLIP cannot choose exposures from an all-black reference (it would end the process).
    black = np.zeros((8, 8, 3), np.float32)
    assert metrics.flip_error(black, black)[1] == 0.0
    _, mean = metrics.flip_error(_image(2, 8, 8), black)
    assert mean > 0.1


def test_nonfinite_pixels_are_counted_and_do_not_poison_metrics():
    ref = _image()
    ours = ref.copy()
    ours[0, 0, 0] = np.nan
    ours[1, 1, 2] = np.inf
    m = metrics.metrics(ours, ref)
    assert m["nonfinite_pixels"] == 2
    assert np.isfinite(m["rmse"]) and m["rmse"] > 0
    assert np.isfinite(m["flip_mean"]) and np.isfinite(m["de2000_mean"])


def test_shape_mismatch_is_an_error():
    with pytest.raises(ValueError, match="shape"):
        metrics.metrics(_image(h=8), _image(h=9))


def test_abs_heatmap_scale_and_colours():
    ref = np.full((6, 6, 3), 0.5, np.float32)
    ours = ref.copy()
    ours[2, 3, 1] += 0.25
    rgb, scale = metrics.abs_error_heatmap(ours, ref, cmap="inferno")
    assert rgb.shape == (6, 6, 3) and rgb.dtype == np.uint8
    assert scale == pytest.approx(0.25, rel=1e-5)
    stops = metrics.colormap_stops("inferno", 2)
    low, high = (tuple(int(s[i:i + 2], 16) for i in (1, 3, 5)) for s in stops)
    assert tuple(rgb[0, 0]) == low
    assert tuple(rgb[2, 3]) == high
    rgb2, scale2 = metrics.abs_error_heatmap(ours, ref, scale=1.0)
    assert scale2 == 1.0 and tuple(rgb2[2, 3]) != high


def _estimates(rng, mean, sigma, n, shape):
    """Sample mean and variance of the mean from n normal samples per value."""
    samples = rng.normal(mean, sigma, (n, *shape))
    return samples.mean(0), samples.var(0, ddof=1) / n


def test_z_test_passes_for_same_distribution_and_fails_for_bias():
    rng = np.random.default_rng(7)  # fixed seed: the test's outcome is reproducible
    shape = (16, 16, 3)
    truth = rng.uniform(0.1, 1.0, shape)
    sigma = 0.3
    n = 256
    ref_m, ref_v = _estimates(rng, truth, sigma, n, shape)
    ours_m, ours_v = _estimates(rng, truth, sigma, n, shape)
    frac, mask = metrics.z_test(ours_m, ours_v, ref_m, ref_v)
    assert mask.shape == shape and mask.dtype == bool
    assert frac == 1.0

    # A bias of 8 standard errors of the difference fails nearly everywhere.
    bias = 8 * sigma * np.sqrt(2.0 / n)
    biased_m, biased_v = _estimates(rng, truth + bias, sigma, n, shape)
    frac_b, mask_b = metrics.z_test(biased_m, biased_v, ref_m, ref_v)
    assert frac_b < 0.1
    # A bias confined to one region is found there and only there.
    local = truth.copy()
    local[:4, :4] += bias
    local_m, local_v = _estimates(rng, local, sigma, n, shape)
    _, mask_l = metrics.z_test(local_m, local_v, ref_m, ref_v)
    assert not mask_l[:4, :4].all()
    assert mask_l[4:, 4:].all()


def test_z_test_rejects_bad_arguments():
    a = np.zeros((2, 2))
    with pytest.raises(ValueError, match="ref_var"):
        metrics.z_test(a, a, a, np.zeros((3, 2)))
    with pytest.raises(ValueError, match="alpha"):
        metrics.z_test(a, a, a, a, alpha=1.5)


def test_student_t_quantile_matches_tables():
    # two-sided critical values from standard t tables
    assert abs(metrics.student_t_quantile(0.05, 10) - 2.228) < 1e-3
    assert abs(metrics.student_t_quantile(0.01, 15) - 2.947) < 1e-3
    assert abs(metrics.student_t_quantile(0.01, 30) - 2.750) < 1e-3
    assert abs(metrics.student_t_quantile(0.05, float("inf")) - 1.960) < 1e-3


@pytest.mark.parametrize("equal_var", [False, True])
def test_welch_test_false_failures_match_alpha_and_bias_fails(equal_var):
    """16 normal batches a side, 32x32x3 values, Šidák at alpha = 0.05: over 200 null
    trials about 5 % fail (binomial 99.9 % range 2-19); a 12 sigma bias on one value is
    caught and nothing else fails."""
    rng = np.random.default_rng(3)
    fails = 0
    for _ in range(200):
        a, b = rng.normal(size=(2, 16, 32, 32, 3))
        _, mask, _ = metrics.welch_test(a.mean(0), a.var(0, ddof=1), 16, b.mean(0),
                                        b.var(0, ddof=1), 16, alpha=0.05, equal_var=equal_var)
        fails += not mask.all()
    assert 2 <= fails <= 19, fails
    a, b = rng.normal(size=(2, 16, 64, 64, 3))
    a[:, 10, 20, 1] += 12.0 * np.sqrt(2.0 / 16)     # 12 sigma of the difference of means
    _, mask, _ = metrics.welch_test(a.mean(0), a.var(0, ddof=1), 16, b.mean(0),
                                    b.var(0, ddof=1), 16, alpha=0.05, equal_var=equal_var)
    assert not mask[10, 20, 1] and mask.sum() >= mask.size - 1
