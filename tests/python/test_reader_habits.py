"""Habits of the programs that write recordings, each read as written (found by a blind check of the readers):
a decimal-comma export with whole numbers, pandas' index column, log tags in brackets, quoted header names
holding the delimiter, a units comment against the header, thousands separators in whole numbers, and the
Arduino IDE's clock before table lines."""
import warnings

import numpy as np
import pytest

from fluxcal.io import read_recording, sniff


def write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_decimal_comma_table_with_whole_numbers_keeps_its_header(tmp_path):
    # Excel's General format writes 60, not 60,0: the row before it is data, not a header under a title
    path = write(tmp_path, "de.csv", "mx;my;mz\n59,5;-17,7;7,4\n60,1;-19,9;10,5\n60;-23;18,9\n60,2;-24,1;21,5\n"
                                     "59,8;-23,5;26,2\n")
    rec = read_recording(path)
    assert rec.roles()["magnetometer"] == "mx,my,mz"
    assert rec.samples().tolist() == [[59.5, -17.7, 7.4], [60.1, -19.9, 10.5], [60.0, -23.0, 18.9],
                                      [60.2, -24.1, 21.5], [59.8, -23.5, 26.2]]
    assert rec.line_numbers.tolist() == [2, 3, 4, 5, 6]
    assert "preamble" not in rec.metadata


def test_pandas_index_column_is_named_and_not_data(tmp_path):
    path = write(tmp_path, "df.csv", ",mag_x,mag_y,mag_z\n0,59.26,-17.65,6.54\n1,59.66,-17.72,7.41\n"
                                     "2,59.85,-19.90,10.52\n")
    rec = read_recording(path)
    assert list(rec.columns) == ["index", "mag_x", "mag_y", "mag_z"]
    assert rec.columns["index"].tolist() == [0, 1, 2]
    assert rec.roles()["magnetometer"] == "mag_x,mag_y,mag_z"
    assert rec.samples().tolist() == [[59.26, -17.65, 6.54], [59.66, -17.72, 7.41], [59.85, -19.90, 10.52]]


def test_bracketed_log_tags_are_text_not_json(tmp_path):
    tagged = write(tmp_path, "tag.txt", "[MAG] X: 50.00 Y: 0.00 Z: 20.00 uT\n[MAG] X: 49.75 Y: 4.99 Z: 20.10 uT\n"
                                        "[MAG] X: 49.01 Y: 9.93 Z: 20.20 uT\n")
    assert sniff(tagged) == "text"
    rec = read_recording(tagged)
    assert rec.samples().tolist() == [[50.0, 0.0, 20.0], [49.75, 4.99, 20.1], [49.01, 9.93, 20.2]]
    assert {rec.units[n] for n in rec.mag_names()} == {"uT"}

    info = write(tmp_path, "info.txt", "[INFO] mx=50.00, my=0.00, mz=20.00\n[INFO] mx=49.75, my=4.99, mz=20.10\n")
    assert read_recording(info).samples().tolist() == [[50.0, 0.0, 20.0], [49.75, 4.99, 20.1]]

    # two sensors told apart only by the tag: both listed, never interleaved into one triple
    two = write(tmp_path, "two.txt", "".join(f"[1] X: {50 - k}.00 Y: 0.00 Z: 20.00 uT\n[2] X: {30 - k}.00 Y: 0.00 "
                                             f"Z: -20.00 uT\n" for k in range(4)))
    with pytest.raises(ValueError, match=r"\[1\] X, \[1\] Y, \[1\] Z, \[2\] X, \[2\] Y, \[2\] Z"):
        read_recording(two).samples()
    assert read_recording(two, columns="[2] X,[2] Y,[2] Z").samples()[:, 0].tolist() == [30, 29, 28, 27]

    # not readable as text either: the error is about the text, not JSON
    junk = write(tmp_path, "junk.txt", "[BOOT] starting\n[BOOT] sensor missing\n[BOOT] halted\n")
    with pytest.raises(ValueError) as err:
        read_recording(junk).samples()
    assert "JSON" not in str(err.value)

    # JSON that starts with '[' is still JSON
    assert sniff(write(tmp_path, "a.json", "[1, 2, 3]\n")) == "json"
    assert sniff(write(tmp_path, "b.json", '[\n  {"mx": 1, "my": 2, "mz": 3}\n]\n')) == "json"
    assert sniff(write(tmp_path, "c.json", "[[1, 2, 3], [4, 5, 6]]\n")) == "json"


