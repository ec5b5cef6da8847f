"""Input checks shared by the Python layer: every public function turns array-likes into the exact
layout the C++ core maps without a copy, and names the input when something is wrong."""
from __future__ import annotations

import os

import numpy as np


def as_samples(values, name: str = "samples", columns: int = 3) -> np.ndarray:
    """Return `values` as a C-contiguous float64 (N, columns) array; ValueError naming `name` otherwise."""
    if hasattr(values, "samples") and callable(values.samples):  # a Recording
        values = values.samples()
    elif _is_table(values):  # a DataFrame: by its columns' names (its order mz,mx,my was taken as x,y,z)
        chosen = table_columns(values, name, columns)
        values = values.to_numpy() if chosen is None else values[chosen].to_numpy()
    not_a_file_name(values, name)
    if np.iscomplexobj(values):  # float64 would drop the imaginary part with only a warning
        raise ValueError(f"{name}: complex numbers; readings are real (pass .real or abs() explicitly)")
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: not numeric ({exc})") from None
    if arr.ndim != 2 or arr.shape[1] != columns:
        transposed = arr.ndim == 2 and arr.shape[0] == columns
        hint = " (it looks transposed: pass one row per reading)" if transposed else ""
        raise ValueError(f"{name}: shape {arr.shape}, expected (N, {columns}) with one row per reading{hint}")
    return np.ascontiguousarray(arr)


def not_a_file_name(values, name: str = "samples") -> None:
    """ValueError when `values` is a file name (str, bytes, a Path) rather than readings, pointing to read_recording
    (numpy's own "could not convert string to float" names no file)."""
    if isinstance(values, (str, bytes, os.PathLike)):
        raise ValueError(f"{name}: {os.fspath(values)!r} is a file name, not readings; read it first: "
                         "fluxcal.read_recording(path) gives a Recording every fit takes")


def _is_table(values) -> bool:
    """Whether `values` is a table with named columns (a pandas or polars DataFrame), not an array."""
    return hasattr(values, "columns") and callable(getattr(values, "to_numpy", None)) and not isinstance(
        values, np.ndarray)


def table_columns(table, name: str = "samples", columns: int = 3):
    """The labels of a DataFrame's magnetometer columns in x, y, z order, found by their names as a Recording finds
    them (fluxcal.io.columns.find_magnetometer: mx,my,mz; x,y,z; Bx,By,Bz; MagX..; mag_x_uT.., in any order and
    beside other columns); None when no name says so and the table has exactly `columns` columns (taken in order, as
    an array is); ValueError naming the columns otherwise."""
    from .io.columns import find_magnetometer, find_magnetometer_pair  # (io imports this module)

    labels = list(table.columns)
    text = [str(c) for c in labels]
    listed = ", ".join(text) if len(text) <= 12 else ", ".join(text[:12]) + f", … ({len(text)} columns)"
    if columns == 3:
        try:
            found = find_magnetometer(text, name)
        except ValueError as exc:  # several triples: its advice (--columns / select()) is the command line's
            raise ValueError(f"{str(exc).split('; choose')[0]}; pass the three you mean, in x, y, z order "
                             "(frame[[...]])") from None
        if found is not None:
            return [labels[text.index(n)] for n in found]
        pair = find_magnetometer_pair(text, name) if len(text) == columns else None
        if pair is not None:  # (t, mx, my: by position the time would be taken as the x axis)
            raise ValueError(f"{name}: columns {listed}: {' and '.join(pair[0])} are named as two magnetometer axes "
                             "and the other is not one; give the three field columns (a biaxial sensor's two: "
                             "fluxcal.calibrate_planar)")
    if len(text) == columns:
        return None
    raise ValueError(f"{name}: a table with columns {listed}: no {columns} of them are named as magnetometer axes "
                     f"(mx,my,mz; x,y,z; Bx,By,Bz; MagX,MagY,MagZ; mag_x,…), and by position it has not {columns}; pass "
                     "the field columns in x, y, z order (frame[[...]]) or rename them")


def sample_names(values) -> list | None:
    """The names of the columns as_samples takes from `values` (a Recording's magnetometer columns, a DataFrame's),
    for messages; None for an array."""
    if hasattr(values, "samples") and callable(values.samples) and hasattr(values, "mag_names"):
        return [str(n) for n in values.mag_names()]
    if _is_table(values):
        chosen = table_columns(values)
        return [str(c) for c in (list(values.columns) if chosen is None else chosen)]
    return None


