"""Image-comparison metrics between our render and Mitsuba's, plus error maps for reports.

Every function takes two linear-light RGB images, float32 arrays of shape (H, W, 3) with the
same shape: ``ours`` (the image under test) and ``ref`` (the reference, Mitsuba's image).
Non-finite values (NaN, inf) in either image are counted in ``metrics()["nonfinite_pixels"]``
and replaced by 0 before any other metric is computed, so a stray NaN shows up as a large
error at its pixel instead of poisoning every number.

Metrics (``metrics()``):

- ``rmse``: sqrt(mean((a - r)^2)) over all pixels and channels.
- ``relmse``: mean((a - r)^2 / (r^2 + eps)) over all pixels and channels.
- ``max_abs``: max |a - r| over all pixels and channels.
- ``mean_rel`` / ``max_rel``: per-pixel relative error, the max over channels of
  |a - r| / max(|r|, eps); its mean and max over pixels.
- ``outliers``: number of pixels where some channel has relative error > ``OUTLIER_REL``
  *and* absolute error > ``OUTLIER_ABS`` (both must hold, so dark pixels with tiny absolute
  errors and bright pixels with tiny relative errors are not outliers): ``outlier_mask``.
- ``flip_mean``: mean HDR-FLIP error (NVIDIA's ``flip-evaluator``, HDR mode on the linear
  images, default viewing conditions of 67 pixels per degree), in [0, 1].
- ``de2000_mean`` / ``de2000_p99`` / ``de2000_max``: CIEDE2000 colour difference per
  pixel, linear sRGB (D65) -> CIE XYZ -> CIELAB with Y = 1 for white (1, 1, 1); mean,
  99th percentile and max over pixels.
  Values above 1 are not clipped (L* > 100 for over-white pixels).

``image_difference`` is the numpy-only subset (rmse, max_abs, mean_rel, outliers) for the
benchmark, which runs where colour-science and FLIP are not installed. ``z_test`` is the
statistical test for converged (noisy) renders, in the style of Mitsuba's ``test_renders.py``.
"""
from __future__ import annotations

import functools
import math
import warnings

import numpy as np

#: A pixel is an outlier if some channel has relative error above this ...
OUTLIER_REL = 0.1
#: ... and absolute error above this (linear radiance units).
OUTLIER_ABS = 0.01

__all__ = [
    "OUTLIER_ABS",
    "OUTLIER_REL",
    "abs_error",
    "abs_error_heatmap",
    "colormap_stops",
    "delta_e2000",
    "flip_error",
    "flip_heatmap",
    "image_difference",
    "metrics",
    "outlier_mask",
    "student_t_quantile",
    "welch_test",
    "z_test",
]


