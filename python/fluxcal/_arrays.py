"""Input checks shared by the Python layer: every public function turns array-likes into the exact
layout the C++ core maps without a copy, and names the input when something is wrong."""
from __future__ import annotations

import numpy as np


def as_samples(values, name: str = "samples", columns: int = 3) -> np.ndarray:
    """Return `values` as a C-contiguous float64 (N, columns) array; ValueError naming `name` otherwise."""
    if hasattr(values, "samples") and callable(values.samples):  # a Recording
        values = values.samples()
    try:
        arr = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: not numeric ({exc})") from None
    if arr.ndim != 2 or arr.shape[1] != columns:
        transposed = arr.ndim == 2 and arr.shape[0] == columns
        hint = " (it looks transposed: pass one row per reading)" if transposed else ""
        raise ValueError(f"{name}: shape {arr.shape}, expected (N, {columns}) with one row per reading{hint}")
    return np.ascontiguousarray(arr)


def first_nonfinite(arr: np.ndarray):
    """(row, column) of the first NaN/Inf in `arr`, or None."""
    bad = ~np.isfinite(arr)
    if not bad.any():
        return None
    row = int(np.argmax(bad.any(axis=1)))
    return row, int(np.argmax(bad[row]))


def set_options(options, settings: dict, what: str):
    """Set each keyword of `settings` on a bound C++ options struct; unknown names are a TypeError."""
    for name, value in settings.items():
        if not hasattr(options, name):
            raise TypeError(f"{what}: unknown option {name!r}")
        setattr(options, name, value)
    return options


def held_copies(m: np.ndarray):
    """Mask of the readings that are sample-and-hold copies of the one before (a logger faster than its
    sensor repeats the last reading), or None when there are none to speak of. Copies: ≥ 10 % of the rows
    repeat the previous row exactly, in runs of one typical length L ≥ 2 (≥ 80 % of the runs of length
    L − 1, L or L + 1). A coarse ADC on a slow turn also repeats readings, but in runs of spread-out
    lengths, and those repeats are real readings."""
    repeat = np.concatenate([[False], np.all(m[1:] == m[:-1], axis=1)])
    if len(m) < 3 or repeat.mean() < 0.1:
        return None
    runs = np.diff(np.append(np.flatnonzero(~repeat), len(repeat)))
    counts = np.bincount(runs)
    mode = int(np.argmax(counts))
    regular = mode >= 2 and counts[max(mode - 1, 1):mode + 2].sum() >= 0.8 * len(runs)
    return repeat if regular else None
