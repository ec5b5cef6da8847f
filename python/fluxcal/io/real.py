"""Readers for the layouts real instruments and published data sets use (see formats.py for which
layout a file is recognised as).

* `key,value` preamble before the header (the QMC5883L logger of tomisuarez2/MagnetometerCalibration:
  `Fs,50.00` / `Initialization time,60` / `mx,my,mz`): the pairs become metadata, `Fs` (Hz) gives a
  time column t = row / Fs, and a file with both `Fs` and `Initialization time` is that logger's raw
  output, in sensor counts.
* Header-less tables of numbers: the columns are named by the caller (`names`, the CLI's `--columns`
  with one name per column), or the file matches the airborne (MagNav) layout of 10 columns — time,
  flux x, y, z (nT), INS pitch, roll, yaw (deg), IGRF north, east, down (nT) — see `airborne_layout`.
* JSON shots: an object whose lists of triples are readings, e.g. the SAP6 cave-survey instrument
  (CircuitPython mag_cal): `{"mag": [[x, y, z], …], "grav": [[x, y, z], …]}` in the CircuitPython sensor
  units (magnetic µT, acceleration m/s²); its maker's calibration `<name>.cfg` beside it goes to the
  metadata. fluxcal's own JSON layout is `{"kind": "fluxcal recording", "columns": {name: [...]},
  "units": {...}, "metadata": {...}}`.
Errors name the file, line and column.
"""
from __future__ import annotations

import json
import re
import warnings
from pathlib import Path

import numpy as np

from .csv import (readable_file, _is_number, decimal_points, is_comment, parse_csv, parse_rows,
                  read_lines, read_text, thousands_read)
from .columns import find_time
from .recording import ATTITUDE_COLUMNS, FIELD_NED_COLUMNS, Recording

# -- key,value preamble (QMC5883L logger) -------------------------------------------------------------------


def preamble_length(lines, start: int, delimiter) -> int:
    """How many lines from `start` are `name<delimiter>number` pairs (a preamble before the header)."""
    k = start
    while k < len(lines):
        cells = [c.strip() for c in lines[k].split(delimiter)]
        if len(cells) != 2 or _is_number(cells[0]) or not _is_number(cells[1]):
            break
        k += 1
    return k - start


def read_preamble_csv(path, columns=None, units: str | None = None, delimiter=",", bad_lines: str = "error"
                      ) -> Recording:
    """A CSV with `key,value` lines before its header (see the module docstring)."""
    path = readable_file(path)
    lines = read_lines(path)
    start = _skip_comments(lines)
    n = preamble_length(lines, start, delimiter)
    preamble, line_of = {}, {}
    for k in range(start, start + n):
        key, value = (c.strip() for c in lines[k].split(delimiter))
        preamble[key], line_of[key] = float(value), k + 1
    # the rest is an ordinary CSV: parse it with line numbers of the real file
    rec = parse_csv(path, lines, delimiter, preamble_lines=n, bad_lines=bad_lines)
    known = {"Fs": "sample_rate_hz", "Initialization time": "initialization_time_s"}
    rec.metadata.update({known.get(k, _key(k)): v for k, v in preamble.items()})
    if "Fs" in preamble and "t" not in rec.columns:
        fs = preamble["Fs"]
        if not fs > 0:
            raise ValueError(f"{path}, line {line_of['Fs']}, column 2: sample rate Fs = {fs} must be > 0")
        rec.columns = {"t": np.arange(len(rec)) / fs, **rec.columns}
        rec.units["t"] = "s"
        rec.metadata["t"] = f"row / Fs (Fs = {fs:g} Hz from line {line_of['Fs']})"
    if "Fs" in preamble and "Initialization time" in preamble:
        rec.metadata["layout"] = ("QMC5883L logger (tomisuarez2/MagnetometerCalibration): raw counts, the first "
                                  "initialization_time_s seconds static")
        for name in rec.mag_names():
            rec.units.setdefault(name, "counts")
    return rec.choose(columns, units)


def _key(name: str) -> str:
    return re.sub(r"\W+", "_", name.strip()).strip("_").lower() or "value"


def _skip_comments(lines, start: int = 0) -> int:
    while start < len(lines) and (not lines[start].strip() or is_comment(lines[start])):
        start += 1
    return start


