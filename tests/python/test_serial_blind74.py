"""Defects a blind check (s74/serial) found in `fluxcal record`'s reader (fluxcal.io.serial): decimal commas between
';' or tab separated fields refused (a European logger's `12,5;-3,25;40,0`: 6 fields); a good line after the NULs a
device sends at a reset dropped as binary; gauss written `Gs`, or in the names (`magnetometer_ga[0]`, `mag_x_ga`),
not kept as the recording's unit; a reference field bx,by,bz beside mx,my,mz refused without a word of why or what
to do. Checked on the decoder, and through a pseudo-terminal with the `fluxcal record` command line."""
from __future__ import annotations

import numpy as np
import pytest

import fluxcal
from fluxcal.io.serial import Reject, TextDecoder, parse_columns
from conftest import run_cli  # noqa: E402  (tests/python is on sys.path)
from test_serial_header import device  # noqa: E402


def events(decoder, data: bytes, quiet: bool = True) -> list:
    """Records as tuples, rejects and followed headers as (reason, detail)."""
    if quiet:
        decoder.port_was_quiet()  # (the first line is whole)
    return [e if isinstance(e, tuple) else (e.reason, e.detail) for e in decoder.feed(data)]


def record(tmp_path, data: bytes, *options, duration: float = 1.5):
    """`fluxcal record` of a pty device that writes `data` once the recording exists (the port is open); returns
    (the command's CompletedProcess, the recording's path)."""
    with device(tmp_path, [data]) as (link, recording, sent):
        result = run_cli("record", "--port", link, "-o", recording, "--duration", duration, *options)
    assert sent.is_set(), "the device did not see its bytes read"
    return result, recording


# -- 1: decimal commas between ';' or tab separated fields ---------------------------------------------------------

@pytest.mark.parametrize("sep", [b";", b"\t"])
def test_decimal_commas_between_semicolons_or_tabs_are_read(sep):
    # 12,5;-3,25;40,0 had been split at every comma: "6 fields, expected 3", every line of a European logger refused
    decoder = TextDecoder(parse_columns(None))
    lines = [b"12,5", b"-3,25", b"40,0"], [b"1,234", b"5,678", b"9,012"], [b"0,5", b"-1,25", b"3"]
    out = events(decoder, b"".join(sep.join(cells) + b"\r\n" for cells in lines) + b"1,234;5,678;9,012\r\n")
    assert out[0] == (12.5, -3.25, 40.0) and decoder.decimal_comma
    # 1,234 once a decimal comma that cannot group thousands came: 1.234 (as kv lines read it)
    assert out[1:] == [(1.234, 5.678, 9.012), (0.5, -1.25, 3.0), (1.234, 5.678, 9.012)]
    # before one came, a line of 1,234s is read with decimal commas too, as the file readers read a ';' or tab table
    # (a logger printing three decimals, 20,500;-3,250;40,125, had every line refused), and said in a note; beside a
    # whole number a comma is a thousands separator (the file readers' rule), not read: refused, naming the line
    fresh = TextDecoder(parse_columns(None))
    out = events(fresh, sep.join(lines[1]) + b"\n" + sep.join([b"12,345", b"812", b"-95"]) + b"\n")
    assert out[0] == (1.234, 5.678, 9.012) and len(fresh.notes) == 1
    assert "'1,234' read as 1.234 with a decimal comma" in fresh.notes[0] and "1234 with a thousands" in fresh.notes[0]
    other = TextDecoder(parse_columns(None))
    ((reason, detail),) = events(other, sep.join([b"12,345", b"812", b"-95"]) + b"\n")
    assert reason == "fields" and "thousands separator" in detail
    assert repr(f"12,345{sep.decode()}812{sep.decode()}-95") in detail


def test_comma_separated_lines_whose_commas_may_be_decimal_commas_are_refused_saying_so():
    decoder = TextDecoder(parse_columns(None))
    (reason, detail), *rest = events(decoder, b"12,5,-3,25,40,0\n1.5,-2,3\n1,2,3\n")
    assert reason == "ambiguous" and "'12,5,-3,25,40,0'" in detail and "decimal commas" in detail
    assert "separates its fields by ';' or tabs" in detail
    assert rest == [(1.5, -2.0, 3.0), (1.0, 2.0, 3.0)]  # the other lines kept; commas still separate fields


def test_record_keeps_a_european_loggers_lines(tmp_path):
    rows = [(k, 20.5 + k, -3.25 - k, 40.125) for k in range(20)]
    text = "t;mx;my;mz\r\n" + "".join(f"{t};{x:.3f};{y:.3f};{z:.3f}\r\n".replace(".", ",") for t, x, y, z in rows)
    result, recording = record(tmp_path, text.encode())
    assert result.returncode == 0 and f"Kept {len(rows)} records" in result.stdout, result.stdout + result.stderr
    rec = fluxcal.read_csv(recording)
    got = np.column_stack([rec.columns[n] for n in ("t", "mx", "my", "mz")])
    np.testing.assert_array_equal(got, np.array(rows))


