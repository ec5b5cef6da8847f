"""Multi-position calibration with accelerometer levelling (seed 002, the twelve-position method).

Model: a three-axis sensor at rest reads U = U0 + K H (U, U0 in output units such as mV or counts;
H the field in the body frame, nT or µT; K = scale factors on the diagonal, installation /
non-orthogonality coefficients off it). Each static position has an accelerometer reading that
levels it; the local geomagnetic field (from IGRF, or given) rotated into the body frame is the
reference H. U0 and K come from least squares over any ≥ 4 well-spread positions (C++ core,
`fluxcal._core.calibrate_positions`); seed 002's closed-form sums are kept as a check
(`closed_form_twelve`).

Frames (`frame=`):
  "ned"  body x forward, y right, z down; local north, east, down. A level static accelerometer
         reads specific force (0, 0, −g). The usual INS/AHRS convention (fluxcal.attitude "aerospace").
  "nue"  seed 002: body x forward, y up, z right; local north, up, east. Level: (0, +g, 0); pitch
         θ = arcsin(Ax/|A|), roll γ = arctan(−Az/Ay) (eq. 4); fluxcal.attitude "seed002".
The field is always given in NED (what IGRF/WMM give); K relates U to H written in the frame's body
axes, so K differs between frames by a permutation and signs of its columns.

Headings: with `estimate_yaw=True` a heading correction per position is estimated jointly with U0
and K (Ceres). Observable then: U0, all of K, each position's magnetic heading and (with
`estimate_inclination=True`) the dip. Not observable: the field magnitude separately from K's scale
(give it), and the declination (headings are relative to the given field's horizontal direction).
Without nominal attitudes at all (`preset=None, attitudes=None`), headings are estimated from an
ellipsoid-fit start (≥ 10 positions).

    import fluxcal.positions as fp
    f = fp.reference_field(total=52200, inclination=52)            # (N, E, D) nT
    acc_cal = fp.calibrate_accelerometer(acc_raw_six_or_more)      # offset, scale, misalignment
    res = fp.calibrate(mag, acc_cal.apply(acc_raw), f, frame="nue", preset="twelve")
    res.offset, res.K, res.verify(mag2, acc2, attitudes=...)
"""
from __future__ import annotations

import datetime as _dt
import itertools
import math
import re
import warnings
from dataclasses import dataclass, field as _field

import numpy as np

from . import _core
from ._arrays import as_number, as_samples, as_specific_force, set_options, units_text
from .attitude import axis_remapping
from .bounds import few_dof_words

FRAMES = ("ned", "nue")
_FRAME = {"ned": _core.Frame.ned, "nue": _core.Frame.nue}
#: The twelve positions of seed 002: where the body axes x, y, z (x forward, y up, z right) point,
#: N/S/U/D/E/W. Order as in the paper (positions 1–12).
TWELVE = ("N-U-E", "S-U-W", "S-D-E", "N-D-W", "U-S-E", "U-N-W", "D-N-E", "D-S-W", "N-W-U", "S-E-U", "N-E-D", "S-W-D")
PRESETS = {"twelve": TWELVE}
STANDARD_GRAVITY = 9.80665
# Rows: the frame's local axes written in NED.
_NED_TO_LOCAL = {"ned": np.eye(3), "nue": np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])}


def _frame(frame: str):
    if frame not in _FRAME:
        raise ValueError(f"frame: {frame!r} is not one of {', '.join(FRAMES)}")
    return _FRAME[frame]


def _rotations(rows, name: str = "rotations") -> np.ndarray:
    """N rotation matrices (N×3×3 or N×9 rows), checked proper and orthonormal: a scaled or reflected
    matrix would scale K or flip an axis without a word."""
    R = np.asarray(rows, dtype=float)
    if R.size % 9:
        raise ValueError(f"{name}: {R.shape} is not N rotation matrices (N×3×3 or N×9)")
    R = R.reshape(-1, 3, 3)
    if not np.all(np.isfinite(R)):
        raise ValueError(f"{name}: matrix {int(np.flatnonzero(~np.isfinite(R).all(axis=(1, 2)))[0])} is not finite")
    off = np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(R)
    bad = np.flatnonzero((off > 1e-4) | (det < 0))  # 1e-4: matrices written with 5–6 decimals still pass
    if len(bad):
        k = int(bad[0])
        raise ValueError(f"{name}: matrix {k} is not a rotation (RᵀR − I up to {off[k]:.2g}, det {det[k]:.4g}); "
                         "give proper orthonormal matrices")
    return R


# --- reference field --------------------------------------------------------------------------------

def field_from_inclination(total, inclination, declination=0.0) -> np.ndarray:
    """(N, E, D) from total intensity F, inclination I (degrees, positive down) and declination D
    (degrees east): N = F cos I cos D, E = F cos I sin D, D = F sin I. One field: fluxcal.attitude's, which
    broadcasts and refuses NaN."""
    from .attitude import field_from_inclination as field_of

    if abs(float(inclination)) > 90.0:  # 128° was taken as a field pointing back up, north reversed (NaN: below)
        raise ValueError(f"inclination: {float(inclination):g}° is outside −90…90° (the dip, positive down)")
    return field_of(float(total), float(inclination), float(declination))


def up_component(total, inclination) -> float:
    """Magnitude of the vertical field, F sin I (seed 002: H = 52200 nT, I = 52° → 41134 nT). Seed 002
    calls it H_u and quotes it unsigned; with the field dipping down (I > 0) the up component proper is
    negative: (N, U, E) = (F cos I, −F sin I, 0)."""
    return float(total) * np.sin(np.radians(float(inclination)))


def igrf_field(lat: float, lon: float, alt_km: float = 0.0, date=None) -> np.ndarray:
    """IGRF field (N, E, D) in nT at geodetic latitude/longitude (degrees), altitude (km above the
    ellipsoid) and date (datetime.date/datetime or 'YYYY-MM-DD'; default today), from `ppigrf`."""
    if date is None:
        date = _dt.date.today()
    if isinstance(date, str):
        try:
            date = _dt.date.fromisoformat(date)
        except ValueError:
            raise ValueError(f"date: {date!r} is not YYYY-MM-DD") from None
    if isinstance(date, _dt.date) and not isinstance(date, _dt.datetime):
        date = _dt.datetime(date.year, date.month, date.day)
    if not (-90.0 <= lat <= 90.0) or not np.isfinite(lon):
        raise ValueError(f"lat/lon: ({lat}, {lon}) is not a place on Earth")
    be, bn, bu = _igrf(lon, lat, alt_km, date, "give the field directly (--field N,E,D or total/inclination)")
    f = np.array([float(np.squeeze(bn)), float(np.squeeze(be)), -float(np.squeeze(bu))])
    if not np.all(np.isfinite(f)):
        raise ValueError(f"IGRF (ppigrf) gave no finite field at ({lat}, {lon}), {date:%Y-%m-%d}")
    return f


def _igrf(lon, lat, alt_km, date: _dt.datetime, otherwise: str):
    """ppigrf's (east, north, up) at one date, or ValueError for a date outside its model (`otherwise`: what to
    do instead). ppigrf returns NaN before its first epoch and silently holds the last secular variation after
    the model's end (printing a warning): both are refused rather than a wrong field returned."""
    import ppigrf

    try:
        from ppigrf.ppigrf import read_shc

        epochs = read_shc()[0].index
        first, last = epochs[0].to_pydatetime(), epochs[-1].to_pydatetime()
    except Exception:  # a ppigrf without read_shc: fall back to IGRF-14's validity
        first, last = _dt.datetime(1900, 1, 1), _dt.datetime(2030, 1, 1)
    if not (first <= date <= last):
        raise ValueError(f"date: {date:%Y-%m-%d} is outside the IGRF model of ppigrf ({first:%Y-%m-%d} to "
                         f"{last:%Y-%m-%d}); {otherwise}")
    try:
        return ppigrf.igrf(lon, lat, alt_km, date)
    except Exception as exc:  # ppigrf raises plain exceptions for dates outside its model
        raise ValueError(f"IGRF (ppigrf) cannot evaluate {date:%Y-%m-%d}: {exc}") from None


# Beyond about ten Earth radii (the magnetopause) the field is the solar wind's, not the IGRF's: an altitude past it
# is metres given as km (a satellite's 500 000 m read as km had |F| 0.1 nT, returned without a word).
IGRF_TOP_KM = 64000.0


def first_bad_place(lat, lon, alt_km, utc_seconds=None):
    """("latitude"/"longitude"/"altitude"/"time", reading, value) of the first value that is no place on Earth (a
    latitude beyond ±90°, a longitude beyond ±360° or a time not finite, an altitude below −20 km or past the
    magnetopause, IGRF_TOP_KM), or None."""
    checks = [("latitude", lat, np.abs(lat) <= 90.0), ("longitude", lon, np.abs(lon) <= 360.0),
              ("altitude", alt_km, (alt_km > -20.0) & (alt_km < IGRF_TOP_KM))]
    if utc_seconds is not None:
        checks.append(("time", utc_seconds, np.isfinite(utc_seconds)))
    for name, values, ok in checks:
        if not ok.all():
            i = int(np.argmin(ok))
            return name, i, float(values[i])
    return None


IGRF_CHUNK = 5000  # points per ppigrf call (200 000 in one call took 1.5 GB)


