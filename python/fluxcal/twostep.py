"""TWOSTEP calibration from field magnitudes, on the C++ core (cpp/include/fluxcal/twostep.hpp).

2-D (seed 000, Song et al. 2017): a biaxial sensor whose reading ĥ obeys
    h_k² = (ĥx − bx)²/γx² + (ĥy − by)²/γy²
with h_k the true field magnitude of reading k, known per reading (reference current and geometry) and
allowed to differ between readings. `twostep_2d` returns the offset b (reading units) and gains γ
(reading units per field unit); compensation (eq. 19) is h = (ĥ − b) ⊘ γ.

3-D (Alonso & Shuster 2002; Gebre-Egziabher et al. 2006): a three-axis sensor in a field of known
constant magnitude H. `twostep` returns a `fluxcal.Calibration` in fluxcal's convention
h = A (m − b), A symmetric (A = I + D, b = (I + D)⁻¹ b_AS in Alonso & Shuster's notation).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from . import _core
from ._arrays import (as_field_norms, as_samples, samples_units, changing_field, field_norm_given, field_norms_summary,
                      positive_field_norm, recording_times, set_options, units_text)
from .calibration import Calibration, scale_words
from .ellipsoid import _calibration
from .refine import parameter_statistics, serial_correlation_mode


@dataclass
class TwoStep2D:
    """Offset and gains of a biaxial sensor: reading ĥ = γ ⊙ h + b + noise, so h = (ĥ − b) ⊘ γ.

    `constant_field` is True when every field magnitude was the same (the first step then used the
    known-radius ellipse form); `covariance` that of (bx, by, γx, γy) (σ̂²(JᵀJ)⁻¹ of the magnitude residuals at
    the result; inf when the data do not determine them) and `offset_se`, `gain_se` its standard errors; `summary` holds the fit statistics
    (see twostep.hpp).
    """

    offset: np.ndarray
    gain: np.ndarray
    units: str = ""
    constant_field: bool = False
    summary: dict = field(default_factory=dict)
    offset_se: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    gain_se: np.ndarray = field(default_factory=lambda: np.full(2, np.nan))
    covariance: np.ndarray = field(default_factory=lambda: np.full((4, 4), np.nan))  # (bx, by, γx, γy)

    def __post_init__(self):
        self.offset = np.asarray(self.offset, dtype=float).reshape(2)
        self.gain = np.asarray(self.gain, dtype=float).reshape(2)
        if not (np.all(np.isfinite(self.offset)) and np.all(np.isfinite(self.gain)) and np.all(self.gain != 0)):
            # a zero gain made apply() divide by zero
            raise ValueError(f"TwoStep2D: offset {self.offset.tolist()} and gain {self.gain.tolist()} must be finite, "
                             "the gains non-zero")

    def apply(self, readings) -> np.ndarray:
        """Compensated field (eq. 19) of one reading (2,) or of N×2 readings, the same shape out. A NaN
        reading gives a NaN field, row by row, as Calibration.apply."""
        if np.ndim(readings) == 1:
            return (np.asarray(readings, dtype=float).reshape(2) - self.offset) / self.gain
        return (as_samples(readings, "readings", columns=2) - self.offset) / self.gain

    def reading(self, fields) -> np.ndarray:
        """The readings true fields would produce (the forward model ĥ = γ ⊙ h + b, no noise)."""
        return np.asarray(fields, dtype=float) * self.gain + self.offset


def twostep_2d(readings, field_norms, units: str | None = None, refine: bool = True,
               **settings) -> TwoStep2D:
    """Two-step calibration of a biaxial sensor from N ≥ 5 readings (N×2) and the true field
    magnitude of each (`field_norms`, N values > 0, field units; one value: the same for every reading).

    First step: least squares on z = ĥx² = [2ĥx, 2ĥy, −ĥy², −1, h²]·x with
    x = (bx, r·by, r, bx² + r·by², γx²), r = (γx/γy)² (the paper's eqs. 8–17 with corrected signs);
    second step: bx = x1, by = x2/x3, γx² = x5, γy² = x5/x3. With `refine` (default) Gauss–Newton then
    minimises Σ (|(ĥ − b) ⊘ γ| − h_k)² over (b, γ). The field must change direction between readings
    (turn the sensor) and, unless all magnitudes are equal, its magnitude between readings too.

    settings: max_iterations=50, tolerance=1e-12 (refinement), noise_bias_correction=True (noise makes the corrected
    magnitudes σ²/2h too long on average, which raised the gains by that fraction: the fit is solved again towards
    each reading's Rice mean E|h_k + ε| less the Sampson normaliser's move, and the Jacobian's move with the noise
    taken off; not when a gain is poorly determined), misfit_spread=0.05 (a warning when |h|/h
    scatters more after the fit: field_norms that do not belong to the readings), poorly_determined=0.02 (a
    warning when a gain's standard error is a larger fraction of it: too short an arc), runaway_factor=10 (a
    refinement that did not converge with a gain grown more than this over the first step's raises: one field
    magnitude and a short arc let offsets and gains run to infinity). A misfit that follows twice the
    heading is warned about too: a coupling between the axes that offsets and gains cannot fit (`_axis_coupling`).
    Raises ValueError on NaN/Inf, too few
    readings, a length mismatch, non-positive magnitudes, a rank-deficient first step, or γ² ≤ 0.
    """
    arr = as_samples(readings, "readings", columns=2)
    try:
        norms = np.asarray(field_norms, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"field_norms: {field_norms!r:.60} is not numbers") from None
    if norms.ndim == 0:  # one magnitude for every reading: a field that does not change (the horizontal field)
        norms = np.full(len(arr), float(norms))
    if norms.ndim != 1:
        raise ValueError(f"field_norms: shape {norms.shape}, expected one magnitude per reading (N,) or one for all")
    if not isinstance(refine, (bool, np.bool_)):  # bool("no") is True
        raise TypeError(f"refine: {refine!r} is not True or False")
    options = _core.TwoStep2DOptions()
    options.refine = bool(refine)
    options.units = units_text(units)
    set_options(options, settings, "twostep_2d")
    r = _core.twostep_2d(arr, np.ascontiguousarray(norms), options)
    result = TwoStep2D(offset=r["offset"], gain=r["gain"], units=r["units"], constant_field=r["constant_field"],
                       summary=r["summary"], offset_se=np.asarray(r["offset_se"]), gain_se=np.asarray(r["gain_se"]),
                       covariance=np.asarray(r["covariance"]))
    said = [w for w in (_far_off(result, arr, norms), _axis_coupling(result, arr, norms), _unit_mismatch(result),
                        _few_readings_words(result.summary, len(arr), 4, bool(np.all(np.isfinite(result.offset_se))
                                                                               and np.any(result.offset_se > 0))))
            if w]
    result.summary["warnings"] = list(result.summary["warnings"]) + said
    return result


def _unit_mismatch(result: TwoStep2D) -> str | None:
    """Readings stated in a field unit whose gains are far from 1: field_norms in another unit (nT magnitudes for
    µT readings gave gains of 1e-3 without a word). As the 3-D form's check; readings in volts or counts are not
    judged."""
    from .io.columns import FIELD_UNITS

    gain = float(np.sqrt(np.prod(result.gain)))
    if result.units not in set(FIELD_UNITS.values()) - {"counts"} or 0.2 <= gain <= 5.0:
        return None
    return (f"the gains {np.round(result.gain, 6).tolist()} are {gain:.3g} readings ({result.units}) per unit of "
            "field_norms: field_norms are probably in another unit than the readings — check the units")


FAR_OFF_ALPHA = 1e-3  # a reading is far off when its misfit lies beyond this tail (two-sided, Bonferroni over the
FAR_OFF_LEAST = 5.0   # readings) of the others' robust spread, and at least this many of those σ off


def _far_off(result: TwoStep2D, readings: np.ndarray, norms: np.ndarray) -> str | None:
    """A warning naming the readings whose |h| − h lies far off the others' (beyond Bonferroni's line at FAR_OFF_ALPHA
    in units of their robust σ, and FAR_OFF_LEAST σ): glitches (an I²C read of 0, 0; a spike) or magnitudes that do
    not belong to them, which pull the least-squares offsets and gains their way. A blind check's 30 readings of 0, 0
    in 10 000 moved the offsets by 5 standard errors without a word (the 3-D form names such a reading)."""
    from scipy import stats

    n = len(readings)
    if n < 10:
        return None
    r = np.linalg.norm(result.apply(readings), axis=1) - norms
    spread = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    if not spread > 0:
        return None
    z = np.abs(r - np.median(r)) / spread
    far = np.flatnonzero(z > max(FAR_OFF_LEAST, float(stats.norm.isf(FAR_OFF_ALPHA / (2 * n)))))
    if not far.size:
        return None
    rows = ", ".join(str(int(i)) for i in far[:8]) + (", …" if far.size > 8 else "")
    sizes = f"{z[far].min():.3g}" if f"{z[far].min():.3g}" == f"{z[far].max():.3g}" else \
        f"{z[far].min():.3g}–{z[far].max():.3g}"
    return (f"{far.size} of {n} readings lie {sizes} robust σ off their field magnitudes "
            f"(rows {rows}): glitches (a read of 0, 0; a spike) or magnitudes that do not belong to them, which pull "
            "the offsets and gains their way — leave them out and fit again")


# The share of the relative misfit's variance that twice the heading must explain before it is named: noise and
# a field that changes with position leave no such pattern; a coupling between the axes does.
COUPLING_SHARE = 0.25


def _axis_coupling(result: TwoStep2D, readings: np.ndarray, norms: np.ndarray) -> str | None:
    """A warning when |h|/h − 1 follows twice the heading: what a coupling between the two axes (a rotated or
    sheared soft iron, non-orthogonal axes) leaves, which the model's offsets and per-axis gains cannot fit —
    a yaw-only log with 5 % coupling kept a 3.7 % |h| spread at σ 1 %, with no warning. F-test of cos 2θ, sin 2θ
    against a constant (p < 1e-3), and at least COUPLING_SHARE of the misfit's variance."""
    from scipy import stats

    h = result.apply(readings)
    n = len(h)
    if n < 10:
        return None
    theta = np.arctan2(h[:, 1], h[:, 0])
    y = np.linalg.norm(h, axis=1) / norms - 1.0
    X = np.column_stack([np.ones(n), np.cos(2 * theta), np.sin(2 * theta)])
    beta, *_ = np.linalg.lstsq(X, y, rcond=None)
    rss1, rss0 = float(np.sum((y - X @ beta) ** 2)), float(np.sum((y - y.mean()) ** 2))
    if not (rss0 > 0 and rss1 > 0):
        return None
    share = 1.0 - rss1 / rss0
    p = float(stats.f.sf((rss0 - rss1) / 2 / (rss1 / (n - 3)), 2, n - 3))
    if p >= 1e-3 or share < COUPLING_SHARE:
        return None
    return (f"|h|/h follows twice the heading (±{100 * np.hypot(beta[1], beta[2]):.2g} %, {100 * share:.0f} % of the "
            "misfit): a coupling between the two axes (a rotated or sheared soft iron, axes not at right angles) "
            "that the 2-D model's offsets and gains leave out; the corrected headings carry it — a 3-D calibration "
            "(tumble the sensor) or a vector fit against reference vectors models it")


