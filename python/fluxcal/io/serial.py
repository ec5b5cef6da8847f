"""Recording from a serial port (pyserial): parse device lines, timestamp them, append them to a CSV.

Formats a device may print, one record per line (`--format`):

  csv          numbers separated by commas, semicolons, tabs or spaces: `12.3,-4,7` / `12.3 -4 7`. Between
               semicolons or tabs a comma is a decimal comma (`12,5;-3,25;40,0`; 1,234 there too, said in a note,
               unless a whole number beside it makes it a thousands separator, as the file readers take it);
               comma-separated fields that may hold decimal commas (`12,5,-3,25,40,0`) are `ambiguous`.
               `--columns` names them in order (default mx,my,mz), e.g. `t,mx[nT],my[nT],mz[nT]`.
               A header line the device prints (`seq,mx[uT],my[uT],mz[uT]`, `mx [uT]`, `mx (uT)`) is
               matched on its names without units or case: one in another order is followed (a note in
               the file says so); without --columns, one printed before the first record, holding
               mx,my,mz, names the columns and their units (`fluxcal record`: an Arduino prints it on
               the reset the open causes). A unit it prints is the recording's when none is stated;
               another unit than the recording's, or mx,my,mz at other places under names that are not
               the columns', cannot be followed: its line and the lines after it are refused (`unit`,
               `fields`), with a warning and a note, until a header that can be followed comes (no
               conversion, as for kv). A header of as many fields naming none of the columns' names
               elsewhere (`time,x,y,z` for --columns t,mx,my,mz) is taken by position, and a later
               header of its names in another order is followed. A unit in the magnetometer's names
               (`mag_x_ga`, `magnetometer_ga[0]`) is the recording's; bx,by,bz beside mx,my,mz are recorded as
               a reference field (`fluxcal calibrate --reference bx,by,bz`), as the file readers take them; a
               header naming the columns and more, or two magnetometer triples, refuses its lines with the
               --columns that would keep them.
  kv           `key=value` or `key:value` pairs: `X=12.3 Y=-4 Z=7`, `mx:1,my:2,mz:3`. Keys match the
               column names case-insensitively; `KEY=NAME` in `--columns` renames (default
               `x=mx,y=my,z=mz`, which also accepts the keys mx,my,mz). Every column's key must be on the
               line; a key beyond them (`temp=25`, `Temp: 25 C`) is ignored, and said: a note in the file the
               first time, its count in the report.
               Lines as sketches print them are read too (fluxcal.io.labelled): `Mag X: 12.3 Y: -4 Z: 7 uT`
               (the magnetometer's words before the labels, units after the numbers); lines of another
               sensor (`Accel X: …`) are rejected as `fields`, never recorded as the magnetometer. The
               unit a line prints is checked: mx,my,mz must be in a magnetic-field unit (`X: .. m/s^2`
               is rejected as `unit`), in the one --units/--columns state, or else in the one the first
               recorded line printed, which goes into the recording's units header (no conversion).
  nmea         `$VNYMR,…*64` sentences (fluxcal.io.sentences' layouts), checksums verified. A device that sends
               none (nothing after the fields, or VectorNav's literal `*XX`: checksums off) is recorded
               unverified, with a note; once a sentence with a checksum came, one without is cut or garbled:
               rejected as `checksum`.
  binary-spec  fixed-size binary frames: a sync word (`--sync A55A`, hex), then a `struct` layout
               (`--frame "<hhh"`, one field per column), then optionally a one-byte checksum of the
               payload (`--checksum sum8|xor8`). Bytes between frames are garbage and counted.
               `--scale` turns raw counts into units: one factor per column in --columns order
               (`--scale 1,0.1,0.1,0.1`), or one factor for every column but the device time t
               (`--scale 0.1`). The units in --columns and the bounds of --range are those of the
               scaled values; the factors are written to the recording's metadata.

A column `t` is the device's own time and is kept as it is (a whole number beyond 2**53, such as an epoch
time in ns, is kept and written digit for digit, not rounded to a double); every record also gets `t_host`, the
host's monotonic time (s) since the recording started when the chunk holding it was read.

What is rejected, and counted by reason (never written as data): `binary` (bytes that are not text:
invalid UTF-8 or control characters, or garbage between binary frames; NULs before a line, as a device sends them
at a reset, are dropped and the line kept, noted once; a line ending in NULs is one the reset cut: binary), `partial` (the first line
after the port opens, which may be the tail of a line already in flight, unless it is a csv header of
the columns or no byte came for QUIET_OPEN_S (0.5 s) after the open: pyserial's open empties the input
queue, so a line that starts after that silence is whole (a note in the file says so); the line in
flight at a disconnect or at the end), `fields` (wrong number of fields, missing keys; a csv header line the device
prints that names neither the columns nor its earlier header), `non_numeric`
(a field that is not a finite decimal number), `ambiguous` (kv: a number whose comma may be a decimal comma
or a thousands separator, 1,234, until a line shows a decimal comma that cannot be one, 12,34 or 0,123;
or a comma between digits on a line whose fields are separated by commas), `unit` (kv: a unit that is not a magnetic-field unit on
mx,my,mz, or differs from --units/--columns or from the first recorded line), `out_of_range` (outside `--range`), `too_long` (no line
end within 1024 bytes), `checksum` (binary frame or sentence whose checksum does not match; a sentence without
one where the device's others carry one). A csv header line the device prints and the recorder follows (its order,
its units; see csv above) is no data and no rejection: counted apart ("Followed 2 header lines"); one whose units
cannot be the recording's is rejected as `unit`.

The output is the CSV layout of fluxcal.io.write_csv (`# fluxcal recording`, `# units: ...`, metadata,
header, rows), flushed after every record so that a crash loses at most the line in flight. A
disconnect writes `# note: disconnected ...`, then the port is reopened with growing back-off until
the duration ends (`# note: reconnected ...`); the last line is a `# note: summary ...`. read_csv
keeps those comment lines as metadata["notes"].
"""
from __future__ import annotations

import contextlib
import functools
import math
import numbers
import operator
import os
import re
import signal
import struct
import sys
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import serial  # pyserial (absolute import: this module's own name does not shadow it)

from .columns import (FIELD_UNITS, MAG_WORDS, _triples, comma_kind, field_unit_of, find_magnetometer, is_unit,
                      unit_name, words)

REASONS = {
    "binary": "non-text bytes (invalid UTF-8, control characters, garbage between frames)",
    "partial": "partial line (first after opening the port unless half a second of silence came before it, or in "
               "flight at a disconnect or the end)",
    "fields": "wrong number of fields or missing keys",
    "non_numeric": "a field that is not a finite number",
    "unit": "a unit that is not a magnetic-field unit on mx,my,mz, or not the recording's unit",
    "out_of_range": "a value outside --range",
    "too_long": "no line end within 1024 bytes",
    "checksum": "checksum mismatch (a binary frame's, or a $…*XX sentence's), or a sentence without one where the "
                "device's others carry one",
    "sentence": "a $TYPE sentence without the magnetometer's layout (a register reply, $VNERR)",
    "ambiguous": "a number whose comma may be a decimal comma, a thousands separator or a field separator",
}
FORMATS = ("csv", "kv", "nmea", "binary-spec")
MAG = ("mx", "my", "mz")
# nmea: the recording's names for the fields of fluxcal.io.sentences' layouts (VectorNav $VNYMR, $VNMAR, …)
_XYZ_FIELDS = {f"{p}{a}": f"{field}_{a}" for p, field in (("m", "mag"), ("a", "accel"), ("g", "gyro")) for a in "xyz"}
NMEA_FIELDS = {**_XYZ_FIELDS, **{n: n for n in ("yaw", "pitch", "roll", "temp", "pressure")}}
MAX_LINE = 1024
_INTEGER = re.compile(r"[+-]?\d+")
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")  # strict: no "nan", "1_000", "0x10"
# KEY=NAME[unit]; a key may hold spaces ("Mag1 X=mx": two magnetometers on a line)
_ENTRY = re.compile(r"(?:([A-Za-z_][\w. ]*?)\s*=)?([A-Za-z_][\w.]*)\s*(?:\[([^\]]*)\])?")
_PAIR = re.compile(r"([A-Za-z_][\w.]*)\s*[=:]\s*([^\s,;=:]+)")
_PAIR_SEPARATOR = re.compile(r"[\s,;]*")
_LINE_END = re.compile(rb"\r\n|\r|\n")
# kv: 1,234,567 (or 1,2,3); a comma between fields (1,234 itself: fluxcal.io.columns.comma_kind)
_COMMAS = re.compile(r"\d+(?:,\d+){2,}")
_FIELD_COMMA = re.compile(r"(?<!\d),|,(?!\d)")
_CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f]")
# kv: "Gs" written as a unit after a number or in brackets (not a key "Gs: 1")
_GS_UNIT = re.compile(r"(?<=[\d\s(\[])gs\b(?!\s*[:=])", re.IGNORECASE)
# csv: a cell of a header line the device prints: NAME, NAME[unit], NAME [unit], NAME(unit); an index in brackets
# is the name's (PX4's magnetometer_ga[0], [1], [2]: taken for a unit "0", the three names were one)
_HEADER_CELL = re.compile(r"([A-Za-z_][\w.]*(?:\[\d+\])?)\s*(?:\[\s*([^\]]*?)\s*\]|\(\s*([^)]*?)\s*\))?")
_HEADER_WORDS = re.compile(r"[^\s\[(]+(?:\s*(?:\[[^\]]*\]|\([^)]*\)))?")  # cells of a header without , or ;
# seconds without a byte after the port opens (pyserial's open empties the input queue) after which the first
# line is taken whole: the tail of a line in flight at the open comes at once (a USB adapter holds bytes for
# at most its latency timer, 16 ms by default, 255 ms at most: twice that is the bound). It was 1 s, longer
# than a device at more than 1 Hz ever stays quiet, and about as long as an Arduino takes from the reset the
# open causes to its first line (~1 s with optiboot): such a device lost its first line
QUIET_OPEN_S = 0.5


def _name_unit(name: str) -> str:
    """The field unit a magnetometer axis's name carries, else "": as the file readers take it (field_unit_of:
    mag_x_uT, Bx_T, magnetometer_ga[0]), or a unit word just before its axis or index (mag_ga_x, mag_mg[0]), which
    in a magnetometer's name can only be its unit."""
    ws = words(name)
    return field_unit_of(name) or (unit_name(ws[-2]) if len(ws) > 2 and ws[-2] in FIELD_UNITS else "")


