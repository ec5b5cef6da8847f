"""NumPy/SciPy reference for fluxcal.drift.fit_drift: per-range polynomial least squares (numpy lstsq on
the raw Vandermonde matrix, no balancing), F-test with scipy.stats.f, optional AR whitening; the coefficients'
covariance from statsmodels' OLS on the (whitened) rows, or with no AR model whitening the rows and noise not
found white the sandwich P Vᵀ Σ V P under an AR model (order by AIC) of the residuals in time order, Σ = σ² L⁻¹L⁻ᵀ
from the sparse whitening filter L (scipy's sparse triangular solve) — the prewhitened Newey–West sandwich
(fluxcal.oracle.serial's, on arch's block lengths and statsmodels' S_hac_simple) only when no AR model can be fitted."""
from __future__ import annotations

import numpy as np
import statsmodels.api as sm
from scipy import stats
from scipy import sparse
from scipy.sparse.linalg import spsolve_triangular

from .serial import newey_west_covariance
from .timeseries import ar_aic, ar_fit, lagged


def _members(temp, edges, k):
    lo, hi = edges[k], edges[k + 1]
    last = k == len(edges) - 2
    return np.flatnonzero((temp >= lo) & ((temp < hi) | (last & (temp <= hi))))


def _rows(x, w, idx, ar, order, stretch):
    V = np.vander(x[idx], order + 1, increasing=True)
    target = w[idx]
    p = len(ar)
    if p == 0:
        return V, target
    # p consecutive predecessors in the range and in the same stretch between gaps in time
    keep = [j for j in range(p, idx.size) if idx[j - p] == idx[j] - p and stretch[idx[j - p]] == stretch[idx[j]]]
    keep = np.array(keep, dtype=int)
    Vw, tw = V[keep].copy(), target[keep].copy()
    for q in range(1, p + 1):
        Vw -= ar[q - 1] * V[keep - q]
        tw -= ar[q - 1] * target[keep - q]
    return Vw, tw


UNIT_ROOT = 0.98  # whitening AR coefficients summing above this: fitted unweighted


def separate_levels(x, width):
    """Levels of x in a range `width` wide: runs of sorted values whose steps stay within 5 % of the width,
    each counting 1 + its extent in 5 % steps (np.diff, np.split)."""
    v = np.sort(np.asarray(x, dtype=float))
    resolution = 0.05 * width
    if not resolution > 0 or not v[-1] > v[0]:
        return 1
    runs = np.split(v, np.nonzero(np.diff(v) > resolution)[0] + 1)
    return int(sum(1 + np.floor((r[-1] - r[0]) / resolution) for r in runs))


def covering_edges(select, breakpoints, min_samples=10):
    """The edges made to cover the data: outer edges at its ends, inner edges inside it kept, the thinnest
    range (fewer than min_samples) joined to its thinner neighbour until none is."""
    select = np.asarray(select, dtype=float)
    lo, hi = float(select.min()), float(select.max())
    if not hi > lo:
        return list(breakpoints)
    edges = [lo] + [float(e) for e in breakpoints[1:-1] if lo < e < hi] + [hi]
    while len(edges) > 2:
        counts = np.histogram(select, bins=edges)[0]  # [lo, hi) bins, the last one closed: as the core's ranges
        k = int(np.argmin(counts))
        if counts[k] >= min_samples:
            break
        last = len(counts) - 1
        drop = 1 if k == 0 else last if k == last else (k if counts[k - 1] <= counts[k + 1] else k + 1)
        del edges[drop]
    return edges


