"""Reference magnitude-model refinement: scipy.optimize.least_squares (finite-difference Jacobian)
on the Sampson residual (|h| − H)|h|/|A h|, θ = [b (3), a00 a01 a02 a11 a12 a22]; covariance
σ̂² (JᵀJ)⁻¹ with σ̂² = Σr²/(N − 9), or with a robust loss (SciPy's `huber` / `cauchy`, `f_scale` =
fluxcal's loss_scale) Huber's (1981) σ̂² = K² [Σψ²/(N − 9)] / mean(ψ')², K = 1 + (p/N) var(ψ')/mean(ψ')²."""
from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares


def _matrix(theta):
    a = theta[3:]
    return np.array([[a[0], a[1], a[2]], [a[1], a[3], a[4]], [a[2], a[4], a[5]]])


def residuals(theta, m, H, axis_weights=None):
    """The Sampson residual; with axis_weights w (σ̄/σ_axis) the gradient's norm is taken in units of each axis's
    noise, |(h A)/w|: the distance to the ellipsoid in noise units."""
    A = _matrix(theta)
    h = (m - theta[:3]) @ A.T
    hn = np.linalg.norm(h, axis=1)
    g = h @ A.T
    return (hn - H) * hn / np.linalg.norm(g if axis_weights is None else g / np.asarray(axis_weights), axis=1)


def _psi(r, loss: str, scale: float):
    """ψ = d/dr of ½·scale²·ρ((r/scale)²) and its derivative, for SciPy's losses."""
    z = (r / scale) ** 2
    if loss == "huber":
        inside = z <= 1.0
        return np.where(inside, r, scale * np.sign(r)), inside.astype(float)
    if loss == "cauchy":
        return r / (1 + z), (1 - z) / (1 + z) ** 2
    raise ValueError(f"loss: {loss!r} is not one of linear, huber, cauchy")


def _jacobian(theta, m, H, step=1e-6):
    """Central differences of the plain residuals (SciPy's `jac` is rescaled by the loss)."""
    cols = []
    for j in range(len(theta)):
        h = step * max(1.0, abs(theta[j]))
        up, down = theta.copy(), theta.copy()
        up[j] += h
        down[j] -= h
        cols.append((residuals(up, m, H) - residuals(down, m, H)) / (2 * h))
    return np.column_stack(cols)


# θ (9) = P φ for each shape: the free parameters' columns (a sphere's one scale sets a00 = a11 = a22).
SHAPE_COLUMNS = {"sym": [[j] for j in range(9)],
                 "diag": [[0], [1], [2], [3], [6], [8]],
                 "sphere": [[0], [1], [2], [3, 6, 8]]}


def shape_matrix(shape: str) -> np.ndarray:
    P = np.zeros((9, len(SHAPE_COLUMNS[shape])))
    for j, rows in enumerate(SHAPE_COLUMNS[shape]):
        P[rows, j] = 1.0
    return P


