"""Flight-controller logs: ArduPilot DataFlash (.bin and text .log) and PX4 ULog (.ulg), the optional
extra `fluxcal[drone]` (pymavlink parses DataFlash, pyulog parses ULog; fluxcal parses neither itself).

Both give a Recording with t (s), mx, my, mz (the magnetometer), units and metadata (source format,
compass instance, the instances present, what the autopilot had already applied, firmware version).

ArduPilot DataFlash: MAG messages (older logs: MAG, MAG2, MAG3, one per compass; newer: one MAG with
the instance number I). Columns:
    t            TimeUS / 1e6 (seconds since the autopilot booted; TimeMS / 1e3 in very old logs)
    mx, my, mz   MagX, MagY, MagZ AS LOGGED. These are NOT raw readings: ArduPilot logs the field after
                 its own compass calibration, in the body frame,
                     Mag = M·s·(raw + Ofs) + MO
                 with Ofs the offsets OfsX..Z (COMPASS_OFS*), M the soft-iron matrix (COMPASS_DIA*,
                 COMPASS_ODI*), s the scale (COMPASS_SCALE*) and MO the motor compensation MOX..Z
                 (MOfsX.. in older logs). Calibrating mx,my,mz therefore measures what is still wrong
                 after ArduPilot's calibration (for a fresh, uncalibrated vehicle Ofs = 0 and M = I).
    ofs_x..z     OfsX..Z, the offsets already added (mG)
    mot_x..z     MOX..Z, the motor compensation already added (mG)
    raw_x..z     the readings before that correction, raw = (M·s)⁻¹(Mag − MO) − Ofs, with M and s from the
                 log's PARM messages (identity when absent; metadata "raw_reconstruction" says which).
                 Select them to calibrate from scratch: columns="raw_x,raw_y,raw_z". (Older firmware
                 added MO before applying M; the two orders agree when M = I and s = 1.)
    health       the Health flag, when logged
    roll, pitch, yaw   ATT Roll, Pitch, Yaw (deg) interpolated to the MAG times (NaN outside the ATT
                 span), when the log has ATT; metadata attitude_convention "aerospace" (body FRD → NED).
    current      BAT Curr (A) of the first battery interpolated to the MAG times (the first and last value
                 held outside the BAT span), when logged: what `fluxcal.diagnose` tries motor_current on
                 (compass-motor interference).
Units: from the log's UNIT/MULT/FMTU messages when present (current logs say mGauss; a label that is not
a multiple of the gauss is kept as stated), else ArduPilot's convention, milligauss: mx..z are "mG".

PX4 ULog: topic sensor_mag (x, y, z in gauss, board frame FRD, the driver's output BEFORE PX4's
CAL_MAGn calibration, i.e. raw) is used when logged, else vehicle_magnetometer (magnetometer_ga[0..2],
calibrated by PX4, body frame). In logs of PX4 1.10 and older (sensor_mag has x_raw, y_raw, z_raw) the
driver had already applied the calibration to x, y, z: metadata "offsets_applied" says so. Columns
t (timestamp_sample, else timestamp, µs → s), mx, my, mz ("G"), temp (°C, when logged) and roll, pitch,
yaw (deg) from vehicle_attitude q (body FRD → NED) when logged, current (A) from battery_status[0]
current_a interpolated to the magnetometer times (held outside its span; −1, "unknown", left out). The CAL_MAGn parameters whose CAL_MAGn_ID
matches the device go to metadata "px4_calibration".

Several compasses: the first instance is read by default. Pick another with `instance` (an integer,
or a name as below), or through `columns` (what the CLI's --columns passes), a name
    "MAG[1]" (ArduPilot, instance I = 1; "MAG2"/"MAG3" of older logs are MAG[1]/MAG[2]),
    "sensor_mag[1]" / "vehicle_magnetometer[0]" (PX4, the topic's multi-instance),
optionally followed by three column names: "MAG[1],raw_x,raw_y,raw_z". Three names alone select
those columns of the first instance. metadata "instances" lists what the log has.

Damaged logs: a log cut off inside its last message (a vehicle powered off while logging) keeps its
complete messages; the damage is stated in metadata "damage" and a warning (so are bytes between
DataFlash messages that pymavlink skipped; DataFlash has no checksums, so a message overwritten in place
goes unnoticed). A file with no readable
magnetometer message (garbled, cut before the first one, or without a compass) is a ValueError naming
the file and the problem, as is an instance that the log does not have.
"""
from __future__ import annotations

import codecs
import contextlib
import io
import math
import os
import re
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np

from .csv import readable_file
from .recording import Recording

MAG_AXES = ("mx", "my", "mz")
ATTITUDE = ("roll", "pitch", "yaw")
NEWLINE = b"\n"
INSTALL_HINT = "pip install 'fluxcal[drone]' (or pip install pymavlink pyulog)"
# ArduPilot names a compass's parameters COMPASS_OFS_X (first), COMPASS_OFS2_X, COMPASS_OFS3_X
_AP_PARAM_SUFFIX = ("", "2", "3")
_INSTANCE_SPEC = re.compile(r"^\s*([A-Za-z_][A-Za-z_0-9]*?)(\d*)\s*(?:\[\s*(\d+)\s*\])?\s*$")


