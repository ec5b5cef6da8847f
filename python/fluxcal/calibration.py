"""The Calibration value: h = A (m − b) for a three-axis sensor that reads m = W h + b + noise."""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._arrays import as_samples, samples_units
from ._saved import load_json_object

CONVENTION = ("h = A (m - b); rows of samples are readings; for a sensor reading m = W h + b, A W is a rotation: from "
              "magnitudes alone A is the symmetric (W W^T)^-1/2, with reference vectors A = W^-1")
# magnetic-field units fluxcal converts between (the unit names of fluxcal.io.columns.FIELD_UNITS)
TESLA_PER_UNIT = {"T": 1.0, "mT": 1e-3, "uT": 1e-6, "nT": 1e-9, "pT": 1e-12, "G": 1e-4, "mG": 1e-7}
# A given field norm that scales readings stated in a field unit by more than this either way (but less than the 5×
# of every solver's "check the units"): a magnetometer's gain in its stated unit is within about ±20 % (datasheet
# sensitivities 5–15 %, soft iron a few %), so such a norm is more often the wrong number (another site's field, a
# total field for a horizontal one) than the sensor. A blind check's 2.4× and 0.5× norms had been fitted in silence.
SCALE_PLAUSIBLE = 1.5
SCALE_WORDS = "times the readings' field"  # how scale_words' warning reads (the CLI redoes it)


def readings_scale(cal: "Calibration") -> tuple[float, float] | None:
    """(gain, radius): how many of the field norm's unit the calibration maps each of the readings' unit to (in
    tesla: 1 for a sensor that reads its stated unit), and the readings' own radius field_norm / det(A)^⅓, their
    unit; None unless both units are field units and A is a 3×3 matrix with a positive determinant."""
    units, h_units = cal.units, cal.h_units
    det = float(np.linalg.det(cal.matrix)) if np.shape(cal.matrix) == (3, 3) else float("nan")
    if units not in TESLA_PER_UNIT or h_units not in TESLA_PER_UNIT or not det > 0 or not cal.field_norm > 0:
        return None
    radius = cal.field_norm / det ** (1 / 3)
    return cal.field_norm * TESLA_PER_UNIT[h_units] / (radius * TESLA_PER_UNIT[units]), radius


def scale_words(cal: "Calibration", units_too: bool = False) -> str | None:
    """The warning for a field norm SCALE_PLAUSIBLE× or more off the field the readings show (`units_too`: also one
    5× off, "check the units", which the solvers say themselves when the two units are one)."""
    found = readings_scale(cal)
    if found is None:
        return None
    gain, radius = found
    if 1 / SCALE_PLAUSIBLE <= gain <= SCALE_PLAUSIBLE or (not units_too and not 0.2 <= gain <= 5.0):
        return None
    shown = radius * TESLA_PER_UNIT[cal.units] / TESLA_PER_UNIT[cal.h_units]
    head = (f"field_norm {cal.field_norm:g} {cal.h_units} is {gain:.3g} {SCALE_WORDS} ({radius:.5g} {cal.units}" +
            (f" = {shown:.5g} {cal.h_units}" if cal.h_units != cal.units else "") + ")")
    if not 0.2 <= gain <= 5.0:
        return head + ": check the units"
    return (head + f": the calibration rescales every reading by that, while a magnetometer's gain in its stated unit "
            f"is within about ±20 %; is field_norm this site's total field |F| (IGRF/WMM) in {cal.h_units}, and are "
            f"the readings in {cal.units}?")


# extensions that name another format (a recording's, a table's, a header's, a text): JSON under them misleads
OTHER_FORMATS = {".csv", ".tsv", ".txt", ".npz", ".npy", ".mat", ".parquet", ".pq", ".h5", ".hdf5", ".xlsx", ".xls",
                 ".h", ".c", ".hpp", ".yaml", ".yml", ".toml", ".ini", ".xml", ".bin", ".log", ".pdf", ".png", ".html"}


def json_path(path, option: str = "") -> Path:
    """`path` as a Path for a calibration's JSON; ValueError (naming `option`, the command line's, when given) for a
    name whose extension says another format (.csv, .npz, .txt, .h, …). The command line checks it
    before it reads (fluxcal live's calibration is written at the end of a session)."""
    path = Path(path)
    # (only another format's extension: "cal_v1.2" or "sensor.A" are names, not formats)
    if path.suffix.lower() in OTHER_FORMATS:
        raise ValueError(f"{option + ' ' if option else ''}{path}: a calibration is saved as JSON, the one format "
                         f"Calibration.load reads; name the file .json (the {path.suffix} would hold JSON under "
                         "another format's name)")
    return path


