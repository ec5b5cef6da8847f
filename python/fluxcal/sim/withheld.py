"""Withheld-effect trials: simulate a hand-turned sensor with chosen effects, for checking a diagnosis
blind (tests/python/test_diagnose.py, bench/diagnose.py).

    sim_result, kwargs = withheld_trial(["temp_scale"], seed=3)
    fluxcal.diagnose(sim_result.readings, **kwargs)

The sensor: a minute at 50 Hz turned smoothly through every orientation (`tumble`) while its
temperature swings ±10 °C about 25 °C, in a 50 µT field; scale errors of ±5 %, soft iron (off-diagonal
±3 %, none for the scale-only models), hard iron up to 10 µT, white noise 0.05 µT (0.1 % of the
field), and each named effect at a typical magnitude drawn from its class's `typical`. Real sensors
are often worse (hard iron of 1–7× the Earth's field on phones, drones and a QMC5883L board; scale
and soft-iron errors of 10–20 %): `hard_iron` and `soft_iron` set those sizes.
"""
from __future__ import annotations

import numpy as np

from .effects import CANDIDATES, HardIron, SoftIron, WhiteNoise, describe_parameters
from .inject import TIMED
from .scene import tumble
from .simulate import simulate

FIELD = np.array([20.0, 1.0, 45.8]) * 50.0 / np.linalg.norm([20.0, 1.0, 45.8])  # µT, world (N, E, D)
NOISE = 0.05  # µT
DURATION = 60.0
HARD_IRON = 0.2  # largest |b|, field norms (10 µT)
SOFT_IRON = 0.05  # scale errors ±5 %
OFF_DIAGONAL = 0.03  # soft iron's off-diagonal terms ±3 % at the default SOFT_IRON
CURRENT = (20.0, 4.0)  # A peak, s per throttle setting (scene.tumble), when motor_current is withheld
# Effects that a full matrix absorbs are checked against a scale-only base model, and one that no
# magnitude shows against reference vectors.
MODEL_FOR = {"non_orthogonality": "scale", "misalignment": "vector_scale", "time_offset": "vector"}
# Effects applied before soft iron and the axes' scale factors (they act on the field, or, for
# misalignment, turn it into the sensor's axes before each axis scales it), the rest after the hard iron
# (before it when the offset is electronic: `withheld_trial(electronic_offset=True)`).
FIELD_EFFECTS = ("moving_dipole", "eddy_current", "misalignment")
NOISE_EFFECTS = ("colored_noise", "quantization")


