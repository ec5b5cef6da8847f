"""Run a scene through a chain of sensor effects."""
from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
from scipy.linalg import polar

from ..calibration import Calibration
from .effects import HardIron, SoftIron


@dataclass
class Simulation:
    readings: np.ndarray  # N×3, what the sensor reports
    truth: np.ndarray     # N×3, true field in the sensor frame
    clean: np.ndarray     # N×3, the readings without the random (is_noise) effects
    t: np.ndarray
    effects: list
    field_norm: float
    temperature: np.ndarray | None = None  # °C, when the scene has one
    current: np.ndarray | None = None      # A, when the scene has one

    def true_calibration(self, units: str = "") -> Calibration:
        """The correction that undoes the linear effects: offset = Σ hard iron, matrix = (Π W)⁻¹ made
        symmetric (its polar factor), which is what field-magnitude calibration can identify."""
        W, b = np.eye(3), np.zeros(3)
        for e in self.effects:
            if isinstance(e, SoftIron):
                W, b = e.matrix @ W, e.matrix @ b
            elif isinstance(e, HardIron):
                b = b + e.offset
        _, sym = polar(np.linalg.inv(W), side="right")  # inv(W) = rotation · sym; |h| fixes only sym
        return Calibration(offset=b, matrix=sym, field_norm=self.field_norm, units=units, model="truth")


def simulate(scene, effects, field, rng=None) -> Simulation:
    """Readings of a sensor with `effects` (applied in order) turned through `scene` in the world
    field `field` (3-vector, world frame)."""
    rng = np.random.default_rng(rng)
    truth = scene.sensor_field(field)
    values, clean = truth.copy(), truth.copy()
    current = getattr(scene, "current", None)
    context = SimpleNamespace(t=scene.t, temp=scene.temperature, current=current, rotations=scene.rotations,
                              rng=rng, truth=truth)
    for effect in effects:
        values = effect.apply(values, context)
        if not effect.is_noise:
            clean = effect.apply(clean, context)
    return Simulation(readings=values, truth=truth, clean=clean, t=scene.t, effects=list(effects),
                      field_norm=float(np.linalg.norm(field)), temperature=scene.temperature, current=current)
