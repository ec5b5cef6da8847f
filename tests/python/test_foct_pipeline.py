"""The C++ FOCT pipeline (fluxcal._core.fit_foct, cpp/include/fluxcal/foct.hpp) against the Python
orchestration fluxcal.drift.fit_pipeline (the reference) on the simulated FOCT of test_drift.py."""
import inspect

import numpy as np
import pytest

from fluxcal import _core, drift, sim
from fluxcal import timeseries as ts

RATED = 1000.0  # A: the simulated FOCT's rated current
RTOL = 1e-9


def fit_cpp(zero_bias, temp, temp_outside=None, regressor="temp", breakpoints=drift.DEFAULT_BREAKPOINTS,
            max_order=4, significance=0.05, continuous=False, ar_max_order=10, q=None, r=None, steady_state=False,
            subseries=20, rated=None, accuracy_class="0.2S", whiten=True, drift_input="zero_bias", t=None) -> dict:
    """fit_pipeline's signature on the C++ pipeline: knobs into FoctOptions, nothing else."""
    if regressor not in drift.REGRESSORS:
        raise ValueError(f"regressor: {regressor!r} is not one of {', '.join(drift.REGRESSORS)}")
    o = _core.FoctOptions()
    o.regressor = getattr(_core.DriftRegressor, regressor)
    o.drift.breakpoints = [float(b) for b in breakpoints]
    o.drift.max_order = int(max_order)
    o.drift.significance = float(significance)
    o.drift.continuous = bool(continuous)
    o.drift.whiten = bool(whiten)
    o.ar.max_order = int(ar_max_order)
    o.q = None if q is None else float(q)
    o.r = None if r is None else float(r)
    o.kalman.steady_state = bool(steady_state)
    o.preprocess.subseries = int(subseries)
    o.rated = None if rated is None else float(rated)
    o.accuracy_class = accuracy_class
    o.drift_input = getattr(_core.DriftInput, drift_input)
    o.breaks = [] if t is None else ts.find_breaks(t).tolist()
    outside = None if temp_outside is None else ts.as_series(temp_outside, "temp_outside")
    return _core.fit_foct(ts.as_series(zero_bias, "zero_bias"), ts.as_series(temp, "temp"), outside, o)


_SIMS = {}


def foct(seed):
    if seed not in _SIMS:
        _SIMS[seed] = sim.foct_zero_bias(rng=np.random.default_rng(seed)).columns
    return _SIMS[seed]


