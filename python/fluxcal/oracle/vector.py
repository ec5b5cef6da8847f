"""Reference vector calibration: readings with a known field VECTOR per reading.

Model: m_k = W r_k + b + e_k, e_k ~ N(0, σ² I), with m_k the N×3 readings, r_k the true field in the
sensor/body frame (e.g. `fluxcal.attitude.reference_vectors` of IGRF and the attitude), W (3×3) the
forward distortion (scale, soft iron, misalignment, any fixed mounting rotation) and b (3,) the
offset. The model is linear in (W, b), so plain least squares on the N×4 design X = [r, 1] is the
maximum-likelihood estimate (unbiased and efficient). fluxcal's correction convention h = A (m − b)
holds with A = W⁻¹. Unlike a magnitude-only ellipsoid fit this needs no coverage of the sphere: it
is well posed as soon as the r_k span three dimensions.

Parameter order used by `crlb_vector` (12): W row-major (W11, W12, W13, W21, …, W33), then
(b1, b2, b3); index 3 i + j is W[i, j], index 9 + i is b[i].
"""
from __future__ import annotations

import numpy as np


def _design(reference) -> np.ndarray:
    r = np.asarray(reference, dtype=float)
    if r.ndim != 2 or r.shape[1] != 3 or len(r) < 4:
        raise ValueError("reference must be N×3 with N ≥ 4")
    return np.column_stack([r, np.ones(len(r))])


def fit_vector(samples, reference) -> dict:
    """Least-squares fit of m = W r + b.

    Returns dict: offset b (3,), matrix A = W⁻¹ (3×3), forward W (3×3), residual_rms =
    √(mean_k ‖m_k − W r_k − b‖²) (reading units, all three axes together), axis_rms (3,) the per-axis
    RMS, and sigma = √(SSR / (3 (N − 4))), the unbiased per-axis noise estimate.
    """
    m = np.asarray(samples, dtype=float)
    X = _design(reference)
    if m.shape != (len(X), 3):
        raise ValueError("samples must be N×3 like reference")
    P, *_ = np.linalg.lstsq(X, m, rcond=None)  # 4×3: rows 0–2 = Wᵀ, row 3 = bᵀ
    W = P[:3].T
    b = P[3]
    res = m - X @ P
    ssr = float(np.sum(res * res))
    return {"offset": b, "matrix": np.linalg.inv(W), "forward": W,
            "residual_rms": float(np.sqrt(ssr / len(m))), "axis_rms": np.sqrt(np.mean(res * res, axis=0)),
            "sigma": float(np.sqrt(ssr / (3 * (len(m) - 4))))}


def jacobian(reference) -> np.ndarray:
    """∂(m − W r − b)/∂θ in fluxcal's order θ = [b (3), W row-major (9)]: 3N × 12, reading-major rows."""
    r = np.asarray(reference, dtype=float)
    J = np.zeros((len(r), 3, 12))
    for a in range(3):
        J[:, a, a] = -1.0
        J[:, a, 3 + 3 * a:6 + 3 * a] = -r
    return J.reshape(-1, 12)


def crlb_vector(reference, sigma) -> np.ndarray:
    """Cramér–Rao bound (12×12 covariance) of (W row-major, b) for m = W r + b + N(0, σ² I), or N(0, Σ) when
    `sigma` is the 3×3 noise covariance Σ between the axes.

    Each output axis i has its own parameters θ_i = (W[i, 0], W[i, 1], W[i, 2], b[i]) and the same
    design X = [r, 1], so cov(θ_i, θ_l) = Σ_il (XᵀX)⁻¹: with σ² I different axes are uncorrelated. Arranged in
    the module's order: W entries at 3 i + j, b[i] at 9 + i. Least squares attains this bound exactly (with the
    same regressors on every axis, generalised least squares with Σ is least squares axis by axis).
    """
    X = _design(reference)
    G = np.linalg.inv(X.T @ X)  # 4×4 over (w_i0, w_i1, w_i2, b_i)
    noise = float(sigma) ** 2 * np.eye(3) if np.ndim(sigma) == 0 else np.asarray(sigma, dtype=float)
    order = np.array([[3 * i, 3 * i + 1, 3 * i + 2, 9 + i] for i in range(3)]).ravel()
    out = np.zeros((12, 12))
    out[np.ix_(order, order)] = np.kron(noise, G)
    return out


__all__ = ["crlb_vector", "fit_vector", "jacobian"]
