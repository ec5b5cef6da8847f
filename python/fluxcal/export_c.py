"""Firmware export: a calibration as a C header, in float and in int32 Q-format fixed point.

    from fluxcal.export_c import export_c
    result = export_c(cal, "magcal.h", q_format=None, name="magcal", kalman="drift.json")
    print(result.describe())

The header (C99, also valid C++) holds the offset b and matrix A in float and in fixed point, a static
inline correction h = A (m − b) for each, a test vector (inputs and fluxcal's double-precision outputs)
and `<name>_self_test()`, so firmware can check itself. Fixed point:

* Signal format Qm.n (int32: a sign bit, m integer and n fraction bits, m + n = 31) for the readings m and
  the offset b; the output h has its own, Qp.q, the most fraction bits that hold every output (counts corrected
  to tesla in the readings' Q16.15 had an LSB of 30 µT against a 48 µT field: a blind check). Matrix entries
  have their own fraction bits na, chosen so that |a_ij| ≤ 2^30 · 2^-na: three products of an int32
  difference sum exactly in int64.
* Arithmetic: d = m − b in int64 saturated to int32; acc = Σ a_ij d_j exact in int64 (scale 2^-(na+n));
  h_i = acc / 2^(na + n − q) rounded to nearest, ties away from zero, saturated to int32; the function
  returns 1 if anything saturated (values never wrap). Constants are rounded to nearest.
* Stated input range |m_j| ≤ R: R = 2 × the readings' extent (max_i |b_i| + F ‖row i of A⁻¹‖, the largest
  component of a reading of the calibration's field magnitude F), so that fields up to twice the
  calibration field still fit, reduced if needed so that neither d nor h can saturate in the format. With
  `input_range` (`--input-range`, the sensor's full scale, e.g. 32768 counts) R is that, and a format that
  cannot hold it is refused: the readings that reach the rails are the ones a fixed-point overflow hurts.
* Default format: the smallest m for which inputs of ±R and the differences d fit, and an output format
  that holds every output for such inputs (max_i Σ_j |a_ij| (R + |b_j|)) — all remaining bits are fraction bits.
* Error bound, for every input in the range: |h_fixed − A (m − b)| ≤ E per component,
  E = max_i [2^-(q+1) + 2^-(n+1) Σ_j |a_ij| + 2^-(na+1) Σ_j (R + |b̃_j|)] — rounding of the output, of b and
  of A; exact arithmetic otherwise, so E is a bound, not an estimate.
* Float: b is held as two floats, b_hi + b_lo, and d = (m − b_hi) − b_lo: one float b loses |b| 2^-24, which
  an offset 15 times the field made larger than the float path's own tolerance (a blind check's self-test
  failed 30 components of a correct calibration).

With `kalman` (a JSON saved by `save_kalman`, or a drift model from `fluxcal drift fit`) the header also
carries the fixed-point AR Kalman coefficients (`FixedArKalman.export_header`), the filter itself in C99
(`<name>_kalman_reset`, `<name>_kalman_step`: the arithmetic of cpp/include/fluxcal/fixed_kalman.hpp, for
firmware without C++), and a test vector of int32 inputs and the outputs of `FixedArKalman.filter_int`
that both must reproduce bit for bit (`<name>_kalman_self_test()`).
"""
from __future__ import annotations

import copy
import hashlib
import json
import math
import re
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._arrays import as_number
from ._saved import load_json_object
from .calibration import Calibration
from .kalman import signal_format
from .timeseries import GAP_STEPS
from .planar import offset_moved

INT32_MIN, INT32_MAX = -(2 ** 31), 2 ** 31 - 1
FLOAT_RELATIVE_TOLERANCE = 1e-6  # float32 result vs double: relative to max(|h|∞, field norm)
RANGE_MARGIN = 2.0               # the stated input range is this many times the readings' extent
RANGE_LSB_SHARE = 16.0           # a Kalman filter's LSB under its input's σ over this (rounding adds 0.02 σ)
# The fixed-point error bound E is said when it exceeds the calibration's own residual RMS (|h| − F: the noise and
# model error h already has; below it the format does not limit h), held within these shares of the field F: a
# noise-free simulation's residual of 1e-14 is no line, nor a failed fit's several %. Without a residual (a hand-made
# or multi-position calibration): PRECISION_SHARE of F, 1 mrad of heading.
PRECISION_SHARE, PRECISION_SHARE_RANGE = 1e-3, (1e-6, 1e-2)
KALMAN_KIND = "fluxcal fixed AR Kalman"


@dataclass(frozen=True)
class QFormat:
    """int32 Qm.n: value = integer · 2^-n; a sign bit, m integer bits and n fraction bits (m + n = 31)."""

    int_bits: int
    frac_bits: int

    @classmethod
    def parse(cls, text: str) -> "QFormat":
        match = re.fullmatch(r"\s*[Qq](\d+)\.(\d+)\s*", str(text))
        if not match:
            raise ValueError(f"--q-format: {text!r} is not Qm.n (e.g. Q12.19)")
        m, n = int(match.group(1)), int(match.group(2))
        if m + n != 31:
            raise ValueError(f"--q-format: {text}: an int32 has a sign bit and 31 more, so m + n must be 31 "
                             f"(e.g. Q{min(m, 31)}.{31 - min(m, 31)})")
        return cls(m, n)

    @property
    def lsb(self) -> float:
        return 2.0 ** -self.frac_bits

    @property
    def max_value(self) -> float:
        return 2.0 ** self.int_bits - self.lsb

    def __str__(self) -> str:
        return f"Q{self.int_bits}.{self.frac_bits}"


def reading_extent(cal: Calibration) -> float:
    """The largest |component| of a reading of a field of the calibration's magnitude: max_i |b_i| + F ‖W_i‖; for a
    planar calibration at least its readings' own (summary["readings_extent"]): F is the horizontal field there, and
    the axis passed through reads the vertical one (44–60 µT beside H 14–20 at high latitudes), which the model
    does not know."""
    w = cal.forward_matrix
    extent = float(np.max(np.abs(cal.offset) + cal.field_norm * np.linalg.norm(w, axis=1)))
    return max(extent, float(cal.summary.get("readings_extent", 0.0) or 0.0))


def _output_range(a: np.ndarray, b: np.ndarray, r: float) -> float:
    """max |h_i| over inputs |m_j| ≤ r."""
    return float(np.max(np.abs(a) @ (r + np.abs(b))))


@dataclass
class FixedCalibration:
    """The fixed-point form of a calibration (module docstring for the rules)."""

    calibration: Calibration
    fmt: QFormat          # of the readings m and the offset b
    matrix_frac_bits: int
    offset_q: np.ndarray  # int64 (3,), signal format
    matrix_q: np.ndarray  # int64 (3, 3), 2^-matrix_frac_bits
    input_range_q: int    # |m_j| ≤ input_range_q (signal format) is the stated range
    error_bound: float    # per component, in the calibration's units
    range_note: str
    out_fmt: QFormat      # of the output h

    @property
    def output_shift(self) -> int:
        """acc (2^-(na + n)) to h (2^-q): shifted right by na + n − q."""
        return self.matrix_frac_bits + self.fmt.frac_bits - self.out_fmt.frac_bits

    @property
    def input_range(self) -> float:
        return self.input_range_q * self.fmt.lsb

    @property
    def error_bound_lsb(self) -> float:
        """error_bound in the output's LSB."""
        return self.error_bound / self.out_fmt.lsb

    @property
    def reading_error_bound(self) -> float:
        """The error bound for a real reading r rounded into the format (round(r·2^n)): error_bound holds against
        A (m − b) of the rounded m; against A (r − b) the rounding adds up to 2^−(n+1) Σ_j |a_ij| (a blind check
        measured 1.60 against E = 1.26 at Q31.0)."""
        return self.error_bound + self.fmt.lsb / 2 * float(np.max(np.abs(self.calibration.matrix).sum(axis=1)))

    def to_fixed(self, m) -> np.ndarray:
        """Readings in the signal format: round to nearest, saturate to int32."""
        scaled = np.rint(np.asarray(m, dtype=float) * 2.0 ** self.fmt.frac_bits)
        return np.clip(scaled, INT32_MIN, INT32_MAX).astype(np.int64)

    def apply_int(self, m_q) -> tuple[np.ndarray, bool]:
        """The firmware's fixed-point correction, bit for bit (N×3 int in, N×3 int out in out_fmt, saturated?)."""
        m_q = np.atleast_2d(np.asarray(m_q, dtype=np.int64))
        raw_d = m_q - self.offset_q
        d = np.clip(raw_d, INT32_MIN, INT32_MAX)
        saturated = bool(np.any(d != raw_d))
        shift = self.output_shift
        h = []
        for row in d.tolist():  # Python integers: exact like the firmware's int64
            out = []
            for i in range(3):
                acc = sum(int(self.matrix_q[i, j]) * row[j] for j in range(3))
                half = 1 << (shift - 1)
                acc = (acc + half) >> shift if acc >= 0 else -((-acc + half) >> shift)
                saturated |= not INT32_MIN <= acc <= INT32_MAX
                out.append(min(max(acc, INT32_MIN), INT32_MAX))
            h.append(out)
        return np.array(h, dtype=np.int64), saturated


