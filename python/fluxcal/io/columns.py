"""Which column is which: the magnetometer axes, time, temperature, current and accelerometer of a
recording whose columns are not named fluxcal's way (mx,my,mz, t, temp, current, ax,ay,az).

Loggers name them MagX, mag_x, Mag_X (uT), magnetometer_ga[0], Bx, compass_x, x_mag; TimeUS, time_ms,
timestamp; Temperature, temp_C, die_temp; Current, curr_mA, motor_current_A, BAT's Curr; AccX, accel_x, acc_x_g. A name is split into lowercase words
(at separators, case changes and brackets); trailing unit words are peeled off and become the column's
unit when the file states none; the axis is a last word x/y/z (or a last word such as "magx", or an
index 0/1/2 or 1/2/3 after a magnetometer word). Three axes under the same words that include a magnetometer
word (mag, magnetometer, magnetic, compass, field, b, h, m, ...) are a magnetometer. When two such
triples exist (raw and calibrated, two compasses) the one without a "calibrated/corrected" word wins,
else the one marked raw/uncalibrated; anything still ambiguous is an error listing the triples, so the
user picks one with --columns. Plain x,y,z (any case) is a magnetometer only when nothing else is.
"""
from __future__ import annotations

import functools
import re

import numpy as np

MAG_WORDS = {"m", "mag", "mags", "magn", "magnet", "magnetometer", "magnetic", "magneticfield", "compass",
             # the magnetic field in the languages of a phone app's export (phyphox: "Magnetfeld x (µT)")
             # (accented ones split at the accent into "magn": "Campo magnético x" is found by that)
             "magnetfeld", "magnetisch", "magnetico", "magnetique", "magnetyczne",
             "b", "bfield", "h", "field", "flux", "fluxgate"}
ACC_WORDS = {"a", "acc", "accel", "accelerometer", "acceleration", "accl"}
TIME_WORDS = {"t", "ts", "time", "times", "timestamp", "elapsed", "sec", "secs", "seconds", "datetime",
              "utc", "gps", "gpstime", "zeit", "tiempo", "tempo", "tijd", "czas",
              "uhrzeit", "heure", "hora"}  # (the clock time beside a Datum/Date column; "temps" is also temperatures)
TEMP_WORDS = {"temp", "temperature", "tmp", "temperatur", "celsius"}
GYRO_WORDS = {"gyro", "gyr", "gyroscope", "gyros", "omega", "angular", "rad"}
# "motion": iOS Core Motion's device-motion field (SensorLog's motionMagneticFieldX beside the raw
# magnetometerX) is the calibrated, fused one
CALIBRATED_WORDS = {"cal", "calibrated", "corr", "corrected", "comp", "compensated", "filtered", "fused", "motion"}
RAW_WORDS = {"raw", "uncal", "uncalibrated", "uncorrected"}
# unit words a logger appends to a name -> the unit string fluxcal records
FIELD_UNITS = {"nt": "nT", "ut": "uT", "µt": "uT", "mt": "mT", "g": "G", "ga": "G", "gauss": "G", "mg": "mG",
               "mgauss": "mG", "milligauss": "mG", "counts": "counts", "lsb": "counts", "utesla": "uT",
               "µtesla": "uT", "microtesla": "uT", "nanotesla": "nT", "pt": "pT", "picotesla": "pT",
               "gamma": "nT", "γ": "nT", "gs": "G"}  # (gamma: the geophysicists' nT; Gs: gauss)
# the field units no other quantity writes the same way (g and mg are also accelerations; counts are anything's; Gs a
# ground speed too)
FIELD_ONLY_UNITS = set(FIELD_UNITS) - {"g", "mg", "counts", "lsb", "gs"}
TIME_UNITS = {"s": 1.0, "sec": 1.0, "secs": 1.0, "seconds": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6,
              "ns": 1e-9, "min": 60.0, "mins": 60.0, "minutes": 60.0, "h": 3600.0, "hr": 3600.0, "hours": 3600.0}
TEMP_UNITS = {"c": "C", "degc": "C", "celsius": "C", "°c": "C", "k": "K", "kelvin": "K", "°k": "K", "f": "F",
              "degf": "F", "fahrenheit": "F", "°f": "F"}
CURRENT_WORDS = {"current", "curr", "amps", "amperes"}
# what a current column's name may add: whose current it is (not "total": ArduPilot's CurrTot is mAh used)
CURRENT_QUALIFIERS = {"motor", "motors", "bat", "batt", "battery", "load", "supply", "heater", "coil"}
CURRENT_UNITS = {"a": 1.0, "amp": 1.0, "amps": 1.0, "ma": 1e-3}
# a cable's currents, a transformer's rating: also kA; a current transformer's zero bias: also µA
LARGE_CURRENT_UNITS = {**CURRENT_UNITS, "ka": 1e3, "ua": 1e-6, "µa": 1e-6}
_UNIT_WORDS = set(FIELD_UNITS) | set(TIME_UNITS) | set(TEMP_UNITS) | set(CURRENT_UNITS) | {"hz", "khz"}
_AXES = {"x": 0, "y": 1, "z": 2}
_OTHER_UNITS = {"tesla", "dps", "deg", "degrees", "rad", "%", "v", "mv", "pa", "hpa", "rpm"}


