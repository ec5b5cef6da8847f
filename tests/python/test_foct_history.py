"""The FOCT drift fit on a chamber run's history: hysteresis (heating and cooling differ at the same temperature), a
sensing element that lags its thermometer, and a log that runs one way without holds (a blind check: a 3 °C
hysteresis passed the "drift alone" class check and was named a 383 s lag; a single ramp with a 15 min lag gave a
model 2× the 0.2S limit off at steady state with no word)."""
import numpy as np
from scipy.signal import lfilter

from fluxcal import drift
from fluxcal.sim.foct import foct_zero_bias


def fit(sim, temp=None):
    c = sim.columns
    return drift.fit_pipeline(c["zero_bias"], c["temp"] if temp is None else temp, t=c["t"], rated=1000.0)


def test_hysteresis_is_named_with_its_dead_band_and_judged_per_branch():
    sim = foct_zero_bias(rng=0, cycle=True, hysteresis=2.0)
    _, report = fit(sim)
    found = report["thermal_lag"]
    assert found["hysteresis"]["said"] and not found["said"], found
    assert 1.5 < found["hysteresis"]["dead_band_c"] < 2.5  # truth 2 °C
    said = [w for w in report["warnings"] if "differs between heating and cooling" in w]
    assert len(said) == 1 and "dead band of ±1.9 °C" in said[0] and "lags the thermometer" not in " ".join(
        report["warnings"])
    # heating minus cooling at a level, against the truth's (the drift at the two branches' states)
    c, truth = sim.columns, sim.truth["drift"]["zero_bias"]
    branch = drift.temperature_branch(c["temp"])
    level = found["hysteresis"]["at_level"]
    at = np.round(c["temp"] / 5.0) * 5.0 == level
    true_difference = truth[at & (branch > 0)].mean() - truth[at & (branch < 0)].mean()
    assert abs(found["hysteresis"]["difference_by_level"][level] - true_difference) < 0.25 * abs(true_difference)
    # the class per level and branch: averaged over both branches the difference had cancelled
    averaged = drift.accuracy(list(drift.level_means(report["compensated"], c["temp"]).values()), 1000.0)
    assert report["accuracy_drift"]["max_abs_residual"] > 2 * averaged["max_abs_residual"]
    assert not report["accuracy_drift"]["met"]


def test_a_lag_longer_than_the_holds_is_a_lag_not_hysteresis():
    """The element 10 min behind the chamber, the thermometer 1 min: on 20 min holds the lag's error is still there
    at their ends, where a test on the holds alone took it for hysteresis."""
    sim = foct_zero_bias(rng=1, cycle=True, thermal_lag_s=600.0)
    a = 1.0 - np.exp(-1.0 / 60.0)
    chamber = sim.columns["temp_outside"]
    thermometer = lfilter([a], [1.0, a - 1.0], chamber, zi=[chamber[0] * (1.0 - a)])[0]
    _, report = fit(sim, thermometer)
    found = report["thermal_lag"]
    assert found["said"] and 350.0 < found["tau_s"] < 700.0, found  # about 540 s
    assert not found["hysteresis"]["said"]
    assert not any("heating and cooling" in w for w in report["warnings"])


def test_a_clean_cycle_says_neither():
    for seed in (0, 1):
        _, report = fit(foct_zero_bias(rng=seed, cycle=True))
        found = report["thermal_lag"]
        assert not found["said"] and not found["hysteresis"]["said"], found
        assert found["one_way"] is None and drift.one_way_note(found) is None


def test_a_log_that_runs_one_way_without_holds_says_what_a_lag_would_do():
    _, report = fit(foct_zero_bias(rng=2, hold_s=0.0))
    said = [w for w in report["warnings"] if "runs the temperature one way (heating) without settled holds" in w]
    assert len(said) == 1 and "each minute of lag moves the model by up to" in said[0]
    assert report["thermal_lag"]["one_way"]["per_minute_of_lag"] > 0
    # with holds it is a note (hysteresis cannot show), not a warning
    _, report = fit(foct_zero_bias(rng=2))
    assert not any("one way" in w for w in report["warnings"])
    assert "cannot show in it" in drift.one_way_note(report["thermal_lag"])