# -- header-less tables ---------------------------------------------------------------------------------------

AIRBORNE_COLUMNS = ("t", "mx", "my", "mz") + ATTITUDE_COLUMNS + FIELD_NED_COLUMNS
AIRBORNE_UNITS = dict(zip(AIRBORNE_COLUMNS, ("s", "nT", "nT", "nT", "deg", "deg", "deg", "nT", "nT", "nT")))
_INFO_FIELDS = re.compile(r"time\s*,\s*flux_xyz\s*,\s*ins_pry\s*,\s*igrf_ned")


def airborne_layout(path, rows: np.ndarray):
    """Why `rows` (the first rows of a header-less 10-column table) are the airborne layout, or None.

    Recognised when the sibling `<stem>_info.txt` declares the fields `time, flux_xyz, ins_pry, igrf_ned`
    (as the published segment does), or when the numbers fit that layout: time non-decreasing, attitude
    angles in degrees (_attitude_like), an IGRF vector that is the Earth's field along a flight track
    (_igrf_like), and the flux vector's norm within a factor of 3 of the IGRF's."""
    info = _info_file(path)
    if info is not None and _INFO_FIELDS.search(info.read_text(errors="replace")):
        return f"declared by {info.name}"
    if rows.ndim != 2 or rows.shape[1] != 10 or len(rows) < 2:
        return None
    t, flux, attitude, igrf = rows[:, 0], rows[:, 1:4], rows[:, 4:7], rows[:, 7:10]
    igrf_norm, flux_norm = np.linalg.norm(igrf, axis=1), np.linalg.norm(flux, axis=1)
    fits = (np.all(np.diff(t) >= 0) and _attitude_like(attitude) and _igrf_like(igrf)
            and np.all((flux_norm > igrf_norm / 3) & (flux_norm < 3 * igrf_norm)))
    return ("the numbers fit it: time, nT field vectors, attitude angles in degrees, a smooth IGRF model; name "
            "the columns with --columns if it is another table") if fits else None


def _attitude_like(attitude: np.ndarray) -> bool:
    """Pitch, roll, yaw columns as degrees: |pitch| ≤ 90, |roll| ≤ 180, yaw in -180 … 360 (a heading either
    way), and pitch and roll turning by at most 30° from one row to the next (an aircraft's attitude turns
    smoothly). An accelerometer's m/s² can pass this: _igrf_like is what tells a second sensor apart."""
    pitch, roll, yaw = attitude.T
    steps = np.abs(np.diff(attitude[:, :2], axis=0))
    return bool(np.all(np.abs(pitch) <= 90) and np.all(np.abs(roll) <= 180)
                and np.all((yaw >= -180) & (yaw <= 360)) and np.all(steps <= 30))


def _igrf_like(igrf: np.ndarray) -> bool:
    """IGRF north, east, down columns as a model of the Earth's field along a track: norm 20 000 … 70 000 nT,
    each column stepping at most 2 nT from one row to the next (the model changes a few nT per km; a second
    sensor's readings turn with it by hundreds) and the norm varying by less than 1 % over the rows."""
    norm = np.linalg.norm(igrf, axis=1)
    return bool(np.all((norm > 20000) & (norm < 70000)) and np.all(np.abs(np.diff(igrf, axis=0)) <= 2)
                and np.ptp(norm) < 0.01 * np.median(norm))


def _info_file(path: Path):
    info = path.with_name(path.stem + "_info.txt")
    return info if info.is_file() else None


def read_headerless(path, names=None, columns=None, units: str | None = None, delimiter=None) -> Recording:
    """A table of numbers without a header: `names` (one per column) name the columns; without names it
    must be the airborne layout (`airborne_layout`), else the error asks for them."""
    path = readable_file(path)
    lines = read_lines(path)
    start = _skip_comments(lines)
    separated = {}
    lines, converted = decimal_points(lines, start, delimiter, separated, path)
    rec = _read_headerless(path, lines, start, names, columns, units, delimiter)
    if converted:
        rec.metadata["decimal_separator"] = "comma"
    thousands_read(path, rec.metadata, {n: separated[j] for j, n in enumerate(rec.columns) if j in separated})
    return rec



