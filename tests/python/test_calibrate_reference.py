"""`fluxcal calibrate` with reference vectors in the file (a blind check's findings): a raw-count magnetometer
against a field model in nT, reference columns named on the command line or noticed when not, a vector method
without a reference named as such, outliers named by their file lines, a held-out check without the outliers,
and the coverage of a short full tumble not called poor."""
import json

import numpy as np
from scipy.spatial.transform import Rotation

from conftest import run_cli
from fluxcal.attitude import reference_vectors
from fluxcal.io import write_csv

NED = np.array([36109.5, 5513.85, -9706.13])  # nT


def _flight(n=800, seed=0):
    rng = np.random.default_rng(seed)
    pitch, roll, yaw = rng.uniform(-80, 80, n), rng.uniform(-180, 180, n), rng.uniform(-180, 180, n)
    return pitch, roll, yaw, reference_vectors(NED, pitch, roll, yaw)


def test_counts_against_a_field_model_in_nt_are_calibrated_in_nt(tmp_path):
    pitch, roll, yaw, r = _flight()
    W = np.array([[0.0068, 0.0002, -0.0001], [0.0002, 0.0057, 0.0003], [-0.0001, 0.0003, 0.0066]])  # counts per nT
    b = np.array([-150.0, -100.0, 470.0])
    m = np.round(r @ W.T + b + np.random.default_rng(1).normal(0, 2.0, r.shape))
    cols = {"pitch": pitch, "roll": roll, "yaw": yaw, "igrf_n": np.full(len(m), NED[0]),
            "igrf_e": np.full(len(m), NED[1]), "igrf_d": np.full(len(m), NED[2]), "mx": m[:, 0], "my": m[:, 1], "mz": m[:, 2]}
    path = write_csv(tmp_path / "counts.csv", cols, units={"pitch": "deg", "roll": "deg", "yaw": "deg", "igrf_n": "nT",
                                                           "igrf_e": "nT", "igrf_d": "nT", "mx": "counts", "my": "counts",
                                                           "mz": "counts"})
    out = run_cli("calibrate", path, "-o", tmp_path / "cal.json")
    assert out.returncode == 0, out.stderr
    saved = json.loads((tmp_path / "cal.json").read_text())
    assert saved["summary"]["method"] == "vector"
    assert saved["field_units"] == "nT" and saved["units"] == "counts"
    A = np.array(saved["matrix"])
    assert np.max(np.abs(A @ W - np.eye(3))) < 0.01  # A inverts counts per nT
    assert np.allclose(saved["offset"], b, atol=1.0)
    # the diagnosis' vector model would mix counts and nT in its errors: refused, with the way round it
    out = run_cli("diagnose", path, "--quiet")
    assert out.returncode == 2 and "calibrate first" in out.stderr


def test_reference_columns_are_used_when_named_and_noticed_when_not(tmp_path):
    pitch, roll, yaw, r = _flight()
    turn = Rotation.from_rotvec(np.radians([0.0, 0.0, 5.0])).as_matrix()  # the sensor turned 5° on its board
    m = r @ turn.T * 1e-3 + np.array([3.0, -2.0, 1.0]) + np.random.default_rng(2).normal(0, 0.05, r.shape)  # µT
    ref = r * 1e-3  # the reference in µT as well, under other names
    cols = {"mx": m[:, 0], "my": m[:, 1], "mz": m[:, 2], "rx": ref[:, 0], "ry": ref[:, 1], "rz": ref[:, 2]}
    path = write_csv(tmp_path / "ref.csv", cols, units={k: "uT" for k in cols})
    plain = run_cli("calibrate", path)
    assert plain.returncode == 0 and "give --reference rx,ry,rz for the vector fit" in plain.stdout
    vector = run_cli("calibrate", path, "--reference", "rx,ry,rz", "-o", tmp_path / "cal.json")
    assert vector.returncode == 0, vector.stderr
    saved = json.loads((tmp_path / "cal.json").read_text())
    assert saved["summary"]["method"] == "vector"
    turned = np.degrees(Rotation.from_matrix(np.linalg.inv(np.array(saved["matrix"]))).magnitude())
    assert abs(turned - 5.0) < 0.1
    # reference columns in nT against readings in µT are converted: the same answer
    cols.update(rx=ref[:, 0] * 1e3, ry=ref[:, 1] * 1e3, rz=ref[:, 2] * 1e3)
    nt = write_csv(tmp_path / "ref_nt.csv", cols, units={**{k: "uT" for k in ("mx", "my", "mz")},
                                                         **{k: "nT" for k in ("rx", "ry", "rz")}})
    again = run_cli("calibrate", nt, "--reference", "rx,ry,rz", "-o", tmp_path / "cal_nt.json")
    assert again.returncode == 0, again.stderr
    assert np.allclose(json.loads((tmp_path / "cal_nt.json").read_text())["matrix"], saved["matrix"], atol=1e-9)
    missing = run_cli("calibrate", path, "--method", "vector")
    assert missing.returncode == 2 and "--reference with three columns" in missing.stderr
    magnitudes = run_cli("calibrate", path, "--reference", "rx,ry,rz", "--method", "als")
    assert magnitudes.returncode == 2 and "fits field magnitudes only" in magnitudes.stderr
    # the readings named as their own reference: a perfect fit of nothing ("identifiable yes", errors of 1e-29)
    itself = run_cli("calibrate", path, "--reference", "mx,my,mz")
    assert itself.returncode == 2 and "reference: it is the readings themselves" in itself.stderr, itself.stderr


