"""A fake serial magnetometer on a pseudo-terminal, run as its own process by tests/python/test_serial.py.

    python fake_device.py --link LINK --recording REC.csv --sent SENT.json [--script full|endless] ...

The device owns the master side of a pty pair; the program under test opens the slave through the
stable symlink LINK, as it would open /dev/serial/by-id/usb-... for a USB adapter. A disconnect is a
replug: the device closes the master (the reader gets EIO → SerialException, and the slave node
disappears), waits, makes a NEW pty pair and atomically repoints LINK at the new slave — what udev
does when a USB adapter re-enumerates as another /dev/ttyACMn. The reader has to reopen LINK.

Synchronisation without timing guesses:
- "ready" on stdout once LINK exists (the test then starts the recorder, which must open it at once);
- the device starts writing on connection k only when the recorder has opened the port: pyserial's
  open flushes the input queue, so anything written earlier would be lost by design of the port, not
  by the recorder. The recorder writes the recording's header after opening, and a
  "# note: reconnected" line after each reopen; the device waits for those in REC.csv;
- before a disconnect and at the end it waits until the reader has consumed every byte (the slave's
  input queue, FIONREAD on the slave fd the device also holds, stays empty), because a hang-up
  discards bytes not yet read.

Stream: a simulated rotating magnetometer (fluxcal.sim.tumble, random_sensor, field 50000 nT, seeded),
one record per line `t,mx,my,mz` (csv) or `t=.. X=.. Y=.. Z=..` (kv), t the device time (s), fields in nT.
Script "full" injects: a partial line at the start of each connection (2), garbage bytes (2 lines),
a non-numeric line, an out-of-range line (needs --range -200000:200000), a line with too few fields,
a 0.5 s pause, a partial line just before the disconnect, and the reconnect. SENT.json (written when
the reader has consumed everything) lists the exact text of every good record and the injected
counts by reason. Script "endless" streams good records until terminated, appending each one to
SENT.json's sibling SENT.jsonl as it goes, and writes the true calibration to SENT.json first.

Binary frames (`--format binary`, script "full"): each record is the sync word (`--sync`, hex), the
reading packed with `--frame` (3 fields mx,my,mz or 4 fields t,mx,my,mz; integer fields carry t in ms
and the field in counts of `--count-nt` nT, float fields carry s and nT), then with `--checksum
sum8|xor8` one byte: the sum mod 256 or the XOR of the payload bytes. `--faults` picks what is injected
(default: every fault the checksum setting can detect), each checked against the stream it lands in so
that its outcome is the one counted (a violated assumption stops the device with a message):
  start           the tail of a frame at the start of each connection (partial)
  garbage         bytes without the sync word between frames (binary)
  sync-in-garbage garbage holding the sync word by accident, the next frame starting within one frame
                  length of it (binary for the bytes before it, checksum for the false frame)
  checksum        a frame with one payload bit flipped (checksum)
  lost-sync       a frame with bytes lost from its middle, the next frame right after (checksum)
  bad-sync        a frame whose sync word is damaged: its bytes are garbage (binary)
  out-of-range    a frame with mx at 30000 counts, 30000 × --count-nt nT in a float field (out_of_range;
                  needs a --range that excludes it)
  replug          half a frame, then the disconnect (partial)
The frames lost to faults are not in SENT.json's records, which hold every good frame's fields as the
frame carries them (unscaled, float32 fields rounded as packed), in order.
"""
from __future__ import annotations

import argparse
import contextlib
import fcntl
import functools
import json
import operator
import os
import re
import struct
import subprocess
import sys
import termios
import threading
import time
import tty
from pathlib import Path

import numpy as np

FIELD_NT = 50000.0


class Pty:
    """A pty pair whose slave is published at `link`."""

    def __init__(self, link: Path):
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)  # no echo, no line editing, no signals from garbage bytes such as 0x03
        tmp = link.with_name(link.name + ".new")
        tmp.unlink(missing_ok=True)
        os.symlink(os.ttyname(self.slave), tmp)
        os.replace(tmp, link)  # atomic: the reader sees the old or the new target, never none

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            view = view[os.write(self.master, view):]

    def unread(self) -> int:
        return struct.unpack("i", fcntl.ioctl(self.slave, termios.FIONREAD, b"\0" * 4))[0]

    def drain(self, timeout: float = 20.0) -> None:
        """Wait until the reader has taken every byte (three empty looks 20 ms apart: the kernel moves
        written bytes to the slave's queue asynchronously)."""
        end, empty = time.monotonic() + timeout, 0
        while empty < 3:
            if time.monotonic() > end:
                raise SystemExit("fake_device: the reader does not consume the stream")
            empty = empty + 1 if self.unread() == 0 else 0
            time.sleep(0.02)

    def close(self) -> None:
        os.close(self.master)
        os.close(self.slave)