def igrf_magnitudes(lat, lon, alt_km, utc_seconds) -> np.ndarray:
    """|F| in nT of the IGRF at each reading: geodetic latitude and longitude (degrees), altitude above the
    ellipsoid (km) and UTC time (seconds since 1970), from ppigrf — the known field magnitude of each reading
    along a track (a satellite's orbit, a survey flight) for TWOSTEP or the refinement. Evaluated once per UTC
    day, at the mean time of that day's readings: the main field changes by well under 1 nT a day."""
    lat, lon, alt, t = (np.asarray(a, dtype=float).ravel() for a in (lat, lon, alt_km, utc_seconds))
    if not len(lat) == len(lon) == len(alt) == len(t):
        raise ValueError(f"igrf_magnitudes: {len(lat)} latitudes, {len(lon)} longitudes, {len(alt)} altitudes and "
                         f"{len(t)} times; give one of each per reading")
    if not len(lat):
        return np.zeros(0)
    bad = first_bad_place(lat, lon, alt, t)
    if bad is not None:
        name, i, value = bad
        raise ValueError(f"{name}: reading {i} is {value:g}, not a place (latitude within ±90°, altitude in km above "
                         f"the ellipsoid, below {IGRF_TOP_KM:.0f} km: metres given as km?) at a finite time")
    years = 1970.0 + t / (365.25 * 86400.0)
    late = np.flatnonzero((years < 1800.0) | (years > 2200.0))  # (a date the model refuses by name is left to it)
    if late.size:
        raise ValueError(f"time: reading {late[0]} is {t[late[0]]:.6g} s since 1970, the year {years[late[0]]:.0f}: "
                         "not a date of the IGRF (utc_seconds in milliseconds, or not since 1970?)")
    if t.min() >= 0.0 and t.max() < 1e8:  # (from 0 up: a clock started with the log)
        warnings.warn(f"utc_seconds: every time is before 1973 ({t.min():g} to {t.max():g} s since 1970): seconds "
                      "from the log's start rather than since 1970? The IGRF of 1970 differs from today's by "
                      "about 3 % of |F|", stacklevel=2)
    if len(lat) > 1 and np.all(np.abs(lat) <= np.pi / 2) and np.all(np.abs(lon) <= 2 * np.pi):
        warnings.warn("lat, lon: every latitude within ±π/2 and longitude within ±2π: in radians? "
                      "igrf_magnitudes takes degrees", stacklevel=2)
    out = np.empty(len(lat))
    days = np.floor(t / 86400.0)
    for day in np.unique(days):
        on = days == day
        when = _dt.datetime.fromtimestamp(float(t[on].mean()), _dt.timezone.utc).replace(tzinfo=None)
        rows = np.flatnonzero(on)
        for chunk in np.array_split(rows, -(-len(rows) // IGRF_CHUNK)):  # ppigrf's memory grows with the points
            be, bn, bu = _igrf(lon[chunk], lat[chunk], alt[chunk], when, "give each reading's |field| directly")
            out[chunk] = np.sqrt(np.square(be) + np.square(bn) + np.square(bu)).ravel()
    if not np.all(np.isfinite(out)):
        bad = int(np.flatnonzero(~np.isfinite(out))[0])
        raise ValueError(f"IGRF (ppigrf) gave no finite field at reading {bad} ({lat[bad]}, {lon[bad]}, "
                         f"{alt[bad]} km)")
    return out


def reference_field(field=None, *, total=None, inclination=None, declination=0.0, lat=None, lon=None,
                    alt_km=0.0, date=None) -> np.ndarray:
    """The local field (N, E, D) from exactly one of: `field` = (N, E, D); `total` + `inclination`
    (+ `declination`, default 0 = magnetic north); `lat` + `lon` (+ `alt_km`, `date`) through IGRF.
    Missing or contradictory input is a ValueError."""
    given = [field is not None, total is not None or inclination is not None, lat is not None or lon is not None]
    if sum(given) == 0:
        raise ValueError("reference field missing: give field=(N, E, D), total= and inclination=, or lat=/lon= "
                         "(and date=) for IGRF")
    if sum(given) > 1:
        raise ValueError("reference field: give only one of field=, total/inclination=, lat/lon=")
    if field is not None:
        f = np.asarray(field, dtype=float).reshape(-1)
        if f.shape != (3,) or not np.all(np.isfinite(f)) or not np.any(f):
            raise ValueError(f"field: {field!r} is not a finite, non-zero (N, E, D) 3-vector")
        return f
    if total is not None or inclination is not None:
        if inclination is None or total is None:
            raise ValueError("reference field: total and inclination are both needed")
        return field_from_inclination(total, inclination, declination)
    if lat is None or lon is None:
        raise ValueError("reference field: lat and lon are both needed")
    return igrf_field(float(lat), float(lon), float(alt_km), date)


def to_local(field_ned, frame: str) -> np.ndarray:
    """The NED field written in the frame's local axes ((N, E, D) or (N, U, E))."""
    _frame(frame)
    return _NED_TO_LOCAL[frame] @ np.asarray(field_ned, dtype=float)


def inclination_of(field_ned) -> float:
    """Inclination (dip, degrees, positive down) of an (N, E, D) field."""
    n, e, d = np.asarray(field_ned, dtype=float)
    return float(np.degrees(np.arctan2(d, np.hypot(n, e))))


# --- presets and attitudes --------------------------------------------------------------------------

def preset_rotations(preset="twelve", frame: str = "ned") -> np.ndarray:
    """Body→local rotations (N×3×3) of a preset's positions in `frame` (columns: where the body axes point)."""
    if isinstance(preset, str):
        if preset.lower() not in PRESETS:
            raise ValueError(f"preset: {preset!r} is not one of {', '.join(PRESETS)}")
        return _rotations(_core.twelve_positions(_frame(frame)))
    raise ValueError("preset: give a preset name such as 'twelve'")


def attitude_rotations(attitudes, frame: str = "ned") -> np.ndarray:
    """Body→local rotations from an N×3 array of (pitch, roll, heading) in degrees."""
    a = np.asarray(attitudes, dtype=float)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"attitudes: shape {a.shape}, expected (N, 3) rows of pitch, roll, heading (degrees)")
    f = _frame(frame)
    r = np.radians(a)
    return np.stack([_core.body_to_local(p, q, y, f) for p, q, y in r])


def pitch_roll(acc, frame: str = "ned") -> np.ndarray:
    """(pitch, roll) in degrees of each static accelerometer reading (specific force, N×3)."""
    f = _frame(frame)
    a = as_samples(np.atleast_2d(acc), "acc")
    return np.degrees(np.array([_core.pitch_roll(row, f) for row in a]))


def pitch_sensitivity(field_body=(32140.0, 41132.0, 0.0), pitch_error_deg=0.01, roll_error_deg=0.0,
                      pitch_deg=0.0, roll_deg=0.0) -> dict:
    """Error of the up component caused by a levelling error (seed 002 eqs. 7–9), computed.

    field_body: (H_bx, H_by, H_bz) in the seed 002 body frame (default: the paper's x-north level
    position). Returns the exact error (eq. 8 − eq. 7), the first-order one (eq. 9 generalised to any
    attitude: ∂H_py/∂θ Δθ + ∂H_py/∂γ Δγ) and the level-position approximation Δθ H_bx − Δγ H_bz.
    `local_error` is the exact error of all three local components (N, U, E) = (R(θ+Δθ, γ+Δγ) − R(θ, γ)) H_b
    (eq. 6): at the paper's level x-north position a 0.01° pitch error moves the north component by
    H_by Δθ ≈ 7.2 nT and the up component by H_bx Δθ ≈ 5.6 nT — the paper's "≈ 7 nT" matches the former
    although it quotes H_bx = 32140 nT."""
    hx, hy, hz = (float(v) for v in field_body)

    def up(theta, gamma):  # eq. 7
        return np.sin(theta) * hx + np.cos(theta) * np.cos(gamma) * hy - np.cos(theta) * np.sin(gamma) * hz

    th, ga = np.radians(pitch_deg), np.radians(roll_deg)
    dth, dga = np.radians(pitch_error_deg), np.radians(roll_error_deg)
    exact = up(th + dth, ga + dga) - up(th, ga)
    d_theta = np.cos(th) * hx - np.sin(th) * np.cos(ga) * hy + np.sin(th) * np.sin(ga) * hz
    d_gamma = -np.cos(th) * np.sin(ga) * hy - np.cos(th) * np.cos(ga) * hz
    nue = _FRAME["nue"]
    local_error = (np.asarray(_core.body_to_local(th + dth, ga + dga, 0.0, nue))
                   - np.asarray(_core.body_to_local(th, ga, 0.0, nue))) @ np.array([hx, hy, hz])
    return {"exact": float(exact), "first_order": float(d_theta * dth + d_gamma * dga),
            "local_error": local_error.tolist(), "local_error_norm": float(np.linalg.norm(local_error)),
            "eq9": float(dth * hx - dga * hz), "pitch_error_deg": pitch_error_deg, "roll_error_deg": roll_error_deg,
            "per_degree_pitch": float(d_theta * np.radians(1.0))}


# --- accelerometer ----------------------------------------------------------------------------------

@dataclass
class AccelerometerCalibration:
    """a = T (raw − b), T upper triangular (see fluxcal/positions.hpp)."""
    offset: np.ndarray
    matrix: np.ndarray
    gravity: float
    misalignment_estimated: bool
    magnitude_errors: np.ndarray
    tilt_error_deg: float
    summary: dict

    def apply(self, raw) -> np.ndarray:
        r = as_samples(np.atleast_2d(raw), "acc")
        return (r - self.offset) @ self.matrix.T


def calibrate_accelerometer(readings, gravity: float = STANDARD_GRAVITY, max_iterations: int = 100
                            ) -> AccelerometerCalibration:
    """Multi-position accelerometer calibration from static positions, |a| = gravity as the reference: ≥ 6
    distinct gravity directions give offset + scales, ≥ 9 add the three misalignments. Directions within 5°
    count once: turning the sensor about the vertical (the twelve positions) repeats one, so the twelve
    positions alone give 6 and the misalignment is left 0 with a warning."""
    d = _core.calibrate_accelerometer(as_samples(readings, "readings"), float(gravity), int(max_iterations))
    return AccelerometerCalibration(np.asarray(d["offset"]), np.asarray(d["matrix"]), d["gravity"],
                                    d["misalignment_estimated"], np.asarray(d["magnitude_errors"]),
                                    d["tilt_error_deg"], dict(d["summary"]))


# --- magnetometer -----------------------------------------------------------------------------------

@dataclass
class PositionsResult:
    """U = U0 + K H. `offset` = U0, `K`; `field_ned` the field used (dip estimated if asked);
    `yaw_deg` heading corrections; `reference` body-frame field per position; `residuals`."""
    offset: np.ndarray
    K: np.ndarray
    frame: str
    field_ned: np.ndarray
    yaw_deg: np.ndarray
    rotations: np.ndarray
    reference: np.ndarray
    residuals: np.ndarray
    parameter_names: list
    parameters: np.ndarray
    standard_errors: np.ndarray
    determined: list
    noise_sigma: float
    units: str
    summary: dict
    metadata: dict = _field(default_factory=dict)
    noise_dof: float = float("inf")  # behind the standard errors' σ: 3N − p for σ̂, inf when σ was given, 0 exact

    def field_of(self, outputs) -> np.ndarray:
        """Body-frame field H = K⁻¹ (U − U0) of each output row (N×3)."""
        u = as_samples(np.atleast_2d(outputs), "outputs")
        return np.linalg.solve(self.K, (u - self.offset).T).T

    def verify(self, outputs, acc, preset=None, attitudes=None, rotations=None, acc_measures="specific_force") -> dict:
        """Verification at positions not used in the fit (see `verification_report`)."""
        return verification_report(self, outputs, acc, preset=preset, attitudes=attitudes, rotations=rotations,
                                   acc_measures=acc_measures)

    def to_dict(self) -> dict:
        return {"offset": self.offset.tolist(), "K": self.K.tolist(), "units": self.units, "frame": self.frame,
                "field_ned": self.field_ned.tolist(), "inclination_deg": inclination_of(self.field_ned),
                "yaw_deg": self.yaw_deg.tolist(), "noise_sigma": self.noise_sigma,
                "noise_dof": float(self.noise_dof) if np.isfinite(self.noise_dof) else None,  # (null: σ given)
                "parameter_names": list(self.parameter_names), "determined": [bool(d) for d in self.determined],
                "standard_errors": [
                    (float(v) if np.isfinite(v) else None) for v in self.standard_errors],
                "residual_rms": self.summary["residual_rms"], "condition_number": self.summary["condition_number"],
                "message": self.summary["message"], "warnings": list(self.summary["warnings"]), **self.metadata}


def _specific_force(acc, acc_measures: str) -> np.ndarray:
    return as_specific_force(acc, acc_measures, "acc")


def _nominal(n: int, frame: str, preset, attitudes, rotations) -> np.ndarray:
    chosen = sum(x is not None for x in (preset, attitudes, rotations))
    if chosen > 1:
        raise ValueError("give only one of preset=, attitudes=, rotations=")
    if preset is not None:
        R = preset_rotations(preset, frame)
    elif attitudes is not None:
        R = attitude_rotations(attitudes, frame)
    elif rotations is not None:
        R = _rotations(rotations)
    else:
        return np.zeros((0, 9))
    if len(R) != n:
        raise ValueError(f"positions: {n} readings but the nominal attitudes describe {len(R)} positions")
    return np.ascontiguousarray(R.reshape(-1, 9))


def calibrate(mag, acc, field_ned, frame: str = "ned", preset=None, attitudes=None, rotations=None,
              estimate_yaw=None, estimate_inclination: bool = False, acc_measures: str = "specific_force",
              units: str = "", gravity: float = 0.0, gravity_tolerance: float = 0.05, field_units: str = "",
              position_labels=None, _judge_misfit: bool = True, **settings) -> PositionsResult:
    """Calibrate U = U0 + K H from N static positions.

    mag: N×3 outputs; acc: N×3 calibrated accelerometer readings in the same body axes
    (`acc_measures`: "specific_force" — a level device reads up — or "gravity"); field_ned: (N, E, D)
    local field (see `reference_field`; None is an error). Nominal attitudes: `preset` ("twelve", in
    the paper's order), `attitudes` (N×3 pitch, roll, heading in degrees) or `rotations` (N×3×3
    body→local); none = headings unknown. estimate_yaw: None = only when no nominal attitudes are
    given. settings: tilt_sigma_deg (a levelling correction per position with this Gaussian prior, for an
    accelerometer noisier than the magnetometer), output_sigma (the outputs' noise σ when known), max_iterations,
    determined_tolerance.

    No noise σ is needed to see a wrong reference field: when the residual misplaces the field by more than
    MISPLACED_DEG per position, or the same fit against a plausible mistake in it (a component's sign, N and E
    swapped, ENU or N,U,E given for N,E,D) leaves MISFIT_RATIO× less, the first warning says so and names that
    mistake. With the headings unknown (no nominal attitudes) only the mistakes that change the field's dip can be
    seen (the headings absorb any turn or mirror of its horizontal part, and K's sign a reversed down component,
    which is said when K comes out a mirror); a fit that fails against the field given but succeeds against a
    corrected one is an error naming the mistake. A field in another unit than the readings' is seen only by K's
    gain (`units` a field unit: nT, uT, ...), and said. A fit that leaves the field's magnitude wrong by more
    than GROSS_MISFIT of it at its own positions, with nothing else said, is said first (`field_units`, the
    field's unit, e.g. "nT" for IGRF, names the error's unit there; a stated unit the field's magnitude contradicts
    is said too: 48.9 stated in nT is an Earth field in µT). A misfit that one or two positions make (the fit
    without them leaves MISFIT_RATIO× less) names them and how they read by the other positions' calibration: a
    quarter turn from the label, the attitudes of two positions swapped, a field disturbed there
    (`position_labels`: the positions' names in those words, default 1, 2, … in the order given).
    """
    if field_ned is None:
        raise ValueError("field_ned: the reference field is missing; give (N, E, D), or use reference_field() "
                         "with total/inclination or lat/lon/date (IGRF)")
    f = reference_field(field_ned)
    fr = _frame(frame)
    U = as_samples(mag, "mag")
    sf = _specific_force(acc, acc_measures)
    if len(sf) != len(U):  # (before the refits that try the field's mistakes, which index both by position)
        raise ValueError(f"acc: {len(sf)} rows for the {len(U)} positions of mag: give one accelerometer reading per "
                         "position, in the same order")
    nominal = _nominal(len(U), frame, preset, attitudes, rotations)
    options = _core.PositionsOptions()
    options.frame = fr
    options.estimate_yaw = bool(len(nominal) == 0) if estimate_yaw is None else bool(estimate_yaw)
    options.estimate_inclination = bool(estimate_inclination)
    options.gravity = as_number(gravity, "gravity")
    options.gravity_tolerance = as_number(gravity_tolerance, "gravity_tolerance")
    options.units = units_text(units)
    set_options(options, settings, "calibrate")
    sf = np.ascontiguousarray(sf)

    def refit(g=None, without=()):  # the same fit against another field, or without these positions (None: it fails)
        keep = np.setdiff1d(np.arange(len(U)), without)
        try:
            return _result(_core.calibrate_positions(U[keep], sf[keep], nominal[keep] if len(nominal) else nominal,
                                                     to_local(f if g is None else g, frame), options), frame)
        except ValueError:
            return None

    def refit_without(rows):
        return refit(without=rows)

    # with no nominal attitudes the headings are free (the core estimates them whatever estimate_yaw says)
    sameness = {"headings_free": not len(nominal), "dip_free": options.estimate_inclination}
    try:
        d = _core.calibrate_positions(U, sf, nominal, to_local(f, frame), options)
    except ValueError as exc:
        # a field that fits no attitude can leave the solver a flat, inflated K ("not observable"): when a
        # corrected field fits, the field is the error to give, not the positions' spread
        said = _refused_field(str(exc), f, frame, refit, **sameness) or (
            _one_attitude(sf) if not len(nominal) and any(w in str(exc) for w in ("ellipsoid", "plane", "observable")) else None)
        if said is None and any(w in str(exc) for w in ("ellipsoid", "plane", "observable", "converge", "singular")):
            said = _refused_for_one(str(exc), len(U), refit_without, position_labels)  # (a fit's refusal, not input's)
        if said is None:
            raise
        raise ValueError(said) from None
    res = _result(d, frame)
    odd = _OddPositions(U, sf, nominal, refit_without, position_labels, headings_fixed=not options.estimate_yaw)
    _check_field_fit(res, f, frame, U, sf, nominal, refit, odd=odd, **sameness)
    res.summary["warnings"] = list(res.summary["warnings"]) + _unit_warnings(res, f, units, field_units)
    if options.estimate_inclination:
        said = _dip_moved(res, f)
        if said:
            res.summary["warnings"].append(said)
    if options.estimate_yaw and len(nominal):
        said = _turned_around(res)
        if said:
            if "K's sign is reversed" in said:  # (not a relabelling that "holds": the same reversal, its cause said)
                res.summary["warnings"] = [w for w in res.summary["warnings"]
                                           if not w.startswith("K is an axis relabelling")]
            res.summary["warnings"].append(said)
    gross = _gross_misfit(res.verify(U, acc, preset=preset, attitudes=attitudes, rotations=rotations,
                                     acc_measures=acc_measures), f, res.summary["warnings"],
                          f" {field_units}" if field_units else "")
    if gross:
        res.summary["warnings"] = _misfit_first(res, gross, res.summary["warnings"])
    sigma = float(options.output_sigma)
    if sigma > 0 and _judge_misfit:  # (`fluxcal positions` judges it against the repeats' scatter itself)
        labels = list(position_labels) if position_labels is not None else list(range(1, len(U) + 1))
        misfit = _misfit_warnings(res, f, _given_noise(sigma, labels))
        if misfit:  # (the residual against the σ given: a heading 3° off had K 2.5 % off, said by nothing — a blind
            # check; the command line, with the same σ, said "109x what the noise σ given allows")
            kept = [w for w in res.summary["warnings"] if not w.startswith(GROSS_SAID)]
            res.summary["warnings"] = _misfit_first(res, misfit[0], kept + misfit[1:])
    return res


def _refused_for_one(message: str, n: int, refit_without, labels=None) -> str | None:
    """The error to give when the fit was refused but succeeds without one position, within MISPLACED_DEG and
    MISFIT_RATIO× better than without any other (with the headings unknown, one position with steel near it had left the ellipsoid start "no ellipsoid … record a few
    hundred while turning", a turning log's advice); None when no single position is to blame. One refit per
    position, only on a refusal."""
    if n < 7:  # (the others must still determine the fit)
        return None
    fits = []
    for row in range(n):
        alt = refit_without([row])
        if alt is not None and np.isfinite(alt.summary["residual_rms"]) and \
                np.degrees(_misplacement(alt)) <= MISPLACED_DEG:
            fits.append((float(alt.summary["residual_rms"]), row))
    fits.sort()
    if not fits or (len(fits) > 1 and fits[0][0] * MISFIT_RATIO > fits[1][0]):
        return None  # (none, or several alike: then it is no one position's doing)
    rms, row = fits[0]
    label = labels[row] if labels is not None else row + 1
    return (f"the positions cannot be fitted (the fit failed: {message.rstrip('.')}), but without position {label} "
            f"they fit (residual RMS {rms:.4g}): a magnetic object near it, the device moved while it was logged, or "
            f"its readings garbled — log it again or leave it out (fluxcal positions --leave-out {label})")


# Positions whose accelerometer directions all lie within this of their mean were held in one tilt
ONE_TILT_DEG = 5.0


def _one_attitude(sf) -> str | None:
    """With the headings unknown, a refused fit of positions that all share one tilt: the start's ellipsoid fit had
    answered with advice for a turning log ("record a few hundred while turning the sensor")."""
    up = sf / np.linalg.norm(sf, axis=1, keepdims=True)
    mean = up.mean(axis=0)
    spread = float(np.degrees(np.arccos(np.clip(up @ (mean / np.linalg.norm(mean)), -1.0, 1.0))).max())
    if not spread < ONE_TILT_DEG:
        return None
    return (f"specific_force: every position has the same tilt (the accelerometer's directions within {spread:.2g}° "
            "of their mean), and with the headings unknown the fit needs positions that differ: hold the device in 10 "
            "or more attitudes, tilted several ways and turned round (or give nominal attitudes: a preset such as "
            "the twelve)")


# Every estimated heading turned the same way by more than this (and beyond their scatter): said, with its causes
COMMON_TURN_DEG = 1.0


def _common_turn(turn) -> str | None:
    """Headings estimated beside nominal attitudes that share one turn (their mean beyond COMMON_TURN_DEG and
    beyond 3 standard errors of the mean by their scatter): a declination not given (magnetic north taken for true
    north on the bench, or the reverse) or the bench's north mark off — the fit absorbs either, unsaid (a newcomer's
    −3° on every position)."""
    mean = float(np.mean(turn))
    spread = float(np.std(turn, ddof=1)) / np.sqrt(len(turn)) if len(turn) > 1 else np.inf
    if abs(mean) <= COMMON_TURN_DEG or abs(mean) <= 3.0 * spread:
        return None
    return (f"every estimated heading is turned by about {mean:+.2f}° from its nominal attitude (mean; their scatter "
            f"±{spread:.2f}°): a declination not given or given with the wrong sign (--declination; the field's "
            "north against the bench's), or the bench's north mark off by that; the fit absorbs it, K is unaffected")


# An estimated dip this far from the given field's: no local anomaly or model error (IGRF's dip is good to a fraction of
# a degree away from anomalies of a few degrees) — the reference field is wrong as a whole
DIP_CONTRADICTED_DEG = 5.0


def _dip_moved(res, given) -> str | None:
    """The dip estimated far from the reference field's (DIP_CONTRADICTED_DEG): the dip is free, but the magnitude
    that sets K's scale still comes from the same reference (a newcomer's IGRF at swapped lat/lon: dip 16° given,
    68° estimated, K 29 % too large with a perfect residual and no word)."""
    def dip(v):
        return float(np.degrees(np.arctan2(v[2], np.hypot(v[0], v[1]))))

    f = np.asarray(given, dtype=float)
    moved = dip(res.field_ned) - dip(f)
    if abs(moved) <= DIP_CONTRADICTED_DEG:
        return None
    return (f"the dip estimated, {dip(res.field_ned):.2f}°, is {abs(moved):.1f}° from the reference field's "
            f"({dip(f):.2f}°): more than a local anomaly or the field model's error — the reference field is "
            f"probably wrong as a whole (the place, the date, the components' order), and its magnitude "
            f"({np.linalg.norm(f):.6g}), which sets K's scale, comes from it: check it (without estimating the dip the "
            "fit names a field that does not fit)")


# A heading correction beyond this from a nominal attitude contradicts it: a bench sets its positions to a few degrees,
# and a position mislabelled is a quarter or half turn off (at 90° a strict "> 90°" had left it to the noise's sign)
HEADING_CONTRADICTED_DEG = 45.0


def _turned_around(res) -> str | None:
    """Headings estimated beside nominal attitudes that turn positions by more than HEADING_CONTRADICTED_DEG: the fit
    turned them about the vertical rather than fit the attitudes given. Every one, with K's sign reversed: the
    reference field's sign (a down component given up: −(N, E, −D) is (N, E, D) turned 180°, a negated K then fits
    it exactly — a newcomer's inclination of −52° for +52° passed with K negated and only an axis-relabelling note);
    every one with K upright: the bench's north mark; some: positions swapped (an attitude turned 180° about the
    vertical is another of the preset's). Without estimated headings the fit names each of these mistakes."""
    turn = np.mod(np.asarray(res.yaw_deg, dtype=float) + 180.0, 360.0) - 180.0
    rows = np.flatnonzero(np.abs(turn) > HEADING_CONTRADICTED_DEG)
    if not len(rows):
        return _common_turn(turn)
    size = f"{np.median(np.abs(turn[rows])):.0f}°"
    remedy = "; fit without estimating the headings (no --estimate-yaw; estimate_yaw=False), which names the mistake"
    # a turn about the vertical is what an estimated heading is: it absorbs the mistake, and U0 and K hold
    holds = ("; the estimated headings absorb it, so U0 and K hold — correct the nominal attitudes (a fit without "
             "estimating the headings then agrees)")
    if len(rows) < len(turn):
        turns = ", ".join(f"{r + 1} by {turn[r]:+.0f}°" for r in rows)
        return (f"the estimated headings turn position(s) {turns} (counted from 1 in the order given) from their "
                f"nominal attitudes: positions mislabelled or swapped (a quarter or half turn about the vertical is "
                f"another position), or misplaced on the bench{holds}")
    if np.trace(res.K) < 0:
        return (f"the estimated headings turn every position by {size} from its nominal attitude, and K's sign is "
                "reversed with them: the reference field's down component probably has the wrong sign (the "
                f"inclination's: up taken for down), which such a fit absorbs into K's sign{remedy}")
    return (f"the estimated headings turn every position by {size} from its nominal attitude: the bench's north "
            f"reference reversed, or the field's horizontal part given with the wrong sign{holds}")


def fit(mag, reference, units: str = "", frame: str = "ned", position_labels=None) -> PositionsResult:
    """Linear least squares of U = U0 + K H when each position's body-frame field H is known (N×3).

    A reference that does not fit (its residual misplaces the field by more than MISPLACED_DEG per position) is
    said first, as by `calibrate`; which mistake it holds cannot be named here (see _check_field_fit), but one or two
    positions that make the misfit are, as by `calibrate`, with how far their reading turns from their reference and
    how far its magnitude is off (a coil's axis or polarity wrong for one position, two references swapped, a
    disturbed field). With `units` a field unit, a reference in another unit than the readings' is said by K's gain."""
    options = _core.PositionsOptions()
    options.frame = _frame(frame)
    options.units = units_text(units)
    U, H = as_samples(mag, "mag"), as_samples(reference, "reference")

    def refit_without(rows):
        keep = np.setdiff1d(np.arange(len(U)), rows)
        try:
            return _result(dict(_core.fit_positions(U[keep], H[keep], options), field=np.full(3, np.nan)), frame)
        except ValueError:
            return None

    d = _core.fit_positions(U, H, options)
    d = dict(d, field=np.full(3, np.nan))
    res = _result(d, frame)
    odd = _OddPositions(U, None, np.zeros((0, 9)), refit_without, position_labels, reference=H)
    _check_field_fit(res, None, frame, None, None, np.zeros((0, 9)), None, odd=odd)
    # the reference's own size stands for |f| (a coil's varying fields: their RMS)
    res.summary["warnings"] = list(res.summary["warnings"]) + _unit_warnings(
        res, float(np.sqrt(np.mean(np.sum(H ** 2, axis=1)))), units)
    return res


def _result(d: dict, frame: str) -> PositionsResult:
    local = np.asarray(d["field"], dtype=float)
    field_ned = _NED_TO_LOCAL[frame].T @ local
    remapped = axis_remapping(d["K"])
    if remapped:  # K absorbs it, but differently labelled axes deserve a word (SAP6's mag +X+Y-Z, grav -Y-X+Z)
        # every axis reversed is seldom a mounting and often a sign: gravity for specific force, the field's down
        every = remapped[1].replace(" ", "") == "-x,-y,-z"
        d = dict(d, summary=dict(d["summary"], warnings=list(d["summary"]["warnings"]) + [
            f"K is an axis relabelling: the magnetometer's x, y, z read the field's {remapped[1]} in the "
            "accelerometer's axes" + (" (a mirror)" if every else " (a mirror: the two frames differ in handedness)"
                                      if remapped[2] else "")
            + (". Every axis reversed is seldom a mounting and often a sign: what the accelerometer reports (gravity "
               "or specific force) or the field's signs; K includes the reversal, so the calibration holds with this "
               "accelerometer and field, but check both before using it with others" if every else
               ". The two sensors' axes are labelled (or mounted) differently; K includes the remapping, so the "
               "calibration holds, but check the chips' axis conventions if this is unexpected")]))
    dof = float(d["noise_dof"])
    said = few_dof_words(dof, f"the {len(d['residuals'])} positions' residuals",
                         "add positions, or give the noise σ per position (output_sigma, --noise-sigma; repeated "
                         "readings at each position show it)")
    loose = any(w.startswith("output noise σ") for w in d["summary"]["warnings"])  # (the core's words on σ̂ beside tilts)
    if said and not loose:  # (a blind check: 5 positions, 3 degrees of freedom, an offset 6.7 standard errors off)
        d = dict(d, summary=dict(d["summary"], warnings=list(d["summary"]["warnings"]) + [said]))
    return PositionsResult(offset=np.asarray(d["offset"]), K=np.asarray(d["K"]), frame=frame, field_ned=field_ned,
                           yaw_deg=np.degrees(np.asarray(d["yaw"])), rotations=_rotations(d["rotations"]),
                           reference=np.asarray(d["reference"]), residuals=np.asarray(d["residuals"]),
                           parameter_names=list(d["parameter_names"]), parameters=np.asarray(d["parameters"]),
                           standard_errors=np.asarray(d["standard_errors"]), determined=list(d["determined"]),
                           noise_sigma=float(d["noise_sigma"]), units=d["units"], summary=dict(d["summary"]),
                           noise_dof=dof)


# --- does the reference field fit? -----------------------------------------------------------------

# A field misplaced by more than this per position (the residual over K's reading of the field, as an angle) is
# more than noise or placement makes: a magnetometer's noise is well under 1 % of the Earth's field (a MEMS chip
# unaveraged ~0.5 %, a fluxgate ppm, i.e. < 0.6°) and a twelve-position bench sets and levels its positions to a
# degree or two; a wrong reference field misplaces it by tens of degrees (a north sign flipped: 43°).
MISPLACED_DEG = 5.0
# Below this misplacement a field mistake matters little (under 1° of heading, 2 % of K) and the refits against
# mistaken fields are not tried: with headings estimated they cost ~70 ms a calibration (10× the fit itself).
LOOK_DEG = 1.0
HEADING_REVERSED_DEG = 135.0  # in-sample heading error RMS nearer 180° than 90°: the field's horizontal part reversed

# Mistakes in the reference field (N, E, D) that a fit against the field as given cannot absorb: how each maps the
# field given (and the frame) to the one meant — None where it does not apply — and what it says. Which of them a
# fit can tell from the field given: _same_to_the_fit. A field in another unit is no entry: K's scale absorbs it in
# every fit (it is seen by K's gain against the readings' unit, _unit_warnings).
_FIELD_MISTAKES = (
    ("the north component negated", lambda f, frame: f * [-1.0, 1.0, 1.0], "its north component has the wrong sign"),
    ("the east component negated", lambda f, frame: f * [1.0, -1.0, 1.0],
     "its east component has the wrong sign (the declination's)"),
    ("the down component negated", lambda f, frame: f * [1.0, 1.0, -1.0],
     "its down component has the wrong sign (the inclination's: up taken for down)"),
    ("north and east swapped", lambda f, frame: f[[1, 0, 2]], "its north and east are swapped"),
    ("the field read as east, north, up", lambda f, frame: np.array([f[1], f[0], -f[2]]),
     "it was given as E,N,U (the ENU convention), not N,E,D"),
    ("the field read in the frame's local axes",
     lambda f, frame: None if frame == "ned" else _NED_TO_LOCAL[frame].T @ f,
     "it was given in the frame's local axes (N,U,E for --frame nue), not N,E,D"),
    # seed 002 writes the field N,U,E: with --frame ned, that order given for N,E,D is the same mix-up
    ("the field read as north, up, east", lambda f, frame: _NED_TO_LOCAL["nue"].T @ f if frame == "ned" else None,
     "it was given as N,U,E (seed 002's local axes, those of --frame nue), not N,E,D"),
)


def _same_to_the_fit(g, f, headings_free: bool = False, dip_free: bool = False) -> bool:
    """Whether a fit cannot tell the field g from f at all, so that refitting against g is pointless. K takes a sign
    (±f fit alike). Headings estimated without nominal attitudes turn the field's horizontal part at will (a north
    or east sign, N and E swapped: the same fit, only the headings differ, U0 and K untouched) and, with K's sign,
    reverse its down component too (−(N, E, −D) is (N, E, D) turned 180°): only |horizontal| and |down| remain, and
    with the dip estimated as well only |f|. A down component reversed there leaves one trace, K's handedness
    (_mirror_said)."""
    tol = 1e-9 * float(np.linalg.norm(f))
    if headings_free:
        def seen(v):
            return np.array([np.linalg.norm(v)]) if dip_free else np.array([np.hypot(v[0], v[1]), abs(v[2])])
        return float(np.abs(seen(g) - seen(f)).max()) <= tol
    return min(float(np.abs(g - f).max()), float(np.abs(g + f).max())) <= tol


def _mistake_refits(f, frame, refit, headings_free: bool = False, dip_free: bool = False) -> list:
    """(residual RMS, what, cause, field, fit) of the same fit against each mistake of _FIELD_MISTAKES that the fit
    can tell from the field given, best first (refits that fail are left out)."""
    tried = []
    for what, mistake, cause in _FIELD_MISTAKES:
        g = mistake(f, frame)
        if g is None or _same_to_the_fit(g, f, headings_free, dip_free):
            continue
        alt = refit(g)
        if alt is not None and np.isfinite(alt.summary["residual_rms"]):
            tried.append((float(alt.summary["residual_rms"]), what, cause, g, alt))
    return sorted(tried, key=lambda t: t[0])


def _named(tried, rms: float) -> list:
    """The mistakes whose refits leave MISFIT_RATIO× less than the fit's residual `rms` (inf: the fit failed), all
    within 10 % of the best: equally good ones are said together."""
    return [t for t in tried if t[0] * MISFIT_RATIO <= rms and t[0] <= 1.1 * tried[0][0]] if tried else []


def _mistake_named(named, outcome: str) -> str:
    """What the best refits say: the mistakes, the field they point to, `outcome` (how the refit fares)."""
    which = " or, equally, ".join(t[1] for t in named)
    said = ", or ".join(t[2] for t in named)
    return (f"With {which}, {_vector(named[0][3])}, {outcome}: the reference field is wrong — {said}? (--field is "
            "N,E,D: north, east, down; the inclination is positive down)")


def _misplacement(res) -> float:
    """The fit's residual as the angle (radians) by which it misplaces the field at each position: the RMS residual
    vector over the RMS of K's reading of the reference field, |K H|. Not |K|·|f|: a wrong field with the headings
    estimated can leave K inflated along a direction the field hardly takes (|K| 190× the sensor's gain), and the
    angle with it (0.07° for a field misplaced by 4.5°); K H stays what the sensor read."""
    reading = float(np.sqrt(np.mean(np.sum((res.reference @ res.K.T) ** 2, axis=1))))
    rms = float(np.sqrt(np.mean(np.sum(res.residuals ** 2, axis=1))))
    return rms / reading if reading > 0 else float("inf")


def _heading_rms(res, U, sf, nominal) -> float | None:
    """In-sample heading error RMS (degrees) against the nominal attitudes, or None without them."""
    if not len(nominal):
        return None
    try:
        return verification_report(res, U, sf, rotations=nominal)["heading_error_rms_deg"]
    except (ValueError, np.linalg.LinAlgError):  # a K that cannot be inverted: no heading to speak of
        return None


# What fit() can say about a body-frame reference that does not fit: it holds no north, east or down of its own (any
# fixed relabelling, sign or order of its body axes K absorbs), and the local field and the attitudes it was rotated
# with are not given, so no mistake can be tried — only the size of the misfit against K's reading of it.
_BODY_FRAME_CAUSE = ("Which mistake a body-frame reference holds cannot be told from it (K absorbs any relabelling or "
                     "sign of its body axes; the local field and the attitudes it was rotated with are not given): "
                     "check the field (N,E,D order, inclination sign, declination), the rotations (H = Rᵀ f with R "
                     "body→local: the transpose used?), the position order and magnetic objects near the bench — or "
                     "give the field and the accelerometer readings to calibrate(), which names a field's mistake")


def _check_field_fit(res, field_ned, frame, U, sf, nominal, refit, headings_free: bool = False,
                     dip_free: bool = False, odd: "_OddPositions | None" = None) -> None:
    """Warn, without any noise σ, when the fit does not fit the reference field: its residual misplaces the field by
    more than MISPLACED_DEG per position, or (above LOOK_DEG) the same fit against a plausibly mistaken field
    (_FIELD_MISTAKES, those the fit can tell apart: _same_to_the_fit) leaves MISFIT_RATIO× less — an upper bound on
    the noise found in the data themselves, as the repeats within positions give one when there are any. Names that
    mistake when one fits; puts the warning first (a misfit inflates the standard errors: "12 parameters poorly
    determined" was the only word for a north sign flipped) and keeps its parts in `res.summary["field_misfit"]` for
    run_cli. `field_ned` None: a body-frame reference (fit()), only the misfit's size is judged. `headings_free`: no
    nominal attitudes; a K that comes out a mirror without a misfit is said too (_mirror_said). `odd`: when no field
    mistake is named, the positions whose leaving out removes the misfit are sought, and named."""
    rms = float(res.summary["residual_rms"])
    if not (rms > 0 and np.all(np.isfinite(res.K)) and np.all(np.isfinite(res.reference)) and _gain(res) > 0):
        return
    f = None if field_ned is None else np.asarray(field_ned, float)
    angle = _misplacement(res)
    unit = f" {res.units}" if res.units else ""
    tried = []
    if refit is not None and f is not None and np.degrees(angle) > LOOK_DEG:
        tried = _mistake_refits(f, frame, refit, headings_free, dip_free)
    named = _named(tried, rms)
    # (its own yardstick, and screened before any refit: tried on every fit)
    odd_said = odd.said(res) if odd is not None and not named else None
    gross = np.degrees(angle) > MISPLACED_DEG
    if not (gross or named or odd_said):
        if headings_free and f is not None:  # (a misfit's K, mirror or not, is no evidence of either)
            _mirror_said(res, f)
        return
    heading = _heading_rms(res, U, sf, nominal)
    against = "the body-frame reference" if f is None else f"the reference field N,E,D = {_vector(f)}"
    text = (f"the model does not fit {against}: residual RMS {rms:.4g}{unit} misplaces the field by "
            f"{_deg(np.degrees(angle))}° per position")
    if heading is not None and heading > HEADING_REVERSED_DEG:
        text += f", and the in-sample heading error RMS is {heading:.0f}° (the field's horizontal part reversed)"
    if gross:
        text += (f"; noise would have to be {100 * angle / np.sqrt(3):.2g} % of the sensor's reading of the field to "
                 "make that, so no noise σ is needed to see it")
    if named:
        best = named[0]
        alt_heading = _heading_rms(best[4], U, sf, nominal)
        turn = (f", heading error RMS {_deg(heading)}° → {_deg(alt_heading)}°" if heading is not None and
                alt_heading is not None else "")
        cause = _mistake_named(named, f"the residual falls to {best[0]:.4g}{unit} ({rms / best[0]:.0f}× less{turn})")
    elif odd_said:
        cause = odd_said
    elif f is None:
        cause = _BODY_FRAME_CAUSE
    else:
        cause = ("Check the reference field (inclination sign, declination, --field order N,E,D), the frame "
                 "(--frame), the position order or labels and magnetic objects near the bench")
    text += f". U0 and K are biased by about {angle:.1g} of K. {cause}"
    res.summary["warnings"] = _misfit_first(res, text, res.summary["warnings"])
    res.summary["field_misfit"] = {"warning": text, "cause": cause if named or odd_said else None,
                                   "misplacement_deg": float(np.degrees(angle)), "gross": bool(gross)}


# The positions with the largest residuals tried as the misfit's source, singly and in pairs: a position mislabelled
# or disturbed has the largest residual or nearly (least squares spreads part of it over the others), and trying
# only these bounds the search at 10 refits (a log's many positions would otherwise cost one refit each)
ODD_SUSPECTS = 4
# A position read this near a quarter or half turn from its label was set or labelled that way, not misplaced
QUARTER_TOL_DEG = 15.0
ODD_P = 1e-3  # the odd positions' F test, Bonferroni over the choices of positions
# A position whose |H| is this many times the others' |H| error RMS off the field's magnitude holds a disturbance (a
# magnetic object near it): a heading set off or mislabelled turns the field, it leaves |H| as the others'
DISTURBED_RATIO = 5.0


class _OddPositions:
    """Whether leaving one or two positions out removes the fit's misfit (their refit leaves MISFIT_RATIO× less), and
    what they read by the other positions' calibration: how far their heading is from their label (headings fixed),
    whether two read as each other's attitude, how far |H| is from the field's magnitude."""

    def __init__(self, U, sf, nominal, refit_without, labels=None, headings_fixed: bool = True, reference=None):
        self.U, self.sf, self.nominal, self.refit_without = U, sf, nominal, refit_without
        self.labels = list(labels) if labels is not None else list(range(1, len(U) + 1))
        if len(self.labels) != len(U):
            raise ValueError(f"position_labels: {len(self.labels)} labels for {len(U)} positions")
        # fit()'s body-frame reference H per position (sf None): a position is read against its own H
        self.reference = None if reference is None else np.asarray(reference, float)
        self.headings = headings_fixed and (len(nominal) > 0 or self.reference is not None)

    def search(self, res):
        """(rows, refit, ratio) of the fewest positions (one, else two, among ODD_SUSPECTS) whose leaving out leaves
        MISFIT_RATIO× less residual RMS, and significantly so: the F test of the residual they take away against
        what is left, p below ODD_P over every choice of that many positions (the suspects are picked as the worst:
        6 arbitrary positions without this test: noise alone gave a 5× fall in 16 of 300 fits, 8 with the headings
        estimated in 56 of 300; with it, 0 in either). None otherwise.

        Each choice is screened first by the fall the linear model U = U0 + K H over the fit's own reference predicts,
        Σ_axes e_Sᵀ (I − P_SS)⁻¹ e_S (P the projection onto [1, H], exact with the headings fixed): only a choice it
        puts near the line is refitted — a fit that fits refits nothing (twelve positions, a calibration without the
        search / with it refitting every choice / screened: 0.52 / 2.5 / 1.0 ms with the headings fixed, 2.1 / 8.1 /
        2.3 ms estimated). Estimated headings make the
        prediction short of the fall as the misfit grows (a position 13 % off |H| screened out), so past LOOK_DEG's
        misplacement, where the field's mistakes are refitted too, every choice is."""
        from scipy.stats import f as f_dist

        n = len(self.U)
        rms = float(res.summary["residual_rms"])
        ssr = float(np.sum(res.residuals ** 2))
        X = np.column_stack([np.ones(n), res.reference])
        P = X @ np.linalg.pinv(X.T @ X) @ X.T
        suspects = sorted(int(r) for r in np.argsort(-np.linalg.norm(res.residuals, axis=1))[:ODD_SUSPECTS])
        everyone = np.degrees(_misplacement(res)) > LOOK_DEG
        # (pairs with the headings fixed only: estimated headings absorb two positions swapped within a tilt)
        for size in (1, 2) if self.headings else (1,):
            screened = []
            for rows in itertools.combinations(suspects, size):
                S = list(rows)
                e = res.residuals[S]
                try:
                    fall = float(np.sum(e * np.linalg.solve(np.eye(size) - P[np.ix_(S, S)], e)))
                except np.linalg.LinAlgError:  # a position the others cannot predict at all: refit to see
                    fall = ssr
                left = np.sqrt(max(ssr - fall, 0.0) / (3 * (n - size)))
                if left * MISFIT_RATIO <= 2.0 * rms or everyone:  # (a loose screen: the refit decides)
                    screened.append((left, S))
            for _, S in sorted(screened, key=lambda t: t[0])[:None if everyone else 2]:
                alt = self.refit_without(S)
                if alt is None or not np.isfinite(alt.summary["residual_rms"]):
                    continue
                rms_left = float(alt.summary["residual_rms"])
                dof_left = 3 * (n - size) - len(alt.parameters)
                ssr_left = float(np.sum(alt.residuals ** 2))
                if dof_left < 1 or not rms_left * MISFIT_RATIO <= rms:
                    continue
                taken = max(ssr - ssr_left, 0.0) / (3 * size)
                p = f_dist.sf(taken / max(ssr_left / dof_left, 1e-300 * ssr), 3 * size, dof_left)
                if p * math.comb(n, size) < ODD_P:
                    return tuple(S), alt, rms / max(rms_left, 1e-300)
        return None

    def _body_reading(self, alt, row: int, against: int) -> tuple:
        """fit()'s position `row` read by the calibration `alt`, H = K⁻¹(U − U0), against position `against`'s
        reference: (the angle between them in degrees, |H| less |reference| as a share of |reference|)."""
        seen = np.linalg.solve(alt.K, self.U[row] - alt.offset)
        given = self.reference[against]
        cosine = float(seen @ given) / max(float(np.linalg.norm(seen) * np.linalg.norm(given)), 1e-300)
        return (float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))),
                float(np.linalg.norm(seen) / max(float(np.linalg.norm(given)), 1e-300) - 1.0))

    def _body_said(self, text: str, rows: tuple, alt) -> str:
        """fit()'s words for the positions found: how each reads against its reference, or each against the other's."""
        if len(rows) == 2:
            a, b = rows
            crossed = [self._body_reading(alt, a, b), self._body_reading(alt, b, a)]
            if all(turn < QUARTER_TOL_DEG and abs(share) < 0.05 for turn, share in crossed):
                return (f"{text}, and each reads as the other's reference (turned {crossed[0][0]:.1f}° and "
                        f"{crossed[1][0]:.1f}° from it): their references swapped, or the positions logged in each "
                        "other's place? U0 and K above include the mix-up")
        parts = []
        for r in rows:
            turn, share = self._body_reading(alt, r, r)
            why = ("reversed: a coil's current or an axis's sign wrong for it?" if turn > 180.0 - QUARTER_TOL_DEG else
                   "a quarter turn: an axis of its reference wrong, or the device set a quarter turn off?"
                   if abs(turn - 90.0) < QUARTER_TOL_DEG else
                   "its reference wrong, or the field disturbed while it was logged?")
            parts.append(f"position {self.labels[r]} reads the field turned {turn:.1f}° from its reference and |H| "
                         f"{100 * share:+.2g} % off its reference's: {why}")
        return (f"{text}; by the others' calibration {' '.join(parts)} Correct its reference, log the position again "
                "or leave it out; U0 and K above include it")

    def _reading(self, alt, row: int, attitude: int) -> dict:
        """Position `row` read by the calibration `alt`, against the nominal attitude of position `attitude`."""
        rotations = self.nominal[[attitude]] if self.headings else None
        return verification_report(alt, self.U[[row]], self.sf[[row]], rotations=rotations)

    def said(self, res) -> str | None:
        found = self.search(res)
        if found is None:
            return None
        rows, alt, ratio = found
        unit = f" {alt.units}" if alt.units else ""
        names = " and ".join(str(self.labels[r]) for r in rows)
        text = (f"Position{'s' if len(rows) > 1 else ''} {names} do{'' if len(rows) > 1 else 'es'} not fit the "
                f"others: without {'them' if len(rows) > 1 else 'it'} the residual falls to "
                f"{alt.summary['residual_rms']:.4g}{unit} ({ratio:.0f}x less)")
        if self.reference is not None:
            return self._body_said(text, rows, alt)
        F = float(np.linalg.norm(alt.field_ned))
        if self.headings and len(rows) == 2:
            a, b = rows
            crossed = [self._reading(alt, a, b), self._reading(alt, b, a)]
            if all(abs(r["heading_error_deg"][0]) < QUARTER_TOL_DEG and abs(r["dip_error_deg"][0]) < QUARTER_TOL_DEG
                   for r in crossed):
                return (f"{text}, and each reads as the other's attitude (headings "
                        f"{_signed(crossed[0]['heading_error_deg'][0], 1)}° and "
                        f"{_signed(crossed[1]['heading_error_deg'][0], 1)}° from them): logged in each other's place, or "
                        "their labels swapped? Correct the labels or the order; U0 and K above include the mix-up")
        keep = np.setdiff1d(np.arange(len(self.U)), rows)
        others = verification_report(alt, self.U[keep], self.sf[keep])["magnitude_error_rms"]
        parts = []
        for r in rows:
            seen = self._reading(alt, r, r)
            share = seen["magnitude_error"][0] / F if F > 0 else 0.0
            disturbed = abs(seen["magnitude_error"][0]) > DISTURBED_RATIO * max(others, 1e-9 * F)
            said = f"|H| {100 * share:+.2g} % off the field's"
            turn = float(seen["heading_error_deg"][0]) if self.headings else 0.0
            quarter = 90.0 * round(turn / 90.0)
            if quarter and abs(turn - quarter) < QUARTER_TOL_DEG:
                half = abs(quarter) == 180.0  # (±180° are one turn)
                said = (f"turned {'180' if half else f'{turn:+.0f}'}° from its label: mislabelled, or set a quarter "
                        "or half turn off?")
            elif disturbed:
                said = (f"{said} ({abs(seen['magnitude_error'][0]) / max(others, 1e-9 * F):.0f}x the others')"
                        + (f" and a heading {_signed(turn, 1)}° from its label" if self.headings else
                                     f" and its dip {_signed(seen['dip_error_deg'][0], 2)}°")
                        + ": a magnetic object near it, or the field disturbed while it was logged?")
            else:
                said = f"a heading {_signed(turn, 1)}° from its label, {said}: misplaced on the bench?"
            parts.append(f"position {self.labels[r]} reads {said}")
        return (f"{text}; by the others' calibration {' '.join(parts)} Correct the attitude, log the position again "
                f"or leave it out (fluxcal positions --leave-out {','.join(str(self.labels[r]) for r in rows)}); U0 "
                "and K above include it")


