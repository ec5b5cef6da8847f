"""A misfit is said even when no noise σ is given (newcomer review W2 and M3).

W2: `diagnose --model cable` on a lab ring (ferrous parts, z leakage, the Earth's field) calibrated on the paper's
rig, with no repeated snapshots, took σ from its own base fit's residuals and said "the ring's model explains the
readings to the noise" (0.83 σ), while `cable solve` flagged MISFIT in 6 of 8 snapshots against the calibration's σ.
M3: `positions` with the north component's sign wrong (residual 1618 mV against 16.6 mV, heading error 174°) only
warned "12 parameter(s) poorly determined"; the misfit warning needed --noise-sigma.
"""
import numpy as np
import pytest

import fluxcal.positions as fp
from fluxcal import sim
from fluxcal.cable import RingCalibration, read_ring_csv
from fluxcal.diagnose import diagnose_cable

from conftest import run_cli

ROTATIONS = "0,45,90,135,180,225,270,315"
G = 9.80665
FIELD = np.array([17000.0, 1000.0, 48000.0])  # (N, E, D) nT, the newcomer's
NOT_COUPLING = "helical_lay,finite_length,sensor_position_error,cable_tilt,z_leakage"  # the candidates of the time


# ---------------------------------------------------------------- W2: the cable ring's diagnosis

@pytest.fixture(scope="module")
def ring_files(tmp_path_factory):
    """The newcomer's files: a calibration run on the paper's rig, and 8 snapshots (one per rotation, no
    repeats) of the same ring in the lab (`--lab`), and of the paper's rig (clean)."""
    d = tmp_path_factory.mktemp("ring")
    assert run_cli("cable", "simulate", "-o", d / "calrun.csv", "--calibration").returncode == 0
    assert run_cli("cable", "calibrate", d / "calrun.csv", "-o", d / "ringcal.json").returncode == 0
    for name, extra in (("lab", ["--lab"]), ("clean", [])):
        r = run_cli("cable", "simulate", "-o", d / f"{name}.csv", "--current", "10", "--rotations", ROTATIONS, *extra)
        assert r.returncode == 0, r.stderr
    return d


def test_cable_diagnosis_judges_the_fit_against_the_calibrations_noise(ring_files):
    d = ring_files
    solve = run_cli("cable", "solve", d / "lab.csv", "--calibration", d / "ringcal.json")
    # the solver itself flags it in every snapshot, by the F test with the calibration's repeats' degrees of freedom
    # (the 5 σ rule alone flagged 6 of 8), and exits 3 since no snapshot fits
    assert solve.returncode == 3 and solve.stdout.count("MISFIT (p ") == 8, solve.stdout
    # its warning once, with the snapshots it concerns and the worst one's numbers
    assert solve.stdout.count("the readings do not fit the model") == 1, solve.stdout
    line = next(x for x in solve.stdout.splitlines() if "the readings do not fit the model" in x)
    assert line.startswith("warning: snapshots 0–7: the readings do not fit the model: residual ")
    worst = max(float(x.split("residual RMS ")[1].split()[0]) for x in solve.stdout.splitlines() if "MISFIT" in x)
    worst_at = next(x.split(":")[0] for x in solve.stdout.splitlines() if f"residual RMS {worst:.3g} T" in x)
    assert line.endswith(f"({worst_at}'s numbers, the largest)"), (line, worst_at)
    # without the candidate for what the lab's ferrous parts do (sensor_coupling), nothing explains the departure
    r = run_cli("diagnose", d / "lab.csv", "--model", "cable", "--calibration", d / "ringcal.json", "--quiet",
                f"--candidates={NOT_COUPLING}")
    assert r.returncode == 0, r.stderr
    assert "explains the readings to the noise" not in r.stdout, r.stdout
    assert "from the calibration run's repeated readings" in r.stdout, r.stdout
    assert "the readings still depart from the ring's model" in r.stdout, r.stdout
    # with it, the lab rig's ferrous parts (each sensor's field through a 2×2 matrix: its off-diagonal part) are named
    r = run_cli("diagnose", d / "lab.csv", "--model", "cable", "--calibration", d / "ringcal.json", "--quiet")
    assert r.returncode == 0 and "FOUND: sensor_coupling (largest: sensor " in r.stdout, r.stdout
    # which sensor and how much, not only in the JSON
    assert "° off right angles and turned together by" in r.stdout or "both axes turned together by" in r.stdout


