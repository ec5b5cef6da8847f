"""Regressions a review (s75) found in the seventy-fourth session's readers: any column named like an instance (id,
compass) holding a few whole numbers was taken for interleaved compasses — a position number held over blocks of
rows kept one block of six; and a temperature with blank cells, read as NaN, cost the diagnosis its temperature
candidates (with --bad-lines skip those lines had been left out and the temperature used). And a blind check's
(s75/workflow): a DataFrame's unit in its column names (mx [nT]) was ignored — a µT calibration applied to nT
readings gave |h| 1000× the field, silently, where the same file on the command line was converted."""
from __future__ import annotations

import numpy as np
import pytest

import fluxcal
from fluxcal import read_recording
from fluxcal.diagnose.core import usable_regressors


def sphere(n, offset, radius=50.0, seed=0):
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return radius * v / np.linalg.norm(v, axis=1, keepdims=True) + offset


def table(tmp_path, column, ids, name="log.csv"):
    m = sphere(len(ids), (5.0, -3.0, 2.0))
    lines = [f"t,{column},mx,my,mz"] + [f"{0.1 * k:.1f},{i},{x:.3f},{y:.3f},{z:.3f}"
                                        for k, (i, (x, y, z)) in enumerate(zip(ids, m))]
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_position_number_held_over_blocks_of_rows_is_no_compass(tmp_path):
    rec = read_recording(table(tmp_path, "id", [k // 50 + 1 for k in range(300)]))
    assert len(rec) == 300 and "instances" not in rec.metadata
    rec = read_recording(table(tmp_path, "ID", [(3, 3, 3, 7, 7, 7)[k % 6] for k in range(300)], "ids.csv"))
    assert len(rec) == 300 and "instances" not in rec.metadata


def test_a_slow_compass_between_a_fast_ones_rows_is_still_interleaved(tmp_path):
    ids = [1 if k % 4 == 3 else 0 for k in range(400)]  # compass 1 at a quarter of compass 0's rate
    rec = read_recording(table(tmp_path, "I", ids))
    assert len(rec) == 300 and rec.metadata["instance"] == "I = 0 (300 rows)"


def test_a_temperature_blank_in_short_runs_is_interpolated_and_said():
    temp = 20.0 + 0.01 * np.arange(600)
    temp[7::40] = np.nan                      # a read missed now and then
    side, missing, filled = usable_regressors(temp, None)
    assert filled == {"temp": 15} and not missing
    assert np.allclose(side["temp"], 20.0 + 0.01 * np.arange(600))  # a straight course interpolated exactly
    slow = np.full(600, np.nan)
    slow[::10] = 20.0 + 0.1 * np.arange(60)  # a thermometer read once per ten rows
    assert usable_regressors(slow, None)[2] == {"temp": 540}
    gap = 20.0 + 0.01 * np.arange(600)
    gap[7::40] = np.nan
    gap[100:160] = np.nan                     # disconnected for a tenth of the recording, beside single misses
    side, missing, filled = usable_regressors(gap, None)
    assert side["temp"] is None and missing == {"temp": 74} and not filled
    slow[300:400] = np.nan                    # the slow thermometer out for ten of its reads: a run of 119 rows
    assert usable_regressors(slow, None)[0]["temp"] is None
    current = np.ones(600)
    current[7] = np.nan                       # a current may switch within a gap: left out
    assert usable_regressors(None, current)[0]["current"] is None


def test_diagnose_tries_the_temperature_of_a_log_with_blank_temperature_cells(tmp_path):
    rng = np.random.default_rng(1)
    n = 600
    m = sphere(n, (5.0, -3.0, 2.0), seed=1) * np.array([1.1, 0.9, 1.0]) + rng.normal(0, 0.2, (n, 3))
    lines = ["t,mx,my,mz,temp"] + [f"{0.1 * k:.1f},{x:.4f},{y:.4f},{z:.4f},{'' if k % 40 == 7 else f'{20 + 10 * k / n:.2f}'}"
                                   for k, (x, y, z) in enumerate(m)]
    path = tmp_path / "blank_temp.csv"
    path.write_text("\n".join(lines) + "\n")
    d = fluxcal.diagnose(read_recording(path, bad_lines="skip"))
    tried = {r["effect"] for r in d.ranking}
    assert {"temp_offset", "temp_scale"} <= tried
    assert "15 missing or non-finite values, in short runs: interpolated" in d.text()


def test_a_dataframes_unit_in_its_column_names_is_taken_as_a_files():
    pd = pytest.importorskip("pandas")
    m = sphere(400, (5.0, -3.0, 2.0), seed=3) + np.random.default_rng(3).normal(0, 0.05, (400, 3))
    ut = pd.DataFrame(m, columns=["mx [uT]", "my [uT]", "mz [uT]"])
    cal = fluxcal.calibrate(ut)
    assert cal.units == "uT"
    nt = pd.DataFrame(m * 1000, columns=["mx [nT]", "my [nT]", "mz [nT]"])[["mz [nT]", "mx [nT]", "my [nT]"]]
    assert np.allclose(cal.apply(nt), cal.apply(ut))  # converted (and taken by name), as a file of nT readings is
    assert fluxcal.calibrate(pd.DataFrame(m, columns=["mx", "my", "mz"])).units == ""
    with pytest.raises(ValueError, match=r"mx \[uT\] \(uT\), my \[nT\] \(nT\), mz \(no unit\) do not name one"):
        fluxcal.calibrate(pd.DataFrame(m, columns=["mx [uT]", "my [nT]", "mz"]))


def test_batch_field_units_name_the_norms_unit_for_a_fleet_logged_in_nT_and_uT(tmp_path):
    """(s75/workflow) A fleet of nT and µT loggers with --field-norm 49.2: the nT units' calibrations said h in nT with
    |h| 49.2 — µT values labelled nT — and batch had no --field-units to say otherwise."""
    from fluxcal.batch import calibrate_fleet, calibrate_unit

    m = sphere(500, (3.0, -2.0, 1.0), radius=49.2, seed=4) * [1.05, 0.97, 1.0]
    m += np.random.default_rng(4).normal(0, 0.05, m.shape)
    path = tmp_path / "B.csv"
    path.write_text("t,mx [nT],my [nT],mz [nT]\n" + "".join(f"{0.02 * k:.2f},{x * 1000:.2f},{y * 1000:.2f},{z * 1000:.2f}\n"
                                                             for k, (x, y, z) in enumerate(m)))
    out = calibrate_unit(path, tmp_path / "B.json", field_norm=49.2, field_units="uT")
    assert out["status"] == "ok", out
    cal = fluxcal.Calibration.load(tmp_path / "B.json")
    assert cal.units == "nT" and cal.field_units == "uT"
    assert abs(np.median(np.linalg.norm(cal.apply(read_recording(path)), axis=1)) - 49.2) < 0.05
    assert not [w for w in cal.summary["warnings"] if "far from the Earth's field" in w]  # judged in uT, not nT
    assert cal.metadata["batch_settings"]["field_units"] == "uT"
    with pytest.raises(ValueError, match="field_units: names the unit of field_norm"):
        calibrate_fleet(tmp_path, tmp_path / "out", field_units="uT")
    with pytest.raises(ValueError, match="'furlong' is not a magnetic-field unit"):
        calibrate_fleet(tmp_path, tmp_path / "out", field_norm=3.0, field_units="furlong")


def test_a_file_name_given_as_readings_points_to_read_recording():
    with pytest.raises(ValueError, match=r"samples: 'log.csv' is a file name, not readings; read it first: "
                                         r"fluxcal.read_recording"):
        fluxcal.calibrate("log.csv")


def test_apply_says_readings_on_a_rail(tmp_path):
    """(s75/workflow) A held-out log with x clipped on 9 % of its rows was corrected 2.7 µT off there, unsaid."""
    from conftest import run_cli

    m = sphere(2000, (3.0, -2.0, 1.0), radius=49.2, seed=5) + np.random.default_rng(5).normal(0, 0.05, (2000, 3))
    good, clipped = tmp_path / "good.csv", tmp_path / "clipped.csv"
    for path, x in ((good, m[:, 0]), (clipped, np.minimum(m[:, 0], 40.0))):
        path.write_text("mx,my,mz\n" + "".join(f"{a:.3f},{b:.3f},{c:.3f}\n" for a, b, c in zip(x, m[:, 1], m[:, 2])))
    run_cli("calibrate", good, "-o", tmp_path / "cal.json")
    out = run_cli("apply", tmp_path / "cal.json", clipped, "-o", tmp_path / "out.csv").stdout
    assert f"warning: {clipped}: readings on a rail: mx at 40 in {int(np.sum(m[:, 0] >= 40.0))} of 2000" in out
    assert "Their corrected field is not the field" in out
    assert "rail" not in run_cli("apply", tmp_path / "cal.json", good, "-o", tmp_path / "out2.csv").stdout


def test_a_slow_thermometers_column_in_a_file_is_read_and_used(tmp_path):
    """(s75/review2) A thermometer read once per ten lines left its column mostly blank, which the reader took for
    text: the temperature was dropped before the interpolation could fill it."""
    m = sphere(1000, (5.0, -3.0, 2.0), seed=6) * [1.1, 0.9, 1.0] + np.random.default_rng(6).normal(0, 0.1, (1000, 3))
    path = tmp_path / "slow.csv"
    path.write_text("t,mx,my,mz,temp\n" + "".join(
        f"{0.01 * k:.2f},{x:.3f},{y:.3f},{z:.3f},{f'{20 + 5 * k / 1000:.2f}' if k % 10 == 0 else ''}\n"
        for k, (x, y, z) in enumerate(m)))
    rec = read_recording(path)
    assert "text_columns" not in rec.metadata and np.isnan(rec.temperature()).sum() == 900
    side, missing, filled = usable_regressors(rec.temperature(), None)
    assert filled == {"temp": 900} and np.nanmax(np.abs(side["temp"][:991] - (20 + 5 * np.arange(991) / 1000))) < 0.006


def test_compasses_logged_in_bursts_by_their_own_instance_column_are_read_one_at_a_time(tmp_path):
    """(s75/review2) A FIFO's bursts (I 0 ×10, 1 ×10, …) or one table per compass joined had been fitted as one
    sensor once the instance rule asked every name for row-by-row interleaving; only a generic `id` needs it."""
    ids = [(k // 10) % 2 for k in range(400)]
    rec = read_recording(table(tmp_path, "I", ids))
    assert len(rec) == 200 and rec.metadata["instance"] == "I = 0 (200 rows)"
    rec = read_recording(table(tmp_path, "I", sorted(ids), "sorted.csv"))
    assert len(rec) == 200
    rec = read_recording(table(tmp_path, "id", ids, "id.csv"))
    assert len(rec) == 400 and "instances" not in rec.metadata


def test_a_rail_met_once_while_turning_is_left_out_not_called_held_still():
    """(s75/workflow) A hand turn passes x's saturating directions once, in one stretch of time: called "a sensor held
    still … kept in the fit" while the outlier screen left most of them out. Its other axes sweep: a rail."""
    from fluxcal.outliers import one_stretch

    k = np.linspace(0, 1, 2000)
    theta, phi = np.arccos(1 - 2 * k), np.pi / 2 + 2 * np.pi * k
    m = 50.0 * np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], 1) + [3.0, -2.0, 1.0]
    m += np.random.default_rng(9).normal(0, 0.05, m.shape)
    m[:, 0] = np.minimum(m[:, 0], 45.0)
    hit = m[:, 0] == 45.0
    assert one_stretch(hit) and 20 < hit.sum() < 300
    cal = fluxcal.calibrate(m)
    said = [w for w in cal.summary["warnings"] if "on a rail" in w]
    assert said and "held still" not in said[0] and "are left out of the fit" in said[0]
    assert set(np.flatnonzero(hit)) <= set(cal.summary["outliers"]["rows"])


def test_sparse_columns_beside_the_magnetometer_stay_text_but_a_slow_thermometer(tmp_path):
    """(s75/review3) Counting blank cells out for every column had made a sparse mag_raw_x… triple the magnetometer
    (20 of 400 rows, the wrong sensor calibrated) and a sparse gps_time a needed column (8 rows kept): only the
    recording's temperature is judged by its filled cells."""
    m = sphere(400, (10.0, -5.0, 3.0), seed=8)
    lines = ["t,mag_x,mag_y,mag_z,mag_raw_x,mag_raw_y,mag_raw_z,gps_time"]
    for k, (x, y, z) in enumerate(m):
        raw = f"{2 * x:.3f},{2 * y:.3f},{2 * z:.3f}" if k % 20 == 0 else ",,"
        lines.append(f"{0.1 * k:.1f},{x:.3f},{y:.3f},{z:.3f},{raw},{1000 + k if k % 50 == 0 else ''}")
    path = tmp_path / "sparse.csv"
    path.write_text("\n".join(lines) + "\n")
    rec = read_recording(path)
    assert len(rec) == 400 and rec.mag_names() == ("mag_x", "mag_y", "mag_z")
    assert "mag_raw_x" in rec.metadata["text_columns"] and "gps_time" in rec.metadata["text_columns"]
