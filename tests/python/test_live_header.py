"""`fluxcal live` takes its columns from a header the device prints at start-up, as `fluxcal record` does (one
mechanism: fluxcal.io.serial.decoder_from_args(header_columns=True) and the decoder's header handling; the live fit
finds mx, my, mz among the columns the header named).

The device is tests/python/fake_device.py's Pty, written from a thread: it starts once the raw recording exists (the
port is open then: pyserial's open empties the input queue), prints its header and streams until the test is done;
the session stops by itself when its thresholds are met (--duration is only a safeguard)."""
from __future__ import annotations

import threading
import time

import numpy as np

import fluxcal
from fluxcal.cli import main
from conftest import simulated  # noqa: E402  (tests/python is on sys.path)
from fake_device import Pty  # noqa: E402


def test_live_takes_its_columns_from_a_header_printed_on_start_up(tmp_path, capsys):
    """`seq,mx[uT],my[uT],mz[uT]`, then `seq,mx,my,mz` rows, no --columns: the header was thrown away as partial and
    every row rejected (4 fields, expected 3), so `live` had no reading to calibrate (exit 2)."""
    s = simulated(8, n=400, noise=0.002, field_norm=50.0)
    link, raw, cal_path = tmp_path / "ttyDEV", tmp_path / "raw.csv", tmp_path / "cal.json"
    port, stop = Pty(link), threading.Event()

    def device():
        end = time.monotonic() + 20
        while not raw.exists() and time.monotonic() < end:  # the port is open once live has created --raw
            time.sleep(0.01)
        port.write(b"seq,mx[uT],my[uT],mz[uT]\r\n")
        seq = 0
        while not stop.is_set() and time.monotonic() < end:  # 1000 rows a second, round the simulated turns
            rows = [f"{k},{','.join(f'{v:.4f}' for v in s.readings[k % len(s.readings)])}\r\n"
                    for k in range(seq, seq + 20)]
            port.write("".join(rows).encode())
            seq += 20
            time.sleep(0.02)

    thread = threading.Thread(target=device, daemon=True)
    thread.start()
    try:
        code = main(["live", "--port", str(link), "-o", str(cal_path), "--raw", str(raw), "--duration", "5",
                     "--min-records", "100", "--min-coverage", "0.8", "--max-spread", "0.02", "--quiet"])
    finally:
        stop.set()
        thread.join(timeout=5)
        port.close()
    out = capsys.readouterr()
    assert code == 0, out.out + out.err
    # (a line in flight when the session stops is partial; the first line, the header, is not)
    assert "Stopped: done" in out.out and "first line after opening the port" not in out.out, out.out
    cal = fluxcal.Calibration.load(cal_path)
    truth = s.true_calibration()
    assert cal.units == "uT"  # as the header printed it
    assert np.linalg.norm(cal.offset - truth.offset) < 0.01 * 50.0, (cal.offset, truth.offset)
    rec = fluxcal.read_csv(raw)
    assert list(rec.columns) == ["t_host", "seq", "mx", "my", "mz"] and rec.units["mx"] == "uT"
    assert "columns from the device's header line 'seq,mx[uT],my[uT],mz[uT]'" in rec.metadata["notes"]
    assert cal.metadata["records"] == len(rec) and np.array_equal(np.diff(rec.columns["seq"]), np.ones(len(rec) - 1))