def _matrix_frac_bits(a: np.ndarray) -> int:
    biggest = float(np.max(np.abs(a)))
    if not biggest > 0:
        raise ValueError("calibration: the matrix is zero")
    bits = 30 - math.ceil(math.log2(biggest))
    if bits < 1:
        raise ValueError(f"calibration: matrix entries up to {biggest:.6g} do not fit an int32 with a fraction bit "
                         "(the readings in a far smaller unit than h's: state the readings' unit, or calibrate to a "
                         "field norm in theirs)")
    return min(bits, 61)  # 61: the rounding add (acc + 2^(na-1)) stays inside int64


def _error_bound(a, b_q, fmt: QFormat, out: QFormat, na: int, r: float) -> float:
    rows = out.lsb / 2 + fmt.lsb / 2 * np.abs(a).sum(axis=1) + 2.0 ** -(na + 1) * np.sum(r + np.abs(b_q))
    return float(np.max(rows))


def _output_format(a, b, fmt: QFormat, na: int, r: float) -> QFormat | None:
    """The int32 Q format of h with the most fraction bits that holds every output for inputs |m| ≤ r (with its
    rounding error), at least one bit below the product's 2^-(na + n) to round by, and no more than 62 above
    (an int64 shift); None: none does."""
    top = _output_range(a, b, r)
    for m in range(32):
        out = QFormat(m, 31 - m)
        shift = na + fmt.frac_bits - out.frac_bits
        if 1 <= shift <= 62 and top + _error_bound(a, b, fmt, out, na, r) <= out.max_value:
            return out
    return None


def _fits(a, b, fmt: QFormat, na: int, r: float) -> bool:
    """Inputs |m| ≤ r: the differences d fit the format, and the outputs (with their rounding error) an output one."""
    return r + float(np.max(np.abs(b))) <= fmt.max_value and _output_format(a, b, fmt, na, r) is not None


def _smallest_format(a, b, na: int, r: float) -> QFormat | None:
    """The int32 Q format with the fewest integer bits that holds inputs |m| ≤ r (None: none does)."""
    return next((QFormat(m, 31 - m) for m in range(32) if _fits(a, b, QFormat(m, 31 - m), na, r)), None)


def fixed_point(cal: Calibration, q_format: str | QFormat | None = None,
                input_range: float | None = None) -> FixedCalibration:
    """Quantise `cal` (module docstring: format choice, range and bound). `input_range`: the sensor's full
    scale in the calibration's units (e.g. 32768 counts, 8 G); every reading up to it must then be corrected
    without saturating, instead of the default 2 × the calibration readings' extent."""
    a, b = cal.matrix, cal.offset
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b)) and np.isfinite(cal.field_norm)):
        raise ValueError("calibration: offset, matrix and field norm must be finite")
    na = _matrix_frac_bits(a)
    extent = reading_extent(cal)
    units = f" {cal.units}".rstrip()
    if q_format is not None and not isinstance(q_format, QFormat):
        q_format = QFormat.parse(q_format)
    if input_range is not None:
        r = as_number(input_range, "input_range")
        if not (math.isfinite(r) and r > 0):
            raise ValueError(f"--input-range {input_range}: must be a positive number (the sensor's full scale)")
        if r < extent:  # a reading of the calibration field itself would be out of range
            raise ValueError(f"--input-range {r:.6g}{units}: smaller than the calibration readings' extent "
                             f"{extent:.6g}{units} (a reading of the calibration field reaches it); give the "
                             "sensor's full scale in the calibration's units")
        fmt = _smallest_format(a, b, na, r) if q_format is None else q_format
        if fmt is None or not _fits(a, b, fmt, na, r):
            smallest = _smallest_format(a, b, na, r)
            raise ValueError((f"--q-format {fmt}: " if fmt is not None else "") +
                             f"readings up to the input range ±{r:.6g}{units} per axis, and their corrections "
                             f"(up to ±{_output_range(a, b, r):.6g} at the box's worst corner), do not fit " +
                             (f"the format's ±{fmt.max_value:.6g}; use at least {smallest}" if smallest else
                              "any int32 Q format"))
        note = f"the sensor's full scale (--input-range), {r / extent:.3g} x the readings' extent {extent:.6g}{units}"
    elif q_format is None:
        wanted = RANGE_MARGIN * extent
        fmt = _smallest_format(a, b, na, wanted)
        if fmt is None:
            raise ValueError(f"calibration: readings up to {wanted:.6g} {cal.units} do not fit any int32 Q format")
        r, note = wanted, f"{RANGE_MARGIN:g} x the readings' extent {extent:.6g} {cal.units}".rstrip()
    else:
        wanted = RANGE_MARGIN * extent
        fmt = q_format
        if not _fits(a, b, fmt, na, extent):
            smallest = _smallest_format(a, b, na, extent)
            raise ValueError(f"--q-format {fmt}: readings of the calibration field reach ±{extent:.6g} {cal.units} "
                             f"per axis, and a reading in that box corrects to up to ±{_output_range(a, b, extent):.6g} "
                             f"(its worst corner): beyond the format's ±{fmt.max_value:.6g}; use at least {smallest}")
        lo, hi = extent, wanted  # the largest range up to `wanted` that fits: bisection (both sides monotone)
        if _fits(a, b, fmt, na, hi):
            lo = hi
        for _ in range(60):
            mid = (lo + hi) / 2
            lo, hi = (mid, hi) if _fits(a, b, fmt, na, mid) else (lo, mid)
        r = lo
        note = (f"{RANGE_MARGIN:g} x the readings' extent {extent:.6g} {cal.units}".rstrip() if r == wanted else
                f"{r / extent:.3g} x the readings' extent {extent:.6g} {cal.units} ({fmt} holds no more "
                f"without saturating)")
    offset_q = np.rint(b * 2.0 ** fmt.frac_bits).astype(np.int64)
    matrix_q = np.rint(a * 2.0 ** na).astype(np.int64)
    range_q = int(math.floor(r * 2.0 ** fmt.frac_bits))
    out = _output_format(a, offset_q * fmt.lsb, fmt, na, range_q * fmt.lsb) or _output_format(a, b, fmt, na, r)
    bound = _error_bound(a, offset_q * fmt.lsb, fmt, out, na, range_q * fmt.lsb)
    return FixedCalibration(cal, fmt, na, offset_q, matrix_q, range_q, bound, note, out)


def vector_inputs(fx: FixedCalibration, seed: int = 0) -> np.ndarray:
    """Test readings on the signal grid (int64 N×3): the calibration field from 14 directions, the 8
    corners of the stated range, 6 random points in it, the offset (h = 0) and zero; a biaxial sensor's absent
    axis 0 in each (repeats left out)."""
    cal = fx.calibration
    axes = np.vstack([np.eye(3), -np.eye(3)])
    diagonals = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) / np.sqrt(3.0)
    on_sphere = cal.reading(cal.field_norm * np.vstack([axes, diagonals]))
    r = fx.input_range
    corners = r * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    random = np.random.default_rng(seed).uniform(-r, r, (6, 3))
    m = np.vstack([on_sphere, corners, random, cal.offset, np.zeros(3)])
    if cal.summary.get("biaxial"):  # its absent axis reads 0 on the firmware (as the header says): tested so
        m[:, "xyz".index(cal.summary["not_calibrated"]["axis"])] = 0.0
        m = m[np.sort(np.unique(m, axis=0, return_index=True)[1])]
    return np.clip(fx.to_fixed(m), -fx.input_range_q, fx.input_range_q)


# -- Kalman filter coefficients ----------------------------------------------------------------------------

def save_kalman(f, path) -> Path:
    """Save a FixedArKalman's settings as JSON (what `export_c(kalman=...)` and `--kalman` read)."""
    d = f.double
    data = {"kind": KALMAN_KIND, "ar_coeffs": d.ar_coeffs.tolist(), "q": d.q, "r": d.r,
            "steady_state": f.steady_state, "initial_variance": float(d.options.initial_variance),
            "frac_bits": f.frac_bits, "coef_frac_bits": f.coef_frac_bits, "cov_frac_bits": f.cov_frac_bits}
    path = Path(path)
    path.write_text(json.dumps(data, indent=2) + "\n")
    return path


