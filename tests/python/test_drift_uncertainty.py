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


def _ramps(phi: float, continuous: bool, whiten: bool = True, runs: int = 200, n: int = 3000, cycles: float = 1.5):
    """Fits of a quadratic drift under AR(1) noise on a temperature crossing each range 2 × `cycles` times."""
    rng = np.random.default_rng(11)
    temp = 15 + 35 * np.sin(2 * np.pi * cycles * np.linspace(0, 1, n))
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


@pytest.mark.parametrize("continuous", [False, True])
def test_unwhitened_errors_hold_on_a_fast_temperature_cycle(continuous):
    """whiten=False with the temperature cycling every 50 samples: each range's rows come from 60 separate visits,
    and the Newey–West sandwich of each range's scores (AR(1)-prewhitened column by column across the joins) made the
    errors 3.7–21.5× the spread of the coefficients and 1.7–6.3× that of f(T) (continuous 2.1–6.6×, 1.55–2.4×), a
    review. Now the sandwich under an AR model of the residuals in time order: measured 0.95–1.06 and 0.99–1.01
    (continuous 0.96–1.08, 0.99–1.02) over 200 fits."""
    coefficients, at = _ramps(0.9, continuous, whiten=False, runs=300, cycles=60)
    assert np.all((coefficients > 0.75) & (coefficients < 1.35)), coefficients
    assert np.all((at > 0.75) & (at < 1.35)), at


def test_unwhitened_covariance_on_a_fast_cycle_matches_the_oracle():
    """The sandwich under the AR model of the residuals (fitted by AIC in time order across the ranges) against the
    oracle's: a dense-in-spirit Σ = σ² L⁻¹L⁻ᵀ from the sparse whitening filter and numpy's pseudo-inverse."""
    n = 3000
    temp = 15 + 35 * np.sin(2 * np.pi * np.arange(n) / 50)
    w = 0.02 + 1e-3 * temp + 2e-5 * temp ** 2 + lfilter([1], [1, -0.9], np.random.default_rng(4).normal(0, 0.01, n))
    got = drift.fit_drift(w, temp, whiten=False)
    ref, _ = oracle.fit_drift(temp, temp, w, whiten=False)
    for g, r in zip(got.segments, ref):
        assert g["order"] == r["order"]
        scale = np.sqrt(np.outer(np.diag(r["covariance"]), np.diag(r["covariance"])))
        assert np.max(np.abs(np.asarray(g["covariance"]) - r["covariance"]) / scale) < 1e-8  # measured 4e-13


def _near_unit_root(kind: str, whiten: bool, runs: int, n: int = 3000):
    rng = np.random.default_rng(7)
    temp = 15 + 35 * np.sin(2 * np.pi * 1.5 * np.linspace(0, 1, n))
    truth = lambda t: 0.02 + 1e-3 * t + 2e-5 * t ** 2
    probe = np.array([-10.0, 10.0, 40.0])
    err, se, said = [], [], []
    for _ in range(runs):
        e = rng.normal(0, 0.01, n)
        model = drift.fit_drift(truth(temp) + (0.1 * np.cumsum(e) if kind == "rw" else lfilter([1], [1, -0.99], e)),
                                temp, order=2, whiten=whiten)
        err.append(model.evaluate(probe) - truth(probe))
        se.append(model.standard_error(probe))
        said.append(model.summary["warnings"])
    return np.mean(se, axis=0) / np.std(err, axis=0, ddof=1), said


@pytest.mark.parametrize("kind, whiten", [("0.99", True), ("rw", False)])
def test_errors_near_a_unit_root_are_said_to_be_lower_bounds(kind, whiten):
    """Near a random walk the whitening model is dropped (whiten=True) or none was asked for; the errors were
    Newey–West's, clipped prewhitening and all — f(T)'s 0.47–0.60 of the spread for AR(1) 0.99 (95 % intervals
    covering 63–77 %), 0.10–0.28 for a random walk — and a note called them Newey–West's. Now they are the
    sandwich under the AR model of the residuals, measured 0.74–0.82 and 0.45–0.50 of the spread over 200–300
    fits, still too small: each fit says they are lower bounds (the whitened ones too, their AR model summing to
    0.95–0.98)."""
    ratio, said = _near_unit_root(kind, whiten, runs=200)
    assert np.all(ratio > (0.65 if kind == "0.99" else 0.35)), ratio
    assert np.all(ratio < 1.0), ratio  # lower bounds indeed: what the warning says
    for warnings in said:
        assert any("standard errors are lower bounds" in w and "random walk" in w for w in warnings), warnings
        assert not any("Newey" in w for w in warnings)


def test_the_cli_says_the_errors_near_a_unit_root_are_lower_bounds(tmp_path):
    """`drift fit` prints the drift's standard error per range; near a random walk it must say they are lower
    bounds (the core's warning, printed as the fit's)."""
    n = 3000
    rng = np.random.default_rng(8)
    temp = 15 + 35 * np.sin(2 * np.pi * 1.5 * np.linspace(0, 1, n))
    w = 0.02 + 1e-3 * temp + 2e-5 * temp ** 2 + 0.001 * np.cumsum(rng.normal(size=n))
    src = write_csv(tmp_path / "walk.csv", {"t": np.arange(n, dtype=float), "zero_bias": w, "temp": temp})
    run = run_cli("drift", "fit", src, "-o", tmp_path / "model.json")
    assert run.returncode == 0, run.stderr
    lines = run.stdout.splitlines()
    bound = [k for k, line in enumerate(lines) if line.startswith("warning: the drift's standard errors are lower bounds")]
    ranges = [k for k, line in enumerate(lines) if "drift's standard error up to" in line]
    assert bound and ranges and bound[0] < ranges[0], run.stdout


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


def test_the_pipelines_report_holds_the_lower_bound_warning():
    """report["warnings"] (the README's example prints it as "the fit's warnings") had missed the drift fit's own:
    "lower bounds" was only in model.summary["warnings"] (a blind check)."""
    n = 3000
    rng = np.random.default_rng(8)
    temp = 15 + 35 * np.sin(2 * np.pi * 1.5 * np.linspace(0, 1, n))
    w = 0.02 + 1e-3 * temp + 2e-5 * temp ** 2 + 0.001 * np.cumsum(rng.normal(size=n))
    model, report = drift.fit_pipeline(w, temp, t=np.arange(n, dtype=float))
    assert any("standard errors are lower bounds" in x for x in report["warnings"]), report["warnings"]
    assert not set(model.summary.get("range_notes", [])) & set(report["warnings"])
    assert drift.fit_warnings(model).count(next(x for x in report["warnings"] if "lower bounds" in x)) == 1