def assert_agree(got, model, report, zero_bias):
    assert got["orders"] == report["orders"]
    assert got["ar"]["order"] == report["ar"]["order"]
    np.testing.assert_allclose(got["ar"]["coefficients"], report["ar"]["coefficients"], rtol=RTOL, atol=0)
    # Both fit the AR model to the noise about the first drift model and test it over the same lags.
    assert got["ar"]["whiteness"]["lags"] == report["ar"]["whiteness"]["lags"]
    assert got["ar"]["whiteness"]["p_value"] == pytest.approx(report["ar"]["whiteness"]["p_value"], rel=1e-6)
    # Both say alike when (and why) there is no Kalman filter: white noise about the drift.
    assert got["notes"] == report["notes"]
    kal = model.settings["kalman"]
    if kal is None:
        assert got["kalman"] is None and report["ar"]["order"] == 0
    else:
        assert got["kalman"]["q"] == pytest.approx(kal["q"], rel=RTOL)
        assert got["kalman"]["r"] == pytest.approx(kal["r"], rel=RTOL)
        assert set(got["kalman"]) == set(kal)
        assert got["kalman"]["steady_state"] == kal["steady_state"]
    assert got["regressor"] == model.regressor
    assert got["drift_input"] == model.settings["drift_input"]
    np.testing.assert_allclose(got["noise_ar"], model.settings["noise_ar"], rtol=RTOL, atol=RTOL)
    assert len(got["segments"]) == len(model.segments)
    for g, p in zip(got["segments"], model.segments):
        assert g["range"] == list(p["range"]) and g["order"] == p["order"]
        np.testing.assert_allclose(g["coefficients"], p["coefficients"], rtol=RTOL, atol=0)
    # Series: relative to the size of the zero bias (values cross zero, so not sample by sample).
    scale = np.max(np.abs(zero_bias))
    for key in ("filtered", "compensated"):
        np.testing.assert_allclose(got[key], report[key], rtol=RTOL, atol=RTOL * scale)
    for key in ("drift_span_before", "drift_span_after", "drift_reduction"):
        assert got[key] == pytest.approx(report[key], rel=RTOL)
    # The C++ summary also carries the drift model's (and the Kalman filter's) warnings. (Python's checks of the data
    # beyond the pipeline are its own: here, the other regressor tried.)
    own = ("the device temperature explains this drift better", "met by the Kalman-filtered output only")
    # (report["warnings"] holds the drift model's too, after the data's)
    data = [w for w in report["warnings"] if not any(o in w for o in own) and w not in model.summary["warnings"]]
    assert got["warnings"] == data + model.summary["warnings"]
    for key in ("accuracy", "accuracy_drift"):
        if key not in report:
            assert got[key] is None
            continue
        g, p = got[key], report[key]
        assert g["met"] == p["met"] and g["class"] == p["class"] and g["rated"] == p["rated"]
        assert g["max_abs_residual"] == pytest.approx(p["max_abs_residual"], rel=RTOL)
        assert [x["met"] for x in g["points"]] == [x["met"] for x in p["points"]]
        np.testing.assert_allclose([x["ratio_error_percent"] for x in g["points"]],
                                   [x["ratio_error_percent"] for x in p["points"]], rtol=RTOL)


def test_defaults_match_fit_pipeline():
    o = _core.FoctOptions()
    params = inspect.signature(drift.fit_pipeline).parameters
    cpp_defaults = {"regressor": "temp" if o.regressor == _core.DriftRegressor.temp else "difference",
                    "breakpoints": tuple(o.drift.breakpoints), "max_order": o.drift.max_order,
                    "significance": o.drift.significance, "continuous": o.drift.continuous,
                    "ar_max_order": o.ar.max_order, "q": o.q, "r": o.r, "steady_state": o.kalman.steady_state,
                    "subseries": o.preprocess.subseries, "rated": o.rated, "accuracy_class": o.accuracy_class,
                    "whiten": o.drift.whiten, "drift_input": o.drift_input.name}
    # Every knob of fit_pipeline (beyond the three series) has a C++ counterpart with the same default; the
    # times t are FoctOptions.breaks, the gaps in them (none by default).
    # spikes: a screen of the input series in Python (the C++ pipeline takes the series it is given); a leading
    # underscore: the refit's own (the ageing taken out), not a knob.
    knobs = {name for name in params if not name.startswith("_")}
    assert knobs - {"zero_bias", "temp", "temp_outside", "t", "spikes"} == set(cpp_defaults)
    assert params["t"].default is None and o.breaks == []
    for name, value in cpp_defaults.items():
        assert value == params[name].default, name
    # What fit_pipeline leaves at fit_drift's / fit_ar's defaults, FoctOptions does too.
    fit_drift_params = inspect.signature(drift.fit_drift).parameters
    assert o.drift.order == -1 and fit_drift_params["order"].default is None
    assert o.drift.whiten_max_order == fit_drift_params["whiten_max_order"].default
    assert o.drift.min_samples == fit_drift_params["min_samples"].default
    assert o.ar.order == -1 and o.kalman.initial_variance == 0.0 and o.level_step == 5.0


