"""Reference Newey–West covariance for estimates from readings correlated in time (what
fluxcal's refine/fit_vector report when their residuals fail a Ljung–Box test).

For least squares θ̂ with Jacobian J and residuals r, the scores of reading t are g_t = Σ_a J_ta r_ta
(one row of J per residual, `per_reading` consecutive rows a reading). The sandwich covariance is
F⁻¹ S F⁻¹ with F = JᵀJ and S the long-run covariance of the scores, prewhitened as Andrews & Monahan
(1992) with a diagonal first-order autoregression: per column a_j = Σ g_t g_{t−1} / Σ g_{t−1}² clipped
to ±0.97, the Bartlett-weighted long-run covariance (statsmodels' S_hac_simple) of the whitened
e_t = g_t − a ∘ g_{t−1} (t ≥ 1), recoloured S = D S* D with D = diag(1/(1 − a)). The bandwidth is the cube
root of the mean cubed Politis–White block length of the whitened columns (arch's optimal_block_length,
circular)."""
from __future__ import annotations

import numpy as np
from statsmodels.stats.sandwich_covariance import S_hac_simple
from arch.bootstrap import optimal_block_length
from statsmodels.tsa.stattools import acf

from .timeseries import ljung_box


def scores(jacobian, residuals, per_reading: int = 1) -> np.ndarray:
    J = np.asarray(jacobian, dtype=float)
    r = np.asarray(residuals, dtype=float).ravel()
    return (J * r[:, None]).reshape(-1, per_reading, J.shape[1]).sum(axis=1)


def bandwidth(g) -> int:
    g = np.asarray(g, dtype=float)
    g = g[:, np.ptp(g, axis=0) > 0]
    b = optimal_block_length(g)["circular"].to_numpy()
    return int(np.clip(np.ceil(np.cbrt(np.mean(b**3))), 1, len(g) - 1))


PREWHITENING_CLIP = 0.97  # Andrews & Monahan's bound on the autoregressive coefficients


def prewhitened_long_run(g, lags: int | None = None):
    """(S, lags, a): the prewhitened long-run covariance of the scores (see the module's docstring),
    S* over `lags` (`bandwidth` of the whitened scores when None), and the coefficients a."""
    g = np.asarray(g, dtype=float)
    x, y = g[:-1], g[1:]
    den = np.sum(x * x, axis=0)
    a = np.where(den > 0, np.sum(x * y, axis=0) / np.where(den > 0, den, 1.0), 0.0)
    a = np.clip(a, -PREWHITENING_CLIP, PREWHITENING_CLIP)
    e = y - x * a
    lags = bandwidth(e) if lags is None else int(lags)
    d = 1.0 / (1.0 - a)
    return d[:, None] * S_hac_simple(e, nlags=lags) * d[None, :], lags, a


def newey_west_covariance(jacobian, residuals, per_reading: int = 1, lags: int | None = None, hessian=None):
    """(covariance, lags): the sandwich F⁻¹ S F⁻¹ × N/(N − p) (N readings, p parameters: the usual
    small-sample correction), S prewhitened and over `lags` of the whitened scores (`bandwidth` when None); F is
    JᵀJ, or the cost's `hessian` when given."""
    J = np.asarray(jacobian, dtype=float)
    g = scores(J, residuals, per_reading)
    S, lags, _ = prewhitened_long_run(g, lags)
    Finv = np.linalg.inv(J.T @ J if hessian is None else hessian)
    n, p = g.shape
    return Finv @ S @ Finv * n / (n - p), lags


def residual_test(residuals, per_reading: int = 1) -> dict:
    """Ljung–Box (20 lags, or N/5) on each residual axis, Bonferroni over the axes, and the mean lag-1
    autocorrelation — the test that switches fluxcal to the Newey–West covariance."""
    r = np.asarray(residuals, dtype=float).reshape(-1, per_reading)
    lags = min(20, len(r) // 5)
    p = min(ljung_box(r[:, a], lags)["p_value"] for a in range(per_reading))
    return {"ljung_box_p": min(1.0, p * per_reading),
            "lag1": float(np.mean([acf(r[:, a], nlags=1, fft=False)[1] for a in range(per_reading)]))}
