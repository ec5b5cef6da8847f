"""Speed of fluxcal's solvers against peers at N = 1e3 and 1e5 readings.

    python bench/solvers.py [--sizes 1000 100000] [--repeat 5] [--seed 7] [--no-magyc]

Data: one seeded simulation per N (fluxcal.sim: uniform orientations, symmetric soft iron ±10 %, offset up
to 50 % of |field|, noise 1 % of |field|), N×3 float64 C-contiguous.

fluxcal                                  peer it is compared with (ratio = peer time / fluxcal time)
  fit_ellipsoid(method="ls")             magyc ellipsoid_fit, ellipsoid_fit_fang, sphere_fit (algebraic fits)
  fit_ellipsoid(method="als")            —
  refine(als fit, x)  (magnitude model)  SciPy least_squares on the same model, residual, parameters and
                                         starting point (the ALS fit), analytic Jacobian; "trf" (default)
                                         and "lm" (MINPACK); also "trf" with 2-point finite differences
  calibrate(x, field_norm=H)             magyc twostep_hsi (attitude-independent ML-type estimator that is
  (ALS + refine of the 3 shapes and      also given |field|)
  the BIC choice, what a user calls)
  fit_vector(x, true field)              NumPy lstsq of the same linear model m = W r + b
Each time is the best of --repeat calls after one warm-up (time.perf_counter); magyc is timed the same
way inside its own interpreter (bench/_magyc_worker.py), so its process start and imports are excluded.
SciPy's answer is checked against fluxcal.refine's (max |Δθ| relative to the parameter scale).
"""
from __future__ import annotations

import argparse
import datetime as _dt
import platform
import sys
from pathlib import Path

import numpy as np
import scipy
from scipy.optimize import least_squares

import fluxcal
from _timing import best_time  # noqa: E402
from fluxcal import sim
from fluxcal.pipeline import usable_cpus

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _magyc_worker import MagycUnavailable, MagycWorker  # noqa: E402

FIELD = np.array([20.0, 1.0, 45.0])
_SYM = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]


# ------------------------------------------------------------------ the magnitude model, for SciPy
def theta_of(cal) -> np.ndarray:
    A = cal.matrix
    return np.concatenate([cal.offset, [A[k, l] for k, l in _SYM]])


def matrix_of(theta) -> np.ndarray:
    a00, a01, a02, a11, a12, a22 = theta[3:]
    return np.array([[a00, a01, a02], [a01, a11, a12], [a02, a12, a22]])


def residual(theta, m, H):
    """Sampson residual (|h| − H)|h| / |A h| of fluxcal.refine's magnitude model, h = A (m − b)."""
    A = matrix_of(theta)
    h = (m - theta[:3]) @ A
    g = np.sqrt(np.einsum("ij,ij->i", h, h))
    Ah = h @ A
    q = np.sqrt(np.einsum("ij,ij->i", Ah, Ah))
    return (g - H) * g / q


def jacobian(theta, m, H):
    """Analytic ∂r/∂θ, r = (g² − H g)/q with g = |h|, q = |A h|:
    ∂r = ((2g − H)/q) ∂g − (r/q) ∂q;  ∂g = uᵀ ∂h, ∂q = vᵀ ∂(A h), u = h/g, v = A h/q.
    b: ∂h = −A, ∂(A h) = −A²;  a_kl (symmetric, E = e_k e_lᵀ + e_l e_kᵀ): ∂h = E d, ∂(A h) = E h + A E d.
    (At g = H this reduces to fluxcal.bounds.magnitude_jacobian.)"""
    A = matrix_of(theta)
    d = m - theta[:3]
    h = d @ A
    g = np.sqrt(np.einsum("ij,ij->i", h, h))
    Ah = h @ A
    q = np.sqrt(np.einsum("ij,ij->i", Ah, Ah))
    r = (g - H) * g / q
    u = h / g[:, None]
    v = Ah / q[:, None]
    w = v @ A
    cg = (2 * g - H) / q
    cq = r / q
    J = np.empty((len(m), 9))
    J[:, :3] = -(cg[:, None] * (u @ A) - cq[:, None] * (v @ (A @ A)))
    for col, (k, l) in enumerate(_SYM):
        if k == l:
            dg = u[:, k] * d[:, k]
            dq = v[:, k] * h[:, k] + w[:, k] * d[:, k]
        else:
            dg = u[:, k] * d[:, l] + u[:, l] * d[:, k]
            dq = v[:, k] * h[:, l] + v[:, l] * h[:, k] + w[:, k] * d[:, l] + w[:, l] * d[:, k]
        J[:, 3 + col] = cg * dg - cq * dq
    return J


