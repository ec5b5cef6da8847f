"""Withheld effects added to a real recording: the diagnosis checked blind on a real sensor's own noise,
disturbances and coverage instead of a simulated hand (bench/diagnose.py --inject, tests).

    rec = fluxcal.read_csv("phone_acc_mag.csv")
    inj = inject(rec.samples(), ["temp_offset"], seed=3, gravity=rec.acceleration())
    fluxcal.diagnose(inj.readings, **inj.kwargs)

The recording is first calibrated (readings m = b + W h); each effect is then added at a typical magnitude
(its class's `typical`, scaled to the recording's field — in readings' units for offsets, against the readings'
typical magnitude, hard iron included, for the non-linearities) where it acts in a sensor:
- on the field, before the soft iron (moving_dipole, eddy_current, misalignment): computed on the
  calibrated field h, smoothed in time, and mapped into readings through W;
- on the transducer's output (temp_scale, scale_drift, cross_axis, nonlinearity_cubic, saturation, hysteresis):
  computed on the smoothed readings, so that the recording's noise is not fed through a non-linearity;
- electronic offsets (temp_offset, offset_drift, offset_step, motor_current) simply added;
- time_offset (the readings delayed against their reference) and the noise effects (colored_noise,
  quantization) applied to the readings themselves.
The regressors an effect needs are the recording's own when given (`temp`, `current`), else made up as a
simulation makes them: a temperature that rises and falls (`scene.warming`), a current that steps between
throttle settings (`scene.throttle`). A moving magnet's
field is fixed in the world: with the down direction (`gravity`, an accelerometer) the sensor's attitude
follows from it and the field; without it only the disturbance's component along the field is added
(all that a magnitude shows to first order; the rest needs the attitude). non_orthogonality is not
offered: a full soft-iron matrix absorbs it, and a real sensor needs the full matrix.
"""
from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
from scipy.spatial.transform import Rotation

from .._arrays import as_samples
from ..attitude import magnetic_frame
from .effects import CANDIDATES, _smooth
from .scene import throttle, warming

FIELD_STAGE = ("moving_dipole", "eddy_current", "misalignment")
TRANSDUCER_STAGE = ("temp_scale", "scale_drift", "cross_axis", "nonlinearity_cubic", "nonlinearity_quadratic",
                    "saturation", "saturation_knee", "hysteresis")
ON_READINGS = ("time_offset", "colored_noise", "quantization")  # applied to the readings as they are
NEEDS_REFERENCE = ("misalignment", "time_offset")
NOT_OFFERED = ("non_orthogonality",)
TIMED = ("offset_drift", "scale_drift", "moving_dipole", "offset_step")  # typical() wants the recording's duration
SIGNAL_SCALED = ("nonlinearity_cubic", "nonlinearity_quadratic", "saturation", "saturation_knee", "cross_axis")
CURRENT = (20.0, 4.0)  # A peak, s per throttle setting


@dataclass
class Injection:
    """`readings` with the effects added; `effects` (each with its true parameters); `kwargs` for
    `fluxcal.diagnose` (t, temp, current, field_norm, reference and gravity as given or made up)."""

    readings: np.ndarray
    effects: list
    kwargs: dict


def injectable(reference: bool) -> list:
    """The candidate names `inject` can add to a recording (with or without reference vectors)."""
    return [c.name for c in CANDIDATES if c.name not in NOT_OFFERED and (reference or c.name not in NEEDS_REFERENCE)]


