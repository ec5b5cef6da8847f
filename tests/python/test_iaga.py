"""IAGA-2002 (geomagnetic observatory data): the vector from each element set, gaps, bad records, appended days,
and the commands on such a file."""
import numpy as np
import pytest

from fluxcal.io import read_recording
from fluxcal.io.formats import sniff

from conftest import run_cli

HEADER = """\
 Format                 IAGA-2002                                    |
 Source of Data         Test Institute                               |
 Station Name           Testville                                    |
 IAGA CODE              TST                                          |
 Geodetic Latitude      55.314                                       |
 Geodetic Longitude     356.794                                      |
 Elevation              245                                          |
 Reported               {elements}                                         |
 Sensor Orientation     HDZF                                         |
 Digital Sampling       0.1 seconds                                  |
 Data Interval Type     Filtered 1-minute (00:15-01:45)              |
 Data Type              variation                                    |
 # written by fluxcal's tests                                        |
DATE       TIME         DOY     TST{0}      TST{1}      TST{2}      TST{3}   |
"""


def field(n=240, seed=0):
    """A quiet day's minutes: X, Y, Z (nT) wandering a few nT about a mid-latitude field."""
    rng = np.random.default_rng(seed)
    wander = np.cumsum(rng.normal(0.0, 0.3, (n, 3)), axis=0)
    return np.array([17300.0, -250.0, 46500.0]) + wander


def write(path, elements, rows, day="2024-03-01", doy=61, start=0, precision=2):
    text = HEADER.format(*elements, elements=elements)
    for k, row in enumerate(rows):
        h, m = divmod(start + k, 60)
        text += f"{day} {h:02d}:{m:02d}:00.000 {doy:03d}    " + " ".join(f"{v:9.{precision}f}" for v in row) + "\n"
    path.write_text(text)
    return path


def test_xyzf_reads_as_a_vector_in_nt_with_its_time_and_header(tmp_path):
    xyz = field()
    f = np.linalg.norm(xyz, axis=1)
    path = write(tmp_path / "tst20240301vmin.min", "XYZF", np.column_stack([xyz, f]))
    assert sniff(path) == "iaga2002"
    rec = read_recording(path)
    np.testing.assert_allclose(rec.samples(), xyz, atol=0.006)
    np.testing.assert_allclose(rec.columns["F"], f, atol=0.006)
    assert rec.field_units() == "nT" and rec.mag_names() == ("X", "Y", "Z")
    np.testing.assert_array_equal(rec.time()[:3], [0.0, 60.0, 120.0])
    assert rec.metadata["t_start"].startswith("2024-03-01T00:00:00")
    assert rec.metadata["iaga_code"] == "TST" and rec.metadata["station_name"] == "Testville"
    assert rec.metadata["iaga_elements"] == "XYZF" and rec.place(0) == "line 15"


def test_hdz_and_dhi_become_the_same_vector(tmp_path):
    xyz = field(seed=1)
    h = np.hypot(xyz[:, 0], xyz[:, 1])
    d = np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0])) * 60.0  # minutes of arc
    i = np.degrees(np.arctan2(xyz[:, 2], h)) * 60.0
    f = np.linalg.norm(xyz, axis=1)
    hdz = read_recording(write(tmp_path / "hdz.min", "HDZF", np.column_stack([h, d, xyz[:, 2], f])))
    dhi = read_recording(write(tmp_path / "dhi.min", "DHIF", np.column_stack([d, h, i, f])))
    # two decimals of D and I (0.01′ = 3e-6 rad, 0.14 nT at 47 000 nT) and of H
    np.testing.assert_allclose(hdz.samples(), xyz, atol=0.1)
    np.testing.assert_allclose(dhi.samples(), xyz, atol=0.3)
    assert "H cos D" in hdz.metadata["vector"] and "H tan I" in dhi.metadata["vector"]
    hez = read_recording(write(tmp_path / "hez.min", "HEZF", np.column_stack([h, np.zeros(len(h)), xyz[:, 2], f])))
    assert "magnetic meridian" in hez.metadata["vector"]


