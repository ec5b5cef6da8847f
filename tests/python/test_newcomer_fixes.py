"""Findings of a newcomer's review (B1, W1, M5, M6; then M1, M4, C2, C5, C6, C10, C12): each as the review ran it,
and what it gives now."""
import dataclasses
import json
import re
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import fluxcal
from conftest import REPO, run_cli
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


# ---- a second round of the newcomer's findings: M1, M4, C2, C5, C6, C10, C12 ----

def _smooth_turn(tmp_path, drift: float, name: str):
    """A minute of a sensor turned smoothly at 50 Hz (readings in time order, σ 0.05 µT), with a slow offset drift
    of `drift` µT that no calibration models."""
    rng = np.random.default_rng(3)
    t = np.arange(3000) / 50.0
    yaw, pitch = 2 * np.pi * t / 20, 1.4 * np.sin(2 * np.pi * t / 13)
    u = np.column_stack([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)])
    W = np.array([[1.08, 0.05, -0.02], [0.05, 0.95, 0.03], [-0.02, 0.03, 1.01]])
    m = 50 * u @ W.T + [12.0, -7.0, 3.0] + drift * np.sin(2 * np.pi * t / 60)[:, None] + rng.normal(0, 0.05, (3000, 3))
    return write_csv(tmp_path / name, {"t": t, "mx": m[:, 0], "my": m[:, 1], "mz": m[:, 2]},
                     units={"t": "s", "mx": "uT", "my": "uT", "mz": "uT"})


def _line(stdout: str, label: str) -> str:
    return next(line for line in stdout.splitlines() if line.startswith(f"  {label}"))


def test_calibrate_names_the_residual_sigma_and_gives_the_readings_own_noise_beside_it(tmp_path):
    """M1: "noise σ (estimated)" was the residual σ, misfit included (airborne 68 nT against 0.42 nT from the readings'
    differences). Now labelled as the residual σ; for readings in time order the third-difference σ (diagnose's) is
    printed beside it, with the ratio, and a ratio far above 1 says the model misses something."""
    run = run_cli("calibrate", _smooth_turn(tmp_path, 2.0, "drift.csv"))
    assert run.returncode in (0, 3), run.stderr
    assert "noise σ (estimated)" not in run.stdout
    residual = _line(run.stdout, "residual σ")
    assert "(from the fit's residuals: the noise plus whatever the model misses)" in residual
    assert float(residual.split()[2]) > 1.0  # the drift, not the 0.05 µT noise
    noise = _line(run.stdout, "noise σ, differences")
    assert 0.045 < float(noise.split()[3]) < 0.055, noise  # the simulated σ
    assert "third differences in time order of the fit's residuals" in noise
    assert "the model misses more than the noise (fluxcal diagnose names what)" in noise
    # without the drift the two agree, and nothing is said to be missing
    run = run_cli("calibrate", _smooth_turn(tmp_path, 0.0, "clean.csv"))
    noise = _line(run.stdout, "noise σ, differences")
    assert "the residual σ is 1.0" in noise and "misses" not in noise, noise
    # independent orientations (fluxcal simulate): differences measure the turning, not the noise: no such line
    sim_path = tmp_path / "sim.csv"
    run_cli("simulate", "-o", sim_path, "--n", 600, "--seed", 1)
    run = run_cli("calibrate", sim_path)
    assert "residual σ" in run.stdout and "noise σ, differences" not in run.stdout, run.stdout


def _sheared(tmp_path):
    """600 readings over the whole sphere of a sensor with soft iron off the diagonal (conftest.simulated seed 3):
    the data reject the sphere and diag shapes, whose refinements the solver also calls undetermined."""
    from conftest import simulated

    m = simulated(3, n=600).readings
    return write_csv(tmp_path / "sheared.csv", {"mx": m[:, 0], "my": m[:, 1], "mz": m[:, 2]},
                     units={k: "nT" for k in ("mx", "my", "mz")}), m