def samples_units(values) -> str:
    """The field unit the readings `values` state: a Recording's (its header, metadata or --units), a DataFrame's from
    its magnetometer columns' names as a file's header gives it (mx [nT], mag_x_uT; fluxcal.io.columns.field_unit_of),
    "" for an array or when none is named. Columns naming different units are a ValueError naming them."""
    if hasattr(values, "field_units") and callable(values.field_units):
        return values.field_units()
    not_a_file_name(values)
    if not _is_table(values):
        return ""
    from .io.columns import field_unit_of

    try:
        chosen = table_columns(values)
    except ValueError:  # (a biaxial sensor's two columns; any other table the fit itself refuses, naming it)
        if len(values.columns) != 2:
            return ""
        chosen = None
    names = [str(c) for c in (list(values.columns) if chosen is None else chosen)]
    named = {n: field_unit_of(n) for n in names}
    units = {u for u in named.values() if u}
    if len(units) > 1 or (units and not all(named.values())):
        raise ValueError("samples: the field columns " + ", ".join(f"{n} ({u or 'no unit'})" for n, u in named.items())
                         + " do not name one unit; rename them (or give units= where the function takes it)")
    return units.pop() if units else ""


def positive_field_norm(field_norm) -> float:
    """One known |field| as a positive finite float, or ValueError naming field_norm and what it takes."""
    value = as_number(field_norm, "field_norm")
    if value > 0 and np.isfinite(value):
        return value
    if value == 0:  # (the core's options take 0 for "fit it"; calibrate's documented way is None)
        raise ValueError("field_norm: 0 is no field magnitude; give the known |field| (a positive number in the "
                         "readings' unit, e.g. from IGRF), or leave it None (calibrate, fit_ellipsoid: the fitted radius)")
    what = "negative" if value < 0 else "not a finite number"
    raise ValueError(f"field_norm: {value:g} is {what}; give the known |field| as a positive number in the readings' "
                     "unit (e.g. from IGRF), or None (calibrate, fit_ellipsoid: the fitted radius)")


def as_specific_force(acc, acc_measures: str = "specific_force", name: str = "acc") -> np.ndarray:
    """Accelerometer rows as the specific force (at rest it points up): `acc_measures` says what the device
    reads — "specific_force" (MEMS parts) or "gravity" (down, as some instruments report it: negated)."""
    a = as_samples(np.atleast_2d(acc), name)
    if acc_measures == "specific_force":
        return a
    if acc_measures == "gravity":
        return -a
    raise ValueError(f"acc_measures: {acc_measures!r} is not 'specific_force' (a level device reads up) or "
                     f"'gravity' (it reads down)")


def require_calibration(value, name: str = "calibration"):
    """TypeError naming `name` unless `value` is a fluxcal Calibration (not None, not a dict)."""
    from .calibration import Calibration

    if not isinstance(value, Calibration):
        raise TypeError(f"{name}: expected a fluxcal.Calibration (from fit_ellipsoid, calibrate, Calibration.load, "
                        f"…), got {type(value).__name__}")
    # Its fields may have been assigned since it was made: checked, and put back in the types the core takes.
    value.offset, value.matrix, value.field_norm = value.checked_fields(name)


def require_finite(arr: np.ndarray, name: str) -> np.ndarray:
    """`arr` (N × 3), or ValueError naming `name` and the first NaN/Inf."""
    bad = first_nonfinite(arr)
    if bad is not None:
        row, col = bad
        raise ValueError(f"{name}: row {row}, column {col} ({'xyz'[col]}) is "
                         f"{'NaN' if np.isnan(arr[row, col]) else 'infinite'}")  # as the core's checks say
    return arr


def past_range(rows: np.ndarray) -> np.ndarray:
    """Mask of the finite rows of `rows` (N×k) whose sum of squares overflows (a garbled reading of 1e300): past
    any sensor's range, and inf or NaN in every norm and fit they enter."""
    with np.errstate(over="ignore", invalid="ignore"):
        return np.isfinite(rows).all(axis=1) & ~np.isfinite(np.einsum("ij,ij->i", rows, rows))


def first_nonfinite(arr: np.ndarray):
    """(row, column) of the first NaN/Inf in `arr`, or None."""
    bad = ~np.isfinite(arr)
    if not bad.any():
        return None
    row = int(np.argmax(bad.any(axis=1)))
    return row, int(np.argmax(bad[row]))