@functools.lru_cache(maxsize=4096)  # a log repeats the same few words on every line
def is_unit(text: str) -> bool:
    """A unit as loggers write it after a value or in a row under the column names: uT, µT, nT, G, mG,
    s, ms, °C, A, Hz, deg, m/s^2, deg/s, % (brackets around it allowed: "(µT)", "[s]")."""
    w = text.strip().strip("[]()").strip().lower().replace("\u03bc", "\u00b5")
    return bool(w) and (w in _UNIT_WORDS or w in _OTHER_UNITS or w in ("°", "°c", "°f", "°k")
                        or bool(re.fullmatch(r"[a-zµ°]+/[a-zµ°]+(?:\^?[23²³])?|(?:[cmk]?m|s|ft|in)\^?[23²³]", w)))
    # a power only of a length or a time (m², s^2): "Mag2", "Acc2" are the second sensor's name
# what a row of units writes under a column that has none (a position number, a count, a flag)
NO_UNIT = frozenset({"-", "–", "—", "n", "#", "none", "n/a", "na", "no."})


def is_unit_cell(text: str) -> bool:
    """A cell of a row of units: a unit, or a placeholder for a column without one ("-", "n")."""
    return is_unit(text) or text.strip().strip("[]()").strip().lower() in NO_UNIT


_CAMEL = re.compile(r"(?<=[a-z0-9])(?=[A-Z])|(?<=[A-Z])(?=[A-Z][a-z])|(?<=[A-Za-z])(?=[0-9])|(?<=[0-9])(?=[A-Za-z])")


def words(name: str) -> list[str]:
    """'Mag_X (uT)' -> ['mag', 'x', 'ut']; 'TimeUS' -> ['time', 'us']; 'magnetometer_ga[0]' -> [..., '0']."""
    out = []
    name = name.replace("\u03bc", "\u00b5")  # Greek mu (μT, as some keyboards type it) → the micro sign
    for segment in filter(None, re.split(r"[^0-9A-Za-zµ°]+", name)):
        if segment.lower() in _UNIT_WORDS:  # uT, mGauss: a unit, not two words
            out.append(segment.lower())
        else:
            out += [w.lower() for w in _CAMEL.sub(" ", segment).split()]
    return out


def _peel_unit(ws: list[str], table) -> tuple[list[str], str | None]:
    if len(ws) > 1 and ws[-1] in table:
        return ws[:-1], ws[-1]
    return ws, None


def _peel_field_unit(ws: list[str]) -> tuple[list[str], str | None]:
    """_peel_unit with FIELD_UNITS, and a last word "t" or "tesla" after a magnetometer's axis (Bx_T, mag_x_T:
    SI's tesla; "t" alone is too often a time to be a unit anywhere else) peeled as "tesla"."""
    rest, unit = _peel_unit(ws, FIELD_UNITS)
    if unit is None and len(ws) > 1 and ws[-1] in ("t", "tesla"):
        hit = _axis_of(ws[:-1])
        if hit is not None and set(hit[0]) & MAG_WORDS:
            return ws[:-1], "tesla"
    return rest, unit


def _axis_of(ws: list[str]):
    """(prefix words, axis) when the name ends in an axis, else None. The axis is 0..2 for x/y/z, or
    ("index", k) for a number 0..3 after a magnetometer/accelerometer word (0-based or 1-based: which
    one is settled once the triple is complete)."""
    if len(ws) >= 2 and ws[-1] in _AXES:
        return tuple(ws[:-1]), _AXES[ws[-1]]
    if len(ws) >= 2 and ws[0] in _AXES:  # x_mag, XMag
        return tuple(ws[1:]), _AXES[ws[0]]
    if ws and len(ws[-1]) > 1 and ws[-1][-1] in _AXES and ws[-1][:-1] in MAG_WORDS | ACC_WORDS:  # magx, bx, ax
        return tuple(ws[:-1]) + (ws[-1][:-1],), _AXES[ws[-1][-1]]
    if len(ws) >= 2 and ws[-1] in ("0", "1", "2", "3") and set(ws[:-1]) & (MAG_WORDS | ACC_WORDS | {"ga"}):
        return tuple(ws[:-1]), ("index", int(ws[-1]))
    return None


def _complete(prefix: tuple, axes: dict):
    """(names x, y, z, numbered) of one prefix's columns, or None: x/y/z, else indices 0,1,2, else 1,2,3
    (1-based only after a word longer than two letters — mag_1, not h1 — since single-letter channels
    numbered from 1 are as often three separate sensors)."""
    options = [((0, 1, 2), False), ((("index", 0), ("index", 1), ("index", 2)), True)]
    if any(len(w) > 2 and not w.isdigit() for w in prefix):
        options.append(((("index", 1), ("index", 2), ("index", 3)), True))
    for keys, numbered in options:
        if all(k in axes for k in keys):
            return tuple(axes[k] for k in keys), numbered
    return None


