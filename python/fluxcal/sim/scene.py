"""Scenes: the sensor's orientations over time in a fixed world field."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation


@dataclass
class Scene:
    """`rotations[i]` turns sensor-frame vectors into the world frame at time `t[i]`."""

    rotations: Rotation
    t: np.ndarray

    def __len__(self) -> int:
        return len(self.t)

    def sensor_field(self, world_field) -> np.ndarray:
        """The world field seen in the sensor frame at every time (N×3)."""
        return self.rotations.inv().apply(np.asarray(world_field, dtype=float))


def uniform(n: int, rng=None, rate_hz: float = 50.0) -> Scene:
    """`n` orientations drawn uniformly (Haar measure): every field direction equally likely."""
    rng = np.random.default_rng(rng)
    return Scene(Rotation.random(n, random_state=rng), np.arange(n) / rate_hz)


def sweeps(axes: str = "yxz", per_turn: int = 600, tilt_deg: float = 0.0, rate_hz: float = 50.0,
           rng=None) -> Scene:
    """Full turns about each body axis in `axes`, one after the other (seed 004: y, then x, then z).

    `tilt_deg` adds a random hand wobble (standard deviation, degrees) so the turns are not perfect
    great circles, as when an instrument is turned by hand.
    """
    rng = np.random.default_rng(rng)
    angles = np.linspace(0.0, 2 * np.pi, per_turn, endpoint=False)
    unit = {"x": [1, 0, 0], "y": [0, 1, 0], "z": [0, 0, 1]}
    parts = []
    for axis in axes:
        if axis not in unit:
            raise ValueError(f"axes: {axis!r} is not one of x, y, z")
        parts.append(Rotation.from_rotvec(np.outer(angles, unit[axis])))
    rot = Rotation.concatenate(parts)
    if tilt_deg > 0:
        rot = rot * Rotation.from_rotvec(np.deg2rad(tilt_deg) * rng.standard_normal((len(rot), 3)))
    return Scene(rot, np.arange(len(rot)) / rate_hz)
