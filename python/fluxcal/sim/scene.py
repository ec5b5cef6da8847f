"""Scenes: the sensor's orientations over time in a fixed world field."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter
from scipy.spatial.transform import Rotation


@dataclass
class Scene:
    """`rotations[i]` turns sensor-frame vectors into the world frame at time `t[i]`; `temperature`
    (°C) is the sensor's temperature at each time, `current` (A) the current drawn near the sensor
    (motors, a heater), when the scene has them."""

    rotations: Rotation
    t: np.ndarray
    temperature: np.ndarray | None = None
    current: np.ndarray | None = None

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


def tumble(duration_s: float = 60.0, rate_hz: float = 50.0, turn_rate_deg: float = 60.0,
           temperature=(25.0, 10.0, 40.0), current=None, rng=None) -> Scene:
    """A sensor turned smoothly by hand through every orientation: the body rate wanders (a low-pass
    random process of RMS `turn_rate_deg` °/s per axis), so the path is smooth at the sample rate and
    covers the sphere within a minute. `temperature` = (mean, amplitude, period s): the sensor warms and
    cools as a sine plus a slow random wander (not monotonic in time, so temperature and time effects
    can be told apart); or a function of t (s) giving °C, e.g. a warm-up `lambda t: 20 + 15 * t / t[-1]`
    (monotonic: temperature and time effects then look alike); None for no temperature. `current` =
    (peak A, hold s): the current drawn near the sensor steps between random levels (throttle settings,
    10–100 % of the peak, each held for about `hold` s, with a 0.3 s spin-up lag); or a function of t;
    None (default) for none."""
    rng = np.random.default_rng(rng)
    n = int(round(duration_s * rate_hz))
    dt = 1.0 / rate_hz
    # Body rate: white noise through three first-order low-passes (0.5 s each), scaled to the requested
    # RMS — smooth to its second derivative, as a hand is at the sample rate.
    alpha = dt / 0.5
    omega = rng.standard_normal((n, 3))
    for _ in range(3):
        omega = lfilter([alpha], [1.0, alpha - 1.0], omega, axis=0)
    omega *= np.deg2rad(turn_rate_deg) / np.sqrt(np.mean(omega ** 2))
    quats = _integrate(Rotation.random(random_state=rng).as_quat(), Rotation.from_rotvec(omega * dt).as_quat())
    t = np.arange(n) * dt
    temp = None
    if callable(temperature):
        temp = np.asarray(temperature(t), dtype=float)
        if temp.shape != t.shape:
            raise ValueError(f"temperature: the function returned shape {temp.shape} for {t.size} times")
    elif temperature is not None:
        temp = warming(t, rng, *temperature, dt=dt)
    amps = None  # drawn last, so that a scene without current keeps the random stream of earlier versions
    if callable(current):
        amps = np.asarray(current(t), dtype=float)
        if amps.shape != t.shape:
            raise ValueError(f"current: the function returned shape {amps.shape} for {t.size} times")
    elif current is not None:
        amps = throttle(t, rng, *current, duration_s=duration_s, dt=dt)
    return Scene(Rotation.from_quat(quats), t, temp, amps)


def _integrate(start: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """The attitudes (n, 4 scalar-last quaternions) from `start` through the body-frame `steps` (n, 4): attitude i
    is start · step 0 ⋯ step i−1. The product SciPy's `Rotation.__mul__` forms, then normalised as it does, in the
    same order of operations (the same bits; checked over 120 000 steps), on Python floats: a Rotation per
    step cost 0.4 s of a minute's recording, a seventh of the time a diagnosis of it takes."""
    quats = np.empty((len(steps), 4))
    px, py, pz, pw = start.tolist()
    for i, (qx, qy, qz, qw) in enumerate(steps.tolist()):
        quats[i] = (px, py, pz, pw)
        cx, cy, cz = py * qz - pz * qy, pz * qx - px * qz, px * qy - py * qx  # p⃗ × q⃗
        x, y, z = pw * qx + qw * px + cx, pw * qy + qw * py + cy, pw * qz + qw * pz + cz
        w = pw * qw - px * qx - py * qy - pz * qz
        norm = math.sqrt(x * x + y * y + z * z + w * w)
        px, py, pz, pw = x / norm, y / norm, z / norm, w / norm
    return quats


def warming(t: np.ndarray, rng, mean: float = 25.0, amplitude: float = 10.0, period: float = 40.0,
            dt: float | None = None) -> np.ndarray:
    """A sensor's temperature (°C) at times t: a sine of `amplitude` about `mean` with `period` s plus a
    slow random wander (5 % of the amplitude per √s) — it rises and falls, so it does not follow time."""
    dt = float(np.median(np.diff(t))) if dt is None else dt
    wander = np.cumsum(rng.standard_normal(len(t))) * np.sqrt(dt) * 0.05 * amplitude
    return mean + amplitude * np.sin(2 * np.pi * t / period + rng.uniform(0, 2 * np.pi)) + wander - wander.mean()


def throttle(t: np.ndarray, rng, peak: float, hold: float, duration_s: float | None = None,
             dt: float | None = None) -> np.ndarray:
    """The current (A) drawn near the sensor at times t: random levels of 10–100 % of `peak`, each held
    for about `hold` s, reached through a first-order spin-up of 0.3 s (throttle settings of motors)."""
    dt = float(np.median(np.diff(t))) if dt is None else dt
    duration_s = float(np.ptp(t)) + dt if duration_s is None else duration_s
    ends = t[0] + np.cumsum(hold * rng.uniform(0.5, 1.5, int(duration_s / (0.5 * hold)) + 2))
    levels = peak * rng.uniform(0.1, 1.0, len(ends))
    lag = 1.0 - np.exp(-dt / 0.3)  # a first-order spin-up of 0.3 s, stable at any sample rate
    return lfilter([lag], [1.0, lag - 1.0], levels[np.searchsorted(ends, t)], zi=[levels[0] * (1 - lag)])[0]


def jittering(rng, levels=(0.0, 0.0, 5.0, 10.0, 15.0), block: int = 250, jitter: float = 5.0):
    """A current for `tumble(current=…)`: levels (A) drawn from `levels`, each held for `block` readings, with white
    jitter of `jitter` A while on — a motor's throttle or PWM noise, faster than the sampling —, never below 0."""
    def current(t):
        level = np.repeat(rng.choice(levels, size=len(t) // block + 1), block)[:len(t)]
        return np.clip(level + jitter * rng.standard_normal(len(t)) * (level > 0), 0, None)

    return current
