"""Session 36 fixes of the drift path: glitches at a log's ends (the running median's mirrored edge), one text for
temperatures outside a model's ranges (the model's and drift apply's), and the ranges' note left out of the
repeated warnings by what the fit did, not by its words (review s35, section 10)."""
import json

import numpy as np
import pytest

import fluxcal
from fluxcal import drift, write_csv
from fluxcal.cli import main


def chamber_temp(n=2000, seed=0):
    """A chamber log: 23 → −20 → 50 → 23 °C ramps and holds, 0.05 °C noise, logged to 0.01 °C."""
    rng = np.random.default_rng(seed)
    k = np.arange(n, dtype=float)
    course = np.interp(k, [0, 200, 500, 800, 1100, 1400, 1700, n], [23, 23, -20, -20, 50, 50, 23, 23])
    return np.round(course + rng.normal(0.0, 0.05, n), 2)


def warm_up(n=2000, tau=3.0, seed=1):
    """A device that warms 23 → 40 °C with a time constant of `tau` samples from its first reading (a slow log
    of a fast warm-up), 0.05 °C noise, logged to 0.01 °C."""
    rng = np.random.default_rng(seed)
    k = np.arange(n, dtype=float)
    return np.round(23.0 + 17.0 * (1.0 - np.exp(-k / tau)) + rng.normal(0.0, 0.05, n), 2)


def cli(capsys, *args):
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


# -- 1: glitches at the very start or end of a log ----------------------------------------------------------------

def test_three_glitches_at_the_start_or_the_end_of_a_log_are_found():
    """Mirrored at the ends, the running median of the first rows was made of the glitches themselves: three 85 °C
    readings at rows 0–2 were not found (they filled 5 of its 7 samples), and at rows 1–3 the genuine row 0 was
    named instead of rows 1 and 2. The ends' median is now of the first (last) 7 samples."""
    temp = chamber_temp()
    assert drift.temperature_glitches(temp).size == 0
    n = temp.size
    for rows in ([0, 1, 2], [1, 2, 3], [2, 3, 4], [n - 3, n - 2, n - 1], [0]):
        glitched = temp.copy()
        glitched[rows] = 85.0
        assert drift.temperature_glitches(glitched).tolist() == rows, rows
    mixed = temp.copy()
    mixed[[0, 1, 2]] = [-127.0, 85.0, 85.0]  # a dropout, then two power-on codes
    assert drift.temperature_glitches(mixed).tolist() == [0, 1, 2]


def test_a_log_that_starts_or_ends_on_a_fast_ramp_is_not_a_glitch():
    """A log that starts on a warm-up ramp (time constant 3 samples: each first step larger than the rest of the
    log's: the session-35 rule named its first row) is no glitch, nor one that ends on the mirror image; glitches
    before such a ramp still are, and the ramp's first row beside them is not (its median, pulled along the ramp by
    them, is taken again without them)."""
    for tau in (3.0, 10.0, 120.0):
        ramp = warm_up(tau=tau)
        assert drift.temperature_glitches(ramp).size == 0, tau
        assert drift.temperature_glitches(ramp[::-1].copy()).size == 0, tau  # a cool-down at the end
    glitched = warm_up(tau=10.0)
    glitched[:3] = 85.0
    assert drift.temperature_glitches(glitched).tolist() == [0, 1, 2]


# -- 2: one text for temperatures outside a model's ranges ---------------------------------------------------------

@pytest.fixture(scope="module")
def linear_model():
    temp = np.linspace(-20.0, 50.0, 1500)
    w = 0.01 * temp + 0.002 * np.random.default_rng(5).standard_normal(temp.size)
    return drift.fit_drift(w, temp)


