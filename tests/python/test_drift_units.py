"""Temperatures in °F or K logged with no unit are read as °C: drift.temperature_unit_hint says so (newcomer C7:
`drift fit` only warned "ranges … adjusted to the data: [-4, 0, 30, 122]"), and does not say it of °C logs that
merely reach a little beyond the ranges."""
import json

import numpy as np
import pytest

from fluxcal import cli, drift, sim, write_csv


@pytest.fixture(scope="module")
def foct():
    # a short chamber cycle over seed 001's ranges −20…50 °C (4400 samples: each fit well under a second)
    return sim.foct_zero_bias(rng=np.random.default_rng(11), hold_s=200.0, ramp_s=100.0).columns


def _hints(report):
    return [w for w in report["warnings"] if "read as °C" in w]


def test_unlabelled_fahrenheit_is_hinted_with_the_range_the_celsius_and_the_remedy(foct):
    temp_f = foct["temp"] * 1.8 + 32.0
    model, report = drift.fit_pipeline(foct["zero_bias"], temp_f)
    hints = _hints(report)
    assert len(hints) == 1
    hint = hints[0]
    lo, hi = temp_f.min(), temp_f.max()  # −4 … ≈122
    assert hint.startswith(f"temp: {lo:.4g} … {hi:.4g} read as °C is beyond the -55 … 100 °C")
    assert f"in °F it would be {foct['temp'].min():.3g} … {foct['temp'].max():.3g} °C" in hint
    assert "Is temp in °F?" in hint and "'# units: temp=degF'" in hint and "temp_F" in hint
    # what it was before: the ranges stretched to the °F numbers, said only as an adjustment
    assert model.segments[-1]["range"][1] == pytest.approx(hi)
    # the same data in °C: no hint
    _, report_c = drift.fit_pipeline(foct["zero_bias"], foct["temp"])
    assert _hints(report_c) == []


def test_unlabelled_kelvin_is_hinted(foct):
    temp_k = foct["temp"] + 273.15
    _, report = drift.fit_pipeline(foct["zero_bias"], temp_k)
    hints = _hints(report)
    assert len(hints) == 1
    assert hints[0].startswith(f"temp: {temp_k.min():.4g} … {temp_k.max():.4g} read as °C")
    assert "in K it would be -20 … 49.9 °C, the ranges edge to edge" in hints[0]
    assert "'# units: temp=K'" in hints[0] and "°F" not in hints[0]


def test_a_fahrenheit_chamber_cycle_over_narrow_ranges_is_hinted_by_its_edges():
    """0…30 °C logged in °F is 32…86: as °C not beyond what a device meets, but it spans the stated ranges [0, 30]
    edge to edge in °F — which a °C log leaving them cannot (its span would have to be 1.8 times theirs)."""
    cycle = np.r_[np.linspace(0, 30, 300), np.linspace(30, 0, 300)]
    hint = drift.temperature_unit_hint(cycle * 1.8 + 32, breakpoints=(0, 10, 30))
    assert hint is not None and "in °F it would be 0 … 30 °C, the ranges edge to edge" in hint
    assert "56 °C beyond the ranges [0, 30]" in hint
    assert drift.temperature_unit_hint(cycle, breakpoints=(0, 10, 30)) is None
    # the same °F numbers with the default ranges: 86 °C is a hot device, not evidence of °F (no hint)
    assert drift.temperature_unit_hint(cycle * 1.8 + 32) is None


@pytest.mark.parametrize("lo, hi", [(-45.0, 50.0),   # a cold start below the rating
                                    (-20.0, 95.0),   # a chamber cycle with a hot end
                                    (20.0, 95.0),    # a warm-up to 95 °C (°F would put it at −7 … 35, inside)
                                    (-25.0, 55.0),   # a little beyond both ends
                                    (-55.0, 60.0)])
def test_celsius_logs_reaching_beyond_the_ranges_are_not_taken_for_fahrenheit(lo, hi):
    temp = np.r_[np.linspace(lo, hi, 500), np.linspace(hi, lo, 500)]
    assert drift.temperature_unit_hint(temp) is None


def test_a_value_a_little_past_a_models_range_is_not_taken_for_fahrenheit():
    """A model's evaluation refused outside its ranges: a blind check's single 80 °C (an overheat 10 °C past a
    −40 … 70 °C model) was asked "is it in °F?" because 80 °F is 26.7 °C. Values all outside but within
    UNIT_OVERSHOOT of the range are a hot or cold log; far past it, a °F reading that falls inside is hinted."""
    assert drift.outside_unit_hint([80.0], -40.0, 70.0) is None
    assert drift.outside_unit_hint([-50.0, -48.0], -40.0, 70.0) is None
    assert "is it in °F?" in drift.outside_unit_hint([100.0], -40.0, 70.0)