# -- options shared by both formats -------------------------------------------------------------------------


def _split_choice(columns, instance, names_known, source):
    """(instance spec or None, three column names or None) from `columns` and `instance`.

    `columns` is a string "a,b,c" or a list; an item naming a message/topic (names_known) is the instance."""
    items = [c.strip() for c in columns.split(",")] if isinstance(columns, str) else list(columns or [])
    items = [c for c in items if c != ""]
    spec, names = instance, []
    for item in items:
        m = _INSTANCE_SPEC.match(str(item))
        if m and m.group(1).upper() in names_known:
            if spec is not None and spec != item:
                raise ValueError(f"{source}: two compass instances asked for ({spec!r} and {item!r})")
            spec = item
        else:
            names.append(item)
    if names and len(names) != 3:
        raise ValueError(f"{source}: --columns takes a compass instance (e.g. {_example(names_known)}) "
                         f"and/or three column names; got {', '.join(map(repr, names))}")
    return spec, (names or None)


def _example(names_known):
    return "MAG[1]" if "MAG" in names_known else "sensor_mag[1]"


def _parse_spec(spec, default_name: str, source: str, numbered: bool = False):
    """(message/topic name in upper case or None, instance number) of an `instance` argument.
    `numbered`: NAME2, NAME3 mean the second and third instance (ArduPilot's MAG2, MAG3)."""
    if spec is None:
        return None, 0
    if isinstance(spec, (int, np.integer)) and not isinstance(spec, bool):
        if spec < 0:
            raise ValueError(f"{source}: compass instance must be >= 0, got {spec}")
        return None, int(spec)
    m = _INSTANCE_SPEC.match(str(spec))
    if not m:
        raise ValueError(f"{source}: {spec!r} is not a compass instance (e.g. {default_name}[1])")
    name, digits, index = m.group(1).upper(), m.group(2), m.group(3)
    if digits and not numbered:
        raise ValueError(f"{source}: {spec!r}: write the instance as {name.lower()}[k]")
    if digits and index is not None:
        raise ValueError(f"{source}: {spec!r}: give the instance either as {name}{digits} or as {name}[k]")
    if digits:  # MAG2 / MAG3 of older ArduPilot logs are the second and third compass
        n = int(digits)
        if n < 2:
            raise ValueError(f"{source}: {spec!r}: numbered messages start at {name}2 (the second compass)")
        return name, n - 1
    return name, int(index) if index is not None else 0


def _finish(rec: Recording, names, units, source: str) -> Recording:
    rec.select(MAG_AXES)
    return rec.choose(names, units)


def _note_damage(metadata: dict, source: str, problems: list):
    if problems:
        metadata["damage"] = "; ".join(problems)
        warnings.warn(f"{source}: {metadata['damage']}", stacklevel=3)


@contextlib.contextmanager
def _collected_output(lines: list):
    """pymavlink and pyulog print their parse complaints (some from C, straight to file descriptor 2):
    collect them into `lines` so the user sees one summary instead of hundreds of lines."""
    buffer = io.StringIO()
    saved = None
    sink = tempfile.TemporaryFile()
    try:
        sys.stderr.flush()
        saved = os.dup(2)
        os.dup2(sink.fileno(), 2)
    except (OSError, ValueError, AttributeError):  # no real descriptor 2 (embedded interpreter)
        saved = None
    try:
        with contextlib.redirect_stdout(buffer), contextlib.redirect_stderr(buffer):
            yield
    finally:
        if saved is not None:
            os.dup2(saved, 2)
            os.close(saved)
        sink.seek(0)
        text = sink.read().decode(errors="replace") + buffer.getvalue()
        sink.close()
        lines.extend(line.strip() for line in text.splitlines() if line.strip())


def _summary(lines: list, limit: int = 2) -> str:
    shown = "; ".join(lines[:limit])
    return shown + (f" (and {len(lines) - limit} more)" if len(lines) > limit else "")


def _interp_angles(t_src, angles_deg, t_dst, wrap360: bool):
    """Angles (deg) at times t_dst by linear interpolation on the unwrapped angle; NaN outside t_src."""
    t_src, angles = np.asarray(t_src, float), np.asarray(angles_deg, float)
    good = np.isfinite(t_src) & np.isfinite(angles)
    if not good.any():
        return np.full(len(t_dst), np.nan)
    order = np.argsort(t_src[good], kind="stable")
    t_src, angles = t_src[good][order], angles[good][order]
    unwrapped = np.degrees(np.unwrap(np.radians(angles)))
    out = np.interp(t_dst, t_src, unwrapped)
    out[(t_dst < t_src[0]) | (t_dst > t_src[-1])] = np.nan
    if wrap360:
        out = np.mod(out, 360.0)
    else:
        out = (out + 180.0) % 360.0 - 180.0
    return out


# -- ArduPilot DataFlash ------------------------------------------------------------------------------------


