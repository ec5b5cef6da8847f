"""Findings of a newcomer's review (B1, W1, M5, M6): each as the review ran it, and what it gives now."""
import dataclasses
import json

import numpy as np
import pytest

import fluxcal
from conftest import run_cli
from fluxcal import drift, read_csv, write_csv
from fluxcal.sim.effects import CANDIDATES
from fluxcal.sim.inject import TIMED
from fluxcal.sim.withheld import withheld_trial

# A drift model over −20 … 50 °C (the segments alone: compensation needs nothing else).
SEGMENTS = [{"range": [-20.0, 0.0], "order": 1, "coefficients": [0.8, 0.05]},
            {"range": [0.0, 50.0], "order": 1, "coefficients": [0.8, -0.03]}]


@pytest.fixture
def model(tmp_path):
    path = tmp_path / "drift.json"
    path.write_text(json.dumps({"kind": "fluxcal drift model", "regressor": "temp", "segments": SEGMENTS,
                                "column": "zero_bias"}))
    return path


def test_drift_apply_with_every_sample_outside_the_range_writes_all_nan_and_says_so(tmp_path, model):
    """B1: every sample at 75 °C against a −20 … 50 °C model exited 2 with "values: empty, no samples to average"
    after writing the output. Now: written, all NaN as --outside-range nan asks, exit 0, a warning on stderr."""
    zero_bias = 0.8 + 0.01 * np.random.default_rng(1).standard_normal(40)
    hot = write_csv(tmp_path / "hot.csv", {"t": np.arange(40.0), "zero_bias": zero_bias, "temp": np.full(40, 75.0)},
                    units={"t": "s", "zero_bias": "A", "temp": "C"})
    out = tmp_path / "out.csv"
    run = run_cli("drift", "apply", model, hot, "-o", out, "--outside-range", "nan")
    assert run.returncode == 0, run.stdout + run.stderr
    assert "no samples to average" not in run.stderr and "error:" not in run.stderr
    assert "every sample (40 of 40) is outside the model's range [-20, 50] °C of its temperature 'temp'" in run.stderr
    assert "(this file's 75 °C)" in run.stderr and "--outside-range nan" in run.stderr
    assert "every value NaN: no sample compensated" in run.stdout
    written = read_csv(out).columns
    assert np.isnan(written["zero_bias_compensated"]).all()
    np.testing.assert_array_equal(written["zero_bias"], zero_bias)  # the input kept as read
    # the default is still an error, and writes nothing
    refused = tmp_path / "refused.csv"
    run = run_cli("drift", "apply", model, hot, "-o", refused)
    assert run.returncode == 2 and "outside every range" in run.stderr and not refused.exists()


def test_drift_apply_with_some_samples_outside_is_unchanged(tmp_path, model):
    """Only some samples outside: compensated as before, the others NaN, the span of those compensated."""
    temp = np.array([10.0, 20.0, 75.0, 30.0, 80.0])
    half = write_csv(tmp_path / "half.csv", {"zero_bias": np.full(5, 0.5), "temp": temp})
    run = run_cli("drift", "apply", model, half, "-o", tmp_path / "out.csv", "--outside-range", "nan")
    assert run.returncode == 0, run.stderr
    assert "warning: 2 of 5 samples" in run.stdout and "drift span" in run.stdout and "every sample" not in run.stderr
    out = read_csv(tmp_path / "out.csv").columns["zero_bias_compensated"]
    np.testing.assert_array_equal(np.isnan(out), [False, False, True, False, True])
    expected = drift.DriftModel.load(model).compensate(np.full(3, 0.5), temp[[0, 1, 3]])
    np.testing.assert_allclose(out[[0, 1, 3]], expected)


def test_drift_apply_with_every_sample_outside_or_missing(tmp_path, model):
    """A sample that is no number and the rest outside: all NaN, both said, no internal error."""
    path = write_csv(tmp_path / "mixed.csv", {"zero_bias": [0.5, np.nan, 0.5], "temp": [70.0, 20.0, 90.0]})
    run = run_cli("drift", "apply", model, path, "-o", tmp_path / "out.csv", "--outside-range", "nan")
    assert run.returncode == 0, run.stdout + run.stderr
    assert "1 of 3 samples of zero_bias are not numbers" in run.stdout
    assert "every sample with a zero_bias reading (2 of 3) is outside" in run.stderr
    assert "(this file's 70 … 90 °C)" in run.stderr
    assert np.isnan(read_csv(tmp_path / "out.csv").columns["zero_bias_compensated"]).all()


def _headerless(tmp_path, columns: int):
    """A comma-separated file of `columns` numbers per line, no header: a sensor turned through every direction
    in the first three columns."""
    rng = np.random.default_rng(5)
    u = rng.standard_normal((300, 3))
    m = 45 * u / np.linalg.norm(u, axis=1, keepdims=True) + [10, 1, -1] + 0.2 * rng.standard_normal((300, 3))
    data = np.column_stack([m] + [np.arange(300.0)] * (columns - 3)) if columns > 3 else m[:, :columns]
    path = tmp_path / f"plain{columns}.txt"
    path.write_text("".join(",".join(f"{v:.4f}" for v in row) + "\n" for row in data))
    return path