SPELLED_COLUMNS = 12  # an example of --columns spelt out up to this many names; beyond, its pattern and count


def _short(token: str) -> str:
    """A number of a row as a message shows it: as written when short, else to 6 significant digits (every column
    of a 40-column row then fits in ~600 characters, where full precision had filled three terminal lines)."""
    text = token.strip()
    try:
        return text if len(text) <= 10 else f"{float(text):.6g}"
    except ValueError:
        return text

def _read_headerless(path, lines, start, names, columns, units, delimiter) -> Recording:
    first = lines[start].split(delimiter)
    sep = {"\t": "tab", ",": "comma", None: "whitespace"}.get(delimiter, repr(delimiter))
    if names is not None:
        names = [n.strip() for n in (names.split(",") if isinstance(names, str) else names)]
        if len(names) != len(first):
            raise ValueError(f"{path}, line {start + 1}: {len(first)} {sep}-separated numbers and no header; "
                             f"--columns (columns=) gives {len(names)} names, need one per column")
        data, line_numbers, notes = parse_rows(path, lines, start, names, delimiter, expected="--columns")
        rec = Recording(columns=dict(zip(names, data.T)), source=str(path), line_numbers=line_numbers)
        # the magnetometer's columns (two: a biaxial sensor's), less a clock among them (t,mx,my: a biaxial log);
        # a "clock" that goes back at more than one step in a hundred is a three-axis sensor's x misnamed (half its
        # steps go back), which select() refuses; a clock reset now and then (a reboot, a wrap) is still a clock
        clock = find_time(names, rec.units)
        ticking = clock is not None and np.mean(np.diff(rec.columns[clock[0]]) >= 0) >= 0.99
        field = [n for n in names if not ticking or n != clock[0]]
        if len(field) in (2, 3):
            rec.select(field)
        if notes:
            rec.metadata["notes"] = "; ".join(f"line {n}: {text}" for n, text in notes)
        return rec.choose(None, units)
    probe = _probe_rows(lines, start, delimiter, 200)
    why = airborne_layout(path, probe) if len(first) == 10 else None
    if why is None and columns is not None:
        given = len(columns.split(",")) if isinstance(columns, str) else len(columns)
        raise ValueError(f"{path}, line {start + 1}: {len(first)} {sep}-separated numbers and no header; "
                         f"--columns (columns=) gives {given} names, need one per column")
    if why is None:
        # three columns or fewer hold no time: "t,mx,my" made the x readings the times as well
        example = (",".join(["mx", "my", "mz"][:len(first)] if len(first) <= 3 else
                            ["t", "mx", "my", "mz"] + [f"c{k}" for k in range(5, len(first) + 1)])
                   if len(first) <= SPELLED_COLUMNS else f"t,mx,my,mz,c5,…,c{len(first)}: {len(first)} names")
        # Beyond four columns the example's order is a pattern, not a guess that holds (a 10-column IMU log's
        # gyro then stood in the magnetometer's place): the first row, numbered, lets the reader point at them.
        shown = "" if len(first) <= 4 else (
            f"; line {start + 1} reads " + ", ".join(f"{k}: {_short(v)}" for k, v in enumerate(first, 1)) +
            " — name the magnetometer's three mx,my,mz where they are (and ax,ay,az an accelerometer's, t a clock)")
        raise ValueError(f"{path}, line {start + 1}: {len(first)} {sep}-separated numbers and no header; name the "
                         f"columns with --columns (Python: columns=; one name per column, e.g. {example}) or add a header "
                         f"line{shown}")
    data, line_numbers, notes = parse_rows(path, lines, start, AIRBORNE_COLUMNS, delimiter,
                                           expected="the airborne layout")
    metadata = {"layout": f"airborne MagNav segment: time, flux x,y,z, INS pitch,roll,yaw, IGRF N,E,D ({why})",
                "attitude_convention": "aerospace"}
    if not why.startswith("declared"):  # a guess from the numbers: said, as the columns become a reference field
        warnings.warn(f"{path}: read as {metadata['layout']}", stacklevel=5)
    info = _info_file(path)
    if info is not None:
        for line in info.read_text(errors="replace").splitlines():
            if "=" in line:
                key, value = (s.strip() for s in line.split("=", 1))
                metadata[_key(key)] = float(value) if _is_number(value) else value
    if notes:
        metadata["notes"] = "; ".join(f"line {n}: {text}" for n, text in notes)
    rec = Recording(columns=dict(zip(AIRBORNE_COLUMNS, data.T)), units=dict(AIRBORNE_UNITS), metadata=metadata,
                    source=str(path), line_numbers=line_numbers)
    return rec.choose(columns, units)


