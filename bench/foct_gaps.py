"""FOCT drift compensation on a log with gaps in time: spliced (the samples taken as evenly spaced) against
the gaps found in t (fluxcal.timeseries.find_breaks; the whitening, the AR model and the Kalman filter do not
reach across them).

    python bench/foct_gaps.py [--seeds 10]

Data: fluxcal.sim.foct_zero_bias(logged="holds"): the recorder logs each temperature hold only (seed 001's
S1), so t jumps at each of the 14 ramps while the zero bias's AR noise runs on unseen. Per configuration
(hold length, AR coefficients, innovation σ 0.01 A) and seed, both fits of the same log; the table gives
the means over the seeds of the drift model's RMS error against the simulated drift law (A) and of the AR
model's first coefficient, and how often the F-tests chose the law's orders (2, 1, 3).
"""
from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from fluxcal import drift
from fluxcal.sim.foct import foct_zero_bias

CONFIGS = [(1200.0, (0.5, -0.2)), (120.0, (0.95,)), (30.0, (0.95,)), (120.0, (0.5, -0.2))]


def rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=10)
    args = p.parse_args(argv)
    print(f"# {platform.processor() or platform.machine()}, Python {platform.python_version()}, "
          f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, seeds 0..{args.seeds - 1}")
    print("| hold (s) | AR truth | samples | fit | drift RMS error (A) | a1 | orders 2, 1, 3 |")
    print("|---:|---|---:|---|---:|---:|---:|")
    for hold, ar in CONFIGS:
        rows = {"spliced": [], "gaps in t": []}
        for seed in range(args.seeds):
            s = foct_zero_bias(rng=seed, logged="holds", hold_s=hold, ar=ar, sigma=0.01)
            c, truth = s.columns, s.truth["drift"]["zero_bias"]
            for key, t in (("spliced", None), ("gaps in t", c["t"])):
                model, report = drift.fit_pipeline(c["zero_bias"], c["temp"], t=t)
                a = model.settings["ar"]["coefficients"]
                rows[key].append((rms(model.evaluate(c["temp"]) - truth), a[0] if a else 0.0,
                                  report["orders"] == [2, 1, 3]))
        for key, values in rows.items():
            v = np.mean(values, axis=0)
            print(f"| {hold:g} | {', '.join(f'{x:g}' for x in ar)} | {c['t'].size} | {key} | {v[0]:.5f} | "
                  f"{v[1]:.3f} | {round(v[2] * len(values))}/{len(values)} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
