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
    # review: both had been read ×1000); only whole numbers of three digits beside the commas make it so
    for name, cell in (("zero.tsv", "0"), ("whole.tsv", "45")):
        path = write(tmp_path, name, f"mx\tmy\tmz\n21,456\t-4,312\t44,187\n-19,874\t{cell}\t-46,233\n"
                                     "47,215\t3,718\t-18,904\n")
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            rec = read_recording(path)
        assert rec.samples()[:, 0].tolist() == [21.456, -19.874, 47.215]
        assert rec.samples()[1, 1] == float(cell)
