"""A newcomer's walk-through of the FOCT temperature-drift path (session 35): an 85 °C DS18B20 power-on reading
inside a −40…70 °C log went unnoticed and turned a class-0.2S verdict; the fit's warnings (a °F log with no unit,
an AR model Ljung–Box rejected) were lost on saving, so drift apply and export-c went ahead silently; drift apply
did not reuse the model's temperature column; NaN and out-of-range errors named a 0-based sample, not the file's
line, and left out the option that handles them; an 8-row log got a glitch error instead of its size's."""
import json

import numpy as np
import pytest
from scipy.signal import lfilter

from fluxcal import drift, read_csv, write_csv
from fluxcal.cli import main
from fluxcal.export_c import export_c

DT = 5.0  # s


def chamber(rate=1.0 / 60, hold=1800.0, dt=DT, levels=(23.0, -40.0, 70.0, 23.0)):
    """A chamber cycle through `levels` at `rate` °C/s with `hold` s at each: (t, temperature)."""
    points, t = [(0.0, levels[0])], 0.0
    for a, b in zip(levels[:-1], levels[1:]):
        t += abs(b - a) / rate
        points.append((t, b))
        t += hold
        points.append((t, b))
    tp, temp = np.array(points).T
    tt = np.arange(0.0, tp[-1], dt)
    return tt, np.interp(tt, tp, temp)


def truth(temp):
    u = np.asarray(temp) - 20.0
    return 0.8 + 0.012 * u - 2e-4 * u ** 2 + 3e-6 * u ** 3


def foct_log(seed=1, coil_lag=0.0):
    """A housing thermometer 15 min behind the chamber (0.05 °C noise, logged to 0.01 °C), the zero bias (A) the
    cubic `truth` of the fibre coil's temperature (`coil_lag` s behind the thermometer) plus AR(2) noise."""
    rng = np.random.default_rng(seed)
    t, chamber_temp = chamber()
    housing = lfilter([DT / 900.0], [1.0, DT / 900.0 - 1.0], chamber_temp - chamber_temp[0]) + chamber_temp[0]
    coil = housing if coil_lag == 0 else (
        lfilter([DT / coil_lag], [1.0, DT / coil_lag - 1.0], housing - housing[0]) + housing[0])
    noise = lfilter([1.0], [1.0, -1.5, 0.6], rng.normal(0.0, 0.003, t.size + 500))[500:]
    temp = np.round(housing + rng.normal(0.0, 0.05, t.size), 2)
    return {"t": t, "zero_bias": np.round(truth(coil) + noise, 5), "temp": temp}


@pytest.fixture(scope="module")
def log():
    return foct_log()


def line_of(path, row: int) -> int:
    """The file line (1-based) of data row `row` of a CSV written by write_csv (a comment line, the header)."""
    lines = path.read_text().splitlines()
    return next(k for k, line in enumerate(lines) if not line.startswith("#")) + 2 + row


def cli(capsys, *args):
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


# -- finding 1: an 85 °C reading within the log's range; finding 6: the size first -------------------------

def test_a_ds18b20_power_on_reading_within_the_range_is_a_glitch(log):
    """85 °C at 23 °C in a −40…70 °C log is within the range of the rest (the old rule could not flag it), but no
    temperature that moves like the rest (steps of a few 0.01 °C) departs 62 °C from its running median."""
    temp = log["temp"].copy()
    assert drift.temperature_glitches(temp).size == 0
    temp[10] = 85.0
    assert drift.temperature_glitches(temp).tolist() == [10]
    with pytest.raises(drift.TemperatureGlitches, match=r"\(row 10: 85 °C\)"):
        drift.fit_pipeline(log["zero_bias"], temp, t=log["t"])
    first = log["temp"].copy()
    first[0] = 85.0  # at power-on it is the first reading: judged against the ones after it
    assert drift.temperature_glitches(first).tolist() == [0]
    several = log["temp"].copy()
    rows = [5, 6, 700, 1500, 2400, 3000]
    several[rows] = [-127.0, -127.0, 85.0, 85.0, 85.0, 40.0]  # a dropout and glitches that would hide each other
    assert drift.temperature_glitches(several).tolist() == rows


