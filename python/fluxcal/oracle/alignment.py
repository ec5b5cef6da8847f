"""Reference magnetometer-to-accelerometer alignment (dot-product invariance), SciPy only.

At rest, down d_k = −f_k/|f_k| and the field direction ĥ_k (magnetometer axes) keep a fixed angle: the dip each
reading shows, arcsin(d_k · R ĥ_k), is δ for the rotation R (magnetometer → accelerometer axes). Least squares on
arcsin(d_k · R ĥ_k) − δ over a rotation vector and δ with `scipy.optimize.least_squares`, from R = I and δ from the
median (it needs the axes roughly aligned to start: within some tens of degrees), then the dip's noise bias
(−σ²/2 · tan δ) added back. `crlb` is the bound of that model for direction noise σ (radians, the two vectors
together): every residual has variance σ².

The covariance is the sandwich σ² H⁻¹ JᵀJ H⁻¹, H the cost's Hessian by central second differences (not the
Gauss–Newton JᵀJ: where the attitudes barely move about one axis the direction noise lends JᵀJ curvature the cost does
not have, and H takes it back).
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _dip_residuals(h, d, rotation):
    return np.arcsin(np.clip(np.einsum("ij,ij->i", d, h @ np.asarray(rotation).T), -1, 1))


def cost_hessian(field, specific_force, rotation, dip: float, step: float = 1e-4) -> np.ndarray:
    """The Hessian of ½Σe² over (small rotation applied after `rotation`, dip) by central second differences."""
    h, d = _unit(field), -_unit(specific_force)

    def half_cost(p):
        turned = Rotation.from_rotvec(p[:3]).as_matrix() @ rotation
        return 0.5 * np.sum((_dip_residuals(h, d, turned) - dip - p[3]) ** 2)

    eye = np.eye(4) * step
    return np.array([[(half_cost(a + b) - half_cost(a - b) - half_cost(b - a) + half_cost(-a - b)) / (4 * step ** 2)
                      for b in eye] for a in eye])


def align_to_gravity(field, specific_force) -> dict:
    """R (3×3), dip (radians) and the covariance of (small rotation applied after R, dip) from least squares."""
    h, d = _unit(field), -_unit(specific_force)

    def residuals(p):
        return _dip_residuals(h, d, Rotation.from_rotvec(p[:3]).as_matrix()) - p[3]

    start = np.r_[0.0, 0.0, 0.0, np.median(np.arcsin(np.clip(np.einsum("ij,ij->i", d, h), -1, 1)))]
    fit = least_squares(residuals, start, xtol=1e-14, ftol=1e-14, gtol=1e-14)
    rotation = Rotation.from_rotvec(fit.x[:3]).as_matrix()
    v = h @ rotation.T
    across = np.cross(v, d)
    jac = np.column_stack([across / np.linalg.norm(across, axis=1, keepdims=True), -np.ones(len(d))])
    sigma2 = np.sum(fit.fun ** 2) / (len(d) - 4)
    # noise across the two directions' plane widens their angle: the dip reads nearer 0 by ≈ σ²/2 · tan δ
    dip = float(fit.x[3] + 0.5 * sigma2 * np.tan(fit.x[3]))
    bread = np.linalg.inv(cost_hessian(field, specific_force, rotation, fit.x[3]))
    return {"rotation": rotation, "dip": dip, "covariance": sigma2 * bread @ jac.T @ jac @ bread,
            "residual_rms": float(np.sqrt(np.mean(fit.fun ** 2)))}


def crlb(field_directions, down, rotation, sigma: float) -> np.ndarray:
    """Cramér–Rao bound (4×4) of (small rotation about x, y, z; dip) for direction noise σ (the two vectors'
    together, per axis): the dip each reading shows has variance σ²."""
    v = _unit(field_directions) @ np.asarray(rotation).T
    across = np.cross(v, _unit(down))
    jac = np.column_stack([across / np.linalg.norm(across, axis=1, keepdims=True), -np.ones(len(v))])
    return sigma ** 2 * np.linalg.inv(jac.T @ jac)
