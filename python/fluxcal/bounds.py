"""Cramér–Rao lower bounds of the calibration parameters under Gaussian noise (NumPy).

Parameter order is that of fluxcal.refine: magnitude model [b (3), a00 a01 a02 a11 a12 a22];
vector model [b (3), W row-major (9)].
"""
from __future__ import annotations

import numpy as np

from ._arrays import as_samples, require_calibration, require_finite
from .calibration import Calibration

_SYM = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]

# Below this many degrees of freedom behind an estimated σ Student's t 95 % quantile is above 2.23 (1.96 with σ known):
# the interval 14 % wider or more. (Twelve positions leave 24, or 12 with their headings estimated: 5 % and 11 %,
# which every standard run would say.)
FEW_DOF = 10


def few_dof_words(dof: float, source: str, remedy: str, below: float = FEW_DOF) -> str | None:
    """Words for standard errors scaled by a σ estimated with few degrees of freedom (0 < dof < `below`), else None:
    the errors over them follow Student's t, so a 95 % interval is wider than ±1.96 of them (a blind check's twelve
    planar readings, 7 degrees of freedom, had an offset 15 standard errors off, unsaid). `source`: what σ was
    estimated from; `remedy`: how to do better."""
    if not 0 < dof < below:
        return None
    from scipy import stats

    return (f"σ is estimated from {source} with {dof:g} degrees of freedom: the errors over their standard errors "
            f"follow Student's t, a 95 % interval is ±{float(stats.t.ppf(0.975, dof)):.3g} standard errors (not "
            f"±1.96); {remedy}")


def magnitude_jacobian(calibration: Calibration, clean_readings) -> np.ndarray:
    """∂r_i/∂θ of the Sampson residual r = (|h| − H)|h|/|A h| at noise-free readings (|h| = H)."""
    A = calibration.matrix
    d = as_samples(clean_readings, "clean_readings") - calibration.offset
    h = d @ A.T
    hn = np.linalg.norm(h, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):  # a reading at the offset: NaN rows, named by crlb
        u = h / hn[:, None]
        scale = hn / np.linalg.norm(h @ A.T, axis=1)  # |h| / |A h|
    J = np.empty((len(d), 9))
    J[:, :3] = -(u @ A) * scale[:, None]
    for col, (k, l) in enumerate(_SYM):
        dh = u[:, k] * d[:, l] + (u[:, l] * d[:, k] if k != l else 0.0)
        J[:, 3 + col] = dh * scale
    return J


def vector_information(reference) -> np.ndarray:
    """JᵀJ of the residual m − W r − b over θ = [b, W row-major] (independent of the parameters)."""
    r = as_samples(reference, "reference")
    X = np.column_stack([np.ones(len(r)), r])  # constant, r0, r1, r2
    F = np.zeros((12, 12))
    for j in range(3):
        idx = [j, 3 + 3 * j, 4 + 3 * j, 5 + 3 * j]
        F[np.ix_(idx, idx)] = X.T @ X
    return F


def crlb(calibration: Calibration, clean_readings=None, sigma=1.0, reference=None) -> np.ndarray:
    """Covariance bound F⁻¹ for Gaussian noise σ (reading units) on each axis: one σ for every axis, or three
    (σ x, y, z: axes of unequal noise, as `fluxcal.refine(..., noise_sigma=[…])` weighs them).

    Magnitude model (reference None): pass the true calibration (symmetric A, offset, |h|) and the
    noise-free readings; each reading's residual then has the variance Σ_k σ_k² (∂r/∂m_k)² of the noise along
    its field's direction. Vector model: pass the reference vectors (the bound does not depend on the
    parameters, so `calibration` and `clean_readings` are not used); axis k's σ scales its own row of W and b.
    """
    try:
        sigmas = np.atleast_1d(np.asarray(sigma, dtype=float))
    except (TypeError, ValueError):
        raise ValueError(f"crlb: sigma {sigma!r}, need the noise's positive standard deviation (one, or three: "
                         "x, y, z)") from None
    if sigmas.ndim != 1 or len(sigmas) not in (1, 3) or not (np.all(np.isfinite(sigmas)) and np.all(sigmas > 0)):
        raise ValueError(f"crlb: sigma {sigma}, need the noise's positive standard deviation (one, or three: x, y, z)")
    sigmas = np.broadcast_to(sigmas, 3)
    if reference is not None:
        F = vector_information(require_finite(as_samples(reference, "reference"), "reference"))
        axis = np.r_[0, 1, 2, np.repeat([0, 1, 2], 3)]  # b_k and W's row k: axis k's equations alone
        F = F / np.outer(sigmas[axis], sigmas[axis])
    else:
        if clean_readings is None:
            raise ValueError("crlb: the magnitude model needs the noise-free readings")
        require_calibration(calibration)
        J = magnitude_jacobian(calibration, require_finite(as_samples(clean_readings, "clean_readings"),
                                                           "clean_readings"))
        if not np.all(np.isfinite(J)):
            bad = int(np.flatnonzero(~np.all(np.isfinite(J), axis=1))[0])
            raise ValueError(f"crlb: clean_readings row {bad} sits at the offset (no field direction); "
                             "the bound is not defined there")
        variance = (J[:, :3] ** 2) @ (sigmas ** 2)  # ∂r/∂m = −∂r/∂b
        F = J.T @ (J / variance[:, None])
    names = ["b0", "b1", "b2"] + ([f"w{i}{j}" for i in range(3) for j in range(3)] if reference is not None
                                  else [f"a{k}{l}" for k, l in _SYM])
    return _inverse(F, names)


def _inverse(F: np.ndarray, names) -> np.ndarray:
    """F⁻¹, or an error naming the parameters of F's null directions (a singular information: the readings
    do not determine them and no unbiased estimator has a finite variance). Judged on the scaled F, as
    refine's identifiability, so units do not matter."""
    d = 1.0 / np.sqrt(np.maximum(np.diag(F), 1e-300))
    lam, V = np.linalg.eigh(d[:, None] * F * d[None, :])
    null = lam <= 1e-10 * lam[-1]
    if null.any():
        weight = np.sum(V[:, null] ** 2, axis=1)
        undetermined = [n for n, w in zip(names, weight) if w > 0.01]
        raise ValueError(f"crlb: the Fisher information is singular: the readings do not determine "
                         f"{', '.join(undetermined)} (no finite bound); they need more orientations")
    return np.linalg.inv(F)
