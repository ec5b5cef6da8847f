"""Labelled text logs: a serial monitor's capture of a device that prints its readings with names.

    Mag X: -13.62  Y: 27.37  Z: -17.02 uT              (Adafruit sensor examples)
    X: -13.62 	Y: 27.37 	Z: -17.02 uTesla
    mx=-13.62, my=27.37, mz=-17.02
    12:30:01.123 -> Mag X: -13.62 Y: 27.37 Z: -17.02   (Arduino IDE serial monitor, timestamps on)
    Accel X: 0.12 Y: -0.03 Z: 9.81 m/s^2               (one line per sensor, repeated every cycle)
    Mag X: -13.62 Y: 27.37 Z: -17.02 uT
    Mag: -13.62 27.37 -17.02                           (one label, then the vector: space, tab or comma apart)
    Acc: 0.12, -0.03, 9.81 Mag: -13.62, 27.37, -17.02 uT
    Scaled. Acc (mg) [ 00000.00, 00020.00, 01000.00 ], Mag (uT) [ 00049.74, 00003.05, -00018.99 ]   (SparkFun ICM-20948)
    Sensor 1: X: 50.00 Y: 0.00 Z: 20.00 uT             (two sensors, a line each: "Sensor 1 X", "Sensor 2 X" …)

Each `label: number` or `label=number` is a value; a label followed by several numbers is a vector whose
components are named `label X`, `label Y`, `label Z` (three), else `label 1`, `label 2`, …. Words before a line's first label name its sensor
("Mag X: …" gives the column "Mag X"; fluxcal.io.columns then finds the magnetometer by name), a unit
word after a number ("uT", "uTesla", "m/s^2") is its column's unit. A leading clock time (the IDE's
`hh:mm:ss.mmm ->`, or `[date time]`) becomes the column `time` in seconds.

The columns are the names that most lines carry (a start-up banner's "Data rate set to: 155 Hz" is not
one). Lines fill a row in turn; a line whose names the row already holds starts the next row, so one line
per reading and one line per sensor per cycle both read. Lines before the first complete row are the
preamble (banners, the partial line a capture starts with) and are kept in metadata["preamble"]. After
it, a line that does not fit (garbled, two lines run together, a truncated row, a non-number) is an error
naming its line (bad_lines="error") or is left out and listed in metadata["skipped_lines"] ("skip").
"""
from __future__ import annotations

import re
from collections import Counter
from pathlib import Path

import numpy as np

from .columns import FIELD_UNITS, TIME_WORDS, comma_kind, is_unit, words
from .csv import (readable_file, CUT_PROBLEM, CUT_SHORT, NOT_TEXT, SKIP_HINT, _timestamps, check_bad_lines, data_lines,
                  is_comment, listing, read_lines, stop_at_first)
from .recording import Recording

# label (a word not glued to what precedes it, hyphens inside allowed: X-acceleration), ':', '=' or ' is '
# (`Temperature is 24.0 degrees C`), then a number with all its commas between digits (`X: -13,62`,
# `X: 1,234,567`, `X: 1,234.5`: what they are is decided for the file, see _Commas; a unit may be glued on)
_PAIR = re.compile(r"(?<![\w.\-:])([A-Za-z_][\w.]*(?:-[A-Za-z][\w.]*)*(?:\[\d+\])?)(?:\s*\(([^()\d]{1,16})\))?"
                   r"(?:\s*[:=]\s*|\s+is\s+)"
                   r"([+-]?(?:\d+(?:,\d+)*(?:\.\d*)?|[.,]\d+)(?:[eE][+-]?\d+)?|[+-]?(?:nan|inf)\b)([^\s,;|]*)",
                   re.IGNORECASE)
CLOCK = re.compile(r"^\s*\[?((?:\d{4}-\d{1,2}-\d{1,2}[ T])?\d{1,2}:\d{2}:\d{2}(?:[.,]\d+)?)\]?\s*(?:->|>|\|)?\s*")
_WORD = re.compile(r"[^\s,;|]+")
SAMPLE_LINES = 50


def _field_unit(word: str) -> str:
    if word in ("g", "mg"):  # lower-case: gravities (MPU9250 sketches print mg beside mG, milligauss)
        return word
    return FIELD_UNITS.get(word.lower().replace("\u03bc", "\u00b5"), word)