def _triples(names, kind_words):
    """{prefix words: (name_x, name_y, name_z)} for complete triples whose prefix has a word of kind_words
    (a magnetometer's prefix must not also name an accelerometer or a gyro). Qualifiers after the axis
    (mag_x_raw, MagXCal) count as part of the prefix."""
    groups, by_unit = _axis_groups(names, kind_words)
    found = {p: _complete(p, g) for p, g in groups.items()}
    if not any(t is not None for t in found.values()):  # an igrf_x_nT beside mag_x_nT is not a second sensor
        found = {p: _complete(p, g) for p, g in by_unit.items()}
    found = {p: t for p, t in found.items() if t is not None}
    lettered = {p: names for p, (names, numbered) in found.items() if not numbered}
    return lettered or {p: names for p, (names, _) in found.items()}  # numbered channels rank below x/y/z


def _axis_groups(names, kind_words) -> tuple:
    """({prefix words: {axis: name}} of the columns named by an axis under a prefix with a word of kind_words,
    the same of those named only by an axis and a field unit (x_uT)) — what _triples completes into triples and
    find_magnetometer_pair into pairs."""
    groups: dict[tuple, dict[int, str]] = {}
    by_unit: dict[tuple, dict[int, str]] = {}  # named by an axis and a field unit only: when nothing else is
    other = (ACC_WORDS | GYRO_WORDS) if kind_words is MAG_WORDS else (MAG_WORDS - {"m"}) | GYRO_WORDS
    for name in names:
        ws = words(name)
        ws = _drop_accel_unit(ws)
        ws, unit = _peel_field_unit(ws) if kind_words is MAG_WORDS else _peel_unit(ws, {"g": 1})
        qualifiers = []
        while len(ws) > 1 and ws[-1] in RAW_WORDS | CALIBRATED_WORDS:
            qualifiers.insert(0, ws.pop())
        field_unit = kind_words is MAG_WORDS and unit in FIELD_ONLY_UNITS
        hit = ((), _AXES[ws[0]]) if field_unit and len(ws) == 1 and ws[0] in _AXES else _axis_of(ws)
        if hit is None:
            continue
        prefix, axis = hit
        prefix = prefix + tuple(qualifiers)
        kinds = _kind_words(prefix, name)
        if kinds & other:
            continue
        if kinds & kind_words:  # the unit keeps two sensors' same names apart (Mag X in mG and in uT)
            groups.setdefault(prefix + ((unit,) if unit else ()), {}).setdefault(axis, name)
        elif field_unit:  # x_uT: the unit says it is a field
            by_unit.setdefault(prefix + (unit,), {}).setdefault(axis, name)
    return groups, by_unit


# words of a device that a letter after them tags ("Sensor A", "IMU B", "Mag A": which of two, not an
# accelerometer or a field B)
SENSOR_OWNERS = {"sensor", "imu", "chip", "board", "device", "probe", "module", "node", "unit"}


def _kind_words(prefix: tuple, name: str) -> set:
    """The prefix's words that may say what it measures: all but a letter tagging a sensor — written apart by
    spaces in `name` ("Sensor A X", as labelled lines name it; in imu_mx or imu_m_x the m is the magnetometer)
    after a word of SENSOR_OWNERS or a sensor kind's word of two or more letters."""
    def tagged(k):
        before = prefix[k - 1] if k > 0 else ""
        apart = re.search(rf"(?:^|\s){re.escape(prefix[k])}(?:\s|$)", name, re.IGNORECASE)
        return apart and (before in SENSOR_OWNERS or (len(before) > 1 and before in MAG_WORDS | ACC_WORDS | GYRO_WORDS))

    return {w for k, w in enumerate(prefix) if not (len(w) == 1 and tagged(k))}


def _drop_accel_unit(ws: list[str]) -> list[str]:
    """Remove an acceleration unit written as words (m_s2, m/s^2 → m, s, 2) wherever it sits."""
    out, k = [], 0
    while k < len(ws):
        if ws[k:k + 3] == ["m", "s", "2"]:
            k += 3
            continue
        if ws[k] in ("ms2", "mss"):
            k += 1
            continue
        out.append(ws[k])
        k += 1
    return out


