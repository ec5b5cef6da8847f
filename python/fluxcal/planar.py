"""Planar (2-D) calibration of a magnetometer that only turns about one axis: a vehicle's heading, a biaxial
compass. `fluxcal.calibrate` refuses such readings (a 3-D ellipsoid is not identifiable from one plane of
directions); `calibrate_planar` calibrates the two axes of the turning plane and returns a `Calibration` that
apply, save and export-c use, with the third axis passed through.

Model, in the plane's two coordinates u (the readings' components along the plane axes):

    h = A (u − b),   |h_k| = H_k (the horizontal field: one value, one per reading, or unknown)

A symmetric positive definite (2×2: a_xx, a_xy, a_yy) and b the hard-iron offset: five parameters, as many as an
ellipse has, so a full turn determines them all. A symmetric A is fluxcal's convention (as the 3-D fits'): a field
magnitude cannot see a rotation of h, so the rotation part of the soft iron stays a constant heading offset
(the mounting's alignment), as with any compass swing.

Why the full symmetric matrix and not TWOSTEP 2-D's diagonal gains (seed 000, `fluxcal.twostep_2d`): a vehicle's
soft iron is in general rotated against the sensor axes, which couples x and y; the ellipse the readings trace is
then rotated, and per-axis gains cannot map it to a circle — they leave |h| following twice the heading and a
heading error of the coupling's size. On a 30°-rotated soft iron of gains 1.12/0.90 (σ 0.5 % of H, N = 2000,
tests/python/test_planar.py) the diagonal fit leaves out a cross term of 600 of the symmetric fit's standard
errors, keeps a 6.7 % |h| spread and 3.8° RMS heading error; the symmetric fit lands within a few standard errors
of the truth, 0.5 % spread (the noise) and 0.29° (the noise floor σ/a_min = 0.32°). Like `fluxcal.calibrate`,
shape "auto" (default) refines the circle (one gain), the diagonal and the symmetric matrix and keeps the lowest
BIC, so a sensor without coupling gets no noise in a_xy.

The fit of each shape is the C++ core's `fluxcal::fit_planar` (cpp/include/fluxcal/planar.hpp; its independent
NumPy/SciPy reference is fluxcal.oracle.planar): two starts — the direct ellipse fit (Halir & Flusser 1998, an
ellipse whatever the noise) and TWOSTEP 2-D (`twostep_2d`, which takes a field that changes from reading to
reading); from the one that fits better (the other too when that one does not converge) Levenberg–Marquardt on the
Sampson residual (|h| − H)·|h|/|A h| (the reading-space distance to the ellipse to first order: maximum likelihood
for isotropic Gaussian noise, as fluxcal.refine's magnitude model); then one more solve with the targets raised by
the noise's bias of |h| (≈ σ²‖A‖²_F/(4H): the tangential noise lengthens |h|), which fitting |h| to H would
otherwise put into A; the covariance σ̂²(JᵀJ)⁻¹, or for readings correlated in time (a sensor's own filter, noise
that wanders) the prewhitened Newey–West sandwich, as fluxcal.refine's: with AR(1) noise of φ 0.9 the independent
errors were 4–5× too small (the offset more than 4 of them off in 13 of 20 logs), the sandwich's within 1.0–1.25×.
This module finds the plane, chooses the shape by BIC, checks the arc and the ellipse, compares the offsets fitted
before and after a quarter, a half and three quarters of the log (a hard iron that moved), and words the warnings:
they judge a vehicle's log rather than solve for a calibration.

Which plane (N×3 readings): the readings' scatter's thinnest direction is the plane's normal. Within
`axis_tolerance` degrees of a sensor axis (a level mounting; a soft iron coupling of a few % between the normal
axis and the others tips the plane by as many hundredths of a radian, 5 % ≈ 3°) the other two sensor axes are
calibrated as they are: for a rigid mounting their readings trace an exact ellipse (an affine image of the turning
field's circle), and atan2(h_y, h_x) is the heading up to a constant. Farther from every axis (a tilted mounting)
the calibration is made in the fitted plane, its axes e1, e2 given in the summary, with a warning: the sensor's
own x and y then trace no circle; the heading is the angle of h in (e1, e2). `axes="xy"` forces the sensor axes.

The axis along the normal is not calibrated: turning about it never changes the field's component along it, so
its offset and gain leave no trace in the readings (the offset and the vertical field add into one constant, the
gain scales a constant). The Calibration passes it through scaled by the plane's mean gain √det A (its offset 0):
h along the normal is the raw reading in h's unit, not calibrated. summary["not_calibrated"] says so, with a
warning.
"""
from __future__ import annotations

import numpy as np

from . import _core
from ._arrays import as_field_norms, field_norm_given, first_nonfinite, readings_times, samples_units, units_text
from .bounds import few_dof_words
from .calibration import Calibration
from .outliers import Quadric, far_readings, find_outliers
from .refine import serial_correlation_mode

AXES = "xyz"
SHAPES = ("circle", "diag", "sym")  # as calibrate's sphere, diag, sym: one gain, per-axis gains, symmetric matrix
SHAPE_ALIASES = {"sphere": "circle", "eye": "circle", "diagonal": "diag", "symmetric": "sym"}
PARAMETERS = 5  # b (2) and the symmetric A (3): an ellipse's five
# Readings needed: twice the parameters, so that the noise σ and the standard errors rest on as many spare
# readings as parameters (fewer, and the identifiability check judges nothing).
MIN_READINGS = 2 * PARAMETERS
# Below half a turn the ellipse's parameters are poorly determined by any noise: on a 180° arc the worst standard
# error is 10× a full turn's, on 120° 50×, on 90° 130×, on 60° 800× (the Fisher information of the five
# parameters on an arc, `_arc_inflation`), and the headings outside the arc are extrapolated from the fitted
# ellipse, not measured. A vehicle can always drive one circle: calibration needs the whole compass rose.
MIN_ARC_DEG = 180.0
# A plane fitted to readings whose two smaller spreads are not this many times apart is not the turn's: a blind check's
# 90° turns with 4° of pitch and roll (spreads 10.4, 2.0 and 1.0) had been fitted a plane tilted 20° and "turned
# through 271°" in it (a full circle's are ~1 apart from the widest and ≥ 10× the thinnest)
PLANE_DEFINED = 3.0
SHORT_ARC_BOW = 0.5  # ... when the readings' middle spread is under this share of their widest (an arc — a half
                     # circle's is 0.44 —, not a circle whose tilt wanders widely: that one is fitted, its tilt said)
