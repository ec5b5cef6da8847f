"""Planar (yaw-only) calibration: fluxcal against the peers an engineer uses today, timed in the same run.

    .venv/bin/python bench/planar.py [--repeat 5]

Peers: the hand-written NumPy direct ellipse fit (Halir & Flusser; the usual "fit an ellipse to the compass
swing", algebraic, not maximum likelihood) and SciPy least_squares on the same Sampson residuals (fluxcal.oracle.planar,
MINPACK's Levenberg–Marquardt). fluxcal: calibrate_planar (C++ fit_planar per shape, plane finding and checks in
Python), shape "sym" and "auto" (three shapes, BIC). Data: a level vehicle turning twice at uneven speed, a 30°-rotated
soft iron (gains 1.12/0.90), H = 20 µT, σ = 0.1 µT per axis. Prints times, ratios against fluxcal sym and the
offset error of each in units of fluxcal's standard error.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _timing import best_time, machine_facts, table  # noqa: E402

import fluxcal  # noqa: E402
from fluxcal.oracle import planar as oracle  # noqa: E402
from fluxcal.planar import calibrate_planar  # noqa: E402

H, Z, SIGMA = 20.0, 45.0, 0.1
OFFSET = np.array([12.0, -7.0, 4.0])


def yaw_only(n: int, rng) -> tuple[np.ndarray, np.ndarray]:
    psi = np.cumsum(rng.uniform(0.2, 1.8, n))
    psi = psi / psi[-1] * 4 * np.pi
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    r = np.array([[c, -s], [s, c]])
    W = np.eye(3)
    W[:2, :2] = r @ np.diag([1.12, 0.9]) @ r.T
    h = np.column_stack([H * np.cos(psi), H * np.sin(psi), np.full(n, Z)])
    return h @ W.T + OFFSET + rng.normal(0, SIGMA, (n, 3)), OFFSET[:2] + W[:2, 2] * Z


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    print("# planar calibration: fluxcal against the NumPy ellipse fit and SciPy least_squares\n")
    table(["fact", "value"], [list(f) for f in machine_facts(fluxcal=fluxcal.__version__, numpy=np.__version__)])
    for n in (1000, 100_000):
        m, b = yaw_only(n, np.random.default_rng(2026))
        methods = {
            "fluxcal calibrate_planar (sym)": lambda: calibrate_planar(m, field_norm=H, shape="sym"),
            "fluxcal calibrate_planar (auto)": lambda: calibrate_planar(m, field_norm=H),
            # the model's fit and covariance alone (no test for correlation in time, which fluxcal's timing includes)
            "SciPy least_squares, same model (oracle)": lambda: oracle.fit_planar(m[:, :2], H, shape="sym",
                                                                                 serial_correlation="independent"),
            "NumPy direct ellipse fit (algebraic)": lambda: oracle.direct_ellipse(m[:, :2]),
        }
        reference = calibrate_planar(m, field_norm=H, shape="sym")
        se = np.asarray(reference.summary["standard_errors"][:2])
        rows, base = [], None
        for name, fn in methods.items():
            t = best_time(fn, args.repeat if n < 10**5 else max(1, args.repeat // 2))
            base = base or t
            out = fn()
            offset = (out.offset[:2] if hasattr(out, "offset") else
                      np.asarray(out["offset"]) if isinstance(out, dict) else out[0])
            rows.append([name, f"{1e3 * t:.3g}", f"{t / base:.2f}",
                         f"{np.max(np.abs(offset - b) / se):.2f}"])
        print(f"\n## N = {n}\n")
        table(["method", "time (ms)", "× fluxcal sym", "max abs(offset − truth) / SE"], rows)


if __name__ == "__main__":
    main()