class Reject(Exception):
    """A line (or frame) that does not become a record: `reason` is a key of REASONS. `note`: a line the
    recording keeps as a `# note:` (a header the device printed, and what the recorder made of it);
    `warning`: that, and something the user must hear at once (the Recorder warns once per text)."""

    def __init__(self, reason: str, detail: str, note: str = "", warning: str = ""):
        super().__init__(detail)
        self.reason, self.detail, self.note, self.warning = reason, detail, note, warning


@dataclass(frozen=True)
class Column:
    name: str       # column in the recording
    key: str = ""   # kv: the device's key (matched case-insensitively); "" = the name
    unit: str = ""


def parse_columns(spec: str | None, fmt: str = "csv", units: str | None = None) -> list:
    """Columns from a spec such as "t,mx[nT],my[nT],mz[nT]" (kv also "X=mx,..."). `units` is given to
    mx, my, mz when the spec does not state theirs. Default: mx,my,mz (kv: keys x,y,z or mx,my,mz)."""
    if not spec:
        spec = "x=mx,y=my,z=mz" if fmt == "kv" else "mx,my,mz"
    columns = []
    for entry in (e.strip() for e in spec.split(",")):
        m = _ENTRY.fullmatch(entry)
        if not m:
            raise ValueError(f"--columns: entry {entry!r} is not NAME or NAME[unit]"
                             + (" or KEY=NAME[unit]" if fmt == "kv" else ""))
        key, name, unit = " ".join((m.group(1) or "").split()), m.group(2), (m.group(3) or "").strip()
        if key and fmt != "kv":
            raise ValueError(f"--columns: entry {entry!r}: KEY=NAME renames keys of --format kv only")
        if name == "t_host":
            raise ValueError("--columns: t_host is the host time the recorder adds; name the device's time t")
        if not unit and units and name in ("mx", "my", "mz"):
            unit = units
        if unit.lower() == "gs":
            unit = "G"  # (gauss as some write it; written as G, the unit every reader knows)
        columns.append(Column(name, key, unit))
    names = [c.name for c in columns]
    if len(set(names)) != len(names):
        raise ValueError(f"--columns: repeated column name in {spec!r}")
    return columns


def parse_range(text: str, columns) -> dict:
    """`LO:HI` (every column but the device time t) or `NAME=LO:HI` → {name: (lo, hi)}."""
    names = [c.name for c in columns]
    target, _, bounds = text.rpartition("=")
    lo_text, sep, hi_text = bounds.partition(":")
    try:
        lo, hi = float(lo_text), float(hi_text)
    except ValueError:
        lo = hi = None
    if not sep or lo is None or not lo < hi:
        raise ValueError(f"--range: {text!r} is not LO:HI or NAME=LO:HI with LO < HI")
    if target and target not in names:
        raise ValueError(f"--range: {text!r}: no column {target!r} (columns: {', '.join(names)})")
    return {n: (lo, hi) for n in ([target] if target else [n for n in names if n != "t"])}


def parse_scale(text: str, columns) -> tuple:
    """`F1,F2,...` (one factor per column, in order) or `F` (every column but the device time t, which
    keeps 1) → factors in column order. A negative factor flips an axis; zero is refused."""
    names = [c.name for c in columns]
    factors = []
    for item in text.split(","):
        try:
            factor = float(item)
        except ValueError:
            raise ValueError(f"--scale: {item.strip()!r} in {text!r} is not a number") from None
        if not math.isfinite(factor) or factor == 0:
            raise ValueError(f"--scale: {item.strip()!r} in {text!r} must be a finite, non-zero factor")
        factors.append(factor)
    if len(factors) == 1:
        return tuple(1.0 if n == "t" else factors[0] for n in names)
    if len(factors) != len(names):
        raise ValueError(f"--scale: {text!r} has {len(factors)} factors; give one, or one per column "
                         f"({len(names)}: {','.join(names)})")
    return tuple(factors)


def _exact(value):
    """A whole number beyond 2**53 (an epoch time in ns: 1732600000123456789) stays a Python int, which the
    recording writes digit for digit: as a double it would be rounded to a multiple of 256 ns, and the
    differences of consecutive times with it. Everything else (up to 64 bits: what a device can send) is a float."""
    return value if isinstance(value, int) and 2 ** 53 < abs(value) < 2 ** 64 else float(value)


def _sentence_columns(columns) -> list:
    """--format nmea's columns: names it knows, in the sentence's own units unless stated (gauss, m/s², rad/s)."""
    from .sentences import UNITS

    unknown = [c.name for c in columns if c.name not in NMEA_FIELDS]
    if unknown or any(c.key for c in columns):
        raise ValueError(f"--columns: --format nmea takes {', '.join(NMEA_FIELDS)} (no KEY=NAME); got "
                         + ", ".join(c.name for c in columns))
    return [c if c.unit else Column(c.name, "", UNITS.get(NMEA_FIELDS[c.name], "")) for c in columns]


def _number(text: str, column: str) -> float:
    if not _NUMBER.fullmatch(text):
        raise Reject("non_numeric", f"column {column!r}: {text!r} is not a number" if text else
                     f"column {column!r} is empty")
    if _INTEGER.fullmatch(text) and len(text.lstrip("+-")) <= 20:  # a whole number of up to 64 bits
        exact = _exact(int(text))
        if isinstance(exact, int):
            return exact
    value = float(text)
    if value in (float("inf"), float("-inf")):
        raise Reject("non_numeric", f"column {column!r}: {text!r} overflows a double")
    return value


def _check_ranges(values, names, ranges):
    for value, name in zip(values, names):
        if value != value or value in (float("inf"), float("-inf")):  # from a binary float field
            raise Reject("non_numeric", f"column {name!r} is {value}")
        if name in ranges:
            lo, hi = ranges[name]
            if not lo <= value <= hi:
                raise Reject("out_of_range", f"column {name!r}: {value:g} outside [{lo:g}, {hi:g}]")


