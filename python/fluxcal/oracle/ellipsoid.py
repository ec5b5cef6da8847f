"""Reference ellipsoid fit: the same estimator as the C++ core (algebraic least squares of the
general quadric with trace(M) = 1), computed the textbook way — the full N×10 design matrix, a
different normalisation (mean and standard deviation), and an SVD-based least-squares solve."""
from __future__ import annotations

import numpy as np


def fit_ellipsoid(samples, field_norm=None) -> dict:
    m = np.asarray(samples, dtype=float)
    mean = m.mean(axis=0)
    scale = m.std()
    u = (m - mean) / scale
    x, y, z = u.T
    one = np.ones_like(x)
    # Quadric uᵀMu + 2vᵀu + k with coefficients [M11 M22 M33 M12 M13 M23 v1 v2 v3 k].
    D = np.column_stack([x * x, y * y, z * z, 2 * x * y, 2 * x * z, 2 * y * z, 2 * x, 2 * y, 2 * z, one])
    # trace(M) = 1: M11 = 1 − M22 − M33, so D p = D[:,0] + (D[:,1:] − D[:,0] on the M22, M33 columns) q.
    Dq = D[:, 1:].copy()
    Dq[:, 0] -= D[:, 0]
    Dq[:, 1] -= D[:, 0]
    q, *_ = np.linalg.lstsq(Dq, -D[:, 0], rcond=None)
    p = np.concatenate([[1.0 - q[0] - q[1]], q])
    M = np.array([[p[0], p[3], p[4]], [p[3], p[1], p[5]], [p[4], p[5], p[2]]])
    v = p[6:9]
    k = p[9]
    c = -np.linalg.solve(M, v)
    rho2 = c @ M @ c - k
    B = M / rho2  # (u − c)ᵀ B (u − c) = 1
    w, V = np.linalg.eigh(B)
    if np.any(w <= 0):
        raise ValueError("oracle: not an ellipsoid")
    semi_axes = scale / np.sqrt(w)
    H = float(np.prod(semi_axes) ** (1 / 3)) if field_norm is None else float(field_norm)
    A = (H / scale) * (V * np.sqrt(w)) @ V.T
    return {"offset": mean + scale * c, "matrix": A, "field_norm": H, "quadric_trace1": p}


def _hermite(x, n, v):
    """t_n(x) with E[t_n(x0 + e)] = x0ⁿ for e ~ N(0, v)."""
    return [np.ones_like(x), x, x**2 - v, x**3 - 3 * v * x, x**4 - 6 * v * x**2 + 3 * v**2][n]


def fit_ellipsoid_als(samples, field_norm=None) -> dict:
    """Reference adjusted least squares (Markovsky, Kukush & Van Huffel 2004), computed per sample:
    the adjusted scatter ψ(v) = Σ_i [Π_axes t(·)] over every product of two design entries, and v
    from scipy's brentq on its smallest eigenvalue."""
    from scipy.optimize import brentq

    m = np.asarray(samples, dtype=float)
    mean, scale = m.mean(axis=0), m.std()
    u = (m - mean) / scale
    # design entries as (exponents, factor): u², v², w², 2uv, 2uw, 2vw, 2u, 2v, 2w, 1
    design = [((2, 0, 0), 1), ((0, 2, 0), 1), ((0, 0, 2), 1), ((1, 1, 0), 2), ((1, 0, 1), 2), ((0, 1, 1), 2),
              ((1, 0, 0), 2), ((0, 1, 0), 2), ((0, 0, 1), 2), ((0, 0, 0), 1)]

    def psi(v):
        out = np.empty((10, 10))
        for a, (ea, fa) in enumerate(design):
            for b, (eb, fb) in enumerate(design):
                e = [ea[k] + eb[k] for k in range(3)]
                out[a, b] = fa * fb * np.sum(_hermite(u[:, 0], e[0], v) * _hermite(u[:, 1], e[1], v)
                                             * _hermite(u[:, 2], e[2], v))
        return out / len(u)

    def lam(v):
        return np.linalg.eigvalsh(psi(v))[0]

    hi = 1e-8
    while lam(hi) > 0:
        hi *= 4
    v = brentq(lam, hi / 4 if hi > 1e-8 else 0.0, hi, xtol=1e-16, rtol=1e-14)
    w, vecs = np.linalg.eigh(psi(v))
    p = vecs[:, 0] / vecs[:3, 0].sum()
    M = np.array([[p[0], p[3], p[4]], [p[3], p[1], p[5]], [p[4], p[5], p[2]]])
    c = -np.linalg.solve(M, p[6:9])
    rho2 = c @ M @ c - p[9]
    wB, V = np.linalg.eigh(M / rho2)
    semi_axes = scale / np.sqrt(wB)
    H = float(np.prod(semi_axes) ** (1 / 3)) if field_norm is None else float(field_norm)
    A = (H / scale) * (V * np.sqrt(wB)) @ V.T
    return {"offset": mean + scale * c, "matrix": A, "field_norm": H, "noise_sigma": np.sqrt(v) * scale}
