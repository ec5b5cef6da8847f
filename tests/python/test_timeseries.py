"""fluxcal.timeseries against statsmodels (N = 10⁴, where statsmodels still fits in memory), the NumPy
oracle, and seeded AR simulations."""
import numpy as np
import pytest
from scipy.signal import lfilter

from fluxcal import timeseries as ts
from fluxcal.oracle import timeseries as oracle


def ar_series(coefficients, n, seed, sigma=1.0):
    rng = np.random.default_rng(seed)
    e = sigma * rng.standard_normal(n + 1000)
    return lfilter([1.0], np.concatenate(([1.0], -np.asarray(coefficients))), e)[1000:]


CASES = [((0.6, -0.3, 0.2), 11), ((0.9,), 12), ((0.4, 0.2, -0.25, 0.1, 0.15), 13)]


@pytest.mark.parametrize("coefficients,seed", CASES)
def test_ar_matches_statsmodels(coefficients, seed):
    from statsmodels.stats.diagnostic import acorr_ljungbox
    from statsmodels.tsa.ar_model import AutoReg, ar_select_order

    y = ar_series(coefficients, 10_000, seed)
    model = ts.fit_ar(y, max_order=8)
    selected = ar_select_order(y, 8, ic="aic", trend="n")
    assert model.order == len(selected.ar_lags or [])
    assert model.order == len(coefficients)
    ref = AutoReg(y, lags=model.order, trend="n").fit()
    np.testing.assert_allclose(model.coefficients, ref.params, rtol=0, atol=1e-6)
    assert model.sigma2 == pytest.approx(ref.sigma2, rel=1e-9)
    np.testing.assert_allclose(model.residuals, ref.resid, rtol=0, atol=1e-6)
    lags = model.whiteness["lags"]
    lb = acorr_ljungbox(model.residuals, lags=[lags], model_df=model.order)
    assert model.whiteness["statistic"] == pytest.approx(float(lb["lb_stat"].iloc[0]), rel=0, abs=1e-8)
    assert model.whiteness["p_value"] == pytest.approx(float(lb["lb_pvalue"].iloc[0]), rel=1e-8, abs=1e-12)
    assert model.whiteness["white"]  # the right order leaves white residuals


def test_aic_curve_matches_oracle():
    y = ar_series((0.5, -0.4), 5000, 3)
    model = ts.fit_ar(y, max_order=6)
    np.testing.assert_allclose(model.aic, oracle.ar_aic(y, 6), rtol=1e-10)


@pytest.mark.parametrize("forgetting", [1.0, 0.999])
def test_rls_matches_oracle(forgetting):
    y = ar_series((0.7, -0.2), 4000, 5)
    model = ts.fit_ar(y, order=2, forgetting=forgetting, init_samples=20)
    np.testing.assert_allclose(model.coefficients, oracle.rls(y, 2, 20, forgetting), rtol=0, atol=1e-9)
    if forgetting == 1.0:  # without forgetting RLS is the batch least-squares solution
        np.testing.assert_allclose(model.coefficients, oracle.ar_fit(y, 2)[0], rtol=0, atol=1e-10)


def stretches_with_gaps(seed):
    """AR(1) noise near a unit root logged in 12 stretches of 40–300 samples, the noise running on unseen for
    200 samples between them (a recorder paused between holds): the breaks and the spliced series."""
    rng = np.random.default_rng(seed)
    y = ar_series((0.95,), 12 * 500, seed)
    lengths = rng.integers(40, 300, 12)
    starts = np.arange(12) * 500
    pieces = [y[s:s + n] for s, n in zip(starts, lengths)]
    return np.concatenate(pieces), np.cumsum(lengths)[:-1]


@pytest.mark.parametrize("seed", [0, 1])
def test_gaps_in_time_match_the_oracle(seed):
    """With breaks no lag reaches across a gap: the AIC curve, the RLS coefficients and the residual count are
    the oracle's, which fits the stacked rows of each stretch (np.split at the breaks)."""
    y, breaks = stretches_with_gaps(seed)
    model = ts.fit_ar(y, max_order=6, breaks=breaks)
    np.testing.assert_allclose(model.aic, oracle.ar_aic(y, 6, breaks), rtol=1e-10)
    p = model.order
    np.testing.assert_allclose(model.coefficients, oracle.ar_fit(y, p, breaks)[0], rtol=0, atol=1e-10)
    assert model.residuals.size == y.size - p * (len(breaks) + 1)
    fixed = ts.fit_ar(y, order=1, breaks=breaks, forgetting=0.999)
    np.testing.assert_allclose(fixed.coefficients, oracle.rls(y, 1, 20, 0.999, breaks), rtol=0, atol=1e-9)
    # Not a trivial agreement: spliced, the 11 jumps between stretches pull a1 from the truth (0.95).
    spliced = ts.fit_ar(y, order=1)
    assert abs(ts.fit_ar(y, order=1, breaks=breaks).coefficients[0] - 0.95) < abs(spliced.coefficients[0] - 0.95)


