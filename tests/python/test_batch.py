"""Fleet calibration on a Dask cluster of two worker processes: 200 simulated units, some broken, some
outliers; every good unit recovers its simulated truth, failures are named, outliers flagged, re-runs
skip what is done."""
import csv
import json
import logging
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest

from fluxcal import Calibration, sim, write_csv
from fluxcal.batch import calibrate_fleet, fleet_statistics

H = 50000.0         # field norm, nT
N = 300             # readings per unit: enough for a 9-parameter fit, small enough to keep the test fast
NOISE = 0.005       # white noise, fraction of H (250 nT)
MAG_UNITS = {"mx": "nT", "my": "nT", "mz": "nT"}
OUTLIERS = {"big_offset": "offset", "double_gain": "scale", "noisy": "noise"}
BROKEN = {"truncated": r"line \d+: 2 fields, the header has 4",
          "has_nan": r"line \d+, column 'my' is nan",
          "planar": r"lie in one plane: axis z reads"}


def _unit(seed, scene="uniform", gain=1.0, extra_offset=(0.0, 0.0, 0.0), noise=NOISE):
    """A unit of one sensor model (soft iron ±5 %, offset ≤ 10 % of H), turned in a random field direction."""
    rng = np.random.default_rng(seed)
    direction = rng.standard_normal(3)
    field = H * direction / np.linalg.norm(direction)
    soft, hard, _ = sim.random_sensor(H, rng, soft_iron=0.05, offset=0.1)
    effects = [sim.SoftIron(gain * soft.matrix), sim.HardIron(hard.offset + np.asarray(extra_offset)),
               sim.WhiteNoise(noise * H)]
    motion = sim.uniform(N, rng) if scene == "uniform" else sim.sweeps("z", per_turn=N, tilt_deg=5.0, rng=rng)
    return sim.simulate(motion, effects, field, rng)


def _write(path, readings, t):
    write_csv(path, {"t": t, "mx": readings[:, 0], "my": readings[:, 1], "mz": readings[:, 2]}, units=MAG_UNITS)


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """200 recordings: 193 normal units, 3 outliers, 3 broken files, 1 turned about one axis only.
    Returns (folder, {unit: (simulation, noise fraction)}) for the units that can be calibrated."""
    folder = tmp_path_factory.mktemp("fleet")
    truth = {}
    for i in range(193):
        truth[f"unit_{i:03d}"] = (_unit(i), NOISE)
    truth["big_offset"] = (_unit(1001, extra_offset=(2 * H, 0.0, 0.0)), NOISE)
    truth["double_gain"] = (_unit(1002, gain=2.0), NOISE)
    truth["noisy"] = (_unit(1003, noise=10 * NOISE), 10 * NOISE)
    for name, (s, _) in truth.items():
        _write(folder / f"{name}.csv", s.readings, s.t)
    _write(folder / "yaw_only.csv", _unit(1004, scene="yaw").readings, np.arange(N) / 50.0)

    good = _unit(1005)
    _write(folder / "truncated.csv", good.readings, good.t)
    text = (folder / "truncated.csv").read_text().splitlines()
    text[100] = ",".join(text[100].split(",")[:2])  # a line cut short, as by a logger losing power
    (folder / "truncated.csv").write_text("\n".join(text) + "\n")
    with_nan = good.readings.copy()
    with_nan[57, 1] = np.nan
    _write(folder / "has_nan.csv", with_nan, good.t)
    flat = good.readings.copy()
    flat[:, 2] = 1234.0  # the board was only turned flat on the bench
    _write(folder / "planar.csv", flat, good.t)
    return folder, truth


@pytest.fixture(scope="module")
def cluster():
    """One local Dask cluster of two single-threaded worker processes for the whole module."""
    from dask.distributed import LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None, silence_logs=logging.ERROR) as c:
        yield c


@pytest.fixture(scope="module")
def first_run(fleet, cluster, tmp_path_factory):
    folder, _ = fleet
    out = tmp_path_factory.mktemp("calibrations")
    result = calibrate_fleet(folder, out, scheduler=cluster.scheduler_address, field_norm=H, progress=False)
    return out, result


