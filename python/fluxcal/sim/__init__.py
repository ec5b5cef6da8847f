"""Simulation: scenes of orientations in a known field, and sensor effects applied in order.

    scene = sim.sweeps("yxz", per_turn=600) or sim.uniform(2000, rng)
    sensor = [sim.SoftIron(W), sim.HardIron(b), sim.WhiteNoise(sigma)]
    result = sim.simulate(scene, sensor, field=[20e3, 1e3, 45e3], rng=rng)   # result.readings, result.truth

A new effect is one small class (see effects.py)."""
from .effects import (CANDIDATES, ColoredNoise, CrossAxis, CubicNonlinearity, EddyCurrent, Effect, HardIron,
                      Hysteresis, Misalignment, MotorCurrent, MovingDipole, NonOrthogonality, OffsetDrift,
                      Quantization, Saturation, ScaleDrift, SoftIron, TemperatureOffset, TemperatureScale, TimeOffset,
                      WhiteNoise, ZLeakage, random_sensor)
from .scene import Scene, jittering, sweeps, tumble, uniform
from .simulate import Simulation, simulate

__all__ = ["CANDIDATES", "ColoredNoise", "CrossAxis", "CubicNonlinearity", "EddyCurrent", "Effect", "HardIron",
           "Hysteresis", "Misalignment", "MotorCurrent", "MovingDipole", "NonOrthogonality", "OffsetDrift",
           "Quantization", "Saturation", "ScaleDrift", "SoftIron", "TemperatureOffset", "TemperatureScale", "TimeOffset",
           "WhiteNoise", "ZLeakage", "random_sensor", "Scene", "sweeps", "tumble", "uniform", "Simulation",
           "simulate"]
from .positions import Accelerometer, PositionsScene, PositionsSimulation, paper_sensor, random_scene, simulate_positions, twelve_scene  # noqa: E402,F401
from . import cable
from .foct import FoctSimulation, foct_zero_bias