def load_kalman(path):
    """A FixedArKalman from a JSON of `save_kalman` or a drift model of `fluxcal drift fit` (its AR model and
    Kalman q, r). Without stated signal fraction bits they follow FixedArKalman's own rule
    (`FixedArKalman.signal_frac_bits`: 2·G·max|y| fits, G the filter's signal gain) with max|y| = 8 σ_y,
    σ_y² = the AR process's stationary variance + r. A drift model's AR model is that of the noise about
    the drift ("fitted_to": "zero_bias - drift"), so the firmware filter takes the compensated zero bias
    W − f(T), and the format is sized for it (models saved before that have no "fitted_to": their AR
    model is of the zero-mean zero bias, drift included). A drift model whose noise about the drift is
    white has no filter ("kalman": null): ValueError saying so."""
    from .kalman import FixedArKalman

    path = Path(path)
    data = load_json_object(path, "a saved FixedArKalman or drift model")
    try:
        if data.get("kind") == KALMAN_KIND:
            settings = dict(ar_coeffs=data["ar_coeffs"], q=data["q"], r=data["r"],
                            steady_state=bool(data.get("steady_state", False)),
                            initial_variance=float(data.get("initial_variance", 0.0)),
                            coef_frac_bits=data.get("coef_frac_bits"), cov_frac_bits=data.get("cov_frac_bits"))
            frac_bits = data.get("frac_bits")
        elif data.get("kind") == "fluxcal drift model" and data.get("kalman", 0) is None:
            # fit_pipeline found the noise about the drift white (AR order 0): there is no filter. A pass-through
            # would output W − f(T) unfiltered, not the pipeline's L (whose noise estimate is 0), and a filter
            # that outputs 0 is not one: refuse, saying what the firmware does instead.
            raise ValueError(f"{path}: this drift model has no Kalman filter to export: the noise about its drift is "
                             "white (AR order 0), so the compensation is W - f(T) alone (fluxcal drift apply; "
                             "export-c without --kalman)")
        elif data.get("kind") == "fluxcal drift model" and "ar" in data and "kalman" in data:
            settings = dict(ar_coeffs=data["ar"]["coefficients"], q=data["kalman"]["q"], r=data["kalman"]["r"],
                            steady_state=bool(data["kalman"].get("steady_state", False)))
            frac_bits = None
        else:
            raise ValueError(f"{path}: neither a saved FixedArKalman (kind {KALMAN_KIND!r}) nor a drift model with "
                             "'ar' and 'kalman' sections (fluxcal drift fit)")
        try:
            f = FixedArKalman(**settings, frac_bits=frac_bits)
        except ValueError as exc:  # (the filter's own check, "ar_coeffs: NaN/Inf", had not named the file)
            raise ValueError(f"{path}: {exc}") from None
    except (KeyError, TypeError) as exc:
        raise ValueError(f"{path}: malformed Kalman settings (missing or wrong {exc})") from None
    # A non-stationary AR model: ArKalman starts from 10 (q + r) in place of the stationary covariance, so σ stays
    # finite and the check below it never fired; a drift model's coefficients edited to [2, -0.5, 0.1] (root 1.75)
    # were exported silently, and that filter amplified the device's noise (std 0.057 against 0.051: a blind check).
    # A drift model's AR model is of the noise about the drift, stationary by construction: refused whatever the
    # format. A saved filter with frac_bits stated may be a deliberate random walk (a1 = 1): only its format's
    # rule, 8 σ of the stationary noise, has no meaning without them.
    rho = float(f.double.spectral_radius)
    drift_model = data.get("kind") == "fluxcal drift model"
    if not rho < 1.0 and (drift_model or f.frac_bits is None):
        field_name = "ar.coefficients" if drift_model else "ar_coeffs"
        coefficients = ", ".join(f"{a:.6g}" for a in f.double.ar_coeffs)
        raise ValueError(
            f"{path}: {field_name} [{coefficients}]: the AR model is not stationary (a root of magnitude {rho:.4g} "
            "≥ 1): its noise would grow without bound, and a Kalman filter on it amplifies the noise instead of "
            "smoothing it" + ("; the noise about a drift is stationary: the file was edited or damaged, or the fit "
                              "left a trend in that noise — fit the drift model again (fluxcal drift fit)"
                              if drift_model else "; give frac_bits explicitly if a random walk is meant"))
    if f.frac_bits is None:
        sigma = _input_sigma(f)
        if not math.isfinite(sigma):
            raise ValueError(f"{path}: the AR model is not stationary; give frac_bits explicitly")
        f.frac_bits = f.signal_frac_bits(8.0 * sigma)
    return f


def _input_sigma(f) -> float:
    """The σ of a FixedArKalman's input: √(the AR process's stationary variance + r)."""
    return math.sqrt(float(f.double.initial_covariance[0, 0]) + f.double.r)


def _kalman_range_warnings(f, kalman_range) -> list:
    """What a --kalman-range does to the filter of its input's own noise: an LSB coarse beside its σ (1e9 in place
    of 1: every output 0), or a reach below 3 σ (5998 of 6000 samples saturated) — both compiled and passed the
    self-test, whose vector is the same integers at every scale."""
    sigma, lsb, reach = _input_sigma(f), 2.0 ** -f.frac_bits, f.input_reach()
    if not math.isfinite(sigma) or not sigma > 0:
        return []
    # (a saved filter's own format is judged alike: frac_bits 40 beside a noise σ of 0.02 saturated every sample)
    given = (f"--kalman-range {kalman_range:g}" if kalman_range is not None else
             f"the filter's signal format 2^-{f.frac_bits} (its JSON's)")
    if lsb > sigma / RANGE_LSB_SHARE:
        return [f"{given}: the filter's LSB 2^{-f.frac_bits} = {lsb:.3g} is {lsb / sigma:.2g} times "
                f"its input's σ {sigma:.3g} (its own model's noise): the output loses that precision. Give the "
                "largest |input| in the model's unit with --kalman-range (default 8 σ)"]
    if reach < 3.0 * sigma:
        return [f"{given}: inputs past ±{reach:.3g} saturate, {reach / sigma:.2g} σ of its "
                f"input's own noise (σ {sigma:.3g}): most samples will. Give the largest |input| in the model's unit "
                "with --kalman-range (default 8 σ)"]
    return []


# The filter of cpp/include/fluxcal/fixed_kalman.hpp in C99 (also valid C++), for firmware without C++: the same
# operations in the same order, so it reproduces FixedArKalman.filter_int bit for bit. KNAME/KUP are replaced by
# the filter's name. C99 leaves a right shift of a negative value to the implementation, so the floor shift
# only ever shifts non-negative values (~v ≥ 0 when v < 0): the same bits as an arithmetic shift, on any compiler.
_KALMAN_C = """
/* The filter state: KNAME_reset() starts it, KNAME_step() filters one sample. overflow is sticky (set when
 * anything saturated; outputs are clamped, never wrapped) until the caller clears it. */
typedef struct {
  int32_t x[KUP_ORDER];
  int32_t k[KUP_ORDER];
  int32_t p[KUP_ORDER][KUP_ORDER];
  int overflow;
} KNAME_t;

static inline int32_t KNAME_sat32_(int64_t v, int *of) {
  if (v > INT32_MAX) { *of = 1; return INT32_MAX; }
  if (v < INT32_MIN) { *of = 1; return INT32_MIN; }
  return (int32_t)v;
}
static inline int64_t KNAME_add64_(int64_t a, int64_t b, int *of) {
  if ((b > 0 && a > INT64_MAX - b) || (b < 0 && a < INT64_MIN - b)) { *of = 1; return b > 0 ? INT64_MAX : INT64_MIN; }
  return a + b;
}
static inline int64_t KNAME_mul_(int32_t a, int32_t b) { return (int64_t)a * (int64_t)b; }
/* floor(v / 2^s), shifting only non-negative values (portable C99) */
static inline int64_t KNAME_floor_shift_(int64_t v, int s) { return v >= 0 ? v >> s : ~(~v >> s); }
/* floor((v + 2^(s-1)) / 2^s): round half up */
static inline int64_t KNAME_shift_(int64_t v, int s, int *of) {
  return s == 0 ? v : KNAME_floor_shift_(KNAME_add64_(v, (int64_t)1 << (s - 1), of), s);
}
/* num / den to nearest, ties away from zero; den > 0 */
static inline int64_t KNAME_div_(int64_t num, int64_t den) {
  const int64_t mag = (2 * (num < 0 ? -num : num) + den) / (2 * den);
  return num < 0 ? -mag : mag;
}

/* State to zero, covariance to P0, gain to the steady-state gain; overflow cleared. */
static inline void KNAME_reset(KNAME_t *f) {
  int i, j;
  for (i = 0; i < KUP_ORDER; ++i) {
    f->x[i] = 0;
    f->k[i] = KNAME_gain[i];
    for (j = 0; j < KUP_ORDER; ++j) f->p[i][j] = KNAME_p0[i * KUP_ORDER + j];
  }
  f->overflow = 0;
}

/* One sample y (signal format) in, the filtered output (signal format) out. */
static inline int32_t KNAME_step(KNAME_t *f, int32_t y) {
  const int n = KUP_ORDER, cf = KUP_COEF_FRAC_BITS;
  int *of = &f->overflow;
  int64_t acc = 0;
  int32_t x0, e;
  int i, j;
  for (i = 0; i < n; ++i) acc = KNAME_add64_(acc, KNAME_mul_(KNAME_a[i], f->x[i]), of);
  x0 = KNAME_sat32_(KNAME_shift_(acc, cf, of), of);
  for (i = n - 1; i > 0; --i) f->x[i] = f->x[i - 1];
  f->x[0] = x0;
  if (!KUP_STEADY_STATE) {
    int32_t u[KUP_ORDER], t[KUP_ORDER], m[KUP_ORDER][KUP_ORDER], s;
    int64_t s00 = 0;
    /* predict the covariance: M = A P A' + Q e1 e1' (companion A, u = P a) */
    for (j = 0; j < n; ++j) {
      int64_t v = 0;
      for (i = 0; i < n; ++i) v = KNAME_add64_(v, KNAME_mul_(f->p[j][i], KNAME_a[i]), of);
      u[j] = KNAME_sat32_(KNAME_shift_(v, cf, of), of);
    }
    for (i = 0; i < n; ++i) s00 = KNAME_add64_(s00, KNAME_mul_(KNAME_a[i], u[i]), of);
    for (i = n - 1; i > 0; --i)
      for (j = n - 1; j > 0; --j) m[i][j] = f->p[i - 1][j - 1];
    m[0][0] = KNAME_sat32_(KNAME_add64_(KNAME_shift_(s00, cf, of), KNAME_q, of), of);
    for (j = 1; j < n; ++j) m[0][j] = m[j][0] = u[j - 1];
    /* gain: one division per entry */
    s = KNAME_sat32_((int64_t)m[0][0] + KNAME_r, of);
    if (s <= 0) {
      *of = 1;
      for (i = 0; i < n; ++i) f->k[i] = 0;
    } else {
      for (i = 0; i < n; ++i) f->k[i] = KNAME_sat32_(KNAME_div_((int64_t)m[i][0] * ((int64_t)1 << cf), s), of);
    }
    /* Joseph form for C = e1': P = M - K m0' - m0 K' + S K K' */
    for (i = 0; i < n; ++i) t[i] = KNAME_sat32_(KNAME_shift_(KNAME_mul_(s, f->k[i]), cf, of), of);
    for (j = 0; j < n; ++j) {
      for (i = j; i < n; ++i) {
        int64_t v = (int64_t)m[i][j] * ((int64_t)1 << cf);
        v = KNAME_add64_(v, -KNAME_mul_(f->k[i], m[j][0]), of);
        v = KNAME_add64_(v, -KNAME_mul_(m[i][0], f->k[j]), of);
        v = KNAME_add64_(v, KNAME_mul_(t[i], f->k[j]), of);
        f->p[i][j] = f->p[j][i] = KNAME_sat32_(KNAME_shift_(v, cf, of), of);
      }
    }
  }
  if (y == INT32_MAX || y == INT32_MIN) *of = 1;  /* a saturated conversion of the input */
  e = KNAME_sat32_((int64_t)y - f->x[0], of);
  for (i = 0; i < n; ++i)
    f->x[i] = KNAME_sat32_(KNAME_add64_(f->x[i], KNAME_shift_(KNAME_mul_(f->k[i], e), cf, of), of), of);
  return f->x[0];
}

/* Runs the test vector: the number of outputs that differ from fluxcal's (0 = pass; an overflow counts one). */
static inline int KNAME_self_test(void) {
  KNAME_t f;
  int k, misses = 0;
  KNAME_reset(&f);
  for (k = 0; k < KUP_TEST_COUNT; ++k) misses += KNAME_step(&f, KNAME_test_input[k]) != KNAME_test_output[k];
  return misses + f.overflow;
}
"""