def test_every_good_unit_recovers_its_simulated_truth(fleet, first_run):
    folder, truth = fleet
    out, result = first_run
    assert result.workers == 2 and result.calibrated == 200 and result.skipped == 0
    for name, (s, noise) in truth.items():
        cal = Calibration.load(out / f"{name}.json")
        true = s.true_calibration()
        # Offset error per axis ≈ σ·√(3/N) (25 nT here; measured 24–26 nT over 300 seeded units): 6× that.
        # Matrix entries ≈ 1.4·(σ/H)·√(3/N) (measured 5.6–7.4e-4): 10·(σ/H)·√(3/N) is ≥ 7 of those.
        sigma = noise * H
        np.testing.assert_allclose(cal.offset, true.offset, rtol=0, atol=6 * sigma * np.sqrt(3 / N), err_msg=name)
        np.testing.assert_allclose(cal.matrix, true.matrix, rtol=0, atol=10 * noise * np.sqrt(3 / N), err_msg=name)
        assert cal.units == "nT" and cal.field_norm == H
        assert cal.metadata["source"] == str(folder / f"{name}.csv") and len(cal.metadata["source_sha256"]) == 64
    rows = {r["unit"]: r for r in result.rows}
    assert rows["double_gain"]["scale_3"] > 1.8  # every gain about doubled (2 × (1 ± 5 %))
    assert rows["yaw_only"]["status"] == "not_identifiable" and "coverage" in rows["yaw_only"]["warnings"]
    assert not list(out.glob(".*.tmp")), "atomic writes leave no temporary files behind"


def test_broken_units_are_reported_with_file_and_problem(fleet, first_run):
    folder, _ = fleet
    out, result = first_run
    failures = json.loads((out / "failures.json").read_text())
    assert sorted(f["unit"] for f in failures) == sorted(BROKEN)
    for f in failures:
        assert str(folder / f"{f['unit']}.csv") in f["error"]
        assert re.search(BROKEN[f["unit"]], f["error"]), f["error"]
        assert not (out / f"{f['unit']}.json").exists()
    counts = result.summary["counts"]
    assert counts == {**counts, "units": 200, "ok": 196, "not_identifiable": 1, "failed": 3}
    assert "3 failed" in result.report() and "line 61, column 'my' is nan" in result.report()


def test_outliers_flagged_with_reason_and_nothing_else(first_run):
    out, result = first_run
    summary = json.loads((out / "fleet_summary.json").read_text())
    flagged = {}
    for o in summary["outliers"]:
        flagged.setdefault(o["unit"], set()).add(o["quantity"])
        assert "robust σ" in o["reason"] and abs(o["deviation_sigmas"]) > 5
    assert set(flagged) == set(OUTLIERS), "exactly the outlier units: none of the 193 normal ones"
    assert {"offset_x", "offset_norm"} <= flagged["big_offset"]
    assert {"scale_1", "scale_2", "scale_3"} <= flagged["double_gain"]
    assert {"norm_std_over_mean", "residual_rms"} <= flagged["noisy"]
    # The distribution is that of the sensor model: gains 1 ± 5 %, residual spread ≈ the 0.5 % noise.
    dist = summary["distribution"]
    assert 0.95 < dist["scale_2"]["median"] < 1.05 and dist["scale_2"]["n"] == 196
    assert dist["norm_std_over_mean"]["median"] == pytest.approx(NOISE, rel=0.1)
    assert summary["fleet_units"] == "nT" and summary["settings"]["outlier_k"] == 5.0


def test_summary_csv_has_one_row_per_unit(first_run):
    out, _ = first_run
    with (out / "fleet_summary.csv").open() as f:
        rows = {r["unit"]: r for r in csv.DictReader(f)}
    assert len(rows) == 200
    assert rows["big_offset"]["outlier"].startswith("offset_x") and rows["unit_000"]["outlier"] == ""
    assert float(rows["big_offset"]["offset_x"]) == pytest.approx(2 * H, rel=0.1)
    assert rows["planar"]["status"] == "failed" and "one plane" in rows["planar"]["error"]
    assert rows["unit_000"]["status"] == "ok" and rows["unit_000"]["method"] == "als+refine"
    assert rows["unit_000"]["shape"] in ("sphere", "diag", "sym") and rows["planar"]["shape"] == ""
    assert float(rows["unit_000"]["direction_coverage"]) > 0.8
    # the held-out check calibrate prints: fitted on the first half, |h|'s spread on the second — about the noise
    # over the field (σ/H), a little above the whole fit's own; the noisy unit's ten times it
    spreads = np.array([float(r["held_out_spread"]) for u, r in rows.items() if u.startswith("unit_")])
    whole = np.array([float(r["norm_std_over_mean"]) for u, r in rows.items() if u.startswith("unit_")])
    assert 0.9 * NOISE < np.median(spreads) < 1.2 * NOISE and np.median(spreads / whole) > 1.0, np.median(spreads)
    assert float(rows["noisy"]["held_out_spread"]) > 8 * NOISE and rows["unit_000"]["held_out_rms"] == ""
    assert rows["planar"]["held_out_spread"] == ""
    summary = json.loads((out / "fleet_summary.json").read_text())
    assert summary["distribution"]["held_out_spread"]["n"] == 196 and "held_out_rms" not in summary["distribution"]
    assert "second half" in summary["definitions"]["held_out_spread"]


