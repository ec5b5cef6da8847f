"""CSV recordings.

Layout written (and read) by fluxcal:

    # fluxcal recording
    # units: mx=nT, my=nT, mz=nT, t=s
    # sensor: RM3100            <- any other "# key: value" line is metadata (free text: "comments")
    t,mx,my,mz
    0.00,123.4,-456.7,890.1

Units may also sit in the header cells: `mx[nT]` or `mx (nT)`. A header-only CSV (no comments) reads
with empty units. Errors name the file, line and column.
"""
from __future__ import annotations

import contextlib
import contextvars
import csv as _csv
import gzip
import io
import re
import zlib
from pathlib import Path

import numpy as np

from .recording import COMMAS_HINT, Recording

BAD_LINES = ("error", "skip")
SKIP_HINT = "pass bad_lines='skip' (--bad-lines skip) to leave such lines out"
# comment lines: fluxcal's and most loggers' '#', Xsens MT Manager's '//', MATLAB's '%'
COMMENT_MARKS = ("#", "//", "%")


def is_comment(line: str) -> bool:
    return line.lstrip().startswith(COMMENT_MARKS)


def data_lines(lines, start: int, count: int) -> list:
    """Up to `count` lines from `start` on that are neither blank nor comments (a sample to sniff a layout by)."""
    return [line for line in lines[start:start + 8 * count] if line.strip() and not is_comment(line)][:count]


def comment_text(line: str) -> str:
    """A comment line's text without its mark."""
    body = line.strip()
    mark = next((m for m in COMMENT_MARKS if body.startswith(m)), "")
    return body[len(mark):].lstrip(mark[:1]).strip()  # '##' or '%%' as well


def check_bad_lines(bad_lines: str) -> None:
    if bad_lines not in BAD_LINES:
        raise ValueError(f"bad_lines: {bad_lines!r} is not one of {', '.join(BAD_LINES)}")


def stop_at_first(path, problems, bad_lines: str) -> None:
    """With bad_lines "error", a line reader's first [(line, problem)] as an error naming the file and the line."""
    if problems and bad_lines == "error":
        line, problem = problems[0]
        raise ValueError(f"{path}, line {line}: {problem}; {SKIP_HINT}")


def listing(entries, total: int | None = None, shown: int = 10) -> str:
    """'k of total: e1; e2; … n more' (the first `shown` entries), for metadata such as skipped_lines."""
    head = f"{len(entries)} of {total}: " if total is not None else ""
    more = f"; … {len(entries) - shown} more" if len(entries) > shown else ""
    return head + "; ".join(entries[:shown]) + more


def skipped_words(skipped_lines: str, why: str = "") -> str:
    """What the command line prints of a recording's metadata "skipped_lines" (`listing`'s 'k of total: …'):
    'skipped k of total lines: …', then `why` in parentheses."""
    return f"skipped {skipped_lines.replace(':', ' lines:', 1)}" + (f" ({why})" if why else "")


def warn_skipped(rec: Recording) -> Recording:
    """`rec`, with a warning of the lines bad_lines="skip" left out (metadata "skipped_lines", `listing`'s 'k of total:
    …') when there are any: the command line prints them, and Python had left them out without a word. Said by the
    public readers (read_recording, read_csv) once per read, with the lines as the recording's metadata numbers them."""
    import warnings

    if rec.metadata.get("skipped_lines"):
        warnings.warn(f"{rec.source}: {skipped_words(rec.metadata['skipped_lines'], SKIPPED_WHY)}", UserWarning,
                      stacklevel=3)
    return rec


SKIPPED_WHY = "bad_lines='skip'"  # ends the warning (quiet_skipped filters it by that)


@contextlib.contextmanager
def quiet_skipped():
    """No warn_skipped warning within: for a caller that says metadata "skipped_lines" itself (the command line
    prints it, a batch keeps it with each unit's warnings), so that it is not said twice."""
    import warnings

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=rf".*\({re.escape(SKIPPED_WHY)}\)$", category=UserWarning)
        yield


_UNIT_IN_HEADER = re.compile(r"^\s*([^\[\(]+?)\s*[\[\(]\s*([^\]\)]*)\s*[\]\)]\s*$")


def _split_header(cell: str):
    """'mx [nT]' -> ('mx', 'nT'); an index in brackets is part of the name: 'mag[0]' -> ('mag[0]', '');
    quotes around a name are dropped."""
    from .columns import is_unit

    cell = cell.strip().strip('"').strip("'")
    m = _UNIT_IN_HEADER.match(cell)
    if m is None or m.group(2).strip().isdigit():
        return cell, ""
    unit, _, note = (s.strip() for s in m.group(2).partition(","))
    if note and is_unit(unit):  # 'Bx (uT, raw)': the unit, and a note kept in the name ('Bx raw': reads back)
        return f"{m.group(1).strip()} {note}", unit
    return m.group(1).strip(), m.group(2).strip()


def _header_cells(line: str, delimiter) -> list:
    """The header's cells; quotes are honoured as in the data rows ("Bx (uT, raw)" is one name)."""
    if delimiter and '"' in line:
        return next(_csv.reader([line], delimiter=delimiter), [])
    return line.split(delimiter)


def read_csv(path, columns=None, units: str | None = None, delimiter: str | None = None, bad_lines: str = "error"
             ) -> Recording:
    """Read a CSV recording. `columns`: the three magnetometer columns (default mx,my,mz, or x,y,z).
    `units`: the field unit, when the file does not state it. `delimiter`: by default the file's own, and its layout
    read as fluxcal.read_recording reads a text table (';' or tab with decimal commas, a spreadsheet's `sep=;` line, a
    banner above the header, no header); ",", ";" or "\t" reads the plain layout with that one. `bad_lines`: "error"
    or "skip"."""
    path = readable_file(path)
    try:
        if delimiter is None:
            from .formats import _read_table

            return warn_skipped(_read_table(path, columns, units, bad_lines))
        return warn_skipped(parse_csv(path, read_lines(path), delimiter, bad_lines=bad_lines).choose(columns, units))
    except ValueError as exc:
        other = _not_a_table(path)
        if other:  # (a blind check: JSON Lines read as "no column of numbers", a flight log as a bad header)
            raise ValueError(f"{exc}; {other}") from None
        raise


def _not_a_table(path) -> str:
    """What a file read_csv refused looks like when it is a format fluxcal.read_recording reads, else ""."""
    try:
        head = [line.strip() for line in read_lines(path)[:50] if line.strip()]
    except ValueError:
        return ""
    what = ("JSON records" if head and head[0][:1] in "{[" else
            "an ArduPilot text log" if any(line.startswith("FMT,") for line in head) else "")
    return (f"it looks like {what}, not a table: read it with fluxcal.read_recording (the command line does)"
            if what else "")


