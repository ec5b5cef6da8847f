"""Wall-clock benchmark of fluxcal.fit_ellipsoid from Python.

    python bench/ellipsoid.py [--n 1000000] [--repeat 7] [--oracle-repeat 3] [--seed 4]

What it measures, on one seeded N×3 float64 C-contiguous array of simulated readings
(m = W h + b + noise, h uniform on a sphere of radius 50, W a symmetric soft-iron matrix):
  fluxcal.fit_ellipsoid(x)                          default: moments pass + solve + statistics pass
  fluxcal.fit_ellipsoid(x, exact_statistics=False)  moments pass + solve only
  fluxcal.oracle.fit_ellipsoid(x)                   NumPy reference (N×10 design matrix + lstsq)
  np.einsum('ij,ij->', x, x)                        one plain NumPy pass over the data (the yardstick)
  magyc.ellipsoid_fit / magyc.sphere_fit            only if `magyc` is importable (never installed here)
Each time is the best (minimum) of --repeat runs after one warm-up run, taken with time.perf_counter.
It also checks that fluxcal and the oracle agree (offset and matrix) and prints the max relative
difference. The project's target: fluxcal.fit_ellipsoid within 4x of the single einsum pass.
"""
from __future__ import annotations

import argparse
import os
import platform
import sys

import numpy as np

import fluxcal
from _timing import best_time  # noqa: E402
import fluxcal.oracle
from fluxcal.pipeline import usable_cpus

TARGET_RATIO = 4.0


def simulate(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    W = np.array([[1.10, 0.05, -0.03], [0.05, 0.92, 0.04], [-0.03, 0.04, 1.03]])  # symmetric soft iron
    b = np.array([12.0, -7.5, 3.25])
    h = rng.standard_normal((n, 3))
    h *= 50.0 / np.linalg.norm(h, axis=1, keepdims=True)
    x = h @ W.T + b + 0.05 * rng.standard_normal((n, 3))
    return np.ascontiguousarray(x, dtype=np.float64)




def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine_facts() -> list[tuple[str, str]]:
    usable = usable_cpus()
    try:
        load = "%.2f %.2f %.2f" % os.getloadavg()
    except OSError:
        load = "n/a"
    threads = ", ".join(f"{k}={os.environ[k]}" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                                        "MKL_NUM_THREADS") if k in os.environ) or "(unset)"
    return [
        ("CPU", cpu_model()),
        ("cores (os.cpu_count / usable)", f"{os.cpu_count()} / {usable}"),
        ("load average (1/5/15 min)", load),
        ("OS", f"{platform.system()} {platform.release()} ({platform.machine()})"),
        ("Python", platform.python_version()),
        ("NumPy", np.__version__),
        ("fluxcal", getattr(fluxcal, "__version__", "?")),
        ("BLAS thread env", threads),
    ]


def rel_diff(a, b) -> float:
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), np.finfo(float).tiny))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=1_000_000, help="number of readings (default 1e6)")
    ap.add_argument("--repeat", type=int, default=7, help="timed runs per case; the minimum is kept")
    ap.add_argument("--oracle-repeat", type=int, default=3,
                    help="timed runs for the slow NumPy oracle and magyc (default 3)")
    ap.add_argument("--seed", type=int, default=4)
    args = ap.parse_args(argv)

    print("machine")
    for k, v in machine_facts():
        print(f"  {k:<32} {v}")

    x = simulate(args.n, args.seed)
    assert x.flags.c_contiguous and x.dtype == np.float64 and x.shape == (args.n, 3)
    print(f"\ndata: {args.n} x 3 float64 C-contiguous ({x.nbytes / 1e6:.1f} MB), seed {args.seed}; "
          f"best of {args.repeat} (oracle/magyc: {args.oracle_repeat}) after one warm-up\n")

    rows: list[tuple[str, float]] = []
    t_einsum = best_time(lambda: np.einsum("ij,ij->", x, x), args.repeat)
    rows.append(("np.einsum('ij,ij->', x, x)", t_einsum))
    t_fit = best_time(lambda: fluxcal.fit_ellipsoid(x), args.repeat)
    rows.append(("fluxcal.fit_ellipsoid(x)", t_fit))
    t_mom = best_time(lambda: fluxcal.fit_ellipsoid(x, exact_statistics=False), args.repeat)
    rows.append(("fluxcal.fit_ellipsoid(x, exact_statistics=False)", t_mom))
    t_oracle = best_time(lambda: fluxcal.oracle.fit_ellipsoid(x), args.oracle_repeat)
    rows.append(("fluxcal.oracle.fit_ellipsoid(x)", t_oracle))

    magyc_note = None
    try:
        import magyc  # noqa: F401  (optional third-party comparison; not a dependency)
    except Exception as exc:  # ImportError, or a broken install
        magyc_note = f"magyc: skipped (not importable: {type(exc).__name__}: {exc})"
    else:
        for name in ("ellipsoid_fit", "sphere_fit"):
            fn = getattr(magyc, name, None)
            if fn is None:
                continue
            try:
                rows.append((f"magyc.{name}(x)", best_time(lambda fn=fn: fn(x), args.oracle_repeat)))
            except Exception as exc:
                rows.append((f"magyc.{name}(x) FAILED: {type(exc).__name__}: {exc}", float("nan")))

    width = max(len(name) for name, _ in rows)
    print(f"  {'case':<{width}}  {'time [ms]':>10}  {'ns/sample':>10}  {'x einsum':>9}")
    for name, t in rows:
        print(f"  {name:<{width}}  {1e3 * t:10.3f}  {1e9 * t / args.n:10.2f}  {t / t_einsum:9.2f}")
    if magyc_note:
        print(f"  {magyc_note}")

    print("\nratios")
    for label, t in (("default", t_fit), ("exact_statistics=False", t_mom)):
        r = t / t_einsum
        verdict = "met" if r <= TARGET_RATIO else "NOT met"
        print(f"  {'fluxcal (' + label + ') / einsum':<44} {r:7.2f}   (target <= {TARGET_RATIO:g}x: {verdict})")
    print(f"  {'oracle / fluxcal (default)':<44} {t_oracle / t_fit:7.1f}")
    print(f"  {'oracle / fluxcal (exact_statistics=False)':<44} {t_oracle / t_mom:7.1f}")

    # Agreement of the two implementations of the same estimator.
    cal = fluxcal.fit_ellipsoid(x)
    ref = fluxcal.oracle.fit_ellipsoid(x)
    d_off = rel_diff(cal.offset, ref["offset"])
    d_mat = rel_diff(cal.matrix, ref["matrix"])
    d_norm = abs(cal.field_norm - ref["field_norm"]) / abs(ref["field_norm"])
    print("\nagreement fluxcal vs oracle (max |a-b| / max |b|)")
    print(f"  offset      {d_off:.3e}")
    print(f"  matrix      {d_mat:.3e}")
    print(f"  field_norm  {d_norm:.3e}")
    ok = max(d_off, d_mat, d_norm) < 1e-6
    print(f"  {'OK' if ok else 'MISMATCH'} (tolerance 1e-6)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
