"""The seventy-sixth session's reader additions: values written with their unit in each cell ("12.3uT"), and
LabVIEW measurement files (.lvm)."""
import numpy as np
import pytest

import fluxcal
from conftest import run_cli


def _sphere(n=200, seed=0, radius=48.0, offset=(5.0, -3.0, 2.0)):
    v = np.random.default_rng(seed).standard_normal((n, 3))
    return radius * v / np.linalg.norm(v, axis=1, keepdims=True) + offset


@pytest.mark.parametrize("space", ["", " "])
def test_a_unit_after_every_value_is_read_as_that_unit(tmp_path, space):
    # (had been: "no magnetometer columns … left out as text: mx (e.g. -0.39uT, …)")
    m = _sphere()
    path = tmp_path / "cells.csv"
    path.write_text("time,mx,my,mz,temp\n" + "".join(
        f"{k * 0.02:.2f},{a:.3f}{space}uT,{b:.3f}{space}uT,{c:.3f}{space}uT,{20 + k / 100:.2f}{space}°C\n"
        for k, (a, b, c) in enumerate(m)))
    rec = fluxcal.read_recording(path)
    np.testing.assert_allclose(rec.samples(), m, atol=6e-4)
    assert rec.units["mx"] == "uT" and rec.units["temp"] == "°C"
    assert "mx: uT" in rec.metadata["units_in_cells"]
    out = run_cli("calibrate", str(path))
    assert out.returncode == 0, out.stderr
    assert "units in the cells: mx: uT" in out.stdout and "|h| = 48" in out.stdout and "uT" in out.stdout


def test_a_unit_in_the_cells_against_another_in_the_header_is_named(tmp_path):
    path = tmp_path / "conflict.csv"
    path.write_text("t,mx [nT],my [nT],mz [nT]\n" + "".join(f"{k},{a:.2f}uT,{b:.2f}uT,{c:.2f}uT\n"
                                                            for k, (a, b, c) in enumerate(_sphere(30))))
    with pytest.raises(ValueError, match=r"column 'mx' is in nT by the header and its cells read .*uT"):
        fluxcal.read_recording(path)


def test_units_that_change_down_a_column_are_not_taken(tmp_path):
    path = tmp_path / "mixed.csv"
    path.write_text("t,mx,my,mz\n" + "".join(f"{k},{a:.2f}uT,{b:.2f}uT,{c:.2f}{'nT' if k % 2 else 'uT'}\n"
                                             for k, (a, b, c) in enumerate(_sphere(30))))
    rec = fluxcal.read_recording(path)  # (mx, my: a biaxial sensor's pair; mz named as text)
    assert "mz" not in rec.columns and "mz (e.g." in rec.metadata["text_columns"] and "nT" in rec.metadata["text_columns"]


def _lvm(path, segments, separator="\t", decimal=".", x_columns="One", units=("uT", "uT", "uT"), bad_row=None):
    """A LabVIEW measurement file of `segments` (each an N×3 array of Mag X/Y/Z at 50 Hz)."""
    sep = separator
    out = ["LabVIEW Measurement" + sep, "Writer_Version" + sep + "2", "Reader_Version" + sep + "2",
           "Separator" + sep + ("Tab" if sep == "\t" else "Comma"), "Decimal_Separator" + sep + decimal,
           "Multi_Headings" + sep + "No", "X_Columns" + sep + x_columns, "Time_Pref" + sep + "Relative",
           "Operator" + sep + "bench", "Date" + sep + "2026/12/08", "Time" + sep + "10:00:00", "***End_of_Header***",
           ""]
    t0 = 0.0
    for seg in segments:
        out += ["Channels" + sep + sep.join(["3"] * 1), "Samples" + sep + sep.join([str(len(seg))] * 3),
                "Y_Unit_Label" + sep + sep.join(units), "X_Dimension" + sep + sep.join(["Time"] * 3),
                "X0" + sep + sep.join(["0"] * 3), "Delta_X" + sep + sep.join(["0.02"] * 3),
                "***End_of_Header***" + sep]
        heads = (["X_Value"] if x_columns != "No" else [])
        for name in ("Mag X", "Mag Y", "Mag Z"):
            heads += [name] + (["X_Value"] if x_columns == "Multi" else [])
        out.append(sep.join(heads[:1] + heads[1:] + ["Comment"]) if x_columns != "Multi"
                   else sep.join(["X_Value", "Mag X", "X_Value", "Mag Y", "X_Value", "Mag Z", "Comment"]))
        for k, row in enumerate(seg):
            t = f"{t0 + 0.02 * k:.2f}"
            vals = [f"{v:.4f}" for v in row]
            cells = ([t] + vals if x_columns == "One" else vals if x_columns == "No"
                     else [t, vals[0], t, vals[1], t, vals[2]])
            line = sep.join(cells) + sep
            out.append(line.replace(".", ",") if decimal == "," else line)
        t0 += 0.02 * len(seg)
        out.append("")
    if bad_row is not None:
        out[bad_row] = out[bad_row].replace(out[bad_row].split(sep)[2], "garbled", 1)
    path.write_text("\n".join(out) + "\n")
    return out


