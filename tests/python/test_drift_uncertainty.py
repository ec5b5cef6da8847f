"""Standard errors of the FOCT models: the AR noise model's coefficients and the drift polynomials' (and so of
the drift at each temperature), against statsmodels and the NumPy oracle, and against the Monte-Carlo spread."""
import json

import numpy as np
import pytest
from scipy.signal import lfilter
from statsmodels.tsa.ar_model import AutoReg

from conftest import run_cli
from fluxcal import drift, sim, write_csv
from fluxcal import timeseries as ts
from fluxcal.oracle import drift as oracle
from fluxcal.oracle import timeseries as oracle_ts


@pytest.fixture(scope="module")
def foct():
    return sim.foct_zero_bias(rng=np.random.default_rng(2016))


def test_ar_standard_errors_are_autoregs():
    y = lfilter([1], [1, -0.6, 0.2], np.random.default_rng(1).normal(size=3000))
    model = ts.fit_ar(y, order=2)
    ref = AutoReg(y, 2, trend="n").fit()
    np.testing.assert_allclose(model.coefficients, ref.params, rtol=1e-9)
    np.testing.assert_allclose(model.covariance, ref.cov_params(), rtol=1e-8)
    np.testing.assert_allclose(model.standard_errors, ref.bse, rtol=1e-8)


def test_ar_standard_errors_with_forgetting_are_the_weighted_fits_sandwich():
    y = lfilter([1], [1, -0.5], np.random.default_rng(2).normal(size=2000))
    model = ts.fit_ar(y, order=1, forgetting=0.99)
    expected = oracle_ts.weighted_ls_covariance(y, 1, model.sigma2, forgetting=0.99)
    np.testing.assert_allclose(model.covariance, expected, rtol=1e-6)
    # a memory of 100 rows: the spread of an estimate from about 1/(1 − λ) rows, ~√(2000 (1 − λ)/(1 + λ)) wider
    assert 2.5 < model.standard_errors[0] / ts.fit_ar(y, order=1).standard_errors[0] < 3.8


@pytest.mark.parametrize("forgetting", [1.0, 0.99])
def test_ar_standard_errors_match_the_monte_carlo_spread(forgetting):
    rng = np.random.default_rng(3)
    fits = [ts.fit_ar(lfilter([1], [1, -0.6, 0.2], rng.normal(size=4000)), order=2, forgetting=forgetting)
            for _ in range(300)]
    spread = np.std([f.coefficients for f in fits], axis=0, ddof=1)
    said = np.mean([f.standard_errors for f in fits], axis=0)
    # measured 0.99–1.01 (λ = 1) and 1.005–1.01 (λ = 0.99) over 400 fits
    np.testing.assert_allclose(said / spread, 1.0, atol=0.12)


@pytest.mark.parametrize("whiten", [True, False])
def test_drift_covariance_matches_the_oracles(whiten, foct):
    c = foct.columns
    w, t = c["zero_bias"][::3], c["temp"][::3]
    got = drift.fit_drift(w, t, whiten=whiten, significance=0.01)
    ref, _ = oracle.fit_drift(t, t, w, significance=0.01, whiten=whiten)
    for g, r in zip(got.segments, ref):
        scale = np.sqrt(np.outer(np.diag(r["covariance"]), np.diag(r["covariance"])))
        assert np.max(np.abs(np.asarray(g["covariance"]) - r["covariance"]) / scale) < 1e-8  # measured 1e-11
        np.testing.assert_allclose(g["standard_errors"], np.sqrt(np.diag(r["covariance"])), rtol=1e-8)
    # the drift's standard error at a temperature: the quadratic form in (1, T, T², …)
    seg = got.segments[1]
    v = 12.5 ** np.arange(seg["order"] + 1)
    assert got.standard_error([12.5])[0] == pytest.approx(np.sqrt(v @ np.asarray(seg["covariance"]) @ v), rel=1e-12)