def test_a_cold_start_fit_warns_of_the_ranges_but_not_of_the_unit(foct):
    """The newcomer's situation (the ranges adjusted to the data) from a genuine °C log: no °F hint."""
    n = 400
    temp = np.r_[np.linspace(-45.0, -20.0, n), foct["temp"]]
    w = np.r_[foct["zero_bias"][0] + 0.01 * np.random.default_rng(1).standard_normal(n), foct["zero_bias"]]
    model, report = drift.fit_pipeline(w, temp)
    assert any("adjusted to the data" in m for m in model.summary["warnings"])
    assert _hints(report) == []


def test_readings_no_unit_explains_and_ranges_that_mean_them():
    counts = np.linspace(0, 4095, 1000)  # a raw ADC temperature column
    hint = drift.temperature_unit_hint(counts)
    assert hint.startswith("temp: 0 … 4095 read as °C is beyond the -55 … 100 °C")
    assert "as °F or K too" in hint and "--temp-column" in hint
    # ranges that cover the numbers: the user means them (a hot process), nothing to hint
    assert drift.temperature_unit_hint(np.linspace(253, 323, 100), breakpoints=(250, 290, 330)) is None


def _write(path, c, temp, temp_unit):
    units = {"t": "s", "zero_bias": "A", **({"temp": temp_unit} if temp_unit else {})}
    return write_csv(path, {"t": c["t"], "zero_bias": c["zero_bias"], "temp": temp}, units=units)


def test_cli_hints_unlabelled_fahrenheit_and_converts_labelled(tmp_path, capsys, foct):
    temp_f = foct["temp"] * 1.8 + 32.0
    src = _write(tmp_path / "foct_F.csv", foct, temp_f, None)
    assert cli.main(["drift", "fit", str(src), "-o", str(tmp_path / "m.json")]) == 0
    out = capsys.readouterr().out
    assert "warning: temp: -4 … 121.8 read as °C" in out and "Is temp in °F?" in out
    # stated in the file: converted by the reader (cli._temperatures), a model in °C, no hint
    src = _write(tmp_path / "foct_F_labelled.csv", foct, temp_f, "degF")
    assert cli.main(["drift", "fit", str(src), "-o", str(tmp_path / "m2.json")]) == 0
    out = capsys.readouterr().out
    assert "in °F, converted to °C" in out and "read as °C" not in out
    model = json.loads((tmp_path / "m2.json").read_text())
    assert model["segments"][0]["range"][0] == pytest.approx(-20.0)
    assert model["segments"][-1]["range"][1] == pytest.approx(foct["temp"].max())
    assert model["temperature"]["unit"] == "F"


def test_cli_hint_names_the_files_temperature_column(tmp_path, capsys, foct):
    """A column named otherwise (--temp-column T_dev): the hint and its remedy name it, not 'temp'."""
    path = write_csv(tmp_path / "foct_T_dev.csv", {"t": foct["t"], "zero_bias": foct["zero_bias"],
                                                    "T_dev": foct["temp"] * 1.8 + 32.0},
                     units={"t": "s", "zero_bias": "A"})
    assert cli.main(["drift", "fit", str(path), "--temp-column", "T_dev", "-o", str(tmp_path / "m.json")]) == 0
    out = capsys.readouterr().out
    assert "warning: T_dev: -4 … 121.8 read as °C" in out and "'# units: T_dev=degF'" in out
    assert "warning: temp:" not in out


def test_a_temperature_that_barely_moves_is_said(foct):
    """A blind check's temperature held at 25 ± 0.1 °C, the zero bias wandering by 0.38 A for another reason: fitted
    as a one-range model over 0.2 °C with no word of the span. Within one 5 °C level the span is said, with the zero
    bias's own spread there; a chamber cycle says nothing of it."""
    rng = np.random.default_rng(2)
    n = 2000
    temp = 25.0 + 0.1 * np.sin(np.linspace(0, 20, n)) + 0.005 * rng.standard_normal(n)
    w = 0.19 * np.sin(np.linspace(0, 3, n)) + 0.01 * rng.standard_normal(n)
    _, report = drift.fit_pipeline(w, temp)
    said = [m for m in report["warnings"] if "temp moves only" in m]
    assert len(said) == 1 and "(24.89 … 25.11; within one 5 °C level)" in said[0] and "the operating range" in said[0]
    _, report = drift.fit_pipeline(foct["zero_bias"], foct["temp"])
    assert not [m for m in report["warnings"] if "temp moves only" in m]


