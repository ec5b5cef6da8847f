import numpy as np
import pytest

from fluxcal.io import read_csv, write_csv


def test_round_trip_keeps_columns_units_and_metadata(tmp_path):
    t = np.arange(5) * 0.02
    cols = {"t": t, "mx": t + 1, "my": t - 2, "mz": 3 * t, "temp": 20 + t}
    path = write_csv(tmp_path / "r.csv", cols, units={"t": "s", "mx": "uT", "my": "uT", "mz": "uT", "temp": "degC"},
                     metadata={"sensor": "RM3100"})
    rec = read_csv(path)
    assert list(rec.columns) == ["t", "mx", "my", "mz", "temp"]
    np.testing.assert_allclose(rec.samples(), np.column_stack([t + 1, t - 2, 3 * t]))
    assert rec.field_units() == "uT" and rec.units["temp"] == "degC"
    assert rec.metadata["sensor"] == "RM3100"
    assert len(rec) == 5


def test_units_in_header_cells_and_other_column_names(tmp_path):
    p = tmp_path / "h.csv"
    p.write_text("x [G],y [G],z [G]\n0.1,0.2,0.3\n0.4,0.5,0.6\n")
    rec = read_csv(p)
    assert rec.field_units() == "G"
    np.testing.assert_allclose(rec.samples()[1], [0.4, 0.5, 0.6])
    p.write_text("a,b,c,d\n1,2,3,4\n")
    np.testing.assert_allclose(read_csv(p, columns="b,c,d", units="counts").samples(), [[2, 3, 4]])
    assert read_csv(p, columns="b,c,d", units="counts").field_units() == "counts"


@pytest.mark.parametrize("body, message", [
    ("mx,my,mz\n1,2,3\n4,abc,6\n", r"bad.csv, line 3, column 'my': 'abc' is not a number"),
    ("mx,my,mz\n1,2,3\n4,,6\n", r"bad.csv, line 3, column 'my': empty"),
    ("# units: mx=nT\nmx,my,mz\n1,2,3\n4,5\n", r"bad.csv, line 4: 2 fields, the header has 3"),
    ("1,2,3\n4,5,6\n", r"bad.csv, line 1: 3 comma-separated numbers and no header; name the columns"),
    ("mx,my,mz\n", r"bad.csv: header but no data rows"),
    ("", r"bad.csv: no header line"),
    ("mx,mx,mz\n1,2,3\n", r"bad.csv, line 1: header .* repeated"),
    ("# units: furlongs\nmx,my,mz\n1,2,3\n", r"bad.csv, line 1: units 'furlongs' is no field unit"),
    ("# units: x=nT, uT\nmx,my,mz\n1,2,3\n", r"bad.csv, line 1: units entry 'uT' is not name=unit"),
])
def test_reader_errors_name_file_line_and_column(tmp_path, body, message):
    p = tmp_path / "bad.csv"
    p.write_text(body)
    with pytest.raises(ValueError, match=message):
        read_csv(p)


def test_missing_columns_and_missing_file(tmp_path):
    p = tmp_path / "r.csv"
    p.write_text("ax,ay,az\n1,2,3\n")
    with pytest.raises(ValueError, match=r"no magnetometer columns \(looked for mx,my,mz.*columns are: ax, ay, az\)"):
        read_csv(p).samples()
    with pytest.raises(ValueError, match=r"no column 'mz'; columns are: ax, ay, az"):
        read_csv(p, columns="ax,ay,mz")
    with pytest.raises(ValueError, match="cannot read"):
        read_csv(tmp_path / "absent.csv")


def test_nan_cell_is_reported_with_its_file_line(tmp_path):
    p = tmp_path / "n.csv"
    p.write_text("# note: x\nmx,my,mz\n1,2,3\n\n4,nan,6\n")
    rec = read_csv(p)
    with pytest.raises(ValueError, match=r"n.csv: line 5, column 'my' is nan"):
        rec.samples()