def find_magnetometer(names, source: str = "recording", units=None):
    """The three magnetometer columns among `names`, or None when there is no candidate. An ambiguous
    choice is a ValueError that lists the candidates. `units` (column → stated unit) lets axes named only
    as axes ("x-axis (T)", MbientLab's export) be a magnetometer when their unit is a field's."""
    names = list(names)
    found = _triples(names, MAG_WORDS)
    if len(found) > 1:
        plain = {p: t for p, t in found.items() if not set(p) & CALIBRATED_WORDS}
        if len(plain) > 1:
            plain = {p: t for p, t in plain.items() if set(p) & RAW_WORDS} or plain
        found = plain or found
    if len(found) == 1:
        return next(iter(found.values()))
    if len(found) > 1:
        listed = "; ".join(",".join(t) for t in found.values())
        raise ValueError(f"{source}: several magnetometer column triples ({listed}); choose one with --columns "
                         "/ select()")
    # bare axes: x_raw,y_raw,z_raw beside x,y,z are the raw readings (PX4 1.10's sensor_mag: x,y,z are the
    # driver's calibrated field), as a raw magnetometer triple wins over a plain one
    bare = _bare_axes(names, units)
    for qualifier in ("raw", "", "axis"):
        if len(bare.get(qualifier, {})) == 3:
            return tuple(bare[qualifier][a] for a in "xyz")
    return None


def rival_magnetometers(names, chosen, units=None) -> list:
    """The magnetometer triples among `names` beside `chosen` (the three taken by default: mx,my,mz, or what
    find_magnetometer found) that rank as high: another sensor's named triple (MagX.. or Bx.. beside mx..), plain
    x,y,z beside a named one (unless only the named one states a field unit), or pandas' x.1,y.1,z.1 for a second
    x,y,z. A calibrated triple ranks below (mx_cal, and fluxcal apply's hx,hy,hz), and so does a plain one below a
    raw one chosen (x,y,z beside x_raw..). Two compasses had been taken one of them without a word (a blind
    check): the caller refuses them."""
    names, chosen = list(names), tuple(chosen)
    found = _triples(names, MAG_WORDS)
    mine = next((p for p, t in found.items() if t == chosen), None)
    raw = bool(set(mine or ()) & RAW_WORDS) or all("raw" in words(n) for n in chosen)
    # bx,by,bz beside fluxcal's own mx,my,mz are as often the true field a vector fit is given (--reference
    # bx,by,bz, read after the magnetometer is taken) as a second sensor: not refused (the columns line names mx)
    reference = chosen == ("mx", "my", "mz")
    rivals = [t for p, t in found.items() if t != chosen and not set(p) & CALIBRATED_WORDS and p[:1] != ("h",)
              and (not raw or set(p) & RAW_WORDS) and not (reference and p == ("b",))]
    bare = _bare_axes(names, units).get("", {})

    def field(n):
        return bool(field_unit_of(n) or _states_field((units or {}).get(n)))

    # x,y,z beside x_uT..: the field unit says which is the magnetometer (a sketch's counts beside its µT)
    if len(bare) == 3 and not raw and tuple(bare[a] for a in "xyz") != chosen \
            and not (all(map(field, chosen)) and not any(map(field, bare.values()))):
        rivals.append(tuple(bare[a] for a in "xyz"))
    twins = tuple(f"{n}.1" for n in chosen)  # pandas' names for a second column of the same name
    if all(n in names for n in twins):
        rivals.append(twins)
    return [t for t in dict.fromkeys(rivals) if not set(t) & set(chosen)]


def _bare_axes(names, units) -> dict:
    """{qualifier: {axis letter: name}} of the columns named by an axis alone: x, Y, x_raw, "x-axis" (with a
    field unit stated)."""
    bare = {}
    for n in names:
        ws = words(n)
        axes, rest = [w for w in ws if w in _AXES], [w for w in ws if w not in _AXES]
        if len(axes) == 1 and (rest in ([], ["raw"]) or rest == ["axis"] and _states_field((units or {}).get(n))):
            bare.setdefault("".join(rest), {}).setdefault(axes[0], n)
    return bare


def find_magnetometer_pair(names, source: str = "recording", units=None):
    """A biaxial magnetometer's two columns among `names` (a HMC1052, a car compass: no third axis), for when
    find_magnetometer finds no triple: ((name, name), axes) with axes "xy", "xz" or "yz" when the names say which
    sensor axes they are (mx,my; Bx,Bz; mag_y,mag_z; x,y; x_uT,y_uT — ordered by axis), None when they do not
    (mag_1,mag_2: numbered channels); None when there is no pair. The names are judged by the triples' rules (a
    magnetometer word with the axis; plain x,y only when nothing else is; the raw pair before a calibrated one);
    an ambiguous choice is a ValueError listing the pairs."""
    names = list(names)
    groups, by_unit = _axis_groups(names, MAG_WORDS)

    def pairs(grouped) -> dict:
        found = {}
        for prefix, axes in grouped.items():
            lettered = sorted(a for a in axes if a in (0, 1, 2))
            numbered = sorted(a[1] for a in axes if isinstance(a, tuple))
            if len(lettered) == 2:
                found[prefix] = (tuple(axes[a] for a in lettered), "".join("xyz"[a] for a in lettered))
            elif not lettered and len(numbered) == 2 and any(len(w) > 2 and not w.isdigit() for w in prefix):
                # (mag_1, mag_2; not h1, h2: single letters numbered are as often separate sensors)
                found[prefix] = (tuple(axes[("index", k)] for k in numbered), None)
        return found

    found = pairs(groups) or pairs(by_unit)
    lettered = {p: f for p, f in found.items() if f[1] is not None}
    found = lettered or found
    if len(found) > 1:
        plain = {p: f for p, f in found.items() if not set(p) & CALIBRATED_WORDS}
        if len(plain) > 1:
            plain = {p: f for p, f in plain.items() if set(p) & RAW_WORDS} or plain
        found = plain or found
    if len(found) > 1:
        listed = "; ".join(",".join(f[0]) for f in found.values())
        raise ValueError(f"{source}: several magnetometer column pairs ({listed}); choose one with --columns / "
                         "select()")
    if found:
        return next(iter(found.values()))
    bare = _bare_axes(names, units)
    for qualifier in ("raw", "", "axis"):
        if len(bare.get(qualifier, {})) == 2:
            axes = "".join(a for a in "xyz" if a in bare[qualifier])
            pair = tuple(bare[qualifier][a] for a in axes)
            # x,y alone are as often a position (a car driving its calibration circles traces one): a field's
            # only when their unit says so, or when nothing but a time stands beside them
            if all(_states_field((units or {}).get(n)) for n in pair) or len(names) <= 3:
                return pair, axes
    return None