@dataclass
class Calibration:
    """Offset `offset` (b, reading units), matrix `matrix` (A) and the field norm |h| it maps to.

    `summary` holds the fit statistics of the solver that produced it; `metadata` anything the caller
    wants stored with it (source file, columns, date).
    """

    offset: np.ndarray
    matrix: np.ndarray
    field_norm: float = 1.0
    units: str = ""
    model: str = ""
    summary: dict = field(default_factory=dict)
    metadata: dict = field(default_factory=dict)
    # unit of the corrected field h and of field_norm: None = the readings' unit (`units`); "" = not stated
    # (readings in counts calibrated to a field norm given without its unit)
    field_units: str | None = None

    @property
    def h_units(self) -> str:
        """The unit of the corrected field h (and of field_norm): `field_units`, else the readings' unit."""
        return self.units if self.field_units is None else self.field_units

    def __post_init__(self):
        self.offset, self.matrix, self.field_norm = self.checked_fields("Calibration")

    def _plane_axes(self) -> list | None:
        """A planar calibration's plane axes (summary["plane_axes"]: two sensor axes, or a fitted plane's e1, e2),
        None for a 3-D calibration."""
        return self.summary.get("plane_axes") if self.summary.get("method") == "planar" else None

    @property
    def plane(self) -> dict | None:
        """A planar calibration of two sensor axes (fluxcal.calibrate_planar): {"axes": "xy", "offset": its 2 values,
        "matrix": its 2×2} — what the calibration is, without the third axis that passes through (a biaxial
        sensor has none). None for a 3-D calibration or one in a fitted, tilted plane (its 3×3 is the plane's)."""
        axes = self._plane_axes()
        if not (isinstance(axes, list) and len(axes) == 2 and set(axes) <= set("xyz")):
            return None
        idx = ["xyz".index(a) for a in axes]
        return {"axes": "".join(axes), "offset": self.offset[idx], "matrix": self.matrix[np.ix_(idx, idx)]}

    def checked_fields(self, source: str) -> tuple[np.ndarray, np.ndarray, float]:
        """(offset as 3 floats, matrix as 3×3, field_norm as a float), or an error naming `source` and the
        field: also for fields assigned after construction (cal.field_norm = "50"), which the solvers
        would otherwise reject with pybind11's listing of their signatures."""
        def numbers(name, value, shape, need):
            try:
                if np.asarray(value).dtype.kind in "USb":  # NumPy would read "5e4" as a number, and true as 1.0
                    raise TypeError
                if isinstance(value, (list, tuple)) and any(isinstance(v, (bool, np.bool_))
                                                            for v in np.asarray(value, dtype=object).ravel()):
                    raise TypeError  # (a hand edit's true beside numbers: a blind check exported it as 1.0)
                return np.asarray(value, dtype=float).reshape(shape)
            except (TypeError, ValueError):
                shown = " ".join(repr(value).split())
                raise ValueError(f"{source}: {name} {shown[:80]}{'…' if len(shown) > 80 else ''} must be "
                                 f"{need}") from None

        for name in ("units", "model"):
            if not isinstance(getattr(self, name), str):
                raise TypeError(f"{source}: {name} {getattr(self, name)!r} must be a string")
        if self.field_units is not None and not isinstance(self.field_units, str):
            raise TypeError(f"{source}: field_units {self.field_units!r} must be a string or None")
        return (numbers("offset", self.offset, (3,), "3 numbers"), numbers("matrix", self.matrix, (3, 3), "3 × 3 numbers"),
                float(numbers("field_norm", self.field_norm, (), "a number")))

    # -- use ---------------------------------------------------------------------------------------
    def apply(self, samples) -> np.ndarray:
        """Corrected field of each reading: one row (3,) or N×3 in, the same shape out. A Recording whose
        magnetometer unit differs from the calibration's is converted to it first when both are field units
        (µT readings through an nT calibration); a unit that cannot be converted (counts against nT) is a
        ValueError naming both, never a silently wrong field.

        A biaxial sensor's readings (two values a row, or a Recording of two field columns) go through a planar
        calibration of the same two sensor axes (fluxcal.calibrate_planar): the plane's two corrected components
        come out, one row (2,) or N×2."""
        factor = self.unit_factor(samples_units(samples), getattr(samples, "source", "samples"))
        biaxial = callable(getattr(samples, "biaxial", None)) and samples.biaxial()
        if biaxial:
            return self._apply_biaxial(samples.samples(biaxial=True) * factor, self._biaxial_axes(samples),
                                       samples.source)
        if np.shape(samples)[-1:] == (2,):
            return self._apply_biaxial(samples if factor == 1.0 else as_samples(samples, columns=2) * factor, None,
                                       "samples")
        if np.ndim(samples) == 1:
            return self.matrix @ (np.asarray(samples, dtype=float).reshape(3) - self.offset)
        return (as_samples(samples) * factor - self.offset) @ self.matrix.T

    def _biaxial_axes(self, rec) -> str | None:
        """A biaxial Recording's sensor axes for this calibration: by the columns' names, or what said them; when
        nothing did, the calibration's plane's (taken, and said in rec.biaxial_axes_from)."""
        plane = self._plane_axes()
        if not rec.biaxial_axes_from and plane is not None and set(plane) <= set("xyz"):
            rec.take_axes("".join(sorted(plane)), "the calibration")
        return rec.biaxial_axes

    def _apply_biaxial(self, readings, axes: str | None, source: str) -> np.ndarray:
        """apply() of a biaxial sensor's readings (N×2 or one row of 2) in the sensor axes `axes` ("xz"; None: the
        calibration's plane's, in its order): embedded with the missing axis 0, corrected, the plane's components
        returned in the readings' axis order."""
        plane = self._plane_axes()
        if plane is None:
            raise ValueError(f"{source}: 2 field columns (a biaxial sensor's), and this is a 3-D calibration, "
                             "which needs three axes' readings; a biaxial sensor takes a planar calibration "
                             "(fluxcal calibrate --planar; fluxcal.calibrate_planar)")
        if not set(plane) <= set("xyz"):
            raise ValueError(f"{source}: 2 field columns, and the calibration was made in a fitted plane tilted "
                             "from the sensor axes (summary plane_basis), which needs all three axes' readings")
        if axes is not None and set(axes) != set(plane):
            raise ValueError(f"{source}: the sensor's {' and '.join(axes)} axes, and the calibration is of axes "
                             f"{' and '.join(plane)}: apply a calibration of these axes")
        axes = axes or "".join(plane)  # the readings' own axis order (a Recording's: x before z)
        rows = np.atleast_2d(np.asarray(readings, dtype=float))
        if rows.ndim != 2 or rows.shape[1] != 2:
            raise ValueError(f"{source}: shape {np.shape(readings)}, expected (N, 2) readings of a biaxial sensor")
        h = ((in_sensor_axes(rows, axes) - self.offset) @ self.matrix.T)[:, ["xyz".index(a) for a in axes]]
        return h[0] if np.ndim(readings) == 1 else h

    def unit_factor(self, units: str, source: str = "samples") -> float:
        """What readings in `units` are multiplied by to be in the calibration's unit (1 when either is not
        stated or they agree); ValueError when they are different units and not both magnetic-field units."""
        from .io.columns import unit_name

        if not units or not self.units or unit_name(units) == unit_name(self.units):
            return 1.0
        to, frm = TESLA_PER_UNIT.get(unit_name(self.units)), TESLA_PER_UNIT.get(unit_name(units))
        if to is None or frm is None:
            raise ValueError(f"{source}: readings in {units}, the calibration was fitted to readings in {self.units}; "
                             "apply it to readings in the unit it was fitted in")
        return frm / to

    def reading(self, field_vectors) -> np.ndarray:
        """The readings true fields would produce (the forward model m = A⁻¹ h + b, no noise)."""
        h = np.asarray(field_vectors, dtype=float)
        return (self.forward_matrix @ h.T).T + self.offset

    @property
    def forward_matrix(self) -> np.ndarray:
        """W = A⁻¹: how the sensor distorts the field."""
        try:
            return np.linalg.inv(self.matrix)
        except np.linalg.LinAlgError:
            raise ValueError(f"calibration: the matrix A is singular ({self.matrix.tolist()}): it sends some field "
                             "direction to zero, so no readings correspond to a field") from None

    # -- other conventions ----------------------------------------------------------------------------
    def to_magcal(self):
        """MATLAB magcal convention (row vectors, C = (D − b)·A): returns (A_magcal, b, expmfs)."""
        return self.matrix.T.copy(), self.offset.copy(), self.field_norm

    @classmethod
    def from_magcal(cls, A, b, expmfs=1.0, units: str = "") -> "Calibration":
        """From MATLAB magcal's [A, b, expmfs] (C = (D − b)·A)."""
        return cls(offset=np.ravel(b), matrix=np.asarray(A, dtype=float).T, field_norm=expmfs, units=units,
                   model="magcal")._finite("from_magcal")

    def _finite(self, source: str) -> "Calibration":
        """self, or ValueError naming `source` when the offset, matrix or field norm holds NaN/Inf (a
        calibration read in, which every use would turn into NaN fields)."""
        for name, value in (("offset", self.offset), ("matrix", self.matrix), ("field_norm", self.field_norm)):
            if not np.all(np.isfinite(value)):
                raise ValueError(f"{source}: {name} is not finite ({np.asarray(value).tolist()})")
        condition = np.linalg.cond(self.matrix)
        if not condition < 1e12:  # maps every reading onto a plane or a line: no calibration does
            raise ValueError(f"{source}: matrix is singular or nearly so (condition number {condition:.3g}; "
                             f"{self.matrix.tolist()})")
        return self

    # -- files ---------------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        from . import __version__

        plane = self.plane
        # a planar calibration's own two axes, for the reader (fluxcal loads offset and matrix, which embed them)
        plane = {} if plane is None else {"plane": {"axes": plane["axes"], "offset": plane["offset"].tolist(),
                                                    "matrix": plane["matrix"].tolist(),
                                                    "note": "the plane's part of offset and matrix, for reading; "
                                                            "fluxcal loads offset and matrix"}}
        return {
            "fluxcal_version": __version__,
            "convention": CONVENTION,
            "model": self.model,
            "units": self.units,
            "field_units": self.h_units,
            "offset": self.offset.tolist(),
            "matrix": self.matrix.tolist(),
            **plane,
            "field_norm": self.field_norm,
            "summary": _jsonable(self.summary),
            "metadata": _jsonable(self.metadata),
        }

    @classmethod
    def from_dict(cls, data: dict, source: str = "calibration") -> "Calibration":
        missing = [k for k in ("offset", "matrix", "field_norm") if k not in data]
        if missing and {"offset", "K", "field_ned"} <= set(data):
            data = _from_positions(data, source)
            missing = []
        if missing and {"offsets", "gains"} <= set(data):
            raise ValueError(f"{source}: a ring calibration (`fluxcal cable calibrate`), not a magnetometer "
                             "calibration (`fluxcal calibrate -o`)")
        if missing:
            raise ValueError(f"{source}: missing {', '.join(missing)}")
        convention = data.get("convention", CONVENTION)
        if not (isinstance(convention, str) and _model_part(convention) == _model_part(CONVENTION)):
            # the offset and matrix mean something else under another convention: applied as h = A (m - b),
            # a magcal (m - b) A or an h = A m + b file would give a wrong field, silently
            raise ValueError(f"{source}: convention {convention!r:.80} is not fluxcal's {CONVENTION.split(';')[0]!r}; "
                             "convert the offset and matrix (Calibration.from_magcal for MATLAB magcal's (m - b) A)")
        for name in ("summary", "metadata"):
            if not isinstance(data.get(name, {}), dict):
                raise ValueError(f"{source}: {name} {data[name]!r:.60} must be a JSON object")
        for flag in ("identifiable", "converged"):  # export-c refuses on them: a string "false" had been true
            value = data.get("summary", {}).get(flag, True)
            if not isinstance(value, bool):
                raise ValueError(f"{source}: summary.{flag} {value!r:.40} must be true or false (JSON, unquoted)")
        if not (isinstance(data["field_norm"], (int, float)) and data["field_norm"] > 0):
            raise ValueError(f"{source}: field_norm {data['field_norm']!r} must be a positive number")
        try:
            cal = cls(offset=data["offset"], matrix=data["matrix"], field_norm=data["field_norm"],
                      units=data.get("units", ""), model=data.get("model", ""),
                      summary=data.get("summary", {}), metadata=data.get("metadata", {}),
                      field_units=data.get("field_units"))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{source}: {str(exc).removeprefix('Calibration: ')}") from None
        return cal._finite(source)

    def save(self, path) -> Path:
        """Write the calibration as JSON (Calibration.load reads it back) to `path`: named .json, or without an
        extension; another extension (.npz, .csv, .txt) is a ValueError, as JSON under it would be read as that
        format's file."""
        path = json_path(path)
        path.write_text(json.dumps(self.to_dict(), indent=2) + "\n")
        return path

    @classmethod
    def load(cls, path) -> "Calibration":
        return cls.from_dict(load_json_object(path, "a fluxcal calibration"), source=str(path))

    def __str__(self) -> str:
        u = f" {self.units}" if self.units else ""
        hu = f" {self.h_units}" if self.h_units else " (no unit stated)"
        # a biaxial sensor's calibration is its two axes' (the 3×3 it is stored as passes a third column through)
        plane = self.plane if self.summary.get("biaxial") else None
        offset, matrix = (self.offset, self.matrix) if plane is None else (plane["offset"], plane["matrix"])
        axes = "" if plane is None else f" ({', '.join(plane['axes'])})"
        with np.printoptions(precision=6, suppress=True):
            # each row of A on its own line, columns aligned (the nested-list form indents all but the first)
            rows = np.array2string(matrix).replace("[[", "[").replace("]]", "]").splitlines()
            rows = "\n".join("    " + line.strip() for line in rows)
            horizontal = " (horizontal)" if self.summary.get("method") == "planar" else ""
            # a planar calibration's offset has no component along the normal: not a measured 0 but none removed
            normal = self.summary.get("not_calibrated", {}).get("axis") if plane is None else None
            along = "" if normal is None else f"   (none along {normal}: not calibrated)"
            return (f"{self.model or 'calibration'}: h = A (m - b), |h|{horizontal} = {self.field_norm:.6g}{hu}\n"
                    f"  offset b{axes} = {_significant(offset, 7)}{u}{along}\n"
                    f"  matrix A{axes} =\n{rows}")