def _pymavlink_dfreader():
    try:
        from pymavlink import DFReader
    except ImportError:
        return None
    return DFReader


def _unit_of(label: str):
    """(fluxcal unit, factor that brings the values to it) of a DataFlash unit label such as "mGauss";
    (None, None) when the label is not a multiple of the gauss."""
    label = (label or "").strip()
    prefixes = {"": 1.0, "m": 1e-3, "µ": 1e-6, "u": 1e-6, "c": 1e-2, "d": 1e-1, "n": 1e-9}
    m = re.fullmatch(r"(?:([0-9.eE+-]+)\s+)?(µ|u|m|c|d|n)?(Gauss|G)", label)
    if not m:
        return None, None
    scale = (float(m.group(1)) if m.group(1) else 1.0) * prefixes[m.group(2) or ""]
    if math.isclose(scale, 1e-3):
        return "mG", 1.0
    if math.isclose(scale, 1.0):
        return "G", 1.0
    return "mG", scale / 1e-3  # any other multiple of the gauss: stated in mG


def read_dataflash(path, columns=None, units: str | None = None, instance=None) -> Recording:
    """Read the compass of an ArduPilot DataFlash log, binary (.bin) or text (.log), through pymavlink's
    DFReader. See the module docstring for the columns and for what ArduPilot has already applied
    (mx, my, mz are MagX..Z as logged, offset- and motor-corrected; raw_x..z undo that)."""
    path = readable_file(path)
    source = str(path)
    DFReader = _pymavlink_dfreader()
    if DFReader is None:
        raise ValueError(f"{source}: an ArduPilot DataFlash log; reading it needs pymavlink: {INSTALL_HINT}")
    spec, names = _split_choice(columns, instance, {"MAG"}, source)
    wanted_name, wanted = _parse_spec(spec, "MAG", source, numbered=True)
    if wanted_name is not None and wanted_name != "MAG":
        raise ValueError(f"{source}: {spec!r}: an ArduPilot log's compass messages are MAG (MAG[k])")
    try:
        with path.open("rb") as f:
            text = f.read(2) != b"\xa3\x95"
            size = f.seek(0, os.SEEK_END)
            f.seek(max(size - 1, 0))
            unterminated = text and f.read(1) != NEWLINE
        if text:
            _check_text(path, source)
    except OSError as exc:
        raise ValueError(f"{source}: cannot read ({exc.strerror or exc})") from None
    chatter: list = []
    try:
        with _collected_output(chatter):
            reader = (DFReader.DFReader_text if text else DFReader.DFReader_binary)(str(path))
    except Exception as exc:  # pymavlink raises whatever its parse hits (UnicodeDecodeError, struct.error, ...)
        raise ValueError(f"{source}: not a readable DataFlash {'text ' if text else ''}log (garbled or truncated?"
                         f" pymavlink: {type(exc).__name__}: {exc})") from None
    try:
        return _read_dataflash(reader, path, size, text, unterminated, wanted, names, units, chatter)
    finally:
        with contextlib.suppress(Exception):
            reader.close()


def _check_text(path: Path, source: str):
    """pymavlink decodes text logs as UTF-8 and fails on the first other byte: name it instead."""
    decoder = codecs.getincrementaldecoder("utf-8")()
    offset, lines = 0, 0
    with path.open("rb") as f:
        while True:
            chunk = f.read(1 << 20)
            try:
                decoder.decode(chunk, final=not chunk)
            except UnicodeDecodeError as exc:
                # the decoder may hold back up to 3 bytes of a character begun in the previous chunk
                bad = max(exc.start - len(exc.object) + len(chunk), 0)
                line = lines + chunk.count(NEWLINE, 0, bad) + 1
                raise ValueError(f"{source}: not a readable DataFlash text log: line {line} (byte {offset + bad}) is "
                                 "not text (garbled, or a binary log with a damaged start?)") from None
            if not chunk:
                return
            offset, lines = offset + len(chunk), lines + chunk.count(NEWLINE)


def _message_types(reader) -> list:
    return sorted(n for n in getattr(reader, "name_to_id", {}) if n != "FMT")


def _logged_types(reader) -> list:
    """The message types that occur in the log (besides the format definitions)."""
    counts = getattr(reader, "counts", None)
    if isinstance(counts, dict):  # the text reader counts by name
        found = [n for n, c in counts.items() if c]
    elif counts is not None:  # the binary reader counts by type number
        found = [reader.id_to_name[i] for i, c in enumerate(counts) if c and i in reader.id_to_name]
    else:
        found = []
    return sorted(n for n in found if n not in ("FMT", "FMTU", "UNIT", "MULT"))


