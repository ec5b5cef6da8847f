"""Maximum-likelihood joint refinement (Ceres) and reference-vector calibration.

Magnitude model: parameters [b0 b1 b2, a00 a01 a02 a11 a12 a22] (A symmetric), Sampson residual
(|h| − H)|h|/|A h| in reading units — maximum likelihood for isotropic Gaussian noise on the readings.
Vector model: each reading m has its true field r in the sensor frame; m = W r + b, parameters
[b0 b1 b2, w00 … w22] (W row-major), A = W⁻¹. See cpp/include/fluxcal/refine.hpp.

The returned Calibration's summary carries the parameters, their covariance and standard errors,
which of them the data determine, the Fisher-information condition number and the noise estimate.
"""
from __future__ import annotations

import numpy as np

from . import _core
from ._arrays import as_field_norms, as_number, as_samples, field_norms_summary, require_calibration, set_options, units_text
from ._axis_weights import map_fit, restate_summary, sampson_jacobian, scaled_start, weights_of
from .attitude import axis_remapping
from .calibration import Calibration

LOSSES = {"none": _core.Loss.none, "huber": _core.Loss.huber, "cauchy": _core.Loss.cauchy}
# The magnitude model's matrix (MATLAB magcal's 'eye', 'diag', 'sym'; "eye" is accepted for "sphere": with a
# known field norm the sphere still needs its one scale).
SHAPES = {"sphere": _core.Shape.sphere, "diag": _core.Shape.diagonal, "sym": _core.Shape.symmetric}
SHAPE_ALIASES = {"eye": "sphere", "diagonal": "diag", "symmetric": "sym"}
SERIAL_CORRELATION = {"automatic": _core.SerialCorrelation.automatic,
                      "independent": _core.SerialCorrelation.independent,
                      "newey_west": _core.SerialCorrelation.newey_west}


def shape_name(shape) -> str:
    """The canonical name ("sphere", "diag", "sym") of a shape or its alias; ValueError otherwise."""
    name = SHAPE_ALIASES.get(shape, shape) if isinstance(shape, str) else shape
    if name not in SHAPES:
        raise ValueError(f"shape: {shape!r} is not one of {', '.join(SHAPES)} (or magcal's 'eye' for 'sphere')")
    return name


def _options(loss="none", loss_scale=0.0, units="", shape="sym", **settings):
    options = _core.RefineOptions()
    if loss not in LOSSES:
        raise ValueError(f"loss: {loss!r} is not one of {', '.join(LOSSES)}")
    options.loss = LOSSES[loss]
    options.shape = SHAPES[shape_name(shape)]
    options.loss_scale = as_number(loss_scale, "loss_scale")
    options.units = units_text(units)
    if "serial_correlation" in settings:
        settings = {**settings, "serial_correlation": serial_correlation_mode(settings["serial_correlation"])}
    return set_options(options, settings, "refine")


def serial_correlation_mode(name):
    """The C++ SerialCorrelation for "automatic", "independent" or "newey_west"; ValueError otherwise."""
    if isinstance(name, _core.SerialCorrelation):
        return name
    if not isinstance(name, str) or name not in SERIAL_CORRELATION:
        raise ValueError(f"serial_correlation: {name!r} is not one of {', '.join(SERIAL_CORRELATION)}")
    return SERIAL_CORRELATION[name]


def _calibration(result: dict, method: str) -> Calibration:
    summary = dict(result["summary"])
    for key in ("noise_sigma", "fisher_condition", "solver_report"):
        summary[key] = result[key]
    summary["method"] = method
    parameter_statistics(summary, result, 3 if method in ("vector", "refine_vector") else 1)
    return Calibration(offset=result["offset"], matrix=result["matrix"], field_norm=result["field_norm"],
                       units=result["units"], model=result["model"], summary=summary)


