"""calibrate_planar's standard errors when the readings are correlated in time (a sensor's own low-pass filter, noise
that wanders): the Newey–West sandwich of the C++ core against its oracle (fluxcal.oracle.planar with
fluxcal.oracle.serial: statsmodels' Bartlett sums, arch's block length), Monte-Carlo honesty of the reported errors,
and the CLI's --serial-correlation with --planar.

Before the sandwich, AR(1) noise of φ 0.9 left the offset more than 4 of its reported errors off in 13 of 20 logs
(a blind check's simulator, /work/scratch/s33/blind_planar); the z-scores' spread was 4–5."""
import numpy as np
import pytest
from scipy.signal import lfilter

from fluxcal.cli import main
from fluxcal.oracle import planar as oracle_planar
from fluxcal.planar import calibrate_planar, summary_lines

H, Z, SIGMA = 20.0, 45.0, 0.2
OFFSET = np.array([12.0, -7.0])
W2 = np.array([[1.05, 0.06], [0.06, 0.92]])


def turning(seed, n=1000, phi=0.9, turns=2.0, W=W2):
    """A level vehicle turning `turns` circles at an uneven rate, readings N×3 (the third axis the vertical field),
    soft iron W, noise AR(1) of coefficient phi and stationary σ SIGMA per axis (white when phi = 0)."""
    rng = np.random.default_rng(seed)
    psi = np.cumsum(rng.uniform(0.2, 1.8, n))
    psi = psi / psi[-1] * 2 * np.pi * turns + rng.uniform(0, 2 * np.pi)
    h = H * np.column_stack([np.cos(psi), np.sin(psi)])
    e = lfilter([1.0], [1.0, -phi], rng.normal(0.0, SIGMA * np.sqrt(1 - phi ** 2), (n, 3)), axis=0)
    return np.column_stack([h @ W.T + OFFSET, np.full(n, Z)]) + e


@pytest.mark.parametrize("seed, field, shape", [(0, H, "sym"), (1, None, "sym"), (2, H, "diag"), (3, None, "circle")])
def test_newey_west_errors_match_the_oracle(seed, field, shape):
    # a soft iron the shape fits, so that the correlation is the noise's
    m = turning(seed, W={"sym": W2, "diag": np.diag(np.diag(W2)), "circle": 1.1 * np.eye(2)}[shape])[:, :2]
    cal = calibrate_planar(m, field_norm=field, shape=shape)
    ref = oracle_planar.fit_planar(m, field, shape)
    serial, expected = cal.summary["serial_correlation"], ref["serial_correlation"]
    assert serial["lags"] == expected["lags"] >= 1
    assert serial["ljung_box_p"] == pytest.approx(expected["ljung_box_p"], abs=1e-12) and serial["ljung_box_p"] < 0.01
    assert serial["lag1"] == pytest.approx(expected["lag1"], abs=1e-9) and serial["lag1"] > 0.7
    free = ref["standard_errors"] > 1e-12 * np.abs(ref["parameters"])  # (a relative circle's gain is exact)
    np.testing.assert_allclose(np.array(cal.summary["standard_errors"])[free], ref["standard_errors"][free], rtol=1e-6)
    np.testing.assert_allclose(np.array(serial["standard_errors_independent"])[free],
                               expected["standard_errors_independent"][free], rtol=1e-6)
    assert serial["inflation"] == pytest.approx(expected["inflation"], rel=1e-6) and serial["inflation"] > 2
    assert any("correlated in time" in w and "Newey-West" in w for w in cal.summary["warnings"])


def test_reported_errors_match_the_spread_under_correlated_noise():
    """40 logs with AR(1) noise φ 0.9: the offset's z-scores against the reported errors have a spread near 1 (the
    independent-readings errors' would be 4–5), and none lies beyond 4."""
    z, z_independent = [], []
    for seed in range(40):
        cal = calibrate_planar(turning(100 + seed), field_norm=H)
        s = cal.summary
        assert s["identifiable"]  # judged on the coverage (independent errors), not the noise's colour
        se = np.array(s["standard_errors"][:2])
        se_independent = np.array(s["serial_correlation"]["standard_errors_independent"][:2])
        z.append((cal.offset[:2] - OFFSET) / se)
        z_independent.append((cal.offset[:2] - OFFSET) / se_independent)
    z, z_independent = np.array(z), np.array(z_independent)
    assert 0.75 < z.std() < 1.35  # measured 1.18
    assert np.sum(np.abs(z) > 4) == 0
    assert z_independent.std() > 3  # what was reported before (measured 4.77)


def test_white_noise_keeps_the_independent_errors():
    kept = 0
    for seed in range(10):
        s = calibrate_planar(turning(200 + seed, phi=0.0), field_norm=H).summary
        if s["serial_correlation"]["lags"] == 0:
            kept += 1
            assert s["standard_errors"] == s["serial_correlation"]["standard_errors_independent"]
            assert not any("correlated in time" in w for w in s["warnings"])
    assert kept >= 8  # α = 0.01 per log, and a sandwich that widens nothing is never taken


def test_modes_and_bad_mode():
    m = turning(5)
    independent = calibrate_planar(m, field_norm=H, serial_correlation="independent").summary
    assert independent["serial_correlation"]["lags"] == 0
    assert independent["standard_errors"] == independent["serial_correlation"]["standard_errors_independent"]
    forced = calibrate_planar(turning(6, phi=0.0), field_norm=H, serial_correlation="newey_west").summary
    assert forced["serial_correlation"]["lags"] >= 1
    with pytest.raises(ValueError, match="serial_correlation: 'hac' is not one of automatic, independent, newey_west"):
        calibrate_planar(m, field_norm=H, serial_correlation="hac")


def test_the_printout_and_the_cli(tmp_path, capsys):
    path = tmp_path / "yaw.csv"
    m = turning(7)
    np.savetxt(path, m, delimiter=",", header="mx_uT,my_uT,mz_uT", comments="")
    assert main(["calibrate", str(path), "--planar", "--field-norm", str(H)]) == 0
    out = capsys.readouterr().out
    assert "widened for readings correlated in time" in out and "Newey-West" in out
    assert main(["calibrate", str(path), "--planar", "--field-norm", str(H), "--serial-correlation",
                 "independent"]) == 0
    out = capsys.readouterr().out
    assert "widened" not in out and "Newey-West" not in out
    lines = summary_lines(calibrate_planar(m, field_norm=H))
    assert any(line.lstrip().startswith("identifiable") and "independent readings" in line for line in lines)