def test_three_unnamed_columns_are_never_suggested_as_time_and_an_axis(tmp_path):
    """W1: the error for 3 header-less columns suggested --columns t,mx,my, which made column t both the x axis
    and the time (diagnose then sorted the rows by the x readings). Now it suggests mx,my,mz, which works, and a
    column chosen as an axis whose name makes it the time is an error."""
    plain = _headerless(tmp_path, 3)
    run = run_cli("calibrate", plain)
    assert run.returncode == 2 and "e.g. mx,my,mz)" in run.stderr and "t,mx" not in run.stderr, run.stderr
    run = run_cli("calibrate", plain, "--columns", "mx,my,mz")  # the suggestion, followed
    assert run.returncode == 0, run.stderr
    assert "columns: magnetometer mx,my,mz\n" in run.stdout and "time" not in run.stdout.splitlines()[0]
    for command in ("calibrate", "diagnose"):  # what the old suggestion led to
        run = run_cli(command, plain, "--columns", "t,mx,my")
        assert run.returncode == 2, run.stdout
        assert "column 't' is chosen as a magnetometer axis (t, mx, my) and its name makes it the time as well" \
            in run.stderr and "name them e.g. mx,my,mz" in run.stderr, run.stderr
    # wider files: a time column first, then the axes, then the rest
    assert "e.g. t,mx,my,mz)" in run_cli("calibrate", _headerless(tmp_path, 4)).stderr
    assert "e.g. t,mx,my,mz,c5)" in run_cli("calibrate", _headerless(tmp_path, 5)).stderr
    assert "e.g. mx,my)" in run_cli("calibrate", _headerless(tmp_path, 2)).stderr


def test_a_time_column_is_not_taken_as_an_axis_in_python_either():
    rec = fluxcal.Recording(columns={"time": np.arange(5.0), "a": np.ones(5), "b": np.ones(5), "c": np.ones(5)})
    with pytest.raises(ValueError, match="column 'time' is chosen as a magnetometer axis .* choose three other"):
        rec.select(["time", "a", "b"])
    assert rec.select(["a", "b", "c"]).mag_names() == ("a", "b", "c") and rec.roles()["time"] == "time"


def test_simulate_effects_writes_each_effects_size_with_units(tmp_path):
    """M5: the help promised "the truth in the file's metadata", which held only the effects' names. Now each
    effect's parameters, with units, the noise and the base correction."""
    path = tmp_path / "w.csv"
    run = run_cli("simulate", "-o", path, "--effects", "temp_offset,offset_step", "--seed", 3)
    assert run.returncode == 0, run.stderr
    meta = fluxcal.read_recording(path).metadata
    simulation, _ = withheld_trial(["temp_offset", "offset_step"], seed=3)
    by_name = {e.name: e for e in simulation.effects if e.name}
    text = meta["true_temp_offset"]
    assert text.startswith("beta [") and "] uT/degC, t0 25 degC, lag_s 0 s" in text, text
    beta = np.array(text[text.index("[") + 1:text.index("]")].split(), dtype=float)
    np.testing.assert_allclose(beta, by_name["temp_offset"].beta, rtol=1e-5)
    assert meta["true_offset_step"].startswith("delta [") and " uT, t_on " in meta["true_offset_step"]
    assert meta["true_noise"] == "white, sigma 0.05 uT per axis"
    np.testing.assert_allclose(np.array(meta["true_offset"].split(), dtype=float),
                               simulation.true_calibration().offset, rtol=1e-9)
    assert meta["effects"] == "temp_offset, offset_step"
    help_text = run_cli("simulate", "--help").stdout
    assert "true_<effect>" in " ".join(help_text.split())


def test_every_candidates_parameters_have_a_unit():
    """The truth names every parameter of every candidate with its unit (a new candidate must add its own)."""
    from fluxcal.sim.effects import PARAMETER_UNITS, describe_parameters

    for cls in CANDIDATES:
        assert set(PARAMETER_UNITS[cls.name]) == {f.name for f in dataclasses.fields(cls)}, cls.name
    rng = np.random.default_rng(0)
    for cls in CANDIDATES:
        effect = cls.typical(50.0, rng, 60.0) if cls.name in TIMED else cls.typical(50.0, rng)
        text = describe_parameters(effect, "uT")
        assert text.isascii() and "\n" not in text, text


def test_plain_simulate_writes_no_time_column_and_diagnose_reads_it(tmp_path):
    """M6: plain `simulate` wrote a 50 Hz t column beside readings in independent orientations (README: "not a
    time series"). Now no t column, said when written; calibrate and diagnose read the file as before."""
    path = tmp_path / "sim.csv"
    run = run_cli("simulate", "-o", path, "--n", 300, "--seed", 2)
    assert run.returncode == 0 and "independent orientations (no time column)" in run.stdout, run.stderr
    rec = fluxcal.read_recording(path)
    assert list(rec.columns) == ["mx", "my", "mz"] and rec.time() is None
    assert rec.metadata["field_norm"] == "50000" and "true_offset" in rec.metadata
    run = run_cli("calibrate", path)
    assert run.returncode == 0 and "columns: magnetometer mx,my,mz\n" in run.stdout, run.stderr
    run = run_cli("diagnose", path, "--quiet")
    assert run.returncode == 0 and "not a time series" in run.stdout, run.stdout + run.stderr
    assert "independent orientations, no time column" in " ".join(run_cli("--help").stdout.split())
