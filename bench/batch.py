"""Throughput of fleet calibration (fluxcal.batch) on a local Dask cluster against a plain serial loop.

    python bench/batch.py [--units 400] [--readings 300] [--workers 1,2] [--seed 0]

Writes --units simulated recordings (CSV, --readings readings each, one sensor model: soft iron ±5 %,
offset ≤ 10 % of 50 000 nT, noise 0.5 %) into a temporary folder, then calibrates all of them
  serial      a Python loop calling fluxcal.batch.calibrate_unit on each file (read, calibrate, write JSON)
  dask N      fluxcal.batch.calibrate_fleet on a LocalCluster of N single-threaded worker processes:
              the same function, one task per recording
each into a fresh output folder. Throughput = units / seconds from the first submission to the last
result; the cluster start (processes, imports, warm-up task) is shown apart, since a fleet run pays it
once for thousands of units. Ratios are against the serial loop of the same run. The machine may be
shared: the load average before the run is printed with the table.
"""
from __future__ import annotations

import argparse
import logging
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import fluxcal
from fluxcal import sim, write_csv
from fluxcal.batch import calibrate_fleet, calibrate_unit
from _timing import machine_facts  # noqa: E402  (bench/ is on sys.path when run as a script)

H = 50000.0


def write_fleet(folder: Path, units: int, readings: int, seed: int) -> list:
    paths = []
    for i in range(units):
        rng = np.random.default_rng([seed, i])
        direction = rng.standard_normal(3)
        s = sim.simulate(sim.uniform(readings, rng), sim.random_sensor(H, rng, soft_iron=0.05, offset=0.1),
                         H * direction / np.linalg.norm(direction), rng)
        path = folder / f"unit_{i:05d}.csv"
        write_csv(path, {"t": s.t, "mx": s.readings[:, 0], "my": s.readings[:, 1], "mz": s.readings[:, 2]},
                  units={"mx": "nT", "my": "nT", "mz": "nT"})
        paths.append(path)
    return paths


def serial(paths, out: Path) -> float:
    out.mkdir()
    start = time.perf_counter()
    for p in paths:
        record = calibrate_unit(p, out / f"{p.stem}.json", "auto", H)
        if record["status"] != "ok":
            raise RuntimeError(f"{p}: {record}")
    return time.perf_counter() - start


def on_dask(folder: Path, out: Path, workers: int) -> tuple[float, float]:
    """(startup seconds, calibration seconds) for a fresh LocalCluster of `workers` processes."""
    from dask.distributed import Client, LocalCluster

    start = time.perf_counter()
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None, silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        client.run(lambda: __import__("fluxcal.batch"))  # imports happen once per worker, not per unit
        startup = time.perf_counter() - start
        result = calibrate_fleet(folder, out, scheduler=cluster.scheduler_address, field_norm=H, progress=False)
    if result.summary["counts"]["ok"] != len(result.rows):
        raise RuntimeError(f"dask {workers}: {result.summary['counts']}")
    return startup, result.seconds


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--units", type=int, default=400)
    p.add_argument("--readings", type=int, default=300)
    p.add_argument("--workers", default="1,2", help="comma-separated worker counts")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    workers = [int(w) for w in args.workers.split(",")]

    import dask

    print(f"command: python bench/batch.py {' '.join(argv if argv is not None else sys.argv[1:])}".rstrip())
    print("machine (before the run): " + "; ".join(f"{k} {v}" for k, v in machine_facts(
        fluxcal=fluxcal.__version__, dask=dask.__version__)))
    print(f"fleet: {args.units} units × {args.readings} readings (CSV), calibrate method auto (ALS + ML "
          f"refinement), field norm given")

    with tempfile.TemporaryDirectory(prefix="fluxcal-bench-batch-") as tmp:
        tmp = Path(tmp)
        folder = tmp / "recordings"
        folder.mkdir()
        paths = write_fleet(folder, args.units, args.readings, args.seed)
        rows = [("serial loop", 1, None, serial(paths, tmp / "serial"))]
        for w in workers:
            startup, seconds = on_dask(folder, tmp / f"dask{w}", w)
            rows.append(("dask LocalCluster", w, startup, seconds))

    base = args.units / rows[0][3]
    print()
    print(f"| {'run':<18} | workers | startup s | calibration s | units/s | × serial |")
    print(f"|{'-' * 20}|---------|-----------|---------------|---------|----------|")
    for name, w, startup, seconds in rows:
        rate = args.units / seconds
        start = "—" if startup is None else f"{startup:.2f}"
        print(f"| {name:<18} | {w:>7} | {start:>9} | {seconds:>13.2f} | {rate:>7.1f} | {rate / base:>8.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