def _drift_part(drift, name: str):
    """The header lines of the drift f(T) of a DriftModel (or its JSON path) in double, with a test vector of
    temperatures across every range and the model's own values there; and the model."""
    from .drift import EDGE_MARGIN, DriftModel, range_index

    model = DriftModel.load(drift) if isinstance(drift, (str, Path)) else drift
    if not isinstance(model, DriftModel):
        raise TypeError(f"drift: expected a DriftModel or the path of its JSON, got {type(drift).__name__}")
    dname, dup = f"{name}_drift", f"{name}_drift".upper()
    segments = model.segments
    edges = [float(segments[0]["range"][0])] + [float(seg["range"][1]) for seg in segments]
    top = max(int(seg["order"]) for seg in segments)
    coefficients = [list(map(float, seg["coefficients"])) + [0.0] * (top - int(seg["order"])) for seg in segments]
    # each range at its edges, a quarter and three quarters in; the inside-outside difference varies with it
    temps = np.concatenate([np.linspace(lo, hi, 5) for lo, hi in zip(edges[:-1], edges[1:])])
    # the difference's fitted range per range (DriftModel.beyond_differences): the function refuses beyond it too
    seen = model.difference_ranges
    if seen:  # each test temperature's x within what its own range saw (an edge belongs to the range above it)
        bounds = np.array(seen, dtype=float)[range_index(segments, temps)]
        outside = temps - (bounds[:, 0] + np.tile(np.linspace(0.0, 1.0, 5), len(segments)) * np.ptp(bounds, axis=1))
    else:
        outside = temps - np.linspace(-5.0, 15.0, temps.size)
    expected = model.evaluate(temps, outside if model.regressor == "difference" else None)
    d = lambda v: f"{v:.17g}"  # noqa: E731  (round-trips a double)
    x = "temp" if model.regressor == "temp" else "temp - temp_outside"
    lines = [
        "/* ---- Temperature drift of the zero bias (fluxcal drift fit) ----",
        f" * f = sum_i c_i x^i with x = {x} (degrees C), the polynomial of the range that holds the device",
        " * temperature temp: lo <= temp < hi (the last range includes its hi). Compensated: W_c = W - f.",
        (" * The same model's Kalman filter (--kalman) runs on W_c, the noise about the drift, in its signal format."
         if model.settings.get("kalman") is not None else
         " * The noise about this drift is white (AR order 0): there is no Kalman filter, W_c is the output."),
        f" * {dname}(temp, temp_outside, &f) returns 0, or 1 when temp is outside every range"
        + (" or temp - temp_outside outside what its range was fitted over" if seen else "")
        + (",\n * or either is NaN or inf" if model.regressor == "difference" else " or NaN")
        + " (f = 0 then: a",
        f" * polynomial is not extrapolated){'' if model.regressor == 'difference' else '; temp_outside is unused'}.",
        f" * {dname}_self_test() compares the test temperatures with fluxcal's values (0 = pass). */",
        f"#define {dup}_RANGES {len(segments)}",
        f"#define {dup}_MAX_ORDER {top}",
        f"#define {dup}_EDGE_MARGIN {d(EDGE_MARGIN * (edges[-1] - edges[0]))} /* degC: DriftModel.evaluate's margin */",
        f"static const double {dname}_edges[{len(edges)}] = {{{', '.join(map(d, edges))}}};",
        f"static const double {dname}_coefficients[{len(segments)}][{top + 1}] = {{  /* c_0 ... c_m per range */",
        _rows(coefficients, d) + "};",
        *([f"static const double {dname}_difference_range[{len(segments)}][2] = {{  /* fitted x per range, "
           f"{EDGE_MARGIN:g} of its span beyond taken */", _rows(seen, d) + "};"] if seen else []),
        f"static inline int {dname}(double temp, double temp_outside, double *f) {{",
        f"  const double x = {x};",
        "  int s, j;",
        *(["  (void)temp_outside;"] if model.regressor == "temp" else []),
        "  *f = 0.0;",
        f"  for (s = 0; s < {dup}_RANGES; ++s) {{",
        f"    const double lo = {dname}_edges[s] - (s == 0 ? {dup}_EDGE_MARGIN : 0.0);",
        f"    const double hi = {dname}_edges[s + 1] + (s == {dup}_RANGES - 1 ? {dup}_EDGE_MARGIN : 0.0);",
        f"    if (temp >= lo && (temp < hi || (s == {dup}_RANGES - 1 && temp <= hi))) {{",
        # written so that NaN fails it: `x < lo || x > hi` is false for NaN, and a NaN temp_outside (a failed
        # thermometer) had returned 0 with f = NaN (a blind check)
        *([f"      const double span = {dname}_difference_range[s][1] - {dname}_difference_range[s][0];",
           f"      if (!(x >= {dname}_difference_range[s][0] - {d(EDGE_MARGIN)} * span &&",
           f"            x <= {dname}_difference_range[s][1] + {d(EDGE_MARGIN)} * span)) return 1;"] if seen else
          # (a model saved without the difference's ranges: x is still refused when it is not a finite number)
          ["      if (!(x >= -1e308 && x <= 1e308)) return 1;"] if model.regressor == "difference" else []),
        f"      for (j = {dup}_MAX_ORDER; j >= 0; --j) *f = *f * x + {dname}_coefficients[s][j];",
        "      return 0;",
        "    }",
        "  }",
        "  return 1;",
        "}",
        f"#define {dup}_TEST_COUNT {temps.size}",
        f"static const double {dname}_test_temp[{temps.size}] = {{{', '.join(map(d, temps))}}};",
        f"static const double {dname}_test_outside[{temps.size}] = {{{', '.join(map(d, outside))}}};",
        f"static const double {dname}_test_expected[{temps.size}] = {{{', '.join(map(d, expected))}}};",
        f"static inline int {dname}_self_test(void) {{",
        "  int k, misses = 0;",
        "  double scale = 1e-300, f;",
        f"  for (k = 0; k < {dup}_TEST_COUNT; ++k)",
        f"    if ({dname}_test_expected[k] > scale || -{dname}_test_expected[k] > scale) "
        f"scale = {dname}_test_expected[k] > 0 ? {dname}_test_expected[k] : -{dname}_test_expected[k];",
        f"  for (k = 0; k < {dup}_TEST_COUNT; ++k) {{",
        f"    if ({dname}({dname}_test_temp[k], {dname}_test_outside[k], &f)) ++misses;",
        f"    else if (f - {dname}_test_expected[k] > 1e-9 * scale || {dname}_test_expected[k] - f > 1e-9 * scale) "
        "++misses;",
        "  }",
        "  return misses;",
        "}",
    ]
    return lines, model


