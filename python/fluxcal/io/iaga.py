"""IAGA-2002: the exchange format of geomagnetic observatories and variometer stations (INTERMAGNET, USGS, BGS, and
the loggers of many observatory-grade magnetometers).

    Format                 IAGA-2002                                    |   header: a label in columns 2–24,
    IAGA CODE              ESK                                          |   its value from column 25 to the
    Reported               XYZF                                         |   bar in column 70
    # a comment                                                         |
   DATE       TIME         DOY     ESKX      ESKY      ESKZ      ESKF   |   the data header
   2024-03-01 00:00:00.000 061     17301.22   -251.03  46499.70  49614.69   data: UT date and time, day of year,
                                                                            four elements

Elements (the last letter of each name in the data header; the first three form the vector, the fourth is a scalar):
X north, Y east, Z down, H horizontal, E east in the magnetic meridian's frame, F total and G its difference in nT;
D declination and I inclination in minutes of arc (the format's unit; a DHIF file in degrees is told apart by its F,
which only degrees then match, and read so with a warning; HDZ's D is not, as D does not change |field|). The
vector becomes the columns X, Y, Z in nT: XYZ as they are, HDZ as X = H cos D, Y = H sin D, DHI with Z = H tan I,
HEZ as (H, E, Z) in the magnetic meridian's frame (a variometer's: its axes, not geographic ones). The fourth
element (F, G) is kept as a column, NaN where a record lacks it.

99999.00 marks a missing value and 88888.00 an element not recorded: a record missing a component of the vector is
a bad line (`bad_lines`: an error naming it, or left out and listed in metadata "skipped_lines"), as is a record
with the wrong number of fields, a non-number, or a date and time not YYYY-MM-DD hh:mm:ss.sss. Files appended one
after another (a header before each day) are read in turn; their elements must agree.

Written by hand, not through geomagpy (MagPy), which reads it among many formats: its requirements (an MQTT
client, a MySQL driver, cdflib pinned below 1.4) are not a calibration library's.
"""
from __future__ import annotations

import warnings

import numpy as np

from .csv import CUT_PROBLEM, CUT_SHORT, _is_number, check_bad_lines, listing, read_lines, stop_at_first
from .recording import Recording

MISSING = 88888.0  # 88888.00 (not recorded) and 99999.00 (missing) both at or above it


def looks_like_iaga(head: bytes) -> bool:
    """Whether the first bytes of a file are an IAGA-2002 header (its "Format" record first)."""
    first = head.lstrip(b"\xef\xbb\xbf").split(b"\n", 1)[0].upper()
    return first.startswith(b" FORMAT") and (b"IAGA-2002" in first or b"IAGA2002" in first)


def _header(line: str) -> tuple[str, str]:
    """A header record's label and value (columns 2–24, then up to the closing bar)."""
    body = line.rstrip()
    body = body[:-1] if body.endswith("|") else body
    return body[:24].strip(), body[24:].strip()


def read_iaga2002(path, columns=None, units: str | None = None, bad_lines: str = "error") -> Recording:
    """A Recording of an IAGA-2002 file (module docstring): X, Y, Z in nT, t in seconds from the first record
    (metadata t_start, UT), F or G, and the header in the metadata."""
    check_bad_lines(bad_lines)
    lines = read_lines(path)
    metadata, elements, names = {}, None, None
    stamps, values, line_numbers, problems = [], [], [], []
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        # the data header starts in column 1 (header records with a space): " Date of file …" is a header record
        is_data_header = line.upper().startswith("DATE ") and "TIME" in line.upper()
        if is_data_header or (line.rstrip().endswith("|") and not line[:1].isdigit()):
            if is_data_header:
                found = line.rstrip(" |").split()[3:]
                letters = [n[-1].upper() for n in found]
                if len(found) != 4:
                    raise ValueError(f"{path}, line {number}: the data header names {len(found)} elements "
                                     f"({', '.join(found)}); IAGA-2002 records hold four")
                if elements is not None and letters != elements:
                    raise ValueError(f"{path}, line {number}: elements {''.join(letters)} after "
                                     f"{''.join(elements)}; files appended must report the same elements")
                elements, names = letters, found
                continue
            label, value = _header(line)
            if label.startswith("#"):
                metadata["comments"] = "; ".join(filter(None, [metadata.get("comments"), line.strip(" #|")]))
            elif label and elements is None:
                metadata.setdefault(label.lower().replace(" ", "_"), value)
            continue
        if elements is None:
            raise ValueError(f"{path}, line {number}: a record before the data header (DATE TIME DOY …); "
                             "not an IAGA-2002 file, or its header is damaged")
        cells = line.split()
        problem = None
        if CUT_SHORT in line:
            problem = CUT_PROBLEM
        elif len(cells) != 7:
            problem = f"{len(cells)} fields, an IAGA-2002 record has 7 (date, time, day of year, four elements)"
        else:
            try:
                row = [float(c) for c in cells[3:]]
            except ValueError:
                bad = next(c for c in cells[3:] if not _is_number(c))
                problem = f"{bad!r} is not a number"
        if problem is None:  # a component of the vector missing (the fourth element may be: it is not needed)
            absent = [k for k in range(3) if not row[k] < MISSING]
            if absent:
                problem = "; ".join(f"{names[k]} is {_missing_word(row[k])}" for k in absent)
        if problem is None:
            try:
                stamp = np.datetime64(f"{cells[0]}T{cells[1]}", "ns")
            except ValueError:
                problem = f"{cells[0]} {cells[1]!r} is not a date and time (YYYY-MM-DD hh:mm:ss.sss)"
        if problem is not None:
            problems.append((number, problem))
            continue
        stamps.append(stamp)
        values.append(row)
        line_numbers.append(number)
    if elements is None:
        raise ValueError(f"{path}: no data header (DATE TIME DOY and four elements); not an IAGA-2002 file")
    stop_at_first(path, problems, bad_lines)
    if not values:
        raise ValueError(f"{path}: no records" + (f" (all {len(problems)} bad)" if problems else ""))
    data = np.array(values)
    stamps = np.array(stamps)  # UT, as the format's times are
    seconds = (stamps - stamps[0]) / np.timedelta64(1, "s")
    out, note = _vector(path, elements, data)
    out["t"] = seconds
    units_of = {"X": "nT", "Y": "nT", "Z": "nT", "t": "s"}
    scalar = data[:, 3]
    if np.any(scalar < MISSING):  # F or G where recorded (88888: not recorded; 99999: missing)
        name = elements[3] if elements[3] not in out else names[3]
        out[name], units_of[name] = np.where(scalar < MISSING, scalar, np.nan), "nT"
    metadata.update(t_start=f"{np.datetime_as_string(stamps[0], unit='ms')}+00:00", iaga_elements="".join(elements),
                    iaga_columns=", ".join(names), vector=note)
    if problems:
        metadata["skipped_lines"] = listing([f"{n} ({p})" for n, p in problems], len(problems) + len(values))
    return Recording(columns=out, units=units_of, metadata=metadata, source=str(path),
                     line_numbers=np.array(line_numbers)).choose(columns, units)


