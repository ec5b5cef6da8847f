"""Reference TWOSTEP solvers: the same estimators as the C++ core (cpp/include/fluxcal/twostep.hpp),
computed the textbook way — explicit design matrices in the papers' own layout solved by
np.linalg.lstsq, and scipy.optimize.least_squares for the iterated steps (the core uses one-pass
normal equations, moment sums and its own Gauss–Newton)."""
from __future__ import annotations

import numpy as np
from scipy import special
from scipy.optimize import least_squares

# Field magnitudes within this relative spread count as one magnitude (as in the core).
CONSTANT_FIELD = 1e-6
# A gain known worse than this (relative standard error) gets no noise-bias correction (TwoStep2DOptions's default).
POORLY_DETERMINED = 0.02
# Readings whose field is within this many noise σ keep their magnitude as the target and are left out of the
# Jacobian term (as in the core): the O(σ²) expansion does not hold there.
EXPANSION_REACH = 5.0


def _lstsq_scaled(H, z):
    """Least squares with the columns scaled to unit norm (a standard conditioning step)."""
    norms = np.linalg.norm(H, axis=0)
    norms[norms == 0] = 1.0
    x, *_ = np.linalg.lstsq(H / norms, z, rcond=None)
    return x / norms


# ---- 2-D (seed 000) ------------------------------------------------------------------------------------

def twostep_2d_first_step(readings, field_norms) -> dict:
    """Closed-form two-step estimate. The paper's layout (eq. 8, H = [−2ĥx, −2ĥy, ĥy², 1, h²],
    x = (bx, r·by, r, bx² + r·by², −γx²), r = (γx/γy)²) with the sign of z corrected: z = −ĥx².
    Readings are centred on their mean first (the estimator does not depend on the origin)."""
    m = np.asarray(readings, dtype=float)
    h = np.asarray(field_norms, dtype=float)
    mean = m.mean(axis=0)
    hx, hy = (m - mean).T
    one = np.ones_like(hx)
    constant = np.ptp(h) <= CONSTANT_FIELD * h.max()
    if not constant:
        H = np.column_stack([-2 * hx, -2 * hy, hy**2, one, h**2])
        x = _lstsq_scaled(H, -hx**2)
        gx2 = -x[4]
    else:
        # x4' = x4 − γx² h²: the h² column merges with the constant one; x4 = x1² + x2²/x3.
        H = np.column_stack([-2 * hx, -2 * hy, hy**2, one])
        x = _lstsq_scaled(H, -hx**2)
        gx2 = (x[0] ** 2 + x[1] ** 2 / x[2] - x[3]) / np.mean(h**2)
    b = np.array([x[0], x[1] / x[2]]) + mean
    gain = np.sqrt([gx2, gx2 / x[2]])
    return {"offset": b, "gain": gain, "constant_field": bool(constant), "state": x}


def _rice_mean(nu, s):
    """E|v + ε|, |v| = ν, ε 2-D Gaussian of σ = s per axis: s√(π/2)·L½(−ν²/2s²) with exponentially scaled Bessel
    functions (scipy.stats.rice.mean overflows beyond ν/s ≈ 40); s = 0 gives ν."""
    z = (nu / np.where(s > 0, s, 1.0)) ** 2 / 4
    mean = s * np.sqrt(np.pi / 2) * ((1 + 2 * z) * special.i0e(z) + 2 * z * special.i1e(z))
    return np.where(s > 0, mean, nu)