def test_shapes_the_data_reject_are_labelled_rejected_not_undetermined(tmp_path):
    """M4: on full-sphere data the shape line read "diag 1774.3 (undetermined)" for a shape the data reject by
    thousands in BIC. Now "(rejected by BIC: +N)"; "(not determined by the data)" is kept for a shape within
    REJECTED_BIC of the lowest that the data do not determine."""
    path, _ = _sheared(tmp_path)
    run = run_cli("calibrate", path)
    assert run.returncode == 0, run.stderr
    line = _line(run.stdout, "shape")
    assert "(undetermined)" not in line and "not determined" not in line, line
    assert re.search(r"sphere -?[\d.]+ \(rejected by BIC: \+\d+\), diag -?[\d.]+ \(rejected by BIC: \+\d+\), sym "
                     r"-?[\d.]+\)$", line), line
    from fluxcal.cli import _shape_scores

    table = {"sphere": {"bic": 100.0, "identifiable": True}, "diag": {"bic": 104.0, "identifiable": False},
             "sym": {"bic": 130.0, "identifiable": False}, "eye": {"error": "no"}}
    assert _shape_scores(table) == ("sphere 100.0, diag 104.0 (not determined by the data), sym 130.0 (rejected by "
                                    "BIC: +30), eye failed")


def test_a_rejected_forced_shape_is_not_sent_to_check_reference_vectors(tmp_path):
    """M4: calibrate(rec, shape="diag") on those data said "check the reference vectors' attitude convention and
    time alignment" — a magnitude fit has none. The refinement now gives a magnitude fit's causes (beside the
    forced shape's own warning that the data reject it); the choice is unchanged."""
    path, m = _sheared(tmp_path)
    cal = fluxcal.calibrate(m, shape="diag")
    text = " ".join(cal.summary["warnings"])
    assert "reference vectors" not in text and "attitude convention" not in text, text
    assert "because the residuals are" in text and "check for outliers or a disturbance" in text, text
    assert "the data reject shape 'diag'" in text and cal.summary["shape"] == "diag"
    assert cal.summary["identifiable"] is False  # as before: only the words changed
    run = run_cli("calibrate", path, "--shape", "diag")
    assert run.returncode == 3 and "the data reject shape 'diag'" in run.stdout
    assert "reference vectors' attitude" not in run.stdout