def _drift_fit_said(kalman, drift, force: bool):
    """What the fits of the drift models given as `kalman` and `drift` said (a DriftModel or the path of its
    JSON; a saved FixedArKalman says nothing): ({part: comment lines for the header}, warnings to print). A drift
    model whose temperatures looked like °F or K logged with no unit is refused unless `force`, and then the header
    says it; a Kalman filter whose noise model the fit rejected (residuals not white) is written with that warning
    in the header and printed (its 5 % test rejects one good model in twenty: a refusal would need --force there)."""
    from .drift import DriftModel, fit_warnings, noise_model_rejected

    lines, warnings, said = {}, [], set()
    for part, given in (("kalman", kalman), ("drift", drift)):
        model, where = given, "drift model"
        if isinstance(given, (str, Path)):
            data = load_json_object(given, "a saved FixedArKalman or drift model")
            if data.get("kind") != "fluxcal drift model":
                continue
            model, where = DriftModel.from_dict(data, str(given)), str(given)
        if not isinstance(model, DriftModel):
            continue
        if part == "kalman":
            rejected = noise_model_rejected(model)
            comment = _c_comment(f"WARNING: {rejected}: this filter's q, r and coefficients may describe another "
                                 "noise than the device's (a thermal lag, a step, a longer memory).") if rejected else []
            if rejected:
                warnings.append(f"{where}: {rejected}: the filter is written, its header says so; find the cause (a "
                                "thermal lag, a step, a memory beyond --ar-max-order) and fit again for one that fits")
            why = rejected
        else:
            why = model.summary.get("temperature_unit_hint")
            if why and not force:
                raise ValueError(f"drift: {where}: its fit warned that the temperatures are not °C: {why}; the header "
                                 "would say degrees C over those numbers. Fit again with the unit stated, or export it "
                                 "anyway with force=True (--force), which the header then says")
            comment = _c_comment(f"WARNING (exported with --force): {why}.") if why else []
        for w in fit_warnings(model):
            if (where, w) not in said and w != why:
                said.add((where, w))
                warnings.append(f"{where} (at its fit): {w}")
                comment += _c_comment(f"The fit of {Path(where).name} warned: {w}")
        if why and part == "drift":
            warnings.append(f"{where}: exported with --force: {why}")
        unit = model.settings.get("unit")  # (a blind check fed amperes to a header fitted in mA: nothing said so)
        what = "f and W - f" if part == "drift" else "the filter's input and output"
        comment += _c_comment(f"Unit: {what} are in {unit}, the unit of the zero bias this model was fitted to "
                              f"({model.settings.get('column', 'zero_bias')} of {Path(where).name}); feed the zero "
                              f"bias in {unit}." if unit else
                              f"Unit: {what} are in the unit of the zero bias this model was fitted to (not stated "
                              "in its file).")
        lines[part] = comment
    return lines, warnings


# What fluxcal's own text and a user's units carry beyond ASCII, spelled in ASCII: a header is compiled by tool
# chains that read sources as Latin-1 or refuse bytes above 127, so it stays plain ASCII.
_ASCII_SPELLING = {"±": "+/-", "σ": "sigma", "µ": "u", "μ": "u", "°": "deg", "−": "-", "–": "-", "—": "-",
                   "×": "x", "·": ".", "≤": "<=", "≥": ">=", "≈": "~", "≪": "<<", "≫": ">>", "²": "^2", "³": "^3",
                   "√": "sqrt", "Σ": "sum", "Δ": "delta", "…": "...", "→": "->", "’": "'", "‘": "'", "“": '"',
                   "”": '"', "Ω": "Ohm"}


def _ascii(text: str) -> str:
    """`text` in ASCII: the spellings above, accents dropped (NFKD), anything else as '?'."""
    import unicodedata

    if text.isascii():
        return text
    out = []
    for ch in text:
        if ch.isascii():
            out.append(ch)
        elif ch in _ASCII_SPELLING:
            out.append(_ASCII_SPELLING[ch])
        else:
            plain = unicodedata.normalize("NFKD", ch).encode("ascii", "ignore").decode()
            out.append(plain if plain else "?")
    return "".join(out)


def _in_comment(text) -> str:
    """`text` (a unit, a file name, a column: the user's) safe inside a C comment: no comment end or start, no line
    break (a unit 'counts*/x' had ended the comment, and the header failed to compile; '*/ int evil; /*' compiled)."""
    return " ".join(_ascii(str(text)).replace("*/", "* /").replace("/*", "/ *").split())  # ASCII first: NFKD makes ＊／ */


def _c_comment(text: str) -> list:
    """`text` as a C comment in lines of at most 110 characters."""
    import textwrap

    body = textwrap.wrap(_in_comment(text), 104, break_long_words=False, break_on_hyphens=False)
    return [("/* " if k == 0 else " * ") + line for k, line in enumerate(body)][:-1] + \
        [("/* " if len(body) == 1 else " * ") + body[-1] + " */"]


def _kalman_test_vector(f, n: int = 256, seed: int = 0):
    """An AR series of the filter's own model (seeded) in the signal format, and filter_int's outputs."""
    d = f.double
    rng = np.random.default_rng(seed)
    burn = 200
    x = np.zeros(n + burn)
    for k in range(n + burn):
        past = x[max(0, k - d.order):k][::-1]
        x[k] = float(np.dot(d.ar_coeffs[:past.size], past)) + math.sqrt(d.q) * rng.standard_normal()
    y = x[burn:] + math.sqrt(d.r) * rng.standard_normal(n)
    # Scaled to the signal range, so the vector exercises the format's bits whatever its scale, but inside it
    # with the state, prediction and innovation (up to signal_gain·max|y|) and a guard bit for the
    # time-varying transient: no saturation to test here.
    limit = 0.45 * 2.0 ** (31 - f.frac_bits) / f.signal_gain
    y *= limit / np.max(np.abs(y))
    y_int, _ = f.to_fixed(y)
    out = f.filter_int(y_int)
    return np.asarray(y_int, dtype=np.int64), np.asarray(out, dtype=np.int64), f.overflowed


# -- the header ----------------------------------------------------------------------------------------------

@dataclass
class ExportResult:
    path: Path
    fixed: FixedCalibration | None = None
    inputs_q: np.ndarray | None = None
    kalman: object = None
    kalman_test: tuple | None = None
    drift: object = None  # the DriftModel written as f(T)
    warnings: list = field(default_factory=list)  # what the fit of a drift model (--drift, --kalman) warned
    name: str = ""  # the prefix of the header's functions and (upper-cased) macros

    def describe(self) -> str:
        said = []
        if self.fixed is not None:
            fx, u, hu = self.fixed, self.fixed.calibration.units, self.fixed.calibration.h_units
            unit, h_unit = f" {u}" if u else "", f" {hu}" if hu else ""
            said.append(f"float and {fx.fmt} fixed point (h in {fx.out_fmt}, matrix 2^-{fx.matrix_frac_bits}); inputs "
                        f"|m| ≤ {fx.input_range:.6g}{unit}; fixed-point error ≤ {fx.error_bound:.3g}{h_unit} "
                        f"({fx.error_bound_lsb:.2f} LSB; {fx.reading_error_bound:.3g}{h_unit} for real readings "
                        f"rounded into it); {len(self.inputs_q)} test vectors")
        if self.kalman is not None:
            said.append(f"AR({self.kalman.order}) Kalman filter in C99 (signal {signal_format(self.kalman.frac_bits)}, "
                        f"inputs to ±{self.kalman.input_reach():.3g})"
                        f" with a {len(self.kalman_test[0])}-sample bit-exact test vector")
        if self.drift is not None:
            orders = ", ".join(str(int(seg["order"])) for seg in self.drift.segments)
            said.append(f"drift f({'T' if self.drift.regressor == 'temp' else 'T - T_outside'}) in "
                        f"{len(self.drift.segments)} temperature range(s) (orders {orders}) with a test vector")
        # (a blind check had to open the header to learn the functions' names: the prefix follows -o's file name)
        calls = ([f"{self.name}_apply_float/_apply_fixed/_self_test()"] if self.fixed is not None else []) + \
            ([f"{self.name}_kalman_reset/_step/_self_test()"] if self.kalman is not None else []) + \
            ([f"{self.name}_drift/_drift_self_test()"] if self.drift is not None else [])
        return (f"wrote {self.path}: " + "; ".join(said)
                + (f"; functions {', '.join(calls)}, macros {self.name.upper()}_*" if self.name and calls else ""))


def _c_name(name: str) -> str:
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name or ""):
        raise ValueError(f"--name: {name!r} is not a C identifier (letters, digits, _; not starting with a digit)")
    if name.startswith("_"):  # the header's file-scope functions and macros would start with it
        raise ValueError(f"--name: {name!r} starts with '_': C reserves such file-scope names and macros (C99 7.1.3) "
                         "for the compiler and its library; start it with a letter")
    return name


def default_name(path) -> str:
    stem = re.sub(r"[^A-Za-z0-9_]", "_", Path(path).stem) or "fluxcal_cal"  # ASCII: C99 identifiers
    return stem if stem[0].isalpha() else "cal_" + stem.lstrip("_")


def _float_literal(v: float) -> str:
    text = str(np.float32(v))  # the shortest digits that give back this float
    return (text if any(c in text for c in ".en") else text + ".0") + "f"


def _rows(values, fmt, indent="  ") -> str:
    return ",\n".join(indent + "{" + ", ".join(fmt(v) for v in row) + "}" for row in values)