def _degrees(words: list) -> str:
    """Pop the unit that starts `words`: "degrees C" (two words) is °C, as a temperature column reads it."""
    unit = words.pop(0)
    if unit.lower() in ("deg", "degree", "degrees") and words and words[0] in ("C", "F"):
        return "°" + words.pop(0)
    return unit


_LABEL = re.compile(r"(?<![\w.\-])([A-Za-z_][\w.\-]*(?: [A-Za-z_][\w.\-]*)*)\s*[:=]")
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|[+-]?(?:nan|inf)", re.IGNORECASE)


def _vector_tokens(segment: str, loose: bool = False) -> list:
    """The words of a vector's values: apart by spaces, tabs, ';', '|', a comma before a space, or commas —
    when one comes before a sign, every number has a decimal point (55.84,-5.84,44.54), there are three or
    more numbers that are not thousands groups (120,45,30), or `loose` (the file's other lines are vectors:
    120,456,789 is one too). Else a comma stays in its word ("12,34", "1,234"): a decimal comma or a
    thousands group, which the pairs' parse decides on."""
    words = [w for w in re.split(r"[\s;|]+|,(?=\s)", segment.strip()) if w]
    unit = [words.pop()] if len(words) > 1 and is_unit(words[-1]) else []  # "1,374 counts": one number
    parts = [p for w in words for p in w.split(",")]
    if len(parts) == len(words) or len(words) > 1:  # apart already: a comma inside a word is a decimal one
        return words + unit
    apart = (loose or re.search(r",(?=[+-])", segment) is not None or all("." in p for p in parts) or
             (len(parts) > 2 and not all(len(p) == 3 and p.isdigit() for p in parts[1:])))
    return (parts if apart else words) + unit


def _vector_line(line: str):
    """The values of a line of vectors after its clock (see _vectors), or None."""
    clock = CLOCK.match(line)
    return _vectors(line[clock.end():] if clock else line)


# `Label (unit) [ n1, n2, n3 ]`: SparkFun's ICM-20948 examples
_BRACKETED = re.compile(r"([A-Za-z_][\w.]*)\s*(?:\(([^()]{1,16})\))?\s*:?\s*\[([^\[\]]*)\]")  # mag: [..], (m/s^2)


def _bracketed_vectors(text: str):
    """[(name, value text, unit)] of a line of `Label (unit) [ n1, n2, n3 ]` groups, comma apart, after at
    most one word (SparkFun's ICM-20948 Example1: `Scaled. Acc (mg) [ 00000.00, 00020.00, 01000.00 ], Gyr (DPS)
    [ … ], Mag (uT) [ … ], Tmp (C) [ 00025.41 ]`); None for any other line."""
    groups = list(_BRACKETED.finditer(text)) if "[" in text else []
    if not groups or len(_WORD.findall(text[:groups[0].start()])) > 1:
        return None
    gaps = [text[a.end():b.start()] for a, b in zip(groups, groups[1:])] + [text[groups[-1].end():]]
    if any(gap.strip(" \t,;") for gap in gaps):
        return None
    values = []
    for m in groups:
        numbers = [w for w in re.split(r"[\s,;]+", m.group(3)) if w]
        if not numbers or not all(_NUMBER.fullmatch(w) for w in numbers):
            return None  # a log tag ("[1] X: …"), an index (mag[0]: …): the pairs' parse reads it
        axes = "XYZ" if len(numbers) == 3 else [str(i + 1) for i in range(len(numbers))]
        unit = (m.group(2) or "").strip()
        unit = unit if is_unit(unit) else ""
        values += [(f"{m.group(1)} {axis}" if len(numbers) > 1 else m.group(1), w, unit)
                   for axis, w in zip(axes, numbers)]
    return values


def _vectors(text: str, loose: bool = False):
    """[(name, value text, unit)] of a line of `label: n1 n2 n3 [unit]` groups (numbers apart by spaces, tabs
    or commas), at least one of them a vector of two or more numbers, or of `Label (unit) [ n1, n2, n3 ]`
    groups (_bracketed_vectors); None for any other line (the pairs' parse then reads it)."""
    bracketed = _bracketed_vectors(text)
    if bracketed is not None:
        return bracketed
    labels = list(_LABEL.finditer(text))
    if not labels or text[:labels[0].start()].strip():
        return None
    values = []
    for k, m in enumerate(labels):
        tokens = _vector_tokens(text[m.end():labels[k + 1].start() if k + 1 < len(labels) else len(text)], loose)
        unit = tokens.pop() if len(tokens) > 1 and is_unit(tokens[-1]) else ""
        # every label a vector: a line of `X: 1 Y: 2 Z: 3 1000` or `Mag X: … Acc: 1 2 3` keeps its pairs' parse
        if len(tokens) < 2 or not all(_NUMBER.fullmatch(w) for w in tokens):
            return None
        axes = "XYZ" if len(tokens) == 3 else [str(i + 1) for i in range(len(tokens))]
        label = m.group(1)
        values += [(f"{label} {axis}" if len(tokens) > 1 else label, w, unit) for axis, w in zip(axes, tokens)]
    return values