class TextDecoder:
    """Bytes from the port → records (tuples of floats, in column order) and Rejects, for csv and kv."""

    def __init__(self, columns, fmt: str = "csv", ranges: dict | None = None, header_columns: bool = False):
        """`header_columns` (csv; `fluxcal record` without --columns): a header line the device prints before
        the first record (at start-up, say) names the columns when it holds mx, my and mz, with its units."""
        if fmt not in ("csv", "kv", "nmea"):
            raise ValueError(f"--format: {fmt!r} is not a text format (csv, kv, nmea)")
        if fmt == "nmea":
            columns = _sentence_columns(columns)
        self.columns, self.format, self.ranges = list(columns), fmt, dict(ranges or {})
        self.names = [c.name for c in self.columns]
        self._keys = {}
        for j, c in enumerate(self.columns):
            for k in {c.key.lower(), c.name.lower()} - {""}:
                self._keys[k] = j
        self._buffer = bytearray()
        self._first = True
        self._rest_of_long_line = False
        self.blank_lines = 0
        self.nul_lines = 0  # lines kept after dropping the NULs before them (a device's reset)
        self._order = None  # csv: positions of the columns after the device printed its header in another order
        self._refused = None  # csv: why lines are refused after a header that cannot be followed (a Reject)
        self._header_columns = header_columns and fmt == "csv"
        self._recorded = False  # a line became a record: the columns are the recording's from then on
        self._headers_said = set()  # csv: the header lines already reported (a device reprints it every N lines)
        self._aliases = None  # csv: the device's names of the columns, when --columns renames its fields by position
        # units as --units/--columns state them, and as the first recorded line printed them (kv)
        self._stated = {c.name: unit_name(c.unit) for c in self.columns if c.unit}
        self.printed_units, self._line_units = {}, {}
        # the device writes decimal commas (kv; csv with fields separated by ';' or tabs)
        self.decimal_comma, self._line_decimal_comma = False, False
        self._comma_said = False  # csv: a note said that 1,234 between ';' or tabs is read as a decimal comma
        # kv: the keys beyond the columns on recorded lines ({key as printed: lines}), ignored
        self.ignored_keys, self._line_ignored = Counter(), []
        # nmea: whether a sentence with a checksum came (from then on one without is garbled); sentences recorded
        # without one (unverified)
        self.checksummed, self.unverified, self._line_unverified = False, 0, False
        # what the recording should say once about lines it keeps (an ignored key, unverified sentences): the
        # Recorder writes these as notes and empties the list
        self.notes = []

    @property
    def units(self) -> dict:
        """The unit of each column known so far: stated, or printed by the device."""
        return {**self.printed_units, **{c.name: c.unit for c in self.columns if c.unit}}

    @property
    def may_learn_units(self) -> bool:
        """True while a kv line may still tell the magnetometer's unit (the recording's header waits for it)."""
        return self.format == "kv" and any(n in MAG and n not in self.units for n in self.names)

    def reset(self) -> None:
        """The port was (re)opened: the next line may start mid-line."""
        self._buffer.clear()
        self._first = True
        self._rest_of_long_line = False

    def port_was_quiet(self) -> bool:
        """No byte came for QUIET_OPEN_S after the port opened: the first line starts after the open, it is whole
        (the Recorder calls this when it saw the input queue empty that long after the open). True when that
        changed how the first line is taken."""
        if self._buffer or not self._first:
            return False
        self._first = False
        return True

    def feed(self, data: bytes):
        """Yield a tuple of values or a Reject for every line completed by `data`."""
        self._buffer += data
        start = 0
        for m in _LINE_END.finditer(self._buffer):
            raw = bytes(self._buffer[start:m.start()])
            start = m.end()
            # NULs a device sends at power-up or a reset (a UART's break) before its line: not the line's (a good
            # line after them had been rejected as binary). NULs after a line are not dropped: a line the reset cut
            # ends in them (12.3,4.5,6 of 67.8 had been kept), and stays garbage, as a NUL inside a line. A line
            # they start began after the reset: whole, even as the first after the open
            stripped = raw.lstrip(b"\x00")
            reset = len(stripped) < len(raw) and bool(stripped.strip(b" \t")) and not stripped.endswith(b"\x00")
            raw = stripped if stripped.strip(b"\x00 \t") else b""  # (a line of NULs alone is blank)
            if reset and not self._rest_of_long_line:
                self._first = False
                if not self.nul_lines:
                    self.notes.append(f"NUL bytes before a line (the device's reset or power-up?) were dropped and "
                                      f"the line kept: {_show(stripped[:40])}")
                self.nul_lines += 1
            if self._rest_of_long_line:  # the end of a line already rejected as too long
                self._rest_of_long_line = False
                continue
            if len(raw) > MAX_LINE:
                self._first = False
                yield Reject("too_long", f"{len(raw)} bytes without a line end: {_show(raw[:40])}...")
                continue
            if not raw.strip():
                self.blank_lines += 1  # blank lines carry nothing (a CR LF split across reads gives one)
                continue
            if self._first:
                self._first = False
                header = self._first_line_header(raw)  # a device that prints its header on start-up (a reset)
                yield header or Reject("partial", f"first line after opening the port: {_show(raw)}")
                continue
            try:
                yield self.parse(raw)
            except Reject as reject:
                yield reject
        del self._buffer[:start]
        if len(self._buffer) > MAX_LINE:  # bound the memory a stream without line ends can take
            if not self._rest_of_long_line:
                yield Reject("too_long", f"{len(self._buffer)} bytes without a line end: "
                                         f"{_show(self._buffer[:40])}...")
            self._buffer.clear()
            self._first = False
            self._rest_of_long_line = True

    def flush(self, why: str):
        """The line in flight when the port is lost or the recording ends, as a Reject (or None)."""
        pending, self._buffer = bytes(self._buffer), bytearray()
        if self._rest_of_long_line:
            self._rest_of_long_line = False
            return None
        return Reject("partial", f"{why}: {_show(pending)}") if pending.strip() else None

    def parse(self, raw: bytes) -> tuple:
        """One line (without its end) → values in column order; raises Reject."""
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise Reject("binary", f"byte 0x{raw[exc.start]:02x} at column {exc.start + 1} is not UTF-8 text: "
                                   f"{_show(raw)}") from None
        bad = _CONTROL.search(text)
        if bad:
            raise Reject("binary", f"control character 0x{ord(bad.group()):02x} at column {bad.start() + 1}: "
                                   f"{_show(raw)}")
        text = text.strip()
        self._line_units, self._line_decimal_comma, self._line_ignored = {}, False, []
        self._line_unverified = False
        values = (self._parse_kv(text) if self.format == "kv" else self._parse_sentence(text) if self.format == "nmea"
                  else self._parse_csv(text))
        _check_ranges(values, self.names, self.ranges)
        for name, unit in self._line_units.items():  # the first recorded line's units are the recording's
            self.printed_units.setdefault(name, unit)
        self.decimal_comma = self.decimal_comma or self._line_decimal_comma  # a recorded line's decimal comma
        self._recorded = True
        self._said_of_recorded(text)
        return values

    def _said_of_recorded(self, text: str) -> None:
        """Count what a recorded line left unchecked or unrecorded; the first time, a note for the recording."""
        for key in self._line_ignored:
            if key not in self.ignored_keys:
                spec = ",".join((f"{c.key}=" if c.key else "") + c.name + (f"[{c.unit}]" if c.unit else "")
                                for c in self.columns)
                self.notes.append(f"the device's key {key!r} ({text[:60]!r}) is not in --columns ({spec}): its "
                                  f"values are not recorded; name it in --columns ({spec},{key}) to record it")
            self.ignored_keys[key] += 1
        if self._line_unverified:
            if not self.unverified:
                self.notes.append(f"the device's sentences carry no checksum ({text[:40]!r}…): recorded unverified; "
                                  "once one with a checksum comes, one without is rejected as garbled")
            self.unverified += 1

    def _first_line_header(self, raw: bytes):
        """The first line after the port opens, when it is a complete csv header: its Reject (with what was made
        of it), else None (the line is `partial`). A header cut at the open is no header of these columns: it
        lacks a name, or holds a cut one, and is left as partial, unless it puts mx, my or mz elsewhere."""
        if self.format != "csv":
            return None
        try:
            text = raw.decode("utf-8").strip()
        except UnicodeDecodeError:
            return None
        cells = None if _CONTROL.search(text) else _header_cells(text)
        return self._header(cells, text, first=True) if cells else None

    def _header(self, cells, text: str, first: bool = False):
        """A csv header line the device printed ([(name, unit)]): follow its order, take its columns (before the
        first record, with header_columns), or refuse the lines after it; never store an axis under another's
        name. Names are compared without their units and case. Returns the header line's Reject; None for a
        line of another number of fields that is no header of these columns (a first line after the open: the
        caller calls it partial, it may be a cut header; later: a line of other fields)."""
        printed = [n.lower() for n, _ in cells]
        mine = [n.lower() for n in self.names]
        # Plain words with spaces ("my sensor ready", "Sensor init OK": a sketch's status line) are a header only
        # when they name two of the columns (or of the device's earlier names): one such line had refused every
        # line after it, another was taken for the device's names and hid its real header's reorder (a review)
        structured = any(c in text for c in ",;[(")
        known = set(mine) | set(self._aliases or ())
        if not structured and len(known.intersection(printed)) < 2:
            return None
        said = text not in self._headers_said
        self._headers_said.add(text)
        line = f"the device's header line {text!r}"
        names = ",".join(self.names)
        try:
            triple, rivals = find_magnetometer([n for n, _ in cells], line), ""
        except ValueError as exc:  # two sensors' triples (MagX.. beside Bx..): the file readers refuse them too
            triple, rivals = None, str(exc)[len(line) + 2:]
        # a unit in the magnetometer's names (mag_x_ga, magnetometer_ga[0]): the recording's, as a file reader's
        cells = [(n, u or (_name_unit(n) if n in (triple or ()) else "")) for n, u in cells]
        if sorted(printed) == sorted(mine):
            return self._follow(cells, mine, line, said)
        if self._aliases is not None and sorted(printed) == sorted(self._aliases):
            return self._follow(cells, self._aliases, line, said)  # the device's own names, reordered
        renamed, original = "", cells
        if self._header_columns and not self._recorded and not all(m in printed for m in MAG):
            # a logger's own names beside a time column (t,Bx,By,Bz; timestamp,x,y,z; millis,mag_x,mag_y,mag_z):
            # its magnetometer, as the readers find one, recorded as mx,my,mz (four fields had been taken for a
            # line of other fields, and every line after it refused: a blind check lost a whole recording)
            if rivals:  # its lines do not fit the columns: refused, saying which triples and how to choose
                found = list(_triples([n for n, _ in cells], MAG_WORDS).values())
                example = ",".join(MAG[found[0].index(n)] if n in found[0] else n for n, _ in cells)
                return self._refuse("fields", line, rivals.split("; choose")[0], said,
                                    remedy=f"record again with --columns naming its fields, the magnetometer's as "
                                           f"mx,my,mz (e.g. {example}); a reference field beside them is for "
                                           "`fluxcal calibrate --reference`")
            if triple and len(printed) > len(MAG):
                cells = [(MAG[triple.index(n)] if n in triple else n, unit) for n, unit in cells]
                renamed = "; " + ", ".join(f"{n} as {m}" for n, m in zip(triple, MAG))
                printed = [n.lower() for n, _ in cells]
        if (self._header_columns and not self._recorded and all(m in printed for m in MAG)
                and "t_host" not in printed):
            known = {c.name.lower(): c for c in self.columns}
            # before the first record, only units the user stated bind: a header the device printed earlier (or
            # a banner taken for one by position, `QMC5883L at (0x0D) ready` giving my the unit 0x0D) has
            # recorded nothing, and its units had refused the real header after it (a blind check lost all)
            clash = self._header_unit_clash(cells, mine, stated_only=True)
            if clash:
                return self._refuse("unit", line, clash, said)
            self.printed_units = {}
            self.columns = [Column(known[n.lower()].name if n.lower() in known else n, "",
                                   unit or (self._stated.get(known[n.lower()].name, "") if n.lower() in known
                                            else ""))
                            for n, unit in cells]
            self.names = [c.name for c in self.columns]
            # the device's own names, remembered when its triple was renamed: a reprint in another order (t,Bz,Bx,By
            # after t,Bx,By,Bz) is followed by them (it had been taken by position, Bz recorded as mx)
            self._order, self._refused = None, None
            self._aliases = [n.lower() for n, _ in original] if renamed else None
            spec = ",".join(f"{c.name}[{c.unit}]" if c.unit else c.name for c in self.columns)
            reference = _triples(self.names, MAG_WORDS).get(("b",))
            if reference:  # bx,by,bz beside mx,my,mz: a reference field to the file readers (rival_magnetometers)
                renamed += (f"; {','.join(reference)}: a reference field beside the magnetometer mx,my,mz, recorded "
                            f"as printed (fluxcal calibrate --reference {','.join(reference)})")
            return Reject("header", f"{line}: its columns are the recording's ({spec}{renamed})",
                          note=f"columns from {line}: {spec}{renamed}")
        if len(printed) > len(mine) and all(n in printed for n in mine):
            # the columns and more (bx,by,bz beside t,mx,my,mz): its lines do not fit --columns; said with the remedy
            # (every line had been rejected as `fields` with none)
            extra = [n for n, _ in cells if n.lower() not in mine]
            own = {c.name.lower(): c.name + (f"[{c.unit}]" if c.unit else "") for c in self.columns}
            spec = ",".join(own.get(n.lower(), n + (f"[{u}]" if u else "")) for n, u in cells)
            reference = _triples([n for n, _ in cells], MAG_WORDS).get(("b",)) if set(MAG) <= set(mine) else None
            return self._refuse("fields", line, f"it names {','.join(extra)} beside the columns {names}", said,
                                remedy=f"record again with --columns {spec} to keep them"
                                + (f" ({','.join(reference)}: a reference field, for fluxcal calibrate --reference "
                                   f"{','.join(reference)})" if reference else ""))
        if len(printed) != len(mine):  # no header of these columns; its lines do not fit them either
            if said:
                self._headers_said.discard(text)
            return None  # a cut header (first line: partial), a status word: rejected as a line of other fields
        axes = [m for m in MAG if m in mine]
        for reference, whose in ((mine, f"the columns {names}"), (self._aliases, "the device's earlier header")):
            misplaced = [n for j, n in enumerate(reference or ()) if n in printed and printed.index(n) != j]
            # mz where mx was: never record by position — a header, when it names every axis; a line that names
            # some at other places is a line of other fields, which changes nothing
            if misplaced and not all(m in printed for m in axes):
                if said:
                    self._headers_said.discard(text)
                return None
            if misplaced:
                return self._refuse(
                    "fields", line, f"it puts {', '.join(misplaced)} at other places than {whose}, and its other "
                    "names are not theirs (compared without units): the new order cannot be followed", said)
        if triple and all(m in mine for m in MAG):
            # the device's magnetometer names its axes (MagZ,MagX,MagY; time,Bz,Bx,By) in another order than the
            # columns': followed by those names, its other fields by position (by position alone MagZ had been
            # recorded as mx)
            device = {MAG[i]: n.lower() for i, n in enumerate(triple)}
            others = [n for n in printed if n not in device.values()]
            mine_others = [n for n in mine if n not in MAG]
            reference = [device.get(n) for n in mine]
            if len(others) == len(mine_others) and any(printed.index(device[m]) != mine.index(m) for m in MAG):
                for j, n in enumerate(mine_others):
                    reference[mine.index(n)] = others[j]
                event = self._follow(cells, reference, line, said, note=f"{line}: its magnetometer "
                                     f"{','.join(triple)} taken as {','.join(MAG)} by its names, in its order")
                if event.reason == "header":
                    self._aliases = reference
                return event
        if self._aliases is not None:  # a status line of as many words, or the device renamed its fields
            warning = (f"{line} names neither the columns {names} nor the fields of the device's earlier header "
                       f"({','.join(self._aliases)}): its lines are read as before; if the device reorders them "
                       "under these names, that is not seen. Give --columns with the device's names to have its "
                       "header followed") if said else ""
            return Reject("fields", f"{line} names neither the columns nor the device's earlier header",
                          warning=warning)
        # as many fields, none of the columns' names elsewhere: --columns names the device's fields by position;
        # the device's names are remembered, so that a header it prints later in another order is followed (not
        # from plain words, which name nothing of the columns: a status line)
        # a start-up banner of as many words, one in brackets (`QMC5883L at (0x0D) ready`, `MagLogger v2.1 (c)
        # ACME`), is no header: its bracket was taken for a unit (my=0x0D) and refused the real header after it.
        # A bracket that is a unit keeps the line a header, on some names only too (`time(ms) X Y Z`: a review
        # found such a header dropped, and the device's later reorder recorded on the wrong axes) — unless it gives
        # one magnetometer axis a unit and not the others (`v2.1 (c)` in the my place)
        axes = [bool(u) for (_, u), name in zip(cells, self.names) if name.lower() in MAG]
        banner = not any(c in text for c in ",;") and (any(u and not is_unit(u) for _, u in cells)
                                                       or (any(axes) and not all(axes)))
        if not structured or banner:
            if said:
                self._headers_said.discard(text)
            return None
        renamed = ", ".join(f"{n}={c}" for (n, _), c in zip(cells, self.names) if n.lower() != c.lower())
        event = self._follow(cells, printed, line, said, note=f"{line}: its fields taken as the columns {names} "
                             f"by position ({renamed}); a header in another order is followed")
        if event.reason == "header":
            self._aliases = printed
        return event

    def _follow(self, cells, reference, line: str, said: bool, note: str = ""):
        """Follow a header whose names are `reference` (the device's names of the columns, in column order) in
        another order: the lines after it are read in its order; units it prints are the recording's when none
        are stated (a unit other than the recording's refuses the lines after it)."""
        clash = self._header_unit_clash(cells, reference)
        if clash:
            return self._refuse("unit", line, clash, said)
        printed = [n.lower() for n, _ in cells]
        for name, unit in cells:
            if unit:  # the recording's units when --units/--columns state none
                self.printed_units.setdefault(self.names[reference.index(name.lower())], unit)
        order = [printed.index(n) for n in reference]
        identity = list(range(len(order)))
        changed = (self._order or identity) != order or self._refused is not None
        self._order, self._refused = (None if order == identity else order), None
        return Reject("header", line + (": columns now in its order" if self._order else ""),
                      note=note or (f"{line}: columns in its order from here on" if changed else ""))

    def _header_unit_clash(self, cells, reference, stated_only: bool = False) -> str:
        """Why a header's units cannot be those of the recording (the stated or first printed ones; with
        `stated_only`, those --units/--columns state), or ""."""
        for name, unit in cells:
            if not unit or name.lower() not in reference:
                continue
            column = self.columns[reference.index(name.lower())]
            stated = (self._stated.get(column.name) if stated_only else
                      unit_name(column.unit) if column.unit else self.printed_units.get(column.name))
            if stated and unit != stated:
                return (f"column {column.name!r} is in {unit} there, in {stated} in the recording (no conversion: a "
                        "range change? another sensor?)")
        return ""

    def _refuse(self, reason: str, line: str, why: str, said: bool, remedy: str = ""):
        """A header that cannot be followed: its line and every line after it are refused until a header that can
        be comes, loudly (a warning and a note), never recorded as if nothing had changed."""
        self._refused = Reject(reason, f"a line after {line}, which cannot be followed: {why}")
        remedy = remedy or ("record each unit setting of the device on its own" if reason == "unit" else
                            "stop, and record again with --columns naming the columns as the device prints them")
        warning = (f"{line}: {why}. The lines after it are refused until the device prints a header of the "
                   f"columns {','.join(self.names)} again; {remedy}") if said else ""
        return Reject(reason, f"{line} cannot be followed: {why}", warning=warning)

    def _parse_sentence(self, text: str) -> tuple:
        """`$VNYMR,…*64` (fluxcal.io.sentences' layouts): its checksum, then the columns' fields."""
        from .sentences import LAYOUTS, _SENTENCE, _body, _verified, sentence_problem

        m = _SENTENCE.match(_body(text)[1])
        if m is None:
            raise Reject("fields", f"not a $TYPE,fields*checksum sentence: {text[:60]!r}")
        kind, fields, given = m.groups()
        layout = LAYOUTS.get(kind)
        problem = sentence_problem(kind, fields, given, len(layout) if layout else 0)
        if problem and (problem[0] == "checksum" or layout):
            raise Reject(problem[0], f"${kind}: {problem[1]}")
        verified = _verified(given)
        if not verified and self.checksummed:
            # "*64" lost to line noise or a dropped byte; a device does not stop sending checksums mid-stream
            raise Reject("checksum", f"${kind} without a checksum ({'*XX' if given else 'none'}), where the device's "
                                     "earlier sentences carry one: cut or garbled. (A checksum setting changed while "
                                     "recording? Record each setting on its own)")
        if verified and not self.checksummed:
            self.checksummed = True
            if self.unverified:
                self.notes.append(f"the device's sentences carry a checksum from here on (${kind}…*{given}): the "
                                  f"{self.unverified} recorded before without one are unverified; a sentence "
                                  "without one is rejected from here on")
        self._line_unverified = not verified
        if layout is None or "mag_x" not in layout:
            raise Reject("sentence", f"${kind} (no magnetometer in it)")
        cells = fields.split(",")
        missing = [n for n in self.names if NMEA_FIELDS[n] not in layout]
        if missing:
            raise Reject("fields", f"a {kind} sentence has no {', '.join(missing)}")
        return tuple(_number(cells[layout.index(NMEA_FIELDS[n])].strip(), n) for n in self.names)

    def _parse_csv(self, text: str) -> tuple:
        # ';' or a tab between fields leaves the commas to decimal commas (12,5;-3,25;40,0: a European logger;
        # they had been split into 6 fields) when each field's commas can be one; else (1.5 ,\t-2 ; 3) commas
        # separate fields too, as before — and so they do for 1,234 beside a whole number (1,234;5;6), which the
        # file readers take for a thousands separator, unless a decimal comma settled it
        sep = ";" if ";" in text else "\t" if "\t" in text else None
        fields = [f.strip() for f in text.split(sep)] if sep and "," in text else []
        kinds = [comma_kind(f) for f in fields]
        column_of = dict(zip(self._order or range(len(self.names)), self.names))  # by the field's place on the line
        thousands = not self.decimal_comma and "decimal" not in kinds and any(  # (a device time t is no evidence)
            _INTEGER.fullmatch(f) and column_of.get(j) != "t" for j, f in enumerate(fields))
        if not fields or "invalid" in kinds or thousands:
            sep = "," if "," in text or ";" in text else None
            fields = [f.strip() for f in re.split(r"[,;]", text)] if sep else text.split()
        if len(fields) == len(self.columns) + 1 and fields[-1] == "":
            fields.pop()  # a separator after the last field, as a sketch's print loop writes: 12.3,-4.5,40.1,
        cells = _header_cells(text) if fields[0][:1].isalpha() or fields[0][:1] == "_" else None
        header = self._header(cells, text) if cells else None
        if header:  # the device (re)printed its header: follow its order, never record mz under mx
            raise header
        if self._refused is not None:
            raise Reject(self._refused.reason, f"{self._refused.detail}: {text!r}")
        if self._order is not None and len(fields) == len(self.columns):
            fields = [fields[j] for j in self._order]
        if len(fields) != len(self.columns):
            if sep == "," and "." not in text and len(fields) == 2 * len(self.columns):  # 12,5,-3,25,40,0
                raise Reject("ambiguous", f"{len(fields)} fields, expected {len(self.columns)} "
                                          f"({','.join(self.names)}): its commas may be decimal commas or field "
                                          "separators; not guessed: "
                                          f"{text!r} (a device that writes decimal commas separates its fields by "
                                          "';' or tabs)")
            if text.startswith("{") and text.endswith("}"):  # (a blind check's ESP32 printed JSON lines: "4 fields")
                raise Reject("fields", f"a JSON record, not a csv line: record it with --format kv (its keys name "
                                       f"the columns): {text!r}")
            raise Reject("fields", f"{len(fields)} fields, expected {len(self.columns)} ({','.join(self.names)}): "
                                   f"{text!r}" + (" (its commas read as separators: 1,234 beside a whole number is a "
                                                  "thousands separator, which the recorder does not read)"
                                                  if thousands else ""))
        if sep != ",":  # (a comma left in a field is a decimal comma)
            fields = self._decimal_commas(text, fields, table=True)
        return tuple(_number(f, n) for f, n in zip(fields, self.names))

    def _parse_kv(self, text: str) -> tuple:
        if text.startswith("{") and text.endswith("}"):  # a JSON line ({"t": 0.1, "x": 11.0, …}): its pairs
            text = _json_pairs(text)
        try:
            return self._parse_pairs(text)
        except Reject as strict:
            if strict.reason != "fields":
                raise
            values = self._parse_labelled(text)  # "Mag X: 1.2 Y: 3.4 Z: 5.6 uT", as sketches print it
            if values is None:
                raise
            return values

    def _parse_labelled(self, text: str):
        """Values in column order from a line of fluxcal.io.labelled's form, or None when it does not fit the
        columns. A name matches a key whole ("mag x"), or by its label ("x") when the words before it are
        a magnetometer's (Mag, Compass) — an "Accel X:" line never fills the magnetometer."""
        from .labelled import _parse_line

        _, pairs = _parse_line(_GS_UNIT.sub("G", text))  # (Gs: not a unit to the labelled reader)
        values, units, ignored = [None] * len(self.columns), {}, []
        for name, value, unit in pairs:
            *group, label = name.lower().split()
            j = self._keys.get(name.lower())
            if j is None and set(group) <= MAG_WORDS:
                j = self._keys.get(label)
            if j is None:  # another quantity (Temp: 25 C, Accel X: ...): ignored when the columns are all there
                ignored.append(name)
                continue
            if values[j] is not None:
                return None
            if unit and not is_unit(unit):
                raise Reject("non_numeric", f"column {self.names[j]!r}: {value + unit!r} is not a number")
            if unit:
                units[self.names[j]] = unit
            values[j] = value
        if any(v is None for v in values):
            return None
        said = {units[n] for n in MAG if n in units}
        if ignored and len(said) == 1:  # "Mag X: 1 Y: 2 Z: 3 uT Temp: 25 C": the unit after Z is the sensor's
            units.update({n: next(iter(said)) for n in MAG if n in self.names})
        values = self._decimal_commas(text, values)
        self._line_units = self._check_units(units)
        self._line_ignored = ignored
        return tuple(_number(v, n) for v, n in zip(values, self.names))

    def _decimal_commas(self, text: str, values: list, table: bool = False) -> list:
        """Values with a comma between digits read with a decimal comma (`X: -13,62`), or Reject("ambiguous")
        when the comma may mean something else: on a line whose fields are separated by commas (`X: 1,5, Y: 2`),
        in a number with several (1,234,567), or as a thousands separator (1,234 with three digits after it),
        unless a decimal comma that cannot be one (12,34, 0,123, -0,5, 1234,5) was on this line or an earlier
        recorded one: never a guess that is 1000 times off. `table`: a csv line separated by ';' or tabs, whose
        1,234 is a decimal comma as the file readers read such a table (a thousands separator there is an English
        number in a European layout; refusing it had refused every line of a logger printing three decimals), said
        in a note the first time."""
        with_comma = [(n, v) for n, v in zip(self.names, values) if "," in v]
        if not with_comma:
            return values
        name, value = with_comma[0]
        many = _COMMAS.search(text)
        if many:
            raise Reject("ambiguous", f"{many.group()!r} has several commas between digits (thousands separators?); "
                                      f"not guessed: {text!r}")
        if _FIELD_COMMA.search(text):
            raise Reject("ambiguous", f"column {name!r}: {value!r} has a comma between digits on a line that separates "
                                      f"its fields with commas: a decimal comma, or two fields? Not guessed: {text!r}")
        other = next(((n, v) for n, v in with_comma if comma_kind(v) not in ("decimal", "ambiguous")), None)
        if other:  # 1,234.5: a thousands separator, which the recorder does not read
            raise Reject("non_numeric", f"column {other[0]!r}: {other[1]!r} is not a number with a decimal comma: "
                                        f"{text!r}")
        grouped = [(n, v) for n, v in with_comma if comma_kind(v) == "ambiguous"]
        if grouped and len(grouped) == len(with_comma) and not self.decimal_comma:
            name, value = grouped[0]
            if not table:
                raise Reject("ambiguous", f"column {name!r}: {value!r} is {value.replace(',', '.')} with a decimal "
                                          f"comma, {value.replace(',', '')} with a thousands separator; not guessed (a "
                                          "line with a decimal comma that cannot be a thousands separator, such as "
                                          f"12,34 or -0,123, settles it for the recording): {text!r}")
            if not self._comma_said:
                self._comma_said = True
                self.notes.append(f"column {name!r}: {value!r} read as {value.replace(',', '.')} with a decimal comma, "
                                  f"as a line separated by ';' or tabs writes one ({value.replace(',', '')} with a "
                                  f"thousands separator): {text!r}")
        self._line_decimal_comma = True
        return [v.replace(",", ".") for v in values]

    def _check_units(self, printed: dict) -> dict:
        """The units a line prints ({column: unit word}) → their names; Reject("unit") when a magnetometer
        column's is not a field unit, or a column's differs from the stated or first recorded one: values
        in two units under one label would be silently wrong (a range change, another sensor's line)."""
        named = {}
        for name, word in printed.items():
            unit = named[name] = unit_name(word)
            if name in MAG and unit not in {*FIELD_UNITS.values(), "T"}:
                raise Reject("unit", f"column {name!r}: {word!r} is not a magnetic-field unit (another sensor's "
                                     "line?)")
            if name in self._stated and unit != self._stated[name]:
                raise Reject("unit", f"column {name!r} is in {word} on this line, but --units/--columns say "
                                     f"{self._stated[name]}")
            if name in self.printed_units and unit != self.printed_units[name]:
                raise Reject("unit", f"column {name!r} is in {word} on this line, in {self.printed_units[name]} "
                                     "on the first recorded line (a range change? another sensor?)")
        mag = {named[n] for n in MAG if n in named}
        if len(mag) > 1:
            raise Reject("unit", f"the magnetometer's axes print different units ({', '.join(sorted(mag))})")
        return named

    def _parse_pairs(self, text: str) -> tuple:
        values = [None] * len(self.columns)
        pos, unknown = 0, []
        while pos < len(text):
            m = _PAIR.match(text, pos)
            if not m:
                raise Reject("fields", f"column {pos + 1}: {text[pos:pos + 20]!r} is not key=value or key:value")
            key, value = m.group(1), m.group(2)
            j = self._keys.get(key.lower())
            if j is None:
                unknown.append(key)
            elif values[j] is not None:
                raise Reject("fields", f"key {key!r} appears twice: {text!r}")
            else:
                values[j] = value
            pos = _PAIR_SEPARATOR.match(text, m.end()).end()
        missing = [n for n, v in zip(self.names, values) if v is None]
        if missing:
            others = f" (keys {', '.join(unknown)} are not in --columns)" if unknown else ""
            raise Reject("fields", f"missing {', '.join(missing)}{others}; line {text!r}")
        # keys beyond the columns (temp=25 beside mx,my,mz): the columns are all there; the rest is ignored, and
        # said once with its count (they had cost every line)
        self._line_ignored = unknown
        return tuple(_number(v, n) for v, n in zip(values, self.names))