def parameter_statistics(summary: dict, result: dict, per_reading: int) -> None:
    """A fit's parameter statistics from the core (its result's parameters, parameter_names, covariance,
    standard_errors, determined, identifiable, serial_correlation) into `summary` as plain lists and dicts, with
    the degrees of freedom of `per_reading` residuals a reading (_few_spare_readings). A result without a
    covariance (TWOSTEP's exact fit of 9 readings) gives the verdict alone."""
    summary["parameter_names"] = result["parameter_names"]
    summary["identifiable"] = result["identifiable"]
    summary["parameters"] = np.asarray(result["parameters"]).tolist()
    summary["determined"] = list(result["determined"])
    if "covariance" not in result:
        return
    for key in ("standard_errors", "covariance"):
        summary[key] = np.asarray(result[key]).tolist()
    summary["serial_correlation"] = dict(result["serial_correlation"])
    _few_spare_readings(summary, per_reading)


FEW_SPARE = 10  # below this many residuals beyond the parameters, t(ν) is ≥ 14 % wider than the normal


def _few_spare_readings(summary: dict, per_reading: int) -> None:
    """summary["degrees_of_freedom"] (residuals − parameters), and a warning when it is small: the noise σ
    and so every standard error then rest on a few spare readings (at 11 readings for 9 parameters they
    were 20–60× too small in some fits), and a 95 % interval is ±t·SE, not ±1.96·SE."""
    from scipy import stats

    dof = int(summary["samples"]) * per_reading - len(summary["parameters"])
    summary["degrees_of_freedom"] = dof
    if dof < FEW_SPARE:
        t = float(stats.t.ppf(0.975, max(dof, 1)))
        summary["warnings"] = list(summary.get("warnings", [])) + [
            f"only {dof} residual(s) beyond the {len(summary['parameters'])} parameters: the noise σ and the standard "
            f"errors are rough estimates (a 95 % interval is ±{t:.3g}·SE, not ±1.96·SE); record more readings"]


def refine(calibration: Calibration, samples, reference=None, loss: str = "none", loss_scale: float = 0.0,
           shape: str = "sym", field_norms=None, noise_sigma=None, **settings) -> Calibration:
    """Refine `calibration` on `samples` by maximum likelihood (Ceres).

    Without `reference` the magnitude model is used with |h| = calibration.field_norm (known), or with
    `field_norms` (N values > 0) each reading's own |h|: a field that changes while the sensor turns, logged by
    a scalar magnetometer beside it or an observatory's F (the result's field_norm is then their mean, and its
    |h| statistics are of |h_i| − field_norms[i]); A is made symmetric first. `shape` restricts A: "sym"
    (symmetric, 9 parameters b0 b1 b2 a00 a01 a02 a11 a12 a22), "diag" (axis scales only, 6: b0 b1 b2 a00 a11 a22)
    or "sphere" (one scale, 4: b0 b1 b2 a; magcal's 'eye'); the summary's parameters, covariance and standard
    errors are the shape's free parameters.
    With `reference` (N×3 true field per reading, sensor frame) the vector model, whose W is always full.
    loss: "none", "huber" or "cauchy"; loss_scale in reading units (0 = 3 × robust noise estimate).
    settings: max_iterations, function_tolerance, gradient_tolerance, parameter_tolerance,
    determined_tolerance (default 0.01 of each parameter's scale), serial_correlation ("automatic":
    Newey–West standard errors when the residuals, rows in time order, fail a Ljung–Box test at
    serial_correlation_alpha = 0.01 and the sandwich widens an error, or when it widens one ≥ 1.5×;
    never to a sandwich that widens nothing. "independent"; "newey_west": whatever it gives).
    The Newey–West long-run covariance is prewhitened (Andrews & Monahan 1992: a lag-1 autoregression
    per score column, clipped at ±0.97, Bartlett over the whitened scores, recoloured).
    summary["serial_correlation"] holds the residuals' lag-1 autocorrelation, the test's p-value, the
    Newey–West lags of the whitened scores (0 = independent readings assumed), the inflation of the standard errors and the
    independent-readings ones. Whether the data determine a parameter is judged on the latter.
    noise_sigma: three values (σ x, y, z: a datasheet's, or a diagnosis's `axis_noise` against reference vectors) when the axes' noise
    differs — only their ratios matter: the magnitude model's residual is then the distance to the ellipsoid with
    each axis in units of its own noise (maximum likelihood for that noise; with z 3× as noisy the unweighted fit's
    offset and matrix errors are 1.1–1.2× the bound `fluxcal.crlb(..., sigma=[…])`, the weighted fit's 1.0). The summary's
    residuals and noise σ are then in those units (σ̄, the three's RMS), "axis_noise" holds the three scaled by
    σ̂/σ̄, and the parameters, covariance and coverage are in the readings' own axes. Not for "sphere" (scaled axes
    make it an ellipsoid) nor with `reference` (the vector model fits each axis's row apart: its noise weights
    nothing). One value, or three equal, is the plain fit.
    """
    require_calibration(calibration)
    m = as_samples(samples)
    if reference is not None and shape_name(shape) != "sym":
        raise ValueError(f"shape: {shape!r} restricts the magnitude model's A; with a reference the vector model "
                         "fits a full W (give shape='sym' or no reference)")
    if reference is not None and field_norms is not None:
        raise ValueError("field_norms: the vector model's reference vectors already give every reading's field; "
                         "give one or the other")
    options = _options(loss, loss_scale, calibration.units, shape, **settings)
    w = _axis_weights(noise_sigma, shape, reference)
    if w is not None:
        return _weighted_refine(calibration, m, w, shape, field_norms, options)
    args = (calibration.offset, calibration.matrix, calibration.field_norm, calibration.units, m)
    if reference is None:
        if field_norms is None:
            cal = _calibration(_core.refine(*args, options), "refine")
        else:
            norms = as_field_norms(field_norms, len(m))
            cal = _calibration(_core.refine_norms(*args, norms, options), "refine")
            cal.summary["field_norms"] = field_norms_summary(norms)
        cal.summary["shape"] = shape_name(shape)
        return cal
    return _calibration(_core.refine_vector(*args, as_samples(reference, "reference"), options), "refine_vector")