def test_a_dhif_file_in_degrees_is_told_apart_by_its_f(tmp_path):
    # IAGA-2002's angles are minutes of arc; a logger writing degrees gave Z = H tan(I/60): |field| ≈ H, 65 % below
    # F at this 70° inclination. Only degrees match F, so the file is read in degrees, with a warning that says so.
    xyz = field(seed=2)
    h = np.hypot(xyz[:, 0], xyz[:, 1])
    d, i = np.degrees(np.arctan2(xyz[:, 1], xyz[:, 0])), np.degrees(np.arctan2(xyz[:, 2], h))
    f = np.linalg.norm(xyz, axis=1)
    rows = np.column_stack([np.round(d, 4), h, np.round(i, 4), f])
    with pytest.warns(UserWarning, match=r"D and I read in degrees.*missed F by 65\.\d %"):
        rec = read_recording(write(tmp_path / "deg.min", "DHIF", rows, precision=4))
    np.testing.assert_allclose(rec.samples(), xyz, atol=0.3)
    assert "in degrees" in rec.metadata["vector"]
    # the same file without F cannot be told apart: minutes of arc, the format's unit, and so Z ≈ 0.02 H
    not_recorded = np.full(len(rows), 88888.0)
    no_f = read_recording(write(tmp_path / "deg_no_f.min", "DHIF", np.column_stack([rows[:, :3], not_recorded]),
                                precision=4))
    assert "minutes of arc" in no_f.metadata["vector"] and np.all(no_f.samples()[:, 2] < 0.05 * h)


def test_gaps_and_bad_records_are_named_or_left_out_and_listed(tmp_path):
    xyz = field(n=60, seed=2)
    rows = np.column_stack([xyz, np.full(60, 88888.0)])  # F not recorded: left out, not a gap
    rows[7, 1] = 99999.0
    path = write(tmp_path / "gap.min", "XYZF", rows)
    with pytest.raises(ValueError, match=r"gap.min, line 22: TSTY is 99999.00 \(missing\); pass bad_lines='skip'"):
        read_recording(path)
    rec = read_recording(path, bad_lines="skip")
    assert len(rec) == 59 and "F" not in rec.columns
    assert rec.metadata["skipped_lines"] == "1 of 60: 22 (TSTY is 99999.00 (missing))"
    assert rec.time()[7] == 480.0  # the gap stays a gap in time
    rows[7, 1] = xyz[7, 1]
    lines = write(path, "XYZF", rows).read_text().splitlines()
    lines[30] = lines[30][:40] + " x17.3 " + lines[30][47:]
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"gap.min, line 31: 8 fields, an IAGA-2002 record has 7"):
        read_recording(path)
    path.write_text("\n".join(lines[:-1] + [lines[-1][:35]]))  # the file ends inside its last record
    rec = read_recording(path, bad_lines="skip")
    assert "the file ends in the middle of this line" in rec.metadata["skipped_lines"]
    # a garbled date is that record's problem, not the file's (nor a reason to read the others day first)
    rows[:, 3] = np.linalg.norm(xyz, axis=1)
    rows[40, 3] = 88888.0  # one F not recorded: F kept, NaN there
    lines = write(path, "XYZF", rows).read_text().splitlines()
    lines[20] = "2024-13-45" + lines[20][10:]
    lines.insert(3, " Date of file           2024-03-02                                   |")
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"gap.min, line 22: 2024-13-45 '00:06:00.000' is not a date and time"):
        read_recording(path)
    rec = read_recording(path, bad_lines="skip")
    assert len(rec) == 59 and rec.metadata["t_start"].startswith("2024-03-01T00:00:00")
    assert rec.time()[6] == 420.0 and rec.metadata["date_of_file"] == "2024-03-02"
    assert np.isnan(rec.columns["F"][39]) and np.isfinite(rec.columns["F"]).sum() == 58


def test_appended_days_are_read_in_turn_and_must_agree(tmp_path):
    a, b = field(n=30, seed=3), field(n=30, seed=4)
    first = write(tmp_path / "a.min", "XYZF", np.column_stack([a, np.linalg.norm(a, axis=1)]))
    second = write(tmp_path / "b.min", "XYZF", np.column_stack([b, np.linalg.norm(b, axis=1)]), day="2024-03-02",
                   doy=62)
    both = tmp_path / "both.min"
    both.write_text(first.read_text() + second.read_text())
    rec = read_recording(both)
    assert len(rec) == 60 and rec.time()[30] == 86400.0
    other = write(tmp_path / "c.min", "HDZF", np.column_stack([b[:, 0], b[:, 1] * 0, b[:, 2], b[:, 0]]))
    both.write_text(first.read_text() + other.read_text())
    with pytest.raises(ValueError, match=r"both.min, line 58: elements HDZF after XYZF"):
        read_recording(both)