def parse_csv(path, lines, delimiter=",", preamble_lines: int = 0, bad_lines: str = "error") -> Recording:
    """The CSV layout above from the file's lines; `preamble_lines` lines between the comments and the
    header are left to the caller (fluxcal.io.real reads `key,value` preambles). `bad_lines`: "error"
    (default) or "skip" (see parse_mixed_rows)."""
    from .columns import unit_name

    check_bad_lines(bad_lines)
    metadata, unit_map, comments = {}, {}, []
    i = 0
    while i < len(lines) and (is_comment(lines[i]) or not lines[i].strip()):
        body = comment_text(lines[i])
        if ":" in body or "=" in body:
            key, value = (s.strip() for s in body.split(":" if ":" in body else "=", 1))
            if key.lower() in ("units", "unit"):
                _banner_units(path, i + 1, value, unit_map, metadata)
            else:
                metadata[key] = value
        elif body and body != "fluxcal recording":  # free text above the header (a title, who recorded it)
            comments.append(body)
        i += 1
    if comments:
        metadata.setdefault("comments", "; ".join(comments))
    i += preamble_lines
    if i >= len(lines):
        raise ValueError(f"{path}: no header line (expected column names such as t,mx,my,mz)")
    header_line = i + 1
    names = []
    for cell in _header_cells(lines[i], delimiter):
        name, unit = _split_header(cell)
        names.append(name)
        if unit:
            if unit_map.get(name, unit) != unit and unit_name(unit_map[name]) != unit_name(unit):
                raise ValueError(f"{path}, line {header_line}: column {name!r} is in {unit} by the header but in "
                                 f"{unit_map[name]} by the '# units:' comment; correct one of them")
            unit_map.setdefault(name, unit)
    # before an empty first name becomes pandas' index: a partial line of numbers (",52.1,-18.2") is data
    if _is_number(names[0]) or (not names[0] and len(names) > 1 and all(_is_number(n) for n in names[1:])):
        raise ValueError(f"{path}, line {header_line}: the first line holds numbers, not column names; "
                         + _later_header(lines, i, len(names), delimiter))
    if len(names) > 1 and not names[0] and "index" not in names:  # pandas to_csv(): its unnamed index column
        names[0] = "index"
    for k in range(1, len(names)):  # a header ending in the delimiter (mx,my,mz,,), or a spreadsheet's spacer
        if not names[k]:  # column: unnamed columns, kept under these names (left out later, said, if they are empty)
            names[k] = f"column{k + 1}"
    if any(not n for n in names) or len(set(names)) != len(names):
        raise ValueError(f"{path}, line {header_line}: header {lines[i]!r} has empty or repeated column names")
    lines = _units_row(lines, i + 1, names, delimiter, unit_map)
    lines = _repeated_headers(path, lines, i, names, delimiter, unit_map, metadata)
    lines = _trailing_delimiters(lines, i + 1, names, delimiter)
    separated = {}
    lines, converted = decimal_points(lines, i + 1, delimiter, separated, path)
    if converted:
        metadata["decimal_separator"] = "comma"
        grouped = [j for j in converted if 0 <= j < len(names)]
        if grouped:
            metadata["thousands_separator"] = "point (" + ", ".join(names[j] for j in grouped) + ")"
    thousands_read(path, metadata, {names[j]: mark for j, mark in separated.items() if j < len(names)})
    try:
        data, line_numbers, notes = parse_rows(path, lines, i + 1, names, delimiter)
        # NaN/Inf written out (Arduino's "nan") in a column of numbers: lines to skip, as an empty cell is (a
        # column that is never a number, say an altitude the logger did not have, is left as it is)
        if bad_lines == "skip" and not np.isfinite(data[:, np.isfinite(data).any(axis=0)]).all():
            raise ValueError("non-finite values")
    except ValueError as exc:
        # text or timestamp columns, or lines to skip: the slow per-cell parse (the same errors otherwise)
        names, data, line_numbers, notes = parse_mixed_rows(path, lines, i + 1, names, delimiter, bad_lines,
                                                            unit_map, metadata, exc)
    if notes:  # comment lines among the data (e.g. a recorder's reconnection note) are kept, not parsed
        metadata["notes"] = "; ".join(f"line {n}: {text}" for n, text in notes)
    _units_from_notes(notes, names, unit_map, metadata)
    return Recording(columns={n: data[:, j] for j, n in enumerate(names)}, units=unit_map, metadata=metadata,
                     source=str(path), line_numbers=line_numbers)


def _later_header(lines, start: int, width: int, delimiter) -> str:
    """What to do about a table starting with numbers: a header line further down (a logger reset, its banner and
    header printed again under rows of before) is named, the rows above it to delete; else add a header."""
    for k in range(start + 1, min(len(lines), start + 2000)):
        cells = [c.strip() for c in _header_cells(lines[k].strip(), delimiter)]
        if len(cells) == width and all(c and not _is_number(c) for c in cells) and not is_comment(lines[k]):
            return (f"the header {lines[k].strip()!r} is on line {k + 1}: delete the lines above it (rows of before "
                    "a logger's reset?), or add a header on line 1")
    return "add a header such as mx,my,mz"


# `fluxcal record`'s note when the device prints its units only after the first rows (its header reprinted)
UNITS_FROM_HERE = "units printed by the device from here on:"


def _units_from_notes(notes, names, unit_map: dict, metadata: dict) -> None:
    """Units a recorder's note gives for columns the head states none for (`fluxcal record` of a device that printed
    `mx[uT],…` after its first rows): the device's units, the rows before the note being its own too (a blind check's
    `calibrate` had said "no unit stated" beside the note). Said in metadata["units_from_note"]."""
    for line, text in notes:
        text = text.strip()
        text = text[len("note:"):].strip() if text.startswith("note:") else text
        if not text.startswith(UNITS_FROM_HERE):
            continue
        pairs = [p.strip().split("=", 1) for p in text[len(UNITS_FROM_HERE):].split(",") if "=" in p]
        taken = {k.strip(): u.strip() for k, u in pairs if k.strip() in names and not unit_map.get(k.strip())}
        if taken:
            unit_map.update(taken)
            metadata["units_from_note"] = (f"line {line}: " + ", ".join(f"{k}={u}" for k, u in taken.items())
                                           + " (the device's, printed after its first rows)")


def _banner_units(path, line: int, value: str, unit_map: dict, metadata: dict) -> None:
    """A `# units:` comment: name=unit pairs (fluxcal's own, `x=nT, y=nT`) into unit_map, or one field unit for
    the magnetometer (a logger's banner, `# Units: nT`) into metadata["field_unit"] (see Recording.choose)."""
    from .columns import is_field_unit, unit_name

    entries = [p.strip() for p in value.split(",") if p.strip()]
    if len(entries) == 1 and "=" not in entries[0]:
        if not is_field_unit(entries[0]):
            raise ValueError(f"{path}, line {line}: units {entries[0]!r} is no field unit (nT, uT, mG, G, T) nor "
                             "name=unit pairs (x=nT, y=nT, z=nT)")
        metadata["field_unit"] = unit_name(entries[0])
        return
    for pair in entries:
        if "=" not in pair:
            raise ValueError(f"{path}, line {line}: units entry {pair!r} is not name=unit (a single field unit, "
                             "'# units: nT', is taken for the magnetometer)")
        name, unit = (s.strip() for s in pair.split("=", 1))
        unit_map[name] = unit


def thousands_read(path, metadata: dict, marks: dict) -> None:
    """Record in metadata, and warn, that the columns of `marks` (name -> ',' or '.') were read with thousands
    separators (48,123 or 48.123 as 48123; see _comma_thousands_columns, _point_thousands_whole_columns): a
    guess from the values, so it is said."""
    import warnings

    if not marks:
        return
    names, mark = list(marks), next(iter(marks.values()))
    word = "comma" if mark == "," else "point"
    metadata["thousands_separator"] = f"{word} (" + ", ".join(names) + ")"
    warnings.warn(f"{path}: column{'s' if len(names) > 1 else ''} {', '.join(names)}: 1{mark}234 read as 1234 (a "
                  f"thousands separator, not a decimal {word}): every {word} has three digits after it and the "
                  f"whole numbers beside them are below 1000; if they are decimal {word}s, save the table with decimals "
                  "written out", stacklevel=4)