def _json_pairs(text: str) -> str:
    """A JSON object's number members as `key: value` pairs (the kv format's), or Reject("fields")."""
    import json

    try:
        record = json.loads(text)
    except ValueError:
        raise Reject("fields", f"a JSON record that does not parse (cut short?): {text[:40]!r}") from None
    if not isinstance(record, dict):
        raise Reject("fields", f"a JSON value that is no object of key: number members: {text[:40]!r}")
    return ", ".join(f"{key}: {value!r}" for key, value in record.items()
                     if isinstance(value, (int, float)) and not isinstance(value, bool))


def _header_cells(text: str):
    """[(name, unit)] when every field of a csv line is a column name with an optional unit (mx, mx[uT],
    mx [uT], mx(uT)) and no name repeats (case ignored), else None. Units as the recording writes them."""
    if "," in text or ";" in text:
        cells = [f.strip() for f in re.split(r"[,;]", text)]
        if len(cells) > 1 and cells[-1] == "":
            cells.pop()  # a separator after the last name
    else:
        cells = _HEADER_WORDS.findall(text)
    header = []
    for cell in cells:
        m = _HEADER_CELL.fullmatch(cell)
        if not m:
            return None
        unit = m.group(2) or m.group(3) or ""
        header.append((m.group(1), unit_name(unit) if unit else ""))
    names = [n.lower() for n, _ in header]
    return header if header and len(set(names)) == len(names) else None


