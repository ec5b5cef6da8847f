"""Reference planar (2-D) fit: the same estimator as the C++ core's fit_planar (cpp/include/fluxcal/planar.hpp),
computed the textbook way — the direct ellipse fit as Halir & Flusser write it (explicit design matrices), the
reference TWOSTEP 2-D (fluxcal.oracle.twostep) as the other start, scipy.optimize.least_squares (MINPACK's
Levenberg–Marquardt) on the N Sampson residuals with their N×k Jacobian, the covariance from the pseudo-inverse of
that Jacobian and, for a relative scale, a numerical delta method. The core instead accumulates JᵀJ in one pass per
step in its own Levenberg–Marquardt and differentiates the relative scale analytically.

Model h = A (u − b), |h_k| = H_k, A symmetric positive definite as Σ c_j B_j over a shape's basis (circle: I; diag:
E00, E11; sym: E00, E01 + E10, E11); residual r_k = (|h_k| − H_k)|h_k|/|A h_k| (reading units); after the first
solve the targets are raised by σ̂²‖A‖_F²/(4 H_k) (the tangential noise's bias of |h|) and it is solved again.
Readings correlated in time: the Newey–West sandwich of fluxcal.oracle.serial (statsmodels' Bartlett sums, arch's
block length) over the N×k Jacobian and the residuals, taken by the core's rule (refine's): when the residuals fail
Ljung–Box at α and it widens an error, or when it widens one ≥ 1.5× with ≥ 10 readings per parameter.
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from .serial import newey_west_covariance, residual_test
from .twostep import twostep_2d

SHAPES = ("circle", "diag", "sym")
DETERMINED = 0.01


def _basis(shape: str) -> list[np.ndarray]:
    """The matrices A is a combination of, for each shape (A = Σ c_j B_j)."""
    if shape == "circle":
        return [np.eye(2)]
    if shape == "diag":
        return [np.diag([1.0, 0.0]), np.diag([0.0, 1.0])]
    return [np.diag([1.0, 0.0]), np.array([[0.0, 1.0], [1.0, 0.0]]), np.diag([0.0, 1.0])]


def _coefficients(A: np.ndarray, shape: str) -> np.ndarray:
    """A start's matrix projected onto a shape's coefficients."""
    if shape == "circle":
        return np.array([np.sqrt(abs(np.linalg.det(A)))])
    if shape == "diag":
        return np.array([A[0, 0], A[1, 1]])
    return np.array([A[0, 0], 0.5 * (A[0, 1] + A[1, 0]), A[1, 1]])


def _matrix(c, basis) -> np.ndarray:
    return sum(ci * B for ci, B in zip(c, basis))


def direct_ellipse(x: np.ndarray):
    """Halir & Flusser's direct least-squares ellipse fit of 2-D points: (centre, E) with
    (x − centre)ᵀ E (x − centre) = 1, or None when the points determine no ellipse (a line, a point)."""
    D1 = np.column_stack([x[:, 0] ** 2, x[:, 0] * x[:, 1], x[:, 1] ** 2])
    D2 = np.column_stack([x[:, 0], x[:, 1], np.ones(len(x))])
    S1, S2, S3 = D1.T @ D1, D1.T @ D2, D2.T @ D2
    try:
        T = -np.linalg.solve(S3, S2.T)
        M = S1 + S2 @ T
        M = np.array([M[2] / 2, -M[1], M[0] / 2])  # C1⁻¹ M, C1 = [[0, 0, 2], [0, −1, 0], [2, 0, 0]]
        values, vectors = np.linalg.eig(M)
    except np.linalg.LinAlgError:
        return None
    vectors = np.real(vectors)
    cond = 4 * vectors[0] * vectors[2] - vectors[1] ** 2
    ok = np.flatnonzero(cond > 0)
    if ok.size == 0:
        return None
    a1 = vectors[:, ok[0]]
    a, bxy, c = a1
    d, e, f = T @ a1
    Q = np.array([[a, bxy / 2], [bxy / 2, c]])
    if np.trace(Q) < 0:
        Q, d, e, f = -Q, -d, -e, -f
    try:
        centre = -0.5 * np.linalg.solve(Q, [d, e])
    except np.linalg.LinAlgError:
        return None
    k = centre @ Q @ centre - f
    if not (k > 0 and np.all(np.linalg.eigvalsh(Q) > 0)):
        return None
    return centre, Q / k


def _sqrtm(E: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eigh(E)
    return (V * np.sqrt(np.maximum(w, 0.0))) @ V.T


def _starts(u: np.ndarray, norms) -> tuple[list, float]:
    """Start values (name, b, A) in u's units, and the reference radius R0 of a relative scale (the direct fit's
    geometric-mean radius, or the readings' RMS distance from their mean)."""
    centre = u.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((u - centre) ** 2, axis=1))))
    starts = []
    direct = direct_ellipse((u - centre) / scale)
    if direct is not None:
        c, E = direct
        E = E / scale ** 2                                   # (u − b)ᵀ E (u − b) = 1
        radius = float(np.linalg.det(E) ** -0.25)            # √(semi-axes' product)
        starts.append(("direct ellipse fit", centre + scale * c, _sqrtm(E)))
    else:
        radius = scale
    T = np.full(len(u), radius) if norms is None else norms
    try:
        ts = twostep_2d(u, T)  # reading = γ ⊙ h + b
        if np.all(np.isfinite(ts["offset"])) and np.all(np.isfinite(ts["gain"])):
            starts.append(("twostep_2d", np.asarray(ts["offset"]), np.diag(1.0 / np.asarray(ts["gain"]))))
    except (ValueError, np.linalg.LinAlgError, FloatingPointError):
        pass
    return starts, radius