@pytest.mark.parametrize("seed", [2016, 7, 1, 3])
def test_agrees_with_python_on_simulated_foct(seed):
    c = foct(seed)
    model, report = drift.fit_pipeline(c["zero_bias"], c["temp"], c["temp_outside"], rated=RATED)
    got = fit_cpp(c["zero_bias"], c["temp"], c["temp_outside"], rated=RATED)
    assert_agree(got, model, report, c["zero_bias"])
    # Not a trivial agreement: the generating orders come back and the drift is gone.
    assert got["orders"] == [2, 1, 3]
    assert got["drift_reduction"] >= 10.0


CONFIGS = {
    "difference": dict(regressor="difference", max_order=2),
    "continuous_strict": dict(continuous=True, significance=0.01),
    "steady_state_given_r": dict(steady_state=True, r=1e-3, ar_max_order=6),
    "given_q_r_unwhitened": dict(q=2e-3, r=1e-3, whiten=False, subseries=10),
    "phase_b_two_ranges": dict(breakpoints=(-20.0, 15.0, 50.0), accuracy_class="0.5S", rated=RATED),
    "filtered_input": dict(drift_input="filtered", rated=RATED),
}


@pytest.mark.parametrize("seed", [2016, 7])
@pytest.mark.parametrize("config", sorted(CONFIGS))
def test_agrees_with_python_for_other_settings(config, seed):
    c = foct(seed)
    kwargs = CONFIGS[config]
    w = c["zero_bias_b"] if config.startswith("phase_b") else c["zero_bias"]
    model, report = drift.fit_pipeline(w, c["temp"], c["temp_outside"], **kwargs)
    got = fit_cpp(w, c["temp"], c["temp_outside"], **kwargs)
    assert_agree(got, model, report, w)
    assert got["drift_reduction"] > 1.5  # the difference regressor explains the drift least (≈ 1.8)


def test_compensating_new_data_and_the_helpers():
    train, fresh = foct(2016), foct(7)
    for regressor in ("temp", "difference"):
        model, _ = drift.fit_pipeline(train["zero_bias"], train["temp"], train["temp_outside"], regressor=regressor)
        segs = [((s["range"][0], s["range"][1]), list(s["coefficients"])) for s in model.segments]
        got = _core.foct_compensate(segs, getattr(_core.DriftRegressor, regressor), fresh["zero_bias"],
                                    fresh["temp"], fresh["temp_outside"])
        np.testing.assert_array_equal(got, model.compensate(fresh["zero_bias"], fresh["temp"], fresh["temp_outside"]))
    with pytest.raises(ValueError, match="temp_outside: needed"):
        _core.foct_compensate(segs, _core.DriftRegressor.difference, fresh["zero_bias"], fresh["temp"])
    w, t = fresh["zero_bias"], fresh["temp"]
    levels_py, levels_cpp = drift.level_means(w, t), _core.foct_level_means(w, t)
    assert list(levels_cpp) == list(levels_py)  # the same levels in the same (ascending) order
    np.testing.assert_allclose(list(levels_cpp.values()), list(levels_py.values()), rtol=1e-12)
    assert _core.foct_drift_span(w, t) == pytest.approx(drift.drift_span(w, t), rel=1e-12)
    # Half-to-even rounding of the levels, as np.round: 2.5 → 0, 7.5 → 10.
    assert list(_core.foct_level_means(np.array([1.0, 2.0, 4.0]), np.array([2.5, 7.5, 12.4]))) == [0.0, 10.0]
    k = drift.ArKalman([0.5, -0.2], 0.0025, 0.0025)
    assert _core.kalman_dc_gain(k.ar_coeffs, k.q, k.r, k.options) == pytest.approx(drift.dc_gain(k), rel=1e-12)
    residual = 0.1 * (w - w.mean()) / np.max(np.abs(w - w.mean()))  # 0.1 A worst: 1 % at 1 % of rated
    verdicts = set()
    for cls in ("0.2S", "0.5S"):
        got, ref = _core.zero_bias_accuracy(residual, RATED, cls), drift.accuracy(residual, RATED, cls)
        assert got.pop("class") == ref.pop("class") == cls
        points, ref_points = got.pop("points"), ref.pop("points")
        assert got == pytest.approx(ref, rel=1e-15)
        assert len(points) == len(ref_points) == 5
        for g, r in zip(points, ref_points):
            assert g == pytest.approx(r, rel=1e-15)
        verdicts.add(got["met"])
    assert verdicts == {False, True}  # this residual fails 0.2S but meets 0.5S: both branches compared