def test_the_model_and_drift_apply_say_temperatures_outside_its_ranges_alike(tmp_path, linear_model, capsys):
    """DriftModel.evaluate and drift apply each built their own text (the model's had no count and no °C, drift
    apply's another remedy phrase): one function now, the input, its problem and the remedies said alike."""
    lo, hi = linear_model.segments[0]["range"][0], linear_model.segments[-1]["range"][1]
    temp = np.array([20.0, 30.0, 55.0, 40.0, 70.0])
    with pytest.raises(ValueError) as said:
        linear_model.compensate(np.zeros(5), temp)
    lib = str(said.value)
    assert lib.startswith(f"sample 2: temp 55 °C is outside every range of the drift model ({lo:g} … {hi:g} °C; "
                          "2 of 5 samples outside): the polynomials are not extrapolated; pass outside='nan' "
                          "(--outside-range nan) to mark them NaN and compensate the rest, or fit the drift over"), lib
    assert lib == drift.outside_ranges_words(linear_model, temp, "outside='nan' (--outside-range nan)")
    model_path = linear_model.save(tmp_path / "m.json")
    src = write_csv(tmp_path / "hot.csv", {"zero_bias": np.zeros(5), "temp": temp})
    code, _, err = cli(capsys, "drift", "apply", model_path, src, "-o", tmp_path / "out.csv")
    line = next(k for k, text in enumerate(src.read_text().splitlines(), 1) if text.endswith(",55.0"))
    expected = (f"{src}, line {line}: temp 55 °C is outside every range of the drift model {model_path} "
                f"({lo:g} … {hi:g} °C; 2 of 5 samples outside): the polynomials are not extrapolated; pass "
                "--outside-range nan to mark them NaN and compensate the rest, or fit the drift over")
    assert code == 2 and expected in err, err
    within = [lo, hi, lo - 0.005 * (hi - lo)]  # (within the margin)
    assert drift.outside_ranges_words(linear_model, within, "x") is None


def test_a_unit_hint_and_a_missing_zero_bias_are_said_alike(linear_model):
    """The °F hint comes with the model's text too (drift apply's did), and samples that do not count (drift apply:
    no zero-bias reading) are not named."""
    temp = np.array([10.0, 40.0]) * 1.8 + 32.0  # 50, 104: °F numbers of 10 and 40 °C
    said = drift.outside_ranges_words(linear_model, temp, "OPTION")
    assert said.startswith("sample 1: temp 104 °C") and "is it in °F?" in said and "Else: pass OPTION" in said, said
    assert drift.outside_ranges_words(linear_model, temp, "OPTION", counted=[True, False]) is None


# -- 3: the ranges' note told by what the fit did ------------------------------------------------------------------

def adjusted_fit():
    """A cycle to −40 and 70 °C: the default ranges are adjusted to it, which the core notes."""
    temp = np.linspace(-40.0, 70.0, 1500)
    return drift.fit_drift(0.01 * temp + 0.002 * np.random.default_rng(3).standard_normal(temp.size), temp)


def test_a_reworded_range_note_is_still_left_out(monkeypatch):
    """fit_warnings left out the note that the ranges were adjusted by its words ("adjusted to the data:"): the same
    note reworded in the core would have been repeated by drift apply and export-c as a warning on the model."""
    real = drift._core.fit_drift

    def reworded(*args):
        r = real(*args)
        if r["range_note"]:  # (the core's note, reworded)
            said = r["summary"]["warnings"]
            said[said.index(r["range_note"])] = r["range_note"] = "the ranges were moved to cover the samples"
        return r

    monkeypatch.setattr(drift._core, "fit_drift", reworded)
    model = adjusted_fit()
    assert model.summary["warnings"][0] == "the ranges were moved to cover the samples"
    assert drift.fit_warnings(model) == model.summary["warnings"][1:]
    assert model.summary["range_notes"] == ["the ranges were moved to cover the samples"]
    model.summary["fit_warnings"] = ["a warning of the data"]
    assert drift.fit_warnings(model) == ["a warning of the data"] + model.summary["warnings"][1:]
    # ranges as given: no note, nothing left out
    inside = np.linspace(-20.0, 50.0, 1500)
    assert drift.fit_drift(0.01 * inside, inside).summary["range_notes"] == []


