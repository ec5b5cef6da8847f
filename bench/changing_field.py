"""A field whose magnitude changes while the sensor turns: how much each reading's own |field| gives back.

    python bench/changing_field.py [--runs 200] [--seeds 20]

(a) Calibration: the refinement's Monte-Carlo (--runs seeded runs, N = 300, sigma = 1 % of |field|, soft iron
    within +-10 %, offset up to 50 %), the field's magnitude changing by +-2 % (a storm) and +-30 % (an orbit)
    as 1 + c sin(t) over the run. RMS error of the offset and of the matrix's upper triangle over sqrt(CRLB)
    (fluxcal.crlb at the clean readings), and the largest |mean error| over sqrt(CRLB), for TWOSTEP and the
    refinement given each reading's |field| and for TWOSTEP given one |field| (their mean).
(b) Diagnosis: the withheld trials of seeds 0..--seeds-1 (a minute hand-turned at 50 Hz, 3000 readings), nothing
    or a temp_offset simulated, in a field whose magnitude changes by +-1 % (1.3 slow periods over the minute),
    diagnosed with one |field| for all and with each reading's: what each names.
"""
from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import machine_facts  # noqa: E402  (bench/ is on sys.path when run as a script)

import fluxcal  # noqa: E402
from fluxcal import sim  # noqa: E402
from fluxcal.sim.withheld import FIELD, withheld_trial  # noqa: E402

SYM = np.triu_indices(3)


def theta(cal) -> np.ndarray:
    return np.r_[cal.offset, cal.matrix[SYM]]


def calibration_table(runs: int) -> None:
    fits = {"twostep, each |field|": lambda m, norms: theta(fluxcal.twostep(m, norms)),
            "twostep, one |field|": lambda m, norms: theta(fluxcal.twostep(m, float(np.mean(norms)))),
            "refine, each |field|": lambda m, norms: np.array(
                fluxcal.calibrate(m, field_norm=norms, shape="sym", outliers="keep").summary["parameters"])}
    print("| change | fit | offset RMS / sqrt(CRLB) | matrix RMS / sqrt(CRLB) | largest |mean| / sqrt(CRLB) |")
    print("|---|---|---:|---:|---:|")
    for change in (0.02, 0.3):
        rng = np.random.default_rng(7)
        H, noise = 50000.0, 0.01
        effects = sim.random_sensor(H, rng, soft_iron=0.1, offset=0.5, noise=noise)
        field = H * np.array([0.3, -0.2, 0.93]) / np.linalg.norm([0.3, -0.2, 0.93])
        z = {name: [] for name in fits}
        for run in range(runs):
            s = sim.simulate(sim.uniform(300, rng), effects, field, rng)
            k = 1 + change * np.sin(np.linspace(0, 3, 300) + run)
            b = s.true_calibration().offset
            clean = b + k[:, None] * (s.clean - b)
            readings, norms = clean + (s.readings - s.clean), k * H
            bound = np.sqrt(np.diag(fluxcal.crlb(s.true_calibration(), clean, noise * H)))
            for name, fit in fits.items():
                z[name].append((fit(readings, norms) - theta(s.true_calibration())) / bound)
        for name, e in z.items():
            e = np.array(e)
            rms = [np.sqrt(np.mean(e[:, g] ** 2)) for g in (slice(0, 3), slice(3, 9))]
            print(f"| ±{100 * change:g} % | {name} | {rms[0]:.3f} | {rms[1]:.3f} | {np.abs(e.mean(axis=0)).max():.2f} |")
    print("(one |field|: their mean; the tests' 'one |field|' is the nominal 50 000, whose matrix is further off)")


def diagnosis_table(seeds: int) -> None:
    H = float(np.linalg.norm(FIELD))
    print("\n| simulated | given | what the diagnosis names (of", seeds, "seeds) |")
    print("|---|---|---|")
    for names in ([], ["temp_offset"]):
        found = {"one |field|": Counter(), "each reading's |field|": Counter()}
        for seed in range(seeds):
            result, kwargs = withheld_trial(names, seed)
            kwargs.pop("field_norm", None)
            n = len(result.readings)
            k = 1 + 0.01 * np.sin(2 * np.pi * 1.3 * np.arange(n) / n + seed)
            b = result.true_calibration().offset
            readings = b + k[:, None] * (result.clean - b) + (result.readings - result.clean)
            for given, norms in (("one |field|", None), ("each reading's |field|", k * H)):
                accepted = fluxcal.diagnose(readings, field_norm=norms, **kwargs).accepted
                found[given][", ".join(accepted) or "nothing"] += 1
        for given, counts in found.items():
            listing = "; ".join(f"{what} {count}" for what, count in counts.most_common())
            print(f"| {', '.join(names) or 'nothing'} | {given} | {listing} |")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=200)
    parser.add_argument("--seeds", type=int, default=20)
    args = parser.parse_args()
    print("machine (before the run): " + "; ".join(f"{k} {v}" for k, v in machine_facts(
        fluxcal=fluxcal.__version__, NumPy=np.__version__)))
    calibration_table(args.runs)
    diagnosis_table(args.seeds)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
