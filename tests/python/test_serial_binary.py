"""Binary frames (`--format binary-spec`) of fluxcal.io.serial: on bytes, and through a real pseudo-terminal
driven by tests/python/fake_device.py (`--format binary`: sync word, struct payload, checksum, and the
faults it injects are described there)."""
from __future__ import annotations

import contextlib
import functools
import json
import operator
import struct
import subprocess
import sys
from argparse import Namespace
from pathlib import Path

import numpy as np
import pytest

import fluxcal
from fluxcal.io.serial import FrameDecoder, Recorder, Reject, decoder_from_args, parse_columns, parse_range, \
    parse_scale
from fake_device import running  # noqa: E402  (tests/python is on sys.path)

HERE = Path(__file__).resolve().parent
SYNC = bytes.fromhex("A55A")
COUNT_NT = 5.0  # the fake device's integer fields: 5 nT per count


def xor8(payload: bytes) -> int:
    return functools.reduce(operator.xor, payload, 0)


def frame(values, layout="<hhh", sync=SYNC):
    payload = struct.pack(layout, *values)
    return sync + payload + bytes([xor8(payload)])


def decode(decoder, data: bytes, chunk: int | None = None):
    """Feed `data` whole or in `chunk`-byte pieces; returns (records, reject reasons in order)."""
    records, reasons = [], []
    for piece in [data] if chunk is None else [data[i:i + chunk] for i in range(0, len(data), chunk)]:
        for event in decoder.feed(piece):
            (reasons.append(event.reason) if isinstance(event, Reject) else records.append(event))
    return records, reasons


# -- on bytes ----------------------------------------------------------------------------------------------

@pytest.mark.parametrize("chunk", [None, 1, 4, 9])
def test_a_false_sync_or_a_cut_frame_does_not_swallow_the_next_frame(chunk):
    """A sync word in garbage, or a frame that lost bytes, starts a frame that fails its checksum; the good
    frame that begins inside that false frame's length is still decoded."""
    cut = frame((1, 2, 3))[:5]                                   # sync + 3 payload bytes, the rest lost
    stream = (frame((0, 0, 1))
              + b"\x01\x02" + SYNC + b"\x09"                     # line noise holding the sync word
              + frame((4, 5, 6))
              + cut + frame((7, 8, 9))
              + frame((10, 11, 12)))
    decoder = FrameDecoder("<hhh", SYNC, parse_columns(None), "xor8")
    decoder.reset()
    records, reasons = decode(decoder, stream, chunk)
    assert records == [(0.0, 0.0, 1.0), (4.0, 5.0, 6.0), (7.0, 8.0, 9.0), (10.0, 11.0, 12.0)]
    assert reasons == ["binary", "checksum", "checksum"]


@pytest.mark.parametrize("chunk", [None, 1, 5])
def test_one_damaged_frame_is_one_checksum_reject_even_when_the_sync_overlaps_itself(chunk):
    """A sync word AAAA overlaps itself (AA AA AA), and payload bytes may hold it: the candidates found
    inside a damaged frame fail too, and are counted with it, not as more damaged frames."""
    sync = bytes.fromhex("AAAA")
    good = [frame((k, 2 * k, -k), sync=sync) for k in (1, 2, 3)]
    damaged = bytearray(frame((0xAA, -0x5556, 7), sync=sync))    # payload AA 00 AA AA (0xAAAA as int16) …
    damaged = bytes([0xAA]) + bytes(damaged)                    # … after an extra AA: three overlapping syncs
    damaged = damaged[:-1] + bytes([damaged[-1] ^ 0xFF])        # and a wrong checksum
    decoder = FrameDecoder("<hhh", sync, parse_columns(None), "xor8")
    decoder.reset()
    records, reasons = decode(decoder, good[0] + damaged + good[1] + good[2], chunk)
    assert records == [(1.0, 2.0, -1.0), (2.0, 4.0, -2.0), (3.0, 6.0, -3.0)]
    assert reasons.count("checksum") == 1, reasons
    # two separate damaged frames are still two rejects, also back to back
    other = frame((9, 9, 9), sync=sync)
    other = other[:-1] + bytes([other[-1] ^ 0x0F])
    for stream in (good[0] + damaged + good[1] + damaged + good[2], good[0] + damaged + other + good[1] + good[2]):
        decoder.reset()
        records, reasons = decode(decoder, stream, chunk)
        assert len(records) == 3 and reasons.count("checksum") == 2, reasons


