"""The cable-ring diagnosis's blind record on withheld-effect simulations (fluxcal.sim.cable_effects).

    .venv/bin/python bench/diagnose_cable.py --trials 30            # each effect, pairs, nothing withheld
    .venv/bin/python bench/diagnose_cable.py --trials 30 --fit-currents

The rig and recording of `cable_trial` (the paper's ring and sensor errors, calibrated the paper's way;
8 rotations × 2, 5, 10 A × go-and-return and each core alone × both polarities × 2 repeats); each effect
at a magnitude drawn from its class's `typical`. Seeds 1000 + i, none shared with the tests. Prints
Markdown tables for bench/RESULTS.md: rank-1 fraction, held-out gap shrink, the held-out current error and
conductor position error before → after (medians over the trials where the effect ranked first), and
seconds per diagnosis.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from fluxcal.diagnose import diagnose_cable
from fluxcal.sim.cable_effects import CABLE_CANDIDATES, cable_trial

MAGNITUDES = {
    "helical_lay": "L = 10–40 × pitch diameter (40–160 mm)",
    "finite_length": "ℓ 0.1–0.25 m each side, return 0.15–0.3 m away",
    "sensor_position_error": "±0.3–0.7°, ±0.1–0.2 mm, axis ±0.5–1.5°",
    "cable_tilt": "tilt 2–5°, any direction",
    "z_leakage": "k_z ±1–2 %, tilt 2–4°",
    "sensor_coupling": "±0.5–2 % per axis (0.3–1.1°)",
    "sensor_nonlinearity": "−0.1 … −0.4 % at 100 µT",
    "background_field": "20–50 µT",
    "background_gradient": "a 5–20 A conductor 40–100 mm from the axis",
    "background_curvature": "a 5–20 A conductor 40–100 mm from the axis",
    "nearby_iron": "a plate 2–5 ring radii away, factor 0.5–1",
}
PAIRS = [("helical_lay", "z_leakage"), ("sensor_position_error", "finite_length"),
         ("z_leakage", "sensor_position_error"), ("finite_length", "z_leakage")]


def _median(values) -> str:
    return "—" if not values else f"{np.median(values):.3g}"


def effects(n: int, seed0: int, fit_currents: bool):
    print("| withheld effect | magnitude | ranked first & significant | held-out gap shrink (median, min) | "
          "held-out current error before → after (median, % RMS) | position error before → after (median, mm) | "
          "s/diagnosis |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for cls in CABLE_CANDIDATES:
        hits, shrink, cur0, cur1, pos0, pos1, seconds = 0, [], [], [], [], [], []
        for i in range(n):
            kwargs, _ = cable_trial([cls.name], seed0 + i)
            t0 = time.perf_counter()
            d = diagnose_cable(**kwargs, fit_currents=fit_currents)
            seconds.append(time.perf_counter() - t0)
            top = d.ranking[0]
            if top["effect"] != cls.name or not top["significant"]:
                continue
            hits += 1
            shrink.append(1 - top["heldout_gap_after"] / top["heldout_gap_before"])
            cur0.append(top["current_error_pct_before"])
            cur1.append(top["current_error_pct_after"])
            pos0.append(top["position_error_mm_before"])
            pos1.append(top["position_error_mm_after"])
        print(f"| {cls.name} | {MAGNITUDES.get(cls.name, 'its class’s typical')} | {hits}/{n} | {_median(shrink)}, "
              f"{'—' if not shrink else f'{min(shrink):.3g}'} | {_median(cur0)} → {_median(cur1)} | "
              f"{_median(pos0)} → {_median(pos1)} | {np.mean(seconds):.2f} |", flush=True)


def pairs(n: int, seed0: int, fit_currents: bool):
    print("\n| withheld pair | both found | found exactly the pair | s/diagnosis |")
    print("|---|---:|---:|---:|")
    for pair in PAIRS:
        found, exact, seconds = 0, 0, []
        for i in range(n):
            kwargs, _ = cable_trial(list(pair), seed0 + i)
            t0 = time.perf_counter()
            d = diagnose_cable(**kwargs, fit_currents=fit_currents)
            seconds.append(time.perf_counter() - t0)
            found += set(pair) <= set(d.accepted)
            exact += set(pair) == set(d.accepted)
        print(f"| {' + '.join(pair)} | {found}/{n} | {exact}/{n} | {np.mean(seconds):.2f} |", flush=True)


def nothing(n: int, seed0: int, fit_currents: bool):
    quiet, seconds, found = 0, [], {}
    for i in range(n):
        kwargs, _ = cable_trial([], seed0 + i)
        t0 = time.perf_counter()
        d = diagnose_cable(**kwargs, fit_currents=fit_currents)
        seconds.append(time.perf_counter() - t0)
        quiet += not d.significant
        for name in d.accepted:
            found[name] = found.get(name, 0) + 1
    print(f"\nnothing withheld: no significant effect in {quiet}/{n} "
          f"(false finds: {found or 'none'}); {np.mean(seconds):.2f} s/diagnosis")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=30, help="trials per effect, pair and for nothing withheld")
    parser.add_argument("--fit-currents", action="store_true", help="fit the currents per snapshot (the "
                        "reference currents then only judge the held-out current error)")
    args = parser.parse_args()
    mode = "currents fitted per snapshot" if args.fit_currents else "reference currents"
    print(f"`.venv/bin/python bench/diagnose_cable.py --trials {args.trials}"
          f"{' --fit-currents' if args.fit_currents else ''}` ({mode})\n")
    effects(args.trials, 1000, args.fit_currents)
    pairs(max(args.trials // 2, 5), 2000, args.fit_currents)
    nothing(args.trials * 2, 3000, args.fit_currents)


if __name__ == "__main__":
    main()