def test_outliers_are_named_by_their_file_lines_and_left_out_of_the_held_out_check(tmp_path):
    pitch, roll, yaw, r = _flight(1000, 3)
    rng = np.random.default_rng(3)
    m = r * 1e-3 + np.array([3.0, -2.0, 1.0]) + rng.normal(0, 0.05, r.shape)
    spikes = [600, 700, 900]
    m[spikes] += 40.0
    ref = r * 1e-3
    lines = ["t,mx,my,mz,rx,ry,rz"] + [",".join(f"{v:.5f}" for v in (i, *m[i], *ref[i])) for i in range(len(m))]
    lines.insert(10, "5,garbled")  # a bad line before the spikes: rows and file lines differ
    path = tmp_path / "spiky.csv"
    path.write_text("\n".join(lines) + "\n")
    out = run_cli("calibrate", path, "--reference", "rx,ry,rz", "--bad-lines", "skip")
    assert out.returncode == 0, out.stderr
    assert "rows 600, 700, 900; file lines 603, 703, 903" in out.stdout
    held = float(out.stdout.split("held-out vector RMS")[1].split()[0])
    assert held < 0.15  # √3 σ = 0.087 µT; with the three 40 µT spikes it would be about 2.2 µT


def test_a_short_full_tumble_is_not_called_poor_coverage(tmp_path):
    rng = np.random.default_rng(4)
    u = rng.normal(size=(30, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    m = 50.0 * u + np.array([5.0, -3.0, 2.0]) + rng.normal(0, 0.2, (30, 3))
    path = write_csv(tmp_path / "short.csv", {"mx": m[:, 0], "my": m[:, 1], "mz": m[:, 2]},
                     units={"mx": "uT", "my": "uT", "mz": "uT"})
    out = run_cli("calibrate", path, "--field-norm", "50")
    assert out.returncode == 0, out.stderr
    assert "of field directions seen" not in out.stdout  # 30 readings can fill about 27 % of the bins
    # The same 30 directions folded into one hemisphere fill nearly as many bins (30 readings rarely share one):
    # what catches it is the Fisher information, not the bins.
    half = np.where(u[:, 2:] < 0, -u, u)
    folded = write_csv(tmp_path / "half.csv", dict(zip(("mx", "my", "mz"), (50.0 * half + rng.normal(0, 0.2, u.shape)).T)),
                       units={"mx": "uT", "my": "uT", "mz": "uT"})
    out = run_cli("calibrate", folded, "--field-norm", "50")
    assert out.returncode == 3 and "identifiable          NO" in out.stdout


def test_a_magnitude_fit_is_judged_on_the_half_it_did_not_see(tmp_path):
    rng = np.random.default_rng(5)
    u = rng.normal(size=(400, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    W = np.array([[1.1, 0.03, 0.0], [0.03, 0.95, -0.02], [0.0, -0.02, 1.02]])
    m = 50.0 * u @ W.T + np.array([20.0, -10.0, 5.0]) + rng.normal(0, 0.5, (400, 3))  # σ 1 % of the field
    path = write_csv(tmp_path / "tumble.csv", dict(zip(("mx", "my", "mz"), m.T)), units={k: "uT" for k in ("mx", "my", "mz")})
    out = run_cli("calibrate", path, "--field-norm", "50")
    spread = float(out.stdout.split("held-out |h| std/mean")[1].split()[0])
    assert 0.9 < spread < 1.5  # % of the field: the noise, 1 %, and a little for the half-size fit
    # A first half that turned only in one plane cannot be fitted alone: said, not a traceback
    flat = np.column_stack([np.cos(np.linspace(0, 12, 200)), np.sin(np.linspace(0, 12, 200)), np.zeros(200)])
    m = 50.0 * np.vstack([flat, u[:200]]) + rng.normal(0, 0.2, (400, 3))
    path = write_csv(tmp_path / "flat_first.csv", dict(zip(("mx", "my", "mz"), m.T)), units={k: "uT" for k in ("mx", "my", "mz")})
    out = run_cli("calibrate", path, "--field-norm", "50")
    # (said as a half that turned through fewer directions than the whole recording, the fit's error beside it)
    assert out.returncode in (0, 3) and ("held-out |h| std/mean —   (the first half alone does not determine the fit: "
                                         "its readings cover") in out.stdout and "lie nearly in one plane" in out.stdout


def test_python_calibrate_of_a_recording_with_attitude_runs_the_vector_fit_as_the_cli_does(tmp_path):
    """fluxcal.calibrate(read_recording(file)) had fitted magnitudes only (als+refine) where `fluxcal calibrate file`
    ran the vector fit; and attitude in radians with no unit had been read as degrees in silence."""
    import fluxcal
    from fluxcal.io import read_recording

    pitch, roll, yaw, r = _flight()
    W = np.array([[0.0068, 0.0002, -0.0001], [0.0002, 0.0057, 0.0003], [-0.0001, 0.0003, 0.0066]])
    b = np.array([-150.0, -100.0, 470.0])
    m = np.round(r @ W.T + b + np.random.default_rng(1).normal(0, 2.0, r.shape))
    field = {"igrf_n": np.full(len(m), NED[0]), "igrf_e": np.full(len(m), NED[1]), "igrf_d": np.full(len(m), NED[2])}
    mag = {"mx": m[:, 0], "my": m[:, 1], "mz": m[:, 2]}
    units = {**{k: "nT" for k in field}, **{k: "counts" for k in mag}}
    path = write_csv(tmp_path / "counts.csv", {"pitch": pitch, "roll": roll, "yaw": yaw, **field, **mag},
                     units={**units, "pitch": "deg", "roll": "deg", "yaw": "deg"})
    cal = fluxcal.calibrate(read_recording(path))
    assert cal.summary["method"] == "vector" and cal.field_units == "nT"
    assert np.max(np.abs(cal.matrix @ W - np.eye(3))) < 0.01 and np.allclose(cal.offset, b, atol=1.0)
    assert cal.metadata["reference"].startswith("attitude pitch,roll,yaw")
    assert fluxcal.calibrate(read_recording(path), method="als+refine").summary["method"] == "als+refine"
    radians = write_csv(tmp_path / "rad.csv", {"pitch": np.radians(pitch), "roll": np.radians(roll),
                                               "yaw": np.radians(yaw), **field, **mag}, units=units)
    out = run_cli("calibrate", radians)
    assert out.returncode == 2 and "attitude columns pitch, roll, yaw state no unit and never pass 2π" in out.stderr
    stated = write_csv(tmp_path / "rad_stated.csv", {"pitch": np.radians(pitch), "roll": np.radians(roll),
                                                     "yaw": np.radians(yaw), **field, **mag},
                       units={**units, "pitch": "rad", "roll": "rad", "yaw": "rad"})
    assert np.allclose(fluxcal.calibrate(read_recording(stated)).matrix, cal.matrix, atol=1e-9)


def test_a_reference_column_missing_or_not_a_number_is_named(tmp_path):
    pitch, roll, yaw, r = _flight(200)
    m = r * 1e-3 + np.array([3.0, -2.0, 1.0])
    ref = r * 1e-3
    ref[57, 1] = np.nan
    cols = {"mx": m[:, 0], "my": m[:, 1], "mz": m[:, 2], "rx": ref[:, 0], "ry": ref[:, 1], "rz": ref[:, 2]}
    path = write_csv(tmp_path / "ref.csv", cols, units={k: "uT" for k in cols})
    typo = run_cli("calibrate", path, "--reference", "rx,ry,qq")
    assert typo.returncode == 2 and "--reference: no column 'qq' in" in typo.stderr, typo.stderr
    nan = run_cli("calibrate", path, "--reference", "rx,ry,rz")
    assert nan.returncode == 2 and "column 'ry' is nan (not a finite number; 1 such rows)" in nan.stderr, nan.stderr
