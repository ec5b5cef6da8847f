"""Kalman filter on the AR(p) companion state space (seed 001, S4), in double and in fixed point.

    k = ArKalman(ar_coeffs, q, r)                  # A companion, B = e1, C = e1ᵀ, Joseph form
    filtered = k.filter(y)                         # C x̂_{k|k} of every sample; k.result has the rest
    f = FixedArKalman(ar_coeffs, q, r, frac_bits=30)
    filtered_fx = f.filter(y)                      # floats at the boundary, int32 Q-format inside
    f.overflowed                                   # sticky saturation flag of the last filter() call
    f.export_header("drift_kalman.h")              # the integer coefficients for firmware

The fixed-point arithmetic is cpp/include/fluxcal/fixed_kalman.hpp; fluxcal.oracle.kalman.FixedModel is
its bit-exact Python integer model (and writes golden vectors).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from . import _core
from ._arrays import as_number
from .timeseries import as_breaks, as_series, as_whole

INT32_MIN, INT32_MAX = -(2 ** 31), 2 ** 31 - 1
# Largest AR order ArKalman takes: each sample costs O(p³) (AR(2000) on 300 samples ran for minutes); AR(100)
# filters 10⁶ samples in about half a minute, ten times fit_pipeline's default ar_max_order.
MAX_ORDER = 100


def _coefficients(ar_coeffs) -> np.ndarray:
    scalar = np.isscalar(ar_coeffs) or (isinstance(ar_coeffs, np.ndarray) and ar_coeffs.ndim == 0)
    a = np.atleast_1d(as_series([ar_coeffs] if scalar else ar_coeffs, "ar_coeffs"))
    if a.size < 1:
        raise ValueError(f"ar_coeffs: shape {a.shape}, expected a non-empty 1-D sequence a1 … ap")
    if not np.all(np.isfinite(a)):
        raise ValueError("ar_coeffs: NaN/Inf")
    return a


def _order_within(a: np.ndarray, maximum: int, what: str) -> np.ndarray:
    if a.size > maximum:
        raise ValueError(f"ar_coeffs: order {a.size} exceeds the {what} maximum {maximum}")
    return a


def _options(initial_variance: float, steady_state: bool):
    o = _core.KalmanOptions()
    o.initial_variance = as_number(initial_variance, "initial_variance")
    o.steady_state = bool(steady_state)
    return o


class ArKalman:
    """Double-precision Kalman filter on the AR(p) model a1 … ap with process variance q and measurement
    variance r. initial_variance: P0 = initial_variance · I (0 = the AR process's stationary covariance, or
    10 (q + r) · I when the model is not stationary or too close to it for that covariance to be determined).
    steady_state: filter with the constant steady-state gain. Orders up to MAX_ORDER = 100 (the cost per
    sample grows as p³); ValueError above."""

    def __init__(self, ar_coeffs, q: float, r: float, initial_variance: float = 0.0, steady_state: bool = False):
        self.ar_coeffs = _order_within(_coefficients(ar_coeffs), MAX_ORDER, "filter's")
        self.q, self.r = as_number(q, "q"), as_number(r, "r")  # (float('a') named neither)
        self.options = _options(initial_variance, steady_state)
        setup = _core.kalman_setup(self.ar_coeffs, self.q, self.r, self.options)
        self.initial_covariance = np.asarray(setup["initial_covariance"])
        self.steady_gain = np.asarray(setup["steady_gain"])
        self.steady_prior_covariance = np.asarray(setup["steady_prior_covariance"])
        self.spectral_radius = setup["spectral_radius"]
        self.result: dict | None = None

    @classmethod
    def from_ar(cls, model, r: float | None = None, initial_variance: float = 0.0,
                steady_state: bool = False) -> "ArKalman":
        """Filter on a fitted AR model (`fluxcal.timeseries.fit_ar`): Q = its residual variance σ², R = `r`
        or, when None, σ² too (an AR fit cannot tell measurement noise from process noise; give r when the
        sensor's white-noise floor is known). ValueError for an order-0 fit."""
        if r is not None and not r >= 0:
            raise ValueError(f"r: measurement variance {r} must be ≥ 0")
        a, q, r = _core.kalman_noise_from_ar(int(model.order), np.asarray(model.coefficients, dtype=np.float64),
                                             float(model.sigma2), -1.0 if r is None else float(r))
        return cls(a, q, r, initial_variance=initial_variance, steady_state=steady_state)

    @property
    def order(self) -> int:
        return self.ar_coeffs.size

    def filter(self, y, breaks=None) -> np.ndarray:
        """Filtered output C x̂_{k|k} of every sample (starting from x = 0, P = P0). `self.result` then
        holds innovations, final state, covariance and gain. breaks: gaps in time
        (fluxcal.timeseries.find_breaks); the filter starts again from x = 0, P = P0 after each."""
        y = as_series(y, "y")
        self.result = _core.kalman_filter(self.ar_coeffs, self.q, self.r, self.options, y,
                                          as_breaks(breaks, y.size))
        return np.asarray(self.result["filtered"])


def _int_bits(value: float) -> int:
    """Bits left of the binary point that hold |value| (0 for |value| ≤ 1)."""
    return max(0, math.ceil(math.log2(value))) if value > 0 else 0


# The signal format is only a scale factor (no shift in the filter depends on it), so its fraction bits
# may exceed 31 or go negative with the signal's units; these limits only keep 2^±frac_bits a double.
SIGNAL_FRAC_BITS_RANGE = (-960, 1000)
# The largest rounding error of q and r the covariance format may leave, as a share (q's of q, r's of q + r): a
# tenth of the output error that 2 LSB of q gave (9.5 % of its σ); the default format keeps ~2^-28.
COV_PRECISION = 0.01


def _signal_frac_bits_holding(value: float) -> int:
    """Fraction bits of the int32 format whose range ±2^(31 − f) just holds `value` (31 for 0)."""
    if not value > 0:
        return 31
    lo, hi = SIGNAL_FRAC_BITS_RANGE
    return int(min(hi, max(lo, 31 - math.ceil(math.log2(value)))))


def signal_format(frac_bits: int) -> str:
    """The signal format's name: Qm.n while it has 0 … 31 fraction bits, else int32 · 2^−f."""
    return f"Q{31 - frac_bits}.{frac_bits}" if 0 <= frac_bits <= 31 else f"int32 x 2^{-frac_bits}"


def signal_gain(ar_coeffs, gain) -> float:
    """Largest ratio, over inputs |y| ≤ 1, of any signal-format value inside the steady-state filter to
    max|y|: the state x (after the update), the prediction Σ a_i x_i and the innovation y − Σ a_i x_i.
    The filter is linear, x_k = F x_{k−1} + K y_k with F = (I − K C) A, so each of them is bounded by
    the ℓ1 norm of its impulse response from y: Σ_j |(F^j K)_i|, Σ_j |a·F^j K| and 1 + the latter.
    (Σ|a_i| · max|y| is not a bound: the state itself can exceed max|y|.)"""
    a = _coefficients(ar_coeffs)
    k = np.asarray(gain, dtype=float)
    if k.shape != a.shape:
        raise ValueError(f"gain: shape {k.shape}, expected {a.shape} (one entry per AR coefficient)")
    if not np.all(np.isfinite(k)):  # NaN ended in a LinAlgError from the matrix power
        raise ValueError("gain: NaN/Inf")
    n = a.size
    comp = np.zeros((n, n))
    comp[0] = a
    comp[np.arange(1, n), np.arange(n - 1)] = 1.0
    f = comp - np.outer(k, comp[0])  # (I − K e1ᵀ) A
    block = 256
    h = np.empty((n, block))  # F^j K for j in the current block
    v = k.copy()
    for j in range(block):
        h[:, j] = v
        v = f @ v
    f_block = np.linalg.matrix_power(f, block)
    state, prediction = np.zeros(n), 0.0
    for _ in range(1 << 14):  # up to 4·10⁶ terms: a closed loop slower than that is summed geometrically below
        part_state, part_prediction = np.abs(h).sum(axis=1), float(np.abs(a @ h).sum())
        state += part_state
        prediction += part_prediction
        if part_state.max() <= 1e-13 * state.max() and part_prediction <= 1e-13 * max(prediction, 1e-300):
            break
        h = f_block @ h
    else:  # the tail at the closed loop's rate
        rho = float(np.max(np.abs(np.linalg.eigvals(f)))) ** block
        state += part_state * rho / (1.0 - rho)
        prediction += part_prediction * rho / (1.0 - rho)
    return float(max(1.0, state.max(), 1.0 + prediction))


def _int32_series(values, name: str = "y_int") -> np.ndarray:
    """`values` as a contiguous int32 series; ValueError naming the first sample that is not an integer or
    does not fit int32 (a plain cast would wrap 2^31 + 5 to −2^31 + 5, or truncate 0.5)."""
    arr = np.asarray(values)
    if arr.ndim != 1:
        raise ValueError(f"{name}: shape {arr.shape}, expected a 1-D series of int32 samples")
    if arr.size and arr.dtype.kind not in "iu":
        try:
            as_float = arr.astype(np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"{name}: not numeric (dtype {arr.dtype})") from None
        bad = ~(np.isfinite(as_float) & (as_float == np.round(as_float)))
        if bad.any():
            i = int(np.argmax(bad))
            raise ValueError(f"{name}: sample {i} is {arr[i]}, not an integer (use to_fixed() for values)")
        arr = as_float
    outside = (arr < INT32_MIN) | (arr > INT32_MAX)
    if np.any(outside):
        i = int(np.argmax(outside))
        raise ValueError(f"{name}: sample {i} is {arr[i]}, outside int32 [{INT32_MIN}, {INT32_MAX}] (use to_fixed() "
                         "to saturate values into the signal format)")
    return np.ascontiguousarray(arr, dtype=np.int32)


def _c_int(v: int) -> str:
    """An integer for a C #define (parenthesised when negative, so the macro expands safely)."""
    return f"({int(v)})" if v < 0 else str(int(v))


def _whole_within(value, name: str, bounds: tuple[int, int]) -> int:
    """`value` as a whole number within `bounds`, or an error naming `name`."""
    lo, hi = bounds
    whole = as_whole(value, name, INT32_MIN)
    if not lo <= whole <= hi:
        raise ValueError(f"{name}: {whole} outside {lo} … {hi}")
    return whole


def _quantize(values, frac_bits: int, name: str) -> np.ndarray:
    scaled = np.rint(np.asarray(values, dtype=np.float64) * 2.0 ** frac_bits)
    if np.any(scaled > INT32_MAX) or np.any(scaled < INT32_MIN):
        raise ValueError(f"{name}: does not fit int32 with {frac_bits} fraction bits")
    return scaled.astype(np.int64)


class FixedArKalman:
    """The ArKalman filter in int32 fixed point with 64-bit accumulators (see fixed_kalman.hpp).

    frac_bits: fraction bits of the signal format (y, state, prediction, innovation); None = derived from
    the first series filtered so that 2·G·max|y| fits (one guard bit), G = `signal_gain` (≥ 1: the
    worst-case ratio of the state, prediction and innovation to max|y| in the steady-state filter; for the
    time-varying filter the double filter's own values on the series count too). The signal format is a
    pure scale (value = int32 · 2^−frac_bits, no shift depends on it), so frac_bits may be above 31 or
    negative: a 1e-6-scale signal gets the same relative precision as a 1-scale one. coef_frac_bits (AR coefficients and gain) and
    cov_frac_bits (Q, R, P) default to values derived from the model: the largest of |a|, the
    steady-state |K| and 1, and the largest of P0, the steady-state prior covariance and q + r, each
    with one guard bit (two for the covariances: S = M00 + R). The filter takes and returns floats; inside everything is int32.
    `overflowed` is the sticky saturation flag of the last filter() call (also set when y itself does
    not fit the signal format)."""

    def __init__(self, ar_coeffs, q: float, r: float, frac_bits: int | None = None, steady_state: bool = False,
                 coef_frac_bits: int | None = None, cov_frac_bits: int | None = None,
                 initial_variance: float = 0.0):
        # The order before the double filter is set up (which takes up to MAX_ORDER, slowly).
        _order_within(_coefficients(ar_coeffs), _core.FIXED_MAX_ORDER, "fixed-point filter's")
        if frac_bits is not None:  # 2^frac_bits must be a double: -2000 or 5000 ended in an OverflowError
            frac_bits = _whole_within(frac_bits, "frac_bits", SIGNAL_FRAC_BITS_RANGE)
        self.double = ArKalman(ar_coeffs, q, r, initial_variance=initial_variance, steady_state=steady_state)
        self.steady_state = bool(steady_state)
        d = self.double
        if coef_frac_bits is None:
            biggest = max(1.0, float(np.max(np.abs(d.ar_coeffs))), float(np.max(np.abs(d.steady_gain))))
            coef_frac_bits = 30 - _int_bits(biggest)
        coef_frac_bits = _whole_within(coef_frac_bits, "coef_frac_bits", (0, 30))
        if cov_frac_bits is None:
            biggest = max(float(np.max(np.abs(d.initial_covariance))), float(np.max(np.abs(d.steady_prior_covariance))),
                          d.q + d.r)
            cov_frac_bits = 29 - math.ceil(math.log2(biggest))  # S = M00 + R may reach twice the largest
        # Like the signal's, the covariance format is a pure scale (no shift uses it); 2^bits must be a double.
        cov_frac_bits = _whole_within(cov_frac_bits, "cov_frac_bits", SIGNAL_FRAC_BITS_RANGE)
        self.coef_frac_bits, self.cov_frac_bits = int(coef_frac_bits), int(cov_frac_bits)
        self.frac_bits = None if frac_bits is None else int(frac_bits)
        self.a_int = _quantize(d.ar_coeffs, self.coef_frac_bits, "ar_coeffs")
        self.gain_int = _quantize(d.steady_gain, self.coef_frac_bits, "steady-state gain")
        self.q_int = int(_quantize(d.q, self.cov_frac_bits, "q"))
        self.r_int = int(_quantize(d.r, self.cov_frac_bits, "r"))
        p0 = d.initial_covariance
        try:
            self.p0_int = _quantize(p0, self.cov_frac_bits, "initial covariance")
        except ValueError:  # (a saved filter edited to a unit root: only "does not fit" had been said)
            a = np.asarray(d.ar_coeffs, dtype=float)
            companion = np.vstack([a, np.eye(a.size)[:-1]]) if a.size else np.zeros((1, 1))
            rho = float(np.max(np.abs(np.linalg.eigvals(companion))))
            fits = 29 - math.ceil(math.log2(float(np.max(np.abs(p0)))))
            raise ValueError(
                f"initial covariance: up to {float(np.max(np.abs(p0))):.3g}, does not fit int32 with {self.cov_frac_bits} "
                f"fraction bits (cov_frac_bits {fits} would hold it)"
                + (f"; the AR model is not stationary (companion spectral radius {rho:.4g} ≥ 1), so the filter starts "
                   "from 10 (q + r) instead of its stationary covariance: is the noise model right?" if rho >= 1.0
                   else "")) from None
        if not self.steady_state:  # the steady-state filter never uses Q, R or P
            self._check_noise_precision()
        self.signal_gain = signal_gain(d.ar_coeffs, d.steady_gain)
        self.overflowed = False
        self.result: dict | None = None

    def _check_noise_precision(self) -> None:
        """q (relative to itself: the gain goes as √(q/r) when q ≪ r) and r (relative to q + r: when r ≪ q the gain
        is near 1 whatever r is) must survive the covariance format within COV_PRECISION; 2 LSB of q put the
        output 9.5 % of its σ off the double filter, and still passed the bit-exact self-test."""
        d, lsb = self.double, 2.0 ** -self.cov_frac_bits
        cover = f"{self.cov_frac_bits} covariance fraction bits (the format also holds P0 and the covariances up " \
                f"to {2.0 ** (30 - self.cov_frac_bits):.3g})"
        remedy = "; use more cov_frac_bits, a smaller initial_variance or steady_state=True"
        if self.q_int <= 0:
            raise ValueError(f"q: {d.q} rounds to 0 with {cover}{remedy}")
        for name, value, held, scale in (("q", d.q, self.q_int, d.q), ("r", d.r, self.r_int, d.q + d.r)):
            error = abs(held * lsb - value)
            if error > COV_PRECISION * scale:
                raise ValueError(f"{name}: {value:.6g} is held as {held} LSB with {cover}, {error / scale:.2g} of "
                                 f"{'q' if name == 'q' else 'q + r'} off (at most {COV_PRECISION:g}){remedy}")

    @property
    def order(self) -> int:
        return self.double.order

    def input_reach(self) -> float:
        """The largest |input| the set signal format holds unsaturated: signal_frac_bits' rule inverted."""
        return 2.0 ** (31 - self.frac_bits) / (2.0 * self.signal_gain)

    def signal_frac_bits(self, y_max: float) -> int:
        """Signal fraction bits for inputs up to ±y_max: 2·signal_gain·y_max fits (one guard bit). They follow
        the signal's scale (beyond 31 for small signals, negative for large ones), so the relative precision
        does not depend on the units."""
        return _signal_frac_bits_holding(2.0 * self.signal_gain * float(y_max))

    def coefficients(self) -> dict:
        """The integer coefficient set (what the firmware and fluxcal.oracle.kalman.FixedModel take)."""
        if self.frac_bits is None:
            raise ValueError("frac_bits: not set yet (give it, or filter a series to derive it)")
        return {"a": [int(v) for v in self.a_int], "gain": [int(v) for v in self.gain_int], "q": self.q_int,
                "r": self.r_int, "p0": [int(v) for v in self.p0_int.ravel()], "signal_frac_bits": self.frac_bits,
                "coef_frac_bits": self.coef_frac_bits, "cov_frac_bits": self.cov_frac_bits,
                "steady_state": self.steady_state}

    def to_fixed(self, y) -> tuple[np.ndarray, bool]:
        """y in the signal format (round half to even, saturated) and whether any value saturated."""
        y = as_series(y, "y")
        if not np.all(np.isfinite(y)):  # a NaN cast to int32 is INT32_MIN: a reading, not a saturation
            raise ValueError(f"y: sample {int(np.argmax(~np.isfinite(y)))} is {y[~np.isfinite(y)][0]}, not a value "
                             "the signal format holds")
        if self.frac_bits is None:
            raise ValueError("frac_bits: not set yet (give it, or filter a series to derive it)")
        scaled = np.rint(y * 2.0 ** self.frac_bits)
        clipped = np.clip(scaled, INT32_MIN, INT32_MAX)
        return clipped.astype(np.int32), bool(np.any(clipped != scaled))

    def filter_int(self, y_int, checkpoint_every: int = 0, breaks=None) -> np.ndarray:
        """Filter a series already in the signal format (int32 in, int32 out). checkpoint_every > 0 also
        records the filter's whole state (x, K, P) before every checkpoint_every-th sample in
        self.result["checkpoint_state" / "checkpoint_gain" / "checkpoint_covariance"]. breaks: gaps in time
        (fluxcal.timeseries.find_breaks); the filter is reset before each, as firmware calls
        <name>_kalman_reset() after a gap."""
        y_int = _int32_series(y_int)
        self.result = self._run_int(y_int, checkpoint_every, as_breaks(breaks, y_int.size))
        self.overflowed = bool(self.result["overflowed"])
        return np.asarray(self.result["output"])

    def _run_int(self, y_int: np.ndarray, checkpoint_every: int = 0, breaks=()) -> dict:
        c = self.coefficients()
        return _core.fixed_kalman_filter(c["a"], c["gain"], c["q"], c["r"], c["p0"], c["signal_frac_bits"],
                                         c["coef_frac_bits"], c["cov_frac_bits"], c["steady_state"], y_int,
                                         int(checkpoint_every), list(breaks))

    def filter(self, y, breaks=None) -> np.ndarray:
        """Filtered output of every sample, as floats (the int32 outputs times 2^−frac_bits). breaks: see
        filter_int."""
        y = as_series(y, "y")
        if not np.all(np.isfinite(y)):
            raise ValueError(f"y: sample {int(np.argmax(~np.isfinite(y)))} is NaN/Inf")
        if self.frac_bits is None:
            y_max = float(np.max(np.abs(y))) if y.size else 0.0
            bits = self.signal_frac_bits(y_max)
            if not self.steady_state and y.size:  # the transient gains are not the steady ones: count the values
                d = ArKalman(self.double.ar_coeffs, self.double.q, self.double.r,
                             initial_variance=self.double.options.initial_variance)
                filtered = d.filter(y)
                e = d.result["innovations"]
                seen = max(float(np.max(np.abs(filtered))), float(np.max(np.abs(e))), float(np.max(np.abs(y - e))))
                bits = min(bits, _signal_frac_bits_holding(2.0 * seen))
            self.frac_bits = bits
        y_int, clipped = self.to_fixed(y)
        out = self.filter_int(y_int, breaks=breaks)
        self.overflowed = self.overflowed or clipped
        return out.astype(np.float64) * 2.0 ** -self.frac_bits

    def error_bound(self, y) -> float:
        """First-order bound on |fixed − double| of the steady-state filter's output on series y.

        With F = (I − K C) A the double recursion is x_k = F x_{k−1} + K y_k. The fixed filter runs the
        same recursion with quantised F̃, K̃, quantised y and per-step rounding ρ (the predicted x0, each
        K_i e and y: at most h = 2^−(frac_bits+1) each, |ρ|∞ ≤ h (2 + |K̃|∞)). Its error e_k therefore obeys
        e_k = F e_{k−1} + d_k with |d_k|∞ ≤ ‖F̃ − F‖∞ X + |K̃|∞ h + |K̃ − K|∞ Y + h (2 + |K̃|∞), X = max‖x_k‖∞
        (from the double run), Y = max|y|, so |e|∞ ≤ G · max|d| with G = Σ_k ‖F^k‖∞ (summed until the
        terms vanish; finite because F is stable). Second-order terms (‖F̃ − F‖ · |e|) are neglected.

        Returns math.inf when the fixed-point filter saturates on y (or y does not fit the signal format):
        a saturated filter can be off by any amount, so there is no finite bound."""
        if self.frac_bits is None:
            raise ValueError("frac_bits: not set yet")
        if not self.steady_state:  # the bound models the constant gain K; the time-varying filter's gains differ
            raise ValueError("error_bound: holds for the steady-state filter only (steady_state=True); the "
                             "time-varying filter's fixed-point gains and covariances are not covered by it")
        y = as_series(y, "y")
        if not np.all(np.isfinite(y)):
            raise ValueError(f"y: sample {int(np.argmax(~np.isfinite(y)))} is NaN/Inf")
        y_int, clipped = self.to_fixed(y)
        if clipped or self._run_int(y_int)["overflowed"]:
            return math.inf
        d = self.double
        n = d.order
        a_q = self.a_int / 2.0 ** self.coef_frac_bits
        k_q = self.gain_int / 2.0 ** self.coef_frac_bits

        def closed_loop(a, k):
            comp = np.zeros((n, n))
            comp[0] = a
            comp[np.arange(1, n), np.arange(n - 1)] = 1.0
            return (np.eye(n) - np.outer(k, np.eye(n)[0])) @ comp

        f, f_q = closed_loop(d.ar_coeffs, d.steady_gain), closed_loop(a_q, k_q)
        g, power = 0.0, np.eye(n)
        for _ in range(100000):
            term = np.abs(power).sum(axis=1).max()
            g += term
            if term < 1e-12:
                break
            power = f @ power
        steady = ArKalman(d.ar_coeffs, d.q, d.r, steady_state=True)
        steady.filter(y)
        x_max = float(np.max(np.abs(steady.result["filtered"]))) if y.size else 0.0
        # The state holds delayed filtered outputs, so max‖x‖∞ = max|C x|; a little slack for the final state.
        x_max = max(x_max, float(np.max(np.abs(steady.result["state"]))))
        h = 2.0 ** -(self.frac_bits + 1)
        k_inf = float(np.max(np.abs(k_q)))
        d_max = (np.abs(f_q - f).sum(axis=1).max() * x_max + k_inf * h
                 + float(np.max(np.abs(k_q - d.steady_gain))) * float(np.max(np.abs(y))) + h * (2.0 + k_inf))
        return float(g * d_max)

    def export_header(self, path, name: str = "fluxcal_ar_kalman") -> Path:
        """Write the integer coefficients as a C header (include it next to fixed_kalman.hpp or any C
        implementation of the same arithmetic)."""
        c = self.coefficients()
        up = name.upper()
        n = self.order

        def arr(values):
            return "{" + ", ".join(f"{int(v)}" for v in values) + "}"

        lines = [
            f"/* {name}: fixed-point AR({n}) Kalman filter coefficients, written by fluxcal.",
            f" * AR coefficients (double): {', '.join(f'{v:.17g}' for v in self.double.ar_coeffs)}",
            f" * q = {self.double.q:.17g}, r = {self.double.r:.17g}",
            " * Formats: value = integer * 2^-frac_bits; arithmetic as cpp/include/fluxcal/fixed_kalman.hpp. */",
            f"#ifndef {up}_H", f"#define {up}_H", "#include <stdint.h>",
            f"#define {up}_ORDER {n}",
            # Signal and covariance formats are pure scales: their fraction bits may be > 31 or negative.
            f"#define {up}_SIGNAL_FRAC_BITS {_c_int(c['signal_frac_bits'])} /* {signal_format(c['signal_frac_bits'])} */",
            f"#define {up}_COEF_FRAC_BITS {c['coef_frac_bits']}",
            f"#define {up}_COV_FRAC_BITS {_c_int(c['cov_frac_bits'])}",
            f"#define {up}_STEADY_STATE {1 if c['steady_state'] else 0}",
            f"static const int32_t {name}_a[{n}] = {arr(c['a'])};",
            f"static const int32_t {name}_gain[{n}] = {arr(c['gain'])};",
            f"static const int32_t {name}_q = {c['q']};",
            f"static const int32_t {name}_r = {c['r']};",
            f"static const int32_t {name}_p0[{n * n}] = {arr(c['p0'])}; /* row-major */",
            f"#endif /* {up}_H */", ""]
        path = Path(path)
        path.write_text("\n".join(lines))
        return path
