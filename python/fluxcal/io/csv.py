"""CSV recordings.

Layout written (and read) by fluxcal:

    # fluxcal recording
    # units: mx=nT, my=nT, mz=nT, t=s
    # sensor: RM3100            <- any other "# key: value" line is metadata
    t,mx,my,mz
    0.00,123.4,-456.7,890.1

Units may also sit in the header cells: `mx[nT]` or `mx (nT)`. A header-only CSV (no comments) reads
with empty units. Errors name the file, line and column.
"""
from __future__ import annotations

import io
import re
from pathlib import Path

import numpy as np

from .recording import Recording

_UNIT_IN_HEADER = re.compile(r"^\s*([^\[\(]+?)\s*[\[\(]\s*([^\]\)]*)\s*[\]\)]\s*$")


def _split_header(cell: str):
    m = _UNIT_IN_HEADER.match(cell)
    return (m.group(1).strip(), m.group(2).strip()) if m else (cell.strip(), "")


def read_csv(path, columns=None, units: str | None = None, delimiter: str = ",") -> Recording:
    """Read a CSV recording. `columns`: the three magnetometer columns (default mx,my,mz, or x,y,z).
    `units`: the field unit, when the file does not state it."""
    path = Path(path)
    return parse_csv(path, read_text(path).splitlines(), delimiter).choose(columns, units)


def parse_csv(path, lines, delimiter=",", preamble_lines: int = 0) -> Recording:
    """The CSV layout above from the file's lines; `preamble_lines` lines between the comments and the
    header are left to the caller (fluxcal.io.real reads `key,value` preambles)."""
    metadata, unit_map = {}, {}
    i = 0
    while i < len(lines) and (lines[i].startswith("#") or not lines[i].strip()):
        body = lines[i].lstrip("#").strip()
        if ":" in body:
            key, value = (s.strip() for s in body.split(":", 1))
            if key == "units":
                for pair in filter(None, (p.strip() for p in value.split(","))):
                    if "=" not in pair:
                        raise ValueError(f"{path}, line {i + 1}: units entry {pair!r} is not name=unit")
                    name, unit = (s.strip() for s in pair.split("=", 1))
                    unit_map[name] = unit
            else:
                metadata[key] = value
        i += 1
    i += preamble_lines
    if i >= len(lines):
        raise ValueError(f"{path}: no header line (expected column names such as t,mx,my,mz)")
    header_line = i + 1
    names = []
    for cell in lines[i].split(delimiter):
        name, unit = _split_header(cell)
        names.append(name)
        if unit:
            unit_map.setdefault(name, unit)
    if any(not n for n in names) or len(set(names)) != len(names):
        raise ValueError(f"{path}, line {header_line}: header {lines[i]!r} has empty or repeated column names")
    if _is_number(names[0]):
        raise ValueError(f"{path}, line {header_line}: the first line holds numbers, not column names; "
                         "add a header such as mx,my,mz")
    data, line_numbers, notes = parse_rows(path, lines, i + 1, names, delimiter)
    if notes:  # comment lines among the data (e.g. a recorder's reconnection note) are kept, not parsed
        metadata["notes"] = "; ".join(f"line {n}: {text}" for n, text in notes)
    return Recording(columns={n: data[:, j] for j, n in enumerate(names)}, units=unit_map, metadata=metadata,
                     source=str(path), line_numbers=line_numbers)


def read_text(path) -> str:
    """The file's text; undecodable bytes are an error naming their line and column."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ValueError(f"{path}: cannot read ({exc.strerror or exc})") from None
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        column = exc.start - (raw.rfind(b"\n", 0, exc.start) + 1) + 1
        raise ValueError(f"{path}, line {line}, column {column} (character): byte 0x{raw[exc.start]:02x} is not "
                         "text (UTF-8); a binary file, or garbage from a serial line?") from None


def parse_rows(path, lines, start: int, names, delimiter, expected: str = "the header"):
    """Parse lines[start:] as rows of len(names) numbers; blank lines are skipped and "#" lines returned
    as notes. Returns (data N×len(names), the 1-based file line of each row, [(line, note)]); errors
    name line and column (`expected`: where the column names came from, for those messages)."""
    body = lines[start:]
    keep = [k for k, line in enumerate(body) if line.strip() and not line.lstrip().startswith("#")]
    notes = [(start + k + 1, line.lstrip().lstrip("#").strip()) for k, line in enumerate(body)
             if line.lstrip().startswith("#")]
    if not keep:
        raise ValueError(f"{path}: header but no data rows")
    line_numbers = np.array([start + k + 1 for k in keep], dtype=int)
    try:
        data = np.loadtxt(io.StringIO("\n".join(body[k] for k in keep)), delimiter=delimiter, ndmin=2,
                          dtype=float, comments=None)
        if data.shape[1] != len(names):
            raise ValueError("column count")
    except ValueError:
        _raise_parse_error(path, [body[k] for k in keep], line_numbers, names, delimiter, expected)
        raise  # unreachable: _raise_parse_error always raises
    return data, line_numbers, notes


def _is_number(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


def _raise_parse_error(path, rows, line_numbers, names, delimiter, expected="the header"):
    """Find the first bad cell the slow way, so the message names line and column."""
    for row, line_no in zip(rows, line_numbers):
        cells = row.split(delimiter)
        if len(cells) < len(names):
            raise ValueError(f"{path}, line {line_no}: {len(cells)} fields, {expected} has {len(names)}: column "
                             f"{names[len(cells)]!r} (field {len(cells) + 1}) is missing (truncated or garbled line?)")
        if len(cells) > len(names):
            raise ValueError(f"{path}, line {line_no}: {len(cells)} fields, {expected} has {len(names)}: field "
                             f"{len(names) + 1} ({cells[len(names)].strip()!r}) has no column (garbled line?)")
        for cell, name in zip(cells, names):
            if not _is_number(cell):
                what = "empty" if not cell.strip() else f"{cell.strip()!r} is not a number"
                raise ValueError(f"{path}, line {line_no}, column {name!r}: {what}")
    raise ValueError(f"{path}: could not parse the data rows")


def write_csv(path, recording_or_columns, units=None, metadata=None, fmt: str | None = None) -> Path:
    """Write a recording (or a dict of columns) with its units and metadata as comment lines.
    Numbers are written in the shortest form that reads back to the same double (nothing lost), unless
    `fmt` (a printf format such as "%.10g") asks for fewer digits."""
    if isinstance(recording_or_columns, Recording):
        rec = recording_or_columns
        columns, units, metadata = rec.columns, {**rec.units, **(units or {})}, {**rec.metadata, **(metadata or {})}
    else:
        columns, units, metadata = dict(recording_or_columns), dict(units or {}), dict(metadata or {})
    names = list(columns)
    data = np.column_stack([np.asarray(columns[n], dtype=float) for n in names])
    head = ["# fluxcal recording"]
    if units:
        head.append("# units: " + ", ".join(f"{n}={u}" for n, u in units.items() if n in columns and u))
    head += [f"# {k}: {v}" for k, v in metadata.items()]
    path = Path(path)
    with path.open("w") as f:
        f.write("\n".join(head) + "\n" + ",".join(names) + "\n")
        if fmt is not None:
            np.savetxt(f, data, delimiter=",", fmt=fmt)
        else:  # repr of a Python float is the shortest string that round-trips
            f.writelines(",".join(map(repr, row)) + "\n" for row in data.tolist())
    return path
