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
