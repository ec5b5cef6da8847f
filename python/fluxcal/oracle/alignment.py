"""Reference magnetometer-to-accelerometer alignment (dot-product invariance), SciPy only.

At rest, down d_k = −f_k/|f_k| and the field direction ĥ_k (magnetometer axes) keep a fixed angle:
d_k · R ĥ_k = sin δ for the rotation R (magnetometer → accelerometer axes) and the dip δ. Least squares over a
rotation vector and δ with `scipy.optimize.least_squares`, from R = I and δ from the median of d·ĥ (it needs
the axes roughly aligned to start: within some tens of degrees); then, since both vectors are noisy, the root
(`scipy.optimize.root`) of the bias-corrected normal equations Jᵀe + σ̂² sin δ (Σ_k R ĥ_k × d_k, 0) = 0 (the
noise in J correlates with the noise in e), and the dip's noise bias divided out.
`crlb` is the bound of that model for
direction noise σ (radians, the two vectors together): every residual has variance σ² cos²δ.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares, root
from scipy.spatial.transform import Rotation


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def align_to_gravity(field, specific_force) -> dict:
    """R (3×3), dip (radians) and the covariance of (rotation vector perturbation, dip) from least squares."""
    h, d = _unit(field), -_unit(specific_force)

    def residuals(p):
        return np.einsum("ij,ij->i", d, Rotation.from_rotvec(p[:3]).apply(h)) - np.sin(p[3])

    def jacobian(p):  # over (a small rotation applied after R, δ), as the C++ one
        v = Rotation.from_rotvec(p[:3]).apply(h)
        return np.column_stack([np.cross(v, d), np.full(len(d), -np.cos(p[3]))])

    def noise(p):  # σ_h² + σ_f² (per axis) from the residual variance σ² cos² δ
        return np.sum(residuals(p) ** 2) / (len(d) - 4) / np.cos(p[3]) ** 2

    def unbiased_normal_equations(p):
        jac = jacobian(p)
        g = jac.T @ residuals(p)
        g[:3] += noise(p) * np.sin(p[3]) * jac[:, :3].sum(axis=0)
        return g

    start = np.r_[0.0, 0.0, 0.0, np.arcsin(np.clip(np.median(np.einsum("ij,ij->i", d, h)), -1, 1))]
    fit = least_squares(residuals, start, xtol=1e-14, ftol=1e-14, gtol=1e-14)
    p = root(unbiased_normal_equations, fit.x, tol=1e-14).x
    p[3] = np.arctan2(np.sin(p[3]), abs(np.cos(p[3])))  # the same sin δ, |δ| ≤ 90°
    rotation = Rotation.from_rotvec(p[:3]).as_matrix()
    jac, sigma2 = jacobian(p), noise(p) * np.cos(p[3]) ** 2
    # noise bias: E[d̃·ṽ] = sin δ (1 − σ_h² − σ_f²) for direction noise σ per axis
    dip = float(np.arcsin(np.clip(np.sin(p[3]) / (1 - noise(p)), -1, 1)))
    return {"rotation": rotation, "dip": dip, "covariance": sigma2 * np.linalg.inv(jac.T @ jac),
            "residual_rms": float(np.sqrt(np.mean(residuals(p) ** 2)))}


def crlb(field_directions, down, rotation, dip: float, sigma: float) -> np.ndarray:
    """Cramér–Rao bound (4×4) of (small rotation about x, y, z; dip) for residual noise σ cos δ."""
    v = _unit(field_directions) @ np.asarray(rotation).T
    d = _unit(down)
    jac = np.column_stack([np.cross(v, d), np.full(len(d), -np.cos(dip))])
    return (sigma * np.cos(dip)) ** 2 * np.linalg.inv(jac.T @ jac)