def wait_for(recording: Path, text: str, count: int = 1, timeout: float = 20.0) -> None:
    """Wait until the recorder has written `text` `count` times into its recording."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if recording.exists() and recording.read_text(errors="replace").count(text) >= count:
            return
        time.sleep(0.01)
    raise SystemExit(f"fake_device: {recording} never showed {text!r} x{count}")


class Stream:
    """Good records of the simulated sensor, formatted as the device prints them."""

    def __init__(self, seed: int, fmt: str, rate_hz: float, turn_rate_deg: float, n: int):
        from fluxcal import sim

        rng = np.random.default_rng(seed)
        direction = np.array([0.4, 0.05, 0.915])
        field = FIELD_NT * direction / np.linalg.norm(direction)
        scene = sim.tumble(duration_s=n / rate_hz, rate_hz=rate_hz, turn_rate_deg=turn_rate_deg,
                           temperature=None, rng=rng)
        self.simulation = sim.simulate(scene, sim.random_sensor(FIELD_NT, rng, noise=0.002), field, rng)
        self.fmt, self.rate_hz, self.i = fmt, rate_hz, 0

    def truth(self) -> dict:
        cal = self.simulation.true_calibration(units="nT")
        return {"offset": cal.offset.tolist(), "matrix": cal.matrix.tolist(), "field_norm": cal.field_norm}

    def next(self):
        """(fields as text, the line's bytes) of the next record."""
        k = self.i % len(self.simulation.t)  # the endless script goes round the scene again
        t = self.i / self.rate_hz
        self.i += 1
        fields = [f"{t:.3f}", *(f"{v:.2f}" for v in self.simulation.readings[k])]
        if self.fmt == "kv":
            line = " ".join(f"{k}={v}" for k, v in zip(("t", "X", "Y", "Z"), fields))
        else:
            line = ",".join(fields)
        return fields, (line + "\r\n").encode()


def send_good(port: Pty, stream: Stream, n: int, rate: float, sent: list) -> None:
    """n good records at `rate` lines per second, written in 10 ms batches."""
    batch = max(1, int(rate * 0.01))
    for start in range(0, n, batch):
        chunk = b""
        for _ in range(min(batch, n - start)):
            fields, line = stream.next()
            sent.append(fields)
            chunk += line
        port.write(chunk)
        time.sleep(batch / rate)


def run_full(args, stream: Stream, link: Path, recording: Path) -> None:
    sent, injected = [], {"partial": 0, "binary": 0, "non_numeric": 0, "out_of_range": 0, "fields": 0}
    block = args.records // 3

    def inject(port, data, reason):
        port.write(data)
        injected[reason] += 1

    port = Pty(link)
    print("ready", flush=True)
    wait_for(recording, "\nt_host,")                            # connection 1 is open
    inject(port, b"5,-1520.25,331.5\r\n", "partial")              # tail of a line the device was printing
    send_good(port, stream, block // 2, args.rate, sent)
    inject(port, b"\x00\x13\xff\xfe\x1b[2J\x80\x81\r\n", "binary")   # line noise
    send_good(port, stream, 5, args.rate, sent)
    inject(port, b"12.5,\xff\xfe,3.0,4.0\r\n", "binary")          # a good-looking line with a bad byte
    send_good(port, stream, 5, args.rate, sent)
    inject(port, (b"t=1 X=a Y=b Z=c" if args.format == "kv" else b"1.000,12.5,abc,7.0") + b"\r\n", "non_numeric")
    inject(port, (b"t=1.0 X=9900000.00 Y=1.00 Z=2.00" if args.format == "kv" else b"1.000,9900000.00,1.00,2.00")
           + b"\r\n", "out_of_range")
    inject(port, (b"t=1.0 X=1.00" if args.format == "kv" else b"1.000,1.00") + b"\r\n", "fields")
    send_good(port, stream, block - block // 2, args.rate, sent)
    time.sleep(0.5)                                             # the pause: quiet, not a disconnect
    send_good(port, stream, block, args.rate, sent)
    port.drain()
    inject(port, b"1234.5,-6", "partial")                       # cut off by the disconnect
    port.drain()
    port.close()                                                # unplugged: reader gets EIO
    time.sleep(0.3)                                             # LINK points nowhere meanwhile
    port = Pty(link)                                            # plugged in again, new pty
    wait_for(recording, "# note: reconnected")
    inject(port, b"7.5,88.25\r\n", "partial")
    send_good(port, stream, args.records - 2 * block, args.rate, sent)
    port.drain()
    tmp = Path(args.sent).with_suffix(".tmp")
    tmp.write_text(json.dumps({"records": sent, "injected": injected, "truth": stream.truth()}))
    os.replace(tmp, args.sent)
    linger(port)


CHECKSUMS = {"sum8": lambda payload: sum(payload) & 0xFF,
             "xor8": lambda payload: functools.reduce(operator.xor, payload, 0)}
FAULTS = ("start", "garbage", "sync-in-garbage", "checksum", "lost-sync", "bad-sync", "out-of-range", "replug")
NEED_CHECKSUM = ("sync-in-garbage", "checksum", "lost-sync")  # without one, these frame wrong records


class FrameStream:
    """Good records of the simulated sensor as binary frames: sync word, struct payload, checksum."""

    def __init__(self, stream: Stream, frame: str, sync: bytes, checksum: str, count_nt: float):
        self.stream, self.struct, self.sync, self.count_nt = stream, struct.Struct(frame), sync, count_nt
        self.checksum = CHECKSUMS.get(checksum)
        codes = []
        for count, code in re.findall(r"(\d*)([a-zA-Z?])", frame.lstrip("@=<>!")):
            codes += [] if code == "x" else [code] * int(count or 1)
        self.integer = [code not in "efd" for code in codes]  # integer fields carry ms and counts
        if len(codes) not in (3, 4) or len(self.struct.unpack(bytes(self.struct.size))) != len(codes):
            raise SystemExit(f"fake_device: --frame {frame!r}: give 3 (mx,my,mz) or 4 (t,mx,my,mz) numeric fields")
        self.size = len(sync) + self.struct.size + (1 if self.checksum else 0)

    def pack(self, fields) -> bytes:
        payload = self.struct.pack(*fields)
        return self.sync + payload + (bytes([self.checksum(payload)]) if self.checksum else b"")

    def fields(self, t: float, reading) -> tuple:
        """The fields a frame carries for device time t (s) and a reading (nT), float32 rounding included."""
        values = [t * 1000.0 if self.integer[0] else t] if len(self.integer) == 4 else []
        values += [v / self.count_nt if integer else v for v, integer in zip(reading, self.integer[-3:])]
        values = [round(v) if integer else v for v, integer in zip(values, self.integer)]
        return self.struct.unpack(self.struct.pack(*values))

    def next(self, reading=None):
        """(fields, frame bytes) of the next sample: the simulated reading, or `reading` (nT) instead."""
        s = self.stream
        t = s.i / s.rate_hz
        if reading is None:
            reading = s.simulation.readings[s.i % len(s.simulation.t)]
        s.i += 1
        fields = self.fields(t, reading)
        return fields, self.pack(fields)

    def valid(self, candidate: bytes) -> bool:
        """Whether frame-sized bytes starting with the sync word pass the checksum (never without one)."""
        payload = candidate[len(self.sync):len(self.sync) + self.struct.size]
        return self.checksum is not None and self.checksum(payload) == candidate[-1]


def run_binary(args, stream: Stream, link: Path, recording: Path) -> None:
    frames = FrameStream(stream, args.frame, bytes.fromhex(args.sync), args.checksum, args.count_nt)
    sync, size = frames.sync, frames.size
    if args.faults == "all":
        faults = [f for f in FAULTS if args.checksum != "none" or f not in NEED_CHECKSUM]
    else:
        faults = [f for f in args.faults.split(",") if f]
    unknown = sorted(set(faults) - set(FAULTS))
    if unknown:
        raise SystemExit(f"fake_device: --faults: unknown {unknown} (known: {', '.join(FAULTS)})")
    if args.checksum == "none" and set(faults) & set(NEED_CHECKSUM):
        raise SystemExit(f"fake_device: --faults {', '.join(NEED_CHECKSUM)} need a --checksum")
    sent, injected = [], {}

    def good_frames(n: int) -> bytes:
        data = b""
        for _ in range(n):
            fields, data_frame = frames.next()
            sent.append(list(fields))
            data += data_frame
        return data

    def send_good_frames(port, n: int) -> None:
        """n good frames at --rate frames per second, in 10 ms batches."""
        batch = max(1, int(args.rate * 0.01))
        for start in range(0, n, batch):
            port.write(good_frames(min(batch, n - start)))
            time.sleep(min(batch, n - start) / args.rate)

    def skipped_whole(junk: bytes, after: bytes) -> bool:
        """Hunting skips all of `junk` in one run: the first sync word is where `after` starts."""
        return (junk + after).find(sync) == len(junk)

    def inject(port, fault: str, make, **reasons) -> None:
        """If `fault` is on: write the bytes of make() -> (bytes, as_intended(following)), then a good frame,
        and count `reasons`. The fault's outcome depends on what follows it, hence the check."""
        if fault not in faults:
            return
        junk, as_intended = make()
        following = good_frames(1)
        if not as_intended(following):
            raise SystemExit(f"fake_device: fault {fault!r} would not be counted as {reasons} in this stream")
        for reason, n in reasons.items():
            injected[reason] = injected.get(reason, 0) + n
        port.write(junk + following)

    def frame_tail():
        tail = frames.next()[1][len(sync) + 1:]                  # the device was mid-frame
        return tail, lambda following: skipped_whole(tail, following)

    def garbage():
        junk = b"\x00\x13\xff\xfe\x1b[2J\x80" + sync[:1] + b"\x81"
        return junk, lambda following: skipped_whole(junk, following)

    def sync_in_garbage():
        before, after = b"\x13\x37", b"\x42\x00"                # a sync word amid line noise
        return before + sync + after, lambda following: (
            skipped_whole(before, sync) and skipped_whole(after, following) and len(sync) + len(after) < size
            and not frames.valid((sync + after + following)[:size]))

    def bad_checksum():
        damaged = bytearray(frames.next()[1])
        damaged[len(sync) + 1] ^= 0x10                           # one bit: sum8 and xor8 both change
        return bytes(damaged), lambda following: skipped_whole(bytes(damaged[1:]), following)

    def lost_sync():
        whole = frames.next()[1]
        lost = 2                                                 # a UART overrun lost `lost` bytes
        cut = whole[:len(sync) + 1] + whole[len(sync) + 1 + lost:]
        # the false frame runs into the next one; if it passed its checksum it would be a wrong record
        return cut, lambda following: skipped_whole(cut[1:], following) and not frames.valid((cut + following)[:size])

    def bad_sync():
        damaged = bytes([sync[0] ^ 0xFF]) + frames.next()[1][1:]
        return damaged, lambda following: skipped_whole(damaged, following)

    def out_of_range():
        return frames.next([30000.0 * args.count_nt, 0.0, 0.0])[1], lambda following: True  # mx: 30000 counts

    port = Pty(link)
    print("ready", flush=True)
    wait_for(recording, "\nt_host,")                            # connection 1 is open
    inject(port, "start", frame_tail, partial=1)
    block = args.records // 3
    send_good_frames(port, block // 2)
    for fault, make, reasons in [("garbage", garbage, {"binary": 1}),
                                 ("sync-in-garbage", sync_in_garbage, {"binary": 1, "checksum": 1}),
                                 ("checksum", bad_checksum, {"checksum": 1}),
                                 ("lost-sync", lost_sync, {"checksum": 1}),
                                 ("bad-sync", bad_sync, {"binary": 1}),
                                 ("out-of-range", out_of_range, {"out_of_range": 1})]:
        inject(port, fault, make, **reasons)
        send_good_frames(port, 5)
    send_good_frames(port, max(block - len(sent), 0))
    time.sleep(0.3)                                             # a pause: quiet, not a disconnect
    send_good_frames(port, block)
    if "replug" in faults:
        port.drain()
        port.write(frames.next()[1][:size // 2])                # the frame in flight at the disconnect
        injected["partial"] = injected.get("partial", 0) + 1
        port.drain()
        port.close()                                            # unplugged: reader gets EIO
        time.sleep(0.3)                                         # LINK points nowhere meanwhile
        port = Pty(link)                                        # plugged in again, new pty
        wait_for(recording, "# note: reconnected")
        inject(port, "start", frame_tail, partial=1)
    send_good_frames(port, max(args.records - len(sent), 0))
    port.drain()
    tmp = Path(args.sent).with_suffix(".tmp")
    tmp.write_text(json.dumps({"records": sent, "injected": injected, "faults": faults, "frame_size": size,
                               "truth": stream.truth()}))
    os.replace(tmp, args.sent)
    linger(port)


def run_endless(args, stream: Stream, link: Path, recording: Path) -> None:
    Path(args.sent).write_text(json.dumps({"truth": stream.truth()}))
    port = Pty(link)
    print("ready", flush=True)
    wait_for(recording, "\nt_host,")
    port.write(b"-1520.25,331.5\r\n")                           # partial first line, as in "full"
    unplugged = threading.Event()  # set when the test closes our stdin
    threading.Thread(target=lambda: (sys.stdin.read(), unplugged.set()), daemon=True).start()
    with Path(args.sent).with_suffix(".jsonl").open("w") as log:
        while not unplugged.is_set():
            sent = []
            send_good(port, stream, max(1, int(args.rate * 0.05)), args.rate, sent)
            log.writelines(json.dumps(fields) + "\n" for fields in sent)
            log.flush()
    port.close()


def linger(port: Pty) -> None:
    """Stay plugged in, quiet, until the test closes our stdin or terminates us."""
    sys.stdin.read()
    port.close()


@contextlib.contextmanager
def running(tmp_path, *args):
    """For the tests: start this device as a process; yields (link, recording, sent) once its port exists.
    `args` are its command-line options (e.g. "--format", "binary", "--seed", 3)."""
    link, recording, sent = tmp_path / "ttyFAKE", tmp_path / "recording.csv", tmp_path / "sent.json"
    proc = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--link", str(link), "--recording",
                             str(recording), "--sent", str(sent), *map(str, args)],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "ready", "fake device did not start: " + proc.stderr.read()
        yield link, recording, sent
    finally:
        proc.stdin.close()  # the device lingers, plugged in, until its stdin closes
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.terminate()
            proc.wait(timeout=5)
        if not sent.exists():  # the device stopped early: say why (e.g. a fault it could not place)
            print("fake device stderr:", proc.stderr.read())
        proc.stderr.close()
        proc.stdout.close()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--link", required=True, help="symlink the reader opens (repointed on a replug)")
    p.add_argument("--recording", required=True, help="the recorder's output, watched to know it has opened")
    p.add_argument("--sent", required=True, help="JSON of the good records sent and the injected counts")
    p.add_argument("--script", choices=("full", "endless"), default="full")
    p.add_argument("--format", choices=("csv", "kv", "binary"), default="csv",
                   help="binary: frames as --frame/--sync/--checksum describe (script full only)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--records", type=int, default=450, help="good records in the full script")
    p.add_argument("--rate", type=float, default=500.0, help="lines per second of wall time")
    p.add_argument("--sim-rate", type=float, default=50.0, help="device sample rate (Hz): the t column")
    p.add_argument("--turn-rate", type=float, default=90.0, help="RMS turn rate of the hand, deg/s")
    p.add_argument("--frame", default="<Ihhh", help="binary: struct layout of the payload (3 or 4 fields)")
    p.add_argument("--sync", default="A55A", help="binary: sync word in hex")
    p.add_argument("--checksum", choices=("none", "sum8", "xor8"), default="xor8", help="binary: checksum byte")
    p.add_argument("--count-nt", type=float, default=5.0, help="binary: nT per count in integer fields")
    p.add_argument("--faults", default="all", help=f"binary: comma list of {','.join(FAULTS)} (default all "
                                                   "that the checksum setting can detect)")
    args = p.parse_args()
    n = args.records if args.script == "full" else 6000
    stream = Stream(args.seed, args.format, args.sim_rate, args.turn_rate, n)
    runner = run_full if args.script == "full" else run_endless
    if args.format == "binary":
        if args.script != "full":
            raise SystemExit("fake_device: --format binary runs the full script only")
        runner = run_binary
    runner(args, stream, Path(args.link), Path(args.recording))


if __name__ == "__main__":
    main()