def _read_dataflash(reader, path: Path, size: int, text: bool, unterminated: bool, wanted: int, names, units,
                    chatter) -> Recording:
    source = str(path)
    types = _message_types(reader)
    mag_types = [n for n in _AP_MAG_MESSAGES if n in types]
    problems = _dataflash_damage(reader, size, text, unterminated)
    if not types:
        raise ValueError(f"{source}: not a readable DataFlash log: no message format (FMT) could be read from it "
                         f"(garbled?{' pymavlink: ' + _summary(chatter) if chatter else ''})")
    if chatter:
        problems.append(f"pymavlink: {_summary(chatter)}")
        del chatter[:]
    if not mag_types:
        damage = f"; {'; '.join(problems)}" if problems else ""
        raise ValueError(f"{source}: no magnetometer messages (MAG) in this DataFlash log (message types present: "
                         f"{', '.join(types)}){damage}")

    wanted_types = mag_types + [n for n in ("ATT", "BAT", "PARM", "VER", "MSG") if n in types]
    per_instance: dict = {}
    attitude = {"t": [], "roll": [], "pitch": [], "yaw": []}
    battery = {"t": [], "current": []}
    params, version, messages = {}, {}, []
    time_field, kind = None, "first"
    try:
        with _collected_output(chatter):
            while True:
                msg = reader.recv_match(type=wanted_types, strict=True)
                if msg is None:
                    break
                if text and reader.offset > reader.data_len:
                    break  # the unterminated last line: its last field may be cut short
                kind = msg.get_type()
                if kind in mag_types:
                    fields = msg.fmt.columns
                    if time_field is None:
                        time_field = "TimeUS" if "TimeUS" in fields else "TimeMS" if "TimeMS" in fields else None
                        if time_field is None:
                            raise ValueError(f"{source}: {kind} messages have no TimeUS/TimeMS column "
                                             f"(columns: {', '.join(fields)})")
                    k = int(msg.I) if "I" in fields else _AP_MAG_MESSAGES[kind]
                    per_instance.setdefault(k, []).append(_mag_row(msg, fields, time_field))
                elif kind == "ATT":
                    attitude["t"].append(float(msg.TimeUS) * 1e-6 if "TimeUS" in msg.fmt.columns
                                         else float(msg.TimeMS) * 1e-3)
                    for a, field in zip(ATTITUDE, ("Roll", "Pitch", "Yaw")):
                        attitude[a].append(float(getattr(msg, field)))
                elif kind == "BAT" and "Curr" in msg.fmt.columns and _battery_instance(msg) == 0:
                    battery["t"].append(float(msg.TimeUS) * 1e-6 if "TimeUS" in msg.fmt.columns
                                        else float(msg.TimeMS) * 1e-3)
                    battery["current"].append(float(msg.Curr))
                elif kind == "PARM":
                    params.setdefault(str(msg.Name), float(msg.Value))  # the value when logging started
                elif kind == "VER" and not version:
                    version = msg.to_dict()
                elif kind == "MSG" and len(messages) < 40:
                    messages.append(str(msg.Message))
    except ValueError as exc:
        if str(exc).startswith(source):
            raise
        where = _text_line(path, reader.offset) if text else ""
        raise ValueError(f"{source}: a {kind} message{where} has a value that is not a number ({exc})") from None
    except Exception as exc:
        raise ValueError(f"{source}: the DataFlash log could not be read past a {kind} message (garbled? "
                         f"pymavlink: {type(exc).__name__}: {exc})") from None

    if chatter:
        problems.append(f"pymavlink: {_summary(chatter)}")
    if not per_instance:
        logged = ", ".join(_logged_types(reader)) or "none"
        raise ValueError(f"{source}: no magnetometer messages (MAG) in this DataFlash log: {', '.join(mag_types)} "
                         f"is defined but no complete {mag_types[0]} message was logged (messages logged: {logged})"
                         f"{'; ' + '; '.join(problems) if problems else ''}")
    instances = sorted(per_instance)
    if wanted not in per_instance:
        raise ValueError(f"{source}: no compass instance {wanted} (MAG[{wanted}]); the log has "
                         f"{', '.join(f'MAG[{k}]' for k in instances)}")
    rows = np.array(per_instance[wanted], dtype=float)
    cols = {name: rows[:, j] for j, name in enumerate(_MAG_LAYOUT)}
    cols["t"] = cols["t"] * (1e-6 if time_field == "TimeUS" else 1e-3)
    if np.all(np.isnan(cols["health"])):
        del cols["health"]
    has_motor = not np.all(np.isnan(cols["mot_x"]))
    if not has_motor:
        for a in "xyz":
            del cols[f"mot_{a}"]
    has_offsets = not np.all(np.isnan(cols["ofs_x"]))
    if not has_offsets:
        for a in "xyz":
            del cols[f"ofs_{a}"]

    mag_fmt = reader.formats[reader.name_to_id[mag_types[0]]] if not text else reader.formats[mag_types[0]]
    label = _fmt_unit(mag_fmt, "MagX")
    unit, factor = _unit_of(label)
    units_from = "the log's FMTU/UNIT messages"
    if not label:
        unit, factor = "mG", 1.0
        units_from = "ArduPilot's convention (milligauss): the log states no unit for MagX"
    elif unit is None:  # not a multiple of the gauss: keep what the log says
        unit, factor = label, 1.0
        units_from = f"the log's FMTU/UNIT messages ({label!r}, kept as stated)"
    scaled = [n for n in MAG_AXES + tuple(f"{p}_{a}" for p in ("ofs", "mot") for a in "xyz") if n in cols]
    if factor != 1.0:
        for n in scaled:
            cols[n] = cols[n] * factor
    metadata = {"source_format": "ArduPilot DataFlash " + ("text log" if text else "binary log"),
                "instance": f"MAG[{wanted}]" + ("" if "I" in mag_fmt.columns else
                                                 f" (message {_AP_MAG_NAMES[wanted]})"),
                "instances": ", ".join(f"MAG[{k}] ({len(per_instance[k])} readings)" for k in instances),
                "units_from": units_from,
                "t": f"{time_field} of the log (seconds since the autopilot booted)"}
    metadata["readings"] = ("MagX..Z as logged: ArduPilot's corrected field Mag = M·s·(raw + Ofs) + MO in the "
                            "body frame, not raw sensor readings (raw_x..z undo the correction)")
    metadata["offsets_applied"] = ("yes: OfsX..Z (ofs_x..z)" if has_offsets else "unknown: no OfsX..Z logged") + \
        (" and motor compensation MOX..Z (mot_x..z)" if has_motor else "") + " are already added into MagX..Z"
    column_units = {"t": "s", **{n: unit for n in scaled}}
    if has_offsets:
        raw, how = _ardupilot_raw(cols, params, wanted, has_motor)
        for a, values in zip("xyz", raw.T):
            cols[f"raw_{a}"] = values
            column_units[f"raw_{a}"] = unit
        metadata["raw_reconstruction"] = how
    if attitude["t"]:
        t_att = np.array(attitude["t"])
        for a in ATTITUDE:
            cols[a] = _interp_angles(t_att, attitude[a], cols["t"], wrap360=(a == "yaw"))
            column_units[a] = "deg"
        metadata["attitude"] = "ATT Roll, Pitch, Yaw interpolated to the MAG times (NaN outside the ATT span)"
        metadata["attitude_convention"] = "aerospace"
    if battery["t"]:
        cols["current"] = _current_at(cols["t"], battery["t"], battery["current"])
        column_units["current"] = "A"
        metadata["current"] = "BAT Curr (first battery) interpolated to the MAG times, held outside the BAT span"
    if "health" in cols:
        unhealthy = int(np.sum(cols["health"] == 0))
        if unhealthy:
            metadata["unhealthy_readings"] = unhealthy
    metadata.update(_ardupilot_version(version, messages))
    compass = _compass_params(params, wanted)
    if compass:
        metadata["compass_parameters"] = compass
    _note_damage(metadata, source, problems)
    rec = Recording(columns=cols, units=column_units, metadata=metadata, source=source)
    return _finish(rec, names, units, source)