def test_the_step_rule_leaves_genuine_temperatures_alone(log):
    """No constant to tune, and nothing genuine flagged: a chamber log, one sampled every 10 min on 1 °C/min ramps
    (10 °C steps, triangle corners), and holds read by a 1/16 °C thermometer, one so quiet that a reading one step
    off comes seldom (the whole-range rule had flagged those: the rest's range was 0)."""
    assert drift.temperature_glitches(log["temp"]).size == 0
    rng = np.random.default_rng(3)
    minutes = np.arange(0.0, 48 * 60, 10.0)
    triangle = 15.0 + 55.0 * (2.0 * np.abs((minutes / 110.0) % 2.0 - 1.0) - 1.0)  # −40…70 °C at 1 °C/min
    for series in (triangle, triangle + rng.normal(0.0, 0.05, triangle.size)):
        assert drift.temperature_glitches(series).size == 0
    for sigma in (0.01, 0.02, 0.1):
        hold = np.round((25.0 + rng.normal(0.0, sigma, 5000)) / 0.0625) * 0.0625
        assert drift.temperature_glitches(hold).size == 0, sigma
    quiet = np.full(2000, 25.0)
    quiet[[300, 1200]] = [25.0625, 24.9375]  # one step of the thermometer, twice in 2000 readings
    assert drift.temperature_glitches(quiet).size == 0


def test_the_cli_names_the_line_of_the_glitch(tmp_path, log, capsys):
    temp = log["temp"].copy()
    temp[10] = 85.0
    src = write_csv(tmp_path / "glitch85.csv", {**log, "temp": temp})
    code, _, err = cli(capsys, "drift", "fit", src, "-o", tmp_path / "m.json", "--rated", 1000)
    assert code == 2 and f"(line {line_of(src, 10)}: 85 °C)" in err and "--bad-lines skip" in err, err
    assert not (tmp_path / "m.json").exists()


def test_a_short_log_is_judged_by_its_size_before_its_glitches(tmp_path, log, capsys):
    """8 rows at 22.93…23.04 °C: too few for the fit, which is said first (22.93 had been called a glitch)."""
    few = write_csv(tmp_path / "few8.csv", {k: v[:8] for k, v in log.items()} | {
        "temp": np.array([23.02, 23.04, 23.02, 22.93, 23.04, 23.02, 22.96, 23.02])})
    code, _, err = cli(capsys, "drift", "fit", few, "-o", tmp_path / "few.json")
    assert code == 2 and "zero_bias: 8 samples, need at least" in err and "reading(s)" not in err, err


# -- finding 2: the fit's warnings go with the model -------------------------------------------------------

def test_a_unit_hint_is_kept_repeated_by_apply_and_refused_by_export_c(tmp_path, log, capsys):
    """A °F log with no unit: the fit warns and writes the model; the model keeps the warning, drift apply repeats
    it, export-c --drift refuses it (its header would say degrees C over °F numbers) unless --force, which the
    header then says."""
    src = write_csv(tmp_path / "f.csv", {**log, "temp": np.round(log["temp"] * 1.8 + 32.0, 2)})
    model_path = tmp_path / "f.json"
    code, out, err = cli(capsys, "drift", "fit", src, "-o", model_path)
    assert code == 0 and "Is temp in °F?" in out, out + err
    data = json.loads(model_path.read_text())
    assert any("Is temp in °F?" in w for w in data["summary"]["fit_warnings"])
    assert "Is temp in °F?" in data["summary"]["temperature_unit_hint"]
    celsius = write_csv(tmp_path / "c.csv", log)
    code, out, err = cli(capsys, "drift", "apply", model_path, celsius, "-o", tmp_path / "out.csv")
    assert code == 0 and f"warning: {model_path} (at its fit): temp: " in out and "Is temp in °F?" in out, out
    assert "adjusted to the data" not in out  # (the ranges' note describes the fit, not the model's validity)
    header = tmp_path / "f.h"
    code, out, err = cli(capsys, "export-c", "-o", header, "--drift", model_path)
    assert code == 2 and "its fit warned that the temperatures are not °C" in err and "--force" in err, err
    assert not header.exists()
    with pytest.raises(ValueError, match=r"force=True \(--force\)"):
        export_c(None, header, drift=model_path)
    code, out, err = cli(capsys, "export-c", "-o", header, "--drift", model_path, "--force")
    assert code == 0 and "warning:" in out, out + err
    assert "WARNING (exported with --force)" in header.read_text() and "Is temp in" in header.read_text()