# Residual RMS over the noise of the readings' own successive values above which a |field| log is said not to fit:
# white noise alone leaves about 1 (its radial share), and the noise estimate only grows with a sensor's motion.
FIELD_LOG_MISFIT = 3.0
FIELD_LOG_STEP = 0.5  # |correlation| of the misfit with the log's change per reading that says "out of step"
# The misfit RMS with the log shifted by the lag found, at most this share of the unshifted one, says "out of step"
# too: a lag longer than the field's changes last leaves a misfit that the change per reading no longer predicts
# (a storm's log 600 readings late: correlation 0.1–0.4), which the shift still removes; no shift helps a log that
# is rounded, in another unit or of another place.
FIELD_LOG_REALIGNED = 0.5
FIELD_LOG_REFITS = 3  # most TWOSTEP refits at the lag found (_log_lag); 1–3 were needed, each a few ms at N = 1e5
FIELD_LOG_WORDS = "the readings miss each reading's |field|"  # how the warning starts (calibrate replaces its start's)


def field_log_misfit(m: np.ndarray, cal: Calibration, norms: np.ndarray, interval: float | None = None) -> str | None:
    """A warning when readings calibrated with each one's |field| (`norms`, changing) miss them by more than
    FIELD_LOG_MISFIT times the noise their successive values show: the log out of step with them (said with its
    shift, in readings, and in seconds with `interval`, the readings' time step), rounded, in another unit — or
    the sensor departs from the model. A blind check's log lagged by 2 h or rounded to 1 µT was 10–15× the noise,
    and said nothing.

    The shift is the lag that minimises the misfit (_log_lag). Its first guess, d ≈ −L·rate (the misfit's
    regression on the log's change per reading), holds only while the field's rate stays the same over the lag:
    a 50 Hz minute with its log 150 readings late said +114 to +135, a storm's ±56 to ±84 for ±150 (or no shift:
    the correlation then falls under FIELD_LOG_STEP)."""
    from .diagnose.core import estimate_noise

    if len(m) < 20 or not changing_field(norms):
        return None
    d = np.linalg.norm(cal.apply(m), axis=1) - norms * (cal.field_norm / np.mean(norms))
    rms = float(np.sqrt(np.mean(d * d)))
    noise = float(np.cbrt(abs(np.linalg.det(cal.matrix)))) * estimate_noise(m)  # in |h|'s unit
    if not (noise > 0.0 and rms > FIELD_LOG_MISFIT * noise):  # (0: readings coarser than their noise, an ADC's
        return None                                           # steps: no yardstick here)
    text = (f"{FIELD_LOG_WORDS} by {rms:.4g} RMS, {rms / noise:.3g} times the noise of their successive values "
            f"({noise:.3g}): ")
    rate = np.gradient(norms * (cal.field_norm / np.mean(norms)))
    dc, rc = d - d.mean(), rate - rate.mean()
    scale = float(np.sqrt(np.dot(dc, dc) * np.dot(rc, rc)))
    corr = float(np.dot(dc, rc)) / scale if scale > 0 else 0.0
    lag, realigned = _log_lag(m, cal, norms)
    if lag != 0 and (abs(corr) > FIELD_LOG_STEP or realigned <= FIELD_LOG_REALIGNED * rms):
        seconds = f" ({lag * interval:+.3g} s)" if interval else ""
        text += (f"the misfit follows the |field| log's change (correlation {corr:.2f} with its change from reading "
                 f"to reading; shifted by {lag:+d} readings it falls to {realigned:.4g} RMS, "
                 f"{realigned / noise:.3g} times the noise): it looks out of step with the readings, its value k the "
                 f"field at about reading k {lag:+d}{seconds}; ")
    return text + ("check the |field| log's alignment in time, its resolution and its unit — or ask fluxcal diagnose "
                   "what else departs")