@pytest.mark.parametrize("seed", [2016, 7])
def test_gaps_in_time_agree_with_python(seed):
    """A recorder that logs the temperature holds only (seed 001's S1): a gap in t at each of the 14 ramps.
    Both pipelines whiten, fit the AR model and restart the filter within the stretches alike."""
    c = sim.foct_zero_bias(rng=np.random.default_rng(seed), logged="holds", hold_s=300.0, ar=(0.9,)).columns
    model, report = drift.fit_pipeline(c["zero_bias"], c["temp"], rated=RATED, t=c["t"])
    got = fit_cpp(c["zero_bias"], c["temp"], rated=RATED, t=c["t"])
    assert report["gaps"]["count"] == 14 and report["gaps"]["longest"] == pytest.approx(601.0)
    assert_agree(got, model, report, c["zero_bias"])
    assert got["notes"][0] == drift.gaps_note(14)
    spliced = fit_cpp(c["zero_bias"], c["temp"], rated=RATED)  # not a trivial agreement: the gaps change the fit
    assert not np.array_equal(spliced["ar"]["coefficients"], got["ar"]["coefficients"])
    assert not np.allclose(spliced["filtered"], got["filtered"])


def test_gaps_are_set_once():
    o = _core.FoctOptions()
    o.ar.breaks = [10]
    c = foct(2016)
    with pytest.raises(ValueError, match="FoctOptions::ar.breaks: set FoctOptions::breaks instead"):
        _core.fit_foct(c["zero_bias"], c["temp"], None, o)
    o = _core.FoctOptions()
    o.breaks = [5, 5]
    with pytest.raises(ValueError, match="FoctOptions::breaks: break 1 at sample 5"):
        _core.fit_foct(c["zero_bias"], c["temp"], None, o)


WHITE_SEEDS = (2, 3)  # sim.foct_zero_bias(ar=()) seeds whose noise about the drift AIC calls white (order 0)


@pytest.mark.parametrize("drift_input", ["zero_bias", "filtered"])
@pytest.mark.parametrize("case", ["white_about_drift", "white_without_drift"])
def test_white_noise_agrees_with_python(case, drift_input):
    # No Kalman filter (AR order 0): L = the drift model + the noise mean in both, the same notes, and
    # drift_input "filtered" falls back to the fit to the zero bias in both (L has no noise to refit).
    if case == "white_about_drift":
        c = sim.foct_zero_bias(rng=np.random.default_rng(WHITE_SEEDS[0]), ar=()).columns
        w, t, kwargs = c["zero_bias"], c["temp"], dict(rated=RATED)
    else:  # seed 001's white series without a drift: what used to fail with "AIC chose AR order 0"
        w = np.random.default_rng(0).normal(0.0, 0.05, 3000)
        t, kwargs = np.linspace(-20, 50, w.size), {}
    model, report = drift.fit_pipeline(w, t, drift_input=drift_input, **kwargs)
    got = fit_cpp(w, t, drift_input=drift_input, **kwargs)
    assert report["ar"]["order"] == 0 and model.settings["kalman"] is None
    assert_agree(got, model, report, w)
    assert got["drift_input"] == "zero_bias"
    assert got["notes"][0] == drift.WHITE_NOISE_NOTE
    assert (drift.WHITE_NOISE_NO_REFIT in got["notes"]) == (drift_input == "filtered")
    assert got["summary"]["message"].startswith("FOCT drift compensation: " + drift.WHITE_NOISE_NOTE)