# Axes asked for whose plane the readings' is tilted beyond this from (nearly edge-on, and nearer another pair's): the
# readings turn in that other plane (a blind check's x, z turn forced into x, y: 88.5°). Below it a tilted circle's
# projection is still an ellipse the fit maps back (headings 0.006 rad RMS at 44–60°, a review)
EDGE_ON = 75.0
# A parameter counts as determined when its standard error is below this fraction of its scale (the mean radius
# for the offset, ‖A‖_F/√2 for matrix entries) — fluxcal.refine's determined_tolerance.
DETERMINED = 0.01
# The fit's residual σ must be small against the ellipse's radius: scatter about a point (a vehicle that did not turn,
# a sensor noisier than 1 % of its readings) gives about 2 (2-D Gaussian scatter's distances from its centre: mean
# 1.25σ, spread 0.65σ), while a sensor that turned gives 50 (a QMC5883L, ~2 % noise) and far more.
MIN_RADIUS_OVER_NOISE = 3.0
# The horizontal |h| spread after the fit above which the readings are said not to fit the planar model (twostep_2d's
# misfit_spread): noise gives σ/H, a sensor's below 2 %.
MISFIT_SPREAD = 0.05
# Tilt while turning: a small tilt α about a horizontal axis moves a reading out of the plane by H·α and along its
# radius in the plane by Z·α with the same sign pattern (δr = −(Z/H)·δn, Z the field along the normal): the radial
# misfit follows the out-of-plane deviation. Said when that line explains at least this share of the misfit's
# variance (and p < 1e-3); noise leaves the two uncorrelated (as twostep.COUPLING_SHARE for twice the heading).
TILT_SHARE = 0.25
# The readings' spread out of the plane over the fit's noise σ above which they are "thick": noise alone gives about
# 1 (the std of N ≥ 10 readings' noise within ±0.25 of it), a tilt while turning more.
THICK_OVER_NOISE = 2.0
# A horizontal field given in a field unit off the readings' radius by more than these factors: the total field
# |F| = H / cos(inclination) instead of its horizontal H (≥ 1.3× for inclinations above 40°, i.e. most of the
# inhabited world), while a sensor's gain and a vehicle's soft iron in a field unit stay within ~±20 %.
TOTAL_FIELD_RATIO = 1.25
UNITS_RATIO = 5.0  # beyond this, another unit (as every fluxcal solver's "check the units")
# The rows _step_or_drift fits its two models to at most (evenly spread in time): enough to tell a step from a drift
STEP_OR_DRIFT_ROWS = 5000
# Whether the offset moved within the log: the offsets fitted to the readings before and after each of SPLITS
# (fractions of the heading turned over the log, in time order) compared by Hotelling's F on 2 degrees of freedom
# (the two sides' covariances Newey–West where the readings are correlated), the smallest p × the splits compared
# (Bonferroni) against MOVED_ALPHA. The misfit check (residual σ against the readings' own noise) misses a move under
# ~10 % of H, which still turns the headings by degrees (a blind check: silent in 8 of 30 logs, 2° RMS). Three places,
# because a move inside one side makes that side's residuals correlated, which widens its errors and can leave it too
# few effective readings: halves alone found a step of 10–20 % of H at 1/4 or 3/4 of the log in a third of a blind
# check's logs, where the split at the step finds it as a step at the middle (bench/RESULTS.md, thirty-fourth session).
SPLITS = (0.25, 0.5, 0.75)
# Strict, since a clean log must stay silent and the sides' Newey–West errors run ~1.2× narrow at a few hundred
# readings, which the F squares: over clean logs with AR(1) noise of φ 0–0.95 (N 300–3000, bench/planar_checks.py)
# p fell under 1e-2 in 2–6 % of logs, under 1e-4 in 3 of 2102, under 1e-5 in 1. A move of the noise's size at the
# middle of 300 white readings is still found in 36 of 40 (38 at 1e-4), one of 2 % of H in every log.
MOVED_ALPHA = 1e-5
# Effective readings (n(1 − ρ)/(1 + ρ) for residuals of lag-1 autocorrelation ρ) per parameter on each side of a
# split: the sides' Newey–West errors are themselves noisy with fewer. With 5, AR(1) noise of φ 0.8–0.9 gave
# 0.5–1 % false alarms at α 1e-4; with 10, φ 0.95 (N 3000) 1 in 138 compared logs at 1e-5; with 15 none of 335
# (φ 0.9–0.95, N 1000–3000), a move of 1 % of H under φ 0.9 still found as often (bench/planar_checks.py).
SIDE_READINGS = 15
# Heading each side of a split must cover. Under MIN_ARC_DEG: a side's offset on 150° has errors 7–22× a full
# turn's (_arc_inflation) but they hold — a single circle split at its middle (each side ~180°, which the
# calibration's own 180° rule had refused by a reading or two) warned in 1 of 1500 clean logs (white and AR(1) noise,
# N 300–3000, at α 1e-4) and found a move of 5 % of H in 111 of 120; a blind check's single circles with a move had
# been silent (99 in 1000 wrong with no warning).
SIDE_ARC_DEG = 150.0


