"""Statistical pre-processing and AR(p) noise models of a sensor series (seed 001, S2–S3).

    z, mean = timeseries.zero_mean(x)
    timeseries.reverse_arrangement(np.diff(z), subseries=20)["stationary"]
    model = timeseries.fit_ar(z, max_order=10)          # order by AIC, coefficients by RLS
    model.order, model.coefficients, model.sigma2, model.whiteness["p_value"]
    gaps = timeseries.find_breaks(t)                    # where the time column has gaps
    timeseries.fit_ar(z, breaks=gaps)                   # no lag reaches across a gap

Conventions follow statsmodels where users compare: AIC selection on the common sample N − max_order
(`ar_select_order(..., ic='aic', trend='n')`), sigma2 = SSR/(N − p) (`AutoReg`), Ljung–Box on the
demeaned series (`acorr_ljungbox(model_df=p)`), kurtosis not excess. Unlike statsmodels every
function streams: 10⁶ samples and more fit in memory. See cpp/include/fluxcal/timeseries.hpp.
"""
from __future__ import annotations

import operator
from dataclasses import dataclass, field

import numpy as np

from . import _core
from ._arrays import set_options


INT_MAX = 2 ** 31 - 1  # the core's int


def as_series(values, name: str = "series") -> np.ndarray:
    """`values` as a contiguous float64 1-D array; ValueError naming `name` otherwise."""
    try:  # a ragged list fails in iscomplexobj already
        is_complex = np.iscomplexobj(values)
        arr = None if is_complex else np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: not numeric ({exc})") from None
    if is_complex:  # float64 would drop the imaginary part with only a ComplexWarning
        raise ValueError(f"{name}: complex values; a series is real (pass .real or abs() explicitly)")
    if arr.ndim != 1:
        raise ValueError(f"{name}: shape {arr.shape}, expected a 1-D series")
    return np.ascontiguousarray(arr)


def as_whole(value, name: str, minimum: int) -> int:
    """`value` as an int in minimum … 2³¹ − 1 (the core's int), or ValueError naming `name`: int() truncated
    2.7 to 2 without a word, and 10¹² failed in the binding with a TypeError quoting the whole series."""
    try:
        whole = operator.index(value)  # int, numpy integers
    except TypeError:
        if not isinstance(value, (float, np.floating)):
            raise TypeError(f"{name}: expected a whole number, got {type(value).__name__}") from None
        if not float(value).is_integer():
            raise ValueError(f"{name}: {value} is not a whole number") from None
        whole = int(value)
    if whole < minimum:
        raise ValueError(f"{name}: {whole}, need ≥ {minimum}")
    if whole > INT_MAX:
        raise ValueError(f"{name}: {whole} is too large (at most {INT_MAX})")
    return whole


# A step in time this many times the nominal step or longer is a gap: at least one sample is missing (a
# recorder paused between temperature holds, a lost line). A logger's jitter of up to ±a fifth of the step (steps
# of 0.6 … 1.4) stays below it. The nominal step is the median over GAP_SPAN steps: a period that is not a whole
# number of clock ticks steps unevenly (1.5 s on a whole-second clock: 1, 2, 1, 2 s), evenly over several; a step
# may then be one tick longer than the threshold.
GAP_STEPS = 1.5
GAP_SPAN = 10


