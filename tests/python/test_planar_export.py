"""export-c of a planar calibration: the axis passed through reads the vertical field, which the plane's model does not
know. The stated input range came from the horizontal field alone (2 × 42 µT at H 14 µT) while that axis read 69 µT at
a high latitude, so the firmware's fixed-point correction saturated on every reading (a newcomer's walk-through)."""
import numpy as np

from fluxcal.export_c import fixed_point
from fluxcal.planar import calibrate_planar


def high_latitude_log(n=1500, seed=0):
    """A yaw-only vehicle where H = 14 µT and Z = 60 µT, hard iron 6.5, -4.2, +8 µT."""
    rng = np.random.default_rng(seed)
    psi = np.cumsum(rng.uniform(0.2, 1.8, n))
    psi = psi / psi[-1] * 4 * np.pi
    h = np.column_stack([14.0 * np.cos(psi), 14.0 * np.sin(psi), np.full(n, 60.0)])
    W = np.array([[1.04, 0.03, 0.0], [0.03, 0.97, 0.0], [0.0, 0.0, 1.0]])
    return h @ W.T + [6.5, -4.2, 8.0] + rng.normal(0, 0.1, (n, 3))


def test_the_fixed_point_range_holds_the_axis_passed_through():
    m = high_latitude_log()
    cal = calibrate_planar(m, field_norm=14.0)
    fixed = fixed_point(cal)
    assert fixed.input_range >= np.max(np.abs(m))
    h_q, saturated = fixed.apply_int(fixed.to_fixed(m[:50]))
    assert not saturated
    assert np.allclose(h_q * fixed.out_fmt.lsb, cal.apply(m[:50]), atol=fixed.error_bound)


def test_the_header_says_it_is_planar_and_what_passes_through(tmp_path):
    from fluxcal.export_c import export_c

    cal = calibrate_planar(high_latitude_log(), field_norm=14.0)
    export_c(cal, tmp_path / "cal.h")
    text = (tmp_path / "cal.h").read_text()
    assert "Planar (x, y): |h| is the HORIZONTAL field in that plane; axis z passes through uncalibrated" in text
    biaxial = calibrate_planar(high_latitude_log()[:, :2], field_norm=14.0)
    export_c(biaxial, tmp_path / "bi.h")
    assert "axis z is absent (a biaxial sensor: give 0)" in (tmp_path / "bi.h").read_text()
    assert "plane_axes" not in text  # (the sensor's own x, y: nothing to give)


def test_a_tilted_plane_gives_its_axes_and_the_heading_rule(tmp_path):
    """A mounting tilted 20° about x: the header named axes e1, e2 without their values, and firmware that took
    atan2(h_y, h_x) was up to 14° off (a blind check). Their unit vectors are in the header, as the fit found them,
    and the heading's rule beside them."""
    from fluxcal.export_c import export_c

    m = high_latitude_log()
    c, s = np.cos(np.radians(20.0)), np.sin(np.radians(20.0))
    cal = calibrate_planar(m @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]]).T, field_norm=14.0)
    assert cal.summary["plane_axes"] == ["e1", "e2"]
    export_c(cal, tmp_path / "tilt.h", name="tilt")
    text = (tmp_path / "tilt.h").read_text()
    assert "atan2(h . e2, h . e1) - NOT atan2(h_y, h_x)" in text
    block = text.split("tilt_plane_axes[3][3] = {")[1].split("};")[0]
    axes = np.array([[float(v.rstrip("f")) for v in row.strip(" {},\n").split(",")] for row in block.split("},")])
    np.testing.assert_allclose(axes, np.vstack([cal.summary["plane_basis"], cal.summary["plane_normal"]]), atol=1e-7)