def test_scale_factors_per_column():
    columns = parse_columns("t[ms],mx[nT],my[nT],mz[nT]")
    assert parse_scale("1,0.1,-0.1,2", columns) == (1.0, 0.1, -0.1, 2.0)   # a negative factor flips an axis
    assert parse_scale("0.1", columns) == (1.0, 0.1, 0.1, 0.1)             # one factor: all but device time t
    for bad, fragment in [("0.1,0.1", "2 factors"), ("a", "'a' in 'a' is not a number"), ("0", "non-zero"),
                          ("1,0.1,inf,1", "finite"), ("", "not a number")]:
        with pytest.raises(ValueError, match="--scale") as info:
            parse_scale(bad, columns)
        assert fragment in str(info.value)

    base = dict(format="binary-spec", columns="t[ms],mx[nT],my[nT],mz[nT]", units=None, frame="<Ihhh",
                sync="A55A", checksum="xor8", scale="1,0.1,0.1,0.1", range=["-1000:1000"])
    decoder = decoder_from_args(Namespace(**base))
    raw = [(0, 1234, -5, 9999), (20, -7, 3, 10001)]              # 10001 counts = 1000.1 nT: out of range
    records, reasons = decode(decoder, b"".join(frame(v, "<Ihhh") for v in raw))
    assert records == [(0.0, 1234 * 0.1, -5 * 0.1, 9999 * 0.1)] and reasons == ["out_of_range"]
    assert decoder.metadata["scale"] == "t=1.0,mx=0.1,my=0.1,mz=0.1"
    unscaled = decoder_from_args(Namespace(**{**base, "scale": None, "range": []}))
    assert decode(unscaled, frame(raw[0], "<Ihhh"))[0] == [tuple(map(float, raw[0]))]
    assert "scale" not in unscaled.metadata
    with pytest.raises(ValueError, match="--scale"):
        decoder_from_args(Namespace(**{**base, "format": "csv", "frame": None, "sync": None}))
    with pytest.raises(ValueError, match="3 factors for 4 columns"):
        FrameDecoder("<Ihhh", SYNC, parse_columns("t,mx,my,mz"), scale=(1, 1, 1))


# -- through a pseudo-terminal ------------------------------------------------------------------------------

@contextlib.contextmanager
def binary_device(tmp_path, *args):
    """Start the fake device sending binary frames; yields (link, recording, sent) once its port exists."""
    with running(tmp_path, "--format", "binary", *args) as handles:
        yield handles


def recorded(recording, names):
    rec = fluxcal.read_csv(recording)
    return rec, np.column_stack([rec.columns[n] for n in names])


@pytest.mark.parametrize("layout, checksum, seed", [("<Ihhh", "xor8", 7), (">Ihhh", "sum8", 8)])
def test_recorder_keeps_every_good_frame_through_pty(tmp_path, layout, checksum, seed):
    """Every fault the device injects (frame tails at each connection, garbage, a sync word in garbage,
    a flipped bit, lost bytes, a damaged sync word, an out-of-range frame, a replug mid-frame): every
    good frame is recorded exactly, in order, nothing else is, and each fault is counted by its reason."""
    names = ["t", "mx", "my", "mz"]
    columns = parse_columns("t[ms],mx[counts],my[counts],mz[counts]")
    with binary_device(tmp_path, "--frame", layout, "--checksum", checksum, "--seed", seed, "--records", 300,
                       "--rate", 1000) as (link, recording, sent):
        decoder = FrameDecoder(layout, SYNC, columns, checksum, parse_range("-20000:20000", columns))
        stats = Recorder(str(link), 115200, decoder, output=recording, duration=20,
                         units={c.name: c.unit for c in columns}, should_stop=sent.exists).run()
    assert sent.exists(), "the device did not finish within the recording's duration"
    truth = json.loads(sent.read_text())
    assert set(truth["faults"]) == {"start", "garbage", "sync-in-garbage", "checksum", "lost-sync", "bad-sync",
                                    "out-of-range", "replug"}
    rec, rows = recorded(recording, names)
    assert np.array_equal(rows, np.array(truth["records"], dtype=float))  # values, order and count
    assert stats.records == len(truth["records"]) == 300
    assert dict(stats.rejected) == truth["injected"] == {"partial": 3, "binary": 3, "checksum": 3,
                                                         "out_of_range": 1}
    assert stats.reconnects == 1 and stats.stopped == "done"
    assert np.all(np.diff(rec.columns["t_host"]) >= 0) and rec.units["mx"] == "counts"
    assert rec.metadata["frame"] == layout and rec.metadata["sync"] == "A55A" and rec.metadata["checksum"] == checksum
    notes = rec.metadata["notes"]
    assert "disconnected at t_host=" in notes and "reconnected at t_host=" in notes
    assert "summary: 300 records, 10 rejected (3 binary, 3 checksum, 1 out_of_range, 3 partial), 1 reconnects" in notes
    # the device time (ms, 50 Hz) shows what was lost between recorded frames: one sample each for the
    # flipped bit, the lost bytes, the damaged sync word, the out-of-range frame, and two at the replug
    # (the frame in flight, the tail at the reconnect); garbage is not a sample
    gaps = np.diff(rows[:, 0]) / 20.0 - 1
    assert np.all(gaps >= 0) and np.sum(gaps) == 6