def find_breaks(t, name: str = "t") -> np.ndarray:
    """The gaps in a time column: the indices of the samples that follow a step of at least GAP_STEPS times
    the median step. An AR model's lags, a whitening filter and a Kalman filter must not reach across
    them (fit_ar, ArKalman.filter, fit_drift and fluxcal.drift.fit_pipeline take them as `breaks`): the
    jump between the stretches would be modelled as noise. ValueError naming `name` when t is not finite or
    does not increase."""
    t = as_series(t, name)
    bad = ~np.isfinite(t)
    if bad.any():
        i = int(np.argmax(bad))
        raise ValueError(f"{name}: sample {i} is {t[i]} (NaN/Inf not allowed)")
    step = np.diff(t)
    if (step <= 0).any():
        i = int(np.argmax(step <= 0)) + 1
        raise ValueError(f"{name}: sample {i} ({t[i]:g}) is not after sample {i - 1} ({t[i - 1]:g}); the gaps in "
                         "time need increasing times (sort the recording, or drop repeated rows)")
    if step.size == 0:
        return np.zeros(0, dtype=np.int64)
    span = min(GAP_SPAN, step.size)
    nominal = float(np.median((t[span:] - t[:-span]) / span))
    # the clock's tick: the spacing of the step values a whole-tick clock gives about the nominal step (1 s for
    # 1, 1, 1, 1, 2 s); a step may be one tick longer than the threshold before it is a gap
    usual = np.unique(step[step < 2 * nominal])
    tick = float(np.min(np.diff(usual))) if usual.size > 1 else 0.0
    return np.flatnonzero(step >= GAP_STEPS * nominal + tick).astype(np.int64) + 1


def as_breaks(breaks, n: int, name: str = "breaks") -> list:
    """`breaks` (None, or sample indices) as the core's list; ValueError naming `name` when they are not
    ascending indices in 1 … n − 1."""
    if breaks is None:
        return []
    b = np.asarray(breaks)
    if b.ndim != 1 or (b.size and not np.issubdtype(b.dtype, np.integer)):
        raise ValueError(f"{name}: expected a 1-D list of sample indices (fluxcal.timeseries.find_breaks)")
    if b.size and (b[0] < 1 or b[-1] > n - 1 or (np.diff(b) <= 0).any()):
        raise ValueError(f"{name}: {b.tolist()[:5]}{' …' if b.size > 5 else ''} are not ascending sample indices "
                         f"in 1 … {n - 1}")
    return b.astype(np.int64).tolist()


def zero_mean(x):
    """(x − mean(x), mean)."""
    z, mean = _core.ts_zero_mean(as_series(x))
    return np.asarray(z), float(mean)


def difference(x, order: int = 1) -> np.ndarray:
    return np.asarray(_core.ts_difference(as_series(x), as_whole(order, "order", 0)))


def remove_trend(x, degree: int = 1) -> np.ndarray:
    """x minus its least-squares polynomial of `degree` in the sample index."""
    return np.asarray(_core.ts_remove_trend(as_series(x), as_whole(degree, "degree", 0)))


def reverse_arrangement(x, subseries: int = 20, threshold: float = 1.96) -> dict:
    """Reverse-arrangement stationarity test on the means of `subseries` consecutive sub-series.
    Returns arrangements A, expected, variance, u, stationary (|u| < threshold), means."""
    x = as_series(x)
    r = _core.ts_reverse_arrangement(x, as_whole(subseries, "subseries", 3), float(threshold))
    # Equal sub-series means give A = 0 and "not stationary": a constant series has no trend to test.
    if not (x != x[0]).any():
        raise ValueError(f"series: constant (every sample equals {x[0]:g}), the stationarity test needs variation")
    return r


def normality(x, significance: float = 0.05) -> dict:
    """Skewness, kurtosis (3 for a normal law), Jarque–Bera and its χ²(2) p-value, normal flag."""
    return _core.ts_normality(as_series(x), float(significance))


