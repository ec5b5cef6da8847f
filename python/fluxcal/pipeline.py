"""fluxcal.calibrate: one call that picks the right solver for the data it is given."""
from __future__ import annotations

import os
import re
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from . import _core
from ._arrays import (as_samples, held_copies, samples_units, positive_field_norm, readings_times, repeated_blocks, repeated_words,
                      sample_names)
from .calibration import TESLA_PER_UNIT, Calibration, scale_words
from .ellipsoid import fit_ellipsoid
from .outliers import DOMINATING, MIN_SAMPLES, far_readings, find_outliers, held_still, rail_values, rail_words
from ._arrays import as_field_norms, changing_field, field_norm_given
from ._axis_weights import sampson, weights_of
from .refine import SHAPES, fit_vector, refine, shape_name
from .twostep import FIELD_LOG_WORDS, field_log_misfit, reading_interval, twostep

METHODS = ("auto", "vector", "als", "ls", "als+refine", "twostep")
OUTLIERS = ("drop", "keep")
# From this many readings shape="auto" refines its shapes in threads (the solver releases the GIL; each fit is
# the same as alone). Below it the three fits take a few ms together, less than the threads would save.
PARALLEL_SHAPES = 5000
# Settings of the algebraic ellipsoid fit (EllipsoidOptions); calibrate's other settings are the refinement's.
ELLIPSOID_SETTINGS = frozenset(name for name in dir(_core.EllipsoidOptions())
                               if not name.startswith("_")) - {"field_norm", "method", "units"}


# How every solver's "the field norm is in another unit" warning ends (cpp/src/checks.hpp units_mismatch).
UNITS_WORDS = " of the readings — check the units"