def test_a_rejected_noise_model_is_kept_and_its_kalman_filter_said(tmp_path, log, capsys):
    """An AR(1) cannot whiten AR(2) noise (a1 = 1.5, a2 = −0.6): Ljung–Box rejects it. The model keeps the test
    and the warning; export-c writes its --kalman with the warning printed and in the header (its 5 % test rejects
    one good model in twenty: a refusal would need --force there); drift apply and export-c --drift repeat it."""
    src = write_csv(tmp_path / "log.csv", log)
    model_path = tmp_path / "m.json"
    code, out, err = cli(capsys, "drift", "fit", src, "-o", model_path, "--ar-max-order", 1)
    assert code == 0 and "residuals are not white" in out, out + err
    model = drift.DriftModel.load(model_path)
    assert model.settings["ar"]["whiteness"]["white"] is False
    assert "residuals are not white" in drift.noise_model_rejected(model)
    assert any("residuals are not white" in w for w in drift.fit_warnings(model))
    code, out, _ = cli(capsys, "drift", "apply", model_path, src, "-o", tmp_path / "out.csv")
    assert code == 0 and "(at its fit): residuals are not white" in out, out
    header = tmp_path / "k.h"
    code, out, err = cli(capsys, "export-c", "-o", header, "--kalman", model_path, "--drift", model_path)
    assert code == 0 and "warning: " in out and "the fit rejected the AR(1) model" in out, out + err
    text = header.read_text()
    assert "WARNING: the fit rejected the AR(1) model" in text
    assert all(len(line) <= 120 for line in text.splitlines() if line.startswith(("/*", " *")))
    code, out, err = cli(capsys, "export-c", "-o", tmp_path / "d.h", "--drift", model_path)
    assert code == 0 and "warning: " in out and "residuals are not white" in out, out + err
    # a white model is exported as before, without a word
    code, out, err = cli(capsys, "drift", "fit", src, "-o", tmp_path / "white.json")
    assert code == 0 and drift.noise_model_rejected(drift.DriftModel.load(tmp_path / "white.json")) is None
    code, out, err = cli(capsys, "export-c", "-o", tmp_path / "w.h", "--kalman", tmp_path / "white.json",
                         "--drift", tmp_path / "white.json")
    assert code == 0 and "warning" not in out and "WARNING" not in (tmp_path / "w.h").read_text(), out + err


# -- finding 4: apply's temperature column ------------------------------------------------------------------

def test_apply_takes_the_models_temperature_column(tmp_path, log, capsys):
    logger = {"time_s": log["t"], "T_chamber_F": np.round(log["temp"] * 1.8 + 32.0, 2),
              "T_housing_C": log["temp"], "zero_A": log["zero_bias"]}
    src = write_csv(tmp_path / "logger.csv", logger)
    model_path = tmp_path / "m.json"
    code, _, err = cli(capsys, "drift", "fit", src, "-o", model_path, "--column", "zero_A",
                       "--temp-column", "T_housing_C")
    assert code == 0, err
    code, out, err = cli(capsys, "drift", "apply", model_path, src, "-o", tmp_path / "out.csv")
    assert code == 0, err
    out_rec = read_csv(tmp_path / "out.csv")
    model = drift.DriftModel.load(model_path)
    np.testing.assert_allclose(out_rec.columns["zero_A_compensated"], model.compensate(log["zero_bias"], log["temp"]))


# -- finding 5: errors with the file's line and the remedy --------------------------------------------------

def test_a_nan_names_the_file_line_and_bad_lines_skip(tmp_path, log, capsys):
    zero_bias = log["zero_bias"].copy()
    zero_bias[[100, 2000]] = np.nan
    src = write_csv(tmp_path / "nan.csv", {**log, "zero_bias": zero_bias})
    code, _, err = cli(capsys, "drift", "fit", src, "-o", tmp_path / "m.json")
    assert code == 2 and f"{src}, line {line_of(src, 100)}, column 'zero_bias': nan is not finite" in err, err
    assert f"2 lines: {line_of(src, 100)}, {line_of(src, 2000)}" in err and "--bad-lines skip" in err
    with pytest.raises(ValueError, match=r"zero_bias: sample 100 is nan .*--bad-lines skip"):
        drift.fit_pipeline(zero_bias, log["temp"])


def test_outside_the_ranges_names_the_line_the_option_and_a_unit(tmp_path, log, capsys):
    src = write_csv(tmp_path / "log.csv", log)
    model_path = tmp_path / "m.json"
    assert cli(capsys, "drift", "fit", src, "-o", model_path)[0] == 0
    hot = write_csv(tmp_path / "hot.csv", {**log, "temp": log["temp"] + 6.0})
    code, _, err = cli(capsys, "drift", "apply", model_path, hot, "-o", tmp_path / "x.csv")
    first = int(np.flatnonzero(np.isnan(drift.DriftModel.load(model_path).evaluate(log["temp"] + 6.0,
                                                                                    outside="nan")))[0])
    assert code == 2 and f"{hot}, line {line_of(hot, first)}: temp " in err and "--outside-range nan" in err, err
    assert " in °F" not in err and " in K" not in err  # 6 °C hotter is not another unit
    kelvin = write_csv(tmp_path / "k.csv", {**log, "temp": log["temp"] + 273.15})
    code, _, err = cli(capsys, "drift", "apply", model_path, kelvin, "-o", tmp_path / "x.csv")
    assert code == 2 and "is it in K?" in err and "'# units: temp=K'" in err, err
    # a model fitted on K numbers (no unit), applied to a °C log: the model's unit is the suspect
    k_model = tmp_path / "k.json"
    assert cli(capsys, "drift", "fit", kelvin, "-o", k_model)[0] == 0
    code, _, err = cli(capsys, "drift", "apply", k_model, src, "-o", tmp_path / "x.csv")
    assert code == 2 and "was the model fitted on a temperature in K logged with no unit?" in err, err
    # the Python spelling names outside='nan'
    with pytest.raises(ValueError, match=r"outside='nan' \(--outside-range nan\)"):
        drift.DriftModel.load(model_path).compensate(log["zero_bias"], log["temp"] + 6.0)