def test_readers_refuse_what_is_not_a_recording_file(tmp_path):
    import os

    import fluxcal
    from fluxcal.io import read_npz, read_parquet

    pipe = tmp_path / "pipe"
    os.mkfifo(pipe)  # a named pipe with no writer: every reader blocked forever on it
    for read in (fluxcal.read_recording, read_csv, read_npz):
        with pytest.raises(ValueError, match="pipe: not a regular file"):
            read(pipe)
    with pytest.raises(ValueError, match="a folder, not a recording file"):
        read_parquet(tmp_path)  # returned an empty recording
    nested = tmp_path / "nested.json"
    nested.write_text("[" * 100000 + "]" * 100000)  # RecursionError from the JSON parser
    with pytest.raises(ValueError, match="nested.json: JSON nested too deeply"):
        fluxcal.read_recording(nested)
    path = tmp_path / "g.csv"
    path.write_text("mx,my,mz\n1,2,3\n4,5,1e400\n")
    with pytest.raises(TypeError, match="units: 5 is not a string"):
        fluxcal.read_recording(path, units=5)  # AttributeError: 'int' object has no attribute 'strip'
    with pytest.raises(ValueError, match="mx, mx, mx repeat a name"):
        fluxcal.read_recording(path, columns="mx,mx,mx")  # calibrated one axis three times
    with pytest.raises(ValueError, match=r"line 3, column 'mz' is infinite \(inf, or beyond ±1.8e308\)"):
        fluxcal.read_recording(path).samples()  # the file says 1e400, not inf


def test_writers_refuse_what_the_readers_could_not_take_back(tmp_path):
    from fluxcal.io import Recording, write_recording

    good = {"mx": np.ones(3), "my": np.ones(3), "mz": np.ones(3)}
    cases = [(lambda: write_csv(tmp_path / "a.csv", good, metadata={"note": "a\nb,c"}), "metadata 'note' cannot be"),
             (lambda: write_csv(tmp_path / "b.csv", {"m,x": np.ones(3)}), "column name 'm,x' cannot be"),
             (lambda: Recording(columns={"mx": np.ones((2, 2))}), r"column 'mx' has shape \(2, 2\)"),
             (lambda: write_csv(tmp_path / "c.csv", {"mx": ["a", "b"]}), "column 'mx' is not numbers"),
             (lambda: write_recording(tmp_path / "d.npz", Recording(columns={})), "d.npz: no columns to write")]
    for call, message in cases:  # each was written (or failed) without naming what could not be stored
        with pytest.raises(ValueError, match=message):
            call()
    assert not any(tmp_path.iterdir())


def test_skipping_most_lines_is_refused_as_a_wrong_header(tmp_path):
    import fluxcal

    path = tmp_path / "qmc.csv"  # a QMC5883L logger's preamble above the table
    path.write_text("Fs,100\nGain,2\nt,mx,my,mz\n0,1,2,3\n1,2,3,4\n2,3,4,5\n")
    with pytest.raises(ValueError, match=r"4 of 5 lines do not fit the header on line 1 \(Fs, 100\)"):
        read_csv(path, delimiter=",", bad_lines="skip")  # the plain layout: kept one row, a column named '100'
    for read in (fluxcal.read_recording, read_csv):  # the file's own layout: the header after the preamble
        assert len(read(path, bad_lines="skip")) == 3