class FrameDecoder:
    """Fixed-size binary frames: sync word, struct payload (one field per column), optional checksum.

    The decoder hunts for the sync word; bytes skipped to find it are one `binary` reject per run
    (`partial` right after the port opens). A frame must begin right where the previous one ended,
    otherwise hunting resumes. A frame whose checksum fails is one `checksum` reject, and hunting
    resumes at the next sync word inside it: a sync word in garbage, or a frame cut short by lost
    bytes, must not swallow the good frame that starts within its length. Without a checksum a sync
    word inside garbage can frame a wrong record; use `--checksum` where the device provides one.
    A candidate that starts inside a frame already rejected for its checksum and fails too (a sync word
    that overlaps itself, AAAA, or sync bytes in the payload) is the same damage: it extends that reject
    instead of counting another one.
    `scale` (factors in column order, see parse_scale) multiplies the unpacked fields.
    """

    CHECKSUMS = {"sum8": lambda payload: sum(payload) & 0xFF,
                 "xor8": lambda payload: functools.reduce(operator.xor, payload, 0)}

    def __init__(self, frame: str, sync: bytes, columns, checksum: str | None = None, ranges: dict | None = None,
                 scale=None):
        try:
            self.struct = struct.Struct(frame)
            n_fields = len(self.struct.unpack(bytes(self.struct.size)))
        except struct.error as exc:
            raise ValueError(f"--frame: {frame!r} is not a struct layout ({exc})") from None
        if re.search(r"[spP?]", frame):
            raise ValueError(f"--frame: {frame!r}: only numeric fields (bBhHiIlLqQefd, x for padding)")
        self.columns, self.ranges = list(columns), dict(ranges or {})
        self.names = [c.name for c in self.columns]
        if n_fields != len(self.columns):
            raise ValueError(f"--frame: {frame!r} has {n_fields} fields, --columns names {len(self.columns)} "
                             f"({','.join(self.names)})")
        if not sync:
            raise ValueError("--sync: give the frame's sync word in hex, e.g. A55A")
        if checksum not in (None, "none", *self.CHECKSUMS):
            raise ValueError(f"--checksum: {checksum!r} is not none, sum8 or xor8")
        self.sync = bytes(sync)
        self.checksum = None if checksum in (None, "none") else self.CHECKSUMS[checksum]
        self.scale = None if scale is None else tuple(float(f) for f in scale)
        if self.scale is not None and len(self.scale) != len(self.columns):
            raise ValueError(f"scale: {len(self.scale)} factors for {len(self.columns)} columns "
                             f"({','.join(self.names)})")
        if self.scale is not None and not all(math.isfinite(f) and f != 0 for f in self.scale):
            # as parse_scale (--scale): a zero factor made every record 0,0,0, which the fits then drop
            raise ValueError(f"scale: {self.scale} must be finite, non-zero factors")
        # provenance for the recording's header: how raw bytes became the recorded values
        self.metadata = {"frame": frame, "sync": self.sync.hex().upper(), "checksum": checksum or "none"}
        if self.scale is not None:
            self.metadata["scale"] = ",".join(f"{n}={f!r}" for n, f in zip(self.names, self.scale))
        self.frame_size = len(self.sync) + self.struct.size + (1 if self.checksum else 0)
        self._buffer = bytearray()
        self._skipped = 0
        self._first = True
        self._damaged = 0  # bytes at the buffer's start that belong to the last frame rejected for its checksum
        self.blank_lines = 0

    def reset(self) -> None:
        self._buffer.clear()
        self._skipped = 0
        self._first = True
        self._damaged = 0

    def _drop(self, n: int) -> None:
        del self._buffer[:n]
        self._damaged = max(self._damaged - n, 0)

    def _skipped_reject(self, why: str = ""):
        n, self._skipped = self._skipped, 0
        if self._first:
            return Reject("partial", f"{n} bytes before the first sync word after opening the port{why}")
        return Reject("binary", f"{n} bytes of garbage before a sync word{why}")

    def feed(self, data: bytes):
        self._buffer += data
        while True:
            at = self._buffer.find(self.sync)
            if at < 0:  # keep a possible start of the sync word
                keep = len(self.sync) - 1
                drop = max(len(self._buffer) - keep, 0)
                self._skipped += drop
                self._drop(drop)
                return
            if at > 0:
                self._skipped += at
                self._drop(at)
            if len(self._buffer) < self.frame_size:
                return
            if self._skipped:
                yield self._skipped_reject()
            self._first = False
            frame = bytes(self._buffer[:self.frame_size])
            payload = frame[len(self.sync):len(self.sync) + self.struct.size]
            if self.checksum and self.checksum(payload) != frame[-1]:
                # drop the bad frame's bytes (not garbage to count again), but only up to a sync word
                # inside it: a false sync in garbage or a frame cut short is followed by a good frame
                again = frame.find(self.sync, 1)
                same_damage = self._damaged > 0
                self._drop(again if again > 0 else self.frame_size)
                if not same_damage:  # a new damaged frame: its rest is the span later failures share
                    self._damaged = self.frame_size - again if again > 0 else 0
                    yield Reject("checksum", f"frame {frame.hex()}: checksum 0x{frame[-1]:02x}, payload gives "
                                             f"0x{self.checksum(payload):02x}")
                continue
            self._drop(self.frame_size)
            values = tuple(_exact(v) for v in self.struct.unpack(payload))  # an int64 ns time stays exact
            if self.scale is not None:
                values = tuple(v if f == 1 else v * f for v, f in zip(values, self.scale))
            try:
                _check_ranges(values, self.names, self.ranges)
            except Reject as reject:
                yield reject
                continue
            yield values

    def flush(self, why: str):
        pending = len(self._buffer) + self._skipped
        self._buffer.clear()
        self._skipped = 0
        return Reject("partial", f"{why}: {pending} bytes of an incomplete frame") if pending else None