def calibrate_planar(samples, field_norm=None, axes=None, units: str | None = None, shape: str = "auto",
                     min_arc: float = MIN_ARC_DEG, axis_tolerance: float = 5.0, planar_ratio: float = 0.02,
                     max_iterations: int = 100, tolerance: float = 1e-10, field_units: str | None = None,
                     outliers: str = "drop", serial_correlation: str = "automatic", times=None) -> Calibration:
    """Calibrate the two axes of the plane a magnetometer turns in (yaw-only vehicle, biaxial compass).

    samples: N×3 readings (or a fluxcal Recording, whose unit is carried), or N×2 of a biaxial sensor.
    field_norm: the HORIZONTAL field magnitude (its component in the turning plane, e.g. IGRF's H — not the total
    F), one value or one per reading, in the unit h should come out in; with a Recording a column name. None: the
    scale is the fitted mean radius (geometric mean of the semi-axes, det of the plane's A = 1), as
    fluxcal.calibrate without a field norm: the gains are then relative and h is in the readings' unit.
    axes: which sensor axes the plane's are — "xy", "xz", "yz" (or two indices). N×3: None finds them (module
    docstring: the thinnest direction of the readings' scatter); given, those two axes are calibrated whatever the
    plane's tilt. N×2: which axes the two columns are (default "xy"), so that the 3×3 Calibration puts them there.
    shape: "auto" (default: the lowest BIC of "circle", "diag", "sym", as calibrate's shape), "sym", "diag"
    (TWOSTEP 2-D's per-axis gains) or "circle".
    min_arc: degrees of heading the readings must cover (MIN_ARC_DEG; a ValueError below it).
    axis_tolerance: degrees between the fitted normal and a sensor axis within which that axis is the normal.
    planar_ratio: thinnest/widest spread above which N×3 readings are checked for 3-D coverage (calibrate's).
    field_units: the unit of field_norm and of h when it is not the readings' (readings in counts, H in µT): h is
    labelled in it, and field_norm is not judged against the readings' radius as if in their unit.
    outliers: "drop" (default, as fluxcal.calibrate's): gross outliers (I²C glitches reading 0,0,0, ADC rails,
    spikes, bursts of garbage) are screened against the robustly fitted ellipse (fluxcal.outliers: least median of
    squares, then the Bonferroni line at α = 1 %), and readings 10× farther from the readings' median than the median
    reading are left out before the plane is found; summary["outliers"] lists the rows, a warning says how many.
    "keep": every reading is fitted.
    serial_correlation: the standard errors' treatment of readings correlated in time, rows in time order (as
    fluxcal.refine's): "automatic" (default) takes the Newey–West sandwich when the residuals fail a Ljung–Box test
    and it widens an error, or when it widens one ≥ 1.5× with ≥ 10 readings per parameter; "independent" never (for
    rows not in time order: it also leaves out the moved-offset check, whose splits need time order); "newey_west"
    always. summary["serial_correlation"] says what the residuals showed.
    times: each reading's time (seconds; a Recording's own when None), as fluxcal.calibrate's: the readings' own noise
    is taken in their order. The standard errors and the moved-offset check take the rows as they come, in time order
    (as fluxcal.refine).

    Returns a Calibration h = A (m − b): the plane's 2×2 A and offset embedded in 3×3, the normal axis passed through
    (A's row and column for it √det A on the diagonal, its offset 0). Its apply takes N×2 readings (or a biaxial
    Recording) of the plane's axes and returns the plane's two components. summary: method "planar", plane_axes,
    biaxial, normal_axis, plane_basis, plane_normal, plane_tilt_deg, thinnest_over_widest, arc_deg,
    largest_heading_gap_deg, norm_std_over_mean (of the horizontal |h|, against each reading's own H when given per
    reading), norm_std_over_mean_raw (|u| of the raw plane readings), residual_rms (|h| − H, h's unit), noise_sigma
    (Sampson residuals, reading units), readings_noise_sigma and readings_noise_stride (the readings' own noise, for
    readings in time order: pipeline.readings_noise's rule), parameter_names/parameters/standard_errors/determined
    (the plane's, in the sensor axes' names), identifiable (all of them determined), not_calibrated, scale ("given"
    or "relative"), shape and shapes (BIC), start, converged, iterations, readings_extent (the largest |component|
    read, for export-c's range), outliers (with outliers="drop"), serial_correlation (lag1, ljung_box_p, lags: 0 =
    independent readings assumed, inflation, standard_errors_independent), offset_split (the offsets fitted before
    and after SPLITS of the turning, in time order, each split's difference, its standard errors, Hotelling's F and
    p, the smallest p × the splits compared and its split, the change row when a move is said; or compared False and
    the reason: a warning says when the offset moved, p < MOVED_ALPHA), warnings.

    Raises ValueError naming the input on: too few readings, NaN/Inf, readings that hardly change, readings
    that span three dimensions well enough for fluxcal.calibrate to determine every axis, an arc under `min_arc`,
    and readings that trace no ellipse.
    """
    if units is None:
        units = samples_units(samples)
    units = units_text(units)
    field_norm = field_norm_given(samples, field_norm)
    recording = samples  # (its times, once its two field columns replace it below)
    if callable(getattr(samples, "biaxial", None)) and samples.biaxial():  # a Recording of two field columns
        if axes is not None:
            samples.take_axes("".join(AXES[a] for a in _axes(axes)), f"axes={axes!r}")
        axes, samples = samples.biaxial_axes, samples.samples(biaxial=True)
    m = _readings(samples)
    shapes = _shapes(shape)
    for name, value, low in (("min_arc", min_arc, 0.0), ("axis_tolerance", axis_tolerance, 0.0),
                             ("planar_ratio", planar_ratio, 0.0), ("tolerance", tolerance, 0.0)):
        if not (isinstance(value, (int, float, np.integer, np.floating)) and np.isfinite(value) and value > low):
            raise ValueError(f"{name}: {value!r} must be a positive number")
    if not (isinstance(max_iterations, (int, np.integer)) and max_iterations >= 1):
        raise ValueError(f"max_iterations: {max_iterations!r} must be a whole number ≥ 1")
    n = n_given = len(m)
    if n < MIN_READINGS:
        raise ValueError(f"samples: {n} readings; a planar calibration fits {PARAMETERS} parameters (offset and a "
                         f"2×2 matrix) and needs at least {MIN_READINGS} — log more readings while the vehicle turns "
                         "a full circle")
    times = readings_times(recording, times, n)
    norms = None if field_norm is None else as_field_norms(field_norm, n, "field_norm")
    correlation = serial_correlation_mode(serial_correlation)
    if outliers not in ("drop", "keep"):
        raise ValueError(f"outliers: {outliers!r} is not 'drop' (screen the readings, the default) or 'keep'")
    warnings: list[str] = []
    # a spike far off along the normal would tip the plane's scatter, and one in the plane the ellipse: left out first
    far = far_readings(m) if outliers == "drop" else np.zeros(0, dtype=int)
    # readings of exactly 0,0,0 (an I²C glitch) too: off the plane along its normal, where the ellipse's screen never
    # looks, one of 45 had tilted the plane by 5° (3 of 30 simulated logs kept it)
    zeros = np.flatnonzero(~m.any(axis=1)) if outliers == "drop" and m.shape[1] == 3 else np.zeros(0, dtype=int)
    plane = _plane(np.delete(m, np.union1d(far, zeros), axis=0), axes, axis_tolerance, planar_ratio, warnings)
    u = m @ plane["basis"].T  # N×2: the readings' components along the plane's axes
    left_out = _screen(u, norms, far, zeros, max_iterations, tolerance) if outliers == "drop" else None
    if left_out is not None and len(left_out.rows):
        m = np.delete(m, left_out.rows, axis=0)
        norms = None if norms is None else np.delete(norms, left_out.rows)
        times = None if times is None else np.delete(times, left_out.rows)
        n = len(m)
        # found again without them: a burst of readings 2–5× the field, under the far rule, had tipped the plane by
        # 5–15° (a blind check)
        if len(np.setdiff1d(left_out.rows, np.union1d(far, zeros))):
            warnings = []
            plane = _plane(m, axes, axis_tolerance, planar_ratio, warnings)
        u = m @ plane["basis"].T
    if plane["names"] == ("e1", "e2"):  # (a fitted plane: is it the turn's? judged without the screen's outliers)
        _refuse_undefined_plane(m if left_out is not None else np.delete(m, np.union1d(far, zeros), axis=0))
    fit = _fit(u, norms, shapes, max_iterations, tolerance, correlation)
    names = plane["names"]
    h = fit["h"]
    targets = fit["targets"]
    heading = np.arctan2(h[:, 1], h[:, 0])
    arc, gap = _arc(heading)
    radius = fit["radius"]
    if arc < min_arc:
        raise ValueError(f"samples: the readings turn through only {arc:.0f}° of the plane {names[0]}{names[1]} "
                         f"(their largest gap in heading is {gap:.0f}°); on less than {min_arc:g}° the ellipse's "
                         "offset and soft iron trade off against each other and the headings outside the arc are "
                         "extrapolated — turn the vehicle (or the sensor) through at least one full circle")
    if not radius > MIN_RADIUS_OVER_NOISE * fit["sigma"]:
        raise ValueError(f"samples: the readings scatter about their fitted ellipse by {fit['sigma']:.3g} RMS, "
                         f"{100 * fit['sigma'] / radius:.0f} % of its mean radius {radius:.3g}: they trace no "
                         "ellipse — "
                         "a vehicle that barely turned (turn a full circle), or readings disturbed far beyond a "
                         "sensor's noise (a magnet or motor near the sensor, a tumbled or shaken sensor)")
    # (collinear readings, a thin ellipse around them: a blind check's came back with gains of 7.7e5 "converged")
    # (and a tenth of their spread along it: glitches kept by outliers="keep" make a turn's scatter as wide)
    narrow, wide = np.sqrt(np.maximum(np.linalg.eigvalsh(np.cov(u.T)), 0.0))
    scatter = 1.4826 * float(np.median(np.abs(fit["residuals"])))
    if not narrow > MIN_RADIUS_OVER_NOISE * scatter and narrow < 0.1 * wide:
        raise ValueError(f"samples: the readings lie along a line in the plane {names[0]}{names[1]}: they spread "
                         f"{narrow:.3g} (RMS) across it, {narrow / scatter:.2g}× their scatter about the ellipse "
                         f"fitted through them ({scatter:.3g}, robust σ), so they trace no ellipse (a sensor moved "
                         "along one direction, or an axis that did not change) — turn the vehicle (or the sensor) "
                         "through a full circle")
    q = np.linalg.norm(h, axis=1) / targets
    raw = np.linalg.norm(u, axis=1)
    summary = {
        "method": "planar",
        "samples": n,
        "plane_axes": list(names),
        "biaxial": plane["biaxial"],
        "normal_axis": plane["normal_name"],
        "plane_basis": plane["embed"].tolist(),
        "plane_normal": plane["normal"].tolist(),
        "plane_tilt_deg": plane["tilt"],
        "thinnest_over_widest": plane["ratio"],
        "arc_deg": arc,
        "largest_heading_gap_deg": gap,
        "norm_std_over_mean": float(q.std() / q.mean()),
        "norm_std_over_mean_raw": float(raw.std() / raw.mean()),
        "residual_rms": float(np.sqrt(np.mean((np.linalg.norm(h, axis=1) - targets) ** 2))),
        "noise_sigma": fit["sigma"],
        "shape": fit["shape"],
        "shapes": fit["table"],
        "start": fit["start"],
        "parameter_names": _parameter_names(fit["shape"], names),
        "parameters": fit["parameters"].tolist(),
        "standard_errors": fit["standard_errors"].tolist(),
        "determined": [bool(d) for d in fit["determined"]],
        "serial_correlation": fit["serial_correlation"],
        "identifiable": bool(all(fit["determined"])) and not fit["undetermined_larger"],
        "fisher_condition": fit["fisher_condition"],
        "degrees_of_freedom": n - fit["k"],
        "converged": fit["converged"],
        "iterations": fit["iterations"],
        "scale": "given" if norms is not None else "relative",
        # the readings' largest |component|, the axis passed through included (its field, unknown to the plane's
        # model, is often the largest: export-c states an input range that holds it)
        "readings_extent": float(np.max(np.abs(m))),
    }
    if norms is not None and np.ptp(norms) > 0:
        summary["field_norms"] = {"count": n, "min": float(norms.min()), "max": float(norms.max())}
    if plane["biaxial"]:
        summary["not_calibrated"] = {
            "axis": plane["normal_name"],
            "reason": "a biaxial sensor has no such axis: the Calibration passes a third column through (0 for N×2 "
                      "readings), scaled by the plane's mean gain √det A"}
    elif plane["normal_name"] is not None:
        summary["not_calibrated"] = {
            "axis": plane["normal_name"],
            "reason": "the vehicle turns about it: the field's component along it never changes, so its offset and "
                      "gain leave no trace in the readings; it passes through, scaled by the plane's mean gain √det A "
                      "into h's unit (its offset not removed)"}
    if left_out is not None:
        summary["outliers"] = left_out.to_dict()
        warnings += left_out.messages(n + len(left_out.rows))
    stated = units_text(field_units) if field_units else ""
    warnings += _notes(m, summary, plane, fit, norms, units if not stated or stated == units else "", planar_ratio)
    few = few_dof_words(n - fit["k"], f"the {n} readings' distances to the ellipse",
                        "log more readings (a slower turn, or a second one)")
    if few:  # (a blind check: 12 readings, an offset 15 standard errors off, "identifiable yes", nothing said)
        warnings.append(few)
    summary["warnings"] = warnings
    summary["message"] = (f"planar: {n} readings in the plane {'/'.join(names)}, shape {fit['shape']}, "
                          f"{'converged' if fit['converged'] else 'NOT converged'} in {fit['iterations']} iterations, "
                          f"horizontal |h| std/mean {100 * summary['norm_std_over_mean']:.3g} %, arc {arc:.0f}°")
    offset, matrix = _embed(plane, fit["b"], fit["A"])
    what = (f"axis {plane['normal_name']} not calibrated" if plane["normal_name"] in tuple(AXES)
            else "its normal not calibrated")
    model = (f"biaxial {names[0]}, {names[1]} (planar)" if plane["biaxial"] else
             f"planar {''.join(names) if len(''.join(names)) == 2 else '(fitted plane)'}, {what}")
    cal = Calibration(offset=offset, matrix=matrix, field_norm=fit["field_norm"], units=units, model=model,
                      summary=summary)
    if stated:
        cal.field_units = stated
    # the residual σ against the readings' own noise (as calibrate's): a hard iron that moved within the log (a
    # load on the seat) had left a 4.7° heading error with a residual σ 6× the noise, unsaid
    from .diagnose.core import residual_noise  # (here: diagnose imports fluxcal, and fluxcal this module)
    from .pipeline import misfit_said, plausible_field

    said = [misfit_said(cal, residual_noise(u, fit["residuals"], h / np.linalg.norm(h, axis=1, keepdims=True),
                                            times), planar=True), plausible_field(cal, horizontal=True)]
    cal.summary["warnings"] += [w for w in said if w]
    split = _offset_split(u, norms, fit, correlation, max_iterations, tolerance)
    if split.get("change_row") is not None:  # in the rows as given (the outlier screen's left out), and its time
        kept = np.arange(n_given) if left_out is None else np.delete(np.arange(n_given), left_out.rows)
        if times is not None:
            split["change_time"] = float(times[split["change_row"]])
        split["change_row"] = int(kept[split["change_row"]])
    cal.summary["offset_split"] = split
    if offset_moved(cal.summary):  # (kept with the split too: export-c says it, whatever its wording)
        split["said"] = _moved_words(split, names, units)
        if any(w.startswith(LEAVES_PLANE) for w in cal.summary["warnings"]):
            # a mean pitch or roll that differs between the parts shifts the plane's readings as an offset does
            # (a blind check: 2.3° of wander with a constant hard iron was said "a load placed or removed")
            split["said"] += (" — or the tilt said above: a pitch or roll whose mean differs between the two parts "
                              "moves the readings in the plane as an offset does (by the field along the normal "
                              "times the tilt), so the move may be the tilt's")
        cal.summary["warnings"].append(split["said"])
    return cal


