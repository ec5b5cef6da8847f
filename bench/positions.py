"""Wall-clock benchmark of fluxcal.positions (seed 002, multi-position calibration) from Python.

    python bench/positions.py [--sizes 12,1000] [--repeat 5] [--oracle-max-joint 100] [--seed 7]

Scenes (seeded): seed 002's sensor (U0, K in mV, mV/nT), field 52200 nT at 52° dip, noise 0.45 mV
(≈ 5 nT), accelerometer with noise ≈ 0.005°. N = 12: the twelve positions tilted ≤ 1° and turned ≤ 2°
in heading; other N: random static attitudes, turned ≤ 2° in heading (nominal = without the turn).
Cases, each timed against its NumPy/SciPy oracle (fluxcal.oracle.positions) in the same run:
  linear     fp.calibrate(mag, acc, f, rotations=nominal)          levelling + least squares + statistics
             vs oracle.level + oracle.fit_positions (numpy lstsq, no statistics)
  joint yaw  fp.calibrate(..., estimate_yaw=True)                  Ceres, 12 + N parameters
             vs oracle.calibrate_joint (scipy least_squares 'lm', finite-difference Jacobian); the oracle
             is only run for N <= --oracle-max-joint (it costs O(N²) per iteration)
  accel      fp.calibrate_accelerometer(acc_raw)                   Ceres, 9 parameters
             vs oracle.calibrate_accelerometer (scipy least_squares)
No third-party peer implements this method (imu_tk does the accelerometer part in C++ only; it is not
installable from PyPI), so the oracle is the yardstick. Each time is the best of --repeat runs after one
warm-up (bench/_timing.py). Agreement of fluxcal and oracle (max |ΔK| in nT equivalent) is printed too.
"""
from __future__ import annotations

import argparse
import sys

import numpy as np
from scipy.spatial.transform import Rotation

import fluxcal
import fluxcal.positions as fp
from fluxcal import sim
from fluxcal.oracle import positions as oracle
from _timing import best_time, machine_facts  # noqa: E402

G = 9.80665
FIELD = fp.reference_field(total=52200.0, inclination=52.0)


def scene(n: int, rng):
    if n == 12:
        sc = sim.twelve_scene("ned", tilt_deg=1.0, yaw_deg=2.0, rng=rng)
    else:
        nominal = Rotation.random(n, random_state=rng.integers(2**31)).as_matrix()
        turn = Rotation.from_rotvec(np.outer(rng.uniform(-2, 2, n), [0, 0, np.radians(1.0)])).as_matrix()
        sc = sim.PositionsScene("ned", nominal, turn @ nominal)
    acc = sim.Accelerometer.random(rng, noise=G * np.radians(0.005))
    s = sim.simulate_positions(sc, FIELD, noise=0.45, accelerometer=acc, rng=rng)
    return sc, s


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="12,1000", help="numbers of positions (comma separated)")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--oracle-max-joint", type=int, default=100, help="largest N for the SciPy joint oracle")
    ap.add_argument("--seed", type=int, default=7)
    args = ap.parse_args(argv)
    sizes = [int(v) for v in args.sizes.split(",")]
    sizes_joint_oracle = sorted(set(sizes) | {min(args.oracle_max_joint, max(sizes))})

    print("machine")
    for k, v in machine_facts(NumPy=np.__version__, fluxcal=getattr(fluxcal, "__version__", "?")):
        print(f"  {k:<32} {v}")
    print(f"\nbest of {args.repeat} after one warm-up; oracle joint only for N <= {args.oracle_max_joint}\n")
    k_scale = float(np.mean(np.diag(sim.paper_sensor()[1])))
    header = f"  {'case':<12} {'N':>6} {'fluxcal [ms]':>13} {'oracle [ms]':>12} {'oracle/fluxcal':>15} {'max|dK| [nT]':>13}"
    print(header)
    ok = True
    for n in sorted(set(sizes) | set(sizes_joint_oracle)):
        rng = np.random.default_rng(args.seed + n)
        sc, s = scene(n, rng)
        acc_cal = fp.calibrate_accelerometer(s.acc_raw)
        acc = acc_cal.apply(s.acc_raw)
        f_local = fp.to_local(FIELD, "ned")

        def lin():
            return fp.calibrate(s.outputs, acc, FIELD, rotations=sc.nominal)

        def lin_oracle():
            H = np.array([oracle.level(R, a, "ned").T @ f_local for R, a in zip(sc.nominal, acc)])
            return oracle.fit_positions(s.outputs, H)

        def joint():
            return fp.calibrate(s.outputs, acc, FIELD, rotations=sc.nominal, estimate_yaw=True)

        def joint_oracle():
            return oracle.calibrate_joint(s.outputs, acc, sc.nominal, f_local, "ned")

        cases = []
        if n in sizes:
            cases.append(("linear", lin, lin_oracle, args.repeat))
        cases.append(("joint yaw", joint, joint_oracle if n <= args.oracle_max_joint else None, args.repeat))
        if n in sizes:
            cases.append(("accel", lambda: fp.calibrate_accelerometer(s.acc_raw),
                          lambda: oracle.calibrate_accelerometer(s.acc_raw), args.repeat))
        for name, fn, ofn, rep in cases:
            t = best_time(fn, rep)
            to = best_time(ofn, min(rep, 2)) if ofn else float("nan")
            dk = float("nan")
            if ofn is not None and name != "accel":
                K_o = ofn()[1]
                dk = float(np.abs(fn().K - K_o).max() / k_scale)
                ok = ok and dk < 1e-3
            elif name == "accel":
                dk = float(np.abs(fn().matrix - ofn()[1]).max())  # dimensionless (T), not nT
            print(f"  {name:<12} {n:6d} {1e3 * t:13.3f} {1e3 * to:12.3f} {to / t:15.1f} {dk:13.2e}")
    print("\n(max|dK|: fluxcal vs oracle, in nT equivalent of K's mean diagonal; for 'accel' the max |ΔT|.)")
    print("OK" if ok else "MISMATCH (fluxcal and oracle differ by more than 1e-3 nT equivalent)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