def test_the_first_fits_range_note_is_left_out_of_a_refit_to_the_filtered_output():
    """drift_input="filtered": the first fit's warnings are repeated with a prefix; its note on the ranges is a note
    on the ranges there too."""
    rng = np.random.default_rng(8)
    temp = np.r_[np.linspace(-40.0, 70.0, 1500), np.linspace(70.0, -40.0, 1500)]
    w = 0.01 * temp + 0.01 * np.convolve(rng.standard_normal(temp.size + 20), [1, 0.6, 0.3], "same")[10:-10]
    model, report = drift.fit_pipeline(w, temp, drift_input="filtered", ar_max_order=3)
    prefixed = [m for m in report["warnings"] if m.startswith("drift fit to the zero bias: ")]
    assert any("--breakpoints" in m for m in prefixed), report["warnings"]  # (the note, by its words, in the test)
    assert not any("--breakpoints" in m for m in drift.fit_warnings(model)), drift.fit_warnings(model)


def test_models_saved_before_the_notes_were_kept_by_name_still_load_and_leave_them_out(tmp_path):
    """A model saved by session 35's code has no "range_notes": it loads, and fit_warnings leaves out its note by
    the words it had; a model saved now keeps its notes through the round trip."""
    model = adjusted_fit()
    # (the core's note, by its words here only: what fit_drift keeps by name is that note and no other warning)
    assert model.summary["range_notes"] == [w for w in model.summary["warnings"] if "adjusted to the data:" in w] != []
    model.summary["fit_warnings"] = ["temp: a unit hint"]
    path = model.save(tmp_path / "new.json")
    back = drift.DriftModel.load(path)
    assert back.summary["range_notes"] == model.summary["range_notes"] != []
    repeated = ["temp: a unit hint"] + model.summary["warnings"][1:]
    assert drift.fit_warnings(back) == drift.fit_warnings(model) == repeated
    older = json.loads(path.read_text())
    del older["summary"]["range_notes"]  # the layout the code before wrote
    (tmp_path / "old.json").write_text(json.dumps(older))
    old = drift.DriftModel.load(tmp_path / "old.json")
    assert "adjusted to the data:" in old.summary["warnings"][0]
    assert drift.fit_warnings(old) == repeated
    np.testing.assert_array_equal(old.evaluate([0.0, 25.0]), model.evaluate([0.0, 25.0]))


def test_a_held_error_code_or_a_stuck_thermometer_is_refused_by_its_lines(tmp_path, capsys):
    """A DS18B20's 85 °C held through a brown-out (51 samples), −127 °C for 4, or a thermometer stuck on its last
    reading while the chamber moved on (a blind check: 601 samples at 49.99 °C, the top range 0.97 A off, said by
    nothing) hold one value and jump out of it farther than the log ever steps: refused, naming the lines. A chamber's
    plateau logged on a 1/16 °C grid (long runs of one value, left by one step) is no such hold."""
    temp = chamber_temp()
    assert drift.temperature_holds(temp) == []
    for rows, value in ((slice(900, 951), 85.0), (slice(300, 304), -127.0)):
        coded = temp.copy()
        coded[rows] = value
        assert drift.temperature_holds(coded) == [(rows.start, rows.stop - 1)], value
    stuck = temp.copy()
    stuck[1250:1500] = stuck[1249]  # stuck at 50 °C through the 50 → 23 °C ramp
    (first, last), = drift.temperature_holds(stuck)
    assert first <= 1249 and last == 1499
    plateau = np.round(np.interp(np.arange(2000.0), [0, 400, 800, 2000], [23, 23, 40, 40])
                       + np.random.default_rng(3).normal(0, 0.02, 2000), 0) / 1.0  # whole degrees: long runs
    assert drift.temperature_holds(np.round(plateau * 16) / 16) == []
    w = 0.01 * stuck + 0.002 * np.random.default_rng(4).standard_normal(stuck.size)
    path = write_csv(tmp_path / "stuck.csv", {"t": np.arange(stuck.size, dtype=float), "zero_bias": w, "temp": stuck})
    assert main(["drift", "fit", str(path), "-o", str(tmp_path / "m.json")]) == 2
    err = capsys.readouterr().err
    assert "stuck.csv: temp: the temperature holds one value to the last digit" in err and "lines " in err \
        and "a thermometer stuck on its last reading" in err, err