def summary_lines(cal: Calibration) -> list[str]:
    """What `fluxcal calibrate --planar` prints after the Calibration itself (str(cal)) and before its warnings:
    the plane, the arc, the horizontal |h| spread before/after, the noise, the standard errors and whether the
    data determine the plane's parameters."""
    from .pipeline import noise_line

    s = cal.summary
    u = f" {cal.units}" if cal.units else ""
    hu = f" {cal.h_units}" if cal.h_units else ""
    names = s["plane_axes"]
    normal = s.get("normal_axis")
    normal_text = ("a biaxial sensor" if s.get("biaxial") else
                   f"normal {normal}, the readings' normal {s['plane_tilt_deg']:.1f}° from it" if normal in tuple(AXES)
                   else f"a fitted plane tilted {s['plane_tilt_deg']:.1f}° from the nearest sensor axis")
    lines = [f"  plane                 {', '.join(names)} ({normal_text}"
             + (f"; thinnest/widest spread {100 * s['thinnest_over_widest']:.2f} %)" if s.get("thinnest_over_widest")
                is not None else ")"),
             f"  samples used          {s['samples']}",
             f"  turned through        {s['arc_deg']:.0f}° of heading "
             f"(largest gap {s['largest_heading_gap_deg']:.0f}°)",
             f"  horizontal |h| std/mean before   {100 * s['norm_std_over_mean_raw']:.3f} %   "
             f"(raw |({', '.join(names)})|)",
             f"  horizontal |h| std/mean after    {100 * s['norm_std_over_mean']:.3f} %"
             + ("   (against each reading's own H)" if "field_norms" in s else ""),
             f"  residual RMS          {s['residual_rms']:.6g}{hu}   (of the corrected |h| − H)",
             f"  residual σ            {s['noise_sigma']:.4g}{u}   (the readings' distance to the fitted ellipse: the "
             "noise plus whatever the model misses)",
             *filter(None, [noise_line(s, u, planar=True)]),
             f"  scale                 " + ("the horizontal field given" if s["scale"] == "given" else
                                           f"relative: |h| = the fitted mean radius {cal.field_norm:.6g}{hu} "
                                           "(no horizontal field given)"),
             f"  shape                 {s['shape']}"
             + (f" (BIC: {_bic_text(s['shapes'])})" if len(s.get("shapes", {})) > 1 else ""),
             f"  method                planar (2-D), {'converged' if s['converged'] else 'NOT converged'} in "
             f"{s['iterations']} iterations"]
    offsets = [se for name, se in zip(s["parameter_names"], s["standard_errors"]) if name.startswith("b_")]
    caveat = "" if s["identifiable"] else "   (NOT the error: the data do not determine every parameter)"
    lines.append(f"  std error of b        {', '.join(f'{v:.3g}' for v in offsets)}{u}{caveat}")
    # judged on the independent-readings errors (as calibrate's printout says beside Newey–West-widened ones)
    widened = (", judged on the Fisher information of independent readings; the std errors above are widened for "
               "readings correlated in time" if s.get("serial_correlation", {}).get("lags", 0) > 0 else "")
    lines.append(f"  identifiable          {'yes' if s['identifiable'] else 'NO'} (the plane's {len(s['parameters'])} "
                 f"parameters{widened})")
    split = s.get("offset_split", {})
    if split.get("compared"):
        best = _best_split(split)
        first, second = (", ".join(f"{v:.4g}" for v in b) for b in best["offsets"])
        moved = offset_moved(s)
        lines.append(f"  offset before/after   ({first}) then ({second}){u}, split at "
                     f"{100 * split['fraction']:.0f} % of the turning: "
                     + (("DRIFTED (a steady drift fits better than one step)" if split.get("kind") == "drift" else
                         f"MOVED, most likely at reading {split['change_row']}") if moved else
                        "the same within their errors") + f" ({_p_text(split)})")
    elif split.get("splits"):
        half = next(sp for sp in split["splits"] if sp["fraction"] == 0.5)
        lines.append(f"  offset before/after   not judged at any split; at the middle, {half['reason']}")
    elif split:
        lines.append(f"  offset before/after   not judged: {split['reason']}")
    if s.get("biaxial"):
        lines.append(f"  third axis            {s['not_calibrated']['axis']}: none (a biaxial sensor)")
    elif "not_calibrated" in s:
        lines.append(f"  not calibrated        {s['not_calibrated']['axis']} (passes through, × the plane's mean gain: "
                     "the turns leave its offset and gain no trace; tumble the sensor for a 3-D calibration)")
    return lines


def _bic_text(table: dict) -> str:
    return ", ".join(f"{name} {row['bic']:.1f}" if "bic" in row else f"{name} failed" for name, row in table.items())


# ---- input ------------------------------------------------------------------------------------------------------

def _readings(samples) -> np.ndarray:
    """N×2 or N×3 finite float rows; ValueError naming `samples` otherwise."""
    if hasattr(samples, "samples") and callable(samples.samples):  # a Recording (its own NaN check names the line)
        samples = samples.samples()
    if np.iscomplexobj(samples):
        raise ValueError("samples: complex numbers; readings are real (pass .real or abs() explicitly)")
    try:
        m = np.asarray(samples, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"samples: not numeric ({exc})") from None
    if m.ndim != 2 or m.shape[1] not in (2, 3):
        transposed = m.ndim == 2 and m.shape[0] in (2, 3) and m.shape[1] > 3
        raise ValueError(f"samples: shape {m.shape}, expected (N, 3) readings of a three-axis sensor or (N, 2) of a "
                         f"biaxial one, one row per reading{' (it looks transposed)' if transposed else ''}")
    bad = first_nonfinite(m)
    if bad is not None:
        row, col = bad
        raise ValueError(f"samples: row {row}, column {col} ({AXES[col]}) is "
                         f"{'NaN' if np.isnan(m[row, col]) else 'infinite'}; remove or repair non-finite readings")
    # the ellipse's moments are fourth powers: at 1e170 an eigen solver failed unnamed, at 1e-170 a division by zero
    largest = np.max(np.abs(m)) if m.size else np.float64(0.0)
    with np.errstate(over="ignore", under="ignore"):
        fourth = largest**4
    if largest > 0 and not (np.isfinite(fourth * len(m)) and fourth >= np.finfo(float).tiny):
        raise ValueError(f"samples: readings up to {largest:.3g}, whose fourth powers (the ellipse's moments) "
                         "are no finite double: give them in another unit (nT, µT, counts)")
    return np.ascontiguousarray(m)


def _shapes(shape) -> tuple:
    name = SHAPE_ALIASES.get(shape, shape) if isinstance(shape, str) else shape
    if name == "auto":
        return SHAPES
    if name not in SHAPES:
        raise ValueError(f"shape: {shape!r} is not one of auto, {', '.join(SHAPES)}")
    return (name,)


def _axes(axes) -> tuple[int, int]:
    """Two distinct sensor-axis indices from "xy", ("x", "y"), (0, 1)…; ValueError naming `axes`."""
    if isinstance(axes, str):
        letters = axes.replace(",", "").replace(" ", "").lower()
        picked = [AXES.find(c) for c in letters]
    else:
        try:
            picked = [AXES.find(a.lower()) if isinstance(a, str) else int(a) for a in axes]
        except (TypeError, ValueError):
            picked = [-1]
    if len(picked) != 2 or any(not 0 <= a < 3 for a in picked) or picked[0] == picked[1]:
        raise ValueError(f"axes: {axes!r} is not two different sensor axes (\"xy\", \"xz\", \"yz\", or two indices "
                         "0–2)")
    return picked[0], picked[1]


# ---- the plane ----------------------------------------------------------------------------------------------------