def _show(raw) -> str:
    """A short printable form of raw line bytes, for messages."""
    text = repr(bytes(raw))[2:-1]
    return text if len(text) <= 80 else text[:77] + "..."


class RecordingWriter:
    """Appends records to a CSV in the layout of fluxcal.io.write_csv, flushing after each.

    `defer_head`: the header is written with the first row (or at close), so that `units` can still take the
    units the device prints on its first good line; notes before it are held until then."""

    def __init__(self, path, names, units: dict | None = None, metadata: dict | None = None,
                 defer_head: bool = False):
        self.path = Path(path)
        self.names = list(names)
        self.units, self.metadata = dict(units or {}), dict(metadata or {})
        self.rows = 0
        # unbuffered: each row goes to the OS whole or, on a write error (disk full), is cut off again
        self._file = self.path.open("wb", buffering=0)
        self._size = 0  # bytes of whole rows and notes in the file
        self.head_written = False
        self._notes = []  # the notes written before the first row (a new head before it keeps them)
        self._held = [] if defer_head else None  # notes that wait for the deferred head
        if not defer_head:
            self._write_head()

    def _write_head(self) -> None:
        self.head_written = True
        head = ["# fluxcal recording"]
        units = {n: u for n, u in self.units.items() if n in self.names and u}
        if units:
            head.append("# units: " + ", ".join(f"{n}={u}" for n, u in units.items()))
        head += [f"# {k}: {_one_line(v)}" for k, v in self.metadata.items()]
        self._write("\n".join(head) + "\n" + ",".join(self.names) + "\n")
        held, self._held = self._held or [], None
        for text in held:
            self.note(text)

    def _write(self, text: str) -> None:
        """Write `text` whole; on an OSError cut the file back to its last whole line and raise."""
        data = text.encode("utf-8")
        rest = memoryview(data)
        try:
            while rest:
                rest = rest[self._file.write(rest):]
        except OSError:
            with contextlib.suppress(OSError):
                os.ftruncate(self._file.fileno(), self._size)
            raise
        self._size += len(data)

    def append(self, values) -> None:
        if not self.head_written:
            self._write_head()
        # repr of a float is the shortest text that reads back to the same double (as write_csv); an int (a
        # time in ns beyond 2**53, see _exact) is written exactly
        self._write(",".join(str(v) if isinstance(v, int) else repr(float(v)) for v in values) + "\n")
        self.rows += 1

    def note(self, text: str) -> None:
        if not self.head_written and self._held is not None:  # (a note must not fix the units before a line says them)
            self._held.append(text)
            return
        if not self.head_written:
            self._write_head()
        self._write(f"# note: {_one_line(text)}\n")
        if not self.rows:
            self._notes.append(text)

    def restart_head(self, names, units: dict) -> None:
        """Before the first row: the columns (or their units) are now `names` (`units`), as a header line the
        device printed says; the file is written again from its head, with the notes it had."""
        if self.rows:
            raise ValueError(f"{self.path}: the columns cannot change after {self.rows} rows")
        self.names = list(names)
        self.units.update(units)
        if not self.head_written:
            return
        os.ftruncate(self._file.fileno(), 0)
        self._file.seek(0)
        self._size = 0
        notes, self._notes = self._notes, []
        self._write_head()
        for text in notes:
            self.note(text)

    def close(self) -> None:
        if not self._file.closed:
            try:
                if not self.head_written:
                    self._write_head()
                os.fsync(self._file.fileno())  # the file is complete on disk, not only in the OS cache
            finally:
                self._file.close()


def _one_line(value) -> str:
    return " ".join(str(value).split())


@dataclass
class RecordStats:
    """What a recording kept, rejected (by reason) and survived."""

    port: str
    records: int = 0
    rejected: Counter = field(default_factory=Counter)
    examples: dict = field(default_factory=dict)  # reason -> the first rejected line's description
    last_examples: dict = field(default_factory=dict)  # reason -> the last one's (the first is often a boot banner)
    reconnects: int = 0
    disconnected_s: float = 0.0
    duration_s: float = 0.0
    stopped: str = ""      # "duration", "interrupted" (Ctrl-C), "terminated (SIGTERM)", "hung up (SIGHUP)",
                           # "done" (a callback asked to stop), "write error"
    blank_lines: int = 0
    output: str | None = None
    write_error: str = ""  # why the output could not be written (disk full, ...): the recording stopped there
    ignored_keys: Counter = field(default_factory=Counter)  # kv: keys beyond the columns on kept lines -> lines
    unverified: int = 0  # nmea: sentences kept without a checksum (the device sends none)
    headers: int = 0  # csv: header lines the device printed and the recorder followed (no data, not rejected)
    first_header: str = ""

    def reject(self, reject: Reject, t_host: float) -> None:
        if reject.reason == "header":  # followed, not refused: counted apart from the rejected lines
            self.headers += 1
            self.first_header = self.first_header or f"at t_host={t_host:.3f} s: {reject.detail}"
            return
        self.rejected[reject.reason] += 1
        self.examples.setdefault(reject.reason, f"at t_host={t_host:.3f} s: {reject.detail}")
        self.last_examples[reject.reason] = f"at t_host={t_host:.3f} s: {reject.detail}"

    def rejected_text(self) -> str:
        total = sum(self.rejected.values())
        if not total:
            return "no lines rejected"
        parts = ", ".join(f"{n} {reason}" for reason, n in sorted(self.rejected.items()))
        return f"{total} rejected ({parts})"

    def report(self) -> str:
        """A one-paragraph account for the user."""
        where = f" into {self.output} (flushed after each record)" if self.output else ""
        text = (f"Kept {self.records} records from {self.port} in {self.duration_s:.1f} s{where}; "
                f"{self.rejected_text()}.")
        for reason in sorted(self.rejected):
            text += f" First {reason} {self.examples[reason]}"
            # (a device's every data line refused after its boot banner: the banner alone had been shown, a blind check)
            last = self.last_examples.get(reason)
            text += f"; last {last}." if self.rejected[reason] > 1 and last and last != self.examples[reason] else "."
        if self.headers:
            text += (f" Followed {self.headers} header line{'s' * (self.headers != 1)} the device printed (first "
                     f"{self.first_header}).")
        if self.ignored_keys:
            keys = ", ".join(f"{k!r} on {n} line{'s' * (n != 1)}" for k, n in self.ignored_keys.most_common())
            text += f" Ignored keys not in --columns: {keys} (name a key in --columns to record it)."
        if self.unverified:
            text += f" {self.unverified} sentences without a checksum were kept unverified (the device sent none)."
        if self.reconnects:
            text += (f" Reconnected {self.reconnects} time{'s' if self.reconnects > 1 else ''} "
                     f"({self.disconnected_s:.2f} s without the port).")
        elif self.disconnected_s:
            text += f" The port was lost and not regained ({self.disconnected_s:.2f} s without it)."
        else:
            text += " No disconnects."
        if self.write_error:
            text += f" {self.write_error[0].upper()}{self.write_error[1:]}; the rows before are whole."
        return text + f" Stopped: {self.stopped or 'end'}."

    def summary_note(self) -> str:
        ignored = "".join(f", key {k!r} ignored on {n} line{'s' * (n != 1)}" for k, n in
                          self.ignored_keys.most_common())
        unverified = f", {self.unverified} sentences unverified (no checksum)" if self.unverified else ""
        unverified += f", {self.headers} header line{'s' * (self.headers != 1)} followed" if self.headers else ""
        return (f"summary: {self.records} records, {self.rejected_text()}{ignored}{unverified}, {self.reconnects} "
                f"reconnects, {self.duration_s:.3f} s, stopped: {self.stopped or 'end'}")


