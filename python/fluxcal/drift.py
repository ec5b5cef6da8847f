"""Temperature-drift compensation of a current transformer's zero bias (seed 001, the whole pipeline).

    model, report = drift.fit_pipeline(zero_bias, temp)          # S2 tests, AR, Kalman, S5 drift model
    compensated = model.compensate(zero_bias, temp)              # W_c = W − f(T)
    model.save("drift.json"); drift.DriftModel.load("drift.json")
    drift.accuracy(residual, rated=1000.0, accuracy_class="0.2S")

Steps of fit_pipeline:
  1. zero-mean; reverse-arrangement stationarity test of the differenced series (and a second difference
     plus trend removal when it fails); skewness/kurtosis of the stationary series (diagnostics of the
     zero bias, S2);
  2. a first drift model f1 of the zero bias (step 4's fit), and the AR(p) model of the noise
     zero_bias − f1 − mean: order by AIC, RLS coefficients, Ljung–Box whiteness over max(10, 2 max_order)
     lags, so that correlation beyond the largest order is tested too (S3). S2.3 removes the trend before
     the AR model; for a temperature drift that trend is f1. (Fitted to the zero bias itself, the AR model
     also had to describe the drift: on the simulated FOCT AIC chose the maximum order 10 with a1 ≈ 0.60
     for the true 0.5 and Ljung–Box rejected it, p < 1e-150, on every seed. Differencing instead, S2.3
     literally, does not help: differenced AR noise has a unit moving-average root that no finite AR
     model whitens, AIC again chose 10.)
     A noise that is still not white about the drift (memory beyond max_order, an unmodelled step) is
     reported in the warnings;
  3. Kalman filter on that AR model (`ArKalman.from_ar`: Q = the AR residual variance, R given or Q) → L
     (S4). The drift is a known input of the state-space model, so the filter runs on the noise and
     L = f1 + mean + filter(noise): L follows the drift without the lag (and the DC gain below 1) that
     filtering the zero bias itself gave on temperature ramps. When AIC chooses order 0 (the noise about
     the drift is white) nothing in the noise is predictable and there is no filter: L = f1 + mean,
     settings["kalman"] is None and report["notes"] says so (WHITE_NOISE_NOTE);
  4. piecewise polynomial drift Y = T A of the zero bias in the device temperature or the inside/outside
     difference, balanced columns, F-test orders, AR-whitened (generalised) least squares (S5; see
     cpp/include/fluxcal/drift.hpp for why the whitening): by default the model is f1 itself.
     drift_input="filtered" refits S5 on L, as seed 001 writes it; with L as in step 3 the two agree
     (simulated FOCT at σ = 0.01 A, 40 seeds: spurious orders 2, 2, 4 per range for both). Before, L was
     the filtered zero bias, which lagged the drift on ramps and the F-test read the lag as an extra order
     (order 4 for the true 3 in 26 of those 40 seeds, the drift twice as far from the truth).
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import _core
from . import timeseries as ts
from ._arrays import as_number
from ._saved import load_json_object
from .kalman import ArKalman
from .outliers import _runs as index_runs

DEFAULT_BREAKPOINTS = (-20.0, 0.0, 30.0, 50.0)
EDGE_MARGIN = _core.DRIFT_EDGE_MARGIN  # beyond the outer edges, a fraction of the model's span still evaluated
CURRENT_POINTS = (1, 5, 20, 100, 120)  # % of rated current
# IEC 61869-2 ratio-error limits (± %) at 1 / 5 / 20 / 100 / 120 % of rated current.
IEC_LIMITS = {"0.2S": (0.75, 0.35, 0.2, 0.2, 0.2), "0.5S": (1.5, 0.75, 0.5, 0.5, 0.5)}
REGRESSORS = ("temp", "difference")
DRIFT_INPUTS = ("zero_bias", "filtered")  # what fit_pipeline fits the drift to (module doc, step 4)
AR_FITTED_TO = "zero_bias - drift"  # what fit_pipeline's AR model describes: the noise about the drift (step 2)
# fit_pipeline's report["notes"] (and fit_foct's) when AIC chooses AR order 0 (module doc, step 3).
WHITE_NOISE_NOTE = "noise about the drift is white (AIC order 0): no Kalman filter; L = the drift model"
WHITE_NOISE_NO_REFIT = ("drift_input 'filtered' has nothing to refit (L is the drift model): the model is the fit "
                        "to the zero bias")


def _regressor(temp, temp_outside, regressor: str) -> np.ndarray:
    if regressor not in REGRESSORS:
        raise ValueError(f"regressor: {regressor!r} is not one of {', '.join(REGRESSORS)}")
    if regressor == "temp":
        return temp
    if temp_outside is None:
        raise ValueError("temp_outside: needed for the inside/outside temperature difference regressor")
    outside = _finite(ts.as_series(temp_outside, "temp_outside"), "temp_outside")  # named, not as "regressor"
    if outside.size != temp.size:
        raise ValueError(f"temp_outside: {outside.size} samples, temp has {temp.size}")
    return np.ascontiguousarray(temp - outside)


@dataclass
class DriftModel:
    """Piecewise polynomial drift f of the zero bias; segments are chosen by the device temperature,
    the polynomial variable is `regressor` ("temp" or "difference" = temp − temp_outside)."""
    segments: list
    regressor: str = "temp"
    settings: dict = field(default_factory=dict)   # AR / Kalman / fit settings (what fit_pipeline used)
    summary: dict = field(default_factory=dict)

    def evaluate(self, temp, temp_outside=None, outside: str = "error") -> np.ndarray:
        """f(T) of each sample. A temperature outside every range (by more than EDGE_MARGIN of the span) is a
        ValueError (outside="error"; the polynomials are not extrapolated) or gives NaN (outside="nan": the samples the model cannot speak for,
        marked, the others compensated)."""
        return self._per_sample(_core.drift_evaluate, temp, temp_outside, outside)

    def standard_error(self, temp, temp_outside=None, outside: str = "error") -> np.ndarray:
        """The standard error of f(T) of each sample: √(vᵀCv), v = (1, x, …, x^m), C the range's coefficient
        covariance (generalised least squares' under the AR noise model; see the core's DriftSegment::covariance).
        What compensation adds to each sample's own noise, as a bias shared by the samples at one temperature —
        conditional on the orders the F-tests chose. Outside the ranges as evaluate. A model saved before fluxcal
        kept the covariance has none: ValueError (fit it again)."""
        missing = [k for k, seg in enumerate(self.segments) if seg.get("covariance") is None]
        if missing:
            raise ValueError(f"drift model: segment(s) {missing} have no covariance of their coefficients (a model "
                             "saved before fluxcal kept them, or made by hand): fit it again for standard errors")
        covariances = [np.asarray(seg["covariance"], dtype=float).reshape(len(seg["coefficients"]), -1)
                       for seg in self.segments]
        return self._per_sample(lambda segs, t, x: _core.drift_standard_error(segs, covariances, t, x),
                                temp, temp_outside, outside)

    def _per_sample(self, core, temp, temp_outside, outside) -> np.ndarray:
        """core(segments, temp, x) of each sample, with evaluate's rules for temperatures outside the ranges."""
        if outside not in ("error", "nan"):
            raise ValueError(f"outside: {outside!r} is not one of error, nan")
        temp = ts.as_series(temp, "temp")
        x = _regressor(temp, temp_outside, self.regressor)
        segs = [((float(s["range"][0]), float(s["range"][1])), [float(c) for c in s["coefficients"]])
                for s in self.segments]
        # The outer edges are the fit's coldest and hottest samples: a later log at the same holds reads a little
        # beyond them half the time (0.007 °C was refused). Within EDGE_MARGIN of the span the edge range's
        # polynomial is used, a negligible extrapolation (beyond_ranges).
        lo, hi = self.span()
        margin = EDGE_MARGIN * (hi - lo)
        given = temp
        temp = np.where((temp < lo) & (temp >= lo - margin), lo, np.where((temp > hi) & (temp <= hi + margin), hi, temp))
        unseen = self.beyond_differences(given, x)
        if unseen.any() and outside == "error":
            raise ValueError(self.differences_words(given, x, unseen))
        if outside == "nan":
            inside = (temp >= segs[0][0][0]) & (temp <= segs[-1][0][1]) & ~unseen  # (the ranges are contiguous)
            f = np.full(temp.size, np.nan)
            if inside.any():
                f[inside] = core(segs, np.ascontiguousarray(temp[inside]), np.ascontiguousarray(x[inside]))
            return f
        try:
            return np.asarray(core(segs, temp, np.ascontiguousarray(x)))
        except ValueError:
            # Refused: samples outside the ranges are said as drift apply says them (outside_ranges_words); the
            # core's own error stands for what it finds first (a NaN, segments not ascending and contiguous).
            if np.all(np.isfinite(given)) and self._contiguous():
                said = outside_ranges_words(self, given, "outside='nan' (--outside-range nan)")
                if said:
                    raise ValueError(said) from None
            raise

    def _contiguous(self) -> bool:
        """Whether the ranges are finite, ascending and contiguous (from_dict refuses others; the core too)."""
        edges = [(float(s["range"][0]), float(s["range"][1])) for s in self.segments]
        return all(np.isfinite(a) and np.isfinite(b) and a < b for a, b in edges) and all(
            b == c for (_, b), (c, _) in zip(edges[:-1], edges[1:]))

    def steps(self) -> list:
        """[(T, f just above T − f just below)] at each inner breakpoint T: what the compensated output steps by as
        the device crosses it (each range's polynomial is fitted on its own unless `continuous`; a blind check's
        0.025 A at 30 °C, a third of the 0.2S budget at 1 %, had gone unsaid). Empty for the difference regressor
        (its polynomial's variable is not the temperature that crosses)."""
        if self.regressor != "temp":
            return []
        poly = np.polynomial.polynomial.polyval
        return [(float(b["range"][0]), float(poly(b["range"][0], b["coefficients"])
                                             - poly(b["range"][0], a["coefficients"])))
                for a, b in zip(self.segments[:-1], self.segments[1:])]

    def span(self) -> tuple:
        """(lo, hi): the coldest edge of the model's ranges and the hottest (°C; the ranges are contiguous)."""
        return float(self.segments[0]["range"][0]), float(self.segments[-1]["range"][1])

    def beyond_ranges(self, temp) -> np.ndarray:
        """Which temperatures are outside every range by more than EDGE_MARGIN of the span: those evaluate refuses
        (or gives NaN for). A NaN is not one (it is not a temperature, and is said as such)."""
        t = np.asarray(temp, dtype=float)
        lo, hi = self.span()
        margin = EDGE_MARGIN * (hi - lo)
        with np.errstate(invalid="ignore"):
            return (t < lo - margin) | (t > hi + margin)

    def beyond_differences(self, temp, x) -> np.ndarray:
        """For the difference regressor: which samples' temp − temp_outside lies outside what its range (by the
        device temperature) was fitted over, by more than EDGE_MARGIN of that span (segments' "difference_range";
        models saved before it have none: nothing is). A blind check's model fitted over −1 … 7 °C had given −1.32 A
        at 20 °C, in range by the device temperature, said by nothing."""
        t, x = np.asarray(temp, dtype=float), np.asarray(x, dtype=float)
        if self.difference_ranges is None:
            return np.zeros(t.size, dtype=bool)
        which = range_index(self.segments, t)
        bounds = np.array(self.difference_ranges, dtype=float)
        margin = EDGE_MARGIN * (bounds[:, 1] - bounds[:, 0])
        with np.errstate(invalid="ignore"):
            return (x < bounds[which, 0] - margin[which]) | (x > bounds[which, 1] + margin[which])

    @property
    def difference_ranges(self) -> list | None:
        """Each range's [lo, hi] of temp − temp_outside it was fitted over (the difference regressor), or None."""
        if self.regressor != "difference" or not all("difference_range" in seg for seg in self.segments):
            return None
        return [seg["difference_range"] for seg in self.segments]

    def differences_words(self, temp, x, unseen, where: str = "sample", labels=None,
                          option: str = "outside='nan' (--outside-range nan)") -> str:
        """The error for samples whose temp − temp_outside the model was not fitted over (beyond_differences);
        `option`: how the caller spells the NaN option."""
        k = int(np.flatnonzero(unseen)[0])
        seg = self.segments[int(range_index(self.segments, np.asarray(temp, dtype=float)[k:k + 1])[0])]
        lo, hi = (float(v) for v in seg["difference_range"])
        return (f"{where} {k if labels is None else labels[k]}: temp − temp_outside {float(x[k]):g} °C at temp "
                f"{float(temp[k]):g} °C is outside what the model's range [{seg['range'][0]:g}, {seg['range'][1]:g}] "
                f"°C was fitted over ({lo:g} … {hi:g} °C; {int(unseen.sum())} of {unseen.size} samples outside): "
                f"the polynomials are not extrapolated; pass {option} to mark them NaN and compensate the rest, or "
                "fit the drift over the differences the device will meet")

    def compensate(self, zero_bias, temp, temp_outside=None, outside: str = "error") -> np.ndarray:
        """W_c = W − f(T). A temperature outside every range: ValueError, or NaN with outside="nan"."""
        w = ts.as_series(zero_bias, "zero_bias")
        f = self.evaluate(temp, temp_outside, outside)
        if f.size != w.size:
            raise ValueError(f"zero_bias: {w.size} samples, temp has {f.size}")
        return w - f

    def to_dict(self) -> dict:
        return {"kind": "fluxcal drift model", "regressor": self.regressor,
                "segments": [{"range": list(map(float, s["range"])), "order": int(s["order"]),
                              "coefficients": list(map(float, s["coefficients"])),
                              **{k: v for k, v in s.items() if k not in ("range", "order", "coefficients")}}
                             for s in self.segments],
                **self.settings, "summary": self.summary}

    @classmethod
    def from_dict(cls, data: dict, source: str = "drift model") -> "DriftModel":
        try:
            segments = data["segments"]
            previous_hi = None
            for k, s in enumerate(segments):
                if len(s["range"]) != 2:
                    raise ValueError(f"{source}: segment {k} has the range {s['range']}, expected [lo, hi]")
                lo, hi = (float(v) for v in s["range"])
                try:
                    coefficients = np.asarray(s["coefficients"], dtype=np.float64)
                except ValueError:
                    raise ValueError(f"{source}: segment {k} [{lo:g}, {hi:g}] has coefficients that are not numbers: "
                                     f"{s['coefficients']!r}") from None
                # A NaN coefficient made every temperature of the range compensate to NaN.
                if not np.all(np.isfinite(coefficients)):
                    raise ValueError(f"{source}: segment {k} [{lo:g}, {hi:g}] has a NaN/Inf coefficient: "
                                     f"{list(map(float, np.atleast_1d(coefficients)))}")
                if len(s["coefficients"]) != int(s["order"]) + 1:
                    raise ValueError(f"{source}: segment [{lo:g}, {hi:g}] has order {s['order']} but "
                                     f"{len(s['coefficients'])} coefficients")
                if s.get("covariance") is not None:  # (optional: models saved before fluxcal kept it have none)
                    try:
                        covariance = np.asarray(s["covariance"], dtype=np.float64)
                    except ValueError:
                        covariance = np.array([np.nan])
                    m = len(s["coefficients"])
                    if covariance.shape != (m, m) or not np.all(np.isfinite(covariance)):
                        raise ValueError(f"{source}: segment {k} [{lo:g}, {hi:g}] has a covariance that is not a "
                                         f"finite {m}×{m} matrix of numbers (one row and column per coefficient)")
                # Segments are looked up by ascending edges: a gap or an unsorted list would pick the wrong
                # polynomial without a word.
                if not (np.isfinite(lo) and np.isfinite(hi) and lo < hi):
                    raise ValueError(f"{source}: segment {k} has the range [{lo:g}, {hi:g}], not a finite range "
                                     "with lo < hi")
                if previous_hi is not None and lo != previous_hi:
                    raise ValueError(f"{source}: segment {k} [{lo:g}, {hi:g}] starts at {lo:g} but segment {k - 1} "
                                     f"ends at {previous_hi:g}; the ranges must be ascending and contiguous (no gaps, "
                                     "no overlaps)")
                previous_hi = hi
            if not segments:
                raise ValueError(f"{source}: the drift model has no segments")
        except (KeyError, TypeError) as exc:
            raise ValueError(f"{source}: not a drift model (missing or malformed {exc})") from None
        settings = {k: v for k, v in data.items() if k not in ("kind", "regressor", "segments", "summary")}
        return cls(segments=segments, regressor=data.get("regressor", "temp"), settings=settings,
                   summary=data.get("summary", {}))

    def save(self, path) -> Path:
        path = Path(path)
        data = self.to_dict()
        try:  # refuse to write what load would refuse (a NaN coefficient, …)
            self.from_dict(data, str(path))
        except ValueError as exc:
            raise ValueError(f"{exc} (not saved)") from None
        path.write_text(json.dumps(data, indent=2, default=_jsonable) + "\n")
        return path

    @classmethod
    def load(cls, path) -> "DriftModel":
        return cls.from_dict(load_json_object(path, "a fluxcal drift model"), str(path))


