"""Reference direction binning: the cube-sphere bins of coverage.hpp, vectorised in NumPy."""
from __future__ import annotations

import numpy as np


def direction_bins(v, k: int = 4) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    axis = np.argmax(np.abs(v), axis=1)
    rows = np.arange(len(v))
    big = np.abs(v[rows, axis])
    face = 2 * axis + (v[rows, axis] < 0)

    def cell(ratio):
        return np.clip((np.arctan(ratio) / (np.pi / 2) + 0.5) * k, 0, k - 1).astype(int)

    u = v[rows, (axis + 1) % 3] / big
    w = v[rows, (axis + 2) % 3] / big
    return face * k * k + cell(u) * k + cell(w)


def direction_coverage(v, k: int = 4) -> float:
    return len(np.unique(direction_bins(v, k))) / (6 * k * k)
