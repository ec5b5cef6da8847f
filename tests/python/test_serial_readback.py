"""A recording `fluxcal record` wrote, read back: its host clock t_host is the recording's time when the device gave
no clock of its own; the device's (t, time, millis) wins when it did (fluxcal.io.columns.find_time)."""
from __future__ import annotations

import numpy as np
import pytest

import fluxcal
from fluxcal.cli import main
from fluxcal.io.serial import RecordingWriter
from conftest import simulated  # noqa: E402  (tests/python is on sys.path)


def write(path, names, rows, units):
    """A recording as the Recorder writes it (its writer: head, units, rows, the summary note)."""
    writer = RecordingWriter(path, names, {"t_host": "s", **units}, {"source": "serial port /dev/ttyUSB0"})
    for row in rows:
        writer.append(row)
    writer.note("summary: …")
    writer.close()
    return path


@pytest.fixture
def readings():
    return simulated(3, n=200, noise=0.002, field_norm=50.0).readings


def test_t_host_is_the_time_of_a_recording_without_the_devices_clock(tmp_path, readings, capsys):
    """`t_host` (host seconds, several rows per read chunk) had no part: time() was None, `calibrate` and `diagnose`
    printed no time and judged the rows in file order."""
    t_host = np.repeat(np.arange(100) * 0.02, 2)  # two rows per chunk read, as a fast device's come
    path = write(tmp_path / "rec.csv", ["t_host", "mx", "my", "mz"], np.column_stack([t_host, readings]),
                 {"mx": "uT", "my": "uT", "mz": "uT"})
    rec = fluxcal.read_recording(path)
    np.testing.assert_array_equal(rec.time(), t_host)
    assert rec.roles()["time"] == "t_host" and rec.mag_names() == ("mx", "my", "mz")
    assert main(["calibrate", str(path), "-o", str(tmp_path / "cal.json")]) == 0
    assert "time t_host" in capsys.readouterr().out


@pytest.mark.parametrize("clock, column, factor", [("t", lambda k: 0.02 * k, 1.0),
                                                   ("millis", lambda k: 1000.0 + 20.0 * k, 1e-3),
                                                   ("time", lambda k: 5.0 + 0.02 * k, 1.0)])
def test_the_devices_own_clock_wins_over_t_host(tmp_path, readings, clock, column, factor):
    """The device stamps each sample where it takes it; the host stamps a chunk when it reads it (its latency, rows
    sharing a stamp). A clock named otherwise than t (millis, time) beside t_host would make two disagreeing clocks,
    which are not guessed (None): the device's is taken."""
    k = np.arange(len(readings))
    t_host = 0.1 + np.floor(k / 4) * 0.08 + 0.003 * (k % 3)  # a jittery arrival time
    path = write(tmp_path / "rec.csv", ["t_host", clock, "mx", "my", "mz"],
                 np.column_stack([t_host, column(k), readings]), {})
    rec = fluxcal.read_recording(path)
    assert rec.roles()["time"].split()[0] == clock
    np.testing.assert_allclose(rec.time(), column(k) * factor)


def test_units_a_device_printed_after_its_first_rows_are_the_recordings(tmp_path):
    """A device whose `mx[uT],…` header came after its first rows: `fluxcal record` noted the units from there on,
    and `calibrate` said "no unit stated" beside the note (a blind check). The note's units are the columns'."""
    path = tmp_path / "late.csv"
    rows = "\n".join(f"{0.01 * k},{30 + np.cos(k)},{-5 + np.sin(k)},{40.0}" for k in range(5))
    path.write_text("# fluxcal recording\n# units: t_host=s\nt_host,mx,my,mz\n" + rows + "\n"
                    "# note: units printed by the device from here on: mx=uT, my=uT, mz=uT\n" + rows + "\n")
    rec = fluxcal.read_csv(path)
    assert rec.units["mx"] == rec.units["mz"] == "uT" and "line 9: mx=uT" in rec.metadata["units_from_note"]
