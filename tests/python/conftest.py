import os
import subprocess
import sys
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


def run_cli(*args, cwd=None):
    """Run the installed `fluxcal` command line; returns the CompletedProcess."""
    return subprocess.run([sys.executable, "-m", "fluxcal", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, stdin=subprocess.DEVNULL, timeout=300)


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