def test_nan_and_inf_written_out_are_bad_lines_to_skip(tmp_path):
    """An Arduino prints a failed float read as nan: with bad_lines="skip" such a line is left out as an empty
    cell is (both the fast and the text-column parse); without it the error names the line and the remedy."""
    path = tmp_path / "nan.csv"
    path.write_text("mx,my,mz\n1,2,3\nnan,2,3\n4,5,6\n7,inf,9\n1,1,1\n")
    with pytest.warns(UserWarning, match=r"nan.csv: skipped 2 of 5 lines: 3 .*; 5 .*\(bad_lines='skip'\)"):
        rec = read_csv(path, bad_lines="skip")
    np.testing.assert_array_equal(rec.samples(), [[1, 2, 3], [4, 5, 6], [1, 1, 1]])
    assert rec.metadata["skipped_lines"] == ("2 of 5: 3 (column 'mx': 'nan' is not finite); "
                                             "5 (column 'my': 'inf' is not finite)")
    np.testing.assert_array_equal(rec.line_numbers, [2, 4, 6])
    with pytest.raises(ValueError, match="line 3, column 'mx' is nan .* --bad-lines skip"):
        read_csv(path).samples()
    # a nan before an empty cell is named with it (a blind check's nan on line 103 had gone unnamed beside the empty
    # cell on line 104), after it: a reader that takes NaN (a ring's sensor) stops at the empty cell, not the nan (a
    # later blind check); a column that is nan throughout (no altitude logged) is not bad
    path.write_text("mx,my,mz,alt\n1,2,3,nan\nnan,2,3,nan\n4,,6,nan\n7,8,9,nan\n")
    with pytest.raises(ValueError, match=r"line 4, column 'my': empty \(before it, line 3, column 'mx': 'nan' is not "
                                         r"finite: read as NaN, a failed reading\?\); .*--bad-lines skip"):
        read_csv(path)
    path.write_text("mx,my,mz,alt\n1,2,3,nan\n4,,6,nan\n7,8,9,nan\n")
    with pytest.raises(ValueError, match=r"line 3, column 'my': empty"):
        read_csv(path)
    stamped = tmp_path / "stamped.csv"  # a text (timestamp) column: the slow parse skips them alike
    stamped.write_text("time,mx,my,mz\n2026-01-01T00:00:00,1,2,3\n2026-01-01T00:00:01,NaN,2,3\n"
                       "2026-01-01T00:00:02,4,5,6\n2026-01-01T00:00:03,1,1,1\n")
    with pytest.warns(UserWarning, match="stamped.csv: skipped 1 of 4 lines: 3"):
        assert len(read_csv(stamped, bad_lines="skip")) == 3


def test_arduino_csv_habits(tmp_path):
    """A start-up banner whose line holds commas above the header, and data rows that each end with the
    delimiter under a header that does not (Serial.print(x); Serial.print(",") …)."""
    import fluxcal

    rows = "".join(f"{x:.2f},{-x:.2f},{2 * x:.2f},\n" for x in np.linspace(1, 9, 20))
    path = tmp_path / "arduino.csv"
    path.write_text("Initializing I2C... done\nSensor: QMC5883L, range 8G, ODR 50 Hz\nmx,my,mz\n" + rows)
    rec = fluxcal.read_recording(path)
    assert list(rec.columns) == ["mx", "my", "mz"] and len(rec) == 20
    np.testing.assert_allclose(rec.samples()[0], [1.0, -1.0, 2.0])
    assert "range 8G" in rec.metadata["preamble"]



def test_skipping_keeps_a_column_that_is_never_a_number(tmp_path):
    path = tmp_path / "alt.csv"
    path.write_text("mx,my,mz,alt\n" + "".join(f"{k},{2 * k},{3 * k},nan\n" for k in range(1, 30)) + "1,nan,3,nan\n")
    with pytest.warns(UserWarning, match="alt.csv: skipped 1 of 30 lines: 31"):
        rec = read_csv(path, bad_lines="skip")
    assert len(rec) == 29 and "skipped_lines" in rec.metadata and np.isnan(rec.columns["alt"]).all()


def test_a_banner_of_the_tables_width_on_the_first_line(tmp_path):
    import fluxcal

    rows = "".join(f"{x:.2f},{-x:.2f},{2 * x:.2f},\n" for x in np.linspace(1, 9, 20))
    path = tmp_path / "banner.csv"
    path.write_text("Sensor: QMC5883L, range 8G, ODR 50 Hz\nmx,my,mz\n" + rows)
    rec = fluxcal.read_recording(path)
    assert list(rec.columns) == ["mx", "my", "mz"] and len(rec) == 20