def check_jacobian(m, theta, H) -> float:
    J = jacobian(theta, m, H)
    Jn = np.empty_like(J)
    for j in range(9):
        e = np.zeros(9)
        e[j] = 1e-6 * max(1.0, abs(theta[j]))
        Jn[:, j] = (residual(theta + e, m, H) - residual(theta - e, m, H)) / (2 * e[j])
    return float(np.max(np.abs(J - Jn)) / np.max(np.abs(Jn)))


# ------------------------------------------------------------------------------------- timing


def fmt_t(t) -> str:
    if t is None or not np.isfinite(t):
        return "—"
    if t < 1e-3:
        return f"{t * 1e6:.0f} µs"
    if t < 1:
        return f"{t * 1e3:.2f} ms"
    return f"{t:.2f} s"


def table(header, rows):
    widths = [max(len(str(c)) for c in col) for col in zip(header, *rows)]
    print("| " + " | ".join(str(h).ljust(w) for h, w in zip(header, widths)) + " |")
    print("|" + "|".join("-" * (w + 2) if i == 0 else "-" * (w + 1) + ":" for i, w in enumerate(widths)) + "|")
    for r in rows:
        print("| " + " | ".join(str(c).ljust(w) if i == 0 else str(c).rjust(w)
                                for i, (c, w) in enumerate(zip(r, widths))) + " |")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1000, 100000])
    ap.add_argument("--repeat", type=int, default=5, help="timed calls per case; the minimum is kept")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--no-magyc", action="store_true")
    args = ap.parse_args(argv)

    H = float(np.linalg.norm(FIELD))
    print(f"# fluxcal solver speed against peers — {_dt.date.today().isoformat()}")
    ncpu = usable_cpus()
    print(f"fluxcal {fluxcal.__version__}, NumPy {np.__version__}, SciPy {scipy.__version__}, "
          f"Python {platform.python_version()}, {ncpu} usable CPUs, best of {args.repeat} after a warm-up")
    worker = None
    if args.no_magyc:
        print("magyc: unavailable (skipped by --no-magyc)")
    else:
        worker = MagycWorker()
        if worker.available:
            print(f"magyc {worker.versions['magyc']} (NumPy {worker.versions['numpy']}) timed inside {worker.python}")
        else:
            print(f"magyc: unavailable ({worker.reason})")

    data, times, checks = {}, {}, []
    for n in args.sizes:
        rng = np.random.default_rng((args.seed, n))
        s = sim.simulate(sim.uniform(n, rng), sim.random_sensor(H, rng, soft_iron=0.1, offset=0.5, noise=0.01),
                         FIELD, rng=rng)
        x = np.ascontiguousarray(s.readings)
        ref = np.ascontiguousarray(s.truth)
        data[n] = x
        t = times.setdefault(n, {})
        R = args.repeat
        t["fit_ellipsoid ls"] = best_time(lambda: fluxcal.fit_ellipsoid(x, field_norm=H, method="ls"), R)
        t["fit_ellipsoid als"] = best_time(lambda: fluxcal.fit_ellipsoid(x, field_norm=H, method="als"), R)
        start = fluxcal.fit_ellipsoid(x, field_norm=H, method="als")
        t["refine"] = best_time(lambda: fluxcal.refine(start, x), R)
        t["calibrate"] = best_time(lambda: fluxcal.calibrate(x, field_norm=H), R)
        t["calibrate keep"] = best_time(lambda: fluxcal.calibrate(x, field_norm=H, outliers="keep"), R)
        t["calibrate sym"] = best_time(lambda: fluxcal.calibrate(x, field_norm=H, shape="sym"), R)
        t["fit_vector"] = best_time(lambda: fluxcal.fit_vector(x, ref), R)
        t["calibrate vector"] = best_time(lambda: fluxcal.calibrate(x, reference=ref), R)

        X = np.column_stack([ref, np.ones(n)])
        t["numpy lstsq (vector model)"] = best_time(lambda: np.linalg.lstsq(X, x, rcond=None), R)

        th0 = theta_of(start)
        sols = {}
        for key, kw in (("scipy trf, analytic J", dict(method="trf", jac=jacobian)),
                        ("scipy lm, analytic J", dict(method="lm", jac=jacobian)),
                        ("scipy trf, 2-point FD J", dict(method="trf", jac="2-point"))):
            def run(kw=kw):
                return least_squares(residual, th0, args=(x, H), **kw)
            t[key] = best_time(run, R)
            sols[key] = run()
        fx = theta_of(fluxcal.refine(start, x))
        scale = np.concatenate([np.full(3, H), np.ones(6)])  # offsets relative to |field|, matrix absolute
        jac_err = check_jacobian(x[: min(n, 2000)], th0, H)
        for key, sol in sols.items():
            checks.append(f"N={n}: {key}: {sol.nfev} evaluations, status {sol.status}, cost {sol.cost:.6g}; "
                          f"max |θ_scipy − θ_fluxcal| / scale = {np.max(np.abs(sol.x - fx) / scale):.1e}")
        checks.append(f"N={n}: analytic Jacobian vs central differences (max rel) = {jac_err:.1e}")
        cost_fx = 0.5 * np.sum(residual(fx, x, H) ** 2)
        checks.append(f"N={n}: fluxcal.refine cost {cost_fx:.6g}")

    if worker is not None and worker.available:
        jobs = [{"data": f"n{n}", "method": m, "ref_norm": H, "noise_std": 0.01 * H, "repeat": args.repeat}
                for n in args.sizes for m in ("ellipsoid_fit", "ellipsoid_fit_fang", "sphere_fit", "twostep_hsi")]
        try:
            res = worker.run({f"n{n}": data[n] for n in args.sizes}, jobs)
            for r in res:
                n = int(r["data"][1:])
                times[n][f"magyc {r['method']}"] = r["seconds"] if not r["error"] else float("nan")
                if r["error"]:
                    checks.append(f"magyc {r['method']} N={n} raised {r['error']}")
        except MagycUnavailable as exc:
            print(f"magyc: unavailable ({exc})")

    sizes = args.sizes
    fl_rows = [("fluxcal.fit_ellipsoid(method='ls')", "fit_ellipsoid ls"),
               ("fluxcal.fit_ellipsoid(method='als')", "fit_ellipsoid als"),
               ("fluxcal.refine(als fit) — magnitude model", "refine"),
               ("fluxcal.calibrate() — outlier screen, ALS + refine of 3 shapes", "calibrate"),
               ("fluxcal.calibrate(outliers='keep') — ALS + refine of 3 shapes", "calibrate keep"),
               ("fluxcal.calibrate(shape='sym') — outlier screen, ALS + refine", "calibrate sym"),
               ("fluxcal.fit_vector(x, reference)", "fit_vector"),
               ("fluxcal.calibrate(x, reference=…) — outlier screen + vector fit", "calibrate vector")]
    peers = [("magyc ellipsoid_fit", "fit_ellipsoid ls"), ("magyc ellipsoid_fit_fang", "fit_ellipsoid ls"),
             ("magyc sphere_fit", "fit_ellipsoid ls"),
             ("scipy trf, analytic J", "refine"), ("scipy lm, analytic J", "refine"),
             ("scipy trf, 2-point FD J", "refine"),
             ("magyc twostep_hsi", "calibrate"), ("numpy lstsq (vector model)", "fit_vector")]
    print("\n### fluxcal\n")
    table(["case"] + [f"N = {n:.0e}" for n in sizes] + [f"ns/sample at {sizes[-1]:.0e}"],
          [[label] + [fmt_t(times[n][k]) for n in sizes] + [f"{1e9 * times[sizes[-1]][k] / sizes[-1]:.0f}"]
           for label, k in fl_rows])
    print("\n### peers (ratio = peer time / fluxcal time; > 1: fluxcal faster)\n")
    rows = []
    for k, base in peers:
        if k not in times[sizes[0]]:
            continue
        row = [k, base]
        row += [fmt_t(times[n].get(k)) for n in sizes]
        row += [f"{times[n][k] / times[n][base]:.1f}" if np.isfinite(times[n].get(k, np.nan)) else "—" for n in sizes]
        rows.append(row)
    table(["peer", "vs fluxcal"] + [f"N = {n:.0e}" for n in sizes] + [f"ratio at {n:.0e}" for n in sizes], rows)
    print("\nchecks:")
    for c in checks:
        print(f"  - {c}")
    print("\nreproduce:")
    print("  python3 -m venv build/bench-venv && build/bench-venv/bin/pip install \"numpy<2\" magyc   # peer venv, once")
    print(f"  .venv/bin/python bench/solvers.py --sizes {' '.join(map(str, sizes))} --repeat {args.repeat} --seed {args.seed}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
