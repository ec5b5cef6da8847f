"""JSON records: one object per reading, as IoT loggers write them (an ESP32 over MQTT, Node-RED, a web API).

    {"t": 0.02, "mag": {"x": -13.62, "y": 27.37, "z": -17.02}, "acc": [0.1, 0.0, 9.8]}   JSON Lines, one per line
    [{"ts": 20, "mx": -13.62, "my": 27.37, "mz": -17.02}, ...]                           a list of records
    {"columns": ["time", "Bx (uT)", ...], "data": [[0.0, -13.62, ...], ...]}               a table (pandas "split")
    {"mx": {"0": -13.62, "1": -13.58, ...}, "my": {...}}                                    pandas to_json's default

A record is flattened: nested objects join their keys with "_" (mag.x → mag_x), a list of numbers gives
name[0], name[1], …; fluxcal.io.columns then finds the magnetometer, time, temperature by name. The
columns are the numeric keys most records carry. A text key whose values are dates/times becomes seconds
since the first (metadata "<key>_start"); a text key with one value throughout goes to the metadata; other
text is listed in metadata "text_columns". A record that is not valid JSON (a truncated last line, the
end of a list cut off when the logger stopped), lacks a column, or holds something other than a number
there is an error naming its line (bad_lines="error") or is left out and listed in metadata
"skipped_lines" ("skip").
"""
from __future__ import annotations

import json
import re
from collections import Counter
from pathlib import Path

import numpy as np

from .csv import SKIP_HINT, _is_number, _timestamps, check_bad_lines, listing
from .recording import Recording

_DECODER = json.JSONDecoder()
_SPACE = re.compile(r"[\s,]*")


def _line_of(text: str, offset: int) -> int:
    return text.count("\n", 0, offset) + 1


def json_lines(text: str):
    """[(line, record or the reason it is not one)] when the text holds one JSON value per line (JSON
    Lines) and more than one line, else None."""
    lines = [(k + 1, line.strip()) for k, line in enumerate(text.splitlines()) if line.strip()]
    if len(lines) < 2:
        return None
    out = []
    for line_no, line in lines:
        try:
            out.append((line_no, json.loads(line)))
        except json.JSONDecodeError as exc:
            out.append((line_no, f"not valid JSON ({exc.msg} at column {exc.colno}; truncated or garbled line?)"))
    return out if isinstance(out[0][1], dict) else None


def list_items(text: str):
    """[(line, record or the reason it is not one, where)] of top-level JSON lists, item by item, so that a list
    cut off by a logger that stopped keeps its complete records; lists written one after another (two
    sessions appended) are read in turn, anything else after a list is a bad line. `where` names an item in an
    error: "record at line 12" where a line holds one record, "record 17 (line 1)" in a list written on one line."""
    out, pos, cut = [], 0, False
    while not cut:
        pos = _SPACE.match(text, pos).end()
        if pos >= len(text):
            break
        if text[pos] != "[":
            out.append((_line_of(text, pos), f"text after the list's end: {text[pos:pos + 20]!r}", None))
            break
        pos = _SPACE.match(text, pos + 1).end()
        while pos < len(text) and text[pos] != "]":
            try:
                value, end = _DECODER.raw_decode(text, pos)
            except json.JSONDecodeError as exc:
                out.append((_line_of(text, pos), f"not valid JSON ({exc.msg}; the list is cut off here: "
                                                 "truncated file?)", len(out) + 1))
                cut = True
                break
            out.append((_line_of(text, pos), value, len(out) + 1))
            pos = _SPACE.match(text, end).end()
        pos += 1
    shared = Counter(line for line, _, k in out if k is not None)
    return [(line, value, f"line {line}" if k is None else
             f"record {k} (line {line})" if shared[line] > 1 else f"record at line {line}") for line, value, k in out]


def _flatten(record: dict, prefix: str = "", out: dict | None = None) -> dict:
    out = {} if out is None else out
    for key, value in record.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            _flatten(value, f"{name}_", out)
        elif isinstance(value, list) and value and all(_is_value(v) for v in value):
            out.update({f"{name}[{i}]": v for i, v in enumerate(value)})
        else:
            out[name] = value
    return out


def _is_value(v) -> bool:
    return v is None or isinstance(v, (int, float, str))