def _ramps(phi: float, continuous: bool, whiten: bool = True, runs: int = 200, n: int = 3000):
    """Fits of a quadratic drift under AR(1) noise on a temperature crossing each range three times."""
    rng = np.random.default_rng(11)
    temp = 15 + 35 * np.sin(2 * np.pi * 1.5 * np.linspace(0, 1, n))
    truth = 0.02 + 1e-3 * temp + 2e-5 * temp ** 2
    probe = np.array([-10.0, 10.0, 40.0])
    coefficients, errors, at, at_errors = [], [], [], []
    for _ in range(runs):
        model = drift.fit_drift(truth + lfilter([1], [1, -phi], rng.normal(0, 0.01, n)), temp, order=2,
                                continuous=continuous, whiten=whiten)
        coefficients.append(np.concatenate([s["coefficients"] for s in model.segments]))
        errors.append(np.concatenate([s["standard_errors"] for s in model.segments]))
        at.append(model.evaluate(probe))
        at_errors.append(model.standard_error(probe))
    spread = lambda a: np.std(a, axis=0, ddof=1)
    return np.mean(errors, axis=0) / spread(coefficients), np.mean(at_errors, axis=0) / spread(at)


@pytest.mark.parametrize("phi, whiten", [(0.0, True), (0.8, True), (0.8, False)])
@pytest.mark.parametrize("continuous", [False, True])
def test_drift_standard_errors_match_the_monte_carlo_spread(phi, whiten, continuous):
    """Whitened by the AR model (generalised least squares), the continuous refit's least squares under that model,
    or with no noise model (whiten=False) the Newey–West sandwich: measured 0.92–1.12 of the spread for the
    coefficients and 0.94–1.09 for f(T) over 300 fits. (With σ̂²(VᵀV)⁻¹ at whiten=False they had been 0.33 on AR(1)
    0.8 noise, too small by √((1 + φ)/(1 − φ)): a review.)"""
    coefficients, at = _ramps(phi, continuous, whiten)
    np.testing.assert_allclose(coefficients, 1.0, atol=0.15)
    np.testing.assert_allclose(at, 1.0, atol=0.15)


def test_covariance_is_saved_and_a_model_without_it_says_so(tmp_path, foct):
    c = foct.columns
    model = drift.fit_drift(c["zero_bias"][::3], c["temp"][::3])
    loaded = drift.DriftModel.load(model.save(tmp_path / "m.json"))
    probe = [-15.0, 5.0, 45.0]
    np.testing.assert_array_equal(loaded.standard_error(probe), model.standard_error(probe))
    # outside the ranges as evaluate: an error naming the option, or NaN with it
    with pytest.raises(ValueError, match="outside"):
        model.standard_error([80.0])
    assert np.isnan(model.standard_error([80.0, 5.0], outside="nan")[0])
    data = json.loads((tmp_path / "m.json").read_text())
    for seg in data["segments"]:
        del seg["covariance"]
    old = drift.DriftModel.from_dict(data)
    np.testing.assert_array_equal(old.evaluate(probe), model.evaluate(probe))  # still compensates
    with pytest.raises(ValueError, match=r"segment\(s\) \[0, 1, 2\] have no covariance.*fit it again"):
        old.standard_error(probe)
    data["segments"][0]["covariance"] = [[1.0, 0.0], [0.0, float("nan")]]
    with pytest.raises(ValueError, match=r"segment 0 .* covariance that is not a finite 3×3 matrix"):
        drift.DriftModel.from_dict(data)


def test_pipeline_and_cli_report_the_drifts_standard_error(tmp_path, foct):
    c = foct.columns
    model, report = drift.fit_pipeline(c["zero_bias"], c["temp"], c["temp_outside"], rated=1000.0)
    se = report["drift_standard_error"]
    assert se["max"] == pytest.approx(model.standard_error(c["temp"]).max())
    assert len(se["per_range"]) == len(model.segments) and max(se["per_range"]) == se["max"]
    assert len(report["ar"]["standard_errors"]) == report["ar"]["order"]
    src = write_csv(tmp_path / "foct.csv", {k: c[k] for k in ("t", "zero_bias", "temp", "temp_outside")},
                    units=foct.units)
    run = run_cli("drift", "fit", src, "-o", tmp_path / "model.json", "--rated", 1000)
    assert run.returncode == 0, run.stderr
    said = [line for line in run.stdout.splitlines() if "drift's standard error up to" in line]
    assert len(said) == 3 and f"{se['per_range'][2]:.3g}" in said[2]