_AP_MAG_MESSAGES = {"MAG": 0, "MAG2": 1, "MAG3": 2}  # one message per compass in older logs
_AP_MAG_NAMES = {k: n for n, k in _AP_MAG_MESSAGES.items()}
# t, mx, my, mz, ofs_x..z, mot_x..z, health; NaN where the message has no such field
_MAG_LAYOUT = ("t", "mx", "my", "mz", "ofs_x", "ofs_y", "ofs_z", "mot_x", "mot_y", "mot_z", "health")
_MAG_FIELDS = (("MagX",), ("MagY",), ("MagZ",), ("OfsX",), ("OfsY",), ("OfsZ",), ("MOX", "MOfsX"),
               ("MOY", "MOfsY"), ("MOZ", "MOfsZ"), ("Health",))


def _current_at(t_dst, t_src, amps) -> np.ndarray:
    """The battery current at the magnetometer times: linear between battery messages (sorted by time),
    the first and last value held outside their span."""
    t_src, amps = np.asarray(t_src, dtype=float), np.asarray(amps, dtype=float)
    order = np.argsort(t_src, kind="stable")
    return np.interp(t_dst, t_src[order], amps[order])


def _battery_instance(msg) -> int:
    """BAT's battery number: Inst (ArduPilot 4.1+), Instance (3.6–4.0), none in older logs (one battery)."""
    for name in ("Inst", "Instance"):
        if name in msg.fmt.columns:
            return int(getattr(msg, name))
    return 0


def _mag_row(msg, fields, time_field):
    row = [float(getattr(msg, time_field))]
    for candidates in _MAG_FIELDS:
        name = next((c for c in candidates if c in fields), None)
        row.append(float(getattr(msg, name)) if name else math.nan)
    return row


def _fmt_unit(fmt, column: str) -> str:
    try:
        return fmt.get_unit(column) or ""
    except (KeyError, IndexError, AttributeError):
        return ""