def export_c(cal: Calibration | None, path, q_format=None, name: str | None = None, kalman=None, drift=None,
             source: str = "", force: bool = False, input_range: float | None = None,
             kalman_range: float | None = None) -> ExportResult:
    """Write the firmware header (module docstring). `cal`: a Calibration, or None for a header of the drift
    part alone; `kalman`: a FixedArKalman, or a JSON path for `load_kalman`; `drift`: a DriftModel or its JSON
    path (f(T) in C); `input_range`: the sensor's full scale in the calibration's units (`fixed_point`);
    `kalman_range`: the largest |input| the Kalman filter must take unsaturated (its signal format; default 8 σ of
    its input: a 40 σ readout spike saturated it, the overflow flag set, and nothing let a user widen it). A
    calibration whose summary says its data did not determine every parameter
    (identifiable false: a yaw-only turn, small tilts), or whose offset moved within its log (a planar calibration's
    offset_split: the calibration is of neither part), is refused — firmware would apply a guess with
    nothing to say so — unless `force`, and then the header says it. So is a drift model whose fit warned that
    its temperatures look like °F or K logged with no unit; the other warnings of a drift model's fit (a Kalman
    filter's noise model rejected among them) are repeated in the header and in ExportResult.warnings. Returns what was written (ExportResult.describe() says it in one line)."""
    from . import __version__
    from ._arrays import require_calibration
    from .kalman import FixedArKalman

    if cal is None and kalman is None and drift is None:
        raise ValueError("export-c: nothing to export: give a calibration, a Kalman filter (--kalman) or a drift "
                         "model (--drift)")
    if input_range is not None and cal is None:
        raise ValueError("--input-range: the sensor's full scale sizes a calibration's Q format; give a calibration"
                         + (" (the Kalman filter's input range is --kalman-range)" if kalman is not None else ""))
    if q_format is not None and cal is None:  # (it had been taken and ignored)
        raise ValueError("--q-format: the Q format of a calibration's matrix and offsets; without a calibration nothing "
                         "takes it" + (" (the Kalman filter's signal format follows --kalman-range)"
                                       if kalman is not None else ""))
    if kalman_range is not None and kalman is None:
        raise ValueError("--kalman-range: the largest input of a Kalman filter; give one (--kalman)")
    undetermined = mirror_said = None
    if cal is not None:
        require_calibration(cal, "cal")
        undetermined = _undetermined(cal)
        if undetermined and not force:
            raise ValueError(f"cal: {undetermined}; firmware would apply a guess — recalibrate, or export it anyway "
                             "with force=True (--force), which the header then says")
        mirrored, mirror_said = _mirrored(cal)
        if mirrored and not force:
            raise ValueError(f"cal: {mirrored}; export it anyway with force=True (--force), which the header then "
                             "says, only if that is meant (a reference-vector calibration of axes of the other "
                             "handedness)")
        undetermined = "; ".join(filter(None, (undetermined, mirrored))) or None
    if kalman is not None and not isinstance(kalman, (str, Path, FixedArKalman)):
        raise TypeError(f"kalman: expected a FixedArKalman or the path of its JSON, got {type(kalman).__name__}")
    fit_said, fit_warned = _drift_fit_said(kalman, drift, force)  # (before anything is written)
    path = Path(path)
    if path.is_file() and path.suffix.lower() not in (".h", ".hh", ".hpp", ".hxx"):  # (a recording overwritten, unsaid)
        raise ValueError(f"export-c: {path} exists and is no C header (its name does not end in .h): it would be "
                         "overwritten; name the header *.h")
    name = _c_name(name if name is not None else default_name(path))
    i32 = lambda v: str(int(v)) if v != INT32_MIN else "INT32_MIN"  # noqa: E731
    result = ExportResult(path, warnings=fit_warned, name=name)
    parts = []
    if cal is not None:
        lines, result.fixed, result.inputs_q = _calibration_part(cal, name, q_format, input_range, i32)
        if mirror_said:
            result.warnings.append(f"cal: {mirror_said}")
            lines = _c_comment(f"WARNING: {mirror_said}.") + lines
        precision_said = _precision_warnings(result.fixed, q_format, input_range)
        result.warnings += precision_said
        lines = [line for w in precision_said for line in _c_comment(f"WARNING: {w}.")] + lines
        if undetermined:  # (and a macro a build can refuse: #ifdef NAME_EXPORTED_WITH_FORCE / #error)
            lines = [f"/* WARNING (exported with --force): {_in_comment(undetermined)}. */",
                     f"#define {name.upper()}_EXPORTED_WITH_FORCE 1"] + lines
        parts.append(("magnetometer calibration", lines))
    if kalman is not None:
        lines, result.kalman, result.kalman_test = _kalman_part(kalman, name, i32, kalman_range)
        range_said = _kalman_range_warnings(result.kalman, kalman_range)
        result.warnings += range_said
        lines = [line for w in range_said for line in _c_comment(f"WARNING: {w}.")] + lines
        parts.append(("fixed-point Kalman filter", fit_said.get("kalman", []) + lines))
    if drift is not None:
        lines, result.drift = _drift_part(drift, name)
        parts.append(("temperature drift compensation", fit_said.get("drift", []) + lines))
    body = [line for _, lines in parts for line in ["", *lines]]
    # ... and a hash of the content: two different calibrations exported under one name (magcal.h in two
    # folders) shared the guard, and the second was skipped in silence, the first one's constants used (a blind
    # check); now they clash aloud (redefinition), while the same header included twice is still skipped
    digest = hashlib.sha256(_ascii("\n".join(body)).encode("ascii")).hexdigest()[:8].upper()
    guard = f"FLUXCAL_{name}_{digest}_H"
    head = [f"/* {path.name}: {' and '.join(what for what, _ in parts)} for firmware, written by fluxcal "
            f"{__version__}" + (f" from {_in_comment(source)}." if source else "."),
            " * C99, also valid C++; every function is static inline. */",
            # the guard keeps the name's case and a prefix no part's own guard has: `--name mag` and `--name MAG`,
            # or `--name comb_kalman` beside comb's Kalman part (COMB_KALMAN_H), had one guard and the second
            # header was skipped without a word (a blind check); now their macros or functions clash aloud
            f"#ifndef {guard}", f"#define {guard}",
            # the name's own macro too, for code that tests it (defined alike by every header of the name: no clash)
            f"#define FLUXCAL_{name}_H 1", "", "#include <stdint.h>"]
    path.write_text(_ascii("\n".join(head + body + ["", f"#endif /* {guard} */", ""])), encoding="ascii")
    return result


def _mirrored(cal: Calibration) -> tuple[str | None, str | None]:
    """(a refusal, a warning) for a matrix that mirrors the field. A magnitude calibration's A is symmetric positive
    definite ((W Wᵀ)^-1/2: calibration.CONVENTION): a symmetric A with an eigenvalue ≤ 0 is a hand edit or a sign
    error (a blind check's negated matrix, det A < 0, was exported and passed its self-test), refused. Only with
    reference vectors (A = W⁻¹, a full matrix: fit_vector, fluxcal positions) may A be a mirror — axes of the other
    handedness, which those fits say — and then det A < 0 is repeated as a warning."""
    a = cal.matrix
    det = float(np.linalg.det(a))
    names = cal.summary.get("parameter_names")
    vector = (isinstance(names, list) and names[3:4] == ["w00"]) or cal.model.startswith("positions")
    if not vector and np.allclose(a, a.T, rtol=0.0, atol=1e-12 * float(np.max(np.abs(a)))):
        eigenvalues = np.linalg.eigvalsh((a + a.T) / 2)
        if not np.all(eigenvalues > 0):
            return (f"matrix: symmetric with eigenvalues {', '.join(f'{v:.6g}' for v in eigenvalues)} (det A = "
                    f"{det:.6g}): not positive definite, so it " + ("mirrors" if det < 0 else "turns over") +
                    " the field; a magnitude calibration's A is symmetric positive definite ((W W^T)^-1/2), so this "
                    "one was edited or its sign flipped"), None
    if det < 0:
        return None, (f"matrix: det A = {det:.6g} < 0, a mirror: right only when the sensor's axes and the "
                      "reference's differ in handedness (a reference-vector or multi-position fit says so); a "
                      "sign flipped in the file mirrors every field")
    return None, None


def _undetermined(cal: Calibration) -> str | None:
    """What a calibration's summary says about parameters its data did not determine, or None."""
    if cal.summary.get("converged", True) is False:
        why = next((w for w in cal.summary.get("warnings", []) if "converge" in w), "")
        return ("the calibration's fit did not converge: the result is an intermediate iterate"
                + (f" ({why.rstrip('.')})" if why else ""))
    if offset_moved(cal.summary):  # a planar calibration "of neither" part
        split = cal.summary["offset_split"]
        why = split.get("said", "")
        moved = "drifted through" if split.get("kind") == "drift" else "moved within"
        return f"the offset {moved} the calibration's log" + (f" ({why.rstrip('.')})" if why else "")
    if cal.summary.get("identifiable", True):
        return None
    # the warning that names the parameters first (a blind check got a coverage note that merely says "determined")
    warnings = cal.summary.get("warnings", [])
    why = next((w for w in warnings if "identif" in w), None) or next((w for w in warnings if "determin" in w), "")
    return ("the calibration is not identifiable: its data did not determine every parameter"
            + (f" ({why.rstrip('.')})" if why else ""))