def _probe_rows(lines, start, delimiter, count) -> np.ndarray:
    """Up to `count` leading data rows as numbers, stopping before the first garbled one (which the full
    parse then reports with its line and column)."""
    rows = []
    for line in lines[start:]:
        if len(rows) == count:
            break
        if line.strip() and not is_comment(line):
            cells = line.split(delimiter)
            if not all(_is_number(c) for c in cells) or (rows and len(cells) != len(rows[0])):
                break
            rows.append([float(c) for c in cells])
    return np.array(rows)


# -- JSON -----------------------------------------------------------------------------------------------------

JSON_KIND = "fluxcal recording"
# names of triple lists and the columns they become
_TRIPLES = {"mag": ("mx", "my", "mz"), "grav": ("ax", "ay", "az"), "acc": ("ax", "ay", "az"),
            "accel": ("ax", "ay", "az")}
_CIRCUITPYTHON_UNITS = {"mx": "uT", "my": "uT", "mz": "uT", "ax": "m/s^2", "ay": "m/s^2", "az": "m/s^2"}


def _json_numbers(values) -> list:
    """A column as JSON numbers, a NaN or ±inf as null: standard JSON has no NaN (strict parsers refuse it)."""
    v = np.asarray(values, dtype=float)
    out = v.astype(object)
    out[~np.isfinite(v)] = None
    return out.tolist()


def write_json_recording(path, rec: Recording) -> Path:
    from ..calibration import _jsonable

    path = Path(path)
    data = {"kind": JSON_KIND, "units": dict(rec.units), "metadata": _jsonable(dict(rec.metadata)),
            "columns": {name: _json_numbers(v) for name, v in rec.columns.items()}}
    path.write_text(json.dumps(data) + "\n")
    return path


def read_json_recording(path, columns=None, units: str | None = None, bad_lines: str = "error") -> Recording:
    """A JSON recording: fluxcal's own layout, a shot file of [x, y, z] lists, or records — one object per
    reading as JSON Lines or a list, or a {"columns", "data"} table (fluxcal.io.jsonrecords; `bad_lines`
    applies to those)."""
    path = readable_file(path)
    text = read_text(path)
    try:
        return _json_recording(path, text, columns, units, bad_lines)
    except RecursionError:  # Python's JSON parser recurses per level: [[[[…]]]] is garbage, not a recording
        raise ValueError(f"{path}: JSON nested too deeply to be a recording") from None


def _json_recording(path, text: str, columns, units, bad_lines) -> Recording:
    from . import jsonrecords

    if text.lstrip().startswith("["):
        return jsonrecords.read_records(path, jsonrecords.list_items(text), bad_lines,
                                        what="record at line").choose(columns, units)
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        lines = jsonrecords.json_lines(text)
        if lines is not None:
            return jsonrecords.read_records(path, lines, bad_lines).choose(columns, units)
        raise ValueError(f"{path}, line {exc.lineno}, column {exc.colno} (character): not valid JSON "
                         f"({exc.msg}; truncated file?)") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}, line 1, column 1: expected a JSON object of readings, found a {type(data).__name__}")
    rows = jsonrecords.table_rows(data) if data.get("kind") != JSON_KIND else None
    if rows is not None:
        return jsonrecords.read_records(path, rows, bad_lines, what="data row").choose(columns, units)
    rows = jsonrecords.nested_rows(data) if data.get("kind") != JSON_KIND else None
    if rows is not None:  # (pandas' default to_json had been read as one record, mx_0, mx_1, …)
        return jsonrecords.read_records(path, rows, bad_lines, what="row").choose(columns, units)
    wrapped = _wrapped_records(data) if data.get("kind") != JSON_KIND else None
    if wrapped is not None:  # {"device": …, "unit": "mG", "samples": [{"x": …}, …]}: a phone app's export
        key, items = wrapped
        rec = jsonrecords.read_records(path, [(k + 1, item) for k, item in enumerate(items)], bad_lines,
                                       what=f"{key!r} record")
        _wrapper_metadata(rec, {k: v for k, v in data.items() if k != key})
        return rec.choose(columns, units)
    if data.get("kind") != JSON_KIND and not any(isinstance(v, list) for v in data.values()):
        return jsonrecords.read_records(path, [(1, data)], bad_lines).choose(columns, units)  # one JSON line
    if data.get("kind") == JSON_KIND:
        rec = _fluxcal_json(path, text, data)
    else:
        rec = _shots_json(path, text, data)
    return rec.choose(columns, units)


