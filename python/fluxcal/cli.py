"""The `fluxcal` command line."""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import re
import sys
import warnings
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from . import __version__, cmake_dir
from ._arrays import past_range
from .calibration import SCALE_WORDS, TESLA_PER_UNIT, Calibration, _significant, in_sensor_axes, json_path, scale_words
from .io import Recording, read_csv, read_recording, write_csv, write_recording
from .io.formats import WRITERS
from .io.columns import LARGE_CURRENT_UNITS, unit_name
from .io.csv import quiet_skipped, skipped_words
from .pipeline import METHODS, PLAUSIBLE_WORDS, UNITS_WORDS, calibrate, noise_line, plausible_field
from .planar import plane_axes


def _dof_or_inf(text: str) -> float:
    """argparse type of degrees of freedom: a positive number, or inf (exact)."""
    return float("inf") if text.strip().lower() in ("inf", "infinity") else positive_number(text)


def positive_number(text: str, zero: bool = False) -> float:
    """argparse type of a magnitude (--field-norm, --noise-sigma): a positive finite number, so that the error
    names the option instead of the solver's option struct deep inside; with `zero`, 0 too."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (np.isfinite(value) and (value > 0 or (zero and value == 0))):
        raise argparse.ArgumentTypeError(f"{text} is not a {'non-negative' if zero else 'positive'} finite number")
    return value


def sigma_or_per_axis(text: str):
    """argparse type of diagnose's --noise-sigma: one positive finite σ, or three separated by commas (x, y, z: a
    datasheet's per axis), a list then."""
    parts = text.split(",")
    if len(parts) == 1:
        return positive_number(text)
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"{text!r}: need one σ, or three separated by commas (x, y, z)")
    return [positive_number(p.strip()) for p in parts]


def three_sigmas(text: str) -> list:
    """argparse type of calibrate's --noise-sigma: three positive finite σ separated by commas (x, y, z)."""
    parts = text.split(",")
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"{text!r}: need three σ separated by commas (x, y, z), got {len(parts)}"
                                         + (": one σ for every axis weights nothing" if len(parts) == 1 else ""))
    return [positive_number(p.strip()) for p in parts]


def norm_or_column(text: str):
    """argparse type of calibrate's and diagnose's --field-norm: a positive finite number, or a column holding each
    reading's |field| (not a number: a scalar magnetometer's log, an observatory's F)."""
    try:
        float(text)
    except ValueError:
        return text.strip()
    return positive_number(text)


def non_negative_number(text: str) -> float:
    """argparse type of a noise level (--noise): finite, ≥ 0 (NaN wrote a recording of NaN)."""
    return positive_number(text, zero=True)


def positive_int(text: str) -> int:
    """argparse type of a count (--repeats, --workers): a whole number ≥ 1."""
    try:
        value = int(text)
    except ValueError:  # else argparse names this function: "invalid positive_int value"
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text} is not a positive whole number")
    return value


def _spread(values: np.ndarray) -> float:
    norm = np.linalg.norm(values, axis=1)
    return float(norm.std() / norm.mean())


def _report(cal: Calibration, raw: np.ndarray, out=None, t=None) -> None:
    """The calibration's printout (to `out`, default the sys.stdout of the call, not of the import); `t` (the
    readings' times, or None for row order) orders them for the noise estimate from differences."""
    out = sys.stdout if out is None else out
    s = cal.summary
    print(cal, file=out)
    print(f"  samples used          {s['samples']}", file=out)
    print(f"  |h| std/mean before   {100 * _spread(raw):.3f} %   (raw |m|)", file=out)
    own = "   (|h| against each reading's own |field|)" if "field_norms" in s else ""
    print(f"  |h| std/mean after    {100 * s['norm_std_over_mean']:.3f} %{own}", file=out)
    print(f"  residual RMS          {s['residual_rms']:.6g} {cal.h_units}".rstrip(), file=out)
    print(f"  condition number      {s['condition_number']:.3g}", file=out)
    print(f"  coverage              {100 * s['direction_coverage']:.0f} % of directions, thinnest/widest "
          f"spread {s['coverage_ratio']:.2f}, direction scatter eigenvalues "
          f"{', '.join(f'{v:.2f}' for v in s['direction_eigenvalues'])} (1/3 each = full sphere)", file=out)
    if "method" in s:
        print(f"  method                {s['method']}", file=out)
    if "shapes" in s:  # what each shape refined scored (all three under auto; a forced one beside sym)
        print(f"  shape                 {s['shape']} (BIC: {_shape_scores(s['shapes'])})", file=out)
    elif s.get("shape", "sym") != "sym":
        print(f"  shape                 {s['shape']}", file=out)
    note = f"; {s['held_out_note']}" if s.get("held_out_note") else ""  # why a check of the first half says little
    if "held_out_spread" in s:
        spread = s["held_out_spread"]
        print("  held-out |h| std/mean " + (f"{100 * spread:.3f} %   (fit on the first half, judged on the second{note})"
                                            if isinstance(spread, float) else f"—   ({spread})"), file=out)
    if "held_out_rms" in s:
        rms = s["held_out_rms"]
        print("  held-out vector RMS   " + (f"{rms:.6g} {cal.h_units}   (fit on the first half, |h - reference| on "
                                            f"the second{note})" if isinstance(rms, float) else f"—   ({rms})"),
              file=out)
    if s.get("noise_sigma"):
        # the σ the residuals imply: the sensor's noise only when the model fits (the airborne segment's magnitude
        # fit gave 68 nT, its readings' differences 0.42 nT), so named for what it is, with the readings' own beside it
        unit = f" {cal.units}" if cal.units else ""
        print(f"  residual σ            {s['noise_sigma']:.4g}{unit}   (from the fit's residuals: the noise plus "
              "whatever the model misses)", file=out)
        if s.get("axis_noise"):  # (refine's noise_sigma: the residuals are in units of each axis's own noise)
            print(f"  axes weighted         σ x, y, z {', '.join(f'{v:.4g}' for v in s['axis_noise'])}{unit}   (the "
                  "given ratios at the residual σ: each axis in units of its own noise)", file=out)
        line = noise_line(s, unit, raw, t)
        if line:
            print(line, file=out)
    if "standard_errors" in s:
        se = np.array(s["standard_errors"])
        # Not identifiable: the errors are those of the directions the data do determine (or of a shape's
        # assumption) and say nothing of the rest — a 30° cap printed 0.09 µT beside a 2–3 µT error.
        caveat = "" if s["identifiable"] else "   (NOT the error: the data do not determine every parameter)"
        print(f"  std error of b        {_significant(se[:3], 3)} {cal.units}{caveat}".rstrip(), file=out)
        # judged on the independent-readings errors (refine): beside Newey–West-widened ones (the airborne segment's
        # 4.25 µT of 54 µT) a bare "yes" read as a contradiction
        widened = s.get("serial_correlation", {}).get("lags", 0) > 0
        why = ("   (judged on the Fisher information of independent readings; the std errors above are widened for "
               "readings correlated in time)" if widened else "")
        print(f"  identifiable          {'yes' if s['identifiable'] else 'NO'}{why}", file=out)
    elif "identifiable" in s:  # a verdict without errors (TWOSTEP's exact fit of 9 readings)
        print(f"  identifiable          {'yes' if s['identifiable'] else 'NO'}   (no standard errors)", file=out)
    for w in s["warnings"]:
        print(f"warning: {w}", file=out)


def _shape_scores(table: dict) -> str:
    """Each refined shape's BIC and, for one not kept, why: the data reject it (its BIC above the lowest by more
    than REJECTED_BIC: it misfits, however well its parameters are determined) or they do not determine it
    (its terms trade off, as on a cap of orientations)."""
    from .pipeline import REJECTED_BIC

    lowest = min((v["bic"] for v in table.values() if "bic" in v), default=0.0)
    scores = []
    for name, row in table.items():
        if "bic" not in row:
            scores.append(f"{name} failed")
            continue
        excess = row["bic"] - lowest
        why = (f"rejected by BIC: +{excess:.0f}" if excess > REJECTED_BIC else
               "" if row["identifiable"] else "not determined by the data")
        scores.append(f"{name} {row['bic']:.1f}" + (f" ({why})" if why else ""))
    return ", ".join(scores)


PLANES = ("auto", "xy", "xz", "yz")  # calibrate --planar's values


def _plane_option(text: str) -> str:
    """--planar's value; a file name there (`--planar log.csv`: the option takes the word after it) is said so."""
    if text.lower() in PLANES:
        return text.lower()
    raise argparse.ArgumentTypeError(f"{text!r} is not a plane ({', '.join(PLANES)}): the file goes before the option "
                                     "(fluxcal calibrate FILE --planar), or name the plane first (--planar xy FILE)")


def reading_unit(text: str) -> str:
    """--units: a field unit (T, mT, uT/µT, nT, G, mG, as loggers spell them) or counts; anything else is an
    error here, not a label that only apply would stumble on."""
    unit = unit_name(text)
    if unit not in TESLA_PER_UNIT and unit != "counts":
        raise argparse.ArgumentTypeError(f"{text!r} is not a field unit ({', '.join(TESLA_PER_UNIT)}) or counts")
    return unit


def _recheck_field_norm(cal: Calibration, units: str, field_units: str) -> None:
    """The solver compares a given field norm with the readings' radius in one unit ("check the units" beyond
    5×); with --field-units naming another unit than the readings' that comparison is void: it is redone
    with both in tesla where the two units are field units, and dropped for counts."""
    warnings = [w for w in cal.summary.get("warnings", []) if UNITS_WORDS not in w and SCALE_WORDS not in w]
    said = scale_words(cal, units_too=True)  # (cal.field_units is set: both in tesla)
    cal.summary["warnings"] = warnings + ([said] if said else [])


def judge_field_again(cal: Calibration, units: str, field_units: str | None) -> None:
    """The warnings on the field's size judged again once cal.field_units says h's unit: the norm against the readings
    (`_recheck_field_norm`) when `field_units`, the given norm's unit, differs from the readings', and its
    plausibility as the Earth's field in h's unit (`fluxcal calibrate` and `fluxcal batch` with --field-units)."""
    if field_units and unit_name(field_units) != units:
        _recheck_field_norm(cal, units, unit_name(field_units))
    said = plausible_field(cal)
    cal.summary["warnings"] = [w for w in cal.summary["warnings"] if not w.startswith(PLAUSIBLE_WORDS)] + (
        [said] if said else [])


def _field_units(args, units: str, field_norm, reference) -> str | None:
    """The unit of the corrected field h: --field-units; else the readings' unit when it is a field unit or no
    norm was given (h is then in the readings' unit); "" (not stated) for counts fitted to a given norm."""
    if args.field_units:
        return unit_name(args.field_units)
    if field_norm is None or reference is not None or units in TESLA_PER_UNIT:
        return None
    print(f"note: the readings are in {units or 'no stated unit'}; |h| = {np.mean(field_norm):g} is in the unit of "
          "--field-norm, which --field-units names (the calibration then says it)")
    return ""


def _held_out_rms(raw, reference, units, cal: Calibration, outliers=()) -> tuple:
    """Vector-fit check on data the fit did not see: fit the first half, RMS of |h − r| on the second, without
    the rows the whole fit left out as outliers (4 spikes made 11.9 µT of a 0.66 µT check). Returns (RMS, note) as
    _held_out_spread does."""
    half = len(raw) // 2
    try:
        first = calibrate(raw[:half], reference=reference[:half], units=units)
    except ValueError as exc:
        return _first_half_unfit(raw, cal, exc), ""
    kept = np.setdiff1d(np.arange(half, len(raw)), np.asarray(outliers, dtype=int))
    rms = float(np.sqrt(np.mean(np.sum((first.apply(raw[kept]) - reference[kept]) ** 2, axis=1))))
    # (no "worse than the whole fit" to compare with: the whole fit's own RMS is of the readings it was fitted on)
    return rms, _first_half_note(raw, cal, first, worse=True, coverage=False)


def _held_out_spread(raw, cal: Calibration, field_norm, settings: dict) -> tuple:
    """Magnitude-fit check on data the fit did not see: the same method and shape fitted on the first half, the
    spread std/mean of |h| on the second without the whole fit's outliers (the spread a peer's fit is judged
    by). Returns (spread, note): the note says why the spread says little of the whole fit when it is far above
    the whole fit's and the first half turned through far fewer directions; or (why the first half alone
    cannot be fitted, "")."""
    half = len(raw) // 2
    per_reading = np.ndim(field_norm) > 0  # each reading's own |field|: the spread of |h| over it
    try:
        first = calibrate(raw[:half], field_norm=field_norm[:half] if per_reading else field_norm,
                          shape=cal.summary.get("shape", "auto"), **settings)
    except ValueError as exc:
        return _first_half_unfit(raw, cal, exc), ""
    kept = np.setdiff1d(np.arange(half, len(raw)), np.asarray(cal.summary.get("outliers", {}).get("rows", []), int))
    norms = np.linalg.norm(first.apply(raw[kept]), axis=1) / (field_norm[kept] if per_reading else 1.0)
    spread = float(norms.std() / norms.mean())
    worse = spread > HELD_OUT_WORSE * cal.summary["norm_std_over_mean"]
    return spread, _first_half_note(raw, cal, first, worse)


# The held-out check said to say little of the whole fit when it is this many times the whole fit's spread and its
# first half covers under FIRST_HALF_COVERAGE of the directions the whole recording does (a recording that starts
# still: 10 turning readings in a first half of 2990 gave 5.3 % against 0.49 %; the report's 156 %).
HELD_OUT_WORSE = 2.0
FIRST_HALF_COVERAGE = 0.5