def _precision_warnings(fx: FixedCalibration, q_format, input_range) -> list:
    """Words when the fixed-point error bound is a large share of the field (PRECISION_SHARE's comment): a typo'd
    --input-range 1e9 (for 1e3 µT) gave Q30.1 and E = 3.6 µT on a 48 µT field, --q-format Q31.0 on µT readings
    0.56 µT, both written without a word (a blind check); the Kalman part says its analogue
    (_kalman_range_warnings)."""
    cal = fx.calibration
    norm, bound = float(cal.field_norm), fx.error_bound
    hu, u = f" {cal.h_units}".rstrip(), f" {cal.units}".rstrip()
    try:
        residual = float(cal.summary.get("residual_rms"))
    except (TypeError, ValueError):
        residual = math.nan
    if math.isfinite(residual) and residual > 0:
        lo, hi = PRECISION_SHARE_RANGE
        line = min(max(residual, lo * norm), hi * norm)
        what = (f"the calibration's own residual RMS {residual:.3g}{hu}" if line == residual else
                f"{line / norm:.2g} of the field (the calibration's residual RMS {residual:.3g}{hu} is no line)")
    else:
        line, what = PRECISION_SHARE * norm, f"{PRECISION_SHARE:.1%} of the field (no residual RMS in its summary)"
    if not (norm > 0 and bound > line):
        return []
    given = " ".join(filter(None, (f"--q-format {fx.fmt}" if q_format is not None else "",
                                   f"--input-range {fx.input_range:g}{u}" if input_range is not None else "")))
    head = (f"{given or f'the default format {fx.fmt}'}: the fixed-point error bound E = {bound:.3g}{hu} "
            f"({fx.fmt}, LSB {fx.fmt.lsb:.3g}{u}) is {bound / norm:.2%} of the field {norm:.6g}{hu}, above {what}: "
            "the format, not the sensor, limits h")
    if q_format is not None:  # what the range's own format gives
        better = fixed_point(cal, None, input_range)
        if better.error_bound <= line:
            return [head + f"; {better.fmt}, the default for this range, gives E = {better.error_bound:.3g}{hu} "
                    "(leave --q-format out)"]
    if input_range is None:  # the range of the calibration's own readings: an int32 has no finer step over it
        return [head + f"; an int32 over the readings' range ±{fx.input_range:.6g}{u} holds no finer step (an offset "
                "that large beside the field?)"]
    extent, unit = reading_extent(cal), cal.units or "the readings' unit"
    return [head + f"; the stated input range ±{fx.input_range:.6g}{u} is {fx.input_range / extent:.3g} x the "
            f"readings' extent {extent:.6g}{u}: is that the sensor's full scale in {unit}?"]


def _calibration_part(cal: Calibration, name: str, q_format, input_range, i32):
    """The header lines of the magnetometer correction, its FixedCalibration and test inputs."""
    up = name.upper()
    fx = fixed_point(cal, q_format, input_range)
    inputs_q = vector_inputs(fx)
    inputs = inputs_q * fx.fmt.lsb                      # the exact values the fixed inputs stand for
    inputs_f = inputs.astype(np.float32).astype(float)  # what the float function is given
    expected = cal.apply(inputs)
    expected_f = cal.apply(inputs_f)
    expected_q = np.rint(expected * 2.0 ** fx.out_fmt.frac_bits).astype(np.int64)
    tolerance_lsb = math.ceil(fx.error_bound_lsb + 0.5)  # the expected value itself is rounded to the grid
    _, saturated = fx.apply_int(inputs_q)
    if saturated:  # cannot happen by construction; a guard against a broken range rule
        raise AssertionError("export-c: a test input saturates inside the stated range")
    units = _in_comment(cal.units) if cal.units else "(units not stated)"
    u = f" {_in_comment(cal.units)}" if cal.units else ""
    hu = f" {_in_comment(cal.h_units)}" if cal.h_units else ""  # h is in the field norm's unit (µT from counts, say)
    n, na, lsb = fx.fmt.frac_bits, fx.matrix_frac_bits, fx.fmt.lsb
    q, shift, out_lsb = fx.out_fmt.frac_bits, fx.output_shift, fx.out_fmt.lsb
    offset_lo = cal.offset - cal.offset.astype(np.float32).astype(float)  # what one float of b loses
    s = cal.summary
    planar = s.get("method") == "planar" and "not_calibrated" in s
    what = ((f" * Planar ({_in_comment(', '.join(s['plane_axes']))}): |h| is the HORIZONTAL field in that plane; axis "
             f"{_in_comment(s['not_calibrated']['axis'])} " + ("is absent (a biaxial sensor: give 0)" if s.get("biaxial") else
                                                   "passes through uncalibrated, only scaled into h's unit")
             + ".") if planar else None)
    # a plane that is no pair of the sensor's axes (a tilted mounting): its axes given, and how the heading is formed
    # (a blind check's firmware took atan2(h_y, h_x) from a header that named e1, e2 without their values: 14° off)
    tilted = planar and set(s.get("plane_axes", [])) - set("xyz") and "plane_basis" in s
    basis = np.vstack([s["plane_basis"], s["plane_normal"]]) if tilted else None
    plane_lines = ([
        f" * The plane's axes in the sensor's (unit vectors): {name}_plane_axes[0] = e1, [1] = e2, [2] = n (its normal).",
        " *   The heading is the angle of h in (e1, e2): atan2(h . e2, h . e1) - NOT atan2(h_y, h_x), which a tilted",
        " *   mounting bends by up to its tilt; h itself is in the sensor's axes."] if tilted else [])
    lines = [
        "/* ---- Magnetometer calibration ----",
        f" * Model: h = A (m - b). m: a raw reading in {units}; h: the corrected field, |h| = {cal.field_norm:.9g}{hu}"
        f" in the calibration field.",
        *([what] if what else []),
        *plane_lines,
        f" * Float: {name}_apply_float(m, h): A and b in float (single precision; b as b_hi + b_lo, d = (m - b_hi) - b_lo,",
        " *   so that a large offset loses nothing to its own rounding). On the test vector it",
        f" *   reproduces fluxcal's double result within {FLOAT_RELATIVE_TOLERANCE:g} x max(|h| (largest component), "
        f"{cal.field_norm:.6g}).",
        f" * Fixed: {name}_apply_fixed(m, h): int32 in and out, int64 inside, no division, no floating point.",
        f" *   Signal format {fx.fmt} for m and b: value = int32 / 2^{n}; a sign bit, {fx.fmt.int_bits} integer and "
        f"{n} fraction bits;",
        f" *     range [-2^{fx.fmt.int_bits}, 2^{fx.fmt.int_bits} - 2^-{n}], LSB 2^-{n} = {lsb:.6g}{u}.",
        f" *   Output format {fx.out_fmt} for h: value = int32 / 2^{q}, LSB {out_lsb:.6g}{hu} ({up}_H_Q_FRAC_BITS; the",
        " *     most fraction bits that hold every output of the stated range).",
        f" *     A raw reading r converts as round(r * 2^{n}), saturated to int32 (integer counts: r * 2^{n}).",
        f" *   Matrix: a_ij = int32 / 2^{na}, |a_ij| <= 2^30, so sums of three products are exact in int64.",
        " *   Arithmetic: d_j = m_j - b_j in int64, saturated to int32; acc_i = sum_j a_ij d_j (exact);",
        f" *     h_i = acc_i / 2^{shift} (= 2^({na} + {n} - {q})) rounded to nearest, ties away from zero, saturated to int32. Constants are",
        " *     rounded to nearest. The function returns 1 when anything saturated (values never wrap), else 0.",
        f" *   Stated input range: |m_j| <= R = {fx.input_range:.9g}{u} ({up}_INPUT_RANGE_Q), {_in_comment(fx.range_note)}.",
        f" *     In it nothing saturates and every component of h is within E = {fx.error_bound:.6g}{hu}",
        f" *     ({fx.error_bound_lsb:.3f} LSB of h) of the exact h = A (m - b):",
        f" *     E = max_i [2^-{q + 1} + 2^-{n + 1} sum_j |a_ij| + 2^-{na + 1} sum_j (R + |b_j|)]  (rounding of h, b, A).",
        f" *     That is against m as given in the format (integer counts are exact). A real reading r rounded into",
        f" *     it adds up to 2^-{n + 1} max_i sum_j |a_ij|: h is within E_r = {fx.reading_error_bound:.6g}{hu} of A (r - b)",
        f" *     ({up}_READING_ERROR_BOUND).",
        f" * Self-check: {name}_self_test() runs the {len(inputs_q)} test vectors through both functions and",
        " *   returns how many components miss fluxcal's double result by more than the tolerance (0 = pass):",
        f" *   float {up}_FLOAT_REL_TOL relative as above, fixed {up}_FIXED_TOL_LSB LSB (E plus the rounding of",
        " *   the expected value to the grid); a saturated test vector counts as a miss.",
        " */",
        f"#define {up}_FIELD_NORM {_float_literal(cal.field_norm)}",
        f"#define {up}_Q_INT_BITS {fx.fmt.int_bits}",
        f"#define {up}_Q_FRAC_BITS {n}",
        f"#define {up}_H_Q_INT_BITS {fx.out_fmt.int_bits}",
        f"#define {up}_H_Q_FRAC_BITS {q}",
        f"#define {up}_MATRIX_FRAC_BITS {na}",
        f"#define {up}_OUTPUT_SHIFT {shift}",
        f"#define {up}_INPUT_RANGE {_float_literal(fx.input_range)}",
        f"#define {up}_INPUT_RANGE_Q {fx.input_range_q}",
        f"#define {up}_FIXED_ERROR_BOUND {_float_literal(fx.error_bound)}",
        f"#define {up}_READING_ERROR_BOUND {_float_literal(fx.reading_error_bound)}",
        f"#define {up}_FIXED_TOL_LSB {tolerance_lsb}",
        f"#define {up}_FLOAT_REL_TOL {_float_literal(FLOAT_RELATIVE_TOLERANCE)}",
        "",
        f"/* double: b = {', '.join(f'{v:.17g}' for v in cal.offset)} */",
        f"static const float {name}_offset_f[3] = {{{', '.join(_float_literal(v) for v in cal.offset)}}};",
        f"static const float {name}_offset_lo_f[3] = {{{', '.join(_float_literal(v) for v in offset_lo)}}};",
        f"/* row-major, h_i = sum_j A[i][j] (m_j - b_j); double: "
        f"{', '.join(f'{v:.17g}' for v in cal.matrix.ravel())} */",
        f"static const float {name}_matrix_f[3][3] = {{\n{_rows(cal.matrix, _float_literal)}}};",
        *([f"static const float {name}_plane_axes[3][3] = {{\n{_rows(basis, _float_literal)}}};"] if tilted else []),
        f"static const int32_t {name}_offset_q[3] = {{{', '.join(i32(v) for v in fx.offset_q)}}};",
        f"static const int32_t {name}_matrix_q[3][3] = {{\n{_rows(fx.matrix_q, i32)}}};",
        "",
        f"static inline void {name}_apply_float(const float m[3], float h[3]) {{",
        f"  const float d0 = (m[0] - {name}_offset_f[0]) - {name}_offset_lo_f[0],",
        f"              d1 = (m[1] - {name}_offset_f[1]) - {name}_offset_lo_f[1],",
        f"              d2 = (m[2] - {name}_offset_f[2]) - {name}_offset_lo_f[2];",
        "  int i;",
        f"  for (i = 0; i < 3; ++i) h[i] = {name}_matrix_f[i][0] * d0 + {name}_matrix_f[i][1] * d1 + "
        f"{name}_matrix_f[i][2] * d2;",
        "}", "",
        f"static inline int32_t {name}_saturate_(int64_t v, int *saturated) {{",
        "  if (v > INT32_MAX) { *saturated = 1; return INT32_MAX; }",
        "  if (v < INT32_MIN) { *saturated = 1; return INT32_MIN; }",
        "  return (int32_t)v;",
        "}", "",
        f"static inline int {name}_apply_fixed(const int32_t m[3], int32_t h[3]) {{",
        f"  const int64_t half = (int64_t)1 << ({up}_OUTPUT_SHIFT - 1);",
        "  int saturated = 0, i, j;",
        "  int32_t d[3];",
        "  /* a reading at INT32_MIN/INT32_MAX is what a saturated conversion round(r * 2^n) leaves: flagged */",
        "  for (j = 0; j < 3; ++j) if (m[j] == INT32_MAX || m[j] == INT32_MIN) saturated = 1;",
        f"  for (j = 0; j < 3; ++j) d[j] = {name}_saturate_((int64_t)m[j] - {name}_offset_q[j], &saturated);",
        "  for (i = 0; i < 3; ++i) {",
        "    int64_t acc = 0;",
        f"    for (j = 0; j < 3; ++j) acc += (int64_t){name}_matrix_q[i][j] * d[j];",
        "    /* nearest, ties away from zero; shifting only non-negative values keeps it portable C99 */",
        f"    acc = acc >= 0 ? (acc + half) >> {up}_OUTPUT_SHIFT : -((-acc + half) >> {up}_OUTPUT_SHIFT);",
        f"    h[i] = {name}_saturate_(acc, &saturated);",
        "  }",
        "  return saturated;",
        "}", "",
        f"/* Test vector: readings (the calibration field from 14 directions, the corners of the range, random",
        f" * points in it, m = b, m = 0) and fluxcal's double-precision h, rounded to float and to {fx.out_fmt}. */",
        f"#define {up}_TEST_COUNT {len(inputs_q)}",
        f"static const float {name}_test_input_f[{up}_TEST_COUNT][3] = {{\n{_rows(inputs_f, _float_literal)}}};",
        f"static const float {name}_test_expected_f[{up}_TEST_COUNT][3] = {{\n{_rows(expected_f, _float_literal)}}};",
        f"static const int32_t {name}_test_input_q[{up}_TEST_COUNT][3] = {{\n{_rows(inputs_q, i32)}}};",
        f"static const int32_t {name}_test_expected_q[{up}_TEST_COUNT][3] = {{\n{_rows(expected_q, i32)}}};",
        "",
        f"static inline int {name}_self_test(void) {{",
        "  int misses = 0, k, i;",
        f"  for (k = 0; k < {up}_TEST_COUNT; ++k) {{",
        "    float hf[3], scale = " + f"{up}_FIELD_NORM;",
        "    int32_t hq[3];",
        f"    {name}_apply_float({name}_test_input_f[k], hf);",
        f"    if ({name}_apply_fixed({name}_test_input_q[k], hq)) ++misses;",
        "    for (i = 0; i < 3; ++i) {",
        f"      float e = {name}_test_expected_f[k][i];",
        "      if (e > scale) scale = e;",
        "      if (-e > scale) scale = -e;",
        "    }",
        "    for (i = 0; i < 3; ++i) {",
        f"      float ef = hf[i] - {name}_test_expected_f[k][i];",
        f"      int64_t eq = (int64_t)hq[i] - {name}_test_expected_q[k][i];",
        f"      if (ef > {up}_FLOAT_REL_TOL * scale || -ef > {up}_FLOAT_REL_TOL * scale) ++misses;",
        f"      if (eq > {up}_FIXED_TOL_LSB || -eq > {up}_FIXED_TOL_LSB) ++misses;",
        "    }",
        "  }",
        "  return misses;",
        "}",
    ]
    return lines, fx, inputs_q