def _signed(x: float, digits: int) -> str:
    """x with its sign, rounded, and no −0."""
    return f"{(round(float(x), digits) or 0.0):+.{digits}f}" if abs(x) < 10 else f"{x:+.0f}"


def _mirror_said(res, field_ned) -> None:
    """With the headings unknown a down component of the wrong sign fits exactly as well as the right one, with K
    negated (_same_to_the_fit): its one trace is K's handedness (det K < 0), which two sensors whose axes differ in
    handedness leave too. When K is a mirror, both are said — added to the axis-relabelling warning if there is one."""
    if not np.linalg.det(res.K) < 0 or abs(field_ned[2]) <= 1e-9 * np.linalg.norm(field_ned):
        return  # (no down component: reversing it changes nothing)
    wrong = (f"the reference field N,E,D = {_vector(field_ned)} has the wrong sign of its down component (the "
             "inclination's: up taken for down; or it was given as E,N,U), or the accelerometer reports gravity "
             "(down) where its specific force (up, what most chips report) is taken (--acc-measures gravity; "
             "acc_measures=\"gravity\")")
    tail = (f"With the headings unknown the data cannot tell these apart: {_vector(field_ned * [1.0, 1.0, -1.0])} "
            "fits exactly as well, with K negated, and so does the accelerometer's sign reversed. Check the "
            "inclination's sign (positive down), what the accelerometer reports and the chips' axis conventions, or "
            "give nominal attitudes (a preset), which tell them apart")
    warnings_ = list(res.summary["warnings"])
    for i, w in enumerate(warnings_):
        if w.startswith("K is an axis relabelling") and "(a mirror" in w:
            warnings_[i] = f"{w}. Or {wrong}. {tail}"
            break
    else:
        warnings_.append(f"K is a mirror (det K < 0): the magnetometer's and accelerometer's axes differ in "
                         f"handedness, or {wrong}. {tail}")
    res.summary["warnings"] = warnings_


