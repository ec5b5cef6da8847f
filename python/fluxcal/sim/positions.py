"""Static multi-position scenes with an accelerometer (seed 002's twelve-position method and others).

    scene = sim.twelve_scene("nue", tilt_deg=1.0, yaw_deg=2.0, rng=rng)       # positioning errors
    s = sim.simulate_positions(scene, field_ned, sensor=sim.paper_sensor(), noise=0.45,
                               accelerometer=sim.Accelerometer.random(rng), rng=rng)
    s.outputs, s.acc_raw, s.acc_true, s.truth

Positions are body→local rotations in the scene's frame ("ned" or "nue", see fluxcal.positions).
Positioning errors: each true attitude is the nominal one tilted by a random rotation of up to
`tilt_deg` about a horizontal axis and turned by up to `yaw_deg` in heading. The accelerometer reads
the true specific force through its own W_a (scale and misalignment), offset and noise.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .. import _core

STANDARD_GRAVITY = 9.80665
_NED_TO_LOCAL = {"ned": np.eye(3), "nue": np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]])}
_UP = {"ned": np.array([0.0, 0, -1]), "nue": np.array([0.0, 1, 0])}

#: Seed 002's published calibration: U0 (mV) and K (mV/nT), in its body axes (x fwd, y up, z right).
PAPER_U0 = np.array([-497.08827, 266.96974, -55.90444])
PAPER_K = np.array([[0.08950715, -0.02225698, -0.00046962],
                    [0.00018554, 0.08954021, -0.00008744],
                    [0.00041184, 0.00018746, 0.08925137]])


@dataclass
class PositionsScene:
    frame: str
    nominal: np.ndarray  # N×3×3 nominal body→local rotations
    true: np.ndarray     # N×3×3 actual rotations (nominal with positioning errors)

    def __len__(self):
        return len(self.nominal)


@dataclass
class Accelerometer:
    """raw = W a + b + noise, a the true specific force (frame body axes)."""
    offset: np.ndarray
    matrix: np.ndarray
    noise: float = 0.0

    @classmethod
    def random(cls, rng, scale=0.02, misalignment=0.005, offset=0.2, noise=0.0005):
        W = np.eye(3) + np.diag(rng.uniform(-scale, scale, 3))
        W += np.triu(rng.uniform(-misalignment, misalignment, (3, 3)), 1)  # upper triangular: x axis defines
        return cls(rng.uniform(-offset, offset, 3), W, noise)

    def read(self, specific_force, rng) -> np.ndarray:
        a = np.asarray(specific_force, dtype=float)
        noise = self.noise * rng.standard_normal(a.shape) if self.noise else 0.0
        return a @ self.matrix.T + self.offset + noise


@dataclass
class PositionsSimulation:
    scene: PositionsScene
    outputs: np.ndarray     # N×3 sensor outputs U
    acc_raw: np.ndarray     # N×3 raw accelerometer readings
    acc_true: np.ndarray    # N×3 true specific force
    reference: np.ndarray   # N×3 true body-frame field
    truth: dict             # U0, K, field_ned, accelerometer


def _perturb(nominal, frame, tilt_deg, yaw_deg, rng):
    up = _UP[frame]
    out = []
    for R in nominal:
        axis = rng.standard_normal(3)
        axis -= axis.dot(up) * up
        axis /= np.linalg.norm(axis)
        tilt = Rotation.from_rotvec(axis * np.radians(rng.uniform(-tilt_deg, tilt_deg))).as_matrix()
        turn = Rotation.from_rotvec(up * -np.radians(rng.uniform(-yaw_deg, yaw_deg))).as_matrix()
        out.append(turn @ tilt @ R)
    return np.array(out)


def twelve_scene(frame: str = "nue", tilt_deg: float = 0.0, yaw_deg: float = 0.0, rng=None) -> PositionsScene:
    """The twelve positions of seed 002 with positioning errors up to tilt_deg / yaw_deg."""
    nominal = np.asarray(_core.twelve_positions(_core.Frame.__members__[frame])).reshape(-1, 3, 3)
    rng = rng if rng is not None else np.random.default_rng(0)
    return PositionsScene(frame, nominal, _perturb(nominal, frame, tilt_deg, yaw_deg, rng))


def random_scene(n: int, frame: str = "ned", rng=None, tilt_deg: float = 0.0, yaw_deg: float = 0.0) -> PositionsScene:
    """n uniformly random attitudes (nominal = random), with positioning errors as above."""
    rng = rng if rng is not None else np.random.default_rng(0)
    nominal = Rotation.random(n, random_state=rng).as_matrix()
    return PositionsScene(frame, nominal, _perturb(nominal, frame, tilt_deg, yaw_deg, rng))


def paper_sensor():
    """(U0, K) of seed 002's example result (mV, mV/nT; body axes x fwd, y up, z right)."""
    return PAPER_U0.copy(), PAPER_K.copy()


def simulate_positions(scene: PositionsScene, field_ned, sensor=None, noise: float = 0.0, accelerometer=None,
                       gravity: float = STANDARD_GRAVITY, rng=None) -> PositionsSimulation:
    """Outputs U = U0 + K Rᵀ f + noise (noise σ in output units) and accelerometer readings.

    sensor: (U0, K), default the paper's; accelerometer: an `Accelerometer` (default ideal, no noise)."""
    rng = rng if rng is not None else np.random.default_rng(0)
    U0, K = sensor if sensor is not None else paper_sensor()
    acc = accelerometer if accelerometer is not None else Accelerometer(np.zeros(3), np.eye(3), 0.0)
    f_local = _NED_TO_LOCAL[scene.frame] @ np.asarray(field_ned, dtype=float)
    H = np.einsum("nji,j->ni", scene.true, f_local)  # Rᵀ f
    U = U0 + H @ np.asarray(K).T
    if noise:
        U = U + noise * rng.standard_normal(U.shape)
    sf_true = gravity * np.einsum("nji,j->ni", scene.true, _UP[scene.frame])  # Rᵀ up · g
    return PositionsSimulation(scene, U, acc.read(sf_true, rng), sf_true, H,
                               {"U0": np.asarray(U0), "K": np.asarray(K), "field_ned": np.asarray(field_ned, float),
                                "accelerometer": acc})


__all__ = ["Accelerometer", "PAPER_K", "PAPER_U0", "PositionsScene", "PositionsSimulation", "paper_sensor",
           "random_scene", "simulate_positions", "twelve_scene"]
