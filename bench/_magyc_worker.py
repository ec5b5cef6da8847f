"""magyc (magyclib, PyPI `magyc` 1.0.0) runner for bench/accuracy.py and bench/solvers.py.

magyc needs NumPy < 2, gtsam and jax, so it cannot live in the project's venv. This file has two halves:

* the WORKER (`python _magyc_worker.py DATA.npz JOBS.json`, run with the interpreter of a venv that has
  magyc): runs each job — one magyc benchmark method on one array of the .npz — and prints a JSON list
  with the estimates (hard iron HI, forward soft iron SI, both as magyc returns them), the best wall time
  of `repeat` calls (taken inside the worker, after one warm-up when repeat > 1), the error if it raised
  and the warnings it gave. `python _magyc_worker.py --probe` prints the versions.
* the CLIENT (`MagycWorker`, imported by the bench scripts in the project venv): finds the interpreter,
  probes it, writes the arrays and jobs to a temporary folder and reads the answer back.

Set-up of the peer venv (build/ is git-ignored):
    python3 -m venv build/bench-venv && build/bench-venv/bin/pip install "numpy<2" magyc
Another interpreter can be named with FLUXCAL_MAGYC_PYTHON.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEFAULT_PYTHON = REPO / "build" / "bench-venv" / "bin" / "python"
SETUP = 'python3 -m venv build/bench-venv && build/bench-venv/bin/pip install "numpy<2" magyc'
METHODS = ("ellipsoid_fit", "ellipsoid_fit_fang", "twostep_hsi", "twostep_hi", "sphere_fit")


# ---------------------------------------------------------------------------------------------- client
class MagycUnavailable(RuntimeError):
    pass


class MagycWorker:
    """Runs magyc jobs in the peer interpreter. `available` / `reason` after construction."""

    def __init__(self, python: str | os.PathLike | None = None, timeout: float = 900.0):
        self.python = Path(python or os.environ.get("FLUXCAL_MAGYC_PYTHON") or DEFAULT_PYTHON)
        self.timeout = timeout
        self.versions: dict = {}
        self.available = False
        self.reason = ""
        if not self.python.exists():
            self.reason = f"no interpreter at {self.python} (set it up with: {SETUP})"
            return
        try:
            out = subprocess.run([str(self.python), __file__, "--probe"], capture_output=True, text=True,
                                 timeout=300)
        except (OSError, subprocess.TimeoutExpired) as exc:
            self.reason = f"{self.python} did not run: {type(exc).__name__}: {exc}"
            return
        if out.returncode != 0:
            last = (out.stderr.strip().splitlines() or ["(no message)"])[-1]
            self.reason = f"`import magyc` failed in {self.python}: {last}"
            return
        self.versions = json.loads(out.stdout)
        self.available = True

    def run(self, arrays: dict, jobs: list[dict]) -> list[dict]:
        """arrays: name → N×3 float array; jobs: dicts with `data` (a name of arrays), `method`, and
        optionally `ref_norm` (twostep: the known field norm), `noise_std` (twostep), `repeat` (timing)."""
        if not self.available:
            raise MagycUnavailable(self.reason)
        import numpy as np

        with tempfile.TemporaryDirectory(prefix="fluxcal-magyc-") as tmp:
            npz, spec = Path(tmp) / "data.npz", Path(tmp) / "jobs.json"
            np.savez(npz, **{k: np.ascontiguousarray(v, dtype=np.float64) for k, v in arrays.items()})
            spec.write_text(json.dumps(jobs))
            out = subprocess.run([str(self.python), __file__, str(npz), str(spec)], capture_output=True,
                                 text=True, timeout=self.timeout)
        if out.returncode != 0:
            raise MagycUnavailable(f"worker failed (exit {out.returncode}): {out.stderr.strip()[-500:]}")
        return json.loads(out.stdout)


# ---------------------------------------------------------------------------------------------- worker
def _probe() -> int:
    import numpy
    import magyc
    import magyc.benchmark_methods  # noqa: F401

    try:
        from importlib.metadata import version
        mv = version("magyc")
    except Exception:
        mv = getattr(magyc, "__version__", "?")
    print(json.dumps({"magyc": mv, "numpy": numpy.__version__, "python": sys.version.split()[0]}))
    return 0


def _call(method: str, x, job: dict):
    import numpy as np
    from magyc import benchmark_methods as bm

    fn = getattr(bm, method)
    if method in ("twostep_hsi", "twostep_hi"):
        ref = np.array([float(job["ref_norm"]), 0.0, 0.0])
        return fn(x, ref, measurement_noise_std=float(job.get("noise_std", 1e-3)))
    return fn(x)


def _work(npz_path: str, jobs_path: str) -> int:
    import warnings

    import numpy as np

    data = np.load(npz_path)
    jobs = json.loads(Path(jobs_path).read_text())
    results = []
    for job in jobs:
        x = data[job["data"]]
        method = job["method"]
        repeat = int(job.get("repeat", 1))
        res = {"data": job["data"], "method": method, "hard_iron": None, "soft_iron": None,
               "seconds": None, "error": None, "warnings": []}
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                if repeat > 1:
                    _call(method, x, job)  # warm-up
                best = float("inf")
                for _ in range(repeat):
                    t0 = time.perf_counter()
                    out = _call(method, x, job)
                    best = min(best, time.perf_counter() - t0)
                res["seconds"] = best
                res["hard_iron"] = np.asarray(out[0], dtype=float).reshape(3).tolist()
                if method in ("ellipsoid_fit", "ellipsoid_fit_fang", "twostep_hsi"):
                    res["soft_iron"] = np.real(np.asarray(out[1])).astype(float).reshape(3, 3).tolist()
            except Exception as exc:  # report, never stop the batch
                res["error"] = f"{type(exc).__name__}: {exc}"
        res["warnings"] = sorted({f"{w.category.__name__}: {w.message}" for w in caught})
        results.append(res)
    json.dump(results, sys.stdout)  # NaN is written as NaN; json.loads reads it back
    return 0


if __name__ == "__main__":
    if sys.argv[1:] == ["--probe"]:
        sys.exit(_probe())
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    sys.exit(_work(sys.argv[1], sys.argv[2]))