def _wrapped_records(data: dict):
    """(key, records) when a JSON object holds one list, of objects (the readings), beside single values (the
    device, the unit), else None."""
    lists = [(k, v) for k, v in data.items() if isinstance(v, list)]
    if len(lists) != 1 or any(isinstance(v, dict) for v in data.values()):
        return None
    key, items = lists[0]
    return (key, items) if items and sum(isinstance(i, dict) for i in items) >= 0.5 * len(items) else None


def _wrapper_metadata(rec: Recording, values: dict) -> None:
    """The single values beside a JSON object's records into the recording's metadata; a "unit" that is a field
    unit states the magnetometer's (see Recording.choose), as a logger's '# units: nT' does."""
    from .columns import is_field_unit, unit_name

    for key, value in values.items():
        if value is None:
            continue
        rec.metadata.setdefault(key, str(value))
        if key.lower() in ("unit", "units", "field_unit") and isinstance(value, str) and is_field_unit(value):
            rec.metadata["field_unit"] = unit_name(value)


def _fluxcal_json(path, text, data) -> Recording:
    cols = data.get("columns")
    if not isinstance(cols, dict) or not cols:
        raise ValueError(_at(path, text, ("columns",), "a fluxcal JSON recording needs a non-empty object 'columns'"))
    out = {}
    for name, values in cols.items():
        out[name] = _numbers(path, text, ("columns", name), values, name)
    lengths = {len(v) for v in out.values()}
    if len(lengths) > 1:
        name = next(n for n, v in out.items() if len(v) != len(next(iter(out.values()))))
        raise ValueError(_at(path, text, ("columns", name), f"column {name!r} has {len(out[name])} values, "
                             f"the first column {len(next(iter(out.values())))}"))
    return Recording(columns=out, units=dict(data.get("units", {})), metadata=dict(data.get("metadata", {})),
                     source=str(path))


def _numbers(path, text, where, values, name) -> np.ndarray:
    if not isinstance(values, list):
        raise ValueError(_at(path, text, where, f"{name!r} is not a list of numbers"))
    for k, v in enumerate(values):
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float))):
            raise ValueError(_at(path, text, where + (k,), f"{name}[{k}] = {json.dumps(v)} is not a number"))
    return np.array(values, dtype=float)  # null, as written for a NaN, is NaN again


def _shots_json(path, text, data) -> Recording:
    columns, metadata, n_rows, lists = {}, {}, None, []
    for key, value in data.items():
        if isinstance(value, list) and value and isinstance(value[0], list):
            lists.append(key)
            for k, triple in enumerate(value):
                if not (isinstance(triple, list) and len(triple) == 3
                        and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in triple)):
                    raise ValueError(_at(path, text, (key, k), f"{key}[{k}] = {json.dumps(triple)} is not a triple "
                                                              "of numbers (truncated or garbled reading?)"))
            if n_rows is not None and len(value) != n_rows:
                raise ValueError(_at(path, text, (key,), f"{key!r} has {len(value)} readings, "
                                                        f"{lists[0]!r} has {n_rows}"))
            n_rows = len(value)
            names = _TRIPLES.get(key, tuple(f"{key}_{a}" for a in "xyz"))
            if names[0] in columns:
                names = tuple(f"{key}_{a}" for a in "xyz")
            columns.update(zip(names, np.array(value, dtype=float).T))
        elif key == "units" and isinstance(value, dict):
            continue
        elif isinstance(value, (str, int, float, bool)) or value is None:
            metadata[key] = value
        else:
            metadata[key] = json.dumps(value)
    if "mx" not in columns:
        raise ValueError(_at(path, text, (), "no 'mag' list of [x, y, z] readings (and not a fluxcal JSON recording); "
                                            f"keys are: {', '.join(data) or 'none'}"))
    units = dict(data["units"]) if isinstance(data.get("units"), dict) else {}
    if not units and {"mag", "grav"} <= set(lists):
        units = {c: u for c, u in _CIRCUITPYTHON_UNITS.items() if c in columns}
        metadata["units_from"] = "CircuitPython sensor units (magnetic µT, acceleration m/s²) of mag_cal shot files"
    line_numbers = _item_lines(text, "mag")
    rec = Recording(columns=columns, units=units, metadata=metadata, source=str(path), line_numbers=line_numbers)
    cfg = Path(path).with_suffix(".cfg")
    if cfg.is_file():
        rec.metadata.update(read_mag_cal_cfg(cfg))
    return rec