def _dataflash_damage(reader, size: int, text: bool, unterminated: bool) -> list:
    """What is wrong with the log's framing: a cut-off last message, bytes that belong to no message."""
    problems = []
    if text:
        if unterminated:
            problems.append("the last line has no line end: the log was cut off there; that line is ignored")
        return problems
    offsets, counts, formats = getattr(reader, "offsets", None), getattr(reader, "counts", None), reader.formats
    if offsets is None or counts is None:
        return problems
    covered, end, last = 0, 0, None
    for mtype, found in enumerate(offsets):
        if not found or mtype not in formats:
            continue
        length = formats[mtype].len
        covered += len(found) * length
        if found[-1] + length > end:
            end, last = found[-1] + length, formats[mtype].name
    if end > size:
        problems.append(f"the log is cut off inside its last message ({last}, {end - size} bytes missing at "
                        f"byte {size}); the complete messages are read")
        covered -= end - size
    stray = size - covered
    if stray > 0:
        problems.append(f"{stray} bytes belong to no message (garbled or padded log); pymavlink skipped them")
    return problems


def _text_line(path: Path, offset: int) -> str:
    """' (line N)' of the text-log line that ends just before byte `offset` (where pymavlink stopped)."""
    data = path.read_bytes()
    end = min(max(offset - 1, 0), len(data))
    start = data.rfind(b"\n", 0, max(end - 1, 0)) + 1
    return f" (line {data.count(NEWLINE, 0, start) + 1})"


def _ardupilot_raw(cols, params, k: int, has_motor: bool):
    """raw = (M·s)⁻¹(Mag − MO) − Ofs, undoing AP_Compass_Backend::correct_field."""
    sfx = _AP_PARAM_SUFFIX[k] if k < len(_AP_PARAM_SUFFIX) else str(k + 1)
    dia = [params.get(f"COMPASS_DIA{sfx}_{a}") for a in "XYZ"]
    odi = [params.get(f"COMPASS_ODI{sfx}_{a}") for a in "XYZ"]
    scale = params.get(f"COMPASS_SCALE{sfx}")
    used = []
    if all(v is not None for v in dia) and any(v != 0 for v in dia):
        used.append(f"COMPASS_DIA{sfx}_X..Z")
    else:
        dia = [1.0, 1.0, 1.0]  # firmware treats zero diagonals as identity
    if all(v is not None for v in odi):
        used.append(f"COMPASS_ODI{sfx}_X..Z")
    else:
        odi = [0.0, 0.0, 0.0]
    matrix = np.array([[dia[0], odi[0], odi[1]], [odi[0], dia[1], odi[2]], [odi[1], odi[2], dia[2]]])
    if scale is not None and 0 < scale <= 1.5:  # outside that the firmware ignores the scale
        matrix = matrix * scale
        used.append(f"COMPASS_SCALE{sfx}")
    field = np.column_stack([cols[n] for n in MAG_AXES])
    if has_motor:
        field = field - np.column_stack([cols[f"mot_{a}"] for a in "xyz"])
    raw = np.linalg.solve(matrix, field.T).T - np.column_stack([cols[f"ofs_{a}"] for a in "xyz"])
    how = ("raw = (M·s)⁻¹(Mag − MO) − Ofs with " + (", ".join(used) if used else
           "M = I, s = 1 (the log has no COMPASS_DIA/ODI/SCALE parameters)"))
    return raw, how


def _compass_params(params: dict, k: int) -> str:
    sfx = _AP_PARAM_SUFFIX[k] if k < len(_AP_PARAM_SUFFIX) else str(k + 1)
    keys = [f"COMPASS_OFS{sfx}_{a}" for a in "XYZ"] + [f"COMPASS_DIA{sfx}_{a}" for a in "XYZ"] + \
           [f"COMPASS_ODI{sfx}_{a}" for a in "XYZ"] + [f"COMPASS_MOT{sfx}_{a}" for a in "XYZ"] + \
           [f"COMPASS_SCALE{sfx}", f"COMPASS_DEV_ID{sfx}", f"COMPASS_ORIENT{sfx}",
            "COMPASS_EXTERNAL" if k == 0 else f"COMPASS_EXTERN{sfx}", "COMPASS_MOTCT", "COMPASS_LEARN",
            "COMPASS_USE" if k == 0 else f"COMPASS_USE{sfx}"]
    return ", ".join(f"{key}={params[key]:g}" for key in keys if key in params)


def _ardupilot_version(version: dict, messages: list) -> dict:
    out = {}
    # ArduPilot's first MSG names the firmware: "ArduCopter V4.5.7 (2a3dc4b7)", "ArduPlane V4.4.0", ...
    firmware = next((m for m in messages if re.match(r"(Ardu\w+|AntennaTracker|Blimp|AP_Periph|APM:\w+)\b.*\d+\.\d+",
                                                     m)), None)
    if firmware:
        out["firmware"] = firmware
    if version:
        if "FWS" in version and str(version["FWS"]).strip():
            out.setdefault("firmware", str(version["FWS"]).strip())
        if all(k in version for k in ("Maj", "Min", "Pat")):
            out["firmware_version"] = f"{version['Maj']}.{version['Min']}.{version['Pat']}"
        if "GH" in version:
            out["firmware_git_hash"] = f"{int(version['GH']):08x}"
        if "BT" in version:
            out["board_type"] = version["BT"]
        if "APJ" in version:
            out["board_id"] = version["APJ"]
    boards = [m for m in messages if m.startswith(("ChibiOS", "NuttX"))]
    if boards:
        out["firmware_os"] = boards[0]
    return out