def sampson(U: np.ndarray, T: np.ndarray, p: np.ndarray, basis: list) -> np.ndarray:
    """The Sampson residuals (|h| − T)|h|/|A h|, h = A (U − b), at p = (b, c)."""
    A = _matrix(p[2:], basis)
    h = (U - p[:2]) @ A
    rho = np.linalg.norm(h, axis=1)
    return (rho - T) * rho / np.maximum(np.linalg.norm(h @ A, axis=1), 1e-300)


def sampson_jacobian(U: np.ndarray, T: np.ndarray, p: np.ndarray, basis: list) -> np.ndarray:
    """Their N×k Jacobian by (b, c), by the chain rule on vectors: r = (ρ² − Tρ)/γ, ρ = |h|, γ = |g|, g = A h;
    ∂h/∂b_i = −A e_i, ∂h/∂c_j = B_j d, ∂g = (∂A) h + A ∂h."""
    A = _matrix(p[2:], basis)
    d = U - p[:2]
    h = d @ A
    g = h @ A
    rho = np.maximum(np.linalg.norm(h, axis=1), 1e-300)
    gam = np.maximum(np.linalg.norm(g, axis=1), 1e-300)
    dr_drho = (2 * rho - T) / gam
    dr_dgam = -(rho - T) * rho / gam ** 2

    def column(dh, dg):
        return dr_drho * np.sum(h * dh, axis=1) / rho + dr_dgam * np.sum(g * dg, axis=1) / gam

    cols = []
    for i in range(2):
        dh = np.broadcast_to(-A[:, i], h.shape)
        cols.append(column(dh, dh @ A))
    for B in basis:
        dh = d @ B
        cols.append(column(dh, h @ B + dh @ A))
    return np.column_stack(cols)


def _least_squares(U, T, p0, basis, max_iterations, tolerance):
    """scipy least_squares (MINPACK LM) from p0: (p, Σr², J, converged, function evaluations)."""
    res = least_squares(lambda p: sampson(U, T, p, basis), p0, jac=lambda p: sampson_jacobian(U, T, p, basis),
                        method="lm", x_scale="jac", xtol=max(tolerance, 1e-15), ftol=1e-15, gtol=1e-15,
                        max_nfev=100 * max_iterations)
    return res.x, float(2 * res.cost), res.jac, bool(res.status > 0), int(res.nfev)