def test_the_zero_bias_unit_goes_with_the_model_and_another_is_refused(tmp_path, capsys, foct):
    """The model remembers its zero bias's unit: `drift apply` refuses a file in another (a blind check applied a
    model fitted in mA to a log in A: the compensation made the zero bias 900x worse, said by nothing) and the
    firmware header says which unit to feed."""
    def log(name, unit, scale):
        return write_csv(tmp_path / name, {"t": foct["t"], "zero_bias": foct["zero_bias"] * scale, "temp": foct["temp"]},
                         units={"t": "s", "zero_bias": unit, "temp": "C"})
    model = tmp_path / "m.json"
    assert cli.main(["drift", "fit", str(log("ma.csv", "mA", 1e3)), "-o", str(model)]) == 0
    assert json.loads(model.read_text())["unit"] == "mA"
    capsys.readouterr()
    assert cli.main(["drift", "apply", str(model), str(log("a.csv", "A", 1.0)), "-o", str(tmp_path / "o.csv")]) == 2
    err = capsys.readouterr().err
    assert "a.csv: zero_bias is in A, and the drift model" in err and "fitted to a zero bias in mA" in err, err
    assert cli.main(["drift", "apply", str(model), str(log("ma2.csv", "mA", 1e3)), "-o", str(tmp_path / "o.csv")]) == 0
    assert cli.main(["export-c", "--drift", str(model), "-o", str(tmp_path / "d.h")]) == 0
    assert "Unit: f and W - f are in mA" in (tmp_path / "d.h").read_text()


def test_a_zero_bias_a_thousand_times_the_models_drift_is_doubted_when_no_unit_is_stated(tmp_path, capsys, foct):
    """Neither file states a unit: an A model applied to a log in mA printed "drift span 594.5 -> 593.9" and nothing
    else (a blind check). Its zero bias drifting ~1000× as much as the model over the same temperatures is said."""
    def log(name, scale):
        return write_csv(tmp_path / name, {"t": foct["t"], "zero_bias": foct["zero_bias"] * scale,
                                           "temp": foct["temp"]})
    model = tmp_path / "m.json"
    assert cli.main(["drift", "fit", str(log("a.csv", 1.0)), "-o", str(model)]) == 0
    capsys.readouterr()
    # (µA: 10⁶ had been silent, a blind check)
    for name, scale, said in (("same.csv", 1.0, None), ("ma.csv", 1e3, "A and the other in mA"),
                              ("ua.csv", 1e6, "A and the other in µA"), ("x30.csv", 30.0, None)):
        assert cli.main(["drift", "apply", str(model), str(log(name, scale)), "-o", str(tmp_path / "o.csv")]) == 0
        out = capsys.readouterr().out
        assert ("neither file states a unit: one in" in out) == bool(said), out
        assert not said or f"one in {said}" in out and f"off by {scale:g}×" in out, out


def test_drift_apply_names_the_line_of_a_difference_its_model_never_saw(tmp_path, capsys, foct):
    """A difference-regressor model refuses an inside–outside difference beyond what its range was fitted over (a
    blind check's −1.32 A at 20 °C, fitted over −1 … 7 °C, "in range"): drift apply names the file line."""
    outside = foct["temp"] - 3.0 - 0.05 * (foct["temp"] - foct["temp"].mean())
    def log(name, out):
        return write_csv(tmp_path / name, {"t": foct["t"], "zero_bias": foct["zero_bias"], "temp": foct["temp"],
                                           "temp_outside": out}, units={"t": "s", "zero_bias": "A", "temp": "C",
                                                                        "temp_outside": "C"})
    model = tmp_path / "m.json"
    assert cli.main(["drift", "fit", str(log("fit.csv", outside)), "--regressor", "difference", "-o", str(model)]) == 0
    far = outside.copy()
    far[100] = foct["temp"][100] - 25.0
    capsys.readouterr()
    assert cli.main(["drift", "apply", str(model), str(log("far.csv", far)), "-o", str(tmp_path / "o.csv")]) == 2
    err = capsys.readouterr().err
    assert "far.csv, line 104: temp − temp_outside 25 °C" in err and "--outside-range nan" in err, err
    assert cli.main(["drift", "apply", str(model), str(log("far.csv", far)), "-o", str(tmp_path / "o.csv"),
                     "--outside-range", "nan"]) == 0
    assert "1 of" in capsys.readouterr().out