def _plane(m: np.ndarray, axes, axis_tolerance: float, planar_ratio: float, warnings: list) -> dict:
    """The plane to calibrate in: its 2×3 basis (rows), names, normal and tilt; for N×3 readings checked to be
    planar (and, when they are not, that the 3-D calibration cannot do better)."""
    if m.shape[1] == 2:  # a biaxial sensor: its two columns are the plane's axes, as they are
        i, j = _axes("xy" if axes is None else axes)
        embed = np.zeros((2, 3))
        embed[0, i] = embed[1, j] = 1.0
        return {"basis": np.eye(2), "embed": embed, "names": (AXES[i], AXES[j]), "normal": np.cross(*embed),
                "normal_name": AXES[3 - i - j], "tilt": 0.0, "ratio": None, "biaxial": True}
    centre = m.mean(axis=0)
    lam, vec = np.linalg.eigh(np.cov((m - centre).T))
    lam = np.maximum(lam, 0.0)
    widest = float(np.sqrt(lam[2]))
    level = float(np.linalg.norm(centre))
    if not widest > 0.01 * level:  # as the 3-D fits' "hardly change" (quadric.hpp hardly_turned)
        raise ValueError(f"samples: the readings hardly change (their widest spread is {100 * widest / level:.2g} % "
                         "of their mean magnitude): the sensor did not turn — log while the vehicle turns a full "
                         "circle")
    ratio = float(np.sqrt(lam[0] / lam[2]))
    normal = vec[:, 0]
    k = int(np.argmax(np.abs(normal)))
    normal = normal * np.sign(normal[k])
    tilt = float(np.degrees(np.arccos(min(1.0, abs(normal[k])))))
    if ratio > planar_ratio:
        _refuse_if_3d(m, ratio, planar_ratio)
    if axes is not None:
        i, j = _axes(axes)
        basis = np.zeros((2, 3))
        basis[0, i] = basis[1, j] = 1.0
        k_given = 3 - i - j
        tilt_given = float(np.degrees(np.arccos(min(1.0, abs(normal[k_given])))))
        if k != k_given and tilt_given > EDGE_ON:  # (the readings turn in another pair's plane: no heading in this one)
            pair = "".join(AXES[a] for a in range(3) if a != k)
            raise ValueError(f"axes: the readings turn in the {pair} plane (its normal is {tilt:.0f}° from "
                             f"axis {AXES[k]}, {tilt_given:.0f}° from axis {AXES[k_given]}), not in the "
                             f"{AXES[i]}{AXES[j]} plane asked for: give axes=\"{pair}\" (--planar {pair}), or none "
                             "to find the plane from the readings")
        if tilt_given > axis_tolerance:
            warnings.append(f"the readings' plane is tilted {tilt_given:.1f}° from axis {AXES[k_given]} (axes "
                            f"{AXES[i]}{AXES[j]} were asked for): axes {AXES[i]}, {AXES[j]} are calibrated as they "
                            f"are — atan2(h_{AXES[j]}, h_{AXES[i]}) is the heading up to a constant for a rigid "
                            f"mounting — and the horizontal field also moves axis {AXES[k_given]}, which passes "
                            "through uncalibrated")
        names, normal_name, tilt = (AXES[i], AXES[j]), AXES[k_given], tilt_given
    elif tilt <= axis_tolerance:
        i, j = [a for a in range(3) if a != k]
        basis = np.zeros((2, 3))
        basis[0, i] = basis[1, j] = 1.0
        names, normal_name = (AXES[i], AXES[j]), AXES[k]
    else:
        # A tilted mounting: the fitted plane, e1 the in-plane direction nearest a sensor axis (the one least along
        # the normal), e2 = n × e1, so that (e1, e2, n) is right-handed.
        a = int(np.argmin(np.abs(normal)))
        e1 = np.eye(3)[a] - normal * normal[a]
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(normal, e1)
        basis = np.vstack([e1, e2])
        names, normal_name = ("e1", "e2"), "n"
        warnings.append(f"the readings' plane is tilted {tilt:.1f}° from the nearest sensor axis "
                        f"({AXES[k]}; normal {np.round(normal, 4).tolist()}): a tilted mounting. Calibrated in the "
                        f"fitted plane, axes e1 = {np.round(e1, 4).tolist()}, e2 = {np.round(e2, 4).tolist()} "
                        "(summary plane_basis): the heading is the angle of h in (e1, e2), not atan2(h_y, h_x); "
                        "h along the normal passes through uncalibrated. axes='xy' (--planar xy; or the two axes "
                        "nearest the plane) calibrates two sensor axes as they are instead")
    return {"basis": basis, "names": names, "normal": normal, "normal_name": normal_name, "tilt": tilt,
            "ratio": ratio, "embed": basis, "biaxial": False}


def _refuse_undefined_plane(m: np.ndarray) -> None:
    """A ValueError when the readings (N×3, the outlier screen's left out: a spike tips the scatter) were given a
    fitted plane that they do not define: their two smaller spreads under PLANE_DEFINED× apart and the middle one
    between a line's and SHORT_ARC_BOW of the widest — an arc whose bow does not stand out of the scatter off it."""
    lam = np.maximum(np.linalg.eigvalsh(np.cov((m - m.mean(axis=0)).T)), 0.0)
    across = float(np.sqrt(lam[1] / lam[0])) if lam[0] > 0 else np.inf
    bow = float(np.sqrt(lam[1] / lam[2])) if lam[2] > 0 else 0.0  # (a full circle's ≈ 1, a half's 0.44)
    if across < PLANE_DEFINED and 0.1 < bow < SHORT_ARC_BOW:  # (under 0.1 a line, which the fit's own check names)
        raise ValueError(f"samples: the readings do not define their turning plane — across their widest spread "
                         f"({np.sqrt(lam[2]):.4g}) they spread {np.sqrt(lam[1]):.4g} one way and {np.sqrt(lam[0]):.4g} "
                         f"the other, under {PLANE_DEFINED:g}× apart: an arc too short for its bow to stand out of the "
                         "readings' scatter off the plane (a tilt while turning, the noise). Turn through a full "
                         "circle, or, for a level mounting, give the plane's axes (axes='xy', --planar xy)")


def _refuse_if_3d(m: np.ndarray, ratio: float, planar_ratio: float) -> None:
    """Readings thicker than a plane (thinnest/widest above planar_ratio, calibrate's own limit): when the 3-D
    calibration determines every parameter from them, that is the calibration to make — a ValueError says so.
    When it cannot (a yaw with a few degrees of roll and pitch), the planar one goes on, and a warning about the
    readings leaving the plane follows from the fit (_notes)."""
    from .pipeline import calibrate

    try:
        full = calibrate(m)
    except (ValueError, RuntimeError):
        return
    if full.summary.get("identifiable", False) and full.summary.get("converged", True):
        raise ValueError(f"samples: the readings are not planar (thinnest/widest spread {100 * ratio:.3g} %; a "
                         f"yaw-only turn gives under {100 * planar_ratio:.3g} %) and the 3-D calibration determines "
                         f"every axis from them (|h| std/mean {100 * full.summary['norm_std_over_mean']:.3g} %): use "
                         "fluxcal.calibrate (`fluxcal calibrate FILE` without the planar option)")


# Body frames of a level vehicle whose sensor's x points forward: y right and z down (FRD: aviation's NED body
# frame, ArduPilot and PX4) or y left and z up (FLU: ROS REP 103). The heading, clockwise from magnetic north,
# is atan2(−h_y, h_x) in the first and atan2(h_y, h_x) in the second (the field points north: forward reads
# H cos ψ, right reads −H sin ψ).
HEADING_FRAMES = ("frd", "flu")


def heading(h, frame: str = "frd", declination: float = 0.0) -> np.ndarray:
    """Heading in degrees [0, 360), clockwise from north, of a level sensor's corrected field: `h` N×2 (its x, y)
    or N×3 (x, y used), as a planar calibration of axes x, y gives it. `frame`: "frd" (x forward, y right, z down)
    or "flu" (x forward, y left, z up). `declination` (degrees, east positive): added, for the true heading; 0
    gives the magnetic one. The constant alignment of the sensor on the vehicle is not known to a magnitude fit and
    is not removed (compare with a known heading once)."""
    if frame not in HEADING_FRAMES:
        raise ValueError(f"frame: {frame!r} is not 'frd' (x forward, y right, z down) or 'flu' (x forward, y left, "
                         "z up)")
    h = np.asarray(h, dtype=float)
    if h.shape[-1] not in (2, 3):
        raise ValueError(f"h: shape {h.shape}, expected (N, 2) or (N, 3) corrected fields")
    y = -h[..., 1] if frame == "frd" else h[..., 1]
    return np.mod(np.degrees(np.arctan2(y, h[..., 0])) + float(declination), 360.0)


def plane_axes(cal: Calibration) -> np.ndarray | None:
    """The 2×3 unit vectors of a planar calibration's plane in the sensor axes (h @ plane_axes(cal).T: h's plane
    components, whose magnitude is the horizontal field the calibration is scaled to), or None for a 3-D one."""
    if cal.summary.get("method") != "planar" or "plane_basis" not in cal.summary:
        return None
    return np.asarray(cal.summary["plane_basis"], dtype=float)