def _log_lag(m: np.ndarray, cal: Calibration, norms: np.ndarray) -> tuple[int, float]:
    """(L, RMS): the shift L in readings (|L| ≤ N/4, so that most readings overlap) at which the log's value k taken
    as the field at reading k + L fits the calibrated readings best, and the misfit's RMS there.

    The misfit d_j = |h_j| − s·norms_(j−L) is computed at every lag at once (_lag_misfits), and L taken at the
    nearest minimum (_nearest_minimum). The calibration was fitted to the log as given, which took up part of
    the lag (a storm's log 150 readings late was put 131–148 late with it), so TWOSTEP is refitted on the readings
    the shifted log covers and the lag sought again until it stays (at most FIELD_LOG_REFITS refits; they ran
    only when the misfit is said, and a TWOSTEP of 1e5 readings takes a few ms, as the search). A refit that fails
    keeps the last lag."""
    n, longest = len(m), len(m) // 4
    fit, lag, said = cal, 0, None
    for refit in range(FIELD_LOG_REFITS + 1):
        x = np.linalg.norm(fit.apply(m), axis=1)
        lags, ms = _lag_misfits(x, norms * (fit.field_norm / np.mean(norms)), longest)
        lag = _nearest_minimum(lags, ms)
        realigned = float(np.sqrt(ms[lag + longest]))
        if lag == 0 or lag == said or refit == FIELD_LOG_REFITS:
            break
        said = lag
        rows, values = (m[lag:], norms[:n - lag]) if lag > 0 else (m[:n + lag], norms[-lag:])
        try:
            quick = _core.TwoStepOptions()
            quick.standard_errors = False  # only its offset and matrix are looked at
            fit = _calibration(_core.twostep_norms(np.ascontiguousarray(rows), np.ascontiguousarray(values), quick))
        except ValueError:
            break
    return lag, realigned