def axis_of_name(name: str):
    """The sensor axis (0, 1, 2 for x, y, z) a column's name says it is (mx, Bz, mag_y_uT, Y, x_raw), or None."""
    ws = _drop_accel_unit(words(name))
    ws, _ = _peel_field_unit(ws)
    while len(ws) > 1 and ws[-1] in RAW_WORDS | CALIBRATED_WORDS:
        ws = ws[:-1]
    hit = _axis_of(ws)
    if hit is not None and hit[1] in (0, 1, 2):
        return hit[1]
    axes = [w for w in ws if w in _AXES]
    return _AXES[axes[0]] if len(axes) == 1 else None


def _states_field(unit) -> bool:
    """Whether a stated unit is a magnetic field's: T, µT, nT, G, mG… (not g or mg, accelerations)."""
    unit = (unit or "").strip().strip("[]()").strip()
    return unit not in ("g", "mg") and unit_name(unit) in ("T", "mT", "uT", "nT", "pT", "G", "mG")


def find_accelerometer(names):
    found = _triples(list(names), ACC_WORDS)
    return next(iter(found.values())) if len(found) == 1 else None


def _single(names, kind_words, unit_table):
    """(column name, unit word or None) of the only column whose words are kind_words (+ a unit)."""
    hits = _named(names, kind_words, unit_table)
    return hits[0] if len(hits) == 1 else None


def _named(names, kind_words, unit_table) -> list:
    """[(column name, unit word or None)] of every column whose words are kind_words (+ a unit)."""
    hits = []
    owners = {"sensor", "die", "chip", "imu", "mag", "board"} | (CLOCK_WORDS | DATE_WORDS if kind_words is TIME_WORDS
                                                               else set())
    for name in names:
        if name == "T":  # time to some loggers, temperature to others: not guessed
            continue
        ws, unit = _peel_unit(words(name), unit_table)
        if ws and all(w in kind_words or w in owners for w in ws) and set(ws) & kind_words:
            hits.append((name, unit))
        elif len(ws) == 1 and ws[0] in ("timeus", "timems"):
            hits.append((name, ws[0][4:]))
        elif kind_words is TIME_WORDS and words(name) in (["ms"], ["us"], ["µs"], ["millis"], ["micros"]):
            # a column named only by its unit: an Arduino sketch printing millis() or micros()
            hits.append((name, {"millis": "ms", "micros": "us"}.get(words(name)[0], words(name)[0])))
    return hits


def _find_one(names, canonical: str, kind_words, unit_table):
    """(column, unit word or None): the canonical column if present, else the only one named by kind_words."""
    if canonical in names:
        return canonical, None
    return _single(names, kind_words, unit_table)


def find_time(names, units: dict, values=None, sensor=None):
    """(column, factor to seconds) or None. The unit comes from the units map, else the name's unit
    word (TimeUS, time_ms), else seconds — except a unitless `timestamp` stepping by ≥ 1000 per row
    (`values`: the columns), which is PX4's microseconds, and Unix times too large for seconds (above
    1e11: ms, 1e14: µs, 1e17: ns). A stated unit that is not a time unit ("ticks") is not guessed: None.
    Several time columns are one clock when their steps agree in seconds (Sensor Logger's epoch `time` and
    `seconds_elapsed`): the first is taken. Clocks that disagree are not guessed: None. `sensor` (the
    magnetometer's column names) picks the magnetometer's own clock among one per sensor (SensorLog's
    magnetometerTimestamp_sinceReboot beside accelerometerTimestamp_sinceReboot …). A host's clock (t_host, which
    `fluxcal record` adds) is the time only when the device's own is not there: t, time, millis win."""
    hits = [("t", None)] if "t" in names else (_own_clock(names, sensor) or _named(names, TIME_WORDS, TIME_UNITS))
    hits = _dated_last(hits, units)
    # the host stamps a chunk when it reads it (latency, several rows per stamp); the device stamps each sample
    hits = [hit for hit in hits if "host" not in words(hit[0])] or hits
    times = [_time_unit(name, word, units, values) for name, word in hits]
    if not times or None in times:
        return None
    if len(times) > 1 and not (values is not None and _one_clock(times, values)):
        return None
    return times[0]