def _refused_field(message: str, f, frame, refit, headings_free: bool = False, dip_free: bool = False) -> str | None:
    """The error to give when the fit against the field given failed (`message`) but the fit against a corrected
    field (_FIELD_MISTAKES) succeeds without misplacing the field by more than MISPLACED_DEG — the line past which
    _check_field_fit says a misfit; None when none does (the failure is not the field's)."""
    fits = [t for t in _mistake_refits(np.asarray(f, float), frame, refit, headings_free, dip_free)
            if np.degrees(_misplacement(t[4])) <= MISPLACED_DEG]
    named = _named(fits, float("inf"))
    if not named:
        return None
    best = named[0][4]
    unit = f" {best.units}" if best.units else ""
    outcome = (f"the positions fit: residual RMS {named[0][0]:.4g}{unit}, the field misplaced by "
               f"{_deg(np.degrees(_misplacement(best)))}° per position")
    return (f"the positions cannot be fitted against the reference field N,E,D = {_vector(f)} (the fit failed: "
            f"{message.rstrip('.')}). {_mistake_named(named, outcome)}")


def _misfit_first(res, misfit: str, others) -> list:
    """`misfit` first, then the other warnings, "poorly determined" told why: a misfit's residuals set the
    standard errors (a north sign flipped left "12 parameter(s) poorly determined" as the only word)."""
    unit = f" {res.units}" if res.units else ""
    why = (f" (their standard errors scale with the residual RMS {res.summary['residual_rms']:.4g}{unit}, which the "
           "misfit above inflates)")
    return [misfit] + [w + why if "poorly determined" in w and why not in w else w for w in others if w != misfit]


