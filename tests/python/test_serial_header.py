"""Header lines a csv device prints (fluxcal.io.serial), through a real pseudo-terminal: a header reprinted in
another order with units in its names (`mx[uT]`, `mx [uT]`) is followed, one that cannot be followed refuses the
lines after it loudly; a header printed on start-up names the columns; the first line after a quiet open is kept.

The device is tests/python/fake_device.py's Pty (a pty pair whose slave is published at a symlink), written from
a thread of the test: it writes only once the recorder has opened the port (the recording file exists: pyserial's
open empties the input queue, so bytes written before it are lost by design of the port), and waits until the
reader has taken every byte before the recorder is asked to stop."""
from __future__ import annotations

import contextlib
import threading
import time

import numpy as np
import pytest

import fluxcal
from fluxcal.io import serial as serial_module
from fluxcal.io.serial import Recorder, TextDecoder, parse_columns
from conftest import run_cli  # noqa: E402  (tests/python is on sys.path)
from fake_device import Pty  # noqa: E402

ROWS = [(k, 10.0 + k, -20.0 - k, 40.0 + k / 4) for k in range(8)]  # seq, mx, my, mz as the device measures them


def line(values) -> bytes:
    return (",".join(f"{v:g}" for v in values) + "\r\n").encode()


def wait_for_file(path, timeout: float = 20.0) -> None:
    """The recorder creates its output right after it has opened the port."""
    end = time.monotonic() + timeout
    while not path.exists():
        if time.monotonic() > end:
            raise TimeoutError(f"{path} was never created: the recorder did not open the port")
        time.sleep(0.01)


@contextlib.contextmanager
def device(tmp_path, chunks, pause: float = 0.0, gap: float = 0.0):
    """A device on a pty that writes `chunks` (bytes, `gap` s apart) once the recording exists (after `pause` s
    more), then waits until the reader took them all; yields (link, recording, done: an Event set then)."""
    link, recording, done = tmp_path / "ttyDEV", tmp_path / "rec.csv", threading.Event()
    port = Pty(link)

    def run():
        wait_for_file(recording)
        time.sleep(pause)
        for chunk in chunks:
            port.write(chunk)
            time.sleep(gap)
        port.drain()
        done.set()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    try:
        yield link, recording, done
    finally:
        thread.join(timeout=25)
        port.close()


def record(tmp_path, spec, chunks, pause: float = 0.0, units=None, gap: float = 0.0):
    """Record `chunks` through a pty with --columns `spec`; returns (stats, recording, warnings)."""
    warnings = []
    with device(tmp_path, chunks, pause, gap) as (link, recording, done):
        columns = parse_columns(spec, units=units)
        recorder = Recorder(str(link), 115200, TextDecoder(columns), output=recording, duration=20,
                            units={c.name: c.unit for c in columns if c.unit}, should_stop=done.is_set,
                            warn=warnings.append)
        stats = recorder.run()
    assert done.is_set(), "the device did not see its bytes read"
    return stats, recording, warnings


def values(recording, names=("seq", "mx", "my", "mz")):
    rec = fluxcal.read_csv(recording)
    return rec, np.column_stack([rec.columns[n] for n in names])