# words that say whose or which clock a time column is (rtcTime, loggingTime, timestamp_sinceReboot)
# ("host": t_host, host_time, the time a logging computer received the row)
CLOCK_WORDS = {"rtc", "logging", "log", "system", "sys", "since", "reboot", "boot", "epoch", "unix", "1970", "host"}
# a date beside the time in one column: DateTime, Date Time, German Datum/Zeit
DATE_WORDS = {"date", "datum", "fecha"}


def _dated_last(hits, units: dict) -> list:
    """The time columns `hits` [(name, word)] with those named by a date (DateTime, Datum/Zeit) taken only when
    no other is there, and only when their stamps were read as text into seconds (a stated unit): a number
    under such a name (Excel's serial days, 20261129) is not guessed to be seconds."""
    plain = [hit for hit in hits if not set(words(hit[0])) & DATE_WORDS]
    return plain or [hit for hit in hits if units.get(hit[0])]


def _own_clock(names, sensor) -> list:
    """[(column, None)] for the one column named by the sensor's own words, a time word and clock words
    (magnetometerTimestamp_sinceReboot for magnetometerX..Z), else []."""
    if not sensor:
        return []
    prefix = [w for w in words(sensor[0]) if w not in _AXES]
    if not prefix or prefix != [w for w in words(sensor[1]) if w not in _AXES]:
        return []
    hits = []
    for name in names:
        ws = words(name)
        rest = ws[len(prefix):]
        if ws[:len(prefix)] == prefix and set(rest) & TIME_WORDS and set(rest) <= TIME_WORDS | CLOCK_WORDS:
            hits.append((name, None))
    return hits if len(hits) == 1 else []


def _one_clock(times, values) -> bool:
    """Whether the time columns `times` [(name, factor)] step alike: each step within 0.1 % of a typical step."""
    steps = [np.diff(np.asarray(values[name], float) * factor) for name, factor in times]
    if len(steps[0]) == 0 or not all(np.all(np.isfinite(s)) for s in steps):
        return False
    tolerance = 1e-3 * float(np.median(np.abs(steps[0])))
    return tolerance > 0 and all(np.max(np.abs(s - steps[0])) <= tolerance for s in steps[1:])


def _time_unit(name: str, word, units: dict, values):
    """(name, factor to seconds) of one time column (see find_time), or None for a stated non-time unit."""
    stated = (units.get(name) or "").strip().lower().replace("μ", "µ")
    if stated:
        return (name, TIME_UNITS[stated]) if stated in TIME_UNITS else None
    if word is None and "timestamp" in words(name) and values is not None and len(values[name]) > 1:
        if np.median(np.diff(values[name])) >= 1000.0:
            return name, 1e-6
    if word is None and values is not None and len(values[name]):
        # Unix time without a unit: seconds since 1970 stay below 1e11 until the year 5138, so larger values
        # are milli-, micro- or nanoseconds (Android's Sensor Logger writes epoch nanoseconds as "time")
        size = float(np.nanmedian(np.abs(values[name])))
        for limit, factor in ((1e17, 1e-9), (1e14, 1e-6), (1e11, 1e-3)):
            if size > limit:
                return name, factor
    return name, TIME_UNITS.get(word or "", 1.0)


def find_temperature(names, units: dict):
    """(column, unit "C"/"K"/"F") or None."""
    hit = _find_one(names, "temp", TEMP_WORDS, TEMP_UNITS) or _named_by_degrees(names)
    if hit is None:
        return None
    name, word = hit
    unit = temperature_unit(name, units, word)
    return None if unit is None else (name, unit)


def temperature_unit(name: str, units: dict, word=None):
    """"C", "K" or "F" of a temperature column: its stated unit, else the unit word of its name (`word`, or
    the name's last word), else "C"; None for a stated unit that is not °C, K or °F (mdegC, raw: not guessed)."""
    stated = (units.get(name) or "").strip().lower().replace("°", "").replace("deg", "")
    if stated:
        return TEMP_UNITS.get(stated)
    return TEMP_UNITS.get(word if word is not None else (words(name) or [""])[-1], "C")


# a temperature in its unit → °C
TO_CELSIUS = {"C": lambda v: v, "K": lambda v: v - 273.15, "F": lambda v: (v - 32.0) / 1.8}