def test_quoted_header_names_may_hold_the_delimiter(tmp_path):
    path = write(tmp_path, "q.csv", '"Bx (uT, raw)","By (uT, raw)","Bz (uT, raw)"\n59.26,-17.65,6.54\n'
                                    "59.66,-17.72,7.41\n")
    rec = read_recording(path)
    assert list(rec.columns) == ["Bx raw", "By raw", "Bz raw"]
    assert {rec.units[n] for n in rec.mag_names()} == {"uT"}
    assert rec.samples().tolist() == [[59.26, -17.65, 6.54], [59.66, -17.72, 7.41]]


def test_units_comment_contradicting_the_header_is_an_error(tmp_path):
    path = write(tmp_path, "u.csv", "# units: mx=uT, my=uT, mz=uT\nmx [nT],my [nT],mz [nT]\n48123.4,-1204.2,20523.1\n"
                                    "47998.0,-987.5,21002.3\n")
    with pytest.raises(ValueError, match=r"line 2: column 'mx' is in nT by the header but in uT by the '# units:'"):
        read_recording(path)
    # the same unit twice (spelt either way) is no contradiction
    same = write(tmp_path, "s.csv", "# units: mx=uT, my=uT, mz=uT\nmx [µT],my [µT],mz [µT]\n48.1,-1.2,20.5\n")
    assert read_recording(same).samples().tolist() == [[48.1, -1.2, 20.5]]