def test_cable_diagnosis_noise_from_the_calibration_in_python(ring_files):
    data = read_ring_csv(ring_files / "lab.csv")
    cal = RingCalibration.load(ring_files / "ringcal.json")
    dg = diagnose_cable(data["readings"], data["ring"], currents=data["currents_a"],
                        rotations_deg=data["rotations_deg"], positions=data["positions_m"], calibration=cal)
    assert dg.noise_source.startswith("from the calibration run's repeated readings")
    # σ per sensor is the scatter of the calibration run's repeats over its gain (refined gains: its own parameter
    # errors left out)
    np.testing.assert_allclose(dg.where["noise_sigma_per_sensor"],
                               np.sqrt(np.mean((cal.repeat_sigma / cal.gains) ** 2, axis=1)), rtol=1e-12)
    assert dg.where["overall"]["rms_z"] > 3.0  # 7.7 σ: the departure the solver flags
    # a calibration without its repeats' scatter (saved before it was kept): its scatter about its fit
    older = RingCalibration(cal.offsets, cal.gains, residual_sigma=cal.residual_sigma, covariance=cal.covariance)
    dg = diagnose_cable(data["readings"], data["ring"], currents=data["currents_a"],
                        rotations_deg=data["rotations_deg"], positions=data["positions_m"], calibration=older)
    assert dg.noise_source.startswith("from the calibration's scatter")
    np.testing.assert_allclose(dg.where["noise_sigma_per_sensor"],
                               np.sqrt(np.mean((cal.residual_sigma / cal.gains) ** 2, axis=1)), rtol=1e-12)
    # the solver's own σ is the RMS over the sensors of the per-sensor σ at these fields: the repeats' scatter when
    # the calibration has it, else its residuals'
    assert cal.field_sigma(data["readings"]) == pytest.approx(
        float(np.sqrt(np.mean(cal.sensor_sigma(data["readings"], repeats=True) ** 2))), rel=1e-12)
    assert older.field_sigma(data["readings"]) == pytest.approx(
        float(np.sqrt(np.mean(cal.sensor_sigma(data["readings"]) ** 2))), rel=1e-12)


def test_clean_ring_is_still_explained_to_the_calibrations_noise(ring_files):
    d = ring_files
    r = run_cli("diagnose", d / "clean.csv", "--model", "cable", "--calibration", d / "ringcal.json", "--quiet")
    assert r.returncode == 0, r.stderr
    assert "FOUND: no significant effect — the ring's model explains the readings to the noise" in r.stdout, r.stdout
    assert "CAVEAT" not in r.stdout, r.stdout


def test_cable_diagnosis_with_sigma_from_its_own_residuals_says_it_cannot_judge(ring_files):
    # no calibration, no repeats, no --noise-sigma: σ can only come from the residuals, which hold the misfit
    r = run_cli("diagnose", ring_files / "lab.csv", "--model", "cable", "--quiet", f"--candidates={NOT_COUPLING}")
    assert r.returncode == 0, r.stderr
    assert "explains the readings to the noise" not in r.stdout, r.stdout
    assert "whether the ring's model fits cannot be judged" in r.stdout, r.stdout
    caveat = next(line for line in r.stdout.splitlines() if line.startswith("CAVEAT: σ was estimated"))
    assert "--noise-sigma" in caveat and "by construction" in caveat, caveat


# ---------------------------------------------------------------- M3: the twelve positions