def ar_about_a_drift(seed: int) -> dict:
    """A chamber log: AR(1) 0.7 noise about a linear drift (zero_bias, temp)."""
    temp = chamber_temp()
    rng = np.random.default_rng(seed)
    e = np.zeros(temp.size)
    for i in range(1, temp.size):
        e[i] = 0.7 * e[i - 1] + rng.normal(0, 0.002)
    return {"zero_bias": 0.01 * temp + e, "temp": temp}


def fit_both(tmp_path, capsys, a, b) -> tuple:
    """`drift fit` of files a and b: (b's printed output, a's model, b's model) as JSON."""
    assert main(["drift", "fit", str(a), "-o", str(tmp_path / "a.json")]) == 0
    capsys.readouterr()
    assert main(["drift", "fit", str(b), "-o", str(tmp_path / "b.json")]) == 0
    out = capsys.readouterr().out
    return (out,) + tuple(json.loads((tmp_path / n).read_text()) for n in ("a.json", "b.json"))


def test_shuffled_rows_are_fitted_in_the_order_of_their_times(tmp_path, capsys):
    cols = {"t": np.arange(chamber_temp().size, dtype=float), **ar_about_a_drift(6)}
    ordered = write_csv(tmp_path / "ordered.csv", cols)
    order = np.random.default_rng(6).permutation(cols["t"].size)
    shuffled = write_csv(tmp_path / "shuffled.csv", {k: v[order] for k, v in cols.items()})
    out, a, b = fit_both(tmp_path, capsys, ordered, shuffled)
    assert "rows of " in out and "are out of time order: the samples are taken in the order of their times" in out, out
    assert a["segments"] == b["segments"] and a["ar"] == b["ar"]


def test_a_row_written_a_step_late_is_sorted_not_a_new_stretch(tmp_path, capsys):
    cols = {"t": np.arange(chamber_temp().size, dtype=float), **ar_about_a_drift(7)}
    order = np.arange(cols["t"].size)
    order[[500, 501]] = order[[501, 500]]  # one row a step late (a logger's buffer)
    late = write_csv(tmp_path / "late.csv", {k: v[order] for k, v in cols.items()})
    out, a, b = fit_both(tmp_path, capsys, write_csv(tmp_path / "ordered.csv", cols), late)
    assert "1 of " not in out and "2 of " in out and "are out of time order" in out and "steps back" not in out, out
    assert a["segments"] == b["segments"] and a["ar"] == b["ar"]


@pytest.mark.parametrize("stamp", [0.0, 1e6])
def test_a_lone_bad_time_stamp_is_taken_between_its_neighbours(tmp_path, capsys, stamp):
    """One stamp set to 0 (or far ahead) in a running log had been taken for a restart, half the log shifted (AR(10),
    the ageing 0.6 of itself; a review); sorted, its row moved to the start and the temperature left its course."""
    cols = {"t": np.arange(chamber_temp().size, dtype=float), **ar_about_a_drift(5)}
    glitched = {**cols, "t": cols["t"].copy()}
    glitched["t"][1000] = stamp
    out, a, b = fit_both(tmp_path, capsys, write_csv(tmp_path / "ordered.csv", cols),
                         write_csv(tmp_path / "glitch.csv", glitched))
    assert "1 time stamp(s)" in out and "taken between their neighbours" in out and "steps back" not in out, out
    assert a["segments"] == b["segments"] and a["ar"] == b["ar"]