def twostep_2d(readings, field_norms, refine: bool = True, noise_bias_correction: bool = True) -> dict:
    """First step, then (refine) least squares on the Sampson residual (ρ_k − h_k)/|∇ρ_k|, ρ_k = √((ĥx − bx)²/γx² +
    (ĥy − by)²/γy²) and ∇ its gradient in the reading: the reading's distance from its field's ellipse. With
    noise_bias_correction (σ² the first fit's residuals' mean square over N − 4; both gains known to 2 % or better):
    solved again towards each reading's target — its Rice mean E|h_k + ε| (_rice_mean), ε the noise across its direction in field units, less
    σ²(q₄/q − q)/h_k, the normaliser's move (q = ûᵀΓ⁻²û, q₄ = ûᵀΓ⁻⁴û) — then moved by σ²(JᵀJ)⁻¹Σ∂J_k/∂n_k, the
    Jacobian's move along each reading's normal (SciPy's Jacobian, central differences in the readings); a reading
    whose h_k is within EXPANSION_REACH noise σ keeps h_k and is left out of that sum."""
    first = twostep_2d_first_step(readings, field_norms)
    if not refine:
        return first
    m = np.asarray(readings, dtype=float)
    h = np.asarray(field_norms, dtype=float)

    def residual(p, targets, m=m):
        hx, hy = (m[:, 0] - p[0]) / p[2], (m[:, 1] - p[1]) / p[3]
        rho = np.hypot(hx, hy)
        return (rho - targets) * rho / np.hypot(hx / p[2], hy / p[3])

    def fit(p0, targets):
        return least_squares(residual, p0, args=(targets,), method="lm", x_scale="jac", xtol=1e-15, ftol=1e-15,
                             gtol=1e-15)

    sol = fit(np.concatenate([first["offset"], first["gain"]]), h)
    sigma2 = sol.fun @ sol.fun / (len(h) - 4)
    gain_se = np.sqrt(sigma2 * np.diag(np.linalg.pinv(sol.jac.T @ sol.jac))[2:]) / np.abs(sol.x[2:])
    if noise_bias_correction and gain_se.max() <= POORLY_DETERMINED:  # (a gain known worse: no O(σ²) correction)
        p = sol.x
        a, c = (m[:, 0] - p[0]) / p[2], (m[:, 1] - p[1]) / p[3]
        rho2 = a**2 + c**2
        across = (c**2 / p[2] ** 2 + a**2 / p[3] ** 2) / rho2  # (field per reading)² across ρ's direction
        q = (a**2 / p[2] ** 2 + c**2 / p[3] ** 2) / rho2
        q4 = (a**2 / p[2] ** 4 + c**2 / p[3] ** 4) / rho2
        noise = np.sqrt(sigma2 * across)
        targets = np.where(h > EXPANSION_REACH * noise, _rice_mean(h, noise) - sigma2 * (q4 / q - q) / h, h)
        sol = fit(p, targets)
        p = sol.x
        # Σ_k ∂J_k/∂n_k: J by central differences in the parameters, then along each reading's normal ∇ρ/|∇ρ|
        a, c = (m[:, 0] - p[0]) / p[2], (m[:, 1] - p[1]) / p[3]
        normal = np.column_stack([a / p[2], c / p[3]])
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        # readings whose field lies within EXPANSION_REACH noise σ of 0 are left out of this term (as in the core)
        across = (c**2 / p[2] ** 2 + a**2 / p[3] ** 2) / (a**2 + c**2)
        keep = targets > EXPANSION_REACH * np.sqrt(sigma2 * across)
        step = 1e-4 * np.ptp(m, axis=0).max() / 2

        def jacobian(x, shifted=m, aims=targets):  # central differences in the parameters
            dp = 1e-6 * np.maximum(np.abs(x), 1e-3)
            return np.column_stack([(residual(x + dp[j] * np.eye(4)[j], aims, shifted)
                                     - residual(x - dp[j] * np.eye(4)[j], aims, shifted)) / (2 * dp[j])
                                    for j in range(4)])

        near, aims = m[keep], targets[keep]
        dj = (jacobian(p, near + step * normal[keep], aims).sum(axis=0)
              - jacobian(p, near - step * normal[keep], aims).sum(axis=0)) / (2 * step)
        sol.x = p + sigma2 * np.linalg.solve(sol.jac.T @ sol.jac, dj)
        sol.fun, sol.jac = residual(sol.x, targets), jacobian(sol.x)
    # covariance of (bx, by, γx, γy): s²(JᵀJ)⁻¹ with SciPy's Jacobian at the solution (γ's sign made positive)
    flip = np.concatenate([np.ones(2), np.sign(sol.x[2:])])
    J = sol.jac * flip
    covariance = (sol.fun @ sol.fun / (len(h) - 4)) * np.linalg.inv(J.T @ J)
    return {"offset": sol.x[:2], "gain": np.abs(sol.x[2:]), "constant_field": first["constant_field"],
            "first_step": first, "covariance": covariance}