def _named_by_degrees(names):
    """(column, unit word) of the only column named by a sensor word and degrees Celsius or Fahrenheit alone
    (SparkFun OpenLog Artemis's imu_degC), else None: degC says temperature as a field unit says field."""
    hits = []
    for name in names:
        ws = words(name)
        unit = "".join(ws[-2:]) if ws[-2:-1] == ["deg"] else ws[-1] if ws else ""  # deg C, degC
        rest = ws[:-2] if ws[-2:-1] == ["deg"] else ws[:-1]
        if unit in ("degc", "degf") and rest and set(rest) <= {"imu", "sensor", "die", "chip", "board", "mag", "cpu",
                                                               "mcu"}:
            hits.append((name, unit))
    return hits[0] if len(hits) == 1 else None


# a reading's place on Earth (GPS/GNSS logs, a satellite's orbit): the IGRF's field there
LATITUDE_WORDS, LONGITUDE_WORDS = {"lat", "latitude"}, {"lon", "lng", "long", "longitude"}
ALTITUDE_WORDS = {"alt", "altitude", "height"}
POSITION_OWNERS = {"gps", "gnss", "pos", "position", "geodetic", "wgs84"}
ANGLE_UNITS = {"deg", "degree", "degrees", "°", "degrees_north", "degrees_east", "degree_north", "degree_east"}
ALTITUDE_UNITS = {"m": 1e-3, "meter": 1e-3, "meters": 1e-3, "metre": 1e-3, "metres": 1e-3, "km": 1.0,
                  "kilometers": 1.0, "kilometres": 1.0, "ft": 0.3048e-3, "feet": 0.3048e-3, "foot": 0.3048e-3}  # → km


def find_position(names, units: dict):
    """The columns of each reading's place: {"lat": column, "lon": column, "alt": column or None, "alt_km": factor to
    km, "alt_unit": the unit taken, "alt_unit_assumed": True when nothing said it (m)} from latitude and longitude columns (lat, Latitude,
    GPS_Lat, lat [deg], in degrees) and an altitude column (alt, Altitude, height, alt_km; m unless its stated unit
    or name says another length); None without latitude or longitude. ValueError naming the columns when more
    than one could be a coordinate (GPS_Lat and POS_Lat), or when a coordinate's stated unit is not degrees or a
    length: not guessed."""
    def only(kind_words, unit_words, what):
        hits = []
        for name in names:
            ws = words(name)
            unit = ws[-1] if len(ws) > 1 and ws[-1] in unit_words else None
            ws = ws[:-1] if unit else ws
            if ws and set(ws) & kind_words and set(ws) <= kind_words | POSITION_OWNERS:
                hits.append(name)
        if len(hits) > 1:
            raise ValueError(f"{what}: columns {', '.join(hits)} could each be it; keep one (or rename the others)")
        return hits[0] if hits else None

    lat, lon = only(LATITUDE_WORDS, ANGLE_UNITS, "latitude"), only(LONGITUDE_WORDS, ANGLE_UNITS, "longitude")
    if lat is None or lon is None:
        return None
    for column in (lat, lon):
        stated = (units.get(column) or "").strip().lower()
        if stated and stated not in ANGLE_UNITS:
            raise ValueError(f"column {column}: stated in {units[column]}, not degrees")
    alt = only(ALTITUDE_WORDS, set(ALTITUDE_UNITS), "altitude")
    unit = None
    if alt is not None:
        stated = (units.get(alt) or "").strip().lower()
        if stated and stated not in ALTITUDE_UNITS:
            raise ValueError(f"column {alt}: stated in {units[alt]}, not a length (m, km, ft)")
        word = words(alt)[-1]
        unit = stated or (word if word in ALTITUDE_UNITS else None)
    return {"lat": lat, "lon": lon, "alt": alt, "alt_km": ALTITUDE_UNITS[unit or "m"], "alt_unit": unit or "m",
            "alt_unit_assumed": alt is not None and unit is None}


def find_current(names, units: dict):
    """(column, factor to amperes) or None: the column current, else the only one named by a current word
    (current, curr, amps) with at most whose current it is (motor, battery, heater, ...) and a unit (A,
    mA). A stated unit that is not A or mA is not guessed: None."""
    hits = [("current", None)] if "current" in names else []
    for name in [] if hits else names:
        ws, unit = _peel_unit(words(name), CURRENT_UNITS)
        if ws and set(ws) & CURRENT_WORDS and set(ws) <= CURRENT_WORDS | CURRENT_QUALIFIERS:
            hits.append((name, unit))
    if len(hits) != 1:
        return None
    name, unit = hits[0]
    stated = (units.get(name) or "").strip().lower()
    if stated:
        return (name, CURRENT_UNITS[stated]) if stated in CURRENT_UNITS else None
    return name, CURRENT_UNITS.get(unit or "", 1.0)


def unit_name(word: str) -> str:
    """A unit word as a recording writes it: uTesla, µT, [uT] → uT; gauss, Ga → G; tesla → T (others as
    given, stripped)."""
    w = word.strip().strip("[]()").lower().replace("\u03bc", "\u00b5")
    return "T" if w == "tesla" else FIELD_UNITS.get(w, word.strip())


def is_field_unit(word: str) -> bool:
    """Whether a unit word names a magnetic field's unit (nT, µT, gauss, tesla, counts …; see unit_name)."""
    return unit_name(word) in set(FIELD_UNITS.values()) | {"T"}