def _missing_word(value: float) -> str:
    return ("99999.00 (missing)" if value >= 99999.0 else "88888.00 (not recorded)" if value >= MISSING
            else f"{value}, not a number")


# A DHIF file's |X, Y, Z| matches its F when the median of |(|X, Y, Z|/F − 1)| is within this: I read in the wrong
# unit misses by far more (I = 65° read as 65′ gives |field| = H, 58 % below F), a good record by < 1e-4.
F_AGREES = 0.01


def _angle_unit(path, elements: list, data: np.ndarray, column: int, h: np.ndarray) -> tuple[float, str]:
    """(units per degree, the unit's name) of a DHIF file's angles: minutes of arc, the format's unit, unless only
    degrees make |X, Y, Z| = H / |cos I| match the file's F (`F_AGREES`)."""
    f = data[:, 3]
    known = f < MISSING
    if elements[3] != "F" or not known.any():
        return 60.0, "minutes of arc"

    def miss(per_degree):
        cos_i = np.abs(np.cos(np.radians(data[known, column] / per_degree)))
        return float(np.median(np.abs(h[known] / cos_i / f[known] - 1.0)))

    by_minutes, by_degrees = miss(60.0), miss(1.0)
    if by_minutes <= F_AGREES or by_degrees > F_AGREES:
        return 60.0, "minutes of arc"
    warnings.warn(f"{path}: D and I read in degrees, not in minutes of arc (the IAGA-2002 unit): in minutes |X, Y, Z| "
                  f"missed F by {100 * by_minutes:.3g} % (median), in degrees by {100 * by_degrees:.2g} %")
    return 1.0, f"degrees: in minutes of arc |X, Y, Z| missed F by {100 * by_minutes:.3g} %"


def _vector(path, elements: list, data: np.ndarray) -> tuple[dict, str]:
    """The columns X, Y, Z (nT) from the elements reported, and how they were formed."""
    at = {letter: k for k, letter in enumerate(elements[:3])}
    have = set(at)
    if have == {"X", "Y", "Z"}:
        return {c: data[:, at[c]] for c in "XYZ"}, "X, Y, Z as reported"
    if have == {"H", "D", "Z"}:
        d = np.radians(data[:, at["D"]] / 60.0)
        return ({"X": data[:, at["H"]] * np.cos(d), "Y": data[:, at["H"]] * np.sin(d), "Z": data[:, at["Z"]]},
                "X = H cos D, Y = H sin D (D in minutes of arc)")
    if have == {"D", "H", "I"}:
        h = data[:, at["H"]]
        per_degree, unit = _angle_unit(path, elements, data, at["I"], h)
        d, i = np.radians(data[:, at["D"]] / per_degree), np.radians(data[:, at["I"]] / per_degree)
        return ({"X": h * np.cos(d), "Y": h * np.sin(d), "Z": h * np.tan(i)},
                f"X = H cos D, Y = H sin D, Z = H tan I (D, I in {unit})")
    if have == {"H", "E", "Z"}:
        return ({"X": data[:, at["H"]], "Y": data[:, at["E"]], "Z": data[:, at["Z"]]},
                "X = H, Y = E: the magnetic meridian's frame, not geographic north and east")
    raise ValueError(f"{path}: elements {''.join(elements)} do not give a field vector (IAGA-2002 vectors: XYZ, HDZ, "
                     "DHI, HEZ, then F or G)")