def parse_mixed_rows(path, lines, start: int, names, delimiter, bad_lines: str, units: dict, metadata: dict,
                     plain_error: Exception):
    """Rows that np.loadtxt refused. A column without a single number is text: timestamps (ISO 8601 or
    what pandas recognises) become seconds since the first row (unit s, the first stamp in metadata
    "<name>_start"); other text columns are left out and named in metadata "text_columns" with a few of
    their values. Then a line with the wrong number of fields or a non-number in a numeric column is an
    error naming line and column (bad_lines="error"), or is left out and listed in metadata
    "skipped_lines" (bad_lines="skip"). Returns (names kept, data, line numbers, notes); fills units
    and metadata. `plain_error`: the all-numeric parser's error, raised as it was when there is no text
    column and bad lines are errors."""
    body = lines[start:]
    keep = [k for k, line in enumerate(body) if line.strip() and not is_comment(line)]
    if not keep:
        raise plain_error
    notes = [(start + k + 1, comment_text(line)) for k, line in enumerate(body) if is_comment(line)]
    line_numbers = np.array([start + k + 1 for k in keep], dtype=int)
    if delimiter is not None and any('"' in body[k] for k in keep[:200]):  # quoted cells ("a, b")
        cells = list(_csv.reader((body[k] for k in keep), delimiter=delimiter))
    else:
        cells = [body[k].split(delimiter) for k in keep]
    whole = [c for c in cells if len(c) == len(names)]
    separated = _thousands_columns(whole, len(names))
    if separated:
        cells = [[c.replace(",", "") if j in separated else c for j, c in enumerate(row)] for row in cells]
        whole = [c for c in cells if len(c) == len(names)]
        metadata["thousands_separator"] = "comma (" + ", ".join(names[j] for j in separated) + ")"
    decimal = _quoted_decimal_commas(whole, len(names)) if delimiter == "," and not separated else []
    if decimal:  # a German spreadsheet saved as CSV quotes its "-0,16": decimal commas, read as points
        cells = [[c.replace(",", ".") if j in decimal else c for j, c in enumerate(row)] for row in cells]
        whole = [c for c in cells if len(c) == len(names)]
        metadata["decimal_separator"] = "comma (quoted cells: " + ", ".join(names[j] for j in decimal) + ")"
    glued = _units_in_cells(path, whole, names, units, metadata)
    if glued:  # "12.3uT", "25.1 °C": a logger that prints each value with its unit
        cells = [[_UNIT_CELL.sub(r"\1", c) if j in glued else c for j, c in enumerate(row)] for row in cells]
        whole = [c for c in cells if len(c) == len(names)]
    # A column is text when most of its cells are not numbers (a status field that is sometimes "1"); an all-empty
    # column (from a trailing delimiter) is text too and is left out. The recording's temperature is judged by its
    # filled cells (ten at least): a thermometer read once per ten lines had left its column text, its temperature
    # unused. (Blanks counted out for every column, a sparse mag_raw_x… triple had become the magnetometer and a
    # sparse GPS time a needed column: a review.)
    from .columns import find_temperature

    temperature = find_temperature(names, units)
    slow = names.index(temperature[0]) if temperature else None
    text = [j for j in range(len(names)) if whole and (
        _mostly_text([c[j] for c in whole if c[j].strip()], at_least=10) if j == slow
        else sum(_is_number(c[j]) for c in whole) < 0.5 * len(whole))]
    columns, text_notes = {}, []
    for j in text:
        values = [c[j].strip() if len(c) == len(names) else "" for c in cells]
        if names[j].strip().lower() == "position":  # positions named, not numbered (P01, "north up")
            columns[j], metadata["position_labels"] = _position_numbers(values)
            continue
        seconds, first = _timestamps(values)
        if seconds is None:
            shown = sorted({v for v in values if v})[:4]
            text_notes.append(f"{names[j]} (e.g. {', '.join(shown)}{_commas_unsettled(values)})" if shown
                              else f"{names[j]} (empty)")
            continue
        columns[j] = seconds
        units[names[j]] = "s"
        metadata[f"{names[j]}_start"] = first
    if text_notes:
        metadata["text_columns"] = "; ".join(text_notes)
    numeric = [j for j in range(len(names)) if j not in text]
    good, skipped, skipped_in = [], [], set()  # skipped_in: the column of each skipped line's problem (None: fields)
    # skipping, a number written as nan or inf is a bad line too (a sensor's failed read printed as a float)
    usable = _is_finite_number if bad_lines == "skip" else _is_number
    never_finite = {j for j in range(len(names)) if whole and not any(_is_finite_number(c[j]) for c in whole)}
    optional = _optional_columns(names, numeric, units)
    blanks = {}  # column index -> [its blank cells' lines] (read as NaN)
    for row, (c, line_no) in enumerate(zip(cells, line_numbers)):
        problem, where = None, None
        if len(c) != len(names):
            problem = (f"{len(c)} fields, the header has {len(names)} (truncated or garbled line?)")
        else:
            for j in optional:
                if not c[j].strip():
                    blanks.setdefault(j, []).append(int(line_no))
            bad = next((j for j in numeric if not (usable(c[j]) or (j in never_finite and _is_number(c[j]))
                                                   or (j in optional and not c[j].strip()))), None)
            stamp = next((j for j in columns if not np.isfinite(columns[j][row])), None)
            where = bad if bad is not None else stamp
            if bad is not None:
                problem = f"column {names[bad]!r}: {_not_a_number(c[bad])}"
            elif stamp is not None:
                what = ("empty" if not c[stamp].strip() else CUT_PROBLEM if CUT_SHORT in c[stamp]
                        else f"{c[stamp].strip()!r} is not a date/time")
                problem = f"column {names[stamp]!r}: {what}"
        if problem is None:
            good.append(row)
        elif bad_lines == "error":
            if not text and not glued:  # (the plain parser's error is of the cells before their units came off)
                raise ValueError(f"{plain_error}; {SKIP_HINT}") from None
            raise ValueError(f"{path}, line {line_no}: {problem}; {SKIP_HINT}")
        else:
            skipped.append(f"{line_no} ({problem})")
            skipped_in.add(where)
    if not good:
        raise ValueError(f"{path}: no readable data rows" + (f" (all {len(skipped)} lines bad)" if skipped else ""))
    # Most lines skipped: not a few garbled lines, the header is not the table's (a preamble line?) — unless every
    # skipped line has the header's fields and one column's cell is what is missing (a position column filled only
    # while the device is still: a twelve-position log with its moves between positions had been refused so)
    if len(skipped) > len(good) and not (len(skipped_in) == 1 and None not in skipped_in):
        raise ValueError(f"{path}: {len(skipped)} of {len(cells)} lines do not fit the header on line {start} "
                         f"({', '.join(names)}); skipping them would keep {len(good)}. Is a preamble above the "
                         "table? fluxcal.read_recording (and the command line) find the header after one")
    if skipped:
        metadata["skipped_lines"] = listing(skipped, len(cells))
    kept_lines = set(line_numbers[good].tolist())
    kept_blanks = {j: [n for n in b if n in kept_lines] for j, b in blanks.items()}
    said = [f"{names[j]}: {len(b)} (first on line {b[0]})" for j, b in kept_blanks.items() if b]
    if said:
        metadata["blank_cells"] = "; ".join(said) + " read as NaN"
    kept = [j for j in range(len(names)) if j in numeric or j in columns]
    if not any(j in numeric for j in kept):
        raise ValueError(f"{path}: no column of numbers (" + metadata.get("text_columns", "") + ")"
                         + (f"; is the delimiter {delimiter!r} right?" if delimiter else ""))
    data = np.empty((len(good), len(kept)))
    for out, j in enumerate(kept):
        data[:, out] = columns[j][good] if j in columns else [float(cells[r][j] if cells[r][j].strip() else "nan")
                                                              for r in good]
    return [names[j] for j in kept], data, line_numbers[good], notes


# A number with a unit after it in the same cell ("12.3uT", "-0.4 µT", "25.1°C", "9.81 m/s^2")
_UNIT_CELL = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([^\d\s.,+-][^\s]*)\s*$")
_ACCELERATION_UNITS = {"m/s2", "m/s^2", "m/s²", "mg", "g"}


def _units_in_cells(path, whole, names, units: dict, metadata: dict) -> list:
    """The columns whose every filled cell is a number followed by one and the same known unit ("12.3uT"): their
    indices; the unit goes into `units` (said in metadata "units_in_cells"). A unit in the header that differs
    (`mx [nT]` over cells in µT) is a ValueError naming both. Cells with units that differ down a column, or words
    that are not units, leave the column as it was (text)."""
    from .columns import _OTHER_UNITS, _UNIT_WORDS, unit_name

    found, said = [], []
    for j, name in enumerate(names):
        filled = [c[j].strip() for c in whole if c[j].strip()]
        if not filled or any(_is_number(c) for c in filled):
            continue
        matches = [_UNIT_CELL.match(c) for c in filled]
        written = {m.group(2) for m in matches if m}
        if not all(matches) or len(written) != 1:
            continue
        unit = written.pop()
        word = unit.lower().replace("\u03bc", "\u00b5")
        if word not in _UNIT_WORDS | _OTHER_UNITS | _ACCELERATION_UNITS:
            continue
        stated = units.get(name, "")
        if stated and unit_name(stated) != unit_name(unit):
            raise ValueError(f"{path}: column {name!r} is in {stated} by the header and its cells read {filled[0]!r} "
                             f"({unit}): which is it? Correct the header (or the logger's format)")
        units[name] = stated or unit
        found.append(j)
        said.append(f"{name}: {unit}")
    if said:
        metadata["units_in_cells"] = ", ".join(said) + " (written after each value; read as numbers in that unit)"
    return found


def _mostly_text(filled: list, at_least: int = 1) -> bool:
    """Whether a column's filled cells are mostly not numbers (or there are fewer than `at_least`)."""
    return sum(_is_number(c) for c in filled) < 0.5 * len(filled) if len(filled) >= at_least else True


def _optional_columns(names, numeric, units) -> list:
    """The numeric columns whose blank cells are read as NaN rather than bad lines: those neither the
    magnetometer's (by name) nor a time (a temperature the logger left out on some lines, as it writes 'nan'
    elsewhere; what needs that column refuses its NaN, naming it). None when no magnetometer is found by name
    (--columns will name it: no column is known not to be needed)."""
    from .columns import TIME_UNITS, TIME_WORDS, _named, find_magnetometer

    try:
        mag = find_magnetometer(names, units=units)
    except ValueError:  # several triples: one is picked later
        return []
    if mag is None:
        return []
    needed = set(mag) | {n for n, _ in _named(names, TIME_WORDS, TIME_UNITS)} | {"t"}
    # (a twelve-position log's empty position cell marks a move: a bad line, left out with --bad-lines skip)
    return [j for j in numeric if names[j] not in needed and names[j].strip().lower() != "position"]