def fit_vector(samples, reference, units: str = "", loss: str = "none", loss_scale: float = 0.0,
               **settings) -> Calibration:
    """Reference-vector calibration: m = W r + b by linear least squares (closed form; the maximum-
    likelihood estimate under Gaussian noise), A = W⁻¹ — a full matrix, since the reference fixes the
    rotation. Its covariance is the multivariate regression's, Σ ⊗ (XᵀX)⁻¹ with Σ the axes' residual covariance
    (each axis' own σ, summary["noise_sigma_axes"]; summary["noise_sigma"] pools them); the standard errors are of W
    and b, summary["matrix_standard_errors"] those of A (3×3, delta method). With a robust `loss` the linear fit then seeds a Ceres refinement of the same model.
    `reference`: the true field of each reading in the sensor frame (see fluxcal.attitude)."""
    m, r = as_samples(samples), as_samples(reference, "reference")
    cal = _calibration(_core.fit_vector(m, r, _options(units=units, **settings)), "vector")
    if loss != "none":
        cal = refine(cal, m, reference=r, loss=loss, loss_scale=loss_scale, **settings)
    # each axis' own noise (its standard errors are from it: an axis 6× noisier than the others has 6× the errors)
    residuals = m - r @ np.linalg.inv(cal.matrix).T - cal.offset
    cal.summary["noise_sigma_axes"] = np.sqrt(np.sum(residuals ** 2, axis=0) / max(len(m) - 4, 1)).tolist()
    # the parameters are W's (m = W r + b); the correction applies A = W⁻¹: dA = −A dW A, so in row-major order
    # d vec(A) = −(A ⊗ Aᵀ) d vec(W), and A's standard errors follow by the delta method
    if cal.summary.get("covariance") is not None and cal.summary.get("parameter_names", [])[3:4] == ["w00"]:
        J = -np.kron(cal.matrix, cal.matrix.T)
        cov_w = np.asarray(cal.summary["covariance"])[3:12, 3:12]
        cal.summary["matrix_standard_errors"] = np.sqrt(np.clip(np.diag(J @ cov_w @ J.T), 0, None)).reshape(3, 3).tolist()
    remapped = axis_remapping(cal.matrix)
    if remapped:  # the fit holds, but a sensor mounted rotated, or a reference in other axes, deserves a word
        cal.summary["warnings"] = list(cal.summary["warnings"]) + [
            f"the matrix is an axis relabelling: the reference's x, y, z are the sensor's {remapped[1]}"
            + (" (a mirror: the two frames differ in handedness)" if remapped[2] else "")
            + ". The sensor is mounted rotated, or the reference is written in other axes (check the attitude "
            "convention); the matrix includes the remapping, so the calibration holds"]
    return cal