def _vector(v) -> str:
    return "(" + ", ".join(f"{x:.6g}" for x in np.asarray(v, float)) + ")"


def _deg(angle: float) -> str:
    return f"{angle:.2g}" if abs(angle) < 10 else f"{angle:.0f}"


def closed_form_twelve(mag, field_up: float):
    """Seed 002's closed-form sums (eqs. 14–29, typos corrected; see cpp/src/positions.cpp) for the
    twelve positions in the paper's order, seed 002 body axes. `field_up`: the SIGNED up component
    (to_local(f, "nue")[1]; −41134 nT for 52200 nT at 52° dip — the paper quotes the magnitude).
    Returns (U0, K)."""
    d = _core.twelve_position_closed_form(as_samples(mag, "mag"), float(field_up))
    return np.asarray(d["offset"]), np.asarray(d["K"])


# --- verification -----------------------------------------------------------------------------------

def _azimuth(v_local: np.ndarray, frame: str) -> np.ndarray:
    """Azimuth (degrees clockwise from north) of local vectors' horizontal parts."""
    v = np.atleast_2d(v_local)
    east = v[:, 1] if frame == "ned" else v[:, 2]
    return np.degrees(np.arctan2(east, v[:, 0]))


def verification_report(result: PositionsResult, outputs, acc, preset=None, attitudes=None, rotations=None,
                        acc_measures: str = "specific_force") -> dict:
    """Errors of the calibrated sensor at positions not used in the fit.

    Each position is levelled by its accelerometer. With nominal attitudes (preset/attitudes/rotations)
    the per-axis field error H − Rᵀf (body axes, field units) and the heading error are reported; the
    magnitude error |H| − |f| and the dip error (angle of H below the horizontal, from the
    accelerometer, minus the field's inclination) need no heading. Heading error: the tilt-compensated
    magnetic heading the calibrated sensor would give minus the nominal heading (degrees)."""
    U = as_samples(outputs, "outputs")
    sf = _specific_force(acc, acc_measures)
    if len(sf) != len(U):
        raise ValueError(f"acc: {len(sf)} rows for {len(U)} outputs")
    frame = result.frame
    fr = _frame(frame)
    H = result.field_of(U)
    up_b = sf / np.linalg.norm(sf, axis=1, keepdims=True)
    f = result.field_ned
    F = float(np.linalg.norm(f))
    dip = np.degrees(np.arcsin(np.clip(-(H * up_b).sum(axis=1) / np.linalg.norm(H, axis=1), -1, 1)))
    report = {"positions": int(len(U)), "units_field": "as the reference field",
              "magnitude_error": (np.linalg.norm(H, axis=1) - F).tolist(),
              "dip_error_deg": (dip - inclination_of(f)).tolist()}
    nominal = _nominal(len(U), frame, preset, attitudes, rotations)
    if len(nominal):
        f_local = to_local(f, frame)
        axis_err, heading_err = [], []
        for i, R0 in enumerate(nominal.reshape(-1, 3, 3)):
            L = np.asarray(_core.level_rotation(R0, up_b[i], fr))
            axis_err.append(H[i] - L.T @ f_local)
            # Heading error: the measured field seen in the levelled local frame is turned by −δ if the
            # sensor's heading is off by δ.
            d = _azimuth(f_local, frame)[0] - _azimuth(L @ H[i], frame)[0]
            heading_err.append((d + 180.0) % 360.0 - 180.0)
        axis_err = np.array(axis_err)
        report["field_error"] = axis_err.tolist()
        report["field_error_rms"] = np.sqrt((axis_err ** 2).mean(axis=0)).tolist()
        report["heading_error_deg"] = heading_err
        report["heading_error_rms_deg"] = float(np.sqrt(np.mean(np.square(heading_err))))
    for key in ("magnitude_error", "dip_error_deg"):
        report[key + "_rms"] = float(np.sqrt(np.mean(np.square(report[key]))))
    report["dip_deg"] = dip.tolist()
    report["dip_mean_deg"] = float(dip.mean())
    report["dip_std_deg"] = float(dip.std())
    mags = np.linalg.norm(H, axis=1)
    report["field_magnitude_mean"] = float(mags.mean())
    report["field_magnitude_std"] = float(mags.std())
    return report