# ---- 3-D (Alonso & Shuster 2002) ----------------------------------------------------------------------

def _sym(v):
    return np.array([[v[0], v[3], v[4]], [v[3], v[1], v[5]], [v[4], v[5], v[2]]])


def _sqrtm_spd(M):
    w, V = np.linalg.eigh(M)
    if np.any(w <= 0):
        raise ValueError("oracle: not positive definite")
    return (V * np.sqrt(w)) @ V.T


def _sampson(p, u, H2, mu):
    """The Sampson residuals (|A(u − o)|² − H_k² − μ_k)/|M (u − o)| at p = (o, M's 00 11 22 01 02 12)."""
    d = u - p[:3]
    M = _sym(p[3:])
    return (np.einsum("ij,jk,ik->i", d, M, d) - H2 - mu) / np.linalg.norm(d @ M, axis=1)


def _jacobian(p, u, H2, mu, step=1e-6):
    """∂r_k/∂p by central differences (each step 1e-6 of the parameter's scale)."""
    scales = np.r_[np.full(3, max(1.0, np.abs(p[:3]).max())), np.full(6, np.abs(p[3:]).max())]
    J = np.empty((len(u), 9))
    for j in range(9):
        e = np.zeros(9)
        e[j] = step * scales[j]
        J[:, j] = (_sampson(p + e, u, H2, mu) - _sampson(p - e, u, H2, mu)) / (2 * e[j])
    return J


# The Jacobian's move is taken where every parameter's standard error is below this many `tolerance` (as in the core).
BIAS_MOVE_TOLERANCE = 10.0


def _without_noise_bias(u, H2, p, mu, sigma, tolerance):
    """The noise's O(σ²) bias taken off a converged Sampson fit (the core's second step does the same, as refine's
    noise_bias_correction): each reading's noise mean μ_k = σ²(tr M − 2 n̂ᵀM n̂) along its normal n̂ = M(u − o)/|M(u −
    o)|, where E[r_k] = 0, and least squares again with those — always, whatever the coverage; then, only when every
    parameter's standard error (var r F⁻¹ at that fit) is below BIAS_MOVE_TOLERANCE × `tolerance` of its scale (1/√λ̄
    for o, λ̄ = tr M/(3 mean H_k²)·mean H_k² for M), p += F⁻¹ 2σ² Σ ∂J_k/∂n̂ (E[J_k r_k] = 2σ² ∂J_k/∂n̂), ∂J/∂n̂ by
    central differences of J in the readings (1e-4 of the mean radius). Both over the readings whose surface lies
    beyond 5σ from the centre along their normal (nearer, no μ_k and no term). σ² from the residuals, var r ≈ 4σ²,
    unless given."""
    n = len(u)
    r = _sampson(p, u, H2, mu)
    var_r = 4 * sigma**2 if sigma is not None else np.sum(r**2) / (n - 9)
    M = _sym(p[3:])
    v = (u - p[:3]) @ M
    q = np.einsum("ij,jk,ik->i", v, M, v) / np.sum(v * v, axis=1)
    # where the expansion holds: the surface's distance from the centre along the normal beyond 5 σ (else no μ_k and
    # no Jacobian term: the terms are O(σ) there, as in 2-D)
    within = np.einsum("ij,ij->i", u - p[:3], v) / np.linalg.norm(v, axis=1) > 5.0 * np.sqrt(var_r / 4)
    mus = np.where(within, var_r / 4 * (np.trace(M) - 2 * q), 0.0)
    p = least_squares(lambda x: _sampson(x, u, H2, mus), p, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15).x
    M = _sym(p[3:])
    J = _jacobian(p, u, H2, mus)
    try:
        se = np.sqrt(var_r * np.diag(np.linalg.inv(J.T @ J)))
    except np.linalg.LinAlgError:  # (a singular F: no move, as in the core)
        return p
    mean_eigen = np.trace(M) / 3 / H2.mean()  # (the core's N = M / mean H_k²)
    loose = BIAS_MOVE_TOLERANCE * tolerance
    if not (np.all(se[:3] < loose / np.sqrt(mean_eigen)) and np.all(se[3:] < loose * mean_eigen * H2.mean())):
        return p
    v = (u - p[:3]) @ M
    normal = within[:, None] * v / np.linalg.norm(v, axis=1)[:, None]
    h = 1e-4 / np.sqrt(np.trace(M) / 3 / H2.mean())
    dJ = (_jacobian(p, u + h * normal, H2, mus) - _jacobian(p, u - h * normal, H2, mus)).sum(axis=0) / (2 * h)
    return p + np.linalg.solve(J.T @ J, var_r / 2 * dJ)