def _model_part(convention: str) -> str:
    """The equation of a convention string ("h = A (m - b)"), spaces and case left out."""
    return "".join(convention.split(";")[0].split()).lower()


def _significant(values, digits: int) -> str:
    """A vector with `digits` significant digits per entry: fixed decimals would print an offset in
    tesla (1e-6) or a standard error of 1e-4 as 0."""
    return np.array2string(np.asarray(values, float), formatter={"float_kind": lambda v: f"{v:.{digits}g}"})


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def _from_positions(data: dict, source: str) -> dict:
    """A multi-position result (`fluxcal positions -o`: U = U0 + K H) as a calibration h = A (m − b): b = U0,
    A = K⁻¹, |h| the reference field's; the correction firmware needs (export-c) and apply uses."""
    try:
        k = np.asarray(data["K"], dtype=float)
        matrix = np.linalg.inv(k)
        norm = float(np.linalg.norm(np.asarray(data["field_ned"], dtype=float)))
    except (TypeError, ValueError, np.linalg.LinAlgError) as exc:
        raise ValueError(f"{source}: a multi-position result whose K cannot be inverted ({exc})") from None
    field_unit = data.get("units_of", {}).get("field_ned", "")
    return {"offset": data["offset"], "matrix": matrix.tolist(), "field_norm": norm, "units": data.get("units", ""),
            "model": "positions: h = K⁻¹ (U − U0)", "field_units": field_unit if field_unit in TESLA_PER_UNIT else "",
            "summary": {"identifiable": _positions_determined(data), "message": data.get("message", "")},
            "metadata": {"source": data.get("source", source), "frame": data.get("frame", "")}}


def _positions_determined(data: dict) -> bool:
    """Whether a multi-position result determined its correction: U0 and K (the headings and the dip, nuisance
    parameters, do not enter h = K⁻¹ (U − U0)). Results saved before the flags were kept: their warnings."""
    if "determined" in data and "parameter_names" in data:
        return all(d for name, d in zip(data["parameter_names"], data["determined"]) if name.startswith(("U0", "K_")))
    return not any("poorly determined" in w for w in data.get("warnings", []))


def in_sensor_axes(readings: np.ndarray, axes: str) -> np.ndarray:
    """A biaxial sensor's N×2 readings (or corrected fields) as N×3 rows in the sensor axes `axes` ("xz": the two
    columns are x and z), the third 0: what a planar calibration of those axes takes and passes through."""
    out = np.zeros((len(readings), 3))
    out[:, ["xyz".index(a) for a in axes]] = readings
    return out