def average_positions(ids, *arrays):
    """Average rows sharing a position id. Numeric ids are positions' numbers (1, 2, … as a preset numbers
    them) and come out in that order, whatever order the rows were logged in (position 2's shots logged
    first were taken for position 1's, and K came out wrong); other ids in order of first appearance.
    Returns (unique ids, averaged arrays...)."""
    ids = np.asarray(ids)
    uniq, first, inverse = np.unique(ids, return_index=True, return_inverse=True)
    order = np.arange(len(uniq)) if np.issubdtype(uniq.dtype, np.number) else np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    groups = rank[inverse]
    out = []
    for a in arrays:
        a = np.asarray(a, dtype=float)
        sums = np.zeros((len(uniq), a.shape[1]))
        np.add.at(sums, groups, a)
        out.append(sums / np.bincount(groups)[:, None])
    return (uniq[order], *out)


__all__ = ["FRAMES", "PRESETS", "TWELVE", "STANDARD_GRAVITY", "AccelerometerCalibration", "PositionsResult",
           "attitude_rotations", "average_positions", "calibrate", "calibrate_accelerometer", "closed_form_twelve",
           "field_from_inclination", "fit", "igrf_field", "igrf_magnitudes", "inclination_of", "pitch_roll", "pitch_sensitivity",
           "preset_rotations", "reference_field", "to_local", "up_component", "verification_report"]


def _replicate_scatter(ids, uniq, acc, mag, acc_av, mag_av) -> dict:
    """Pooled scatter of the rows within each position (outputs, and the accelerometer's direction), over the
    positions held still: one whose rows moved (_unsteady_positions, or a tilt beyond moved_limit_deg) is named,
    not taken as the sensor's noise (a position turned 10° about the vertical for 4 of its 10 rows had made the
    yardstick 20× too wide, and the fit's misfit unsaid)."""
    ids = np.asarray(ids)
    dm, da, counts, worst = [], [], [], []
    with np.errstate(divide="ignore", invalid="ignore"):  # an accelerometer reading 0 is refused later, named
        for k, u in enumerate(uniq):
            m = ids == u
            counts.append(int(m.sum()))
            if m.sum() > 1:
                dm.append(mag[m] - mag_av[k])
                a = acc[m] / np.linalg.norm(acc[m], axis=1, keepdims=True)
                ang = np.degrees(np.arccos(np.clip(a @ (acc_av[k] / np.linalg.norm(acc_av[k])), -1, 1)))
                da.append(np.radians(np.nan_to_num(ang)))
                worst.append((float(np.nan_to_num(ang).max()), _label(u)))
    if not dm:
        return None
    # a reading this far from its position's mean direction moved: the angle of two axes' noise is Rayleigh
    # (median 1.1774 σ), beyond 5 σ once in 270 000 readings; at least 1° for a quiet accelerometer
    moved = max(1.0, np.degrees(5.0 * float(np.median(np.concatenate(da))) / 1.1774))
    step = _lattice_step(mag) / np.sqrt(12.0)  # repeats that read alike (quantised) still carry the step's rounding
    unsteady = _unsteady_positions([(d ** 2).sum() for d in dm], [3 * (len(d) - 1) for d in dm], step ** 2)
    still = [k for k in range(len(dm)) if k not in unsteady and worst[k][0] <= moved] or list(range(len(dm)))
    dof = max(sum(len(dm[k]) - 1 for k in still), 1)  # each position spends one degree of freedom on its mean
    n_mean = float(np.mean(counts))
    mag_sigma = max(float(np.sqrt(sum((dm[k] ** 2).sum() for k in still) / (3 * dof))), step)
    tilt_sigma = float(np.sqrt(sum((da[k] ** 2).sum() for k in still) / (2 * dof)))  # radians per axis, one reading
    return {"mag_sigma": mag_sigma, "mag_sigma_per_position": mag_sigma / np.sqrt(n_mean),
            "tilt_sigma_per_position": tilt_sigma / np.sqrt(n_mean), "worst_tilt": max(worst),
            "moved_limit_deg": moved, "labels": [_label(u) for u in uniq],
            "unsteady": [(worst[k][1], float(np.sqrt(unsteady[k])), mag_sigma) for k in sorted(unsteady)]}


# A position whose outputs scatter this many times (in σ) the steady positions' is no held position; the F test's
# p below UNSTEADY_P (Bonferroni over the positions) as well, so a few readings' chance scatter is not named
UNSTEADY_RATIO = 3.0
UNSTEADY_P = 1e-3


