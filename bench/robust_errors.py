"""Reported standard errors of refine with a robust loss against the Monte-Carlo spread (200 runs per row).

    .venv/bin/python bench/robust_errors.py

N = 600 readings over the sphere, |h| = 50, noise σ = 0.5, a fraction of the readings hit by spikes of
N(0, 10²) per axis (20 σ class). Prints, per loss and fraction, the spread of the offset estimates, the
mean reported error and their ratio (1 = honest).
"""
import warnings

import numpy as np

import fluxcal

warnings.simplefilter("ignore")
rng = np.random.default_rng(5)
A = np.array([[1.05, 0.02, -0.01], [0.02, 0.97, 0.03], [-0.01, 0.03, 1.01]]); b = np.array([10., -5., 3.])
N, H, sig = 600, 50.0, 0.5
for frac, loss in [(0.0, "none"), (0.0, "huber"), (0.1, "huber"), (0.1, "cauchy"), (0.2, "huber")]:
    est, ses = [], []
    for k in range(200):
        u = rng.normal(size=(N, 3)); u /= np.linalg.norm(u, axis=1, keepdims=True)
        m = (H * u) @ np.linalg.inv(A).T + b + sig * rng.normal(size=(N, 3))
        bad = rng.random(N) < frac
        m[bad] += rng.normal(size=(bad.sum(), 3)) * 10  # 20σ-class spikes
        cal = fluxcal.refine(fluxcal.fit_ellipsoid(m, method="als"), m, loss=loss, serial_correlation="independent")
        est.append(cal.offset); ses.append(cal.summary["standard_errors"][:3])
    est, ses = np.array(est), np.array(ses)
    print(frac, loss, "MC sd", np.round(est.std(0), 4), "reported", np.round(ses.mean(0), 4), "ratio", np.round(ses.mean(0) / est.std(0), 2))
