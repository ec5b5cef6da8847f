"""Axes of unequal noise in the magnitude model, by scaling the readings (fluxcal.refine, fluxcal.diagnose).

With each axis weighted by w = σ̄/σ_axis (D = diag(w)), |(m − b) A| = |(D m − D b) A'| for the symmetric
A' = root(D⁻¹ A² D⁻¹): the magnitude model of the scaled readings has the same form, and its Sampson residual is the
distance to the ellipsoid with every axis in units of its own noise — σ̄ in every direction, the maximum-likelihood
residual for Gaussian noise σ_axis on each axis. The solvers fit the scaled readings; these map their parameters,
Jacobian and covariance back to b and A.
"""
from __future__ import annotations

import numpy as np

from . import _core

UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))  # the magnitude model's a00 a01 a02 a11 a12 a22
DIAGONAL = (0, 3, 5)  # a00 a11 a22 among UPPER (the "diag" shape's own)


def symmetric_root(A: np.ndarray, left: np.ndarray) -> np.ndarray:
    """The symmetric positive root of (A L)ᵀ(A L) = L AᵀA L for L = diag(left): the symmetric matrix whose magnitudes
    |A'(m − b)| of readings scaled by 1/left equal those of A (a magnitude sees A only through AᵀA; a matrix that is
    not symmetric, a rotation times one, gives its polar factor, as the core's refine takes it)."""
    lam, V = np.linalg.eigh(left[:, None] * (A.T @ A) * left[None, :])
    return (V * np.sqrt(np.clip(lam, 0.0, None))) @ V.T


def scaled_start(offset, matrix, w: np.ndarray) -> tuple:
    """(D b, A') of a start calibration for the readings scaled by w."""
    return np.asarray(offset, dtype=float) * w, symmetric_root(np.asarray(matrix, dtype=float), 1.0 / w)


def root_jacobian(A: np.ndarray, w: np.ndarray) -> np.ndarray:
    """∂a'/∂a (6 × 6, the upper triangles row by row) of A' = symmetric_root(A, 1/w): A'² = D⁻¹ A² D⁻¹, so
    A' dA' + dA' A' = D⁻¹ (dA A + A dA) D⁻¹, solved in A''s eigenbasis (a Sylvester equation)."""
    lam, V = np.linalg.eigh(symmetric_root(A, 1.0 / w))
    out = np.empty((6, 6))
    for j, (r, c) in enumerate(UPPER):
        E = np.zeros((3, 3))
        E[r, c] = E[c, r] = 1.0
        X = (E @ A) / np.outer(w, w)
        Y = V.T @ (X + X.T) @ V / (lam[:, None] + lam[None, :])
        dA = V @ Y @ V.T
        out[:, j] = [dA[i, k] for i, k in UPPER]
    return out


def symmetric(a) -> np.ndarray:
    """The symmetric matrix of its upper triangle a00 a01 a02 a11 a12 a22."""
    return np.array([[a[0], a[1], a[2]], [a[1], a[3], a[4]], [a[2], a[4], a[5]]])


def unscaled(parameters, w: np.ndarray, n_matrix: int = 6) -> tuple:
    """The parameters [D b, A' (its `n_matrix` free entries: 6 symmetric, 3 diagonal), rest] of a fit to readings
    scaled by w, back in the readings' own units: (θ, A, M) with M = ∂θ'/∂θ at the solution (D on the offset,
    `root_jacobian` on the matrix, 1 on the rest) — J = J' M, C = M⁻¹ C' M⁻ᵀ."""
    theta_w = np.asarray(parameters, dtype=float)
    a = np.zeros(6)
    a[list(range(6)) if n_matrix == 6 else list(DIAGONAL)] = theta_w[3:3 + n_matrix]
    A = symmetric_root(symmetric(a), w)
    M = np.eye(len(theta_w))
    M[:3, :3] = np.diag(w)
    full = root_jacobian(A, w)
    M[3:3 + n_matrix, 3:3 + n_matrix] = full if n_matrix == 6 else full[np.ix_(DIAGONAL, DIAGONAL)]
    entries = [A[i, k] for i, k in UPPER]
    matrix = entries if n_matrix == 6 else [entries[j] for j in DIAGONAL]
    theta = np.concatenate([theta_w[:3] / w, matrix, theta_w[3 + n_matrix:]])
    return theta, A, M


def map_fit(fit: dict, w: np.ndarray, n_matrix: int = 6) -> np.ndarray:
    """A core fit's result (refine, refine_terms) of readings scaled by w, mapped back in place: parameters,
    standard errors, covariance and the Jacobian of the (weighted) residuals, offset and matrix. Returns M = ∂θ'/∂θ."""
    theta, A, M = unscaled(fit["parameters"], w, n_matrix)
    T = np.linalg.inv(M)
    fit["parameters"] = theta
    fit["covariance"] = T @ np.asarray(fit["covariance"]) @ T.T
    fit["standard_errors"] = np.sqrt(np.clip(np.diag(fit["covariance"]), 0.0, None))
    if "jacobian" in fit:
        fit["jacobian"] = np.asarray(fit["jacobian"]) @ M  # ∂r'/∂θ of the weighted residuals r'
    fit["offset"] = theta[:3]
    fit["matrix"] = A
    return M