def _axis_weights(noise_sigma, shape, reference) -> np.ndarray | None:
    """refine's weights σ̄/σ_axis from `noise_sigma` (None when one σ, or three equal, is given or none)."""
    w = weights_of(noise_sigma)
    if w is None:
        return None
    if reference is not None:
        raise ValueError("noise_sigma: three values weight the magnitude model's axes; with reference vectors each "
                         "axis's row of W is fitted apart, so its noise changes nothing (leave noise_sigma out)")
    if shape_name(shape) == "sphere":
        raise ValueError("noise_sigma: with three values the readings' axes are scaled to equal noise, which makes a "
                         "sphere an ellipsoid: give shape='diag' or 'sym'")
    return w


def _weighted_refine(calibration: Calibration, m: np.ndarray, w: np.ndarray, shape: str, field_norms,
                     options) -> Calibration:
    """refine of the magnitude model with each axis weighted by w (fluxcal._axis_weights): the readings scaled,
    the core's fit mapped back, its summary restated in the readings' axes."""
    offset, matrix = scaled_start(calibration.offset, calibration.matrix, w)
    args = (offset, matrix, calibration.field_norm, calibration.units, np.ascontiguousarray(m * w))
    if field_norms is None:
        result = _core.refine(*args, options)
    else:
        norms = as_field_norms(field_norms, len(m))
        result = _core.refine_norms(*args, norms, options)
    result = dict(result)
    diag = shape_name(shape) == "diag"
    J = sampson_jacobian(result["offset"], result["matrix"], args[4],
                         result["field_norm"] if field_norms is None else norms)
    result["jacobian"] = J[:, [0, 1, 2, 3, 6, 8]] if diag else J
    # the independent-readings errors (a sandwich's are the covariance when the residuals are correlated):
    # s²(J'ᵀJ')⁻¹ with the core's scale s² (σ̂², or Huber's for a robust loss), mapped as the covariance is
    serial = dict(result["serial_correlation"])
    info = result["jacobian"].T @ result["jacobian"]  # (column-scaled before the inverse: offset columns ~1 and
    d = 1.0 / np.sqrt(np.clip(np.diag(info), 1e-300, None))  # matrix columns ~|field| put it past 1e15)
    plain = d[:, None] * np.linalg.pinv(d[:, None] * info * d[None, :], rcond=1e-14) * d[None, :]
    independent = np.square(serial["standard_errors_independent"])
    s2 = float(np.median(independent[np.diag(plain) > 0] / np.diag(plain)[np.diag(plain) > 0]))
    T = np.linalg.inv(map_fit(result, w, 3 if diag else 6))
    serial["standard_errors_independent"] = np.sqrt(np.clip(np.diag(s2 * T @ plain @ T.T), 0.0, None)).tolist()
    result["serial_correlation"] = serial
    result["summary"] = dict(result["summary"])
    restate_summary(result, m, w)
    cal = _calibration(result, "refine")
    cal.summary["shape"] = shape_name(shape)
    cal.summary["axis_noise"] = (result["noise_sigma"] / w).tolist()
    if field_norms is not None:
        cal.summary["field_norms"] = field_norms_summary(norms)
    return cal
