"""Reference magnitude-model refinement: scipy.optimize.least_squares (finite-difference Jacobian)
on the Sampson residual (|h| − H)|h|/|A h|, θ = [b (3), a00 a01 a02 a11 a12 a22]; covariance
σ̂² (JᵀJ)⁻¹ with σ̂² = Σr²/(N − 9)."""
from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares


def _matrix(theta):
    a = theta[3:]
    return np.array([[a[0], a[1], a[2]], [a[1], a[3], a[4]], [a[2], a[4], a[5]]])


def residuals(theta, m, H):
    A = _matrix(theta)
    h = (m - theta[:3]) @ A.T
    hn = np.linalg.norm(h, axis=1)
    return (hn - H) * hn / np.linalg.norm(h @ A.T, axis=1)


def refine(offset, matrix, field_norm, samples) -> dict:
    m = np.asarray(samples, dtype=float)
    w, V = np.linalg.eigh(np.asarray(matrix).T @ np.asarray(matrix))
    A = (V * np.sqrt(w)) @ V.T  # symmetric start
    theta0 = np.r_[offset, A[0, 0], A[0, 1], A[0, 2], A[1, 1], A[1, 2], A[2, 2]]
    sol = least_squares(residuals, theta0, args=(m, field_norm), method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    sigma2 = np.sum(sol.fun**2) / (len(m) - 9)
    cov = sigma2 * np.linalg.inv(sol.jac.T @ sol.jac)
    return {"parameters": sol.x, "offset": sol.x[:3], "matrix": _matrix(sol.x), "covariance": cov,
            "noise_sigma": np.sqrt(sigma2), "jacobian": sol.jac, "residuals": sol.fun}


def refine_terms(start, samples, features) -> np.ndarray:
    """The magnitude model with extra terms (fluxcal._core.refine_terms): readings corrected by
    m − Σ_j c_j f_j (features N × p × 3), then the Sampson residual; θ = [b, A (6), c]."""
    m = np.asarray(samples, dtype=float)
    f = np.asarray(features, dtype=float)
    w, V = np.linalg.eigh(np.asarray(start.matrix).T @ np.asarray(start.matrix))
    A = (V * np.sqrt(w)) @ V.T
    theta0 = np.r_[start.offset, A[0, 0], A[0, 1], A[0, 2], A[1, 1], A[1, 2], A[2, 2], np.zeros(f.shape[1])]

    def fun(theta):
        return residuals(theta[:9], m - np.einsum("p,npk->nk", theta[9:], f), start.field_norm)

    sol = least_squares(fun, theta0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    return sol.x