def _sensor_words(words: list, tags: bool = True, taken: list | None = None) -> list:
    """The words before a label that name its sensor: words (not units), a log tag in brackets ("[MAG] X: …"),
    and (`tags`) a number in brackets ("[2] X: …") or a number or letter right after a name ("Sensor 1: X: …",
    "Sensor A X: …"): which of two sensors; the A is not amperes. A tag taken is appended to `taken`."""
    named = []
    for k, w in enumerate(words):
        tag = tags and (re.fullmatch(r"\[\d+\]", w) or k > 0 and named and named[-1] == words[k - 1].strip(":=-")
                        and re.fullmatch(r"\d{1,2}|[A-Za-z]", w.strip(":=-")))
        if tag and taken is not None:
            taken.append(w)
        if tag or (re.search(r"[A-Za-z]", w) and not is_unit(w)):
            named.append(w.strip(":=-"))
    return named


def _parse_line(text: str, loose: bool = False, tags: bool = True, taken: list | None = None):
    """(clock text or None, [(name, value text, unit)]) of one line; names carry the sensor words (`tags`,
    `taken`: see _sensor_words). `loose`: the file's lines are mostly vectors (see _vector_tokens)."""
    clock = CLOCK.match(text)
    after_clock = clock.end() if clock else 0
    vectors = _vectors(text[after_clock:], loose)
    if vectors is not None:
        return (clock.group(1) if clock else None), vectors
    stamp = clock.group(1) if clock and _PAIR.search(text, clock.end()) else None
    pos = clock.end() if stamp else 0
    group, values, groups = "", [], []
    for m in _PAIR.finditer(text, pos):
        words = _WORD.findall(text[pos:m.start()])
        if values and words and is_unit(words[0]) and not values[-1][2]:
            values[-1][2] = _degrees(words)  # the previous value's unit
        named = _sensor_words(words, tags, taken)
        if named or not groups:
            group = " ".join(named)
            groups.append([next((w.strip(":=-") for w in words if is_unit(w.strip(":=-"))), "")])  # "Mag (uT) X:"
        groups[-1].append(len(values))
        # a unit in brackets between the name and the colon ("Heading (degrees): 0.86") or glued after the number
        bracketed = (m.group(2) or "").strip()
        unit = m.group(4) or (bracketed if is_unit(bracketed) else "")
        label = m.group(1) if not bracketed or is_unit(bracketed) else f"{m.group(1)} ({bracketed})"  # X (raw)
        values.append([f"{group} {label}" if group else label, m.group(3), unit])
        pos = m.end()
    if values and not values[-1][2]:
        tail = _WORD.findall(text[pos:])
        if tail and is_unit(tail[0]):
            values[-1][2] = _degrees(tail)
    for group_unit, *members in groups:  # "Mag X: 1 Y: 2 Z: 3 uT": a unit after the last value is the sensor's
        units = [values[k][2] for k in members]
        unit = units[-1] if units[-1] and is_unit(units[-1]) and not any(units[:-1]) else \
            (group_unit.strip("[]()") if not any(units) else "")
        for k in members:
            values[k][2] = values[k][2] or unit
    return stamp, [tuple(v) for v in values]


_BARE_NUMBER = re.compile(r"(?<![\w.])[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?(?![\w.])")


def _is_labelled(line: str) -> bool:
    """The line holds `label: number` pairs and (besides a clock) at most one number outside them: a
    table row with a `mode=1` text cell has its numbers outside the pair."""
    if not _parse_line(line)[1]:
        return False
    if _vector_line(line) is not None:
        return True
    clock = CLOCK.match(line)
    rest = _PAIR.sub(" ", line[clock.end():] if clock else line)
    return len(_BARE_NUMBER.findall(rest)) < 2