def _embed(plane: dict, b: np.ndarray, A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The plane's offset and 2×2 matrix as the 3×3 Calibration's: A3 = P diag(A, g) Pᵀ with P = [e1 e2 n], the
    offset in the plane (none along the normal), so h along the normal is the raw reading's component times the
    plane's mean gain g = √det A: not calibrated, but in h's unit (with the field in µT and readings in counts or
    nT, a pass-through axis in the readings' unit had been labelled in h's)."""
    e = plane["embed"]
    normal = np.cross(e[0], e[1])
    P = np.column_stack([e[0], e[1], normal])
    block = np.eye(3)
    block[:2, :2] = A
    block[2, 2] = np.sqrt(abs(np.linalg.det(A)))
    matrix = P @ block @ P.T
    offset = e.T @ b
    return offset, matrix


def _arc(heading: np.ndarray) -> tuple[float, float]:
    """(degrees of heading covered, largest gap): 360° less the largest gap between the sorted headings."""
    s = np.sort(np.mod(heading, 2 * np.pi))
    gaps = np.diff(np.concatenate([s, [s[0] + 2 * np.pi]]))
    gap = float(np.degrees(gaps.max()))
    return 360.0 - gap, gap


def _arc_inflation(arc_deg: float, n: int = 4000) -> np.ndarray:
    """How much larger each of the five parameters' standard errors is on an arc than on a full turn (a circle,
    evenly spread readings): the ratio behind MIN_ARC_DEG."""
    def information(arc):
        p = np.linspace(0.0, arc, n)
        c, s = np.cos(p), np.sin(p)
        J = np.column_stack([-c, -s, c * c, 2 * s * c, s * s])
        return J.T @ J / n
    return np.sqrt(np.diag(np.linalg.inv(information(np.radians(arc_deg)))) /
                   np.diag(np.linalg.inv(information(2 * np.pi))))


# ---- the fit ------------------------------------------------------------------------------------------------------

# calibrate_planar's shape names → the core's PlanarShape
_CORE_SHAPES = {"circle": "circle", "diag": "diagonal", "sym": "symmetric"}


def _parameter_names(shape: str, names) -> list[str]:
    x, y = names
    return [f"b_{x}", f"b_{y}"] + {"circle": ["a"], "diag": [f"a_{x}{x}", f"a_{y}{y}"],
                                   "sym": [f"a_{x}{x}", f"a_{x}{y}", f"a_{y}{y}"]}[shape]


def _fit(u: np.ndarray, norms, shapes: tuple, max_iterations: int, tolerance: float,
         serial_correlation=_core.SerialCorrelation.independent, start: tuple | None = None) -> dict:
    """Each shape's fit by the C++ core (`fluxcal::fit_planar`, cpp/include/fluxcal/planar.hpp: both starts,
    Levenberg–Marquardt on the Sampson residual, the noise-bias solve, the covariance; its reference is
    fluxcal.oracle.planar), then the BIC choice across shapes and what the summary reads, in u's units.
    serial_correlation: the core's SerialCorrelation (independent for the outlier screen's many subset fits, which
    use no standard error). start: (b, A) to refine from instead of the core's two starts (a whole log's fit for its
    parts: the same answer in fewer passes)."""
    n = len(u)
    u = np.ascontiguousarray(u, dtype=np.float64)
    field_norms = None if norms is None else np.ascontiguousarray(norms, dtype=np.float64)
    fits, table, errors = {}, {}, {}
    for shape in shapes:
        options = _core.PlanarOptions()
        options.shape = getattr(_core.PlanarShape, _CORE_SHAPES[shape])
        options.max_iterations = int(max_iterations)
        options.tolerance = float(tolerance)
        options.serial_correlation = serial_correlation
        if start is not None:
            options.start = _core.PlanarStart(*start)
        # "traces no ellipse" is judged once, on the chosen shape (calibrate_planar): a circle that misfits an
        # elongated ellipse should lose on BIC, not fail the calibration
        options.min_radius_over_noise = 0.0
        try:
            r = _core.fit_planar(u, field_norms, options)
        except ValueError as exc:  # the core names its argument "readings": here they are calibrate_planar's samples
            message = str(exc)
            errors[shape] = "samples: " + message[len("readings: "):] if message.startswith("readings: ") else message
            table[shape] = {"error": errors[shape]}
            continue
        k = len(r["parameters"])
        fits[shape] = r
        table[shape] = {"parameters": k, "rss": float(r["rss"]),
                        "bic": float(n * np.log(max(r["rss"], 1e-300) / n) + k * np.log(n)),
                        "identifiable": bool(r["identifiable"])}
    if not fits:
        if len(set(errors.values())) == 1:  # the same in every shape: the readings, not a shape
            raise ValueError(next(iter(errors.values())))
        raise ValueError("samples: the planar fit failed in every shape ("
                         + "; ".join(f"{k}: {v}" for k, v in errors.items())
                         + "): check the readings for outliers, and that the vehicle turned a full circle")
    chosen = min(fits, key=lambda s: table[s]["bic"])
    r = fits[chosen]
    b, A = np.asarray(r["offset"], dtype=float), np.asarray(r["matrix"], dtype=float)
    targets = np.full(n, float(r["field_norm"])) if norms is None else norms
    result = {"b": b, "A": A, "h": (u - b) @ A.T, "targets": targets, "field_norm": float(r["field_norm"]),
              "radius": float(r["mean_radius"]), "sigma": float(r["sigma"]),
              "parameters": np.asarray(r["parameters"], dtype=float),
              "standard_errors": np.asarray(r["standard_errors"], dtype=float),
              "determined": np.asarray(r["determined"], dtype=bool), "fisher_condition": float(r["fisher_condition"]),
              "covariance": np.asarray(r["covariance"], dtype=float),
              "residuals": np.asarray(r["residuals"], dtype=float), "shape": chosen, "table": table,
              "start": r["start"], "converged": bool(r["summary"]["converged"]),
              "iterations": int(r["summary"]["iterations"]), "k": len(r["parameters"]),
              "serial_correlation": {key: (list(value) if key == "standard_errors_independent" else value)
                                     for key, value in r["serial_correlation"].items()},
              # the core's words when it widened the errors (Newey–West), kept as it says them
              "correlated": [w for w in r["summary"]["warnings"] if "correlated in time" in w]}
    # As calibrate's shape "auto": a smaller shape that wins while the data cannot determine the larger one holds
    # only if the terms it leaves out are zero, which these data cannot test.
    larger = SHAPES[SHAPES.index(chosen) + 1:]
    result["undetermined_larger"] = [s for s in larger if s in table and not table[s].get("identifiable", False)]
    return result


def offset_moved(summary: dict) -> bool:
    """Whether a planar calibration's summary says its offset moved within the log (offset_split, p < MOVED_ALPHA):
    the calibration is of neither part (export-c refuses it without force)."""
    split = summary.get("offset_split", {})
    return bool(split.get("compared")) and split.get("p_value", 1.0) < MOVED_ALPHA


def _offset_split(u: np.ndarray, norms, fit: dict, correlation, max_iterations: int, tolerance: float) -> dict:
    """Whether the offset moved within the log: the chosen shape fitted to the readings before and after each of
    SPLITS (fractions of the net heading turned, else of the rows; the rows taken in time order as the standard errors
    take them), the two offsets compared by
    Hotelling's F; {"compared", "splits" (each {"fraction", "offsets", "difference", "standard_error" of each of its
    components, "statistic", "p_value" (this split's own)} or {"fraction", "compared": False, "reason"}),
    "p_value" (the smallest split's × the number compared: Bonferroni), "fraction" (that split's), "judged" (how many
    splits were compared), "change_row" (when the move is said: where it most likely is, _change_row), "kind" (then:
    "step" or "drift", _step_or_drift), "radius"} — or
    {"compared": False, "reason"} when no split can be judged or the rows are not in time order (serial_correlation
    "independent")."""
    if correlation == _core.SerialCorrelation.independent:
        return {"compared": False, "reason": "serial_correlation 'independent': the rows are not taken in time order"}
    # each split where the vehicle has turned that fraction of its net turn (the fit's headings unwrapped, their
    # running extreme so that the noise's jitter does not count), not of the rows: a single circle turned at an uneven
    # rate had left a side of 112° at the row midpoint and a move unjudged (a blind check: 211 of 367 single circles
    # not compared). Rows when the log turns back and forth (under half a turn net).
    psi = np.unwrap(np.arctan2(fit["h"][:, 1], fit["h"][:, 0]))
    turned = np.maximum.accumulate(np.sign(psi[-1] - psi[0]) * (psi - psi[0]))
    progress = turned if turned[-1] > np.pi else np.arange(len(u), dtype=float)
    cuts = [int(np.clip(np.searchsorted(progress, f * progress[-1]), 1, len(u) - 1)) for f in SPLITS]
    sides = [[_side(u, norms, rows, fit, correlation, max_iterations, tolerance) for rows in
              (slice(0, cut), slice(cut, len(u)))] for cut in cuts]
    splits = [_split(fraction, pair, fit) for fraction, pair in zip(SPLITS, sides)]
    judged = [sp for sp in splits if sp.get("compared", True)]
    if not judged:
        return {"compared": False, "splits": splits,
                "reason": "; ".join(f"at {100 * sp['fraction']:.0f} %: {sp['reason']}" for sp in splits)}
    best = min(judged, key=lambda sp: sp["p_value"])
    p = min(1.0, best["p_value"] * len(judged))
    result = {"compared": True, "splits": splits, "fraction": best["fraction"], "judged": len(judged),
              "radius": fit["radius"], "p_value": p}
    if p < MOVED_ALPHA:
        change = _change_row(u, fit, best["offsets"])
        # once more from the offsets on either side of that row: the split's sides held a few of the other's readings
        at = [_side(u, norms, rows, fit, correlation, max_iterations, tolerance)
              for rows in (slice(0, change), slice(change, len(u)))]
        offsets = best["offsets"]  # (a side at the change row too short to refit, as a warm-up's first one)
        if all("fit" in side for side in at):
            offsets = [side["fit"]["b"] for side in at]
            change = _change_row(u, fit, offsets)
        result["kind"] = _step_or_drift(u, fit, [change, *cuts], offsets)
        result["change_row"] = change
    return result


def _step_or_drift(u: np.ndarray, fit: dict, changes, offsets) -> str:
    """"step" or "drift": whether one step (at the first of `changes`, the change row, or at another of them, the
    splits' rows: in a single circle the change row can miss) or an offset that drifts through the rows — linearly,
    or settling as a warm-up does (1 − e^(−s/τ), τ a twentieth to two fifths of the log) — fits the readings better,
    each fitted by least squares (SciPy) with its own symmetric matrix — 7 parameters each: the offset at the start,
    its change (at the step, or over the course), the matrix — against the fit's targets, on at most
    STEP_OR_DRIFT_ROWS rows evenly spread in time. (A wandering offset got the step's remedy, calibrate the two parts
    apart, in 88 % of such logs; a drift wants the warm-up left out or shorter logs. Judged with the whole log's
    matrix, a drift over two turns looked like a step: the matrix had taken part of it.)"""
    from scipy.optimize import least_squares

    n = len(u)
    rows = np.unique(np.linspace(0, n - 1, min(n, STEP_OR_DRIFT_ROWS)).astype(int))
    x, targets = u[rows], fit["targets"][rows]
    b0, b1 = (np.asarray(b, dtype=float) for b in offsets)
    A = fit["A"]
    start = np.concatenate([b0, b1 - b0, [A[0, 0], A[0, 1], A[1, 1]]])
    s = rows / max(n - 1, 1)
    first = int(np.searchsorted(rows, changes[0]))

    def cost(course):
        def residuals(p):
            a = np.array([[p[4], p[5]], [p[5], p[6]]])
            return np.linalg.norm((x - p[:2] - np.outer(course, p[2:4])) @ a.T, axis=1) - targets
        x0 = start.copy()  # the same means on either side of the change row as the offsets given
        m0, m1 = course[:first].mean() if first else 0.0, course[first:].mean()
        if m1 != m0:
            x0[2:4] = (b1 - b0) / (m1 - m0)
            x0[:2] = b0 - m0 * x0[2:4]
        return float(np.sum(least_squares(residuals, x0, method="lm").fun ** 2))

    step = min(cost((rows >= c).astype(float)) for c in dict.fromkeys(int(c) for c in changes))
    drifts = [s] + [1.0 - np.exp(-s / tau) for tau in (0.05, 0.1, 0.2, 0.4)]
    return "drift" if min(cost(course) for course in drifts) < step else "step"


def _best_split(split: dict) -> dict:
    """The split of _offset_split whose p is the smallest."""
    return next(sp for sp in split["splits"] if sp["fraction"] == split["fraction"])


def _side(u: np.ndarray, norms, rows: slice, fit: dict, correlation, max_iterations: int, tolerance: float) -> dict:
    """One side of a split: its fit ({"fit", "lag1"}), or {"refused": why} when it cannot determine its offset (under
    SIDE_ARC_DEG of heading, an offset not determined, a fit that fails)."""
    # the heading the side turned through, by the whole log's fit: a side's own fit of a short arc can land far off
    # (a clean single circle's last quarter, 37° of heading, fitted an offset 23 µT off that saw ≥ 150° of its own
    # headings, and "moved" was said at p = 0: a blind check)
    h = fit["h"][rows]
    arc, _ = _arc(np.arctan2(h[:, 1], h[:, 0]))
    if arc < SIDE_ARC_DEG:
        return {"refused": f"turn through {arc:.0f}° of heading (under {SIDE_ARC_DEG:g}°)"}
    try:
        part = _fit(u[rows], None if norms is None else norms[rows], (fit["shape"],), max_iterations, tolerance,
                    correlation, start=(fit["b"], fit["A"]))
    except ValueError as exc:
        return {"refused": f"fit no ellipse ({exc})"}
    if not all(part["determined"][:2]):
        return {"refused": "do not determine their offset (its standard error above 1 % of the radius)"}
    return {"fit": part, "lag1": float(np.nan_to_num(part["serial_correlation"]["lag1"], nan=1.0))}


def _split(fraction: float, sides: list, fit: dict) -> dict:
    """One split of _offset_split from its two sides (_side): the offsets' difference and its F test, or
    {"compared": False, "reason"} when a side was refused or holds fewer effective readings than SIDE_READINGS per
    parameter (AR(1)'s count n(1 − ρ)/(1 + ρ), ρ the noise's lag-1 autocorrelation: the lesser of the two sides'
    residuals'. A move inside one side correlates that side's residuals too, a step under the noise: judged by its
    own, a move at 60 % of a log was left unjudged, every split having it in one side.)"""
    from scipy.stats import f as f_distribution

    for name, side in zip(("before", "after"), sides):
        if "refused" in side:
            return {"fraction": fraction, "compared": False, "reason": f"the readings {name} {side['refused']}"}
    rho = float(np.clip(min(side["lag1"] for side in sides), 0.0, 0.999))
    effective = []
    for name, side in zip(("before", "after"), sides):
        effective.append(len(side["fit"]["h"]) * (1 - rho) / (1 + rho))
        if effective[-1] < SIDE_READINGS * side["fit"]["k"]:
            return {"fraction": fraction, "compared": False,
                    "reason": f"the readings {name} hold {effective[-1]:.0f} effective readings (the noise's lag-1 "
                              f"autocorrelation {rho:.2f}), under the {SIDE_READINGS * side['fit']['k']} a comparison "
                              "needs: log longer (more turns), or at a lower rate"}
    offsets = [side["fit"]["b"] for side in sides]
    d = offsets[1] - offsets[0]
    c = sides[0]["fit"]["covariance"][:2, :2] + sides[1]["fit"]["covariance"][:2, :2]
    statistic = float(d @ np.linalg.pinv(c) @ d) / 2
    if not np.isfinite(statistic):
        return {"fraction": fraction, "compared": False, "reason": "the two offsets' errors are not finite"}
    return {"fraction": fraction, "offsets": [b.tolist() for b in offsets], "difference": d.tolist(),
            "standard_error": np.sqrt(np.diag(c)).tolist(), "statistic": statistic,
            "p_value": float(f_distribution.sf(statistic, 2, sum(effective) - 2 * fit["k"]))}


def _change_row(u: np.ndarray, fit: dict, offsets) -> int:
    """The row where the offset most likely moved from the first of `offsets` to the second: the k that minimises the
    misfit of rows before k to the first offset and of the rest to the second (the fit's matrix and targets; a
    change point between two known models, by prefix sums). The splits only test a move; this says where it is."""
    A, targets = fit["A"], fit["targets"]
    misfit = [(np.linalg.norm((u - np.asarray(b)) @ A.T, axis=1) - targets) ** 2 for b in offsets]
    before_minus_after = np.cumsum(misfit[0] - misfit[1])[:-1]  # k = 1 … N − 1: a reading on either side
    return int(np.argmin(before_minus_after)) + 1


def _moved_words(split: dict, names, units: str) -> str:
    unit = f" {units}" if units else ""
    best = _best_split(split)
    d, se = best["difference"], best["standard_error"]
    moved = ", ".join(f"{v:+.3g} ± {e:.2g}" for v, e in zip(d, se))
    at = f"reading {split['change_row']}" + (f" (t = {split['change_time']:.6g} s)" if "change_time" in split else "")
    if split.get("kind") == "drift":
        return (f"the offset drifted through the log: the offsets fitted before and after "
                f"{100 * split['fraction']:.0f} % of the turning differ by ({moved}){unit} in {names[0]}, {names[1]} "
                f"(F {best['statistic']:.3g}, {_p_text(split)}), and a steady drift fits the readings better than one "
                f"step, so the calibration is of no moment of it and the headings are off by up to "
                f"{np.degrees(np.hypot(*d) / split['radius']):.2g}° — a sensor warming up, a field or a load that "
                "changes slowly (a battery discharging, a motor heating): log once the drift has settled (after the "
                "warm-up), or in shorter logs")
    return (f"the offset moved within the log, most likely at {at}: the offsets fitted before and after "
            f"{100 * split['fraction']:.0f} % of the turning differ by ({moved}){unit} in {names[0]}, {names[1]} "
            f"(F {best['statistic']:.3g}, {_p_text(split)}), so the calibration is of neither and the headings are off "
            f"by up to {np.degrees(np.hypot(*d) / split['radius']):.2g}° — a load placed or removed, a battery or "
            f"board moved, a device switched on, or an offset that drifts (a sensor warming up, a wandering field): "
            f"calibrate the readings before and after {at} apart, or log again with nothing aboard changing")


def _p_text(split: dict) -> str:
    """The moved-offset check's p as the printout and the warning say it: Bonferroni over the splits judged, and the
    line."""
    p = split["p_value"]
    return (f"p {'< 1e-16' if p < 1e-16 else f'= {p:.2g}'} over the {split['judged']} split"
            f"{'s' if split['judged'] > 1 else ''} judged; said below {MOVED_ALPHA:g}")


def _screen(u: np.ndarray, norms, far: np.ndarray, zeros: np.ndarray, max_iterations: int, tolerance: float):
    """The rows to leave out (fluxcal.outliers.Outliers): those the outlier screen flags off the ellipse of the plane
    coordinates `u` (its fits are this module's symmetric one), and the `far` and `zeros` (0,0,0) ones found before
    the plane (a spike along the normal leaves no trace in u)."""
    from dataclasses import replace

    def ellipse(x, x_norms):
        try:
            r = _fit(x, x_norms, ("sym",), max_iterations, tolerance)
        except (ValueError, RuntimeError):
            return None
        return Quadric(offset=r["b"], matrix=r["A"])

    changing = norms is not None and np.ptp(norms) > 0  # (one H given is every reading's: no log of |field| to judge)
    screen = find_outliers(u, field_norms=norms if changing else None, ellipse=ellipse)
    if not screen.robust_sigma * MIN_RADIUS_OVER_NOISE < 1:  # scatter about a point: no ellipse to judge by, and
        screen = replace(screen, rows=np.zeros(0, dtype=int), kinds={}, stretches=[])  # the fit says so
    for kind, rows in (("far", np.setdiff1d(far, zeros)), ("zero", zeros)):
        extra = np.setdiff1d(rows, screen.rows)
        if len(extra):
            screen = replace(screen, rows=np.union1d(screen.rows, extra), screened=True,
                             kinds={**screen.kinds, kind: screen.kinds.get(kind, 0) + len(extra)})
    return screen


# ---- what the summary says ---------------------------------------------------------------------------------------

def _notes(m: np.ndarray, summary: dict, plane: dict, fit: dict, norms, units: str, planar_ratio: float) -> list[str]:
    from .io.columns import FIELD_UNITS

    notes = []  # (the axis along the normal, not calibrated by design, is summary["not_calibrated"], printed)
    notes += fit["correlated"]
    if not summary["converged"]:
        notes.append(f"the planar fit did not converge in {summary['iterations']} iterations: the result is the last "
                     "iterate — check the readings for outliers and that the vehicle turned a full circle")
    if fit["undetermined_larger"] and all(fit["determined"]):
        summary["identifiable_if"] = fit["shape"]
        notes.append(f"not identifiable without an assumption: the data do not determine shape "
                     f"{' or '.join(fit['undetermined_larger'])}, so shape {fit['shape']!r} won by fit alone, and its "
                     f"answer holds only if the sensor has none of the terms it leaves out — which these data cannot "
                     "test; turn through a full circle, evenly")
    elif not summary["identifiable"]:
        bad = [nm for nm, d in zip(summary["parameter_names"], summary["determined"]) if not d]
        notes.append(f"not identifiable: the data do not determine {', '.join(bad)} (standard error above "
                     f"{100 * DETERMINED:g} % of its scale); turn through more of the circle, more evenly, or log "
                     "more readings")
    if plane.get("ratio") is not None:
        thickness = _out_of_plane(m, plane, fit, planar_ratio)
        if thickness:
            notes.append(thickness)
    if summary["norm_std_over_mean"] > MISFIT_SPREAD:
        notes.append(f"the readings do not fit the planar model: the horizontal |h| scatters by "
                     f"{100 * summary['norm_std_over_mean']:.3g} % after the fit (more than {100 * MISFIT_SPREAD:g} %, "
                     "far beyond a sensor's noise): a tilt while turning, a disturbance (a magnet, a motor, a current "
                     "near the sensor), or a horizontal field that changes — fluxcal diagnose looks for the cause")
    if norms is not None and units in set(FIELD_UNITS.values()) - {"counts"}:
        ratio = float(np.mean(norms)) / _semi_axes_mean(fit)
        if ratio > UNITS_RATIO or ratio < 1 / UNITS_RATIO:
            notes.append(f"field_norm {np.mean(norms):.4g} is {ratio:.3g} times the radius of the readings' ellipse "
                         f"({_semi_axes_mean(fit):.4g} {units}): field_norm is probably in another unit than the "
                         "readings — check the units")
        elif ratio > TOTAL_FIELD_RATIO:
            notes.append(f"field_norm {np.mean(norms):.4g} is {ratio:.3g} times the radius of the readings' ellipse "
                         f"({_semi_axes_mean(fit):.4g} {units}): is it the total field? The planar calibration needs "
                         "the horizontal component H = F·cos(inclination) (IGRF/WMM give H)")
    return notes


def _semi_axes_mean(fit: dict) -> float:
    """The readings' ellipse's geometric-mean radius, reading units: |h| / det(A)^(1/2) for the fitted A."""
    return float(np.mean(fit["targets"]) / np.sqrt(abs(np.linalg.det(fit["A"]))))


LEAVES_PLANE = "the readings leave the turning plane by"  # (how _out_of_plane's warning starts)


def _out_of_plane(m: np.ndarray, plane: dict, fit: dict, planar_ratio: float) -> str | None:
    """A warning when N×3 readings leave the turning plane: thicker than calibrate's planar limit (and the 3-D fit
    could not determine them, or _refuse_if_3d would have refused), or a radial misfit that follows the
    out-of-plane deviation (TILT_SHARE): the sensor tilts while it turns."""
    from scipy import stats

    n = len(m)
    normal = plane["normal"]
    dn = (m - m.mean(axis=0)) @ normal                       # out of the plane, reading units
    e = fit["residuals"]                                     # radial misfit in the plane, reading units
    X = np.column_stack([np.ones(n), dn])
    beta, *_ = np.linalg.lstsq(X, e, rcond=None)
    rss1, rss0 = float(np.sum((e - X @ beta) ** 2)), float(np.sum((e - e.mean()) ** 2))
    share = 1.0 - rss1 / rss0 if rss0 > 0 else 0.0
    p = float(stats.f.sf((rss0 - rss1) / (rss1 / (n - 2)), 1, n - 2)) if rss1 > 0 else 0.0
    tilted = p < 1e-3 and share >= TILT_SHARE
    # thick only when the spread out of the plane clearly exceeds the noise, which alone gives about σ: a flat log
    # of a noisy chip in a weak horizontal field (σ 0.4 µT, H 15 µT) is thicker than planar_ratio by noise alone
    thick = plane["ratio"] > planar_ratio and float(dn.std()) > THICK_OVER_NOISE * fit["sigma"]
    if not (tilted or thick):
        return None
    spread = float(dn.std())
    tilt = float(np.degrees(spread / fit["radius"]))         # δn = H·α: about the tilt's RMS about one axis
    why = []
    if thick:
        why.append(f"thinnest/widest spread {100 * plane['ratio']:.3g} %, above the {100 * planar_ratio:g} % of a "
                   "turn about one axis, and too little for a 3-D calibration to determine every axis")
    if tilted:
        why.append(f"the radial misfit follows the deviation from the plane ({100 * share:.0f} % of its variance, "
                   f"slope {beta[1]:.2g}: the field along the normal over the horizontal one, as a tilt makes it)")
    return (f"{LEAVES_PLANE} {spread:.3g} RMS ({'; '.join(why)}): the sensor tilts while "
            f"it turns (roll, pitch: about {tilt:.2g}° RMS) — through a tilt the field along the normal moves the "
            "plane's axes, which the planar calibration cannot remove, and the headings carry it. Level the sensor "
            "(a gimbal; an accelerometer's tilt compensation), calibrate from the level stretches, or tumble it for a "
            "3-D calibration")