def _lag_misfits(x: np.ndarray, y: np.ndarray, longest: int) -> tuple[np.ndarray, np.ndarray]:
    """The lags L = −longest … longest and the mean square about its mean of d_j = x_j − y_(j−L) over the readings
    j that have a y_(j−L), from one FFT cross-correlation and running sums: O(N log N)."""
    from scipy import fft

    n = len(x)
    x, y = x - x.mean(), y - y.mean()  # (d about its mean is the same; the sums lose no digits to the level)
    size = fft.next_fast_len(n + longest, real=True)  # (the circular correlation wraps only beyond ±longest)
    cross = fft.irfft(fft.rfft(x, size) * np.conj(fft.rfft(y, size)), size)  # [L mod size]: Σ_j x_j y_(j−L)
    lags = np.arange(-longest, longest + 1)
    sx, sx2 = np.r_[0.0, np.cumsum(x)], np.r_[0.0, np.cumsum(x * x)]
    sy, sy2 = np.r_[0.0, np.cumsum(y)], np.r_[0.0, np.cumsum(y * y)]
    x0, x1 = np.maximum(lags, 0), n + np.minimum(lags, 0)  # the readings j covered: x0 ≤ j < x1
    y0, y1 = x0 - lags, x1 - lags
    count = n - np.abs(lags)
    mean = (sx[x1] - sx[x0] - sy[y1] + sy[y0]) / count
    square = (sx2[x1] - sx2[x0] + sy2[y1] - sy2[y0] - 2.0 * cross[lags % size]) / count
    return lags, np.maximum(square - mean * mean, 0.0)