def looks_labelled(lines, start: int) -> bool:
    """True when most of the first data lines are labelled (`label: number` or `label=number` pairs)."""
    sample = data_lines(lines, start, SAMPLE_LINES)
    return bool(sample) and sum(_is_labelled(line) for line in sample) >= 0.6 * len(sample)


SETTLE_HINT = ("pass decimal=',' (a decimal comma) or thousands=',' (a thousands separator) to read_recording "
               "(the command line: --decimal , or --decimal .)")


def stated_comma(decimal, thousands) -> str | None:
    """What the caller says a comma between digits is: "decimal" (decimal=','), "thousands" (thousands=',', or
    decimal='.': pandas' names), or None when neither is given; an error for other values."""
    if decimal not in (None, ".", ",") or thousands not in (None, ","):
        raise ValueError(f"decimal={decimal!r}, thousands={thousands!r}: decimal is '.' or ',', thousands ','")
    if decimal == "," and thousands == ",":
        raise ValueError("decimal=',' and thousands=',': a comma cannot be both")
    return None if not (decimal or thousands) else "decimal" if decimal == "," else "thousands"


def _comma_reading(path, parsed, names, decimal, thousands) -> str | None:
    """What a comma between digits is in this file: "decimal", "thousands", or None (no number in the file
    says). Stated by `decimal`/`thousands` (pandas' names: decimal=',' is a decimal comma; thousands=',', or
    decimal='.', a thousands separator), else decided by the values of the columns: a decimal comma that
    cannot be a thousands separator (12,34, 0,123, -0,5, 1234,5) against thousands groups beside a decimal
    point (1,234.5). Numbers that show both are an error naming a line of each."""
    stated = stated_comma(decimal, thousands)
    if stated:
        return stated
    first = {}
    for line_no, _, _, values in parsed:
        for name, value, _ in values:
            kind = comma_kind(value)
            if name in names and kind in ("decimal", "thousands"):
                first.setdefault(kind, (line_no, name, value))
    if len(first) == 2:
        (a, an, av), (b, bn, bv) = first["decimal"], first["thousands"]
        raise ValueError(f"{path}: {an}: {av!r} on line {a} has a decimal comma, {bn}: {bv!r} on line {b} a thousands "
                         f"separator; {SETTLE_HINT}")
    return next(iter(first), None)


def _number(text: str, reading: str | None):
    """(value, None) or (None, what is wrong) of a number's text, its commas read as `reading` says."""
    kind = comma_kind(text)
    if kind == "invalid" or (reading == "decimal" and kind in ("several", "thousands")) \
            or (reading == "thousands" and kind == "decimal"):
        what = {"decimal": "a decimal comma", "thousands": "a thousands separator"}.get(reading, "a number")
        return None, f"{text!r} is not {what}" + (" (the file's commas are read so)" if reading else "")
    if kind in ("ambiguous", "several") and reading is None:
        return None, "ambiguous"
    text = text.replace(",", "") if reading == "thousands" else text.replace(",", ".")
    value = float(text)
    return (value, None) if np.isfinite(value) else (None, f"{text!r} is not a finite number")


def _ambiguous(path, line_no: int, name: str, value: str) -> ValueError:
    what = (f"{value.replace(',', '.', 1)} with a decimal comma or {value.replace(',', '')} with a thousands "
            "separator" if comma_kind(value) == "ambiguous" else
            f"{value.replace(',', '')} with thousands separators, or numbers run together")
    return ValueError(f"{path}, line {line_no}: {name}: {value!r} is {what}, and no number in the file settles which "
                      "(a decimal comma that cannot be a thousands separator, such as 12,34 or -0,5, or a thousands "
                      f"separator beside a decimal point, such as 1,234.5); not guessed: {SETTLE_HINT}")