def twostep(samples, field_norm, iterate: bool = True, noise_sigma: float = -1.0,
            determined_tolerance: float = 0.01) -> dict:
    """A&S TWOSTEP with a constant field magnitude H, or each reading's H_k (`field_norm` N values), in
    coordinates u = (m − mean)/std.

    First step: centred least squares of z_k = |u_k|² on L_k = [−(v² − u²), −(w² − u²), −2uv, −2uw, −2vw, 2u,
    2v, 2w] (E with tr E = 0 eliminated through E11; c) and, when the H_k differ, H_k² with a free coefficient;
    then M = I + E, o = M⁻¹c and the scale from the mean H_k². Second step (iterate): least_squares on the Sampson
    residuals (|A(u − o)|² − H_k² − μ)/|M (u − o)| over (o, M = A²) (r_k = |A(u − o)|² − H_k² over its gradient in
    the readings: its σ around the ellipsoid), with μ = −¼ of the r_k's variance weighted by w_k = (tr M/3)/|M (u −
    o)|² about their weighted mean (or −σ² tr A²/3 for a known noise σ, 0 for none: the noise mean of r_k weighted
    by 1/|M (u − o)|², whose noise is correlated with r_k's), repeated with μ updated until it stops changing — the
    fixed point the core's scoring reaches."""
    B = np.asarray(samples, dtype=float)
    mean, std = B.mean(axis=0), B.std()
    u = (B - mean) / std
    Hs = np.broadcast_to(np.asarray(field_norm, dtype=float), len(u)) / std
    H2 = Hs**2
    changing = np.std((Hs / Hs.mean()) ** 2 - 1.0) > 1e-6  # (the core's test)
    x, y, w = u.T
    z = (u * u).sum(axis=1)
    L = np.column_stack([-(y * y - x * x), -(w * w - x * x), -2 * x * y, -2 * x * w, -2 * y * w, 2 * x, 2 * y, 2 * w]
                        + ([H2] if changing else []))
    th = _lstsq_scaled(L - L.mean(axis=0), z - z.mean())
    E = _sym([-th[0] - th[1], th[0], th[1], th[2], th[3], th[4]])
    c = th[5:8]
    kappa = z.mean() - L.mean(axis=0) @ th
    M = np.eye(3) + E
    o = np.linalg.solve(M, c)
    rho2 = kappa + (th[8] * H2.mean() if changing else 0.0) + o @ M @ o  # the quadric's radius² at the mean H_k²
    M = M * H2.mean() / rho2
    Hbar = Hs.mean()

    if iterate:
        def raw(p):
            d = u - p[:3]
            return np.einsum("ij,jk,ik->i", d, _sym(p[3:]), d) - H2

        def gradient(p):  # |M (u − o)|: r_k's gradient in the readings, over 2
            return np.linalg.norm((u - p[:3]) @ _sym(p[3:]), axis=1)

        def noise_mean(p):
            if noise_sigma == 0:
                return 0.0
            if noise_sigma > 0:
                return -((noise_sigma / std) ** 2) * np.trace(_sym(p[3:])) / 3.0
            r = raw(p)  # w_k var r_k = (4/3) σ² tr M: each weighted by w_k, about their weighted mean
            w = np.trace(_sym(p[3:])) / 3.0 / gradient(p) ** 2
            mean = np.sum(w * r) / np.sum(w)
            return -0.25 * np.mean(w * (r - mean) ** 2)

        p = np.concatenate([o, M[[0, 1, 2, 0, 0, 1], [0, 1, 2, 1, 2, 2]]])
        for _ in range(100):
            mu = noise_mean(p)
            p = least_squares(lambda q: (raw(q) - mu) / gradient(q), p, method="lm", xtol=1e-15, ftol=1e-15,
                              gtol=1e-15).x
            if abs(noise_mean(p) - mu) <= 1e-14 * Hbar**2:
                break
        if noise_sigma != 0 and len(u) > 9:
            p = _without_noise_bias(u, H2, p, mu, noise_sigma / std if noise_sigma > 0 else None,
                                    determined_tolerance)
        o, M = p[:3], _sym(p[3:])

    A = _sqrtm_spd(M)  # h = std·A_u(u − o) = A_u (m − offset): the std cancels
    return {"offset": mean + std * o, "matrix": A, "field_norm": float(np.mean(field_norm))}


