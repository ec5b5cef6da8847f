"""FOCT zero-bias simulation (seed 001): a fibre-optic current transformer held in a climate chamber at
−20 … 50 °C in 5 °C steps with ramps between the holds; three phases; AR(p) noise; a drift law of the
zero bias that changes between the temperature ranges −20…0, 0…30 and 30…50 °C.

    sim = foct_zero_bias(rng=np.random.default_rng(1))
    sim.columns["t"], sim.columns["zero_bias"], sim.columns["temp"], sim.columns["temp_outside"]
    sim.truth["segments"]   # [{"range": [lo, hi], "order": m, "coefficients": [c0 … cm]}, …]

Units: zero bias in amperes (primary-referred), temperatures in °C, time in s. The device's own
temperature `temp` follows the chamber (`temp_outside`) with a first-order thermal lag plus a small
self-heating rise, so the inside/outside difference is a second, physically different regressor.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Default drift law of phase A (amperes), in the device temperature T (°C): orders 2, 1, 3, the pieces
# meeting at 0 and 30 °C (a drift that jumps would be a different fault). The cubic is
# −0.1 − 0.02 u + 0.004 u² − 0.0004 u³ with u = T − 30, expanded in T.
def default_segments():
    u = np.polynomial.Polynomial([-30.0, 1.0])
    cubic = -0.1 - 0.02 * u + 0.004 * u ** 2 - 0.0004 * u ** 3
    return [{"range": [-20.0, 0.0], "order": 2, "coefficients": [0.8, 0.05, 0.004]},
            {"range": [0.0, 30.0], "order": 1, "coefficients": [0.8, -0.03]},
            {"range": [30.0, 50.0], "order": 3, "coefficients": [float(c) for c in cubic.coef]}]


def drift_law(temp, segments) -> np.ndarray:
    """The drift of each temperature under a piecewise-polynomial law (last range closed)."""
    temp = np.asarray(temp, dtype=float)
    out = np.full(temp.shape, np.nan)
    for k, seg in enumerate(segments):
        lo, hi = seg["range"]
        inside = (temp >= lo) & ((temp < hi) | ((k == len(segments) - 1) & (temp <= hi)))
        out[inside] = np.polynomial.polynomial.polyval(temp[inside], seg["coefficients"])
    return out


def chamber_profile(levels=np.arange(-20.0, 50.0 + 1e-9, 5.0), hold_s: float = 1200.0, ramp_s: float = 600.0,
                    rate_hz: float = 1.0, cycle: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, chamber temperature, hold index or −1 on ramps): holds at every level joined by linear ramps; with
    `cycle`, up the levels and back down them (a heating and a cooling branch)."""
    if cycle:
        levels = np.concatenate([levels, np.asarray(levels)[-2::-1]])
    pieces, holds = [], []
    for i, level in enumerate(levels):
        pieces.append(np.full(int(round(hold_s * rate_hz)), level))
        holds.append(np.full(pieces[-1].size, i))
        if i + 1 < len(levels):
            n = int(round(ramp_s * rate_hz))
            pieces.append(level + (levels[i + 1] - level) * (np.arange(1, n + 1) / (n + 1)))
            holds.append(np.full(n, -1))
    temp = np.concatenate(pieces)
    return np.arange(temp.size) / rate_hz, temp, np.concatenate(holds)


def ar_noise(n: int, coefficients, sigma: float, rng, burn_in: int = 1000) -> np.ndarray:
    """AR(p) noise y_k = Σ a_i y_{k−i} + σ ε_k (stationary after a burn-in)."""
    from scipy.signal import lfilter

    e = sigma * rng.standard_normal(n + burn_in)
    return lfilter([1.0], np.concatenate(([1.0], -np.asarray(coefficients, dtype=float))), e)[burn_in:]


@dataclass
class FoctSimulation:
    columns: dict                         # t, zero_bias (phase A), zero_bias_b, zero_bias_c, temp, temp_outside
    units: dict
    truth: dict = field(default_factory=dict)  # segments, ar, sigma, drift (per phase), holds, rated


def foct_zero_bias(rng=None, segments=None, ar=(0.5, -0.2), sigma: float = 0.05, hold_s: float = 1200.0,
                   ramp_s: float = 600.0, rate_hz: float = 1.0, thermal_lag_s: float = 60.0,
                   self_heating: float = 0.0, phase_gains=(1.0, 0.9, 1.1), rated: float = 1000.0,
                   logged: str = "all", cycle: bool = False, hysteresis: float = 0.0,
                   ageing: float = 0.0) -> FoctSimulation:
    """Simulated zero bias of the three phases of a FOCT over the chamber cycle (see the module doc).
    The device temperature lags the chamber by `thermal_lag_s` (first order) and sits `self_heating` °C
    above it; each phase has the drift law times its gain plus its own AR noise (coefficients `ar`,
    innovation σ `sigma`). logged: "all" (the recorder runs through the ramps) or "holds" (it records at
    each temperature point only, as seed 001's S1 reads: the log has a gap in t at every ramp, and the
    noise has run on unseen through it). cycle: the chamber goes up the levels and back down. hysteresis: the drift
    follows the device temperature through a play operator of this half-width (°C; heating and cooling then differ
    by about 2 × hysteresis × the drift's slope; negative: the band in the thermometer, heating reads as if hotter).
    ageing: a trend of the zero bias in time (amperes per hour, times
    each phase's gain)."""
    if logged not in ("all", "holds"):
        raise ValueError(f"logged: {logged!r} is not one of all, holds")
    rng = np.random.default_rng(rng)  # None, a seed or a Generator, as sim.simulate takes
    segments = default_segments() if segments is None else segments
    t, chamber, holds = chamber_profile(hold_s=hold_s, ramp_s=ramp_s, rate_hz=rate_hz, cycle=cycle)
    alpha = 1.0 - np.exp(-1.0 / (thermal_lag_s * rate_hz)) if thermal_lag_s > 0 else 1.0
    from scipy.signal import lfilter

    device, _ = lfilter([alpha], [1.0, alpha - 1.0], chamber, zi=[chamber[0] * (1.0 - alpha)])
    device = device + self_heating
    lo, hi = segments[0]["range"][0], segments[-1]["range"][1]
    device = np.clip(device, lo, hi)  # the chamber never leaves the modelled span; rounding must not either
    from ..drift import play

    # (hysteresis < 0: the band in the thermometer, the element's state 2T − play(T): heating, it reads as if hotter)
    banded = play(device, abs(hysteresis)) if hysteresis else device
    drift = drift_law(np.clip(banded if hysteresis > 0 else 2.0 * device - banded, lo, hi) if hysteresis else device,
                      segments)
    drift = drift + ageing * t / 3600.0
    columns = {"t": t, "temp": device, "temp_outside": chamber}
    phases = {}
    for name, gain in zip(("zero_bias", "zero_bias_b", "zero_bias_c"), phase_gains):
        phases[name] = gain * drift
        columns[name] = gain * drift + ar_noise(t.size, ar, sigma, rng)
    units = {"t": "s", "temp": "degC", "temp_outside": "degC", **{k: "A" for k in phases}}
    if logged == "holds":
        kept = holds >= 0
        columns = {k: v[kept] for k, v in columns.items()}
        phases = {k: v[kept] for k, v in phases.items()}
        holds = holds[kept]
    truth = {"segments": segments, "ar": list(ar), "sigma": sigma, "drift": phases, "holds": holds, "rated": rated,
             "phase_gains": list(phase_gains)}
    return FoctSimulation(columns=columns, units=units, truth=truth)