# -- PX4 ULog ----------------------------------------------------------------------------------------------

PX4_TOPICS = ("sensor_mag", "vehicle_magnetometer")


class _ReadWatch(io.BufferedReader):
    """A file that remembers a read ending short of what was asked (pyulog stops there silently when a
    log is cut inside a message)."""

    short_read = None

    def read(self, size=-1):
        chunk = super().read(size)
        if size is not None and size > 0 and 0 < len(chunk) < size:
            self.short_read = (self.tell() - len(chunk), size, len(chunk))
        elif size and len(chunk) == size:
            self.short_read = None  # reading went on: that was not the end
        return chunk


def read_ulog(path, columns=None, units: str | None = None, instance=None) -> Recording:
    """Read the magnetometer of a PX4 ULog through pyulog: sensor_mag (raw) when logged, else
    vehicle_magnetometer (calibrated by PX4). See the module docstring."""
    path = readable_file(path)
    source = str(path)
    try:
        from pyulog import ULog
    except ImportError:
        raise ValueError(f"{source}: a PX4 ULog; reading it needs pyulog: {INSTALL_HINT}") from None
    spec, names = _split_choice(columns, instance, {t.upper() for t in PX4_TOPICS}, source)
    wanted_topic, wanted = _parse_spec(spec, "sensor_mag", source)
    if wanted_topic is not None:
        wanted_topic = wanted_topic.lower()
        if wanted_topic not in PX4_TOPICS:
            raise ValueError(f"{source}: {spec!r}: a PX4 log's magnetometer topics are "
                             f"{' and '.join(PX4_TOPICS)} (e.g. sensor_mag[1])")
    chatter: list = []
    problems: list = []
    try:
        watch = _ReadWatch(io.FileIO(str(path), "rb"))
    except OSError as exc:
        raise ValueError(f"{source}: cannot read ({exc.strerror or exc})") from None
    try:
        with _collected_output(chatter):
            ulog = ULog(watch, message_name_filter_list=list(PX4_TOPICS) + ["vehicle_attitude", "battery_status"])
    except Exception as exc:  # ULogException, struct.error, IndexError ... from a damaged file
        watch.close()
        raise ValueError(f"{source}: not a readable ULog (truncated or garbled? pyulog: "
                         f"{type(exc).__name__}: {exc})") from None
    if watch.short_read is not None:
        at, asked, got = watch.short_read
        problems.append(f"the log is cut off inside its last message ({asked - got} bytes missing at byte "
                        f"{at + got}); the complete messages are read")
    if getattr(ulog, "file_corruption", False):
        problems.append("pyulog found corrupt data and skipped it")
    if chatter:
        problems.append(f"pyulog: {_summary(chatter)}")
    datasets = {(d.name, d.multi_id): d for d in ulog.data_list}
    present = sorted(datasets)
    topic = wanted_topic or next((t for t in PX4_TOPICS if any(n == t for n, _ in present)), None)
    if topic is None or not any(n == topic for n, _ in present):
        what = f"no {topic} data" if wanted_topic else "no magnetometer data (sensor_mag or vehicle_magnetometer)"
        logged = ", ".join(f"{n}[{k}]" for n, k in present) or "none"
        damage = f"; {'; '.join(problems)}" if problems else ""
        raise ValueError(f"{source}: {what} in this ULog: no message of it was logged (of the topics fluxcal reads, "
                         f"the log has: {logged}){damage}")
    if (topic, wanted) not in datasets:
        have = ", ".join(f"{n}[{k}]" for n, k in present if n in PX4_TOPICS)
        raise ValueError(f"{source}: no compass instance {topic}[{wanted}]; the log has {have}")
    dataset = datasets[(topic, wanted)].data
    t = _ulog_time(dataset)
    if topic == "sensor_mag":
        mag = [dataset[a] for a in ("x", "y", "z")]
    else:
        mag = [dataset[f"magnetometer_ga[{i}]"] for i in range(3)]
    cols = {"t": t, **{n: np.asarray(v, dtype=float) for n, v in zip(MAG_AXES, mag)}}
    column_units = {"t": "s", **{n: "G" for n in MAG_AXES}}
    if "temperature" in dataset:
        temp = np.asarray(dataset["temperature"], dtype=float)
        if np.any(np.isfinite(temp)):
            cols["temp"], column_units["temp"] = temp, "C"
    device_id = int(dataset["device_id"][0]) if "device_id" in dataset and len(dataset["device_id"]) else None
    metadata = {"source_format": "PX4 ULog", "instance": f"{topic}[{wanted}]",
                "instances": ", ".join(_ulog_instance(n, k, datasets[(n, k)]) for n, k in present
                                       if n in PX4_TOPICS),
                "t": ("timestamp_sample" if "timestamp_sample" in dataset else "timestamp") +
                     " of the log (seconds since the autopilot booted)"}
    if topic == "sensor_mag" and "x_raw" in dataset:  # PX4 1.10 and older: drivers applied the calibration
        metadata["readings"] = ("calibrated: sensor_mag x,y,z of PX4 1.10 or older, calibrated by the driver "
                                "(x_raw.. are the sensor's counts), gauss")
        metadata["offsets_applied"] = "yes: the driver had applied the CAL_MAGn offsets and scales"
    elif topic == "sensor_mag":
        metadata["readings"] = "raw: sensor_mag x,y,z, the driver's output in the board frame (FRD), gauss"
        metadata["offsets_applied"] = "no: PX4 applies its CAL_MAGn calibration after sensor_mag"
    else:
        metadata["readings"] = ("calibrated: vehicle_magnetometer magnetometer_ga, PX4's corrected field in the body "
                                "frame (FRD), gauss")
        metadata["offsets_applied"] = "yes: PX4's CAL_MAGn offsets and scales are already applied"
    if device_id is not None:
        metadata["device_id"] = device_id
        calibration = _px4_calibration(ulog.initial_parameters, device_id)
        if calibration:
            metadata["px4_calibration"] = calibration
    attitude = next((d for (n, _), d in sorted(datasets.items()) if n == "vehicle_attitude"), None)
    if attitude is not None and all(f"q[{i}]" in attitude.data for i in range(4)):
        angles = _ulog_attitude(attitude.data, t)
        for a in ATTITUDE:
            cols[a], column_units[a] = angles[a], "deg"
        metadata["attitude"] = "vehicle_attitude q as roll, pitch, yaw, interpolated to the magnetometer times"
        metadata["attitude_convention"] = "aerospace"
    battery = datasets.get(("battery_status", 0))
    if battery is not None and "current_a" in battery.data:
        t_bat, amps = _ulog_time(battery.data), np.asarray(battery.data["current_a"], dtype=float)
        good = np.isfinite(amps) & (amps >= 0)  # PX4 logs −1 while the current is unknown
        if good.sum() >= 2:
            cols["current"] = _current_at(t, t_bat[good], amps[good])
            column_units["current"] = "A"
            metadata["current"] = ("battery_status[0] current_a interpolated to the magnetometer times, held outside "
                                   "its span")
    metadata.update(_px4_version(ulog))
    _note_damage(metadata, source, problems)
    rec = Recording(columns=cols, units=column_units, metadata=metadata, source=source)
    return _finish(rec, names, units, source)