@pytest.mark.parametrize("back_s", [None, 3600.0])  # a logger restarted at 0; a clock set back an hour
def test_time_that_steps_back_between_stretches_keeps_the_files_order(tmp_path, capsys, back_s):
    """Sorted by time, a restart's two stretches had been interleaved: AR(3)/AR(10) fitted for AR(1) 0.7, exported,
    and `drift apply --filtered` refused the file ("sort the recording"). Now each stretch follows the one before
    after a gap, as the file has them: the same model as the stretches' rows with rising times."""
    cols = ar_about_a_drift(8)
    t = np.arange(cols["temp"].size, dtype=float)
    half = t.size // 2
    logged = t.copy()
    logged[half:] = t[half:] - t[half] if back_s is None else t[half:] - back_s
    rising = t.copy()
    rising[half:] += 10.0  # the gap the fit puts between the stretches
    ordered = write_csv(tmp_path / "ordered.csv", {"t": rising, **cols})
    restarted = write_csv(tmp_path / "restarted.csv", {"t": logged, **cols})
    out, a, b = fit_both(tmp_path, capsys, ordered, restarted)
    assert "steps back 1x (line " in out and "taken in the file's order" in out, out
    assert a["segments"] == b["segments"] and a["ar"] == b["ar"]
    for name in ("a", "b"):
        source = ordered if name == "a" else restarted
        assert main(["drift", "apply", str(tmp_path / f"{name}.json"), str(source), "-o",
                     str(tmp_path / f"{name}_out.csv"), "--filtered"]) == 0
    filtered = [fluxcal.read_recording(tmp_path / f"{n}_out.csv").columns["zero_bias_filtered"] for n in "ab"]
    np.testing.assert_allclose(filtered[1], filtered[0], atol=1e-12)


def test_apply_warns_when_one_side_states_a_unit(tmp_path, linear_model, capsys):
    temp = np.linspace(-10.0, 40.0, 500)
    path = write_csv(tmp_path / "mA.csv", {"zero_bias": 10.0 * temp, "temp": temp}, units={"zero_bias": "mA"})
    model = tmp_path / "m.json"
    linear_model.save(model)  # fitted to numbers with no unit
    assert main(["drift", "apply", str(model), str(path), "-o", str(tmp_path / "out.csv")]) == 0
    out = capsys.readouterr().out
    assert "warning: zero_bias is in mA in" in out and "fitted to one in no unit stated" in out, out


def test_a_current_unit_in_the_zero_bias_name_and_micro_amperes_are_read(tmp_path, capsys):
    """zero_bias_mA had been "states no unit: taken in A" beside --rated 1000A (the class judged 1000x off: 186 % for
    0.186 %), and µA was no current unit ("zero_bias is in µA, not a current")."""
    temp = chamber_temp()
    rng = np.random.default_rng(9)
    zero_ma = 2.0 + 0.05 * temp + rng.normal(0, 0.5, temp.size)  # mA
    t = np.arange(temp.size, dtype=float)
    files = {"header_mA": ({"t": t, "zero_bias": zero_ma, "temp": temp}, {"zero_bias": "mA"}, "zero_bias"),
             "name_mA": ({"t": t, "zero_bias_mA": zero_ma, "temp": temp}, {}, "zero_bias_mA"),
             "name_uA": ({"t": t, "zero_bias_uA": 1e3 * zero_ma, "temp": temp}, {}, "zero_bias_uA"),
             "header_µA": ({"t": t, "zero_bias": 1e3 * zero_ma, "temp": temp}, {"zero_bias": "µA"}, "zero_bias")}
    classes = {}
    for name, (cols, units, column) in files.items():
        path = write_csv(tmp_path / f"{name}.csv", cols, units=units)
        assert main(["drift", "fit", str(path), "--column", column, "--rated", "1000A",
                     "-o", str(tmp_path / f"{name}.json")]) == 0, name
        out = capsys.readouterr().out
        assert "states no unit" not in out, (name, out)
        classes[name] = [line.split(" at rated ")[1].split(" ", 2)[2] for line in out.splitlines()
                         if line.strip().startswith("class ")]
    assert classes["header_mA"] and all(c == classes["header_mA"] for c in classes.values()), classes


def test_a_log_too_short_for_the_stationarity_test_names_the_zero_bias():
    # (had been "series: 30 samples, need at least 42 for the stationarity test on 20 sub-series")
    temp = np.linspace(-10.0, 40.0, 30)
    with pytest.raises(ValueError, match=r"^zero_bias: 30 samples.*stationarity test.*`subseries`.*operating range"):
        drift.fit_pipeline(0.01 * temp + np.random.default_rng(0).normal(0, 1e-3, 30), temp)