def test_preprocess_differences_within_the_stretches():
    """S2 with breaks: the differences of each stretch, as the oracle's np.diff of each np.split piece; the
    jumps between stretches at different levels no longer make the differenced series heavy-tailed."""
    rng = np.random.default_rng(3)
    levels = np.repeat(rng.normal(0.0, 5.0, 8), 300)  # eight holds at their own levels, white noise about them
    x = levels + rng.normal(0.0, 0.1, levels.size)
    breaks = np.arange(300, levels.size, 300)
    got, ref = ts.preprocess(x, breaks=breaks), oracle.preprocess(x, breaks=breaks)
    np.testing.assert_allclose(got["series"], ref["series"], rtol=0, atol=1e-12)
    assert got["normality"]["kurtosis"] == pytest.approx(ref["normality"]["kurtosis"], rel=1e-10)
    assert got["series"].size == x.size - (2 if got["differences"] == 2 else 1) * 8
    assert got["normality"]["normal"] and not ts.preprocess(x)["normality"]["normal"]
    with pytest.raises(ValueError, match="stretches between gaps in time leave fewer than 40"):
        ts.preprocess(x[:60], breaks=np.arange(3, 60, 3))


def test_find_breaks():
    t = np.arange(100.0) + np.random.default_rng(0).uniform(-0.2, 0.2, 100)  # a logger's jitter: no gap
    assert ts.find_breaks(t).size == 0
    t = np.r_[np.arange(10.0), np.arange(12.0, 20.0), np.arange(620.0, 700.0)]  # one lost sample, one pause
    np.testing.assert_array_equal(ts.find_breaks(t), [10, 18])
    with pytest.raises(ValueError, match=r"t: sample 3 \(2\) is not after sample 2 \(2\)"):
        ts.find_breaks([0.0, 1.0, 2.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="t: sample 1 is nan"):
        ts.find_breaks([0.0, np.nan, 2.0])
    y, breaks = stretches_with_gaps(0)
    with pytest.raises(ValueError, match="breaks: .* are not ascending sample indices"):
        ts.fit_ar(y, breaks=[5, 3])
    with pytest.raises(ValueError, match="stretches are too short"):  # every stretch shorter than the lags
        ts.fit_ar(y[:400], max_order=10, breaks=np.arange(8, 400, 8))


@pytest.mark.parametrize("forgetting", [0.97, 0.9, 0.8])
def test_rls_forgetting_is_weighted_least_squares(forgetting):
    # RLS with λ < 1 is exponentially weighted least squares; it used to diverge (λ = 0.8: [22.8, −40.5]
    # for [0.96, −0.59]) because the covariance downdate was not exactly symmetric and dividing by λ
    # every step grew its antisymmetric part.
    y = ar_series((0.5, -0.2), 2000, 1)
    y = y - y.mean()
    model = ts.fit_ar(y, order=2, forgetting=forgetting)
    exact = oracle.weighted_ls(y, 2, 20, forgetting)
    np.testing.assert_allclose(model.coefficients, exact, rtol=0, atol=1e-9)
    np.testing.assert_allclose(model.coefficients, oracle.rls(y, 2, 20, forgetting), rtol=0, atol=1e-9)


def test_million_samples():
    truth = np.array([0.6, -0.3, 0.2])
    y = ar_series(truth, 1_000_000, 21)
    model = ts.fit_ar(y, max_order=6)
    assert model.order == 3
    # Standard error of each coefficient ≈ 1/√N = 1e-3.
    np.testing.assert_allclose(model.coefficients, truth, atol=5e-3)
    assert model.sigma2 == pytest.approx(1.0, rel=5e-3)
    assert model.whiteness["white"]


def test_long_memory_hits_the_maximum_order():
    y = ar_series((0.3, 0.2, 0.1, 0.1, 0.1, 0.1, 0.05), 20_000, 4)  # order 7, only 3 allowed
    model = ts.fit_ar(y, max_order=3)
    assert model.order == 3 and model.order_at_maximum
    assert any("maximum order" in w for w in model.summary["warnings"])


def test_reverse_arrangement_matches_oracle_and_detects_a_trend():
    rng = np.random.default_rng(8)
    x = rng.standard_normal(2003)
    got, ref = ts.reverse_arrangement(x, 20), oracle.reverse_arrangement(x, 20)
    assert got["arrangements"] == ref["arrangements"]
    assert got["u"] == pytest.approx(ref["u"], rel=1e-12)
    np.testing.assert_allclose(got["means"], ref["means"], rtol=1e-12)
    assert got["expected"] == 20 * 19 / 4 and got["variance"] == pytest.approx(20 * 45 * 19 / 72)
    trend = x + np.linspace(0, 5, x.size)
    r = ts.reverse_arrangement(trend, 20)
    assert not r["stationary"] and r["u"] < -1.96  # rising means: few reverse arrangements


def test_normality_matches_scipy_and_statsmodels():
    from statsmodels.stats.stattools import jarque_bera

    rng = np.random.default_rng(9)
    for x, normal in ((rng.standard_normal(5000), True), (rng.exponential(size=5000), False)):
        got, ref = ts.normality(x), oracle.normality(x)
        for key in ("skewness", "kurtosis", "jarque_bera", "p_value"):
            assert got[key] == pytest.approx(ref[key], rel=1e-9, abs=1e-300)
        jb, p, skew, kurt = jarque_bera(x)
        assert got["jarque_bera"] == pytest.approx(jb, rel=1e-9) and got["kurtosis"] == pytest.approx(kurt, rel=1e-9)
        assert got["normal"] == normal


def test_ljung_box_matches_oracle():
    x = ar_series((0.3,), 3000, 10)
    for df in (0, 2):
        got, ref = ts.ljung_box(x, 15, df), oracle.ljung_box(x, 15, df)
        assert got["statistic"] == pytest.approx(ref["statistic"], rel=1e-12)
        assert got["p_value"] == pytest.approx(ref["p_value"], rel=1e-9, abs=1e-300)
    assert not ts.ljung_box(x, 15)["white"]  # AR(1) with a = 0.3 is not white


def test_ljung_box_pairs_samples_of_one_stretch_only():
    """White noise in 10-sample stretches whose first sample repeats the previous stretch's last (a recorder
    that logs the hold it resumes): joined, lag 1 sees the repeats; within the stretches it is white."""
    rng = np.random.default_rng(12)
    x = rng.standard_normal(3000)
    breaks = np.arange(10, 3000, 10)
    x[breaks] = x[breaks - 1]
    assert not ts.ljung_box(x, 10)["white"]
    got, ref = ts.ljung_box(x, 12, 1, breaks=breaks), oracle.ljung_box(x, 12, 1, breaks=breaks)
    # lags 10 … 12 span a whole stretch: no pair, left out
    assert got["statistic"] == pytest.approx(ref["statistic"], rel=1e-12) and got["lags"] == ref["lags"] == 9
    assert got["p_value"] == pytest.approx(ref["p_value"], rel=1e-9) and got["white"]
    short = [3, 6]  # stretches of 3, 3 and 4 samples: lags 4 … 6 have no pair and are left out
    got, ref = ts.ljung_box(x[:10], 6, breaks=short), oracle.ljung_box(x[:10], 6, breaks=short)
    assert got["lags"] == ref["lags"] == 3 and got["statistic"] == pytest.approx(ref["statistic"], rel=1e-12)
    with pytest.raises(ValueError, match="breaks"):
        ts.ljung_box(x, 10, breaks=[5, 3])
    with pytest.raises(ValueError, match="breaks: the stretches between them allow only 3 of the 6 lags"):
        ts.ljung_box(x[:10], 6, model_df=3, breaks=short)
    # fit_ar's whiteness test on its residuals: white within the stretches, not when joined across the gaps
    assert ts.fit_ar(x, order=0, breaks=breaks).whiteness["white"]
    assert not ts.fit_ar(x, order=0).whiteness["white"]


def test_difference_and_trend():
    rng = np.random.default_rng(11)
    x = rng.standard_normal(500).cumsum()
    np.testing.assert_allclose(ts.difference(x, 2), np.diff(x, 2), atol=1e-12)
    t = np.arange(500.0)
    line = 3.0 + 0.01 * t
    np.testing.assert_allclose(ts.remove_trend(line + np.sin(t), 1),
                               np.sin(t) - np.polyval(np.polyfit(t, np.sin(t), 1), t), atol=1e-9)
    pre = ts.preprocess(x)  # a random walk: the first difference is stationary
    assert pre["differences"] == 1 and pre["stationarity"]["stationary"]
    assert pre["mean"] == pytest.approx(x.mean())


@pytest.mark.parametrize("kind", ["random_walk", "quadratic_trend"])
def test_preprocess_matches_oracle(kind):
    """S2: a random walk needs one difference; a quadratic trend on AR noise leaves a linear trend in the
    first difference (not stationary), so a second difference and a trend removal follow."""
    rng = np.random.default_rng(12)
    n = 4000
    if kind == "random_walk":
        x = 5.0 + rng.standard_normal(n).cumsum()
    else:
        t = np.arange(n) / n
        x = 300.0 * t ** 2 + ar_series((0.5,), n, 13, sigma=0.01).cumsum()
    got, ref = ts.preprocess(x), oracle.preprocess(x)
    assert got["differences"] == ref["differences"] == (1 if kind == "random_walk" else 2)
    assert got["mean"] == pytest.approx(ref["mean"], rel=1e-12)
    np.testing.assert_allclose(got["series"], ref["series"], rtol=0, atol=1e-9)
    for key in ("stationarity", "stationarity_after"):
        assert got[key]["arrangements"] == ref[key]["arrangements"]
        assert got[key]["u"] == pytest.approx(ref[key]["u"], rel=1e-12)
    assert got["stationarity_after"]["stationary"]
    assert got["normality"]["kurtosis"] == pytest.approx(ref["normality"]["kurtosis"], rel=1e-9)
    assert got["summary"]["warnings"] == []
    if kind == "quadratic_trend":
        assert not got["stationarity"]["stationary"]


def test_preprocess_reports_what_it_cannot_fix():
    rng = np.random.default_rng(14)
    # Exponential growth keeps a curved second difference, which removing a line cannot flatten
    # (u ≈ 2.7 after; the NumPy oracle gives the same).
    t = np.linspace(0.0, 1.0, 4000)
    x = np.exp(12.0 * t) + 0.01 * rng.standard_normal(t.size)
    pre = ts.preprocess(x)
    assert pre["differences"] == 2 and not pre["stationarity_after"]["stationary"]
    assert any("not stationary" in w for w in pre["summary"]["warnings"])
    with pytest.raises(ValueError, match="constant"):
        ts.preprocess(np.full(100, 1.5))
    with pytest.raises(ValueError, match="polynomial trend"):
        ts.preprocess(np.arange(100.0) * 0.5)
    with pytest.raises(ValueError, match="need at least 42"):
        ts.preprocess(rng.standard_normal(41))


def test_bad_input():
    with pytest.raises(ValueError, match="need at least"):
        ts.fit_ar(np.arange(10.0), max_order=8)
    with pytest.raises(ValueError, match="constant"):
        ts.fit_ar(np.full(1000, 2.5), max_order=4)
    y = ar_series((0.5,), 1000, 1)
    y[17] = np.nan
    with pytest.raises(ValueError, match="sample 17"):
        ts.fit_ar(y)
    with pytest.raises(ValueError, match="constant"):
        ts.normality(np.ones(100))
    with pytest.raises(ValueError, match="sub-series"):
        ts.reverse_arrangement(np.arange(10.0), 20)
    with pytest.raises(ValueError, match="1-D"):
        ts.fit_ar(np.zeros((10, 2)))


def test_real_sensor_noise_hits_the_maximum_order(real_data):
    """The static first 60 s (3000 samples at 50 Hz) of a real QMC5883L recording: its noise has long
    memory (the recording is pre-filtered by its author), so AIC takes the maximum order 10 on every
    axis — reported — and the residuals are not white; with room up to 20 it settles below the maximum.
    fluxcal must agree with the oracle and statsmodels on this real series too."""
    from statsmodels.tsa.ar_model import AutoReg

    data = np.loadtxt(real_data / "qmc5883l_filtered.csv", delimiter=",", skiprows=3)
    for axis in range(3):
        z, _ = ts.zero_mean(data[:3000, axis])
        capped = ts.fit_ar(z, max_order=10)
        assert capped.order == 10 and capped.order_at_maximum
        assert any("maximum order" in w for w in capped.summary["warnings"])
        assert not capped.whiteness["white"]
        roomy = ts.fit_ar(z, max_order=20)
        assert 10 < roomy.order < 20 and not roomy.order_at_maximum
        # The AIC curve against the NumPy oracle (statsmodels' ar_select_order agrees — checked by hand,
        # orders 17/16/19 — but takes ≈ 10 s per axis here, its N×N temporary).
        np.testing.assert_allclose(roomy.aic, oracle.ar_aic(z, 20), rtol=1e-9)
        ref = AutoReg(z, lags=roomy.order, trend="n").fit()
        np.testing.assert_allclose(roomy.coefficients, ref.params, rtol=0, atol=1e-6)


def test_untestable_whiteness_is_not_a_rejection():
    # 23 samples, AR(10): the (N − p)/2 cap leaves 6 Ljung–Box lags ≤ p, so the p-value is NaN. The
    # warning used to read "residuals are not white (Ljung-Box p = nan): the AR model is rejected".
    y = ar_series((0.5, -0.3, 0.2, -0.1), 23, 2)
    model = ts.fit_ar(y - y.mean(), order=10)
    assert model.whiteness["lags"] == 6 and np.isnan(model.whiteness["p_value"])
    warnings = model.summary["warnings"]
    assert any("whiteness could not be tested" in w and "only 6 Ljung-Box lags" in w and "order 10" in w
               for w in warnings), warnings
    assert not any("rejected" in w or "nan" in w for w in warnings), warnings
    assert "whiteness not tested" in model.summary["message"]
    # An explicit whiteness_lags ≤ p says so.
    y = ar_series((0.5,), 500, 3)
    model = ts.fit_ar(y, order=3, whiteness_lags=3)
    assert any("whiteness_lags = 3" in w for w in model.summary["warnings"]), model.summary["warnings"]
    # A testable fit still reports its p-value.
    model = ts.fit_ar(y, order=1)
    assert np.isfinite(model.whiteness["p_value"]) and "Ljung-Box p" in model.summary["message"]


def test_bad_input_is_named():
    y = ar_series((0.5,), 500, 4)
    # model_df ≥ lags left no degrees of freedom: p-value NaN and "not white".
    with pytest.raises(ValueError, match=r"model_df: 10 is not below lags = 5"):
        ts.ljung_box(y, 5, 10)
    # A constant series was "not stationary" (equal sub-series means, A = 0).
    for value in (2.0, 0.0):
        with pytest.raises(ValueError, match="series: constant"):
            ts.reverse_arrangement(np.full(500, value))
    # Integer arguments: 10¹² failed in the binding quoting the array, 2.7 was truncated to 2.
    with pytest.raises(ValueError, match=r"order: 1000000000000 is too large"):
        ts.difference(y, 10 ** 12)
    with pytest.raises(ValueError, match=r"max_order: 2\.7 is not a whole number"):
        ts.fit_ar(y, max_order=2.7)
    with pytest.raises(ValueError, match=r"whiteness_lags: 2\.5 is not a whole number"):
        ts.fit_ar(y, whiteness_lags=2.5)
    with pytest.raises(ValueError, match="subseries: 2, need ≥ 3"):
        ts.reverse_arrangement(y, 2.0)
    with pytest.raises(TypeError, match="order: expected a whole number"):
        ts.fit_ar(y, order="3")
    assert ts.fit_ar(y, max_order=4.0).order == ts.fit_ar(y, max_order=4).order  # whole floats still fine
    # Complex input was cast to float with a ComplexWarning, dropping the imaginary part.
    for call in (ts.zero_mean, ts.fit_ar, ts.normality, ts.preprocess, lambda x: ts.difference(x, 1)):
        with pytest.raises(ValueError, match="series: complex values"):
            call(y + 1j)


def test_find_breaks_on_a_coarse_clock():
    """A period that is not a whole number of clock ticks steps unevenly (1.5 s on a whole-second clock: 1, 2,
    1, 2 s; millis() at 1.5 ms): no gap, while a lost sample still is one."""
    assert ts.find_breaks(np.floor(np.arange(2000) * 1.5)).size == 0
    assert ts.find_breaks(np.floor(np.arange(2000) * 1.2)).size == 0
    assert ts.find_breaks(np.floor(np.arange(2000) * 1.5) / 1000).size == 0
    t = np.delete(np.floor(np.arange(2000) * 1.5), [500, 501])
    np.testing.assert_array_equal(ts.find_breaks(t), [500])
