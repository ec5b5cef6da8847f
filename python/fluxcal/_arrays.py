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