def ljung_box(x, lags: int, model_df: int = 0, significance: float = 0.05, breaks=None) -> dict:
    """Ljung–Box Q over `lags` lags against χ²(lags − model_df); keys statistic, p_value, white, lags.
    breaks: gaps in time (`find_breaks`); a lag pairs samples of one stretch only, and a lag no stretch is
    long enough for is left out of `lags`."""
    lags, model_df = as_whole(lags, "lags", 1), as_whole(model_df, "model_df", 0)
    if model_df >= lags:  # χ²(lags − model_df) has no degrees of freedom: p-value NaN, "not white"
        raise ValueError(f"model_df: {model_df} is not below lags = {lags} (the test needs lags > model_df)")
    x = as_series(x)
    r = _core.ts_ljung_box(x, lags, model_df, float(significance), as_breaks(breaks, x.size))
    if r["lags"] <= model_df:  # the stretches between the breaks are shorter than the lags asked for
        raise ValueError(f"breaks: the stretches between them allow only {r['lags']} of the {lags} lags, the test "
                         f"needs more than model_df = {model_df}")
    return r


@dataclass
class ArModel:
    order: int
    coefficients: np.ndarray
    sigma2: float
    aic: np.ndarray                 # AIC(p) for p = 0 … max_order (empty for a fixed order)
    order_at_maximum: bool
    residuals: np.ndarray
    whiteness: dict                 # Ljung–Box of the residuals, model_df = order
    summary: dict = field(default_factory=dict)
    # of the coefficients: σ̂²(XᵀX)⁻¹ (statsmodels AutoReg's cov_params); with forgetting < 1 the weighted fit's
    # sandwich, the spread over its memory of about 1/(1 − λ) rows
    covariance: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    standard_errors: np.ndarray = field(default_factory=lambda: np.zeros(0))


def fit_ar(y, max_order: int = 10, order: int | None = None, **settings) -> ArModel:
    """AR(p) model y_k = Σ a_i y_{k−i} + r_k (no constant: pass a zero-mean series).

    order None: chosen by AIC among 0 … max_order (`order_at_maximum` and a warning when the maximum
    wins). settings: init_samples (20: rows of the batch least-squares start of the RLS), forgetting
    (1.0: RLS forgetting factor), whiteness_lags (0 = max(10, 2p)), significance (0.05), breaks (gaps in
    time, `find_breaks`: no row's lags reach across one; each stretch's first p rows are not regressed
    and have no residual)."""
    options = _core.ArOptions()
    options.max_order = as_whole(max_order, "max_order", 0)
    options.order = -1 if order is None else as_whole(order, "order", 0)
    for name in ("init_samples", "whiteness_lags"):
        if name in settings:
            settings[name] = as_whole(settings[name], name, 0)
    y = as_series(y)
    options.breaks = as_breaks(settings.pop("breaks", None), y.size)
    set_options(options, settings, "fit_ar")
    r = _core.fit_ar(y, options)
    return ArModel(order=r["order"], coefficients=np.asarray(r["coefficients"]), sigma2=r["sigma2"],
                   aic=np.asarray(r["aic"]), order_at_maximum=r["order_at_maximum"],
                   residuals=np.asarray(r["residuals"]), whiteness=r["whiteness"], summary=r["summary"],
                   covariance=np.asarray(r["covariance"]).reshape(r["order"], r["order"]),
                   standard_errors=np.asarray(r["standard_errors"]))


def preprocess(x, subseries: int = 20, threshold: float = 1.96, trend_degree: int = 1,
               significance: float = 0.05, breaks=None) -> dict:
    """Seed 001 S2: zero-mean, reverse-arrangement test of the once-differenced series; if it is not
    stationary, difference once more and remove a polynomial trend of `trend_degree`. Returns `mean`,
    `series` (the stationary series), `differences` (1 or 2), `stationarity` (the test of the first
    difference), `stationarity_after` (the test of `series`), `normality` (of `series`) and `summary`
    (warnings when `series` is still not stationary or not normal). breaks: gaps in time (`find_breaks`);
    the differences are taken within each stretch between them."""
    x = as_series(x)
    r = _core.ts_preprocess(x, as_whole(subseries, "subseries", 3), float(threshold),
                            as_whole(trend_degree, "trend_degree", 0), float(significance), as_breaks(breaks, x.size))
    r["series"] = np.asarray(r["series"])
    return r