def _kalman_part(kalman, name: str, i32, kalman_range: float | None = None):
    """The header lines of the fixed-point AR Kalman filter (coefficients, C99 filter, test vector), the filter
    and its test (input, output); `kalman_range` sizes its signal format for inputs up to that."""
    f = load_kalman(kalman) if isinstance(kalman, (str, Path)) else kalman
    if kalman_range is not None:
        f = copy.copy(f) if f is kalman else f  # (the caller's filter keeps its format)
        y_max = as_number(kalman_range, "kalman_range")
        if not y_max > 0:
            raise ValueError(f"--kalman-range {kalman_range}: must be a positive number (the largest |input|)")
        f.frac_bits = f.signal_frac_bits(y_max)
    if f.frac_bits is None:
        raise ValueError("kalman: the filter's signal format (frac_bits) is not set")
    y_int, out, overflowed = _kalman_test_vector(f)
    if overflowed:
        raise ValueError("kalman: the filter saturates on its own test signal; check its fraction bits")
    kname = f"{name}_kalman"
    with tempfile.TemporaryDirectory() as tmp:  # reuse FixedArKalman's own header writer
        coefficients = f.export_header(Path(tmp) / "kalman.h", name=kname).read_text()
    lines = [
        f"/* ---- Fixed-point AR({f.order}) Kalman filter (fluxcal.kalman.FixedArKalman) ----",
        f" * C:   {kname}_t f; {kname}_reset(&f); then y_hat = {kname}_step(&f, y) per sample (int32, signal",
        f" *      format 2^-{kname.upper()}_SIGNAL_FRAC_BITS: inputs up to about ±{f.input_reach():.3g} unsaturated);",
        " *      f.overflow says whether anything saturated (a readout spike past that: --kalman-range widens it).",
        f" *      Call {kname}_reset() again after a gap in time and after samples left out (a temperature the drift",
        " *      model refuses): fluxcal's filter restarts there too (FixedArKalman.filter(y, breaks), drift apply).",
        f" *      A gap is a time step of {GAP_STEPS:g} times the log's median step or more (fluxcal.timeseries.find_breaks).",
        " * C++: fluxcal::FixedArKalman<MaxOrder> of cpp/include/fluxcal/fixed_kalman.hpp, configured from these",
        " *      coefficients, runs the same arithmetic.",
        f" * Either, fed {kname}_test_input, returns {kname}_test_output bit for bit (fluxcal's",
        f" * FixedArKalman.filter_int computed them); {kname}_self_test() checks it (0 = pass). */",
        coefficients.rstrip("\n"),
        f"#define {kname.upper()}_TEST_COUNT {len(y_int)}",
        f"static const int32_t {kname}_test_input[{len(y_int)}] = {{{', '.join(i32(v) for v in y_int)}}};",
        f"static const int32_t {kname}_test_output[{len(out)}] = {{{', '.join(i32(v) for v in out)}}};",
        _KALMAN_C.replace("KNAME", kname).replace("KUP", kname.upper()).strip("\n"),
    ]
    return lines, f, (y_int, out)
