import io
import os
import subprocess
import sys
import traceback
import warnings
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
# Others' real recordings live beside the clone (../shared/data/real); never copied into the repo.
REAL_DATA = Path(os.environ.get("FLUXCAL_REAL_DATA", REPO.parent / "shared" / "data" / "real"))


@pytest.fixture
def real_data() -> Path:
    if not REAL_DATA.is_dir():
        pytest.fail(f"real recordings not found at {REAL_DATA} (set FLUXCAL_REAL_DATA)")
    return REAL_DATA


def run_cli(*args, cwd=None, process=False):
    """Run the `fluxcal` command line; returns a CompletedProcess. By default in this process, as
    `python -m fluxcal` runs it (`fluxcal.cli.main`: its exit code and output; an uncaught exception's traceback
    on stderr and code 1; a fresh interpreter's warning filters; empty standard input), because starting Python
    and importing NumPy and SciPy took ~2 s of each of some 300 runs in the tests. `process=True` starts
    `python -m fluxcal` itself."""
    argv = [str(a) for a in args]
    if process:
        return subprocess.run([sys.executable, "-m", "fluxcal", *argv], capture_output=True, text=True,
                              cwd=cwd, stdin=subprocess.DEVNULL, timeout=300)
    from fluxcal.cli import main

    out, err, streams, here = io.StringIO(), io.StringIO(), (sys.stdin, sys.stdout, sys.stderr), os.getcwd()
    try:
        if cwd is not None:
            os.chdir(cwd)
        sys.stdin, sys.stdout, sys.stderr = io.StringIO(""), out, err
        with warnings.catch_warnings():
            warnings.resetwarnings()  # as a fresh interpreter without -W has them
            for category in (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning):
                warnings.simplefilter("ignore", category)
            try:
                code = main(argv)
            except SystemExit as exc:  # argparse's usage errors
                code = exc.code
            except Exception:  # noqa: BLE001 — what the interpreter does with an uncaught exception
                traceback.print_exc()
                code = 1
    finally:
        sys.stdin, sys.stdout, sys.stderr = streams
        os.chdir(here)
    if code is not None and not isinstance(code, int):
        print(code, file=err)
        code = 1
    return subprocess.CompletedProcess([sys.executable, "-m", "fluxcal", *argv], code or 0, out.getvalue(),
                                       err.getvalue())


def simulated(seed, n=2000, noise=0.005, field_norm=50000.0):
    """A random sensor (soft iron ±20 %, offset ≤ 50 % of the field) turned uniformly."""
    from fluxcal import sim

    rng = np.random.default_rng(seed)
    direction = rng.standard_normal(3)
    field = field_norm * direction / np.linalg.norm(direction)
    return sim.simulate(sim.uniform(n, rng), sim.random_sensor(field_norm, rng, noise=noise), field, rng)


def changing_field(s, k):
    """The simulation `s` in a field whose magnitude is k_i × |field| at reading i (a diurnal change, a storm):
    its clean readings b + k_i (m_i − b), the same noise, and each reading's |field|."""
    b = s.true_calibration().offset
    clean = b + k[:, None] * (s.clean - b)
    return clean, clean + (s.readings - s.clean), k * s.field_norm


SYM = np.triu_indices(3)


def theta_magnitude(cal):
    """θ of the magnitude model: the offset, then the matrix's upper triangle."""
    return np.r_[cal.offset, cal.matrix[SYM]]


def bound_sensor(seed):
    """The Monte-Carlo tests' sensor: |field| 50 000, σ = 1 % of it, soft iron within ±10 %, offset up to 50 %;
    (rng, |field|, σ as a share of it, its effects, the field vector)."""
    from fluxcal import sim

    rng = np.random.default_rng(seed)
    H, noise = 50000.0, 0.01
    effects = sim.random_sensor(H, rng, soft_iron=0.1, offset=0.5, noise=noise)
    return rng, H, noise, effects, H * np.array([0.3, -0.2, 0.93]) / np.linalg.norm([0.3, -0.2, 0.93])


def changing_field_errors(fit, runs: int = 200, seed: int = 7, change: float = 0.02) -> dict:
    """The Monte-Carlo of a field whose magnitude changes by ±`change` while the sensor turns (N = 300, σ = 1 % of
    |field|, soft iron ±10 %, offset ≤ 50 %: bound_sensor): each run's errors of θ = [b, A's upper
    triangle] over √CRLB for `fit(readings, field_norm)` → θ, given each reading's |field| ("own") and one |field|
    for all ("one"); with "rms" the RMS of each group (offset, matrix) and "mean" the largest |mean error|."""
    from fluxcal import crlb, sim

    rng, H, noise, effects, field = bound_sensor(seed)
    z = {"own": [], "one": []}
    for run in range(runs):
        s = sim.simulate(sim.uniform(300, rng), effects, field, rng)
        clean, readings, norms = changing_field(s, 1 + change * np.sin(np.linspace(0, 3, 300) + run))
        truth = s.true_calibration()
        bound = np.sqrt(np.diag(crlb(truth, clean, noise * H)))
        for name, given in (("own", norms), ("one", H)):
            z[name].append((fit(readings, given) - theta_magnitude(truth)) / bound)
    return {name: {"rms": [float(np.sqrt(np.mean(np.array(e)[:, g] ** 2))) for g in (slice(0, 3), slice(3, 9))],
                   "mean": float(np.abs(np.mean(e, axis=0)).max())} for name, e in z.items()}