def _ulog_time(dataset) -> np.ndarray:
    stamp = dataset.get("timestamp_sample")
    if stamp is None or not np.all(np.asarray(stamp) > 0):
        stamp = dataset["timestamp"]
    return np.asarray(stamp, dtype=float) * 1e-6


def _ulog_instance(name, k, dataset) -> str:
    ids = dataset.data.get("device_id")
    device = f", device_id {int(ids[0])}" if ids is not None and len(ids) else ""
    return f"{name}[{k}] ({len(dataset.data['timestamp'])} readings{device})"


def _ulog_attitude(data, t_dst) -> dict:
    from scipy.spatial.transform import Rotation, Slerp

    t_src = _ulog_time(data)
    q = np.column_stack([data[f"q[{i}]"] for i in (1, 2, 3, 0)]).astype(float)  # PX4 stores w, x, y, z
    good = np.isfinite(q).all(axis=1) & (np.linalg.norm(q, axis=1) > 0.5)
    t_src, q = t_src[good], q[good]
    out = {a: np.full(len(t_dst), np.nan) for a in ATTITUDE}
    if len(t_src) < 2:
        return out
    order = np.argsort(t_src, kind="stable")
    t_src, q = t_src[order], q[order]
    keep = np.concatenate([[True], np.diff(t_src) > 0])  # Slerp needs increasing times
    t_src, q = t_src[keep], q[keep]
    inside = (t_dst >= t_src[0]) & (t_dst <= t_src[-1])
    if len(t_src) >= 2 and inside.any():
        yaw, pitch, roll = Slerp(t_src, Rotation.from_quat(q))(t_dst[inside]).as_euler("ZYX", degrees=True).T
        out["roll"][inside], out["pitch"][inside], out["yaw"][inside] = roll, pitch, np.mod(yaw, 360.0)
    return out


def _px4_calibration(params: dict, device_id: int) -> str:
    for n in range(8):
        if int(params.get(f"CAL_MAG{n}_ID", -1)) == device_id:
            keys = [k for k in sorted(params) if k.startswith(f"CAL_MAG{n}_")]
            return ", ".join(f"{k}={params[k]:g}" for k in keys)
    return ""


def _px4_version(ulog) -> dict:
    info = ulog.msg_info_dict
    out = {}
    release = ulog.get_version_info_str() if hasattr(ulog, "get_version_info_str") else None
    if release:
        out["firmware_version"] = release
    for key, name in (("sys_name", "firmware"), ("ver_sw", "firmware_git_hash"), ("ver_sw_branch", "firmware_branch"),
                      ("ver_hw", "board"), ("sys_os_name", "firmware_os"), ("sys_os_ver", "firmware_os_git_hash")):
        if key in info and str(info[key]).strip():
            out[name] = str(info[key]).strip()
    return out
