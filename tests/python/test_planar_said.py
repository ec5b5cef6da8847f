"""What calibrate_planar says of a log its model does not fit, as calibrate does (a newcomer's walk-through): a hard iron
that moved halfway through (a load put on the seat) left a 4.7° heading error and a residual σ 6× the noise, printed
as the 'noise σ'; readings in mG labelled µT gave |h| = 200 "µT", and H given in µT but labelled nT |h| = 20 nT,
both unsaid."""
import numpy as np
import pytest
from scipy.signal import lfilter

from fluxcal.planar import calibrate_planar, summary_lines

from test_planar import H, yaw_only


def misses(cal):
    return [w for w in cal.summary["warnings"] if "the readings' own noise" in w]


@pytest.mark.parametrize("seed", [0, 1])
def test_a_hard_iron_that_moved_is_said(seed):
    m, _ = yaw_only(seed, n=3000)
    m[1500:, 0] += 2.0  # 10 % of H, halfway
    said = misses(calibrate_planar(m, field_norm=H))
    assert len(said) == 1 and "an offset that moved within the log" in said[0] and "headings" in said[0]


@pytest.mark.parametrize("seed", [0, 1])
def test_right_models_are_not_said_to_miss_also_with_correlated_noise(seed):
    m, _ = yaw_only(seed, n=3000)
    assert not misses(calibrate_planar(m, field_norm=H))
    e = lfilter([1.0], [1.0, -0.9], np.random.default_rng(seed).standard_normal((3000, 3)), axis=0)
    cal = calibrate_planar(m + 0.2 * e / e.std(axis=0), field_norm=H)  # a sensor's first-order filter
    assert not misses(cal) and cal.summary["readings_noise_stride"] > 1
    lines = summary_lines(cal)
    assert any(line.startswith("  residual σ") and "whatever the model misses" in line for line in lines)
    assert any(line.startswith("  noise σ, differences") and "readings apart" in line for line in lines)


def test_a_field_far_from_any_horizontal_field_is_said():
    m, _ = yaw_only(2)
    def far(cal):
        return [w for w in cal.summary["warnings"] if "far from the Earth's horizontal field" in w]
    assert not far(calibrate_planar(m, units="uT", field_norm=H))
    assert far(calibrate_planar(10 * m, units="uT"))  # mG labelled µT
    assert far(calibrate_planar(m, units="uT", field_norm=H, field_units="nT"))  # H in µT labelled nT


def test_calibrate_planar_plots_the_plane_before_and_after(tmp_path, capsys):
    """--plot with --planar (refused before: a newcomer expected the ellipse-to-circle picture here most): the plane's
    two axes raw and corrected, and the horizontal |h|; for three columns and for a biaxial sensor's two."""
    import matplotlib.image

    from fluxcal.cli import main

    m, _ = yaw_only(5, n=600)
    for name, header, rows in (("three.csv", "mx [uT],my [uT],mz [uT]", m), ("two.csv", "Bx [uT],By [uT]", m[:, :2])):
        log = tmp_path / name
        log.write_text(header + "\n" + "".join(",".join(f"{v:.5f}" for v in row) + "\n" for row in rows))
        png = tmp_path / (name + ".png")
        assert main(["calibrate", str(log), "--planar", "--field-norm", str(H), "--plot", str(png)]) == 0
        assert f"wrote {png}" in capsys.readouterr().out
        assert matplotlib.image.imread(png).shape[0] > 100
