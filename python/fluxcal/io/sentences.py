"""NMEA-style sentences from an IMU's serial port: `$VNYMR,+010.071,-002.267,-001.100,+01.0968,…*64`.

Each line is `$<type>,<field>,…*<checksum>`: an 8-bit XOR of the characters between `$` and `*` as two
hex digits, or VectorNav's CRC-16 (CCITT, XMODEM) as four; a sentence whose checksum does not match is
a bad line. Known layouts (VectorNav ASCII asynchronous outputs; magnetic field in gauss, acceleration in
m/s², angular rate in rad/s, attitude in degrees):

    VNYMR  yaw, pitch, roll, mag x,y,z, accel x,y,z, gyro x,y,z
    VNMAR  mag x,y,z, accel x,y,z, gyro x,y,z
    VNQMR  quaternion x,y,z,w, mag x,y,z, accel x,y,z, gyro x,y,z
    VNIMU  mag x,y,z, accel x,y,z, gyro x,y,z, temperature (°C), pressure (kPa)   (uncompensated)
    VNMAG  mag x,y,z

The rows are the most frequent sentence type that carries a magnetometer; other sentences (register
replies, $VNERR) are counted in metadata["other_sentences"]. A sentence of an unknown type gives
columns <TYPE>_1, <TYPE>_2, …. A leading clock time (a serial monitor's) becomes the column `time`. Lines before the first sentence (the
part of one a capture starts in, a start-up banner) are kept in metadata["preamble"].
Bad lines (checksum, field count, a non-number, bytes that are not text; a sentence without a checksum in
a file whose other sentences carry one) are errors naming the line, or are left out with bad_lines="skip";
a file without checksums is read and says so in metadata["checksums"].
"""
from __future__ import annotations

import binascii
import re
from collections import Counter
from functools import reduce
from pathlib import Path

import numpy as np

from .csv import (readable_file, CUT_PROBLEM, CUT_SHORT, NOT_TEXT, _is_number, _timestamps, check_bad_lines, data_lines,
                  is_comment, listing, read_lines, stop_at_first)
from .labelled import CLOCK
from .recording import Recording

_XYZ = ("x", "y", "z")
_MAG, _ACC, _GYRO = (tuple(f"{s}_{a}" for a in _XYZ) for s in ("mag", "accel", "gyro"))
LAYOUTS = {
    "VNYMR": ("yaw", "pitch", "roll") + _MAG + _ACC + _GYRO,
    "VNMAR": _MAG + _ACC + _GYRO,
    "VNQMR": ("quat_x", "quat_y", "quat_z", "quat_w") + _MAG + _ACC + _GYRO,
    "VNIMU": _MAG + _ACC + _GYRO + ("temp", "pressure"),
    "VNMAG": _MAG,
}
UNITS = {**dict.fromkeys(_MAG, "G"), **dict.fromkeys(_ACC, "m/s^2"), **dict.fromkeys(_GYRO, "rad/s"),
         "yaw": "deg", "pitch": "deg", "roll": "deg", "temp": "C", "pressure": "kPa"}
_SENTENCE = re.compile(r"\$([A-Z][A-Z0-9]{2,9}),([^*]*)(?:\*([0-9A-Fa-f]{2}|[0-9A-Fa-f]{4}|XX))?\s*$")
_START = re.compile(r"\$[A-Z][A-Z0-9]{2,9},")
_COUNTER = re.compile(r"^[TS][0-9A-Fa-f]+$")  # VectorNav's appended time/status fields (T…, S…)


def _body(line: str):
    """(clock text or None, the line from its '$' on)."""
    clock = CLOCK.match(line)
    if clock and line[clock.end():].startswith("$"):
        return clock.group(1), line[clock.end():].strip()
    return None, line.strip()


def looks_like_sentences(lines, start: int, sample: int = 50) -> bool:
    body = [_body(line)[1] for line in data_lines(lines, start, sample)]
    return bool(body) and sum(bool(_START.match(b)) for b in body) >= 0.6 * len(body)


def _checksum_problem(payload: str, given: str | None):
    if given is None or given == "XX":  # none sent, or VectorNav's "do not check"
        return None
    data = payload.encode("ascii", "replace")
    expected = (f"{reduce(lambda a, b: a ^ b, data, 0):02X}" if len(given) == 2
                else f"{binascii.crc_hqx(data, 0):04X}")
    return None if given.upper() == expected else f"checksum {given} does not match the sentence ({expected})"


def _verified(given) -> bool:
    """Whether a sentence's checksum field is one that is checked (not absent, not VectorNav's *XX)."""
    return given is not None and given.upper() != "XX"