def fit_planar(readings, field_norms=None, shape: str = "sym", max_iterations: int = 100,
               tolerance: float = 1e-10, noise_bias_correction: bool = True, serial_correlation: str = "automatic",
               serial_correlation_alpha: float = 0.01) -> dict:
    """The planar fit of N×2 readings in one shape ("circle", "diag", "sym"); field_norms: one value, one per
    reading, or None (relative scale: det A = 1, field_norm the fitted mean radius). Returns what the core's
    fit_planar does: offset, matrix, field_norm, parameters, covariance, standard_errors, determined, sigma, rss,
    mean_radius, fisher_condition, residuals (reading units, against each target), start, converged, serial_correlation
    (lag1, ljung_box_p, lags, inflation, standard_errors_independent) and evaluations (MINPACK's function
    evaluations, the core counts iterations)."""
    u = np.asarray(readings, dtype=float)
    n = len(u)
    norms = None if field_norms is None else np.broadcast_to(np.asarray(field_norms, dtype=float), (n,)).copy()
    basis = _basis(shape)
    k = len(basis) + 2
    starts, radius = _starts(u, norms)
    if not starts:
        raise ValueError("readings: trace no ellipse (no start)")
    targets = np.full(n, radius) if norms is None else norms
    centre = u.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((u - centre) ** 2, axis=1))))
    tscale = float(np.mean(targets))
    U, Tn = (u - centre) / scale, targets / tscale
    best = None
    for name, b0, A0 in starts:  # every start, the lowest cost kept
        h = ((u - b0) / scale) @ A0
        An = A0 * np.mean(Tn) / np.mean(np.linalg.norm(h, axis=1))
        p0 = np.concatenate([(b0 - centre) / scale, _coefficients(An, shape)])
        if not np.all(np.isfinite(p0)):
            continue
        fit = _least_squares(U, Tn, p0, basis, max_iterations, tolerance)
        if np.all(np.isfinite(fit[0])) and np.all(np.linalg.eigvalsh(_matrix(fit[0][2:], basis)) > 0) and \
                (best is None or fit[1] < best[1][1]):
            best = (name, fit)
    if best is None:
        raise ValueError("readings: the planar fit found no ellipse from any start")
    start, (p, cost, J, converged, evaluations) = best
    fitted = Tn
    if noise_bias_correction:
        sigma2 = cost / (n - k)
        A = _matrix(p[2:], basis)
        fitted = Tn + sigma2 * float(np.sum(A * A)) / (4 * Tn)
        p, cost, J, converged, more = _least_squares(U, fitted, p, basis, max_iterations, tolerance)
        evaluations += more
    sigma2 = cost / (n - k)
    # Covariance σ̂² J⁺ J⁺ᵀ (the pseudo-inverse by SVD), back to u's units: b = centre + scale·β, A = A_n·tscale/scale.
    Jp = np.linalg.pinv(J)
    cov = independent = sigma2 * Jp @ Jp.T
    # (with "independent" the residuals are not tested: statsmodels' direct acf is O(N²), 0.5 s at N = 1e5)
    test = {"ljung_box_p": None, "lag1": None}
    lags, inflation = 0, 1.0
    if serial_correlation != "independent" and np.linalg.matrix_rank(J) == k and n // 5 >= 1:
        r = sampson(U, fitted, p, basis)
        test = residual_test(r)
        sandwich, nw_lags = newey_west_covariance(J, r)
        ratio = np.sqrt(np.diag(sandwich)) / np.sqrt(np.diag(independent))
        rejected = test["ljung_box_p"] < serial_correlation_alpha
        if serial_correlation == "newey_west" or (rejected and ratio.max() > 1) or (n >= 10 * k and ratio.max() >= 1.5):
            cov, lags, inflation = sandwich, nw_lags, float(ratio.max())
    Js = J / np.linalg.norm(J, axis=0)
    fisher_condition = float(np.linalg.cond(Js) ** 2)
    to = np.concatenate([[scale, scale], np.full(k - 2, tscale / scale)])
    values = np.concatenate([centre + scale * p[:2], p[2:] * tscale / scale])
    cov, independent = cov * np.outer(to, to), independent * np.outer(to, to)
    A = _matrix(values[2:], basis)
    field_norm = tscale
    if norms is None:
        def normalised(c):
            return c / np.sqrt(np.linalg.det(_matrix(c, basis)))
        c = values[2:]
        G = np.eye(k)
        eps = 1e-6 * max(1.0, float(np.max(np.abs(c))))
        for j in range(k - 2):
            step = np.zeros(k - 2)
            step[j] = eps
            G[2:, 2 + j] = (normalised(c + step) - normalised(c - step)) / (2 * eps)
        s = float(np.sqrt(np.linalg.det(A)))
        values = np.concatenate([values[:2], normalised(c)])
        cov, independent = G @ cov @ G.T, G @ independent @ G.T
        A = A / s
        field_norm = radius / s
        targets = np.full(n, field_norm)
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    se_independent = np.sqrt(np.maximum(np.diag(independent), 0.0))
    if lags:  # the widening of the reported parameters (after the delta method)
        inflation = float(np.max(se[se_independent > 0] / se_independent[se_independent > 0]))
    b = values[:2]
    h = (u - b) @ A
    rho = np.linalg.norm(h, axis=1)
    residuals = (rho - targets) * rho / np.maximum(np.linalg.norm(h @ A, axis=1), 1e-300)
    mean_radius = float(np.mean(np.linalg.norm(u - b, axis=1)))
    scales = np.concatenate([[mean_radius, mean_radius], np.full(k - 2, np.linalg.norm(A) / np.sqrt(2))])
    return {"offset": b, "matrix": A, "field_norm": float(field_norm), "parameters": values, "covariance": cov,
            "standard_errors": se, "determined": se_independent < DETERMINED * scales,
            "sigma": float(np.sqrt(sigma2) * scale),
            "rss": float(cost * scale ** 2), "mean_radius": mean_radius, "fisher_condition": fisher_condition,
            "residuals": residuals, "start": start, "converged": converged, "evaluations": evaluations,
            "serial_correlation": {**test, "lags": lags, "inflation": inflation,
                                   "standard_errors_independent": se_independent}}