@pytest.mark.parametrize("spec, first, again", [
    ("seq,mx[uT],my[uT],mz[uT]", "seq,mx[uT],my[uT],mz[uT]", "seq,mz[uT],mx[uT],my[uT]"),  # the newcomer's csvh3
    ("seq,mx [uT],my [uT],mz [uT]", "seq,mx [uT],my [uT],mz [uT]", "seq,mz [uT],mx [uT],my [uT]"),
    ("seq,mx,my,mz", "seq,MX[µT],MY[µT],MZ[µT]", "seq,MZ (uT),MX (uT),MY (uT)"),  # units printed, none stated
    ("seq,mx[uT],my[uT],mz[uT]", "n,x,y,z", "n,z,x,y"),  # --columns renames the device's fields by position
])
def test_a_reprinted_header_with_units_is_followed(tmp_path, spec, first, again):
    """`seq,mz[uT],mx[uT],my[uT]` after `seq,mx[uT],...`: the lines after it are in its order. It was rejected as
    `non_numeric` (its names carry units, --columns' were compared whole) and mz was stored under mx."""
    chunks = [(first + "\r\n").encode(), b"".join(line(r) for r in ROWS[:4]),
              (again + "\r\n").encode(), b"".join(line((s, z, x, y)) for s, x, y, z in ROWS[4:])]
    stats, recording, warnings = record(tmp_path, spec, chunks)
    rec, got = values(recording, ("seq", "mx", "my", "mz") if spec.startswith("seq") else ("t", "mx", "my", "mz"))
    np.testing.assert_array_equal(got, np.array(ROWS, dtype=float))
    # the two headers are followed: counted apart, not rejected (a blind check: a header used was reported as the
    # first rejected line, hiding the first real one)
    assert stats.records == len(ROWS) and stats.headers == 2 and not stats.rejected and not warnings
    assert "Followed 2 header lines the device printed" in stats.report() and "no lines rejected" in stats.report()
    assert rec.units["mx"] == "uT"
    assert f"header line {again!r}: columns in its order from here on" in rec.metadata["notes"]


@pytest.mark.parametrize("spec, header, reason, said", [
    ("seq,mx[uT],my[uT],mz[uT]", "seq,mz[nT],mx[nT],my[nT]", "unit", "column 'mz' is in nT there, in uT"),
    ("t,mx,my,mz", "seq,mz,mx,my", "fields", "it puts mx, my, mz at other places than the columns t,mx,my,mz"),
])
def test_a_reprinted_header_that_cannot_be_followed_refuses_the_lines_after_it(tmp_path, spec, header, reason, said):
    """A header in other units (no conversion, as for kv lines), or one that puts mx elsewhere without naming
    the columns: the lines after it are refused, with a warning and a note, until a header that can be followed;
    they were recorded as if nothing had changed (mz under mx, nT under uT)."""
    names = spec.replace("[uT]", "")
    chunks = [(names + "\r\n").encode(), b"".join(line(r) for r in ROWS[:3]),
              (header + "\r\n").encode(), b"".join(line((s, z, x, y)) for s, x, y, z in ROWS[3:6]),
              (names + "\r\n").encode(), b"".join(line(r) for r in ROWS[6:])]
    stats, recording, warnings = record(tmp_path, spec, chunks)
    _, got = values(recording, (names.split(",")[0], "mx", "my", "mz"))
    np.testing.assert_array_equal(got, np.array(ROWS[:3] + ROWS[6:], dtype=float))
    assert stats.records == 5 and stats.rejected[reason] >= 4  # the header and the three lines after it
    assert sum(stats.rejected.values()) == 4 and stats.headers == 2  # the columns' own two headers, followed
    assert len(warnings) == 1 and said in warnings[0] and "The lines after it are refused" in warnings[0]
    assert said in recording.read_text()  # the file says why lines are missing


def test_a_header_printed_on_start_up_names_the_columns(tmp_path):
    """`fluxcal record` without --columns; the device prints `seq,mx[uT],my[uT],mz[uT]` as it starts (an Arduino
    resetting on the open), then its rows. The header was thrown away as partial and every row rejected (4 fields,
    3 expected): 0 records."""
    link, recording = tmp_path / "ttyDEV", tmp_path / "rec.csv"
    port = Pty(link)
    sent = threading.Event()

    def run():
        wait_for_file(recording)
        port.write(b"seq,mx[uT],my[uT],mz[uT]\r\n" + b"".join(line(r) for r in ROWS))
        port.drain()
        sent.set()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    try:
        result = run_cli("record", "--port", link, "-o", recording, "--duration", 1.5)
    finally:
        thread.join(timeout=25)
        port.close()
    assert sent.is_set() and result.returncode == 0, result.stdout + result.stderr
    assert f"Kept {len(ROWS)} records" in result.stdout and "partial" not in result.stdout, result.stdout
    rec, got = values(recording)
    assert list(rec.columns) == ["t_host", "seq", "mx", "my", "mz"] and rec.units["mz"] == "uT"
    np.testing.assert_array_equal(got, np.array(ROWS, dtype=float))