_LABEL_NUMBER = re.compile(r"^(\D*?)(\d+)(\D*)$")


def _position_numbers(values) -> tuple:
    """A text position column as numbers (fluxcal positions averages and matches positions by number): the
    number in each name (P01 → 1) when every name has one, with the same text around it, none twice; else
    1, 2, … in order of first appearance. Returns (numbers, NaN for an empty cell; "name=number, …")."""
    labels = list(dict.fromkeys(v for v in values if v))
    parts = [_LABEL_NUMBER.match(v) for v in labels]
    if (parts and all(parts) and len({(p.group(1), p.group(3)) for p in parts}) == 1
            and len({int(p.group(2)) for p in parts}) == len(labels)):
        number = {v: float(int(p.group(2))) for v, p in zip(labels, parts)}
    else:
        number = {v: float(k + 1) for k, v in enumerate(labels)}
    return np.array([number.get(v, np.nan) for v in values]), ", ".join(f"{v}={number[v]:g}" for v in labels)


_STAMP = re.compile(r"\d{1,2}:\d{2}|\d{4}-\d{1,2}-\d{1,2}|\d{1,2}[/.]\d{1,2}[/.]\d{2,4}")
_DATE = re.compile(r"\d{4}-\d{1,2}-\d{1,2}|\d{1,2}[/.]\d{1,2}[/.]\d{2,4}")
_MINUTES_SECONDS = re.compile(r"\s*(\d+):(\d{2}(?:[.,]\d+)?)\s*")  # 00:30.0 or 12:00: mm:ss or hh:mm


def _minutes_seconds(values):
    """(seconds since the first, the first as written) of a column of mm:ss values (a logger's elapsed time,
    00:00.0 … 00:30.0) when at least 90 % of the values are two-part colon values and some have a fraction
    after the seconds or more than 23 before the colon (no time of day: pandas read them as hh:mm, 60× too
    long); else (None, None): 12:00, 12:01 stays a time of day."""
    parts = [_MINUTES_SECONDS.fullmatch(v) if v else None for v in values]
    found = [m for m in parts if m]
    if len(found) < 0.9 * len(values) or not any(re.search(r"[.,]", m.group(2)) or int(m.group(1)) > 23
                                                 for m in found):
        return None, None
    seconds = np.array([60.0 * int(m.group(1)) + float(m.group(2).replace(",", ".")) if m else np.nan
                        for m in parts])
    return seconds - seconds[np.isfinite(seconds)][0], found[0].group(0).strip()


def _timestamps(values):
    """(seconds since the first, first as ISO text) when at least 90 % of the values are dates/times
    (the rest, garbled or empty, become NaN and their lines bad lines), else (None, None). Only values
    that look like a clock time or a date are tried (not labels such as "T1" or "3-1"); offsets are
    taken to UTC; of month-first and day-first the reading that runs forward wins (day-first tried first
    for dotted dates, 01.03.2024: no locale writes them month-first); a time of day without a date is
    unwrapped across midnight. Elapsed minutes:seconds (00:30.0) are read as such (_minutes_seconds; the first
    as written)."""
    import warnings

    import pandas as pd

    present = [v for v in values if v]
    sample = present[:200]
    if not sample or sum(bool(_STAMP.search(v)) for v in sample) < 0.9 * len(sample):
        return None, None
    seconds, first = _minutes_seconds(values)
    if seconds is not None:
        return seconds, first
    dates = [m.group(0) for m in map(_DATE.search, sample) if m]
    dotted = bool(dates) and all("." in d for d in dates)  # 01.03.2024 (German, Russian …): the 1st of March
    orders = (("mixed", True), ("mixed", False)) if dotted else (("mixed", False), ("mixed", True))
    series = pd.Series(values).replace("", None)
    best = None
    for fmt, dayfirst in (("ISO8601", False),) + orders:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                if pd.to_datetime(pd.Series(sample), format=fmt, dayfirst=dayfirst, utc=True,
                                  errors="coerce").notna().mean() < 0.9:
                    continue  # decided on a sample: a whole column of non-dates is not parsed one by one
                stamps = pd.to_datetime(series, format=fmt, dayfirst=dayfirst, utc=True, errors="coerce")
        except (ValueError, TypeError, OverflowError):
            continue
        if stamps.notna().sum() < 0.9 * len(values):
            continue
        first = stamps[stamps.notna()].iloc[0]
        seconds = ((stamps - first).dt.total_seconds()).to_numpy(dtype=float)
        start = first.isoformat()
        if not any(_DATE.search(v) for v in sample):  # a time of day: add a day at each wrap past midnight
            steps = np.diff(np.nan_to_num(seconds, nan=0.0), prepend=0.0)
            seconds = seconds + 86400.0 * np.cumsum(steps < -43200.0)
            start = first.time().isoformat()  # not the date pandas fills in (the day it is read)
        backwards = int(np.sum(np.diff(seconds[np.isfinite(seconds)]) < 0))
        if best is None or backwards < best[0]:
            best = (backwards, seconds, start)
        if backwards == 0:
            break
    return (None, None) if best is None else best[1:]


# what a legacy 8-bit export (Windows-1252: "Bx [µT]", "T [°C]", a German "Zeit") holds besides ASCII
_LEGACY_TEXT = re.compile("[^\x00-\x7fµ°²³±·×äöüÄÖÜßéèêëàâçîïôùûñÑøØåÅæÆ€£§–—‘’“”«»]")
NOT_TEXT = "\ufffd"  # stands for bytes that are not text
# binary formats fluxcal reads, by file name: a file so named that is not one is not a text table either
BINARY_SUFFIXES = {".mat": "a MATLAB .mat", ".npz": "a NumPy .npz", ".npy": "a NumPy .npy", ".parquet": "a Parquet",
                   ".h5": "an HDF5", ".hdf5": "an HDF5", ".xlsx": "an Excel .xlsx", ".ulg": "a PX4 ULog",
                   ".bin": "an ArduPilot DataFlash .bin", ".bag": "a ROS bag", ".db3": "a ROS 2 bag",
                   ".mcap": "a ROS 2 bag", ".sqlite": "an SQLite", ".db": "an SQLite"}