class Recorder:
    """Reads a serial port (any pyserial URL: /dev/ttyUSB0, loop://, rfc2217://...) and appends every good
    record to `output` (or only hands it to `on_record` when output is None).

    `on_record(t_host, values)` is called for every good record after it is written; a true return stops
    the recording (stopped = "done"), as does `should_stop()` returning true (checked between reads).
    `duration` None records until Ctrl-C. `stats` is filled as it goes and returned by run().
    `warn_after` (s): when no good record has come by then, `warn(text)` is called once with the likely
    causes (default: print to stderr); None never warns. `hold_ctrl_c`: once a stop was asked, further
    Ctrl-C stays ignored after run() returns (a command line whose report and exit follow: a Ctrl-C pressed
    twice must not kill it while it prints, and the restored default handler would); False restores the
    caller's handler. `quiet_open_s`: the silence after an open (and a reopen) after which the device's first
    line is taken whole, with a note in the file (see QUIET_OPEN_S); None: the first line is always `partial`.
    """

    def __init__(self, port: str, baudrate: int = 115200, decoder=None, output=None, duration: float | None = None,
                 units: dict | None = None, metadata: dict | None = None, on_record=None, should_stop=None,
                 read_timeout: float = 0.05, max_backoff: float = 0.1, clock=time.monotonic,
                 warn_after: float | None = None, warn=None, hold_ctrl_c: bool = False,
                 quiet_open_s: float | None = QUIET_OPEN_S):
        self.port, self.baudrate, self.hold_ctrl_c = port, int(baudrate), hold_ctrl_c
        self.quiet_open_s = quiet_open_s
        self.decoder = decoder or TextDecoder(parse_columns(None))
        if duration is not None and not (isinstance(duration, numbers.Real) and math.isfinite(duration)
                                         and duration > 0):
            # NaN never reached the deadline (recorded forever); ≤ 0 recorded nothing without a word
            raise ValueError(f"duration: {duration!r} is not a positive number of seconds (None records until "
                             "stopped)")
        if quiet_open_s is not None and not (isinstance(quiet_open_s, numbers.Real) and quiet_open_s > 0):
            raise ValueError(f"quiet_open_s: {quiet_open_s!r} is not a positive number of seconds (None: the first "
                             "line after an open is always taken as partial)")
        self.output, self.duration = output, duration
        self.units, self.metadata = dict(units or {}), dict(metadata or {})
        self.should_stop = should_stop or (lambda: False)
        self.on_record, self.read_timeout, self.max_backoff, self.clock = on_record, read_timeout, max_backoff, clock
        self.names = ["t_host"] + list(self.decoder.names)
        self.stats = RecordStats(port=port, output=str(output) if output else None)
        self.writer = None
        self.warn_after = warn_after
        self.warn = warn or (lambda text: print(text, file=sys.stderr, flush=True))
        self._warned = set()  # the warnings given (a device that reprints a header warns once)
        self._opened_at = None  # when the port (re)opened, until its first byte comes
        self._quiet_said = ""  # the note that the first line after a quiet open is taken whole, for when it comes

    def _open(self):
        return serial.serial_for_url(self.port, baudrate=self.baudrate, timeout=self.read_timeout)

    def run(self) -> RecordStats:
        """Record until the duration ends, Ctrl-C, or a stop request. Raises ValueError when the port
        cannot be opened at the start (afterwards a lost port is reopened, not an error)."""
        try:
            port = self._open()
        except (serial.SerialException, OSError, ValueError) as exc:
            raise ValueError(f"{self.port}: cannot open the serial port ({exc})") from None
        start = self._opened_at = self.clock()
        deadline = None if self.duration is None else start + float(self.duration)
        # the stop signals are ours before the file exists: a kill that comes once it does is a stop request
        with _ctrl_c_as_request(self.hold_ctrl_c) as self._interrupted:
            if self.output is not None:
                from .. import __version__

                meta = {"source": f"serial port {self.port} at {self.baudrate} baud",
                        "started": datetime.now(timezone.utc).isoformat(timespec="seconds"),
                        "recorder": f"fluxcal {__version__}", **getattr(self.decoder, "metadata", {}),
                        **self.metadata}
                try:
                    self.writer = RecordingWriter(self.output, self.names, {"t_host": "s", **self.units}, meta,
                                                  defer_head=getattr(self.decoder, "may_learn_units", False))
                except OSError as exc:
                    port.close()
                    raise ValueError(f"{self.output}: cannot write the recording ({exc.strerror or exc})") from None
            self.decoder.reset()
            stats = self.stats
            try:
                while True:
                    stop = self._stop_reason(deadline)
                    if stop:
                        stats.stopped = stop
                        self._drain(port, start)  # bytes already received belong to the recording
                        break
                    try:
                        if self._opened_at is not None:  # no byte yet since the port opened
                            self._listen(port)
                        data = port.read(port.in_waiting or 1)
                    except (serial.SerialException, OSError) as exc:
                        port = self._reconnect(port, exc, start, deadline)
                        if port is None:
                            break
                        continue
                    if data:
                        self._opened_at = None
                        if self._quiet_said:  # said with the line it concerns (a silent device: nothing to say)
                            came = self.clock() - start
                            self._note(f"{self._quiet_said}; its first byte came at t_host={came:.3f} s")
                            self._quiet_said = ""
                    if data and self._handle(self.decoder.feed(data), self.clock() - start):
                        stats.stopped = "write error" if stats.write_error else "done"
                        break
                    self._warn_if_silent(start)
            except KeyboardInterrupt:  # a second Ctrl-C, or Ctrl-C outside the main thread
                stats.stopped = "interrupted"
            finally:
                self._interrupted.closing = True  # a further Ctrl-C must not cut the summary or the fsync
                now = self.clock()
                if port is not None:
                    reject = self.decoder.flush("line in flight at the end")
                    if reject:
                        stats.reject(reject, now - start)
                    port.close()
                stats.duration_s = now - start
                stats.blank_lines = self.decoder.blank_lines
                stats.ignored_keys = Counter(getattr(self.decoder, "ignored_keys", {}))
                stats.unverified = getattr(self.decoder, "unverified", 0)
                if self.writer:
                    if not stats.write_error:
                        self._note(stats.summary_note())
                    try:
                        self.writer.close()
                    except OSError as exc:
                        self._write_failed(exc)
        return stats

    def _listen(self, port) -> None:
        """Before the first byte after an open: once the input queue is seen empty QUIET_OPEN_S after it (pyserial's
        open empties it), the device was quiet at the open and its first line is whole, not a tail to reject."""
        now = self.clock()  # before the look: nothing had come by `now`
        if port.in_waiting:
            self._opened_at = None
        elif self.quiet_open_s is not None and now - self._opened_at >= self.quiet_open_s:
            quiet = getattr(self.decoder, "port_was_quiet", None)
            if quiet is not None and quiet():  # said in the file: a tail taken whole would be a wrong first record
                self._quiet_said = (f"no byte for {now - self._opened_at:.2f} s after the port opened: the device's "
                                    "first line is taken whole")
            self._opened_at = None

    def _warn_if_silent(self, start: float) -> None:
        if self.warn_after is None or self.stats.records or self.clock() - start < self.warn_after:
            return
        self.warn_after = None  # once
        heard = self.stats.rejected_text() if self.stats.rejected else "nothing received"
        self.warn(f"no good record from {self.port} in the first {self.clock() - start:.1f} s ({heard}): a wrong "
                  "--baud (garbled bytes), a wrong --format or --columns (lines rejected), or a silent device? "
                  "Still recording.")

    def _write_failed(self, exc: OSError) -> None:
        if not self.stats.write_error:
            self.stats.write_error = (f"could not write {self.output} after {self.stats.records} records: "
                                      f"{exc.strerror or exc}")

    def _note(self, text: str) -> None:
        if self.writer and not self.stats.write_error:
            try:
                self.writer.note(text)
            except OSError as exc:
                self._write_failed(exc)

    def _drain(self, port, start: float) -> None:
        """Handle what the port has already buffered (a slow reader can be behind the device by many
        frames when the stop comes), without waiting for more."""
        for _ in range(10000):  # bounded: a device that never pauses cannot keep the recorder alive
            try:
                waiting = port.in_waiting
                if not waiting:
                    return
                data = port.read(waiting)
            except (serial.SerialException, OSError):
                return
            if data and self._handle(self.decoder.feed(data), self.clock() - start):
                return

    def _stop_reason(self, deadline) -> str:
        if self.stats.write_error:
            return "write error"
        if self._interrupted.is_set():
            return self._interrupted.stopped
        if self.should_stop():
            return "done"
        if deadline is not None and self.clock() >= deadline:
            return "duration"
        return ""

    def _handle(self, events, t_host: float) -> bool:
        if self.stats.write_error:  # the output is full: nothing more can be kept
            return True
        stop = False
        for event in events:
            if isinstance(event, Reject):
                self.stats.reject(event, t_host)
                self._header_said(event, t_host)
                self._decoder_said(t_host)
                continue
            if self.writer:
                if not self.writer.head_written:  # the units the first good line printed
                    self.writer.units.update(getattr(self.decoder, "units", {}))
                # a unit the device first prints after the header (lines without one came first): said in the file
                learned = {k: u for k, u in getattr(self.decoder, "printed_units", {}).items()
                           if u and self.writer.units.get(k) != u}
                if learned and self.writer.head_written:
                    self.writer.units.update(learned)
                    self.writer.note("units printed by the device from here on: "
                                     + ", ".join(f"{k}={u}" for k, u in learned.items()))
                try:
                    self.writer.append((t_host, *event))
                except OSError as exc:  # disk full: keep the whole rows written, stop, report
                    self._write_failed(exc)
                    self.stats.stopped = "write error"
                    return True
            self.stats.records += 1
            self._decoder_said(t_host)  # after the row: the head holds the units its line printed
            if self.on_record is not None and self.on_record(t_host, event):
                stop = True  # finish the chunk: its records are written, nothing read is dropped
        return stop

    def _decoder_said(self, t_host: float) -> None:
        """The notes the decoder has for the recording (a key it ignores, sentences without a checksum), once."""
        notes = getattr(self.decoder, "notes", None)
        while notes:
            self._note(f"{notes.pop(0)} (t_host={t_host:.3f} s)")

    def _header_said(self, reject: Reject, t_host: float) -> None:
        """After a rejected line: a header the device printed may have changed the columns or their units (the
        file's head is written again while it holds no row), and may carry a note or a warning."""
        names = ["t_host", *self.decoder.names]
        if self.writer and not self.writer.rows and not self.stats.write_error:
            # the columns a header named, with their units; or the units a header printed for them
            units = getattr(self.decoder, "units" if names != self.writer.names else "printed_units", {})
            units = {k: u for k, u in units.items() if u}
            if names != self.writer.names or any(self.writer.units.get(k) != u for k, u in units.items()):
                try:
                    self.writer.restart_head(names, units)
                except OSError as exc:
                    self._write_failed(exc)
        self.names = names
        if reject.note or reject.warning:
            self._note(f"{reject.warning or reject.note} (t_host={t_host:.3f} s)")
        if reject.warning and reject.warning not in self._warned:
            self._warned.add(reject.warning)
            self.warn(reject.warning)

    def _reconnect(self, port, exc, start, deadline):
        """The port failed: note it, reopen with back-off until a stop. Returns the new port or None."""
        lost = self.clock()
        reject = self.decoder.flush("line in flight at the disconnect")
        if reject:
            self.stats.reject(reject, lost - start)
        try:
            port.close()
        except (serial.SerialException, OSError):
            pass  # already gone
        self._note(f"disconnected at t_host={lost - start:.3f} s ({exc}), reconnecting")
        # (growing to max_backoff, 0.1 s: what the device sends between its port's return and the reopen is lost, and
        # a blind check lost 0.26 s with a 1 s cap; opening a port that is not there yet costs nothing)
        backoff, attempts = 0.02, 0
        while not (stop := self._stop_reason(deadline)):
            time.sleep(backoff if deadline is None else min(backoff, max(deadline - self.clock(), 0.0)))
            attempts += 1
            try:
                port = self._open()
            except (serial.SerialException, OSError, ValueError):
                backoff = min(2 * backoff, self.max_backoff)
                continue
            back = self._opened_at = self.clock()
            self._quiet_said = ""
            self.decoder.reset()
            self.stats.reconnects += 1
            self.stats.disconnected_s += back - lost
            self._note(f"reconnected at t_host={back - start:.3f} s after {back - lost:.3f} s ({attempts} attempts)")
            return port
        self.stats.disconnected_s += self.clock() - lost
        self.stats.stopped = stop
        self._note(f"still disconnected at the end, t_host={self.clock() - start:.3f} s")
        return None