# -- 2: NULs of a reset before a line --------------------------------------------------------------------------

def test_a_line_after_the_nuls_of_a_reset_is_kept():
    decoder = TextDecoder(parse_columns(None))
    out = events(decoder, b"1,2,3\n\x00\x00\x0012.5,-3.2,40.1\n\x00\x00\n4,5,6\n7,\x008,9\n12.3,4.5,6\x00\x00\r\n")
    # the NULs before a line are dropped; a line of NULs is blank; a NUL inside a line is garbage, and so is a line
    # ending in them — one a reset cut (12.3,4.5,6 of 12.3,4.5,67.8 must not be kept: a review)
    assert out[:3] == [(1.0, 2.0, 3.0), (12.5, -3.2, 40.1), (4.0, 5.0, 6.0)]
    assert out[3][0] == "binary" and "7,\\x008,9" in out[3][1]
    assert out[4][0] == "binary" and len(out) == 5
    assert decoder.nul_lines == 1 and len(decoder.notes) == 1 and "NUL bytes before a line" in decoder.notes[0]
    # a device reset by the open (an Arduino) sends NULs and then its first line: whole, not the tail of one
    opened = TextDecoder(parse_columns(None))
    assert events(opened, b"\x00\x0012.5,-3.2,40.1\n", quiet=False) == [(12.5, -3.2, 40.1)]
    assert events(TextDecoder(parse_columns(None)), b"12.5,-3.2,40.1\n", quiet=False)[0][0] == "partial"


def test_record_keeps_the_lines_after_a_reset(tmp_path):
    rows = [f"{k},{20 + k}.5,-5.25,40.125\r\n".encode() for k in range(12)]
    data = b"t,mx,my,mz\r\n" + b"".join(rows[:6]) + b"\x00\x00\x00" + b"".join(rows[6:])
    result, recording = record(tmp_path, data)
    assert result.returncode == 0 and "Kept 12 records" in result.stdout and "no lines rejected" in result.stdout, \
        result.stdout
    rec = fluxcal.read_csv(recording)
    assert list(rec.columns["t"]) == list(range(12))
    assert "NUL bytes before a line" in rec.metadata["notes"]


# -- 3: gauss as Gs, or in the names ---------------------------------------------------------------------------

@pytest.mark.parametrize("spec, fmt, units, data", [
    (None, "csv", "Gs", b"0.1,0.2,0.3\n"),
    ("mx[Gs],my[Gs],mz[Gs]", "csv", None, b"0.1,0.2,0.3\n"),
    (None, "csv", None, b"mx [Gs],my [Gs],mz [Gs]\n0.1,0.2,0.3\n"),
    (None, "kv", None, b"Mag X: 0.1 Y: 0.2 Z: 0.3 Gs\n"),
    (None, "csv", None, b"t,magnetometer_ga[0],magnetometer_ga[1],magnetometer_ga[2]\n0,0.1,0.2,0.3\n"),
    (None, "csv", None, b"timestamp,mag_x_ga,mag_y_ga,mag_z_ga\n0,0.1,0.2,0.3\n"),
])
def test_gauss_as_gs_or_in_the_names_is_the_recordings_unit(spec, fmt, units, data):
    # "Gs" had been kept as a unit nothing converts (or dropped, on a kv line); magnetometer_ga[0] read as a name
    # "magnetometer_ga" in unit "0", the three one name: no header, every line refused; mag_x_ga's gauss dropped
    decoder = TextDecoder(parse_columns(spec, fmt, units), fmt, header_columns=spec is None)
    out = events(decoder, data)
    assert out[-1][-3:] == (0.1, 0.2, 0.3)
    assert {n: u for n, u in decoder.units.items() if n in ("mx", "my", "mz")} == {"mx": "G", "my": "G", "mz": "G"}


def test_record_carries_gauss_from_px4_names(tmp_path):
    data = b"t,magnetometer_ga[0],magnetometer_ga[1],magnetometer_ga[2]\r\n" + b"".join(
        f"{k},0.2{k},-0.05,0.4\r\n".encode() for k in range(8))
    result, recording = record(tmp_path, data)
    assert result.returncode == 0 and "Kept 8 records" in result.stdout, result.stdout + result.stderr
    rec = fluxcal.read_csv(recording)
    assert rec.field_units() == "G" and rec.mag_names() == ("mx", "my", "mz")
    assert "magnetometer_ga[0] as mx" in rec.metadata["notes"]


# -- 4: a reference field bx,by,bz beside mx,my,mz -------------------------------------------------------------