@pytest.mark.parametrize("layout", [dict(), dict(separator=",", x_columns="No"), dict(decimal=",", separator="\t"),
                                    dict(x_columns="Multi")])
def test_a_labview_measurement_file_is_read(tmp_path, layout):
    # (had been: "line 18: header 'X_Dimension\tTime\tTime\tTime\t' has empty or repeated column names")
    m = _sphere()
    path = tmp_path / "bench.lvm"
    _lvm(path, [m[:120], m[120:]], **layout)
    rec = fluxcal.read_recording(path)
    np.testing.assert_allclose(rec.samples(), m, atol=6e-5)
    assert list(rec.mag_names()) == ["Mag X", "Mag Y", "Mag Z"] and rec.units["Mag X"] == "uT"
    assert rec.metadata["format"] == "LabVIEW measurement (.lvm), 2 segments"
    if layout.get("x_columns", "One") != "No":
        assert rec.units["time"] == "s"
        np.testing.assert_allclose(np.diff(rec.columns["time"]), 0.02, atol=1e-9)
    cal = fluxcal.calibrate(rec)
    np.testing.assert_allclose(cal.offset, [5.0, -3.0, 2.0], atol=1e-3)


def test_a_garbled_lvm_line_is_named_by_its_line_in_the_file(tmp_path):
    path = tmp_path / "bench.lvm"
    lines = _lvm(path, [_sphere(50)], bad_row=30)
    with pytest.raises(ValueError, match=r"bench\.lvm, line 31, column 'Mag Y': 'garbled'"):
        fluxcal.read_recording(path)
    assert "garbled" in lines[30]


def test_lvm_segments_of_other_channels_are_refused(tmp_path):
    path = tmp_path / "two.lvm"
    _lvm(path, [_sphere(20), _sphere(20, seed=1)])
    path.write_text(path.read_text().replace("X_Value\tMag X\tMag Y\tMag Z\tComment", "X_Value\tBx\tBy\tBz\tComment")
                    .replace("X_Value\tBx\tBy\tBz\tComment", "X_Value\tMag X\tMag Y\tMag Z\tComment", 1))
    with pytest.raises(ValueError, match=r"line 50: segment 2 names the channels X_Value, Bx, By, Bz, the first segment X_Value, Mag X"):
        fluxcal.read_recording(path)


def test_a_ring_conductor_beyond_the_bore_is_said_with_its_distance_and_the_printed_number(tmp_path):
    """A 3-core cable off-centre, one conductor 4.157 mm out (the default bore: 4 mm), reference currents i0..i2 and no
    positions: found right, but said "conductor 0 ended on the bore's edge (4 mm from the ring's centre)" — the
    solver's own numbering, not the printed one, and the bore's radius for the conductor's (a blind check)."""
    from fluxcal import cable

    ring = cable.Ring(np.arange(8) * 45.0, 0.010)
    a = np.radians(90.0 + 120.0 * np.arange(3))
    pos = np.column_stack([-1.8e-3 + 2.5e-3 * np.cos(a), 2.5e-3 * np.sin(a)])  # radii 3.08, 4.157, 1.30 mm
    cur = np.array([[10.0, -4.0, -6.0]])
    wide = cable.Ring(ring.angles_deg, ring.radius_m, bore_radius_m=6e-3)  # (the field refuses it beyond the bore)
    y = wide.field(pos, cur) + 1e-8 * np.random.default_rng(0).standard_normal((1, 8, 2))
    path = tmp_path / "meas.csv"
    cable.write_ring_csv(path, ring, y, np.zeros(1), cur)
    out = run_cli("cable", "solve", str(path), "--conductors", "3", "--noise-sigma", "1e-8")
    printed = next(line for line in out.stdout.splitlines() if line.startswith("snapshot 0:"))
    first = printed.split(": ", 1)[1].split("; ")[:3]
    radii = [np.hypot(*[float(v.split(" ± ")[0]) for v in c.strip("() mm").split(", ")]) for c in first]
    beyond = int(np.argmax(radii))
    assert abs(radii[beyond] - 4.157) < 0.01, radii
    warned = [line for line in out.stdout.splitlines() if "from the ring's centre" in line]
    assert warned and f"conductor {beyond} ended 4.15" in warned[0] and "beyond the bore (radius 4 mm" in warned[0], \
        out.stdout