def withheld_trial(names, seed: int, duration_s: float = DURATION, temperature=None, noise: float = NOISE,
                   rate_hz: float = 50.0, model: str | None = None, current=None, hard_iron: float = HARD_IRON,
                   soft_iron: float = SOFT_IRON, electronic_offset: bool = False, dipole=None):
    """Simulate the effects `names` (candidate names, may be empty); returns the Simulation and the
    keyword arguments of `fluxcal.diagnose` for it (t, temp, field_norm, model, and the reference with the
    down direction, the current, or the given noise, where the effect needs them). `temperature`: the scene's
    temperature (see `scene.tumble`; default its sine and wander). `noise`: the white noise σ (µT);
    `rate_hz`: the sample rate (the hand turns at the same speed whatever the rate). `model`: the base
    model to check against instead of the effects' own (e.g. "vector" to see an effect against reference
    vectors). `current`: the scene's current (see `scene.tumble`; default `CURRENT` when motor_current is
    withheld, else none). `hard_iron`: the largest hard iron |b| as a multiple of the field (each axis
    uniform within ±hard_iron·H/√3); `soft_iron`: the axes' scale errors (uniform within ±soft_iron), the
    soft iron's off-diagonal terms within ±0.6 of that. `electronic_offset`: the offset is the sensor's own, added
    after the transducer's effects (its gain and non-linearity do not act on it), not the platform's hard iron.
    `dipole`: the moving_dipole to simulate when it is withheld, instead of a typical one (e.g.
    `MovingDipole.straight_pass`), or a list of them (a magnet carried past more than once)."""
    by_name = {c.name: c for c in CANDIDATES}
    unknown = [n for n in names if n not in by_name]
    if unknown:
        raise ValueError(f"names: unknown effect(s) {', '.join(unknown)}")
    rng = np.random.default_rng(seed)
    model = model or next((MODEL_FOR[n] for n in names if n in MODEL_FOR), "ellipsoid")
    scale_only = model in ("scale", "vector_scale")
    off = OFF_DIAGONAL * (soft_iron / SOFT_IRON)  # exactly the default's ±3 % at the default
    E = np.zeros((3, 3)) if scale_only else rng.uniform(-off, off, (3, 3))
    W = np.diag(1 + rng.uniform(-soft_iron, soft_iron, 3)) + np.triu(E, 1) + np.triu(E, 1).T
    b = rng.uniform(-1, 1, 3) * (hard_iron * float(np.linalg.norm(FIELD))) / np.sqrt(3)

    dipoles = [] if dipole is None else list(dipole) if isinstance(dipole, (list, tuple)) else [dipole]

    def make(name):
        cls = by_name[name]
        if name in TIMED:
            return cls.typical(50.0, rng, duration_s)
        return cls.typical(50.0, rng)

    # misalignment last among them: it turns the whole field, a dipole's included, into the sensor's axes
    effects = [e for n in sorted((n for n in names if n in FIELD_EFFECTS), key=lambda n: n == "misalignment")
               for e in (dipoles if n == "moving_dipole" and dipoles else [make(n)])]
    transducer = [make(n) for n in names if n not in FIELD_EFFECTS and n not in NOISE_EFFECTS]
    effects += [SoftIron(W)] + (transducer + [HardIron(b)] if electronic_offset else [HardIron(b)] + transducer)
    effects.append(WhiteNoise(noise))
    effects += [make(n) for n in names if n in NOISE_EFFECTS]
    extra = {} if temperature is None else {"temperature": temperature}
    if current is not None or "motor_current" in names:
        extra["current"] = CURRENT if current is None else current
    scene = tumble(duration_s, rate_hz=rate_hz, rng=rng, **extra)
    result = simulate(scene, effects, FIELD, rng)
    kwargs = {"t": result.t, "temp": result.temperature, "field_norm": 50.0, "model": model}
    if result.current is not None:
        kwargs["current"] = result.current
    if model.startswith("vector"):
        kwargs["reference"] = result.truth
        kwargs["gravity"] = scene.sensor_field([0.0, 0.0, 1.0])  # down, sensor frame: an ideal accelerometer
    if "quantization" in names:
        kwargs["noise_sigma"] = noise  # the datasheet noise: only a given σ can reveal quantisation
    return result, kwargs


def truth(simulation, unit: str = "uT") -> dict:
    """What a withheld-effect trial simulated, as metadata lines (`unit`: the readings'): each withheld effect's
    parameters with units ("true_<name>"; an effect simulated twice, both, joined by " + "), the white noise,
    and the base sensor's correction (true_offset, true_matrix: what a field-magnitude calibration can
    identify, as `fluxcal simulate` states it)."""
    out = {}
    for e in simulation.effects:
        if e.name:
            key = f"true_{e.name}"
            out[key] = " + ".join(filter(None, (out.get(key), describe_parameters(e, unit))))
    noise = [e.sigma for e in simulation.effects if isinstance(e, WhiteNoise)]
    if noise:
        out["true_noise"] = f"white, sigma {noise[0]:.6g} {unit} per axis"
    correction = simulation.true_calibration(units=unit)
    out["true_offset"] = " ".join(f"{v:.10g}" for v in correction.offset)
    out["true_matrix"] = " ".join(f"{v:.10g}" for v in correction.matrix.ravel())
    return out