def test_rerun_skips_every_unit_already_done(first_run, cluster, tmp_path):
    out, first = first_run
    again = tmp_path / "again"
    shutil.copytree(out, again)
    before = {p.name: p.stat().st_mtime_ns for p in again.glob("unit_*.json")}
    result = calibrate_fleet(first.directory, again, scheduler=cluster.scheduler_address, field_norm=H, progress=False)
    assert result.skipped == 197 and result.calibrated == 3  # only the broken files are tried again
    assert {p.name: p.stat().st_mtime_ns for p in again.glob("unit_*.json")} == before
    assert [r["unit"] for r in result.rows] == [r["unit"] for r in first.rows]
    assert result.summary["distribution"] == first.summary["distribution"]
    assert result.summary["outliers"] == first.summary["outliers"]
    assert "197 skipped (already done)" in result.report()


def test_changed_recording_corrupt_json_or_new_settings_are_redone(cluster, tmp_path):
    folder = tmp_path / "recordings"
    folder.mkdir()
    for i in range(6):
        s = _unit(2000 + i)
        _write(folder / f"u{i}.csv", s.readings, s.t)
    out = tmp_path / "out"
    calibrate_fleet(folder, out, scheduler=cluster.scheduler_address, field_norm=H, progress=False)
    s = _unit(3000)
    _write(folder / "u0.csv", s.readings, s.t)               # the unit was recorded again
    (out / "u1.json").write_text('{"offset": [1, 2')           # a calibration file damaged by hand
    result = calibrate_fleet(folder, out, scheduler=cluster.scheduler_address, field_norm=H, progress=False)
    c = result.summary["counts"]
    assert (c["skipped"], c["recalibrated_stale"], c["recalibrated_invalid"]) == (4, 1, 1)
    np.testing.assert_allclose(Calibration.load(out / "u0.json").offset, s.true_calibration().offset, atol=150)
    assert Calibration.load(out / "u1.json").summary["samples"] == N
    result = calibrate_fleet(folder, out, scheduler=cluster.scheduler_address, field_norm=None, progress=False)
    assert result.summary["counts"]["recalibrated_stale"] == 6  # another field norm is another calibration


def test_fleet_statistics_rules():
    rows = [{"unit": f"u{i}", "status": "ok", "units": "uT", **{q: 1.0 for q in
             ("offset_x", "offset_y", "offset_z", "offset_norm", "scale_1", "scale_2", "scale_3", "field_norm",
              "norm_std_over_mean", "residual_rms", "direction_coverage")}} for i in range(8)]
    for i, r in enumerate(rows):
        r["offset_x"] = 1.0 + 0.01 * i
    rows[3]["offset_x"] = 9.0
    rows[5]["units"] = "nT"
    rows.append({"unit": "bad", "status": "failed", "units": ""})
    dist, outliers = fleet_statistics(rows, outlier_k=5.0)
    reasons = {(o["unit"], o["quantity"]) for o in outliers}
    assert reasons == {("u3", "offset_x"), ("u5", "units")}  # identical values (MAD 0, no spread) flag nothing
    assert dist["offset_x"]["n"] == 7 and dist["field_norm"]["robust_sigma"] == 0
    # a tie between two units is said, not passed off as the fleet's units (the first in order is taken)
    tied = [{"unit": f"u{i}", "status": "ok", "units": "nT" if i < 2 else "uT", "offset_x": 1.0} for i in range(4)]
    said = [o["reason"] for o in fleet_statistics(tied)[1]]
    assert said == ["readings in uT, left out of the distributions: the fleet's units tie (nT 2, uT 2) and the "
                    "distributions are of those in nT, the first in order"] * 2, said


