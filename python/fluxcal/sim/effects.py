"""Sensor effects. Each turns the values so far (N×3, starting from the true field in the sensor frame)
into what the next stage sees. Adding an effect means adding one class with `apply` and `n_params`."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


class Effect:
    """Base class. `apply(values, context)`: context has `t` (s), `rng` and `truth` (true field).
    `is_noise`: a random effect, left out of Simulation.clean (the noise-free readings)."""

    n_params = 0
    is_noise = False

    def apply(self, values: np.ndarray, context) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError


@dataclass
class SoftIron(Effect):
    """Soft iron, scale factors and non-orthogonality as one matrix: m = W h."""

    matrix: np.ndarray
    n_params = 9

    def apply(self, values, context):
        return values @ np.asarray(self.matrix, dtype=float).T


@dataclass
class HardIron(Effect):
    """Hard iron and electronic zero offset: m = h + b."""

    offset: np.ndarray
    n_params = 3

    def apply(self, values, context):
        return values + np.asarray(self.offset, dtype=float)


@dataclass
class WhiteNoise(Effect):
    """Independent Gaussian noise of standard deviation `sigma` on every axis."""

    sigma: float
    n_params = 1
    is_noise = True

    def apply(self, values, context):
        return values + self.sigma * context.rng.standard_normal(values.shape)


def random_sensor(field_norm: float, rng=None, soft_iron: float = 0.2, offset: float = 0.5,
                  noise: float = 0.005) -> list:
    """A random three-axis sensor: symmetric soft-iron matrix I + E with |E_ij| ≤ `soft_iron`,
    offset of length up to `offset`·|field|, white noise `noise`·|field|."""
    rng = np.random.default_rng(rng)
    E = rng.uniform(-soft_iron, soft_iron, (3, 3))
    W = np.eye(3) + np.triu(E) + np.triu(E, 1).T
    direction = rng.standard_normal(3)
    b = direction / np.linalg.norm(direction) * rng.uniform(0, offset) * field_norm
    return [SoftIron(W), HardIron(b), WhiteNoise(noise * field_norm)]
