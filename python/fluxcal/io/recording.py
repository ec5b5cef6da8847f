"""Recording: named columns (mx, my, mz, optional t, ax, ay, az, temp, ...) with units and metadata."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._arrays import first_nonfinite

MAG_COLUMNS = ("mx", "my", "mz")


@dataclass
class Recording:
    columns: dict  # name -> 1-D float array, all the same length
    units: dict = field(default_factory=dict)  # name -> unit string ("nT", "uT", "Gauss", "counts", ...)
    metadata: dict = field(default_factory=dict)
    source: str = "recording"  # file name for messages
    line_numbers: np.ndarray | None = None  # file line of each row, for messages

    def __post_init__(self):
        self.columns = {k: np.asarray(v, dtype=float) for k, v in self.columns.items()}
        lengths = {len(v) for v in self.columns.values()}
        if len(lengths) > 1:
            raise ValueError(f"{self.source}: columns have different lengths {sorted(lengths)}")
        self.mag_columns = MAG_COLUMNS if all(c in self.columns for c in MAG_COLUMNS) else None

    def __len__(self) -> int:
        return len(next(iter(self.columns.values()))) if self.columns else 0

    def select(self, names) -> "Recording":
        """Use `names` (three columns) as the magnetometer axes."""
        names = tuple(names)
        if len(names) != 3:
            raise ValueError(f"{self.source}: need three magnetometer columns, got {', '.join(names) or 'none'}")
        missing = [n for n in names if n not in self.columns]
        if missing:
            raise ValueError(f"{self.source}: no column {', '.join(repr(m) for m in missing)}; "
                             f"columns are: {', '.join(self.columns)}")
        self.mag_columns = names
        return self

    def mag_names(self) -> tuple:
        """The three magnetometer columns: those selected, else mx,my,mz, else x,y,z."""
        if self.mag_columns is None:
            if all(c in self.columns for c in ("x", "y", "z")):
                return ("x", "y", "z")
            raise ValueError(f"{self.source}: no magnetometer columns mx,my,mz (columns are: "
                             f"{', '.join(self.columns)}); choose three with --columns / select()")
        return self.mag_columns

    def samples(self, check_finite: bool = True) -> np.ndarray:
        """The magnetometer readings, N×3. NaN/Inf is an error naming the file line and column."""
        names = self.mag_names()
        arr = np.column_stack([self.columns[n] for n in names])
        bad = first_nonfinite(arr) if check_finite else None
        if bad is not None:
            row, col = bad
            where = f"line {self.line_numbers[row]}" if self.line_numbers is not None else f"row {row}"
            raise ValueError(f"{self.source}: {where}, column {names[col]!r} is {arr[row, col]} "
                             f"(non-finite readings cannot be calibrated; remove or repair them)")
        return arr

    def field_units(self) -> str:
        """The unit of the magnetometer columns ("" when the recording does not state it)."""
        units = {self.units.get(n, "") for n in self.mag_names()}
        if len(units) > 1:
            raise ValueError(f"{self.source}: magnetometer columns have different units {sorted(units)}")
        return units.pop()