def refine(offset, matrix, field_norm, samples, loss: str = "linear", loss_scale: float = 1.0,
           shape: str = "sym") -> dict:
    """shape "diag" / "sphere": the free parameters φ (θ = P φ, the start projected by least squares), and
    "parameters" and "covariance" are φ's. `field_norm` is one |h| or one per reading (the residuals
    broadcast over it: fluxcal.refine's field_norms)."""
    m = np.asarray(samples, dtype=float)
    w, V = np.linalg.eigh(np.asarray(matrix).T @ np.asarray(matrix))
    A = (V * np.sqrt(w)) @ V.T  # symmetric start
    P = shape_matrix(shape)
    phi0 = np.linalg.lstsq(P, np.r_[offset, A[0, 0], A[0, 1], A[0, 2], A[1, 1], A[1, 2], A[2, 2]], rcond=None)[0]

    def fun(phi, m, H):
        return residuals(P @ phi, m, H)

    n, p = len(m), P.shape[1]
    if loss == "linear":
        sol = least_squares(fun, phi0, args=(m, field_norm), method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
        jac = sol.jac
        sigma2 = np.sum(sol.fun**2) / (n - p)
        variance = sigma2
    else:
        sol = least_squares(fun, phi0, args=(m, field_norm), method="trf", loss=loss, f_scale=loss_scale,
                            xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=2000)
        jac = _jacobian(P @ sol.x, m, field_norm) @ P
        sigma2 = np.sum(sol.fun**2) / (n - p)
        psi, dpsi = _psi(sol.fun, loss, loss_scale)
        K = 1 + p / n * np.var(dpsi) / np.mean(dpsi) ** 2
        variance = K**2 * np.sum(psi**2) / (n - p) / np.mean(dpsi) ** 2
    cov = variance * np.linalg.inv(jac.T @ jac)
    return {"parameters": sol.x, "offset": sol.x[:3], "matrix": _matrix(P @ sol.x), "covariance": cov,
            "noise_sigma": np.sqrt(sigma2), "jacobian": jac, "residuals": sol.fun}


def refine_terms(start, samples, features, field_norms=None, axis_weights=None) -> np.ndarray:
    """The magnitude model with extra terms (fluxcal._core.refine_terms): readings corrected by
    m − Σ_j c_j f_j (features N × p × 3), then the Sampson residual against start.field_norm, or against each
    reading's own |field| (`field_norms`, N values), each axis weighted by `axis_weights` (the diagnosis's axes of
    unequal noise); θ = [b, A (6), c]."""
    H = start.field_norm if field_norms is None else np.asarray(field_norms, dtype=float)
    m = np.asarray(samples, dtype=float)
    f = np.asarray(features, dtype=float)
    w, V = np.linalg.eigh(np.asarray(start.matrix).T @ np.asarray(start.matrix))
    A = (V * np.sqrt(w)) @ V.T
    theta0 = np.r_[start.offset, A[0, 0], A[0, 1], A[0, 2], A[1, 1], A[1, 2], A[2, 2], np.zeros(f.shape[1])]

    def fun(theta):
        return residuals(theta[:9], m - np.einsum("p,npk->nk", theta[9:], f), H, axis_weights)

    sol = least_squares(fun, theta0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    return sol.x


def vector_terms(samples, reference, features, axis_weights=None, held=None) -> tuple:
    """The vector model with extra terms (fluxcal._core.refine_terms with reference vectors) by weighted linear least
    squares: m = b + W r + Σ_j c_j f_j, each axis's equations × axis_weights[k] (default 1); `held` {θ index: value}
    holds parameters (a scale-only model's off-diagonal W). Returns θ = [b, W (row-major), c], its covariance
    σ̂² (XᵀX)⁻¹ over the free parameters (zero for held ones) with σ̂² = Σr²/(3N − free), the weighted residuals
    (reading-major) and their Jacobian ∂r/∂θ (−X, weighted)."""
    m, r, f = (np.asarray(x, dtype=float) for x in (samples, reference, features))
    n, p = len(m), f.shape[1]
    w = np.ones(3) if axis_weights is None else np.asarray(axis_weights, dtype=float)
    X = np.zeros((n, 3, 12 + p))
    for k in range(3):
        X[:, k, k] = 1.0
        X[:, k, 3 + 3 * k:6 + 3 * k] = r
    X[:, :, 12:] = np.swapaxes(f, 1, 2)
    X, y = (X * w[None, :, None]).reshape(3 * n, -1), (m * w).ravel()
    theta = np.zeros(12 + p)
    for i, value in (held or {}).items():
        theta[i] = value
    free = np.setdiff1d(np.arange(12 + p), list(held or {}))
    theta[free] = np.linalg.lstsq(X[:, free], y - X @ theta, rcond=None)[0]
    e = y - X @ theta
    covariance = np.zeros((12 + p, 12 + p))
    covariance[np.ix_(free, free)] = e @ e / (3 * n - len(free)) * np.linalg.inv(X[:, free].T @ X[:, free])
    return theta, covariance, e, -X