def _coverages(raw, cal: Calibration) -> tuple:
    """The share of the field directions the first half of the readings and all of them visit, as the whole fit
    corrects them."""
    from .coverage import direction_coverage

    h = cal.apply(raw)
    return direction_coverage(h[:len(raw) // 2]), direction_coverage(h)


def _still_start(first: float, whole: float) -> str:
    return (f"its readings cover {100 * first:.0f} % of the field directions, the whole recording's {100 * whole:.0f} % "
            "(still, or turned little, at the start?)")


def _first_half_unfit(raw, cal: Calibration, exc: ValueError) -> str:
    """Why the held-out check has no number: the first half alone cannot be fitted; when it turned through far
    fewer directions than the whole recording (a still start), said as the reason."""
    error = str(exc).split(";")[0]
    first, whole = _coverages(raw, cal)
    if first < FIRST_HALF_COVERAGE * whole:
        return (f"the first half alone does not determine the fit: {_still_start(first, whole)}, and its own fit "
                f"fails ({error}); the whole fit is judged by the lines above")
    return f"the first half alone cannot be fitted: {error}"


def _first_half_note(raw, cal: Calibration, first: Calibration, worse: bool, coverage: bool = True) -> str:
    """Why a held-out number far above the whole fit's says little of it: the first half's fit, which made it,
    is not determined by its readings or (with `coverage`: a magnitude fit, which needs the directions; a vector
    fit's reference vectors do not) saw far fewer directions (a still start); "" otherwise."""
    if not worse:
        return ""
    if not first.summary.get("identifiable", True):
        return ("the first half alone does not determine the fit (identifiable NO on its own), so this is of that "
                "poorer fit, not of the whole one")
    if not coverage:
        return ""
    mine, whole = _coverages(raw, cal)
    if mine < FIRST_HALF_COVERAGE * whole:
        return (f"the first half alone does not determine the fit well: {_still_start(mine, whole)}, so this is of "
                "that poorer fit, not of the whole one")
    return ""


# A list of row numbers in a message: "rows 600, 700, 900", "row 12", "rows 2953–2999 (up to 7 σ), 9653–9660 (up to
# 5 σ), …" (each number or range with an optional note in parentheses)
_ROW_ITEM = r"\d+(?:–\d+)?(?: \([^()]*\))?"
_ROW_LIST = re.compile(rf"\brows? ({_ROW_ITEM}(?:, {_ROW_ITEM})*(?:, …)?)")


def _with_file_lines(message: str, line_numbers) -> str:
    """`message` with every list of (0-based) row numbers followed by the file lines they were read from (after a
    header, comments or skipped lines the two differ): "; file lines …" inside parentheses, " (file lines …)"
    elsewhere. The one place calibrate's warnings that name rows (outliers left out, stretches kept) get them."""
    def lines(match):
        items = re.findall(r"(\d+)(?:–(\d+))?(?: \([^()]*\))?", match.group(1))
        if any(int(x) >= len(line_numbers) for first, last in items for x in (first, last) if x):
            return match.group(0)  # (not rows of this recording)
        shown = ", ".join(str(line_numbers[int(first)]) + (f"–{line_numbers[int(last)]}" if last else "")
                          for first, last in items) + (", …" if match.group(1).endswith("…") else "")
        word = "file lines" if len(items) > 1 or items[0][1] or match.group(1).endswith("…") else "file line"
        inside = message[:match.start()].count("(") > message[:match.start()].count(")")
        return match.group(0) + (f"; {word} {shown}" if inside else f" ({word} {shown})")

    if line_numbers is None or "file line" in message:
        return message
    return _ROW_LIST.sub(lines, message)


def _name_file_lines(cal: Calibration, rec: Recording) -> None:
    """The calibration's warnings that name rows also name their file lines; the outliers' file lines kept in
    the summary beside their rows."""
    if rec.line_numbers is None:
        return
    rows = cal.summary.get("outliers", {}).get("rows", [])
    if rows:
        cal.summary["outliers"]["file_lines"] = [int(rec.line_numbers[r]) for r in rows]
    cal.summary["warnings"] = [_with_file_lines(w, rec.line_numbers) for w in cal.summary["warnings"]]


def _reference(rec: Recording, names: str | None, file) -> tuple:
    """The true field per reading and its unit: --reference's three columns, else the recording's attitude and
    local field (Recording.reference_field), else None. Columns in another field unit than the readings' are
    converted to it; against readings in counts they keep theirs (the corrected field is then in it)."""
    if not names:
        reference = rec.reference_field()
        return reference, rec.reference_units() if reference is not None else rec.field_units()
    names = names.split(",")
    missing = [n for n in names if n not in rec.columns]
    if len(names) != 3 or missing:
        what = (f"no column {', '.join(map(repr, missing))} in {file}" if missing and len(names) == 3 else
                f"{len(names)} names, need three columns of {file}")
        raise ValueError(f"--reference: {what} (columns are: {', '.join(rec.columns)})")
    units, mag = {unit_name(rec.units.get(n, "")) for n in names}, rec.field_units()
    if len(units) > 1:
        raise ValueError(f"--reference: the columns {', '.join(names)} have different units ({', '.join(sorted(units))})")
    unit = units.pop()
    scale = TESLA_PER_UNIT[unit] / TESLA_PER_UNIT[mag] if unit in TESLA_PER_UNIT and mag in TESLA_PER_UNIT else 1.0
    reference = np.column_stack([rec.columns[n] for n in names]) * scale
    bad = np.argwhere(~np.isfinite(reference))
    if bad.size:
        row, k = (int(v) for v in bad[0])
        raise ValueError(f"--reference: {file}, {rec.place(row)}: column {names[k]!r} is {rec.columns[names[k]][row]} "
                         f"(not a finite number; {len(np.unique(bad[:, 0]))} such rows)")
    return reference, mag if scale != 1.0 or unit == mag or not unit else unit


REFERENCE_NAMES = ("rx", "ry", "rz", "ref_x", "ref_y", "ref_z", "bx_ref", "by_ref", "bz_ref")


def _note_reference_columns(rec: Recording, reference, method: str) -> None:
    """Columns that look like reference vectors but are not used: said, not silently left (a magnitude fit
    loses the misalignment a vector fit would find)."""
    unused = [n for n in rec.columns if n.lower() in REFERENCE_NAMES]
    if reference is None and len(unused) >= 3 and method in ("auto", "vector"):
        print(f"note: columns {', '.join(unused)} look like reference vectors (the true field per reading) but are not "
              f"used: give --reference {','.join(unused[:3])} for the vector fit (the full matrix, misalignment included)")


def _reference_role(rec: Recording, names: str | None) -> str:
    """The columns a vector fit takes its reference from, for the columns line: --reference's, else the attitude
    and local field (Recording.reference_field), with their units and the attitude convention."""
    from .io.recording import ATTITUDE_COLUMNS, FIELD_NED_COLUMNS

    def with_unit(columns):
        units = {rec.units.get(c, "") for c in columns}
        return ",".join(columns) + (f" ({units.pop()})" if len(units) == 1 and "" not in units else "")

    if names:
        return f"reference {with_unit(names.split(','))} (--reference)"
    convention = rec.metadata.get("attitude_convention", "aerospace")
    return (f"reference attitude {with_unit(ATTITUDE_COLUMNS)}, {convention} convention, with local field "
            f"{with_unit(FIELD_NED_COLUMNS)}")


def _print_roles(rec: Recording, reference: str | None = None, rails: bool = True):
    """Say which columns were taken for what (so a name-guessed choice is visible), the reference's (`reference`,
    from _reference_role) among them, and which lines and text columns the reader left out. `rails`: and an axis on
    a rail (not for calibrate, whose summary says it with what it did about it)."""
    print("columns: " + "; ".join([f"{role} {names}" for role, names in rec.roles().items()]
                                  + ([reference] if reference else [])))
    from .outliers import rail_words

    said = rails and rail_words({n: rec.columns[n] for n in rec.mag_names()})
    if said:
        print(f"warning: {said}")
    if "skipped_lines" in rec.metadata:
        print(skipped_words(rec.metadata['skipped_lines']))
    if "units_from_note" in rec.metadata:  # `fluxcal record` of a device that printed its units late
        print(f"units from the recorder's note at {rec.metadata['units_from_note']}")
    if "repeated_header" in rec.metadata:  # a logger restarted, or two logs joined: the rows below it are read on
        print(f"the header again at {rec.metadata['repeated_header']}: passed over, the rows on both sides read")
    if "text_columns" in rec.metadata:
        print(f"text columns not used: {rec.metadata['text_columns']}")
    if "blank_cells" in rec.metadata:  # in columns the magnetometer does not need (a temperature left out)
        print(f"blank cells: {rec.metadata['blank_cells']}")
    if "units_in_cells" in rec.metadata:  # "12.3uT": a logger that prints each value's unit
        print(f"units in the cells: {rec.metadata['units_in_cells']}")
    # which compass of several, and what the logger had already done to its readings (a flight log's, or a table
    # interleaving compasses by an instance column): an answer for the wrong one looks as plausible as the right one
    for key, label in (("instance", "compass instance"), ("instances", "instances in the file"),
                       ("readings", "readings"), ("offsets_applied", "offsets already applied")):
        if rec.metadata.get(key):
            print(f"{label}: {rec.metadata[key]}")


def _field_norms_given(rec: Recording, name: str, args) -> np.ndarray:
    """--field-norm COLUMN (each reading's |field|; its unit, when the file states one, is --field-units') or
    --field-norm FILE (another recording's F, or its vector's magnitude, at this one's clock times)."""
    if name not in rec.columns and Path(name).is_file():
        return _field_norm_from(rec, name, args)
    if name not in rec.columns and name.lower() == "igrf":
        return _field_norm_igrf(rec, args)
    if name not in rec.columns:
        raise ValueError(f"--field-norm {name}: not a number, nor a column of {args.file} (columns: "
                         f"{', '.join(rec.columns)}), nor a file, nor igrf")
    if name in rec.mag_names():
        raise ValueError(f"--field-norm {name}: a magnetometer column; give the column of the true |field|")
    factor = _take_field_units(args, rec.units.get(name, ""), f"--field-norm {name}")
    values = rec.columns[name]
    bad = np.flatnonzero(~(np.isfinite(values) & (values > 0)))
    if bad.size:
        raise ValueError(f"{args.file}, {rec.place(int(bad[0]))}: column {name} reads {values[bad[0]]:g}; every "
                         "reading needs its positive |field| (a line with a non-number is left out by --bad-lines "
                         "skip)")
    print(f"field norm of each reading from column {name}" + (f" ({rec.units[name]})" if rec.units.get(name) else ""))
    return values * factor


def _field_norm_igrf(rec: Recording, args) -> np.ndarray:
    """--field-norm igrf: the IGRF's |F| at each reading's position (its latitude, longitude and altitude columns)
    and clock time: a satellite along its orbit, a survey flight."""
    from .positions import first_bad_place, igrf_magnitudes

    try:
        place = rec.position()
    except ValueError as exc:
        raise ValueError(f"--field-norm igrf: {args.file}: {exc}") from None
    t = rec.utc_seconds()
    if place is None:
        raise ValueError(f"--field-norm igrf: {args.file} has no latitude and longitude columns in degrees (lat, lon "
                         "and alt in m, or alt_km; GPS_Lat, Longitude, …) to evaluate the IGRF at")
    if t is None:
        raise ValueError(f"--field-norm igrf: {args.file} has no clock time (a time column of dates and times, or "
                         "Unix seconds) to date the IGRF by")
    lat, lon, alt, names = place
    bad = first_bad_place(lat, lon, alt)
    if bad is not None:
        column = names[{"latitude": "lat", "longitude": "lon", "altitude": "alt"}[bad[0]]]
        raise ValueError(f"--field-norm igrf: {args.file}, {rec.place(bad[1])}: column {column} reads "
                         f"{rec.columns[column][bad[1]]:g}, not a place on Earth")
    no_fix = (lat == 0.0) & (lon == 0.0)
    if no_fix.any():
        raise ValueError(f"--field-norm igrf: {args.file}, {rec.place(int(np.argmax(no_fix)))}: latitude and longitude "
                         "read 0, 0 (a GPS without a fix?); leave such lines out")
    try:
        norms = igrf_magnitudes(lat, lon, alt, t)
    except ValueError as exc:  # a date outside the model
        raise ValueError(f"--field-norm igrf: {args.file}: {exc}") from None
    checked = _altitude_unit_checked(rec, args, names, lat, lon, alt, t, norms) if names["alt_unit_assumed"] else ""
    factor = _take_field_units(args, "nT", "--field-norm igrf")
    days = sorted({datetime.fromtimestamp(x, timezone.utc).strftime("%Y-%m-%d") for x in (t.min(), t.max())})
    height = (f"{names['alt']} in {names['alt_unit']}"
              f"{' (no unit stated: assumed' + checked + ')' if names['alt_unit_assumed'] else ''}"
              f", {alt.min():.4g} to {alt.max():.4g} km" if names["alt"] else "no altitude column: 0 km")
    print(f"field norm of each reading from the IGRF (ppigrf) at its position ({names['lat']}, {names['lon']}; "
          f"{height}) and UTC date ({' to '.join(days)}): {norms.min():.1f} to {norms.max():.1f} nT")
    return norms * factor


def _altitude_unit_checked(rec: Recording, args, names, lat, lon, alt, t, norms) -> str:
    """An altitude column that states no unit is taken in metres. A satellite's 500 (km) read so put it on the
    ground, 20 % off in |F|, and the fit went on without a word (a blind check). So the readings judge: TWOSTEP
    fitted to the |F| of either unit, an error when they fit km's by more than twice better; else the text that says
    the metres were checked."""
    from .positions import IGRF_TOP_KM, igrf_magnitudes
    from .twostep import twostep

    if not np.any(alt > 0.0):
        return ""
    if np.max(alt) * 1000.0 >= IGRF_TOP_KM:
        return f"; in km it would reach {np.max(alt) * 1000.0:.4g} km, past the magnetopause"
    if np.min(alt) * 1000.0 <= -20.0:  # (GPS heights a little below sea level: in km, deep in the Earth)
        return f"; in km it would reach {np.min(alt) * 1000.0:.4g} km, below the Earth's crust"
    with warnings.catch_warnings():  # (what the IGRF's inputs look like was said of the first call)
        warnings.simplefilter("ignore")
        in_km = igrf_magnitudes(lat, lon, alt * 1000.0, t)
    if np.max(np.abs(in_km - norms) / norms) < 1e-4:  # (a few metres or km alike: nothing to tell apart)
        return ""
    try:
        m = rec.samples()
        # (relative to each |F|: 500 000 m read as km puts the sensor far out, where the field and all misfits vanish)
        misfit = {unit: twostep(m, values, standard_errors=False).summary["residual_rms"] / np.mean(values)
                  for unit, values in (("m", norms), ("km", in_km))}
    except ValueError:  # readings TWOSTEP cannot fit: the calibration itself says why
        return ""
    if misfit["km"] < 0.5 * misfit["m"]:
        raise ValueError(f"--field-norm igrf: {args.file}: column {names['alt']} states no unit, so it was taken in m, "
                         f"but the readings fit the IGRF far better in km (TWOSTEP's residual RMS {misfit['km']:.2%} "
                         f"of |F| against {misfit['m']:.2%} in m): state its unit (a header {names['alt']} [km], or "
                         "name it alt_km)")
    worse = "worse" if misfit["km"] > 1.1 * misfit["m"] else "no better"
    return f"; in km the readings would fit the IGRF {worse}: residual {misfit['km']:.2%} of |F| against {misfit['m']:.2%}"


def _take_field_units(args, stated: str, what: str) -> float:
    """The unit a field norm's source states becomes --field-units. When --field-units says another field unit:
    the factor that converts the source's values to it (an error for a unit that does not convert); else 1."""
    if stated and args.field_units and unit_name(stated) != unit_name(args.field_units):
        frm, to = TESLA_PER_UNIT.get(unit_name(stated)), TESLA_PER_UNIT.get(unit_name(args.field_units))
        if frm is None or to is None:
            raise ValueError(f"{what}: stated in {stated}, --field-units says {args.field_units}")
        print(f"{what}: in {stated}, converted to {args.field_units} (--field-units)")
        return frm / to
    if stated and not args.field_units:
        args.field_units = stated
    return 1.0


def _field_norm_from(rec: Recording, path: str, args) -> np.ndarray:
    """--field-norm FILE: the |field| another recording logged (a scalar magnetometer's or an observatory's F, else
    the magnitude of its vector), interpolated at this recording's clock times; both need clock times (dates),
    and this one's must lie within the other's."""
    other = read_recording(path)
    mine, theirs = rec.utc_seconds(), other.utc_seconds()
    for t, name in ((mine, args.file), (theirs, path)):
        if t is None:
            raise ValueError(f"--field-norm {path}: {name} has no clock time (a time column of dates and times, or "
                             "Unix seconds) to match the two recordings' readings by")
    scalar = next((c for c in ("F", "f", "total", "field_norm") if c in other.columns), None)
    if scalar is None and other.metadata.get("data_type", "").lower().startswith("variation"):
        raise ValueError(f"--field-norm {path}: no F, and its vector is variation data (no baselines): its "
                         "magnitude is not the field's; give a file with F, or definitive or quasi-definitive data")
    values = other.columns[scalar] if scalar else np.linalg.norm(other.samples(), axis=1)
    known = np.isfinite(values)  # an F not recorded at some minutes: the others bridge them
    if not known.any():
        raise ValueError(f"--field-norm {path}: its {scalar or 'field'} has no value")
    theirs, values = theirs[known], values[known]
    unit = other.units.get(scalar, "") if scalar else other.field_units()
    order = np.argsort(theirs, kind="stable")
    theirs, values = theirs[order], values[order]
    outside = (mine < theirs[0]) | (mine > theirs[-1])
    if outside.any():
        utc = lambda x: datetime.fromtimestamp(x, timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC")  # noqa: E731
        raise ValueError(f"--field-norm {path}: it covers {utc(theirs[0])} to {utc(theirs[-1])}; {args.file}, "
                         f"{rec.place(int(np.argmax(outside)))}, reads at {utc(mine[outside][0])}, outside it")
    factor = _take_field_units(args, unit, f"--field-norm {path}")
    what = f"column {scalar}" if scalar else f"|{','.join(other.mag_names())}|"
    print(f"field norm of each reading from {path}: its {what}{f' ({unit})' if unit else ''} at this recording's "
          "clock times (interpolated; times that state no zone are taken as UTC)")
    return np.interp(mine, theirs, values) * factor


def cmd_calibrate(args) -> int:
    if args.output:  # (before the fit: a name that says another format is refused when the calibration is saved)
        json_path(args.output, "-o")
    rec = read_recording(args.file, columns=args.columns, units=args.units, bad_lines=args.bad_lines,
                         decimal=args.decimal)
    raw = rec.samples(biaxial=bool(args.planar))  # two field columns: only the planar fit takes them
    if args.planar:
        return _calibrate_planar(args, rec)
    # attitude + local field in the recording (e.g. the airborne layout): the vector fit, unless a
    # magnitude-only method is asked for
    units, field_norm = rec.field_units(), args.field_norm
    if args.reference and args.method not in ("auto", "vector"):
        raise ValueError(f"--reference: the vector fit's; --method {args.method} fits field magnitudes only (leave "
                         "--method out, or give vector)")
    reference, reference_units = (_reference(rec, args.reference, args.file) if args.method in ("auto", "vector")
                                  else (None, units))
    _print_roles(rec, _reference_role(rec, args.reference) if reference is not None else None, rails=False)
    if isinstance(field_norm, str):
        field_norm = _field_norms_given(rec, field_norm, args)
    if reference is not None and not reference_units and units == "counts":
        print("note: the reference field states no unit: the corrected field is in its unit (state it, e.g. "
              "igrf_n [nT], for the calibration to say so)")
    if args.method == "vector" and reference is None:
        raise ValueError(f"{args.file}: --method vector needs the true field of each reading: --reference with three "
                         "columns (e.g. --reference rx,ry,rz), or attitude columns pitch, roll, yaw with the local "
                         "field igrf_n, igrf_e, igrf_d")
    _note_reference_columns(rec, reference, args.method)
    if field_norm is None and reference is None and rec.stated_field_norm() is not None:
        field_norm = rec.stated_field_norm()  # `fluxcal simulate` states the field it simulated
        print(f"field norm {field_norm:g} {units} from the simulation's metadata".rstrip())
    # the refinement's setting only when asked for: methods ls and als refuse it, having no refinement
    settings = {} if args.serial_correlation is None else {"serial_correlation": args.serial_correlation}
    if args.noise_sigma is not None:  # (calibrate refuses it, by name, where no magnitude refinement runs)
        settings["noise_sigma"] = args.noise_sigma
    try:
        cal = calibrate(raw, method=args.method, field_norm=field_norm, reference=reference, units=units, times=rec.time(),
                        outliers=args.outliers, shape=args.shape, **settings)
    except ValueError as exc:  # the solvers name their argument ("samples: …"); the user knows the file
        raise ValueError(f"{args.file}: {exc}") from None
    cal.field_units = _field_units(args, units, field_norm, reference)
    if reference is not None and reference_units != units:  # counts fitted to a field model in nT: h is in nT
        cal.field_units = reference_units
    judge_field_again(cal, units, args.field_units if field_norm is not None else None)
    cal.metadata.update(source=str(args.file), columns=",".join(rec.mag_names()))
    _name_file_lines(cal, rec)
    held_out = None
    if reference is None and len(raw) >= 80 and args.method in ("auto", "als+refine"):
        cal.summary["held_out_spread"], held_out = _held_out_spread(raw, cal, field_norm, settings)
    if reference is not None:
        cal.metadata["reference"] = (f"columns {args.reference} of the recording" if args.reference else
                                     "attitude pitch,roll,yaw and local field igrf_n,igrf_e,igrf_d of the recording")
        if len(raw) >= 40:
            cal.summary["held_out_rms"], held_out = _held_out_rms(raw, reference, cal.units, cal,
                                                                  cal.summary.get("outliers", {}).get("rows", []))
    if held_out:
        cal.summary["held_out_note"] = held_out
    if args.align_accelerometer:
        cal = _aligned(cal, rec, raw, args.file, args.acc_measures, args.serial_correlation)
    if args.output:  # before the report: a reader that stops early (| head) must not cost the calibration
        path = cal.save(args.output)
    _report(cal, raw, t=rec.time())
    if args.align_accelerometer:
        print(_alignment_line(cal.summary["alignment"]))
    if args.output:
        print(f"wrote {path}")
    if args.plot:
        from .plots import before_after

        print(f"wrote {before_after(raw, cal, args.plot, title=Path(args.file).name)}")
    if not cal.summary.get("identifiable", True):  # a script must not take it for a calibration to ship
        print(f"fluxcal calibrate: {args.file}: not identifiable (exit status 3): see 'identifiable' above",
              file=sys.stderr)
        return 3
    return 0


def _calibrate_planar(args, rec: Recording) -> int:
    """calibrate --planar: the two axes of the plane a yaw-only vehicle's sensor turns in (fluxcal.planar), the
    third passed through; the options of the 3-D fits that have no planar meaning are refused, not ignored."""
    from .planar import calibrate_planar, summary_lines

    refused = [name for name, given in (("--reference", args.reference), ("--method", args.method != "auto"),
                                        ("--align-accelerometer", args.align_accelerometer)) if given]
    if refused:
        raise ValueError(f"--planar: {', '.join(refused)} {'belong' if len(refused) > 1 else 'belongs'} to the 3-D "
                         "fits (the planar fit has one method, no reference or alignment); leave them out")
    field_norm = args.field_norm
    if isinstance(field_norm, str) and field_norm not in rec.columns:
        raise ValueError(f"--field-norm {field_norm}: with --planar, the HORIZONTAL field H (a number, or a column "
                         "of each reading's H); the total |F| of a file or of igrf is not the field in the turning "
                         f"plane (H = F cos(inclination)); the recording's columns: {', '.join(rec.columns)}")
    axes = None if args.planar == "auto" else args.planar
    if rec.biaxial() and axes is not None:  # a biaxial sensor's two columns: the recording carries their axes (by
        rec.take_axes(axes, f"--planar {axes}")  # their names, --planar's, else x,y said)
        axes = None
    try:
        cal = calibrate_planar(rec, field_norm=field_norm, axes=axes, shape=args.shape,
                               field_units=unit_name(args.field_units) if args.field_units else None,
                               outliers=args.outliers, serial_correlation=args.serial_correlation or "automatic")
    except ValueError as exc:
        raise ValueError(f"{args.file}: {exc}") from None
    cal.metadata.update(source=str(args.file), columns=",".join(rec.mag_names()))
    _name_file_lines(cal, rec)
    _print_roles(rec)
    if args.output:
        path = cal.save(args.output)
    print(cal)
    for line in summary_lines(cal):
        print(line)
    if args.plot:
        from .plots import before_after

        print(f"wrote {before_after(rec.samples(biaxial=rec.biaxial()), cal, args.plot, title=Path(args.file).name)}")
    for w in cal.summary["warnings"]:
        print(f"warning: {w}")
    if args.output:
        print(f"wrote {path}")
    if not cal.summary.get("identifiable", True):
        print(f"fluxcal calibrate: {args.file}: not identifiable (exit status 3): see 'identifiable' above",
              file=sys.stderr)
        return 3
    return 0


def _aligned(cal: Calibration, rec, raw: np.ndarray, file, acc_measures: str, serial: str | None) -> Calibration:
    """`cal` turned into the accelerometer's axes (--align-accelerometer); the fit's outliers left out;
    --serial-correlation reaches it."""
    from .alignment import align_to_gravity

    if "reference" in cal.metadata:
        raise ValueError(f"{file}: --align-accelerometer: the vector fit already corrects into the reference's axes")
    acc = rec.acceleration()
    if acc is None:
        raise ValueError(f"{file}: --align-accelerometer needs accelerometer columns (ax,ay,az, AccX…); the "
                         f"recording has {', '.join(rec.columns)}")
    keep = np.ones(len(raw), dtype=bool)
    keep[list(cal.summary.get("outliers", {}).get("rows", []))] = False
    missing = ~np.isfinite(acc).all(axis=1)  # (said by name and line: a blind check's were dropped without a word, and
    if missing.all():                        # all of them named the field's "0 rows")
        raise ValueError(f"{file}: --align-accelerometer: every accelerometer row has a value that is not a number")
    keep &= ~missing
    try:
        aligned = align_to_gravity(cal.apply(raw[keep]), acc[keep], acc_measures=acc_measures,
                                   serial_correlation=serial or "automatic").calibration(cal)
    except ValueError as exc:
        raise ValueError(f"{file}: --align-accelerometer: {exc}") from None
    if missing.any():
        aligned.summary["warnings"] = list(aligned.summary.get("warnings", [])) + [
            f"alignment to the accelerometer: {missing.sum()} of {len(acc)} rows left out, their accelerometer not a "
            f"number ({_lines_of(rec, missing)})"]
    return aligned


def _lines_of(rec, mask: np.ndarray) -> str:
    """The rows of `rec` where `mask` holds, as a message names them: "file lines 12, 40, …" (the first five), or
    "rows …" for a recording read without line numbers."""
    rows = np.flatnonzero(mask)
    lines = rec.line_numbers[rows] if rec.line_numbers is not None else rows
    shown = ", ".join(str(x) for x in lines[:5]) + (", …" if len(rows) > 5 else "")
    return f"{'file line' if rec.line_numbers is not None else 'row'}{'s' if len(rows) > 1 else ''} {shown}"


def _alignment_line(a: dict) -> str:
    se = ", ".join(f"{axis} ±{v:.2g}°" for axis, v in zip("xyz", a["rotation_se_deg"]))
    line = (f"aligned to the accelerometer: turned {a['rotation_deg']:.3g}° ({se}), dip {a['dip_deg']:.4g}° "
            f"± {a['dip_se_deg']:.2g}°, from {a['readings_used']} readings at rest")
    return "\n".join([line] + [f"  warning: {w}" for w in a["warnings"]])


def _same_file(a, b) -> bool:
    try:
        return Path(a).resolve() == Path(b).resolve() or (Path(b).exists() and Path(a).samefile(b))
    except OSError:
        return False


# What a command writes, by option (the argparse dest): a file, except the folders below, which it makes.
WRITES = {"output": "-o", "json": "--json", "plot": "--plot", "report": "--report", "raw": "--raw"}
FOLDERS_WRITTEN = {("demo", "output"), ("batch", "output"), ("diagnose", "report")}
READ_AS = {"file": "the recording", "calibration": "the calibration", "model": "the model"}


def check_writes(args) -> None:
    """Before a command reads anything: refuse an output that is a file it reads (a recording replaced by its
    calibration, a calibration by its C header: every command but apply had done it) and a file in a folder that
    does not exist (found only after the other outputs were written, with exit status 2)."""
    reads = [(name, v) for name, value in vars(args).items() if name not in WRITES
             for v in (value if isinstance(value, list) else [value])
             if isinstance(v, (str, Path)) and os.path.isfile(v)]
    for name, option in WRITES.items():
        path = getattr(args, name, None)
        if not isinstance(path, (str, Path)):
            continue
        for read, read_path in reads:
            if _same_file(path, read_path):
                raise ValueError(f"{option} {path} is {READ_AS.get(read, f'the {read}')} it reads: writing it would "
                                 "replace that file; name another")
        if (args.command, name) not in FOLDERS_WRITTEN and not Path(path).parent.is_dir():
            raise ValueError(f"{option} {path}: the folder {Path(path).parent} does not exist")


def _naming_the_input(message: str, args) -> str:
    """An error about what a command read, prefixed with the file when it reads one file and the message does not
    name it (a check deep in a solver knows its array, "zero_bias: sample 100 is nan", not the file); an option's
    error ("--plot …") as it is."""
    inputs = [str(v) for v in (getattr(args, k, None) for k in READ_AS) if isinstance(v, (str, Path))]
    if len(inputs) != 1 or inputs[0] in message or message.startswith("-"):
        return message
    return f"{inputs[0]}: {message}"


def cmd_apply(args) -> int:
    cal = Calibration.load(args.calibration)
    rec = read_recording(args.file, columns=args.columns, units=args.units, bad_lines=args.bad_lines,
                         decimal=args.decimal)
    taken = [k for k in ("hx", "hy", "hz") + (("heading",) if args.heading else ()) if k in rec.columns]
    if taken:  # the corrected columns would replace them (raw readings named hx,hy,hz, an earlier correction)
        raise ValueError(f"{args.file}: already has column(s) {', '.join(taken)}, which the corrected field would "
                         "overwrite; rename them (or apply to the recording the correction was made from)")
    if "skipped_lines" in rec.metadata:
        print(skipped_words(rec.metadata['skipped_lines']))
    if "text_columns" in rec.metadata:
        print(f"note: text columns are not written to {args.output}: {rec.metadata['text_columns']}")
    from .outliers import rail_words

    railed = rail_words({n: rec.columns[n] for n in rec.mag_names()}, applied=True)
    if railed:
        print(f"warning: {args.file}: {railed}")
    factor = cal.unit_factor(rec.field_units(), f"{args.file}")
    # a biaxial sensor's two columns (a planar calibration's axes): corrected in its axes, those two written
    axes, named = None, (rec.biaxial_axes_from if rec.biaxial() else None)
    with np.errstate(over="ignore", invalid="ignore"):  # said below, naming the files
        try:
            h = cal.apply(rec)
        except ValueError as exc:  # (Calibration.apply names the recording; here the calibration too)
            raise ValueError(f"{args.calibration} on {exc}") from None
    if factor != 1.0:  # (said once applied: a refusal had followed a conversion it never made)
        print(f"readings in {rec.field_units()} converted to the calibration's {cal.units} (× {factor:g})")
    if named is not None:
        axes = rec.biaxial_axes
        if not named:
            print(f"note: {args.file}: columns {', '.join(rec.mag_names())} taken as the calibration's axes "
                  f"{', '.join(axes)} (their names do not say which)")
        h = in_sensor_axes(h, axes)
    raw = (rec.samples(check_finite=False) if axes is None
           else in_sensor_axes(rec.samples(check_finite=False, biaxial=True), axes))
    bad = ~np.isfinite(h).all(axis=1) & np.isfinite(raw).all(axis=1)
    if bad.any():  # a finite reading corrected to inf: nothing is written
        raise ValueError(f"{args.calibration}: correcting {args.file} overflows from row {int(np.argmax(bad))} on "
                         "(offset or matrix out of range for these readings)")
    written = [f"h{a}" for a in (axes or "xyz")]
    columns = {**rec.columns, **{k: h[:, "xyz".index(k[1])] for k in written}}
    units = {**rec.units, **({k: cal.h_units for k in written} if cal.h_units else {})}
    if args.heading:
        columns["heading"], units["heading"] = _heading_column(cal, h, args), "deg"
        written.append("heading")
    # a planar calibration passes the axis it turns about through: said in the file and here (a blind check read hz,
    # its hard iron still in it, as the vertical field: 12 % off)
    loose = cal.summary.get("not_calibrated") if axes is None else None
    passed = ({"not_calibrated": f"h{loose['axis']} is not calibrated: {loose['reason']}"}
              if loose and loose.get("axis") in ("x", "y", "z") else {})
    write_output(args.output, Recording(columns=columns, units=units, source=str(args.output),
                                        metadata={**rec.metadata, "calibration": args.calibration, **passed}))
    if passed:
        print(f"note: {passed['not_calibrated']}")
    # a planar calibration's field norm is the horizontal field's: |h| and its spread are judged in its plane
    plane = plane_axes(cal)
    to_plane = np.eye(3) if plane is None else plane.T
    far = past_range(h)  # |h| overflows: 1e300
    if far.any():  # written as read; left out of the statistics below, which they would make inf or NaN
        rows = np.flatnonzero(far)
        where = rec.line_numbers[rows] if rec.line_numbers is not None else rows
        word = "file line" if rec.line_numbers is not None else "row"
        print(f"warning: {args.file}: {len(rows)} reading(s) past any sensor's range ({word} "
              f"{', '.join(map(str, where[:5]))}{', …' if len(rows) > 5 else ''}: a garbled line?), left out of "
              "|h| std/mean")
    print(f"wrote {args.output}: {len(rec)} rows, corrected columns {','.join(written)} "
          f"({'horizontal ' if plane is not None else ''}|h| std/mean {100 * _spread(h[~far] @ to_plane):.3f} %)")
    scale = _scale_warning(cal, h[~far] @ to_plane, rec.field_units())
    if scale:
        print(f"warning: {scale}")
    else:  # (a whole file in another unit is that warning's, not a few readings')
        gross = _gross_readings(cal, raw, h @ to_plane, far)
        if gross:
            gross = gross.format(file=args.file)
            print(f"warning: {gross if rec.line_numbers is None else _with_file_lines(gross, rec.line_numbers)}")
    t = rec.time()
    misfit = _misfit_warning(cal, raw[~far] @ to_plane, h[~far] @ to_plane,
                             None if t is None else t[~far],
                             args.calibration, args.file)
    if misfit:
        print(f"warning: {misfit}")
    if cal.summary.get("converged", True) is False:  # export-c refuses such a calibration without --force
        print(f"warning: {args.calibration}: the calibration's fit did not converge (an intermediate iterate): "
              "recalibrate before relying on the corrected field")
    if not cal.summary.get("identifiable", True):
        print(f"warning: {args.calibration}: the calibration is not identifiable (its data did not determine every "
              "parameter): |h| of the readings it was fitted on looks right, other orientations may not")
    return 0


def _heading_column(cal: Calibration, h: np.ndarray, args) -> np.ndarray:
    """apply --heading: each reading's heading (planar.heading) from a planar calibration of the sensor's x, y
    axes; any other calibration is an error naming it and the remedy."""
    from .planar import heading

    if cal.summary.get("method") != "planar" or cal.summary.get("plane_axes") != ["x", "y"]:
        what = ("a 3-D calibration: a heading needs the sensor's attitude as well (tilt compensation), which apply "
                "does not have" if cal.summary.get("method") != "planar" else
                f"a planar calibration of axes {', '.join(cal.summary.get('plane_axes', []))}, not x, y")
        raise ValueError(f"--heading: {args.calibration} is {what}; --heading takes a planar calibration of the "
                         "axes x, y of a level sensor (fluxcal calibrate FILE --planar xy)")
    return heading(h, args.heading, args.declination)


def _gross_readings(cal: Calibration, raw: np.ndarray, h: np.ndarray, far: np.ndarray) -> str | None:
    """A warning (with "{file}" to fill) naming the readings that read exactly 0 in every axis or whose corrected
    |h| is off these readings' median |h| by more than outliers.GROSS of it, as calibrate leaves them out: I²C
    glitches, a burst of garbage, a magnet at the sensor. Corrected and written like the rest; said so that no one
    takes them for the field. (Against the median, not the calibration's field: in another place's field every
    reading would be 'off'; that is _scale_warning's.)"""
    from .outliers import GROSS

    finite = ~far & np.isfinite(raw).all(axis=1)
    with np.errstate(over="ignore", invalid="ignore"):  # (the readings past range are `far`, said apart)
        size = np.linalg.norm(h, axis=1)
        typical = float(np.median(size[finite])) if finite.any() else 0.0
        off = np.abs(size - typical) > GROSS * typical
    rows = np.flatnonzero((off | ~raw.any(axis=1)) & finite)
    if not len(rows) or not typical > 0:
        return None
    shown = ", ".join(str(r) for r in rows[:8]) + (", …" if len(rows) > 8 else "")
    return (f"{{file}}: {len(rows)} reading(s) read 0 in every axis or are off |h| by more than {GROSS:.0%} of the "
            f"readings' median |h| (rows {shown}): glitches (zeros, a burst of garbage) or a magnet at the sensor, "
            "corrected like the rest and written — drop them before using the field (fluxcal calibrate leaves such "
            "readings out)")


# |h| this far from the calibration's field norm: readings in another unit (a factor 10 or more between field
# units), another sensor, or another field (the Earth's is 25–65 µT: a move across latitudes can reach 1.6×,
# which the warning's text names too)
FIELD_NORM_RATIO = 1.6


def _scale_warning(cal: Calibration, h: np.ndarray, units: str) -> str | None:
    """Why the corrected field's size does not look like the calibration's field, or None."""
    norms = np.linalg.norm(h[np.isfinite(h).all(axis=1)], axis=1)
    if not (cal.field_norm and np.isfinite(cal.field_norm) and len(norms)):
        return None
    ratio = float(np.median(norms)) / cal.field_norm
    if 1 / FIELD_NORM_RATIO <= ratio <= FIELD_NORM_RATIO:
        return None
    unit = f" {cal.h_units}" if cal.h_units else ""  # h and field_norm are in the field's unit
    why = (f"the readings state no unit: are they in {cal.units}? (--units)" if cal.units and not units else
           "readings in another unit than the calibration's, of another sensor, or taken in another field?")
    return (f"the corrected |h| is {np.median(norms):.6g}{unit} (median), {ratio:.3g}× the calibration's field "
            f"norm {cal.field_norm:.6g}{unit}; {why}")


# Whether a calibration fits the readings it is applied to, judged on the spread std/mean of the corrected |h|
# against two figures: the spread the calibration left on its own readings (its summary's norm_std_over_mean),
# widened in quadrature by these readings' own noise when it is larger (noisier readings of the same sensor spread
# more by that much), and these readings' raw spread |m|. The same sensor's other recording spreads somewhat more
# than the fit's own, having other directions and noise (the real recordings fitted on one half and applied to the
# other: 0.8–2.6×, 3× for the airborne segment's magnitude fit that its poor coverage leaves unsound) and far less
# than raw (a right calibration removes the distortion: 2–33 % raw to 0.1–3 %). Another sensor's calibration leaves
# the spread of the two offsets' and matrices' difference, about the raw spread (the real recordings with each
# other's calibrations: 6–400× the fit's own). So: more than MISFIT_FAR × the fit's own is another sensor, and so
# is no better than raw while above MISFIT_NEAR × the fit's own (a sensor that hardly needs correcting, whose raw
# spread is near the fit's own, corrects to about its raw spread: not a mismatch).
MISFIT_FAR = 5.0
MISFIT_NEAR = 2.0


def _spread_kept(norms: np.ndarray) -> tuple:
    """(std/mean of `norms`, rows left out): without the values further from the median than the two-sided normal
    quantile at 0.01/N × the robust σ (1.4826 MAD), the outlier screen's rule, so that a few glitches (0,0,0
    readings) do not make a right calibration look wrong, while the broad spread of a wrong one stays."""
    from scipy import stats

    from .outliers import _robust_z

    z, sigma = _robust_z(norms)
    keep = z <= stats.norm.isf(0.005 / len(norms)) if sigma > 0 else np.ones(len(norms), dtype=bool)
    kept = norms[keep]
    return float(kept.std() / kept.mean()), int((~keep).sum())


def _misfit_warning(cal: Calibration, raw: np.ndarray, h: np.ndarray, t, cal_file, file) -> str | None:
    """Why the calibration does not look like this sensor's (see MISFIT_FAR), or None; None too when the calibration
    carries no spread of its own (a multi-position result) or was fitted to each reading's own |field| (the |h| of
    these readings then follows their field, which apply does not know)."""
    from .diagnose.core import _difference_noise, time_series_noise

    own = cal.summary.get("norm_std_over_mean")
    finite = np.isfinite(raw).all(axis=1) & np.isfinite(h).all(axis=1)
    raw, h = raw[finite], h[finite]
    if not isinstance(own, (int, float)) or not own >= 0 or "field_norms" in cal.summary or len(h) < 20:
        return None
    after, dropped = _spread_kept(np.linalg.norm(h, axis=1))
    before, _ = _spread_kept(np.linalg.norm(raw, axis=1))
    # these readings' noise, as a share of |h|, from third differences in time order (as diagnose estimates it); not
    # for rows that are not a time series (their differences measure the turning). The readings' differences hold
    # the turn between rows too, across the field, and those of |h| what a wrong calibration leaves as the sensor
    # turns; each bounds the noise along the field, which is what spreads |h|: the smaller is taken
    order = slice(None) if t is None else np.argsort(np.asarray(t)[finite], kind="stable")
    m, norms = raw[order], np.linalg.norm(h[order], axis=1)
    sigma = time_series_noise(m)  # (on the plane's two columns too)
    noise = 0.0
    if sigma is not None:
        gain = abs(float(np.linalg.det(cal.matrix))) ** (1 / 3)  # (reading units to h's)
        noise = min(sigma * gain, _difference_noise(norms, 3)) / float(np.median(norms))
    expected = float(np.hypot(own, noise))
    if not (after > MISFIT_FAR * expected or (after >= before and after > MISFIT_NEAR * expected)):
        return None
    times = after / own if own > 0 else np.inf
    times = f"{times:.2g}× " if times < 10 else f"{times:.0f}× " if np.isfinite(times) else ""
    noisier = (f" ({100 * expected:.3g} % allowing for these readings' noise, {100 * noise:.3g} % of |h|)"
               if expected > 1.05 * own else "")
    left = f", {dropped} reading(s) far off the rest left out" if dropped else ""
    raw_words = (f"no better than the raw readings' {100 * before:.3g} %" if after >= before else
                 f"the raw readings spread {100 * before:.3g} %")
    return (f"{cal_file} does not fit {file}: the corrected |h| spreads {100 * after:.3g} % (std/mean{left}), "
            f"{times}the {100 * own:.3g} % the calibration left on the readings it was fitted on{noisier}; "
            f"{raw_words}. Is it another sensor's calibration, has the mounting changed or iron come near the "
            "sensor (recalibrate), or is it the wrong file?")


def write_output(path, rec: Recording) -> None:
    """A command's output recording in the format of its extension (.npz .mat .parquet .json), tab-separated
    for .tsv and .tab, CSV otherwise."""
    suffix = Path(path).suffix.lower()
    if suffix in WRITERS:
        write_recording(path, rec)
    else:
        write_csv(path, rec, delimiter="\t" if suffix in (".tsv", ".tab") else ",")


def cmd_simulate(args) -> int:
    from . import sim

    if args.effects is not None:
        return _simulate_effects(args)
    rng = np.random.default_rng(args.seed)
    field = args.field_norm * np.array([0.4, 0.05, 0.915]) / np.linalg.norm([0.4, 0.05, 0.915])
    effects = sim.random_sensor(args.field_norm, rng, noise=args.noise)
    result = sim.simulate(sim.uniform(args.n, rng), effects, field, rng)
    truth = result.true_calibration(units=args.units)
    # independent orientations, no time series: no t column (a 50 Hz clock made diagnose take them for one)
    cols = {"mx": result.readings[:, 0], "my": result.readings[:, 1], "mz": result.readings[:, 2]}
    meta = {"simulated": f"fluxcal {__version__}, seed {args.seed}, noise {args.noise} of |field|",
            "true_offset": " ".join(f"{v:.10g}" for v in truth.offset),
            "true_matrix": " ".join(f"{v:.10g}" for v in truth.matrix.ravel()),
            "field_norm": f"{args.field_norm:.10g}"}
    write_output(args.output, Recording(columns=cols, units={c: args.units for c in ("mx", "my", "mz")},
                                        metadata=meta, source=str(args.output)))
    print(f"wrote {args.output}: {args.n} readings in independent orientations (no time column), field "
          f"{args.field_norm:g} {args.units}")
    return 0


def _simulate_effects(args) -> int:
    """`simulate --effects`: a withheld-effect trial (fluxcal.sim.withheld) written with every column the
    diagnosis reads — t, temp, and the current, reference vectors (rx, ry, rz) and accelerometer where the
    effects need them."""
    from .sim.effects import CANDIDATES
    from .sim.withheld import truth, withheld_trial

    names = [] if args.effects.strip() == "none" else [n.strip() for n in args.effects.split(",") if n.strip()]
    unknown = [n for n in names if n not in {c.name for c in CANDIDATES}]
    if unknown:
        raise ValueError(f"--effects: unknown effect(s) {', '.join(unknown)} (the candidates: "
                         f"{', '.join(c.name for c in CANDIDATES)}; or none)")
    simulation, kw = withheld_trial(names, seed=args.seed)
    m = simulation.readings
    cols = {"t": kw["t"], "mx": m[:, 0], "my": m[:, 1], "mz": m[:, 2], "temp": kw["temp"]}
    units = {"t": "s", "mx": "uT", "my": "uT", "mz": "uT", "temp": "C"}
    if "current" in kw:
        cols["current"], units["current"] = kw["current"], "A"
    for key, names_ in (("reference", ("rx", "ry", "rz")), ("gravity", ("ax", "ay", "az"))):
        if key in kw:
            cols.update(zip(names_, np.asarray(kw[key]).T))
            units.update(dict.fromkeys(names_, "uT" if key == "reference" else "m/s^2"))
    # the truth the diagnosis is to be compared with: each effect's size, not its name alone
    meta = {"simulated": f"fluxcal {__version__} withheld-effect trial, seed {args.seed}",
            "effects": ", ".join(names) or "none", **truth(simulation, "uT"),
            "field_norm": f"{kw['field_norm']:.10g}", "model": kw["model"]}
    write_output(args.output, Recording(columns=cols, units=units, metadata=meta, source=str(args.output)))
    hint = f" --model {kw['model']} --reference rx,ry,rz" if "reference" in kw else ""
    duration = len(m) * float(np.median(np.diff(kw["t"])))
    print(f"wrote {args.output}: {len(m)} readings ({duration:g} s), effects: "
          f"{meta['effects']}; try: fluxcal diagnose {args.output}{hint}")
    return 0


def _side_columns(rec, args) -> tuple:
    """(temperature °C, current A), each None unless named by --temp-column / --current-column (a blind check's `T`
    and `motor_I` were ignored by name, and nothing could point diagnose at them): converted by the column's unit."""
    temp = current = None
    if args.temp_column:
        temp, _, _ = _temperatures(rec, args.temp_column, "", args.file)
        print(f"temperature: column {args.temp_column} (--temp-column)")
    if args.current_column:
        from .cable import _column_scale

        name = args.current_column
        if name not in rec.columns:
            raise ValueError(f"{args.file}: no column {name!r} (--current-column; columns: {', '.join(rec.columns)})")
        current = np.asarray(rec.columns[name], dtype=float) * _column_scale(
            args.file, name, rec.units.get(name, ""), LARGE_CURRENT_UNITS, "A", "a current")
        print(f"current: column {name} (--current-column)")
    return temp, current


def cmd_diagnose(args) -> int:
    from .diagnose import diagnose

    if args.model == "cable":
        if args.detection_limits:
            raise ValueError("--detection-limits: measured for magnetometer recordings, not for a cable ring (--model cable)")
        return _diagnose_cable(args)
    rec = read_recording(args.file, columns=args.columns, units=args.units, bad_lines=args.bad_lines,
                         decimal=args.decimal)
    rec.samples()  # the magnetometer columns exist and are finite before the diagnosis starts
    # a recording with attitude + local field gives the vector model its reference, unless told otherwise
    reference, reference_units = ((None, "") if not args.reference and args.model in ("ellipsoid", "scale")
                                  else _reference(rec, args.reference, args.file))
    _print_roles(rec, _reference_role(rec, args.reference) if reference is not None else None)
    if reference is not None and reference_units != rec.field_units():
        raise ValueError(f"{args.file}: the readings are in {rec.field_units() or 'no stated unit'} and the reference "
                         f"vectors in {reference_units or 'no stated unit'}: the vector model's errors would mix the "
                         "two; calibrate first (fluxcal calibrate … -o cal.json, then fluxcal apply) and diagnose the "
                         "corrected field against the reference")
    candidates = args.candidates.split(",") if args.candidates else None
    field_norm = args.field_norm
    if isinstance(field_norm, str):
        field_norm = _field_norms_given(rec, field_norm, args)
    temp, current = _side_columns(rec, args)
    with warnings.catch_warnings():  # the report prints its caveats (CAVEAT: …): not twice
        warnings.filterwarnings("ignore", message="t: readings")
        result = diagnose(rec, reference=reference, field_norm=field_norm, model=args.model, temp=temp, current=current,
                          noise_sigma=args.noise_sigma, candidates=candidates, alpha=args.alpha,
                          max_effects=args.max_effects, progress=not args.quiet)
        limits = None
        if args.detection_limits:
            from .diagnose import detection_limits

            limits = detection_limits(rec, reference=reference, field_norm=field_norm, model=args.model,
                                      noise_sigma=args.noise_sigma, alpha=args.alpha, seeds=args.seeds, names=candidates,
                                      progress=not args.quiet, diagnosis=None if candidates else result)
    if (said := plausible_field(result.base)) is not None:  # every size below is in that unit (calibrate says it too)
        print(f"warning: {said}")
    return _print_diagnosis(result, args, limits)


def cmd_export_c(args) -> int:
    from .export_c import export_c

    cal = Calibration.load(args.calibration) if args.calibration else None
    sources = [Path(f).name for f in dict.fromkeys(filter(None, (args.calibration, args.kalman, args.drift)))]
    result = export_c(cal, args.output, q_format=args.q_format, name=args.name, kalman=args.kalman,
                      drift=args.drift, source=", ".join(sources), force=args.force, input_range=args.input_range,
                      kalman_range=args.kalman_range)
    for w in result.warnings:  # what the fit of a drift model warned (in the header too)
        print(f"warning: {w}")
    print(result.describe())
    return 0


def cmd_demo(args) -> int:
    from . import sim
    from .plots import before_after

    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(args.seed)
    # A hand-turned RM3100-class magnetometer in a mid-latitude field (µT): turns about y, x, z with
    # wobble, hard iron of a nearby battery, soft iron and scale errors of a few per cent, 0.05 µT noise.
    field = np.array([19.6, 0.8, 45.2])
    W = np.array([[1.045, 0.021, -0.013], [0.021, 0.962, 0.034], [-0.013, 0.034, 1.008]])
    effects = [sim.SoftIron(W), sim.HardIron([8.7, -14.2, 5.3]), sim.WhiteNoise(0.05)]
    result = sim.simulate(sim.sweeps("yxz", per_turn=700, tilt_deg=12.0, rng=rng), effects, field, rng)
    raw = result.readings
    cols = {"t": result.t, "mx": raw[:, 0], "my": raw[:, 1], "mz": raw[:, 2]}
    rec_path = write_csv(out / "demo_recording.csv", cols, units={"t": "s", "mx": "uT", "my": "uT", "mz": "uT"},
                         metadata={"simulated": "fluxcal demo"})
    rec = read_csv(rec_path)
    cal = calibrate(rec, field_norm=float(np.linalg.norm(field)))
    print(f"fluxcal {__version__} demo: simulated hand-turned magnetometer, {len(raw)} readings, "
          f"|field| {np.linalg.norm(field):.2f} uT (written to {rec_path})\n")
    _report(cal, raw)
    truth = result.true_calibration(units="uT")
    err_b = np.linalg.norm(cal.offset - truth.offset)
    err_a = np.linalg.norm(cal.matrix - truth.matrix) / np.linalg.norm(truth.matrix)
    print(f"\nagainst the simulation's truth: offset error {err_b:.4f} uT, matrix error {100 * err_a:.3f} %")
    print(f"wrote {cal.save(out / 'demo_calibration.json')}")
    print(f"wrote {before_after(raw, cal, out / 'demo_before_after.png', title='fluxcal demo')}")
    return 0


def cmd_positions(args) -> int:
    from .positions import run_cli

    return run_cli(args)


def cmd_cable(args) -> int:
    from . import cable
    from .sim import cable as simcable

    if args.cable_command == "simulate":
        # the rig (sensor errors) comes from --seed; the noise from --noise-seed, so that a calibration and
        # later measurements can share one simulated instrument
        rig_rng = np.random.default_rng(args.seed)
        rig = simcable.lab_rig(rig_rng) if args.lab else simcable.paper_rig(rig_rng)
        rng = np.random.default_rng(args.seed if args.noise_seed is None else args.noise_seed)
        if args.calibration:
            raw, _ = simcable.calibration_data(rig, simcable.reference_currents(args.current), rng,
                                               repeats=args.repeats)
            rot = np.repeat(simcable.ROTATIONS_DEG, 2 * args.repeats)
            cur = np.tile(np.repeat(np.array(simcable.reference_currents(args.current)), args.repeats, axis=0),
                          (len(simcable.ROTATIONS_DEG), 1))
        else:
            rot = np.array([float(v) for v in args.rotations.split(",")])
            raw = rig.read(rot, [args.current, -args.current], rng) - rig.earth_in_sensor_axes(rot)
            cur = np.tile([args.current, -args.current], (len(rot), 1))
        cable.write_ring_csv(args.output, rig.ring, raw, rot, cur, rig.positions_m,
                             {"simulated": f"fluxcal {__version__} cable rig, seed {args.seed}, noise seed "
                                           f"{args.seed if args.noise_seed is None else args.noise_seed}",
                              "true_offsets": " ".join(f"{v:.10g}" for v in rig.errors.true_offset().ravel()),
                              "true_gains": " ".join(f"{v:.10g}" for v in rig.errors.gain.ravel())})
        print(f"wrote {args.output}: {len(rot)} snapshots of {rig.ring.n_sensors} sensors")
        return 0
    data = cable.read_ring_csv(args.file, bad_lines=args.bad_lines)
    ring = data["ring"]
    _ring_notes(cable, data)
    clipped = cable.clipped_readings(data["readings"])  # (raw: a rail is one value before any calibration)
    if clipped.any():
        print(f"warning: {args.file}: {cable.clipped_words(data['readings'], clipped)}")
    if args.cable_command == "calibrate":
        if data["currents_a"] is None or data["positions_m"] is None:
            raise ValueError(f"{args.file}: a calibration recording needs reference currents (i0, i1, …) and "
                             "the conductor positions (positions_m metadata)")
        if not np.all(np.isfinite(data["currents_a"])):  # (the core had said "currents: value 0 is not finite")
            row, j = (int(v[0]) for v in np.nonzero(~np.isfinite(data["currents_a"])))
            line = f" (file line {data['line_numbers'][row]})" if data.get("line_numbers") is not None else ""
            raise ValueError(f"{args.file}: {data['current_names'][j]} of snapshot {row}{line} is not a number: a "
                             "calibration needs the reference current of every reading (repair the line, or leave it "
                             "out with --bad-lines skip)")
        truth = _recording_fields(data)
        why = ""
        if args.method == "in_field":
            cal = cable.calibrate_ring_in_field(data["readings"], truth, ring, data["rotations_deg"])
        elif args.method == "auto":
            cal, why = _ring_calibration_auto(cable, data, truth)
        else:
            cal = cable.calibrate_ring(data["readings"], truth, method=args.method)
        print(f"method: {cal.method}{why}")
        # offsets of a ring's sensors are tenths of µT to tens (5.183e-07 T read poorly): one unit for all
        unit, per_tesla = ("nT", 1e9) if np.max(np.abs(cal.offsets)) < 1e-6 else ("µT", 1e6)
        for k in range(ring.n_sensors):
            print(f"sensor {k}: offset {cal.offsets[k, 0] * per_tesla:.4g} {cal.offsets[k, 1] * per_tesla:.4g} "
                  f"{unit}, gain {cal.gains[k, 0]:.6f} {cal.gains[k, 1]:.6f}")
        if cal.method == "in_field" and cal.lack_of_fit_p is not None and np.any(cal.lack_of_fit_p < cable.LACK_OF_FIT_P):
            missed = np.nonzero(np.min(cal.lack_of_fit_p, axis=1) < cable.LACK_OF_FIT_P)[0]
            ratio = float(np.max(cal.residual_sigma[missed] / cal.repeat_sigma[missed]))
            print(f"warning: in_field's fit still misses its model on sensor(s) {', '.join(map(str, missed))} (residual "
                  f"σ up to {ratio:.3g}× the repeats' scatter): a field that changes faster across the ring than its "
                  "third term (a conductor within ~4 ring radii), an axis misaligned, crosstalk or iron near a sensor, "
                  "or a drift between the poses; `fluxcal diagnose RUN.csv --model cable` says which")
        if args.method != "auto" and cal.method != "in_field":  # (auto has looked already)
            explained = _in_field_explains(cable, cal, data, truth)
            if explained is not None:  # said first: it explains the sensors' warnings below
                print(f"warning: {explained[1]}. `--method in_field` (or auto) fits it")
        mislabelled = _reference_mislabelled(cable, cal, data)
        if mislabelled:  # said first too: the sensors' warnings below are its consequence
            print(f"warning: {mislabelled}")
        for line in _sensor_warning_lines(cal, data.get("line_numbers")):
            print(line)
        if cal.background is not None:  # (the room's field, the ring's turns told from the sensors' offsets)
            b = [complex(*t) for t in cal.background["terms_t"]]
            se = [np.hypot(*t) for t in cal.background.get("terms_sigma_t", [[np.nan, np.nan]] * len(b))]
            print(f"field that does not follow the currents: {1e6 * abs(b[0]):.4g} ± {1e6 * se[0]:.2g} µT towards "
                  f"{np.degrees(np.angle(b[0])) % 360:.0f}° (cable frame) at the ring's centre; its terms at the "
                  "ring's radius " + ", ".join(f"{1e6 * abs(t):.3g} ± {1e6 * e:.2g}" for t, e in zip(b[1:], se[1:]))
                  + " µT")
        far = float(np.max(np.abs(np.log(cal.gains))))
        if far > np.log(1.2):  # readings in tesla: an AMR's gain error is a few %, not tens
            print(f"warning: gains up to ×{np.exp(far):.3g} away from 1: the readings' scale is not the ring model's — "
                  "check ring_radius_m (metres), the positions (positions_m), the currents' and readings' units")
        if args.output:
            Path(args.output).write_text(json.dumps(cal.to_dict(), indent=2))
            print(f"wrote {args.output}")
        return 0
    raw, rotations = data["readings"], data["rotations_deg"]
    ring_cal = cable.RingCalibration.load(args.calibration) if args.calibration else None
    if args.subtract_zero and args.subtract_background:
        raise ValueError("--subtract-zero and --subtract-background: the zero-current snapshots already hold the "
                         "room's field; give one of them")
    if args.noise_sigma_dof is not None and args.noise_sigma is None:
        raise ValueError("--noise-sigma-dof: the degrees of freedom of --noise-sigma, which is not given")
    if args.subtract_background and (ring_cal is None or ring_cal.background is None):
        raise ValueError("--subtract-background: needs --calibration with a background field (`fluxcal cable "
                         "calibrate --method in_field` fits one)")
    if args.subtract_background:  # (a bench's field taken off a switch room's recording had read 6–7.5 % off)
        b0 = complex(*ring_cal.background["terms_t"][0])
        print(f"subtracting the calibration run's field that does not follow the currents ({1e6 * abs(b0):.3g} µT towards "
              f"{np.degrees(np.angle(b0)) % 360:.0f}° at the ring's centre): right only where the ring was calibrated"
              + ("; --fit-background fits what is left beyond it" if args.fit_background else
                 " — elsewhere leave it out and give --fit-background"))
    if ring_cal is not None and ring_cal.offsets.shape[0] != ring.n_sensors:
        raise ValueError(f"{args.calibration}: a calibration of {ring_cal.offsets.shape[0]} sensors, the ring has "
                         f"{ring.n_sensors}")
    if ring_cal is not None and ring_cal.lack_of_fit_p is not None:
        missed = np.nonzero(np.min(ring_cal.lack_of_fit_p, axis=1) < cable.LACK_OF_FIT_P)[0]
        if len(missed):  # (a TWOSTEP calibration beside the Earth's field read 3.4 % low, only "ILL-CONDITIONED" said)
            print(f"warning: {args.calibration}: its own fit missed its model on sensor(s) "
                  f"{', '.join(map(str, missed))} (its lack-of-fit test): its gains and offsets may be off, and the "
                  "currents with them — recalibrate (`cable calibrate` says whether `--method in_field` explains it)")
    args.left_out = _left_out(args.leave_out, ring.n_sensors)
    if args.left_out.any():
        print(f"sensor(s) {', '.join(map(str, np.nonzero(args.left_out)[0]))} left out (--leave-out): solved with "
              f"the other {int((~args.left_out).sum())}")
    solve, zeros = np.arange(len(raw)), {}
    if args.subtract_zero:
        raw, solve, ring_cal, zeros = _zero_differences(data, ring_cal, args)
    if args.joint:  # the conductors do not move: every snapshot at one rotation shares their positions
        groups = [solve[rotations[solve] == r] for r in dict.fromkeys(rotations[solve].tolist())]
    else:
        groups = [np.array([k]) for k in solve]
    if ring_cal is None and args.noise_sigma is None:
        print(f"note: the standard errors take the sensors' noise σ as {cable._core.CableSolveOptions().noise_sigma:g} T "
              "(neither --calibration nor --noise-sigma gives it): give either for errors of this ring")
    solutions = []
    for rows in groups:
        rotation = float(rotations[rows[0]])
        sol = _solve_ring_snapshots(ring, ring_cal, raw[rows], rotation, rows, args, zeros.get(rotation))
        solutions.append(sol)
    for s in solutions:  # a clipped reading leaves no misfit: the solution is flagged for it
        s["clipped"] = bool(clipped[s["snapshots"]].any())
        if s["clipped"] and "_said" in s:
            s["_said"]["tail"] += ", ON A RAIL (clipped readings)"
    numbered = _number_conductors(solutions, data)
    if numbered:
        print(f"conductors numbered as the recording's {numbered}")
    for sol in solutions:
        _print_ring_solution(sol)
    # each kind of warning once, with the snapshots it concerns (24 snapshots' misfit had run to 48 lines)
    said = [(s["where"], w) for s in solutions for w in s.pop("warnings_said", [])
            if not w.startswith("readings on a rail")]  # (said once for the recording, above)
    for line in _grouped_warning_lines([where for where, _ in said], [w for _, w in said], _snapshots_words):
        print(line)
    if args.subtract_zero and any(not s["fits_model"] and "left_out" not in s for s in solutions):
        # (the misfit's hint names --fit-background, which has nothing left to fit here)
        print("note: the zero-current snapshots took off every field that does not follow the currents: a misfit here "
              "is the sensors' gains" + (" (give --calibration)" if ring_cal is None else "") + ", a wrong number "
              "of conductors, or a field that changed between the zero snapshots and the others")
    heavy = _implausible_current_words(solutions, ring)
    if heavy:
        print(f"warning: {heavy}")
    lone = _lone_sensor_words(ring, ring_cal, raw, solutions, args, zeros)
    if lone:
        print(f"warning: {lone}")
    if all("left_out" in s for s in solutions):  # nothing solved: the ring cannot, whatever the snapshot
        raise ValueError(f"{args.file}: every snapshot " + solutions[0]["left_out"].split(" — ", 1)[1] +
                         " (or add sensors, or --zero-sum-currents when the currents sum to zero)")
    if args.output:
        Path(args.output).write_text(json.dumps({"source": str(args.file), "joint": bool(args.joint),
                                                 "solutions": solutions}, indent=2))
        print(f"wrote {args.output}")
    if not any(s["well_conditioned"] and s["fits_model"] and not s["clipped"] for s in solutions):
        # (a script reads the exit status: every solution flagged had exited 0)
        print("error: no snapshot's solution both fits the model and is well conditioned"
              + (" with no reading on a rail" if any(s["clipped"] for s in solutions) else "") + " (exit status 3)",
              file=sys.stderr)
        return 3
    return 0


def _left_out(text: str | None, n_sensors: int) -> np.ndarray:
    """--leave-out's sensor numbers as a mask of the ring's sensors."""
    mask = np.zeros(n_sensors, bool)
    for word in filter(None, (w.strip() for w in (text or "").split(","))):
        if not word.isdigit() or int(word) >= n_sensors:
            raise ValueError(f"--leave-out: {word!r} is no sensor of this ring (0–{n_sensors - 1})")
        mask[int(word)] = True
    if (~mask).sum() < 3:
        raise ValueError(f"--leave-out: {int(mask.sum())} of the ring's {n_sensors} sensors left out; at least 3 "
                         "must stay")
    return mask


# A current beyond this many amperes per mm² of the ring's inner area (generous: copper carries ~3–6 continuously,
# a fuse link ~20) is another unit: readings in mT written as tesla read 8 A as 8000 A through a ring of 1 cm
PLAUSIBLE_CURRENT_DENSITY = 20.0


def _implausible_current_words(solutions: list, ring) -> str | None:
    """A warning when the largest current solved could not flow in any cable inside the ring (its whole inner area at
    PLAUSIBLE_CURRENT_DENSITY): the readings' or the currents' unit."""
    largest = max((float(np.nanmax(np.abs(s["currents_a"]))) for s in solutions if s.get("currents_a")), default=0.0)
    area_mm2 = np.pi * (1e3 * ring.radius_m) ** 2
    if not largest > PLAUSIBLE_CURRENT_DENSITY * area_mm2:
        return None
    return (f"currents up to {largest:.4g} A inside a ring of {1e3 * ring.radius_m:.3g} mm radius: a cable that fits "
            f"({area_mm2:.3g} mm² at most) carries {PLAUSIBLE_CURRENT_DENSITY * area_mm2:.3g} A at "
            f"{PLAUSIBLE_CURRENT_DENSITY:g} A/mm² — readings in mT or µT written as tesla (units: s0_x=mT, …), or "
            "ring_radius_m not in metres?")


# Misfitting snapshots solved again without each sensor in turn, to find one that departs alone
LONE_TRIALS = 4


def _lone_sensor_words(ring, ring_cal, raw, solutions: list, args, zeros: dict) -> str | None:
    """When most solved snapshots misfit: a few of them (LONE_TRIALS) solved again without each sensor in turn; the
    warning naming the one sensor without which they all fit the model, and with which none does (a swapped sensor
    had the whole recording misfit, no sensor named — a fit spreads a lone sensor's misfit over the others)."""
    import contextlib
    import io

    solved = [s for s in solutions if "sensor_residual_rms_t" in s]
    misfit = [s for s in solved if not s["fits_model"]]
    if not solved or len(misfit) < 0.5 * len(solved):
        return None
    trials = misfit[::max(1, len(misfit) // LONE_TRIALS)][:LONE_TRIALS]
    given = args.left_out
    fits = {}
    for i in np.nonzero(~given)[0]:
        if (~given).sum() - 1 < 3:
            break
        without = given.copy()
        without[i] = True
        with contextlib.redirect_stdout(io.StringIO()):  # (the trials' own lines are not the recording's)
            fits[int(i)] = sum(bool(_solve_ring_snapshots(ring, ring_cal, raw[s["snapshots"]], s["rotation_deg"],
                                                          np.array(s["snapshots"]), args, zeros.get(s["rotation_deg"]),
                                                          left_out=without).get("fits_model"))
                               for s in trials)
    alone = [i for i, n in fits.items() if n == len(trials)]
    if len(alone) != 1 or sum(n > 0 for n in fits.values()) > 1:
        return None
    j = alone[0]
    return (f"sensor {j} departs alone: {len(trials)} misfitting snapshot(s) solved again without each sensor in turn "
            f"fit the model without sensor {j}, and without no other — a sensor miswired, with its axes swapped, "
            "turned, its gain changed, or iron beside it? `fluxcal diagnose FILE --model cable` says how its readings "
            f"depart; --leave-out {j} solves without it")


def _zero_differences(data: dict, ring_cal, args) -> tuple:
    """--subtract-zero: every snapshot less the mean of the zero-current snapshots at its rotation (the Earth's, a
    busbar's field — its gradient too — and the sensors' offsets cancel); returns the differences, the snapshots to
    solve (those with current), the calibration with its offsets set to 0 (taken off twice otherwise: a newcomer's
    2.7–6 % off) and per rotation its zero snapshots' count and mean current (for _solve_ring_snapshots)."""
    currents, rotations = data["currents_a"], data["rotations_deg"]
    if currents is None:
        raise ValueError(f"--subtract-zero: {args.file} has no reference currents (i0, i1, …) to tell its zero-current "
                         "snapshots by")
    level = np.max(np.abs(currents), axis=1)
    zero = level <= 0.01 * level.max()  # (a logged 0 A jitters about zero: its mean is added back below)
    if zero.all():
        raise ValueError(f"--subtract-zero: every snapshot of {args.file} has no current (at most 1 % of the "
                         f"largest, {level.max():.3g} A): nothing to solve")
    diff = np.full_like(data["readings"], np.nan)
    zeros_at = {}
    for r in np.unique(rotations):
        at, zeros = rotations == r, (rotations == r) & zero
        if not zeros.any():
            raise ValueError(f"--subtract-zero: no zero-current snapshot at rotation {r:g}° (snapshots "
                             f"{', '.join(map(str, np.nonzero(at)[0][:6]))}…): record one in each pose")
        diff[at] = data["readings"][at] - np.nanmean(data["readings"][zeros], axis=0)
        # the difference reads the currents less the zeros' mean (the model is linear in them): added back after
        zeros_at[float(r)] = (int(zeros.sum()), currents[zeros].mean(axis=0))
    print(f"subtracting each rotation's zero-current snapshots ({int(zero.sum())} of {len(zero)}, up to "
          f"{level[zero].max():.3g} A, their mean added back to the currents; not solved)"
          + ("; the calibration's gains only: its offsets cancel" if ring_cal is not None else
             "; without --calibration the sensors' gains are taken as 1"))
    if ring_cal is not None:
        ring_cal = dataclasses.replace(ring_cal, offsets=np.zeros_like(ring_cal.offsets))
    return diff, np.nonzero(~zero)[0], ring_cal, zeros_at


def _in_field_explains(cable, cal, data: dict, truth):
    """(the in_field calibration, what it explains said) when a field that does not follow the currents explains a
    calibration's lack of fit — every bench has the Earth's, which TWOSTEP takes into the gains (6 % off, 18 warnings
    naming other causes, for a newcomer's 36 µT) — else None: no lack of fit, or no currents reversed at 3 rotations
    to tell. Without repeated readings (no lack-of-fit test) the residuals alone decide: in_field's half or less."""
    if cal is not None and cal.lack_of_fit_p is not None and not np.any(cal.lack_of_fit_p < cable.LACK_OF_FIT_P):
        return None
    try:
        other = cable.calibrate_ring_in_field(data["readings"], truth, data["ring"], data["rotations_deg"])
    except ValueError:
        return None
    after = float(np.median(other.residual_sigma))
    if cal is None:  # TWOSTEP refused: in_field must fit to its own repeats' scatter, where it has repeats
        if other.lack_of_fit_p is not None and np.any(other.lack_of_fit_p < cable.LACK_OF_FIT_P):
            return None
        change = (", which twostep refused; in_field fits it " +
                  ("to its repeats' scatter" if other.lack_of_fit_p is not None else
                   "(no repeated readings to judge its fit by)") + f" (residual σ {_tesla_words(after)})")
    else:
        before = float(np.median(cal.residual_sigma))
        if not after < 0.5 * before:
            return None
        change = (f"; {cal.method} took it into the gains and offsets (residual σ {_tesla_words(before)} → "
                  f"{_tesla_words(after)}, gains up to {100 * float(np.max(np.abs(other.gains / cal.gains - 1))):.2g} % "
                  "apart)")
    b0 = complex(*other.background["terms_t"][0])
    if abs(b0) < 3.0 * after:  # a field within the noise explains nothing (least squares' own misfit halved by in_field)
        return None
    return other, (f"a field that does not follow the currents explains this run's lack of fit: the Earth's or a "
                   f"neighbouring conductor's, {1e6 * abs(b0):.3g} µT towards {np.degrees(np.angle(b0)) % 360:.0f}° "
                   f"(cable frame){change}")


def _recording_fields(data: dict, currents=None) -> np.ndarray:
    """The true field of a ring calibration recording at each snapshot: its rotation and its reference currents
    (`currents`: others in their place)."""
    currents = data["currents_a"] if currents is None else currents
    return np.stack([data["ring"].rotated(a).field(data["positions_m"], c)
                     for a, c in zip(data["rotations_deg"], currents)])


def _misfit_ratio(cal) -> float:
    """A ring calibration's worst residual σ over its repeats' (inf without repeats: nothing to compare)."""
    if cal.repeat_sigma is None or cal.residual_sigma is None:
        return float("inf")
    return float(np.max(cal.residual_sigma / np.maximum(cal.repeat_sigma, 1e-300)))


def _reference_mislabelled(cable, cal, data: dict) -> str | None:
    """When the calibration misses its model on every sensor, whether the reference currents mislabelled explain it:
    the conductors' currents swapped (i0 ↔ i1: the columns or the positions_m in another order) or all their signs
    reversed. TWOSTEP uses |h| alone, so its gains come out right either way, but the readings' components then
    miss the model by hundreds of times the repeats' scatter, and the warning had named a field, an axis or iron (a
    blind check: i0 and i1 swapped, residual σ 683× the repeats')."""
    from itertools import permutations

    if cal.lack_of_fit_p is None or not np.all(np.min(cal.lack_of_fit_p, axis=1) < cable.LACK_OF_FIT_P):
        return None
    ratio = _misfit_ratio(cal)
    n = data["currents_a"].shape[1]
    tried = []
    for order in list(permutations(range(n)))[:6]:
        for sign in (1.0, -1.0):
            if order == tuple(range(n)) and sign > 0:
                continue
            truth = _recording_fields(data, sign * data["currents_a"][:, list(order)])
            try:
                alt = cable.calibrate_ring(data["readings"], truth, method=cal.method if cal.method != "in_field"
                                           else "twostep")
            except ValueError:
                continue
            if alt.lack_of_fit_p is not None and np.all(np.min(alt.lack_of_fit_p, axis=1) >= cable.LACK_OF_FIT_P):
                tried.append((_misfit_ratio(alt), order, sign))
    if not tried:
        return None
    best = min(tried)[0]
    if not best * 5.0 <= ratio:
        return None

    def words(order, sign):
        return " and ".join(filter(None, [
            "the currents' signs reversed" if sign < 0 else "",
            ("the conductors' currents taken as " + ", ".join(f"i{k}" for k in order) + " (swapped)")
            if order != tuple(range(n)) else ""]))

    # (equally good ones said together: go and return currents swapped are the same as their signs reversed)
    what = " or, equally, ".join(words(order, sign) for fit, order, sign in sorted(tried) if fit <= 1.1 * best)
    return (f"with {what}, the calibration fits its model (residual σ {ratio:.3g}× the repeats' → {best:.3g}×): the "
            "reference currents do not match the conductors in positions_m — swapped columns, the conductors listed "
            "in another order, or the currents' sense. The gains and offsets above hold either way (TWOSTEP uses "
            "the field's magnitude), but check the recording's labels before a calibration with directions (in_field)")


def _ring_calibration_auto(cable, data: dict, truth):
    """`cable calibrate --method auto`: TWOSTEP, or in_field when a field that does not follow the currents explains
    TWOSTEP's lack of fit or its refusal (the Earth's on a bench). Returns (calibration, why said after the method)."""
    try:
        cal = cable.calibrate_ring(data["readings"], truth)
    except ValueError:  # the first step's refusal names in_field among its causes: try it
        explained = _in_field_explains(cable, None, data, truth)
        if explained is None:
            raise
        return explained[0], f" (auto: {explained[1]})"
    explained = _in_field_explains(cable, cal, data, truth)
    if explained is None:
        if cal.lack_of_fit_p is None:
            return cal, ""
        return cal, (" (auto: no field that does not follow the currents explains its lack of fit)"
                     if np.any(cal.lack_of_fit_p < cable.LACK_OF_FIT_P) else " (auto: it fits to its repeats' scatter)")
    return explained[0], f" (auto: {explained[1]})"


def _grouped_warning_lines(labels: list, texts: list, words) -> list:
    """Warnings (`texts`, each of the item `labels[i]`) said once per kind — their words before the first number's
    clause — with the items it concerns (`words(labels)`) and the numbers of the one whose first number is largest
    (the worst: a reviewer's line had quoted 6.8× beside a sensor at 88×): 6 sensors × 3 warnings of one cause had
    buried the line naming it."""
    kinds: dict = {}
    for label, text in zip(labels, texts):
        kinds.setdefault(re.split(r" \(|: ", text, maxsplit=1)[0], []).append((label, text))

    def first_number(hit) -> float:
        found = re.search(r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?", hit[1])
        return abs(float(found.group())) if found else 0.0

    lines = []
    for hits in kinds.values():
        worst, text = max(hits, key=first_number)
        differ = len({t for _, t in hits}) > 1
        lines.append(f"warning: {words([label for label, _ in hits])}: {text}" + (f" ({words([worst])}'s numbers, the "
                                                                                   "largest)" if differ else ""))
    return lines


def _sensor_warning_lines(cal, line_numbers=None) -> list:
    """The per-sensor warnings of a ring calibration, each kind once (_grouped_warning_lines); rows they name (a
    reading left out) with their file lines when `line_numbers` are given."""
    pairs = [(k, w if line_numbers is None else _with_file_lines(w, line_numbers))
             for k, fit in enumerate(cal.sensors or []) for w in fit.summary.get("warnings", [])]
    return _grouped_warning_lines([k for k, _ in pairs], [w for _, w in pairs],
                                  lambda ks: f"sensor{'s' if len(ks) > 1 else ''} {', '.join(map(str, ks))}")


def _snapshots_words(wheres: list) -> str:
    """"snapshots 0–7, 9" from single snapshots' "snapshot k" (as _solve_ring_snapshots says them), else joined."""
    singles = [int(w.split()[1]) for w in wheres if re.fullmatch(r"snapshot \d+", w)]
    if len(wheres) == 1 or len(singles) < len(wheres):
        return "; ".join(wheres)
    runs, start = [], singles[0]
    for a, b in zip(singles, singles[1:] + [None]):
        if b != a + 1:
            runs.append(f"{start}" if start == a else f"{start}–{a}")
            start = b
    return "snapshots " + ", ".join(runs)


PLAUSIBLE_RING_FIELD_T = 0.1  # a reading beyond this (tesla) is another unit: 5000 A at 1 cm
IMPOSSIBLE_RING_FIELD_T = 1.0  # beyond this no ring's sensor reads (50 kA at 1 cm): an error, not a warning
PLAUSIBLE_RING_RADIUS_M = 0.5  # a ring beyond this radius (metres) is another unit


def _ring_notes(cable, data: dict) -> None:
    """What a ring recording's read left out (--bad-lines skip) and the columns it does not use, printed."""
    if data["skipped_lines"]:
        print(skipped_words(data['skipped_lines'], "their snapshots left out"))
    note = cable.ring_columns_note(data)
    if note:
        print(note)
    if data.get("bore_note"):
        print(f"note: {data['bore_note']}")
    if not data.get("rotations_given", True) and len(data["readings"]) > 1:
        print(f"note: no rotation_deg column: all {len(data['readings'])} snapshots taken at rotation 0° (the ring's "
              "turn about the cable is read from rotation_deg, in degrees)")
    # The field scales as I/r: readings or a radius in the wrong unit fit exactly, the currents or positions scaled by
    # it (µT read as tesla gave 8 MA, well conditioned; a radius in mm, conductors metres apart). Said by their size.
    # (the largest hundredth: a unit is every reading's, a garbled line's 1e300 one snapshot's, named when solved)
    finite = np.abs(data["readings"][np.isfinite(data["readings"])])
    largest = float(np.percentile(finite, 99)) if finite.size else 0.0
    if largest > IMPOSSIBLE_RING_FIELD_T:  # (µT read as tesla had exited 0 with the currents 10⁶ times too large)
        raise ValueError(f"readings up to {largest:.4g} T: no cable ring's sensor reads that ({PLAUSIBLE_RING_FIELD_T:g} "
                         "T is 5000 A at 1 cm) — are they in µT or mT, not tesla? Name the unit in the header (units: "
                         "s0_x=uT, …); the currents scale with it")
    if largest > PLAUSIBLE_RING_FIELD_T:
        print(f"warning: readings up to {largest:.4g} T: no cable ring's sensor reads that ({PLAUSIBLE_RING_FIELD_T:g} "
              "T is 5000 A at 1 cm) — are they in µT or mT, not tesla? Name the unit in the header (units: s0_x=uT, …); "
              "the currents scale with it")
    if data["ring"].radius_m > PLAUSIBLE_RING_RADIUS_M:
        print(f"warning: ring_radius_m {data['ring'].radius_m:g}: a ring {data['ring'].radius_m:g} m in radius — is it in mm "
              "(ring_radius_m is metres)? The positions and the currents scale with it")


def _solve_ring_snapshots(ring, ring_cal, snaps, rotation: float, rows, args, zero=None, left_out=None) -> dict:
    """`cable solve` of snapshots `rows` (one, or those sharing a rotation with --joint): sensors with a NaN
    left out (a dead sensor: the ring of the others), the calibration's σ for the solver, and a line per
    snapshot with positions, currents and their standard errors (said by _print_ring_solution, once numbered);
    `zero`: with --subtract-zero, (count, mean current) of the zero snapshots taken off. Returns the solution as a
    JSON-ready dict (its `_said` for the printing). `left_out`: the sensors left out, instead of --leave-out's."""
    from ._core import CableSolveOptions
    from .cable import silent_sensors, silent_words

    silent = silent_sensors(snaps)
    given = getattr(args, "left_out", None) if left_out is None else left_out  # --leave-out: said once, by cmd_cable
    given = np.zeros(snaps.shape[1], bool) if given is None else given
    live = np.isfinite(snaps).all(axis=(0, 2)) & ~silent & ~given
    contiguous = np.all(np.diff(rows) == 1)
    where = (f"snapshot {rows[0]}" if len(rows) == 1 else f"snapshots {', '.join(map(str, rows))}" if len(rows) <= 6
             else f"snapshots {rows[0]}–{rows[-1]}" if contiguous else f"the {len(rows)} snapshots at {rotation:g}°")
    if not live.any():
        raise ValueError(f"{where}: no sensor has a finite reading (every sensor NaN)")
    huge = past_range(snaps.reshape(-1, 1)).reshape(snaps.shape)  # (a garbled line: it overflows the fit's sums)
    if huge.any():
        k, sensor, axis = np.argwhere(huge)[0]
        raise ValueError(f"{args.file}, {where}: sensor {sensor} reads {snaps[k, sensor, axis]:.3g} on its "
                         f"{'xy'[axis]} axis, "
                         "past any sensor's range (a garbled line?)")
    if not (live | given).all():
        named = lambda mask, words: f"sensor(s) {', '.join(map(str, np.nonzero(mask)[0]))} {words}"  # noqa: E731
        unread = ~live & ~silent & ~given
        # a sensor not finite in every snapshot may be dead; in some only, a dropped reading, which costs it the whole
        # joint fit (which takes the same sensors in each): said so, by snapshot (a blind check's one NaN in 12 read
        # "not finite (dead?)")
        bad = ~np.isfinite(snaps).all(axis=2)  # (snapshots, sensors)
        dead = unread & bad.all(axis=0)
        dropped = [f"sensor {j} not finite in snapshot(s) {', '.join(str(rows[k]) for k in np.nonzero(bad[:, j])[0])} "
                   f"(left out of all {len(rows)} solved together: the joint fit takes the same sensors in each)"
                   for j in np.nonzero(unread & ~dead)[0]]
        said = ([named(dead, "not finite (dead?)")] if dead.any() else []) + dropped + silent_words(snaps, silent & ~given)
        print(f"{where}: {'; '.join(said)}: solved with the other {int(live.sum())}")
    sub = ring.subset(live)
    snaps = snaps[:, live]
    settings = {}
    if ring_cal is not None:
        cal = ring_cal.subset(live)
        # the solver's σ: the calibration's scatter and what its own gains and offsets leave at these fields
        sigma = cal.field_sigma(snaps)
        settings = {} if sigma is None else {"noise_sigma": sigma}
        dof = cal.field_sigma_dof(snaps, len(rows))
        if sigma is not None and dof is not None:  # each sensor weighted by its own σ, the F test on the whole
            per_sensor = cal.sensor_sigma(snaps, repeats=True)
            settings.update(noise_sigma_dof=dof, relative_sigma=per_sensor / sigma)
        snaps = cal.apply(snaps)
        if args.subtract_background:  # the room's field the calibration found, at this rotation
            snaps = snaps - cal.background_in_axes(sub, rotation)
    if args.noise_sigma is not None:  # the user's σ (a datasheet's, repeats'): before the calibration's
        settings = {"noise_sigma": args.noise_sigma}
        if args.noise_sigma_dof is not None:
            settings["noise_sigma_dof"] = args.noise_sigma_dof
    if zero:  # each difference holds the zero snapshots' mean too: √(1 + 1/n₀) per reading for the misfit test
        sigma0 = settings.get("noise_sigma", CableSolveOptions().noise_sigma)
        settings = {**settings, "noise_sigma": sigma0 * np.sqrt(1.0 + 1.0 / zero[0])}
        if settings.get("noise_sigma_dof") and len(rows) > 1:
            # the zeros' mean is one draw per sensor axis, shared by the snapshots solved together: Satterthwaite's
            # dof with it (taken as independent, one zero per rotation gave 2.3 % false misfits at p < 1e-3)
            share = 1.0 / zero[0]
            settings["noise_sigma_dof"] = (1.0 + share) ** 2 / (1.0 / settings["noise_sigma_dof"]
                                                                + share ** 2 / (2 * int(live.sum())))
    n = args.conductors
    per_snapshot = n - bool(args.zero_sum_currents) + 2 * bool(args.fit_background)  # what each must tell apart
    unknowns = 2 * n + len(rows) * (n - bool(args.zero_sum_currents)) + 2 * bool(args.fit_background)
    if snaps.size < unknowns or 2 * int(live.sum()) < per_snapshot:
        # (a dead sensor in one snapshot had ended the whole run, the others unsolved)
        why = (f"{where}: left out — {snaps.size} readings ({int(live.sum())} live sensors) for {unknowns} unknowns"
               + (" with the background field: --joint shares it and the positions between a rotation's snapshots "
                  "(record several at each)" if args.fit_background
                  else "; --joint shares the positions between a rotation's snapshots (record several at each)"))
        print(why)
        return {"snapshots": [int(k) for k in rows], "rotation_deg": rotation, "left_out": why,
                "well_conditioned": False, "fits_model": False}
    if snaps.size == unknowns:
        print(f"{where}: {snaps.size} readings for {unknowns} unknowns: the fit is exact and cannot show a misfit"
              + (" (--joint shares the background and positions between a rotation's snapshots)"
                 if args.fit_background and not args.joint else ""))
    sol = sub.rotated(rotation).solve(snaps if len(rows) > 1 else snaps[0], n_conductors=n,
                                      zero_sum_currents=args.zero_sum_currents, fit_background=args.fit_background,
                                      **settings)
    currents = np.atleast_2d(sol.currents)
    if zero:
        currents = currents + zero[1]
    from_calibration = ring_cal is not None and args.noise_sigma is None and "noise_sigma" in settings
    se = np.sqrt(np.diag(_solution_covariance(sub.rotated(rotation), sol, cal if ring_cal is not None else None,
                                              snaps, settings, zero, from_calibration,
                                              (args.placement_sigma or 0.0, args.axis_sigma or 0.0))))
    se = np.where(np.isfinite(se), se, np.nan)
    pos_se = se[:2 * n].reshape(n, 2)
    cur_se = se[2 * n:2 * n + len(rows) * n].reshape(len(rows), n)  # zero-sum currents: the last one's is derived
    flag = ("well conditioned" if sol.well_conditioned else "ILL-CONDITIONED") + \
        ("" if sol.fits_model else f", MISFIT (p {sol.misfit_p:.2g} for σ {sol.noise_sigma:.3g} T)"
         if sol.misfit_p < CableSolveOptions().misfit_alpha else f", MISFIT (residual above 5 × σ {sol.noise_sigma:.3g} T)")
    out = {"snapshots": [int(k) for k in rows], "rotation_deg": rotation, "sensors_used": np.nonzero(live)[0].tolist(),
           "sensor_residual_rms_t": np.sqrt(np.mean(np.reshape(sol.residuals, (-1, int(live.sum()), 2)) ** 2,
                                                    axis=(0, 2))).tolist(),
           "positions_m": sol.positions.tolist(), "position_sigma_m": _nan_to_none_rows(pos_se),
           "currents_a": currents.tolist(), "current_sigma_a": _nan_to_none_rows(cur_se),
           "residual_rms_t": sol.summary["residual_rms"], "noise_sigma_t": sol.noise_sigma,
           "well_conditioned": sol.well_conditioned, "fits_model": sol.fits_model,
           "misfit_p": float(sol.misfit_p) if np.isfinite(sol.misfit_p) else None}
    # said once the conductors are numbered as the recording's (_number_conductors, _print_ring_solution)
    out["_said"] = {"where": where, "tail": f"residual RMS {sol.summary['residual_rms']:.3g} T (σ {sol.noise_sigma:.3g} T); "
                                            f"{flag}", "after": []}
    if sol.background_t is not None:
        b, sb = sol.background_t, se[-2:]
        beyond = " beyond the calibration run's" if args.subtract_background else ""
        out["_said"]["after"].append(
            f"{where}: background field{beyond} ({1e6 * b[0]:.4g} ± {1e6 * sb[0]:.2g}, {1e6 * b[1]:.4g} ± "
            f"{1e6 * sb[1]:.2g}) µT, {1e6 * np.hypot(*b):.4g} µT towards {np.degrees(np.arctan2(b[1], b[0])) % 360:.0f}° "
            "(cable frame)")
        out.update(background_t=b.tolist(), background_sigma_t=_nan_to_none_rows(sb)[0])
    out["warnings"] = list(sol.summary.get("warnings", []))
    out["where"] = where
    # (the exact fit is said above, with the CLI's remedy)
    out["warnings_said"] = [w for w in out["warnings"]
                            if not (snaps.size == unknowns and w.startswith("as many readings as unknowns: the fit is exact"))]
    return out


def _number_conductors(solutions: list, data: dict) -> str | None:
    """Put each solution's conductors (the solver sorts them by x) in the recording's order, in place: nearest to its
    `positions_m`, else — the conductors staying put at one rotation — each rotation's solutions linked by position to
    its first, and those matched to the reference currents i0, i1, … over all of that rotation's snapshots (near-equal
    phases had swapped from one snapshot to the next). Solved conductors beyond the recording's come last. Returns
    what numbered them, or None (neither given, one conductor). (By x, a newcomer's i0 had come out second.)"""
    from scipy.optimize import linear_sum_assignment

    solved = [s for s in solutions if "left_out" not in s]
    if not solved or len(solved[0]["positions_m"]) < 2:
        return None

    def order_of(cost) -> list:  # cost (recording's, solved): the solved in the recording's order, the rest after
        rows, cols = linear_sum_assignment(cost)
        first = [int(c) for _, c in sorted(zip(rows, cols))]
        return first + [j for j in range(cost.shape[1]) if j not in first]

    known, reference = data["positions_m"], data["currents_a"]
    if known is not None:
        for s in solved:
            s["_order"] = order_of(np.linalg.norm(np.asarray(known)[:, None] - np.asarray(s["positions_m"])[None], axis=-1))
        by = "positions_m (nearest)"
    elif reference is not None:
        for rotation in dict.fromkeys(s["rotation_deg"] for s in solved):
            group = [s for s in solved if s["rotation_deg"] == rotation]
            anchor = np.asarray(group[0]["positions_m"])
            links = [order_of(np.linalg.norm(anchor[:, None] - np.asarray(s["positions_m"])[None], axis=-1))
                     for s in group]
            currents = np.vstack([np.asarray(s["currents_a"])[:, link] for s, link in zip(group, links)])
            wanted = np.vstack([reference[s["snapshots"]] for s in group])
            logged = np.all(np.isfinite(wanted), axis=1)  # (a meter's dropped reading: not matched on)
            if not logged.any():
                continue
            cost = np.sum((wanted[logged][:, :, None] - currents[logged][:, None, :]) ** 2, axis=0)
            for s, link in zip(group, links):
                s["_order"] = [link[j] for j in order_of(cost)]
        by = "reference currents i0, i1, … (best match over each rotation's snapshots)"
    else:
        return None
    for s in solved:
        order = s.pop("_order", None)
        if order is not None:
            for key in ("positions_m", "position_sigma_m"):
                s[key] = [s[key][j] for j in order]
            for key in ("currents_a", "current_sigma_a"):
                s[key] = [[row[j] for j in order] for row in s[key]]
            # the solver's warnings name its conductors by its own order: said in the printed one (a blind check's
            # "conductor 0 ended on the bore's edge" was the one printed as conductor 1)
            renumber = {str(old): str(new) for new, old in enumerate(order)}
            for key in ("warnings", "warnings_said"):
                if key in s:
                    s[key] = [re.sub(r"\bconductor (\d+)", lambda m: f"conductor {renumber.get(m[1], m[1])}", w)
                              for w in s[key]]
    return by


def _print_ring_solution(sol: dict) -> None:
    """A `cable solve` solution's lines: positions, each snapshot's currents, with their standard errors."""
    said = sol.pop("_said", None)
    if said is None:  # left out, said already
        return
    def pm(v, scale: float = 1.0) -> str:  # JSON's null (or NaN) for an undetermined standard error: said so
        return "± undetermined" if v is None or not np.isfinite(v) else f"± {v * scale:.2g}"

    at = "; ".join(f"({x * 1e3:.4f} {pm(sx, 1e3)}, {y * 1e3:.4f} {pm(sy, 1e3)}) mm"
                   for (x, y), (sx, sy) in zip(sol["positions_m"], sol["position_sigma_m"]))
    rows = sol["snapshots"]
    if len(rows) > 1:
        print(f"{said['where']} (joint, rotation {sol['rotation_deg']:g}°): conductors at {at}; {said['tail']}")
    for k, cur, err in zip(rows, sol["currents_a"], sol["current_sigma_a"]):
        amps = ", ".join(f"{i:.5g} {pm(e)} A" for i, e in zip(cur, err))
        print(f"snapshot {k}: " + (f"{amps}" if len(rows) > 1 else f"{at}; {amps}; {said['tail']}"))
    for line in said["after"]:
        print(line)


def _solution_covariance(ring, sol, cal, fields, settings: dict, zero, from_calibration: bool,
                         placement=(0.0, 0.0)) -> np.ndarray:
    """A `cable solve` solution's covariance with the errors its snapshots share (cable.propagated_covariance): each
    reading's own noise — the calibration's repeats' (or residuals') scatter, else the solver's σ — plus the
    calibration's own gains and offsets (the offsets cancel with --subtract-zero), the zero snapshots' mean and the
    sensors' placement tolerance (`placement`: position σ in metres, axes' σ in degrees)."""
    from . import cable

    relative = settings.get("relative_sigma")
    m = ring.n_sensors
    sigma0 = settings.get("noise_sigma", sol.noise_sigma) / (np.sqrt(1.0 + 1.0 / zero[0]) if zero else 1.0)
    noise = np.full((m, 2), sigma0 ** 2) * (1.0 if relative is None else relative[:, None] ** 2)
    shared = []
    if cal is not None and cal.covariance is not None:
        if from_calibration:  # the solver's σ held the calibration's own errors too: its scatter alone here
            noise = cal.noise_variance()
        shared.append(cable.calibration_shared_errors(cal, fields.reshape(-1, m, 2), offsets=not zero))
    if zero:
        shared.append((np.broadcast_to(np.eye(2 * m).reshape(1, m, 2, 2 * m), (len(fields), m, 2, 2 * m)),
                       np.diag(noise.ravel() / zero[0])))
    if any(placement):
        shared.append(cable.placement_shared_errors(ring, sol, *placement))
    if not shared and relative is None:
        return sol.covariance
    return cable.propagated_covariance(ring, sol, noise, shared, relative)


def _tesla_words(value: float) -> str:
    return f"{1e9 * value:.3g} nT" if value < 1e-6 else f"{1e6 * value:.3g} µT"


def _nan_to_none_rows(a) -> list:
    """Rows of `a` as JSON lists, a non-finite value (an undetermined standard error) as null."""
    return [[None if not np.isfinite(v) else float(v) for v in row] for row in np.atleast_2d(a)]


def _temperatures(rec, column: str | None, outside_column: str, file) -> tuple:
    """(temperature °C, outside temperature °C or None, {"column", "unit"}) of a zero-bias recording: the
    column `column`, else the one recognised as the temperature (temp, temperature, Temperature (°F), temp_K,
    …), each converted from °F or K by its stated or named unit; a stated unit that is not a temperature is
    an error, not a guess. The model is always in °C (its ranges are)."""
    from .io.columns import TO_CELSIUS, find_temperature, temperature_unit

    def unit_of(name):
        unit = temperature_unit(name, rec.units)
        if unit is None:
            raise ValueError(f"{file}: column {name!r} is in {rec.units[name]!r}, not °C, K or °F")
        return unit

    if column is not None:
        if column not in rec.columns:
            raise ValueError(f"{file}: no column {column!r} (--temp-column; columns: {', '.join(rec.columns)})")
        name, unit = column, unit_of(column)
    else:
        candidates = [c for c in rec.columns if c != outside_column]
        hit = find_temperature(candidates, rec.units)
        named = find_temperature(candidates, {})
        if hit is None and named is not None:
            unit_of(named[0])  # named a temperature, in a unit that is not one: say so
        if hit is None:
            raise ValueError(f"{file}: no temperature column (looked for temp, temperature, temp_C, Temperature (°F), "
                             f"…; columns: {', '.join(rec.columns)}); name it with --temp-column")
        name, unit = hit
    outside = rec.columns.get(outside_column)
    if outside is not None:
        outside = TO_CELSIUS[unit_of(outside_column)](outside)
    return TO_CELSIUS[unit](rec.columns[name]), outside, {"column": name, "unit": unit}


def _require_finite(rec, file, named) -> None:
    """ValueError naming the file's line, the column and --bad-lines skip for the first value of `named` ((column,
    values or None) pairs) that is NaN or infinite (the fit would name a 0-based sample of an array)."""
    for name, values in named:
        bad = np.flatnonzero(~np.isfinite(values)) if values is not None else []
        if len(bad):
            at = rec.line_numbers[bad] if rec.line_numbers is not None else bad
            word = "line" if rec.line_numbers is not None else "row"
            more = (f" ({len(bad)} {word}s: {', '.join(map(str, at[:5]))}{', …' if len(bad) > 5 else ''})"
                    if len(bad) > 1 else "")
            raise ValueError(f"{file}, {word} {at[0]}, column {name!r}: {float(values[bad[0]])} is not finite "
                             f"(NaN/Inf not allowed){more}; pass bad_lines='skip' (--bad-lines skip) to leave such "
                             "lines out")


def _zero_bias_recording(args, column: str):
    """The recording of `drift fit`/`drift apply` (any format read_recording takes) and its zero-bias column."""
    rec = read_recording(args.file, bad_lines=args.bad_lines)
    if column not in rec.columns:
        raise ValueError(f"{args.file}: no column {column!r} (columns: {', '.join(rec.columns)}); name the zero bias "
                         "with --column")
    # a unit as the name's last part (zero_bias_mA, zero_bias_uA), as temp_F names °F (a blind check: zero_bias_mA
    # "states no unit: taken in A", and its class judged 1000x off)
    last = re.split(r"[_\s-]+", column.strip())[-1]
    # spelt as units are (A, mA, uA, µA, kA): zero_bias_a (phase a) or _ma (a moving average) are names (a review)
    if not rec.units.get(column) and last != column.strip() and last in ("A", "mA", "uA", "µA", "\u03bcA", "kA"):
        rec.units[column] = last
        print(f"note: {column}: in {last}, by its name")
    return rec


def _current_unit(word: str) -> str:
    """A current unit as LARGE_CURRENT_UNITS keys it (uA, µA, μA → "µa")."""
    return word.strip(" []()").lower().replace("\u03bc", "\u00b5").replace("ua", "µa") if word else ""


def _reword(report: dict, model, said: str, named: str, keys=("warnings",)) -> None:
    """One of the drift fit's messages (`said`) in the file's words (`named`), in the report and in the model."""
    for key in keys:
        report[key] = [named if w == said else w for w in report[key]]
    model.summary["fit_warnings"] = [named if w == said else w for w in model.summary["fit_warnings"]]


def _rated(text: str | None, unit: str | None, column: str) -> tuple:
    """`--rated` in the zero bias's unit, and a note or None: a bare number is in that unit already; `1000A`,
    `1.2 kA`, `800 mA` are converted to it (a blind check's `--rated 1000` beside a column in mA was taken as
    1 A, below the zero bias itself, and `1000A` was refused as no number). A column that states no unit is taken
    in A then, said."""
    if text is None:
        return None, None
    hit = re.fullmatch(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([A-Za-z\u00b5\u03bc]*)\s*", text)
    if not hit:
        raise ValueError(f"--rated {text!r}: not a current (a number in the zero bias's unit, or with its own: "
                         "1000A, 1.2kA, 800mA)")
    value, given = float(hit[1]), _current_unit(hit[2])
    if not given:
        return value, None
    if given not in LARGE_CURRENT_UNITS:
        raise ValueError(f"--rated {text!r}: {hit[2]} is no current unit (A, mA, µA or kA)")
    stated = _current_unit(unit or "")
    if not stated:
        return value * LARGE_CURRENT_UNITS[given], f"{column} states no unit: taken in A beside --rated {text}"
    if stated not in LARGE_CURRENT_UNITS:
        raise ValueError(f"--rated {text!r}: {column} is in {unit}, not a current; give --rated as a bare number "
                         f"in {unit}")
    return value * LARGE_CURRENT_UNITS[given] / LARGE_CURRENT_UNITS[stated], None


# Runs of rising time this long (median) between steps back are stretches of a log, not rows out of order
STRETCH_ROWS = 10


def _bad_stamps(times: np.ndarray, step: float) -> tuple:
    """(times, rows): a lone time stamp out of its neighbours' course (they one or two steps apart) where the other
    stamps leave no gap for it — 0 or far ahead in a running log, a clock's glitch, its row's data where the file has
    it — taken between its neighbours (a review: one stamp set to 0 had moved its row to the start, and the fit was
    refused for the temperature that then left its course). A row written late leaves a gap where its time belongs,
    and is left to be sorted."""
    times, rows = times.copy(), []
    out = np.flatnonzero((times[1:-1] < times[:-2]) | (times[1:-1] > times[2:])) + 1
    for k in out[:20]:
        if not (0 < times[k + 1] - times[k - 1] <= 2.5 * step):
            continue
        others = np.sort(np.delete(times, k))
        i = int(np.searchsorted(others, times[k]))
        if 0 < i < others.size and others[i] - others[i - 1] >= 1.5 * step:
            continue  # a gap where it belongs: written late
        beyond = others[0] - times[k] if i == 0 else times[k] - others[-1] if i == others.size else None
        if beyond is not None and 0 < beyond <= 1.5 * step:
            continue  # the first or last sample, written late or early
        times[k] = 0.5 * (times[k - 1] + times[k + 1])
        rows.append(int(k))
    return times, rows


def _drift_time_order(rec: Recording, file) -> tuple:
    """(order, times) for a zero bias's AR model and Kalman filter: `times` rising, in the rows' order `order` (None:
    the file's). Time that steps back by more than STRETCH_ROWS samples between long stretches of rising time (a
    logger restarted at 0, a clock set back, local time across the end of summer time) keeps the file's order, each
    stretch taken as following the one before after a gap, so that the models start again there (a blind check:
    sorted by time, a restart's two stretches were interleaved, AR(3)/AR(10) fitted for AR(1) and exported); rows out
    of order one by one (shuffled), or a few rows late by a step or two, are sorted by time. Both said. (None, None)
    without a time column (a sample rate's times have no gaps)."""
    if rec._time_column() is None:
        return None, None
    times = np.asarray(rec.time(), dtype=float)
    back = np.flatnonzero(np.diff(times) < 0) + 1
    if not back.size:
        return None, times
    rising = np.diff(times)
    step = float(np.median(rising[rising > 0])) if np.any(rising > 0) else 1.0
    runs = np.diff(np.r_[0, back, len(times)])
    times, stamps = _bad_stamps(times, step) if np.median(runs) >= STRETCH_ROWS else (times, [])  # (not shuffled)
    if stamps:
        lines = [int(rec.line_numbers[k]) if rec.line_numbers is not None else int(k) for k in stamps]
        print(f"note: {len(stamps)} time stamp(s) of {file} leave the time's course where no sample is missing "
              f"({'line' if rec.line_numbers is not None else 'row'} {', '.join(map(str, lines[:5]))}"
              f"{' …' if len(lines) > 5 else ''}: a clock's glitch): taken between their neighbours")
    back = np.flatnonzero(np.diff(times) < 0) + 1
    if not back.size:
        return None, times
    # A step back starts a new stretch when the time then runs on from there for long (5 × STRETCH_ROWS rows) through
    # what the rows before it had covered (STRETCH_ROWS of them at least, against the median of the last five: one
    # bad timestamp's neighbour is no reference): a restart, a clock set back. A lone bad timestamp, a row written
    # late, blocks shuffled are sorted, within their stretch (a review: one timestamp set to 0 had been taken for a
    # restart and half the log shifted; blocks of 5 rows shuffled for 209 restarts).
    large = back[times[back - 1] - times[back] > STRETCH_ROWS * step]  # (a row a step or two late: no restart)
    ends = np.r_[large[1:], len(times)]
    restarts = np.array([b for b, e in zip(large, ends) if e - b >= 5 * STRETCH_ROWS and np.sum(
        times[b:e] <= np.median(times[max(0, b - 5):b])) >= STRETCH_ROWS], dtype=int)
    edges = np.r_[0, restarts, len(times)]
    order = np.concatenate([lo + np.argsort(times[lo:hi], kind="stable") for lo, hi in zip(edges[:-1], edges[1:])])
    moved = int(np.sum(order != np.arange(len(order))))
    if moved:
        print(f"note: {moved} of {len(order)} rows of {file} are out of time order: the samples are taken in the "
              "order of their times" + (" within each stretch (below)" if restarts.size else ""))
    shifted = times[order]
    for start in restarts:  # each stretch after the last, ten steps on: a gap, where the filter starts again
        shifted[start:] += shifted[start - 1] + 10 * step - shifted[start]
    if not restarts.size:
        return order, shifted
    back = restarts
    lines = rec.line_numbers[back] if rec.line_numbers is not None else back
    word = "line" if rec.line_numbers is not None else "row"
    shown = ", ".join(str(int(v)) for v in lines[:5]) + (f" and {len(lines) - 5} more" if len(lines) > 5 else "")
    print(f"note: the time in {file} steps back {len(back)}x ({word} {shown}: a logger restarted, a clock set back, "
          "local time across the end of summer time?): the rows are taken in the file's order, each stretch after a "
          "step back as following the one before with a gap (the AR model and the Kalman filter start again there)")
    return (order if moved else None), shifted


def cmd_drift(args) -> int:
    """`fluxcal drift fit FILE -o MODEL.json` and `fluxcal drift apply MODEL.json FILE -o OUT` (seed 001)."""
    from . import drift

    if args.drift_command == "fit":
        rec = _zero_bias_recording(args, args.column)
        order, times = _drift_time_order(rec, args.file)
        if order is not None:
            rec.columns = {name: np.asarray(values)[order] for name, values in rec.columns.items()}
            if rec.line_numbers is not None:
                rec.line_numbers = np.asarray(rec.line_numbers)[order]
        if (doubt := rec.time_unit_doubt()) is not None:  # the thermal lag and the ageing are said in its seconds
            print(f"note: {doubt}")
        if "skipped_lines" in rec.metadata:  # the AR model and the Kalman filter assume evenly spaced samples
            where = ("the gaps they leave in t are not reached across" if times is not None else
                     "no time column: the series is modelled as if they were not there, a time step is missing at "
                     "each")
            print(skipped_words(rec.metadata['skipped_lines'], where))
        temp, outside, temperature = _temperatures(rec, args.temp_column, args.outside_column, args.file)
        _require_finite(rec, args.file, ((args.column, rec.columns[args.column]), (temperature["column"], temp),
                                         (args.outside_column, outside)))
        try:
            breakpoints = [float(v) for v in args.breakpoints.split(",")]
        except ValueError:
            raise ValueError(f"--breakpoints: {args.breakpoints!r} is not a comma-separated list of numbers") from None
        rated, rated_note = _rated(args.rated, rec.units.get(args.column), args.column)
        if rated_note:
            print(f"note: {rated_note}")
        if 0.1 < args.significance < 1:  # (a blind check's 0.5 took orders 4, 3, 4 for a quadratic, unsaid)
            print(f"warning: --significance {args.significance:g}: the F-test then keeps a power the drift does not "
                  f"have in {args.significance:.0%} of its tests (seed 001 takes 0.05 or 0.01)")
        try:
            model, report = drift.fit_pipeline(rec.columns[args.column], temp, outside,
                                               regressor=args.regressor, breakpoints=breakpoints,
                                               max_order=args.max_order, significance=args.significance,
                                               continuous=args.continuous, ar_max_order=args.ar_max_order,
                                               steady_state=args.steady_state, rated=rated,
                                               accuracy_class=args.accuracy_class, drift_input=args.drift_input,
                                               t=times if times is not None else rec.time(),  # (a sample rate's)
                                               spikes="drop" if args.drop_spikes else "keep")
        except drift.TemperatureGlitches as exc:  # said with their file lines (after the fit's size checks)
            word = "line" if rec.line_numbers is not None else "row"
            said = (drift.hold_words(temp, exc.holds, word, rec.line_numbers) if exc.holds else
                    drift.glitch_words(temp, exc.rows, word, rec.line_numbers[exc.rows]
                                       if rec.line_numbers is not None else None))
            raise ValueError(f"{args.file}: {temperature['column']}: {said}") from None
        found = report["spikes"]
        u = f" {rec.units[args.column]}" if rec.units.get(args.column) else ""  # the file's unit of the column
        # the fit's messages said again in the file's words: its lines, its column, its unit
        if found["rows"] and rec.line_numbers is not None:
            _reword(report, model, drift.spike_words(found["rows"], found["sigmas"], dropped=found["dropped"]),
                    drift.spike_words(found["rows"], found["sigmas"], "line", rec.line_numbers[found["rows"]],
                                      dropped=found["dropped"]), ("warnings", "notes"))
        if report["frozen"] and rec.line_numbers is not None:
            w = rec.columns[args.column]
            _reword(report, model, drift.frozen_words(w, report["frozen"]),
                    drift.frozen_words(w, report["frozen"], "line", rec.line_numbers, u))
        for said, named in zip(drift.history_warnings(report.get("thermal_lag")),
                               drift.history_warnings(report.get("thermal_lag"), u)):
            _reword(report, model, said, named)
        if temperature["column"] != "temp":  # the °F/K hint names the file's column, and the remedy its unit line
            named = drift.temperature_unit_hint(temp, breakpoints, name=temperature["column"])
            _reword(report, model, drift.temperature_unit_hint(temp, breakpoints), named)
            if "temperature_unit_hint" in model.summary:
                model.summary["temperature_unit_hint"] = named
        model.settings["source"] = str(args.file)
        model.settings["column"] = args.column
        model.settings["unit"] = rec.units.get(args.column) or None  # apply and export-c say it, apply checks it
        # the model's temperatures are °C whatever the file's; apply converts its file's alike
        model.settings["temperature"] = {**temperature, "outside": args.outside_column if outside is not None else None}
        pre, ar = report["preprocess"], report["ar"]
        print(f"{args.column}: {len(rec)} samples, mean {pre['mean']:.6g}{u}")
        if temperature["column"] != "temp" or temperature["unit"] != "C":
            converted = {"C": "", "F": " in °F, converted to °C", "K": " in K, converted to °C"}[temperature["unit"]]
            print(f"  temperature: column {temperature['column']!r}{converted}")
        gaps = report["gaps"]
        if gaps and gaps["count"]:
            many = "s" if gaps["count"] > 1 else ""
            print(f"  time: step {gaps['step']:.4g} s, {gaps['count']} gap{many} (the longest {gaps['longest']:.4g} s)")
        print(f"  stationarity (reverse arrangement, differenced {pre['differences']}x): u = "
              f"{pre['stationarity']['u']:.3f} ({'stationary' if pre['stationarity']['stationary'] else 'NOT stationary'})")
        print(f"  normality: skewness {pre['normality']['skewness']:.3f}, kurtosis {pre['normality']['kurtosis']:.3f}")
        p_value = ar["whiteness"]["p_value"]
        white = (f"Ljung-Box p {p_value:.3g} over {ar['whiteness']['lags']} lags" if p_value == p_value
                 else "whiteness not tested (too few lags)")
        squared = f" ({u.strip()})²" if u else ""  # the unit squared, not the number
        print(f"  AR({ar['order']}) by AIC of the noise (zero bias - drift model), sigma2 {ar['sigma2']:.4g}{squared}, "
              f"{white}")
        for note in report["notes"] + [n for n in [drift.one_way_note(report.get("thermal_lag"))] if n]:
            print(f"  {note}")  # white noise about the drift (no Kalman filter), gaps, a log that runs one way
        for w in list(report["warnings"]) + [w for w in model.summary["warnings"] if w not in report["warnings"]]:
            print(f"warning: {w}")
        for seg, se in zip(model.segments, report["drift_standard_error"]["per_range"]):
            lo, hi = seg["range"]
            print(f"  range [{lo:g}, {hi:g}]: order {seg['order']}, {seg['samples']} samples, residual RMS "
                  f"{seg['residual_rms']:.4g}{u}, drift's standard error up to {se:.3g}{u}")
        steps = [] if args.continuous else model.steps()  # the output steps there as the device crosses
        if steps:
            print("  the model steps by " + ", ".join(f"{step:+.4g}{u} at {where:g} °C" for where, step in steps)
                  + " (each range fitted on its own; --continuous joins them)")
        print(f"  drift over the temperature span (per-level means, peak to peak): "
              f"{report['drift_span_before']:.4g}{u} -> {report['drift_span_after']:.4g}{u} "
              + (f"({report['drift_reduction']:.1f}x smaller)" if np.isfinite(report["drift_reduction"]) else
                 "(one temperature level: no span to compare)"))
        if rated is not None and not rated > abs(pre["mean"]):  # a rating in another unit than the column's
            print(f"warning: --rated {rated:g}{u} is no larger than the zero bias itself (mean {pre['mean']:.4g}{u}): "
                  "is it in another unit? Give it one (--rated 1000A, 1.2kA)")
        output = "filtered output" if model.settings.get("kalman") else "compensated output (no filter)"
        for key, what in (("accuracy", f"{output}, sample by sample"),
                          ("accuracy_compensated", "compensated zero bias W - f(T), sample by sample"),
                          ("accuracy_drift", "drift alone, per-level means")):
            if key in report:
                acc = report[key]
                cells = ", ".join(f"{p['percent_rated']}%: {p['ratio_error_percent']:.3g} % "
                                  f"({'ok' if p['met'] else 'over'} {p['limit_percent']} %)" for p in acc["points"])
                print(f"  class {acc['class']} at rated {acc['rated']:g}{u or (' A' if rated_note else '')} {'MET' if acc['met'] else 'NOT met'} for "
                      f"the {what} ({cells})")
        print(f"wrote {model.save(args.output)}")
        return 0
    model = drift.DriftModel.load(args.model)
    column = args.column or model.settings.get("column", "zero_bias")  # the model remembers what it was fitted on
    rec = _zero_bias_recording(args, column)
    fitted_unit, unit = model.settings.get("unit"), rec.units.get(column)
    # (a blind check fed a log in A to a model fitted in mA: 900x the drift, said by nothing)
    if fitted_unit and unit and fitted_unit.strip(" []()") != unit.strip(" []()"):
        raise ValueError(f"{args.file}: {column} is in {unit}, and the drift model {args.model} was fitted to a zero "
                         f"bias in {fitted_unit}: convert the column to {fitted_unit}, or fit a model to this file")
    if bool(fitted_unit) != bool(unit):  # (a blind check: an A model on a mA file, 1000× off, said by nothing)
        print(f"warning: {column} is in {unit or 'no unit stated'} in {args.file}, the drift model {args.model} was "
              f"fitted to one in {fitted_unit or 'no unit stated'}: they are taken as the same unit — if they are "
              "not (A and mA), the compensation is off by the factor; state the unit in both files")
    if "skipped_lines" in rec.metadata:
        print(skipped_words(rec.metadata['skipped_lines'], "not in the output"))
    for w in drift.fit_warnings(model):  # what the fit said of the model goes with it
        print(f"warning: {args.model} (at its fit): {w}")
    fitted = model.settings.get("temperature") or {}
    # the temperature column the model was fitted on, as the zero bias's, when this file has it
    temp_column = args.temp_column or (fitted.get("column") if fitted.get("column") in rec.columns else None)
    temp, outside, temperature = _temperatures(rec, temp_column, args.outside_column or fitted.get("outside")
                                               or "temp_outside", args.file)
    if outside is None and model.regressor == "difference":  # (a blind check: "temp_outside: needed", no file named)
        wanted = args.outside_column or fitted.get("outside") or "temp_outside"
        raise ValueError(f"{args.file}: no column {wanted!r}: the drift model {args.model} is a function of the inside-"
                         f"outside temperature difference and needs the outside temperature (columns: "
                         f"{', '.join(rec.columns)}; name it with --outside-column)")
    # a temperature that is not a number is the file's (not one outside the model's ranges): said as drift fit says it
    _require_finite(rec, args.file, ((temperature["column"], temp), (args.outside_column or "temp_outside", outside)))
    lo, hi = model.span()
    if args.outside_range == "error":  # the model's text, with the file's line and the option as the CLI spells it
        said = drift.outside_ranges_words(model, temp, "--outside-range nan", counted=np.isfinite(rec.columns[column]),
                                          name=temperature["column"], where=str(args.file),
                                          word="line" if rec.line_numbers is not None else "row",
                                          labels=rec.line_numbers, source=f"the drift model {args.model}")
        if said:
            raise ValueError(said)
        if outside is not None and model.regressor == "difference":  # (said with its file line, as the above)
            unseen = model.beyond_differences(temp, temp - outside) & np.isfinite(rec.columns[column])
            if unseen.any():
                raise ValueError(model.differences_words(
                    temp, temp - outside, unseen, f"{args.file}, {'line' if rec.line_numbers is not None else 'row'}",
                    rec.line_numbers, option="--outside-range nan"))
    compensated = model.compensate(rec.columns[column], temp, outside, outside=args.outside_range)
    known = ~np.isnan(compensated)  # with --outside-range nan, the samples the model speaks for
    missing = ~np.isfinite(rec.columns[column])  # (NaN in, NaN out: not the temperature's doing)
    if missing.any():
        print(f"warning: {args.file}: {missing.sum()} of {len(rec)} samples of {column} are not numbers "
              f"({_lines_of(rec, missing)}): NaN in {column}_compensated")
    unknown = int((~known & ~missing).sum())
    if unknown and not known.any():
        # NaN for every sample is what --outside-range nan asks for, but a file of nothing but NaN is seldom what
        # was meant (another chamber, a temperature in another unit, the wrong model): written, and said loudly
        hot = temp[~missing & np.isfinite(temp)]
        seen = ("" if not hot.size else f" (this file's {hot.min():g} °C)" if hot.min() == hot.max() else
                f" (this file's {hot.min():g} … {hot.max():g} °C)")
        every = f"every sample with a {column} reading" if missing.any() else "every sample"
        print(f"warning: {args.file}: {every} ({unknown} of {len(rec)}) is outside the model's range "
              f"[{lo:g}, {hi:g}] °C of its temperature {temperature['column']!r}{seen}: {column}_compensated is NaN "
              "throughout (--outside-range nan; without it this is an error). Is it the right model, and the "
              "temperature's column and unit?" + (f" ({hint})" if (hint := drift.outside_unit_hint(
                  hot, lo, hi, temperature["column"])) else ""), file=sys.stderr)
    elif unknown:
        print(f"warning: {unknown} of {len(rec)} samples at temperatures outside the model's {lo:g} … {hi:g} °C"
              f"{' (or inside–outside differences outside those its ranges saw)' if model.regressor == 'difference' else ''}"
              f" are NaN in {column}_compensated (the polynomials are not extrapolated)")
    out_name = f"{column}_compensated"
    columns = {**rec.columns, out_name: compensated}
    names = [out_name]
    if args.filtered:  # the firmware's output (export-c --kalman runs this filter on W − f(T))
        order, times = _drift_time_order(rec, args.file)  # filtered in time, written in the file's order
        filtered = np.empty_like(compensated)
        filtered[slice(None) if order is None else order] = drift.filter_compensated(
            model, compensated if order is None else compensated[order], times)
        columns[f"{column}_filtered"] = filtered
        names.append(f"{column}_filtered")
        kalman = model.settings["kalman"]
        gain = drift.dc_gain(drift.ArKalman(model.settings["ar"]["coefficients"], kalman["q"], kalman["r"],
                                            steady_state=True))
        if abs(gain - 1) > 0.01:  # (a blind check's 0.0200 A offset came out as 0.0122 A, unsaid)
            print(f"note: the filter passes a constant at {gain:.3g}x: an offset left in {column} after the drift model "
                  f"shows {gain:.3g}x in {column}_filtered — judge offsets on {column}")
    units = {**rec.units, **({n: rec.units[column] for n in names} if rec.units.get(column) else {})}
    write_output(args.output, Recording(columns=columns, units=units, source=str(args.output),
                                        metadata={**rec.metadata, "drift_model": args.model}))
    # the span is of the samples compensated: with none there is none to give
    span = (f"drift span {drift.drift_span(rec.columns[column][known], temp[known]):.4g} -> "
            f"{drift.drift_span(compensated[known], temp[known]):.4g}" if known.any() else
            "every value NaN: no sample compensated")
    print(f"wrote {args.output}: {len(rec)} rows, column{'s' if len(names) > 1 else ''} {', '.join(names)} ({span})")
    if not fitted_unit and not unit and known.any():
        raw = rec.columns[column][known]
        factor = _unit_factor(raw, raw - compensated[known], temp[known])  # (the model's f: what it took off)
        if factor:
            print(f"warning: {column} in {args.file} drifts over its temperatures {factor:.3g}× as much as the drift "
                  f"model {args.model} does there, and neither file states a unit: one in {_unit_pair(factor)}? "
                  f"(the compensation is then off by {10 ** round(np.log10(max(factor, 1 / factor))):g}×; state the "
                  "unit in both files)")
    return 0


def _unit_pair(factor: float) -> str:
    """The units a factor of 10³, 10⁶ or 10⁹ between two logs of a current suggests ("A and the other in mA")."""
    decades = round(np.log10(max(factor, 1.0 / factor)))
    return {3: "A and the other in mA (or mA and µA)", 6: "A and the other in µA", 9: "kA and the other in µA"}.get(
        decades, "another unit")


def _unit_factor(values, model_drift, temp) -> float | None:
    """How many times the drift of `values` over temperature (per-level means) is the model's over the same
    temperatures, when that is a unit's factor (within 3x of 10³, 10⁶, 10⁹ either way: a blind check's mA log compensated by an A model,
    neither stating a unit, had "drift span 594.5 -> 593.9" printed and nothing else), else None."""
    from . import drift

    ours, its = drift.drift_span(values, temp), drift.drift_span(model_drift, temp)
    if not (ours > 0 and its > 0):
        return None
    factor = ours / its
    # within 3x of 10³, 10⁶ or 10⁹: A against mA, µA (a blind check's µA log beside an A model: silent), kA
    decades = np.log10(max(factor, 1.0 / factor))
    return factor if any(abs(decades - k) <= np.log10(3.0) for k in (3, 6, 9)) else None


def _print_diagnosis(result, args, limits=None) -> int:
    """The diagnosis as text (and its detection limits), plus the JSON and the report folder when asked (both
    models)."""
    print(result.text())
    if limits is not None:
        print("\n" + limits.text())
    if args.json:
        path = result.save_json(args.json)
        if limits is not None:  # one file: the diagnosis with its limits under "detection_limits"
            content = json.loads(path.read_text())
            content["detection_limits"] = json.loads(limits.to_json())
            path.write_text(json.dumps(content, indent=2) + "\n")
        print(f"wrote {path}")
    if args.report:
        print(f"wrote {result.report(args.report)}")
    return 0


def _diagnose_cable(args) -> int:
    """`fluxcal diagnose RING.csv --model cable`: the ring's sim-to-real gap (fluxcal.diagnose.diagnose_cable)."""
    from . import cable
    from .diagnose import diagnose_cable

    if isinstance(args.noise_sigma, list):
        raise ValueError("--noise-sigma: --model cable takes one σ (tesla) for all the ring's sensors, got three "
                         "(one per sensor: fluxcal.diagnose_cable(noise_sigma=[…]) in Python)")
    ring = cable.read_ring_csv(args.file, bad_lines=args.bad_lines)
    _ring_notes(cable, ring)
    candidates = args.candidates.split(",") if args.candidates else None
    result = diagnose_cable(ring["readings"], ring["ring"], currents=ring["currents_a"],
                            rotations_deg=ring["rotations_deg"], positions=ring["positions_m"], t=ring["t_s"],
                            calibration=args.calibration, noise_sigma=args.noise_sigma, candidates=candidates,
                            fit_currents=args.fit_currents or None, alpha=args.alpha, progress=not args.quiet,
                            max_effects=args.max_effects, source=str(args.file))
    return _print_diagnosis(result, args)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="fluxcal", description="Calibrate magnetic-field and current sensors.")
    p.add_argument("--version", action="version", version=f"fluxcal {__version__}")
    p.add_argument("--cmake-dir", action="store_true",
                   help="print the folder of fluxcalConfig.cmake (for C++: find_package(fluxcal))")
    sub = p.add_subparsers(dest="command")

    columns_help = ("the three magnetometer columns (default mx,my,mz or x,y,z; two of a biaxial sensor, for "
                    "calibrate --planar and apply); for a table without a header one name per column; for .mat/.npz "
                    "the N×3 matrix variable")
    output_help = "the format follows the extension (.npz .mat .parquet .json), CSV text otherwise"
    bad_lines_help = ("a text line with the wrong number of fields or a non-number: stop with its line and column "
                      "(error, default) or leave it out and list it (skip)")
    decimal_help = ("labelled text logs (X: 1,234) and ';' or tab tables whose commas nothing in the file "
                    "settles: ',' reads them as decimal commas, '.' as thousands separators")
    c = sub.add_parser("calibrate", help="calibrate a magnetometer from a recording (CSV, TSV, .npz, .mat, Parquet, "
                                         "JSON)",
                       epilog="exit status: 0 a calibration; 2 an error (nothing written); 3 not identifiable: the "
                              "data did not determine every parameter (with -o it is written for inspection; export-c "
                              "refuses it)")
    c.add_argument("file")
    c.add_argument("--field-norm", type=norm_or_column, default=None,
                   help="known |field|, in --field-units (default: fitted; a fluxcal simulation's own metadata); or "
                        "the name of a column holding each reading's |field| (a scalar magnetometer logged beside "
                        "it): the refinement and twostep fit each reading to its own; or a file whose F (or vector's "
                        "magnitude) is taken at this recording's clock times (an observatory's IAGA-2002 file); or "
                        "igrf: the IGRF's |F| at each reading's lat, lon, alt columns and clock time (an orbit, a "
                        "survey flight)")
    c.add_argument("--field-units", default=None,
                   help="unit of --field-norm and of the corrected field h (default: the readings' unit; give it when "
                        "the readings are counts, e.g. --field-norm 48.2 --field-units uT)")
    c.add_argument("--columns", default=None, help=columns_help)
    c.add_argument("--bad-lines", default="error", choices=["error", "skip"], help=bad_lines_help)
    c.add_argument("--decimal", default=None, choices=[",", "."], metavar="{',' or '.'}", help=decimal_help)
    c.add_argument("--units", default=None, type=reading_unit, help="units of the readings when the file does not say")
    c.add_argument("--reference", default=None,
                   help="three columns with the true field per reading, sensor frame (e.g. rx,ry,rz): the vector "
                        "fit (default: attitude pitch,roll,yaw with local field igrf_n,igrf_e,igrf_d when present)")
    c.add_argument("--method", default="auto", choices=METHODS,
                   help="auto = consistent ellipsoid fit (ALS) + maximum-likelihood refinement (default)")
    c.add_argument("--shape", default="auto", choices=["auto", "sym", "diag", "sphere", "eye"],
                   help="the refinement's matrix, as MATLAB magcal's fit types: auto (default: the "
                        "lowest BIC), sym (symmetric soft iron), diag (axis scales), sphere or eye (one scale)")
    c.add_argument("--outliers", default="drop", choices=["drop", "keep"],
                   help="drop (default): leave gross outliers (0,0,0 glitches, ADC rails, spikes) out of the fit "
                        "and list them; keep: fit every reading")
    c.add_argument("--noise-sigma", type=three_sigmas, default=None, metavar="SX,SY,SZ",
                   help="the axes' white-noise σ (a datasheet's, or `fluxcal diagnose`'s against reference vectors), in the readings' "
                        "unit: the refinement weights each axis by its own (maximum likelihood when one axis, often z, "
                        "is noisier); only their ratios matter")
    c.add_argument("--serial-correlation", default=None, choices=["automatic", "independent", "newey_west"],
                   help="standard errors: automatic (default) widens them (Newey-West) when the readings are "
                        "correlated in time; independent when the rows are not in time order (with --planar it also "
                        "leaves out the check of an offset that moved, which needs time order)")
    c.add_argument("--align-accelerometer", action="store_true",
                   help="also turn the magnetometer's axes onto the accelerometer's (its columns ax,ay,az or "
                        "AccX…), from the dip that stays the same at rest in every attitude; the calibration "
                        "then corrects into the accelerometer's axes (fluxcal.alignment)")
    c.add_argument("--acc-measures", choices=["specific_force", "gravity"], default="specific_force",
                   help="with --align-accelerometer: what the accelerometer reads at rest: specific_force (up, as "
                        "MEMS parts do; default) or gravity (down)")
    c.add_argument("--planar", nargs="?", const="auto", default=None, type=_plane_option, metavar="{" + ",".join(PLANES) + "}",
                   help="a sensor that only turns about one axis (a vehicle's heading): calibrate the two axes of "
                        "its turning plane (offset and 2×2 soft iron; found from the readings, or the sensor axes "
                        "given, e.g. --planar xy) and pass the third through, whose offset and gain such data "
                        "cannot show; --field-norm is then the HORIZONTAL field H (fluxcal.calibrate_planar)")
    c.add_argument("-o", "--output", help="write the calibration (JSON)")
    c.add_argument("--plot", help="write a before/after plot (PNG)")
    c.set_defaults(run=cmd_calibrate)

    a = sub.add_parser("apply", help="correct a recording with a saved calibration")
    a.add_argument("calibration")
    a.add_argument("file")
    a.add_argument("-o", "--output", required=True, help=output_help)
    a.add_argument("--columns", default=None, help=columns_help)
    a.add_argument("--units", default=None, type=reading_unit, help="units of the readings when the file does not say (converted to "
                                                  "the calibration's)")
    a.add_argument("--bad-lines", default="error", choices=["error", "skip"], help=bad_lines_help)
    a.add_argument("--decimal", default=None, choices=[",", "."], metavar="{',' or '.'}", help=decimal_help)
    a.add_argument("--heading", nargs="?", const="frd", default=None, choices=["frd", "flu"],
                   help="also write each reading's heading in degrees [0, 360), clockwise from north, for a planar "
                        "calibration of a level sensor's x, y: frd (default: x forward, y right, z down, as "
                        "ArduPilot and PX4) or flu (x forward, y left, z up, as ROS); the sensor's mounting "
                        "alignment is not removed")
    a.add_argument("--declination", type=float, default=0.0,
                   help="with --heading: the magnetic declination in degrees, east positive, added for the true "
                        "heading (default 0: magnetic)")
    a.set_defaults(run=cmd_apply)

    s = sub.add_parser("simulate", help="write a simulated magnetometer recording: readings in independent "
                                        "orientations, no time column (--effects: a time series)")
    s.add_argument("-o", "--output", required=True, help=output_help)
    s.add_argument("--n", type=positive_int, default=2000, help="readings (independent orientations; default 2000)")
    s.add_argument("--noise", type=non_negative_number, default=0.005, help="white noise, fraction of |field|")
    s.add_argument("--seed", type=int, default=0, help="random seed of the sensor's errors and the noise")
    s.add_argument("--field-norm", type=positive_number, default=50000.0, help="|field| (default 50000)")
    s.add_argument("--units", default="nT", help="unit of the field and the readings (default nT)")
    s.add_argument("--effects", default=None,
                   help="instead: a minute of a hand-turned sensor at 50 Hz in uT, with temperature, carrying these "
                        "unmodelled effects (comma-separated names of `fluxcal diagnose`'s candidates; 'none' for "
                        "none), to try the diagnosis on (fluxcal.sim.withheld; the truth in the file's metadata: "
                        "each effect's parameters with units as true_<effect>, the noise, the base correction; "
                        "--n/--noise/--field-norm/--units do not apply)")
    s.set_defaults(run=cmd_simulate)

    g = sub.add_parser("diagnose", help="find which unmodelled effect makes a recording depart from its model")
    g.add_argument("file", help="a recording with mx,my,mz and whatever of t, temp, current it has; with --model "
                                "cable a ring recording (s0_x, s0_y, …, i0, …: see fluxcal.cable.RING_FORMAT)")
    g.add_argument("--model", default=None, choices=["ellipsoid", "scale", "vector", "vector_scale", "cable"],
                   help="base model (default: ellipsoid, or vector with --reference; cable: a ring CSV)")
    g.add_argument("--calibration", default=None,
                   help="--model cable: ring calibration JSON (`fluxcal cable calibrate`); readings raw")
    g.add_argument("--fit-currents", action="store_true",
                   help="--model cable: fit currents per snapshot (i0, i1… only judge the error)")
    g.add_argument("--reference", default=None, help="three columns with the true field per reading (vector model)")
    g.add_argument("--columns", default=None, help=columns_help)
    g.add_argument("--bad-lines", default="error", choices=["error", "skip"], help=bad_lines_help)
    g.add_argument("--decimal", default=None, choices=[",", "."], metavar="{',' or '.'}", help=decimal_help)
    g.add_argument("--units", default=None, type=reading_unit, help="units of the readings when the file does not say")
    g.add_argument("--field-norm", type=norm_or_column, default=None,
                   help="known |field| (default: fitted), or each reading's: a column (a scalar magnetometer logged "
                        "beside the sensor), another recording with clock times (an observatory's IAGA-2002 F) or "
                        "igrf (at each reading's lat, lon, alt), for a field that changes while the sensor turns "
                        "(the magnitude models)")
    g.add_argument("--noise-sigma", type=sigma_or_per_axis, default=None,
                   help="white-noise σ of the readings, in their unit (tesla for --model cable), or three separated "
                        "by commas (x, y, z: a datasheet's per axis: each axis is weighted by its own, against reference "
                        "vectors and in a magnitude's distance to the ellipsoid alike). Default, in this "
                        "order: --model cable: the scatter of repeated snapshots (same rotation and currents), else "
                        "the --calibration's scatter, else the base fit's residuals (a misfit then counts as noise); "
                        "the other models: third differences of the readings in time order, or of the base model's "
                        "residuals when those are smaller and the readings' differences hold the motion (fast turns, "
                        "held positions, uneven times) or the rows are not a time series (then an upper bound: the "
                        "residuals hold the model's misses too); at least the quantization floor LSB/√12")
    g.add_argument("--temp-column", default=None,
                   help="the sensor's temperature column when its name is not recognised (T, thermistor, …); °F and "
                        "K converted by its unit")
    g.add_argument("--current-column", default=None,
                   help="the column of a current drawn near the sensor when its name is not recognised (I, motor_I, "
                        "…), in A or mA by its unit")
    g.add_argument("--candidates", default=None, help="comma-separated effect names (default: all)")
    g.add_argument("--alpha", type=float, default=0.01, help="significance level (default 0.01)")
    g.add_argument("--max-effects", type=positive_int, default=3,
                   help="stop after accepting this many effects (default 3; the report lists any further "
                        "significant one)")
    g.add_argument("--detection-limits", action="store_true",
                   help="also measure how large each candidate must be before this recording's diagnosis confirms "
                        "it (those of --candidates, default all, each judged as in the full diagnosis): each added to the recording "
                        "at doubling sizes "
                        "(fluxcal.detection_limits; minutes on a long recording)")
    g.add_argument("--seeds", type=positive_int, default=3,
                   help="--detection-limits: shapes of each effect per size (default 3)")
    g.add_argument("--json", default=None, help="write the ranking and tables (JSON)")
    g.add_argument("--report", default=None, help="folder for the report: summary, figures, index.html")
    g.add_argument("--quiet", action="store_true", help="no progress bar")
    # (no --field-units: the base model's |h| is in the unit of the |field| given, which --field-norm's readers
    # note here as calibrate's do)
    g.set_defaults(run=cmd_diagnose, field_units="")

    k = sub.add_parser("cable", help="multicore-cable current ring: simulate, calibrate (TWOSTEP per sensor), solve")
    ksub = k.add_subparsers(dest="cable_command", required=True)
    ks = ksub.add_parser("simulate", help="write a simulated ring recording (CSV, columns s<k>_x, s<k>_y in tesla)")
    ks.add_argument("-o", "--output", required=True)
    ks.add_argument("--calibration", action="store_true", help="the calibration procedure: 5 × 72°, both polarities")
    ks.add_argument("--current", type=positive_number, default=5.0,
                    help="current of the two cores, equal and opposite (A)")
    ks.add_argument("--rotations", default="0", help="comma-separated ring rotations (degrees) of the snapshots")
    ks.add_argument("--repeats", type=positive_int, default=5,
                    help="readings per calibration state; with --calibration only (a measurement's snapshots are one "
                         "per --rotations entry: repeat an entry for repeated snapshots, e.g. 0,0,0,0,90,90,90,90,…, "
                         "which diagnose --model cable takes the noise from when they hold at least 10 beyond the "
                         "first of each run)")
    ks.add_argument("--lab", action="store_true", help="add the unmodelled effects (ferro parts, z leakage, Earth)")
    ks.add_argument("--seed", type=int, default=0, help="the simulated instrument (sensor errors)")
    ks.add_argument("--noise-seed", type=int, default=None, help="the noise (default: --seed)")
    kc = ksub.add_parser("calibrate", help="per-sensor calibration from a calibration recording")
    kc.add_argument("file")
    kc.add_argument("--method", default="auto", choices=["auto", "twostep", "least_squares", "in_field"],
                    help="auto (default): twostep, or in_field when a field that does not follow the currents explains "
                         "twostep's lack of fit or refusal (the Earth's on a bench; said); "
                         "twostep: TWOSTEP 2-D per sensor with the true magnitude of every reading; "
                         "least_squares: the ordinary ellipse fit on one magnitude (the RMS), the paper's "
                         "comparison; in_field: in a field that does not follow the currents (the Earth's, a "
                         "neighbouring conductor's), fitted with the offsets, from each rotation's currents reversed")
    kc.add_argument("--bad-lines", default="error", choices=["error", "skip"], help=bad_lines_help)
    kc.add_argument("-o", "--output", help="write the calibration (JSON)")
    kv = ksub.add_parser("solve", help="conductor positions and currents of every snapshot")
    kv.add_argument("file")
    kv.add_argument("--calibration", help="a calibration JSON from `fluxcal cable calibrate`")
    kv.add_argument("--subtract-background", action="store_true",
                    help="take the calibration's field that does not follow the currents (`cable calibrate --method "
                         "in_field`) off every snapshot: for a ring recording where it was calibrated")
    kv.add_argument("--subtract-zero", action="store_true",
                    help="take each rotation's zero-current snapshots (all reference currents 0) off the others: the "
                         "room's field, its gradient too, and the sensors' offsets cancel (DC currents; the "
                         "calibration's gains are applied, its offsets not)")
    kv.add_argument("--fit-background", action="store_true",
                    help="fit a uniform field that does not follow the currents (the Earth's, a far busbar's) beside "
                         "the conductors, in the cable's frame; with --joint one per rotation, shared by its snapshots (on a "
                         "4-sensor ring a snapshot alone is then an exact fit: use --joint)")
    kv.add_argument("--leave-out", default=None, metavar="SENSORS",
                    help="comma-separated sensor numbers to solve without (a sensor miswired, swapped or stuck: "
                         "`fluxcal diagnose FILE --model cable` names one that departs alone)")
    kv.add_argument("--conductors", type=positive_int, default=2, help="conductors in the cable (default 2)")
    kv.add_argument("--zero-sum-currents", action="store_true",
                    help="the currents sum to zero (go and return, a balanced three-phase load): one unknown "
                         "fewer per snapshot")
    kv.add_argument("--joint", action="store_true",
                    help="solve the snapshots at each rotation together: the conductors' positions shared, the "
                         "currents per snapshot (AC waveforms; three or more conductors need it)")
    kv.add_argument("--noise-sigma", type=positive_number, default=None,
                    help="the sensors' noise σ (T) the standard errors take (default: the calibration's scatter, "
                         "else 1e-8 T, said)")
    kv.add_argument("--noise-sigma-dof", type=_dof_or_inf, default=None,
                    help="the degrees of freedom behind --noise-sigma (e.g. repeated readings less one per pose): a "
                         "misfit is then also an F test's p below 1e-3, which catches a residual of 1.5–5 σ; without "
                         "it only a residual above 5 σ is (σ from the calibration's repeats brings its own). inf: σ "
                         "known exactly — claimed for a σ 30 %% too small, it flagged 32 %% of good fits in a blind "
                         "check (79 %% at 31 dof or more)")
    kv.add_argument("--placement-sigma", type=positive_number, default=None, metavar="M",
                    help="each sensor's position tolerance (metres, radial and along the ring), carried into the "
                         "standard errors: few sensors absorb a misplacement without a misfit (one of 4 sensors "
                         "0.25 mm out left the currents 9 %% off, ± 7–11x too small)")
    kv.add_argument("--axis-sigma", type=positive_number, default=None, metavar="DEG",
                    help="each sensor's axes' angular tolerance (degrees), carried into the standard errors")
    kv.add_argument("--bad-lines", default="error", choices=["error", "skip"], help=bad_lines_help)
    kv.add_argument("-o", "--output", default=None, help="write the solutions (positions, currents, standard "
                                                        "errors, flags) as JSON; exit status 3 when no snapshot's "
                                                        "solution fits the model and is well conditioned")
    k.set_defaults(run=cmd_cable)

    x = sub.add_parser("export-c", help="write a calibration as a C header for firmware (float and Q-format), "
                                        "with a drift model's f(T) and fixed-point Kalman filter if asked")
    x.add_argument("calibration", nargs="?", default=None,
                   help="a calibration JSON (fluxcal calibrate -o); leave it out for a header of --drift/--kalman only")
    x.add_argument("-o", "--output", required=True, help="the header to write (.h)")
    x.add_argument("--q-format", default=None, help="int32 fixed-point format Qm.n, m + n = 31 (default: the "
                                                    "smallest m that holds the calibration's range)")
    x.add_argument("--input-range", type=positive_number, default=None,
                   help="the sensor's full scale in the calibration's units (e.g. 32768 for int16 counts): the "
                        "Q format must correct every reading up to it without saturating (default: 2 x the "
                        "calibration readings' extent)")
    x.add_argument("--kalman-range", type=positive_number, default=None,
                   help="the largest |input| the Kalman filter must take without saturating, in its input's unit "
                        "(default: 8 sigma of its input; readout spikes beyond it saturate, overflow flagged)")
    x.add_argument("--name", default=None, help="C prefix of every name (default: the header's file name)")
    x.add_argument("--kalman", default=None, help="also export a fixed-point AR Kalman filter: a JSON of "
                                                  "fluxcal.export_c.save_kalman or a drift model (fluxcal drift fit)")
    x.add_argument("--drift", default=None, help="also export a drift model's f(T) per temperature range (a JSON of "
                                                 "fluxcal drift fit), in double with a test vector")
    x.add_argument("--force", action="store_true", help="export a calibration whose data did not determine every "
                                                        "parameter (identifiable NO), or whose offset moved within "
                                                        "its log; a --drift whose fit warned its temperatures look "
                                                        "like °F or K: marked so in the header (a --kalman whose "
                                                        "noise model the fit rejected is written with a WARNING in "
                                                        "the header, without --force)")
    x.set_defaults(run=cmd_export_c)

    d = sub.add_parser("demo", help="simulate a magnetometer, calibrate it, print and plot the result")
    d.add_argument("-o", "--output", default="fluxcal-demo", help="folder for the outputs")
    d.add_argument("--seed", type=int, default=2017)
    d.set_defaults(run=cmd_demo)

    q = sub.add_parser("positions", help="multi-position calibration U = U0 + K H with accelerometer levelling")
    q.add_argument("file", help="a recording with an accelerometer and a magnetometer (ax,ay,az, mx,my,mz, or "
                                "as calibrate finds them) and optionally a column position (rows averaged per "
                                "position)")
    q.add_argument("--columns", default=None, help=columns_help)
    q.add_argument("--bad-lines", default="error", choices=["error", "skip"], help=bad_lines_help)
    q.add_argument("--noise-sigma", type=float, default=0.0, help="the outputs' noise per position (after averaging); default: from the scatter within positions when the rows repeat")
    q.add_argument("--preset", choices=["twelve"], default=None,
                   help="nominal attitudes: twelve = where the body axes x, y, z point in positions 1–12 (frame nue: "
                        "x forward, y up, z right; N/S/E/W/U/D): N-U-E, S-U-W, S-D-E, N-D-W, U-S-E, U-N-W, D-N-E, "
                        "D-S-W, N-W-U, S-E-U, N-E-D, S-W-D (the recording's rows in this order, or a position column)")
    q.add_argument("--frame", choices=["ned", "nue"], default="ned",
                   help="ned: body forward-right-down; nue: seed 002 forward-up-right (default ned)")
    q.add_argument("--field", help="local field N,E,D (field units)")
    q.add_argument("--total", type=float, help="field magnitude (with --inclination)")
    q.add_argument("--inclination", type=float, help="dip in degrees, positive down")
    q.add_argument("--declination", type=float, help="degrees east (default 0)")
    q.add_argument("--lat", type=float, help="latitude (IGRF)")
    q.add_argument("--lon", type=float, help="longitude (IGRF)")
    q.add_argument("--alt-km", type=float, help="altitude in km (IGRF)")
    q.add_argument("--date", help="YYYY-MM-DD (IGRF; default today)")
    q.add_argument("--estimate-yaw", action="store_true", help="estimate a heading correction per position")
    q.add_argument("--estimate-inclination", action="store_true", help="estimate the dip jointly")
    q.add_argument("--tilt-sigma", type=float, default=0.0, help="levelling uncertainty (deg); 0 = exact")
    q.add_argument("--acc-measures", choices=["specific_force", "gravity"], default="specific_force",
                   help="what the accelerometer reads at rest: specific_force (up, as MEMS parts do; default) or "
                        "gravity (down)")
    q.add_argument("--calibrate-accelerometer", action="store_true",
                   help="calibrate the accelerometer from the same positions first (>= 6 distinct gravity "
                        "directions; its misalignment needs 9, which the twelve positions alone do not give)")
    q.add_argument("--leave-out", default=None, metavar="LABELS",
                   help="positions to leave out of the fit, as the position column names them (e.g. 7 or 5,9): "
                        "each is reported held out, read by the others' calibration against its nominal attitude")
    q.add_argument("-o", "--output", help="write the result (JSON)")
    q.set_defaults(run=cmd_positions)
    dr = sub.add_parser("drift", help="temperature-drift compensation of a current transformer's zero bias (seed 001)")
    drs = dr.add_subparsers(dest="drift_command", required=True)
    df = drs.add_parser("fit", help="fit a drift model to a CSV with columns t, zero_bias, temp [, temp_outside]; "
                                    "gaps in t (holds logged alone, lost lines) are not reached across")
    df.add_argument("file")
    df.add_argument("-o", "--output", required=True, help="drift model (JSON)")
    df.add_argument("--column", default="zero_bias", help="the zero-bias column to model (e.g. one phase's)")
    temp_help = ("the device temperature's column (default: the one named temp, temperature, temp_C, "
                 "Temperature (°F), …); °F and K are converted to °C by the column's unit")
    outside_help = "the outside (chamber) temperature's column, for --regressor difference (default temp_outside)"
    df.add_argument("--temp-column", default=None, help=temp_help)
    df.add_argument("--outside-column", default="temp_outside", help=outside_help)
    df.add_argument("--regressor", default="temp", choices=("temp", "difference"),
                    help="polynomial variable: device temperature or temp - temp_outside")
    df.add_argument("--breakpoints", default="-20,0,30,50", help="temperature range edges (degC)")
    df.add_argument("--max-order", type=int, default=4, help="highest polynomial order the F-test may choose "
                                                             "per range (default 4)")
    df.add_argument("--significance", type=float, default=0.05, help="of the F-test (0.05 or 0.01)")
    df.add_argument("--continuous", action="store_true", help="drift continuous at the breakpoints")
    df.add_argument("--drop-spikes", action="store_true",
                    help="leave the zero bias's spikes (a readout's glitches: samples that leave the noise's course "
                         "for at most 3 samples, farther than it can) out of the fit; without it they are named in a "
                         "warning")
    df.add_argument("--ar-max-order", type=int, default=10,
                    help="highest AR order AIC may choose for the noise about the drift (default 10)")
    df.add_argument("--steady-state", action="store_true", help="Kalman filter with the steady-state gain")
    df.add_argument("--rated", default=None, help="rated current for the class check: a number in the zero bias's "
                                                  "unit, or with its own (1000A, 1.2kA, 800mA)")
    df.add_argument("--class", dest="accuracy_class", default="0.2S", choices=("0.2S", "0.5S"))
    df.add_argument("--drift-input", default="zero_bias", choices=("zero_bias", "filtered"),
                    help="fit the drift to the zero bias (default; GLS with an AR noise model) or refit it to the "
                         "Kalman output L (seed 001 as written; L = that drift + the filtered noise)")
    df.add_argument("--bad-lines", default="error", choices=["error", "skip"], help=bad_lines_help)
    da = drs.add_parser("apply", help="compensate a recording: writes its columns plus zero_bias_compensated")
    da.add_argument("model")
    da.add_argument("file")
    da.add_argument("-o", "--output", required=True, help=output_help)
    da.add_argument("--column", default=None, help="column to compensate (default: the one the model was fitted on)")
    da.add_argument("--temp-column", default=None, help=temp_help)
    da.add_argument("--outside-range", default="error", choices=["error", "nan"],
                    help="a sample hotter or colder than the model's ranges: an error (default), or NaN in the "
                         "output (the others compensated; every sample outside: all NaN, with a warning)")
    da.add_argument("--outside-column", default=None,
                    help="the outside temperature's column (default: the one the model was fitted with)")
    da.add_argument("--filtered", action="store_true",
                    help="also write <column>_filtered: the model's Kalman filter on the compensated zero bias (what "
                         "export-c --kalman runs in firmware), started again after gaps in t and NaN stretches")
    da.add_argument("--bad-lines", default="error", choices=["error", "skip"], help=bad_lines_help)
    dr.set_defaults(run=cmd_drift)
    from .batch import add_batch_parser
    from .io.serial import add_record_parser
    from .live import add_live_parser

    add_record_parser(sub)
    add_live_parser(sub)
    add_batch_parser(sub)
    return p


# a list of numbers that starts with a minus (--breakpoints -20,0,30,50, --field -3.1,20,45): argparse would take
# it for an option and stop with "expected one argument"
_NUMBER_LIST = re.compile(r"-(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?(?:,\s*-?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)+")


def _join_negative_lists(argv: list) -> list:
    """`--option -20,0,30` → `--option=-20,0,30`, so a comma-separated list of numbers may start with a minus."""
    out = []
    for word in argv:
        if out and out[-1].startswith("--") and "=" not in out[-1] and _NUMBER_LIST.fullmatch(word):
            out[-1] = f"{out[-1]}={word}"
        else:
            out.append(word)
    return out


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """A library's warning on the command line as `warning: …` (with its kind unless a UserWarning), without
    Python's source line."""
    kind = "" if category is UserWarning else f"{category.__name__}: "
    print(f"warning: {kind}{message}", file=sys.stderr if file is None else file)


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(_join_negative_lists(list(sys.argv[1:] if argv is None else argv)))
    if args.cmake_dir:
        try:
            print(cmake_dir())
        except FileNotFoundError as exc:  # a source checkout on PYTHONPATH: the wheel carries the C++ library
            print(f"fluxcal --cmake-dir: error: {exc}", file=sys.stderr)
            return 2
        return 0
    if not args.command:
        parser.print_help()
        return 1
    try:
        with warnings.catch_warnings(), quiet_skipped():  # (each command prints the lines it skipped)
            warnings.showwarning = _show_warning
            check_writes(args)
            return args.run(args)
    except (ValueError, FileNotFoundError) as exc:
        print(f"fluxcal {args.command}: error: {_naming_the_input(str(exc), args)}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # the reader stopped early (| head): not an error of ours; quiet, as cat is
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # Python's exit flush must not fail again
        return 141
    except OSError as exc:  # a file that cannot be written (a folder, no permission, disk full): name it
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"fluxcal {args.command}: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
