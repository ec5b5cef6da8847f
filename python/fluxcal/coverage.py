"""How well readings cover the sphere of field directions (see cpp/include/fluxcal/coverage.hpp)."""
from __future__ import annotations

import numpy as np

from . import _core
from ._arrays import as_samples, require_finite

N_DIRECTION_BINS = 96


def direction_coverage(field_vectors, max_rows: int = 0) -> float:
    """Fraction of the 96 direction bins (cube sphere, 6 faces × 4 × 4 equal-angle cells) holding at
    least one vector. Pass corrected fields (calibration.apply(raw)); raw readings are off-centre.
    A full hand-turned recording reaches 0.9–1.0; a yaw-only turn about 0.1. `max_rows` > 0 looks at
    an evenly strided subsample of at most that many rows. A NaN or infinite row is a ValueError naming it
    (the fraction of the other rows would pass for the whole recording's), and so is an empty array."""
    if isinstance(max_rows, bool) or not isinstance(max_rows, (int, np.integer)) or max_rows < 0:
        raise ValueError(f"max_rows: {max_rows!r}, need a whole number ≥ 0 (0 looks at every row)")
    fields = require_finite(as_samples(field_vectors, "field_vectors"), "field_vectors")
    return _core.direction_coverage(fields, int(max_rows))