def test_a_ring_files_lengths_take_their_unit(tmp_path):
    # (a blind check: `ring_radius_m: 10 mm` gave "could not convert string to float: '10 mm'", naming no key)
    from fluxcal import cable

    ring = cable.Ring(np.arange(8) * 45.0, 0.010)
    pos = np.array([[1e-3, 0.0], [-1e-3, 0.0]])
    path = tmp_path / "ring.csv"
    cable.write_ring_csv(path, ring, ring.field(pos, np.array([[5.0, -5.0]])), np.zeros(1), np.array([[5.0, -5.0]]))
    text = path.read_text()
    assert "# ring_radius_m: 0.01" in text
    (tmp_path / "mm.csv").write_text(text.replace("# ring_radius_m: 0.01", "# ring_radius_m: 10 mm"))
    assert cable.read_ring_csv(tmp_path / "mm.csv")["ring"].radius_m == pytest.approx(0.010)
    (tmp_path / "bad.csv").write_text(text.replace("# ring_radius_m: 0.01", "# ring_radius_m: 10 furlongs"))
    with pytest.raises(ValueError, match=r"ring_radius_m: '10 furlongs' is not a length"):
        cable.read_ring_csv(tmp_path / "bad.csv")


def test_a_joint_solves_dropped_reading_is_said_by_snapshot_not_as_a_dead_sensor(tmp_path):
    # (a blind check: one NaN in snapshot 2 of 12 read "snapshots 0–11: sensor(s) 0 not finite (dead?)")
    from fluxcal import cable

    ring = cable.Ring(np.arange(8) * 45.0, 0.010)
    pos = np.array([[1.5e-3, 0.5e-3], [-1.5e-3, 0.5e-3], [0.0, -1.6e-3]])
    phase = 2 * np.pi * np.arange(12) / 12
    cur = 10.0 * np.cos(phase[:, None] + np.radians([0.0, -120.0, 120.0])[None])
    y = ring.field(pos, cur) + 1e-8 * np.random.default_rng(1).standard_normal((12, 8, 2))
    y[2, 0, 1] = np.nan
    path = tmp_path / "meas.csv"
    cable.write_ring_csv(path, ring, y, np.zeros(12), cur)
    out = run_cli("cable", "solve", str(path), "--conductors", "3", "--joint", "--noise-sigma", "1e-8")
    assert "sensor 0 not finite in snapshot(s) 2 (left out of all 12 solved together" in out.stdout, out.stdout
    assert "dead?" not in out.stdout


def test_review_of_the_readers_mends(tmp_path):
    """A review: a garbled first cell in a segment before the last had been taken for the next segment's header, the
    rest of the segment dropped unsaid; a bad line in a file of glued units was named as line 2's first cell."""
    path = tmp_path / "two.lvm"
    lines = _lvm(path, [_sphere(40), _sphere(40, seed=1)])
    k = next(i for i, line in enumerate(lines) if line.startswith("0.20\t"))  # a row of the first segment
    lines[k] = "garbled" + lines[k][4:]
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=rf"two\.lvm, line {k + 1}, column 'time': 'garbled' is not a number"):
        fluxcal.read_recording(path)
    glued = tmp_path / "glued.csv"
    rows = [f"{k},{a:.2f}uT,{b:.2f}uT,{c:.2f}uT" for k, (a, b, c) in enumerate(_sphere(60))]
    rows[50] = rows[50].rsplit(",", 2)[0] + ",,1.0uT"
    glued.write_text("t,mx,my,mz\n" + "\n".join(rows) + "\n")
    with pytest.raises(ValueError, match=r"glued\.csv, line 52: column 'my': empty"):
        fluxcal.read_recording(glued)


def test_a_zero_bias_names_unit_is_spelt_as_a_unit(tmp_path, capsys):
    # (a review: zero_bias_a, phase a, had been read as amperes; _ma, a moving average, as mA)
    from fluxcal.cli import main

    temp = np.linspace(-10, 40, 600)
    t = np.arange(temp.size, dtype=float)
    for name, unit in (("zero_bias_a", None), ("zero_bias_ma", None), ("zero_bias_mA", "mA")):
        path = tmp_path / f"{name}.csv"
        fluxcal.write_csv(path, {"t": t, name: 2 + 0.05 * temp + np.random.default_rng(0).normal(0, 0.5, t.size),
                                 "temp": temp})
        assert main(["drift", "fit", str(path), "--column", name, "-o", str(tmp_path / "m.json")]) == 0
        out = capsys.readouterr().out
        assert (f"note: {name}: in {unit}, by its name" in out) == (unit is not None), out
