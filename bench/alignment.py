"""Wall-clock benchmark of fluxcal.alignment.align_to_gravity (magnetometer axes onto the accelerometer's).

    python bench/alignment.py [--sizes 1000,100000] [--repeat 5] [--seed 3]

Scene (seeded): uniformly random static attitudes, the field at 62° dip, a magnetometer turned 3° about a random
axis from the accelerometer, 1 % direction noise on each. fluxcal's C++ (linear start, Gauss–Newton from it and
from R = I) against its SciPy oracle (fluxcal.oracle.alignment: scipy least_squares from R = I) in the same run;
no PyPI package implements the dot-product-invariance alignment, so the oracle is the yardstick. Each time is
the best of --repeat runs after one warm-up (bench/_timing.py); the agreement (rotation angle between the two,
dip difference) is printed too.
"""
from __future__ import annotations

import argparse

import numpy as np
import scipy
from scipy.spatial.transform import Rotation

import fluxcal
from fluxcal import oracle
from fluxcal.alignment import align_to_gravity
from _timing import best_time, machine_facts, table  # noqa: E402

DIP = np.radians(62.0)


def scene(n: int, rng):
    turn = Rotation.from_rotvec(np.radians(3.0) * Rotation.random(random_state=rng).apply([1, 0, 0]))
    attitudes = Rotation.random(n, random_state=rng)
    field = turn.inv().apply(attitudes.inv().apply(50.0 * np.array([np.cos(DIP), 0.0, np.sin(DIP)])))
    force = attitudes.inv().apply([0.0, 0.0, -9.81])
    return field + 0.5 * rng.standard_normal(field.shape), force + 0.0981 * rng.standard_normal(force.shape)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", default="1000,100000")
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--seed", type=int, default=3)
    args = p.parse_args()
    rng = np.random.default_rng(args.seed)
    rows = []
    for n in (int(v) for v in args.sizes.split(",")):
        h, f = scene(n, rng)
        ours = best_time(lambda: align_to_gravity(h, f), args.repeat)
        ref = best_time(lambda: oracle.align_to_gravity(h, f), max(1, args.repeat // 2))
        a, o = align_to_gravity(h, f), oracle.align_to_gravity(h, f)
        angle = np.degrees(np.linalg.norm(Rotation.from_matrix(a.rotation @ o["rotation"].T).as_rotvec()))
        rows.append([f"{n}", f"{1e3 * ours:.3g}", f"{1e3 * ref:.3g}", f"{ref / ours:.1f}",
                     f"{angle:.1e}", f"{abs(a.dip_deg - np.degrees(o['dip'])):.1e}"])
    for name, value in machine_facts(fluxcal=fluxcal.__version__, numpy=np.__version__, scipy=scipy.__version__):
        print(f"{name}: {value}")
    table(["N", "fluxcal (ms)", "SciPy oracle (ms)", "oracle / fluxcal", "rotation Δ (°)", "dip Δ (°)"], rows)


if __name__ == "__main__":
    main()