def _twelve(seed, noise=0.45, tilt=1.0, yaw=0.0):
    rng = np.random.default_rng(seed)
    scene = sim.twelve_scene("nue", tilt_deg=tilt, yaw_deg=yaw, rng=rng)
    acc = sim.Accelerometer(np.zeros(3), np.eye(3), G * np.radians(0.01) / np.sqrt(2))
    return sim.simulate_positions(scene, FIELD, noise=noise, accelerometer=acc, rng=rng)


def _misfit(res):
    return [w for w in res.summary["warnings"] if w.startswith("the model does not fit")]


def test_wrong_north_sign_is_said_first_and_named_without_a_noise_sigma():
    s = _twelve(0)
    wrong = fp.calibrate(s.outputs, s.acc_raw, FIELD * [-1, 1, 1], frame="nue", preset="twelve", units="mV")
    warnings = wrong.summary["warnings"]
    assert warnings[0].startswith("the model does not fit the reference field"), warnings
    text = warnings[0]
    assert "its north component has the wrong sign" in text, text
    assert "no noise σ is needed to see it" in text and "heading error RMS" in text, text
    assert "(17000, 1000, 48000)" in text, text  # the field the data point to, as numbers
    poor = [w for w in warnings if "poorly determined" in w]
    assert all("which the misfit above inflates" in w for w in poor), poor
    right = fp.calibrate(s.outputs, s.acc_raw, FIELD, frame="nue", preset="twelve", units="mV")
    assert not _misfit(right), right.summary["warnings"]


@pytest.mark.parametrize("given, cause", [
    (FIELD * [1, -1, 1], "its east component has the wrong sign"),           # 2.3°: only the refit shows it
    (FIELD[[0, 2, 1]] * [1, -1, 1], "given in the frame's local axes"),      # N,U,E written as N,E,D
    (np.array([FIELD[1], FIELD[0], -FIELD[2]]), "given as E,N,U"),           # the ENU convention
])
def test_field_mistakes_are_named(given, cause):
    s = _twelve(1)
    res = fp.calibrate(s.outputs, s.acc_raw, given, frame="nue", preset="twelve", units="mV")
    said = _misfit(res)
    assert len(said) == 1 and cause in said[0], res.summary["warnings"]


def test_no_misfit_is_said_for_right_fields():
    # placement errors, estimated headings, a noisy sensor (20 mV ≈ 220 nT, a MEMS chip): none is a field mistake
    for seed in range(8):
        for kw, sim_kw in (({}, {}), ({"estimate_yaw": True}, {"yaw": 2.0}), ({}, {"noise": 20.0, "tilt": 2.0})):
            s = _twelve(seed, **sim_kw)
            res = fp.calibrate(s.outputs, s.acc_raw, FIELD, frame="nue", preset="twelve", units="mV", **kw)
            assert not _misfit(res), (seed, kw, res.summary["warnings"])


def test_cli_says_the_misfit_once_with_and_without_a_noise_sigma(tmp_path):
    s = _twelve(2)
    path = tmp_path / "twelve.csv"
    path.write_text("# units: mx=mV, my=mV, mz=mV\nax,ay,az,mx,my,mz\n" + "\n".join(
        ",".join(f"{v:.6f}" for v in [*a, *m]) for a, m in zip(s.acc_raw, s.outputs)) + "\n")
    args = ["positions", path, "--preset", "twelve", "--frame", "nue", "--field", "-17000,1000,48000"]
    for extra in ([], ["--noise-sigma", "0.45"]):
        r = run_cli(*args, *extra)
        # (exit status 3: the misfit leaves U0 and K's diagonal poorly determined)
        assert r.returncode == 3 and "poorly determined" in r.stderr, r.stderr
        warnings = [line for line in r.stdout.splitlines() if line.startswith("warning: ")]
        assert warnings[0].startswith("warning: the model does not fit the reference field"), r.stdout
        assert sum("does not fit" in w for w in warnings) == 1, r.stdout
        assert "its north component has the wrong sign" in warnings[0], r.stdout
    assert "Against the noise σ given as well: the residual is" in warnings[0], r.stdout  # its yardstick added