def field_unit_of(name: str) -> str:
    """The field unit a column's name carries (mag_x_uT -> "uT"; PX4's magnetometer_ga[0] -> "G", its unit before
    the axis's index), "" when none."""
    ws = words(name)
    if len(ws) > 2 and ws[-1] in ("0", "1", "2", "3") and ws[-2] in FIELD_ONLY_UNITS:
        return unit_name(ws[-2])
    _, unit = _peel_field_unit(ws)
    return unit_name(unit) if unit else ""


_RATE_KEYS = {"updaterate", "outputrate", "samplingfrequency", "samplefrequency", "fs", "rate", "samplerate", "samplingrate", "samplerate hz", "odr", "datarate", "frequency", "freq"}


def sample_rate(metadata: dict):
    """(key, rate in Hz) from metadata such as `sample_rate_hz: 50`, `Fs: 50`, `rate: 100 Hz`, `odr: 10`
    (a value in kHz is converted), or None."""
    for key, value in metadata.items():
        ws = words(str(key))
        unit = "khz" if "khz" in ws else "hz"
        name = "".join(w for w in ws if w not in ("hz", "khz"))
        if name not in _RATE_KEYS and name.replace("sampling", "sample") not in _RATE_KEYS:
            continue
        text = str(value).strip().lower()
        if text.endswith("khz"):
            unit, text = "khz", text[:-3]
        elif text.endswith("hz"):
            text = text[:-2]
        try:
            rate = float(text) * (1000.0 if unit == "khz" else 1.0)
        except ValueError:
            continue
        if rate > 0 and np.isfinite(rate):
            return key, rate
    return None


# How a number's commas read (a text log's `X: 1,234`): one helper for the file readers and the serial recorder
_THOUSANDS_GROUPS = r"[+-]?[1-9]\d{0,2}(?:,\d{3})+"
_COMMA_FORMS = (("ambiguous", re.compile(r"[+-]?[1-9]\d{0,2},\d{3}(?:[eE][+-]?\d+)?")),
                ("several", re.compile(_THOUSANDS_GROUPS + r"(?:[eE][+-]?\d+)?")),
                ("thousands", re.compile(_THOUSANDS_GROUPS + r"\.\d*(?:[eE][+-]?\d+)?")),
                ("decimal", re.compile(r"[+-]?\d*,\d+(?:[eE][+-]?\d+)?")))


def comma_kind(number: str) -> str:
    """What the commas of a number's text may be. "" (no comma); "decimal": a decimal comma that cannot be a
    thousands separator (12,34  0,123  -0,5  1234,5  ,5); "ambiguous": one comma before three digits after
    one to three (1,234: 1.234 with a decimal comma, 1234 with a thousands separator); "several": commas
    between three-digit groups (1,234,567: thousands separators, never a decimal comma — or fields run
    together); "thousands": thousands groups before a decimal point (1,234.5: cannot be a decimal comma);
    "invalid": any other comma (1,2,3  1,23.4  12,345.6,7)."""
    text = number.strip()
    if "," not in text:
        return ""
    return next((kind for kind, form in _COMMA_FORMS if form.fullmatch(text)), "invalid")


# A column telling apart compasses whose rows one table interleaves: mavlogdump's MAG `I`, PX4's `device_id`
INSTANCE_NAMES = {"i", "inst", "instance", "id", "deviceid", "sensorid", "compass", "compassid", "magid",
                  "maginstance", "multiid"}


# Of those, names any numbered column may have (a position or status id): an instance only when its rows interleave
GENERIC_INSTANCE_NAMES = {"id", "sensorid"}


def find_instance(columns: dict):
    """(name, values, row counts) of an instance column: named as one (INSTANCE_NAMES, case, '_' and spaces aside),
    whole numbers in every row, 2 to 8 of them each on 3 rows or more (a row counter has hundreds), else None. A
    generic name (GENERIC_INSTANCE_NAMES: id) counts only when its rows interleave — the value changes from one row to
    the next at least as often as the rarest value appears, as compasses logged in turn do: a position or status
    number held over blocks of rows (id 1…6, 50 rows each) is no compass, and all its rows are read. A compass's
    own name (I, instance, device_id, compass…) holds in bursts or sorted by instance too (a FIFO's runs of ten, one
    table per compass joined: each compass's rows fitted alone)."""
    for name, values in columns.items():
        key = re.sub(r"[\s_\-]", "", name.lower())
        if key not in INSTANCE_NAMES:
            continue
        values = np.asarray(values, dtype=float)
        if not np.isfinite(values).all() or (values != np.round(values)).any():
            continue
        kinds, counts = np.unique(values, return_counts=True)
        if not (2 <= len(kinds) <= 8 and counts.min() >= 3):
            continue
        if key not in GENERIC_INSTANCE_NAMES or np.count_nonzero(np.diff(values)) >= counts.min():
            return name, kinds, counts
    return None