def test_rated_takes_a_unit_and_a_rating_below_the_zero_bias_is_warned(tmp_path, capsys, foct):
    """A blind check's `--rated 1000` beside a zero bias in mA was taken as 1 A (below the zero bias itself), unsaid,
    and `--rated 1000A` was refused as no number. A rating with a unit is converted to the column's; one no larger
    than the zero bias's mean is warned of; the class line names the rating and its unit."""
    path = write_csv(tmp_path / "ma.csv", {"t": foct["t"], "zero_bias": foct["zero_bias"] * 1e3, "temp": foct["temp"]},
                     units={"t": "s", "zero_bias": "mA", "temp": "C"})
    assert np.mean(foct["zero_bias"] * 1e3) > 100.0  # (so that a rating of 100 mA sits below it)
    out = {}
    for rated in ("1000A", "1kA", "1e6", "100"):
        assert cli.main(["drift", "fit", str(path), "-o", str(tmp_path / "m.json"), "--rated", rated]) == 0
        out[rated] = capsys.readouterr().out
    for rated in ("1000A", "1kA", "1e6"):
        assert "class 0.2S at rated 1e+06 mA" in out[rated] and "is no larger than the zero bias" not in out[rated]
        assert out[rated].split("class 0.2S")[1] == out["1e6"].split("class 0.2S")[1]
    assert "warning: --rated 100 mA is no larger than the zero bias itself" in out["100"]
    assert "class 0.2S at rated 100 mA" in out["100"]
    for bad, said in (("1000xyz", "xyz is no current unit"), ("abc", "not a current")):
        assert cli.main(["drift", "fit", str(path), "-o", str(tmp_path / "m.json"), "--rated", bad]) == 2
        assert said in capsys.readouterr().err
    # a column that states no unit: taken in A beside a rating with one, said
    bare = write_csv(tmp_path / "a.csv", {"t": foct["t"], "zero_bias": foct["zero_bias"], "temp": foct["temp"]})
    assert cli.main(["drift", "fit", str(bare), "-o", str(tmp_path / "m.json"), "--rated", "1kA"]) == 0
    said = capsys.readouterr().out
    assert "note: zero_bias states no unit: taken in A beside --rated 1kA" in said and "at rated 1000 A" in said


def test_a_time_column_in_milliseconds_without_a_unit_is_doubted(tmp_path, capsys, foct):
    """A blind check's t in ms with no unit was read as seconds: a thermal lag of 3.5 days and an ageing 1000 times
    too slow, with no word of the time's unit. A unitless time stepping by 100 or more per sample is said, with how
    it was read and the header that states milliseconds; seconds at 1 Hz and a stated unit are not doubted."""
    for name, t, units, doubted in (("ms.csv", foct["t"] * 1e3, {}, True), ("s.csv", foct["t"], {}, False),
                                    ("ms_stated.csv", foct["t"] * 1e3, {"t": "ms"}, False)):
        path = write_csv(tmp_path / name, {"t": t, "zero_bias": foct["zero_bias"], "temp": foct["temp"]}, units=units)
        assert cli.main(["drift", "fit", str(path), "-o", str(tmp_path / "m.json")]) == 0
        out = capsys.readouterr().out
        step = float(np.median(np.diff(foct["t"]))) * 1e3
        assert (f"note: t states no unit and steps by {step:g} per sample: read as seconds" in out) == doubted, out
        if doubted:
            assert "(t [ms])" in out


def test_a_significance_far_above_the_seeds_is_warned(tmp_path, capsys, foct):
    path = write_csv(tmp_path / "a.csv", {"t": foct["t"], "zero_bias": foct["zero_bias"], "temp": foct["temp"]},
                     units={"t": "s"})
    assert cli.main(["drift", "fit", str(path), "-o", str(tmp_path / "m.json"), "--significance", "0.5"]) == 0
    assert "warning: --significance 0.5: the F-test then keeps a power the drift does not have in 50%" in \
        capsys.readouterr().out
    assert cli.main(["drift", "fit", str(path), "-o", str(tmp_path / "m.json"), "--significance", "0.05"]) == 0
    assert "--significance" not in capsys.readouterr().out


def test_apply_of_a_difference_model_to_a_file_without_the_outside_temperature_names_it(tmp_path, capsys, foct):
    fitted = write_csv(tmp_path / "fit.csv", {k: foct[k] for k in ("t", "zero_bias", "temp", "temp_outside")})
    model = tmp_path / "m.json"
    assert cli.main(["drift", "fit", str(fitted), "-o", str(model), "--regressor", "difference"]) == 0
    bare = write_csv(tmp_path / "bare.csv", {k: foct[k] for k in ("t", "zero_bias", "temp")})
    capsys.readouterr()
    assert cli.main(["drift", "apply", str(model), str(bare), "-o", str(tmp_path / "o.csv")]) == 2
    err = capsys.readouterr().err
    assert "bare.csv: no column 'temp_outside'" in err and "--outside-column" in err, err