def _jsonable(v):
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (np.integer, np.floating, np.bool_)):
        return v.item()
    raise TypeError(f"not JSON serialisable: {type(v).__name__}")


def range_index(segments, temp) -> np.ndarray:
    """The range of `segments` (contiguous, ascending) each device temperature falls in: an inner edge belongs to the
    range above it (as the core evaluates); below the first or above the last, that one."""
    return np.searchsorted([float(seg["range"][0]) for seg in segments[1:]], np.asarray(temp, dtype=float),
                           side="right")


def fit_drift(zero_bias, temp, temp_outside=None, regressor: str = "temp", breakpoints=DEFAULT_BREAKPOINTS,
              max_order: int = 4, significance: float = 0.05, order: int | None = None, continuous: bool = False,
              whiten: bool = True, whiten_max_order: int = 10, min_samples: int = 10, breaks=None) -> DriftModel:
    """S5 alone: the piecewise polynomial drift of `zero_bias` (fit_pipeline passes the zero bias itself, or
    the Kalman-filtered L with drift_input="filtered"). breaks: gaps in time (fluxcal.timeseries.find_breaks),
    which the whitening filter does not reach across."""
    temp = ts.as_series(temp, "temp")
    w = ts.as_series(zero_bias, "zero_bias")
    x = _regressor(temp, temp_outside, regressor)
    options = _core.DriftOptions()
    options.breakpoints = [float(b) for b in breakpoints]
    options.max_order = int(max_order)
    options.significance = as_number(significance, "significance")
    options.order = -1 if order is None else int(order)
    options.continuous = bool(continuous)
    options.whiten = bool(whiten)
    options.whiten_max_order = int(whiten_max_order)
    options.min_samples = int(min_samples)
    options.breaks = ts.as_breaks(breaks, w.size)
    r = _core.fit_drift(temp, np.ascontiguousarray(x), w, options)
    segments = list(r["segments"])
    for seg in segments:  # what each range's polynomial saw of its variable: the difference's (beyond_differences)
        seen = seg.pop("x_range")
        if regressor == "difference" and np.all(np.isfinite(seen)):
            seg["difference_range"] = [float(v) for v in seen]
        seg["covariance"] = np.asarray(seg["covariance"]).tolist()  # (plain lists: the model is saved as JSON)
        seg["standard_errors"] = np.asarray(seg["standard_errors"]).tolist()
    # the edges the fit used: the given ones made to cover the data (the core says so in the warnings)
    used = [float(segments[0]["range"][0])] + [float(seg["range"][1]) for seg in segments]
    settings = {"breakpoints": used, "max_order": options.max_order,
                "significance": options.significance, "continuous": options.continuous, "whiten": options.whiten,
                "noise_ar": np.asarray(r["noise_ar"]).tolist()}
    summary = dict(r["summary"])
    # the core's note that it adjusted the ranges (one of its warnings), kept by name for fit_warnings: told by what
    # the fit did, not by its words
    summary["range_notes"] = [r["range_note"]] if r["range_note"] else []
    return DriftModel(segments=segments, regressor=regressor, settings=settings, summary=summary)


def accuracy(residual, rated: float, accuracy_class: str = "0.2S") -> dict:
    """Ratio error that a residual zero bias causes at 1/5/20/100/120 % of rated current against the
    IEC 61869 limits of `accuracy_class` ("0.2S" or "0.5S"): error % = 100 · max|residual| / (I_pct)."""
    if accuracy_class not in IEC_LIMITS:
        raise ValueError(f"accuracy_class: {accuracy_class!r} is not one of {', '.join(IEC_LIMITS)}")
    if not rated > 0:
        raise ValueError(f"rated: {rated} must be > 0")
    residual = _finite(ts.as_series(residual, "residual"), "residual")  # a NaN gave "met": False without a word
    if residual.size == 0:
        raise ValueError("residual: empty, no samples to assess")
    worst = float(np.max(np.abs(residual)))
    points = []
    for pct, limit in zip(CURRENT_POINTS, IEC_LIMITS[accuracy_class]):
        err = 100.0 * worst / (pct / 100.0 * rated)
        points.append({"percent_rated": pct, "ratio_error_percent": err, "limit_percent": limit, "met": err <= limit})
    return {"class": accuracy_class, "rated": rated, "max_abs_residual": worst, "points": points,
            "met": all(p["met"] for p in points)}


def level_bins(temp, step: float = 5.0) -> np.ndarray:
    """Each sample's temperature level: its temperature rounded to a multiple of `step` (the chamber's holds)."""
    return np.round(np.asarray(temp, dtype=float) / step) * step


def level_means(values, temp, step: float = 5.0) -> dict:
    """Mean of `values` in each temperature bin of width `step` centred on multiples of `step`
    (the chamber's hold levels)."""
    values = _finite(ts.as_series(values, "values"), "values")
    temp = _finite(ts.as_series(temp, "temp"), "temp")
    if temp.size != values.size:
        raise ValueError(f"temp: {temp.size} samples, values has {values.size}")
    if values.size == 0:
        raise ValueError("values: empty, no samples to average")
    if not (np.isfinite(step) and step > 0):  # 0 divided by zero, a negative step was taken as given
        raise ValueError(f"step: {step} must be a finite number > 0")
    bins = level_bins(temp, step)
    return {float(b): float(values[bins == b].mean()) for b in np.unique(bins)}


def drift_span(values, temp, step: float = 5.0) -> float:
    """Peak-to-peak of the per-level means: the zero-bias drift over the temperature span, noise averaged."""
    m = np.array(list(level_means(values, temp, step).values()))
    return float(m.max() - m.min())


def dc_gain(kalman: ArKalman) -> float:
    """Output per unit constant input of the steady-state filter: e1ᵀ (I − F)⁻¹ K, F = (I − K e1ᵀ) A: how a
    slow input passes the filter (fit_pipeline keeps the drift out of the filter, so it no longer divides by it)."""
    n = kalman.order
    A = np.zeros((n, n))
    A[0] = kalman.ar_coeffs
    A[np.arange(1, n), np.arange(n - 1)] = 1.0
    K = kalman.steady_gain
    F = (np.eye(n) - np.outer(K, np.eye(n)[0])) @ A
    return float(np.linalg.solve(np.eye(n) - F, K)[0])


