"""Sensor effects: each one both simulates and, in the sim-to-real diagnosis, is a candidate model term.

Simulation: `apply(values, context)` turns the values so far (N×3, starting from the true field in the
sensor frame) into what the next stage sees. The physical order a sensor imposes is: field effects
(a moving dipole, eddy currents) → misalignment (the field turned into the sensor's axes) → soft iron
(`SoftIron`) → hard iron (`HardIron`) → transducer effects (scale and its temperature coefficient,
non-orthogonality, cross-axis field, non-linearity, saturation, hysteresis) → electronic offsets (temperature coefficient, drift) → noise →
quantisation. `context` has `t` (s), `temp` (°C or None), `rotations` (sensor → world, or None), `rng`
and `truth`.

Diagnosis: a class with a `name` is a candidate. `features(ctx)` returns its effect on the readings
per unit coefficient, N × p × 3 (exact when the effect is linear in its parameters, first-order
otherwise), computed from what the base fit estimates: `ctx.signal` (N×3, what the transducer saw —
hard iron is a field and passes through it; for a `transducer` candidate the diagnosis also tries the offset as
electronic, added after it: then W h alone — as the fitted model predicts it, free of the reading noise),
`ctx.readings` (N×3, the raw readings — less that offset in the electronic form —, for features that smooth
them in time),
`ctx.field` (N×3, the field in the sensor frame: the calibrated readings' directions on the fitted sphere
|h| = H, or the reference), `ctx.W`
(the fitted reading-from-field matrix), `ctx.scale` (a typical |signal|), `ctx.direction` (N×3, the fitted
field direction mapped back to reading space, times H), and the regressors `ctx.t`, `ctx.temp`. A
candidate with an unknown non-linear parameter (a switching time) returns several alternatives from
`alternatives(ctx)`; the diagnosis takes the best and pays for the choice in its p-value. `regime` names
the variable whose unseen values validate it (held out). `n_params` counts the candidate's
coefficients.

Default magnitudes (`typical(field_norm, rng)`) follow datasheet classes and are stated per class.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter, savgol_filter
from scipy.spatial.transform import Rotation

from .. import _core

AXES = np.eye(3)


class Effect:
    """Base class. `is_noise`: a random effect, left out of Simulation.clean (the noise-free readings).
    Candidates set `name`, `regime` ("orientation", "temperature", "current", "time", "events"), `needs`
    (regressors: "t" the time, the row number when none is given; "timestamps" a time that was given;
    "temp"; "current"). The regime names what the validation holds back: the quarter of the orientations,
    the hottest quarter, the highest-current quarter, the last quarter in time, or interleaved blocks of
    time (an event can be interpolated, not foretold)."""

    name = ""
    n_params = 0
    is_noise = False
    regime = "orientation"
    needs: tuple = ()
    # Found once, it may be found again beside itself (another line of a periodic interference): each further one an
    # episode of its block, as an event's recurrence is.
    recurs = False
    # It leaves every field magnitude unchanged (a rotation, a delay): only reference vectors show it.
    needs_reference = False
    # A fixed linear map of the field: a full soft-iron matrix represents it exactly (only a scale-only
    # model can show it), whatever its first-order features leave numerically.
    linear = False
    # Its features are first order in a move of the reference vectors (θ × r for a rotation, −δ dm/dt for a
    # delay): once accepted, the diagnosis moves the reference exactly (`move_reference`, see diagnose.core).
    moves_reference = False
    # Its features are non-linear in the signal (`ctx.signal`): the diagnosis recomputes them at the signal
    # of the fit that models the effect (the base fit's own estimate absorbs part of the effect), and at its
    # coefficients (`ctx.coefficients`, None at first) for a candidate whose features are exact only there.
    signal_features = False
    # A non-linear parameter profiled, not fitted (saturation's limit): `profile_grid(ctx)` gives the values
    # searched and `features_at(ctx, value)` the features (linear in the coefficients) at one; the diagnosis
    # refines the best between grid points, counts the parameter in ΔBIC and the likelihood ratio's degrees
    # of freedom, and reports it (`profile_name`) with the row.
    profile_name = ""
    profile_null = None      # a value at which the candidate is its plain form (kept unless the profile pays for itself)
    profile_open_end = True  # the refinement may go one grid step beyond the last finite grid value
    profile_xatol = 1e-3     # the refinement's tolerance in log(value) (a frequency needs far finer)
    # It acts in the transducer, on what the transducer sees (`ctx.signal`): a gain, a non-linearity. Whether
    # that includes the offset is the sensor's: a platform's hard iron is a field at the sensor and passes
    # through the transducer; a sensor's own electronic offset is added after it. The diagnosis tries both
    # (`ctx.signal` the fitted b + W h, or W h alone) and says which when the data decide.
    transducer = False
    # Its features are functions of the time, the temperature or the current alone, not of the readings: held out,
    # its fit cannot predict a reading better than the noise lets it (a fit that does shows the noise σ overstated).
    exogenous = False

    @classmethod
    def searched_times(cls, described: dict) -> int:
        """How many times in the recording the search placed (`describe`'s output in): a box's edges, a pass's
        closest approach and passage time. Each is a parameter the data chose: it pays in ΔBIC as a
        coefficient does."""
        return 0

    @classmethod
    def profiled_extras(cls, ctx, value) -> dict:
        """Parameters the features at a profiled `value` settled beside it (a line's drift of frequency), for the
        ranking row: each one given (not None) pays in ΔBIC as a coefficient does."""
        return {}

    @classmethod
    def profile_grid(cls, ctx) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    @classmethod
    def features_at(cls, ctx, value) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    @staticmethod
    def compose(total: np.ndarray, step: np.ndarray) -> np.ndarray:  # pragma: no cover - interface
        """The move `total` followed by `step` (parameter vectors), for a candidate that moves the reference."""
        raise NotImplementedError

    @staticmethod
    def move_reference(reference: np.ndarray, t: np.ndarray, total: np.ndarray) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError

    @staticmethod
    def describe_move(total: np.ndarray) -> dict:  # pragma: no cover - interface
        """The whole move in the units the report gives, as the ranking row's extra fields."""
        raise NotImplementedError

    def apply(self, values: np.ndarray, context) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    @classmethod
    def features(cls, ctx) -> np.ndarray:  # pragma: no cover - interface
        raise NotImplementedError

    @classmethod
    def holds(cls, ctx, coefficients) -> bool:
        """For features exact only at the fit's coefficients: whether these coefficients are in the range
        the features describe (the diagnosis stops recomputing them at a fit that left it)."""
        return True

    @classmethod
    def unphysical(cls, coefficients, standard_errors, vector: bool = False, period: float = 0.0) -> str:
        """Why fitted coefficients describe no such effect — a sign its physics forbids, beyond two standard
        errors — or "" when they can. The diagnosis does not accept such a fit as this effect. vector: the
        readings are fitted to reference vectors (a delay between the two then shows); period: the readings'
        median time step (s, 0 unknown)."""
        return ""

    @classmethod
    def describe(cls, ctx, feats) -> dict:
        """What the chosen alternative says beyond its coefficients (e.g. when an event began), as the
        ranking row's extra fields."""
        return {}

    @classmethod
    def alternatives(cls, ctx) -> list:
        """Feature arrays to choose from (one unless the candidate has a non-linear parameter)."""
        return [cls.features(ctx)]

    @classmethod
    def search(cls, ctx, score):
        """The alternative with the highest `score(features)`, and how many were tried (the multiple-
        comparison correction counts them)."""
        alternatives = cls.alternatives(ctx)
        scores = [score(f) for f in alternatives]
        return alternatives[int(np.argmax(scores))], len(alternatives)


ISOTROPIC_LAG = 1.5  # eddy_current's largest lag under this many times its smallest, against reference vectors: a delay


def _below_zero(coefficients, standard_errors) -> np.ndarray:
    """Which coefficients are negative beyond two standard errors (for `unphysical`)."""
    return np.asarray(coefficients, dtype=float) + 2 * np.asarray(standard_errors, dtype=float) < 0


def _per_axis(columns: np.ndarray) -> np.ndarray:
    """N×3 columns → N × 3 × 3 features: term k moves axis k only."""
    # the diagonal set: 4× faster than columns times AXES, the same values (+0 off the diagonal where that product
    # gave −0 for a negative column, which no sum or product downstream tells apart)
    out = np.zeros((len(columns), 3, 3))
    for k in range(3):
        out[:, k, k] = columns[:, k]
    return out


def _offset_along(x: np.ndarray) -> np.ndarray:
    """Features of an offset per axis proportional to x, centred (its mean is part of the hard iron)."""
    return _per_axis(np.repeat((x - x.mean())[:, None], 3, axis=1))


def _per_context(ctx, key: str, inputs: tuple, compute):
    """compute() once per candidate context `ctx` while its `inputs` are the same arrays (by identity; a context
    that is copied or given a new signal computes again), kept on the context (freed with it)."""
    held = getattr(ctx, key, None)
    if held is not None and len(held[0]) == len(inputs) and all(a is b for a, b in zip(held[0], inputs)):
        return held[1]
    value = compute()
    try:
        setattr(ctx, key, (inputs, value))
    except AttributeError:  # (a context that takes no attributes: computed each time)
        pass
    return value


MEMO_FLOATS = 2 ** 23  # a diagnosis' memo holds at most this many floats (64 MB): then it computes again


def _per_diagnosis(memo, key: tuple, inputs: tuple, compute):
    """compute() once per diagnosis for `key` while its `inputs` are the same arrays (by identity), in the
    diagnosis' `memo` (a dict, `ctx.memo`; None: computed each time). For what does not change between its
    rounds: a temperature's lagged courses and slopes (the lag profile asks for the same grid in every round,
    form and held-out choice), an event's time profiles (every round's search scores the same coarse boxes and
    passes), the world frame. The result is shared: read-only when it is an array of its own."""
    if memo is None:
        return compute()
    held = memo.get(key)
    if held is not None and all(a is b for a, b in zip(held[0], inputs)):
        return held[1]
    value = compute()
    size = getattr(value, "size", 1)
    # (what a replaced entry held is freed: counted once, the cap had been reached by replacements alone)
    held_size = getattr(held[1], "size", 1) if held is not None else 0
    if memo.get("_floats", 0) - held_size + size <= MEMO_FLOATS:
        if isinstance(value, np.ndarray) and value.base is None and not any(value is a for a in inputs):
            value.setflags(write=False)  # (not an input: a lag of 0 gives the temperature itself)
        memo[key] = (inputs, value)
        memo["_floats"] = memo.get("_floats", 0) - held_size + size
    return value


def reach(values: np.ndarray) -> np.ndarray:
    """Each axis' largest |value|, as its 99.9th percentile (a spike must not raise it)."""
    return np.quantile(np.abs(values), 0.999, axis=0)


def _smooth(values: np.ndarray, t: np.ndarray, deriv: int = 0) -> np.ndarray:
    """The values (or their time derivative) smoothed by a Savitzky–Golay filter over ≈ 0.2 s, so that
    reading noise is not amplified."""
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 1.0
    window = max(5, int(round(0.2 / dt)) | 1)  # odd
    if window > len(values):
        return np.gradient(values, t, axis=0) if deriv else values
    return savgol_filter(values, window, 2, deriv=deriv, delta=dt, axis=0)


# ---------------------------------------------------------------- linear model (the base, never candidates)

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


# ---------------------------------------------------------------- transducer effects

@dataclass
class NonOrthogonality(Effect):
    """Axes not at 90°: axis y leans towards x by `angles[0]`, z towards x and y by `angles[1:]` (rad).
    Typical: ±0.5° (MEMS/AMR packages; RM3100 boards ≈ 0.2°). From field magnitudes alone it is the
    symmetric off-diagonal part of the matrix — absorbed by a full soft-iron matrix, visible against a
    scale-only model."""

    angles: np.ndarray
    name = "non_orthogonality"
    n_params = 3
    linear = True

    def apply(self, values, context):
        a = np.asarray(self.angles, dtype=float)
        L = np.array([[1.0, 0, 0], [np.sin(a[0]), np.cos(a[0]), 0], [np.sin(a[1]), np.sin(a[2]), 1.0]])
        L[2, 2] = np.sqrt(max(1.0 - L[2, 0] ** 2 - L[2, 1] ** 2, 0.0))
        return values @ L.T

    @classmethod
    def features(cls, ctx):
        # The axes lean in the field's frame: m = W (I + S) h + b with S symmetric off-diagonal.
        u, W = ctx.field, ctx.W
        pairs = [(0, 1), (0, 2), (1, 2)]
        return np.stack([(u[:, [k]] * AXES[j] + u[:, [j]] * AXES[k]) @ W.T for j, k in pairs], axis=1)

    @classmethod
    def typical(cls, field_norm, rng):
        return cls(np.deg2rad(rng.choice([-1, 1], 3) * rng.uniform(0.3, 0.8, 3)))


@dataclass
class Misalignment(Effect):
    """The sensor axes rotated from the body axes by the rotation vector `rotvec` (rad). Typical ±1°
    (board mounting). Invisible in field magnitudes; against a reference vector it is absorbed by a
    full matrix and visible against a scale-only one."""

    rotvec: np.ndarray
    name = "misalignment"
    n_params = 3
    linear = True
    needs_reference = True
    moves_reference = True

    def apply(self, values, context):
        return Rotation.from_rotvec(self.rotvec).apply(values)

    @staticmethod
    def compose(total, step):
        return (Rotation.from_rotvec(step) * Rotation.from_rotvec(total)).as_rotvec()

    @staticmethod
    def move_reference(reference, t, total):
        return Rotation.from_rotvec(total).apply(reference)

    @staticmethod
    def describe_move(total):
        return {"rotation_deg": np.degrees(total).tolist()}

    @classmethod
    def features(cls, ctx):
        return np.stack([np.cross(AXES[k], ctx.field) @ ctx.W.T for k in range(3)], axis=1)

    @classmethod
    def typical(cls, field_norm, rng):
        return cls(np.deg2rad(rng.choice([-1, 1], 3) * rng.uniform(0.5, 1.5, 3)))


@dataclass
class CrossAxis(Effect):
    """AMR cross-field error: a bridge's sensitivity falls with the field along its easy axis,
    m_k = s_k / (1 + s_e(k)/H_k) (x's easy axis is y; y's and z's are x). `hk`: anisotropy field per
    axis, reading units. Typical: H_k ≈ 20 Oe for HMC100x-class bridges, 40× the Earth's field —
    errors up to ≈ 2.5 % (Honeywell AN-215)."""

    hk: np.ndarray
    name = "cross_axis"
    transducer = True
    n_params = 3
    signal_features = True
    EASY = (1, 0, 0)

    def apply(self, values, context):
        hk = np.asarray(self.hk, dtype=float)
        easy = values[:, list(self.EASY)]
        return values / (1.0 + easy / hk)

    @classmethod
    def _easy(cls, ctx):
        """u = s_e/scale per axis, and the largest |c| that keeps 1 + c u ≥ 0.5 on every reading."""
        u = ctx.signal[:, list(cls.EASY)] / ctx.scale
        return u, 0.5 / np.maximum(np.max(np.abs(u), axis=0), 1e-12)

    @classmethod
    def features(cls, ctx):
        # m_k − s_k = −s_k (c_k u)/(1 + c_k u), u = s_e/scale, c_k = scale/H_k: exactly c_k times the feature
        # −s_k u/(1 + c_k u) at the fit's own c_k (first order, −s_k u, at c = 0). Its second order matters:
        # ≈ 0.2 µT at s_e/H_k ≈ 0.08, with a hard iron of several fields.
        u, bound = cls._easy(ctx)
        c = np.zeros(3) if getattr(ctx, "coefficients", None) is None else np.asarray(ctx.coefficients, float)
        # a wild coefficient of a poor fit must not divide by ~0
        c = np.clip(c, -bound, bound)
        return _per_axis(-ctx.signal * u / (1.0 + c * u))

    @classmethod
    def holds(cls, ctx, coefficients) -> bool:
        # 1 + c u < 0.5 somewhere: a sensitivity halved by an anisotropy field the easy-axis signal nearly
        # reaches, no cross-axis error of a working bridge (typical H_k ≈ 40 fields: |c u| ≈ 0.03 per field).
        # The fit then models something else, and features clipped to the range fit yet another model.
        return bool(np.all(np.abs(np.asarray(coefficients, float)) <= cls._easy(ctx)[1]))

    @classmethod
    def typical(cls, field_norm, rng):
        return cls(rng.choice([-1, 1], 3) * field_norm * rng.uniform(30, 50, 3))


@dataclass
class _Nonlinearity(Effect):
    """m_k = s_k (1 + c_k (s_k / S)^(ORDER − 1)) in the transducer: `relative[k]` is the error fraction at s_k = S
    (`scale`)."""

    relative: np.ndarray
    scale: float
    transducer = True
    n_params = 3
    signal_features = True
    ORDER = 3

    def apply(self, values, context):
        return values * (1.0 + np.asarray(self.relative) * (values / self.scale) ** (self.ORDER - 1))

    @classmethod
    def features(cls, ctx):
        return _per_axis(ctx.signal ** cls.ORDER / ctx.scale ** (cls.ORDER - 1))


@dataclass
class CubicNonlinearity(_Nonlinearity):
    """m_k = s_k (1 + c_k (s_k / S)²): `relative[k]` is the error fraction at |s_k| = S (`scale`). Typical
    ±1–2 % at S: a sensor used at 50–70 % of its range with a datasheet linearity of ±0.5 % FS
    (QMC5883L/AMR class), or a fluxgate near the end of its range."""

    name = "nonlinearity_cubic"

    @classmethod
    def typical(cls, field_norm, rng):
        return cls(rng.choice([-1, 1], 3) * rng.uniform(0.01, 0.02, 3), field_norm)


@dataclass
class QuadraticNonlinearity(_Nonlinearity):
    """m_k = s_k (1 + c_k s_k / S): an even-order error, `relative[k]` the fraction at s_k = S (`scale`; −c_k at −S).
    An AMR bridge whose elements are not matched, a fluxgate whose drive is not symmetric, a Hall element's planar
    term: the reading departs one way at both ends of the range. Typical ±0.3–1 % at S. (Not a candidate, a blind
    check's 0.3–0.4 % was named a cubic or a saturation with opposite signs in two seeds.)"""

    name = "nonlinearity_quadratic"
    ORDER = 2
    LARGEST = 0.05  # at the typical reading: datasheets give an even-order error of 0.1–2 % of full scale

    @classmethod
    def unphysical(cls, coefficients, standard_errors, vector: bool = False, period: float = 0.0):
        # beyond LARGEST it is no sensor's non-linearity but a trade with another term: beside cross_axis (whose y and
        # z fall with x, an s_x s_k term) a blind check's clean cross-axis error took 34.5 % of it on x against
        # anisotropy fields of −142 µT
        c, se = np.abs(np.asarray(coefficients, float)), np.asarray(standard_errors, float)
        if np.any(c - 2.0 * se > cls.LARGEST):
            return (f"an even-order error of {100 * float(np.max(c)):.3g} % at the typical reading: no magnetometer's "
                    f"(datasheets: 0.1–2 % of full scale); it trades with another term")
        return ""

    @classmethod
    def typical(cls, field_norm, rng):
        return cls(rng.choice([-1, 1], 3) * rng.uniform(0.003, 0.01, 3), field_norm)


class _Compression(Effect):
    """A saturating transducer (`saturation`, `saturation_knee`): one coefficient, the size of a compression whose
    shape has one profiled parameter (`profile_grid`, `features_at`); it can only compress (`GROWS`: where, else)."""

    transducer = True
    n_params = 1
    signal_features = True
    GROWS = "the readings"

    @classmethod
    def alternatives(cls, ctx):
        return [cls.features_at(ctx, v) for v in cls.profile_grid(ctx)]

    @classmethod
    def unphysical(cls, coefficients, standard_errors, vector: bool = False, period: float = 0.0):
        # its features are a compression per unit size: a negative size makes the readings grow faster than
        # the field, which no saturating core does (an expanding cubic with equal coefficients on every axis
        # was reported as saturation)
        if _below_zero(coefficients, standard_errors)[0]:
            return (f"a negative size: {cls.GROWS} grow faster than the field (an expanding non-linearity), where "
                    "a saturating sensor compresses them")
        return ""


@dataclass
class Saturation(_Compression):
    """Soft saturation of every axis at `limit`: m = L tanh(s / L). Typical: L = 4× the field (a 2 G range
    sensor in 0.5 G) — 2 % compression at the field's magnitude.

    As a candidate: the limit is profiled (`profile_grid`, `features_at`), with one coefficient for the
    size: L tanh(s/L) − s scaled to tend to the same cubic on every axis, −s³/scale², as L → ∞ (its first
    order; the grid's last value). About a hard iron of several fields the signal reaches L and the tanh is
    far from that cubic, which a per-axis cubic then fits better than the cubic with equal coefficients."""

    limit: float
    name = "saturation"
    profile_name = "limit"
    LIMITS = 16  # values of L searched (then refined between grid points), up to 16× the scale, and ∞

    def apply(self, values, context):
        return self.limit * np.tanh(values / self.limit)

    @classmethod
    def profile_grid(cls, ctx):
        # L tanh(s/L) never reaches L: a limit below what the readings reach is no saturation (free, a
        # strongly bent tanh about a large hard iron fitted the QMC5883L recording's even-order residue with
        # L at 0.4 of its readings). The 99.9th percentile: a spike must not raise the bound.
        largest = float(np.max(reach(ctx.readings)))
        return np.append(np.geomspace(largest, max(16.0 * ctx.scale, 2.0 * largest), cls.LIMITS), np.inf)

    @classmethod
    def features_at(cls, ctx, value):
        s = ctx.signal
        if not np.isfinite(value):
            return (-(s ** 3) / ctx.scale ** 2)[:, None, :]
        # L tanh(s/L) − s = −s³/(3L²) + …: times 3L²/scale² it is −s³/scale² to first order
        return ((value * np.tanh(s / value) - s) * 3 * value ** 2 / ctx.scale ** 2)[:, None, :]

    @classmethod
    def features(cls, ctx):
        return cls.features_at(ctx, np.inf)

    @classmethod
    def typical(cls, field_norm, rng):
        return cls(field_norm * rng.uniform(3.5, 5.0))


@dataclass
class SaturationKnee(_Compression):
    """Saturation that begins at a knee: each axis is linear up to |s| = `knee`, then bends towards
    knee + `width`: m = sign(s) (k + w (1 − exp(−(|s| − k)/w))). A sensor used near the top of its range (an
    AMR bridge's or a Hall ASIC's transfer curve, a fluxgate's feedback running out) is straight over most of it
    and bends only near its end, where tanh (`saturation`) compresses every reading. Typical: a knee at 75–95 %
    of the field's magnitude, bending over 1–2.5 fields.

    As a candidate: the knee is profiled (`profile_grid`, `features_at`) and one coefficient gives the size: the
    bend's first order, −sign(s) (|s| − k)₊² / scale — any curve that is straight up to k and bends smoothly from
    there starts so (its slope continuous, its curvature not: the tanh beyond a knee has none there and is not
    generic). Its coefficient a is the compression a reading scale beyond the knee would have (scale / 2w here)."""

    knee: float
    width: float
    name = "saturation_knee"
    profile_name = "knee"
    GROWS = "the readings beyond the knee"
    profile_open_end = False  # (the grid's last knee is near the readings' reach: beyond it, no reading bends)
    KNEES = 12  # knees searched (then refined between grid points), from LOWEST to HIGHEST of the readings' reach
    LOWEST, HIGHEST = 0.4, 0.95  # below 0.4 of the reach it is a non-linearity of the whole range (cubic, tanh)

    def apply(self, values, context):
        over = np.maximum(np.abs(values) - self.knee, 0.0)
        return values - np.sign(values) * (over - self.width * (1.0 - np.exp(-over / self.width)))

    @classmethod
    def profile_grid(cls, ctx):
        return float(np.max(reach(ctx.readings))) * np.linspace(cls.LOWEST, cls.HIGHEST, cls.KNEES)

    @classmethod
    def features_at(cls, ctx, value):
        s = ctx.signal
        return (-np.sign(s) * np.maximum(np.abs(s) - value, 0.0) ** 2 / ctx.scale)[:, None, :]

    @classmethod
    def features(cls, ctx):
        grid = cls.profile_grid(ctx)
        return cls.features_at(ctx, grid[len(grid) // 2])

    @classmethod
    def typical(cls, field_norm, rng):
        return cls(field_norm * rng.uniform(0.75, 0.95), field_norm * rng.uniform(1.0, 2.5))


@dataclass
class Hysteresis(Effect):
    """Magnetic hysteresis of the core: each axis lags its input by `width` (reading units), a play
    operator — the output holds until the input moves `width` away, then follows it. `share` < 1: only that
    share of the output does (a loop `width` wide and share × width high: the irreversible part of a core's
    magnetisation). Typical: a full play 0.1–0.3 % of the field wide (AMR without set/reset, fluxgate cores)."""

    width: np.ndarray
    share: float = 1.0
    name = "hysteresis"
    n_params = 3
    regime = "time"
    needs = ("t",)

    def apply(self, values, context):
        return values + self.share * (_play(values, np.asarray(self.width, dtype=float)) - values)

    # As a candidate one width for every axis is profiled (reading units; the row's `width`), from a full play's
    # few hundredths of a per cent of the field to a wide loop's quarter of it: a 10 µT loop in a 50 µT field, 5 %
    # of it irreversible, was taken for a cubic or saturation when five widths up to 0.8 % were tried, and left
    # 3.6 σ to coloured noise with ten up to 25.6 % (a helper's blind check). The features are recomputed at the
    # signal of the fit that models the loop: a wide loop lowers the gain while the field moves, which the base
    # fit's matrix took (profiled at the base fit's signal, the same recording still left 3.1 σ; now 1.0 σ).
    profile_name = "width"
    signal_features = True
    WIDTHS = 10  # grid values, geometric from 0.05 % to 25.6 % of the field (then refined between them)

    @classmethod
    def profile_grid(cls, ctx):
        # on the field's scale: a play moves with its input, so the offset does not widen the loops tried
        field = float(np.median(np.linalg.norm(ctx.direction, axis=1)))
        return field * np.geomspace(0.0005, 0.256, cls.WIDTHS)

    @classmethod
    def features_at(cls, ctx, value):
        # the reading lags by up to the width: (play(s, w) − s)/w per axis, whose coefficient is the loop's
        # half-height (the width times the share)
        # the play operator would follow what noise is left; smoothed once per context (the profile asks for dozens
        # of widths at one signal)
        smooth = _per_context(ctx, "_hysteresis_smooth", (ctx.signal, ctx.t), lambda: _smooth(ctx.signal, ctx.t))
        return _per_axis((_play(smooth, np.full(3, value)) - smooth) / value)

    @classmethod
    def features(cls, ctx):
        return cls.features_at(ctx, cls.profile_grid(ctx)[2])  # 0.2 % of the field

    @classmethod
    def unphysical(cls, coefficients, standard_errors, vector: bool = False, period: float = 0.0):
        # the coefficients are the loops' half-heights: a negative one is a reading that runs ahead of its input
        ahead = _below_zero(coefficients, standard_errors)
        if ahead.any():
            return (f"a negative loop height on axis {', '.join('xyz'[k] for k in np.flatnonzero(ahead))}: the reading "
                    "runs ahead of its input, where a core's hysteresis holds it behind")
        return ""

    @classmethod
    def typical(cls, field_norm, rng):
        return cls(field_norm * rng.uniform(0.001, 0.003, 3))


def _play(values: np.ndarray, width: np.ndarray) -> np.ndarray:
    """The play operator along axis 0, each column with its width (`width` broadcast to a row): the output holds
    until the input moves the width away, then follows it. The core's loop (`_core.play`, the same clamp): hysteresis'
    width profile runs it a few dozen times per diagnosis; Python floats (`_play_python`) for what the core refuses
    (a non-finite or negative value, no rows)."""
    values = np.asarray(values, dtype=float)
    widths = np.broadcast_to(np.asarray(width, dtype=float), values.shape[1:]).reshape(-1)
    if not (len(values) and np.all(np.isfinite(values)) and np.all(widths >= 0)):
        return _play_python(values, widths)
    out = np.empty_like(values)
    columns, outs = values.reshape(len(values), -1), out.reshape(len(values), -1)
    for k, w in enumerate(widths.tolist()):
        outs[:, k] = _core.play(np.ascontiguousarray(columns[:, k]), np.array([w]), "signal")[:, 0]
    return out


def _play_python(values: np.ndarray, widths: np.ndarray) -> np.ndarray:
    """`_play` column by column on Python floats (NumPy's per-row overhead made it 8× slower on three columns)."""
    out = np.empty_like(values)
    columns, outs = values.reshape(len(values), -1), out.reshape(len(values), -1)
    for k, w in enumerate(widths.tolist()):
        column = columns[:, k].tolist()
        y, played = column[0] if column else 0.0, []
        for x in column:
            y = x - w if y < x - w else x + w if y > x + w else y
            played.append(y)
        outs[:, k] = played
    return out


def lagged(temp, t, lag_s: float, memo: dict | None = None) -> np.ndarray:
    """`temp` through a first-order lag of time constant `lag_s` (in t's unit, s): the sensing element's own
    temperature when the logged one is measured beside it, behind some thermal mass (a board thermistor, the
    chamber's air). In equilibrium at the start; irregular steps and gaps are followed exactly.

    A negative `lag_s`: the logged temperature lags the element's by |lag_s| (a thermometer behind more thermal
    mass than the element, the element heated by its own current): the element's is the logged one undone of
    that lag, T + |lag_s| dT/dt, the slope smoothed over |lag_s|/2 (`_slope`: a short window would feed the
    thermometer's quantisation steps through the derivative). `memo`: a diagnosis' (`_per_diagnosis`), for the
    slopes."""
    temp = np.asarray(temp, dtype=float)
    if lag_s < 0 and len(temp) > 2:
        return temp - lag_s * _slope(temp, np.asarray(t, dtype=float), -lag_s / 2, memo)
    if not lag_s > 0 or len(temp) < 2:
        return temp
    steps = np.diff(np.asarray(t, dtype=float))
    step = float(np.median(steps))
    if step > 0 and np.all(np.abs(steps - step) <= 1e-3 * step):  # evenly sampled: one recursive filter
        a = 1.0 - np.exp(-step / lag_s)
        return lfilter([a], [1.0, a - 1.0], temp, zi=[(1.0 - a) * temp[0]])[0]
    keep = np.exp(-np.clip(steps, 0.0, None) / lag_s)
    out = np.empty_like(temp)
    out[0] = temp[0]
    for i, k in enumerate(keep, start=1):
        out[i] = k * out[i - 1] + (1.0 - k) * temp[i]
    return out


def _slope(values: np.ndarray, t: np.ndarray, width: float, memo: dict | None = None) -> np.ndarray:
    """d(values)/dt from a quartic fitted over `width` (in t's unit) about each sample (Savitzky–Golay) on an
    even grid at the median step: a dropped row or a jittery clock must not turn quantisation steps into spikes
    (unsmoothed differences did: a 0.1 °C step over one jittered interval). Quartic: a quadratic's slope over
    a window of the lag was 3 % short on a slow sine and left a residual taken for coloured noise. `memo`: a
    diagnosis' (`_per_diagnosis`): the slope depends on the width only through the window, in samples, and the
    lag profile's refinement asks for many widths of one window."""
    order = np.argsort(t, kind="stable")
    ts, vs = t[order], values[order]
    dt = _sample_step(ts, none=0.0)
    if not dt > 0:
        return np.zeros_like(values)
    grid = ts[0] + dt * np.arange(int(np.floor((ts[-1] - ts[0]) / dt)) + 1)
    even = np.interp(grid, ts, vs)
    window = min(max(5, int(round(width / dt)) | 1), len(grid) - (1 - len(grid) % 2))  # odd, at most the grid
    if window < 3:  # two grid points: no slope worth the name
        return np.zeros_like(values)

    def slope():
        out = np.empty_like(values)
        out[order] = np.interp(ts, grid, savgol_filter(even, window, min(4, window - 1), deriv=1, delta=dt))
        return out
    return _per_diagnosis(memo, ("slope", window), (values, t), slope)


def _span_and_step(t) -> tuple:
    """The recording's span and its median sampling step (0, 0 for fewer than two readings): the bounds of a
    profiled time constant's grid."""
    t = np.asarray(t, dtype=float)
    if len(t) < 2:
        return 0.0, 0.0
    return float(np.ptp(t)), float(np.median(np.abs(np.diff(t))))


class _TemperatureLag:
    """A temperature candidate's lag, profiled (`profile_name`): the logged temperature is seldom the
    sensing element's, which follows it with a thermal time constant — or leads it (a negative lag: the
    logged one lags the element's). The grid runs from about one sample interval to a fifth of the recording,
    either way; a lag that does not pay BIC's price for its parameter is none (`profile_null`), and then
    costs nothing."""

    profile_name = "lag_s"
    profile_null = 0.0        # no lag: the logged temperature is the element's
    profile_open_end = False
    LAGS = 12                 # grid values of the lag (then refined between grid points)
    LONGEST = 0.2             # the longest lag tried, as a fraction of the recording: a lag of a large part of it
                              # makes the temperature a smooth curve in time, which fits any slow change (at 0.3 a
                              # gain drifting in time took a made-up temperature); at 0.1 a sensor 20 s behind its
                              # thermometer in a 2-minute recording was missed (a blind check: an offset step or a
                              # magnet named instead)

    @classmethod
    def profile_grid(cls, ctx):
        span, step = _span_and_step(ctx.t)
        if not (span > 0 and step > 0) or cls.LONGEST * span <= step:
            return np.array([0.0])
        lags = np.geomspace(step, cls.LONGEST * span, cls.LAGS)
        return np.concatenate([-lags[::-1], lags])

    @classmethod
    def features(cls, ctx):
        return cls.features_at(ctx, 0.0)


def _lagged_temp(ctx, lag_s: float) -> np.ndarray:
    """`lagged(ctx.temp, ctx.t, lag_s)`, once per diagnosis and lag (`_per_diagnosis`)."""
    memo = getattr(ctx, "memo", None)
    return _per_diagnosis(memo, ("lagged", float(lag_s)), (ctx.temp, ctx.t),
                          lambda: lagged(ctx.temp, ctx.t, lag_s, memo))


@dataclass
class TemperatureScale(_TemperatureLag, Effect):
    """Sensitivity drift with temperature: s_k (1 + α_k (T − T0)), α in 1/°C, T the sensing element's
    temperature: the logged one through a first-order lag `lag_s` (s; 0: the logged one). Typical: ±0.1 %/°C
    (QMC5883L/HMC5883L class without compensation; RM3100 ≈ 0.03 %/°C)."""

    alpha: np.ndarray
    t0: float = 25.0
    lag_s: float = 0.0
    name = "temp_scale"
    transducer = True
    n_params = 3
    regime = "temperature"
    needs = ("temp",)

    def apply(self, values, context):
        temp = lagged(context.temp, context.t, self.lag_s)
        return values * (1.0 + np.outer(temp - self.t0, self.alpha))

    @classmethod
    def features_at(cls, ctx, value):
        temp = _lagged_temp(ctx, value)
        return _per_axis(ctx.signal * (temp - temp.mean())[:, None])

    @classmethod
    def typical(cls, field_norm, rng):
        return cls(rng.choice([-1, 1], 3) * rng.uniform(0.0006, 0.0012, 3))


@dataclass
class TemperatureOffset(_TemperatureLag, Effect):
    """Offset drift with temperature: m + β (T − T0), β in reading units per °C, T the sensing element's
    temperature (the logged one through a first-order lag `lag_s`, s). Typical: ±0.02–0.04 % of the
    Earth's field per °C (QMC5883L/HMC5883L class: ≈ 10–20 nT/°C)."""

    beta: np.ndarray
    t0: float = 25.0
    lag_s: float = 0.0
    name = "temp_offset"
    exogenous = True
    n_params = 3
    regime = "temperature"
    needs = ("temp",)

    def apply(self, values, context):
        return values + np.outer(lagged(context.temp, context.t, self.lag_s) - self.t0, self.beta)

    @classmethod
    def features_at(cls, ctx, value):
        return _offset_along(_lagged_temp(ctx, value))

    @classmethod
    def typical(cls, field_norm, rng):
        return cls(rng.choice([-1, 1], 3) * field_norm * rng.uniform(0.0002, 0.0004, 3))


@dataclass
class MotorCurrent(Effect):
    """A field proportional to a current drawn near the sensor: m + k I, k in reading units per A (per
    axis). Motors and their battery leads on a drone (ArduPilot's compass-motor interference, which
    `compassmot` measures), a heater, a relay coil. Typical: 1–4 % of the Earth's field per axis at 20 A
    (a well-placed compass; ArduPilot calls up to 30 % acceptable)."""

    k: np.ndarray
    name = "motor_current"
    exogenous = True
    n_params = 3
    regime = "current"
    needs = ("current",)

    def apply(self, values, context):
        return values + np.outer(context.current, self.k)

    @classmethod
    def features(cls, ctx):
        return _offset_along(ctx.current)

    @classmethod
    def typical(cls, field_norm, rng):
        return cls(rng.choice([-1, 1], 3) * field_norm * rng.uniform(0.01, 0.04, 3) / 20.0)


class _TimeCourse:
    """A drift's course in time, profiled (`profile_name`): linear, or an exponential settling with time
    constant τ — a sensor warming up after power-on settles so. τ runs from ten samples or 1 % of the
    recording to twice the recording; one that does not pay BIC's price for its parameter is none (linear,
    the `profile_null` ∞), and then costs nothing. A settling drift was taken for a step near the start, or for a linear drift
    plus a step (the linear one overshoots where the drift has settled). The sensor's course: the rate
    (per s) at the start, settling at rate·τ."""

    regime = "time"
    needs = ("t",)
    law_in_time = True   # a law's course (diagnose: an event's free course fits it too)
    profile_name = "warmup_s"
    profile_null = np.inf
    profile_open_end = False
    WARMUPS = 12  # grid values of the time constant (then refined between grid points)

    @staticmethod
    def course(t: np.ndarray, warmup_s: float) -> np.ndarray:
        """The drift since the first reading per unit rate: t, or τ(1 − e^(−t/τ))."""
        t = np.asarray(t, dtype=float) - t[0]
        return warmup_s * -np.expm1(-t / warmup_s) if 0 < warmup_s < np.inf else t

    @classmethod
    def profile_grid(cls, ctx):
        span, step = _span_and_step(ctx.t)
        if not (span > 0 and step > 0):
            return np.array([np.inf])
        # from ten samples or a hundredth of the recording (a faster settling is a glitch to it) to twice the
        # recording (beyond, it is nearly linear)
        return np.append(np.geomspace(max(10.0 * step, 0.01 * span), 2.0 * span, cls.WARMUPS), np.inf)

    @staticmethod
    def shape(ctx, value) -> np.ndarray:
        """The candidate's course: linear across the recording (its coefficient the drift across it), or the
        settling from the first reading on (its coefficient the whole settling). Centred: a constant part
        times the signal would be a scale the matrix holds, and the matrix's fit from the readings and this
        from the signal's estimate differ by the noise — a large coefficient and the matrix cancelling each
        other fitted that noise (a 3-sample "settling" of 50 % in the sensitivity)."""
        t = np.asarray(ctx.t, dtype=float)
        if not np.isfinite(value):
            return (t - t.mean()) / max(float(np.ptp(t)), 1e-12)
        settle = -np.expm1(-(t - t.min()) / value)
        return settle - settle.mean()

    @classmethod
    def features(cls, ctx):
        return cls.features_at(ctx, np.inf)


@dataclass
class OffsetDrift(_TimeCourse, Effect):
    """Offset that drifts in time: a rate (reading units per s; with `warmup_s` > 0 settling with that time
    constant, see `_TimeCourse`) plus a random walk of `random_walk` reading units per √s. Typical: 0.5 % of
    the field over a minute's recording, linear."""

    rate: np.ndarray
    random_walk: float = 0.0
    warmup_s: float = 0.0
    name = "offset_drift"
    exogenous = True
    n_params = 3

    def apply(self, values, context):
        t = context.t - context.t[0]
        drift = np.outer(self.course(context.t, float(self.warmup_s)), self.rate)
        if self.random_walk > 0:
            dt = np.diff(t, prepend=t[0])
            drift += np.cumsum(self.random_walk * np.sqrt(dt)[:, None] * context.rng.standard_normal(values.shape),
                               axis=0)
        return values + drift

    @classmethod
    def features_at(cls, ctx, value):
        return _per_axis(np.repeat(cls.shape(ctx, value)[:, None], 3, axis=1))

    @classmethod
    def typical(cls, field_norm, rng, duration_s: float = 60.0):
        return cls(rng.choice([-1, 1], 3) * field_norm * rng.uniform(0.003, 0.006, 3) / duration_s)


@dataclass
class ScaleDrift(_TimeCourse, Effect):
    """Sensitivity that drifts in time: s_k (1 + rate_k · course(t)), rate in 1/s (with `warmup_s` > 0 settling
    with that time constant, see `_TimeCourse`) — a bridge's or a coil driver's gain warming up with no
    temperature logged (with one, temp_scale). Typical: 0.5–1 % over a minute's recording, linear."""

    rate: np.ndarray
    warmup_s: float = 0.0
    name = "scale_drift"
    transducer = True
    n_params = 3

    def apply(self, values, context):
        return values * (1.0 + np.outer(self.course(context.t, float(self.warmup_s)), self.rate))

    @classmethod
    def features_at(cls, ctx, value):
        return _per_axis(ctx.signal * cls.shape(ctx, value)[:, None])

    @classmethod
    def typical(cls, field_norm, rng, duration_s: float = 60.0):
        return cls(rng.choice([-1, 1], 3) * rng.uniform(0.005, 0.01, 3) / duration_s)


LINE_PEAKS = 4         # periodic_interference: the residual spectrum's highest peaks whose frequencies are tried
LINE_STEPS = (-1.0, -0.5, 0.0, 0.5, 1.0)  # ... each at these offsets, in the recording's frequency resolution 1/T
LINE_LOWEST_CYCLES = 4.0  # ... from this many cycles in the recording (slower is a drift's course) to the Nyquist
LINE_SEGMENTS = 8  # a line's drift of frequency: its peak followed through this many stretches of the recording
LINE_DRIFT_MOST = 0.25  # ... within this share of its frequency either way (a motor's speed, a fan warming up)


def _line_phase(t, f: float, rate: float, ends=None) -> np.ndarray:
    """2π ∫ (f + rate (t − t_mid)) dt from the first reading: a line's phase, its frequency f at the recording's
    middle (`ends`: the recording's first and last times, when t is part of it)."""
    t = np.asarray(t, dtype=float)
    t0, t1 = (float(np.min(t)), float(np.max(t))) if ends is None else ends
    mid = 0.5 * (t0 + t1)
    return 2 * np.pi * f * (t - t0) + np.pi * rate * ((t - mid) ** 2 - (t0 - mid) ** 2)


def _line_inputs(ctx) -> tuple:
    """What a line's residual series is made of (_per_context's key for everything derived from it)."""
    return ctx.t, ctx.readings, ctx.signal, getattr(ctx, "modelled", None)


def _line_series(ctx) -> tuple:
    """(times, series): what the fit leaves of the readings, as the fit sees it (against reference vectors the
    readings less the model's, per axis; against magnitudes that difference along each axis' share of the magnitude:
    the line modulated by the turning, demodulated per axis), resampled onto the median step (a few dropped samples
    do not move a line) and centred. Kept on the context."""
    def compute():
        t = np.asarray(ctx.t, dtype=float)
        _, step = _span_and_step(t)
        order = np.argsort(t, kind="stable")
        # (less the effects modelled: a line found is no peak to find again)
        rest = (np.asarray(ctx.readings) - getattr(ctx, "modelled", 0.0) - np.asarray(ctx.signal))[order]
        if ctx.vector:
            series = rest
        else:  # e = uᵀ A (m − s): each axis' part of the magnitude residual, modulated by u
            A = np.linalg.inv(ctx.W)
            u = np.asarray(ctx.field)[order]
            u = u / np.linalg.norm(u, axis=1, keepdims=True)
            e = np.einsum("nk,nk->n", u @ A, rest)
            series = e[:, None] * (u @ A)
        even = np.arange(t[order][0], t[order][-1] + 0.5 * step, step)
        series = np.column_stack([np.interp(even, t[order], c) for c in series.T])
        return even, series - series.mean(axis=0)

    return _per_context(ctx, "_line_series", _line_inputs(ctx), compute)


def _line_spectra(ctx):
    """_segment_spectra of the context's _line_series, kept on the context (every frequency tried asks)."""
    return _per_context(ctx, "_line_spectra", _line_inputs(ctx), lambda: _segment_spectra(*_line_series(ctx)))


def _demodulated_power(t, series, f: float, rates, ends) -> np.ndarray:
    """Σ over the axes of |Σ series e^(−i phase)|² for the line at f drifting at each of `rates`: the power a line
    of that course takes from the series (`ends`: the recording's first and last times, as for _line_phase). One
    course at a time (a long recording's memory); a rate an even step from the one before turns the last course's
    phasors by that step's, one product instead of an exponential (the rate scan's 33 evenly spaced courses: ~6×
    faster on 20 000 readings, the same to 1e-10 of the highest)."""
    rates = np.atleast_1d(np.asarray(rates, dtype=float))
    gaps = np.diff(rates)
    even = np.r_[False, False, np.abs(np.diff(gaps)) <= 1e-9 * np.abs(gaps[1:])]  # (a step as the one before)
    mid = 0.5 * (ends[0] + ends[1])
    bend = np.pi * ((t - mid) ** 2 - (ends[0] - mid) ** 2)  # the phase a unit rate adds (_line_phase)
    series = np.asarray(series, dtype=complex)  # (once, not by each product)
    sums, phasors, turn, step = np.empty((len(rates), series.shape[1]), dtype=complex), None, None, np.nan
    for k, r in enumerate(rates):
        if even[k]:
            if not abs(gaps[k - 1] - step) <= 1e-9 * abs(step):
                step, turn = gaps[k - 1], np.exp(-1j * gaps[k - 1] * bend)
            phasors = phasors * turn
        else:
            phasors = np.exp(-1j * _line_phase(t, f, r, ends))
        sums[k] = phasors @ series
    return np.sum(np.abs(sums) ** 2, axis=1)


def _segment_spectra(t, series):
    """(frequencies, the stretches' middles from the series' middle, their power spectra LINE_SEGMENTS × bins, the
    narrowest band a peak is looked for in: 3 / a stretch's span): the series' first three quarters in LINE_SEGMENTS
    stretches, each Hann-windowed and padded 8×, for _line_ridge; or None for too short a series. The same for every
    frequency asked about (_line_spectra keeps them per context)."""
    used = int(0.75 * len(t))
    if used < 8 * LINE_SEGMENTS:
        return None
    step = float(t[1] - t[0])
    seg = used // LINE_SEGMENTS
    window = np.hanning(seg)[:, None]
    power, centres = np.empty((LINE_SEGMENTS, 4 * seg + 1)), np.empty(LINE_SEGMENTS)
    for k in range(LINE_SEGMENTS):  # (one stretch at a time: all eight padded at once took 7× the memory)
        power[k] = np.sum(np.abs(np.fft.rfft(series[k * seg:(k + 1) * seg] * window, n=8 * seg, axis=0)) ** 2, axis=1)
        centres[k] = float(np.mean(t[k * seg:(k + 1) * seg])) - 0.5 * float(t[0] + t[-1])
    return np.fft.rfftfreq(8 * seg, step), centres, power, 3.0 / (seg * step)


def _line_ridge(t, series, f: float, spectra=None):
    """(rate Hz/s, frequency at the recording's middle) of the line near f, from its peak in LINE_SEGMENTS stretches
    of the series' first three quarters (a straight line through their frequencies, weighted by their power), or
    None for too short a series. `spectra`: _segment_spectra(t, series) when the caller has them."""
    spectra = _segment_spectra(t, series) if spectra is None else spectra
    if spectra is None or not f > 0:
        return None
    freqs, centres, powers, narrowest = spectra
    band = np.abs(freqs - f) <= max(LINE_DRIFT_MOST * f, narrowest)
    if band.sum() < 3:
        return None
    peaks, weights = [], []
    for power in powers:
        j = np.flatnonzero(band)[np.argmax(power[band])]
        if 0 < j < len(power) - 1:  # the peak between bins (a parabola through its three)
            a, b, c = np.log(power[j - 1:j + 2] + 1e-300)
            j = j + 0.5 * (a - c) / (a - 2 * b + c) if a - 2 * b + c < 0 else j
        peaks.append(float(j) * float(freqs[1]))
        weights.append(float(np.max(power[band])))
    rate, at_middle = np.polyfit(centres, peaks, 1, w=np.sqrt(weights))
    return float(rate), float(at_middle)


def _line_rate(t, series, f: float, spectra=None) -> float:
    """_rate's estimate on the series' first three quarters (see PeriodicInterference._rate); `spectra` as for
    _line_ridge."""
    ridge = _line_ridge(t, series, f, spectra)
    used = int(0.75 * len(t))
    t_used, s_used = t[:used], series[:used]
    span = float(t_used[-1] - t_used[0])
    if ridge is None or abs(ridge[0]) * span < 0.5 / span:  # (steady: no demodulation to pay for)
        return 0.0
    ends = (float(t[0]), float(t[-1]))
    centre = ridge[0]
    for _ in range(4):  # the ridge's slope is rough (a slow drift within a stretch's bin): the steps move with the best
        rates = np.concatenate([[0.0], centre + np.linspace(-4.0, 4.0, 33) / (2.0 * span ** 2)])  # quarter cycles
        power = _demodulated_power(t_used, s_used, f, rates, ends)
        best = int(np.argmax(power[1:])) + 1
        if 1 < best < len(rates) - 1:
            break
        centre = float(rates[best])
    rate = float(rates[best])
    if 1 < best < len(rates) - 1:  # between the steps: a parabola through the three about the best
        a, b, c = power[best - 1:best + 2]
        rate += 0.5 * (a - c) / (a - 2 * b + c) * float(rates[2] - rates[1]) if a - 2 * b + c < 0 else 0.0
    # the power it adds against BIC's price for one parameter, in the series' own noise (its power per sample
    # once the line at that course is taken off)
    noise = max(float(np.sum(s_used ** 2)) - 2.0 * power[best] / used, 0.0) / (used * s_used.shape[1])
    if 2.0 * (power[best] - power[0]) / used < noise * np.log(used) or abs(rate) * span < 1.0 / span:
        return 0.0
    # a line drifts within LINE_DRIFT_MOST of its frequency either way: a short recording's ridge had "a field at
    # −0.151 Hz drifting to 2.163 Hz" take a step (a blind check) — through 0 Hz is no line's course
    if abs(rate) * 0.5 * (ends[1] - ends[0]) > LINE_DRIFT_MOST * f:
        return 0.0
    return rate


@dataclass
class PeriodicInterference(Effect):
    """A field at one frequency fixed in the sensor's frame: m + a sin(2π f t) + c cos(2π f t), a and c per axis
    (reading units) — a motor's or fan's field at a steady speed, a PWM-driven heater or LED, a switching supply,
    the mains aliased by the sampling rate, with no current logged (with one, motor_current). Seen through the
    magnitude its line is spread by the sensor's turning; the candidate models it in the sensor's axes, so the fit
    takes the spread line whole. The frequency is profiled (`frequency_hz`): the exact fit's best among the highest
    peaks of the residuals' spectrum (each projected onto what the fit sees), refined between them. Typical:
    0.5–1.5 % of the field at 1–10 Hz."""

    amplitude: np.ndarray
    frequency_hz: float
    phase: np.ndarray
    # a frequency that drifts (a motor's speed sagging with its supply, a fan warming up): f + rate (t − t_mid), Hz/s
    rate_hz_per_s: float = 0.0
    name = "periodic_interference"
    exogenous = True
    n_params = 6
    regime = "time"
    needs = ("t", "timestamps")  # a frequency in Hz needs real times
    profile_name = "frequency_hz"
    profile_open_end = False
    # (in log f: 1e-3 had left 6 mHz at 5.6 Hz, a third of a cycle over a minute, for colored_noise to take)
    profile_xatol = 1e-7
    recurs = True  # a second motor, the mains beside a motor: another line

    def apply(self, values, context):
        t = np.asarray(context.t, dtype=float)
        w = _line_phase(t, self.frequency_hz, self.rate_hz_per_s) + 2 * np.pi * self.frequency_hz * float(np.min(t))
        return values + np.asarray(self.amplitude) * np.sin(w[:, None] + np.asarray(self.phase))

    @classmethod
    def features_at(cls, ctx, value):
        w = _line_phase(ctx.t, float(value), cls._rate(ctx, float(value)))
        sin, cos = np.sin(w), np.cos(w)
        return np.concatenate([_per_axis(np.repeat(sin[:, None], 3, axis=1)),
                               _per_axis(np.repeat(cos[:, None], 3, axis=1))], axis=1)

    @classmethod
    def profiled_extras(cls, ctx, value) -> dict:
        rate = cls._rate(ctx, float(value))
        return {"rate_hz_per_s": rate} if rate else {}

    @classmethod
    def _rate(cls, ctx, f: float) -> float:
        """The line's drift of frequency (Hz/s) at mean frequency f, or 0.0 for a steady one: its peak followed
        through LINE_SEGMENTS stretches of the residual series (_line_series), the slope of their frequencies
        refined by the demodulated power, taken when the power it adds pays BIC's price for one more parameter.
        Chosen on the first three quarters of the recording: the held-out last quarter chooses nothing."""
        held = _per_context(ctx, "_line_rates", _line_inputs(ctx), dict)
        if f not in held:
            held[f] = _line_rate(*_line_series(ctx), f, _line_spectra(ctx))
        return held[f]

    @classmethod
    def features(cls, ctx):
        return cls.features_at(ctx, cls.profile_grid(ctx)[0])

    @classmethod
    def describe(cls, ctx, feats):
        span = float(np.ptp(ctx.t)) if len(ctx.t) > 1 else 0.0
        return {"resolution_hz": 1.0 / span if span > 0 else np.inf}  # lines closer than 2× this are one

    @classmethod
    def profile_grid(cls, ctx):
        """Frequencies about the LINE_PEAKS highest peaks of what the fit leaves, seen as the fit sees it: against
        reference vectors the readings less the model's (per axis), against magnitudes that difference along
        each axis' share of the magnitude (the line modulated by the turning, demodulated per axis). Readings
        resampled onto their median step (a few dropped samples do not move a line)."""
        span, step = _span_and_step(ctx.t)
        if not (span > 0 and step > 0) or len(ctx.t) < 64:
            return np.array([1.0])
        return _per_context(ctx, "_line_grid", _line_inputs(ctx), lambda: cls._grid(ctx, span, step))

    @staticmethod
    def _grid(ctx, span: float, step: float) -> np.ndarray:
        even, series = _line_series(ctx)
        power = np.sum(np.abs(np.fft.rfft(series, axis=0)) ** 2, axis=1)
        f = np.fft.rfftfreq(len(even), step)
        df = 1.0 / (len(even) * step)
        usable = (f >= LINE_LOWEST_CYCLES / span) & (f <= 0.5 / step - 2 * df)
        peaks = np.flatnonzero(usable[1:-1] & (power[1:-1] >= power[:-2]) & (power[1:-1] >= power[2:])) + 1
        top = peaks[np.argsort(power[peaks])[::-1][:LINE_PEAKS]]
        if not len(top):
            return np.array([max(LINE_LOWEST_CYCLES / span, df)])
        # a line whose frequency drifts spreads its peak: its frequency at the middle, followed through the
        # recording (_line_ridge), is tried beside the peak's
        spectra = _line_spectra(ctx)
        ridges = [_line_ridge(even, series, float(f[j]), spectra) for j in top]
        middles = [r[1] for r in ridges if r is not None and abs(r[0]) * span > 1.0 / span
                   and LINE_LOWEST_CYCLES / span <= r[1] <= 0.5 / step - 2 * df]
        grid = np.unique(np.concatenate([np.concatenate([f[top], middles])[:, None] + df * np.asarray(LINE_STEPS)]
                                        ).ravel())
        return grid[grid > 0]

    @classmethod
    def typical(cls, field_norm, rng):
        return cls(rng.choice([-1, 1], 3) * field_norm * rng.uniform(0.005, 0.015, 3), float(np.exp(rng.uniform(0, np.log(10)))),
                   rng.uniform(0, 2 * np.pi, 3))


# ---------------------------------------------------------------- field effects

def _rows_within(t: np.ndarray, t_on: float, t_off: float, ordered: bool = False):
    """The readings with t_on ≤ t ≤ t_off: a slice when they are consecutive rows (readings in time order),
    else their indices. `ordered`: t is known to be non-decreasing (`_time_ordered`), the slice found by bisection
    (an event search asks some 1000 times)."""
    if ordered:
        lo, hi = int(t.searchsorted(t_on, side="left")), int(t.searchsorted(t_off, side="right"))
        return slice(lo, hi) if lo < hi else slice(0, 0)
    rows = np.flatnonzero((t >= t_on) & (t <= t_off))
    if len(rows) == 0:
        return slice(0, 0)
    return slice(int(rows[0]), int(rows[-1]) + 1) if rows[-1] - rows[0] + 1 == len(rows) else rows


def _time_ordered(ctx) -> bool:
    """Whether the context's times never decrease (the diagnosis sorts them), once per context."""
    return _per_context(ctx, "_time_ordered", (ctx.t,), lambda: bool(np.all(ctx.t[1:] >= ctx.t[:-1])))


def _sample_step(t: np.ndarray, none: float = 1.0) -> float:
    """The readings' median time step between distinct times (`none` when they share one time)."""
    steps = np.diff(np.sort(t))
    return float(np.median(steps[steps > 0])) if np.any(steps > 0) else none


def scatter_rows(n: int, feats: np.ndarray, rows) -> np.ndarray:
    """Features given on `rows` only as an array over all n readings, zero elsewhere."""
    full = np.zeros((n,) + feats.shape[1:])
    full[rows] = feats
    return full


class _TimeBox(Effect):
    """A candidate on within one box of time, [t_on, t_off] (a box that reaches an end of the recording is
    one step): the edges are scanned on a grid of GRID + 1 times, then each refined to the sample. A
    subclass gives the features within a box on the readings in it (`_box_rows`); the search hands the
    score those rows alone, `score(features, rows)` (some 600 boxes are scored: over all readings, most
    of each score's cost was zeros)."""

    regime = "events"
    needs = ("t",)
    GRID = 32  # box edges scanned: every pair of GRID + 1 equally spaced times
    FINE = 4   # refinement: 2·FINE + 1 positions of an edge per level, each level FINE times finer

    @classmethod
    def _box_rows(cls, ctx, t_on, t_off):  # pragma: no cover - interface
        """(features, rows): the features on the readings within the box, and those readings."""
        raise NotImplementedError

    BOX_DEGREE = 0  # within a box: the Legendre polynomials P_0…P_BOX_DEGREE of u (−1…1 across it) times `_carrier`

    @classmethod
    def _carrier(cls, ctx):  # pragma: no cover - interface
        """N × q × 3: what every time profile multiplies (a box's features on its readings are P_k(u) times the
        carrier, column k·q + a) — what a scorer of many boxes at once sums (`score.boxes`)."""
        raise NotImplementedError

    @classmethod
    def _box(cls, ctx, t_on, t_off, *args):
        return scatter_rows(len(ctx.t), *cls._box_rows(ctx, t_on, t_off, *args))

    @classmethod
    def _coarse_edges(cls, ctx):
        edges = np.quantile(ctx.t, np.linspace(0, 1, cls.GRID + 1))
        return [(edges[a], edges[b]) for a in range(cls.GRID) for b in range(a + 1, cls.GRID + 1)
                if not (a == 0 and b == cls.GRID)]  # on throughout is part of the base model

    @classmethod
    def alternatives(cls, ctx):
        return [cls._box(ctx, a, b) for a, b in cls._coarse_edges(ctx)]

    @classmethod
    def search(cls, ctx, score):
        """Coarse scan of the box edges, then each edge refined in turn on ever finer grids down to the
        sample spacing (a misplaced edge of a step leaves large residuals)."""
        edges, _, tried = cls._search_box(ctx, score)
        return cls._box(ctx, *edges), tried

    @classmethod
    def _search_box(cls, ctx, score, near=None):
        """The box search: (edges, best score, alternatives tried). `near` (edges, width): only the refinement,
        from those edges over ± width."""
        if near is not None:
            edges, width = list(near[0]), near[1]
            return cls._refine_box(ctx, score, edges, score(*cls._box_rows(ctx, *edges)), 1, width)
        coarse = cls._coarse_edges(ctx)
        boxes = getattr(score, "boxes", None)  # a scorer of many boxes at once (the diagnosis': score_on.boxes)
        scores = list(boxes(cls, ctx, coarse)) if boxes else [score(*cls._box_rows(ctx, a, b)) for a, b in coarse]
        best_at = int(np.argmax(scores))
        # A box from the recording's start and the box from its other edge to the end are one step told two ways
        # (on one, an offset is the base's offset plus its negative on the other): their scores tie, up to rounding,
        # and the step is told as on from its time
        if coarse[best_at][0] <= ctx.t.min():
            after = [k for k, (a, b) in enumerate(coarse) if a == coarse[best_at][1] and b >= ctx.t.max()]
            if after and scores[after[0]] >= scores[best_at] - 1e-9 * abs(scores[best_at]):
                best_at = after[0]
        return cls._refine_box(ctx, score, list(coarse[best_at]), scores[best_at], len(coarse), np.ptp(ctx.t) / cls.GRID)

    @classmethod
    def _refine_box(cls, ctx, score, edges, best, tried, width):
        """Each edge refined in turn over ± width, on ever finer grids down to the sample spacing."""
        dt = _sample_step(ctx.t)
        # An edge at an end of the recording makes the box a step (one edge): moving it inside adds an
        # edge, worth it only for more than the BIC's price of a parameter (else noise moves it a few samples)
        price = np.log(len(ctx.t))
        while width > dt / 2:
            for side in (0, 1):
                for x in np.linspace(edges[side] - width, edges[side] + width, 2 * cls.FINE + 1):
                    trial = list(edges)
                    trial[side] = x
                    if trial[1] - trial[0] < 4 * dt:
                        continue
                    value = score(*cls._box_rows(ctx, *trial))
                    tried += 1
                    at_end = edges[side] <= ctx.t.min() if side == 0 else edges[side] >= ctx.t.max()
                    if value > best + (price if at_end and ctx.t.min() < x < ctx.t.max() else 0.0):
                        best, edges = value, trial
            width /= cls.FINE
        return edges, best, tried

    @classmethod
    def features(cls, ctx):
        return cls.alternatives(ctx)[0]

    @staticmethod
    def span(ctx, feats):
        """The first and last time within the box of `feats` (None when it is empty)."""
        on = np.any(feats != 0, axis=(1, 2))
        return (float(ctx.t[on].min()), float(ctx.t[on].max())) if on.any() else None

    @classmethod
    def describe(cls, ctx, feats) -> dict:
        """The box found: `on_s`, `off_s` — the first and last reading's time within it; None for an edge
        at the recording's start or end (a step, not an episode)."""
        span = cls.span(ctx, feats)
        if span is None:
            return {}
        return {"on_s": None if span[0] <= ctx.t.min() else span[0],
                "off_s": None if span[1] >= ctx.t.max() else span[1]}

    @classmethod
    def searched_times(cls, described: dict) -> int:
        """The box's edges inside the recording (one at an end makes it a step: one time fewer)."""
        return sum(described.get(k) is not None for k in ("on_s", "off_s"))

    @classmethod
    def placed_again(cls, ctx, part, feats, score, width) -> tuple:
        """The box `feats` (on ctx's readings) placed again on `part`'s readings (some of ctx's, in time order; `score`
        theirs), each edge within ± `width` of where it was: (its edges there, the box laid on ctx's readings with its
        edges halfway between its first and last reading in `part` and their neighbours there)."""
        span = cls.span(ctx, feats)
        if span is None:
            return None, feats
        edges = cls._search_box(part, score, near=(span, width))[0]
        span = cls.span(part, cls._box(part, *edges))
        if span is None:
            return edges, np.zeros_like(feats)
        before, after = part.t[part.t < span[0]], part.t[part.t > span[1]]
        return edges, cls._box(ctx, 0.5 * (before.max() + span[0]) if len(before) else ctx.t.min(),
                               0.5 * (span[1] + after.min()) if len(after) else ctx.t.max())


@dataclass
class MovingDipole(_TimeBox):
    """A nearby magnet that moves or switches: a dipole of moment `moment` (reading units × m³, μ0/4π
    folded in) on at `t_on`…`t_off`, moving from `start` to `end` (m, world frame, relative to the
    sensor) meanwhile. Its field is added in the world frame and turned into the sensor frame.
    Typical: a tool or phone passing 0.25 m away, 3–12 % of the Earth's field.

    As a candidate: while the disturbance is on, the total field's magnitude changes (what a magnitude
    model sees): a level, a slope and a curvature (Legendre P0–P2 across the box: the magnet moving, its
    field falling as 1/r³) within a box in time (see _TimeBox), or a pass on a straight line (Anderson's
    functions, `_pass_rows`), whichever fits better; once accepted, a richer profile (`shapes`)."""

    moment: np.ndarray
    start: np.ndarray
    end: np.ndarray
    t_on: float
    t_off: float
    name = "moving_dipole"
    exogenous = True
    n_params = 3

    def apply(self, values, context):
        t = context.t
        on = (t >= self.t_on) & (t <= self.t_off)
        frac = np.clip((t - self.t_on) / max(self.t_off - self.t_on, 1e-12), 0, 1)
        return values + context.rotations.inv().apply(self._field(frac) * on[:, None])

    def _field(self, frac: np.ndarray) -> np.ndarray:
        """The dipole's field at the sensor (world frame) at fractions `frac` of its way from start to end."""
        r = -(np.asarray(self.start) + frac[:, None] * (np.asarray(self.end) - np.asarray(self.start)))  # → sensor
        d = np.linalg.norm(r, axis=1, keepdims=True)
        rhat = r / d
        mvec = np.asarray(self.moment, dtype=float)
        return (3 * rhat * (rhat @ mvec)[:, None] - mvec) / d ** 3

    @classmethod
    def straight_pass(cls, field_norm, rng, t_close: float, t_pass: float, size: float = 0.03):
        """A magnet carried past on a straight line at a steady speed: closest (0.25 m away) at `t_close`, travelling
        that distance in `t_pass` s, its field at most `size` × `field_norm`; on from PASS_REACH passage times
        before to as many after (beyond, under 0.4 % of its peak). The line's direction and the moment's are
        random."""
        distance = 0.25
        along = rng.standard_normal(3)
        along /= np.linalg.norm(along)
        closest = rng.standard_normal(3)
        closest -= (closest @ along) * along
        closest *= distance / np.linalg.norm(closest)
        reach = cls.PASS_REACH * distance * along
        passing = cls(rng.standard_normal(3), closest - reach, closest + reach, t_close - cls.PASS_REACH * t_pass,
                      t_close + cls.PASS_REACH * t_pass)
        largest = np.max(np.linalg.norm(passing._field(np.linspace(0.0, 1.0, 1601)), axis=1))
        passing.moment = passing.moment * size * field_norm / largest
        return passing

    BOX_DEGREE = 2

    @classmethod
    def _box_rows(cls, ctx, t_on, t_off, degree: int = BOX_DEGREE):
        rows = _rows_within(ctx.t, t_on, t_off, _time_ordered(ctx))

        def shape():
            u = 2 * (ctx.t[rows] - 0.5 * (t_on + t_off)) / (t_off - t_on)  # −1…1 across the box
            return np.polynomial.legendre.legvander(u, degree)
        # (the time profile depends on the times alone: every round's search scores the same coarse boxes)
        shape = _per_diagnosis(getattr(ctx, "memo", None), ("box", t_on, t_off, degree), (ctx.t,), shape)
        return cls._along_field(ctx, rows, shape), rows

    @classmethod
    def _carrier(cls, ctx):
        return cls._along_field(ctx, slice(None), np.ones((len(ctx.t), 1)))

    @staticmethod
    def _along_field(ctx, rows, shape: np.ndarray) -> np.ndarray:
        """Features of a field disturbance whose time profile is each column of `shape` (rows × k): along the
        field (what a magnitude sees), or against reference vectors with the down direction known, each
        world component of the field."""
        if ctx.world is None:
            return shape[:, :, None] * ctx.direction[rows][:, None, :]
        return (shape[:, :, None, None] * ctx.world[rows][:, None, :, :]).reshape(len(shape), 3 * shape.shape[1], 3)

    # A magnet carried past on a straight line at a steady speed (a tool, a phone, a vehicle): with its closest
    # approach at t_c and τ = (t − t_c)/T (T: the time it takes to travel its closest distance), every component
    # of its field is a combination of τⁿ/(1 + τ²)^(5/2), n = 0, 1, 2 — Anderson's functions, the basis of
    # magnetic anomaly detection. A quadratic in a box fitted such a pass poorly (its lobes change sign), and
    # a 20 % pass on a real recording's own wander went unconfirmed (blind20). Beyond |τ| = PASS_REACH the
    # field is under 0.4 % of its peak (it falls as |τ|⁻³ at worst). T up to a 16th of the recording, and both
    # sides of the pass (its closest approach ± PASS_SIDES T, where the envelope has fallen to 2 %) in it: a pass
    # is an event, and a longer "pass" or half of one (a ramp over most of the recording) fitted real recordings'
    # own slow wander in sample, not held out.
    PASS_REACH = 8.0
    PASS_SIDES = 2.0
    PASS_TIMES = 8  # passage times T tried, geometric from a 200th to a 16th of the recording (at least: below)
    # … and down to PASS_SHORTEST (in the time's units; four samples at least) in a long recording, at the same ratio:
    # a magnet carried past at walking pace a metre away takes about 0.7 s (T = distance / speed), 1/900 of ten
    # minutes, where a 200th had left it to a box or a step
    PASS_SHORTEST = 0.5
    PASS_STARTS = 3  # the best passage times on the coarse grid refined

    @classmethod
    def _pass_rows(cls, ctx, t_close, t_pass, order: int = 1):
        """A pass's features on the readings it reaches, and those readings. order 2 (magnitudes only): also
        the magnitude's second-order change |B⊥|²/2H, a quartic in τ over (1 + τ²)⁵ — up to a tenth of a pass at
        20 % of the field."""
        rows = _rows_within(ctx.t, t_close - cls.PASS_REACH * t_pass, t_close + cls.PASS_REACH * t_pass,
                            _time_ordered(ctx))
        # (the time profile depends on the times alone: every round's search scores the same coarse passes)
        shape = _per_diagnosis(getattr(ctx, "memo", None), ("pass", t_close, t_pass, order), (ctx.t,),
                               lambda: cls.pass_profile((ctx.t[rows] - t_close) / t_pass, order))
        return cls._along_field(ctx, rows, shape), rows

    @staticmethod
    def pass_profile(tau: np.ndarray, order: int = 1) -> np.ndarray:
        """A pass's time profiles at τ (any shape; a last axis added): Anderson's functions (order 2: and the
        magnitude's second-order change, see `_pass_rows`)."""
        near = 1.0 / (1.0 + tau * tau)
        envelope = near * near * np.sqrt(near)  # (1 + τ²)^(−5/2) (a fractional power costs 3× this)
        profiles = [envelope, envelope * tau, envelope * tau * tau]
        if order == 2:
            profiles += [envelope * envelope * tau ** n for n in range(5)]
        return np.stack(profiles, axis=-1)

    @classmethod
    def _search_pass(cls, ctx, score):
        """The pass search: coarse closest times (every passage time: the refinement's first level reaches half
        of one either side) for each passage time, then the two refined in turn down to the sample spacing.
        (closest time and passage time or None, best score, alternatives tried)."""
        span, dt = float(np.ptp(ctx.t)), _sample_step(ctx.t)
        shortest = max(2.0 * dt, min(span / 200, max(4.0 * dt, cls.PASS_SHORTEST)))
        ratio = (200 / 16) ** (1 / (cls.PASS_TIMES - 1))
        count = max(cls.PASS_TIMES, int(np.ceil(np.log(span / 16 / shortest) / np.log(ratio) - 1e-9)) + 1)
        times = np.geomspace(shortest, span / 16, count)
        if not span / 16 > 2.0 * dt:
            return None, -np.inf, 0

        def inside(t_close, t_pass):
            return (2.0 * dt <= t_pass <= span / 16 and t_close - cls.PASS_SIDES * t_pass >= ctx.t.min()
                    and t_close + cls.PASS_SIDES * t_pass <= ctx.t.max())

        coarse, tried = [], 0  # per passage time: its best closest time on the coarse grid
        passes = getattr(score, "passes", None)  # a scorer of many passes at once (the diagnosis': score_on.passes)
        for t_pass in times:
            closest = np.arange(ctx.t.min() + cls.PASS_SIDES * t_pass, ctx.t.max() - cls.PASS_SIDES * t_pass,
                                max(t_pass, dt))
            if passes is not None:
                values = list(passes(cls, ctx, closest, t_pass)) if len(closest) else []
            else:
                values = [score(*cls._pass_rows(ctx, t_close, t_pass)) for t_close in closest]
            tried += len(values)
            if values:
                coarse.append((max(values), [closest[int(np.argmax(values))], t_pass]))
        if not coarse:
            return None, -np.inf, tried

        def refine(best, where):
            nonlocal tried
            width, ratio = max(where[1] / 2, dt), times[1] / times[0]
            while width > dt / 2:
                for side, trials in ((0, where[0] + np.linspace(-width, width, 2 * cls.FINE + 1)),
                                     (1, where[1] * ratio ** np.linspace(-1, 1, 2 * cls.FINE + 1))):
                    for x in trials:
                        trial = list(where)
                        trial[side] = x
                        if not inside(*trial):
                            continue
                        value = score(*cls._pass_rows(ctx, *trial))
                        tried += 1
                        if value > best:
                            best, where = value, trial
                width, ratio = width / cls.FINE, ratio ** (1 / cls.FINE)
            return best, where

        # refined from the best of several passage times: the coarse grid's closest times fall up to half a
        # passage time from the truth, so its best can sit at the wrong passage time, and refining one parameter
        # at a time does not leave that ridge (a 1.47 s pass refined from 0.86 s: missed)
        refined = [refine(*start) for start in sorted(coarse, key=lambda c: -c[0])[:cls.PASS_STARTS]]
        best, where = max(refined, key=lambda r: r[0])
        return where, best, tried

    @classmethod
    def search(cls, ctx, score):
        """The better of a box (a magnet switched on or moved within it) and a pass. A box reaching an end of
        the recording is a step, one time fewer than a pass's two: the pass pays BIC's price for it."""
        edges, best, tried = cls._search_box(ctx, score)
        passing, best_pass, tried_pass = cls._search_pass(ctx, score)
        step = edges[0] <= ctx.t.min() or edges[1] >= ctx.t.max()
        if passing is not None and best_pass > best + (np.log(len(ctx.t)) if step else 0.0):
            return scatter_rows(len(ctx.t), *cls._pass_rows(ctx, *passing)), tried + tried_pass
        return cls._box(ctx, *edges), tried + tried_pass

    @classmethod
    def describe(cls, ctx, feats) -> dict:
        """The box's times (see _TimeBox), and for a pass its closest approach `closest_s` and passage time
        `passage_s` (T above), read back from the features: for a pass the second and third profiles over the
        first are τ and τ², for the box's Legendre polynomials u and (3u² − 1)/2."""
        out = super().describe(ctx, feats)
        on = np.any(feats != 0, axis=(1, 2))
        q = feats.shape[1] // 3  # columns per profile: 1 along the field, 3 world components
        if on.sum() < 3 or feats.shape[1] != 3 * q:
            return out
        profile = [np.einsum("nk,nk->n", feats[on, j * q], feats[on, 0]) for j in range(3)]
        tau, square = profile[1] / profile[0], profile[2] / profile[0]
        if np.allclose(square, tau ** 2, rtol=1e-6, atol=1e-9):
            slope, intercept = np.polyfit(ctx.t[on], tau, 1)
            out.update(closest_s=float(-intercept / slope), passage_s=float(1.0 / slope))
        return out

    @classmethod
    def searched_times(cls, described: dict) -> int:
        """A pass: its closest approach and its passage time; a box: its edges inside the recording."""
        return 2 if described.get("closest_s") is not None else super().searched_times(described)

    MAX_DEGREE = 5  # 8 left the fits on the training blocks ill-conditioned (a held-out block inside the box)

    @classmethod
    def shapes(cls, ctx, feats):
        """Once accepted (found and validated with a quadratic in time), the disturbance's time profile in
        its box at degrees 3…MAX_DEGREE, for the diagnosis to choose by BIC: a magnet moved by hand follows
        no quadratic, and what the quadratic leaves would be fitted by the next event candidate as a
        second event. A pass: with its magnitude's second-order change (none against reference vectors, whose
        field components a pass changes linearly, with or without the down direction)."""
        passing = cls.describe(ctx, feats)
        if "closest_s" in passing:
            return [] if ctx.vector else \
                [scatter_rows(len(ctx.t), *cls._pass_rows(ctx, passing["closest_s"], passing["passage_s"], order=2))]
        first, last = cls.span(ctx, feats)
        return [cls._box(ctx, first, last, degree) for degree in range(3, cls.MAX_DEGREE + 1)]

    @classmethod
    def typical(cls, field_norm, rng, duration_s: float = 60.0):
        direction = rng.standard_normal(3)
        direction /= np.linalg.norm(direction)
        distance = 0.25
        moment = field_norm * rng.uniform(0.03, 0.06) * distance ** 3 * direction
        t_on = duration_s * rng.uniform(0.2, 0.35)
        start = distance * np.array([1.0, 0.0, 0.0])
        end = distance * np.array([0.8, 0.6, 0.0])
        return cls(moment, start, end, t_on, t_on + duration_s * rng.uniform(0.2, 0.3))


@dataclass
class OffsetStep(_TimeBox):
    """The offset jumps by `delta` (reading units, sensor frame) at `t_on`, and back at `t_off` (inf: it
    stays): a part next to the sensor magnetised by a shock or a strong field (perming), a device on the
    same board switched on (and off), an AMR bridge's offset after a set/reset pulse. Unlike a moving
    dipole's field (world frame) it turns with the sensor, so what it does to |h| changes with the
    orientation. Typical: 1–2 % of the field; half of them stay.

    As a candidate: a constant offset per axis within a box in time (see _TimeBox; a box from the
    recording's start or to its end is one step)."""

    delta: np.ndarray
    t_on: float
    t_off: float = np.inf
    name = "offset_step"
    exogenous = True
    n_params = 3
    step_at_ends = True  # an edge in the recording's first or last grid cell pays for itself (diagnose._step_at_ends)

    def apply(self, values, context):
        on = (context.t >= self.t_on) & (context.t <= self.t_off)
        return values + np.outer(on, self.delta)

    @classmethod
    def _box_rows(cls, ctx, t_on, t_off):
        rows = _rows_within(ctx.t, t_on, t_off, _time_ordered(ctx))
        # ones per axis: the identity on every row (some 600 boxes are scored). Copied, not the broadcast view:
        # einsum sums over a zero stride in another order, which flipped a tie between a box and its complement
        return np.broadcast_to(AXES, (len(ctx.t[rows]), 3, 3)).copy(), rows

    @classmethod
    def _carrier(cls, ctx):
        return np.broadcast_to(AXES, (len(ctx.t), 3, 3)).copy()

    @classmethod
    def typical(cls, field_norm, rng, duration_s: float = 60.0):
        direction = rng.standard_normal(3)
        delta = field_norm * rng.uniform(0.01, 0.02) * direction / np.linalg.norm(direction)
        t_on = duration_s * rng.uniform(0.2, 0.6)
        # half of them stay (perming), half switch back (a device on the same board switched off)
        t_off = np.inf if rng.uniform() < 0.5 else t_on + duration_s * rng.uniform(0.15, 0.3)
        return cls(delta, t_on, t_off)


@dataclass
class EddyCurrent(Effect):
    """Eddy currents in a conductive housing oppose the change of the field: m = s − τ ds/dt per axis
    (τ in s). Typical: τ ≈ μ0 σ d r / 2 ≈ 1 ms for a 2 mm aluminium wall 2 cm from the sensor, larger
    (3–5 ms) along the normal of a flat box's large faces. A rotating field changes direction, not
    magnitude, so a magnitude model sees only the differences between the axes' τ."""

    tau: np.ndarray
    name = "eddy_current"
    n_params = 3
    regime = "time"
    needs = ("t",)

    def apply(self, values, context):
        return values - np.asarray(self.tau) * np.gradient(values, context.t, axis=0)

    @classmethod
    def features(cls, ctx):
        return _per_axis(-_smooth(ctx.readings, ctx.t, deriv=1))

    @classmethod
    def unphysical(cls, coefficients, standard_errors, vector: bool = False, period: float = 0.0):
        # Against reference vectors nearly the same lag on every axis, of half a sample or more, is a delay between
        # readings and reference (m − δ dm/dt, which this first-order term fits ever worse as δ grows): a blind
        # check's 150 ms delay at 10 Hz came out as "eddy currents" of 171–191 ms on all three axes. Eddy currents
        # lag by milliseconds and by different amounts along a housing's faces (the airborne flight's own
        # 26 / 27 / 38 ms at 10 Hz stay eddy currents).
        tau = np.asarray(coefficients, dtype=float)
        lag = np.abs(tau)
        same_sign = np.all(tau > 0) or np.all(tau < 0)  # a reference that lags the readings: the same, negative
        if vector and period > 0 and same_sign and np.all(lag > 0.5 * period) and lag.max() < ISOTROPIC_LAG * lag.min():
            return (f"nearly the same lag on every axis ({', '.join(f'{1e3 * v:.3g}' for v in tau)} ms, half a sample "
                    "or more) is a delay between the readings and the reference vectors (time_offset), not eddy "
                    "currents")
        if _below_zero(tau, standard_errors).all():
            return "a reading ahead of its field on every axis: eddy currents only ever make it lag"
        return ""

    @classmethod
    def typical(cls, field_norm, rng):
        tau = rng.uniform(0.0005, 0.0015, 3)
        tau[rng.integers(3)] = rng.uniform(0.003, 0.005)  # the flat box's normal
        return cls(tau)


@dataclass
class TimeOffset(Effect):
    """The readings logged `delta` seconds late against their reference vectors (attitude, field model):
    m(t) = s(t − δ) ≈ s − δ ds/dt. Separate clocks or buffers, a filter's group delay, a timestamp taken
    when a sample is read out instead of when it was taken. Typical 5–20 ms either way (one sample period
    of a 50–200 Hz logger). A delayed field keeps its magnitude, so only reference vectors show it; to
    first order it is an eddy current with one τ = δ on every axis, which a negative δ cannot be."""

    delta: float
    name = "time_offset"
    n_params = 1
    regime = "time"
    needs = ("t", "timestamps")  # a delay in seconds needs real times, not row numbers
    needs_reference = True
    moves_reference = True

    def apply(self, values, context):
        return TimeOffset.move_reference(values, context.t, [self.delta])

    @staticmethod
    def compose(total, step):
        return np.asarray(total) + step

    @staticmethod
    def move_reference(reference, t, total):
        return np.column_stack([np.interp(t - total[0], t, v) for v in reference.T])

    @staticmethod
    def describe_move(total):
        return {"delay_ms": 1e3 * float(total[0])}

    @classmethod
    def features(cls, ctx):
        return -_smooth(ctx.readings, ctx.t, deriv=1)[:, None, :]

    @classmethod
    def typical(cls, field_norm, rng):
        return cls(rng.choice([-1.0, 1.0]) * rng.uniform(0.005, 0.02))


@dataclass
class ZLeakage(Effect):
    """A biaxial sensor's x and y read a fraction `k` (2 values) of the out-of-plane field z (package
    tilt, cross-axis). Typical 1–2 %. Simulation only: the 3-axis models absorb it in the matrix."""

    k: np.ndarray
    n_params = 2

    def apply(self, values, context):
        out = values.copy()
        out[:, :2] += np.outer(values[:, 2], self.k)
        return out


# ---------------------------------------------------------------- noise effects

@dataclass
class ColoredNoise(Effect):
    """Correlated noise of standard deviation `sigma`: AR(1) with coefficient `phi`, or flicker (1/f)
    when `kind` = "flicker". Typical: AMR/fluxgate 1/f corner near 1–10 Hz; σ comparable to the white
    noise."""

    sigma: float
    phi: float = 0.95
    kind: str = "ar1"
    name = "colored_noise"
    n_params = 1
    is_noise = True
    regime = "time"
    needs = ("t",)

    @classmethod
    def typical(cls, field_norm, rng):
        return cls(field_norm * rng.uniform(0.001, 0.002), phi=rng.uniform(0.97, 0.99))

    def apply(self, values, context):
        n = len(values)
        white = context.rng.standard_normal(values.shape)
        if self.kind == "flicker":
            f = np.fft.rfftfreq(n)
            shaping = np.where(f > 0, 1.0 / np.sqrt(np.maximum(f, 1.0 / n)), 0.0)
            noise = np.fft.irfft(np.fft.rfft(white, axis=0) * shaping[:, None], n, axis=0)
        else:
            noise = lfilter([1.0], [1.0, -self.phi], white, axis=0)
        return values + self.sigma * noise / noise.std(axis=0)


@dataclass
class Quantization(Effect):
    """An ADC: readings rounded to multiples of `step` (1 LSB). HMC5883L: 0.92 mG/LSB at ±1.3 G (0.2 % of
    the Earth's field); typical here 0.2–0.4 % of the field, several times the white noise of a
    low-noise sensor read through a coarse ADC."""

    step: float
    name = "quantization"
    n_params = 1
    is_noise = True

    @classmethod
    def typical(cls, field_norm, rng):
        return cls(field_norm * rng.uniform(0.002, 0.004))  # a low-noise sensor on a coarse ADC

    def apply(self, values, context):
        return self.step * np.round(values / self.step)


CANDIDATES = (TemperatureScale, TemperatureOffset, MotorCurrent, OffsetDrift, ScaleDrift, CubicNonlinearity,
              QuadraticNonlinearity, Saturation, SaturationKnee, CrossAxis,
              NonOrthogonality, Misalignment, Hysteresis, MovingDipole, OffsetStep, EddyCurrent, TimeOffset,
              PeriodicInterference, ColoredNoise, Quantization)
"""Every effect the diagnosis can rank, by its candidate name (`fluxcal diagnose` documents them)."""

# The unit of each candidate's parameters ("{u}": the readings' unit), for stating a simulation's truth
# (`describe_parameters`). ASCII only: the text goes into every output format's metadata. Angles are given in
# degrees, as the diagnosis reports them (the classes hold radians).
PARAMETER_UNITS = {
    "temp_scale": {"alpha": "1/degC", "t0": "degC", "lag_s": "s"},
    "temp_offset": {"beta": "{u}/degC", "t0": "degC", "lag_s": "s"},
    "motor_current": {"k": "{u}/A"},
    "periodic_interference": {"amplitude": "{u}", "frequency_hz": "Hz", "phase": "rad", "rate_hz_per_s": "Hz/s"},
    "offset_drift": {"rate": "{u}/s", "random_walk": "{u}/sqrt(s)", "warmup_s": "s"},
    "scale_drift": {"rate": "1/s", "warmup_s": "s"},
    "nonlinearity_cubic": {"relative": "(fraction at |s| = scale)", "scale": "{u}"},
    "nonlinearity_quadratic": {"relative": "(fraction at s = scale)", "scale": "{u}"},
    "saturation": {"limit": "{u}"},
    "saturation_knee": {"knee": "{u}", "width": "{u}"},
    "cross_axis": {"hk": "{u}"},
    "non_orthogonality": {"angles": "deg"},
    "misalignment": {"rotvec": "deg"},
    "hysteresis": {"width": "{u}", "share": "(of the output)"},
    "moving_dipole": {"moment": "{u}*m^3", "start": "m", "end": "m", "t_on": "s", "t_off": "s"},
    "offset_step": {"delta": "{u}", "t_on": "s", "t_off": "s"},
    "eddy_current": {"tau": "s"},
    "time_offset": {"delta": "s"},
    "colored_noise": {"sigma": "{u}", "phi": "", "kind": ""},
    "quantization": {"step": "{u}"},
}


def describe_parameters(effect: Effect, unit: str) -> str:
    """A candidate effect's parameters with their units, `unit` the readings': "beta [0.0153 -0.0131 -0.0139]
    uT/degC, t0 25 degC, lag_s 0 s" — the truth a diagnosis of the simulation is compared with."""
    from dataclasses import fields

    units = PARAMETER_UNITS[effect.name]
    parts = []
    for f in fields(effect):
        value, u = getattr(effect, f.name), units[f.name].format(u=unit)
        if isinstance(value, str):
            text = value
        else:
            v = np.degrees(np.asarray(value, float)) if u == "deg" else np.asarray(value, float)
            text = f"{float(v):.6g}" if v.ndim == 0 else "[" + " ".join(f"{x:.6g}" for x in v.ravel()) + "]"
        parts.append(f"{f.name} {text}" + (f" {u}" if u else ""))
    return ", ".join(parts)


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