def sentence_problem(kind: str, fields: str, given, width: int):
    """What is wrong with one `$KIND,fields*given` sentence of `width` fields, as (reason, text) with reason
    "checksum" or "fields" (VectorNav's appended T…/S… counters allowed), or None."""
    problem = _checksum_problem(f"{kind},{fields}", given)
    if problem:
        return "checksum", problem
    cells = fields.split(",")
    if len(cells) < width or any(not _COUNTER.match(c) for c in cells[width:]):
        return "fields", f"{len(cells)} fields, a {kind} sentence has {width}" + (
            " (cut short?)" if len(cells) < width else " (two sentences run together?)")
    return None


def read_sentences(path, columns=None, units: str | None = None, bad_lines: str = "error") -> Recording:
    check_bad_lines(bad_lines)
    path = readable_file(path)
    parsed, problems, types, preamble = [], [], Counter(), []
    for k, line in enumerate(read_lines(path)):
        if not line.strip() or is_comment(line):
            continue
        clock, body = _body(line)
        m = _SENTENCE.match(body)
        if m is None and not types:  # before the first sentence: the part of one a capture starts in, a banner
            preamble.append(f"line {k + 1}: {line.strip()[:60]}")
        elif NOT_TEXT in line:
            problems.append((k + 1, "bytes that are not text (garbage from a serial line?)"))
        elif CUT_SHORT in line:
            problems.append((k + 1, CUT_PROBLEM))
        elif m is None:
            problems.append((k + 1, "not a $TYPE,fields*checksum sentence (garbled or cut short?)"))
        else:
            types[m.group(1)] += 1
            parsed.append((k + 1, clock, m.group(1), m.group(2), m.group(3)))
    if not types:
        raise ValueError(f"{path}: no $TYPE,… sentences")
    with_mag = [t for t, _ in types.most_common() if t in LAYOUTS and "mag_x" in LAYOUTS[t]]
    kind = with_mag[0] if with_mag else types.most_common(1)[0][0]
    counts = Counter(len(fields.split(",")) for _, _, t, fields, _ in parsed if t == kind)
    width = len(LAYOUTS[kind]) if kind in LAYOUTS else counts.most_common(1)[0][0]
    names = LAYOUTS.get(kind) or tuple(f"{kind}_{j + 1}" for j in range(width))
    # once the device sends checksums it does not stop: a sentence without one was cut or garbled (its "*64" lost)
    checksummed = any(_verified(given) for _, _, t, _, given in parsed if t == kind)
    rows, lines_of, stamps = [], [], []
    for line_no, clock, t, fields, given in parsed:
        if t != kind:
            continue
        cells = fields.split(",")
        problem = (sentence_problem(t, fields, given, width) or (None, None))[1]
        if problem is None and checksummed and not _verified(given):
            problem = (f"no checksum ({'*XX' if given else 'none'}), where the file's other {kind} sentences "
                       "carry one: cut or garbled")
        if problem is None:
            bad = next((j for j in range(width) if not _is_number(cells[j])), None)
            if bad is not None:
                problem = f"{names[bad]} (field {bad + 1}): {cells[bad].strip()!r} is not a number"
        if problem:
            problems.append((line_no, problem))
            continue
        rows.append([float(c) for c in cells[:width]])
        lines_of.append(line_no)
        stamps.append(clock or "")
    problems.sort()
    stop_at_first(path, problems, bad_lines)
    if not rows:
        raise ValueError(f"{path}: no readable {kind} sentence" + (f" (all {len(problems)} bad)" if problems else ""))
    data = np.array(rows)
    cols = {n: data[:, j] for j, n in enumerate(names)}
    unit_map = {n: UNITS[n] for n in names if n in UNITS and kind in LAYOUTS}
    metadata = {"layout": f"{kind} sentences" + (" (VectorNav)" if kind in LAYOUTS else "")}
    if preamble:
        metadata["preamble"] = listing(preamble)
    if not checksummed:
        metadata["checksums"] = f"none: the {kind} sentences carry no checksum (or *XX, checksums off) and are unverified"
    others = {t: c for t, c in types.items() if t != kind}
    if others:
        metadata["other_sentences"] = ", ".join(f"{t} {c}" for t, c in others.items())
    if problems:
        metadata["skipped_lines"] = listing([f"{n} ({p})" for n, p in problems], len(rows) + len(problems))
    if all(stamps):
        seconds, first = _timestamps(stamps)
        if seconds is not None and np.all(np.isfinite(seconds)):
            cols["time"], unit_map["time"], metadata["time_start"] = seconds, "s", first
    rec = Recording(columns=cols, units=unit_map, metadata=metadata, source=str(path),
                    line_numbers=np.array(lines_of, dtype=int))
    return rec.choose(columns, units)
