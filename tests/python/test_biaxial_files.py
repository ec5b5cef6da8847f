"""A biaxial magnetometer's log (two field columns: a HMC1052, a car compass) read from a file: the Recording knows
it is biaxial and which sensor axes the columns are, `fluxcal calibrate --planar` fits it, `fluxcal apply` writes
its two corrected columns, and everything that needs three axes says so, naming the file.

The simulation: a vehicle turning (yaw only) in a horizontal field H, hard iron b, a symmetric soft iron whose axes
are rotated against the sensor's (couples the two axes), Gaussian noise σ. The planar fit's standard errors
(summary standard_errors) judge the recovered offset and matrix.
"""
import json

import numpy as np
import pytest

import fluxcal
from fluxcal import cli
from fluxcal.calibration import Calibration

H, SIGMA = 20.0, 0.1
B = np.array([12.0, -7.0])
Z_LIMIT = 4.0  # |z| > 4 has probability 6e-5 per parameter


def soft_iron(angle_deg=30.0, gains=(1.12, 0.9)):
    c, s = np.cos(np.radians(angle_deg)), np.sin(np.radians(angle_deg))
    r = np.array([[c, -s], [s, c]])
    return r @ np.diag(gains) @ r.T


def turning(seed, n=720):
    """Readings N×2 of two sensor axes while the vehicle turns twice, and the calibration A = W⁻¹ (symmetric)."""
    rng = np.random.default_rng(seed)
    psi = np.cumsum(rng.uniform(0.2, 1.8, n))  # uneven turning speed
    psi = psi / psi[-1] * 4 * np.pi
    W = soft_iron()
    m = np.column_stack([H * np.cos(psi), H * np.sin(psi)]) @ W.T + B + rng.normal(0.0, SIGMA, (n, 2))
    return m, np.linalg.inv(W)


def write_log(path, m, names=("Bx", "By"), unit="uT", time=True):
    cells = [f"{n} [{unit}]" if unit else n for n in names]
    head = ",".join((["time_s"] if time else []) + cells)
    rows = "".join((f"{0.1 * k:.1f}," if time else "") + f"{x:.5f},{y:.5f}\n" for k, (x, y) in enumerate(m))
    path.write_text(head + "\n" + rows)
    return path