def test_calibrate_reads_an_observatory_file(tmp_path):
    """An observatory's vector does not turn: calibrate reads the file and says it cannot determine an ellipsoid
    from it, naming the file."""
    xyz = field(n=600, seed=5)
    path = write(tmp_path / "tst.min", "XYZF", np.column_stack([xyz, np.linalg.norm(xyz, axis=1)]))
    r = run_cli("calibrate", path)
    assert r.returncode == 2 and "tst.min" in r.stderr and "the readings hardly change" in r.stderr, r.stderr
    assert "magnetometer X,Y,Z" in r.stdout, r.stdout


def test_an_observatorys_f_gives_each_readings_field_at_its_clock_time(tmp_path):
    """`calibrate --field-norm obs.min`: the observatory's F, logged a minute apart, interpolated at the clock
    times of a sensor turned during a storm's ±1 % change; refused where the times do not meet."""
    from conftest import simulated

    n = 900
    s = simulated(8, n=n, noise=0.002)
    seconds = 600.0 + 0.5 * np.arange(n)  # 00:10:00 to 00:17:29.5 UT, two readings a second
    minutes = np.arange(0, 30)
    f_obs = 50000.0 * (1 + 0.01 * np.sin(minutes / 4.0))
    k = np.interp(seconds, 60.0 * minutes, f_obs) / 50000.0
    b = s.true_calibration().offset
    readings = b + k[:, None] * (s.clean - b) + (s.readings - s.clean)
    stamps = [f"2024-03-01T00:{int(x // 60):02d}:{x % 60:04.1f}Z" for x in seconds]
    sensor = tmp_path / "sensor.csv"
    sensor.write_text("time,mx,my,mz\n" + "".join(f"{t},{x:.10g},{y:.10g},{z:.10g}\n"
                                               for t, (x, y, z) in zip(stamps, readings)))
    xyz = np.column_stack([np.zeros(30), np.zeros(30), f_obs])
    obs = write(tmp_path / "obs.min", "XYZF", np.column_stack([xyz, f_obs]))
    run = run_cli("calibrate", sensor, "--field-norm", obs, "-o", tmp_path / "cal.json")
    assert run.returncode == 0, run.stderr
    assert "field norm of each reading from" in run.stdout and "its column F (nT)" in run.stdout, run.stdout
    import fluxcal

    api = fluxcal.calibrate(readings, field_norm=50000.0 * k)
    np.testing.assert_allclose(fluxcal.Calibration.load(tmp_path / "cal.json").offset, api.offset, rtol=1e-6)
    run = run_cli("diagnose", sensor, "--field-norm", obs, "--quiet")  # the diagnosis takes it the same way
    assert run.returncode == 0, run.stderr
    assert "its column F (nT)" in run.stdout and "(|h| fitted to each reading's own |field|" in run.stdout, run.stdout
    late = write(tmp_path / "late.min", "XYZF", np.column_stack([xyz, f_obs]), start=60)  # 01:00 onwards
    run = run_cli("calibrate", sensor, "--field-norm", late)
    assert run.returncode == 2 and "it covers 2024-03-01 01:00:00 UTC to 2024-03-01 01:29:00 UTC" in run.stderr
    assert "sensor.csv, line 2, reads at 2024-03-01 00:10:00 UTC, outside it" in run.stderr, run.stderr
    # times of day without a date are no clock times to match an observatory's by
    sensor.write_text("time,mx,my,mz\n" + "".join(f"{t[11:]},{x:.10g},{y:.10g},{z:.10g}\n"
                                               for t, (x, y, z) in zip(stamps, readings)))
    run = run_cli("calibrate", sensor, "--field-norm", obs)
    assert run.returncode == 2 and "sensor.csv has no clock time (a time column of dates and times" in run.stderr, \
        run.stderr