def noise_values(noise_sigma, name: str = "noise_sigma") -> np.ndarray:
    """One σ for every axis, or three (x, y, z: a datasheet's per axis), each positive and finite; ValueError naming
    `name` otherwise."""
    try:
        if isinstance(noise_sigma, (bool, np.bool_, str)):
            raise TypeError
        values = np.atleast_1d(np.asarray(noise_sigma, dtype=float))
    except (TypeError, ValueError):
        raise ValueError(f"{name}: need a number (the readings' white-noise σ), or three (x, y, z), got "
                         f"{noise_sigma!r}") from None
    if values.ndim != 1 or len(values) not in (1, 3):
        got = f"{values.size} values" if values.ndim == 1 else f"an array of shape {values.shape}"
        raise ValueError(f"{name}: need one σ for every axis, or three (x, y, z), got {got}")
    if not (np.all(np.isfinite(values)) and np.all(values > 0)):
        raise ValueError(f"{name}: need a positive finite σ (the readings' white noise, in their units), "
                         f"got {noise_sigma!r}")
    return values


def sampson(samples: np.ndarray, offset, matrix: np.ndarray, field_norm, axis_weights=None) -> np.ndarray:
    """The magnitude model's residual, Sampson's (|h| − H)|h|/|A h| with h = A(m − b) (in reading units: the distance
    to the ellipsoid to first order), H one |field| or each reading's; with `axis_weights` w (σ̄/σ_axis) the
    gradient's norm in units of each axis's noise, |A h / w|."""
    h = (samples - offset) @ matrix.T
    size = np.linalg.norm(h, axis=1)
    g = h @ matrix.T
    return (size - field_norm) * size / np.linalg.norm(g if axis_weights is None else g / axis_weights, axis=1)


def sampson_jacobian(offset, matrix, samples: np.ndarray, field_norm) -> np.ndarray:
    """∂r/∂θ (N × 9, θ = [b, A's upper triangle]) of the Sampson residual r = (s − H)s/|g|, s = |h|, h = A(m − b),
    g = A h, at `offset`, `matrix` (symmetric) and each reading's H — in closed form (the core's refine, whose solution
    this is taken at, returns no Jacobian; a refit to get one would move off a solution its noise-bias correction set):
    dr = (2s − H)/|g| ds − (s − H)s/|g|³ gᵀdg, ds = hᵀdh/s, with dh = dA v − A db and dg = dA h + A dh, v = m − b."""
    A = np.asarray(matrix, dtype=float)
    v = samples - np.asarray(offset, dtype=float)
    h = v @ A.T
    g = h @ A.T
    Ag = g @ A.T
    s = np.linalg.norm(h, axis=1)
    gn = np.linalg.norm(g, axis=1)
    H = np.broadcast_to(np.asarray(field_norm, dtype=float), s.shape)
    on_size = ((2 * s - H) / (s * gn))[:, None]  # ∂r/∂s / s: multiplies hᵀdh
    on_g = ((s - H) * s / gn ** 3)[:, None]  # −∂r/∂g / g: multiplies gᵀdg
    J = np.empty((len(samples), 9))
    J[:, :3] = -on_size * g + on_g * (Ag @ A.T)  # dh = −A db: hᵀdh = −gᵀdb, gᵀdg = −gᵀA²db
    for j, (i, k) in enumerate(UPPER):  # dA = E_ik + E_ki (E_ii on the diagonal)
        hdh = h[:, i] * v[:, k] + (h[:, k] * v[:, i] if i != k else 0.0)
        gdg = (g[:, i] * h[:, k] + Ag[:, i] * v[:, k]
               + ((g[:, k] * h[:, i] + Ag[:, k] * v[:, i]) if i != k else 0.0))
        J[:, 3 + j] = on_size[:, 0] * hdh - on_g[:, 0] * gdg
    return J


def weights_of(noise_sigma) -> np.ndarray | None:
    """The weights σ̄/σ_axis (σ̄ the RMS) of a noise_sigma of three unequal values; None for none, one, or three equal."""
    if noise_sigma is None:
        return None
    sigma = np.broadcast_to(noise_values(noise_sigma), 3)
    return None if np.ptp(sigma) == 0 else np.sqrt(np.mean(sigma ** 2)) / sigma


def restate_summary(result: dict, samples: np.ndarray, w: np.ndarray) -> None:
    """A refine result of readings scaled by w (already `map_fit`), its summary's coverage and conditioning restated
    in the readings' own axes: the field's directions as the mapped calibration gives them (the scaled fit's are
    turned by a fixed rotation, and its direction bins differ), the readings' spread, and the Fisher condition of
    the mapped Jacobian (column-scaled, as the core judges it). |h| statistics need nothing: |h| is the same."""
    from .calibration import Calibration

    summary = result["summary"]
    h = Calibration(offset=result["offset"], matrix=result["matrix"], field_norm=result["field_norm"]).apply(samples)
    u = h / np.linalg.norm(h, axis=1, keepdims=True)
    summary["direction_coverage"] = float(_core.direction_coverage(h, 16384))
    summary["direction_eigenvalues"] = np.linalg.eigvalsh(u.T @ u / len(u)).tolist()
    spread = np.linalg.eigvalsh(np.cov(samples.T, bias=True))
    summary["coverage_ratio"] = float(np.sqrt(max(spread[0], 0.0) / spread[2])) if spread[2] > 0 else 0.0
    J = np.asarray(result["jacobian"])
    info = J.T @ J
    d = np.where(np.diag(info) > 0, 1.0 / np.sqrt(np.clip(np.diag(info), 1e-300, None)), 0.0)
    lam = np.linalg.eigvalsh(d[:, None] * info * d[None, :])
    result["fisher_condition"] = summary["condition_number"] = float(lam[-1] / lam[0]) if lam[0] > 0 else np.inf