def _batch_cli(*args):
    return subprocess.run([sys.executable, "-m", "fluxcal", "batch", *map(str, args)], capture_output=True, text=True,
                          stdin=subprocess.DEVNULL, timeout=120)


def test_cli_runs_a_local_cluster_and_exits_0_with_failed_units(tmp_path):
    folder = tmp_path / "recordings"
    folder.mkdir()
    truth = {}
    for i in range(5):
        truth[f"u{i}"] = _unit(4000 + i)
        _write(folder / f"u{i}.csv", truth[f"u{i}"].readings, truth[f"u{i}"].t)
    (folder / "cut.csv").write_text("mx,my,mz\n1,2,3\n4,5\n")
    r = _batch_cli(folder, "-o", tmp_path / "out", "--workers", 2, "--field-norm", H, "--no-progress")
    assert r.returncode == 0, r.stderr
    assert "units 6: 5 ok, 0 not identifiable, 1 failed" in r.stdout and "on 2 workers" in r.stdout
    assert f"{folder / 'cut.csv'}, line 3: 2 fields" in r.stdout and "note: 1 of 6 units failed" in r.stdout
    assert "; 5 of 6 units: those ok in these units)" in r.stdout  # whom the statistics cover (a blind check)
    for name, s in truth.items():
        np.testing.assert_allclose(Calibration.load(tmp_path / "out" / f"{name}.json").offset,
                                   s.true_calibration().offset, atol=6 * NOISE * H * np.sqrt(3 / N))
    assert (tmp_path / "out" / "fleet_summary.csv").exists() and (tmp_path / "out" / "fleet_summary.json").exists()
    # --bad-lines skip reaches the reader: the cut line is left out (3 rows cannot be calibrated, a new error);
    # when every unit fails nothing was calibrated, and the exit status says so
    only_cut = tmp_path / "cut_only"
    only_cut.mkdir()
    (only_cut / "cut.csv").write_text("mx,my,mz\n1,2,3\n4,5\n1,2,4\n")
    r = _batch_cli(only_cut, "-o", tmp_path / "out2", "--workers", 1, "--no-progress")
    assert r.returncode == 1 and "all 1 units failed; nothing was calibrated" in r.stdout, r.stdout + r.stderr
    r = _batch_cli(only_cut, "-o", tmp_path / "out3", "--workers", 1, "--no-progress", "--bad-lines", "skip")
    assert r.returncode == 1 and "2 fields" not in r.stdout, r.stdout
    # a fleet whose only unit was turned about one axis: calibrated, but nothing usable (calibrate exits 3)
    yaw = tmp_path / "yaw_only"
    yaw.mkdir()
    _write(yaw / "y.csv", _unit(1004, scene="yaw").readings, np.arange(N) / 50.0)
    r = _batch_cli(yaw, "-o", tmp_path / "out4", "--workers", 1, "--field-norm", H, "--no-progress")
    assert r.returncode == 1 and "no unit gave a usable calibration (1 not identifiable)" in r.stdout, r.stdout


@pytest.mark.parametrize("make, args, message", [
    (None, (), "no such directory"),
    ("file", (), "a file, not a folder of recordings"),
    ("empty", (), "no recordings matching '*.csv'"),
    ("empty", ("--workers", 0), "--workers: 0 is not a positive whole number"),
    ("empty", ("--method", "vector"), "invalid choice"),
    ("empty", ("--method", "twostep"), "method 'twostep' needs the known field magnitude"),
])
def test_cli_bad_arguments_exit_2(tmp_path, make, args, message):
    folder = tmp_path / "recordings"
    if make == "file":
        folder.write_text("t,mx,my,mz\n")
    elif make:
        folder.mkdir()
    r = _batch_cli(folder, "-o", tmp_path / "out", *args)
    assert r.returncode == 2 and message in r.stderr, r.stderr
    assert not (tmp_path / "out").exists()


def test_fleet_statistics_and_settings_refuse_nan_and_empty(tmp_path):
    from fluxcal.batch import calibrate_fleet, robust_spread

    for values, message in (([], "values: empty"), ([1.0, np.nan, 2.0], "values: NaN")):
        with pytest.raises(ValueError, match=message):  # a RuntimeWarning and NaN, or a NaN spread
            robust_spread(values)
    with pytest.raises(ValueError, match="outlier_k: nan must be a positive number"):
        calibrate_fleet(tmp_path, tmp_path / "out", outlier_k=float("nan"))  # flagged nothing