def _units_apart(parsed: list) -> list:
    """`parsed` with a name printed in several units (or with and without one) split into a column per unit,
    "X" and "X (uT)": Adafruit's LIS3MDL demo prints each reading twice, `X: 3712` in counts and then
    `X: 54.26 … uTesla`, and the two read as one column labelled µT (a calibration of both, 133 µT off).
    Two sensors under the same names, or a range change, are kept apart the same way; which triple is the
    magnetometer is then fluxcal.io.columns' choice (several: an error listing them, for --columns).
    Only units that alternate, each on at least half as many lines as the commonest: a range change (one
    switch) is an error in read_labelled, a lone line without a unit (truncated) a line that does not fit."""
    seen, switches, last = {}, Counter(), {}
    for *_, values in parsed:
        for name, _, unit in values:
            unit = _field_unit(unit) if unit else ""
            seen.setdefault(name, Counter())[unit] += 1
            switches[name] += name in last and last[name] != unit
            last[name] = unit
    split = {name for name, units in seen.items()
             if len(units) > 1 and min(units.values()) >= 0.5 * max(units.values())
             and switches[name] >= min(units.values())}
    if not split:
        return parsed
    return [(line_no, text, stamp, [(f"{name} ({_field_unit(unit)})" if name in split and unit else name, value, unit)
                                    for name, value, unit in values])
            for line_no, text, stamp, values in parsed]


MAX_SENSORS = 8


def _parse_lines(lines, loose: bool) -> list:
    """[(line number, text, clock text, values)] of the (line number, line) pairs. A number or letter after a
    sensor's word names which of a few sensors it is (Sensor 1: X: …); where one name takes more than
    MAX_SENSORS such tags, or three or more that each come once, they count the readings (Sample 17: X: …) and
    are left out."""
    tagged, plain = [], []
    for k, line in lines:
        taken = []
        tagged.append((k, line.strip(), *_parse_line(line, loose, taken=taken)))
        # parsed again without tags only where it took one (most logs: no line)
        plain.append((k, line.strip(), *_parse_line(line, loose, tags=False)) if taken else tagged[-1])
    if all(a is b for a, b in zip(tagged, plain)):
        return tagged
    variants: dict = {}  # untagged name -> {tagged name: lines}
    for (*_, values), (*_, bare) in zip(tagged, plain):
        if len(values) == len(bare):
            for (name, *_), (base, *_) in zip(values, bare):
                variants.setdefault(base, Counter())[name] += 1
    counted = any(len(v) > MAX_SENSORS or (len(v) >= 3 and max(v.values()) == 1) for v in variants.values())
    return plain if counted else tagged