STOP_SIGNALS = {"SIGINT": "interrupted", "SIGTERM": "terminated (SIGTERM)", "SIGHUP": "hung up (SIGHUP)"}


@contextlib.contextmanager
def _ctrl_c_as_request(hold: bool = False):
    """While recording, the first Ctrl-C (or SIGTERM, SIGHUP: a kill, a closed terminal) asks the loop to
    stop between records (no row is cut in half and the summary is written); a second Ctrl-C interrupts
    at once, except once `closing` is set (the summary and fsync are under way: let them finish).
    `stopped` says which signal came. Signals reach only the main thread. `hold`: after a stop request,
    Ctrl-C stays ignored on leaving (Recorder's hold_ctrl_c)."""
    requested = threading.Event()
    requested.closing, requested.stopped = False, "interrupted"
    if threading.current_thread() is not threading.main_thread():
        yield requested
        return

    def handler(signum, frame):
        if requested.is_set():
            if signum == signal.SIGINT and not requested.closing:
                raise KeyboardInterrupt
            return
        requested.stopped = STOP_SIGNALS.get(signal.Signals(signum).name, "interrupted")
        requested.set()

    previous = {}
    for name in STOP_SIGNALS:
        if hasattr(signal, name):  # no SIGHUP on Windows
            previous[name] = signal.signal(getattr(signal, name), handler)
    try:
        yield requested
    finally:
        for name, handler_before in previous.items():
            default = signal.default_int_handler if name == "SIGINT" else signal.SIG_DFL
            if hold and name == "SIGINT" and requested.is_set():
                handler_before = signal.SIG_IGN
            signal.signal(getattr(signal, name), handler_before if handler_before is not None else default)


# -- command line ---------------------------------------------------------------------------------------

def add_stream_arguments(p) -> None:
    """Port and parsing options shared by `fluxcal record` and `fluxcal live`."""
    from ..cli import positive_int, positive_number

    p.add_argument("--port", required=True, help="serial port or pyserial URL (/dev/ttyUSB0, COM3, loop://, "
                                                 "rfc2217://host:port)")
    p.add_argument("--baud", type=positive_int, default=115200, help="baud rate (default 115200)")
    p.add_argument("--duration", type=positive_number, default=None, help="stop after this many seconds (default: Ctrl-C)")
    p.add_argument("--format", choices=FORMATS, default="csv",
                   help="csv: separated numbers; kv: key=value or key:value pairs; nmea: $VNYMR,…*XX sentences "
                        "(checksums verified; a device that sends none is recorded unverified; --columns from "
                        "mx,my,mz, ax,ay,az, gx,gy,gz, yaw,pitch,roll, temp); "
                        "binary-spec: --frame/--sync")
    p.add_argument("--columns", default=None,
                   help="names of the fields in order, optional unit in brackets: t,mx[nT],my[nT],mz[nT] "
                        "(default mx,my,mz, or the columns of a csv header the device prints at start-up; kv: "
                        "KEY=NAME renames, default x=mx,y=my,z=mz, other keys are ignored); t = device time")
    p.add_argument("--units", default=None, help="unit of mx,my,mz when --columns does not state it (nT, uT, counts)")
    p.add_argument("--range", action="append", default=[], metavar="[NAME=]LO:HI",
                   help="reject records with a value outside LO..HI (every column but t, or NAME only); "
                        "repeatable; a negative LO needs '=': --range=-1e5:1e5")
    p.add_argument("--frame", default=None, help="binary-spec: struct layout of a frame's payload, e.g. '<hhh'")
    p.add_argument("--sync", default=None, help="binary-spec: sync word in hex before each frame, e.g. A55A")
    p.add_argument("--checksum", default="none", choices=("none", "sum8", "xor8"),
                   help="binary-spec: one checksum byte after the payload (default none)")
    p.add_argument("--scale", default=None, metavar="F[,F...]",
                   help="binary-spec: multiply raw fields into the units of --columns: one factor per column "
                        "(1,0.1,0.1,0.1) or one for every column but t (0.1); --range applies to scaled values")


def decoder_from_args(args, header_columns: bool = False):
    """The decoder the stream options describe; ValueError names the bad option. `header_columns`: without
    --columns, a csv header the device prints before the first record names the columns (`fluxcal record`)."""
    columns = parse_columns(args.columns, args.format, args.units)
    ranges = {}
    for text in args.range:
        ranges.update(parse_range(text, columns))
    scale_text = getattr(args, "scale", None)  # callers that build args by hand may not set it
    if args.format == "binary-spec":
        if not args.frame or not args.sync:
            raise ValueError("--format binary-spec needs --frame (struct layout, e.g. '<hhh') and --sync (hex)")
        try:
            sync = bytes.fromhex(args.sync)
        except ValueError:
            raise ValueError(f"--sync: {args.sync!r} is not hex bytes (e.g. A55A)") from None
        scale = parse_scale(scale_text, columns) if scale_text is not None else None
        return FrameDecoder(args.frame, sync, columns, args.checksum, ranges, scale)
    if args.frame or args.sync or scale_text is not None:
        raise ValueError("--frame, --sync and --scale belong to --format binary-spec")
    return TextDecoder(columns, args.format, ranges, header_columns=header_columns and not args.columns)


def check_output(path, option: str, overwrite: bool = True) -> None:
    """Before the port opens: refuse an output that cannot be a file (a folder, a missing folder) and one that
    would replace an earlier recording (a non-empty file) unless `overwrite`. ValueError names the option."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{option} {path}: is a folder; name a file in it")
    if not path.parent.is_dir():
        raise ValueError(f"{option} {path}: the folder {path.parent} does not exist")
    if not overwrite and path.is_file() and path.stat().st_size > 0:
        raise ValueError(f"{option} {path}: the file exists and is not empty; give --overwrite to replace it, "
                         "or another name")


def stream_units(decoder) -> dict:
    return {c.name: c.unit for c in decoder.columns if c.unit}


def add_record_parser(subparsers):
    p = subparsers.add_parser(
        "record", help="record a serial device to a CSV, flushed per record, surviving disconnects",
        description="Read records from a serial port, timestamp them (t_host, s) and append every good one to "
                    "FILE as it arrives. Rejected lines are counted by reason and reported; a lost port is "
                    "reopened. Exit status 0, 1 when no record was kept, 2 on a bad argument, a port that "
                    "cannot be opened or a FILE that cannot be written (disk full: the rows before are kept "
                    "whole).",
        epilog="Rejected lines, by reason: " + "; ".join(f"{k}: {v}" for k, v in REASONS.items()) + ".")
    add_stream_arguments(p)
    p.add_argument("-o", "--output", required=True, metavar="FILE",
                   help="recording CSV to write (read it with fluxcal.read_csv); an existing non-empty FILE is "
                        "refused unless --overwrite")
    p.add_argument("--overwrite", action="store_true", help="replace FILE when it exists (default: refuse)")
    p.add_argument("--warn-after", type=float, default=5.0, metavar="S",
                   help="warn on stderr when no good record has come after S seconds (default 5)")
    p.set_defaults(run=cmd_record)
    return p


def cmd_record(args) -> int:
    decoder = decoder_from_args(args, header_columns=True)
    check_output(args.output, "-o", args.overwrite)
    recorder = Recorder(args.port, args.baud, decoder, output=args.output, duration=args.duration,
                        units=stream_units(decoder), metadata={"format": args.format}, warn_after=args.warn_after,
                        warn=lambda text: print(f"fluxcal record: warning: {text}", file=sys.stderr, flush=True),
                        hold_ctrl_c=True)
    until = f"for {args.duration:g} s or Ctrl-C" if args.duration else "until Ctrl-C"
    print(f"fluxcal record: recording {args.port} at {args.baud} baud into {args.output} {until}",
          file=sys.stderr, flush=True)
    stats = recorder.run()
    print(stats.report())
    if stats.write_error:
        print(f"fluxcal record: error: {stats.write_error}", file=sys.stderr, flush=True)
        return 2
    if not stats.records:
        print(f"fluxcal record: no good record from {args.port}; check --baud, --format, --columns and --units",
              flush=True)
        return 1
    return 0