def test_read_csv_takes_the_files_own_delimiter(tmp_path):
    # a spreadsheet's ';' export with decimal commas, its `sep=;` line, and a tab table: read_csv read them as one
    # column and advised skipping every line as garbled; read_recording read them
    rows = [(-19.628, -5.39, -91.966), (-20.58, -5.642, -92.33)]
    bodies = {"semi.csv": "mx;my;mz\n" + "".join(f"{x};{y};{z}\n".replace(".", ",") for x, y, z in rows),
              "excel.csv": "sep=;\nmx;my;mz\n" + "".join(f"{x};{y};{z}\n".replace(".", ",") for x, y, z in rows),
              "tab.txt": "mx\tmy\tmz\n" + "".join(f"{x}\t{y}\t{z}\n" for x, y, z in rows)}
    for name, body in bodies.items():
        (tmp_path / name).write_text(body)
        np.testing.assert_allclose(read_csv(tmp_path / name).samples(), rows)
    with pytest.raises(ValueError, match="the header has 1"):  # a delimiter given is the one used
        read_csv(tmp_path / "semi.csv", delimiter=",")


def _unix(*stamp) -> float:
    import datetime as dt

    return dt.datetime(*stamp, tzinfo=dt.timezone.utc).timestamp()


def test_dotted_dates_are_day_first(tmp_path):
    """01.03.2024 is the 1st of March wherever dates are written with points (German, Russian …); every day ≤ 12
    had been read month-first (3 January). Slash dates stay as they were: month-first when the file cannot say."""
    import fluxcal

    rows = [("12:00:00,000", "-19,628;-5,39;-91,966"), ("12:00:00,020", "-20,58;-5,642;-92,33"),
            ("12:00:00,040", "-21,378;-5,39;-91,49")]
    path = tmp_path / "de.csv"
    path.write_text("Datum/Zeit;mx;my;mz\n" + "".join(f"01.03.2024 {t};{m}\n" for t, m in rows))
    rec = fluxcal.read_recording(path)
    assert rec.metadata["Datum/Zeit_start"].startswith("2024-03-01T12:00:00")
    np.testing.assert_allclose(rec.utc_seconds(), _unix(2024, 3, 1, 12) + np.array([0, 0.02, 0.04]))
    path.write_text("Datum;Uhrzeit;mx;my;mz\n" + "".join(f"01.03.2024;{t};{m}\n" for t, m in rows))
    assert fluxcal.read_recording(path).metadata["Datum_start"].startswith("2024-03-01")
    path = tmp_path / "us.csv"
    path.write_text("Date,Time,mx,my,mz\n03/01/2024,12:00:00.000,1,2,3\n03/01/2024,12:00:00.020,1,2,3\n")
    assert fluxcal.read_recording(path).metadata["Date_start"].startswith("2024-03-01")


def test_a_date_column_beside_a_time_of_day_gives_clock_times(tmp_path):
    """Date,Time (or Datum;Uhrzeit) columns: utc_seconds is the date's first day with the time's start and its
    seconds since (across midnight too); it had been None (no clock time for --field-norm igrf)."""
    import fluxcal

    iso = tmp_path / "iso.csv"
    iso.write_text("Date,Time,lat,lon,alt,mx,my,mz\n" + "".join(
        f"2024-03-01,12:00:00.{20 * k:03d},48.1,11.6,500,{-19.6 - k},-5.39,-91.97\n" for k in range(4)))
    np.testing.assert_allclose(fluxcal.read_recording(iso).utc_seconds(),
                               _unix(2024, 3, 1, 12) + 0.02 * np.arange(4))
    german = tmp_path / "de.csv"  # day-first dotted dates, decimal-comma seconds, crossing midnight
    stamps = [("12.03.2024", "23:59:59,500"), ("12.03.2024", "23:59:59,900"), ("13.03.2024", "00:00:00,300"),
              ("13.03.2024", "00:00:01,100")]
    german.write_text("Datum;Uhrzeit;mx;my;mz\n" + "".join(f"{d};{t};-19,6{k};-5,39;-91,97\n"
                                                          for k, (d, t) in enumerate(stamps)))
    rec = fluxcal.read_recording(german)
    np.testing.assert_allclose(rec.utc_seconds(), _unix(2024, 3, 12, 23, 59, 59) + np.array([0.5, 0.9, 1.3, 2.1]))
    clock = tmp_path / "clock.csv"  # a time of day alone is still no clock time
    clock.write_text("Time,mx,my,mz\n12:00:00.000,1,2,3\n12:00:00.020,1,2,3\n")
    assert fluxcal.read_recording(clock).utc_seconds() is None