def _numeric(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _finite(v) -> bool:
    return _numeric(v) and bool(np.isfinite(v))


def _magnetometer_records(flat):
    """When a text key tells the sensors apart ({"sensor": "mag", "x": …} and {"sensor": "accel", "x": …}
    interleaved), the magnetometer's records only, and a note of the others; else (flat, None). Mixing
    them under the same names would be a wrong answer."""
    from .columns import MAG_WORDS, words

    records = [f for _, f, _ in flat if isinstance(f, dict)]
    for key in dict.fromkeys(k for f in records for k, v in f.items() if isinstance(v, str)):
        values = Counter(f[key] for f in records if isinstance(f.get(key), str))
        mag = [v for v in values if set(words(v)) & (MAG_WORDS - {"b", "h", "m"})]
        if 1 <= len(mag) < len(values) <= 8:
            others = ", ".join(f"{v} {c}" for v, c in values.items() if v not in mag)
            kept = [item for item in flat if not isinstance(item[1], dict) or item[1].get(key) in mag]
            return kept, f"{key} = {others} (the magnetometer's records are {key} = {', '.join(mag)})"
    return flat, None


def read_records(path, items, bad_lines: str = "error", what: str = "line") -> Recording:
    """A Recording from [(line, record or reason)] (json_lines or a table's rows; an error names an item as
    `what` and its line) or [(line, record or reason, where)] (list_items)."""
    check_bad_lines(bad_lines)
    flat = [(n, _flatten(r) if isinstance(r, dict) else
             (r if isinstance(r, str) else f"a JSON {type(r).__name__}, not an object of named values"),
             place[0] if place else f"{what} {n}") for n, r, *place in items]
    flat, kind_note = _magnetometer_records(flat)
    records = [f for _, f, _ in flat if isinstance(f, dict)]
    numeric = Counter(k for f in records for k, v in f.items() if _numeric(v))
    if not numeric:
        raise ValueError(f"{path}: no numbers in the JSON records"
                         + (f" (keys are: {', '.join(dict.fromkeys(k for f in records for k in f))})" if records else ""))
    top = max(numeric.values())
    names = [k for k in dict.fromkeys(k for f in records for k in f) if numeric[k] >= 0.5 * top]
    text_keys = [k for k in dict.fromkeys(k for f in records for k in f)
                 if k not in names and Counter(isinstance(f.get(k), str) for f in records)[True] >= 0.5 * len(records)]
    good, problems = [], []
    for n, f, place in flat:
        where = place.removeprefix(f"{what} ")  # for skipped_lines: the line's number, or the record's place
        if isinstance(f, str):
            problems.append((place, where, f))
            continue
        missing = [k for k in names if k not in f]
        bad = next((k for k in names if k in f and not _finite(f[k])), None)
        if missing:
            problems.append((place, where, f"no {', '.join(repr(k) for k in missing)}"))
        elif bad is not None:
            problems.append((place, where, f"{bad!r} is {json.dumps(f[bad])}, not a number"))
        else:
            good.append((n, f))
    if problems and bad_lines == "error":
        place, _, p = problems[0]
        raise ValueError(f"{path}, {place}: {p}; {SKIP_HINT}")
    if not good:
        raise ValueError(f"{path}: no readable records" + (f" (all {len(problems)} bad)" if problems else ""))
    columns = {k: np.array([f[k] for _, f in good], dtype=float) for k in names}
    metadata, units, notes = {}, {}, []
    for key in text_keys:
        values = [f.get(key) if isinstance(f.get(key), str) else "" for _, f in good]
        seconds, first = _timestamps(values)
        if seconds is not None and np.all(np.isfinite(seconds)):
            columns[key], units[key], metadata[f"{key}_start"] = seconds, "s", first
        elif len(set(values)) == 1:
            metadata[key] = values[0]
        else:
            notes.append(f"{key} (e.g. {', '.join(sorted(set(v for v in values if v))[:4])})")
    if notes:
        metadata["text_columns"] = "; ".join(notes)
    if kind_note:
        metadata["records_left_out"] = kind_note
    if problems:
        metadata["skipped_lines"] = listing([f"{where} ({p})" for _, where, p in problems], len(flat))
    return Recording(columns=columns, units=units, metadata=metadata, source=str(path),
                     line_numbers=np.array([n for n, _ in good], dtype=int))


def table_rows(data: dict):
    """[(row number, record)] of a {"columns": [names], "data": [[values], ...]} table (pandas "split"),
    or None when `data` is not one."""
    names, rows = data.get("columns"), data.get("data")
    if not (isinstance(names, list) and names and all(isinstance(c, str) for c in names) and isinstance(rows, list)):
        return None
    return [(k + 1, dict(zip(names, row)) if isinstance(row, list) and len(row) == len(names) else
             f"{len(row) if isinstance(row, list) else 'not a list of'} values, the table has {len(names)} columns")
            for k, row in enumerate(rows)]


def nested_rows(data: dict):
    """[(row number, record)] of pandas to_json's default layout (orient "columns": {column: {index: value}}) or of
    orient "index" ({index: {column: value}}), told apart by which keys are index labels (numbers: 0, 1, … or epoch
    milliseconds), or None when `data` is neither (a single record with nested objects: {"mag": {"x": …}})."""
    inner = [list(v) for v in data.values() if isinstance(v, dict)]
    if len(inner) != len(data) or not inner or not inner[0] or any(keys != inner[0] for keys in inner):
        return None
    def labels(keys) -> bool:
        return all(_is_number(str(k)) for k in keys)
    if labels(inner[0]) and not labels(data):  # {column: {index: value}}
        return [(k + 1, {c: data[c][i] for c in data}) for k, i in enumerate(inner[0])]
    if labels(data) and not labels(inner[0]):  # {index: {column: value}}
        return [(k + 1, dict(record)) for k, record in enumerate(data.values())]
    return None