def units_text(units) -> str:
    """The readings' unit for an options struct: "" for None, or TypeError naming `units` when it is not a
    string (pybind11 would list the struct's setter signature instead)."""
    if units is None:
        return ""
    if not isinstance(units, str):
        raise TypeError(f"units: {units!r} is not a string (such as 'uT', 'nT', 'mG', or '' for unstated)")
    return units


def as_number(value, name: str) -> float:
    """A scalar argument as a float; anything that is not one a ValueError naming it (float's own message,
    "could not convert string to float: 'abc'", names no argument)."""
    if np.ndim(value) > 0:  # float() of an array is a deprecation warning, then an error that names no size
        if np.size(value) != 1:
            raise ValueError(f"{name}: {np.size(value)} values where one number is taken")
        value = np.ravel(value)[0]
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: {value!r:.60} is not a number") from None


def set_options(options, settings: dict, what: str):
    """Set each keyword of `settings` on a bound C++ options struct; unknown names and values of the wrong
    type are a TypeError naming the option, NaN a ValueError (a NaN tolerance or σ silently switched a
    check off)."""
    for name, value in settings.items():
        if not hasattr(options, name):
            import difflib

            known = sorted(n for n in dir(options) if not n.startswith("_"))
            near = difflib.get_close_matches(name, known, n=1)
            raise TypeError(f"{what}: unknown option {name!r}" + (f" (did you mean {near[0]!r}?)" if near else "")
                            + f"; its options: {', '.join(known)}")
        if isinstance(value, (float, np.floating)) and np.isnan(value):
            raise ValueError(f"{what}: option {name} is NaN")
        current = getattr(options, name)
        try:
            setattr(options, name, value)
        except TypeError:
            raise TypeError(f"{what}: option {name}={value!r} is not a {type(current).__name__}") from None
    return options


def held_copies(m: np.ndarray):
    """Mask of the readings that are sample-and-hold copies of the one before (a logger faster than its
    sensor repeats the last reading), or None when there are none to speak of. Copies: ≥ 10 % of the rows
    repeat the previous row exactly, and regularly — in runs of one typical length L with 2 ≤ L ≤ 10
    (logger 2–10× the sensor's rate), or, below 2×, single repeats at one typical spacing G ≥ 2 (75 Hz
    logged at 100 Hz: every 4th row). "Typical": ≥ 80 % within ±1 of the mode. A coarse ADC on a slow
    turn also repeats readings, but irregularly, and those repeats are real readings; so are a static
    device's long runs."""
    repeat = np.concatenate([[False], np.all(m[1:] == m[:-1], axis=1)])
    if len(m) < 3 or repeat.mean() < 0.1:
        return None

    def typical(values, low, high):
        counts = np.bincount(values)
        mode = int(np.argmax(counts))
        return low <= mode <= high and counts[max(mode - 1, 1):mode + 2].sum() >= 0.8 * len(values)

    runs = np.diff(np.append(np.flatnonzero(~repeat), len(repeat)))
    spacing = np.diff(np.flatnonzero(repeat))
    regular = typical(runs, 2, 10) or (np.all(runs <= 2) and len(spacing) > 2 and typical(spacing, 2, 10 ** 6))
    return repeat if regular else None


REPEAT_BLOCK = 20  # rows: a stretch this long, of as many distinct readings, repeated exactly is a copy (continuous
                   # readings never repeat by chance; a still sensor's few quantised values repeat row by row, but
                   # do not make 20 distinct readings in the same order)


def repeated_blocks(values: np.ndarray) -> np.ndarray:
    """Mask of the rows that repeat an earlier stretch of rows exactly (a log appended to itself, a buffer
    written twice): runs of ≥ REPEAT_BLOCK rows, holding as many distinct rows, equal row by row to an earlier
    run."""
    n = len(values)
    rows = np.ascontiguousarray(values).view(np.dtype((np.void, values.dtype.itemsize * values.shape[1]))).ravel()
    copied = np.zeros(n, dtype=bool)
    if n < 2 * REPEAT_BLOCK:
        return copied
    # each row's first occurrence (a sort, not a Python pass over the rows: 1.2 ms of a 1000-row calibration's 11)
    _, first, inverse = np.unique(rows, return_index=True, return_inverse=True)
    earlier = first[inverse.ravel()]
    i = 0
    for start in np.flatnonzero(earlier != np.arange(n)):  # only rows seen before can begin a copy
        if start < i or start > n - REPEAT_BLOCK:
            continue
        i, j = int(start), int(earlier[start])
        if not np.array_equal(rows[i:i + REPEAT_BLOCK], rows[j:j + REPEAT_BLOCK]):
            continue
        length = REPEAT_BLOCK
        while i + length < n and rows[i + length] == rows[j + length]:
            length += 1
        if len(np.unique(rows[i:i + length])) >= REPEAT_BLOCK:
            copied[i:i + length] = True
        i += length
    return copied