def inject(readings, names, seed: int, t=None, rate_hz: float = 50.0, gravity=None, reference=None,
           field_norm: float | None = None, strength: float = 1.0, temp=None, current=None,
           calibration=None) -> Injection:
    """Add the effects `names` (candidate names) to a real recording `readings` (N×3). `t` (s; default the
    row at `rate_hz`), `gravity` (N×3 down or up direction, sensor frame: the attitude for a world-fixed
    field), `reference` (N×3 true field, sensor frame: a vector fit, and needed for misalignment and
    time_offset), `field_norm` (the field's magnitude, when known), `strength` (each effect's change to
    the readings times this, to find what a recording's own disturbances hide; time_offset's delay times this;
    not for the noise effects), `temp` (°C) and `current` (A): the recording's own regressors (default: made
    up), `calibration`: the recording's own (`calibrate(readings, field_norm=…, reference=…)`), when already made.
    Seeded: the same seed adds the same effects."""
    m = as_samples(readings)
    n = len(m)
    allowed = injectable(reference is not None)
    bad = [x for x in names if x not in allowed]
    if bad:
        raise ValueError(f"names: cannot inject {', '.join(bad)} here (possible: {', '.join(allowed)})")
    t = np.arange(n) / rate_hz if t is None else np.asarray(t, dtype=float)
    if t.shape != (n,):
        raise ValueError(f"t: need {n} times, got shape {t.shape}")
    from ..pipeline import calibrate

    if gravity is not None:
        gravity = as_samples(gravity, "gravity")
        if len(gravity) != n:
            raise ValueError(f"gravity: {len(gravity)} rows, readings have {n}")
    cal = calibration if calibration is not None else calibrate(m, field_norm=field_norm, reference=reference)
    W = np.linalg.inv(np.asarray(cal.matrix))
    h = cal.apply(m)
    H = float(np.mean(np.linalg.norm(h, axis=1)))
    rng = np.random.default_rng(seed)
    by_name = {c.name: c for c in CANDIDATES}
    duration = float(np.ptp(t))
    # Sizes in the units each effect acts in: field effects in field units (they pass through W); offsets
    # and quantisation in reading units (the field's size in readings, |m − b|); transducer non-linearities
    # against what the transducer sees, the field plus the hard iron (often several times the field in a
    # real device), as their typical sizes are given against a sensor's range.
    size = {"field": H, "readings": float(np.median(np.linalg.norm(m - cal.offset, axis=1))),
            "signal": float(np.median(np.linalg.norm(m, axis=1)))}
    effects = [by_name[x].typical(size[_units(x)], rng, duration) if x in TIMED
               else by_name[x].typical(size[_units(x)], rng) for x in names]
    for effect in effects:  # typical() times events from 0: the recording's clock may start anywhere
        if hasattr(effect, "t_on"):
            effect.t_on, effect.t_off = effect.t_on + t[0], effect.t_off + t[0]
    # drawn even when given, so that a seed adds the same effects either way
    made_temp, made_current = warming(t, rng), throttle(t, rng, *CURRENT) if "motor_current" in names else None
    temp = made_temp if temp is None else _regressor(temp, n, "temp")
    current = made_current if current is None else _regressor(current, n, "current")
    h_smooth, m_smooth = _smooth(h, t), _smooth(m, t)
    along_field_only = gravity is None
    context = SimpleNamespace(t=t, temp=temp, current=current, rng=rng, truth=h_smooth,
                              rotations=_attitude(h_smooth if reference is None else reference, gravity))
    out = m.copy()
    for effect in effects:
        if effect.name in FIELD_STAGE:
            dh = effect.apply(h_smooth, context) - h_smooth
            if effect.name == "moving_dipole" and along_field_only:
                u = h_smooth / np.linalg.norm(h_smooth, axis=1, keepdims=True)
                dh = np.sum(dh * u, axis=1, keepdims=True) * u
            out += strength * dh @ W.T
        elif effect.name in TRANSDUCER_STAGE:
            out += strength * (effect.apply(m_smooth, context) - m_smooth)
        elif effect.name not in ON_READINGS:  # electronic offsets: independent of the values
            out += strength * effect.apply(np.zeros_like(m), context)
    for effect in effects:
        if effect.name == "time_offset":
            effect.delta *= strength
        if effect.name in ON_READINGS:
            out = effect.apply(out, context)
    kwargs = {"t": t, "temp": temp, "field_norm": field_norm}
    if current is not None:
        kwargs["current"] = current
    if reference is not None:
        kwargs.update(reference=reference, gravity=gravity)
    if "quantization" in names:
        from ..diagnose import estimate_noise

        kwargs["noise_sigma"] = estimate_noise(m)  # the datasheet noise: what the sensor had before
    return Injection(out, effects, kwargs)


def _regressor(values, n: int, name: str) -> np.ndarray:
    values = np.asarray(values, dtype=float)
    if values.shape != (n,) or not np.all(np.isfinite(values)):
        raise ValueError(f"{name}: need {n} finite values, got shape {values.shape}"
                         + ("" if values.shape != (n,) else " with missing or non-finite ones"))
    return values


def _units(name: str) -> str:
    """Which size an effect's typical magnitude is taken against (see inject)."""
    return "field" if name in FIELD_STAGE else "signal" if name in SIGNAL_SCALED else "readings"


def _attitude(field: np.ndarray, gravity) -> Rotation:
    """Sensor → world rotations from the field and the down direction (`attitude.magnetic_frame`).
    Without gravity, a frame whose first axis is the field: only a field's component along it is then
    meaningful."""
    if gravity is None:
        f = field / np.linalg.norm(field, axis=1, keepdims=True)
        gravity = np.cross(f, np.where(np.abs(f[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]])))
    return Rotation.from_matrix(magnetic_frame(field, gravity))
