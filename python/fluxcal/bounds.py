"""Cramér–Rao lower bounds of the calibration parameters under Gaussian noise (NumPy).

Parameter order is that of fluxcal.refine: magnitude model [b (3), a00 a01 a02 a11 a12 a22];
vector model [b (3), W row-major (9)].
"""
from __future__ import annotations

import numpy as np

from ._arrays import as_samples
from .calibration import Calibration

_SYM = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]


def magnitude_jacobian(calibration: Calibration, clean_readings) -> np.ndarray:
    """∂r_i/∂θ of the Sampson residual r = (|h| − H)|h|/|A h| at noise-free readings (|h| = H)."""
    A = calibration.matrix
    d = as_samples(clean_readings, "clean_readings") - calibration.offset
    h = d @ A.T
    hn = np.linalg.norm(h, axis=1)
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


def crlb(calibration: Calibration, clean_readings=None, sigma: float = 1.0, reference=None) -> np.ndarray:
    """Covariance bound σ² F⁻¹ for isotropic Gaussian noise σ (reading units) on each axis.

    Magnitude model (reference None): pass the true calibration (symmetric A, offset, |h|) and the
    noise-free readings. Vector model: pass the reference vectors (the bound does not depend on the
    parameters, so `calibration` and `clean_readings` are not used).
    """
    if reference is not None:
        F = vector_information(reference)
    else:
        if clean_readings is None:
            raise ValueError("crlb: the magnitude model needs the noise-free readings")
        J = magnitude_jacobian(calibration, clean_readings)
        F = J.T @ J
    return sigma**2 * np.linalg.inv(F)