def readable_file(path, what: str = "a recording file",
                  remedy: str = "record it to a file first (fluxcal record reads a serial port)") -> Path:
    """`path` as a Path; ValueError naming `what` it should be when it is a folder, or not a regular file: a
    named pipe or a device would block the reader until something writes to it (a missing file is left to
    the reader's message)."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{path}: a folder, not {what}")
    if path.exists() and not path.is_file():
        raise ValueError(f"{path}: not a regular file (a named pipe, socket or device), not {what}"
                         + (f"; {remedy}" if remedy else ""))
    return path


def read_text(path) -> str:
    """The file's text: UTF-8 (a BOM dropped), UTF-16 with its BOM (a PowerShell redirect), or Windows-1252
    when that reads every byte that is not UTF-8 as ordinary text (µ, °, umlauts: a legacy Windows export).
    A few bytes that are none of these (garbage from a serial line, NULs of a board's reset) become U+FFFD, so
    that the parse names each line holding them (and bad_lines="skip" can leave it out); more than 5 % of
    lines with such bytes, or NULs among more than 5 % of bytes not text, is an error naming the first one's
    line and column (a binary file)."""
    path = readable_file(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ValueError(f"{path}: cannot read ({exc.strerror or exc})") from None
    if raw.startswith(b"\x1f\x8b"):  # a gzip-compressed log (log.csv.gz, as loggers rotate them): its text
        try:
            raw = gzip.decompress(raw)
        except (OSError, EOFError, zlib.error) as exc:
            raise ValueError(f"{path}: gzip-compressed, but cannot be decompressed ({exc}): cut short while copied?"
                             ) from None
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        try:
            return raw.decode("utf-16")
        except UnicodeDecodeError:
            raise ValueError(f"{path}: starts with a UTF-16 byte-order mark but is not UTF-16 text") from None
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        first = exc.start
    try:
        legacy = raw.decode("cp1252")
        if not _LEGACY_TEXT.search(legacy):
            return legacy
    except UnicodeDecodeError:
        pass
    text = raw.decode("utf-8-sig", errors="replace").replace("\x00", NOT_TEXT)
    lines = text.splitlines()
    # NULs are a binary file's, unless they are a few bytes among text (a board's reset on a serial line)
    nuls = b"\x00" in raw and text.count(NOT_TEXT) > 0.05 * len(raw)
    if nuls or sum(NOT_TEXT in line for line in lines) > max(1.0, 0.05 * len(lines)):
        named = BINARY_SUFFIXES.get(path.suffix.lower())
        if named and b"\n" not in raw[:first]:  # named as a format whose header sniff() did not find, and not
            # text from its first line: no table's line and column would help
            raise ValueError(f"{path}: named as {named} file, but it does not start as one (nor is it text): "
                             "damaged, or another file renamed?")
        line = raw.count(b"\n", 0, first) + 1
        column = first - (raw.rfind(b"\n", 0, first) + 1) + 1
        raise ValueError(f"{path}, line {line}, column {column} (character): byte 0x{raw[first]:02x} is not "
                         "text (UTF-8); a binary file, or garbage from a serial line?")
    return text


def read_lines(path) -> list:
    """The file's lines (read_text), its last line marked with CUT_SHORT when the file ends in the middle
    of it: every line reader then names that line as bad instead of reading 26.3 for the 26.345 it was
    (a log copied while the logger was still writing, or the power cut)."""
    text = read_text(path)
    lines = text.splitlines()
    if lines and not text.endswith(("\n", "\r")) and _cut_short(lines):
        lines[-1] += CUT_SHORT
    return lines


CUT_SHORT = "\ue000"  # marks a last line the file ends in the middle of (read_lines; a private-use character)
CUT_PROBLEM = ("the file ends in the middle of this line (no newline after it, and less of it than of the lines "
               "above: copied while the logger was still writing?)")
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


_PARTIAL_NUMBER_END = re.compile(r"(?:(?<=\d)\.|(?<=[\d.])[eE][-+]?|[-+])$")


def _skeleton(line: str) -> str:
    return " ".join(_NUMBER.sub("#", line).split())


def _decimals(token: str) -> int:
    mantissa = re.split("[eE]", token)[0]
    return len(mantissa.split(".")[1]) if "." in mantissa else 0


def _cut_short(lines) -> bool:
    """Whether the last line (with no newline after it) stops short of the lines above: fewer values than
    they all have (a prefix of their layout), its last number ending in a sign, point or exponent mark, or
    with fewer decimals than that number has on each of at least 100 lines of the layout (a fixed format:
    %g and a spreadsheet's General drop trailing zeros, and 20 lines were not enough to tell), or cut in its
    whole part (_cut_in_whole_part: 32.969 -> 3, 1234 -> 12). Judged only when the 20 data lines above share
    one layout."""
    above = [line.rstrip() for line in lines[-21:-1] if line.strip() and not is_comment(line)]
    last = lines[-1].rstrip()
    if len(above) < 5 or not last.strip() or is_comment(last):
        return False
    layouts = {_skeleton(line) for line in above}
    if len(layouts) != 1:
        return False
    layout = layouts.pop()
    partial = _PARTIAL_NUMBER_END.search(last)  # 26. or 1.5e- or a lone sign: a number the line stops in
    core = last[:partial.start()] if partial else last
    if not _NUMBER.search(core):
        return False
    if _skeleton(core) != layout:
        return layout.startswith(_skeleton(core))
    if core != last and not any(line.endswith(last[len(core):]) for line in above):
        return True
    token = _NUMBER.findall(core)[-1]
    if _cut_in_whole_part(token, [_NUMBER.findall(line)[-1] for line in above]):
        return True
    same = [line.rstrip() for line in lines[:-1] if line.strip() and _skeleton(line.rstrip()) == layout]
    decimals = {_decimals(_NUMBER.findall(line)[-1]) for line in same}
    return len(same) >= 100 and len(decimals) == 1 and _decimals(token) < decimals.pop()


def _cut_in_whole_part(token: str, column) -> bool:
    """Whether the last line's last number, `token`, reads as a cut one beside the same column's numbers on the
    lines above (at least 10): shorter than each of them and under half the smallest in size (32.969 cut to 3
    or to 32 is 10 or 1.03 times smaller: only the first is judged; a column that comes near zero never is)."""
    if len(column) < 10:
        return False
    sizes = [abs(float(t)) for t in column]
    return len(token) < min(map(len, column)) and 2 * abs(float(token)) < min(sizes)


def _not_a_number(cell: str) -> str:
    cell = cell.strip()
    if not cell:
        return "empty"
    if CUT_SHORT in cell:
        return f"{cell.replace(CUT_SHORT, '')!r} is cut short: {CUT_PROBLEM}"
    if _is_number(cell):
        return f"{cell!r} is not finite"
    return f"{cell!r} is not a number" + (" (bytes that are not text: garbage from a serial line?)"
                                          if NOT_TEXT in cell else "")


def _trailing_delimiters(lines, start: int, names, delimiter):
    """The lines with a delimiter that ends a data row dropped when the header has no name for the empty field
    after it: Arduino sketches print `x,y,z,` after each value (on every line, or on some when one branch
    prints it), and the header line was written once, by hand."""
    if not delimiter or not delimiter.strip():
        return lines
    return lines[:start] + [_without_trailing_delimiter(line, len(names), delimiter) for line in lines[start:]]


def _without_trailing_delimiter(line: str, width: int, delimiter: str) -> str:
    """`line` without its last delimiter when that leaves `width` fields and only an empty one after it."""
    cells = line.split(delimiter)
    if len(cells) != width + 1 or cells[-1].strip() or is_comment(line):
        return line
    return line.rstrip()[:-len(delimiter)]


def parse_rows(path, lines, start: int, names, delimiter, expected: str = "the header"):
    """Parse lines[start:] as rows of len(names) numbers; blank lines are skipped and "#" lines returned
    as notes. Returns (data N×len(names), the 1-based file line of each row, [(line, note)]); errors
    name line and column (`expected`: where the column names came from, for those messages)."""
    body = lines[start:]
    keep = [k for k, line in enumerate(body) if line.strip() and not is_comment(line)]
    notes = [(start + k + 1, comment_text(line)) for k, line in enumerate(body) if is_comment(line)]
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


_DECIMAL_COMMA = re.compile(r'^\s*"?[-+]?\d*,\d+([eE][-+]?\d+)?"?\s*$')  # quoted too ("100,25")
_THOUSANDS = re.compile(r"^[-+]?\d+,\d{3}$")  # 1,234: a thousands separator, or a decimal comma


def _repeated_headers(path, lines, header: int, names, delimiter, unit_map: dict, metadata: dict):
    """The lines with the header written again among the data (a logger restarted, two logs joined with cat)
    blanked and counted in metadata["repeated_header"] when it names the same columns in the same order and
    units; a header that orders them otherwise or gives one another unit is an error naming both lines, in
    any bad-lines mode: skipping it would read the rows below it into the wrong columns."""
    from .columns import unit_name

    repeats = []
    # the units the header line itself prints (not a '# units:' comment's): a repeat without them is another log
    printed = {n: u for n, u in map(_split_header, _header_cells(lines[header].strip(), delimiter)) if u}
    for j in range(header + 1, len(lines)):
        text = lines[j].lstrip()
        if not (text[:1].isalpha() or text[:1] in "\"'") or is_comment(text) or not all(n in text for n in names):
            continue  # data rows start with a digit, sign or point, or lack the names (the test stays cheap)
        cells = [_split_header(c) for c in _header_cells(lines[j].strip(), delimiter)]
        if sorted(n for n, _ in cells) != sorted(names):
            continue
        order = [n for n, _ in cells] != list(names)
        units = [n for n, u in cells if u and unit_map.get(n) and unit_name(u) != unit_name(unit_map[n])]
        # `t,mx,my,mz` after `t,mx [uT],…`: its rows had been read in µT, silently (a blind check's were in nT)
        dropped = [n for n, u in cells if not u and printed.get(n)]
        if order or units or dropped:
            change = ("the columns in another order: " + ",".join(n for n, _ in cells) if order else
                      "; ".join(f"{n} in {dict(cells)[n]}, not {unit_map[n]}" for n in units) if units else
                      f"no units for {', '.join(dropped)}: its rows' units are not said")
            raise ValueError(f"{path}, line {j + 1}: the header again, with {change} (line {header + 1}'s header: "
                             f"{lines[header].strip()!r}): two logs joined? Split the file at line {j + 1} and read "
                             "each part")
        repeats.append(j)
    if not repeats:
        return lines
    metadata["repeated_header"] = "line " + ", ".join(str(j + 1) for j in repeats) + " (the same columns and units)"
    repeats = set(repeats)
    return [("" if j in repeats else line) for j, line in enumerate(lines)]


def is_units_row(cells) -> bool:
    """Whether a row's cells (quotes stripped) are a row of units under the column names: no number, and at least
    half of the filled ones ("-" fills a column without one) units — Campbell's TOA5 writes TS, RN beside nT, and
    'Deg C'. The one rule for a table's head (fluxcal.io.formats._title_lines) and for its units (_units_row)."""
    from .columns import NO_UNIT, is_unit

    filled = [c for c in cells if c and c.strip("[]()").strip().lower() not in NO_UNIT]
    return bool(filled) and not any(_is_number(c) for c in filled) and sum(map(is_unit, filled)) >= 0.5 * len(filled)


def _units_row(lines, start: int, names, delimiter, unit_map: dict):
    """The lines with a row of units under the header (`s,uT,uT,uT` or `(s);(µT);…`, as data-logger and
    LabVIEW exports write) blanked, its units recorded for columns that have none; else the lines."""
    from .columns import NO_UNIT, is_unit

    j = start
    while j < len(lines) and (not lines[j].strip() or is_comment(lines[j])):
        j += 1
    if j == len(lines):
        return lines
    cells = [c.strip().strip('"') for c in lines[j].split(delimiter)]
    if len(cells) != len(names) or not is_units_row(cells):
        return lines
    filled = [c for c in cells if c and c.strip("[]()").strip().lower() not in NO_UNIT]
    for name, cell in zip(names, cells):
        unit = cell.strip("[]()").strip()
        unit = unit.replace(" ", "") if is_unit(unit.replace(" ", "")) else unit  # TOA5's 'Deg C'
        if cell in filled and (is_unit(unit) or sum(map(is_unit, filled)) == len(filled)):  # not TOA5's TS, RN
            unit_map.setdefault(name, unit)
    after = [c.strip().strip('"') for c in lines[j + 1].split(delimiter)] if j + 1 < len(lines) else []
    cut = 2 if len(after) == len(names) and is_processing_row(after) else 1  # TOA5's Smp,Avg row under its units
    return lines[:j] + [""] * cut + lines[j + cut:]  # blank: later lines keep their numbers


# a Campbell logger's (TOA5) row under the units: how each column was processed (sample, average, maximum, …)
PROCESSING = {"smp", "avg", "max", "min", "tot", "std", "wvc", "mom", "hst", "tmx", "tmn", "cov", "med", "rms"}


def is_processing_row(cells) -> bool:
    return any(cells) and all(not c or c.lower() in PROCESSING for c in cells)


def decimal_points(lines, start: int, delimiter, separated: dict | None = None, path=None):
    """(lines, converted) with the data lines' decimal commas from `start` on made points when the table writes
    its numbers so (a European spreadsheet export, 1,25;0,5; see _decimal_comma_columns; comment lines stay
    as written) and thousands grouped with points before them dropped (45.199,6), else (lines, []); `converted`
    lists the columns whose thousands are grouped so, or is [-1] when none is. When some columns hold decimal
    points (an ISO time 12:00:01.5, a column a program wrote in its own format), only the decimal-comma columns
    are converted. When the commas group thousands instead (48,123 beside 523, see _comma_thousands_columns),
    or points do (48.123 beside 523, see _point_thousands_whole_columns), they are dropped, those columns are
    added to `separated` (when given) with their mark, and converted is [] unless other columns hold decimal
    commas (0,1;48.123: the points group thousands, the commas are decimal). With `path`, commas that numbers of
    the table settle both ways are an error naming `path` and lines, and commas that none settles are read as
    decimal commas with a warning naming a line (see _comma_thousands_columns); without it (a first look at a
    table) they read as decimal commas."""
    from .columns import comma_kind

    if delimiter not in (";", "\t"):
        return lines, []
    given = COMMA_GIVEN.get()
    if given:
        return _commas_as_given(lines, start, delimiter, given)
    rows = data_cells(lines[start:start + 400], delimiter)
    points = _point_thousands_whole_columns(rows)
    if points:
        if separated is not None:
            separated.update(dict.fromkeys(points, "."))
        lines = _ungrouped(lines, start, delimiter, points, ".", lambda cell: bool(_POINT_THOUSAND.match(cell)))
        rows = data_cells(lines[start:start + 400], delimiter)  # the decimal commas beside them are read next
    columns, grouped = _decimal_comma_columns(rows), _point_thousands_columns(rows)
    if not columns and not grouped:
        return lines, []
    thousands = _comma_thousands_columns(rows, columns, lines, start, delimiter, path)
    if thousands:
        if separated is not None:
            separated.update(dict.fromkeys(thousands, ","))
        # only 1,234 and 1,234,567: another comma (1,2) is left for the parse to name
        return _ungrouped(lines, start, delimiter, thousands, ",",
                          lambda cell: comma_kind(cell.strip().strip('"')) in ("ambiguous", "several")), []
    if not any(_decimal_point(cell) for row in rows for cell in row):  # every number in one form, so far
        columns = sorted(set(columns) | set(range(max(map(len, rows)))))

    def convert(line):
        cells = line.split(delimiter)
        for j in sorted(set(columns) | set(grouped)):
            if j < len(cells):  # 45.199,6 (also past the lines judged): the points group thousands
                cells[j] = (cells[j].replace(".", "") if _POINT_GROUPS.match(cells[j]) else cells[j]).replace(",", ".")
        return delimiter.join(cells)

    return lines[:start] + [line if is_comment(line) else convert(line) for line in lines[start:]], grouped or [-1]


# what the user said a comma between digits is ("decimal" or "thousands"; read_recording's decimal=): it settles
# a ';' or tab table's numbers where the values cannot (1,234 beside 0.5)
COMMA_GIVEN = contextvars.ContextVar("COMMA_GIVEN", default=None)


def _commas_as_given(lines, start: int, delimiter, given: str):
    """decimal_points when the user said what a comma is: "decimal" reads 1,5 as 1.5 and drops the points that
    group thousands before it (45.199,6); "thousands" drops the commas of 1,234 and 1,234,567."""
    from .columns import comma_kind

    def convert(cell):
        if given == "thousands":
            return cell.replace(",", "") if comma_kind(cell.strip().strip('"')) in ("ambiguous", "several") else cell
        return (cell.replace(".", "") if _POINT_GROUPS.match(cell) else cell).replace(",", ".")

    converted = [line if is_comment(line) else delimiter.join(map(convert, line.split(delimiter)))
                 for line in lines[start:]]
    return lines[:start] + converted, ([-1] if given == "decimal" else [])


def _ungrouped(lines, start: int, delimiter, columns, mark: str, grouped) -> list:
    """The lines with the thousands separator `mark` dropped from the cells of `columns` that `grouped` says
    are grouped numbers, from `start` on (comment lines stay as written)."""
    def ungroup(line):
        cells = line.split(delimiter)
        for j in columns:
            if j < len(cells) and grouped(cells[j]):
                cells[j] = cells[j].replace(mark, "")
        return delimiter.join(cells)

    return lines[:start] + [line if is_comment(line) else ungroup(line) for line in lines[start:]]


_DOTTED_DATE = re.compile(r"\b\d{1,2}\.\d{1,2}\.\d{2,4}\b")  # 14.03.2026: a German date, not a decimal point


def _decimal_point(cell: str) -> bool:
    """Whether a cell writes a point other than a dotted date's (a German export's Zeit column, 14.03.2026
    09:26:53, says nothing of how the table writes its numbers)."""
    return "." in _DOTTED_DATE.sub("", cell)


def data_cells(lines, delimiter) -> list:
    """The cells of the data lines among `lines` (blank and comment lines left out)."""
    return [line.split(delimiter) for line in lines if line.strip() and not is_comment(line)]


def _decimal_comma_columns(rows) -> list:
    """The columns of a table delimited by ';' or tab (`rows`: the first data lines' cells) that write their
    numbers with decimal commas: some cell reads as one (-0,123) and none holds a decimal point. When other
    columns do use decimal points, a column whose commas all have three digits after them (1,234) could be
    thousands separators and is not taken (unless one of them cannot be: 0,234, -0,5): it is read as text and
    named as such."""
    from .columns import comma_kind

    points = any(_decimal_point(c) for row in rows for c in row)
    found = []
    for j in range(max(map(len, rows), default=0)):
        cells = [row[j] for row in rows if j < len(row)]
        commas = [c.strip().strip('"') for c in cells if _DECIMAL_COMMA.match(c)]
        if not commas or any("." in c for c in cells):
            continue
        if points and all(comma_kind(c) == "ambiguous" for c in commas):
            continue  # 1,234 beside 0.5: a thousands separator as likely as a decimal comma (0,234 is none)
        found.append(j)
    return found


def _comma_thousands_columns(rows, columns, lines=(), start: int = 0, delimiter=None, path=None) -> list:
    """The decimal-comma `columns` of a ';' or tab table (`rows`: the first data lines' cells) when their commas
    are thousands separators instead (a spreadsheet's #,##0 saved as text: 48,123 beside 523), else []. When no
    cell holds a point, the numbers of those columns in all data lines (`lines` from `start`) are read for what
    settles it, column by column (see _comma_evidence): a decimal comma that cannot group thousands (0,123 12,34)
    or a whole number of four digits (#,##0 writes 1,234) says decimal; 1,234,567, or a whole number beside a
    12,340 (a spreadsheet writing 812 as a whole number trims 12.340 to 12,34) says thousands. Both in one table
    is an error; neither: thousands when the whole numbers among them all have three digits (100–999: the columns
    run on across 1000, said by a warning), else decimal commas, said by a warning naming a line and --decimal (a
    blind check's 12,345 beside a -95 had been read as 12.345 nT without a word) when `path` is given."""
    if not columns or any(_decimal_point(c) for row in rows for c in row):
        return []
    decimal, thousands, first, wholes = None, None, None, []
    body = [(start + k + 1, line.split(delimiter)) for k, line in enumerate(lines[start:])
            if line.strip() and not is_comment(line)] if path is not None else \
        [(None, row) for row in rows]
    for j in columns:
        cells = [(n, row[j].strip().strip('"')) for n, row in body if j < len(row) and row[j].strip()]
        said, ambiguous, whole = _comma_evidence(cells)
        first = first or ambiguous
        wholes += whole
        if said and said[0] == "decimal":
            decimal = decimal or said[1:]
        elif said:
            thousands = thousands or said[1:]
    if decimal is None:  # a clock's seconds with a decimal comma (Excel's German 09:26:53,000): the table's locale
        clocks = ((n, _CLOCK_COMMA.search(delimiter.join(row))) for n, row in body) if delimiter else ()
        decimal = next(((n, m.group()) for n, m in clocks if m), None)
    if decimal and thousands and path is not None:
        raise ValueError(f"{path}: line {decimal[0]}'s {decimal[1]!r} has a decimal comma, line {thousands[0]}'s "
                         f"{thousands[1]!r} {thousands[2]}: the table's commas read both ways" + COMMAS_HINT)
    if decimal or thousands:
        return [] if decimal else list(columns)
    if wholes and all(re.fullmatch(r"[-+]?[1-9]\d{2}", c) for c in wholes):
        return list(columns)
    if path is not None and first is not None:  # decimal commas, as a ';' or tab table's locale writes them; said
        import warnings  # (refused, a review found ordinary European logs to 3 decimals with a counter refused)

        n, cell = first
        warnings.warn(f"{path}, line {n}: {cell!r} read as {cell.replace(',', '.')} (a decimal comma, as a ';' or tab "
                      f"table writes them); it would be {cell.replace(',', '')} with a thousands separator, and no "
                      "number in the table says which (0,5 or 12,34 would be decimal commas, 1,234,567 thousands "
                      "separators)" + COMMAS_HINT, stacklevel=4)
    return []


_CLOCK_COMMA = re.compile(r"\d:\d{2},\d+")  # 09:26:53,000: a decimal comma, never a thousands separator


def _comma_evidence(cells):
    """(what settles a column's commas, its first ambiguous comma, its whole numbers) from its (line, cell)s:
    ("decimal", line, cell) for a comma no thousands separator makes (0,123 12,34) or a whole number of four
    digits or more; ("thousands", line, cell, why) for 1,234,567 or a whole number beside a 12,340 (a fixed
    three decimals never writes a whole number, and a trimmed one no 0 at the end); else None."""
    from .columns import comma_kind

    said, ambiguous, zero, whole = None, None, None, []
    for n, cell in cells:
        kind = comma_kind(cell)
        if kind == "decimal" or (not kind and re.fullmatch(r"[-+]?\d{4,}", cell)):
            return ("decimal", n, cell), ambiguous, whole
        if kind == "several":
            said = said or ("thousands", n, cell, "has thousands separators")
        elif kind == "ambiguous":
            ambiguous = ambiguous or (n, cell)
            zero = zero or (cell.endswith("0") and (n, cell))
        elif not kind and re.fullmatch(r"[-+]?\d{1,3}", cell):
            whole.append(cell)
    if said is None and zero and whole:
        said = ("thousands", *zero, f"has a thousands separator, as the whole number {whole[0]} in its column says "
                                    "(with decimal commas, a table writing whole numbers would write it "
                                    f"{zero[1].rstrip('0').rstrip(',')})")
    return said, ambiguous, whole


_POINT_THOUSAND = re.compile(r'^\s*"?[-+]?[1-9]\d{0,2}\.\d{3}"?\s*$')  # 48.123: 48123 (German #.##0) or 48.123
_WHOLE = re.compile(r'^\s*"?([-+]?\d+)"?\s*$')


def _point_thousands_whole_columns(rows) -> list:
    """The columns of a ';' or tab table (`rows`: the first data lines' cells) whose points group the thousands
    of whole numbers (a German spreadsheet's #.##0 saved as text: 48.123 beside 523), else []; as
    _comma_thousands_columns does for commas. A column is a candidate when its cells are whole numbers or one to
    three digits, a point and three digits (1.234), some of the latter. The candidates are taken when their whole
    numbers (|n| < 1000 written without a point) say so, one of:
    - the table writes decimal commas in other columns (0,1: its points are no decimal points) and some whole
      number of one to three digits stands among the candidates;
    - each candidate holds ten or more 1.234 cells and three or more whole numbers, two thirds of those of three
      digits (a spread over 0–999, as the values below 1000 of a column running to tens of thousands are;
      µT to three decimals prints 45.000, and a %g-printed one has 20.5 beside its few whole numbers);
    - (a few lines) the whole numbers all have three digits (100–999: the columns run on across 1000), and
      each column holding one runs more smoothly read so (-1.204 then -987: -1204, -987).
    µT to three decimals (48.123, 47.998) stays decimal beside 48.5, a 0 or a 45 in a short table without
    commas; so do seconds 100.980 then 101."""
    by_column = {}
    for j in range(max(map(len, rows), default=0)):
        cells = [row[j] for row in rows if j < len(row) and row[j].strip()]
        if any("." in c for c in cells) and all(_POINT_THOUSAND.match(c) or _WHOLE.match(c) for c in cells):
            by_column[j] = cells
    columns = list(by_column)
    whole = {j: [m.group(1).lstrip("+-") for m in map(_WHOLE.match, cells) if m] for j, cells in by_column.items()}
    wholes = [w for ws in whole.values() for w in ws]
    if not wholes or any(len(w) > 3 or (len(w) > 1 and w[0] == "0") for w in wholes):
        return []  # 1234 has no separator; 0123 is no number a spreadsheet writes
    decimal_commas = any(_DECIMAL_COMMA.match(c) for row in rows for c in row)
    if decimal_commas:
        return columns
    if any("," in c for row in rows for c in row):
        return []
    if all(sum("." in c for c in by_column[j]) >= 10 and len(whole[j]) >= 3
           and sum(len(w) == 3 for w in whole[j]) >= 2 * len(whole[j]) / 3 for j in columns):
        return columns
    if not all(len(w) == 3 for w in wholes):
        return []
    if not all(_smoother_as_thousands(by_column[j]) for j in columns if whole[j]):
        return []
    return columns


def _smoother_as_thousands(cells) -> bool:
    """Whether a column of 1.234-like and whole cells varies less from row to row with its points dropped."""
    as_decimal = np.array([float(c.strip().strip('"')) for c in cells])
    as_whole = np.array([float(c.strip().strip('"').replace(".", "")) for c in cells])
    return bool(np.abs(np.diff(as_whole)).sum() < np.abs(np.diff(as_decimal)).sum())


# 45.199,6 or 45.199 (European grouping; a first group of 0 is no group: 0.123), quoted or not
_POINT_GROUPS = re.compile(r'^\s*"?[-+]?[1-9]\d{0,2}(?:\.\d{3})+(?:,\d+)?"?\s*$')
_PLAIN_OR_COMMA = re.compile(r'^\s*"?[-+]?\d+(?:,\d+)?"?\s*$')


def _point_thousands_columns(rows) -> list:
    """The columns of a ';' or tab table (`rows`: the first data lines' cells) that group thousands with points
    before a decimal comma (a European spreadsheet's number format: 45.199,6): some cell has both, and every cell
    is such a number, a plain decimal-comma number or an integer. A point alone (45.199) is not taken for a group
    without a comma beside it in the column."""
    found = []
    for j in range(max(map(len, rows), default=0)):
        cells = [row[j] for row in rows if j < len(row) and row[j].strip()]
        if any(_POINT_GROUPS.match(c) and "," in c for c in cells) and \
                all(_POINT_GROUPS.match(c) or _PLAIN_OR_COMMA.match(c) for c in cells):
            found.append(j)
    return found


def _thousands_columns(rows, width: int) -> list:
    """The columns whose numbers group their thousands with commas (a spreadsheet's number format: "48,123.4"
    quoted in a CSV, or 48,123.4 in a ';' or tab table), as the column's own values show it: some value
    has thousands groups beside a decimal point, or several groups (1,234,567), or the column's other values
    have decimal points; and none has a comma that only a decimal comma makes (12,34). A column whose only
    commas are 1,234 among integers is left as text (1.234 or 1234: not guessed)."""
    from .columns import comma_kind

    found = []
    for j in range(width):
        kinds = {comma_kind(row[j]) for row in rows}
        points = any("." in row[j] for row in rows if not comma_kind(row[j]))
        if "invalid" in kinds or "decimal" in kinds or kinds <= {""}:
            continue
        if kinds & {"thousands", "several"} or ("ambiguous" in kinds and points):
            found.append(j)
    return found


def _quoted_decimal_commas(rows, width: int) -> list:
    """The columns of a comma-delimited table's quoted cells (`rows`: the lines of the header's width) that write
    decimal commas, "-0,16": every filled cell a number with a comma for its point, when some cell of the table has
    a comma only a decimal comma makes (0,5 12,34) and none one only thousands separators make (1,234,567
    1,234.5); a table of 1,234 alone is not guessed (see _commas_unsettled)."""
    from .columns import comma_kind

    kinds = {comma_kind(row[j]) for row in rows for j in range(width)}
    if "decimal" not in kinds or kinds & {"several", "thousands", "invalid"}:
        return []
    return [j for j in range(width) if any("," in row[j] for row in rows)
            and all(_is_number(row[j].replace(",", ".")) for row in rows if row[j].strip())]


def _commas_unsettled(values) -> str:
    """A note for a column left as text whose numbers all read with a comma that is a thousands separator or
    a decimal comma (1,234), and no value says which."""
    from .columns import comma_kind

    kinds = {comma_kind(v) for v in values if v}
    if "ambiguous" in kinds and kinds <= {"ambiguous", ""} and all(_is_number(v.replace(",", "")) for v in values if v):
        return ": thousands separators or decimal commas? no value says, not guessed"
    return ""


def _is_number(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


def _is_finite_number(text: str) -> bool:
    try:
        return bool(np.isfinite(float(text)))
    except ValueError:
        return False


def _raise_parse_error(path, rows, line_numbers, names, delimiter, expected="the header"):
    """Find the first bad cell the slow way, so the message names line and column — and a nan or inf written out
    before it, in a column with finite numbers (a failed read printed as a float: a blind check's 'nan' on line 103
    had gone unnamed beside the empty cell on line 104), after it: the nan alone is read (as NaN), the bad cell is
    what stops the read (a later blind check: the nan named alone, as if it were the problem)."""
    unfinite = {}  # column index -> (line, cell) of its first number that is not finite

    def stop(message: str):
        earlier = [f"line {line}, column {names[j]!r}: {_not_a_number(cell)}"
                   for line, j, cell in sorted((line, j, cell) for j, (line, cell) in unfinite.items())
                   if any(_is_finite_number(r.split(delimiter)[j]) for r in rows if len(r.split(delimiter)) > j)]
        raise ValueError(message + (f" (before it, {earlier[0]}: read as NaN, a failed reading?)" if earlier else ""))

    for row, line_no in zip(rows, line_numbers):
        cells = row.split(delimiter)
        if len(cells) < len(names):
            stop(f"{path}, line {line_no}: {len(cells)} fields, {expected} has {len(names)}: column "
                 f"{names[len(cells)]!r} (field {len(cells) + 1}) is missing (truncated or garbled line?)")
        if len(cells) > len(names):
            stop(f"{path}, line {line_no}: {len(cells)} fields, {expected} has {len(names)}: field "
                 f"{len(names) + 1} ({cells[len(names)].strip()!r}) has no column (garbled line?)")
        for j, (cell, name) in enumerate(zip(cells, names)):
            if not _is_number(cell):
                stop(f"{path}, line {line_no}, column {name!r}: {_not_a_number(cell)}")
            if j not in unfinite and not _is_finite_number(cell):
                unfinite[j] = (line_no, cell)
    raise ValueError(f"{path}: could not parse the data rows")


# The extensions of the other formats fluxcal writes (fluxcal.io.write_recording), and of binary formats it
# reads only: CSV text under one of these names would mislead whoever opens it in MATLAB, Excel or h5py.
OTHER_WRITERS = (".npz", ".mat", ".parquet", ".pq", ".json")
BINARY_NAMES = OTHER_WRITERS + (".npy", ".xlsx", ".xlsm", ".xls", ".h5", ".hdf5", ".bin", ".ulg", ".bag", ".db3",
                                ".mcap", ".db", ".sqlite", ".sqlite3")


def _writable(path, columns: dict, metadata: dict) -> None:
    """ValueError naming what a CSV cannot hold so that read_csv gets it back: no columns, a column name with
    the delimiter or a line break, a metadata key or value with a line break (the file was written, and
    reading it failed on a line that did not say why); and a name of another format."""
    suffix = Path(path).suffix.lower()
    if suffix in BINARY_NAMES:
        also = f", or write {suffix} with fluxcal.write_recording" if suffix in OTHER_WRITERS else ""
        raise ValueError(f"{path}: CSV text under a {suffix} name; name it .csv{also}")
    if not columns:
        raise ValueError(f"{path}: no columns to write")
    for name in columns:
        if not name or any(c in name for c in ",\r\n") or name != name.strip() or name.startswith("#"):
            raise ValueError(f"{path}: column name {name!r} cannot be a CSV header cell (empty, holds a comma or a "
                             "line break, has outer spaces, or starts with '#', a comment)")
    for key, value in metadata.items():
        if any(c in f"{key}{value}" for c in "\r\n") or ":" in str(key):
            raise ValueError(f"{path}: metadata {key!r} cannot be a '# key: value' comment line (a line break, or "
                             "a ':' in the key)")


def write_csv(path, recording_or_columns, units=None, metadata=None, fmt: str | None = None,
              delimiter: str = ",") -> Path:
    """Write a recording (or a dict of columns) with its units and metadata as comment lines.
    Numbers are written in the shortest form that reads back to the same double (nothing lost), unless
    `fmt` (a printf format such as "%.10g") asks for fewer digits. `delimiter`: "," or "\t" (TSV)."""
    if delimiter not in (",", "\t"):
        raise ValueError(f"delimiter: {delimiter!r} is not ',' or a tab")
    path = Path(path)
    if isinstance(recording_or_columns, Recording):
        rec = recording_or_columns
        columns, units, metadata = rec.columns, {**rec.units, **(units or {})}, {**rec.metadata, **(metadata or {})}
    else:  # through Recording: the same checks of each column
        columns = Recording(columns=dict(recording_or_columns), source=str(path)).columns
        units, metadata = dict(units or {}), dict(metadata or {})
    _writable(path, columns, metadata)
    names = list(columns)
    data = np.column_stack([columns[n] for n in names])
    head = ["# fluxcal recording"]
    if units:
        head.append("# units: " + ", ".join(f"{n}={u}" for n, u in units.items() if n in columns and u))
    head += [f"# {k}: {v}" for k, v in metadata.items()]
    with path.open("w") as f:
        f.write("\n".join(head) + "\n" + delimiter.join(names) + "\n")
        if fmt is not None:
            np.savetxt(f, data, delimiter=delimiter, fmt=fmt)
        else:  # repr of a Python float is the shortest string that round-trips
            f.writelines(delimiter.join(map(repr, row)) + "\n" for row in data.tolist())
    return path