def repeated_words(copied: np.ndarray) -> str:
    """What repeated_blocks found, in words: how many rows, from where, and what makes such copies."""
    starts = np.flatnonzero(np.diff(np.concatenate([[0], copied.astype(int)])) == 1)
    return (f"{int(copied.sum())} of {len(copied)} rows (from row{'s' if len(starts) > 1 else ''} "
            f"{', '.join(str(i) for i in starts[:5])}{', …' if len(starts) > 5 else ''}) repeat earlier rows exactly, "
            "in the same order (a log appended to itself, a buffer written twice?)")


def field_norms_summary(norms: np.ndarray) -> dict:
    """What a fit to each reading's own |field| says of them in its summary."""
    return {"count": len(norms), "min": float(norms.min()), "max": float(norms.max())}


def field_norm_given(samples, field_norm):
    """`field_norm` as a calibration takes it: a column's name when `samples` is a Recording (its values in the
    readings' unit, Recording.field_norms), a number written as text as that number; else as given."""
    if not isinstance(field_norm, str):
        return field_norm
    if not (hasattr(samples, "columns") and field_norm in samples.columns):
        try:
            return float(field_norm)  # "50" (as fit_ellipsoid takes it)
        except ValueError:
            pass
    if not hasattr(samples, "field_norms"):
        raise ValueError(f"field_norm: {field_norm!r} names a column, but the samples are an array, not a Recording "
                         "(fluxcal.read_recording); give the values")
    return samples.field_norms(field_norm)


def changing_field(norms: np.ndarray) -> bool:
    """Whether per-reading field magnitudes change: (H_k/H̄)² has a standard deviation above 1e-6 (TWOSTEP's test;
    below it the per-reading fits are the one-|field| ones)."""
    return bool(np.std((norms / np.mean(norms)) ** 2) > 1e-6)


def as_field_norms(values, n: int, name: str = "field_norms") -> np.ndarray:
    """Per-reading field magnitudes (or one for all) as N positive finite floats; ValueError naming the problem
    and the argument (`name`: field_norm where a function takes one value or one per reading)."""
    try:
        norms = np.asarray(values, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: {values!r:.60} is not numbers") from None
    if norms.ndim == 0:  # one for all: the same field throughout
        norms = np.full(n, float(norms))
    norms = np.ascontiguousarray(norms)
    if norms.ndim != 1 or len(norms) != n:
        raise ValueError(f"{name}: shape {norms.shape}, expected one magnitude per reading ({n},)")
    bad = np.flatnonzero(~(np.isfinite(norms) & (norms > 0)))
    if bad.size:  # (as the solver's own check says it, before a mean of them is taken)
        raise ValueError(f"{name}: value {bad[0]} is {norms[bad[0]]:g}; every reading needs a positive finite "
                         "true field magnitude (drop zero-field readings)")
    return norms


def readings_times(samples, times, n: int) -> np.ndarray | None:
    """Each reading's time: `times` (n finite numbers, seconds), else a Recording's own (recording_times), else None;
    ValueError naming `times` otherwise."""
    if times is None:
        return recording_times(samples)
    try:
        t = np.asarray(times, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"times: not numbers ({str(times)[:60]!r}); give each reading's time in seconds") from None
    if t.ndim != 1:
        raise ValueError(f"times: shape {t.shape}; give one time per reading, a 1-D list of {n}")
    if len(t) != n:
        raise ValueError(f"times: {len(t)} values for {n} readings; give one time per reading")
    bad = np.flatnonzero(~np.isfinite(t))
    if len(bad):
        raise ValueError(f"times: value {bad[0]} is {t[bad[0]]}; give each reading a finite time in seconds")
    return t


def recording_times(samples) -> np.ndarray | None:
    """The times of a Recording's rows (its time()), else None: arrays carry none, and a DataFrame's "time" column
    is no method."""
    time = getattr(samples, "time", None)
    t = time() if callable(time) else None
    return None if t is None else np.asarray(t, dtype=float)