def read_labelled(path, columns=None, units: str | None = None, bad_lines: str = "error",
                  decimal: str | None = None, thousands: str | None = None) -> Recording:
    """Read a labelled text log (module docstring). `columns`/`units` as for every reader; `bad_lines`
    "error" (default) or "skip".

    A comma between digits is read as the file's numbers show it: a decimal comma when some value of the
    columns has one that cannot be a thousands separator (12,34, 0,123, -0,5, 1234,5), a thousands separator
    when some value has thousands groups beside a decimal point (1,234.5); both is an error. When only
    ambiguous values hold commas (1,234: 1.234 or 1234? 1,234,567), the read is an error naming the first one
    (whatever bad_lines says: never an answer 1000 times off): `decimal=","` or `thousands=","` (or
    decimal=".") settles it. metadata["decimal_separator"] is "comma" when commas were read as decimal."""
    check_bad_lines(bad_lines)
    path = readable_file(path)
    lines = [(k + 1, line) for k, line in enumerate(read_lines(path)) if line.strip() and not is_comment(line)]
    vector_lines = sum(_vector_line(line) is not None for _, line in lines)
    loose = vector_lines >= 0.5 * len(lines)  # a log of vectors: 120,456,789 is one, not a thousands group
    parsed = _units_apart(_parse_lines(lines, loose))
    counts = Counter(name for *_, values in parsed for name in dict.fromkeys(v[0] for v in values))
    if not counts:
        raise ValueError(f"{path}: no 'label: number' or 'label=number' values")
    top = max(counts.values())
    names = [n for n in counts if counts[n] >= 0.5 * top]  # in order of first appearance
    reading = _comma_reading(path, parsed, names, decimal, thousands)
    ambiguous = {}  # line -> (name, value)
    rows, trouble = [], {}
    row, lines_of_row, clock = {}, [], None

    def close():
        missing = [n for n in names if n not in row]
        if lines_of_row and missing:
            for n in lines_of_row:
                trouble.setdefault(n, f"no {', '.join(repr(m) for m in missing)} (truncated line?)")
        elif lines_of_row:
            rows.append((lines_of_row[0], dict(row), clock))

    for line_no, text, stamp, values in parsed:
        seen = [v[0] for v in values]
        problem = None
        if NOT_TEXT in text:  # a number with a garbage byte in it would read as a shorter number
            problem = "bytes that are not text (garbage from a serial line?)"
        elif CUT_SHORT in text:
            problem = CUT_PROBLEM
        elif not values:
            problem = "no 'label: number' values (garbled line?)"
        elif len(set(seen)) != len(seen):
            problem = f"{next(n for n in seen if seen.count(n) > 1)!r} appears twice (two lines run together?)"
        elif any(n not in names for n in seen):
            problem = f"{next(n for n in seen if n not in names)!r} is not one of the columns ({', '.join(names)})"
        else:
            numbers = [_number(v, reading) for _, v, _ in values]
            bad = next(((v, p) for v, (_, p) in zip(values, numbers) if p), None)
            glued = next((v for v in values if v[2] and not is_unit(v[2])), None)  # 1.2x5: not 1.2
            if bad is not None and bad[1] == "ambiguous":
                ambiguous[line_no] = bad[0][:2]
                problem = f"{bad[0][0]}: {bad[0][1]!r} is ambiguous"
            elif bad is not None:
                problem = f"{bad[0][0]}: {bad[1]}"
            elif glued is not None:
                problem = f"{glued[0]}: {glued[1] + glued[2]!r} is not a number"
        if problem:
            trouble[line_no] = problem
            continue
        if any(n in row for n in seen):
            close()
            row, lines_of_row, clock = {}, [], None
        row.update({n: (x, u, line_no) for (n, _, u), (x, _) in zip(values, numbers)})
        clock = clock or stamp
        lines_of_row.append(line_no)
    close()
    if ambiguous:  # a line of the columns' values, even before the first complete reading: never a preamble
        n = min(ambiguous)
        raise _ambiguous(path, n, *ambiguous[n])
    if not rows:
        raise ValueError(f"{path}: no complete reading (each needs {', '.join(names)})")
    first = rows[0][0]
    preamble = [(n, text) for n, text, *_ in parsed if n < first]
    problems = sorted((n, p) for n, p in trouble.items() if n > first)
    metadata = {"layout": f"labelled lines ({', '.join(names)})"}
    if reading == "decimal":
        metadata["decimal_separator"] = "comma"
    if preamble:
        metadata["preamble"] = listing([f"line {n}: {text}" for n, text in preamble])
    stop_at_first(path, problems, bad_lines)
    if problems:
        metadata["skipped_lines"] = listing([f"{n} ({p})" for n, p in problems], len(parsed) - len(preamble))
    good = [(n, r) for n, r, _ in rows]
    data = {name: np.array([r[name][0] for _, r in good]) for name in names}
    unit_map = {}
    for name in names:
        found = {}
        for _, r in good:
            if r[name][1]:
                found.setdefault(_field_unit(r[name][1]), r[name][2])
        if len(found) > 1:  # a unit on a few lines only (a range change; see _units_apart): never mix them
            (u1, a), (u2, b) = list(found.items())[:2]
            raise ValueError(f"{path}: {name!r} is in {u1} on line {a} and in {u2} on line {b}; a changed range, "
                             "or readings of two sensors under the same names? Name the sensor in each line "
                             "(Mag X: …) or keep one unit per column")
        if found:
            unit_map[name] = next(iter(found))
    stamps = [c or "" for _, _, c in rows]
    clock_name = "clock" if any(set(words(n)) & TIME_WORDS for n in names) else "time"  # the device's own wins
    if sum(bool(s) for s in stamps) >= 0.9 * len(stamps) and clock_name not in names:
        seconds, start = _timestamps(stamps)
        if seconds is not None:
            keep = np.isfinite(seconds)
            if not keep.all() and bad_lines == "error":
                n = good[int(np.argmin(keep))][0]
                raise ValueError(f"{path}, line {n}: no clock time where the other lines have one; {SKIP_HINT}")
            if not keep.all():
                lost = [f"{n} (no clock time)" for (n, _), k in zip(good, keep) if not k]
                metadata["skipped_lines"] = "; ".join(filter(None, [metadata.get("skipped_lines"), *lost]))
            data = {k: v[keep] for k, v in data.items()}
            data[clock_name], unit_map[clock_name] = seconds[keep], "s"
            metadata[f"{clock_name}_start"] = start
            good = [g for g, k in zip(good, keep) if k]
    rec = Recording(columns=data, units=unit_map, metadata=metadata, source=str(path),
                    line_numbers=np.array([n for n, _ in good], dtype=int))
    return rec.choose(columns, units)