def _nearest_minimum(lags: np.ndarray, ms: np.ndarray) -> int:
    """The lag of the least misfit `ms` among those either side of 0 up to where it first exceeds its value at
    0: the nearest minimum, not a later one where a field that repeats (an orbit's |F|, every half orbit) matches
    the log again; 0 when neither side falls."""
    zero = int(np.searchsorted(lags, 0))
    best = zero
    for step in (1, -1):
        side = ms[zero::step]
        above = np.flatnonzero(side > side[0])
        k = int(np.argmin(side[:above[0]] if above.size else side))
        if side[k] < ms[best]:
            best = zero + step * k
    return int(lags[best])


def reading_interval(samples) -> float | None:
    """The readings' time step in seconds (the median), when `samples` is a Recording with times; else None."""
    t = recording_times(samples)
    if t is None or len(t) < 2:
        return None
    step = float(np.median(np.diff(t)))
    return step if np.isfinite(step) and step > 0 else None


def twostep(samples, field_norm, units: str | None = None, **settings) -> Calibration:
    """Two-step (Alonso–Shuster) calibration h = A (m − b) of N×3 readings (N ≥ 9) taken in a field
    of known constant magnitude `field_norm` (e.g. from IGRF, in the units h should come out in), or of known
    magnitude at each reading (N values: a spacecraft along its orbit, as Alonso & Shuster wrote it; a field
    logged by a scalar magnetometer beside the sensor). With N values the first step fits their change with its
    own coefficient and the second step each |h_k| to its own; the calibration's field_norm is their mean.

    First step: the centred linear estimate of z_k = |m_k|² − H² = −m_kᵀ E m_k + 2cᵀm_k + const with
    tr E = 0 (a constant |H| leaves the scale to the second step); second step: Fisher scoring of
    Σ (|A(m_k − b)|² − H² − μ)² over the offset and the symmetric A, then on to its maximum-likelihood form, each
    residual over its own σ_k ∝ |A²(m_k − b)| (the Sampson distance; from the first step when the first scoring ran
    off: a cap of directions, a narrow band of tilts at high noise), μ the noise mean (estimated from the residuals,
    or from `noise_sigma`, the reading noise per axis). `samples` may be a `fluxcal.io.Recording`, whose units are
    then carried.

    settings (defaults in cpp/include/fluxcal/twostep.hpp): max_iterations=50 (0 = first step only),
    tolerance=1e-10, noise_sigma=-1 (estimate; 0 = no noise-mean correction), planar_ratio=0.02,
    poor_coverage_ratio=0.3, poor_direction_coverage=0.5 (of what N readings spread evenly would fill),
    coverage_rows=16384, runaway_misfit=1.1 (inf: never), standard_errors=True, determined_tolerance=0.01,
    serial_correlation="automatic" ("independent", "newey_west"), serial_correlation_alpha=0.01. With the second step
    the summary holds A&S's error covariance of [b0 b1 b2 a00 a01 a02 a11 a12 a22] under refine's keys
    (parameters, parameter_names, covariance, standard_errors, determined, identifiable, serial_correlation):
    from 30 readings the HC2 sandwich of the second step's scores about its Fisher information (the residuals'
    variance changes around an anisotropic ellipsoid), up to 10 the inverse Fisher information times the residuals'
    variance over N − 9, a linear blend between, or the Newey–West sandwich for readings correlated in time;
    9 readings fit exactly: no covariance, identifiable False. standard_errors=False skips its pass over the
    readings. Raises ValueError on a missing field_norm, NaN/Inf, too few rows, planar readings, a non-positive-definite
    result, or a second step that ran away from the readings (not converged, and the readings' misfit to its
    ellipsoid, in their own units, grew by more than runaway_misfit over the first step's; the message names the first
    step's coverage and its farthest reading); a second step that does not converge otherwise is reported in
    summary["converged"] and summary["warnings"]. A cap of directions is answered, flagged not identifiable.
    """
    if units is None:
        units = samples_units(samples)
    field_norm = field_norm_given(samples, field_norm)
    arr = as_samples(samples)
    if field_norm is None:
        raise ValueError("field_norm: required (the known |H|, e.g. from IGRF)")
    options = _core.TwoStepOptions()
    options.units = units_text(units)
    if "serial_correlation" in settings:
        settings = {**settings, "serial_correlation": serial_correlation_mode(settings["serial_correlation"])}
    set_options(options, settings, "twostep")
    if np.ndim(field_norm) > 0:  # each reading's own |H|
        norms = as_field_norms(field_norm, len(arr), "field_norm")
        cal = _with_errors(_core.twostep_norms(arr, norms, options))
        cal.summary["field_norms"] = field_norms_summary(norms)
        said = [field_log_misfit(arr, cal, norms, reading_interval(samples))]
    else:
        options.field_norm = positive_field_norm(field_norm)
        cal = _with_errors(_core.twostep(arr, options))
        said = []
    said = [w for w in said + [scale_words(cal), _few_readings_words(cal.summary, len(arr), 9,
                                                                       bool(cal.summary.get("standard_errors")))] if w]
    cal.summary["warnings"] = list(cal.summary["warnings"]) + said
    return cal


