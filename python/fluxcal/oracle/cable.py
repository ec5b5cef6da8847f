"""Reference cable model and solver (NumPy/SciPy), independent of the C++ core (cable.hpp): the field by
the paper's own angle form (eqs. 2–4: |B| = μ0I/(2πr) split into radial/tangential by the sine and
cosine of the angle between the conductor's field and the sensor's radial direction, with arctan2), a
finite-difference Jacobian, and scipy.optimize.least_squares from a coarse grid for the inverse."""
from __future__ import annotations

import itertools

import numpy as np
from scipy.optimize import least_squares

MU0 = 1.25663706127e-6


def field(angles_rad, radius, positions, currents, axis_angles_rad=None) -> np.ndarray:
    """(M, 2) readings in each sensor's axes (radial, tangential when axis angles are 0)."""
    th = np.asarray(angles_rad, float)
    psi = np.zeros_like(th) if axis_angles_rad is None else np.asarray(axis_angles_rad, float)
    out = np.zeros((th.size, 2))
    for (cx, cy), current in zip(np.asarray(positions, float), np.asarray(currents, float)):
        sx, sy = radius * np.cos(th), radius * np.sin(th)
        r = np.hypot(sx - cx, sy - cy)
        magnitude = MU0 * current / (2 * np.pi * r)
        # direction of B: the conductor→sensor direction turned by +90°
        phi = np.arctan2(sy - cy, sx - cx) + np.pi / 2
        rel = phi - (th + psi)  # angle between B and the sensor's x axis
        out[:, 0] += magnitude * np.cos(rel)
        out[:, 1] += magnitude * np.sin(rel)
    return out


def jacobian_fd(angles_rad, radius, positions, currents, step=1e-9, axis_angles_rad=None) -> np.ndarray:
    """Central finite differences of the flattened readings over [x0, y0, …, I0, …]."""
    pos = np.asarray(positions, float)
    cur = np.asarray(currents, float)
    n = cur.size
    theta = np.concatenate([pos.ravel(), cur])

    def f(t):
        return field(angles_rad, radius, t[: 2 * n].reshape(n, 2), t[2 * n:], axis_angles_rad).ravel()

    J = np.zeros((2 * np.size(angles_rad), 3 * n))
    for k in range(3 * n):
        h = step * (radius if k < 2 * n else max(1.0, abs(theta[k])))
        e = np.zeros_like(theta)
        e[k] = h
        J[:, k] = (f(theta + e) - f(theta - e)) / (2 * h)
    return J


def uniform_field(angles_rad, field_t, axis_angles_rad=None) -> np.ndarray:
    """(M, 2) readings of a uniform field (bx, by) in each sensor's axes, by the angle between the field and
    the sensor's x axis."""
    th = np.asarray(angles_rad, float)
    psi = np.zeros_like(th) if axis_angles_rad is None else np.asarray(axis_angles_rad, float)
    rel = np.arctan2(field_t[1], field_t[0]) - (th + psi)
    return np.hypot(*field_t) * np.column_stack([np.cos(rel), np.sin(rel)])


def solve(angles_rad, radius, readings, n_conductors=2, bore=None, grid=7, background=False, sensor_sigma=None) -> dict:
    """Least squares (SciPy, trust-region reflective with bounds) from every grid combination's linear
    current fit; returns the lowest-cost solution, conductors sorted by x then y. background: a uniform field
    (bx, by) beside the conductors, fitted with the currents (returned as "background"). sensor_sigma: each
    sensor's noise σ (any common scale), its residuals weighted by the inverse."""
    bore = 0.4 * radius if bore is None else bore
    readings = np.asarray(readings, float).ravel()
    weight = np.ones(readings.size) if sensor_sigma is None else np.repeat(1.0 / np.asarray(sensor_sigma, float), 2)
    g = (np.arange(grid) + 0.5) * 2 * bore / grid - bore
    pts = [np.array([x, y]) for x in g for y in g if np.hypot(x, y) < bore]
    n = n_conductors
    uniform = [uniform_field(angles_rad, unit).ravel() for unit in ((1.0, 0.0), (0.0, 1.0))] if background else []
    nb = len(uniform)

    def currents_for(pos):
        G = np.column_stack([field(angles_rad, radius, [p], [1.0]).ravel() for p in pos] + uniform)
        c, *_ = np.linalg.lstsq(G * weight[:, None], readings * weight, rcond=None)
        return c, np.sum(((G @ c - readings) * weight) ** 2)

    seeds = []
    for combo in itertools.combinations(range(len(pts)), n):
        pos = [pts[k] for k in combo]
        c, cost = currents_for(pos)
        seeds.append((cost, np.concatenate([np.ravel(pos), c])))
    seeds.sort(key=lambda s: s[0])
    unit = MU0 / (2 * np.pi) / radius  # field of 1 A at the ring's radius
    scale = np.concatenate([np.full(2 * n, radius), np.ones(n), np.full(nb, unit)])

    def resid(t):
        t = t * scale
        model = field(angles_rad, radius, t[: 2 * n].reshape(n, 2), t[2 * n: 3 * n])
        if nb:
            model = model + uniform_field(angles_rad, t[3 * n:])
        return (model - readings.reshape(-1, 2)).ravel() * weight / unit

    lo = np.concatenate([np.full(2 * n, -bore / radius), np.full(n + nb, -np.inf)])
    hi = -lo
    best = None
    for _, t0 in seeds[:4]:
        sol = least_squares(resid, np.clip(t0 / scale, lo + 1e-12, hi - 1e-12), bounds=(lo, hi), method="trf",
                            xtol=1e-15, ftol=1e-15, gtol=1e-15)
        if best is None or sol.cost < best.cost:
            best = sol
    t = best.x * scale
    pos, cur = t[: 2 * n].reshape(n, 2), t[2 * n: 3 * n]
    order = np.lexsort((pos[:, 1], pos[:, 0]))
    out = {"positions": pos[order], "currents": cur[order], "cost": best.cost}
    if nb:
        out["background"] = t[3 * n:]
    return out


def fit_axis_aligned_ellipse(readings, magnitude) -> tuple:
    """Ordinary least-squares ellipse a x² + c y² + d x + e y = 1 (axis-aligned), scaled so its radius
    in field units is `magnitude`: offsets and gains of h = (ĥ − b) ⊘ γ."""
    x, y = np.asarray(readings, float).T
    A = np.column_stack([x**2, y**2, x, y])
    (a, c, d, e), *_ = np.linalg.lstsq(A, np.ones_like(x), rcond=None)
    bx, by = -d / (2 * a), -e / (2 * c)
    k = 1 + a * bx**2 + c * by**2  # a(x−bx)² + c(y−by)² = k
    gx, gy = np.sqrt(k / a) / magnitude, np.sqrt(k / c) / magnitude
    return np.array([bx, by]), np.array([gx, gy])
