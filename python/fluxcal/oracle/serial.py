"""Reference Newey–West covariance for estimates from readings correlated in time (what
fluxcal's refine/fit_vector report when their residuals fail a Ljung–Box test).

For least squares θ̂ with Jacobian J and residuals r, the scores of reading t are g_t = Σ_a J_ta r_ta
(one row of J per residual, `per_reading` consecutive rows a reading). The sandwich covariance is
F⁻¹ S F⁻¹ with F = JᵀJ and S the Bartlett-weighted long-run covariance of the scores (statsmodels'
S_hac_simple), the bandwidth the cube root of the mean cubed Politis–White block length of the score
columns (arch's optimal_block_length, circular)."""
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


def newey_west_covariance(jacobian, residuals, per_reading: int = 1, lags: int | None = None):
    """(covariance, lags): the sandwich F⁻¹ S F⁻¹ × N/(N − p) (N readings, p parameters: the usual
    small-sample correction), S over `lags` (`bandwidth` when None)."""
    J = np.asarray(jacobian, dtype=float)
    g = scores(J, residuals, per_reading)
    lags = bandwidth(g) if lags is None else int(lags)
    Finv = np.linalg.inv(J.T @ J)
    n, p = g.shape
    return Finv @ S_hac_simple(g, nlags=lags) @ Finv * n / (n - p), lags


def residual_test(residuals, per_reading: int = 1) -> dict:
    """Ljung–Box (20 lags, or N/5) on each residual axis, Bonferroni over the axes, and the mean lag-1
    autocorrelation — the test that switches fluxcal to the Newey–West covariance."""
    r = np.asarray(residuals, dtype=float).reshape(-1, per_reading)
    lags = min(20, len(r) // 5)
    p = min(ljung_box(r[:, a], lags)["p_value"] for a in range(per_reading))
    return {"ljung_box_p": min(1.0, p * per_reading),
            "lag1": float(np.mean([acf(r[:, a], nlags=1, fft=False)[1] for a in range(per_reading)]))}