def test_units_named_like_the_summary_files_are_refused_and_a_failed_unit_loses_its_old_calibration(cluster, tmp_path):
    """A blind check: recordings named fleet_summary/failures were overwritten by the summary (with -o the input
    folder, the recording itself); a unit that now fails kept its old <unit>.json, which passed for current."""
    folder = tmp_path / "recordings"
    folder.mkdir()
    for name in ("u0", "fleet_summary"):
        s = _unit(4000)
        _write(folder / f"{name}.csv", s.readings, s.t)
    with pytest.raises(ValueError, match="fleet_summary.csv: unit names fleet_summary and failures are the batch's"):
        calibrate_fleet(folder, folder, scheduler=cluster.scheduler_address, progress=False)
    (folder / "fleet_summary.csv").unlink()
    out = tmp_path / "out"
    calibrate_fleet(folder, out, scheduler=cluster.scheduler_address, field_norm=H, progress=False)
    with open(folder / "u0.csv", "a") as f:
        f.write("garbage,line\n")
    result = calibrate_fleet(folder, out, scheduler=cluster.scheduler_address, field_norm=H, progress=False)
    assert result.rows[0]["status"] == "failed" and "moved to u0.json.stale" in result.rows[0]["error"]
    assert not (out / "u0.json").exists() and (out / "u0.json.stale").exists()


def test_a_simulated_recording_is_calibrated_as_calibrate_does(cluster, tmp_path):
    """batch took a `fluxcal simulate` recording's field norm from nowhere (45 238 against the stated 50 000)."""
    folder = tmp_path / "recordings"
    folder.mkdir()
    r = subprocess.run([sys.executable, "-m", "fluxcal", "simulate", "-o", str(folder / "sim.csv"), "--n", "800",
                        "--seed", "5"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    calibrate_fleet(folder, tmp_path / "out", scheduler=cluster.scheduler_address, progress=False)
    assert Calibration.load(tmp_path / "out" / "sim.json").field_norm == pytest.approx(50000.0)


def test_a_run_into_the_recordings_own_folder_with_every_file_taken_runs_again(cluster, tmp_path):
    """-o the recordings' folder and --pattern '*': the second run had taken the first's u0.json for a recording
    ("u0.csv and u0.json would both be unit 'u0'"); now it skips every unit already done."""
    for i in range(3):
        s = _unit(4000 + i)
        _write(tmp_path / f"u{i}.csv", s.readings, s.t)
    first = calibrate_fleet(tmp_path, tmp_path, scheduler=cluster.scheduler_address, field_norm=H, pattern="*",
                            progress=False)
    assert first.summary["counts"]["ok"] == 3
    again = calibrate_fleet(tmp_path, tmp_path, scheduler=cluster.scheduler_address, field_norm=H, pattern="*",
                            progress=False)
    assert again.summary["counts"]["skipped"] == 3


def test_the_report_says_whom_the_statistics_cover_and_when_values_are_not_judged(tmp_path):
    """(s75/workflow) 3 of 8 units' statistics printed as the fleet's, and the outlier rule's floor of
    MIN_UNITS_FOR_OUTLIERS units unsaid (a 148 µT hard iron among 18 µT ones went unflagged)."""
    from fluxcal.batch import FleetResult, fleet_statistics

    rows = [{"unit": f"u{i}", "status": "ok", "units": "uT", "offset_x": float(i), "warnings": ""} for i in range(3)]
    rows += [{"unit": "n", "status": "ok", "units": "nT", "offset_x": 1e3, "warnings": ""},
             {"unit": "f", "status": "failed", "error": "cut", "warnings": ""}]
    dist, outliers = fleet_statistics(rows)
    summary = {"counts": {"units": 5, "ok": 4, "not_identifiable": 0, "failed": 1}, "distribution": dist,
               "fleet_units": "uT", "outliers": outliers, "settings": {"outlier_k": 5.0, "pattern": "*.csv"}}
    text = FleetResult(tmp_path, tmp_path, rows, summary).report()
    assert "(uT; 3 of 5 units: those ok in these units)" in text
    assert "outliers (|x - median| > 5·1.4826·MAD): 1 (by value not judged: 3 units, fewer than 5)" in text
    assert "n: readings in nT, the fleet's are in uT" in text