def test_thousands_separators_in_whole_numbers_are_read_and_said(tmp_path):
    # Excel's #,##0 saved as tab-delimited text: numbers of 1000 and more have the comma, smaller ones not
    path = write(tmp_path, "t.txt", "Bx (nT)\tBy (nT)\tBz (nT)\n48,123\t-1,204\t523\n47,998\t-987\t1,002\n"
                                    "48,310\t-1,511\t612\n")
    with pytest.warns(UserWarning, match=r"columns Bx, By, Bz: 1,234 read as 1234"):
        rec = read_recording(path)
    assert rec.samples().tolist() == [[48123, -1204, 523], [47998, -987, 1002], [48310, -1511, 612]]
    assert rec.metadata["thousands_separator"] == "comma (Bx, By, Bz)"
    assert "decimal_separator" not in rec.metadata

    # a whole number of four digits has no thousands separator: the commas are decimal commas, said by the values
    decimal = write(tmp_path, "d.txt", "Bx\tBy\tBz\n48,123\t-1,204\t1523\n47,998\t-987\t1,002\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec = read_recording(decimal)
    assert rec.samples().tolist() == [[48.123, -1.204, 1523], [47.998, -987, 1.002]]
    assert rec.metadata["decimal_separator"] == "comma"

    # decimals of other lengths beside them: decimal commas, as before
    plain = write(tmp_path, "p.csv", "mx;my;mz\n48,123;-1,2;5\n47,998;-0,987;1,002\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_recording(plain).samples().tolist() == [[48.123, -1.2, 5], [47.998, -0.987, 1.002]]


@pytest.mark.parametrize("sep", [",", "\t", " "])
def test_arduino_ide_clock_before_table_lines(tmp_path, sep):
    rows = ["59.66,-17.72,7.41", "59.85,-19.90,10.52", "60.40,-22.21,14.20"]
    header = write(tmp_path, "h.txt", "15:02:11.123 -> " + sep.join(["mx", "my", "mz"]) + "\n" + "".join(
        f"15:02:11.{143 + 20 * k} -> {row.replace(',', sep)}\n" for k, row in enumerate(rows)))
    rec = read_recording(header)
    assert rec.samples().tolist() == [[59.66, -17.72, 7.41], [59.85, -19.90, 10.52], [60.40, -22.21, 14.20]]
    assert np.allclose(rec.time(), [0.0, 0.02, 0.04])
    assert rec.units["time"] == "s"

    bare = write(tmp_path, "b.txt", "".join(f"15:02:11.{143 + 20 * k} -> {row.replace(',', sep)}\n"
                                            for k, row in enumerate(rows)))
    rec = read_recording(bare, columns="mx,my,mz")
    assert rec.samples().tolist() == [[59.66, -17.72, 7.41], [59.85, -19.90, 10.52], [60.40, -22.21, 14.20]]
    assert np.allclose(rec.time(), [0.0, 0.02, 0.04])


def test_terminal_date_time_before_table_lines(tmp_path):
    path = write(tmp_path, "tt.txt", "[2026-11-29 15:02:11.123] 59.66,-17.72,7.41\n"
                                     "[2026-11-29 15:02:11.143] 59.85,-20.10,9.84\n")
    rec = read_recording(path, columns="mx,my,mz")
    assert rec.samples().tolist() == [[59.66, -17.72, 7.41], [59.85, -20.10, 9.84]]
    assert np.allclose(rec.time(), [0.0, 0.02])


def test_nul_bytes_of_serial_garbage_cost_only_their_line(tmp_path):
    # a board's reset or a baud mismatch: NUL among bytes that are not UTF-8, inside one data line
    path = tmp_path / "nul.csv"
    path.write_bytes(b"mx,my,mz\n1.5,-1.25,3.75\n2.5,-2.25,4.75\n3\x00\xff\xfe.5,-3.25,5.75\n4.5,-4.25,6.75\n"
                     b"5.5,-5.25,7.75\n")
    with pytest.raises(ValueError, match=r"nul.csv, line 4, column 'mx': .* is not a number \(bytes that are not text"):
        read_recording(path)
    rec = read_recording(path, bad_lines="skip")
    assert rec.samples().tolist() == [[1.5, -1.25, 3.75], [2.5, -2.25, 4.75], [4.5, -4.25, 6.75], [5.5, -5.25, 7.75]]
    assert rec.line_numbers.tolist() == [2, 3, 5, 6]
    assert rec.metadata["skipped_lines"].startswith("1 of 5: 4 (column 'mx'")


def test_banner_above_a_headerless_table_named_by_columns(tmp_path):
    path = write(tmp_path, "b.txt", "MPU9250 init OK\nAK8963 ready, adj: 1.18 1.19 1.14\n1532,59.26,-17.65,6.54\n"
                                    "1552,59.66,-17.72,7.41\n1572,59.85,-19.90,10.52\n")
    for bad_lines in ("error", "skip"):
        rec = read_recording(path, columns="time_ms,mx,my,mz", bad_lines=bad_lines)
        assert rec.samples().tolist() == [[59.26, -17.65, 6.54], [59.66, -17.72, 7.41], [59.85, -19.90, 10.52]]
        assert np.allclose(rec.time(), [1.532, 1.552, 1.572])
        assert rec.line_numbers.tolist() == [3, 4, 5]
        assert rec.metadata["preamble"] == "line 1: MPU9250 init OK; line 2: AK8963 ready, adj: 1.18 1.19 1.14"


def test_partial_first_line_of_a_headerless_capture(tmp_path):
    path = write(tmp_path, "p.txt", "3.45 -12\n59.26 -17.65 6.54\n59.66 -17.72 7.41\n59.85 -19.90 10.52\n")
    with pytest.raises(ValueError, match=r"p.txt, line 1: 2 fields where the rows under it have 3, as --columns names"):
        read_recording(path, columns="mx,my,mz")
    rec = read_recording(path, columns="mx,my,mz", bad_lines="skip")
    assert rec.samples().tolist() == [[59.26, -17.65, 6.54], [59.66, -17.72, 7.41], [59.85, -19.90, 10.52]]
    assert rec.line_numbers.tolist() == [2, 3, 4]
    assert rec.metadata["skipped_lines"] == "1 of 4: 1 (2 fields, --columns names 3)"


def test_three_decimals_with_a_few_whole_cells_stay_decimal_commas(tmp_path):
    # a decimal-comma table to three decimals with a 0 or a 45 among its cells is not a thousands-separated one (a
    # review: both had been read ×1000); nothing in it settles the commas, so the read says so (a blind check's
    # thousands-separated table with a -95 among its cells had been read ÷1000 without a word), and --decimal
    # settles it
    for name, cell in (("zero.tsv", "0"), ("whole.tsv", "45")):
        path = write(tmp_path, name, f"mx\tmy\tmz\n21,456\t-4,312\t44,187\n-19,874\t{cell}\t-46,233\n"
                                     "47,215\t3,718\t-18,904\n")
        with pytest.warns(UserWarning, match=rf"{name}, line 2: '21,456' read as 21.456 \(a decimal comma"):
            rec = read_recording(path)
        assert rec.samples()[:, 0].tolist() == [21.456, -19.874, 47.215]
        assert rec.samples()[1, 1] == float(cell)
        assert read_recording(path, decimal=".").samples()[0, 0] == 21456


def test_sparkfun_icm20948_bracketed_vectors(tmp_path):
    # SparkFun ICM-20948 Example1: `Label (unit) [ x, y, z ]` groups, zero-padded, after a word
    line = ("Scaled. Acc (mg) [  00000.00,  00020.00,  01000.00 ], Gyr (DPS) [  00000.31, -00000.20,  00000.05 ], "
            "Mag (uT) [  {:09.2f},  {:08.2f}, -00020.00 ], Tmp (C) [  00025.41 ]\n")
    path = write(tmp_path, "icm.txt", "".join(line.format(50 - k, k) for k in range(3)))
    rec = read_recording(path)
    assert rec.roles()["magnetometer"] == "Mag X,Mag Y,Mag Z"
    assert rec.samples().tolist() == [[50, 0, -20], [49, 1, -20], [48, 2, -20]]
    assert {rec.units[n] for n in rec.mag_names()} == {"uT"}
    assert rec.acc_names() == ("Acc X", "Acc Y", "Acc Z") and rec.units["Acc Z"] == "mg"
    assert rec.acceleration()[0].tolist() == [0, 20, 1000]
    assert rec.units["Gyr X"] == "DPS" and rec.columns["Gyr Y"][0] == -0.2
    assert rec.temperature().tolist() == [25.41] * 3
    # the raw form prints no units
    raw = write(tmp_path, "raw.txt", "".join(f"RAW. Acc [ 00012, -00003, 16384 ], Gyr [ 00001, 00000, -00002 ], "
                                             f"Mag [ {150 - k}, -00040, 00210 ], Tmp [ 00123 ]\n" for k in range(3)))
    assert read_recording(raw).samples()[:, 0].tolist() == [150, 149, 148]


@pytest.mark.parametrize("tags", [("Sensor 1:", "Sensor 2:"), ("Sensor A", "Sensor B")])
def test_two_sensors_a_line_each_are_named_apart(tmp_path, tags):
    # "Sensor 1: X: …" / "Sensor 2: X: …": were one interleaved triple; "Sensor A" / "Sensor B": A (read as
    # amperes) was dropped and B taken for a field B
    path = write(tmp_path, "two.txt", "".join(f"{tags[0]} X: {50 - k}.00 Y: 0.00 Z: 20.00 uT\n"
                                              f"{tags[1]} X: {30 - k}.00 Y: 0.00 Z: -20.00 uT\n" for k in range(4)))
    a, b = (t.rstrip(":") for t in tags)
    rec = read_recording(path)
    assert list(rec.columns) == [f"{s} {axis}" for s in (a, b) for axis in "XYZ"]
    listed = ", ".join(f"{s} {axis}" for s in (a, b) for axis in "XYZ")
    with pytest.raises(ValueError, match=f"no magnetometer columns .*columns are: {listed}\\); choose three"):
        rec.samples()
    assert "accelerometer" not in rec.roles()
    picked = read_recording(path, columns=f"{b} X,{b} Y,{b} Z")
    assert picked.samples().tolist() == [[30 - k, 0, -20] for k in range(4)]


def test_a_reading_counter_is_not_a_sensor_number(tmp_path):
    path = write(tmp_path, "count.txt", "".join(f"Sample {k}: X: {50 - k}.0 Y: 1.0 Z: 2.0 uT\n" for k in range(1, 20)))
    rec = read_recording(path, columns="Sample X,Sample Y,Sample Z")
    assert rec.samples()[:, 0].tolist() == [50 - k for k in range(1, 20)]


def test_two_magnetometers_tagged_by_letter_are_both_listed(tmp_path):
    path = write(tmp_path, "mag.txt", "".join(f"Mag A X: {50 - k}.00 Y: 0.00 Z: 20.00 uT\nMag B X: {30 - k}.00 "
                                              "Y: 0.00 Z: -20.00 uT\n" for k in range(4)))
    with pytest.raises(ValueError, match=r"several magnetometer column triples \(Mag A X,Mag A Y,Mag A Z; Mag B X,"):
        read_recording(path).samples()


def _gradiometer_rows(n=60):
    """t, B1 (nT), an accelerometer (m/s²), B2 (nT): a header-less table that is not the airborne layout."""
    rng = np.random.default_rng(3)
    angle = np.linspace(0, 2 * np.pi, n)
    b1 = np.column_stack([48000 * np.cos(angle), 48000 * np.sin(angle), 20000 + 100 * angle])
    acc = np.column_stack([rng.normal(0, 0.1, n), rng.normal(0, 0.1, n), 9.8 + rng.normal(0, 0.1, n)])
    return np.column_stack([0.1 * np.arange(n), b1, acc, b1 * 1.01 + 50])


def test_headerless_gradiometer_table_is_not_the_airborne_layout(tmp_path, real_data):
    path = tmp_path / "grad.txt"
    np.savetxt(path, _gradiometer_rows(), fmt="%.3f", delimiter="\t")
    with pytest.raises(ValueError, match=r"grad.txt, line 1: 10 tab-separated numbers and no header; name the "
                                         r"columns with --columns") as refused:
        read_recording(path)
    # the example's t,mx,my,mz,c5… is a pattern: the first row, numbered, shows where the magnetometer is
    assert "line 1 reads 1: 0.000, 2: 48000.000, 3: 0.000, 4: 20000.000, 5: " in str(refused.value), refused.value
    # the published segment without its _info.txt still reads as the layout, and says it was guessed
    lines = (real_data / "airborne_flt1002_02.tsv").read_text().splitlines(keepends=True)
    for first in (0, 5000, 12000):
        (tmp_path / "segment.tsv").write_text("".join(lines[first:first + 300]))
        with pytest.warns(UserWarning, match=r"segment.tsv: read as airborne MagNav segment: .*the numbers fit it"):
            rec = read_recording(tmp_path / "segment.tsv")
        assert rec.roles()["magnetometer"] == "mx,my,mz" and "igrf_n" in rec.columns


def test_trailing_delimiter_on_some_lines_only(tmp_path):
    path = write(tmp_path, "tc.csv", "mx,my,mz\n50.00,0.00,-20.00\n49.41,4.60,-18.49,\n47.65,9.09,-17.11\n"
                                     "44.77,13.36,-16.01,\n")
    rec = read_recording(path)
    assert rec.samples().tolist() == [[50, 0, -20], [49.41, 4.6, -18.49], [47.65, 9.09, -17.11],
                                      [44.77, 13.36, -16.01]]
    # a field after the delimiter is still one too many
    extra = write(tmp_path, "x.csv", "mx,my,mz\n50.00,0.00,-20.00\n49.41,4.60,-18.49,7\n")
    with pytest.raises(ValueError, match=r"x.csv, line 3: 4 fields, the header has 3: field 4 \('7'\) has no column"):
        read_recording(extra)


def test_point_thousands_in_whole_numbers_are_read_and_said(tmp_path):
    # German Excel's #.##0 saved as ';' text: 48.123 is 48123 nT beside 523 nT
    path = write(tmp_path, "de.csv", "Bx [nT];By [nT];Bz [nT]\n48.123;-1.204;523\n47.998;-987;1.002\n"
                                     "48.310;-1.511;612\n")
    with pytest.warns(UserWarning, match=r"columns Bx, By, Bz: 1\.234 read as 1234 \(a thousands separator, not a "
                                         r"decimal point\)"):
        rec = read_recording(path)
    assert rec.samples().tolist() == [[48123, -1204, 523], [47998, -987, 1002], [48310, -1511, 612]]
    assert rec.metadata["thousands_separator"] == "point (Bx, By, Bz)"

    # µT to three decimals stays decimal: beside 48.5, a 45, or with no whole number at all
    for name, body in (("half.csv", "48.123;-1.204;20.5\n47.998;-0.987;21.002\n48.5;-1.511;20.612\n"),
                       ("whole.tsv", "48.123\t-1.204\t45\n47.998\t-0.987\t21.002\n"),
                       ("plain.csv", "48.123;-1.204;20.512\n47.998;-0.987;21.002\n")):
        path = write(tmp_path, name, "mx;my;mz\n".replace(";", "\t" if name.endswith("tsv") else ";") + body)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            rec = read_recording(path)
        assert rec.samples()[0, :2].tolist() == [48.123, -1.204]
        assert "thousands_separator" not in rec.metadata
    # seconds to three decimals across a whole second (100.980, then 101 from a General format): not thousands
    path = write(tmp_path, "t.csv", "t;mx;my;mz\n100.960;48.123;-1.204;20.500\n100.980;47.998;-0.987;21.002\n"
                                    "101;48.500;-1.511;20.612\n101.020;48.510;-1.521;20.622\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec = read_recording(path)
    assert rec.columns["t"].tolist() == [100.96, 100.98, 101, 101.02]


def test_date_and_time_column_is_the_time_when_there_is_no_other(tmp_path):
    # German Excel: `Datum/Zeit` stamps with a decimal comma in the seconds, read into seconds, were left unused
    path = write(tmp_path, "de.csv", "Datum/Zeit;Bx [µT];By [µT];Bz [µT]\n"
                                     "29.11.2026 10:00:00,000;59,64;-17,78;7,87\n"
                                     "29.11.2026 10:00:00,020;59,99;-20,19;10,25\n"
                                     "29.11.2026 10:00:00,040;60,04;-22,19;13,88\n")
    rec = read_recording(path)
    assert rec.roles()["time"] == "Datum/Zeit" and np.allclose(rec.time(), [0, 0.02, 0.04])
    iso = write(tmp_path, "iso.csv", "DateTime,Bx,By,Bz\n2026-11-29T10:00:00Z,1,2,3\n2026-11-29T10:00:00.5Z,1,2,3\n")
    assert np.allclose(read_recording(iso).time(), [0, 0.5])
    # another clock wins; a number under a date name (Excel serial days) is not taken for seconds
    both = write(tmp_path, "both.csv", "DateTime,time_ms,Bx,By,Bz\n2026-11-29T10:00:00Z,1000,1,2,3\n"
                                       "2026-11-29T10:00:01Z,1020,1,2,3\n")
    assert read_recording(both).roles()["time"].startswith("time_ms") and np.allclose(read_recording(both).time(),
                                                                                       [1, 1.02])
    serial = write(tmp_path, "serial.csv", "Date Time,Bx,By,Bz\n46355.41667,1,2,3\n46355.41668,1,2,3\n")
    assert read_recording(serial).time() is None


@pytest.mark.parametrize("owner", ["imu", "board", "sensor"])
def test_an_owner_word_before_fused_axis_names_keeps_their_sensors(tmp_path, owner):
    """imu_mx, imu_ax: the m and a say magnetometer and accelerometer, not which of two sensors (a review: the tag
    rule for `Sensor A X` had taken them for tags, and no magnetometer was found)."""
    rows = "".join(f"{k},0.1,0.2,9.8,{50 - k:.1f},{3 + k:.1f},-20\n" for k in range(12))
    path = tmp_path / "imu.csv"
    path.write_text(f"t,{owner}_ax,{owner}_ay,{owner}_az,{owner}_mx,{owner}_my,{owner}_mz\n" + rows)
    rec = read_recording(path)
    assert rec.roles()["magnetometer"] == f"{owner}_mx,{owner}_my,{owner}_mz"
    assert rec.roles()["accelerometer"] == f"{owner}_ax,{owner}_ay,{owner}_az"


def test_a_reading_counter_beside_other_labels_is_not_a_sensor_number(tmp_path):
    """`Sample 17: Heading: 17.5 Mag X: …`: the counter takes a new number on every line (a review: it had been kept
    as a sensor's tag, and every line had its own heading column, no complete reading)."""
    path = tmp_path / "count.txt"
    path.write_text("".join(f"Sample {k}: Heading: {k}.5 Mag X: {50 - k:.2f} Y: {3 + k:.2f} Z: -20.00\n"
                            for k in range(12)))
    rec = read_recording(path)
    assert list(rec.columns) == ["Sample Heading", "Mag X", "Mag Y", "Mag Z"]
    assert rec.samples()[1].tolist() == [49.0, 4.0, -20.0]


@pytest.mark.parametrize("line, names", [
    ("mag: [{x}, {y}, {z}]", ["mag X", "mag Y", "mag Z"]),                        # a colon before the bracket
    ("Acc (m/s^2) [ 0.10, 0.20, 9.80 ], Mag (uT) [ {x}, {y}, {z} ]", ["Acc X", "Acc Y", "Acc Z", "Mag X", "Mag Y",
                                                                        "Mag Z"]),  # a digit in a unit
    ("[{ms}] Mag X: {x} Y: {y} Z: {z}", ["Mag X", "Mag Y", "Mag Z"]),              # millis() in brackets
])
def test_more_bracketed_forms(tmp_path, line, names):
    """A review's forms: a colon before a bracketed vector, a unit with a digit, and a millis() count in brackets
    before each line (a new number every line: a counter, not a sensor's tag) — each had given columns named by
    numbers, or one per line."""
    path = tmp_path / "log.txt"
    path.write_text("".join(line.format(x=f"{50 - k:.2f}", y=f"{3 + k:.2f}", z="-20.00", ms=1000 + 20 * k) + "\n"
                            for k in range(12)))
    rec = read_recording(path)
    assert list(rec.columns) == names
    assert rec.samples()[1].tolist() == [49.0, 4.0, -20.0]


def test_columns_given_for_every_column_of_a_header_file_name_the_header(tmp_path):
    """With a header, --columns picks the magnetometer's columns by name: four names for a t,X,Y,Z file are refused
    with the file's own column names to choose from (a blind check's newcomer had only 'got t, mx, my, mz')."""
    path = tmp_path / "eight.csv"
    path.write_text("Collecting time,X,Y,Z\n" + "".join(f"{40 * i},{i % 7},{i % 5},{i % 3}\n" for i in range(50)))
    with pytest.raises(ValueError, match=r"got t, mx, my, mz; of this file's columns \(Collecting time, X, Y, Z\) "
                                         r"name the magnetometer's three \(two for a biaxial sensor\)"):
        read_recording(path, columns="t,mx,my,mz")


def test_a_very_wide_header_less_row_is_shown_short(tmp_path):
    """A 40-column header-less log: the refusal numbers every column of the first row, long numbers to 6 significant
    digits (the magnetometer may be anywhere in it; full precision had filled three terminal lines), and the example
    states the pattern and the count instead of spelling 40 names."""
    path = tmp_path / "wide.csv"
    path.write_text("".join(",".join(f"{i + k}.123456789" for k in range(40)) + "\n" for i in range(30)))
    with pytest.raises(ValueError) as err:
        read_recording(path)
    said = str(err.value)
    assert "t,mx,my,mz,c5,…,c40: 40 names" in said and "1: 0.123457, 2: 1.12346," in said and "40: 39.1235" in said, said
    assert "123456789" not in said and len(said) < 900, len(said)


def _german_whole_numbers(values) -> list:
    """German Excel's #.##0: whole numbers with points between thousands groups (-48.123, 523)."""
    return [f"{v:,.0f}".replace(",", ".") for v in values]


def test_point_thousands_beside_decimal_commas_are_read(tmp_path):
    # a German export: time in seconds with a decimal comma, the field in nT as #.##0 (a 45 among them). The
    # points had been read as decimal points (a field of 50 nT, 1000 times small: a review)
    rng = np.random.default_rng(3)
    field = rng.normal(size=(40, 3)) * 30000
    field[5] = [45, -812, 7]
    lines = [f"{0.1 * i:.1f}".replace(".", ",") + ";" + ";".join(_german_whole_numbers(row))
             for i, row in enumerate(field)]
    path = write(tmp_path, "de.csv", "Zeit;Bx [nT];By [nT];Bz [nT]\n" + "\n".join(lines) + "\n")
    with pytest.warns(UserWarning, match=r"columns Bx, By, Bz: 1\.234 read as 1234 \(a thousands separator"):
        rec = read_recording(path)
    np.testing.assert_array_equal(rec.samples(), np.round(field))
    np.testing.assert_allclose(rec.columns["Zeit"], 0.1 * np.arange(40), atol=1e-12)
    assert rec.metadata["decimal_separator"] == "comma"
    assert rec.metadata["thousands_separator"] == "point (Bx, By, Bz)"


def test_point_thousands_of_a_long_table_are_read_by_the_spread_of_its_whole_numbers(tmp_path):
    # no comma anywhere, independent orientations (no smooth run): the values under 1000 that #.##0 writes
    # without a point spread over 0–999, as only whole numbers of a field in the tens of thousands do
    rng = np.random.default_rng(4)
    field = rng.normal(size=(300, 3)) * 30000
    field[[3, 40, 77, 150], [0, 1, 2, 0]] = [523, -87, 914, -406]
    body = "\n".join(";".join(_german_whole_numbers(row)) for row in field)
    path = write(tmp_path, "de.csv", "Bx [nT];By [nT];Bz [nT]\n" + body + "\n")
    with pytest.warns(UserWarning, match=r"1\.234 read as 1234"):
        rec = read_recording(path)
    np.testing.assert_array_equal(rec.samples(), np.round(field))

    # µT printed with %g: three decimals on most cells, a few exact whole numbers of two digits: decimal
    thousandths = rng.integers(1, 100, size=(30, 3)) * 10 + rng.integers(1, 10, size=(30, 3))  # no trailing 0
    micro = rng.integers(10, 60, size=(30, 3)) + thousandths / 1000
    micro[[2, 9, 17, 25], [0, 0, 0, 0]] = [45, 21, 33, 12]
    body = "\n".join(";".join(f"{v:g}" for v in row) for row in micro)
    path = write(tmp_path, "micro.csv", "mx;my;mz\n" + body + "\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec = read_recording(path)
    np.testing.assert_allclose(rec.samples(), micro)
    assert "thousands_separator" not in rec.metadata


def test_two_trailing_delimiters_in_header_and_rows(tmp_path):
    # a spreadsheet's two empty columns after the readings (Bx (µT),By (µT),Bz (µT),,): refused as empty names
    path = write(tmp_path, "two.csv", "\ufeffBx (µT),By (µT),Bz (µT),,\r\n-3.342,-4.726,-45.408,,\r\n"
                                      "-36.114,-29.139,-4.171,,\r\n")
    rec = read_recording(path)
    assert rec.samples().tolist() == [[-3.342, -4.726, -45.408], [-36.114, -29.139, -4.171]]
    assert rec.field_units() == "uT"


def test_a_tesla_suffix_after_a_field_axis_names_the_magnetometer(tmp_path):
    path = write(tmp_path, "si.csv", "Bx_T,By_T,Bz_T\n-3.341920e-06,-4.725651e-06,-4.540787e-05\n"
                                     "-3.611355e-05,-2.913865e-05,-4.170533e-06\n")
    rec = read_recording(path)
    assert rec.roles()["magnetometer"] == "Bx_T,By_T,Bz_T" and rec.field_units() == "T"
    # a t after anything else stays a word (time_t is no field; Ax_T is an accelerometer's)
    other = write(tmp_path, "other.csv", "time_t,mag_x_T,mag_y_T,mag_z_T,Ax_T\n0,1e-5,2e-5,3e-5,9.8\n")
    rec = read_recording(other)
    assert rec.roles()["magnetometer"] == "mag_x_T,mag_y_T,mag_z_T" and rec.field_units() == "T"
    assert rec.units.get("time_t") != "T" and rec.units.get("Ax_T") != "T"


def test_records_wrapped_in_an_object_with_the_unit_beside_them(tmp_path):
    # a phone app's export: {"device": …, "unit": "mG", "samples": [{"timestamp", "x", "y", "z"}, …]}
    import json

    samples = [{"timestamp": f"2026-03-14T09:26:53.{k}00000", "x": 100.0 + k, "y": -50.0 * k, "z": 3.0}
               for k in range(5)]
    path = write(tmp_path, "phone.json", json.dumps({"device": "Pixel 7", "unit": "mG", "samples": samples}))
    rec = read_recording(path)
    assert rec.samples()[:, 0].tolist() == [100, 101, 102, 103, 104] and rec.field_units() == "mG"
    np.testing.assert_allclose(rec.time(), [0, 0.1, 0.2, 0.3, 0.4])
    assert rec.metadata["device"] == "Pixel 7"
    samples[2]["y"] = "n/a"  # a bad record is named by its place in the list
    write(tmp_path, "phone.json", json.dumps({"device": "Pixel 7", "unit": "mG", "samples": samples}))
    with pytest.raises(ValueError, match=r"phone.json, 'samples' record 3: 'y' is \"n/a\", not a number"):
        read_recording(path)
    assert read_recording(path, bad_lines="skip").samples().shape == (4, 3)


def test_a_capture_that_starts_inside_a_sentence(tmp_path):
    def xor8(body):
        from functools import reduce
        return f"{reduce(lambda a, b: a ^ b, body.encode(), 0):02X}"

    bodies = [f"VNMAG,{0.1 * k:+07.4f},-0.2000,+0.3000" for k in range(4)]
    path = write(tmp_path, "vn.txt", "MR,+012.345,-001.234\r\n" + "".join(f"${b}*{xor8(b)}\r\n" for b in bodies))
    rec = read_recording(path)
    assert rec.samples()[:, 0].tolist() == [0, 0.1, 0.2, 0.3] and "line 1: MR,+012.345" in rec.metadata["preamble"]
    # after the first sentence, a line that is none is a bad line as before
    write(tmp_path, "vn.txt", "".join(f"${b}*{xor8(b)}\r\n" for b in bodies[:2]) + "MR,+012.345\r\n")
    with pytest.raises(ValueError, match=r"vn.txt, line 3: not a \$TYPE,fields\*checksum sentence"):
        read_recording(path)


def test_the_header_again_among_the_rows_is_said(tmp_path, capsys):
    from fluxcal.cli import main

    rng = np.random.default_rng(3)
    u = rng.normal(size=(60, 3))
    rows = [",".join(f"{v:.4f}" for v in 50 * r / np.linalg.norm(r)) for r in u]
    path = write(tmp_path, "joined.csv", "mx,my,mz\n" + "\n".join(rows[:30]) + "\nmx,my,mz\n"
                 + "\n".join(rows[30:]) + "\n")
    assert main(["calibrate", str(path)]) == 0
    assert "the header again at line 32 (the same columns and units): passed over" in capsys.readouterr().out


def test_a_clock_time_column_beside_a_date_column_is_the_time(tmp_path):
    # a German logger's Datum;Uhrzeit (date, clock time) in two columns: the clock time had not been taken for time
    path = write(tmp_path, "de.csv", "Datum;Uhrzeit;X;Y;Z\n14.03.26;09:26:00;-15,571;-47,230;-4,920\n"
                                     "14.03.26;09:26:01;-16,5;-46,2;-5,0\n")
    rec = read_recording(path)
    assert rec.roles()["time"] == "Uhrzeit" and rec.time().tolist() == [0.0, 1.0]
