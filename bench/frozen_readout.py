"""How often `fluxcal.drift.frozen_runs` names a frozen zero-bias readout: false alarms on clean logs and detection
of a readout held for 101 samples, over quantisation and noise correlation.

    python bench/frozen_readout.py [--seeds 100] [--n 6000]

Data: unit-variance AR(1) noise (φ in 0, 0.7, 0.95, 0.99) quantised to a step of 0.01 … 5 σ (a readout's LSB);
"frozen": the same log with samples 3000–3100 held at sample 3000's value. Per cell: clean logs flagged (false
alarms, %) and frozen logs flagged (detections, %). A readout that repeats its last value in more than 9 of 10
samples is not judged (its quantum far above its noise: holding is what it does), hence 0/0 in those cells.
"""
from __future__ import annotations

import argparse
import platform

import numpy as np
from scipy.signal import lfilter

from fluxcal.drift import frozen_runs

PHIS = (0.0, 0.7, 0.95, 0.99)
STEPS = (0.01, 0.5, 1.0, 2.0, 5.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=100)
    parser.add_argument("--n", type=int, default=6000)
    args = parser.parse_args()
    print(f"# frozen_runs: {args.seeds} seeds x {args.n} samples; {platform.processor() or platform.machine()}")
    print("| AR φ | " + " | ".join(f"step {s:g} σ" for s in STEPS) + " |")
    print("|---|" + "---|" * len(STEPS))
    for phi in PHIS:
        cells = []
        for step in STEPS:
            false_alarms = detections = 0
            for seed in range(args.seeds):
                rng = np.random.default_rng(seed)
                x = lfilter([1.0], [1.0, -phi], rng.normal(0.0, 1.0, args.n)) * np.sqrt(1.0 - phi ** 2)
                x = np.round(x / step) * step
                false_alarms += bool(frozen_runs(x))
                held = x.copy()
                held[args.n // 2:args.n // 2 + 101] = held[args.n // 2]
                detections += bool(frozen_runs(held))
            cells.append(f"{100 * false_alarms / args.seeds:.0f} / {100 * detections / args.seeds:.0f}")
        print(f"| {phi:g} | " + " | ".join(cells) + " |")
    print("(cells: false alarms % / detections %)")


if __name__ == "__main__":
    main()
