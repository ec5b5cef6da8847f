"""How honest calibrate_planar's standard errors and moved-offset check are, on simulated yaw-only logs.

    PYTHONPATH=python .venv/bin/python bench/planar_checks.py [--logs 300] [--only errors|clean|power]

errors: the offset's z-scores (estimate − truth)/SE over `logs` logs with AR(1) noise of φ 0 … 0.95 — their spread
        should be about 1 (Newey–West errors), and is shown beside the independent-readings errors'.
clean:  the moved-offset check's smallest Bonferroni p over clean logs (N 300–3000, φ 0–0.95): how many fall under
        1e-2 … 1e-5 (fluxcal.planar.MOVED_ALPHA is the line).
power:  how many of 40 logs with an offset that moves by 0.5, 1 and 2 % of H are said at MOVED_ALPHA.

The simulation: a level vehicle turning at an uneven rate, H = 20 µT, vertical 45 µT, hard iron (12, −7) µT, a
coupled soft iron, AR(1) noise of stationary σ 1 % of H per axis (tests/python/test_planar_serial.py's).
"""
from __future__ import annotations

import argparse

import numpy as np
from scipy.signal import lfilter

from fluxcal import planar

H, Z, SIGMA = 20.0, 45.0, 0.2
OFFSET = np.array([12.0, -7.0])
W2 = np.array([[1.05, 0.06], [0.06, 0.92]])
MOVED = "the offset moved within the log"


def turning(seed, n, phi, turns=2.0, move=0.0, at=0.5):
    rng = np.random.default_rng(seed)
    psi = np.cumsum(rng.uniform(0.2, 1.8, n))
    psi = psi / psi[-1] * 2 * np.pi * turns + rng.uniform(0, 2 * np.pi)
    h = H * np.column_stack([np.cos(psi), np.sin(psi)])
    e = lfilter([1.0], [1.0, -phi], rng.normal(0.0, SIGMA * np.sqrt(1 - phi ** 2), (n, 3)), axis=0)
    m = np.column_stack([h @ W2.T + OFFSET, np.full(n, Z)]) + e
    m[int(at * n):, :2] += move * H * np.array([0.6, 0.8])
    return m


def errors(logs: int) -> None:
    print(f"\n## Offset z-scores, N = 1000, two turns ({logs} logs)\n")
    print("| noise | spread of z (b_x, b_y), reported | \\|z\\| > 3 | with independent-readings errors |")
    print("|---|---|---:|---|")
    for phi in (0.0, 0.5, 0.9, 0.95):
        z, zi = [], []
        for seed in range(logs):
            s = planar.calibrate_planar(turning(seed, 1000, phi), field_norm=H).summary
            b = np.array(s["parameters"][:2]) - OFFSET
            z.append(b / np.array(s["standard_errors"][:2]))
            zi.append(b / np.array(s["serial_correlation"]["standard_errors_independent"][:2]))
        z, zi = np.array(z), np.array(zi)
        print(f"| AR(1) φ {phi} | {z[:, 0].std():.2f}, {z[:, 1].std():.2f} | {100 * np.mean(np.abs(z) > 3):.1f} % | "
              f"{zi[:, 0].std():.2f}, {zi[:, 1].std():.2f} |")


def clean(logs: int) -> None:
    print(f"\n## Moved-offset check on clean logs: smallest Bonferroni p ({logs} logs each)\n")
    print("| N | φ | turns | compared | p < 1e-2 | < 1e-3 | < 1e-4 | < 1e-5 |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|")
    for n, phi, turns in ((300, 0.3, 2), (300, 0.5, 2), (1000, 0.5, 2), (1000, 0.3, 4), (3000, 0.5, 6), (600, 0.0, 2),
                          (2000, 0.6, 4), (1000, 0.9, 2), (2000, 0.9, 2), (3000, 0.95, 6)):
        ps = []
        for seed in range(logs):
            split = planar.calibrate_planar(turning(9000 + seed, n, phi, turns), field_norm=H).summary["offset_split"]
            if split["compared"]:
                ps.append(split["p_value"])
        ps = np.array(ps)
        print(f"| {n} | {phi} | {turns} | {len(ps)} | " + " | ".join(str(int(np.sum(ps < a)))
                                                                    for a in (1e-2, 1e-3, 1e-4, 1e-5)) + " |")


def power(logs: int = 40) -> None:
    print(f"\n## Moved-offset check: logs said of {logs}, at MOVED_ALPHA = {planar.MOVED_ALPHA:g}\n")
    print("| N | φ | turns | move at | 0.5 % of H | 1 % | 2 % |")
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for n, phi, turns, at in ((300, 0.0, 2, 0.5), (1000, 0.0, 4, 0.25), (3000, 0.9, 6, 0.5), (1000, 0.0, 1, 0.5)):
        said = [sum(any(w.startswith(MOVED) for w in planar.calibrate_planar(
            turning(5000 + seed, n, phi, turns, move, at), field_norm=H).summary["warnings"]) for seed in range(logs))
            for move in (0.005, 0.01, 0.02)]
        print(f"| {n} | {phi} | {turns} | {at} | " + " | ".join(map(str, said)) + " |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", type=int, default=300, help="clean logs per case (errors, clean)")
    parser.add_argument("--only", choices=["errors", "clean", "power"])
    args = parser.parse_args()
    for name, run in (("errors", lambda: errors(args.logs)), ("clean", lambda: clean(args.logs)), ("power", power)):
        if args.only in (None, name):
            run()


if __name__ == "__main__":
    main()