def _bad_cases():
    c = foct(2016)
    w, t = c["zero_bias"].copy(), c["temp"].copy()
    w[5] = np.nan
    t[9] = np.inf
    return {
        "nan_zero_bias": ((w, c["temp"]), {}, "zero_bias: sample 5 is nan"),
        "inf_temp": ((c["zero_bias"], t), {}, "temp: sample 9 is inf"),
        "length_mismatch": ((c["zero_bias"], c["temp"][:100]), {}, "temp: 100 samples, zero_bias has 26400"),
        "too_short": ((c["zero_bias"][:30], c["temp"][:30]), {}, "30 samples, need at least 42"),
        "constant": ((np.full(1000, 0.3), np.linspace(-20, 50, 1000)), {}, "constant"),
        "no_temp_outside": ((c["zero_bias"], c["temp"]), {"regressor": "difference"}, "temp_outside: needed"),
        "bad_class": ((c["zero_bias"], c["temp"]), {"rated": RATED, "accuracy_class": "0.1"},
                      "accuracy_class: '0.1' is not one of 0.2S, 0.5S"),
        "bad_rated": ((c["zero_bias"], c["temp"]), {"rated": 0.0}, "rated: 0(.0)? must be > 0"),
        "negative_r": ((c["zero_bias"], c["temp"]), {"r": -1.0}, "r: measurement variance -1(.0)? must be ≥ 0"),
    }


@pytest.mark.parametrize("case", ["nan_zero_bias", "inf_temp", "length_mismatch", "too_short", "constant",
                                  "no_temp_outside", "bad_class", "bad_rated", "negative_r"])
@pytest.mark.parametrize("implementation", ["python", "cpp"])
def test_bad_input_fails_alike(case, implementation):
    args, kwargs, message = _bad_cases()[case]
    fit = drift.fit_pipeline if implementation == "python" else fit_cpp
    with pytest.raises(ValueError, match=message):
        fit(*args, **kwargs)


@pytest.mark.parametrize("shift, breakpoints", [(5.0, drift.DEFAULT_BREAKPOINTS), (0.0, (-20.0, 0.0, 30.0, 60.0, 70.0))])
def test_ranges_that_miss_the_data_are_adjusted_alike(shift, breakpoints):
    """Samples beyond the edges, or a range without samples, used to stop both pipelines; both now make the
    ranges cover the data, the same way, and say so."""
    c = foct(2016)
    temp = c["temp"] + shift
    model, report = drift.fit_pipeline(c["zero_bias"], temp, breakpoints=breakpoints)
    got = fit_cpp(c["zero_bias"], temp, breakpoints=breakpoints)
    assert_agree(got, model, report, c["zero_bias"])
    assert model.segments[-1]["range"][1] == temp.max() and len(model.segments) == 3
    assert any("adjusted to the data" in w for w in model.summary["warnings"])


def test_without_a_filter_the_class_check_judges_the_compensated_output():
    """White noise about the drift: no Kalman filter, so the user's output is the compensated zero bias. The
    sample-by-sample verdict judged L − f, a constant ≈ 0, and said MET at 1e-14 % whatever the noise."""
    rng = np.random.default_rng(4)
    temp = np.r_[np.linspace(-20, 50, 4000), np.linspace(50, -20, 4000)]
    w = 0.01 * temp + 2.0 * rng.standard_normal(temp.size)  # 2 A of white noise on 1000 A: 1 % at 20 % rated
    model, report = drift.fit_pipeline(w, temp, rated=RATED, ar_max_order=0)  # white: no filter, by construction
    assert model.settings["kalman"] is None
    np.testing.assert_array_equal(report["accuracy"]["max_abs_residual"], np.max(np.abs(report["compensated"])))
    assert not report["accuracy"]["met"]
    got = fit_cpp(w, temp, rated=RATED, ar_max_order=0)
    assert got["accuracy"]["max_abs_residual"] == pytest.approx(report["accuracy"]["max_abs_residual"], rel=RTOL)