# ---- inputs -------------------------------------------------------------------------------
def _pair(ours: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Check shapes, convert to float64 and zero non-finite values.

    Returns (ours, ref, number of pixels with a non-finite value in either image)."""
    a = np.asarray(ours)
    r = np.asarray(ref)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"ours: expected an RGB image of shape (H, W, 3), got {a.shape}")
    if r.shape != a.shape:
        raise ValueError(f"ref: shape {r.shape} differs from ours {a.shape}")
    a = a.astype(np.float64)
    r = r.astype(np.float64)
    bad = ~(np.isfinite(a) & np.isfinite(r)).all(axis=2)
    if bad.any():
        a = np.where(np.isfinite(a), a, 0.0)
        r = np.where(np.isfinite(r), r, 0.0)
    return a, r, int(bad.sum())


# ---- per-pixel errors ---------------------------------------------------------------------
def outlier_mask(ours: np.ndarray, ref: np.ndarray, *, eps: float = 1e-2) -> np.ndarray:
    """The outlier rule: bool (H, W), True where some channel has relative error
    ``|a - r| / max(|r|, eps)`` above ``OUTLIER_REL`` and absolute error above
    ``OUTLIER_ABS``. Non-finite values are compared as they are (NaN is never an outlier
    here; ``metrics`` zeroes them first)."""
    a = np.asarray(ours, np.float64)
    r = np.asarray(ref, np.float64)
    err = np.abs(a - r)
    rel = err / np.maximum(np.abs(r), eps)
    return ((rel > OUTLIER_REL) & (err > OUTLIER_ABS)).any(axis=-1)


def abs_error(ours: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Per-pixel absolute error, the max over channels of |a - r|: float32 (H, W)."""
    a, r, _ = _pair(ours, ref)
    return np.abs(a - r).max(axis=2).astype(np.float32)


def _lab(rgb: np.ndarray) -> np.ndarray:
    """Linear sRGB (..., 3) -> CIELAB (..., 3), D65 white, Y = 1 for RGB (1, 1, 1)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # colour warns that optional SciPy features are off
        import colour

        space = colour.RGB_COLOURSPACES["sRGB"]
        xyz = colour.RGB_to_XYZ(rgb, space, apply_cctf_decoding=False)
        return colour.XYZ_to_Lab(xyz, space.whitepoint)


def delta_e2000(ours: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """CIEDE2000 difference per pixel of two linear sRGB images: float32 (H, W), >= 0.

    Negative radiance (never produced by either renderer) is clipped to 0 first."""
    a, r, _ = _pair(ours, ref)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import colour

        de = colour.delta_E(_lab(np.maximum(a, 0)), _lab(np.maximum(r, 0)), method="CIE 2000")
    return np.asarray(de, dtype=np.float32)


def flip_error(ours: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, float]:
    """HDR-FLIP error map and its mean: (float32 (H, W) in [0, 1], float).

    FLIP picks its exposure range from the reference's luminance; it cannot do so for an
    all-black reference (and ends the process if asked to), so then the range is taken
    from ``ours`` instead, and two black images give zero error without calling FLIP.
    Negative values are clipped to 0 (HDR-FLIP needs non-negative input).
    """
    import flip_evaluator

    a, r, _ = _pair(ours, ref)
    a = np.ascontiguousarray(np.maximum(a, 0), dtype=np.float32)
    r = np.ascontiguousarray(np.maximum(r, 0), dtype=np.float32)
    h, w, _ = a.shape
    params: dict = {}
    if r.max() <= 0:
        if a.max() <= 0:
            return np.zeros((h, w), np.float32), 0.0
        _, _, used = flip_evaluator.evaluate(a, a, "HDR", applyMagma=False, computeMeanError=False)
        params = {k: used[k] for k in ("startExposure", "stopExposure", "numExposures")}
    err, mean, _ = flip_evaluator.evaluate(r, a, "HDR", applyMagma=False, parameters=params)
    return np.asarray(err, np.float32).reshape(h, w), float(mean)


# ---- scalar metrics -----------------------------------------------------------------------
def metrics(ours: np.ndarray, ref: np.ndarray, *, eps: float = 1e-2,
            flip_map: np.ndarray | None = None) -> dict:
    """All scalar metrics of ``ours`` against ``ref`` (see the module docstring).

    ours, ref: float32 (H, W, 3) linear RGB, same shape.
    eps: floor of the denominator of the relative errors (``relmse``, ``*_rel``, outliers).
    flip_map: float32 (H, W) from ``flip_error(ours, ref)`` if already computed (saves
        running FLIP twice when a report needs the map too).

    Returns a dict of plain Python numbers: rmse, relmse, max_abs, mean_rel, max_rel,
    outliers (int), outlier_rule (str), eps, pixels (int), nonfinite_pixels (int), flip_mean,
    de2000_mean, de2000_p99, de2000_max.
    """
    a, r, nonfinite = _pair(ours, ref)
    diff = a - r
    absd = np.abs(diff)
    rel = absd / np.maximum(np.abs(r), eps)
    rel_pixel = rel.max(axis=2)
    outlier = outlier_mask(a, r, eps=eps)
    if flip_map is None:
        flip_map, _ = flip_error(a, r)
    de = delta_e2000(a, r)
    return {
        "rmse": float(np.sqrt(np.mean(diff**2))),
        "relmse": float(np.mean(diff**2 / (r**2 + eps))),
        "max_abs": float(absd.max()),
        "mean_rel": float(rel_pixel.mean()),
        "max_rel": float(rel_pixel.max()),
        "outliers": int(outlier.sum()),
        "outlier_rule": f"rel > {OUTLIER_REL:g} and abs > {OUTLIER_ABS:g} in some channel",
        "eps": float(eps),
        "pixels": int(a.shape[0] * a.shape[1]),
        "nonfinite_pixels": nonfinite,
        "flip_mean": float(np.mean(flip_map)),
        "de2000_mean": float(de.mean()),
        "de2000_p99": float(np.percentile(de, 99)),
        "de2000_max": float(de.max()),
    }


def image_difference(ours: np.ndarray, ref: np.ndarray) -> dict:
    """RMSE, max abs, mean relative error (eps 1e-2) and outlier pixels (``outlier_mask``),
    numpy only. Returns a dict of plain Python numbers."""
    a, r = np.asarray(ours, np.float64), np.asarray(ref, np.float64)
    err = np.abs(a - r)
    rel = err / np.maximum(np.abs(r), 1e-2)
    return {"rmse": float(np.sqrt(np.mean(err ** 2))), "max_abs": float(err.max()),
            "mean_rel": float(rel.max(axis=-1).mean()),
            "outliers": int(np.sum(outlier_mask(a, r)))}


# ---- maps for reports ---------------------------------------------------------------------
def _apply_colormap(values: np.ndarray, cmap: str) -> np.ndarray:
    """values float (H, W) in [0, 1] -> uint8 (H, W, 3) through a matplotlib colormap."""
    import matplotlib

    rgba = matplotlib.colormaps[cmap](np.clip(values, 0.0, 1.0))
    return np.round(rgba[..., :3] * 255).astype(np.uint8)


def colormap_stops(cmap: str, n: int = 11) -> list[str]:
    """``n`` evenly spaced colours of a matplotlib colormap as '#rrggbb' (for legends)."""
    rgb = _apply_colormap(np.linspace(0, 1, n)[None, :], cmap)[0]
    return ["#%02x%02x%02x" % tuple(int(c) for c in px) for px in rgb]


def abs_error_heatmap(ours: np.ndarray, ref: np.ndarray, *, scale: float | None = None,
                      cmap: str = "inferno") -> tuple[np.ndarray, float]:
    """Heatmap of the per-pixel absolute error (max over channels of |a - r|).

    The colormap spans [0, scale]: black = no error, the top colour = ``scale`` or more.
    scale: defaults to the image's max absolute error (1e-6 if the images are identical,
        so the map is then uniformly black).
    Returns (uint8 (H, W, 3), the scale used).
    """
    err = abs_error(ours, ref)
    if scale is None:
        scale = float(err.max())
    scale = max(float(scale), 1e-6)
    return _apply_colormap(err / scale, cmap), scale


def flip_heatmap(flip_map: np.ndarray, *, cmap: str = "magma") -> np.ndarray:
    """FLIP error map float (H, W) in [0, 1] -> uint8 (H, W, 3) (FLIP's own magma scale)."""
    return _apply_colormap(np.asarray(flip_map, np.float64), cmap)


# ---- statistical test ---------------------------------------------------------------------
def _normal_quantile_two_sided(alpha: float) -> float:
    """z with P(|Z| > z) = alpha for a standard normal Z (bisection on math.erfc)."""
    lo, hi = 0.0, 40.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if math.erfc(mid / math.sqrt(2.0)) > alpha:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def z_test(ours_mean: np.ndarray, ours_var: np.ndarray, ref_mean: np.ndarray,
           ref_var: np.ndarray, *, alpha: float = 0.01,
           min_var: float = 1e-12) -> tuple[float, np.ndarray]:
    """Per-value test that two Monte Carlo estimates have the same expectation.

    Welch's statistic ``t = (m_a - m_r) / sqrt(v_a + v_r)`` per pixel and channel, where
    ``v`` is the variance *of the mean* (sample variance / sample count). With the many
    samples per pixel of a converged render it is referred to the standard normal
    distribution (as Mitsuba's ``test_renders.py`` does). The significance level is
    Šidák-corrected for the number of values tested: ``1 - (1 - alpha)^(1/N)``, so under
    the null hypothesis *all* values pass with probability 1 - alpha.

    ours_mean, ours_var, ref_mean, ref_var: float arrays of one shape, e.g. (H, W, 3).
    min_var: floor of ``v_a + v_r`` (a noise-free pixel would otherwise fail on rounding).

    Returns (fraction of values that pass, bool mask of that shape, True = pass).
    """
    arrays = [np.asarray(x, np.float64) for x in (ours_mean, ours_var, ref_mean, ref_var)]
    shape = arrays[0].shape
    for name, x in zip(("ours_var", "ref_mean", "ref_var"), arrays[1:]):
        if x.shape != shape:
            raise ValueError(f"{name}: shape {x.shape} differs from ours_mean {shape}")
    if not 0 < alpha < 1:
        raise ValueError(f"alpha: expected a value in (0, 1), got {alpha}")
    m_a, v_a, m_r, v_r = arrays
    var = np.maximum(v_a + v_r, min_var)
    t = np.abs(m_a - m_r) / np.sqrt(var)
    alpha_sidak = 1.0 - (1.0 - alpha) ** (1.0 / max(m_a.size, 1))
    mask = np.nan_to_num(t, nan=np.inf) <= _normal_quantile_two_sided(alpha_sidak)
    return float(mask.mean()) if mask.size else 1.0, mask


def _betacf(a: float, b: float, x: float) -> float:
    """Continued fraction of the regularized incomplete beta function (modified Lentz)."""
    tiny = 1e-300
    c, d = 1.0, 1.0 - (a + b) * x / (a + 1.0)
    d = 1.0 / (d if abs(d) > tiny else tiny)
    h = d
    for m in range(1, 1000):
        m2 = 2 * m
        for aa in (m * (b - m) * x / ((a + m2 - 1) * (a + m2)),
                   -(a + m) * (a + b + m) * x / ((a + m2) * (a + m2 + 1))):
            d = 1.0 + aa * d
            d = 1.0 / (d if abs(d) > tiny else tiny)
            c = 1.0 + aa / c
            c = c if abs(c) > tiny else tiny
            h *= d * c
        if abs(d * c - 1.0) < 1e-15:
            break
    return h


def _student_t_two_sided(t: float, dof: float) -> float:
    """P(|T| > t) for Student's t with ``dof`` degrees of freedom: I_x(dof/2, 1/2) with
    x = dof / (dof + t^2)."""
    if t <= 0:
        return 1.0
    a, b, x = dof / 2.0, 0.5, dof / (dof + t * t)
    lbeta = math.lgamma(a) + math.lgamma(b) - math.lgamma(a + b)
    front = math.exp(a * math.log(x) + b * math.log1p(-x) - lbeta)
    if x < (a + 1.0) / (a + b + 2.0):
        return front * _betacf(a, b, x) / a
    return 1.0 - front * _betacf(b, a, 1.0 - x) / b


@functools.lru_cache(maxsize=4096)
def student_t_quantile(alpha: float, dof: float) -> float:
    """t with P(|T| > t) = alpha for Student's t with ``dof`` degrees of freedom
    (bisection; dof = inf gives the normal quantile)."""
    if math.isinf(dof):
        return _normal_quantile_two_sided(alpha)
    lo, hi = 0.0, 1.0
    while _student_t_two_sided(hi, dof) > alpha:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if _student_t_two_sided(mid, dof) > alpha:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def welch_test(ours_mean: np.ndarray, ours_var: np.ndarray, ours_n: int,
               ref_mean: np.ndarray, ref_var: np.ndarray, ref_n: int, *,
               alpha: float = 0.01, var_floor: np.ndarray | float = 0.0,
               equal_var: bool = False):
    """Per-value two-sample t-test that two Monte Carlo estimates have the same
    expectation, each the mean of ``n`` independent batches whose per-batch sample variance
    is ``var``.

    Welch (``equal_var=False``): ``t = (m_a - m_r) / sqrt(v_a / n_a + v_r / n_r + floor)``
    with the Welch-Satterthwaite degrees of freedom, rounded down (at least
    ``min(n_a, n_r) - 1``). Student (``equal_var=True``): the pooled variance
    ``((n_a-1) v_a + (n_r-1) v_r) / (n_a+n_r-2)`` for both, ``n_a + n_r - 2`` degrees of
    freedom: right when both sides sample the same distribution per batch under the null
    hypothesis (the same estimator at the same spp), and far less fooled by a side whose
    few batches happen to agree. ``var_floor`` is added to the variance of the difference.
    A variance estimated from 16 batches has heavy tails: the normal quantile of ``z_test``
    would fail a correct renderer far more often than ``alpha``. The level is
    Šidák-corrected for the number of values: under the null hypothesis every value passes
    with probability ``1 - alpha``.

    Returns (fraction of values that pass, bool mask, True = pass, the |t| array).
    """
    if ours_n < 2 or ref_n < 2:
        raise ValueError(f"batches: need >= 2 on each side for a variance, got "
                         f"{ours_n} and {ref_n}")
    if not 0 < alpha < 1:
        raise ValueError(f"alpha: expected a value in (0, 1), got {alpha}")
    m_a, v_a, m_r, v_r = (np.asarray(x, np.float64)
                          for x in (ours_mean, ours_var, ref_mean, ref_var))
    for name, x in (("ours_var", v_a), ("ref_mean", m_r), ("ref_var", v_r)):
        if x.shape != m_a.shape:
            raise ValueError(f"{name}: shape {x.shape} differs from ours_mean {m_a.shape}")
    if equal_var:
        pooled = ((ours_n - 1) * v_a + (ref_n - 1) * v_r) / (ours_n + ref_n - 2)
        sa, sr = pooled / ours_n, pooled / ref_n
    else:
        sa, sr = v_a / ours_n, v_r / ref_n
    var = np.maximum(sa + sr + var_floor, 1e-300)
    t = np.nan_to_num(np.abs(m_a - m_r) / np.sqrt(var), nan=np.inf)
    if equal_var:
        dof = np.full(m_a.shape, float(ours_n + ref_n - 2))
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            dof = (sa + sr) ** 2 / (sa ** 2 / (ours_n - 1) + sr ** 2 / (ref_n - 1))
        lo = min(ours_n, ref_n) - 1
        dof = np.floor(np.clip(np.nan_to_num(dof, nan=lo), lo, ours_n + ref_n - 2))
    alpha_sidak = 1.0 - (1.0 - alpha) ** (1.0 / max(m_a.size, 1))
    limits = {k: student_t_quantile(alpha_sidak, float(k)) for k in np.unique(dof)}
    limit = np.vectorize(limits.__getitem__, otypes=[np.float64])(dof) if dof.size else dof
    mask = t <= limit
    return (float(mask.mean()) if mask.size else 1.0), mask, t
