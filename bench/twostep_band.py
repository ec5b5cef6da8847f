"""TWOSTEP on a band of tilts against the Cramér–Rao bound (accuracy, not speed): a sensor that yaws freely but tilts
only ±20…45° (a car, a drone), its offset along the axis it sees least of. Prints, per band and noise, the RMS error
of z's offset and of A's zz entry over `--seeds` runs in units of their bound (fluxcal.crlb), for fluxcal.twostep and
fluxcal.calibrate (maximum likelihood), and how often twostep is flagged not identifiable.

    PYTHONPATH=python .venv/bin/python bench/twostep_band.py [--seeds 12] [--n 1000]
"""
import argparse
import warnings

import numpy as np
from scipy.spatial.transform import Rotation

import fluxcal

H = 50000.0
W = np.array([[1.08, 0.04, -0.03], [0.04, 0.95, 0.02], [-0.03, 0.02, 1.02]])  # symmetric soft iron: reading = W h + b
B = np.array([1500.0, -800.0, 400.0])
DIRECTION = np.array([20000.0, 1000.0, 45000.0]) / np.linalg.norm([20000.0, 1000.0, 45000.0])  # inclination 66°


def readings(rng, n, band_deg, sigma):
    """Field directions of a sensor yawing freely, pitching and rolling within ±band_deg; clean and noisy readings."""
    angles = np.c_[rng.uniform(-180, 180, n), rng.uniform(-band_deg, band_deg, (n, 2))]
    field = Rotation.from_euler("ZYX", angles, degrees=True).inv().apply(H * DIRECTION)
    clean = field @ W.T + B
    return clean, clean + rng.normal(0.0, sigma, (n, 3))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=12)
    parser.add_argument("--n", type=int, default=1000)
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore")
    truth = fluxcal.Calibration(offset=B, matrix=np.linalg.inv(W), field_norm=H)
    print(f"{'band':>5} {'σ nT':>6} | {'twostep b_z':>11} {'a_zz':>6} {'not ident.':>10} | {'calibrate b_z':>13} {'a_zz':>6}")
    for band in (20, 30, 45):
        for sigma in (20.0, 50.0, 100.0, 200.0):
            errors = {"twostep": [], "calibrate": []}
            flagged = 0
            for seed in range(args.seeds):
                rng = np.random.default_rng(1000 * band + seed)
                clean, m = readings(rng, args.n, band, sigma)
                if seed == 0:
                    bound = np.sqrt(np.diag(fluxcal.crlb(truth, clean, sigma)))
                two = fluxcal.twostep(m, H)
                flagged += not two.summary.get("identifiable", True)
                ml = fluxcal.calibrate(m, field_norm=H, shape="sym", outliers="keep")
                for name, cal in (("twostep", two), ("calibrate", ml)):
                    a = 0.5 * (cal.matrix + cal.matrix.T)
                    errors[name].append([cal.offset[2] - B[2], a[2, 2] - truth.matrix[2, 2]])
            ratio = {k: np.sqrt(np.mean(np.square(v), axis=0)) / bound[[2, 8]] for k, v in errors.items()}
            print(f"±{band:>3}° {sigma:6.0f} | {ratio['twostep'][0]:11.2f} {ratio['twostep'][1]:6.2f} "
                  f"{flagged:>4}/{args.seeds:<5} | {ratio['calibrate'][0]:13.2f} {ratio['calibrate'][1]:6.2f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
