"""Speed of fluxcal's AR(p) Kalman filters and AR fit against filterpy and statsmodels on 10⁶ samples.

    python bench/kalman.py [--n 1000000] [--repeat 3] [--seed 7] [--filterpy-n 1000000]

Data: one seeded AR(3) signal (a = 0.6, −0.3, 0.2, innovation variance 0.5) plus white measurement
noise (variance 0.3), scaled to a peak of ±0.9 (so the fixed-point filter's derived format is Q1.30);
q and r scaled alike. Every filter runs the same model from the same start (x = 0, P0 = the AR
process's stationary covariance, which is also statsmodels' default initialisation).

fluxcal                               peer (ratio = peer time / fluxcal time)
  ArKalman.filter (time-varying)      filterpy KalmanFilter predict+update loop (Joseph form update),
                                      statsmodels SARIMAX(order=(3,0,0), measurement_error=True).filter
  ArKalman.filter (steady-state)      —
  FixedArKalman.filter (both forms)   — (float → Q1.30 → float at the boundary included)
  fit_ar(max_order=10) (AIC + RLS)    statsmodels AutoReg(lags=p).fit() (the order fluxcal chose, no selection);
                                      ar_select_order is not run: it builds an N×N temporary
                                      (MemoryError from N = 10⁵, ../shared/ANCHORS.md)
Times are the best of --repeat calls after a warm-up (time.perf_counter); filterpy runs once (it takes
~15 s at 10⁶). Outputs are compared with fluxcal's double filter (max |Δ|).
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import best_time  # noqa: E402

from fluxcal import timeseries  # noqa: E402
from fluxcal.kalman import ArKalman, FixedArKalman  # noqa: E402

A = np.array([0.6, -0.3, 0.2])


def simulate(n, seed):
    rng = np.random.default_rng(seed)
    s = lfilter([1.0], np.concatenate(([1.0], -A)), np.sqrt(0.5) * rng.standard_normal(n + 500))[500:]
    y = s + np.sqrt(0.3) * rng.standard_normal(n)
    scale = 0.9 / np.max(np.abs(y))
    return y * scale, 0.5 * scale ** 2, 0.3 * scale ** 2


def filterpy_filter(y, q, r, p0):
    from filterpy.kalman import KalmanFilter

    n = A.size
    kf = KalmanFilter(dim_x=n, dim_z=1)
    kf.F = np.zeros((n, n))
    kf.F[0] = A
    kf.F[np.arange(1, n), np.arange(n - 1)] = 1.0
    kf.H = np.eye(n)[:1]
    kf.Q = np.zeros((n, n))
    kf.Q[0, 0] = q
    kf.R = np.array([[r]])
    kf.P = p0.copy()
    kf.x = np.zeros((n, 1))
    out = np.empty(y.size)
    for i, yi in enumerate(y):
        kf.predict()
        kf.update(yi)
        out[i] = kf.x[0, 0]
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--n", type=int, default=1_000_000)
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--filterpy-n", type=int, default=None, help="samples for filterpy (default --n)")
    args = p.parse_args(argv)
    y, q, r = simulate(args.n, args.seed)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, Python "
          f"{platform.python_version()}, NumPy {np.__version__}")
    print(f"N = {args.n} samples, AR(3) model, best of {args.repeat}\n")

    tv, ss = ArKalman(A, q, r), ArKalman(A, q, r, steady_state=True)
    fx_tv, fx_ss = FixedArKalman(A, q, r), FixedArKalman(A, q, r, steady_state=True)
    rows = {}
    rows["fluxcal ArKalman (time-varying)"] = best_time(lambda: tv.filter(y), args.repeat)
    rows["fluxcal ArKalman (steady-state)"] = best_time(lambda: ss.filter(y), args.repeat)
    rows["fluxcal FixedArKalman (time-varying)"] = best_time(lambda: fx_tv.filter(y), args.repeat)
    rows["fluxcal FixedArKalman (steady-state)"] = best_time(lambda: fx_ss.filter(y), args.repeat)
    ref = tv.filter(y)
    diffs = {"fluxcal FixedArKalman (time-varying)": np.max(np.abs(fx_tv.filter(y) - ref)),
             "fluxcal FixedArKalman (steady-state)": np.max(np.abs(fx_ss.filter(y) - ss.filter(y)))}

    from statsmodels.tsa.statespace.sarimax import SARIMAX

    model = SARIMAX(y, order=(3, 0, 0), trend="n", measurement_error=True)
    params = np.concatenate((A, [r, q]))
    rows["statsmodels SARIMAX.filter"] = best_time(lambda: model.filter(params), args.repeat)
    diffs["statsmodels SARIMAX.filter"] = np.max(np.abs(model.filter(params).filtered_state[0] - ref))

    n_fp = args.filterpy_n or args.n
    t0 = time.perf_counter()
    fp = filterpy_filter(y[:n_fp], q, r, tv.initial_covariance)
    t_fp = (time.perf_counter() - t0) * args.n / n_fp
    rows["filterpy KalmanFilter loop" + ("" if n_fp == args.n else f" (scaled from {n_fp})")] = t_fp
    diffs[next(k for k in rows if k.startswith("filterpy"))] = np.max(np.abs(fp - ref[:n_fp]))

    base = rows["fluxcal ArKalman (time-varying)"]
    print(f"{'Kalman filter':42s} {'time':>10s} {'samples/s':>12s} {'vs fluxcal TV':>14s} {'max |Δ| vs TV':>14s}")
    for name, t in rows.items():
        d = diffs.get(name)
        print(f"{name:42s} {t * 1e3:8.1f} ms {args.n / t:12.3g} {t / base:13.1f}x "
              f"{'' if d is None else f'{d:14.2e}'}")

    from statsmodels.tsa.ar_model import AutoReg

    t_fit = best_time(lambda: timeseries.fit_ar(y, max_order=10), args.repeat)
    fit = timeseries.fit_ar(y, max_order=10)
    t_sm = best_time(lambda: AutoReg(y, lags=fit.order, trend="n").fit(), args.repeat)
    sm = AutoReg(y, lags=fit.order, trend="n").fit()
    print(f"\n{'AR fit':42s} {'time':>10s}")
    print(f"{'fluxcal fit_ar(max_order=10): AIC + RLS':42s} {t_fit * 1e3:8.1f} ms   order {fit.order}, "
          f"max |Δa| vs AutoReg {np.max(np.abs(fit.coefficients - sm.params)):.1e}")
    print(f"{f'statsmodels AutoReg(lags={fit.order}).fit()':42s} {t_sm * 1e3:8.1f} ms   ({t_sm / t_fit:.1f}x fluxcal, "
          "which also selects the order)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