def usable_cpus() -> int:
    """The CPUs this process may run on (a container's or taskset's share, not the host's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def calibrate(samples, method: str = "auto", field_norm: float | None = None, reference=None,
              units: str | None = None, loss: str = "none", outliers: str = "drop", shape: str = "auto",
              times=None, **settings) -> Calibration:
    """Calibrate a three-axis magnetometer.

    method "auto": with `reference` (true field per reading, sensor frame) the vector fit
    (fluxcal.fit_vector, a full 3×3 matrix) — a Recording with attitude and local field columns gives it
    (Recording.reference_field), as the command line does; otherwise the consistent ellipsoid fit (ALS) refined by
    maximum likelihood (fluxcal.refine) — the estimate that reaches the Cramér–Rao bound. The result's
    summary says what ran ("method") and, after a refinement or a vector fit, whether the data determine
    every parameter ("identifiable"); when they do not (yaw-only turns, small tilts), the summary warns and
    names the remedy instead of passing a confident 3-D answer off as one. Other methods: "vector", "als",
    "ls", "als+refine", "twostep" (Alonso & Shuster's TWOSTEP, fluxcal.twostep: needs the known `field_norm`;
    settings as fluxcal.twostep's). `loss` ("none", "huber", "cauchy") applies to the refinement.
    `field_norm` may be one value per reading (a field that changes while the sensor turns: a scalar
    magnetometer's log beside it, an observatory's F): the refinement then fits each |h_i| to its own
    (fluxcal.refine's field_norms), starting from TWOSTEP with them; "twostep" takes them too. With a Recording,
    `field_norm="F"` names its column (converted to the readings' unit when both state a field unit).

    outliers "drop": the readings are first screened for gross outliers (I²C glitches reading 0,0,0, ADC
    rails, spikes; fluxcal.outliers) — off the ellipsoid, or with `reference` off the vector model — and
    fitted without them; summary["outliers"] lists the rows and a warning says how many. Readings with an axis on
    a rail (saturated: its extreme value far more often than any beside it, as `fluxcal calibrate` judges it) are
    left out before that screen, with a warning naming the axis, the value and how many. "keep" fits every reading
    (a rail is still warned of).

    shape (the refinement's matrix, as MATLAB magcal's fit types): "sym" (symmetric soft iron, 9
    parameters), "diag" (axis scales, 6), "sphere" (one scale, 4; magcal's "eye"), or "auto" (default, as
    magcal's): each is refined and the one with the lowest BIC = N ln(RSS/N) + k ln N is kept, determined
    or not (a smaller shape the data reject would be biased); summary["shapes"] holds every shape's BIC,
    RSS and whether it was determined. A sensor without soft-iron coupling then gets no noise in its
    off-diagonal terms; on the real recordings in ../shared/data/real "sym" wins by thousands. The vector
    fit's W is always full.

    times: each reading's time (seconds; a Recording's own when None), for judging the residuals against the
    readings' own noise in time order (summary["readings_noise_sigma"]); None and no Recording: row order.

    settings: the ellipsoid fit's (planar_ratio, poor_coverage_ratio, … as fluxcal.fit_ellipsoid) go to the
    algebraic fit, the others (max_iterations, serial_correlation, … as fluxcal.refine) to the refinement
    or the vector fit. A setting for a step the method does not run is an error, not silently dropped.
    """
    if method not in METHODS:
        raise ValueError(f"method: {method!r} is not one of {', '.join(METHODS)}")
    if outliers not in OUTLIERS:
        raise ValueError(f"outliers: {outliers!r} is not one of {', '.join(OUTLIERS)}")
    shape = shape if shape == "auto" else shape_name(shape)
    restricted = shape not in ("sym", "auto")
    if restricted and (method in ("vector", "ls", "als", "twostep") or (method == "auto" and reference is not None)):
        fits = {"ls": "the algebraic ellipsoid", "als": "the algebraic ellipsoid",
                "twostep": "a symmetric matrix"}.get(method, "a full W")
        given = " with a reference" if method == "auto" else ""
        raise ValueError(f"shape: {shape!r} restricts the refinement's matrix; method {method!r}{given} fits "
                         f"{fits} (use method 'als+refine', or shape 'sym')")
    # a Recording with attitude and the local field (the airborne layout) gives the vector fit its reference, as
    # `fluxcal calibrate` does (it had fitted magnitudes only from Python, in silence)
    recorded = (samples.reference_field() if reference is None and method in ("auto", "vector")
                and hasattr(samples, "reference_field") else None)
    if recorded is not None:
        reference = recorded
    if "noise_sigma" in settings and (reference is not None or method not in ("auto", "als+refine", "twostep")
                                      or (method == "twostep" and np.size(settings["noise_sigma"]) != 1)):
        why = ("the vector fit fits each axis's row apart, so per-axis noise weighs nothing" if reference is not None
               else "twostep takes one σ of its own" if method == "twostep" else f"method {method!r} has no refinement")
        raise ValueError(f"noise_sigma: three σ weight the axes of the magnitude model's refinement (method 'auto' or "
                         f"'als+refine', no reference); {why}")
    if units is None:
        units = samples_units(samples)
    field_norm = field_norm_given(samples, field_norm)
    if field_norm is not None and np.ndim(field_norm) == 0:  # (the core's refusal named EllipsoidOptions)
        field_norm = positive_field_norm(field_norm)
    m = as_samples(samples)
    dead = [k for k in range(m.shape[1]) if len(m) >= 10 and np.ptp(m[:, k]) == 0]  # (fewer: too few is said)
    if len(dead) == m.shape[1]:
        raise ValueError(f"samples: all {len(m)} readings are the same ({', '.join(f'{v:g}' for v in m[0])}): a "
                         "sensor that is stuck, not updating, or was never turned")
    if dead:  # (a blind check's constant axis was refused as "nearly in one plane … turn the sensor")
        k = dead[0]
        raise ValueError(f"samples: the readings lie in one plane: axis {'xyz'[k] if m.shape[1] == 3 else k} reads "
                         f"{m[0, k]:g} in every one of the {len(m)}: a dead axis, or a column that is not the "
                         "magnetometer's? (a field turned through directions moves every axis; a two-axis sensor: "
                         "calibrate --planar)")
    vector = method == "vector" or (method == "auto" and reference is not None)
    if "field_norms" in settings:  # (refine's keyword: here it would pass the outlier screen and its dropped rows)
        raise ValueError("field_norms: give each reading's |field| to calibrate as field_norm= (one value, or one "
                         "per reading)")
    field_norms = None
    if field_norm is not None and np.ndim(field_norm) > 0:  # each reading's own |h| (a field that changes)
        field_norms = as_field_norms(field_norm, len(m), "field_norm")
        if vector or method in ("ls", "als"):
            raise ValueError(f"field_norm: one magnitude per reading is the refinement's and TWOSTEP's (method "
                             f"'auto', 'als+refine' or 'twostep', without a reference); method {method!r}"
                             f"{' with a reference' if vector and method == 'auto' else ''} takes one value")
        field_norm = float(np.mean(field_norms))
    if method == "twostep":
        if field_norm is None:
            raise ValueError("field_norm: method 'twostep' needs the known field magnitude (--field-norm; e.g. from IGRF, in the "
                             "unit h should come out in)")
        if loss != "none":
            raise ValueError(f"loss: {loss!r} is the refinement's; method 'twostep' has no robust loss")
    start_settings = ({} if method == "twostep" else
                      {k: settings.pop(k) for k in list(settings) if k in ELLIPSOID_SETTINGS})
    _check_steps(method, vector, start_settings, settings, loss)
    if vector:
        if reference is None:
            raise ValueError("reference: the vector method needs the true field of each reading")
        reference = as_samples(reference, "reference")
        if len(reference) != len(m):  # (as the fit says it, before rows are left out of both and the counts change)
            raise ValueError(f"reference: {len(reference)} rows, samples have {len(m)}")
        if reference.shape == m.shape and np.array_equal(reference, m):  # a perfect fit of nothing, 1e-29 errors
            raise ValueError("reference: it is the readings themselves (the same columns given twice?); give the "
                             "true field of each reading (e.g. IGRF rotated by the attitude)")
    railed, said_rails = _railed(m, sample_names(samples), outliers == "drop")
    screened = np.flatnonzero(~railed)  # the rows the outlier screen judges: a clipped reading is known already
    left_out = find_outliers(m[screened], reference[screened] if vector else None,
                             field_norms=None if field_norms is None else field_norms[screened]
                             ) if outliers == "drop" else None
    all_readings = m
    times = readings_times(samples, times, len(m))
    if left_out is not None:  # its rows and stretches in rows of all the readings, as summary["outliers"] lists them
        left_out.rows = screened[left_out.rows]
        left_out.stretches = [(int(screened[a]), int(screened[b]), z) for a, b, z in left_out.stretches]
    dropped = np.union1d(np.flatnonzero(railed), [] if left_out is None else left_out.rows).astype(int)
    if len(dropped):
        times = None if times is None else np.delete(times, dropped)
        m = np.delete(m, dropped, axis=0)
        if vector:
            reference = np.delete(reference, dropped, axis=0)
        if field_norms is not None:
            field_norms = np.delete(field_norms, dropped)
    if vector:
        cal = fit_vector(m, reference, units=units, loss=loss, **settings)
    elif method in ("ls", "als"):
        cal = fit_ellipsoid(m, field_norm=field_norm, units=units, method=method, **start_settings)
        cal.summary["method"] = method
    elif method == "twostep":
        cal = twostep(m, field_norm if field_norms is None else field_norms, units=units, **settings)
        cal.summary["method"] = "twostep"
        said = _twostep_bias(cal, m, field_norms)
        if said:
            cal.summary["warnings"] = list(cal.summary["warnings"]) + [said]
    else:
        start, judged = (_screened_start(m, field_norm, field_norms, units, start_settings, loss)
                         if loss != "none" and outliers == "keep" else
                         (_magnitude_start(m, field_norm, field_norms, units, start_settings), None))
        cal = _refine_shape(start, m, shape, judged=judged, loss=loss, field_norms=field_norms, **settings)
        cal.summary["method"] = "als+refine"
        cal.summary["start"] = start.model  # "ellipsoid_als", or "twostep" in a field that changes (_magnitude_start)
        cal.summary["coverage_ratio"] = start.summary["coverage_ratio"]
        said_units = any(UNITS_WORDS in w for w in start.summary["warnings"])  # (the refinement would say it again)
        cal.summary["warnings"] = list(start.summary["warnings"]) + [
            w for w in cal.summary["warnings"] if w not in start.summary["warnings"]
            and not (said_units and UNITS_WORDS in w)]
        if start.summary.get("noise_sigma"):
            cal.summary["als_noise_sigma"] = start.summary["noise_sigma"]
        if field_norms is not None:  # said of the refined fit, not of its TWOSTEP start
            said = field_log_misfit(m, cal, field_norms, reading_interval(samples))
            cal.summary["warnings"] = [w for w in cal.summary["warnings"] if not w.startswith(FIELD_LOG_WORDS)] + (
                [said] if said else [])
    ignored = []
    if vector and field_norm is not None:
        scale = float(np.mean(np.linalg.norm(reference, axis=1)))
        ignored.append(f"field_norm {field_norm:g} is not used: the reference vectors set the scale "
                       f"(their mean |r| is {scale:.6g})")
    if not vector and reference is not None:
        ignored.append(f"reference is not used by method {method!r}, which fits magnitudes only; "
                       "method='auto' or 'vector' uses it")
    if ignored:
        cal.summary["warnings"] = list(cal.summary["warnings"]) + ignored
    if recorded is not None:
        cal.metadata["reference"] = "attitude pitch,roll,yaw and local field igrf_n,igrf_e,igrf_d of the recording"
        if samples.reference_units() != units:  # counts fitted to a field model in nT: h is in nT
            cal.field_units = samples.reference_units()
    if left_out is not None:
        cal.summary["outliers"] = left_out.to_dict()
        cal.summary["warnings"] = list(cal.summary["warnings"]) + left_out.messages(len(all_readings))
        if railed.any():  # the rows left out, the rail's with the screen's (the CLI names their file lines)
            rails = cal.summary["outliers"]
            rails["kinds"]["rail"] = rails["kinds"].get("rail", 0) + int(railed.sum())
            rails["rows"], rails["count"] = dropped.tolist(), len(dropped)
    if said_rails:
        cal.summary["warnings"] = list(cal.summary["warnings"]) + [said_rails]
    said = [plausible_field(cal)] + ([] if vector else [misses_the_noise(cal, m, times, field_norms)])
    if not vector and method != "twostep" and (field_norm is not None or field_norms is not None):  # (twostep: its own)
        said.append(scale_words(cal))
    cal.summary["warnings"] = list(cal.summary["warnings"]) + [w for w in said if w]
    return _note_copies(cal, all_readings)


def _railed(m: np.ndarray, names, drop: bool) -> tuple:
    """(mask of the readings with an axis on a rail, the warning saying so or None). A saturated axis reads its range's
    limit, not the field, so such a reading is off the ellipsoid: on a handheld recording with x clipped on 20 % of
    the readings, fitting them put the offset 10 standard errors off and A 8 % off, leaving them out 1.4 σ and
    1 %. `drop`: they are left out (unless too few readings would remain), otherwise only said. The same detection
    and words as the command line's (outliers.rail_values, rail_words)."""
    if names is None or len(set(names)) != m.shape[1]:
        names = list("xyz"[:m.shape[1]])
    columns = {name: m[:, k] for k, name in enumerate(names)}
    found = rail_values(columns)
    railed = np.zeros(len(m), dtype=bool)
    if not found:
        return railed, None
    still = []
    for name, value in found:
        hit = columns[name] == value
        if held_still(m, hit, names.index(name)):  # one pose: a rail, or a rest at the axis's extreme on a coarse
            # grid — kept, and said
            still.append(name)
        else:
            railed |= hit
    said = rail_words(columns, found)
    if still:
        said += (f" ({', '.join(still)}: within one stretch of time, a sensor held still — a rest at the axis's "
                 "extreme on a coarse grid reads so too — so kept in the fit)")
    n = int(railed.sum())
    if not n:
        return railed, said
    if not drop:
        return np.zeros(len(m), dtype=bool), f"{said} (fitted here, as outliers='keep' asks)"
    if len(m) - n < MIN_SAMPLES:
        return np.zeros(len(m), dtype=bool), (f"{said} (fitted here: leaving the {n} out would leave "
                                              f"{len(m) - n} readings)")
    return railed, (f"{said} — here the {n} readings with an axis on a rail are left out of the fit (a clipped "
                    "reading is not on the ellipsoid; outliers='keep' keeps them)")


# the Earth's field at the surface (WMM/IGRF: about 22 µT at the equator's anomaly to 67 µT at the poles),
# with room for a building's or a vehicle's disturbance
EARTH_FIELD_UT = (15.0, 100.0)
PLAUSIBLE_WORDS = "|h| = "  # how plausible_field's warning starts (the CLI judges it again in its final unit)


# its horizontal component, a planar calibration's |h|: 0 at the magnetic poles to 41 µT; under 1 µT only within a
# few degrees of a pole, where no compass is calibrated
HORIZONTAL_FIELD_UT = (1.0, 100.0)


def plausible_field(cal: Calibration, horizontal: bool = False) -> str | None:
    """A warning when |h|, in a field unit, is far from any field on the Earth's surface (`horizontal`: from any
    horizontal field, a planar calibration's): a unit mix-up (readings in mG labelled µT: |h| 500 "µT", offsets 10×
    too large; H given in µT and labelled nT) more often than a lab coil."""
    if cal.h_units not in TESLA_PER_UNIT:
        return None
    ut = cal.field_norm * TESLA_PER_UNIT[cal.h_units] / 1e-6
    low, high = HORIZONTAL_FIELD_UT if horizontal else EARTH_FIELD_UT
    if low <= ut <= high:
        return None
    if horizontal:
        return (f"{PLAUSIBLE_WORDS}{cal.field_norm:.6g} {cal.h_units} = {ut:.4g} µT, far from the Earth's horizontal "
                f"field (0–41 µT): is it really in {cal.h_units}? (state the readings' unit: a header 'mx [mG]', "
                "units=, --units; and the horizontal field's: field_units=, --field-units; fine for a coil's field)")
    return (f"{PLAUSIBLE_WORDS}{cal.field_norm:.6g} {cal.h_units} = {ut:.4g} µT, far from the Earth's field (22–67 µT): "
            f"are the readings really in {cal.h_units}? (state their unit: a header 'mx [mG]', units=, --units; fine "
            "for a coil's field)")


# The fit's residual σ over the readings' own noise (third differences in time order) above which the fit is said
# to miss something: a right model leaves about 1 (simulations; the QMC5883L recording 1.3×, the phone's 1.8× with
# its small unmodelled nonlinearity), while a log of two sessions whose offset moved by 5–20 % of the field between
# them left 5–19× and a calibration 2–10 % of the field off, with only the serial correlation said (a blind check),
# and the handheld recording's closing disturbance leaves 3.6×.
MISSES_NOISE = 3.0


def readings_noise(cal: Calibration, m: np.ndarray, t=None, field_norms=None) -> tuple[float, int] | None:
    """The readings' own noise σ (their unit) and the stride it was measured at, for the magnitude fit `cal`
    (diagnose.core.residual_noise: third differences of its residuals in time order at strides over which the sensor
    turns less than ~40° (at most 8 readings apart), so that noise correlated over so few readings counts whole
    while what the model misses, which varies with the direction, does not). `t`: the rows' times, else row order; `field_norms`: each row's |field|. None for
    rows that are no time series."""
    from .diagnose.core import residual_noise

    h = cal.apply(m)
    return residual_noise(m, sampson_residuals(cal, m, field_norms), h / np.linalg.norm(h, axis=1, keepdims=True), t)


def misses_the_noise(cal: Calibration, m: np.ndarray, t=None, field_norms=None) -> str | None:
    """A warning when the magnitude fit's residual σ (summary["noise_sigma"], the readings' unit) is more than
    MISSES_NOISE times the readings' own noise (readings_noise, also put in summary["readings_noise_sigma"] and
    ["readings_noise_stride"]): what the model misses can bias the calibration beyond its standard errors."""
    residual = cal.summary.get("noise_sigma")
    own = readings_noise(cal, m, t, field_norms) if residual else None
    return misfit_said(cal, own)


def misfit_said(cal: Calibration, own: tuple[float, int] | None, planar: bool = False) -> str | None:
    """misses_the_noise's verdict on the readings' own noise `own` ((σ, stride) or None), put in the summary; the
    planar fit's too (`planar`: its words)."""
    residual = cal.summary.get("noise_sigma")
    if not residual or own is None:
        return None
    sigma, stride = own
    cal.summary["readings_noise_sigma"], cal.summary["readings_noise_stride"] = sigma, stride
    if not residual > MISSES_NOISE * sigma:
        return None
    unit = f" {cal.units}" if cal.units else ""
    return (f"the fit's residual σ {residual:.4g}{unit} is {residual / sigma:.3g}× the readings' own noise "
            f"{sigma:.4g}{unit} ({noise_method(stride)}): the model misses something larger than the "
            "noise, which can bias the calibration beyond its standard errors"
            + (" (and the headings by as much)" if planar else "") + " — a disturbance (a magnet, a motor, a "
            "current near the sensor), an offset that moved within the log (two sessions in one file, a battery or "
            "board moved, a load on the seat: calibrate each apart), or a |field| that changed"
            + ("" if planar else "; fluxcal diagnose names what") + ". (Noise correlated over longer than the "
            "sensor takes to turn ~40°, or than 8 readings, also raises the ratio: log at a higher rate or turn more slowly, "
            "or average fewer readings)")


def noise_method(stride: int) -> str:
    """How readings_noise's σ was measured, for a printout (stride: readings_noise's; 0 when the readings' own
    differences, its floor, were the larger: a blind check found them labelled as the residuals')."""
    if stride == 0:
        return "third differences of the readings in time order, above those of the fit's residuals"
    return ("third differences in time order of the fit's residuals, "
            + ("consecutive readings" if stride == 1 else f"{stride} readings apart"))


# The fit's residual σ this many times the readings' own noise (or less than its inverse): said what it means.
# Right models leave the noise (the real recordings' QMC5883L: 1.3×, simulations ≈ 1); the airborne magnitude fit
# left 160×, the handheld's 3.6×, a simulated temperature offset 2×.
NOISE_RATIO = 1.5


def noise_line(summary: dict, unit: str, raw: np.ndarray | None = None, t=None, planar: bool = False) -> str | None:
    """The printout's line of the readings' own noise σ beside the fit's residual σ (summary["noise_sigma"]): the two
    differ by what the model misses. A magnitude fit's (summary["readings_noise_sigma"], readings_noise), else from
    the `raw` readings' third differences in time order (`t`), as `diagnose` estimates it. None for rows that are
    not a time series (consecutive readings differ about as much as any two, e.g. `fluxcal simulate`'s independent
    orientations): their differences measure the turning, not the noise. `planar`: calibrate_planar's words."""
    from .diagnose.core import MAX_STRIDE, time_series_noise

    if "readings_noise_sigma" in summary:
        sigma, how = summary["readings_noise_sigma"], noise_method(summary["readings_noise_stride"])
    elif raw is not None:
        sigma = time_series_noise(raw if t is None else raw[np.argsort(t, kind="stable")])
        how = "third differences of the readings in time order, as diagnose estimates it"
    else:
        return None
    if sigma is None:
        return None
    ratio = summary["noise_sigma"] / sigma
    times = f"{ratio:.2f}×" if ratio < 10 else f"{ratio:.0f}×"
    # (noise correlated over more readings than the stride is a second cause: a sensor's strong low-pass filter)
    what = (f"the residual σ is {times} it: the model misses more than the noise"
            + ("" if planar else " (fluxcal diagnose names what)")
            + (", or the noise is correlated over more than these readings" if summary.get(
                "readings_noise_stride", 1) >= MAX_STRIDE else "") if ratio > NOISE_RATIO else
            f"above the residual σ ({times} it): the readings change between rows faster than their differences "
            "can tell from noise, and the residual σ bounds it" if ratio < 1 / NOISE_RATIO else
            f"the residual σ is {times} it")
    return f"  noise σ, differences  {sigma:.4g}{unit}   ({how}; {what})"


def _magnitude_start(m: np.ndarray, field_norm, field_norms, units, start_settings: dict) -> Calibration:
    """The refinement's start: the ALS ellipsoid, or with each reading's |field| changing, TWOSTEP, whose first step
    takes the change where the ellipsoid's quadric cannot (along an orbit, |F| ±45 %, the ALS quadric was no
    ellipsoid in 14 of 250 blind trials and the refinement never started). Should TWOSTEP fail (its second step
    on a cap of directions), the ellipsoid's start, as before."""
    if field_norms is not None and changing_field(field_norms):
        try:
            return twostep(m, field_norms, units=units, standard_errors=False,  # the refinement gives them
                           **{k: v for k, v in start_settings.items() if k != "exact_statistics"})
        except ValueError as exc:
            start = fit_ellipsoid(m, field_norm=field_norm, units=units, method="als", **start_settings)
            start.summary["warnings"] = list(start.summary["warnings"]) + [
                f"started from the ellipsoid of the |field|'s mean, not TWOSTEP with each one: {str(exc)[:300]}"]
            return start
    return fit_ellipsoid(m, field_norm=field_norm, units=units, method="als", **start_settings)




def _screened_start(m: np.ndarray, field_norm, field_norms, units, start_settings: dict,
                    loss: str) -> tuple[Calibration, np.ndarray | None]:
    """The robust refinement's start when the outliers are kept (outliers='keep', loss 'huber' or 'cauchy'): fitted
    without the readings the outlier screen flags or that lie far out (outliers.far_readings), so that the loss, which
    then weighs every reading, starts near the readings' own ellipsoid; and which readings are not flagged (None:
    all), for choosing the shape (_refine_shape). The algebraic start weighs a reading by its distance to the
    fourth power: one spike at 20× the field in 2000 good readings moved it by 2–5 fields and the Cauchy
    refinement ended 470 fields off; at 170× the start failed ("an outlier dominates their spread"). The screen is
    the one outliers='drop' runs on every default call (on readings it finds none in, one ALS fit); should it fail,
    the start takes every reading but the far ones. (The screen missed a 20× spike in 7 of 30 simulations of
    readings in no time order, whose third differences it took for noise: the far readings catch those.)"""
    try:
        screened = find_outliers(m, field_norms=field_norms)
    except ValueError:
        screened = None
    rows = np.union1d(screened.rows if screened else np.zeros(0, dtype=int), far_readings(m)).astype(int)
    if not len(rows):
        return _magnitude_start(m, field_norm, field_norms, units, start_settings), None
    kept = np.ones(len(m), dtype=bool)
    kept[rows] = False
    start = _magnitude_start(m[kept], field_norm, None if field_norms is None else field_norms[kept], units,
                             start_settings)
    shown = ", ".join(str(r) for r in rows[:8]) + (", …" if len(rows) > 8 else "")
    judged = f"{screened.threshold:.1f} robust σ off the ellipsoid or " if screened and screened.screened else ""
    start.summary["warnings"] = list(start.summary["warnings"]) + [
        f"{len(rows)} of {len(m)} readings lie more than {judged}{DOMINATING:g}× the median reading's distance "
        f"from the readings' median (rows {shown}): kept (outliers='keep'), and the {loss} refinement weighed them "
        "with the others, but its start was fitted without them, and shape 'auto' judged the shapes' fit without "
        "them"]
    return start, kept




def _check_steps(method: str, vector: bool, start_settings: dict, refine_settings: dict, loss: str) -> None:
    """Refuse settings meant for a step that `method` does not run (they would be silently ignored)."""
    if vector and start_settings:
        raise ValueError(f"{_settings_named(start_settings)} of the ellipsoid fit, which the vector fit "
                         "(method 'vector', or 'auto' with a reference) does not run")
    if method in ("ls", "als"):
        unused = list(refine_settings) + (["loss"] if loss != "none" else [])
        if unused:
            raise ValueError(f"{_settings_named(unused)} of the refinement, which method {method!r} does not "
                             "run (method 'auto' or 'als+refine' refines)")


def _settings_named(names) -> str:
    names = list(names)
    return f"{', '.join(names)}: {'a setting' if len(names) == 1 else 'settings'}"


# TWOSTEP's estimate this many of its own standard errors from the maximum-likelihood one is said (_twostep_bias)
TWOSTEP_BIAS_SE = 2.0


def _twostep_bias(cal: Calibration, m: np.ndarray, field_norms=None) -> str | None:
    """How far TWOSTEP's estimate lies from the maximum-likelihood one (the refinement started from it), in TWOSTEP's
    own standard errors, when that is more than TWOSTEP_BIAS_SE. Its second step weighed every reading alike once, and
    a blind check on ±20° of tilt found it 2–12× the bound its standard errors claimed ("identifiable yes"); on the
    Sampson residuals it is the maximum-likelihood estimate now, and this says when it is not (a second step stopped
    short)."""
    se = np.asarray(cal.summary.get("standard_errors") or [], dtype=float)
    if se.size != 9 or not np.all(np.isfinite(se) & (se > 0)):
        return None
    try:
        ml = refine(cal, m, shape="sym", field_norms=field_norms)
    except (ValueError, RuntimeError):
        return None

    def params(c):
        a = np.asarray(c.matrix, dtype=float)
        return np.r_[c.offset, a[0, 0], a[0, 1], a[0, 2], a[1, 1], a[1, 2], a[2, 2]]

    apart = np.abs(params(ml) - params(cal)) / se
    if not apart.max() > TWOSTEP_BIAS_SE:
        return None
    names = ("b0", "b1", "b2", "a00", "a01", "a02", "a11", "a12", "a22")
    worst = np.argsort(-apart)[:3]
    return (f"TWOSTEP's estimate lies up to {apart.max():.1f} of its standard errors from the maximum-likelihood one "
            f"on these readings ({', '.join(f'{names[k]} {apart[k]:.1f}' for k in worst if apart[k] > 1.0)}): its "
            "standard errors are first order and do not hold its bias where the readings leave some directions poorly "
            "determined (a narrow band of tilts); the default method (no --method) gives the maximum-likelihood "
            "calibration and its errors")


def _refine_shape(start: Calibration, m: np.ndarray, shape: str, judged: np.ndarray | None = None,
                  **settings) -> Calibration:
    """The refinement in `shape`, or with "auto" the shape of lowest BIC, determined or not (see calibrate).
    `judged`: the readings whose residuals the BIC sums (None: all) — outliers kept for a robust loss left out, for
    one spike's residual at 170 fields was all of every shape's RSS, and a 'sym' sensor got 'sphere' or 'diag'
    with its matrix 0.02–0.08 off, in half the seeds (_judged_rss)."""
    if shape == "sym":
        return refine(start, m, shape=shape, **settings)
    if shape != "auto":
        return _forced_shape(start, m, shape, judged=judged, **settings)

    def fit(name):
        try:
            return refine(start, m, shape=name, **settings)
        except (ValueError, RuntimeError) as error:  # a restricted shape far from the data may not converge
            return error

    # (axes of unequal noise: the weighted readings' sphere is no shape of the readings' own, so not tried)
    weights = weights_of(settings.get("noise_sigma"))
    shapes = [k for k in SHAPES if k != "sphere" or weights is None]
    workers = min(len(shapes), usable_cpus())
    if len(m) >= PARALLEL_SHAPES and workers > 1:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            results = dict(zip(shapes, pool.map(fit, shapes)))
    else:
        results = {name: fit(name) for name in shapes}
    fits, table = {}, {}
    for name, result in results.items():
        if isinstance(result, Exception):
            table[name] = {"error": str(result)}
            continue
        fits[name] = result
        table[name] = _shape_row(result.summary, len(m), _judged_rss(result, m, judged, settings.get("field_norms"),
                                                                     weights))
    if not fits:
        errors = {k: v["error"] for k, v in table.items()}
        if len({re.sub(r"\d+-parameter ", "", e) for e in errors.values()}) == 1:
            raise ValueError(errors["sym"])  # the data's fault, not a shape's: said once
        raise ValueError("; ".join(f"shape {k}: {e}" for k, e in errors.items()))
    # Chosen by fit alone: a smaller shape the data reject is biased however well determined (on the
    # airborne segment the sphere is "determined" and 1.1 µT off, 3.5 of its standard errors).
    best = min(fits, key=lambda k: table[k]["bic"])
    cal = fits[best]
    cal.summary["shapes"] = table
    cal.summary["shape"] = best
    warnings = [f"shape {k} could not be fitted ({v['error']}); chose among the others"
                for k, v in table.items() if "error" in v]
    if not table[best]["identifiable"]:
        warnings += [f"shape {k} would be determined, but the data reject it (BIC higher by "
                     f"{table[k]['bic'] - table[best]['bic']:.0f}): its answer would be biased, not a remedy"
                     for k in fits if table[k]["identifiable"]]
    # A smaller shape wins without evidence against the larger one when the data cannot determine the larger
    # one (a cap of orientations: the cross-axis terms trade off against the offset). Its determined answer then
    # holds only if the left-out terms are zero, which these data cannot test: a 60° cap chose "diag" and put
    # the offset 14–28 of its standard errors off (blind check, bench/RESULTS.md).
    larger = list(SHAPES)[list(SHAPES).index(best) + 1:]  # SHAPES runs from the sphere to the full matrix
    undetermined = [k for k in larger if "error" in table[k] or not table[k]["identifiable"]]  # a failed fit says no more
    if table[best]["identifiable"] and undetermined:
        cal.summary["identifiable"] = False
        cal.summary["identifiable_if"] = best
        warnings.append(f"not identifiable without an assumption: the data do not determine shape "
                        f"{' or '.join(undetermined)} (its cross-axis or scale terms), so shape {best!r} won by "
                        f"fit alone, and its answer and standard errors hold only if the sensor has none of the "
                        f"terms {best!r} leaves out — which these data cannot test; turn the sensor through more "
                        "orientations (or give reference vectors)")
    cal.summary["warnings"] = list(cal.summary["warnings"]) + warnings
    return cal


def _shape_row(summary: dict, n: int, judged: tuple[float, int] | None = None) -> dict:
    """A refinement's row of the shape table: parameters, RSS, BIC = N ln(RSS/N) + k ln N, determined. `judged`:
    (RSS, N) of the readings judged (_judged_rss) in place of the refinement's over all N."""
    rss, k = float(summary["cost"]) * n, len(summary["parameters"])
    row = {}
    if judged is not None:
        rss, n = judged
        row["readings"] = n
    return {"parameters": k, "rss": rss, "bic": n * np.log(rss / n) + k * np.log(n),
            "identifiable": bool(summary["identifiable"]), **row}


def _judged_rss(cal: Calibration, m: np.ndarray, judged: np.ndarray | None, field_norms=None, axis_weights=None):
    """(RSS, N) of the refinement's residuals (Sampson's, (|h| − H)|h|/|A h|, as refine's, weighted as its were)
    over the `judged` readings, or None when all are judged."""
    if judged is None:
        return None
    r = sampson_residuals(cal, m[judged], None if field_norms is None else np.asarray(field_norms)[judged],
                          axis_weights)
    return float(r @ r), int(np.count_nonzero(judged))


def sampson_residuals(cal: Calibration, m: np.ndarray, field_norms=None, axis_weights=None) -> np.ndarray:
    """Each reading's magnitude residual in the readings' unit, as refine's: Sampson's (|h| − H)|h|/|A h|, with H
    the calibration's field norm or each reading's own `field_norms`; with `axis_weights` (σ̄/σ_axis, refine's
    noise_sigma) the gradient's norm in units of each axis's noise, |A h / w| (fluxcal._axis_weights.sampson)."""
    target = cal.field_norm if field_norms is None else np.asarray(field_norms, dtype=float)
    return sampson(np.asarray(m, dtype=float), cal.offset, np.asarray(cal.matrix, dtype=float), target, axis_weights)


# Kass & Raftery's "very strong" evidence: a BIC lower by more than this (a Bayes factor above ~150).
REJECTED_BIC = 10.0


def _forced_shape(start: Calibration, m: np.ndarray, shape: str, judged: np.ndarray | None = None,
                  **settings) -> Calibration:
    """The refinement in the restricted `shape` the user chose, with a warning when the full symmetric
    matrix fits the data decisively better: the forced shape's answer is then biased (a sensor with
    ±10 % axis scales fitted as a sphere keeps a 5 % spread of |B|), and nothing else would say so."""
    cal = refine(start, m, shape=shape, **settings)
    try:
        full = refine(start, m, shape="sym", **settings)
    except (ValueError, RuntimeError):  # the comparison is a courtesy: the user's fit stands without it
        return cal
    norms = settings.get("field_norms")
    w = weights_of(settings.get("noise_sigma"))
    table = {shape: _shape_row(cal.summary, len(m), _judged_rss(cal, m, judged, norms, w)),
             "sym": _shape_row(full.summary, len(m), _judged_rss(full, m, judged, norms, w))}
    cal.summary["shapes"] = table
    excess = table[shape]["bic"] - table["sym"]["bic"]
    if excess > REJECTED_BIC:
        rms = {name: np.sqrt(row["rss"] / row.get("readings", len(m))) for name, row in table.items()}
        cal.summary["warnings"] = list(cal.summary["warnings"]) + [
            f"the data reject shape {shape!r}: the symmetric matrix fits with BIC lower by {excess:.0f} "
            f"(residual RMS {rms['sym']:.3g} against {rms[shape]:.3g}); the corrected fields keep the soft iron "
            "the shape leaves out, and unless the coverage is even the offset absorbs part of it (shape 'auto' "
            "chooses by BIC)"]
    return cal


# One reading repeated in this many consecutive rows or more (and in 1 % of them), beyond sample-and-hold's regular runs,
# is a sensor that stuck or a logger that held it
STUCK_ROWS = 20


def _note_copies(cal: Calibration, m: np.ndarray) -> Calibration:
    """Warn about sample-and-hold copies (see fluxcal._arrays.held_copies), stretches of the log written twice
    (fluxcal._arrays.repeated_blocks) and one reading held for many rows: each counted as independent readings."""
    copied = repeated_blocks(m)
    if copied.any():  # (a blind check: a file appended to itself left the z spread 1.54 and nothing said)
        cal.summary["warnings"] = list(cal.summary["warnings"]) + [
            f"{repeated_words(copied)}: the fit counts them twice, and its standard errors are too small by up to √2; "
            "drop them"]
    copies = held_copies(m)
    if copies is None:
        same = np.concatenate([[False], np.all(m[1:] == m[:-1], axis=1)])
        starts = np.flatnonzero(np.diff(np.concatenate([[0], same.astype(int), [0]])) == 1)
        ends = np.flatnonzero(np.diff(np.concatenate([[0], same.astype(int), [0]])) == -1)
        longest = int(np.argmax(ends - starts)) if len(starts) else None
        if longest is not None and ends[longest] - starts[longest] + 1 >= max(STUCK_ROWS, 0.01 * len(m)):
            first, count = int(starts[longest]) - 1, int(ends[longest] - starts[longest]) + 1
            cal.summary["warnings"] = list(cal.summary["warnings"]) + [
                f"rows {first}–{first + count - 1} hold one reading {count} times (a sensor that stuck, or a logger "
                "that held its last value while the sensor did not answer?): the fit counts each as a reading"]
        return cal
    corrected = cal.summary.get("serial_correlation", {}).get("lags", 0) > 0
    errors = ("the Newey–West standard errors allow for them, but record at the sensor's rate or drop the copies"
              if corrected else "the standard errors count them as independent readings and are too small by "
              "about √(run length) — record at the sensor's rate or drop the copies")
    cal.summary["warnings"] = list(cal.summary["warnings"]) + [
        f"{int(copies.sum())} of {len(m)} readings ({100 * copies.mean():.0f} %) repeat the previous one exactly "
        f"in regular runs (sample and hold: the logger ran faster than the sensor); {errors}"]
    return cal
