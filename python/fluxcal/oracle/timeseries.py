"""NumPy/SciPy references for fluxcal.timeseries (clarity over speed; no shared code with the core)."""
from __future__ import annotations

import numpy as np
from scipy import stats


def reverse_arrangement(x, subseries=20, threshold=1.96):
    x = np.asarray(x, dtype=float)
    # Sub-series k holds samples [k·N/l, (k+1)·N/l) (integer division), as in fluxcal.
    n, l = x.size, subseries
    edges = [k * n // l for k in range(l + 1)]
    means = np.array([x[edges[k]:edges[k + 1]].mean() for k in range(l)])
    a = sum(1 for i in range(l) for j in range(i + 1, l) if means[i] > means[j])
    e = l * (l - 1) / 4.0
    var = l * (2 * l + 5) * (l - 1) / 72.0
    u = (a - e) / np.sqrt(var)
    return {"arrangements": a, "expected": e, "variance": var, "u": u, "stationary": abs(u) < threshold,
            "means": means}


def normality(x):
    x = np.asarray(x, dtype=float)
    s, k = stats.skew(x), stats.kurtosis(x, fisher=False)
    jb = x.size / 6.0 * (s ** 2 + (k - 3.0) ** 2 / 4.0)
    return {"skewness": s, "kurtosis": k, "jarque_bera": jb, "p_value": stats.chi2.sf(jb, 2)}


def ljung_box(x, lags, model_df=0, breaks=()):
    """With breaks: the lag-k sums and pair counts of each np.split piece, added; lags without a pair dropped."""
    x = np.asarray(x, dtype=float)
    d = x - x.mean()
    n = d.size
    pieces = np.split(d, breaks) if len(breaks) else [d]
    sums = np.array([sum(np.dot(s[k:], s[:s.size - k]) for s in pieces if s.size > k) for k in range(1, lags + 1)])
    pairs = np.array([sum(s.size - k for s in pieces if s.size > k) for k in range(1, lags + 1)])
    used = pairs > 0
    acf = sums[used] / np.dot(d, d)
    q = n * (n + 2) * np.sum(acf ** 2 / pairs[used])
    df = int(used.sum()) - model_df
    return {"statistic": q, "p_value": stats.chi2.sf(q, df) if df > 0 else np.nan, "lags": int(used.sum())}


def lagged(y, p, first, breaks=()):
    """Rows t = first … N−1 of [y_{t−1} … y_{t−p}] and the targets y_t; with breaks (gaps in time) the rows
    of each stretch between them, stacked: np.split at the breaks, then the same per stretch."""
    y = np.asarray(y, dtype=float)
    if len(breaks):
        parts = [lagged(s, p, first) for s in np.split(y, breaks) if s.size > first]
        if not parts:
            return np.empty((0, p)), np.empty(0)
        return np.vstack([X for X, _ in parts]), np.concatenate([t for _, t in parts])
    X = np.column_stack([y[first - j:y.size - j] for j in range(1, p + 1)]) if p else np.empty((y.size - first, 0))
    return X, y[first:]


def ar_aic(y, max_order, breaks=()):
    """AIC(p) = n ln(SSR_p/n) + 2p on the common sample t = max_order … N−1 (lstsq per order)."""
    out = []
    for p in range(max_order + 1):
        X, t = lagged(y, p, max_order, breaks)
        ssr = np.sum((t - X @ np.linalg.lstsq(X, t, rcond=None)[0]) ** 2) if p else np.sum(t ** 2)
        out.append(t.size * np.log(ssr / t.size) + 2 * p)
    return np.array(out)


def ar_fit(y, p, breaks=()):
    """Batch least squares on every row t = p … N−1 (what AutoReg does); (coefficients, sigma2)."""
    X, t = lagged(y, p, p, breaks)
    a = np.linalg.lstsq(X, t, rcond=None)[0]
    return a, np.mean((t - X @ a) ** 2)


def rls(y, p, init_samples=20, forgetting=1.0, breaks=()):
    """Recursive least squares with forgetting, started by batch least squares on the first rows."""
    X, t = lagged(y, p, p, breaks)
    n0 = min(t.size, max(init_samples, 2 * p))
    theta = np.linalg.lstsq(X[:n0], t[:n0], rcond=None)[0]
    P = np.linalg.inv(X[:n0].T @ X[:n0])
    P = 0.5 * (P + P.T)
    for phi, target in zip(X[n0:], t[n0:]):
        g = P @ phi
        denom = forgetting + phi @ g
        theta = theta + g * ((target - phi @ theta) / denom)
        # np.outer(g, g) is exactly symmetric: with forgetting < 1 an antisymmetric rounding part of P
        # would grow as forgetting^−t (the downdate never shrinks it).
        P = (P - np.outer(g, g) / denom) / forgetting
    return theta


def weighted_ls(y, p, init_samples=20, forgetting=1.0):
    """What RLS with forgetting λ computes, in one batch: weighted least squares on the n rows of
    `lagged(y, p, p)`, recursive row i weighted λ^(n−1−i) and the n0 rows of the batch start all
    λ^(n−n0) (the start's information is scaled by λ at each of the n − n0 recursive steps)."""
    X, t = lagged(y, p, p)
    n0 = min(t.size, max(init_samples, 2 * p))
    n = t.size
    w = np.concatenate([np.full(n0, forgetting ** (n - n0)), forgetting ** (n - 1 - np.arange(n0, n))])
    sw = np.sqrt(w)
    return np.linalg.lstsq(X * sw[:, None], t * sw, rcond=None)[0]


def weighted_ls_covariance(y, p, sigma2, init_samples=20, forgetting=1.0):
    """The covariance of weighted_ls's coefficients when each row's noise has variance sigma2: the sandwich
    σ² P (Xᵀ W² X) P with P = (Xᵀ W X)⁻¹ (σ² P for λ = 1)."""
    X, t = lagged(y, p, p)
    n0 = min(t.size, max(init_samples, 2 * p))
    n = t.size
    w = np.concatenate([np.full(n0, forgetting ** (n - n0)), forgetting ** (n - 1 - np.arange(n0, n))])
    P = np.linalg.inv(X.T @ (w[:, None] * X))
    return sigma2 * P @ (X.T @ ((w * w)[:, None] * X)) @ P


def remove_trend(x, degree=1):
    """x minus its least-squares polynomial in the sample index (numpy.polynomial on the scaled index)."""
    x = np.asarray(x, dtype=float)
    s = np.linspace(-1.0, 1.0, x.size)
    return x - np.polynomial.polynomial.polyval(s, np.polynomial.polynomial.polyfit(s, x, degree))


def preprocess(x, subseries=20, threshold=1.96, trend_degree=1, breaks=()):
    """Seed 001 S2: zero-mean; reverse-arrangement test of np.diff; if it fails, np.diff again and detrend.
    With breaks (gaps in time) np.diff of each np.split piece, concatenated."""
    x = np.asarray(x, dtype=float)
    z = x - x.mean()
    pieces = [np.diff(s) for s in np.split(z, breaks)]
    d1 = np.concatenate(pieces)
    test = reverse_arrangement(d1, subseries, threshold)
    series = d1 if test["stationary"] else remove_trend(np.concatenate([np.diff(p) for p in pieces]), trend_degree)
    return {"mean": x.mean(), "series": series, "differences": 1 if test["stationary"] else 2,
            "stationarity": test, "stationarity_after": reverse_arrangement(series, subseries, threshold),
            "normality": normality(series)}