def fit_drift(select, x, w, breakpoints=(-20.0, 0.0, 30.0, 50.0), max_order=4, significance=0.05, whiten=True,
              whiten_max_order=10, min_samples=10, breaks=()):
    select, x, w = (np.asarray(v, dtype=float) for v in (select, x, w))
    stretch = np.zeros(w.size, int)
    stretch[np.asarray(breaks, dtype=int)] = 1
    stretch = np.cumsum(stretch)  # which stretch between the gaps in time each sample is in
    edges = covering_edges(select, breakpoints, min_samples)
    groups = [_members(select, edges, k) for k in range(len(edges) - 1)]
    same = np.array_equal(x, select)  # the device temperature as the regressor: the range's width, else x's span
    widths = [edges[k + 1] - edges[k] if same else np.ptp(x[g]) for k, g in enumerate(groups)]
    tops = [min(max_order, separate_levels(x[g], width) - 1, g.size - 3) for g, width in zip(groups, widths)]
    ar = np.zeros(0)
    white = False  # AIC found the noise white (else, with no AR model, the errors are Newey–West's)
    if whiten:
        resid = np.full(w.size, np.nan)
        for g, top in zip(groups, tops):
            V = np.vander(x[g], top + 1, increasing=True)
            resid[g] = w[g] - V @ np.linalg.lstsq(V, w[g], rcond=None)[0]
        inside = ~np.isnan(resid)
        series = resid[inside]
        # the stretches of the series: a new one where the stretch id changes
        series_breaks = np.flatnonzero(np.diff(stretch[inside]) != 0) + 1
        top = whiten_max_order
        while top > 0 and lagged(series, top, top, series_breaks)[1].size < top + 3:
            top -= 1
        while top > 0 and any(_rows(x, w, g, np.zeros(top), 0, stretch)[1].size < t + 3 for g, t in zip(groups, tops)):
            top -= 1  # each range keeps rows enough to test its orders
        p = int(np.argmin(ar_aic(series, top, series_breaks)))
        ar = ar_fit(series, p, series_breaks)[0] if p else np.zeros(0)
        white = top > 0 and p == 0
        if ar.size and ar.sum() > UNIT_ROOT:
            ar = np.zeros(0)
    segments = []
    for g, top in zip(groups, tops):
        def sse(m):
            V, t = _rows(x, w, g, ar, m, stretch)
            c = np.linalg.lstsq(V, t, rcond=None)[0]
            return c, np.sum((t - V @ c) ** 2), t.size

        m = 0
        c, s, rows = sse(0)
        while m < top:
            c1, s1, _ = sse(m + 1)
            dof = rows - m - 2
            f = (s - s1) / (s1 / dof)
            if not stats.f.sf(f, 1, dof) < significance:
                if m + 2 > top or rows - m - 3 <= 0:  # the step to m+1 failed: m+2 on its own 2 dof (a bowl)
                    break
                c2, s2, _ = sse(m + 2)
                if not stats.f.sf(0.5 * (s - s2) / (s2 / (rows - m - 3)), 2, rows - m - 3) < significance ** 2:
                    break
                m, c, s = m + 2, c2, s2
                continue
            m, c, s = m + 1, c1, s1
        V, t = _rows(x, w, g, ar, m, stretch)
        if len(ar) or white:
            covariance = sm.OLS(t, V).fit().cov_params()
        else:
            covariance = newey_west_covariance(V, t - V @ c)[0]  # replaced below when an AR model can be fitted
        segments.append({"order": m, "coefficients": c, "covariance": covariance})
    if not (len(ar) or white):
        noise = error_ar(x, w, groups, segments, stretch, whiten_max_order)
        if noise is not None:
            for seg, cov in zip(segments, ar_sandwich(x, w, groups, segments, stretch, noise)):
                seg["covariance"] = cov
    return segments, ar


def _in_time(groups, stretch):
    """The samples inside a range in time order, and the stretch each is in: a new one where a sample was left out
    or the stretch between gaps in time changes."""
    at = np.sort(np.concatenate(groups))
    new = np.r_[True, (np.diff(at) != 1) | (np.diff(stretch[at]) != 0)]
    return at, np.cumsum(new)