def temperature_glitches(temp, run: int = 3) -> np.ndarray:
    """Rows where a logged temperature leaves its course for at most `run` samples farther than a temperature
    can: a thermometer's error code (85 °C at a DS18B20's power-on, −127, 327.67 = 32767/100) or a garbled line.
    Two rules, either suffices, neither has a constant to tune (the departure is from the running median over
    2·run + 1 samples; the first and last `run` rows take the median of the first or last 2·run + 1, a window
    within the log: mirrored at the ends, three glitches at the start filled five of its seven samples and were
    the median, and a genuine first row next to them was blamed):
      - the departure exceeds the whole range of the rest by more than the thermometer's resolution (a 327.67
        in a −20…50 °C log had stretched the last range to 327.67 °C and cut the drift reduction from 937× to
        2.8×; a 1/16 °C step off a hold that never moved is no glitch);
      - the departure exceeds run·D, D the largest step |ΔT| between consecutive samples of the rest: the median
        of a series whose steps never exceed D lies within run·D of its centre sample, so no temperature the
        rest of the log moves like departs that far (an 85 °C at 23 °C in a −40…70 °C log, within the range
        of the rest, had changed a class-0.2S verdict and stretched the last range to 85 °C). D is taken over
        the steps that touch none of the largest departures (a hundredth of the samples, twice as many while
        every one of them is beyond the limit that gives), so that several glitches do not hide each other, and
        is at least the thermometer's resolution (its smallest nonzero step: a quantised hold that seldom moves
        is no glitch).
    A row the second rule finds is judged again against its window without the other rows found (the median of
    a genuine row beside a block of glitches is pulled along a fast ramp by them).
    Rows found at an end of the log (a block from the first row, or to the last, within `run` rows) are kept only
    when the block steps into the rest farther than run times its own largest step in that direction (and than
    run·D): a glitch jumps back to the course, while a log that starts (or ends) on a fast warm-up ramp moves into
    it by ever smaller steps, which neither the rest's range nor D (taken without those rows' steps) allows for.
    A slow log's steps are its own scale: at one sample per 10 min on a 1 °C/min ramp D is 10 °C."""
    from scipy.ndimage import median_filter

    t = np.asarray(temp, dtype=float)
    n = len(t)
    if n < 2 * run + 2 or not np.all(np.isfinite(t)):
        return np.zeros(0, dtype=int)
    size = 2 * run + 1
    course = median_filter(t, size=size, mode="nearest")  # (the ends' are replaced: a window within the log)
    course[:run], course[n - run:] = np.median(t[:size]), np.median(t[n - size:])
    off = np.abs(t - course)
    order = np.argsort(-off, kind="stable")  # the largest departures first
    steps = np.abs(np.diff(t))
    moved = steps[steps > 0]
    resolution = float(moved.min()) if moved.size else 0.0
    rows = set()
    for i in order[:max(1, n // 100)]:  # the whole-range rule, a hundredth at most
        rest = t[off < off[i]]  # (without it and the glitches beyond it)
        if len(rest) < n // 2 or not off[i] > np.ptp(rest) + resolution:
            break
        rows.add(int(i))

    def limit(count):  # run·D, D over the steps that touch none of the `count` largest departures
        top = order[:count]
        touched = np.zeros(n - 1, dtype=bool)
        touched[top[top < n - 1]] = True  # the step after each
        touched[top[top > 0] - 1] = True  # and the one before
        free = steps[~touched]
        return run * max(float(free.max()) if free.size else 0.0, resolution)

    count = max(1, n // 100)
    # more glitches than that (every candidate beyond the limit that twice as many give): take twice as many
    while 2 * count <= n // 4 and off[order[count - 1]] > limit(2 * count):
        count *= 2
    beyond = limit(count)
    stepped = {int(i) for i in order[:count] if off[i] > beyond} - rows  # (descending: a leading run of them)
    # A genuine row beside a block of glitches on a fast ramp departs from a median the glitches pulled along it
    # (three 85 °C readings before a warm-up: the fourth row, on the ramp, was named): judged again against its
    # window without the others found
    found = rows | stepped
    for i in stepped:
        a = min(max(i - run, 0), n - size)
        kept = [j for j in range(a, a + size) if j == i or j not in found]
        if abs(t[i] - np.median(t[kept])) > beyond:
            rows.add(i)
    return np.array(sorted(rows - _ramps_at_the_ends(t, rows, run, beyond)), dtype=int)


def held_blocks(values) -> list:
    """[(first row, last row)] of the blocks of two or more consecutive samples that hold one value to the last
    digit (a stuck thermometer's, a frozen readout's)."""
    from .outliers import _runs

    return [(int(a), int(b) + 1) for a, b in _runs(np.diff(np.asarray(values, dtype=float)) == 0)]


def temperature_holds(temp, run: int = 3) -> list:
    """[(first row, last row)] of the blocks longer than `run` samples where a logged temperature holds one value to
    the last digit and the log jumps into or out of it farther than run·D (D the largest step of the rest, at least
    the thermometer's resolution, as temperature_glitches takes it): a thermometer's error code held for many
    samples (a DS18B20's 85 °C through a brown-out), or a sensor stuck on its last reading while the element's
    temperature moved on (a blind check: 601 samples at 49.99 °C while it fell to 43 °C, the top range 0.97 A off,
    said by nothing). A quantised hold (a chamber's plateau) leaves it by one resolution step: no jump."""
    t = np.asarray(temp, dtype=float)
    n = len(t)
    if n < 2 * run + 2 or not np.all(np.isfinite(t)):
        return []
    held = [(a, b) for a, b in held_blocks(t) if run < b - a + 1 < n]
    if not held:
        return []
    steps = np.abs(np.diff(t))
    edge = np.zeros(n - 1, dtype=bool)  # the steps into and out of the held blocks
    for a, b in held:
        edge[[k for k in (a - 1, b) if 0 <= k < n - 1]] = True
    moved = steps[steps > 0]
    resolution = float(moved.min()) if moved.size else 0.0
    free = steps[~edge]
    beyond = run * max(float(free.max()) if free.size else 0.0, resolution)
    return [(int(a), int(b)) for a, b in held
            if max(steps[a - 1] if a > 0 else 0.0, steps[b] if b < n - 1 else 0.0) > beyond]


def hold_words(temp, holds, word: str = "row", labels=None) -> str:
    """`temperature_holds`' blocks said: where (`labels` of the rows, e.g. file lines), the value held, how long,
    the jump, and the remedy."""
    t = np.asarray(temp, dtype=float)
    labels = np.arange(len(t)) if labels is None else np.asarray(labels)

    def jump(a, b):
        return max(abs(t[a] - t[a - 1]) if a > 0 else 0.0, abs(t[b + 1] - t[b]) if b + 1 < len(t) else 0.0)

    shown = "; ".join(f"{word}s {labels[a]}–{labels[b]} read {t[a]:g} °C ({b - a + 1} samples, then a jump of "
                      f"{jump(a, b):.3g} °C)" for a, b in holds[:3])
    return (f"the temperature holds one value to the last digit and jumps {'into or out of it' if len(holds) == 1 else 'at those'} "
            f"farther than the rest of the log ever steps ({shown}{'; …' if len(holds) > 3 else ''}): a thermometer "
            "stuck on its last reading, or an error code held (85 °C: a DS18B20 at power-on; −127 °C: disconnected) "
            "— fitted as temperatures they bias the model and stretch its ranges; remove those rows, or leave their "
            "temperature empty and pass --bad-lines skip")


def _ramps_at_the_ends(t: np.ndarray, found: set, run: int, beyond: float) -> set:
    """The rows of `found` (temperature_glitches') that are a genuine ramp at an end of the log: a block of them
    from the first row (or to the last), within the first (last) `run` rows, that steps into the rest by no more
    than `run` times its own largest step in that direction, or than `beyond` (run·D)."""
    n, ramps = len(t), set()
    for start, direction in ((0, 1), (n - 1, -1)):  # from the first row forwards, from the last backwards
        block = []
        i = start
        while i in found and len(block) < run:
            block.append(i)
            i += direction
        if not block or i in found:  # none, or the block reaches past the ends' rows (judged by centred windows)
            continue
        # in time order: the block's own steps, and the step between it and the rest
        inside = np.diff(t[min(block):max(block) + 1])
        into = t[i] - t[block[-1]] if direction == 1 else t[block[-1]] - t[i]
        along = inside[np.sign(inside) == np.sign(into)]
        if abs(into) <= max(beyond, run * (float(np.abs(along).max()) if along.size else 0.0)):
            ramps.update(block)
    return ramps


class TemperatureGlitches(ValueError):
    """fit_pipeline's error for readings `temperature_glitches` finds; `rows` holds them (the CLI names their file
    lines)."""

    def __init__(self, message: str, rows, holds=None):
        super().__init__(message)
        self.rows = np.asarray(rows, dtype=int)
        self.holds = holds  # temperature_holds' blocks, when those are what was found


def glitch_words(temp, rows, word: str = "row", labels=None) -> str:
    """`temperature_glitches`' rows said: where (`labels`, e.g. file lines, else the rows), what they read, and
    the remedy."""
    labels = rows if labels is None else labels
    shown = ", ".join(f"{word} {k}: {temp[i]:g} °C" for i, k in zip(rows[:5], labels[:5]))
    return (f"{len(rows)} reading(s) leave the temperature's course and come back within 3 samples, farther than "
            "a temperature the rest of the log follows can (by more than the whole range of the rest, or than 3 of "
            f"its largest steps) ({shown}{', …' if len(rows) > 5 else ''}): a thermometer's error code or a garbled "
            "line, which would stretch the model's ranges and bias its fit; remove them, or leave their temperature "
            "empty and pass --bad-lines skip")


# A zero-bias spike is flagged at this family-wise false-alarm rate over the log (Bonferroni): Gaussian noise about
# the drift flags about one log in a hundred, a readout glitch 20–100 σ off is found whatever the log's length
SPIKE_ALPHA = 0.01


# A median absolute deviation's efficiency against the standard deviation's for Gaussian data: its variance is that
# of a standard deviation from 37 % as many samples
MAD_EFFICIENCY = 0.37


def _correlation_factor(x: np.ndarray, lags: int = 50) -> float:
    """1 + 2 Σ ρₖ² over the first `lags` autocorrelations of x: how many times fewer independent values a scale
    estimated from a stretch of x has than its samples (Bartlett's variance of a variance)."""
    y = x - np.mean(x)
    denominator = float(y @ y)
    if not denominator > 0:
        return 1.0
    rho = np.array([float(y[:-k] @ y[k:]) / denominator for k in range(1, min(lags, y.size // 4) + 1)])
    return 1.0 + 2.0 * float(np.sum(rho ** 2))


def zero_bias_spikes(noise, run: int = 3, breaks=(), steps=()) -> tuple[np.ndarray, np.ndarray]:
    """Rows where the zero bias's noise about the drift (`noise`, zero bias − a first drift model) leaves its course
    for at most `run` samples farther than that noise can: a readout's glitch. For blocks of L = 1 … run samples, the
    block's mean less the mean of its two neighbours — a linear function of the noise, so Gaussian noise leaves it
    Gaussian (a running median's departures are not: on AR noise they flagged 1 % of a clean log) — against its own
    scale, a running MAD (robust to the spikes), at Bonferroni's limit for SPIKE_ALPHA over the log's samples (the
    1 … run blocks at a sample are nearly one test) and Student's t for the MAD's own uncertainty,
    standing off both neighbours on the same side (it comes back); each L after the shorter blocks found are
    bridged. (0.2 % of samples 0.2–1 A off, σ 0.01 A, had turned an AR(1) 0.70 into AR(4) 0.08 … and passed through
    the Kalman filter, with only "kurtosis 276" said.) No block is judged across a gap in time (`breaks`: the samples
    after one) or a step of the model (`steps`: where the temperature crosses a breakpoint); a block at the log's
    ends or beside a gap is judged against its one neighbour, at that difference's own scale (the first reading after
    a recorder's pause is as likely to glitch as any). Returns (rows, their departures in their block's scale)."""
    from scipy import stats
    from scipy.ndimage import median_filter

    x = np.array(noise, dtype=float)
    n = x.size
    rows, sizes = [], []
    if n < 20 * run:
        return np.zeros(0, dtype=int), np.zeros(0)
    course = median_filter(x, size=2 * run + 1, mode="mirror")
    cuts = sorted(set(int(b) for b in breaks) | set(int(b) for b in steps))
    starts, ends = [0] + cuts, cuts + [n]  # the stretches no block reaches across
    gaps = set(int(b) for b in breaks)
    size = int(np.clip(2 * (n // 40) + 1, 201, 4001))  # the running MAD's window
    for length in range(1, run + 1):
        k = np.arange(1, n - length)  # blocks x[k:k+length] with a neighbour on each side, within one stretch
        k = k[~np.isin(k, [b - j for b in cuts for j in range(length + 1)])]
        block = np.mean([x[k + j] for j in range(length)], axis=0)
        d = block - 0.5 * (x[k - 1] + x[k + length])
        # the scale where the block is: a running MAD (the noise about the drift grows where the drift is steep, by
        # the thermometer's noise times f'(T): one MAD over the log flagged a newcomer's clean log 3 times at 5 σ)
        scale = 1.4826 * median_filter(np.abs(d - np.median(d)), size=size, mode="mirror")  # (not the edge repeated)
        if not np.any(scale > 0):
            continue
        scale = np.where(scale > 0, scale, np.inf)
        # the running MAD is itself an estimate, from fewer independent values where the noise is correlated: judged
        # at Student's t for its degrees of freedom (a MAD's 37 % of the window, over 1 + 2 Σ ρ²), not the normal's
        # (a blind check's clean logs of AR noise had 1.7–3.3 % flagged for the nominal 1 %; now 0–0.7 %, white 0.3 %
        # as before, and an 8 σ spike in white noise found 90 times in 100, 92 before)
        limit = float(stats.t.isf(SPIKE_ALPHA / (2 * n), max(MAD_EFFICIENCY * size / _correlation_factor(d), 3.0)))
        # …and it comes back: the block stands off each neighbour, on the same side, by half of d at least (a kink
        # of a misfit drift, flat then steep at a ramp's start, stands off one neighbour only), and off the running
        # median of 2·run + 1 samples (a clean sample between two glitches stands off both, not off the median)
        left, right = block - x[k - 1], block - x[k + length]
        off = block - np.mean([course[k + j] for j in range(length)], axis=0)
        back = ((np.sign(left) == np.sign(right)) & (np.minimum(np.abs(left), np.abs(right)) >= 0.5 * np.abs(d))
                & (np.sign(off) == np.sign(d)) & (np.abs(off) >= 0.5 * np.abs(d)))
        # at an end (the log's, or a gap's): the block less its one neighbour, scaled by the running MAD there times
        # the ratio of the one-sided difference's MAD to the two-sided one's over the log (1.15 for white noise)
        one = block - x[k + length]
        ratio = float(np.median(np.abs(one - np.median(one))) / max(np.median(np.abs(d - np.median(d))), 1e-300))
        edge_k, edge_d, edge_scale, edge_back = [], [], [], []
        for lo, hi in zip(starts, ends):
            if hi - lo < 2 * run + 2:
                continue
            for at, nb, judged in ((lo, lo + length, lo == 0 or lo in gaps), (hi - length, hi - length - 1,
                                                                             hi == n or hi in gaps)):
                if not judged:
                    continue
                here = float(np.mean(x[at:at + length]))
                dd = here - x[nb]
                near = int(np.clip(np.searchsorted(k, at), 0, k.size - 1))
                edge_k.append(at)
                edge_d.append(dd)
                edge_scale.append(scale[near] * ratio)
                # its course from the samples on its one side (the running median there, mirrored at the end, had
                # followed a 3-sample glitch in the first rows: a review)
                side = x[at + length:at + length + 2 * run + 1] if at == lo else x[max(lo, at - 2 * run - 1):at]
                o = here - float(np.median(side))
                edge_back.append(np.sign(o) == np.sign(dd) and abs(o) >= 0.5 * abs(dd))
        k, d = np.concatenate([k, edge_k]).astype(int), np.concatenate([d, edge_d])
        scale, back = np.concatenate([scale, edge_scale]), np.concatenate([back, np.asarray(edge_back, dtype=bool)])
        found = np.flatnonzero((np.abs(d) > limit * scale) & back)
        for i in found[np.argsort(-np.abs(d[found]))]:
            start = int(k[i])
            if any(start <= r < start + length for r in rows) or any(r in (start - 1, start + length) for r in rows):
                continue  # (a block beside or over one found: the same spike seen again)
            rows.extend(range(start, start + length))
            sizes.extend([float(d[i] / scale[i])] * length)
            # bridged for the longer blocks: the mean of its neighbours (the one it has at an end)
            neighbours = [x[j] for j in (start - 1, start + length) if 0 <= j < n and not (j < start and start in cuts)
                          and not (j >= start + length and start + length in cuts)]
            x[start:start + length] = np.mean(neighbours)
    order = np.argsort(rows)
    return np.asarray(rows, dtype=int)[order], np.asarray(sizes)[order]


def spike_words(rows, sigmas, word: str = "row", labels=None, dropped: bool = False) -> str:
    """`zero_bias_spikes`' rows said: where (`labels`, e.g. file lines, else the rows), how far off (`sigmas`, in the
    noise's σ), what they do, and the remedy."""
    labels = rows if labels is None else labels
    shown = ", ".join(f"{word} {k}: {z:+.0f} σ" for z, k in zip(sigmas[:5], labels[:5]))
    said = (f"{len(rows)} zero-bias sample(s) leave the noise's course and come back within 3 samples, farther than "
            f"the noise about the drift can ({shown}{', …' if len(rows) > 5 else ''}): a readout's glitch")
    if dropped:
        return said + "; left out of the fit (the AR model, the Kalman filter and the class check)"
    return (said + ", which distorts the AR model of the noise (its order and coefficients), passes through the "
            "Kalman filter and fails the sample-by-sample class check; leave them out (--drop-spikes, "
            "fit_pipeline(spikes=\"drop\")) or find the readout's fault")


def frozen_runs(values, run: int = 3) -> list:
    """[(first row, last row)] of the blocks longer than `run` samples where the zero bias holds one value to the last
    digit for longer than its own noise allows: a readout frozen on its last value (a blind check's 101 identical
    samples were said by nothing, their last 3 called spikes). A block of L samples is that unlikely when
    (n − 1) · p · q^(L − 2) < SPIKE_ALPHA, p the chance that a sample repeats the one before and q that a repeat
    follows a repeat, both counted without the blocks as long as it or longer (plus one: a continuous readout that
    never repeats still allows 8), and when it is more than twice the longest of the shorter blocks (a quantised
    readout's repeats come in runs of every length; judged by a geometric tail alone, the longest of them was named in
    up to 17 of 100 clean logs). A readout that repeats its last value more often than 9 times in 10 (its quantum
    far above its noise) holds values by nature: not judged."""
    x = np.asarray(values, dtype=float)
    n = x.size
    if n < 2 * run + 2 or not np.all(np.isfinite(x)):
        return []
    same = np.diff(x) == 0
    if same.mean() > 0.9:
        return []
    blocks = held_blocks(x)
    lengths = np.array([b - a + 1 for a, b in blocks], dtype=int)
    # per block, its counts without the blocks as long or longer (no repeat pair spans two blocks: a block of L
    # holds L − 1 repeats and L − 2 pairs of them)
    sizes = np.unique(lengths[(lengths > run) & (lengths < n)])  # the block lengths judged
    big = np.sort(lengths)
    above = np.searchsorted(big, sizes)  # the blocks as long or longer: big[above:]
    drop_repeats = np.array([np.sum(big[k:] - 1) for k in above])
    drop_pairs = np.array([np.sum(big[k:] - 2) for k in above])
    rest = same.sum() - drop_repeats
    p = (rest + 1.0) / (n - 1 - drop_repeats + 2.0)
    q = (np.sum(same[1:] & same[:-1]) - drop_pairs + 1.0) / (rest + 2.0)
    shorter = np.concatenate([[1], big])[above]  # the longest block shorter than each (1: none repeats)
    unlikely = {int(size) for size, pp, qq, m in zip(sizes, p, q, shorter)
                if (n - 1) * pp * qq ** (size - 2) < SPIKE_ALPHA and size > 2 * max(m, 1)}
    return [(a, b) for (a, b), size in zip(blocks, lengths) if int(size) in unlikely]


def frozen_words(values, runs, word: str = "row", labels=None, unit: str = "") -> str:
    """`frozen_runs`' blocks said: where (`labels` of the rows, e.g. file lines), the value held, how long, and the
    remedy."""
    x = np.asarray(values, dtype=float)
    labels = np.arange(x.size) if labels is None else np.asarray(labels)
    shown = "; ".join(f"{word}s {labels[a]}–{labels[b]} read {x[a]:.10g}{unit} ({b - a + 1} samples)" for a, b in runs[:3])
    return (f"the zero bias holds one value to the last digit for longer than its noise ever does "
            f"({shown}{'; …' if len(runs) > 3 else ''}): a readout frozen on its last value? Fitted as data, they "
            "pull the drift model there and bend the AR model of the noise; remove those rows, or leave their zero bias "
            "empty and pass --bad-lines skip")


# The temperatures an FOCT's own thermometer reads in service: an outdoor substation's ambient to the rating of its
# electronics, about −40…+85 °C (temperature_unit_hint).
DEVICE_TEMPERATURES = (-40.0, 85.0)
# How far beyond that (or the fit's ranges, if wider) a genuine °C log still reaches: a cold start below the rating, a
# sun-loaded enclosure, a sensing head near a hot conductor. 15 °C keeps a −45 °C cold start and a 95 °C hot log
# quiet, while a −20…50 °C chamber cycle logged in °F (−4…122) is beyond it, and anything in K (≥ 218 for −55 °C).
UNIT_OVERSHOOT = 15.0
# temperature_unit_hint's tolerance on the ranges' edges, a fraction of their span: a chamber's hold temperature as the
# device reads it (control, the device's lag and self-heating, its thermometer's error), a few °C on −20…50 °C.
UNIT_EDGE_TOLERANCE = 0.05
# the units temperature_unit_hint tries (io.columns.TO_CELSIUS converts them), and how to state each in a file
_OTHER_UNITS = (("F", "°F", "degF", "_F"), ("K", "K", "K", "_K"))


def temperature_unit_hint(temp, breakpoints=DEFAULT_BREAKPOINTS, name: str = "temp") -> str | None:
    """A warning when temperatures taken as °C look like °F or K logged with no unit, else None.

    fluxcal converts a column whose unit is stated (a '# units:' line, temp_F, 'Temperature (°F)'); an unstated
    unit is °C, and a log in °F or K then fits without an error: the ranges are adjusted to the numbers and the
    model is in °F or K numbers taken for °C (seed 001's breakpoints 0 and 30 fall at −18 and −1 °C, a °C file
    applied to it later is compensated wrongly or refused; the newcomer's −20…50 °C cycle in °F: drift 22.9× smaller
    and the AR model rejected, against 938× and white residuals with the unit stated). Said when the readings leave
    the ranges (by more than UNIT_EDGE_TOLERANCE of their span) and either
      - as °C they are beyond what the device meets — DEVICE_TEMPERATURES widened to the ranges, plus
        UNIT_OVERSHOOT — and in °F or K they are within it, or
      - in °F or K they span the ranges edge to edge (within the tolerance): a chamber cycle over the ranges,
        which a °C log leaving them cannot do (its span would have to be 1.8 times theirs, from 1.8 lo + 32).
    A °C log reaching a little beyond the ranges is neither: −45…50 °C is −43…10 °C as °F, 20…95 °C is within
    the overshoot. Readings beyond the device's temperatures that no unit explains (raw counts, another
    quantity) are said too. A warning, not an error: the fit is not void (it compensates this file in its own
    numbers), and a device really that hot or cold must still be fittable."""
    from .io.columns import TO_CELSIUS  # the readers' conversion of a stated unit, the same here

    t = np.asarray(temp, dtype=float)
    t = t[np.isfinite(t)]
    try:
        edges = np.asarray([float(b) for b in breakpoints])
    except (TypeError, ValueError):
        return None  # (fit_drift says what is wrong with them)
    if t.size == 0 or edges.size < 2 or not np.all(np.isfinite(edges)) or not np.ptp(edges) > 0:
        return None
    lo, hi = float(edges.min()), float(edges.max())
    a, b = float(t.min()), float(t.max())
    tol = UNIT_EDGE_TOLERANCE * (hi - lo)
    if a >= lo - tol and b <= hi + tol:
        return None  # within the ranges: nothing to explain
    cold, hot = min(lo, DEVICE_TEMPERATURES[0]) - UNIT_OVERSHOOT, max(hi, DEVICE_TEMPERATURES[1]) + UNIT_OVERSHOOT
    implausible = a < cold or b > hot

    def beyond(x, y):  # how far [x, y] reaches beyond the ranges, °C
        return max(0.0, lo - x) + max(0.0, y - hi)

    hits = []
    for unit, sign, stated, suffix in _OTHER_UNITS:
        ca, cb = TO_CELSIUS[unit](a), TO_CELSIUS[unit](b)
        spans = abs(ca - lo) <= tol and abs(cb - hi) <= tol
        if spans or (implausible and ca >= cold and cb <= hot):
            hits.append((beyond(ca, cb), sign, ca, cb, stated, suffix, spans))
    seen = f"{name}: {a:.4g} … {b:.4g} read as °C"
    if not hits:
        if not implausible:
            return None
        return (f"{seen} is beyond the {cold:g} … {hot:g} °C an FOCT's temperature reaches (about "
                f"{DEVICE_TEMPERATURES[0]:g} … {DEVICE_TEMPERATURES[1]:g} °C in service), and as °F or K too: is "
                f"{name} the device temperature, in °C? Name the right column (--temp-column) or state its unit")
    _, sign, ca, cb, stated, suffix, spans = min(hits, key=lambda h: h[0])  # the unit nearest the ranges
    why = (f"beyond the {cold:g} … {hot:g} °C an FOCT's temperature reaches" if implausible else
           f"{beyond(a, b):.3g} °C beyond the ranges [{lo:g}, {hi:g}]")
    fits = ", the ranges edge to edge" if spans else (", within the ranges" if beyond(ca, cb) <= tol else "")
    return (f"{seen} is {why}; in {sign} it would be {ca:.3g} … {cb:.3g} °C{fits}. Is {name} in {sign}? State "
            f"its unit ('# units: {name}={stated}' in a CSV, or name the column {name}{suffix}) and fit again: as it "
            f"is, the model's ranges are {sign} numbers taken for °C")


def outside_ranges_words(model: "DriftModel", temp, option: str, counted=None, name: str = "temp", where: str = "",
                         word: str = "sample", labels=None, source: str = "the drift model") -> str | None:
    """The error for temperatures outside every range of `model` (DriftModel.evaluate's and drift apply's, one
    text), or None when none is: where the first one is (`where`, e.g. the file, then `word` and its label in
    `labels`, e.g. its file line, else its 0-based sample), what `name` reads there, `source`'s ranges, how many are
    outside, and the remedies (not_extrapolated_words: a unit's hint, `option` — how the caller spells the NaN
    option — or a fit over the temperatures the device will meet). counted: a mask of the samples that count
    (drift apply: those with a zero-bias reading; the others are NaN whatever their temperature)."""
    t = np.asarray(temp, dtype=float)
    counted = np.ones(t.size, dtype=bool) if counted is None else np.asarray(counted, dtype=bool)
    beyond = np.flatnonzero(model.beyond_ranges(t) & counted)
    if not beyond.size:
        return None
    k = int(beyond[0])
    lo, hi = model.span()
    at = f"{word} {k if labels is None else labels[k]}"
    hint = outside_unit_hint(t[counted], lo, hi, name)
    return (f"{f'{where}, ' if where else ''}{at}: {name} {t[k]:g} °C is outside every range of {source} ({lo:g} … "
            f"{hi:g} °C; {beyond.size} of {t.size} samples outside): "
            + not_extrapolated_words(hint, f"pass {option} to mark them NaN and compensate the rest"))


def not_extrapolated_words(hint: str | None, use_nan: str) -> str:
    """The remedies for temperatures outside a model's ranges: a unit's `hint` (outside_unit_hint), else `use_nan`
    (how to mark them NaN, as the caller spells it) or a fit over the temperatures the device will meet."""
    return ("the polynomials are not extrapolated; " + (f"{hint}. Else: " if hint else "") + use_nan
            + ", or fit the drift over the temperatures the device will meet (a chamber cycle that reaches them)")


def outside_unit_hint(temp, lo: float, hi: float, name: str = "temp") -> str | None:
    """When temperatures of a log are outside a model's ranges [lo, hi] (°C): the unit that explains it, or None.
    Either the log's numbers are °F or K with no unit (converted, all fall within the ranges, and either span them
    edge to edge within UNIT_EDGE_TOLERANCE or as °C are beyond what an FOCT meets or are all outside: a log a
    few °C hotter than the model is not °F, nor all of them up to UNIT_OVERSHOOT past it), or, when every one is outside, the model's are (a model fitted on
    °F or K numbers taken for °C: its ranges, converted, hold the log and are temperatures an FOCT meets)."""
    from .io.columns import TO_CELSIUS

    t = np.asarray(temp, dtype=float)
    t = t[np.isfinite(t)]
    if t.size == 0 or not hi > lo:
        return None
    a, b = float(t.min()), float(t.max())
    margin = EDGE_MARGIN * (hi - lo)
    within = (t >= lo - margin) & (t <= hi + margin)
    if within.all():
        return None
    cold, hot = DEVICE_TEMPERATURES[0] - UNIT_OVERSHOOT, DEVICE_TEMPERATURES[1] + UNIT_OVERSHOOT
    tol = UNIT_EDGE_TOLERANCE * (hi - lo)
    for unit, sign, stated, suffix in _OTHER_UNITS:
        ca, cb = TO_CELSIUS[unit](a), TO_CELSIUS[unit](b)
        spans = abs(ca - lo) <= tol and abs(cb - hi) <= tol
        # (all outside counts only far outside: an overheat of 10 °C past the model, one value, is not °F)
        far = not within.any() and (a > hi + UNIT_OVERSHOOT or b < lo - UNIT_OVERSHOOT)
        if ca >= lo - margin and cb <= hi + margin and (spans or a < cold or b > hot or far):
            return (f"this log's {name} {a:.4g} … {b:.4g} would be {ca:.3g} … {cb:.3g} °C in {sign}, within the "
                    f"model's ranges {lo:.4g} … {hi:.4g} °C: is it in {sign}? State its unit ('# units: "
                    f"{name}={stated}' in a CSV, or name the column {name}{suffix})")
    for unit, sign, stated, suffix in _OTHER_UNITS if not within.any() else ():
        cl, ch = TO_CELSIUS[unit](lo), TO_CELSIUS[unit](hi)
        slack = EDGE_MARGIN * (ch - cl)
        if cl >= cold and ch <= hot and a >= cl - slack and b <= ch + slack:
            return (f"the model's ranges {lo:.4g} … {hi:.4g} read as {sign} would be {cl:.3g} … {ch:.3g} °C, "
                    "which "
                    f"hold this log's {a:.4g} … {b:.4g} °C: was the model fitted on a temperature in {sign} logged "
                    f"with no unit? Fit it again with the unit stated ('# units: temp={stated}' in a CSV, or a "
                    f"column named temp{suffix})")
    return None


# The warnings of a fit that describe how its ranges were set, not the model's validity (not repeated by
# fit_warnings: apply and export-c enforce the ranges) are kept by name, model.summary["range_notes"] (fit_drift,
# fit_pipeline), so that a reworded note is still left out. A model saved before that (no "range_notes") has only
# the words to go by: this part of the core's note.
_LEGACY_RANGE_NOTE = "adjusted to the data:"


def fit_warnings(model: "DriftModel") -> list:
    """The warnings of the fit that made `model` (fit_pipeline's report["warnings"], kept in
    model.summary["fit_warnings"]: a unit hint, an AR model rejected, a noise not stationary, …, then the drift
    fit's own, model.summary["warnings"]), for `drift apply` and `export-c` to repeat; the notes that the ranges
    were adjusted to the data (model.summary["range_notes"]) are left out. A model saved before fluxcal kept the
    fit's warnings has only the drift fit's."""
    said = list(model.summary.get("fit_warnings", []))
    said += [w for w in model.summary.get("warnings", []) if w not in said]
    if "range_notes" in model.summary:
        notes = set(model.summary["range_notes"])
        return [w for w in said if w not in notes]
    return [w for w in said if _LEGACY_RANGE_NOTE not in w]  # (a model saved before the notes were kept by name)


# A thermal lag (or hysteresis) is said when the compensated zero bias follows its term with a Newey–West p below
# LAG_P and that term takes at least LAG_SHARE of its variance (strict: slow correlated noise on long ramps is common)
LAG_P, LAG_SHARE = 1e-6, 0.1
# The temperature has turned (heating → cooling or back) once it has moved this share of its span, or 5 times its
# sample-to-sample noise if more, against its last extreme: the chamber's level steps, not the thermometer's noise
TURN_SHARE = 0.01
# A sample is settled (at a hold) where |dT/dt| is below this share of the ramps' (the 95th percentile): a log with
# a tenth of its samples settled has holds (a lag's error decays through them where hysteresis's stays)
SETTLED_RATE = 0.1
# A step of the zero bias in time is told from a slow wander where the level moves across its row by this many
# robust σ of how it moves across the other rows (_step_row)
STEP_MOVES = 5.0
# The named lag's τ and dead band's half-width are fitted (`_sized_beside_drift`) within this factor of the sizes
# their profiles gave (the profiles' grid values are about ×1.5 apart: the fit starts near)
SIZE_SEARCH = 4.0
# An effect significant alone but not beside those named is judged again in the state model (`_named_in_state`) on
# at most this many evenly spaced samples (a share of the residual sum of squares is judged, not its last digit: a
# 14 h cycle at 1 Hz is 51600; all of it took 4× the time)
STATE_ROWS = 10000


def _temperature_rate(temp: np.ndarray, time: np.ndarray, breaks=()) -> np.ndarray:
    """dT/dt from differences over a hundredth of the samples either side (the thermometer's noise then shrinks a
    lag's τ little), not across gaps."""
    n = temp.size
    m = max(1, n // 100)
    lo, hi = np.clip(np.arange(n) - m, 0, n - 1), np.clip(np.arange(n) + m, 0, n - 1)
    for b in breaks:  # a difference does not reach across a gap in time
        left, right = np.arange(n) < b, np.arange(n) >= b
        lo = np.where(right & (lo < b), b, lo)
        hi = np.where(left & (hi >= b), b - 1, hi)
    span = time[hi] - time[lo]
    return np.divide(temp[hi] - temp[lo], span, out=np.zeros(n), where=span > 0)


def temperature_branch(temp) -> np.ndarray:
    """Per sample +1 on a heating branch, −1 on a cooling one, 0 before the temperature first moved: the direction
    of its last move of more than a turn (TURN_SHARE of its span, or 5× its sample-to-sample noise) — a play operator
    of that half-width, so a hold keeps the branch that reached it, across gaps in time too."""
    temp = np.asarray(temp, dtype=float)
    steps = np.diff(temp)
    noise = 1.4826 * float(np.median(np.abs(steps - np.median(steps)))) / np.sqrt(2) if temp.size > 2 else 0.0
    turn = max(TURN_SHARE * float(np.ptp(temp)), 5.0 * noise, 1e-12)
    moves = np.sign(np.diff(play(temp, turn, "temp"), prepend=temp[0])).astype(int)
    last = np.maximum.accumulate(np.where(moves != 0, np.arange(temp.size), 0))  # its last move (0: none yet)
    return moves[last]


def _slope(model: "DriftModel", temp: np.ndarray) -> np.ndarray:
    """f'(T) by a central difference, within the model's ranges (NaN outside them)."""
    step = 1e-3 * max(float(np.ptp(temp)), 1e-9)
    above = np.minimum(temp + step, model.segments[-1]["range"][1])
    below = np.maximum(temp - step, model.segments[0]["range"][0])
    return (model.evaluate(above, outside="nan") - model.evaluate(below, outside="nan")) / (above - below)


def play(x, half_width, name: str = "x") -> np.ndarray:
    """A play operator (backlash) of `half_width`: its output moves only once the input has pushed it that far —
    the simplest hysteresis, e.g. a sensing coil's adhesive that follows the temperature with a dead band. Several
    half-widths give one column each (C++: a Python loop took 0.36 s of a 51k-sample cycle's 0.43 s fit)."""
    widths = np.atleast_1d(np.asarray(half_width, dtype=float))
    out = _core.play(np.ascontiguousarray(x, dtype=float), widths, name)
    return out[:, 0] if np.ndim(half_width) == 0 else out


def _profiled(w: np.ndarray, ok: np.ndarray, features: list, maxlags: int, given=(), signed: bool = False) -> dict:
    """The feature of `features` (one per grid value) that fits w best beside the `given` columns and a constant
    (least squares), its HAC (Newey–West) p and the share of var(w) it takes added last: {"best", "coefficient",
    "p", "share", "significant"} — significant: p below LAG_P, a share of at least LAG_SHARE of what the given
    columns leave, and (unless `signed`) a positive coefficient, the effect's own sign."""
    import statsmodels.api as sm

    rest = sm.add_constant(np.column_stack([np.asarray(g)[ok] for g in given]) if len(given) else
                           np.empty((int(ok.sum()), 0)), has_constant="add")
    designs = [np.column_stack([rest, g[ok]]) for g in features]
    solved = [np.linalg.lstsq(X, w[ok], rcond=None)[0] for X in designs]
    rss = [float(np.sum((w[ok] - X @ b) ** 2)) for X, b in zip(designs, solved)]
    # the best of the effect's own sign (a dead band's two senses are near negatives of each other: the best by
    # RSS alone could be the other sense's column, with its sign wrong and so "not significant")
    ranked = np.argsort(rss)
    best = next((int(i) for i in ranked if signed or solved[i][-1] > 0), int(ranked[0]))
    fit = sm.OLS(w[ok], designs[best]).fit(cov_type="HAC", cov_kwds={"maxlags": maxlags})
    share = _term_share(w[ok], designs[best], -1)
    left = float(np.var(w[ok] - rest @ np.linalg.lstsq(rest, w[ok], rcond=None)[0]) / max(np.var(w[ok]), 1e-300))
    p, coefficient = float(fit.pvalues[-1]), float(fit.params[-1])
    return {"best": best, "coefficient": coefficient, "p": p, "share": share,
            "significant": bool(p < LAG_P and share >= LAG_SHARE * left and (signed or coefficient > 0))}


def _named_jointly(w: np.ndarray, ok: np.ndarray, grids: dict, alone: dict, maxlags: int) -> tuple[list, dict]:
    """Which of the features in `grids` (name → (columns over its grid, signed)) the log shows, and their fits
    together: the one significant alone that explains most is named, then, one at a time, the feature that is
    significant beside those named (each re-profiled beside them) and explains most; after each, the named ones'
    grid values are re-profiled beside one another until they settle, and one no longer significant beside the
    others is dropped (and not tried again). Judged alone, one effect's feature takes up
    part of another's (a lag's error on a cycle looks like −0.010 A/h of ageing, so 0.01 A/h of ageing beside it had
    read −0.0003 A/h and gone unsaid; a lag beside a ±2 °C dead band read 1362 s for 540 s). → (named, fits)."""
    named, fits, dropped = [], {}, set()
    while True:
        trial = {}
        for name, (columns, signed) in grids.items():
            if name in named or name in dropped:
                continue
            given = [grids[k][0][fits[k]["best"]] for k in named]
            trial[name] = _profiled(w, ok, columns, maxlags, given, signed) if named else alone[name]
        trial = {k: r for k, r in trial.items() if r["significant"]}
        if not trial:
            return named, fits
        name = max(trial, key=lambda k: trial[k]["share"])
        named.append(name)
        fits[name] = trial[name]
        while len(named) > 1:
            _settle(w, ok, grids, named, fits, maxlags)
            weak = [k for k in named if not fits[k]["significant"]]  # taken up by those named after it
            if not weak:
                break
            gone = min(weak, key=lambda k: fits[k]["share"])
            named.remove(gone)
            dropped.add(gone)
            fits.pop(gone)
        if len(named) == 1:  # (left alone: judged alone again)
            fits[named[0]] = alone[named[0]]
            if not alone[named[0]]["significant"]:
                dropped.add(named.pop())


def _settle(w: np.ndarray, ok: np.ndarray, grids: dict, named: list, fits: dict, maxlags: int) -> None:
    """The named features' grid values re-profiled beside one another (coordinate descent) until they settle."""
    for _ in range(4):
        moved = False
        for k in named:
            given = [grids[j][0][fits[j]["best"]] for j in named if j != k]
            was = fits[k]["best"]
            fits[k] = _profiled(w, ok, grids[k][0], maxlags, given, grids[k][1])
            moved |= fits[k]["best"] != was
        if not moved:
            return


def _state_design(temp: np.ndarray, model: "DriftModel", orders: list, sizes: dict, step: float, breaks, rows,
                  trend: list, X: np.ndarray | None = None) -> np.ndarray:
    """The state model's columns at `sizes` ("lag" τ, "hysteresis" r; either may be absent): each range's polynomial
    (of `orders`) of the element's state — T through the lag, then the dead band — and the `trend` columns, on
    `rows` (None: all); into X when given (a copy of 51k rows per step spared)."""
    lo, hi = float(temp.min()), float(temp.max())
    state = _lagged(temp, step, sizes["lag"], breaks) if "lag" in sizes else temp
    if "hysteresis" in sizes:
        state = _banded(state, sizes["hysteresis"])
    state = np.clip(state if rows is None else state[rows], lo, hi)
    if X is None:
        X = np.zeros((state.size, sum(orders) + len(orders) + len(trend)))
    for j, column in enumerate(trend):
        X[:, X.shape[1] - len(trend) + j] = column if rows is None else column[rows]
    a = 0
    for k, (s, m) in enumerate(zip(model.segments, orders)):
        r0, r1 = (float(v) for v in s["range"])
        # (each sample in one range: a hold at a breakpoint in the upper one; the outer ranges open outwards)
        inside = ((state >= r0) | (k == 0)) & ((state < r1) | (k == len(orders) - 1))
        # (centred and scaled: T⁴ at 60 °C is 1e7)
        x = (state - 0.5 * (r0 + r1)) / max(0.5 * (r1 - r0), 1e-12)
        X[:, a:a + m + 1] = np.polynomial.polynomial.polyvander(x, m) * inside[:, None]
        a += m + 1
    return X


def _banded(state: np.ndarray, r: float) -> np.ndarray:
    """The state through a dead band of half-width |r|: a play operator for r > 0 (the element follows the thermometer
    only once pushed r away: heating, it reads T − r), its mirror 2T − play(T) for r < 0 (heating, T + |r|: the
    thermometer, not the element, follows through the dead band — a blind check's heating branch read as if hotter,
    measured at +0.04 A heating minus cooling with p 1e-134, and was never said)."""
    banded = play(state, abs(r), "temp")
    return banded if r > 0 else 2.0 * state - banded


def _state_fit(W: np.ndarray, ok: np.ndarray, temp: np.ndarray, model: "DriftModel", orders: list, start: dict,
               step: float, breaks=(), hours=None, xtol: float = 1e-4) -> tuple[dict, np.ndarray, np.ndarray]:
    """W (the zero bias) as the state model of the effects in `start` (name → size): the polynomials and the trend
    (if "ageing") by least squares for each (τ, r), and (τ, r) by non-linear least squares on log τ and log r,
    started at `start` and kept within SIZE_SEARCH of it, to a relative step of `xtol` in (τ, r) (1e-3 had stopped a
    first-order 600 s lag beside a band at 580 s). → (sizes, residual, polynomial and trend coefficients)."""
    from scipy.optimize import least_squares

    nonlinear = [k for k in ("lag", "hysteresis") if k in start and np.isfinite(start[k]) and _sized(k, start[k])]
    signs = np.array([np.sign(start[k]) for k in nonlinear])  # (a dead band's sense kept: log |r| fitted)
    trend = [hours] if "ageing" in start and hours is not None else []
    rows = None if ok.all() else ok
    y = W if rows is None else W[rows]
    X = np.zeros((y.size, sum(orders) + len(orders) + len(trend)))

    def fitted(z):
        _state_design(temp, model, orders, dict(zip(nonlinear, signs * np.exp(z))), step, breaks, rows, trend, X)
        # (normal equations: 51k rows, a few columns; rcond: a range the state hardly visits)
        b = np.linalg.lstsq(X.T @ X, X.T @ y, rcond=1e-12)[0]
        return y - X @ b, b

    z = np.log([abs(start[k]) for k in nonlinear])
    if nonlinear:
        wide = np.log(SIZE_SEARCH)
        z = least_squares(lambda v: fitted(v)[0], z, bounds=(z - wide, z + wide), diff_step=1e-3, xtol=xtol,
                          ftol=1e-10, gtol=1e-10).x
    sizes = {k: float(v) for k, v in zip(nonlinear, signs * np.exp(z))}
    e, b = fitted(z)
    if trend:
        sizes["ageing"] = float(b[-1])
    return sizes, e, b


def _sized(name: str, size: float) -> bool:
    """Whether a lag (τ ≠ 0: either sense, _lagged) or a dead band (r ≠ 0: either sense, _banded) of this size is one
    to fit."""
    return size != 0


def _sized_beside_drift(w: np.ndarray, ok: np.ndarray, temp: np.ndarray, f: np.ndarray, model: "DriftModel",
                        start: dict, step: float, breaks=(), hours=None) -> dict:
    """The sizes of the named effects (`start`: name → the profile's size, "lag" τ, "hysteresis" half-width r,
    "ageing" per hour) fitted as what they are: the zero bias W = w + f(T) as the drift polynomials of the element's
    state — T through the lag τ, then through the dead band r (a play operator) — plus a trend in time, the
    polynomials (each range's) and the trend by least squares for each (τ, r), and (τ, r) by non-linear least squares
    (scipy least_squares, on log τ and log r, started at the profiles' sizes and kept within SIZE_SEARCH of them).
    Sized instead as grid value × the coefficient of its feature f(P(T)) − f(T), built through the f that had
    absorbed part of the effects, they came out off: a 2 °C dead band alone 2.33 °C, 3 °C 3.39 °C, a 540 s lag
    beside a 2 °C band 559 s with the band 2.55 °C. With a lag or a dead band the polynomials are of the state, a
    variable other than T, and take the fit's highest order in each range (settings "max_order"): fit_drift chose
    f's orders on T, where the effect blurs the curve (the simulator's cubic range came out order 2 beside a 600 s
    lag, which then read 575 s; 599 s at the highest order); with ageing alone they keep f's orders (a function of T,
    as chosen).
    On the library's FOCT simulator (2 seeds): a 2 °C band alone 2.00 °C, 0.5 °C 0.50, 1 °C 1.00, 3 °C 3.01; a
    first-order 600 s lag 599 s (beside a 2 °C band 590 s / 2.03 °C, beside 0.01 A/h of ageing 598 s / 0.0099 A/h);
    0.02 A/h of ageing beside a 2 °C band 0.0199–0.0200 A/h. An element 600 s and a thermometer 60 s behind the
    chamber (not one first-order lag: about 540 s on the ramps) read 528 s, beside a 2 °C band 505–510 s /
    2.08–2.10 °C (559–566 s / 2.53–2.57 °C before). → {name: size}."""
    of_state = any(k in start and np.isfinite(start[k]) and _sized(k, start[k]) for k in ("lag", "hysteresis"))
    return _state_fit(w + f, ok, temp, model, _state_orders(model, of_state), start, step, breaks, hours)[0]


def _state_orders(model: "DriftModel", of_state: bool = True) -> list:
    """Each range's polynomial order in the state model: f's own, or, when the polynomials are of a state other than
    T (through a lag or a dead band), at least the fit's highest ("max_order")."""
    top = int(model.settings.get("max_order", 0)) if of_state else 0
    return [max(len(s["coefficients"]) - 1, top) for s in model.segments]


def _newey_west_last(X: np.ndarray, y: np.ndarray, maxlags: int) -> tuple[float, float]:
    """OLS of y on X and the Newey–West (Bartlett) z-test of its last coefficient, as statsmodels' cov_type "HAC"
    gives it, from the normal equations (statsmodels' OLS takes two SVDs of the n × k design per call: about 20 ms
    each on 5k rows where BLAS threads compete) → (p, coefficient)."""
    from scipy.ndimage import convolve1d
    from scipy.stats import norm

    inverse = np.linalg.pinv(X.T @ X)
    b = inverse @ (X.T @ y)
    u = X * (y - X @ b)[:, None]
    # Σ over lags −L…L of the Bartlett weight times Σₜ uₜ uₜ₋ₗᵀ: u against itself smoothed in time, one product
    S = u.T @ convolve1d(u, 1.0 - np.abs(np.arange(-maxlags, maxlags + 1)) / (maxlags + 1.0), axis=0,
                         mode="constant")
    se = float(np.sqrt(max((inverse @ S @ inverse)[-1, -1], 0.0)))
    return (float(2.0 * norm.sf(abs(b[-1]) / se)) if se > 0 else 0.0), float(b[-1])


def _named_in_state(w: np.ndarray, ok: np.ndarray, temp: np.ndarray, f: np.ndarray, model: "DriftModel",
                    named: list, starts: dict, candidates: dict, step: float, breaks=(), hours=None,
                    maxlags: int = 1) -> tuple[list, dict, dict] | None:
    """The effects significant alone but not beside those named (`candidates`: name → a start for its size) judged
    again in the state model (`_state_fit`, each range's polynomial at the fit's highest order), beside the named
    ones at their sizes fitted together: one is named when, added, it takes at least LAG_SHARE of what the others
    leave (the residual sum of squares, all sizes refitted both ways) and its term there — the state model with it
    minus without it, beside the others' columns — has a Newey–West p below LAG_P (and, but for ageing, a positive
    coefficient); each named before is then judged beside the others refitted without it, and one that no longer
    takes LAG_SHARE is dropped. Judged through features built through f (fitted without the effects, its orders
    chosen where they blur the curve), a 1 °C dead band beside a 240 s lag and 0.001 A/h of ageing had gone unsaid:
    the lag moved to about 430 s, took up the band, and read so with the ageing doubled; here the band takes about
    20 % of what the others leave, and no wrong one is named in the library's and a blind simulator's 46 cases. Judged on at most STATE_ROWS rows (a share is a ratio of sums of squares). → None when none is named
    so, else (named, their sizes there: starts for `_sized_beside_drift`, {name: {"p", "share"}} of each named beside
    the others, share of var(w))."""
    orders = _state_orders(model)
    W = w + f
    # (judged on evenly spaced rows, at most STATE_ROWS: the state is computed on all of them)
    every = int(np.ceil(ok.sum() / STATE_ROWS))
    ok = ok & (np.cumsum(ok) % every == 0) if every > 1 else ok
    rows = None if ok.all() else ok
    y = W if rows is None else W[rows]
    tss = max(float(np.sum((w[ok] - np.mean(w[ok])) ** 2)), 1e-300)
    fits = {}

    def fit(keys, start):  # (each set of effects fitted once, from the first start it is given)
        key = frozenset(keys)
        if key not in fits:
            # (to 1 % in τ and r: a share is judged, and the sizes are fitted again from there)
            fits[key] = _state_fit(W, ok, temp, model, orders, {k: start[k] for k in keys}, step, breaks, hours,
                                   xtol=1e-2)
        sizes, e, b = fits[key]
        return sizes, float(e @ e), b

    def term(keys, k):  # k's Newey–West p and coefficient at the joint fit
        sizes, _, b = fit(keys, {})
        trend = [hours] if "ageing" in keys else []
        if k == "ageing":
            rest = _state_design(temp, model, orders, sizes, step, breaks, rows, [])
            column = hours if rows is None else hours[rows]
        else:
            rest = _state_design(temp, model, orders, {j: v for j, v in sizes.items() if j != k}, step, breaks,
                                 rows, trend)
            column = (_state_design(temp, model, orders, sizes, step, breaks, rows, trend) - rest) @ b
        return _newey_west_last(np.column_stack([rest, column]), y, maxlags)

    named = list(named)
    sizes, rss, _ = fit(named, starts)
    changed, tried = False, set()
    while True:
        trial = {}
        for k, size in candidates.items():
            if k in named or k in tried or not (k == "ageing" or (np.isfinite(size) and _sized(k, size))):
                continue
            _, with_k, _ = fit(named + [k], {**sizes, k: size})
            if rss - with_k >= LAG_SHARE * rss:
                p, coefficient = term(named + [k], k)
                if p < LAG_P and (k == "ageing" or coefficient > 0):
                    trial[k] = rss - with_k
        if not trial:
            break
        k = max(trial, key=trial.get)
        named.append(k)
        tried.add(k)
        changed = True
        sizes, rss, _ = fit(named, {})
        without = {j: fit([m for m in named if m != j], sizes)[1] for j in named if j != k}
        weak = {j: (r - rss) / max(r, 1e-300) for j, r in without.items() if r - rss < LAG_SHARE * r}
        if weak:  # (taken up by the one just named)
            gone = min(weak, key=weak.get)
            named.remove(gone)
            tried.add(gone)
            sizes, rss, _ = fit(named, {})
    if not changed:
        return None
    judged = {}
    for k in named:
        p, _ = term(named, k)
        judged[k] = {"p": p, "share": max(fit([m for m in named if m != k], sizes)[1] - rss, 0.0) / tss}
    return named, sizes, judged


def _term_share(w: np.ndarray, X: np.ndarray, j) -> float:
    """The share of var(w) that column(s) j of X take when added last (OLS)."""
    full = np.linalg.lstsq(X, w, rcond=None)[0]
    rest = np.delete(X, j, axis=1)
    less = np.linalg.lstsq(rest, w, rcond=None)[0]
    v = float(np.var(w))
    return float((np.var(w - rest @ less) - np.var(w - X @ full)) / v) if v > 0 else 0.0


def _both_ways(rows: np.ndarray, branch: np.ndarray, temp: np.ndarray) -> np.ndarray | None:
    """`rows` (mask) on the temperature levels (level_means' 5 °C bins) that both branches visit with ≥ 10 samples
    each, or None when fewer than 2 levels (or 50 samples) are."""
    bins = level_bins(temp)
    both = np.zeros(temp.size, dtype=bool)
    levels = 0
    for b in np.unique(bins[rows]):
        here = rows & (bins == b)
        if min(np.sum(here & (branch > 0)), np.sum(here & (branch < 0))) >= 10:
            both |= here & (branch != 0)
            levels += 1
    return both if levels >= 2 and both.sum() >= 50 else None


def _lagged(temp: np.ndarray, step: float, tau: float, breaks=()) -> np.ndarray:
    """`temp` through a first-order lag of time constant τ at the sampling `step` (the log's median), started again
    at each gap: what an element τ behind the thermometer is at. τ < 0: the thermometer |τ| behind the element, which
    is at its mirror 2T − lag(T, |τ|) ≈ T + |τ| dT/dt (as a dead band's other sense, _banded: a blind check's
    thermometer 600 s behind the fibre had been named a ±11 °C dead band, "off at the holds too", which it was not)."""
    from scipy.signal import lfilter

    if tau < 0:
        return 2.0 * temp - _lagged(temp, step, -tau, breaks)
    a = float(np.exp(-step / tau))
    out = np.empty(temp.size)
    edges = [0] + sorted(int(b) for b in breaks) + [temp.size]
    for lo, hi in zip(edges[:-1], edges[1:]):
        if hi > lo:
            out[lo:hi] = lfilter([1.0 - a], [1.0, -a], temp[lo:hi], zi=[a * temp[lo]])[0]
    return out


def thermal_lag(model: "DriftModel", compensated, temp, t=None, temp_outside=None, breaks=()) -> dict | None:
    """What in W − f(T) a function of the logged temperature cannot follow, from the log's history:
      - a lag: W − f(T) following f(T_e) − f(T), T_e the logged temperature through a first-order lag (a newcomer's
        coil 10 min behind its thermometer left residuals 16× the noise and nothing named);
      - hysteresis, where the log visits levels both heating and cooling (`temperature_branch`): W − f(T) following
        f(P) − f(T), P the logged temperature through a dead band (a play operator), which stays through a hold where
        a lag's error dies away (a blind check's 3 °C hysteresis had been named a 383 s lag);
      - ageing, once the temperature has turned back: a trend in time.
    The lag's τ and the dead band's half-width are profiled over geometric grids (each scaled by its fitted
    coefficient), one not named then judged again beside those named in the element's state model
    (`_named_in_state`), and the sizes of those named fitted as the element's state (`_sized_beside_drift`); each
    feature is judged by OLS with Newey–West errors (statsmodels), p below LAG_P and at least LAG_SHARE of the
    variance: the one that explains most alone is named, then each other one that still takes
    LAG_SHARE of what is left beside those named, and the sizes of those named are fitted together
    (`_named_jointly`; one significant alone but not beside those named goes in "fits_too": name → the first named).
    {"tau_s", "p_value", "share", "share_alone", "said", "holds", "hysteresis": {"dead_band_c", "p_value", "share",
    "share_alone", "said", "on_holds", "difference_by_level" (heating minus cooling, measured at the holds both
    branches hold at), "largest_difference", "at_level"} or None, "ageing": {"per_hour", "p_value", "share",
    "share_alone", "said", "hours", "step": {"row", "t", "at_s", "size"} where a step at one time fits better than a
    trend (per_hour then 0), else None} or None, "fits_too", "one_way": {"heating", "per_minute_of_lag"} or None} — p and
    share of a named feature beside the others named, of the rest alone — or None when it cannot be judged (no
    temperature change, too few samples, a regressor that is not f(T), a flat drift model on a log that never turns
    back); beside a flat drift model only a trend in time is judged (no lag nor dead band shows through a constant)."""
    w = np.asarray(compensated, dtype=float)
    temp = np.asarray(temp, dtype=float)
    n = w.size
    if n < 50 or model.regressor != "temp":
        return None
    time = np.arange(n, dtype=float) if t is None else np.asarray(t, dtype=float)
    step = float(np.median(np.diff(time)))
    if not step > 0:  # (a time column that does not increase: the samples taken as evenly spaced)
        time, step = np.arange(n, dtype=float), 1.0
    rate = _temperature_rate(temp, time, breaks)
    temp = _held_on_edges(temp, rate, model)
    f = model.evaluate(temp, outside="nan")
    ok = np.isfinite(f) & np.isfinite(w)
    if ok.sum() < 50 or not np.any(rate[ok] != 0):
        return None
    taus = step * np.geomspace(2.0, max(4.0, 0.2 * n), 24)
    taus = np.concatenate([taus, -taus])  # the element behind the thermometer, and the thermometer behind it
    lagged = [model.evaluate(np.clip(_lagged(temp, step, tau, breaks), temp.min(), temp.max()), outside="nan") - f
              for tau in taus]
    # a flat drift model: no lag nor dead band can show, but a trend in time can (a blind check's field log aged by
    # 1.9 A, 37× the noise, with f a constant beside it, had nothing said and no thermal_lag in the report)
    flat = not np.any(np.abs(lagged[-1][ok]) > 0)
    branch = temperature_branch(temp)
    settled = ok & (np.abs(rate) <= SETTLED_RATE * np.percentile(np.abs(rate[ok]), 95))
    holds = bool(settled.sum() >= 0.1 * ok.sum())  # without holds, on ramps of one rate, lag and hysteresis look alike
    maxlags = int(4 * (n / 100) ** (2 / 9))
    grids, scales = ({}, {}) if flat else ({"lag": (lagged, False)}, {"lag": taus})  # name → (columns, either sign)
    out = {"holds": holds, "hysteresis": None, "ageing": None, "one_way": None, "tau_s": 0.0, "p_value": 1.0,
           "share": 0.0, "share_alone": 0.0, "said": False, "seconds": t is not None}  # (without times, τ in samples)
    both_ways = _both_ways(ok, branch, temp)
    if both_ways is not None and not flat:
        # hysteresis as a dead band of half-width r °C: the element's state a play operator of T (it moves only once
        # T has pushed it r away), exact through f rather than r·f'(T) (a 2 °C band on the steep range was off 25 %);
        # or the band in the other sense, the thermometer's (r < 0: _banded)
        widths = float(np.ptp(temp)) * np.geomspace(2e-3, 0.1, 10)
        scales["hysteresis"] = np.concatenate([widths, -widths])
        plays = play(temp, widths, "temp").T
        grids["hysteresis"] = ([model.evaluate(np.clip(p, temp.min(), temp.max()), outside="nan") - f
                                for p in np.concatenate([plays, 2.0 * temp - plays])], False)
        out["hysteresis"] = {"on_holds": holds}
    turned = set(np.unique(branch[branch != 0]).tolist())
    hours = None  # (the trend itself, for the state model, which refits f beside it)
    if len(turned) == 2 and t is not None:  # ageing: a trend in time (times needed), told from the temperature's
        # once the temperature has turned back
        hours = (time - time[0]) / 3600.0
        # judged as the trend that the drift polynomials cannot take (its part that is not a function of T, as in a
        # joint fit: Frisch–Waugh): w is what f left after it took what of the trend it could, so a trend judged whole
        # read 4× small beside it and 2 mA/h (p 1e-19) took 4 % of var(w), unsaid, with f 10× off
        basis = _state_design(temp, model, _state_orders(model, of_state=False), {}, step, breaks, ok, [])
        # or a step at one time, at the row where it fits best: the two compete as one feature, the better named (a
        # blind check's 0.05 A step had been named hysteresis, then a trend, and the model refitted about it)
        # an orthonormal basis of the polynomials' span (a column's part in them by one product; as least squares
        # would, without the directions a range's empty or collinear columns do not span)
        u, sv, _ = np.linalg.svd(basis, full_matrices=False)
        q = u[:, sv > 1e-12 * sv[0]]
        jump = _step_row(w, ok, q)
        trends = [hours] + ([] if jump is None else [(np.arange(n) >= jump).astype(float)])
        beyond = [c.copy() for c in trends]
        for c in beyond:
            c[ok] -= q @ (q.T @ c[ok])
        grids["ageing"], scales["ageing"] = (beyond, True), [1.0] * len(beyond)
        out["ageing"] = {"hours": float(hours[-1])}
    if not grids:
        return None  # (a flat drift model on a log that never turned back: nothing it can show)
    # a lag, a dead band and a trend in time can each stand in for another (on holds not much longer than τ a lag
    # looks like a dead band; heating first and cooling later, a dead band like a trend): named one at a time,
    # each beside those named before, and their sizes fitted together
    alone = {k: _profiled(w, ok, columns, maxlags, signed=signed) for k, (columns, signed) in grids.items()}
    named, together = _named_jointly(w, ok, grids, alone, maxlags)
    starts = {k: float(scales[k][together[k]["best"]] * together[k]["coefficient"]) for k in named}
    if "ageing" in grids:  # (the trend or the step, whichever fits better)
        jumped = (together if "ageing" in named else alone)["ageing"]["best"] == 1
        hours = trends[int(jumped)]
        out["ageing"]["step"] = ({"row": int(jump), "t": float(time[jump]), "at_s": float(time[jump] - time[0])}
                                 if jumped else None)
    # each not named is judged again in the state model, beside those named at their sizes fitted together
    # (`_named_in_state`), from its size alone (its grid value where its coefficient alone has the other sign)
    candidates = {k: float(scales[k][alone[k]["best"]] * (alone[k]["coefficient"] if k == "ageing" or
                                                          alone[k]["coefficient"] > 0 else 1.0))
                  for k in grids if named and k not in named}
    review = _named_in_state(w, ok, temp, f, model, named, starts, candidates, step, breaks, hours,
                             maxlags) if candidates else None
    if review is not None:
        named, starts, judged = review
    sized = _sized_beside_drift(w, ok, temp, f, model, {k: starts[k] for k in named}, step, breaks, hours)
    if review is not None:  # (p and share of each named as judged there)
        together = {k: {**together.get(k, alone[k]), **judged[k], "significant": True} for k in named}
    for k in grids:
        fit = together.get(k, alone[k])  # (a feature not named: its fit alone)
        # a size from the fit: the profile's grid value times its coefficient (a short τ scaled fits a long lag's
        # ramps about as well, and the product is the lag: a newcomer's 600 s coil gave 60 s × 10.1, 170 s × 3.54,
        # 600 s × 1.00); of those named, the start of their sizes fitted together beside the drift refitted
        size = sized.get(k, float(scales[k][fit["best"]] * fit["coefficient"]))
        found = {"p_value": fit["p"], "share": fit["share"], "share_alone": alone[k]["share"], "said": k in named}
        if k == "lag":
            out.update({"tau_s": size, **found})
        elif k == "ageing" and out["ageing"]["step"] is not None:  # (a step: its size, no rate)
            out["ageing"]["step"]["size"] = size
            out["ageing"].update({"per_hour": 0.0, **found})
        else:
            out[k].update({"dead_band_c" if k == "hysteresis" else "per_hour": size, **found})
        if named and k not in named and alone[k]["significant"]:
            out.setdefault("fits_too", {})[k] = named[0]  # significant alone, not beside those named
    if out["hysteresis"] is not None:
        # heating minus cooling as measured, level by level, at the holds where both branches hold there — with the
        # other effects named taken out (cooling comes later: ageing's 0.02 A/h had doubled a 2 °C band's difference)
        if review is None:
            others = sum((together[k]["coefficient"] * grids[k][0][together[k]["best"]] for k in named
                          if k != "hysteresis"), np.zeros(n))
        else:  # (named in the state model: each at its fitted size, its feature's profile taken up by another)
            others = np.zeros(n)
            if "lag" in named:
                others += model.evaluate(np.clip(_lagged(temp, step, sized["lag"], breaks), temp.min(), temp.max()),
                                         outside="nan") - f
            if "ageing" in named:
                others += sized["ageing"] * hours
        levels = level_bins(temp)
        both = _both_ways(settled, branch, temp) if holds else None
        both = both_ways if both is None else both
        at = {float(b): float(np.mean((w - others)[both & (levels == b) & (branch > 0)]) -
                              np.mean((w - others)[both & (levels == b) & (branch < 0)]))
              for b in np.unique(levels[both])}
        worst = max(at, key=lambda b: abs(at[b]))
        out["hysteresis"].update({"difference_by_level": at, "largest_difference": at[worst], "at_level": worst})
    if len(turned) == 1:  # one way only: a lag shifts the whole curve, hysteresis cannot show
        ramps = ok & ~settled
        minute = model.evaluate(np.clip(_lagged(temp, step, 60.0, breaks), temp.min(), temp.max()), outside="nan") - f
        out["one_way"] = {"heating": turned == {1},  # what a minute's lag does on the ramps: the fit's shift
                          "per_minute_of_lag": float(np.percentile(np.abs(minute[ramps]), 95)) if ramps.any() else 0.0}
    return out


def _held_on_edges(temp: np.ndarray, rate: np.ndarray, model: "DriftModel") -> np.ndarray:
    """The temperatures with each hold on an inner edge of the model's ranges taken as the edge itself: a run of
    settled rows (|rate| within SETTLED_RATE of the log's brisk one) whose median lies within the thermometer's noise
    of the edge (4 σ of its third differences, and a step of its resolution), the whole run. The thermometer's noise
    crosses the edge there back and forth and f(T) jumps between the two ranges' polynomials with it, which a lag's or
    a dead band's f(T′) − f(T) took up: a blind check's holds at 0 and 30 °C (seed 001's own levels) had a ±0.02 °C
    "hysteresis" named beside a lag. (Row by row, a hold just off the edge had been cut in two: crossings invented.)"""
    edges = np.array([float(seg["range"][0]) for seg in model.segments[1:]])
    finite = np.isfinite(temp) & np.isfinite(rate)
    if not edges.size or finite.sum() < 20:
        return temp
    d = np.diff(temp[finite], n=3)
    noise = 1.4826 * float(np.median(np.abs(d - np.median(d)))) / np.sqrt(20.0)
    steps = np.abs(np.diff(temp[finite]))
    resolution = float(steps[steps > 0].min()) if np.any(steps > 0) else 0.0
    brisk = float(np.percentile(np.abs(rate[finite]), 95))
    settled = finite & (np.abs(rate) <= SETTLED_RATE * brisk)
    out = temp.copy()
    for first, last in index_runs(settled):
        middle = float(np.median(temp[first:last + 1]))
        near = edges[np.abs(edges - middle) <= 4.0 * noise + resolution]
        if near.size:
            out[first:last + 1] = near[0]
    return out


def _step_row(w: np.ndarray, ok: np.ndarray, q: np.ndarray) -> int | None:
    """The row where a step of w (1 from there on) fits best what the drift polynomials (`q`, an orthonormal basis of
    them on the `ok` rows) leave, not within a fiftieth of the log of its ends (a trend's tail there); None when the log is too short, or
    where the level does not move there abruptly. Every
    row is tried at once: the basis's part of a step from row i is a sum from i to the end, one cumulative sum."""
    y = w[ok] - q @ (q.T @ w[ok])
    tail_q = np.cumsum(q[::-1], axis=0)[::-1]  # Σ_{j ≥ i} q_j: qᵀs for the step s from row i
    n = y.size
    norm = (n - np.arange(n)) - np.einsum("ij,ij->i", tail_q, tail_q)  # s̃ᵀs̃, s̃ the step less its part in the basis
    fit = np.cumsum(y[::-1])[::-1]  # s̃ᵀy = sᵀy (y has no part in the basis)
    edge = max(1, n // 50)
    usable = np.zeros(n, dtype=bool)
    usable[edge:n - edge] = True
    usable &= norm > 1e-9 * n
    if not usable.any():
        return None
    gain = np.where(usable, fit ** 2 / np.where(usable, norm, 1.0), -1.0)
    i = int(np.argmax(gain))
    # a step is abrupt: across its row the level moves by about its size within a fiftieth of the log, and by far
    # more than it moves so elsewhere (the differences of neighbouring means, robust σ): a slow wander's best step
    # moves little more there than anywhere, and had been named a step in 8 of 20 logs
    m = max(edge, 5)
    c = np.concatenate([[0.0], np.cumsum(y)])
    moves = (c[2 * m:] - 2.0 * c[m:-m] + c[:-2 * m]) / m  # mean of the m rows from i less that of the m before
    jump = moves[i - m] if m <= i <= n - m else 0.0
    spread = 1.4826 * float(np.median(np.abs(moves - np.median(moves)))) if moves.size else 0.0
    if abs(jump) < max(0.5 * abs(fit[i] / norm[i]), STEP_MOVES * spread):
        return None
    return int(np.flatnonzero(ok)[i])


def _hours_words(seconds: float) -> str:
    return f"{seconds / 3600.0:.3g} h" if seconds >= 3600.0 else f"{seconds / 60.0:.3g} min"


def _time_words(ageing: dict, unit: str = "") -> str:
    """What thermal_lag's time term is, in a few words: a trend per hour, or a step at one time."""
    jump = ageing.get("step")
    if jump:
        return f"a step of {jump.get('size', 0.0):.3g}{unit} at {_hours_words(jump['at_s'])} into the log"
    return f"a trend of {ageing.get('per_hour', 0.0):.3g}{unit} per hour (ageing)"


def _time_course(ageing: dict, t) -> np.ndarray:
    """The zero bias's course in time that thermal_lag named (a trend, or a step), zero at the end of the log."""
    time = np.asarray(t, dtype=float)
    jump = ageing.get("step")
    if jump:
        return jump["size"] * ((np.arange(time.size) >= jump["row"]) - 1.0)
    return ageing["per_hour"] * (time - time[-1]) / 3600.0


def one_way_note(lag: dict | None) -> str | None:
    """A log with holds that runs the temperature one way: what it cannot show (`drift fit` prints it)."""
    one = (lag or {}).get("one_way")
    if not one or not lag["holds"]:
        return None
    return (f"the log runs the temperature one way ({'heating' if one['heating'] else 'cooling'}): hysteresis, a "
            "difference between heating and cooling at the same temperature, cannot show in it")


def _p_words(p: float) -> str:
    """A p-value said: "< 1e-16" below double precision's resolution of 1 − p (a "p 0" read as a typo)."""
    return "< 1e-16" if p < 1e-16 else f"{p:.2g}"


def _branch_level_means(values, temp, lag: dict | None) -> list:
    """The per-level means of the class check on the drift alone, per branch at the levels the log heats and cools
    through with a quarter of the level's samples on each branch (averaged together, a 3 °C hysteresis's 0.056 A off
    each branch had cancelled to 0.004 A and the class "MET"; a branch's few ramp samples alone had failed clean slow
    noise), else per level."""
    if not lag or not lag.get("hysteresis"):
        return list(level_means(values, temp).values())
    branch = temperature_branch(temp)
    bins = level_bins(temp)
    out = []
    for b in np.unique(bins):
        here = bins == b
        counts = [np.sum(here & (branch == side)) for side in (-1, 1)]
        if min(counts) >= 0.25 * here.sum():
            out += [float(values[here & (branch == side)].mean()) for side in (-1, 1)]
            rest = here & (branch == 0)
            out += [float(values[rest].mean())] if rest.any() else []
        else:
            out.append(float(values[here].mean()))
    return out


def _band_words(r: float) -> str:
    """A dead band's half-width and sense (_banded)."""
    return f"±{abs(r):.2g} °C" + ("" if r >= 0 else ", the thermometer's (heating, the element reads as if hotter)")


def history_warnings(lag: dict | None, unit: str = "") -> list:
    """What thermal_lag found said: a lag, hysteresis, ageing, or a log that runs the temperature one way without
    holds."""
    if lag is None:
        return []
    out = []
    h, a = lag.get("hysteresis") or {}, lag.get("ageing") or {}
    also = lag.get("fits_too", {})
    secs = "s" if lag.get("seconds", True) else "samples (no times given)"
    words = {"lag": f"a lag of about {lag['tau_s']:.3g} {secs}" + (" (the thermometer's)" if lag["tau_s"] < 0 else ""),
             "hysteresis": f"a dead band of {_band_words(h.get('dead_band_c', 0.0))} (hysteresis)",
             "ageing": _time_words(a, unit)}
    shares = {"lag": lag["share_alone"], "hysteresis": h.get("share_alone", 0.0), "ageing": a.get("share_alone", 0.0)}

    def too(name):  # what else, not named, fits nearly as well as a named one (80 % of its share, both alone)
        others = [k for k, v in also.items() if v == name and shares[k] >= 0.8 * shares[name]]
        return (f" ({' and '.join(words[k] for k in others)} fits almost as well: holds several times longer than "
                "the lag, or another cycle, tell them apart)") if others else ""

    if lag["said"]:
        behind = ("the sensing element lags the thermometer" if lag["tau_s"] > 0 else
                  "the thermometer lags the sensing element")
        out.append("the compensated zero bias follows the temperature's rate of change (Newey–West p "
                   f"{_p_words(lag['p_value'])}, {100 * lag['share']:.0f} % of its variance): {behind} by about "
                   f"{abs(lag['tau_s']):.3g} {secs} (first order"
                   + ("; a lower bound: on a log that runs one way the drift model takes up part of the lag"
                      if lag.get("one_way") else "") + ") — the drift model, a function of the "
                   "logged temperature, cannot follow it on the ramps; put the thermometer at the element, log slower "
                   "ramps, or judge the model on the holds" + too("lag"))
    if h.get("said"):
        out.append(f"the compensated zero bias differs between heating and cooling at the same temperature, by up to "
                   f"{h['largest_difference']:.4g}{unit} at {h['at_level']:g} °C (heating minus cooling; as a dead "
                   f"band of {_band_words(h['dead_band_c'])}; Newey–West p {_p_words(h['p_value'])}, "
                   f"{100 * h['share']:.0f} % of "
                   f"its variance, {len(h['difference_by_level'])} levels visited both ways): "
                   + ("hysteresis" if h["on_holds"] else "hysteresis, or the sensing element lagging the thermometer "
                      "(without settled holds the two look alike)")
                   + " — or a step of the zero bias at one time, between the legs that heat and those that cool (a "
                   "blind check's 0.05 A step read so: plot the compensated zero bias against time)"
                   + " — a function of temperature cannot follow it and the model sits between the branches, about "
                   f"{abs(h['largest_difference']) / 2:.3g}{unit} off each there, at the holds too; judge the class "
                   "per branch (accuracy_drift does), or model the branch the device is on" + too("hysteresis"))
    if a.get("said") and a.get("taken_out"):
        jump = a.get("step")
        out.append(f"the zero bias {'steps' if jump else 'drifts with time'} by "
                   + (f"{jump['size']:.3g}{unit} at t = {jump['t']:.6g} s ({_hours_words(jump['at_s'])} into the log; "
                      "a step fits better than a steady trend)" if jump else f"{a['per_hour']:.3g}{unit} per hour")
                   + f" beyond the temperature (Newey–West p {_p_words(a['p_value'])}, {100 * a['share']:.0f} % of "
                   "what the drift model left"
                   + ("): a fault, a knock, a connector or a setting changed, or the readout restarted"
                      if jump else f"; {a['per_hour'] * a['hours']:.3g}{unit} over this log's {a['hours']:.3g} h): "
                      "ageing, or a slow warm-up of the electronics")
                   + f" — the drift model is fitted with the {'step' if jump else 'trend'} taken out, as the device "
                   f"was at the end of this log (fitted beside it, it was up to {a.get('model_moved', 0.0):.3g}{unit} "
                   "different across the temperatures)"
                   + ("; plot the compensated zero bias against time, and log again if the device may have changed"
                      if jump else ", and is off by the trend's rate per hour since if it goes on; log again later "
                      "and compare, or let the device settle before the cycle"))
    elif a.get("said"):
        out.append(f"the compensated zero bias drifts with time by {a['per_hour']:.3g}{unit} per hour beyond the "
                   f"temperature (Newey–West p {_p_words(a['p_value'])}, {100 * a['share']:.0f} % of its variance; "
                   f"{a['per_hour'] * a['hours']:.3g}{unit} over this log's {a['hours']:.3g} h): ageing, or a slow "
                   "warm-up of the electronics — the model is fitted to this log's mean and is off by that much per "
                   "hour since; log again later and compare, or let the device settle before the cycle" + too("ageing"))
    one = lag.get("one_way")
    if one and not lag["holds"] and one["per_minute_of_lag"] > 0:  # (a flat drift model: a lag moves nothing)
        out.append(f"the log runs the temperature one way ({'heating' if one['heating'] else 'cooling'}) without "
                   "settled holds: a lag of the sensing element behind the thermometer shifts the whole drift curve "
                   "here and no fit can tell it from the drift — each "
                   + ("minute" if lag.get("seconds", True) else "60 samples") + " of lag moves the model by up to "
                   f"{one['per_minute_of_lag']:.3g}{unit} at steady state; log holds at settled temperatures, or a "
                   "ramp back")
    return out


def filter_compensated(model: "DriftModel", compensated, t=None) -> np.ndarray:
    """The model's Kalman filter on a log's compensated zero bias W − f(T) (what `export-c --kalman` runs in
    firmware): started again after each gap in `t` (fluxcal.timeseries.find_breaks) and after each stretch of NaN
    (samples outside the model's ranges, or not numbers), which stay NaN. ValueError when the model has no filter
    (white noise about the drift: the compensated zero bias is then its output). The filter's state is the zero-mean
    noise: a constant left in W − f(T) (the drift model off, ageing) passes at its DC gain (`dc_gain`, 0.6 for R = σ²),
    so judge offsets on W − f(T) itself."""
    kalman = model.settings.get("kalman")
    ar = model.settings.get("ar") or {}
    if not kalman:
        raise ValueError("drift model: it has no Kalman filter (the noise about its drift was white: AIC order 0), "
                         "so the compensated zero bias is its output")
    w = np.asarray(compensated, dtype=float)
    if w.ndim != 1:
        raise ValueError(f"compensated: shape {w.shape}, expected one value per sample (N,)")
    if t is not None and np.shape(t) != w.shape:  # (its gaps were found at the wrong rows, silently)
        raise ValueError(f"t: {np.size(t)} times for {w.size} samples of compensated")
    out = np.full(w.shape, np.nan)
    breaks = set(ts.find_breaks(t).tolist()) if t is not None else set()
    finite = np.isfinite(w)
    edges = np.flatnonzero(np.diff(np.concatenate([[False], finite, [False]]).astype(int)))
    for start, stop in zip(edges[::2], edges[1::2]):  # each run of numbers, its own gaps as breaks
        f = ArKalman(ar["coefficients"], float(kalman["q"]), float(kalman["r"]),
                     steady_state=bool(kalman.get("steady_state", False)))
        out[start:stop] = f.filter(w[start:stop], sorted(b - start for b in breaks if start < b < stop))
    return out


def noise_model_rejected(model: "DriftModel") -> str | None:
    """Why the fit rejected the AR model of the noise about the drift (Ljung–Box: residuals not white), or None
    (white, untested, or a model saved before the test was kept)."""
    whiteness = (model.settings.get("ar") or {}).get("whiteness") or {}
    p = whiteness.get("p_value")
    if p is None or not p == p or whiteness.get("white", True):
        return None
    return (f"the fit rejected the AR({model.settings['ar'].get('order')}) model of the noise about the drift: its "
            f"residuals are not white (Ljung-Box p = {p:.3g} over {whiteness.get('lags')} lags)")


def _met_only_filtered(filtered: dict, compensated: dict, kalman: dict, sigma2: float) -> str | None:
    """Words when the class is met by the Kalman output and not by the compensated zero bias W − f(T). With R = σ² (no
    measurement noise given: an AR fit cannot tell it from the process) the filter takes half the noise for the
    sensor's and removes it, so the output judged is smoother than any the device delivers unfiltered (a blind
    check: max 0.0203 A "met", W − f(T) 0.0406 A)."""
    if not filtered["met"] or compensated["met"]:
        return None
    convention = (" — it took R = σ² of the AR fit (the measurement noise not given), which halves the noise it is "
                  "judged on; give r, the sensor's white-noise floor" if abs(kalman["r"] - sigma2) <= 1e-12 * sigma2
                  else "")
    return (f"class {filtered['class']} is met by the Kalman-filtered output only (max {filtered['max_abs_residual']:.4g}"
            f"); the compensated zero bias W − f(T) reaches {compensated['max_abs_residual']:.4g} sample by sample, NOT "
            f"met{convention}. Judge the output the device puts out: filtered only if it runs the filter")


def _refitted_without_trend(w: np.ndarray, temp: np.ndarray, temp_outside, t, lag: dict, first: "DriftModel",
                            options: dict) -> tuple:
    """fit_pipeline again on the zero bias less the ageing that thermal_lag named, the trend's level at the end of
    the log taken as the zero: (model, report) of that fit, the trend in model.settings["ageing"] {"per_hour",
    "hours"} and in the report's thermal_lag, and how far the model fitted beside it had been off."""
    ageing = dict(lag["ageing"])
    model, report = fit_pipeline(w - _time_course(ageing, t), temp, temp_outside, t=t,
                                 _detrended={**ageing, "taken_out": True}, **options)
    # how far f(T) fitted beside the trend was from f(T) fitted without it, over the log's temperatures (the
    # trend's level at the log's mean time is a constant between them: taken out)
    levels = np.linspace(float(temp.min()), float(temp.max()), 200)
    moved = first.evaluate(levels, outside="nan") - model.evaluate(levels, outside="nan")
    moved = moved[np.isfinite(moved)]
    # (the refit's own judgement, or none where the model came out flat without the trend)
    history = report["thermal_lag"] = report.get("thermal_lag") or {
        "said": False, "tau_s": 0.0, "p_value": 1.0, "share": 0.0, "share_alone": 0.0, "holds": False,
        "hysteresis": None, "one_way": None, "ageing": None}
    history["ageing"] = {**ageing, "taken_out": True, "model_moved": float(np.ptp(moved)) if moved.size else 0.0}
    model.settings["ageing"] = {"per_hour": float(ageing["per_hour"]), "hours": float(ageing["hours"]),
                                "step": ageing.get("step")}
    said = history_warnings({"said": False, "tau_s": 0.0, "share_alone": 0.0, "ageing": history["ageing"]})
    report["warnings"] += said
    model.summary["fit_warnings"] = list(model.summary.get("fit_warnings", [])) + said
    return model, report


def _finite(values: np.ndarray, name: str) -> np.ndarray:
    bad = ~np.isfinite(values)
    if bad.any():
        raise ValueError(f"{name}: sample {int(np.argmax(bad))} is {values[np.argmax(bad)]} (NaN/Inf not allowed; "
                         f"{int(bad.sum())} such sample(s)): leave those samples out (in a file: --bad-lines skip)")
    return values


def _gaps(t, n: int, ar_max_order: int) -> tuple:
    """fit_pipeline's gaps in time: (breaks, report["gaps"], notes, warnings). A time column that cannot show
    gaps (not increasing) is not an error — the fit never needed it — but a warning; so are gaps so many that
    the stretches between them would leave the AR model fewer than half the samples."""
    if t is None:
        return [], None, [], []
    t = ts.as_series(t, "t")
    if t.size != n:
        raise ValueError(f"t: {t.size} samples, zero_bias has {n}")
    try:
        breaks = ts.find_breaks(t)
    except ValueError as exc:
        return [], None, [], [f"{exc}: gaps in time were not looked for, the samples are modelled as evenly spaced"]
    step = float(np.median(np.diff(t)))
    gaps = {"count": int(breaks.size), "breaks": breaks.tolist(), "step": step,
            "longest": float(np.max(t[breaks] - t[breaks - 1])) if breaks.size else 0.0}
    if not breaks.size:
        return [], gaps, [], []
    if n - (breaks.size + 1) * ar_max_order < n / 2:
        return [], gaps, [], [f"t: {breaks.size} gaps in {n} samples leave stretches too short for an AR model of "
                              f"order up to {ar_max_order}; the samples are modelled as evenly spaced"]
    return breaks.tolist(), gaps, [gaps_note(breaks.size)], []


def gaps_note(count: int) -> str:
    """fit_pipeline's note on the gaps in time (and fit_foct's, word for word)."""
    return (f"{count} gap{'s' if count != 1 else ''} in time: the whitening, the AR model and the Kalman filter do "
            "not reach across them, the filter starts again after each")


def fit_pipeline(zero_bias, temp, temp_outside=None, regressor: str = "temp", breakpoints=DEFAULT_BREAKPOINTS,
                 max_order: int = 4, significance: float = 0.05, continuous: bool = False, ar_max_order: int = 10,
                 q: float | None = None, r: float | None = None, steady_state: bool = False, subseries: int = 20,
                 rated: float | None = None, accuracy_class: str = "0.2S", whiten: bool = True,
                 drift_input: str = "zero_bias", t=None, spikes: str = "keep", _detrended: dict | None = None,
                 _frozen: dict | None = None):
    """Seed 001 end to end (module doc). drift_input: "zero_bias" (default, GLS on the zero bias) or
    "filtered" (the Kalman output L, seed 001 as written; module doc step 4). The AR model (report["ar"],
    model.settings["ar"], "fitted_to": "zero_bias - drift") is of the noise about a first drift model,
    and the Kalman filter runs on that noise; when that noise is white (AR order 0) there is no filter and
    report["notes"] says so (drift_input="filtered" then has nothing to refit). t: the sample times; where
    they have gaps (timeseries.find_breaks: a recorder paused between temperature holds, lost lines) the
    whitening, the AR model and the Kalman filter do not reach across them and the filter starts again
    after each (report["gaps"], a note). Without t the samples are taken as evenly spaced. spikes: the zero
    bias's spikes (`zero_bias_spikes`: a readout's glitches) are said in a warning ("keep", the default), left out
    of the fit ("drop": the rows go, and with t each leaves a gap) or not looked for ("off"); report["spikes"] =
    {"rows" (of the input), "sigmas", "dropped"}, and with "drop" the report's series are of the rows kept.
    Where thermal_lag names ageing (a trend in time beyond the temperature), the whole fit is made again on the
    zero bias with that trend taken out, as the device was at the end of the log (model.settings["ageing"]): fitted
    beside it, f(T) took part of it (2 mA/h over a 19 h cycle left f 10× further off than the noise alone) and chose
    its orders on it; the report's series are then of the zero bias without the trend. report["thermal_lag"] is
    thermal_lag's finding (None when the log's history cannot be judged) — a trend in time is judged beside a flat
    drift model too.
    Returns (DriftModel, report)."""
    if drift_input not in DRIFT_INPUTS:
        raise ValueError(f"drift_input: {drift_input!r} is not one of {', '.join(DRIFT_INPUTS)}")
    if spikes not in ("keep", "drop", "off"):
        raise ValueError(f"spikes: {spikes!r} is not one of keep, drop, off")
    if isinstance(ar_max_order, bool) or not isinstance(ar_max_order, (int, np.integer)) or ar_max_order < 0:
        raise ValueError(f"ar_max_order: {ar_max_order!r}, need a whole number ≥ 0 (the AR model's largest order)")
    w = _finite(ts.as_series(zero_bias, "zero_bias"), "zero_bias")
    temp = _finite(ts.as_series(temp, "temp"), "temp")
    if temp.size != w.size:
        raise ValueError(f"temp: {temp.size} samples, zero_bias has {w.size}")
    if np.ptp(w) == 0:  # (was "series: constant", naming no input)
        raise ValueError(f"zero_bias: constant (every sample equals {w[0]:g}), there is nothing to model — a "
                         "readout that froze or was not connected?")  # (the C++ pipeline's words, and why)
    breaks, gaps, gap_notes, gap_warnings = _gaps(t, w.size, ar_max_order)
    if _frozen is None:  # (judged on the input: the refits below see it with rows left out or a trend taken out)
        runs = frozen_runs(w)
        _frozen = {"runs": runs, "said": frozen_words(w, runs) if runs else None}
    try:
        pre = ts.preprocess(w, subseries=subseries, breaks=breaks)
    except ValueError as exc:  # (a blind check: "series: 30 samples, need at least 42 …", naming no input)
        if not str(exc).startswith("series: "):
            raise
        raise ValueError(f"zero_bias: {str(exc)[len('series: '):]} (seed 001 S2; `subseries` sets how many, ≥ 3): "
                         "a drift model over temperature needs a log through the operating range, hundreds of samples "
                         "or more") from None
    glitches = temperature_glitches(temp)  # (after the sizes and the length are judged: 8 rows are too few first)
    if len(glitches):
        raise TemperatureGlitches(f"temp: {glitch_words(temp, glitches)}", glitches)
    holds = temperature_holds(temp)
    if holds:
        raise TemperatureGlitches(f"temp: {hold_words(temp, holds)}", np.concatenate(
            [np.arange(a, b + 1) for a, b in holds]), holds)
    if np.ptp(temp) == 0:  # (else "range [-20, 0]: 0 samples", as if the ranges were wrong)
        raise ValueError(f"temp: every sample is {temp[0]:g} °C; a drift with temperature needs the temperature to "
                         "change (a chamber cycle, a warm-up)")
    # °F or K logged with no unit (taken as °C) fit without an error, on ranges adjusted to the wrong numbers
    unit_warnings = [w for w in [temperature_unit_hint(temp, breakpoints)] if w]
    drift_options = dict(regressor=regressor, breakpoints=breakpoints, max_order=max_order,
                         significance=significance, continuous=continuous, whiten=whiten, breaks=breaks)
    # S2.3 removes the trend before the AR model; here the trend is the temperature drift, so the AR model
    # is fitted to the zero bias minus a first drift model (S5 on the zero bias, GLS): the noise. Fitted to
    # the zero bias itself it also had to describe the drift (AIC went to max_order, Ljung–Box rejected it).
    first = fit_drift(w, temp, temp_outside, **drift_options)
    drift_first = first.evaluate(temp, temp_outside)
    # no block judged across a gap, nor where the temperature crosses a breakpoint: the model steps there (a hold
    # on 30 °C with a thermometer's 0.01 °C noise had 288 "spikes", its crossings)
    ranges = range_index(first.segments, temp)  # (an edge's own value belongs to the range above, as evaluated)
    crossings = np.flatnonzero(np.diff(ranges)) + 1
    spike_rows, spike_sigmas = (zero_bias_spikes(w - drift_first, breaks=breaks, steps=crossings.tolist())
                                if spikes != "off" else (np.zeros(0, dtype=int), np.zeros(0)))
    if spike_rows.size and spikes == "drop":
        kept = np.setdiff1d(np.arange(w.size), spike_rows)
        model, report = fit_pipeline(
            w[kept], temp[kept], None if temp_outside is None else np.asarray(temp_outside, float)[kept], regressor,
            breakpoints, max_order, significance, continuous, ar_max_order, q, r, steady_state, subseries, rated,
            accuracy_class, whiten, drift_input, None if t is None else np.asarray(t, float)[kept], spikes="off",
            _frozen=_frozen)
        report["spikes"] = {"rows": spike_rows.tolist(), "sigmas": np.asarray(spike_sigmas).tolist(), "dropped": True}
        jump = ((report.get("thermal_lag") or {}).get("ageing") or {}).get("step")
        if jump:  # (a row of the input, as the spikes' are; the model's settings hold the same dict)
            jump["row"] = int(kept[jump["row"]])
        report["notes"].append(spike_words(spike_rows, report["spikes"]["sigmas"], dropped=True))
        return model, report
    noise, noise_mean = ts.zero_mean(w - drift_first)
    # Ljung–Box over twice the largest order AIC may take, so correlation beyond max_order is tested too.
    ar = ts.fit_ar(noise, max_order=ar_max_order, whiteness_lags=max(10, 2 * ar_max_order), breaks=breaks)
    if ar.order == 0:
        # White noise about the drift: nothing in it is predictable from its past, so there is no state for
        # the Kalman filter to track and its best estimate of the noise is 0: L = f1 + mean, the drift model.
        # q, r and steady_state have nothing to act on; settings["kalman"] is None (no filter to export).
        kalman_settings = None
        filtered = drift_first + noise_mean
        notes = [WHITE_NOISE_NOTE]
        if drift_input == "filtered":  # a refit to a noiseless L is degenerate (rank-deficient GLS, false orders)
            notes.append(WHITE_NOISE_NO_REFIT)
            drift_input = "zero_bias"
    else:
        if q is None:  # Q (and R unless given) estimated from the AR fit
            kalman = ArKalman.from_ar(ar, r=r, steady_state=steady_state)
        else:
            kalman = ArKalman(ar.coefficients, float(q), ar.sigma2 if r is None else float(r),
                              steady_state=steady_state)
        kalman_settings = {"q": kalman.q, "r": kalman.r, "steady_state": steady_state}
        # The drift is a known input of the state-space model: the filter runs on the noise only and L adds
        # the drift back, so L follows the drift without lag or DC-gain loss on the temperature ramps.
        filtered = drift_first + noise_mean + kalman.filter(noise, breaks)
        notes = []
    # drift_input="filtered" refits S5 on L (seed 001 as written); by default the first model is the model.
    model = first if drift_input == "zero_bias" else fit_drift(filtered, temp, temp_outside, **drift_options)
    model.settings.update({"ar": {"order": ar.order, "coefficients": ar.coefficients.tolist(), "sigma2": ar.sigma2,
                                  "max_order": ar_max_order, "order_at_maximum": ar.order_at_maximum,
                                  "fitted_to": AR_FITTED_TO},
                           "kalman": kalman_settings,
                           "drift_input": drift_input,
                           "gaps": len(breaks)})
    # The data's warnings: S2's, S3's, and the first drift fit's when the model is a refit to L (the model's
    # summary keeps the warnings of the fit it is, so by default the first fit's are there).
    first_warnings = [] if model is first else [f"drift fit to the zero bias: {m}" for m in first.summary["warnings"]]
    if model is not first:  # the first fit's notes on its ranges, as said here, are notes on ranges too
        model.summary["range_notes"] = list(model.summary["range_notes"]) + [
            said for said, m in zip(first_warnings, first.summary["warnings"]) if m in first.summary["range_notes"]]
    compensated = model.compensate(w, temp, temp_outside)
    # what the user gets, less the drift model: the Kalman output, or with no filter the compensated zero bias
    # itself (L − f would be a constant, and the class check could not fail)
    residual_filtered = filtered - model.evaluate(temp, temp_outside) if kalman_settings else compensated
    report = {"preprocess": {k: v for k, v in pre.items() if k != "series"},
              "warnings": unit_warnings + gap_warnings + list(pre["summary"]["warnings"]) +
              list(ar.summary["warnings"]) + first_warnings, "gaps": gaps,
              "ar": {"order": ar.order, "coefficients": ar.coefficients.tolist(),
                     "standard_errors": ar.standard_errors.tolist(), "sigma2": ar.sigma2,
                     "order_at_maximum": ar.order_at_maximum, "whiteness": ar.whiteness,
                     "warnings": ar.summary["warnings"], "fitted_to": AR_FITTED_TO},
              "orders": [s["order"] for s in model.segments],
              "drift_span_before": drift_span(w, temp), "drift_span_after": drift_span(compensated, temp),
              "compensated": compensated, "filtered": filtered, "notes": gap_notes + notes,
              "spikes": {"rows": spike_rows.tolist(), "sigmas": np.asarray(spike_sigmas).tolist(), "dropped": False}}
    # the drift model's own uncertainty over the log's temperatures: a bias that compensation adds, shared by the
    # samples at one temperature (the accuracy checks above judge the residuals, this is what they cannot see)
    drift_se = model.standard_error(temp, temp_outside)
    which = range_index(model.segments, temp)
    report["drift_standard_error"] = {
        "max": float(drift_se.max()), "at_temp": float(temp[int(np.argmax(drift_se))]),
        "per_range": [float(drift_se[which == k].max()) if np.any(which == k) else float("nan")
                      for k in range(len(model.segments))]}
    if spike_rows.size:
        report["warnings"].append(spike_words(spike_rows, report["spikes"]["sigmas"]))
    report["frozen"] = _frozen["runs"]
    if _frozen["said"]:
        report["warnings"].append(_frozen["said"])
    # One temperature level (every sample in one 5 °C bin): both spans are 0 and say nothing about the model.
    one_level = len(level_means(w, temp)) < 2
    if one_level:  # (a blind check's 0.2 °C gave a one-range model and no word of the span)
        report["warnings"].append(
            f"temp moves only {np.ptp(temp):.3g} °C ({temp.min():.4g} … {temp.max():.4g}; within one 5 °C level): the "
            f"model holds over that span only, and the zero bias's own spread here ({np.ptp(np.percentile(w, [1, 99])):.3g}, "
            "1st–99th percentile) is not told from a drift with temperature; a drift model needs the operating "
            "range (a chamber cycle or a warm-up)")
    report["drift_reduction"] = (float("nan") if one_level else
                                 report["drift_span_before"] / max(report["drift_span_after"], 1e-300))
    if not one_level and report["drift_reduction"] < 0.5:  # twice as wide: no chance spread of level means with nothing to remove
        report["warnings"].append(
            f"the compensation widens the zero bias's spread over temperature ({report['drift_span_before']:.4g} → "
            f"{report['drift_span_after']:.4g}, per-level means): the model does not describe this drift — a "
            "dependence on the inside–outside difference (--regressor difference), on the rate of change, or "
            "hysteresis? Do not apply it as it is")
    if regressor == "difference" and not one_level:
        # the other regressor tried: at settled holds the inside–outside difference is nearly constant (self-heating)
        # and a blind check's model of it was three constants, 2.9× smaller a drift where the temperature gave 65×
        other = fit_drift(w, temp, None, **{**drift_options, "regressor": "temp"})
        span = drift_span(other.compensate(w, temp), temp)
        if span < 0.5 * report["drift_span_after"]:
            report["warnings"].append(
                f"the device temperature explains this drift better than the inside–outside difference: compensated "
                f"with it the spread over temperature is {span:.4g}, against {report['drift_span_after']:.4g} "
                f"(per-level means, {report['drift_span_after'] / max(span, 1e-300):.3g}× wider with the "
                "difference); fit with --regressor temp")
    lag = thermal_lag(model, compensated, temp, t, temp_outside, breaks)
    if _detrended is None and lag is not None and (lag.get("ageing") or {}).get("said"):
        return _refitted_without_trend(w, temp, temp_outside, t, lag, model, dict(
            regressor=regressor, breakpoints=breakpoints, max_order=max_order, significance=significance,
            continuous=continuous, ar_max_order=ar_max_order, q=q, r=r, steady_state=steady_state,
            subseries=subseries, rated=rated, accuracy_class=accuracy_class, whiten=whiten,
            drift_input=drift_input, spikes=spikes, _frozen=_frozen))
    report["thermal_lag"] = lag  # (None when the log's history cannot be judged: the key is there either way)
    if lag is not None:
        report["warnings"] += history_warnings(lag)
        if _detrended is not None:  # (the trend taken out: named and sized in the first fit, said by the caller)
            lag["ageing"] = _detrended
    if rated is not None:
        # Two views: the filtered output sample by sample (drift residual plus what noise the filter
        # leaves), and the drift alone (the compensated zero bias averaged per temperature level).
        report["accuracy"] = accuracy(residual_filtered, rated, accuracy_class)
        # per level and per branch where the log visits a level both ways: averaged together, a 3 °C hysteresis's
        # 0.056 A off each branch had cancelled to 0.004 A, and the class "MET"
        report["accuracy_drift"] = accuracy(_branch_level_means(compensated, temp, lag), rated, accuracy_class)
        if kalman_settings:  # the third view: W − f(T) itself, what the device puts out without the filter
            report["accuracy_compensated"] = accuracy(compensated, rated, accuracy_class)
            said = _met_only_filtered(report["accuracy"], report["accuracy_compensated"], kalman_settings, ar.sigma2)
            if said:
                report["warnings"].append(said)
    # The data's warnings go with the model (summary["warnings"] keeps the drift fit's own; drift apply and
    # export-c repeat both: fit_warnings), the ones that decide whether the model may be exported as it is also
    # by name: the AR model's whiteness test (noise_model_rejected) and a unit hint (temperature_unit_hint).
    # and the drift fit's own (standard errors that are lower bounds near a unit root …), but for the notes that the
    # ranges were adjusted: report["warnings"] is every warning of the fit (a blind check: the README's example
    # printed it and missed "lower bounds")
    notes = set(model.summary.get("range_notes", []))
    report["warnings"] += [w for w in model.summary.get("warnings", []) if w not in notes and w not in report["warnings"]]
    model.summary["fit_warnings"] = list(report["warnings"])
    p_value = float(ar.whiteness["p_value"])
    model.settings["ar"]["whiteness"] = {"p_value": p_value if p_value == p_value else None,  # (untested: null)
                                         "lags": int(ar.whiteness["lags"]), "white": bool(ar.whiteness["white"])}
    if unit_warnings:
        model.summary["temperature_unit_hint"] = unit_warnings[0]
    return model, report
