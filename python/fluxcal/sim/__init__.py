"""Simulation: scenes of orientations in a known field, and sensor effects applied in order.

    scene = sim.sweeps("yxz", per_turn=600) or sim.uniform(2000, rng)
    sensor = [sim.SoftIron(W), sim.HardIron(b), sim.WhiteNoise(sigma)]
    result = sim.simulate(scene, sensor, field=[20e3, 1e3, 45e3], rng=rng)   # result.readings, result.truth

A new effect is one small class (see effects.py)."""
from .effects import Effect, HardIron, SoftIron, WhiteNoise, random_sensor
from .scene import Scene, sweeps, uniform
from .simulate import Simulation, simulate

__all__ = ["Effect", "HardIron", "SoftIron", "WhiteNoise", "random_sensor", "Scene", "sweeps", "uniform",
           "Simulation", "simulate"]
from .foct import FoctSimulation, foct_zero_bias