def _few_readings_words(summary: dict, n: int, parameters: int, errors: bool) -> str:
    """With under 30 readings beyond the `parameters` (9 in 3-D, 4 in 2-D), the standard errors come from the
    residuals' own scatter: the errors over them follow Student's t with N − p degrees of freedom (measured:
    consistent with t_{N−9} at small N; in 2-D at N = 5, 30 % of the parameters fell outside ±1.96 standard errors,
    a blind check), which the summary says (residual_dof) with the 95 % factor. `errors`: whether the fit has any."""
    dof = n - parameters
    if not errors or not 0 < dof < 30:
        return ""
    summary["residual_dof"] = dof
    return (f"{n} readings for {parameters} parameters: the standard errors rest on {dof} degrees of freedom, and the "
            f"errors over them follow Student's t — a 95 % interval is ±{stats.t.ppf(0.975, dof):.3g} standard errors "
            "(not ±1.96); more readings narrow both")


def _with_errors(result: dict) -> Calibration:
    """The Calibration, its summary holding the second step's parameters, covariance, standard errors,
    determined/identifiable and serial_correlation under refine's keys (absent for the first step alone)."""
    cal = _calibration(result)
    if "identifiable" in result:  # an exact fit of 9 readings has the verdict and no errors
        parameter_statistics(cal.summary, result, 1)
    return cal