def twostep_covariance(samples, field_norm, offset, matrix) -> np.ndarray:
    """Covariance of [b0 b1 b2 a00 a01 a02 a11 a12 a22] at a TWOSTEP result, from its objective Σ r_k² written in
    those parameters: the Sampson residual r_k = (|A(m_k − b)|² − H_k² − μ)/|A² (m_k − b)|, μ the residuals' mean
    weighted by 1/|A² (m_k − b)|² (the noise mean), J_k its gradient by central differences. From 30 readings the
    HC2 sandwich B⁻¹ M B⁻¹, B = Σ J Jᵀ, M = Σ r² J Jᵀ/(1 − h_k) with h_k = J_kᵀ B⁻¹ J_k the leverage; up to 10,
    s² B⁻¹ with s² = Σ r²/(N − 9); a linear blend between. (The core forms the same in its normalised quadric's
    parameters, analytically, and carries it over by the delta method.)"""
    m = np.asarray(samples, dtype=float)
    H2 = np.broadcast_to(np.asarray(field_norm, dtype=float), len(m)) ** 2
    upper = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]

    def parts(theta):
        A = np.zeros((3, 3))
        for v, (i, j) in zip(theta[3:], upper):
            A[i, j] = A[j, i] = v
        d = m - theta[:3]
        R = np.sum((d @ A.T) ** 2, axis=1) - H2
        return R, np.linalg.norm(d @ (A @ A).T, axis=1)

    theta0 = np.concatenate([np.asarray(offset, dtype=float), [np.asarray(matrix)[i, j] for i, j in upper]])
    R0, G0 = parts(theta0)
    mu = np.sum(R0 / G0**2) / np.sum(1.0 / G0**2)  # (held at the result: the core's μ is no free parameter)

    def residual(theta):
        R, G = parts(theta)
        return (R - mu) / G

    r = residual(theta0)
    J = np.empty((len(m), 9))
    for k in range(9):
        step = 1e-6 * max(abs(theta0[k]), np.abs(theta0[3:]).max() if k >= 3 else np.abs(m).max())
        up, down = theta0.copy(), theta0.copy()
        up[k] += step
        down[k] -= step
        J[:, k] = (residual(up) - residual(down)) / (2 * step)
    n, p = J.shape
    B_inv = np.linalg.inv(J.T @ J)
    plain = np.sum(r**2) / (n - p) * B_inv
    share = float(np.clip((n - 10) / 20, 0.0, 1.0))  # the sandwich's share: none at 10 readings, whole from 30
    if share == 0.0:
        return plain
    leverage = np.einsum("ij,jk,ik->i", J, B_inv, J)
    g = (r / np.sqrt(1.0 - np.minimum(leverage, 0.99)))[:, None] * J
    return share * (B_inv @ (g.T @ g) @ B_inv) + (1.0 - share) * plain