def _unsteady_positions(sums, dofs, floor: float) -> dict:
    """{index: variance} of the positions whose outputs scatter far beyond the others' (sums of squared deviations
    from their means over `dofs` degrees of freedom): against the pooled variance of the quieter half (floored at
    `floor`, a quantised sensor's), each by an F test and UNSTEADY_RATIO. A turn about the vertical while logging
    moves the outputs but not the accelerometer's direction: this is its only trace."""
    from scipy import stats

    var = [s / d if d > 0 else 0.0 for s, d in zip(sums, dofs)]
    order = [k for k in np.argsort(var) if dofs[k] > 0]
    quiet = order[:max(len(order) // 2, 1)]
    ref_dof = sum(dofs[k] for k in quiet)
    ref = max(sum(sums[k] for k in quiet) / ref_dof, floor) if ref_dof else 0.0
    if not ref > 0.0 or len(order) < 3:
        return {}
    return {k: var[k] for k in order
            if var[k] > UNSTEADY_RATIO ** 2 * ref
            and stats.f.sf(var[k] / ref, dofs[k], ref_dof) * len(order) < UNSTEADY_P}


def _lattice_step(values: np.ndarray) -> float:
    """The smallest step between the distinct values of any column (0 for a single value)."""
    steps = [np.diff(np.unique(c)) for c in np.asarray(values).T]
    steps = [d[d > 0].min() for d in steps if np.any(d > 0)]
    return float(min(steps)) if steps else 0.0


def _require_preset_ids(source, ids, count: int) -> None:
    """A preset's positions are numbered 1…count: name the numbers missing or extra in the position column
    ("11 readings but the nominal attitudes describe 12 positions" did not say which)."""
    try:
        numbers = {float(u) for u in ids}
    except (TypeError, ValueError):
        return  # text ids: matched in order of appearance
    missing = [k for k in range(1, count + 1) if float(k) not in numbers]
    extra = sorted(_label(u) for u in numbers if not (u.is_integer() and 1 <= u <= count))
    if missing or extra:
        # (not for a label beside a missing position: a mislabelled one, which leaving out would lose)
        odd = [u for u in numbers if not (u.is_integer() and 1 <= u <= count)]
        moving = (f" (rows logged while the device moves between positions, marked {', '.join(map(str, extra))}? "
                  "Leave their position cell empty and pass --bad-lines skip, bad_lines='skip')"
                  if extra and (not missing or all(u <= 0 for u in odd)) else "")
        # (a position not logged: the preset cannot leave it out, the others' attitudes can be given — a blind check)
        remedy = ("" if not missing or extra else
                  f": log {'them' if len(missing) > 1 else 'it'} (in Python the positions logged fit without "
                  f"{'them' if len(missing) > 1 else 'it'}, given their attitudes: attitudes= or rotations= in place of "
                  "the preset)")
        raise ValueError(f"{source}: the preset numbers its positions 1–{count}; the position column "
                         + "; ".join(([f"lacks {', '.join(map(str, missing))}"] if missing else [])
                                     + ([f"has {', '.join(map(str, extra))} besides"] if extra else [])) + moving
                         + remedy)


def _label(position):
    """A position's id as the file writes it (3, not 3.0; a text id as it is)."""
    try:
        return int(position) if float(position).is_integer() else position
    except (TypeError, ValueError):
        return position


# Residuals this many times what the repeats within positions allow: the model does not fit (the blind check's
# wrong-physics cases gave 200× to 200 000×; clean ones about 1×).
MISFIT_RATIO = 5.0


def _gain(res) -> float:
    """K's size as one gain (output units per field unit): its Frobenius norm over √3."""
    return float(np.linalg.norm(res.K) / np.sqrt(3.0))


def _given_noise(sigma: float, labels: list) -> dict:
    """The yardstick `_misfit_warnings` takes from a noise σ given per position (one row each, no repeats to
    measure the scatter within positions or the tilts from)."""
    return {"mag_sigma": sigma, "mag_sigma_per_position": sigma, "tilt_sigma_per_position": 0.0, "worst_tilt": None,
            "moved_limit_deg": None, "given": True, "labels": labels}


def _misfit_warnings(res, field_ned, scatter) -> list:
    """Compare the fit's residuals with what the repeats within positions allow (mag noise + levelling). When
    `calibrate` found the misfit from the field alone (res.summary["field_misfit"]), its warning — with the
    mistake the data point to, if any — is kept and the repeats' ratio added to it: one warning, not two."""
    out = []
    field = res.summary.get("field_misfit")
    gain = _gain(res)
    expected = np.hypot(scatter["mag_sigma_per_position"],
                        gain * np.linalg.norm(field_ned) * scatter["tilt_sigma_per_position"])
    n = len(res.residuals)
    dof_factor = np.sqrt(max(3 * n - len(res.parameters), 1) / (3 * n))
    rms = float(np.sqrt((res.residuals ** 2).mean()))
    ratio = rms / (expected * dof_factor) if expected > 0 else 0.0
    if ratio > MISFIT_RATIO:
        worst = scatter["labels"][int(np.argmax(np.linalg.norm(res.residuals, axis=1)))]
        against = "the noise σ given" if scatter.get("given") else "the scatter within positions"
        # its size as the angle by which the field would be misplaced at each position: K's relative error is of
        # that order in radians (a review: headings set to ±0.1° on a long log, 6×, 4e-4; an uncalibrated MEMS
        # accelerometer, 6×, 4e-3) — the ratio says it is there, this says whether it matters
        if field is not None:
            res.summary["warnings"] = [w for w in res.summary["warnings"] if w != field["warning"]]
            out.append(f"{field['warning'].rstrip('.')}. Against {against} as well: the residual is {ratio:.0f}x what it allows "
                       f"({expected * dof_factor:.3g}); largest at position {worst}")
            return out + _moved_warnings(scatter)
        angle = _misplacement(res)
        out.append(f"the model does not fit: residual RMS {rms:.4g} is {ratio:.0f}x what {against} allows "
                   f"(an RMS of {expected * dof_factor:.3g}); largest at position {worst}. It is a misplacement "
                   f"of the field by {np.degrees(angle):.2g}° per position, and U0 and K are biased by about that "
                   f"({angle:.1g} of K). Check the reference field (inclination sign, declination, --field order "
                   "N,E,D), the position order or labels, heading placement (--estimate-yaw), the accelerometer "
                   "(--calibrate-accelerometer) and magnetic objects near the bench")
    return out + _moved_warnings(scatter)


# A noise σ stated this many times off the scatter within positions (either way) is said: the standard errors take it
STATED_SIGMA_RATIO = 3.0


def _stated_sigma_words(stated: float, measured: float) -> str | None:
    """--noise-sigma against what the repeats within positions measure (both per position, after averaging)."""
    if not (measured > 0 and stated > 0) or 1.0 / STATED_SIGMA_RATIO <= stated / measured <= STATED_SIGMA_RATIO:
        return None
    return (f"--noise-sigma {stated:.3g} is {stated / measured:.2g}x the scatter the repeats within positions show "
            f"per position ({measured:.3g}): the standard errors take the σ given, so they are "
            f"{'too wide' if stated > measured else 'too narrow'} by about that if the repeats are right (is the σ "
            "per reading, not per position after averaging, or in another unit?)")


def _moved_warnings(scatter) -> list:
    out = []
    unsteady = scatter.get("unsteady", [])
    if scatter["worst_tilt"] is not None and scatter["worst_tilt"][0] > scatter["moved_limit_deg"]:
        label = scatter["worst_tilt"][1]
        also = [f"; its outputs scatter {sigma / steady:.3g}x the other positions' (σ {sigma:.3g} against {steady:.3g})"
                for named, sigma, steady in unsteady if named == label]
        unsteady = [u for u in unsteady if u[0] != label]
        out.append(f"position {label}: a reading's accelerometer direction is {scatter['worst_tilt'][0]:.2g}° from "
                   f"the position's mean{''.join(also)} (the device moved while logging?)")
    if unsteady:
        named = ", ".join(f"{label} (σ {sigma:.3g}, {sigma / steady:.3g}x)" for label, sigma, steady in unsteady)
        out.append(f"position(s) {named}: the outputs scatter within the position far beyond the other positions' "
                   f"(σ {unsteady[0][2]:.3g} per reading): the device turned while logging (a turn about "
                   "the vertical leaves the accelerometer's direction as it was) or a magnetic disturbance came and "
                   "went; the position's mean is off by part of that. Log it again, or leave it out (--leave-out "
                   f"{','.join(str(u[0]) for u in unsteady)}); the misfit test takes the other positions' "
                   "scatter as its yardstick")
    return out


def _field_unit_guess(magnitude: float) -> str | None:
    """The unit an Earth field of this magnitude is given in: nT (15 000–80 000) or uT (15–80); None otherwise."""
    return "nT" if 15000 < magnitude < 80000 else ("uT" if 15 < magnitude < 80 else None)


def _unit_warnings(res, field_ned, units, field_units: str = "") -> list:
    """Readings in a field unit should give |K| near the unit conversion: flag µT labelled nT and the like (or the
    field in another unit than the readings': no residual shows it, K's scale absorbs it). `field_ned`: the field,
    or its magnitude; `field_units`: its unit when stated (IGRF's nT), else guessed from its magnitude — and a
    stated unit the magnitude contradicts is said (48.9 given as nT is an Earth field in µT)."""
    from .calibration import TESLA_PER_UNIT
    from .io.columns import unit_name

    F = float(np.linalg.norm(field_ned))
    guessed = _field_unit_guess(F)
    stated = unit_name(field_units) if field_units and unit_name(field_units) in TESLA_PER_UNIT else None
    out = []
    if stated and guessed and stated != guessed:
        out.append(f"the reference field's magnitude {F:.6g} is an Earth field in {guessed}, not in {field_units} as "
                   f"stated: check the field's unit (K is in {units or 'output'} per the unit the field is in)")
    field_unit = stated or guessed
    if unit_name(units) not in TESLA_PER_UNIT or field_unit is None:
        return out
    expected = TESLA_PER_UNIT[field_unit] / TESLA_PER_UNIT[unit_name(units)]  # readings per field unit, unit gain
    gain = _gain(res)
    if not 0.2 < gain / expected < 5.0:
        out.append(f"K's gain is {gain:.3g} {units} per {field_unit}, {gain / expected:.3g}x a unit-gain sensor's: "
                   f"the readings are probably not in {units} (or the field not in {field_unit}); check the unit labels")
    return out


# --- command line (fluxcal positions) ---------------------------------------------------------------

_API_ARRAY = re.compile(r"^(specific_force|readings|outputs|samples|nominal|positions): (?:(row|position) (\d+):? )?")


def _in_file_terms(message: str, source, rec, positions) -> str:
    """An error of calibrate() or calibrate_accelerometer() in the recording's terms: the accelerometer's and
    magnetometer's columns for the arrays they name, a row ("row 0", "position 2") as its file line, or as its
    position when the rows were averaged per position (`positions`, their labels)."""
    found = _API_ARRAY.match(message)
    if not found:
        return message
    array, kind, number = found.groups()
    acc = f"accelerometer {','.join(rec.acc_names())}"
    mag = f"magnetometer {','.join(rec.mag_names())}"
    what = {"specific_force": acc, "readings": acc, "outputs": mag, "samples": mag, "nominal": "nominal attitudes",
            "positions": "positions"}[array]
    where = ""
    if kind is not None:
        row = int(number) - (kind == "position")  # the core counts rows from 0, positions from 1
        where = f", position {_label(positions[row])}" if positions is not None else f", {rec.place(row)}"
    return f"{source}{where}: {what}{' ' if kind else ': '}{message[found.end():]}"


def run_cli(args, out=None) -> int:
    """`fluxcal positions FILE ...`: CSV with ax,ay,az,mx,my,mz (+ optional position) → OUT.json."""
    import json
    import sys
    from pathlib import Path

    from .io import read_recording
    from .io.csv import skipped_words

    out = out or sys.stdout
    # every format calibrate reads (the SAP6 survey instrument's JSON shots, .mat, a logger's CSV)
    rec = read_recording(args.file, columns=getattr(args, "columns", None),
                         bad_lines=getattr(args, "bad_lines", "error"))
    if "skipped_lines" in rec.metadata:
        print(skipped_words(rec.metadata['skipped_lines']), file=out)
    from .outliers import rail_values, rail_words

    axes = {n: rec.columns[n] for n in rec.mag_names()}
    railed = rail_values(axes)
    if railed:
        ids_given = rec.columns.get("position")
        where = ""
        if ids_given is not None:  # which positions, and the remedy that names them (a blind check: only "a rail")
            on = np.zeros(len(ids_given), dtype=bool)
            for name, top in railed:
                on |= np.asarray(axes[name], dtype=float) == top
            named = [_label(u) for u in np.unique(np.asarray(ids_given)[on])]
            where = (f" — in position(s) {', '.join(map(str, named))}, whose averages it biases: --leave-out "
                     f"{','.join(map(str, named))} fits without them")
        print(f"warning: {rail_words(axes, railed)}{where}", file=out)
    acc = rec.acceleration()
    if acc is None:
        raise ValueError(f"{args.file}: no accelerometer columns (ax,ay,az, or a triple named AccX.., accel_x..; "
                         f"columns are: {', '.join(rec.columns)}); the levelling needs one per reading")
    mag = rec.samples(check_finite=False)
    for name, arr in ((f"accelerometer {','.join(rec.acc_names())}", acc),
                      (f"magnetometer {','.join(rec.mag_names())}", mag)):
        if not np.all(np.isfinite(arr)):
            row = int(np.argmax(~np.isfinite(arr).all(axis=1)))
            raise ValueError(f"{args.file}, {rec.place(row)}: {name} is not finite")
    ids = rec.columns.get("position")
    scatter = None
    attitudes = {"preset": args.preset} if args.preset else {}
    held = None  # (labels, accelerometer, magnetometer, nominal rotations or None) of the positions left out
    if ids is not None:
        uniq, acc_av, mag_av = average_positions(ids, acc, mag)
        if args.preset:
            _require_preset_ids(args.file, uniq, len(preset_rotations(args.preset, args.frame)))
        scatter = _replicate_scatter(ids, uniq, acc, mag, acc_av, mag_av)
        acc, mag = acc_av, mag_av
        out_rows = _left_out(getattr(args, "leave_out", None), uniq, args.file)
        if len(out_rows):
            keep = np.setdiff1d(np.arange(len(uniq)), out_rows)
            nominal = preset_rotations(args.preset, args.frame) if args.preset else None
            held = ([_label(uniq[k]) for k in out_rows], acc[out_rows], mag[out_rows],
                    None if nominal is None else nominal[out_rows])
            if nominal is not None:
                attitudes = {"rotations": nominal[keep]}
            dropped = set(held[0])
            scatter = dict(scatter, labels=[label for label in scatter["labels"] if label not in dropped],
                           unsteady=[u for u in scatter["unsteady"] if u[0] not in dropped])
            if scatter["worst_tilt"] is not None and scatter["worst_tilt"][1] in dropped:
                scatter["worst_tilt"] = None
            uniq, acc, mag = uniq[keep], acc[keep], mag[keep]
    elif getattr(args, "leave_out", None):
        raise ValueError(f"--leave-out: {args.file} has no position column to name positions by (its rows are the "
                         "positions: leave rows out of the file)")
    field_args = {}
    if args.field:
        try:
            field_args["field"] = [float(v) for v in args.field.split(",")]
        except ValueError:
            raise ValueError(f"--field: {args.field!r} is not N,E,D") from None
    if args.total is not None or args.inclination is not None:
        field_args.update(total=args.total, inclination=args.inclination, declination=args.declination or 0.0)
    if args.lat is not None or args.lon is not None:
        field_args.update(lat=args.lat, lon=args.lon, alt_km=args.alt_km or 0.0, date=args.date)
    if not field_args:
        raise ValueError("reference field missing: give --field N,E,D, --total/--inclination, or --lat/--lon/--date")
    f = reference_field(**field_args)
    units = rec.field_units()
    acc_cal = None
    extra_warnings = []
    sigma_out = getattr(args, "noise_sigma", 0.0) or 0.0
    if not sigma_out and scatter is not None and args.tilt_sigma > 0:
        sigma_out = scatter["mag_sigma_per_position"]  # σ̂ from 12 positions with 24 tilts is not identified
    if sigma_out and scatter is not None and getattr(args, "noise_sigma", 0.0):
        said = _stated_sigma_words(sigma_out, scatter["mag_sigma_per_position"])
        if said:
            extra_warnings.append(said)
    try:
        if args.calibrate_accelerometer:
            acc_cal = calibrate_accelerometer(acc, gravity=float(np.median(np.linalg.norm(acc, axis=1))))
            acc = acc_cal.apply(acc)
            extra_warnings += [f"accelerometer calibration: {w}" for w in acc_cal.summary.get("warnings", [])]
        res = calibrate(mag, acc, f, frame=args.frame, **attitudes, estimate_yaw=args.estimate_yaw or None,
                        estimate_inclination=args.estimate_inclination, units=units, acc_measures=args.acc_measures,
                        tilt_sigma_deg=args.tilt_sigma, field_units="nT" if args.lat is not None else "",
                        position_labels=[_label(u) for u in uniq] if ids is not None else None,
                        _judge_misfit=False, **({"output_sigma": sigma_out} if sigma_out else {}))
    except ValueError as exc:
        raise ValueError(_in_file_terms(str(exc), args.file, rec, uniq if ids is not None else None)) from None
    if scatter is None and getattr(args, "noise_sigma", 0.0):  # one row per position: the σ given is the yardstick
        scatter = _given_noise(args.noise_sigma,
                               [_label(u) for u in (uniq if ids is not None else range(1, len(mag) + 1))])
    if scatter is not None:
        extra_warnings += _misfit_warnings(res, f, scatter)
    misfit = [w for w in extra_warnings if w.startswith("the model does not fit")]
    # calibrate's own gross-misfit warning (first when said) gives way to a misfit the positions' scatter measured
    warnings_ = [w for w in res.summary["warnings"] if not (misfit and w.startswith(GROSS_SAID))] + \
        [w for w in extra_warnings if w not in misfit]
    res.summary["warnings"] = _misfit_first(res, misfit[0], warnings_) if misfit else warnings_
    report = res.verify(mag, acc, **attitudes, acc_measures=args.acc_measures)
    doc = res.to_dict()
    guess = _field_unit_guess(float(np.linalg.norm(f)))
    field_name = "nT" if args.lat is not None else (guess or "the reference field's unit")  # IGRF gives nT
    by_size = ", the field's unit by its magnitude" if args.lat is None and guess else ""
    # the body frame is the accelerometer's (levelling): K takes up a turn between the two sensors, and with the
    # headings free nothing can see it (a blind check's 1° misalignment left a residual at the noise)
    doc["units_of"] = {"offset": res.units or "the outputs' unit",
                       "K": f"{res.units or 'output'} per {field_name}{by_size}",
                       "K_frame": "the field in the accelerometer's axes: K includes any turn between accelerometer "
                                  "and magnetometer", "field_ned": field_name + by_size, "standard_errors": "each parameter's own (U0, K as above; yaw_* and "
                       "inclination in radians)", "yaw_deg": "degrees"}
    doc.update(source=str(args.file), positions=int(len(mag)), preset=args.preset,
               verification={k: v for k, v in report.items() if not isinstance(v, list) or k == "field_error_rms"})
    if held is not None:
        doc["left_out"] = _held_out(res, held, args.acc_measures)
    if acc_cal is not None:
        doc["accelerometer"] = {"offset": acc_cal.offset.tolist(), "matrix": acc_cal.matrix.tolist(),
                                "tilt_error_deg": acc_cal.tilt_error_deg}
    if args.output:  # before the report: a reader that stops early (| head) must not cost the result
        Path(args.output).write_text(json.dumps(doc, indent=2))
    with np.printoptions(precision=8, suppress=True):
        print(res.summary["message"], file=out)
        print(f"  U0 = {res.offset} {res.units}".rstrip(), file=out)
        rows = ", ".join("[" + ", ".join(f"{v:.8g}" for v in row) + "]" for row in res.K)
        print(f"  K  = [{rows}] ({doc['units_of']['K']})", file=out)
        print(f"  field (N, E, D) = {res.field_ned}  inclination {inclination_of(res.field_ned):.3f}°", file=out)
        v = doc["verification"]
        field_unit = f" {field_name}" if args.lat is not None or guess else f" ({field_name})"
        print(f"  in-sample: |H| error RMS {v['magnitude_error_rms']:.4g}{field_unit}, dip error RMS "
              f"{v['dip_error_deg_rms']:.4g}°"
              + (f", heading error RMS {v['heading_error_rms_deg']:.4g}°" if "heading_error_rms_deg" in v else ""),
              file=out)
        for seen in doc.get("left_out", []):
            print(f"  left out: position {seen['position']}: |H| error {seen['magnitude_error']:+.4g}{field_unit}, dip error "
                  f"{seen['dip_error_deg']:+.3g}°" + (f", heading error {seen['heading_error_deg']:+.3g}°"
                                                      if "heading_error_deg" in seen else ""), file=out)
    for w in res.summary["warnings"]:
        print(f"warning: {w}", file=out)
    if args.output:
        print(f"wrote {args.output}", file=out)
    # the calibration's offset or gains (U0, K's diagonal; not a small cross term, nor the positions' headings and
    # tilts) not determined: a script reading the exit status must not take it for a calibration to ship (it had
    # exited 0 with every parameter poorly determined)
    key = [n.startswith("U0_") or n in ("K_xx", "K_yy", "K_zz") for n in res.parameter_names]
    poor = [n for n, d, k in zip(res.parameter_names, res.determined, key) if k and not d]
    unjudged = [n for n, se, k in zip(res.parameter_names, res.standard_errors, key)
                if k and not np.isfinite(se) and n not in poor]
    if unjudged:  # (a blind check: 4 positions, an exact fit, exit 0 with every standard error null)
        print(f"fluxcal positions: {args.file}: the calibration's {', '.join(unjudged[:6])}"
              f"{', …' if len(unjudged) > 6 else ''} have no standard error (the fit has no degrees of freedom left "
              "for the noise: as many equations as unknowns?): it cannot be judged — log more positions (exit status "
              "3; -o still writes it)", file=sys.stderr)
        return 3
    if poor:
        print(f"fluxcal positions: {args.file}: the calibration's {', '.join(poor[:6])}{', …' if len(poor) > 6 else ''}"
              " poorly determined: see the warnings above (exit status 3; -o still writes it)", file=sys.stderr)
        return 3
    return 0


def _left_out(text, uniq, source) -> np.ndarray:
    """The rows of `uniq` (the position column's labels) that --leave-out names; an unknown label is an error."""
    if not text:
        return np.zeros(0, dtype=int)
    labels = [str(_label(u)) for u in uniq]
    wanted = [w.strip() for w in str(text).split(",") if w.strip()]
    unknown = [w for w in wanted if w not in labels and str(_label(w)) not in labels]
    if unknown:
        raise ValueError(f"--leave-out: {', '.join(unknown)} not among {source}'s positions ({', '.join(labels)})")
    return np.array(sorted({labels.index(w if w in labels else str(_label(w))) for w in wanted}), dtype=int)


def _held_out(res, held, acc_measures: str) -> list:
    """Each position left out, read by the calibration against its nominal attitude (when there is one)."""
    labels, acc, mag, nominal = held
    report = res.verify(mag, acc, **({"rotations": nominal} if nominal is not None else {}), acc_measures=acc_measures)
    out = []
    for i, label in enumerate(labels):
        seen = {"position": label, "magnitude_error": report["magnitude_error"][i],
                "dip_error_deg": report["dip_error_deg"][i]}
        if "heading_error_deg" in report:
            seen["heading_error_deg"] = report["heading_error_deg"][i]
        out.append(seen)
    return out


GROSS_MISFIT = 0.05  # in-sample |H| error RMS, as a share of the field, that no sensor's noise explains (refine's)
GROSS_SAID = "the model does not fit the readings: at its own positions"


def _gross_misfit(report: dict, field_ned, warnings_: list, unit: str) -> str | None:
    """A warning when the fit leaves the field's magnitude wrong by more than GROSS_MISFIT at its own positions
    and nothing said so yet: without repeats within positions or a noise σ there is no yardstick for the
    residual, but 5 % of the field is none's noise (a hand-tumbled stream taken as positions: 20 %, 10.7° of dip,
    with every parameter poorly determined as the only word)."""
    size = float(np.linalg.norm(field_ned))
    error = report.get("magnitude_error_rms", 0.0)
    if not (size > 0 and error > GROSS_MISFIT * size) or any(w.startswith("the model does not fit") for w in warnings_):
        return None
    return (f"{GROSS_SAID} the field's magnitude is {error:.4g}{unit} RMS "
            f"({100 * error / size:.3g} % of it) and the dip {report.get('dip_error_deg_rms', float('nan')):.3g}° "
            "RMS off, far above a sensor's noise. Check that the rows are held positions (a log taken while the "
            "device turns is no set of positions: calibrate the magnetometer from it with fluxcal calibrate), the "
            "reference field (inclination sign, --field order N,E,D), the magnetometer's and accelerometer's axes, "
            "and magnetic objects near the bench")