def test_a_reference_field_beside_the_magnetometer_is_recorded_and_said():
    # as the file readers take it (fluxcal.io.columns.rival_magnetometers): bx,by,bz beside mx,my,mz is the true
    # field a vector fit is given, not a second magnetometer
    decoder = TextDecoder(parse_columns(None), header_columns=True)
    (reason, detail), values = events(decoder, b"t,mx,my,mz,bx,by,bz\n0,1,2,3,4,5,6\n")
    assert reason == "header" and values == (0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
    assert decoder.names == ["t", "mx", "my", "mz", "bx", "by", "bz"]
    assert "bx,by,bz: a reference field beside the magnetometer mx,my,mz" in detail
    assert "fluxcal calibrate --reference bx,by,bz" in detail


def test_a_reference_field_beyond_the_columns_is_refused_naming_it_and_the_remedy():
    # --columns t,mx,my,mz: every line of 7 fields had been refused as `fields`, nothing said of bx,by,bz
    decoder = TextDecoder(parse_columns("t,mx[uT],my[uT],mz[uT]"))
    decoder.port_was_quiet()
    out = list(decoder.feed(b"t,mx,my,mz,bx,by,bz\n0,1,2,3,4,5,6\nt,mx,my,mz\n1,2,3,4\n"))
    header, line, again, kept = out
    assert header.reason == "fields" and "it names bx,by,bz beside the columns t,mx,my,mz" in header.warning
    assert "--columns t,mx[uT],my[uT],mz[uT],bx,by,bz" in header.warning
    assert "fluxcal calibrate --reference bx,by,bz" in header.warning
    assert line.reason == "fields" and "'0,1,2,3,4,5,6'" in line.detail  # each refused line named
    assert again.reason == "header" and kept == (1.0, 2.0, 3.0, 4.0)  # a header of the columns: recorded again


def test_two_magnetometer_triples_are_refused_naming_both():
    # MagX,MagY,MagZ beside bx,by,bz: the file readers refuse them ("several magnetometer column triples"); every
    # line had been refused as 7 fields for 3, without a word of why
    decoder = TextDecoder(parse_columns(None), header_columns=True)
    decoder.port_was_quiet()
    header, line = decoder.feed(b"t,MagX,MagY,MagZ,bx,by,bz\n0,1,2,3,4,5,6\n")
    assert header.reason == "fields" and "several magnetometer column triples (MagX,MagY,MagZ; bx,by,bz)" in \
        header.warning
    assert "--columns" in header.warning and "t,mx,my,mz,bx,by,bz" in header.warning and "--reference" in \
        header.warning
    assert line.reason == "fields" and "'0,1,2,3,4,5,6'" in line.detail


def test_record_keeps_the_reference_and_says_what_to_do_when_it_cannot(tmp_path):
    rows = b"".join(f"{k},{20 + k}.5,-5.25,40.125,21,-5,40\r\n".encode() for k in range(10))
    (tmp_path / "kept").mkdir()
    result, recording = record(tmp_path / "kept", b"t,mx,my,mz,bx,by,bz\r\n" + rows)
    assert result.returncode == 0 and "Kept 10 records" in result.stdout, result.stdout + result.stderr
    rec = fluxcal.read_csv(recording)
    assert rec.mag_names() == ("mx", "my", "mz") and list(rec.columns["bx"]) == [21.0] * 10
    assert "fluxcal calibrate --reference bx,by,bz" in rec.metadata["notes"]
    (tmp_path / "refused").mkdir()
    result, recording = record(tmp_path / "refused", b"t,mx,my,mz,bx,by,bz\r\n" + rows, "--columns", "t,mx,my,mz")
    assert result.returncode == 1 and "record again with --columns t,mx,my,mz,bx,by,bz" in result.stderr, \
        result.stdout + result.stderr
    assert "it names bx,by,bz beside the columns t,mx,my,mz" in recording.read_text()


# -- a header that names its axes in another order is followed by its names, never by position ---------------------

def test_a_header_of_only_the_axes_in_another_order_is_followed_by_their_names():
    # MagZ,MagX,MagY had been taken by position: MagZ's values recorded as mx, without a word
    decoder = TextDecoder(parse_columns(None), header_columns=True)
    out = events(decoder, b"MagZ,MagX,MagY\n3.0,1.0,2.0\n6.0,4.0,5.0\n")
    assert out[0][0] == "header" and out[1:] == [(1.0, 2.0, 3.0), (4.0, 5.0, 6.0)]
    assert "columns now in its order" in out[0][1]
    # so with --columns naming them in order, and a time field by position beside them
    given = TextDecoder(parse_columns("t,mx,my,mz"))
    assert events(given, b"time,Bz,Bx,By\n0.5,3,1,2\n")[1:] == [(0.5, 1.0, 2.0, 3.0)]


def test_a_reprinted_header_in_another_order_is_followed_after_its_names_were_renamed():
    # t,Bx,By,Bz recorded as t,mx,my,mz; its later reprint t,Bz,Bx,By had been taken by position (Bz as mx)
    decoder = TextDecoder(parse_columns(None), header_columns=True)
    out = events(decoder, b"t,Bx,By,Bz\n0.1,1,2,3\nt,Bz,Bx,By\n0.2,6,4,5\n")
    records = [e for e in out if e[0] not in ("header",)]
    assert records == [(0.1, 1.0, 2.0, 3.0), (0.2, 4.0, 5.0, 6.0)]
