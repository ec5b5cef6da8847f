"""Defects a blind check (s73/io) found in the file and serial readers: comma thousands separators in a ';' table
read as decimal commas (1000× too small) when one cell was a whole number of two digits; a device's start-up
banner with a word in brackets taken for its header, refusing the real one (0 records kept); a header reprinted
without units after one with them, its rows read in the first unit; two magnetometer triples in one file, one
taken without a word."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

from fluxcal import read_recording
from fluxcal.io.serial import Reject, TextDecoder, parse_columns
from test_reader_habits import write


# -- F1: what a comma is in a ';' or tab table -----------------------------------------------------------------

def test_comma_thousands_beside_a_two_digit_whole_number_are_read_as_thousands(tmp_path):
    # 31,870 beside 812 cannot be decimal commas: a table that writes 812 as a whole number trims 31,870 to 31,87
    # (a blind check's -95 had turned 12,345 into 12.345 nT beside 812 nT, without a word)
    path = write(tmp_path, "two.csv", "mx [nT];my [nT];mz [nT]\n12,345;-7,012;20,111\n31,870;812;-4,406\n"
                                      "-45,118;18,990;-95\n2,004;-33,121;41,700\n")
    with pytest.warns(UserWarning, match=r"two.csv: columns mx, my, mz: 1,234 read as 1234"):
        rec = read_recording(path)
    assert rec.samples().tolist() == [[12345, -7012, 20111], [31870, 812, -4406], [-45118, 18990, -95],
                                      [2004, -33121, 41700]]


def test_a_long_table_of_whole_nT_with_comma_thousands_is_read_so(tmp_path):
    rng = np.random.default_rng(73)
    values = rng.integers(-60_000, 60_000, size=(400, 3))
    values[::20] = rng.integers(-999, 999, size=(20, 3))  # some below 1000: written without a comma
    path = write(tmp_path, "nT.csv", "t;mx [nT];my [nT];mz [nT]\n" + "".join(
        f"{k};" + ";".join(f"{v:,}" for v in row) + "\n" for k, row in enumerate(values)))
    with pytest.warns(UserWarning, match="1,234 read as 1234"):
        rec = read_recording(path)
    np.testing.assert_array_equal(rec.samples(), values)


def test_commas_nothing_settles_are_said_naming_the_line_and_the_remedy(tmp_path):
    # every value ≥ 1000: 60,740 is 60.74 or 60740 and no cell says which (had been read ÷1000 without a word): read
    # as decimal commas, as a ';' or tab table writes them, with a warning naming the line and --decimal (refusing it
    # refused ordinary European logs to three decimals beside a counter: a review)
    text = "mx;my;mz\n60,740;15,156;28,154\n63,494;-12,561;4,504\n10,992;36,268;4,293\n"
    path = write(tmp_path, "either.csv", text)
    with pytest.warns(UserWarning, match=r"either.csv, line 2: '60,740' read as 60.740 \(a decimal comma.*60740 with "
                                         r"a thousands separator.*--decimal , \(decimal commas\) or --decimal \."):
        assert read_recording(path).samples()[0].tolist() == [60.74, 15.156, 28.154]
    assert read_recording(path, decimal=",").samples()[0].tolist() == [60.74, 15.156, 28.154]
    assert read_recording(path, decimal=".").samples()[0].tolist() == [60740, 15156, 28154]
    # a decimal comma that cannot group thousands (0,5) settles it, anywhere in the table (here past line 400)
    long = write(tmp_path, "long.csv", "mx;my;mz\n" + "60,740;15,156;28,154\n" * 450 + "0,5;1,25;-3,125\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec = read_recording(long)
    assert rec.samples()[0].tolist() == [60.74, 15.156, 28.154] and rec.samples()[-1].tolist() == [0.5, 1.25, -3.125]


def test_commas_settled_both_ways_are_an_error_naming_both_lines(tmp_path):
    # a decimal comma that cannot group thousands (0,5) and a whole number beside 12,340: one table, two readings
    path = write(tmp_path, "both.tsv", "mx\tmy\tmz\n0,5\t-1,204\t12,340\n1,5\t-1,511\t45\n")
    with pytest.raises(ValueError, match=r"both.tsv: line 2's '0,5' has a decimal comma, line 2's '12,340' has a "
                                         r"thousands separator.*read both ways.*--decimal"):
        read_recording(path)


# -- F2: a start-up banner is no header ------------------------------------------------------------------------

@pytest.mark.parametrize("banner", [b"QMC5883L at (0x0D) ready", b"MagLogger v2.1 (c) ACME"])
def test_a_banner_with_a_word_in_brackets_does_not_refuse_the_header_after_it(banner):
    # the banner had been taken for a header by position (my in 0x0D), and the real header's uT refused every
    # line after it: 0 of 100 records kept by `fluxcal record` and `fluxcal live`
    decoder = TextDecoder(parse_columns(None), header_columns=True)
    decoder.port_was_quiet()
    out = list(decoder.feed(banner + b"\r\nt,mx[uT],my[uT],mz[uT]\r\n0,20.5,-5,40\r\n1,21.5,-6,41\r\n"))
    assert [o.reason for o in out[:2]] == ["fields", "header"]
    assert out[2:] == [(0.0, 20.5, -5.0, 40.0), (1.0, 21.5, -6.0, 41.0)]
    assert decoder.names == ["t", "mx", "my", "mz"] and decoder.units == {"mx": "uT", "my": "uT", "mz": "uT"}
    # without a header after it, its bracket is no unit of the records
    decoder = TextDecoder(parse_columns(None), header_columns=True)
    decoder.port_was_quiet()
    out = list(decoder.feed(banner + b"\r\n20.5,-5,40\r\n"))
    assert out[0].reason == "fields" and out[1:] == [(20.5, -5.0, 40.0)] and decoder.units == {}


def test_a_header_before_the_first_record_replaces_an_earlier_one():
    # nothing was recorded under the first: its units do not refuse the second (the user's --units still do)
    decoder = TextDecoder(parse_columns(None), header_columns=True)
    decoder.port_was_quiet()
    out = list(decoder.feed(b"mx[mG],my[mG],mz[mG]\r\nt,mx[uT],my[uT],mz[uT]\r\n0,20.5,-5,40\r\n"))
    assert [o.reason for o in out[:2]] == ["header", "header"] and out[2] == (0.0, 20.5, -5.0, 40.0)
    assert decoder.units == {"mx": "uT", "my": "uT", "mz": "uT"}
    stated = TextDecoder(parse_columns(None, units="mG"), header_columns=True)
    stated.port_was_quiet()
    out = list(stated.feed(b"t,mx[uT],my[uT],mz[uT]\r\n0,20.5,-5,40\r\n"))
    assert [o.reason for o in out] == ["unit", "unit"]


# -- F3: a header reprinted without its units ------------------------------------------------------------------

def test_a_header_reprinted_without_units_is_refused_naming_its_line(tmp_path):
    # the rows under `t,mx,my,mz` had been read in the first header's µT (they were nT), and the file said "the
    # same columns and units"
    rows = "".join(f"{k},{20 + k % 7}.5,-5.25,40.125\n" for k in range(5))
    path = write(tmp_path, "joined.csv", "t,mx [uT],my [uT],mz [uT]\n" + rows + "t,mx,my,mz\n"
                 + rows.replace(".5,", "500,"))
    with pytest.raises(ValueError, match=r"joined.csv, line 7: the header again, with no units for mx, my, mz.*"
                                         r"Split the file at line 7"):
        read_recording(path)
    # the same header again (units and all) is passed over, as before; so is one whose units a comment states
    same = write(tmp_path, "same.csv", "t,mx [uT],my [uT],mz [uT]\n" + rows + "t,mx [uT],my [uT],mz [uT]\n" + rows)
    assert len(read_recording(same)) == 10
    noted = write(tmp_path, "noted.csv", "# units: mx=uT, my=uT, mz=uT\nt,mx,my,mz\n" + rows + "t,mx,my,mz\n" + rows)
    assert len(read_recording(noted)) == 10 and read_recording(noted).field_units() == "uT"


# -- F5: two magnetometer triples ------------------------------------------------------------------------------

@pytest.mark.parametrize("header, first, second", [
    ("t,mx,my,mz,MagX,MagY,MagZ", "mx,my,mz", "MagX,MagY,MagZ"),
    ("t,MagX,MagY,MagZ,mx,my,mz", "mx,my,mz", "MagX,MagY,MagZ"),
    ("t,x,y,z,Bx,By,Bz", "Bx,By,Bz", "x,y,z"),
    ("t,x,y,z,x.1,y.1,z.1", "x,y,z", "x.1,y.1,z.1"),  # pandas' names for two sensors both written x,y,z
])
def test_two_magnetometer_triples_are_an_error_listing_both(tmp_path, header, first, second):
    rows = "".join(f"{k},0.1,0.2,9.8,{20 + k},-5,40\n" for k in range(5))
    path = write(tmp_path, "two.csv", header + "\n" + rows)
    with pytest.raises(ValueError, match=rf"two.csv: several magnetometer column triples \({first}; {second}\); "
                                         r"choose one with --columns"):
        read_recording(path).samples()
    assert read_recording(path, columns=",".join(header.split(",")[4:])).samples()[0].tolist() == [20, -5, 40]


@pytest.mark.parametrize("header", ["mx,my,mz,hx,hy,hz", "mx,my,mz,mx_cal,my_cal,mz_cal", "x,y,z,x_raw,y_raw,z_raw",
                                    "mx,my,mz,bx,by,bz"])
def test_a_corrected_or_calibrated_triple_beside_the_raw_one_is_no_second_sensor(tmp_path, header):
    # fluxcal apply's output (hx,hy,hz beside the input's columns), a device's calibrated copy, PX4's raw beside x;
    # bx,by,bz beside mx,my,mz: as often --reference's true field (test_cli_said), left as it was
    path = write(tmp_path, "one.csv", header + "\n" + "1.5,2.5,3.5,4.5,5.5,6.5\n" * 3)
    names = read_recording(path).mag_names()
    assert names == (("x_raw", "y_raw", "z_raw") if "raw" in header else ("mx", "my", "mz"))


@pytest.mark.parametrize("sep", [b"\t", b" "])
def test_a_header_with_a_unit_on_some_names_is_still_a_header(sep):
    # a review: the banner rule had dropped `time(ms) X Y Z` (a unit on the time only), and the device's reorder after
    # it was recorded on the wrong axes (1, 3, 1, 2 for 1, 1, 2, 3)
    decoder = TextDecoder(parse_columns("t,mx,my,mz"))
    decoder.port_was_quiet()
    stream = b"\r\n".join(sep.join(words) for words in ([b"time(ms)", b"X", b"Y", b"Z"], [b"0", b"1", b"2", b"3"],
                                                        [b"time(ms)", b"Z", b"X", b"Y"], [b"1", b"3", b"1", b"2"]))
    records = [r for r in decoder.feed(stream + b"\r\n") if isinstance(r, tuple)]
    assert records == [(0.0, 1.0, 2.0, 3.0), (1.0, 1.0, 2.0, 3.0)]