def read_mag_cal_cfg(path) -> dict:
    """The maker's calibration of a SAP6 / mag_cal `.cfg` (JSON) as flat metadata entries maker_*.
    The numbers are the maker's, in its own conventions (axes remapped by `axes`, then transform and
    centre); fluxcal stores them for comparison and does not apply them."""
    path = readable_file(path)
    text = read_text(path)
    try:
        cfg = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}, line {exc.lineno}, column {exc.colno} (character): not valid JSON "
                         f"({exc.msg})") from None
    calib = cfg.get("calib", {}) if isinstance(cfg, dict) else {}
    out = {"maker_calibration_file": path.name}
    for sensor in ("mag", "grav"):
        for key in ("axes", "transform", "centre", "field_avg", "field_std"):
            if isinstance(calib.get(sensor), dict) and key in calib[sensor]:
                out[f"maker_{sensor}_{key}"] = calib[sensor][key]
    if "dip_avg" in calib:
        out["maker_dip_avg_deg"] = calib["dip_avg"]
    return out


_WS = re.compile(r"[ \t\n\r]*")


def _offset(text: str, path_keys) -> int:
    """Character offset of the JSON value at `path_keys` (object keys and list indices) in valid JSON."""
    decoder = json.JSONDecoder()
    i = _WS.match(text).end()
    for step in path_keys:
        if text[i] == "{":
            i = _WS.match(text, i + 1).end()
            while text[i] == '"':
                key, i = json.decoder.scanstring(text, i + 1)
                i = _WS.match(text, _WS.match(text, i).end() + 1).end()  # past ':'
                if key == step:
                    break
                i = _WS.match(text, decoder.raw_decode(text, i)[1]).end()
                i = _WS.match(text, i + 1).end() if text[i] == "," else i
            else:
                return i
        elif text[i] == "[":
            i = _WS.match(text, i + 1).end()
            for _ in range(int(step)):
                i = _WS.match(text, decoder.raw_decode(text, i)[1]).end()
                i = _WS.match(text, i + 1).end()  # past ','
    return i


def _line_col(text: str, offset: int):
    return text.count("\n", 0, offset) + 1, offset - (text.rfind("\n", 0, offset) + 1) + 1


def _at(path, text, path_keys, message: str) -> str:
    try:
        line, col = _line_col(text, _offset(text, path_keys))
    except (IndexError, ValueError):  # cannot happen for parsed JSON; never hide the message behind it
        line, col = "?", "?"
    where = "".join(f"[{k}]" if isinstance(k, int) else f".{k}" for k in path_keys).lstrip(".") or "top level"
    return f"{path}, line {line}, column {col} (character; {where}): {message}"


def _item_lines(text: str, key: str):
    """The line of each item of the top-level list `key` (for messages about a reading)."""
    decoder = json.JSONDecoder()
    i = _offset(text, (key,))
    if text[i] != "[":
        return None
    lines, line, pos = [], 1, 0
    i = _WS.match(text, i + 1).end()
    while i < len(text) and text[i] != "]":
        line += text.count("\n", pos, i)
        pos = i
        lines.append(line)
        i = _WS.match(text, decoder.raw_decode(text, i)[1]).end()
        i = _WS.match(text, i + 1).end() if text[i] == "," else i
    return np.array(lines, dtype=int)