def test_record_command_binary_with_scale_through_pty(tmp_path):
    """`fluxcal record --format binary-spec --scale`: counts become nT in the file, --range applies to the
    scaled values, the report counts rejects by reason and the summary note is the last line."""
    with binary_device(tmp_path, "--frame", "<Ihhh", "--checksum", "sum8", "--seed", 5, "--records", 150,
                       "--rate", 1000) as (link, recording, sent):
        result = subprocess.run(
            [sys.executable, "-m", "fluxcal", "record", "--port", str(link), "-o", str(recording), "--duration", "4",
             "--format", "binary-spec", "--frame", "<Ihhh", "--sync", "a55a", "--checksum", "sum8",
             "--columns", "t[ms],mx[nT],my[nT],mz[nT]", f"--scale=1,{COUNT_NT},{COUNT_NT},{COUNT_NT}",
             "--range=-100000:100000"],
            capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL)
    assert result.returncode == 0, result.stdout + result.stderr
    assert sent.exists(), "the device did not finish within the recording's duration"
    truth = json.loads(sent.read_text())
    rec, rows = recorded(recording, ["t", "mx", "my", "mz"])
    expected = np.array(truth["records"], dtype=float) * [1.0, COUNT_NT, COUNT_NT, COUNT_NT]
    assert np.array_equal(rows, expected) and len(rows) == 150
    assert rec.units["mx"] == "nT" and rec.metadata["scale"] == "t=1.0,mx=5.0,my=5.0,mz=5.0"
    assert np.abs(rows[:, 1:]).max() > 20000  # scaled: raw counts stay below 20000 for this device
    report = " ".join(result.stdout.split())
    assert "Kept 150 records" in report and "Reconnected 1 time" in report and "Stopped: duration" in report
    assert "10 rejected (3 binary, 3 checksum, 1 out_of_range, 3 partial)" in report
    last = recording.read_text().splitlines()[-1]
    assert last.startswith("# note: summary: 150 records, 10 rejected") and "stopped: duration" in last


def test_float_frames_without_checksum_through_pty(tmp_path):
    """No checksum, float32 fields, no device time: the faults a decoder can see without a checksum
    (frame tails, garbage, a damaged sync word, out of range, a replug) cost only their own bytes."""
    with binary_device(tmp_path, "--frame", "<fff", "--checksum", "none", "--seed", 9, "--records", 150,
                       "--rate", 1000) as (link, recording, sent):
        columns = parse_columns("mx[nT],my[nT],mz[nT]")
        decoder = FrameDecoder("<fff", SYNC, columns, None, parse_range("-100000:100000", columns))
        stats = Recorder(str(link), 115200, decoder, output=recording, duration=20, units={"mx": "nT"},
                         should_stop=sent.exists).run()
    truth = json.loads(sent.read_text())
    assert truth["faults"] == ["start", "garbage", "bad-sync", "out-of-range", "replug"]
    _, rows = recorded(recording, ["mx", "my", "mz"])
    assert np.array_equal(rows, np.array(truth["records"], dtype=float)) and len(rows) == 150
    assert rows[0, 0] != round(rows[0, 0])  # float fields: not counts
    assert dict(stats.rejected) == truth["injected"] == {"partial": 3, "binary": 2, "out_of_range": 1}
    assert stats.reconnects == 1


def test_a_zero_or_nan_scale_and_a_nan_duration_are_refused():
    for scale in ((0, 1, 1), (float("nan"), 1, 1)):  # 0: every record 0,0,0, silently dropped by the fits
        with pytest.raises(ValueError, match="scale: .* must be finite, non-zero factors"):
            FrameDecoder("<hhh", SYNC, parse_columns(None), scale=scale)
    for duration in (float("nan"), 0, -1):  # NaN recorded forever, ≤ 0 nothing without a word
        with pytest.raises(ValueError, match="duration: .* is not a positive number of seconds"):
            Recorder("loop://", duration=duration)