def test_the_first_line_after_a_quiet_open_is_kept(tmp_path):
    """No byte for QUIET_OPEN_S after the open (pyserial's open empties the input queue): the first line started after
    the open and is whole, and the file says it was taken so. Here a device at 50 Hz starts 0.8 s after the open (an
    Arduino's sketch after the reset the open causes): its first line had been rejected as partial, because the rule
    asked for a second of silence, longer than such a device is ever quiet."""
    assert serial_module.QUIET_OPEN_S <= 0.5  # twice a USB adapter's longest latency timer (255 ms)
    rows = [line((k / 50, *r[1:])) for k, r in enumerate(ROWS)]
    stats, recording, _ = record(tmp_path, "t,mx,my,mz", rows, pause=0.8, units="uT", gap=0.02)
    rec, got = values(recording, ("t", "mx", "my", "mz"))
    assert stats.records == len(ROWS) and not stats.rejected, stats.report()
    np.testing.assert_array_equal(got[:, 1:], np.array(ROWS, dtype=float)[:, 1:])
    assert "after the port opened: the device's first line is taken whole" in rec.metadata["notes"]


def test_the_first_line_is_partial_without_the_quiet_rule():
    """Recorder(quiet_open_s=None): the first line after an open is always `partial` (a device known to stream before
    the open); a silence that is not a positive number of seconds is refused."""
    class QuietPort:
        in_waiting = 0

    for quiet_open_s, first in ((None, "partial"), (0.5, (1.0, 2.0, 3.0))):
        decoder = TextDecoder(parse_columns("mx,my,mz"))
        recorder = Recorder("loop://", decoder=decoder, quiet_open_s=quiet_open_s, clock=lambda: 10.0)
        recorder._opened_at = 9.0  # opened a second ago, nothing came since
        recorder._listen(QuietPort())
        event = next(decoder.feed(b"1,2,3\n"))
        assert (event.reason if hasattr(event, "reason") else event) == first, quiet_open_s
    with pytest.raises(ValueError, match="quiet_open_s: 0 is not a positive number of seconds"):
        Recorder("loop://", decoder=decoder, quiet_open_s=0)


def test_a_status_line_of_plain_words_is_no_header():
    """A sketch's status line ("my sensor ready", "Sensor init OK") is a line of other fields: one had refused every
    line after it (it holds `my` at another place), another was taken for the device's names by position and hid
    its real header's reorder, storing z under mx (a review). A header it prints afterwards is still followed."""
    def events(decoder, lines):
        out = []
        for raw in lines:
            out += list(decoder.feed(raw + b"\n"))
        return [e if isinstance(e, tuple) else e.reason for e in out]

    decoder = TextDecoder(parse_columns("mx,my,mz"))
    decoder.port_was_quiet()  # (the first line is whole)
    got = events(decoder, [b"1,2,3", b"my sensor ready", b"4,5,6", b"7,8,9"])
    assert got == [(1.0, 2.0, 3.0), "non_numeric", (4.0, 5.0, 6.0), (7.0, 8.0, 9.0)], got
    decoder = TextDecoder(parse_columns("mx,my,mz"))
    decoder.port_was_quiet()
    got = events(decoder, [b"Sensor init OK", b"x,y,z", b"1,2,3", b"z,x,y", b"30,10,20"])
    assert got[-1] == (10.0, 20.0, 30.0), got