def run(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_a_two_column_log_is_read_as_a_biaxial_sensor(tmp_path):
    m, _ = turning(1, n=20)
    rec = fluxcal.read_recording(write_log(tmp_path / "a.csv", m))
    assert rec.biaxial() and rec.mag_names() == ("Bx", "By") and rec.biaxial_axes == "xy"
    assert rec.field_units() == "uT" and rec.time() is not None
    np.testing.assert_allclose(rec.samples(biaxial=True), np.round(m, 5))
    assert "biaxial: axes x, y by their names" in rec.roles()["magnetometer"]
    # the axes come from the names, in axis order whatever the columns' order
    for names, axes in ((("mag_z", "mag_y"), "yz"), (("hx", "hz"), "xz"), (("x", "y"), "xy"), (("my", "mx"), "xy")):
        rec = fluxcal.read_recording(write_log(tmp_path / "b.csv", m, names, unit=None, time=False))
        assert rec.biaxial_axes == axes and [n[-1] for n in rec.mag_names()] == list(axes), names
    # three columns stay a three-axis sensor
    three = tmp_path / "c.csv"
    three.write_text("mx,my,mz\n" + "".join(f"{x},{y},1.0\n" for x, y in m))
    rec = fluxcal.read_recording(three)
    assert not rec.biaxial() and rec.samples().shape == (20, 3) and rec.biaxial_axes is None
    # a .npz of two vectors (a NumPy user's save) shares the rule
    np.savez(tmp_path / "d.npz", Bx=m[:, 0], Bz=m[:, 1])
    rec = fluxcal.read_recording(tmp_path / "d.npz")
    assert rec.mag_names() == ("Bx", "Bz") and rec.biaxial_axes == "xz"


def test_cli_calibrates_a_two_column_csv_and_apply_writes_its_two_corrected_columns(tmp_path, capsys):
    m, A = turning(2)
    log = write_log(tmp_path / "car.csv", m)
    code, out, err = run(capsys, "calibrate", log, "--planar", "--field-norm", H, "-o", tmp_path / "cal.json")
    assert code == 0, err
    assert "magnetometer Bx,By (biaxial: axes x, y by their names)" in out
    assert "plane                 x, y (a biaxial sensor)" in out and "wrote" in out
    cal = Calibration.load(tmp_path / "cal.json")
    s = cal.summary
    assert s["biaxial"] and s["plane_axes"] == ["x", "y"] and s["shape"] == "sym"
    truth = dict(zip(["b_x", "b_y", "a_xx", "a_xy", "a_yy"], [*B, A[0, 0], A[0, 1], A[1, 1]]))
    z = {n: (p - truth[n]) / se for n, p, se in zip(s["parameter_names"], s["parameters"], s["standard_errors"])}
    assert set(z) == set(truth) and all(abs(v) < Z_LIMIT for v in z.values()), z
    np.testing.assert_allclose(cal.offset, [*s["parameters"][:2], 0.0])
    assert cal.units == "uT" and cal.metadata["columns"] == "Bx,By"
    # apply: the two corrected columns (no hz: there is no z reading), in h's unit; |h| flat
    code, out, err = run(capsys, "apply", tmp_path / "cal.json", log, "-o", tmp_path / "out.csv")
    assert code == 0, err
    assert "corrected columns hx,hy (horizontal |h| std/mean" in out and "warning" not in out
    res = fluxcal.read_recording(tmp_path / "out.csv")
    assert list(res.columns) == ["time_s", "Bx", "By", "hx", "hy"] and res.units["hx"] == "uT"
    h = np.column_stack([res.columns["hx"], res.columns["hy"]])
    np.testing.assert_allclose(h, (np.round(m, 5) - B) @ A.T, atol=10 * SIGMA)
    spread = lambda v: np.std(np.linalg.norm(v, axis=1)) / np.mean(np.linalg.norm(v, axis=1))  # noqa: E731
    assert spread(m) > 0.2 and spread(h) < 2 * SIGMA / H
    # export-c takes the calibration as it takes a three-axis one's
    code, out, err = run(capsys, "export-c", tmp_path / "cal.json", "-o", tmp_path / "cal.h")
    assert code == 0, err


def test_the_axes_come_from_the_names_or_planar_and_apply_keeps_them(tmp_path, capsys):
    m, _ = turning(3)
    xz = write_log(tmp_path / "xz.csv", m, ("Bx", "Bz"))
    code, out, err = run(capsys, "calibrate", xz, "--planar", "-o", tmp_path / "xz.json")
    assert code == 0, err
    cal = Calibration.load(tmp_path / "xz.json")
    assert cal.summary["plane_axes"] == ["x", "z"] and cal.summary["not_calibrated"]["axis"] == "y"
    code, out, err = run(capsys, "apply", tmp_path / "xz.json", xz, "-o", tmp_path / "xz_out.csv")
    assert code == 0 and "corrected columns hx,hz" in out, err
    assert {"hx", "hz"} <= set(fluxcal.read_recording(tmp_path / "xz_out.csv").columns)
    # names and --planar disagree: said, not guessed
    code, out, err = run(capsys, "calibrate", xz, "--planar", "yz")
    assert code == 2 and "columns Bx, Bz are the sensor's x and z axes by their names, and --planar yz" in err
    code, out, err = run(capsys, "apply", tmp_path / "xz.json", write_log(tmp_path / "xy.csv", m), "-o",
                         tmp_path / "o.csv")
    assert code == 2 and "the calibration" in err and "x and z" in err
    # names that say no axis (chosen with --columns): x,y unless --planar states them, said either way
    plain = write_log(tmp_path / "ch.csv", m, ("ch1", "ch2"))
    code, out, err = run(capsys, "calibrate", plain, "--columns", "ch1,ch2", "--planar")
    assert code == 0 and "taken as axes x, y, the names do not say which" in out, err
    code, out, err = run(capsys, "calibrate", plain, "--columns", "ch1,ch2", "--planar", "yz", "-o",
                         tmp_path / "yz.json")
    assert code == 0 and "biaxial: axes y, z by --planar yz" in out, err
    assert Calibration.load(tmp_path / "yz.json").summary["plane_axes"] == ["y", "z"]
    code, out, err = run(capsys, "apply", tmp_path / "yz.json", plain, "--columns", "ch1,ch2", "-o",
                         tmp_path / "yz_out.csv")
    assert code == 0 and "taken as the calibration's axes y, z" in out and "corrected columns hy,hz" in out, err
    # a table without a header: --columns names its two columns
    bare = tmp_path / "bare.csv"
    bare.write_text("".join(f"{x:.5f},{y:.5f}\n" for x, y in m))
    code, out, err = run(capsys, "calibrate", bare, "--columns", "a,b", "--planar")
    assert code == 0 and "magnetometer a,b (biaxial: taken as axes x, y" in out, err


def test_what_needs_three_axes_refuses_two_columns_naming_the_file(tmp_path, capsys):
    m, _ = turning(4, n=200)
    log = write_log(tmp_path / "car.csv", m)
    for argv in (["calibrate", log], ["diagnose", log]):
        code, out, err = run(capsys, *argv)
        assert code == 2 and f"{log}: 2 field columns (Bx, By" in err and "fluxcal calibrate --planar" in err, err
    with pytest.raises(ValueError, match="2 field columns .*calibrate --planar"):
        fluxcal.read_recording(log).samples()
    with pytest.raises(ValueError, match="2 field columns"):
        fluxcal.calibrate(fluxcal.read_recording(log))
    # a 3-D calibration applied to two columns
    three = tmp_path / "three.csv"
    fluxcal.write_csv(three, _three_axis(300))
    assert run(capsys, "calibrate", three, "-o", tmp_path / "3d.json")[0] == 0
    code, out, err = run(capsys, "apply", tmp_path / "3d.json", log, "-o", tmp_path / "o.csv")
    assert code == 2 and "2 field columns" in err and "is a 3-D calibration" in err, err
    assert not (tmp_path / "o.csv").exists()
    # the refusal is all it says: no unit conversion (µT log, nT calibration) printed before it as if made
    nt = tmp_path / "3d_nT.json"
    fluxcal.write_csv(three, _three_axis(300), units={c: "nT" for c in ("mx", "my", "mz")})
    assert run(capsys, "calibrate", three, "-o", nt)[0] == 0
    code, out, err = run(capsys, "apply", nt, log, "-o", tmp_path / "o.csv")
    assert code == 2 and "is a 3-D calibration" in err and "converted" not in out, out


def _three_axis(n):
    from conftest import simulated

    s = simulated(5, n=n)
    return {"mx": s.readings[:, 0], "my": s.readings[:, 1], "mz": s.readings[:, 2]}


def test_one_column_or_a_third_axis_left_out_is_no_biaxial_sensor(tmp_path, capsys):
    one = tmp_path / "one.csv"
    one.write_text("bx\n" + "".join(f"{v}\n" for v in range(20)))
    for argv in (["calibrate", one, "--planar"], ["calibrate", one]):
        code, out, err = run(capsys, *argv)
        assert code == 2 and f"{one}: one column (bx)" in err and "two of a biaxial sensor" in err, err
    # mz written as text (a logger's "ovf") is left out: mx,my are not taken for a biaxial sensor
    m, _ = turning(6, n=20)
    cut = tmp_path / "cut.csv"
    cut.write_text("mx,my,mz\n" + "".join(f"{x:.4f},{y:.4f},ovf\n" for x, y in m))
    code, out, err = run(capsys, "calibrate", cut, "--planar")
    assert code == 2 and "no magnetometer columns" in err and "left out as text: mz" in err, err


def test_a_headerless_two_column_file_reads_biaxial_in_python(tmp_path):
    """read_recording(file, columns="a,b") of a table without a header: the two named columns are the biaxial
    magnetometer (the CLI selected them; Python had left no magnetometer found)."""
    import fluxcal

    path = tmp_path / "two.txt"
    path.write_text("".join(f"{20 * np.cos(a) + 3:.4f} {20 * np.sin(a) - 1:.4f}\n" for a in np.linspace(0, 12, 300)))
    rec = fluxcal.read_recording(path, columns="a,b")
    assert rec.biaxial() and rec.mag_names() == ("a", "b") and rec.samples(biaxial=True).shape == (300, 2)


def test_a_headerless_biaxial_log_with_its_clock_names_its_columns(tmp_path, capsys):
    """A headerless t, x, y log named by --columns t,mx,my: the clock and a biaxial sensor's two axes (the clock
    had been refused as a third magnetometer axis, with the advice to name it mz)."""
    m, truth = turning(8, n=600)
    path = tmp_path / "car.txt"
    path.write_text("".join(f"{0.1 * k:.1f},{x:.5f},{y:.5f}\n" for k, (x, y) in enumerate(m)))
    rec = fluxcal.read_recording(path, columns="t,mx,my")
    assert rec.biaxial() and rec.mag_names() == ("mx", "my") and rec.time() is not None
    code, out, err = run(capsys, "calibrate", path, "--planar", "--columns", "t,mx,my", "--field-norm", H,
                         "-o", tmp_path / "cal.json")
    assert code == 0 and "time t" in out, err
    cal = Calibration.load(tmp_path / "cal.json")
    se = np.asarray(cal.summary["standard_errors"][:2])
    assert np.all(np.abs(cal.plane["offset"] - B) < Z_LIMIT * se)
    # a clock reset once (a reboot) is still a clock; a three-axis x misnamed t (half its steps back) is not
    path.write_text("".join(f"{0.1 * (k % 400):.1f},{x:.5f},{y:.5f}\n" for k, (x, y) in enumerate(m)))
    assert fluxcal.read_recording(path, columns="t,mx,my").mag_names() == ("mx", "my")
    path.write_text("".join(f"{x:.5f},{y:.5f},{x - y:.5f}\n" for x, y in m))
    with pytest.raises(ValueError, match="column 't' is chosen as a magnetometer axis"):
        fluxcal.read_recording(path, columns="t,mx,my").mag_names()


def test_a_biaxial_header_tests_its_absent_axis_at_zero(tmp_path, capsys):
    """export-c of a biaxial calibration: its self-test's inputs read 0 on the axis the sensor does not have, as
    the header tells the firmware to give (they had held ±|h| there)."""
    from fluxcal.export_c import fixed_point, vector_inputs

    m, _ = turning(9, n=400)
    cal = fluxcal.calibrate_planar(fluxcal.read_recording(write_log(tmp_path / "a.csv", m, names=("Bx", "Bz"))))
    inputs = vector_inputs(fixed_point(cal))
    assert cal.summary["not_calibrated"]["axis"] == "y" and np.all(inputs[:, 1] == 0)
    assert len(np.unique(inputs, axis=0)) == len(inputs) and np.any(inputs[:, 2] != 0)


def test_a_misnamed_third_axis_or_a_position_is_no_biaxial_sensor():
    """Review: mx,my,mz_uT and mag_x,mag_y,mag_z_bad read as a biaxial sensor, the z axis dropped unsaid; bare x,y
    beside lat,lon (a car's position) read as a magnetometer."""
    from fluxcal.io.recording import Recording

    columns = lambda *names: {n: np.arange(50.0) for n in names}  # noqa: E731
    for names in (("mx", "my", "mz_uT"), ("mag_x", "mag_y", "mag_z_bad")):
        with pytest.raises(ValueError, match=f"column {names[2]} its z axis in another form"):
            Recording(columns=columns(*names), source="f.csv").mag_names()
    with pytest.raises(ValueError, match="no magnetometer columns"):
        Recording(columns=columns("t", "lat", "lon", "x", "y", "hdg"), source="f.csv").mag_names()
    assert Recording(columns=columns("t", "x", "y"), source="f.csv").mag_names() == ("x", "y")
    assert Recording(columns=columns("t", "lat", "x", "y"), units={"x": "uT", "y": "uT"},
                     source="f.csv").mag_names() == ("x", "y")


def test_a_biaxial_calibration_prints_and_saves_its_two_axes(tmp_path, capsys):
    """The printout shows the 2 offsets and the 2×2 matrix of the sensor's own axes (not the 3×3 it is stored as, which
    passes a third column through), and the JSON a "plane" block beside the offset and matrix fluxcal loads."""
    m, A = turning(3)
    log = write_log(tmp_path / "car.csv", m, names=("mag_x", "mag_z"))
    code, out, err = run(capsys, "calibrate", log, "--planar", "--field-norm", H, "-o", tmp_path / "cal.json")
    assert code == 0, err
    assert "biaxial x, z (planar): h = A (m - b)" in out and "offset b (x, z) = [" in out
    matrix_rows = out.split("matrix A (x, z) =\n")[1].splitlines()[:3]
    assert matrix_rows[0].count("[") == 1 and matrix_rows[1].count("[") == 1 and "[" not in matrix_rows[2]
    cal = Calibration.load(tmp_path / "cal.json")
    plane = cal.plane
    assert plane["axes"] == "xz"
    np.testing.assert_allclose(plane["offset"], cal.offset[[0, 2]])
    np.testing.assert_allclose(plane["matrix"], cal.matrix[np.ix_([0, 2], [0, 2])])
    np.testing.assert_allclose(plane["offset"], B, atol=Z_LIMIT * max(cal.summary["standard_errors"][:2]))
    saved = json.loads((tmp_path / "cal.json").read_text())["plane"]
    assert saved["axes"] == "xz" and np.allclose(saved["matrix"], plane["matrix"]) and "fluxcal loads" in saved["note"]
    # a three-axis sensor's planar calibration keeps its 3×3 printout (the third axis is read, and passes through);
    # a 3-D calibration has no plane
    three = fluxcal.calibrate_planar(np.column_stack([m, np.full(len(m), 40.0)]), field_norm=H)
    assert three.plane["axes"] == "xy" and "offset b = [" in str(three) and "plane" in three.to_dict()
    assert Calibration(offset=np.zeros(3), matrix=np.eye(3), field_norm=1.0).plane is None