def _residuals(x, w, groups, segments):
    r = np.full(w.size, np.nan)
    for g, seg in zip(groups, segments):
        r[g] = w[g] - np.vander(x[g], seg["order"] + 1, increasing=True) @ seg["coefficients"]
    return r


def error_ar(x, w, groups, segments, stretch, max_order):
    """The AR model (order by AIC ≤ max_order, fewer when the series is short) of the unweighted fits' residuals in
    time order across the ranges, for their errors; None when none can be fitted. Coefficients summing above 1 are
    scaled to sum to 1."""
    at, piece = _in_time(groups, stretch)
    series = _residuals(x, w, groups, segments)[at]
    breaks = np.flatnonzero(np.diff(piece) != 0) + 1
    top = max(0, min(max_order, (series.size - 3) // 2))
    while top > 0 and lagged(series, top, top, breaks)[1].size < top + 3:
        top -= 1
    if top == 0 or np.all(series == series[0]):
        return None
    p = int(np.argmin(ar_aic(series, top, breaks)))
    a = ar_fit(series, p, breaks)[0] if p else np.zeros(0)
    return a / a.sum() if a.size and a.sum() > 1 else a


def ar_sandwich(x, w, groups, segments, stretch, a):
    """Each range's V⁺ Σ V⁺ᵀ (V⁺ = (VᵀV)⁻¹Vᵀ, numpy's SVD pseudo-inverse of its column-scaled Vandermonde rows, placed in the
    in-range samples' time order, zero elsewhere), Σ = σ² L⁻¹L⁻ᵀ, L the sparse lower-triangular whitening filter (1 on
    the diagonal, −a_q q below within a stretch), σ² = |L r|² / (N − Σ columns) of all the residuals r."""
    at, piece = _in_time(groups, stretch)
    n = at.size
    rows, cols, vals = [np.arange(n)], [np.arange(n)], [np.ones(n)]
    for q in range(1, len(a) + 1):
        i = np.arange(q, n)
        i = i[piece[i] == piece[i - q]]
        rows.append(i), cols.append(i - q), vals.append(np.full(i.size, -a[q - 1]))
    L = sparse.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))
    e = L @ _residuals(x, w, groups, segments)[at]
    sigma2 = e @ e / (n - sum(seg["order"] + 1 for seg in segments))
    row = np.empty(w.size, int)
    row[at] = np.arange(n)
    out = []
    for g, seg in zip(groups, segments):
        full = np.zeros((n, seg["order"] + 1))
        V = np.vander(x[g], seg["order"] + 1, increasing=True)
        scale = np.abs(V).max(axis=0)  # V⁺ = S⁻¹ (V S⁻¹)⁺: a cubic's raw columns (1 … 50³) cost 1e-9 of it
        full[row[g]] = (np.linalg.pinv(V / scale) / scale[:, None]).T
        Q = spsolve_triangular(L.T.tocsr(), full, lower=False)  # L⁻ᵀ V⁺ᵀ: V⁺ Σ V⁺ᵀ = σ² QᵀQ
        out.append(sigma2 * Q.T @ Q)
    return out


def play(x, half_width):
    """fluxcal.drift.play as a Python loop: the output clamped to within half_width of each input."""
    out = np.empty(len(x))
    state = float(x[0])
    for k, v in enumerate(np.asarray(x, dtype=float).tolist()):
        state = min(max(state, v - half_width), v + half_width)
        out[k] = state
    return out


def temperature_branch(temp, turn):
    """fluxcal.drift.temperature_branch at a given turn: +1 after a move up of more than `turn` from the play
    operator's state, −1 after one down, 0 before any."""
    branch = np.zeros(len(temp), dtype=int)
    state, side = float(temp[0]), 0
    for k, x in enumerate(np.asarray(temp, dtype=float).tolist()):
        if x > state + turn:
            state, side = x - turn, 1
        elif x < state - turn:
            state, side = x + turn, -1
        branch[k] = side
    return branch