def test_minutes_seconds_elapsed_column(tmp_path):
    """An elapsed column written mm:ss.s (00:00.0 … 00:30.0) is minutes:seconds; it had been read as hours:minutes
    (60× too long, steps of 0 or 6 s). hh:mm without a fraction stays hours:minutes."""
    import fluxcal

    t = np.arange(301) * 0.1
    path = tmp_path / "mmss.csv"
    path.write_text("elapsed,mx,my,mz\n" + "".join(f"{int(s) // 60:02d}:{s % 60:04.1f},{30 + np.cos(s):.3f},"
                                                   f"{30 * np.sin(s):.3f},{s - 20:.3f}\n" for s in t))
    np.testing.assert_allclose(fluxcal.read_recording(path).time(), t, atol=1e-9)
    path.write_text("elapsed,mx,my,mz\n" + "".join(f"{m}:{s:02d},1,2,3\n" for m in (58, 59) for s in range(60)))
    np.testing.assert_allclose(fluxcal.read_recording(path).time(), np.arange(120))  # 58:00: past 23, minutes
    path.write_text("time,mx,my,mz\n12:00,1,2,3\n12:01,1,2,3\n12:02,1,2,3\n")
    np.testing.assert_allclose(fluxcal.read_recording(path).time(), [0, 60, 120])


def test_skipped_lines_are_warned_in_python(tmp_path):
    """bad_lines="skip" said which lines it left out only in metadata["skipped_lines"] (the command line prints
    it): Python had dropped them without a word."""
    import warnings

    import fluxcal

    path = tmp_path / "garbled.csv"
    path.write_text("mx,my,mz\n1,2,3\n0.1,0.2\n4,5,6\ngarbage,1,2\n7,8,9\n")
    for read in (fluxcal.read_recording, read_csv):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            rec = read(path, bad_lines="skip")
        assert len(rec) == 3
        said = [str(w.message) for w in caught if issubclass(w.category, UserWarning)]
        assert said == [f"{path}: skipped 2 of 5 lines: 3 (2 fields, the header has 3 (truncated or garbled line?)); "
                        "5 (column 'mx': 'garbage' is not a number) (bad_lines='skip')"]
    from fluxcal.io.csv import quiet_skipped

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with quiet_skipped():  # for a caller that prints metadata["skipped_lines"] itself (the command line)
            assert "skipped_lines" in fluxcal.read_recording(path, bad_lines="skip").metadata
        path.write_text("mx,my,mz\n1,2,3\n4,5,6\n")  # nothing skipped: nothing said
        assert len(read_csv(path, bad_lines="skip")) == 2
    labelled = tmp_path / "serial.txt"  # any format's skipped lines, numbered as its metadata numbers them
    labelled.write_text("".join(f"X: {k} Y: {k + 1} Z: {k + 2}\n" for k in range(8)) + "X: 1 Y: oops Z: 3\n")
    with pytest.warns(UserWarning, match=r"serial.txt: skipped 1 of 9 lines: 9 \("):
        fluxcal.read_recording(labelled, bad_lines="skip")
