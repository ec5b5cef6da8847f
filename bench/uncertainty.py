"""Are the standard errors fluxcal.calibrate reports honest on real recordings?

    .venv/bin/python bench/uncertainty.py [--reps 200] [--seed 1] [--real ../shared/data/real]

For each real recording (phone, handheld, QMC5883L as recorded, and QMC5883L without its static first
minute) the magnitude model h = A (m - b), |h| = field_norm, is fitted once with fluxcal.calibrate on the
whole recording. Its summary gives two sets of standard errors for the 9 parameters b0 b1 b2 a00 a01 a02
a11 a12 a22: the reported ones ("NW": Newey-West, used whenever the residuals fail a Ljung-Box test) and
the ones that assume independent readings ("indep": sigma^2 (J^T J)^-1). Two checks, neither needs truth:

(1) Circular block bootstrap (arch): the rows are resampled in circular blocks (length by Politis & White,
    arch's optimal_block_length, 'circular' column, on the residual series |h| - mean |h| of the full fit,
    so the readings' time correlation is kept), calibrate is refitted on each of --reps resamples and the
    SD of each parameter across the refits ("boot") is the yardstick. All refits are given field_norm = the
    full fit's field_norm: without it calibrate fits the scale from the data (mean radius, det W = 1) and
    the parameters of different refits would not share one scale. Ratio SE/boot ≈ 1 is honest, < 1 is
    overconfident. Group columns are RMS over the group (offset: b0..b2; matrix: a00..a22) of the
    per-parameter values, ratios included.
(2) Half split, no resampling: fit the first and the second half separately (same field_norm) and form
    z = |theta_1 - theta_2| / sqrt(SE_1^2 + SE_2^2) per parameter. For an honest SE and a stationary
    sensor z is |N(0,1)|: mean 0.80, RMS 1.0 (the RMS over a group of 3 or 6 such values lies, if they
    were independent, within 0.27-1.77 or 0.45-1.55 in 95 % of cases). The bootstrap assumes a stationary
    recording; this check does not, so a sensor whose calibration drifts in time shows up as z >> 1 even
    with honest within-recording SEs.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
from scipy import stats

import fluxcal

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _timing import machine_facts, table  # noqa: E402  (bench/ is on sys.path when run as a script)

REPO = Path(__file__).resolve().parents[1]
DEFAULT_REAL = REPO.parent / "shared" / "data" / "real"
GROUPS = {"offset": slice(0, 3), "matrix": slice(3, 9)}
QMC_STATIC_ROWS = 3000  # first 60 s at 50 Hz, sensor lying still


def load_recordings(folder: Path) -> dict[str, np.ndarray]:
    for name in ("phone_acc_mag.csv", "handheld_set1.csv", "qmc5883l_filtered.csv"):
        if not (folder / name).is_file():
            raise ValueError(f"--real: {folder} has no {name}")
    qmc = np.loadtxt(folder / "qmc5883l_filtered.csv", delimiter=",", skiprows=3)
    return {"phone": pd.read_csv(folder / "phone_acc_mag.csv")[["mx", "my", "mz"]].to_numpy(float),
            "handheld": pd.read_csv(folder / "handheld_set1.csv")[["x", "y", "z"]].to_numpy(float),
            "qmc": qmc,
            "qmc (moving)": qmc[QMC_STATIC_ROWS:]}


def rms(values) -> float:
    v = np.asarray(values, dtype=float)
    return float(np.sqrt(np.mean(v**2)))


def params_and_ses(cal) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    s = cal.summary
    return (np.asarray(s["parameters"], float), np.asarray(s["standard_errors"], float),
            np.asarray(s["serial_correlation"]["standard_errors_independent"], float))


def refit(m: np.ndarray, field_norm: float):
    cal = fluxcal.calibrate(m, field_norm=field_norm)
    if cal.field_norm != field_norm:  # the comparison is meaningless if a refit picked its own scale
        raise RuntimeError(f"refit field_norm {cal.field_norm!r} differs from the full fit's {field_norm!r}")
    return cal


def check_recording(name: str, m: np.ndarray, reps: int, seed: int) -> dict:
    from arch.bootstrap import CircularBlockBootstrap, optimal_block_length

    t0 = time.perf_counter()
    full = fluxcal.calibrate(m)
    names = list(full.summary["parameter_names"])
    theta, se_nw, se_ind = params_and_ses(full)
    serial = full.summary["serial_correlation"]
    field_norm = full.field_norm
    # the refits use field_norm=; on the original rows that must reproduce the full fit
    same = np.max(np.abs(params_and_ses(refit(m, field_norm))[0] - theta) / se_ind)

    radius = np.linalg.norm(full.apply(m), axis=1)
    block_raw = float(optimal_block_length(radius - radius.mean())["circular"].iloc[0])
    block = max(1, int(np.ceil(block_raw)))
    cbb = CircularBlockBootstrap(block, np.arange(len(m)), seed=seed)
    draws, failed = [], 0
    for (rows,), _ in cbb.bootstrap(reps):
        try:
            draws.append(params_and_ses(refit(m[rows], field_norm))[0])
        except ValueError:
            failed += 1
    boot = np.std(np.array(draws), axis=0, ddof=1)

    half = len(m) // 2
    (t1, nw1, in1), (t2, nw2, in2) = (params_and_ses(refit(part, field_norm)) for part in (m[:half], m[half:]))
    z_nw = np.abs(t1 - t2) / np.hypot(nw1, nw2)
    z_ind = np.abs(t1 - t2) / np.hypot(in1, in2)
    return {"name": name, "n": len(m), "names": names, "theta": theta, "boot": boot, "nw": se_nw, "ind": se_ind,
            "z_nw": z_nw, "z_ind": z_ind, "lag1": serial["lag1"], "lags": serial["lags"],
            "ljung_box_p": serial["ljung_box_p"], "inflation": serial["inflation"], "block_raw": block_raw,
            "block": block, "refits": len(draws), "failed": failed, "field_norm": field_norm,
            "same": same, "seconds": time.perf_counter() - t0}


def group_rms(r: dict, key: str, group: str) -> float:
    return rms(r[key][GROUPS[group]])


def ratio_rms(r: dict, key: str, group: str) -> float:
    g = GROUPS[group]
    return rms(r[key][g] / r["boot"][g])


def print_recording(r: dict):
    print(f"\n### {r['name']}: {r['n']} rows, field_norm {r['field_norm']:.6g} (fixed in all refits)\n")
    print(f"residual lag-1 autocorrelation {r['lag1']:.3f}, Ljung-Box p {r['ljung_box_p']:.3g}, Newey-West lags "
          f"{r['lags']}, inflation {r['inflation']:.2f}; block length {r['block_raw']:.1f} → {r['block']} rows; "
          f"{r['refits']} refits ({r['failed']} failed); {r['seconds']:.1f} s")
    print(f"(refit with field_norm= on the original rows reproduces the full fit to "
          f"{r['same']:.1e} independent SEs)\n")
    rows = []
    for i, p in enumerate(r["names"]):
        rows.append([p, f"{r['theta'][i]:.6g}", f"{r['boot'][i]:.3e}", f"{r['nw'][i]:.3e}", f"{r['ind'][i]:.3e}",
                     f"{r['nw'][i] / r['boot'][i]:.2f}", f"{r['ind'][i] / r['boot'][i]:.2f}",
                     f"{r['z_nw'][i]:.2f}", f"{r['z_ind'][i]:.2f}"])
    for g in GROUPS:
        rows.append([f"RMS {g}", "", f"{group_rms(r, 'boot', g):.3e}", f"{group_rms(r, 'nw', g):.3e}",
                     f"{group_rms(r, 'ind', g):.3e}", f"{ratio_rms(r, 'nw', g):.2f}", f"{ratio_rms(r, 'ind', g):.2f}",
                     f"{group_rms(r, 'z_nw', g):.2f}", f"{group_rms(r, 'z_ind', g):.2f}"])
    table(["parameter", "estimate", "boot SD", "NW SE", "indep SE", "NW/boot", "indep/boot",
           "split z NW", "split z indep"], rows)


def verdicts(r: dict) -> list[str]:
    out = []
    for g in GROUPS:
        ratio, z = ratio_rms(r, "nw", g), group_rms(r, "z_nw", g)
        if ratio < 0.67:
            out.append(f"{r['name']} {g}: NW SE {ratio:.2f}× the bootstrap SD — overconfident")
        elif ratio > 1.5:
            out.append(f"{r['name']} {g}: NW SE {ratio:.2f}× the bootstrap SD — conservative")
        if z > 2.0:
            # either the sensor changed, or the model misfits in a way that depends on which orientations a
            # half covers; both mean the SEs understate how far another recording's fit would land
            out.append(f"{r['name']} {g}: the two halves' fits differ by RMS {z:.1f} NW SEs (≈ 1 if stationary) — "
                       f"not explained by the reported SEs (drift in time, or model misfit that depends on the "
                       f"orientations each half covers)")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--reps", type=int, default=200, help="bootstrap resamples per recording (default 200)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--real", type=Path, default=DEFAULT_REAL, help="folder of the real recordings")
    args = ap.parse_args(argv)
    if args.reps < 2:
        raise ValueError(f"--reps: {args.reps} is too few (need at least 2 resamples for an SD)")
    try:
        import arch
    except ImportError:
        print("arch is not installed: .venv/bin/pip install '.[bench]'")
        return 1

    t_start = time.perf_counter()
    print(f"# Standard errors on real recordings — {_dt.date.today().isoformat()}")
    print(" ".join(["command: .venv/bin/python bench/uncertainty.py", *(argv if argv is not None else sys.argv[1:])]))
    print("machine (before the run): " + "; ".join(f"{k} {v}" for k, v in machine_facts(
        fluxcal=fluxcal.__version__, NumPy=np.__version__, arch=arch.__version__)))
    print(f"circular block bootstrap, {args.reps} resamples per recording, seed {args.seed}; data {args.real}")

    results = [check_recording(name, m, args.reps, args.seed)
               for name, m in load_recordings(args.real).items()]
    for r in results:
        print_recording(r)

    print("\n### Summary (RMS over each group; ratios ≈ 1 and split z ≈ 1 when the SEs are honest)\n")
    rows = []
    for r in results:
        row = [r["name"], str(r["n"]), f"{r['lag1']:.2f}", str(r["lags"]), str(r["block"])]
        for g in GROUPS:
            row += [f"{ratio_rms(r, 'nw', g):.2f}", f"{ratio_rms(r, 'ind', g):.2f}",
                    f"{group_rms(r, 'z_nw', g):.1f}", f"{group_rms(r, 'z_ind', g):.1f}"]
        rows.append(row + [f"{r['seconds']:.1f}"])
    table(["recording", "rows", "lag1", "NW lags", "block", "offset NW/boot", "offset indep/boot",
           "offset split z NW", "offset split z indep", "matrix NW/boot", "matrix indep/boot",
           "matrix split z NW", "matrix split z indep", "s"], rows)
    k_lo, k_hi = (np.sqrt(stats.chi2.ppf([0.025, 0.975], k) / k) for k in (3, 6))
    print(f"\nboot = SD over the refits; NW = reported (Newey–West) SE; indep = SE assuming independent readings."
          f"\nsplit z = |θ_first half − θ_second half| / sqrt(SE_1² + SE_2²): RMS ≈ 1.0 (mean ≈ 0.8) when honest and"
          f"\nstationary; 95 % range of the RMS of 3 / 6 independent |N(0,1)|: {k_lo[0]:.2f}–{k_lo[1]:.2f} / "
          f"{k_hi[0]:.2f}–{k_hi[1]:.2f}.\nThe bootstrap SD itself is uncertain by about "
          f"{100 / np.sqrt(2 * (args.reps - 1)):.0f} % (Monte Carlo, {args.reps} resamples), and a block bootstrap "
          f"tends to understate\nthe SD slightly when the correlation outlasts the block.")
    notes = [v for r in results for v in verdicts(r)]
    if notes:
        print("\nplainly:")
        for v in notes:
            print(f"  - {v}")
    print(f"\ntotal {time.perf_counter() - t_start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