def test_a_magnitude_fit_that_misfits_names_a_magnitude_fits_causes():
    """The same misfit warning on the shape `auto` keeps: outliers or a disturbance, not reference vectors."""
    rng = np.random.default_rng(2)
    u = rng.normal(size=(60, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    m = 50 * u + [5, -3, 2] + rng.normal(0, 2.5, (60, 3))  # 5 % of the field: no sensor's noise
    cal = fluxcal.calibrate(m, outliers="keep")
    text = " ".join(cal.summary["warnings"])
    assert "far above a sensor's noise: the readings do not fit the model — check for outliers or a disturbance" \
        in text and "reference vectors" not in text, text


def test_print_of_a_diagnosis_is_its_report_and_its_repr_is_short(tmp_path):
    """C2: print(d) dumped a 28 000-character dataclass repr; d.text() was in no README example. Now str(d) is
    the report, repr(d) one line saying how to get it, for the cable ring's diagnosis too."""
    from fluxcal.diagnose.cable import CableDiagnosis

    path = tmp_path / "trial.csv"
    run_cli("simulate", "-o", path, "--effects", "temp_offset", "--seed", 1)
    d = fluxcal.diagnose(fluxcal.read_recording(path), progress=False)
    assert str(d) == d.text() and str(d).startswith("fluxcal diagnose — ")
    assert repr(d).startswith(f"<Diagnosis of {str(path)!r}, model ellipsoid: ") and len(repr(d)) < 300, repr(d)
    assert "print(d) or d.text() for the report>" in repr(d) and "temp_offset" in repr(d)
    ring = CableDiagnosis(model="cable_ring", noise_sigma=1.5e-8, noise_source="", units="T", source="ring.csv",
                          ranking=[], accepted=[], where={}, remaining={}, base=None)
    assert repr(ring) == ("<CableDiagnosis of 'ring.csv', model cable_ring: no significant effect; noise σ 1.5e-08 T "
                          "— print(d) or d.text() for the report>")
    readme = (REPO / "README.md").read_text()
    assert "print(d)" in readme and "d.text()" in readme


def test_batch_says_which_files_its_pattern_left_out(tmp_path):
    """C5: `fluxcal batch` took only the default *.csv and said nothing of a .tsv beside it ("units 1"). Now the
    files left out are counted by extension with the --pattern that takes them; with none matching, the error
    says what the folder holds."""
    from fluxcal.batch import calibrate_unit

    folder, out = tmp_path / "fleet", tmp_path / "out"
    folder.mkdir()
    out.mkdir()
    m = fluxcal.sim.simulate(fluxcal.sim.uniform(300, np.random.default_rng(0)),
                             fluxcal.sim.random_sensor(50.0, np.random.default_rng(0), noise=0.005),
                             np.array([20.0, 0.0, 45.8]), np.random.default_rng(1)).readings
    columns = {"mx": m[:, 0], "my": m[:, 1], "mz": m[:, 2]}
    write_csv(folder / "unit_a.csv", columns, units={k: "uT" for k in columns})
    write_csv(folder / "unit_b.tsv", columns, units={k: "uT" for k in columns}, delimiter="\t")
    (folder / "unit_b_info.txt").write_text("where unit b was turned\n")
    (folder / ".hidden").write_text("")
    # unit_a already calibrated as the batch would (same bytes, same settings): the run starts no cluster
    assert calibrate_unit(folder / "unit_a.csv", out / "unit_a.json")["status"] == "ok"
    run = run_cli("batch", folder, "-o", out, "--no-progress")
    assert run.returncode == 0, run.stdout + run.stderr
    assert "units 1: 1 ok" in run.stdout
    assert ("note: 2 files of the folder do not match --pattern '*.csv' and were left out (1 .tsv, 1 .txt); to "
            "calibrate them: --pattern '*.tsv' or '*.txt' for those alone, or --pattern '*' for every file") \
        in run.stdout, run.stdout
    run = run_cli("batch", folder, "-o", out, "--pattern", "*.dat", "--no-progress")
    assert run.returncode == 2
    assert ("no recordings matching '*.dat'; the folder holds 1 .csv, 1 .tsv, 1 .txt files; to calibrate them: "
            "--pattern '*.csv' or '*.tsv' or '*.txt' for those alone") in run.stderr, run.stderr


def _readme_block(after: str, lang: str) -> str:
    """The first ```lang block after the text `after` in the README."""
    text = (REPO / "README.md").read_text()
    start = text.index(f"```{lang}\n", text.index(after)) + len(lang) + 4
    return text[start:text.index("```", start)]


def _run_readme_commands(block: str, cwd) -> list:
    """Each `fluxcal …` line of a README block, comments cut, run as written in `cwd`."""
    runs = []
    for line in block.splitlines():
        words = shlex.split(line, comments=True)
        if not words:
            continue
        assert words[0] == "fluxcal", line
        run = run_cli(*words[1:], cwd=cwd)
        assert run.returncode == 0, f"{line}\n{run.stdout}\n{run.stderr}"
        runs.append(run)
    return runs


@pytest.fixture
def source_on_path(monkeypatch):
    """The commands run in another folder import this fluxcal (PYTHONPATH=python is relative to the clone)."""
    monkeypatch.setenv("PYTHONPATH", str(Path(fluxcal.__file__).resolve().parents[1]))


def test_the_readme_quick_start_runs_as_written(tmp_path, source_on_path):
    """C12: the only quick start was `make demo` (root). The README's Quick start: its commands and its Python,
    run in an empty folder as a user with the wheel would."""
    runs = _run_readme_commands(_readme_block("## Quick start", "sh"), tmp_path)
    assert len(runs) == 5 and (tmp_path / "demo" / "demo_before_after.png").is_file()
    assert (tmp_path / "cal.png").is_file() and "hx" in fluxcal.read_recording(tmp_path / "corrected.csv").columns
    code = _readme_block("## Quick start", "python")
    run = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0 and "refine: h = A (m - b)" in run.stdout, run.stderr


def test_the_readme_cable_example_runs_as_written(tmp_path, source_on_path):
    """C6: `cable simulate -o ring.csv` made one snapshot, too few for `diagnose --model cable`. The README's ring
    example, run as written: eight snapshots, solved and diagnosed."""
    runs = _run_readme_commands(_readme_block("A cable ring end to end", "sh"), tmp_path)
    assert "wrote ring.csv: 8 snapshots of 4 sensors" in runs[2].stdout
    assert runs[3].stdout.count("snapshot ") == 8 and "fluxcal diagnose — ring.csv: cable ring, 8 snapshots" \
        in runs[4].stdout


def _still_start(tmp_path, still: int, seed: int, name: str):
    """A sensor left still for `still` readings, then 3000 readings over the whole sphere (σ 0.25 µT)."""
    rng = np.random.default_rng(seed)
    W = np.array([[1.1, 0.03, 0.0], [0.03, 0.95, -0.02], [0.0, -0.02, 1.02]])
    u = rng.normal(size=(3000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    m = 50 * np.vstack([np.repeat(u[:1], still, axis=0), u]) @ W.T + [20.0, -10.0, 5.0] \
        + rng.normal(0, 0.25, (still + 3000, 3))
    return write_csv(tmp_path / name, dict(zip(("mx", "my", "mz"), m.T)), units={k: "uT" for k in ("mx", "my", "mz")})


def test_the_held_out_check_says_why_a_still_start_leaves_it_nothing_to_judge(tmp_path):
    """C10: a recording that starts still printed "— (the first half alone cannot be fitted: …)" or a spread of
    156 % with no reason, while the whole fit was good. Now the line says the first half alone does not determine
    the fit, with the directions it and the whole recording cover."""
    run = run_cli("calibrate", _still_start(tmp_path, 2990, 0, "still.csv"))
    assert run.returncode == 0, run.stderr
    line = _line(run.stdout, "held-out |h| std/mean")
    assert re.search(r"—   \(the first half alone does not determine the fit: its readings cover \d % of the field "
                     r"directions, the whole recording's 100 % \(still, or turned little, at the start\?\), and its own "
                     r"fit fails \(samples: .*\); the whole fit is judged by the lines above\)$", line), line
    from fluxcal.cli import _held_out_spread

    m = fluxcal.read_recording(_still_start(tmp_path, 2980, 1, "little.csv")).samples()
    cal = fluxcal.calibrate(m)
    spread, note = _held_out_spread(m, cal, None, {})
    assert spread > 2 * cal.summary["norm_std_over_mean"], spread  # the first half's fit is the poorer one
    assert note.startswith("the first half alone does not determine the fit"), note
    # a first half that turned as much as the rest: a number, and no excuse for it
    m = fluxcal.read_recording(_still_start(tmp_path, 1000, 1, "turned.csv")).samples()
    cal = fluxcal.calibrate(m)
    spread, note = _held_out_spread(m, cal, None, {})
    assert spread < 1.5 * cal.summary["norm_std_over_mean"] and note == ""


def test_a_source_tree_without_the_built_core_says_so(tmp_path):
    """A blind check ran the CLI from the source tree before the C++ core was copied there: Python's own message
    blamed "a circular import". It names the missing module and how to get it."""
    import shutil

    package = Path(fluxcal.__file__).parent
    shutil.copytree(package, tmp_path / "fluxcal", ignore=shutil.ignore_patterns("_core*.so", "__pycache__"))
    out = subprocess.run([sys.executable, "-c", "import fluxcal"], capture_output=True, text=True,
                         env={"PYTHONPATH": str(tmp_path), "PATH": "/usr/bin:/bin"}, cwd=tmp_path)
    assert out.returncode == 1 and "circular import" not in out.stderr, out.stderr
    assert f"no _core*.so in {tmp_path / 'fluxcal'}" in out.stderr and "pip install ." in out.stderr, out.stderr