def test_drift_apply_writes_the_kalman_output_the_firmware_would(tmp_path, log, capsys):
    """No command wrote a new log's Kalman-filtered output (a newcomer built the filter by hand): `drift apply
    --filtered` adds it, the model's filter on W − f(T) as export-c --kalman runs it, started again after a gap in
    time and after samples outside the model's ranges (NaN there)."""
    from fluxcal.kalman import ArKalman

    src = write_csv(tmp_path / "log.csv", log)
    model_path = tmp_path / "m.json"
    assert cli(capsys, "drift", "fit", src, "-o", model_path)[0] == 0
    model = drift.DriftModel.load(model_path)
    k = model.settings["kalman"]
    filt = ArKalman(model.settings["ar"]["coefficients"], k["q"], k["r"], steady_state=k["steady_state"])
    other = foct_log(seed=2)
    other["t"] = other["t"] + np.where(np.arange(other["t"].size) >= 1500, 3600.0, 0.0)  # an hour's gap
    other["temp"][3000:3010] = 90.0  # beyond the model's ranges
    code, out, err = cli(capsys, "drift", "apply", model_path, write_csv(tmp_path / "new.csv", other),
                         "-o", tmp_path / "out.csv", "--filtered", "--outside-range", "nan")
    assert code == 0 and "columns zero_bias_compensated, zero_bias_filtered" in out, out + err
    got = read_csv(tmp_path / "out.csv")
    w = got.columns["zero_bias_compensated"]
    want = np.full(w.size, np.nan)
    for a, b in ((0, 1500), (1500, 3000), (3010, w.size)):
        want[a:b] = filt.filter(w[a:b])
    np.testing.assert_allclose(got.columns["zero_bias_filtered"], want, rtol=0, atol=1e-12)
    assert np.std(want[np.isfinite(want)]) < np.std(w[np.isfinite(w)])
    white = drift.DriftModel.load(model_path)
    white.settings["kalman"] = None
    with pytest.raises(ValueError, match="no Kalman filter"):
        drift.filter_compensated(white, w)


def test_a_thermal_lag_is_named_with_its_time_constant():
    """A coil 10 min behind its thermometer left residuals 16× the noise and the AR model rejected, with nothing
    naming the cause: the compensated zero bias following f'(T)·dT/dt now says a thermal lag (τ a lower bound);
    the same log without the lag says nothing."""
    lagged = foct_log(seed=3, coil_lag=600.0)
    _, report = drift.fit_pipeline(lagged["zero_bias"], lagged["temp"], t=lagged["t"])
    lag = report["thermal_lag"]
    assert lag["said"] and 300.0 < lag["tau_s"] <= 650.0, lag
    assert any("lags the thermometer by about" in w for w in report["warnings"])
    clean = foct_log(seed=3)
    _, report = drift.fit_pipeline(clean["zero_bias"], clean["temp"], t=clean["t"])
    assert not report["thermal_lag"]["said"] and not any("lags the thermometer" in w for w in report["warnings"])


def test_drift_apply_names_a_temperature_that_is_not_a_number(tmp_path, log, capsys):
    """An empty or NaN temperature in the log to compensate had been said "nan °C is outside every range" with the
    --outside-range remedy (a review): it is the file's, named by its line with --bad-lines skip, as drift fit does."""
    src = write_csv(tmp_path / "log.csv", log)
    model_path = tmp_path / "m.json"
    assert cli(capsys, "drift", "fit", src, "-o", model_path)[0] == 0
    other = {k: v.copy() for k, v in log.items()}
    other["temp"][50] = np.nan
    path = write_csv(tmp_path / "nan.csv", other)
    code, out, err = cli(capsys, "drift", "apply", model_path, path, "-o", tmp_path / "out.csv")
    assert code == 2 and f"line {line_of(path, 50)}, column 'temp'" in err and "--bad-lines skip" in err, err
    assert "outside every range" not in err
