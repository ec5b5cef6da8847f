"""The diagnosis itself (see fluxcal.diagnose for the method)."""
from __future__ import annotations

import json
import warnings
from datetime import datetime, timezone
from dataclasses import dataclass, field, replace
from functools import lru_cache, partial
from math import comb
from pathlib import Path
from types import SimpleNamespace

import numpy as np
from scipy import stats

from .. import _core
from .._arrays import (as_field_norms, as_samples, field_norm_given, held_copies, repeated_blocks, repeated_words,
                       samples_units)
from .._axis_weights import map_fit, noise_values, sampson, scaled_start, symmetric
from ..attitude import magnetic_frame
from ..calibration import Calibration
from ..io.recording import UNIX_SECONDS
from ..outliers import _runs as index_runs, find_outliers
from ..sim.effects import CANDIDATES, MEMO_FLOATS, _Compression, _per_diagnosis, _time_ordered, scatter_rows

# Base models: (uses a reference vector, base parameters held at their start values).
MODELS = {
    "ellipsoid": (False, ()),                      # offset + symmetric matrix, |h| = H
    "scale": (False, ("a01", "a02", "a12")),       # offset + three scale factors, |h| = H
    "vector": (True, ()),                          # offset + full matrix against reference vectors
    "vector_scale": (True, ("w01", "w02", "w10", "w12", "w20", "w21")),
}
ABSORBED = 0.05       # a candidate direction is absorbed when < 5 % of it is new to the base Jacobian (first-order
                      # equivalences hold only up to the residuals, a few per cent when an effect is missing)
HELDOUT_FRACTION = 0.25
HELDOUT_ALPHA = 0.05  # the held-out improvement confirms in-sample evidence that is already strong
MIN_GAIN = 0.1        # an effect worth modelling removes at least 10 % of the held-out gap
# No model predicts held-out readings better than their noise allows. An effect that lowers the sensor's
# gain where it works (saturation about a large hard iron) brings the held-out field error below the
# linear fit's noise floor by that gain — 0.77 of it at the strongest simulated; a fit whose features
# rebuild each reading from its own direction (coefficients of order one) brought it to 0.06–0.32 on a
# real recording.
NOISE_FLOOR_FRACTION = 0.5
# ... and with a base calibration the readings leave partly undetermined (a vehicle driving level: 10–16 % of the
# field's directions seen), a candidate whose features are the signal's alone (cross-axis, a non-linearity) takes up
# the noise along the open direction: blind-check nulls gave cross_axis and the cubic 0.74–0.92 of the floor, held
# out, ΔBIC down to −716 (a right model's is ≈ 1); a temperature's or time's factor in them keeps them from it
UNDETERMINED_FLOOR_FRACTION = 0.95
# A sensor's non-linearity (a cubic, saturation, cross-field error) changes its readings by a few per cent of
# the signal (simulated and found: at most 15 %, saturation about a hard iron of 4.4 fields). Coefficients
# that change them by as much as the signal itself no longer describe a sensor: features taken from the fit's
# own signal can then stand in for the signal (an even-order candidate, tried on the QMC5883L recording,
# reached a coefficient of 15 at the signal's scale once a drift was fitted beside it). The bound is half the signal,
# over three times that largest: a blind check's level drives with correlated noise had a cubic, saturation and a
# cross-axis error accepted at 0.6–0.8 of the signal (164 % departures from a straight line), which no transducer
# whose readings are still a calibration's input makes; 1.0 let them through.
MAX_DISTORTION = 0.5
# Effects' course in time (or temperature, current) shows in the readings unless the field's course cancels it: a
# static sensor's drift is all of their variation (1×); twice it can only be cancelled by the base calibration
MAX_HIDDEN_CHANGE = 2.0
NOISE_CANDIDATES = ("colored_noise", "quantization")
CONFOUND_BIC = 10.0   # a rival within 10 of the winner's ΔBIC is not told apart (2 ln Bayes factor < 10 is short of
                      # "very strong" evidence, Kass & Raftery 1995)
# ... nor an event (a free course in time: a magnet passing, a step) and a candidate driven by a logged quantity
# (temperature, current) or following a law in time (a drift settling after power-on) that take out the same
# departure (the changes their fits make to the residuals agree to a cosine of 0.95) when the other explains at
# least half as much: the free course fits whatever the logged quantity drives, or the law, and noise besides
# (blind checks: a gain equal on all axes following the temperature, or warming up, named moving_dipole with no
# rival said). The event is still named: preferring the logged one took a temperature bump 0.08 of the recording
# after a magnet's pass for an effect. Between two of fixed shape ΔBIC decides.
SAME_DEPARTURE, CONFOUND_SHARE = 0.95, 0.5
# A drift's law beside a logged quantity's effect that take out the same departure are not told apart while the law's
# ΔBIC lead is within this many times what the logging's noise and resolution could cost the logged one (_rivals)
LOGGING_MARGIN = 3.0
LOGGED_REGIMES = ("temperature", "current")
NESTED = 0.999        # signatures this close span one inside the other (saturation = equal cubics on every axis)


@dataclass
class _Data:
    m: np.ndarray
    t: np.ndarray
    temp: np.ndarray | None
    reference: np.ndarray | None
    down: np.ndarray | None  # the down (or up) direction per reading, sensor frame: heading errors
    field_norm: float  # |h| of the magnitude model: the mean of field_norms when those are given
    units: str
    source: str
    notes: list = field(default_factory=list)  # what _prepare changed in the data, for the report
    current: np.ndarray | None = None  # A drawn near the sensor (motors, a heater)
    clipping: list = field(default_factory=list)  # [{axis, rail, readings, fraction}]: the sensor's range clips
    field_norms: np.ndarray | None = None  # each reading's |field| (logged beside it: a field that changes)
    # what the candidates compute once per diagnosis (sim.effects._per_diagnosis; its entries name their inputs)
    memo: dict = field(default_factory=dict, repr=False, compare=False)
    # axes of unequal noise (a vector model's _axis_noise, or σ given per axis): each axis × σ̄/σ_axis in every fit and test
    axis_weights: np.ndarray | None = None


def _field_at(data: _Data, rows=slice(None)):
    """The |h| the magnitude model fits the readings `rows` to: each one's own |field| when logged, else the one."""
    return data.field_norm if data.field_norms is None else data.field_norms[rows]


CLIPPED = 0.005     # an axis at one extreme value in at least this fraction of the readings (and CLIPPED_MIN of them):
CLIPPED_MIN = 20    # the sensor's range clips it (hard saturation), not a glitch
PILE_UP = 4         # the extreme value holds more than this many times the readings of its inward neighbours
CLIP_MARGIN = 3.0   # readings within this many noise σ inside a clipping rail are left out with it: the noise that
                    # would have taken them past it was cut, so those left below are biased inwards (a compression)
RAIL_BAND = 7.0     # a rail the noise blurs: its readings lie within this many σ of the extreme reading (± 3.5 σ)
RAIL_MOVES = 10.0   # ... while the other axes spread over more than this many σ (_mad: the sensor turning, not still)
RAIL_SPREAD = 1.5   # ... its readings spread less than this many σ (_mad; the noise on one value: a band RAIL_BAND
                    # wide over which the readings still rise, a soft saturation or a sine's peak, spreads 2.3 σ)
RAIL_SHORT = 10     # ... a short episode's readings at least (more than in the band inward: not PILE_UP times),
RAIL_DEEP = 4.0     # ... (its readings this many σ inside the others' ellipsoid: those a range cut)
RAIL_SLOPE = 0.5    # ... held at the rail: they follow the value the ellipsoid gives them by less than this slope
RAIL_CUT = 3.0      # ... and its readings fall this many times further inside the others' ellipsoid than they fall off it


def _clipping(m: np.ndarray, sigma: float = 0.0) -> list:
    """[{axis, rail, readings, fraction, noisy}] for each axis whose readings pile up at its minimum or maximum: more
    than PILE_UP times as many as on either of the next two values inward (a coarse ADC's extreme code is as full as
    its neighbours; a rail collects everything beyond the range). With the noise σ given, also a rail the noise
    blurs (an analog front end that saturates before a noisy converter: a blind check's ±55 µT clip was named a 24 %
    cubic non-linearity): readings within RAIL_BAND σ of the extreme, while the other axes move (a sensor held still
    at an extreme orientation piles up too), and are flat: PILE_UP times as many as in the band inward of it, spread
    as the noise alone spreads them, and off the ellipsoid of the readings on no rail (_rail_cut); or, for a short
    episode or a slow way in and out (RAIL_SHORT readings up, more than in the band inward), RAIL_SHORT of them
    deep inside that ellipsoid not following the value it gives them (slope under RAIL_SLOPE)."""
    out, cut, blurred = [], np.zeros(len(m), dtype=bool), []
    for axis, column in enumerate(np.ascontiguousarray(m.T)):
        values, counts = np.unique(column, return_counts=True)
        for end in (slice(None, 3), slice(-1, -4, -1)):
            count, inward = int(counts[end][0]), counts[end][1:]
            rail = float(values[end][0])
            if count >= max(CLIPPED_MIN, CLIPPED * len(column)) and count > PILE_UP * max(inward, default=0):
                out.append({"axis": "xyz"[axis], "rail": float(rail), "readings": count,
                            "fraction": count / len(column), "noisy": False})
                cut |= column == rail
            elif sigma > 0:
                side = 1.0 if end.start == -1 else -1.0  # (the maximum's end, or the minimum's)
                depth = side * (rail - column)  # how far inward of the extreme
                band = depth <= RAIL_BAND * sigma
                count, inward = int(band.sum()), int(np.sum((depth > RAIL_BAND * sigma) & (depth <= 2 * RAIL_BAND * sigma)))
                piled = (count >= max(CLIPPED_MIN, CLIPPED * len(column)) and count > PILE_UP * max(inward, 1)
                         and _mad(column[band]) < RAIL_SPREAD * sigma)
                # a short episode (a hand turn through the rail for half a second, 15–24 readings) or a slow way in
                # and out fills the band inward too: a blind check's went unseen in 7 of 30, named a moving dipole
                if ((piled or (count >= RAIL_SHORT and count > inward))
                        and np.min(_mad(np.delete(m[band], axis, axis=1))) > RAIL_MOVES * sigma):
                    blurred.append((len(out) + len(blurred), axis, side, band, count, piled))
    # each blurred rail judged against the readings on no rail, the others' too (a 24-reading rail judged beside the
    # other end's 229 uncut readings had the ellipsoid's misfit of those, and was missed)
    left_out = cut | np.logical_or.reduce([c[3] for c in blurred]) if blurred else cut
    for place, axis, side, band, count, piled in blurred:
        falls_off, slope = _rail_cut(m, left_out, band, axis, side, sigma)
        if (piled and falls_off) or slope < RAIL_SLOPE:
            out.insert(min(place, len(out)), {"axis": "xyz"[axis], "rail": float(np.median(m[band, axis])),
                                              "readings": count, "fraction": count / len(m), "noisy": True})
    return out


def _mad(values: np.ndarray) -> np.ndarray:
    """Each column's spread as a σ from its median absolute deviation (a few readings far off do not make it: a
    simulation's still start, 43 of a pile's 53 readings, beside 10 from two turns, had a standard deviation of 30 σ)."""
    return 1.4826 * np.median(np.abs(values - np.median(values, axis=0)), axis=0)


def _rail_cut(m: np.ndarray, left_out: np.ndarray, band: np.ndarray, axis: int, side: float, sigma: float):
    """(falls_off, slope) for the readings in `band` (piled up at `axis`'s extreme, `side` +1 its maximum): whether they
    fall inside the ellipsoid the others (not `left_out`: other rails' too) describe, RAIL_CUT times further than
    those fall off it (median |residual|) — a component that turns about one axis piles up at its extremes as well
    (a sine dwells at its peaks: the library's own tumbles were taken for rails in 3 of 30), but on the ellipsoid —;
    and, over the readings that fall inside it by more than RAIL_DEEP of the others' σ (a short episode's way in and
    out is most of its band, on the ellipsoid), how the axis's readings follow the value that puts each on it: a
    range's cut holds them at the rail (slope 0), a soft saturation still rises (inf when fewer than RAIL_SHORT
    readings fall so far inside: nothing is cut)."""
    from ..ellipsoid import fit_ellipsoid

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cal = fit_ellipsoid(m[~left_out])
    except ValueError:  # (the others alone do not span an ellipsoid: not judged a blurred rail)
        return False, np.inf
    corrected = cal.apply(m)
    size = np.linalg.norm(corrected, axis=1)
    radius = np.median(size[~left_out])
    typical = np.median(np.abs(size[~left_out] - radius))
    falls_off = bool(np.median(np.abs(size[band] - radius)) > RAIL_CUT * typical)
    deep = band & (radius - size > RAIL_DEEP * 1.4826 * typical)
    if deep.sum() < RAIL_SHORT:
        return falls_off, np.inf
    # the axis's value on the ellipsoid, the others as read: |h + a s|² = R² for s, its root on the rail's side
    h, a, column = corrected[deep], cal.matrix[:, axis], m[deep, axis]
    ha = h @ a
    root = np.sqrt(np.maximum(ha ** 2 - (a @ a) * (np.sum(h * h, axis=1) - radius ** 2), 0.0))
    implied = column + (-ha + side * root) / (a @ a)
    x = implied - implied.mean()
    return falls_off, float(x @ (column - column.mean()) / (x @ x))


@dataclass
class Diagnosis:
    """What `diagnose` found. `ranking`: one dict per candidate, accepted effects first (in the order
    they were added), then the rest by ΔBIC; an accepted row may carry `confounded_with` (see
    `confounded`) and, for a move of the reference, the whole fitted move: `rotation_deg` (misalignment's
    rotation vector, degrees) or `delay_ms` (time_offset: the readings this late);
    `limit` saturation's profiled limit (reading units; None: its cubic limit, L → ∞); `lag_s` a temperature
    candidate's profiled lag (the sensing element's temperature: the logged one through a first-order lag);
    `warmup_s` offset_drift's profiled settling time constant (an exponential warm-up; absent: linear); `width`
    hysteresis' profiled loop width (reading units, one for every axis);
    `offset_kind` for an effect in the transducer (a gain, a non-linearity), when the data decide it: "hard_iron"
    (it acts on the offset too: a field at the sensor) or "electronic" (the offset is the sensor's own, added
    after the transducer); None when undecided;
    `on_s`/`off_s` give an event's box (moving_dipole, offset_step: first and last time within it, None at
    the recording's ends; for a moving_dipole's pass, the times it reaches), a pass's `closest_s` and
    `passage_s` its closest approach and the time it takes to travel its closest distance, `searched_times`
    how many times the search placed (the box's edges inside the recording, or a pass's two), each counted as
    a parameter in ΔAIC and ΔBIC; an accepted
    offset_step's `jump`, `jump_s`, `back_s` the step as a jump (a box from the recording's start reverses the
    coefficients' sign); `found_with` names the effect a row was found together with (each passed its
    held-out test only with the other modelled); an accepted event that recurred (a magnet carried past twice, a
    device switched on twice) has `episodes`, one dict per episode in the order found, each with its own times,
    evidence when added (`delta_bic`, `lr_pvalue`, held-out gaps and p) and size (`peak_field`… or `jump`…); the
    row's own fields are its first episode's, its `coefficients` the whole block's (the first episode's validated
    terms, each further one's, then the first's refined terms), and `episodes_together` says two were found
    together; `shape_terms` the terms of an accepted dipole's refined
    time profile (its `coefficients`, in units of the field norm: Legendre P0… across the box — for a pass
    against magnitudes Anderson's τⁿ/(1 + τ²)^(5/2), n = 0, 1, 2, then τⁿ/(1 + τ²)⁵, n = 0…4 —, each times
    the world's north, east and down when reference vectors and the down direction are given — P0·N,
    P0·E, P0·D, P1·N, … — else along the field); an accepted moving
    dipole's largest field in field units `peak_field` at `peak_s`, with `peak_ned` (north, east, down)
    or `peak_along_field` (signed);
    an accepted row's `heldout_leverage` is the
    held-out readings' mean leverage for a fit on the rest (the variance, in noise variances, of its
    prediction there) and `heldout_gain_unresolved` whether the held-out gap's fall is within 2√2 σ √leverage
    (what the two fits' parameter noise alone can make), then said in `caveats` (infinite, None in the JSON with
    `heldout_leverage_undetermined`, when the rest does not determine every parameter they depend on);
    a short event's `heldout_block` the readings per held-out block of its own span (None: the recording's 16
    blocks), its gaps measured on the `heldout_n_judged` held-out readings it acts on;
    every judged row's `heldout_noise_floor` is the held-out field error that white noise σ alone leaves
    through the calibration without it, and `distortion` the largest change (RMS, in units of the signal)
    that one signal-dependent effect makes to the readings in the fit with it, `hidden_change` the change (RMS about
    its mean, in units of the readings' own variation) that its other effects make together; a row otherwise
    significant is not accepted, with a `note`, when its held-out field error falls below half that floor or its
    distortion exceeds the signal (`degenerate`, which of the two: its features rebuild the readings from
    themselves), when its hidden change exceeds MAX_HIDDEN_CHANGE (`degenerate` "changes the readings more than they
    vary": the base calibration cancels it), or when its fit cancels an effect found before it (`cancels`, that
    effect's name: each changes the readings by over CANCELLING× what both do together; `degenerate` "cancels …") or
    turns one found before it unphysical by that effect's own rule (`makes_unphysical`: its `effect` and `reason`), or
    when its held-out field error rises (`field_error_rises`: its residuals fell only through its gain); a judged row's `unmet` lists the
    acceptance tests it fails ("in_sample", "bic", "heldout_p", "heldout_gain", "heldout_resolved" — beside an
    effect already found, a held-out fall within what the fits' parameter noise makes —, "pruned"; empty for an
    accepted one): a row that fails only the held-out ones has
    strong evidence in the recording that the held-out readings do not confirm (a profiled lag or warm-up time is
    chosen again without them for that test: `lag_s_without_heldout`, `warmup_s_without_heldout`; a box longer than
    two held-out blocks has its edges refined again without them, within a block's length, `on_s_without_heldout`,
    `off_s_without_heldout`, and the `heldout_n_unplaced` held-out readings of a block an edge may lie in (within its
    95 % interval on the training readings) are not judged, its field errors and noise floor neither: which side of
    it they lie only they would say);
    an effect accepted in an early round that no longer pays BIC's price once the later ones are modelled
    is left out (its row's `note` says so, `pruned_delta_bic` the ΔBIC for keeping it); one placed again once
    later ones were modelled (a step's edges, a drift's time constant) or replaced by its kin (the cubic by
    saturation) has `replaced`: its first placement's `on_s`/`off_s`/profiled value…, the kin's `effect`, the
    effects `modelled` since, and `delta_bic_gain` (the row it left has "replaced" in `unmet`); one taken first
    in a second search, whose model fits better than the first search's, has `another_order`: the first search's
    `first` effect, its `accepted` effects, its residuals' `rms_z` and the `delta_bic` between the two models;
    `significant_not_modelled` marks a candidate still significant when the `max_effects` limit stopped
    the search; an accepted row's `coefficients` and `standard_errors` are those of the final model (every
    accepted effect fitted together), the others' those of their own round. `where`: residual tables per regime;
    `remaining` the same for the final model, and with a given noise σ `remaining["noise_check"]`: whether
    the final residuals exceed it (`exceeds`, χ² `pvalue`, `rms_over_sigma`); `remaining["unexplained"]`: the
    share of the base model's gap² the effects found leave (`share`; colored_noise takes none), and `left`
    when that is most of it and the residuals are well above the noise (the text report says NOT EXPLAINED:
    the cause is outside the candidates). `significant`: any effect found. `axis_noise`: each axis's σ when their
    noise differs (given so; or, against reference vectors, estimated and equal rejected at AXES_ALPHA; `noise_sigma`
    is their RMS): every fit and test weights an axis's residuals by noise_sigma / its σ (a magnitude model scales
    each axis so in its distance to the ellipsoid), and the residuals in `where`, `remaining` and `series` are those
    weighted ones."""

    model: str
    noise_sigma: float
    noise_source: str
    units: str
    source: str
    ranking: list
    accepted: list
    where: dict
    remaining: dict
    base: Calibration
    series: dict = field(repr=False, default_factory=dict)  # per-reading arrays for the figures
    caveats: list = field(default_factory=list)  # what may make the findings untrustworthy (inputs, coverage)
    clipping: list = field(default_factory=list)  # hard saturation: axes whose readings pile up at the range's end
    axis_noise: list | None = None  # σ per axis when their noise differs (given, or a vector model's) (None: noise_sigma on each)

    @property
    def significant(self) -> bool:
        return bool(self.accepted)

    @property
    def confounded(self) -> dict:
        """{accepted effect: [rivals]} for the effects this recording cannot tell apart from a rival
        candidate: the rival was significant in the same round with ΔBIC within CONFOUND_BIC (or an event and
        a temperature or current effect or a drift took out the same departure, `_law_inside_event`: same_departure),
        and once the accepted effect was modelled its evidence collapsed (absorbed, or ΔBIC ≥ 0; a same_departure
        rival: no longer significant). Each rival:
        effect, regime, delta_bic_difference, signature_correlation (largest canonical correlation of
        the two signatures in the residuals), same_departure, and for a temperature/time pair
        temperature_time_correlation."""
        return {r["effect"]: r["confounded_with"] for r in self.ranking if r.get("confounded_with")}

    def to_dict(self) -> dict:
        from .report import confound_lines, temperature_caveat

        return {"source": self.source, "model": self.model, "units": self.units,
                "noise_sigma": self.noise_sigma, "noise_source": self.noise_source, "axis_noise": self.axis_noise,
                **({} if not isinstance(self.base, Calibration) else {  # (a cable diagnosis has no field norm)
                    # |h| of the magnitude models: the mean of each reading's own when those were given
                    "field_norm": self.base.field_norm,
                    "field_norm_per_reading": self.series.get("field_norms") is not None}),
                "significant": self.significant, "accepted": self.accepted, "confounded": self.confounded,
                "ranking": self.ranking, "clipping": self.clipping,
                "where": self.where, "remaining": self.remaining, "caveats": self.caveats,
                # the report's CANNOT TELL APART and MAYBE TEMPERATURE paragraphs, for readers of the JSON only
                "explanations": confound_lines(self) + temperature_caveat(self)}

    def save_json(self, path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(_finite(self.to_dict()), indent=2, default=_jsonable, allow_nan=False) + "\n")
        return path

    def text(self) -> str:
        from .report import text

        return text(self)

    def report(self, folder) -> Path:
        from .report import write_report

        return write_report(self, folder)

    def __str__(self) -> str:  # print(d): the report, not the fields (the dataclass repr ran to 28 000 characters)
        return self.text()

    def __repr__(self) -> str:
        found = ", ".join(map(str, self.accepted)) if self.accepted else "no significant effect"
        unit = f" {self.units}" if self.units else ""
        return (f"<{type(self).__name__} of {self.source!r}, model {self.model}: {found}; noise σ "
                f"{np.mean(self.noise_sigma):.4g}{unit} — print(d) or d.text() for the report>")


def _finite(value):
    """`value` with every non-finite float as None (JSON has no Infinity or NaN: strict readers reject them; an
    undetermined held-out leverage is infinite, and its row says `heldout_leverage_undetermined`)."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_finite(v) for v in value]
    if isinstance(value, (float, np.floating)) and not np.isfinite(value):
        return None
    return value


def _jsonable(value):
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.bool_):
        return bool(value)
    raise TypeError(f"not JSON: {type(value)}")


def estimate_noise(samples) -> float:
    """White-noise σ of the readings (per axis, then RMS over axes) from third differences:
    Δ³m = m[i+2] − 3m[i+1] + 3m[i] − m[i−1] has variance 20σ² for white noise, while a motion smooth at
    the sample rate contributes only its third derivative × Δt³ (second differences would still see a
    brisk turn's curvature); the median absolute deviation ignores the samples where it does not."""
    m = as_samples(samples)
    if len(m) < 20:
        raise ValueError(f"samples: {len(m)} readings, need at least 20 to estimate the noise")
    return _difference_noise(m, 3)


def time_series_noise(values, steady: bool = False) -> float | None:
    """The white-noise σ of readings (rows in time order, any number of columns) from third differences when that
    is a yardstick, else None: not when consecutive readings differ about as much as any two (UNORDERED: rows in
    independent orientations or out of time order, whose differences measure the turning), nor with fewer than 20
    rows (once repeated readings are left out) or a σ of 0 (readings coarser than their noise). `steady`: also not when the 4th-order estimate departs
    from the 3rd (MOTION_DROP: the differences hold motion, and over-estimate the noise)."""
    x = np.asarray(values, dtype=float).reshape(len(values), -1)
    x = x[changed_rows(x)]
    if len(x) < 20:
        return None
    sigma = _difference_noise(x, 3)
    if not (sigma > 0 and sigma <= UNORDERED * np.sqrt(np.mean(np.var(x, axis=0)))):
        return None
    if steady and abs(_difference_noise(x, 4) - sigma) > (1 - MOTION_DROP) * sigma:
        return None
    return sigma


def changed_rows(values) -> np.ndarray:
    """Which rows (in time order) differ from the one before (the first does). A logger that reads faster than the
    sensor updates repeats each value: its zero differences would shrink the MAD of any difference (5.5× too small
    at 5 reads per update), so a noise estimate leaves the repeats out."""
    x = np.asarray(values, dtype=float).reshape(len(values), -1)
    return np.r_[True, np.any(np.diff(x, axis=0) != 0, axis=1)] if len(x) else np.zeros(0, dtype=bool)


def residual_noise(readings, residuals, directions, t=None) -> tuple[float, int] | None:
    """The readings' own noise σ (their unit) and the stride, in readings, it was measured at, for judging a fit's
    residuals (one per reading, the readings' unit) against: noise_within_turns of the residuals in time order
    (`directions`: the corrected field's unit vectors), never below the readings' own third differences
    (time_series_noise), whose test of being a time series it takes. `t`: the rows' times (ordered by them), else row
    order. Stride 0: the readings' own differences were the larger, and taken — also when they hold the motion of a
    fast turn (a figure-8's 6.6 counts where diagnose measured 1.7): the residuals' differences then cannot tell noise
    correlated over a few readings (a sensor's low-pass filter) from white, and taking them for the yardstick had
    said "the model misses" of right models at 3.7–6.8× (a review's simulations). The price: on such a turn a miss
    below the turning's differences goes unsaid (an offset that moved by 5 % of the field, 6.7× the noise, at 5 Hz
    and 60 °/s; at 50 Hz it is said) — log faster or turn more slowly to judge one. The printout names the readings'
    differences, and when the residual σ is below them says that it bounds the noise (noise_line). None for rows
    that are no time series."""
    x, r, u = (np.asarray(a, dtype=float) for a in (readings, residuals, directions))
    order = slice(None) if t is None or len(t) != len(x) else np.argsort(t, kind="stable")
    x, r, u = x[order], r[order], u[order]
    white = time_series_noise(x)
    if white is None:
        return None
    changed = changed_rows(x)  # (as the readings' own σ leaves a logger's repeats out)
    with np.errstate(all="ignore"):  # (a reading far off the fit may overflow its square; the MAD ignores it)
        sigma, stride = noise_within_turns(r[changed], u[changed])
    return (sigma, stride) if sigma > white else (white, 0)


def noise_within_turns(residuals, directions) -> tuple[float, int]:
    """The noise σ of a fit's residuals (rows in time order) and the stride k it was taken at: third differences of
    residuals k apart, k = 1, 2, 4, … (at most MAX_STRIDE and N/24) while the sensor turns less than TURN_SPAN over
    the 3k readings a difference spans in at least half such spans (`directions`: the corrected field's unit vectors,
    the same rows), and while each doubling of k after the first raises the σ by no more than GROWTH; k = 1 unless
    that raised it by more than LEVEL. Noise correlated over fewer readings than that (a sensor's internal low-pass
    filter: AR(1) with φ = 0.9 leaves a quarter of its σ in consecutive readings' third differences) is then all
    counted; what the model misses is not: a miss that varies with the direction varies little over such a span,
    and one that varies smoothly in time (a |field| that changes along a flight) grows faster than noise does."""
    r = np.asarray(residuals, dtype=float).ravel()
    u = np.asarray(directions, dtype=float)
    # the angle turned from each reading to the next (2 arcsin of half the chord: exact at any angle), summed over
    # spans; judged at the spans' median, as the σ is the differences' median: when half the spans turn less, the
    # median difference is one of theirs (a vehicle that stops and goes: its mean turn had been half its turns')
    step = np.nan_to_num(2 * np.arcsin(np.clip(np.linalg.norm(np.diff(u, axis=0), axis=1) / 2, 0, 1)), nan=np.pi)
    path = np.concatenate([[0.0], np.cumsum(step)])

    def turned(span):
        return float(np.median(path[span:] - path[:-span])) if len(path) > span else np.inf

    def sigma(k):
        d = r[3 * k:] - 3 * r[2 * k:-k] + 3 * r[k:-2 * k] - r[:-3 * k] if len(r) > 3 * k else np.zeros(0)
        return float(1.4826 * np.median(np.abs(d - np.median(d))) / np.sqrt(comb(6, 3))) if len(d) else 0.0

    first = sigma(1)
    k, at_k = 1, first
    while 2 * k <= MAX_STRIDE and 3 * 2 * k <= len(r) / 8 and turned(3 * 2 * k) <= TURN_SPAN:
        wider = sigma(2 * k)
        if k > 1 and not wider <= GROWTH * at_k:  # (the first doubling: FIRST_DOUBLING)
            break
        k, at_k = 2 * k, wider
    return (at_k, k) if at_k > LEVEL * first else (first, 1)


TURN_SPAN = 0.75  # rad (≈ 43°) turned over a third difference's span. What the model misses leaks into the stride's
                  # σ by a share of the residual σ that grows with the span: ≤ 0.06 up to 0.76 rad, 0.06–0.2 at
                  # 1–1.5 rad (simulated hand turns at 10, 50 and 100 Hz whose offset moved by 5 or 20 % of the field
                  # halfway), so a miss many times the noise still shows as ≥ 15× it
LEVEL = 1.15  # the longest stride's σ under this × the first's: the noise is white, and the first's σ is kept
              # (estimates at longer strides scatter more: 6 % at stride 16 in 3000 readings)
GROWTH = 3.5  # a doubled stride's σ over the stride's: noise grows by at most ~2^1.5 = 2.8 (white: 1; a first-order
              # filter's, AR(1), like a random walk within its correlation: √2; a second-order low-pass's: 2.8, above
              # 3 in one of four simulated 3000-reading logs), a miss smooth in time by up to 2³ = 8 (the airborne
              # recording's magnitude fit, a |field| changing along the track: 6.5, then 4.7). A smooth miss under
              # white noise inflates the σ by at most 9 % before its growth passes this.
# FIRST_DOUBLING: stride 2 is taken whatever it adds. A low-pass filter's zero at the Nyquist frequency (a
# second-order Butterworth's) hides its noise from consecutive readings' third differences (a quarter of its σ at a
# cutoff of 0.4× Nyquist, growing > 3× at the first doubling), while a miss smooth in time has a negligible share at
# stride 1, and 8× that at stride 2 stays negligible (the airborne magnitude fit: 0.05 → 0.32 nT of a 46 nT residual).
MAX_STRIDE = 8  # readings: a sensor's own filter (an average of ≤ 16 readings, a first-order one of φ ≤ 0.9)
                # correlates its noise over about this many; a slower wander is no noise to ignore but a miss that
                # biases the calibration (a blind check: a |field| wandering as a random walk, 2–5 % of the field, on a
                # slowly turning drone was taken for noise at stride 32, the ratio 2.7 for a miss 13× the noise)


MIXTURE_CLIP = 6.0  # a residual difference beyond this many robust σ is a glitch or an edge, not the noise


def _difference_noise(values: np.ndarray, order: int, mixture: bool = False) -> float:
    """σ from the MAD of `order`-th differences along the rows (variance C(2k, k)σ² for white noise),
    per column, then RMS over the columns. `mixture`: the noise's σ changes from row to row (a magnitude's
    residual is the noise along the field, and the axes' noise differs: σ [0.02, 0.05, 0.12] per axis), and the
    MAD of such a mixture falls short of its RMS (0.0645 for 0.0759: the residuals then read 1.18 σ); instead the
    mean square of the differences, each clipped at MIXTURE_CLIP robust σ (a glitch or a step's edge stays out)."""
    x = np.asarray(values, dtype=float).reshape(len(values), -1)
    d = np.diff(x, n=order, axis=0)
    spread = 1.4826 * np.median(np.abs(d - np.median(d, axis=0)), axis=0)
    if mixture:
        d = d - np.median(d, axis=0)
        spread = np.sqrt(np.mean(np.minimum(np.abs(d), MIXTURE_CLIP * spread) ** 2, axis=0))
    return float(np.sqrt(np.mean(spread ** 2 / comb(2 * order, order))))


def _two_apart_noise(values: np.ndarray, order: int, mixture: bool = False) -> float:
    """`_difference_noise` of the even and of the odd rows (differences of readings two apart), RMS of the two:
    blind to a line at the Nyquist frequency, which alternates from one reading to the next."""
    x = np.asarray(values, dtype=float)
    return float(np.sqrt((_difference_noise(x[0::2], order, mixture) ** 2
                          + _difference_noise(x[1::2], order, mixture) ** 2) / 2))


def _alternating(values: np.ndarray) -> float | None:
    """The ratio of the third-difference σ of consecutive readings to that of readings two apart, when it exceeds
    what white noise gives (ALTERNATING / √N above 1): power near the Nyquist frequency, which consecutive readings'
    third differences weigh 3.2× (a 50 Hz pickup sampled at 100 Hz, 1 % of the field, hid inside a σ raised 1.6×:
    a review). Motion and a sensor's low-pass filter only lower the ratio (0.90–0.97 on the real recordings here);
    None below that or with fewer than 60 readings."""
    x = np.asarray(values, dtype=float)
    if len(x) < 60:
        return None
    apart = _two_apart_noise(x, 3)
    ratio = _difference_noise(x, 3) / apart if apart > 0 else 0.0
    return ratio if ratio > 1 + ALTERNATING / np.sqrt(len(x)) else None


ALTERNATING = 4.0  # white noise's ratio scatters by ≈ 0.95/√N (simulated, N = 200–20 000): 4 of those is beyond its
                   # 99.9th percentile at every N


MOTION_DROP = 0.9  # 4th-order estimate off the 3rd by more than 10 %: the differences hold the motion, not the
                   # noise (below: fast turns; above: steps between held positions; white noise gives the same σ
                   # at every order, within ~1 % at 3000 readings)
CLOCK_JUMPS = 0.01  # t going backwards at up to this fraction of the rows: a log in time order whose clock wrapped
                   # (Arduino's micros() every 71.6 min) or was reset, kept in row order; more: rows out of order
UNEVEN = 0.05  # time steps spread by more than this fraction of the median step (MAD): a turning sensor's readings
              # then differ by the motion × the uneven step as well, which a difference of rows takes for noise
BELOW_NOISE = 0.8  # the base residuals' own 3rd-difference σ under this × σ: σ is not the noise (a right model's
                   # residuals hold the noise, σ √(1 − p/N); the real recordings' ratio is 0.88–1.02)
UNORDERED = 0.25  # a 3rd-difference σ above this × the readings' own spread: consecutive readings differ about
                  # as much as any two (i.i.d. rows give ≈ 1, a turned sensor ≪ 0.01), so they are not a time series


def _uneven_steps(t: np.ndarray) -> float:
    """The spread of the time steps as a fraction of the median step (1.4826 MAD, so gaps do not count), when
    it exceeds UNEVEN; else 0."""
    steps = np.diff(np.sort(np.asarray(t, dtype=float)))
    median = float(np.median(steps)) if steps.size else 0.0
    if not median > 0:
        return 0.0
    spread = 1.4826 * float(np.median(np.abs(steps - median))) / median
    return spread if spread > UNEVEN else 0.0


LINE_POWER = 50.0  # a bin of the differences' periodogram this many times the median of the LINE_SPAN bins about it
                  # is a line: white noise's bins (exponential) pass their median 50× with probability 2⁻⁵⁰; motion and
                  # coloured noise make broad bumps (the real recordings' highest bins stand 4–10× above theirs)
LINE_SPAN = 101   # bins
LINES_MAX = 4     # at most this many lines taken out, one after the other (the most prominent first)
LINE_DROP = 0.9   # taken when the σ without them is under this × the σ with them


def _line_free(x: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, list] | None:
    """The readings `x` (rows in time order, evenly sampled at times `t`) less the lines of their spectrum, and the
    lines' frequencies (Hz): a periodic interference (a motor, the mains aliased by the sampling) passes into third
    differences by (2 sin(π f/fs))³ — 1.2× at a fifth of the sampling rate — and is no noise (a 1.8 Hz line at 10 Hz,
    1 % of the field, had raised an airborne σ 300×, and the degenerate-fit guard then refused the line itself).
    Found in the third differences, where the motion is small: each line, strongest first, fitted as a sine at its
    own frequency (refined between the periodogram's bins: a notch leaves its leakage, 10⁷ times the noise there),
    subtracted, and taken off the readings through the differences' gain (e^{iω} − 1)³. None when no line stands out
    of the bins about it (LINE_POWER), or the readings are not evenly sampled."""
    from scipy.ndimage import median_filter
    from scipy.optimize import minimize_scalar

    steps = np.diff(t)
    step = float(np.median(steps)) if len(steps) else 0.0
    if len(x) < 64 or not step > 0 or np.mean(np.abs(steps - step) < 0.1 * step) < 0.99:
        return None
    x = np.asarray(x, dtype=float).reshape(len(x), -1)
    d = np.diff(x, n=3, axis=0)
    d = d - np.median(d, axis=0)
    n, rows, all_rows = len(d), np.arange(len(d)), np.arange(len(x))

    found, clean = [], x.copy()
    for _ in range(LINES_MAX):
        p = np.sum(np.abs(np.fft.rfft(d, axis=0)) ** 2, axis=1)
        prominence = p / np.maximum(median_filter(p, LINE_SPAN, mode="nearest"), np.finfo(float).tiny)
        k = int(np.argmax(prominence[1:])) + 1
        if prominence[k] < LINE_POWER:
            break
        w = minimize_scalar(lambda w: -float(np.sum(np.abs(np.exp(-1j * w * rows) @ d) ** 2)),
                            bounds=(2 * np.pi * (k - 1) / n, 2 * np.pi * min(k + 1, n / 2) / n), method="bounded",
                            options={"xatol": 1e-3 / n}).x
        X = np.column_stack([np.sin(w * rows), np.cos(w * rows)])
        a, b = np.linalg.lstsq(X, d, rcond=None)[0]
        d = d - X @ np.vstack([a, b])
        amplitude = (b - 1j * a) / (np.exp(1j * w) - 1) ** 3  # d[i] = Δ³x[i], x[i] = Re(c e^{iωi})
        clean -= np.real(np.outer(np.exp(1j * w * all_rows), amplitude))
        found.append(w / (2 * np.pi * step))
    return (clean, found) if found else None


def _logged(temp, current) -> dict:
    """The channels logged beside the readings, by name."""
    return {name: c for name, c in (("temperature", temp), ("current", current)) if c is not None}


def _less_logged(x: np.ndarray, channels: list) -> tuple[np.ndarray, np.ndarray]:
    """The readings `x` (rows in time order) less the part that follows the logged `channels` (each N values, same
    rows), and its coefficients (channels × axes): fitted to the third differences, where the field's motion is
    small, so it is what moves with the channels' own fast changes — a motor current jittering from reading to
    reading (throttle, PWM: k·ΔI), which third differences would take for noise (σ 2–3.4× the sensor's in blind
    checks, and the motor itself then refused as "below the noise"). Least squares, refitted without the
    differences beyond MIXTURE_CLIP robust σ (glitches, a step's edges)."""
    c = np.column_stack(channels)
    dx, dc = np.diff(x, n=3, axis=0), np.diff(c, n=3, axis=0)
    keep = np.ones(len(dx), dtype=bool)
    for _ in range(3):
        coef = np.linalg.lstsq(dc[keep], dx[keep], rcond=None)[0]
        r = dx - dc @ coef
        r = r - np.median(r, axis=0)
        spread = 1.4826 * np.median(np.abs(r), axis=0)
        keep = np.all(np.abs(r) <= MIXTURE_CLIP * np.maximum(spread, np.finfo(float).tiny), axis=1)
        if keep.sum() < 2 * c.shape[1] + 10:
            break
    return x - c @ coef, coef


def _follows_logged(m: np.ndarray, logged: dict) -> tuple[np.ndarray, list, float] | None:
    """The readings `m` (rows in time order) less the part that follows the logged channels' fast changes
    (`_less_logged`; `logged`: name → N values), the names of the channels taken and the noise σ of the readings'
    own third differences, when that part holds a share of them: each channel taken whose part alone lowers the
    σ under LINE_DROP × its. Else None."""
    if not logged or len(m) < 60:
        return None
    with_it = estimate_noise(m)
    taken = [name for name, c in logged.items() if estimate_noise(_less_logged(m, [c])[0]) < LINE_DROP * with_it]
    return (_less_logged(m, [logged[k] for k in taken])[0], taken, with_it) if taken else None


def _noise(data: _Data, base: dict) -> tuple:
    """The noise σ and where it came from. Third differences of the readings, unless the readings
    change too fast for them (a hand turn logged at 10 Hz: the estimate then falls with the difference
    order; steps between positions held a few readings each: it rises) or are not a time series at all
    (rows shuffled or sorted with no times given: consecutive readings differ as much as any two); then
    third differences of the base model's residuals in time order, which no longer hold the field's
    rotation — also when those differ by less than BELOW_NOISE σ (a random walk of the attitude makes white
    steps in the readings, which differences of any order take for noise). A reference-vector model's residuals
    hold the attitude's errors, so the smaller of the two is taken. Returns (σ, source, bound, axes): `bound` when σ
    came from residuals out of time order, which hold all the model misses (an upper bound on the noise, not the
    noise); `axes` a vector model's `_axis_noise` of the same residuals (None: one σ for every axis)."""
    m, lines = data.m, None
    if data.t is not None and _alternating(data.m) is None:  # (a line at the Nyquist frequency: readings two apart)
        order = np.argsort(data.t, kind="stable")
        free = _line_free(data.m[order], np.asarray(data.t, dtype=float)[order])
        if free is not None and _difference_noise(free[0], 3) < LINE_DROP * estimate_noise(data.m[order]):
            m = np.empty_like(data.m)
            m[order] = free[0]
            if _lines_in_the_residuals(data, base, m, order):
                lines = (free[1], estimate_noise(data.m))
            else:
                m = data.m
    unit = f" {data.units}" if data.units else ""
    said_lines = ""  # (said after the source, whichever it is: the readings' and the residuals' lines are the same)
    if lines:
        shown = ", ".join(f"{f:.4g}" for f in lines[0])
        said_lines = (f"; the readings less the line{'s' if len(lines[0]) > 1 else ''} at {shown} Hz in their "
                      f"spectrum ({lines[1]:.4g}{unit} from their differences with them: a periodic interference is "
                      "no noise)")
    followed = _follows_logged(m, _logged(data.temp, data.current))  # (rows in time order: _prepare)
    if followed:
        m, taken, with_it = followed
        said_lines += (f"; the readings less the part that follows the logged {' and '.join(taken)}'s fast changes "
                       f"({with_it:.4g}{unit} from their differences with it: what moves with a logged channel is no "
                       "noise)")
    sigma = estimate_noise(m)
    source = "estimated from third differences of the readings"
    differences = _difference_noise
    alternate = _alternating(m)
    if alternate:
        differences = _two_apart_noise
        source = (f"estimated from third differences of readings two apart: consecutive readings alternate "
                  f"({sigma:.4g}{unit} from consecutive ones, {alternate:.2f}× as much): a line at or near the "
                  "Nyquist frequency (half the sampling rate) — the mains sampled at twice its frequency, a chopper's "
                  "or a set/reset's residue — that readings two apart do not see; it is no noise, and stays in the "
                  "residuals")
        sigma = differences(m, 3)
    fourth = differences(m, 4) if len(m) >= 40 else sigma
    spread = np.sqrt(np.mean(np.var(m, axis=0)))
    uneven = _uneven_steps(data.t)
    # (the base model's residuals of the readings less their lines or the logged channels' part, when taken out)
    e = np.asarray(base["residuals"] if m is data.m else _residuals(base, replace(data, m=m), None, slice(None)))
    e = e.reshape(len(data.m), -1)[np.argsort(data.t, kind="stable")]
    from_residuals = differences(e, 3, mixture=True)
    axes = None
    if e.shape[1] == 3:  # (each axis's quantisation floor, as the one σ's below)
        axes = _axis_noise(e, differences, _axis_steps(data.m) / np.sqrt(12))
    # the base model's residuals differing less than the noise: the readings' differences held motion that is white
    # in them too (a random walk of the attitude: σ 2.8× the truth, every effect then "below the noise"; a brisk
    # random tumble: 1.8–2× with the 4th order only 4 % below the 3rd — two blind checks)
    orders_differ = abs(fourth - sigma) > (1 - MOTION_DROP) * sigma
    below = from_residuals < BELOW_NOISE * sigma
    if below and not (orders_differ or uneven) and e.shape[1] == 1 and differences is _difference_noise:
        across = _across_the_surface(m[np.argsort(data.t, kind="stable")], base)
        if ACROSS_HOLDS * sigma <= across <= sigma / ACROSS_HOLDS:  # (isotropic: noise; the base fit took part of it)
            below = False
            said_lines += (f"; the base model's residuals differ by less ({from_residuals:.4g}{unit}), yet the "
                           f"readings' differences across its ellipsoid, where a turn does not move them, hold the "
                           f"noise ({across:.4g}{unit}): the base fit, which its readings do not determine, has taken "
                           "part of the noise into its shape")
    if orders_differ or sigma > UNORDERED * spread or uneven or below:
        # the readings do vary (not a static sensor, whose spread is its noise), yet jump between rows
        unordered = sigma > UNORDERED * spread and spread > 1 / UNORDERED * from_residuals
        if from_residuals < sigma and unordered:
            source = (f"estimated from the base model's residuals, which also hold whatever the model misses: "
                      f"consecutive readings differ about as much as any two ({sigma:.4g}{unit} from their "
                      "third differences), so differences in time cannot tell noise from signal (readings far "
                      "apart in time, or rows out of time order with no times given): not a time series; give "
                      "noise_sigma (--noise-sigma; the datasheet's) to test the candidates against the sensor's "
                      "own noise")
            return from_residuals, source + said_lines, True, None  # (their differences hold the misfit: no axes)
        elif from_residuals < sigma:
            why = (f"readings taken at uneven times (steps spread by {100 * uneven:.0f} % of the median step)"
                   if uneven else "fast turns, or steps between held positions" if orders_differ
                   else "the base model's residuals differ by less than that")
            source = (f"estimated from third differences of the base model's residuals: the readings' own "
                      f"differences hold the motion — {why} ({sigma:.4g}{unit} from 3rd, {fourth:.4g}{unit} from "
                      "4th order)")
            sigma = from_residuals
    return sigma, source + said_lines, False, axes


def _across_the_surface(m: np.ndarray, base: dict) -> float:
    """The noise σ of the readings `m` (rows in time order) measured across the base ellipsoid: each third difference
    (rows j … j+3) taken along the ellipsoid's normal at the mean of rows j−1 and j+4 (outside the difference, so
    the normal does not follow its noise), clipped mean square as `_difference_noise(mixture=True)`. A steady turn, or
    an attitude's random walk, moves the readings along the surface and leaves this small (a level drive: 0.15 of the
    readings' own differences), while white noise has the same σ along any direction as along each axis. A one-axis
    turntable's readings on one circle leave the ellipsoid undetermined, and the base fit, a pancake whose rim wraps
    the circle, had residuals differing by half the noise: taken for σ, a null recording was given a periodic
    interference and coloured noise (a blind check)."""
    theta = np.asarray(base["parameters"])
    b, A = theta[:3], symmetric(theta[3:9])
    d = np.diff(m, n=3, axis=0)[1:-1]
    g = ((m[:-5] + m[5:]) / 2 - b) @ A.T @ A.T
    size = np.linalg.norm(g, axis=1)
    keep = size > 0
    if keep.sum() < 20:
        return 0.0
    p = np.sum(d[keep] * g[keep], axis=1) / size[keep]
    return _difference_noise(p, 0, mixture=True) / np.sqrt(comb(6, 3))  # (order 0: p are differences already)


ACROSS_HOLDS = 0.9  # the readings' differences across the base ellipsoid hold their σ within this ratio (either way):
                    # isotropic, they are noise (more across it: a turn that speeds up and slows down moves them there
                    # too — a sensor held still, then turned briskly: 6.6 across for 2.7 per axis, σ 0.39)


def _lines_in_the_residuals(data: _Data, base: dict, free: np.ndarray, order: np.ndarray) -> bool:
    """Whether the lines taken out of the readings (`free`: the readings less them) are an interference, not the
    motion: the third differences (in time order) of the base model's residuals of the readings less them are at most
    LINE_RESIDUALS (1.5) times those of its residuals of the readings. A figure-8 waved at 2 Hz is periodic in the
    readings: its lines taken out, the rest of the motion (9.2, 52× the noise) had been taken for the noise, and
    "explains the data to the noise" said of a 3 % saturation missed (a blind check); the model fits the motion, so its
    residuals gain the lines."""
    with_lines = _difference_noise(np.asarray(base["residuals"]).reshape(len(data.m), -1)[order], 3, mixture=True)
    without = np.asarray(_residuals(base, replace(data, m=free), None, slice(None))).reshape(len(data.m), -1)[order]
    return bool(_difference_noise(without, 3, mixture=True) <= LINE_RESIDUALS * with_lines)


LINE_RESIDUALS = 1.5  # lines whose removal raises the base residuals' third-difference σ more than this are the motion


AXES_ALPHA = 0.01      # the axes' noise is taken to differ when equal variances are rejected at this level
AXES_RATIO = 1.1       # ... and the noisiest axis's σ is at least this many times the quietest's (below, no score
                       # moves by more than (1.1² − 1)/3 ≈ 7 %: Brown–Forsythe also sees the shape of a distribution,
                       # rounding's, and rejected σ equal to 0.1 % on a coarse grid)
AXES_LEAST = 0.1       # ... no axis's σ is taken below this share of their RMS


def _axis_noise(e: np.ndarray, differences, floors=0.0) -> tuple | None:
    """A vector model's residuals per axis (N × 3, time order): (weights σ̄/σ_axis, σ_axis / σ̄, p-value) when their
    noise differs — equal variances of their third differences rejected at AXES_ALPHA (Brown–Forsythe, on every
    fourth difference: those share no reading) and σ differing by AXES_RATIO — else None. σ_axis from `differences`
    of that axis alone, at least its `floors` (its quantisation step/√12: an axis that moves by less than a step
    over a few readings has third differences of zero, and had been weighted 10× for it), σ̄ their RMS, so that the
    weighted residuals keep the one σ the diagnosis reports. One pooled σ had judged a candidate acting on the
    noisiest axis against a noise too small (σ_z = 3 σ_x: an offset step named in 2 of 40 recordings with nothing
    withheld) and one on the quiet axes against a noise too large."""
    d = np.diff(e, n=3, axis=0)[::4]
    if len(d) < 10:
        return None
    p = float(stats.levene(*d.T, center="median").pvalue)
    if not p < AXES_ALPHA:
        return None
    sigmas = np.maximum([differences(e[:, [k]], 3) for k in range(3)], floors)
    if not (np.all(sigmas > 0) and sigmas.max() >= AXES_RATIO * sigmas.min()):  # (NaN fails too)
        return None
    relative = np.maximum(sigmas / np.sqrt(np.mean(sigmas ** 2)), AXES_LEAST)
    return 1.0 / relative, relative, p


# ---------------------------------------------------------------- the model and its residuals

def _features(alternative_list, rows=None):
    """Stack N × p_j × 3 feature arrays into N × p × 3 (optionally only `rows`)."""
    if not alternative_list:
        return None
    f = np.concatenate(alternative_list, axis=1)
    return f if rows is None else f[rows]


def _undetermined_start(data: _Data, given, units: str, refusal: Exception):
    """The base model's start when calibrate's full symmetric fit fails (`refusal`), as (start, caveat): calibrate's
    own shape when that holds (caveat None). Readings nearly in one plane (a level drive, a one-axis turntable)
    calibrate refuses outright — a 3-D ellipsoid is not identifiable from them — but the diagnosis owes a verdict on
    them: that refusal lifted (planar_ratio 0; else the plain algebraic fit, whose noise bias keeps a thin scatter's
    quadric an ellipsoid where the noise-corrected one turns it into a hyperboloid), the base is fitted as well as
    they allow and the caveat says what they leave open, so that nothing is cleared (an effect can hide there). A
    ValueError, calibrate's words and not its error chained, when even the plain quadric is no ellipsoid."""
    from ..pipeline import calibrate

    try:
        start = calibrate(data.m, field_norm=given, units=units)
        data.notes.append(f"the base model starts from calibrate's {start.summary.get('shape', 'chosen')} shape: "
                          f"the full symmetric refinement failed on these readings ({refusal})")
        return start, None
    except _core.Error as exc:
        refusal = exc
    for how in ({"planar_ratio": 0.0}, {"method": "ls", "planar_ratio": 0.0}):
        try:
            start = calibrate(data.m, field_norm=given, units=units, **how)
            break
        except _core.Error:
            continue
    else:  # not even the plain algebraic quadric is an ellipsoid: the readings themselves curve away from every
        # ellipsoid (not the noise correction), and no base model holds them — said as calibrate says it, not chained
        raise ValueError(f"samples: no base model can be fitted to these readings, so there is no diagnosis: "
                         f"{refusal}") from None
    words = " (the plain algebraic start: the noise-corrected quadric is no ellipsoid)" if "method" in how else ""
    thin = np.linalg.eigh(np.cov(data.m.T))[1][:, 0]  # (the readings' thinnest direction, its largest part positive)
    thin = thin * np.sign(thin[np.argmax(np.abs(thin))])
    caveat = (f"the base calibration: not identifiable — calibrate refuses these readings ({refusal}). "
              f"The offset and the matrix across their plane (along [{', '.join(f'{v:.2f}' for v in thin)}], x, y, z) are "
              "undetermined: the diagnosis fits them as far as the readings allow"
              + words
              + ", and an effect can stand in for them or hide in them; turn the sensor about more axes (tumble it), "
              "or give the true field per reading (reference=)")
    return start, caveat


def _fit(data: _Data, start: Calibration, fixed, feats, rows=None, start_terms=None) -> dict:
    """Refit the base model plus `feats` (N × p × 3 or None) on `rows` (Ceres, refine_terms)."""
    sel = slice(None) if rows is None else rows
    m = np.ascontiguousarray(data.m[sel])
    p = 0 if feats is None else feats.shape[1]
    f = np.zeros((len(m), 0)) if feats is None else np.ascontiguousarray(feats[sel].reshape(len(m), 3 * p))
    terms = np.zeros(p) if start_terms is None else np.asarray(start_terms, dtype=float)
    options = _core.RefineOptions()
    options.max_iterations = 100
    ref = None if data.reference is None else np.ascontiguousarray(data.reference[sel])
    norms = None if data.field_norms is None else np.ascontiguousarray(data.field_norms[sel])
    w = data.axis_weights
    if w is None:
        return _core.refine_terms(start.offset, start.matrix, start.field_norm, start.units, m, f, terms,
                                  list(fixed), options, ref, norms)
    if ref is None:
        return _weighted_magnitude_fit(start, fixed, m, f, terms, options, norms, w)
    # Weighted least squares as plain least squares of the weighted readings: D m = D b + D W r + D F c + D n has
    # the same form with offset D b and matrix D W (A D⁻¹), the terms' coefficients unchanged; its residuals are
    # the weighted ones the tests need, its parameters are mapped back to b and W.
    tiled = np.tile(w, p)
    fit = _core.refine_terms(start.offset * w, np.asarray(start.matrix) / w, start.field_norm, start.units,
                             np.ascontiguousarray(m * w), np.ascontiguousarray(f * tiled), terms, list(fixed),
                             options, ref, norms)
    scale = np.concatenate([w, np.repeat(w, 3), np.ones(p)])  # θ' = scale·θ: b' = D b, W' = D W (row-major)
    fit["parameters"] = np.asarray(fit["parameters"]) / scale
    fit["standard_errors"] = np.asarray(fit["standard_errors"]) / scale
    fit["covariance"] = np.asarray(fit["covariance"]) / np.outer(scale, scale)
    fit["jacobian"] = np.asarray(fit["jacobian"]) * scale  # ∂r'/∂θ of the weighted residuals r'
    fit["offset"] = np.asarray(fit["offset"]) / w
    fit["matrix"] = np.asarray(fit["matrix"]) * w  # A = (D⁻¹ W')⁻¹ = A' D
    fit["axis_weights"] = w  # (_project weights the candidates' columns alike)
    return fit


def _weighted_magnitude_fit(start: Calibration, fixed, m, f, terms, options, norms, w) -> dict:
    """A magnitude model with each axis's noise weighted by w = σ̄/σ_axis: the Sampson residual of readings scaled
    to D m (D = diag(w)), which is the distance to the ellipsoid in units of each axis's own noise, so that every
    residual has the one σ̄ whatever the field's direction. Same form: |(m − b) A| = |(D m − D b) A'| with the
    symmetric A' = root(D⁻¹ A² D⁻¹), terms D f with their coefficients unchanged; parameters, errors, covariance and
    Jacobian are mapped back to b and A (fluxcal._axis_weights)."""
    p = len(terms)
    offset, matrix = scaled_start(start.offset, start.matrix, w)
    fit = _core.refine_terms(offset, matrix, start.field_norm, start.units, np.ascontiguousarray(m * w),
                             np.ascontiguousarray(f * np.tile(w, p)), terms, list(fixed), options, None, norms)
    map_fit(fit, w)
    fit["axis_weights"] = w
    return fit


def _residuals(result: dict, data: _Data, feats, rows) -> np.ndarray:
    """The model's residuals (reading units) on `rows`, with the fitted parameters of `result`."""
    theta = np.asarray(result["parameters"])
    nb = 12 if data.reference is not None else 9
    m = data.m[rows].copy()
    if feats is not None and feats.shape[1]:
        m -= np.einsum("p,npk->nk", theta[nb:], feats[rows])
    b = theta[:3]
    if data.reference is not None:
        W = theta[3:12].reshape(3, 3)
        e = m - b - data.reference[rows] @ W.T
        return (e if data.axis_weights is None else e * data.axis_weights).ravel()
    return sampson(m, b, symmetric(theta[3:9]), _field_at(data, rows), data.axis_weights)


def _downstream(result: dict, data: _Data, feats, rows) -> dict:
    """What a user of the calibrated field sees on `rows`: the RMS field error (|h| − H for a magnitude
    model, |h − r| against reference vectors), and with reference vectors the RMS angle between h and
    r and, when the down direction is known (accelerometer), the RMS heading error (the angle between
    the horizontal projections of h and r)."""
    h = _calibrated(result, data, feats, rows)
    if data.reference is None:
        return {"field_error": float(np.sqrt(np.mean((np.linalg.norm(h, axis=1) - _field_at(data, rows)) ** 2)))}
    r = data.reference[rows]
    out = {"field_error": float(np.sqrt(np.mean(np.sum((h - r) ** 2, axis=1)))),
           "direction_error_deg": _rms_angle(h, r)}
    if data.down is not None:
        d = data.down[rows] / np.linalg.norm(data.down[rows], axis=1, keepdims=True)
        flat = lambda v: v - np.sum(v * d, axis=1, keepdims=True) * d  # noqa: E731
        hh, rh = flat(h), flat(r)
        signed = np.arctan2(np.sum(np.cross(rh, hh) * d, axis=1), np.sum(rh * hh, axis=1))
        out["heading_error_deg"] = float(np.degrees(np.sqrt(np.mean(signed ** 2))))
    return out


def _calibrated(result: dict, data: _Data, feats, rows) -> np.ndarray:
    """The field of the readings `rows` as the fit `result` calibrates them (its modelled effects taken off)."""
    m = data.m[rows].copy()
    theta = np.asarray(result["parameters"])
    nb = 12 if data.reference is not None else 9
    if feats is not None and feats.shape[1]:
        m -= np.einsum("p,npk->nk", theta[nb:], feats[rows])
    return Calibration(offset=result["offset"], matrix=result["matrix"], field_norm=data.field_norm).apply(m)


def _noise_floor(result: dict, data: _Data, feats, rows, sigma: float) -> float:
    """The RMS field error (as `_downstream`) that the readings' white noise σ alone leaves on `rows` through
    the fit's matrix A: |h| − H moves by u'A n along the field direction u, |h − r| by |A n|."""
    A = np.asarray(result["matrix"])
    if data.reference is not None:  # (each axis's own σ: σ̄ / its weight)
        return float(sigma * np.linalg.norm(A if data.axis_weights is None else A / data.axis_weights))
    h = _calibrated(result, data, feats, rows)
    u = h / np.linalg.norm(h, axis=1, keepdims=True)
    along = u @ A if data.axis_weights is None else (u @ A) / data.axis_weights  # (each axis's σ: σ̄ / its weight)
    return float(sigma * np.sqrt(np.mean(np.sum(along ** 2, axis=1))))


def _rms_angle(a: np.ndarray, b: np.ndarray) -> float:
    cos = np.sum(a * b, axis=1) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1))
    return float(np.degrees(np.sqrt(np.mean(np.arccos(np.clip(cos, -1, 1)) ** 2))))


def _context(data: _Data, result: dict, feats=None) -> SimpleNamespace:
    """What candidates compute their features from: the current fit's estimate of the signal. `feats`:
    the fit's features (N × p × 3), whose modelled part is taken off the readings before they are
    calibrated into field directions (else the directions carry the effects already modelled)."""
    theta = np.asarray(result["parameters"])
    radius = np.reshape(_field_at(data), (-1, 1))  # |h| of each reading on the model (one for all, or its own)
    modelled = np.zeros_like(data.m)  # the effects modelled, in the readings (what the fit takes off them)
    if feats is not None and feats.shape[1]:
        modelled = np.einsum("p,npk->nk", theta[12 if data.reference is not None else 9:], feats)
    if data.reference is not None:
        W = theta[3:12].reshape(3, 3)
        field = data.reference
    else:
        W = np.linalg.inv(np.asarray(result["matrix"]))
        m = data.m
        m = m - modelled
        # on the fitted sphere: the calibrated readings' own magnitude errors in a feature would let a
        # combination of features reproduce them (a degenerate fit to zero residuals: non_orthogonality at
        # coefficients ±1 after a temperature scale error of 4 % was added to a real recording)
        field = (m - theta[:3]) @ np.asarray(result["matrix"]).T
        field *= radius / np.linalg.norm(field, axis=1, keepdims=True)
    direction = radius * (field / np.linalg.norm(field, axis=1, keepdims=True)) @ W.T
    # The transducer sees the field including hard iron (a field too): the fitted model's reading b + W h, with
    # h on the fitted sphere (or the reference); `_forms` gives the other form, an electronic offset b added after.
    # Not the raw readings: a feature non-linear in them (s³, s·s_easy) carries the reading's own noise,
    # whose correlation with the residual's noise fakes a fit — saturation came first in 29 of 30 pure
    # white-noise trials at σ = 1 % of the field, and was accepted in 6.
    signal = theta[:3] + direction
    return SimpleNamespace(signal=signal, readings=data.m, modelled=modelled,
                           scale=float(np.median(np.linalg.norm(signal, axis=1))),
                           vector=data.reference is not None,
                           field=field, W=W, direction=direction, t=data.t, temp=data.temp,
                           current=data.current, world=_world_axes(data, W), memo=data.memo)


def _forms(cls, ctx) -> dict:
    """The contexts a candidate is tried in: one ("hard_iron") unless it acts in the transducer (`transducer`),
    which sees the field and the platform's hard iron but not the sensor's own electronic offset, added after
    it; then also "electronic": the whole fitted offset added after the transducer, which sees W h alone."""
    if not cls.transducer:
        return {"hard_iron": ctx}
    offset = ctx.signal - ctx.direction  # the fitted b, on every row
    return {"hard_iron": ctx, "electronic": SimpleNamespace(**{
        **vars(ctx), "signal": ctx.direction, "readings": ctx.readings - offset,  # what the transducer gave out
        "scale": float(np.median(np.linalg.norm(ctx.direction, axis=1)))})}


def _bic_price(e: np.ndarray) -> float:
    """BIC's price of one parameter in the residuals' sum of squares (ln N residual variances)."""
    return np.log(len(e)) * float(e @ e) / len(e)


def _offset_kind(form: str, taken: dict, e: np.ndarray) -> dict:
    """The ranking row's `offset_kind`: the form chosen when it takes more off the residuals than the other by
    BIC's price of a parameter (the data decide it: a hard iron large enough to show), None when not; nothing
    for a candidate with one form."""
    if len(taken) < 2:
        return {}
    price = _bic_price(e)
    decided = all(taken[form] - g >= price for f, g in taken.items() if f != form)
    return {"offset_kind": form if decided else None}


def _jump(row: dict) -> dict:
    """An accepted offset step as a jump: `jump` (the offset's change, sensor frame), `jump_s` (when) and
    `back_s` (when it came back, None if it stayed). A box from the recording's start is the stretch before
    a jump at its end: the same step the other way round, so its coefficients change sign."""
    c = np.asarray(row["coefficients"], dtype=float)
    if row.get("on_s") is None:
        return {"jump": (-c).tolist(), "jump_s": row.get("off_s"), "back_s": None}
    return {"jump": c.tolist(), "jump_s": row["on_s"], "back_s": row.get("off_s")}


def _world_frame(data: _Data):
    """N × 3 × 3: the world's magnetic north, east and down (rows) in the sensor frame at each reading
    (`attitude.magnetic_frame`); None unless the reference and the down direction are both known, or when
    the field is vertical (at a magnetic pole the horizontal axes are unknown)."""
    if data.reference is None or data.down is None:
        return None

    def frame():
        down = data.down / np.linalg.norm(data.down, axis=1, keepdims=True)
        horizontal = np.linalg.norm(np.cross(data.reference, down), axis=1) / np.linalg.norm(data.reference, axis=1)
        return None if np.median(horizontal) < 1e-3 else magnetic_frame(data.reference, down)
    # (once per reference: every candidate's context asks for it)
    return _per_diagnosis(data.memo, ("world_frame",), (data.reference, data.down), frame)


def _world_axes(data: _Data, W: np.ndarray):
    """The world frame's axes times H in reading units (through W): a field fixed in the world (a magnet
    nearby) is a combination of them. None without the frame (a magnitude shows only the part along the
    field, `direction`)."""
    frame = _world_frame(data)
    return None if frame is None else data.field_norm * frame @ W.T


def _disturbance(data: _Data, result: dict, feats: np.ndarray, coefficients: np.ndarray) -> dict:
    """An accepted field disturbance's size in field units: the largest |Δh| (`peak_field`) and when
    (`peak_s`); with a world frame its north, east, down components then (`peak_ned`), without one the
    signed change along the field (`peak_along_field`)."""
    dh = np.einsum("p,npk->nk", coefficients, feats) @ np.asarray(result["matrix"]).T
    size = np.linalg.norm(dh, axis=1)
    i = int(np.argmax(size))
    out = {"peak_field": float(size[i]), "peak_s": float(data.t[i])}
    frame = _world_frame(data)
    if frame is not None:
        out["peak_ned"] = (frame[i] @ dh[i]).tolist()
    else:
        out["peak_along_field"] = float(dh[i] @ _field_directions(data, result)[i])
    return out


def _field_directions(data: _Data, result: dict) -> np.ndarray:
    if data.reference is not None:
        return data.reference / np.linalg.norm(data.reference, axis=1, keepdims=True)
    h = Calibration(offset=result["offset"], matrix=result["matrix"], field_norm=data.field_norm).apply(data.m)
    return h / np.linalg.norm(h, axis=1, keepdims=True)


def _project(result: dict, feats: np.ndarray, vector: bool, rows=slice(None)) -> np.ndarray:
    """Candidate columns in residual space: ∂r/∂c at the current fit (of the readings `rows` when feats
    holds only those)."""
    if vector:  # −feats with its axes swapped, in one pass (reshaping the swapped view copied it slowly: 8×)
        out = np.empty((feats.shape[0], feats.shape[2], feats.shape[1]))
        np.negative(feats.transpose(0, 2, 1), out=out)
        if result.get("axis_weights") is not None:  # (the weighted residuals', _fit)
            out *= result["axis_weights"][:, None]
        return out.reshape(-1, feats.shape[1])
    jb = np.asarray(result["jacobian"])[rows, :3]  # ∂r/∂b; r depends on m − b, so ∂r/∂c = jb · f
    return np.einsum("nk,npk->np", jb, feats)


def _residual_rows(rows, per_reading: int):
    """The residuals of the readings `rows` (a slice or indices): per_reading consecutive ones each."""
    if isinstance(rows, slice):
        return slice(rows.start * per_reading, rows.stop * per_reading)
    return (np.asarray(rows)[:, None] * per_reading + np.arange(per_reading)).ravel()


# ---------------------------------------------------------------- held-out regimes

def _heldout(regime: str, data: _Data, directions: np.ndarray, block: int | None = None) -> np.ndarray:
    """Boolean mask of the held-out readings: the last quarter in time, the hottest quarter, the
    quarter of the readings nearest one octant's diagonal (orientations the fit never sees), or for
    events every fourth of 16 blocks of time (an event is interpolated from the blocks around it), or of blocks of
    `block` readings (a short event's, `_event_block`)."""
    n = len(data.m)
    if regime == "events":
        rank = np.empty(n, int)
        rank[np.argsort(data.t, kind="stable")] = np.arange(n)
        return (rank * 16 // n if block is None else rank // block) % 4 == 2
    if regime == "temperature" and data.temp is not None:
        return _highest(data.temp)
    if regime == "current" and data.current is not None:
        return _highest(data.current)
    if regime == "orientation":
        diagonals = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) / np.sqrt(3)
        dots = directions @ diagonals.T
        centre = np.argmax(np.sum(dots > 0.8, axis=0))  # the best-populated octant
        d = dots[:, centre]
        return d >= np.quantile(d, 1 - HELDOUT_FRACTION)
    return _highest(data.t)


EVENT_CORE = 0.01           # a short event acts where its features exceed this share of their largest value;
EVENT_BLOCKS = 16          # it is held out as a recording is: every fourth of 16 blocks of its span,
EVENT_BLOCK_CORRELATION = 2  # each at least this many correlation lengths of the base model's residuals


def _event_block(feats: np.ndarray, data: _Data, correlation: int) -> int | None:
    """The readings per held-out block for a short event: one that acts (its features above EVENT_CORE of their
    largest: a box's readings, a pass's ±2.4 passage times) on fewer readings than two of the recording's 16
    blocks, so that it can lie inside one, or across two of which neither is held out. It is held out
    as the recording is, in EVENT_BLOCKS blocks of its own span, each at least EVENT_BLOCK_CORRELATION times the
    base residuals' correlation length (`correlation`, readings: a held-out block's noise is its own, not its
    neighbours'), and judged where it acts (`_where_it_acts`). None for a longer event (the recording's 16
    blocks: finer ones, or its gaps where it acts, had let a box of a fifth of the recording confirm a 1/f
    noise's wander, in 3 of 24 seeds), or when the correlation allows no finer blocks. A magnet's second-long
    pass in ten minutes lay inside one of 16 blocks (38 s): held out, the training readings held none of it;
    trained on, no held-out reading saw it."""
    n = len(data.m)
    span = int(np.count_nonzero(_acts(feats)))
    block = max(span // EVENT_BLOCKS, EVENT_BLOCK_CORRELATION * correlation, 1)
    return block if span < n // 8 and block < n // 16 else None


def _highest(x: np.ndarray) -> np.ndarray:
    """The quarter of the readings with the highest x, by rank (ties in row order): a threshold at the
    quantile would hold out every reading of a value most of them share (motors off at 0 A, a
    temperature logged in whole degrees)."""
    mask = np.zeros(len(x), bool)
    mask[np.argsort(x, kind="stable")[int(round(len(x) * (1 - HELDOUT_FRACTION))):]] = True
    return mask


def _heldout_leverage(data: _Data, result: dict, held: np.ndarray, judged: np.ndarray | None = None) -> float:
    """The mean leverage of the held-out readings (those of them `judged`, default all) for a fit on the rest: the
    variance, in units of the noise variance, with which a model fitted without them predicts them (Jacobian of
    `result`, parameters linearised). ≪ 1: the held-out part is predicted by what the fit learnt; ≳ 1: the fit
    extrapolates (a short recording, or a regime the rest does not cover), and its held-out gaps judge that, not
    the effect."""
    J = np.asarray(result["jacobian"])
    J = J[:, np.any(J != 0, axis=0)]
    J = J / np.linalg.norm(J, axis=0)  # (the columns scaled alike: a dipole's and an offset's differ by decades)
    per_reading = J.shape[0] // len(held)
    train = ~np.repeat(held, per_reading)
    rows = np.repeat(held if judged is None else judged, per_reading)
    w, V = np.linalg.eigh(J[train].T @ J[train])
    determined = w > w.max() * 1e-12
    # Combinations of the parameters the rest does not determine (an event and a temperature term that the rest
    # cannot tell apart, 1e17 conditioned) leave the held-out readings unpredicted: an inverse there had given a
    # leverage of −8e13.
    if not w.max() > 0 or np.sum((J[rows] @ V[:, ~determined]) ** 2) > 1e-6 * np.sum(J[rows] ** 2):
        return float("inf")
    return float(np.mean(np.sum((J[rows] @ V[:, determined] / np.sqrt(w[determined])) ** 2, axis=1)))


def _acts(feats: np.ndarray) -> np.ndarray:
    """The readings a candidate acts on: its features above EVENT_CORE of their largest (a box's readings, a
    pass's ±2.4 passage times; every reading for most candidates)."""
    size = np.max(np.abs(feats.reshape(len(feats), -1)), axis=1)
    return size > EVENT_CORE * size.max() if size.max() > 0 else np.ones(len(feats), bool)


def _where_it_acts(feats: np.ndarray, held: np.ndarray) -> np.ndarray:
    """The held-out readings an event acts on (`_acts`); all held-out readings when it acts on none of them."""
    acts = held & _acts(feats)
    return acts if acts.any() else held


def _correlation_length(series: np.ndarray) -> int:
    """The first lag at which the series' autocorrelation falls below 0.1 (its length when it never does)."""
    n = len(series)
    x = series - series.mean()
    acf = np.fft.irfft(np.abs(np.fft.rfft(x, 2 * n)) ** 2)[:n]
    acf = acf / acf[0] if acf[0] > 0 else np.zeros(n)
    below = np.nonzero(acf < 0.1)[0]
    return int(below[0]) if len(below) else n


def _improvement_pvalue(before: np.ndarray, after: np.ndarray, length: int | None = None) -> float:
    """One-sided test that held-out squared residuals fell: a sign-flip test of the means of consecutive blocks of
    d = before² − after² (their sum against the sums with the blocks' signs flipped, exactly over every pattern),
    each block at least twice the noise's correlation length — `length`, from the augmented fit's own residuals in
    sample, else from `after`'s — so that correlated noise gives few, long blocks and cannot fake significance,
    5 to 30 blocks.
    The block means' sizes count, not only their signs or ranks: an event's gain sits in the few blocks that
    overlap it (a t-test on such skewed means had missed 8 blocks out of 8 positive, p 0.077; the signed ranks that
    followed, a magnet's 4 % pass simulated with white noise: 0.67 → 0.17 of held-out gap, p 0.0625). The held-out
    misprediction of an imperfect shape is no noise: measured on `after` it had given that pass 5 blocks (a
    correlation length of 101 readings, 28 in sample)."""
    d = before ** 2 - after ** 2
    n = len(d)
    if n < 10 or not np.all(np.isfinite(d)):
        return 1.0
    length = _correlation_length(after) if length is None else length
    blocks = int(np.clip(n // max(2 * length, 1), 5, 30))
    means = np.array([c.mean() for c in np.array_split(d, blocks)])
    # (no shortcut for equal means: an absolute tolerance had made every block alike for readings in tesla)
    # exact over all 2^blocks sign patterns: the sums of each half's 2^15 at most, then pairs by sorting
    size = np.abs(means)
    half = blocks // 2
    first, second = _signed_sums(size[:half]), np.sort(_signed_sums(size[half:]))
    at_least = means.sum() - 1e-12 * size.sum()
    count = len(second) * len(first) - np.searchsorted(second, at_least - first, side="left").sum()
    return float(count / 2.0 ** blocks)


EVENT_MIN_BLOCKS = 6  # where a short event acts, its block test needs this many blocks of two correlation lengths


def _event_pvalue(e0: np.ndarray, e1: np.ndarray, within, length: int) -> float:
    """`_improvement_pvalue` of the held-out residuals e0 → e1; for a short event (`within`: its held-out residuals
    where it acts, before and after, else None) also there, the smaller of the two p-values, doubled (Bonferroni). Over
    every held-out reading a second-long pass's gain sat in one or two of 30 blocks (a blind check's, its gap falling
    2.7 → 0.17 on 30 readings: p 0.24 in 2 of 12 seeds; where it acts 15 blocks, p 3e-5); where it acts a slower pass
    lay in one or two held-out blocks of correlated noise (p 0.17), while the fit it had distorted gained everywhere
    (p 8e-5). Where it acts it is tested only with EVENT_MIN_BLOCKS honest blocks (a review: forced to 5 short blocks
    of AR(1) noise, P(p ≤ 1/32) was 0.06–0.07)."""
    p = _improvement_pvalue(e0, e1, length)
    if within is None or len(within[0]) // max(2 * length, 1) < EVENT_MIN_BLOCKS:
        return p  # (too few honest blocks where it acts: the block test's floor of 5 would make them too short)
    return min(1.0, 2.0 * min(p, _improvement_pvalue(*within, length)))


def _signed_sums(values: np.ndarray) -> np.ndarray:
    """Σ ±values over every pattern of signs (2^len of them)."""
    return _sign_patterns(len(values)) @ values


@lru_cache(maxsize=4)
def _sign_patterns(k: int) -> np.ndarray:
    """Every pattern of k signs, 2^k × k (read-only: shared; a diagnosis' held-out tests ask for the same few k)."""
    signs = 1.0 - 2.0 * ((np.arange(2 ** k)[:, None] >> np.arange(k)) & 1)
    signs.setflags(write=False)
    return signs


def _gap(residuals: np.ndarray, sigma: float) -> float:
    return float(np.sqrt(max(np.mean(residuals ** 2) - sigma ** 2, 0.0)))


# ---------------------------------------------------------------- where

def _where(data: _Data, e: np.ndarray, sigma: float, directions: np.ndarray, vector: bool) -> dict:
    """Residuals normalised by the noise, by regime, each with a test."""
    z = e / sigma
    per_reading = np.sqrt(np.mean(z.reshape(-1, 3) ** 2, axis=1)) if vector else z
    # the three axes' sum over √3: one unit-variance value per reading, as the bins' χ² take it (their mean had a
    # third of the variance, and every bin test against reference vectors read p ≈ 1: a blind check)
    signed = z.reshape(-1, 3).sum(axis=1) / np.sqrt(3.0) if vector else z
    out = {"overall": {"n": int(len(per_reading)), "rms_z": float(np.sqrt(np.mean(z ** 2))),
                       "gap": _gap(e, sigma)}}
    tables = {}

    # Orientation: 24 bins (cube face × quadrant of the field direction); χ² of the bin means.
    face = np.argmax(np.abs(directions), axis=1)
    sign = np.sign(directions[np.arange(len(directions)), face]) > 0
    others = np.array([[1, 2], [0, 2], [0, 1]])[face]
    quadrant = (directions[np.arange(len(directions)), others[:, 0]] > 0) * 2 + \
               (directions[np.arange(len(directions)), others[:, 1]] > 0)
    bins = face * 8 + sign * 4 + quadrant
    tables["orientation"] = _binned(signed, bins, [f"{'+' if (b // 4) % 2 else '-'}{'xyz'[b // 8]} q{b % 4}"
                                                   for b in range(24)])
    # Temperature and time: quantile bins plus a regression slope.
    if data.temp is not None:
        tables["temperature"] = _binned(signed, _quantile_bins(data.temp, 8), None, data.temp)
    if data.current is not None:
        tables["current"] = _binned(signed, _quantile_bins(data.current, 8), None, data.current)
    tables["time"] = _binned(signed, _quantile_bins(data.t, 10), None, data.t, time_number(data.t))
    # Per axis: the vector model's own axes; for a magnitude model, the residual's regression on the
    # field direction cosines (a scale or non-linearity error of one axis leans on its cosine²).
    if vector:
        zz = z.reshape(-1, 3)
        tables["axis"] = [{"bin": "xyz"[k], "n": len(zz), "mean_z": float(zz[:, k].mean()),
                           "rms_z": float(np.sqrt(np.mean(zz[:, k] ** 2)))} for k in range(3)]
    else:
        X = np.column_stack([np.ones(len(z)), directions ** 2])
        beta, *_ = np.linalg.lstsq(X, z, rcond=None)
        tables["axis"] = [{"bin": f"cos²({'xyz'[k]})", "slope_z": float(beta[k + 1])} for k in range(3)]
    tests = []
    # (the noise's correlation from the residuals within their orientation bins: the bins' own means, an orientation
    # effect's part, are no noise — taken with it, a cubic's slow course through the turns hid the cubic)
    in_time = np.argsort(data.t, kind="stable")
    within = signed - np.bincount(bins, signed, 24)[bins] / np.maximum(np.bincount(bins, minlength=24)[bins], 1)
    spread = _bin_sum_variance(within[in_time])
    for name in ("orientation", "temperature", "current", "time"):
        if name in tables:
            rows = tables[name]
            chi2 = sum(r["n"] * r["mean_z"] ** 2 for r in rows)
            if name == "orientation" and spread is not None:  # (correlated residuals: each bin's sum as it spreads)
                chi2 = sum(float(np.sum(signed[bins == b])) ** 2 / spread(bins[in_time] == b) for b in np.unique(bins))
            tests.append({"regime": name, "test": "bin means (χ²)", "statistic": chi2,
                          "pvalue": float(stats.chi2.sf(chi2, len(rows)))})
    for name, x in (("temperature", data.temp), ("current", data.current), ("time", data.t)):
        if x is not None and np.ptp(x) > 0:
            res = stats.linregress(x, signed)
            tests.append({"regime": name, "test": "slope", "statistic": float(res.slope / res.stderr),
                          "pvalue": float(res.pvalue)})
    tests += _whiteness(signed[np.argsort(data.t, kind="stable")])
    out["tables"] = tables
    out["tests"] = tests
    return out




def _bin_sum_variance(series: np.ndarray, max_order: int = 30):
    """For residuals z (unit variance if white) in time order: a function giving the variance of the sum of z over
    the readings a mask picks, under the AR(p) noise model the residuals show (`_ar_fit`, p by AIC, as the
    whitened likelihood ratio's), or None when they show none (p 0, or too few readings for it: their bin tests
    then take z as independent). The orientation bins' χ² had taken the residuals as independent: pure AR(1)
    noise of φ 0.9, no effect, a tumble (a bin visited in runs of correlated readings), read p 1e-19…1e-118;
    Var Σ z = Σ_k γ(k) c(k), γ the model's autocovariance and c the mask's own autocorrelation (pairs k apart)."""
    n = len(series)
    if n < 10 * max_order:
        return None
    p, c, rss, *_ = _ar_fit(series - series.mean(), max_order)
    if not p:
        return None
    from scipy.signal import lfilter

    lags = min(n, 4096)  # (the impulse response long enough for a φ of 0.999 to fall under e⁻⁴)
    impulse = np.zeros(lags)
    impulse[0] = 1.0
    psi = lfilter([1.0], np.concatenate([[1.0], -c]), impulse)
    if not np.all(np.isfinite(psi)) or abs(psi[-1]) > 1e-3 * np.max(np.abs(psi)):
        return None  # (a model at the edge of stationarity: no variance to trust)
    innovation = rss[p] / (n - max_order)
    size = 1 << int(np.ceil(np.log2(2 * lags)))
    gamma = innovation * np.fft.irfft(np.abs(np.fft.rfft(psi, size)) ** 2, size)[:lags]

    def spread(mask: np.ndarray) -> float:
        m = mask.astype(float)
        size_m = 1 << int(np.ceil(np.log2(2 * n)))
        pairs = np.fft.irfft(np.abs(np.fft.rfft(m, size_m)) ** 2, size_m)[:lags]  # c(k): picked pairs k apart
        pairs = np.round(pairs)
        return float(gamma[0] * pairs[0] + 2.0 * np.sum(gamma[1:len(pairs)] * pairs[1:]))

    return spread


def time_number(t):
    """A time's digits: four significant ones while they resolve the recording (33.61), else fixed point to a
    ten-thousandth of its span. ".4g" printed a Unix time as 1.733e+09, every event of a log at the same time."""
    t = np.asarray([] if t is None else t, dtype=float).ravel()
    if t.size == 0 or np.max(np.abs(t)) < 1e4:
        return lambda x: f"{x:.4g}"
    span = float(np.ptp(t))
    decimals = int(np.clip(np.ceil(-np.log10(span / 1e4)), 0, 6)) if span > 0 else 0
    return lambda x: f"{x:.{decimals}f}"


def time_words(t, timestamps: bool = True):
    """How a report says when: "row 12" without timestamps, else "t = 33.61 s"; for Unix seconds also the UTC
    clock time and the seconds since the first reading, which a log's own clock can be read against."""
    if not timestamps:
        return lambda x: f"row {x:.0f}"
    number = time_number(t)
    t = np.asarray([] if t is None else t, dtype=float).ravel()
    if not (t.size and UNIX_SECONDS[0] <= t.min() and t.max() <= UNIX_SECONDS[1]):
        return lambda x: f"t = {number(x)} s"
    decimals = len(number(t.min()).partition(".")[2])

    def clock(x):
        at = datetime.fromtimestamp(round(x, decimals), timezone.utc)
        return f"{at:%Y-%m-%d %H:%M:%S.%f}"[:20 + decimals if decimals else 19]
    return lambda x: f"t = {number(x)} s ({clock(x)} UTC, {x - t.min():.{decimals}f} s in)"


def _whiteness(series: np.ndarray) -> list:
    """The Ljung–Box test of a residual series in time order (up to 20 lags), as a one-item list of
    tests, or none when the series is constant. The core's O(N·lags) sum: statsmodels' acorr_ljungbox
    correlates every lag, O(N²), which took minutes on an hour's log."""
    lags = int(min(20, max(1, len(series) // 10)))
    try:
        lb = _core.ts_ljung_box(np.ascontiguousarray(series, float), lags, 0, 0.05)
    except _core.Error:  # zero variance: nothing to test
        return []
    return [{"regime": "time", "test": f"whiteness (Ljung-Box, {lags} lags)",
             "statistic": float(lb["statistic"]), "pvalue": float(lb["p_value"])}]


def _quantile_bins(x: np.ndarray, k: int) -> np.ndarray:
    edges = np.quantile(x, np.linspace(0, 1, k + 1)[1:-1])
    return np.searchsorted(edges, x, side="right")


def _binned(z: np.ndarray, bins: np.ndarray, labels, x=None, number=None, sigma_dof=np.inf) -> list:
    """Per bin of `bins`: n, mean and RMS of z (residual / σ) and the p of Σz² — χ²(n) against a σ known, F(n, ν)
    against one estimated with ν degrees of freedom (`sigma_dof`: one number, or one per bin): with σ from a few
    repeated snapshots its own error is a departure of every bin (σ 21 % low from 23 pairs had read p 3e-19)."""
    number = number or (lambda v: f"{v:.4g}")
    rows = []
    for b in np.unique(bins):
        sel = bins == b
        zb = z[sel]
        nu = float(np.ravel(sigma_dof)[b] if np.ndim(sigma_dof) else sigma_dof)
        p = stats.chi2.sf(np.sum(zb ** 2), sel.sum()) if not np.isfinite(nu) else stats.f.sf(np.mean(zb ** 2),
                                                                                             sel.sum(), nu)
        rows.append({"bin": labels[b] if labels else f"{number(x[sel].min())}…{number(x[sel].max())}",
                     "n": int(sel.sum()), "mean_z": float(zb.mean()), "rms_z": float(np.sqrt(np.mean(zb ** 2))),
                     "pvalue": float(p)})
    return rows


# ---------------------------------------------------------------- which and how far

def _gram_score(ZtZ, W, Zte, norms, Qe):
    """new_part's score × σ² from the Gram matrices of candidate columns Z: Z'Z, W = Q'Z, Z'e, and the columns'
    norms (Q the base Jacobian's orthonormal basis, Qe = Q'e): R'R = (Z'Z − W'W) and R'e = Z'e − W'Q'e of the new
    part R = Z − QW, without forming it. Stacks of candidates alike (leading axes)."""
    norms = np.where(norms == 0, 1.0, norms)
    Wt = np.swapaxes(W, -1, -2)
    s2, V = np.linalg.eigh((ZtZ - Wt @ W) / (norms[..., :, None] * norms[..., None, :]))
    s = np.sqrt(np.maximum(s2, 0.0))
    new = s >= ABSORBED
    along = (np.swapaxes(V, -1, -2) @ ((Zte - Wt @ Qe) / norms)[..., None])[..., 0]
    return np.sum(np.where(new, along / np.where(new, s, 1.0), 0.0) ** 2, axis=-1)


def _rows_score(base, vector, Q, e, Qe, feats, r, rows) -> float:
    """_gram_score of features given on the readings `rows` (their residuals `r`), × σ². (Some 600–1000 calls per
    event candidate: new_part's arithmetic with less call overhead — np.linalg.norm spelt out as the operations it
    performs.)"""
    Z = _project(base, feats, vector, rows)
    norms = np.sqrt(np.add.reduce(Z * Z, axis=0))  # np.linalg.norm(Z, axis=0)
    return float(_gram_score(Z.T @ Z, Q[r].T @ Z, Z.T @ e[r], norms, Qe))


def _placed_without_heldout(cls, data, state, regime, ctx, feats, base, vector, Q, e, sigma2) -> tuple:
    """A box placed again on the readings its held-out test of `regime` trains on, each edge within a held-out
    block's length of where every reading put it (`cls.placed_again`): its features, and the held-out readings of
    a held-out block an edge inside the recording could lie in (moved to its border, the training readings' score
    falls by less than EDGE_OPEN: for them it may sit anywhere across that block). The refinement sees the training
    readings alone: with the held-out ones' rows zeroed instead, its edges lay on flat ground across a held-out
    block. A search of the whole recording on them found another box (a warm-up's curve and a step together)."""
    held = _held_for(data, state, feats, regime)[1]
    keep = ~held
    n = len(data.m)
    part = SimpleNamespace(**{k: v[keep] if isinstance(v, np.ndarray) and v.ndim and len(v) == n else v
                              for k, v in vars(ctx).items()})
    part.memo = None  # (what it holds is the whole recording's)
    r = np.repeat(keep, len(e) // n)
    U, singular, _ = np.linalg.svd(Q[r], full_matrices=False)  # (an event's columns can vanish there)
    Q, e, base = U[:, singular > 1e-10 * singular.max()], e[r], dict(base, jacobian=np.asarray(base["jacobian"])[r])
    Qe = Q.T @ e

    def score_on(feats, rows):
        return _rows_score(base, vector, Q, e, Qe, feats, _residual_rows(rows, len(e) // len(part.t)), rows) / sigma2
    edges, placed = cls.placed_again(ctx, part, feats, score_on, np.ptp(data.t) / EVENT_BLOCKS)
    if edges is None:
        return placed, np.zeros(n, bool)
    best = score_on(*cls._box_rows(part, *edges))
    runs = _runs(data.t, held)
    unplaced = np.zeros(n, bool)
    for side in (0, 1):
        if not part.t.min() < edges[side] < part.t.max():
            continue  # (an end of the recording: a step's one edge is the other)
        for r in runs:  # within a held-out block: open
            unplaced[r] |= data.t[r[0]] <= edges[side] <= data.t[r[-1]]
        later = [r for r in runs if data.t[r[0]] > edges[side]]
        earlier = [r for r in runs if data.t[r[-1]] < edges[side]]
        for rows, border in ((later[:1], 0), (earlier[-1:], -1)):
            for r in rows:
                moved = list(edges)
                moved[side] = data.t[r[border]]
                if best - score_on(*cls._box_rows(part, *moved)) < EDGE_OPEN:
                    unplaced[r] = True
    return placed, unplaced


EDGE_OPEN = float(stats.chi2.ppf(0.95, 1))  # an edge moved to a held-out block's border for less than this loss of
                                          # score (its 95 % interval) may lie within the block


def _runs(t: np.ndarray, mask: np.ndarray) -> list:
    """The runs in time of the readings `mask`: arrays of their indices, each in time order."""
    order = np.argsort(t, kind="stable")
    return [order[first:last + 1] for first, last in index_runs(mask[order])]


# A box narrower than this part of the recording is scored from its own readings: the sums over all boxes hold
# powers of the time across the recording, which a narrow box's Legendre polynomials combine with coefficients up to
# (span / width)² — rounding grows with them (relative 3e-8 at a 16th, 4e-7 at a 32nd), while a narrow box's own
# readings are few.
BOX_SUMS_NARROWEST = 1 / 16


class _EventScores:
    """score_on for many events at once: the coarse scans of the event searches (sim.effects._TimeBox), ~530 boxes
    in time and ~600 passes of a magnet, each of which from its own readings cost ~40 numpy calls. Their features
    are a time profile times the candidate's carrier (`_carrier`) on the readings the event reaches, so one
    projection of the carrier into residual space serves them all. Readings out of time order go to score_on one by
    one."""

    def __init__(self, base: dict, vector: bool, Q: np.ndarray, e: np.ndarray, Qe: np.ndarray, sigma2: float,
                 score_on):
        self.base, self.vector, self.Q, self.e, self.Qe, self.sigma2 = base, vector, Q, e, Qe, sigma2
        self.score_on, self.held = score_on, {}

    def _carrier_columns(self, cls, ctx):
        """The carrier's columns in residual space, reading × its residuals × q, once per context (kept with it:
        its id is not reused meanwhile); None out of time order."""
        if id(ctx) not in self.held:
            Z = None
            if ctx.t[-1] > ctx.t[0] and _time_ordered(ctx):
                carrier = cls._carrier(ctx)
                Z = _project(self.base, carrier, self.vector).reshape(len(ctx.t), -1, carrier.shape[1])
            self.held[id(ctx)] = (ctx, Z)
        return self.held[id(ctx)][1]

    def _running_sums(self, cls, ctx):
        """Running sums over the readings of τ^m z z', τ^m Q'z and τ^m z e (z: the carrier's columns, τ = −1…1
        across the recording), Legendre-major as the box's columns: a box's Gram matrices are their differences
        combined with its Legendre coefficients in τ. None out of time order or beyond a memory's worth."""
        Z, t, degree = self._carrier_columns(cls, ctx), ctx.t, cls.BOX_DEGREE
        if Z is None:
            return None
        n, q = Z.shape[0], Z.shape[2]
        p = (degree + 1) * q
        if n * p * (p + self.Q.shape[1] + 1) > MEMO_FLOATS:
            return None
        mid, half = 0.5 * (t[0] + t[-1]), 0.5 * (t[-1] - t[0])
        powers = ((t - mid) / half)[:, None] ** np.arange(2 * degree + 1)
        k = np.arange(degree + 1)
        hankel = powers[:, np.add.outer(k, k)]  # [n, m, l] = τ^(m+l)
        zz = np.einsum("nra,nrb->nab", Z, Z)
        gram = (hankel[:, :, None, :, None] * zz[:, None, :, None, :]).reshape(n, p, p)
        qz = np.einsum("nrc,nra->nca", self.Q.reshape(n, Z.shape[1], -1), Z)
        cross = (qz[:, :, None, :] * powers[:, None, :len(k), None]).reshape(n, -1, p)
        ez = np.einsum("nr,nra->na", self.e.reshape(n, Z.shape[1]), Z)[:, None, :] * powers[:, :len(k), None]

        def running(x):  # row i: the sum over the first i readings
            out = np.zeros((n + 1,) + x.shape[1:])
            np.cumsum(x, axis=0, out=out[1:])
            return out
        return q, mid, half, running(gram), running(cross), running(ez.reshape(n, -1))

    def boxes(self, cls, ctx, edges) -> np.ndarray:
        """The scores of the boxes (t_on, t_off) in `edges`."""
        sums = self._running_sums(cls, ctx)  # (once: a search scans its coarse boxes in one call)
        on, off = np.asarray(edges, dtype=float).reshape(-1, 2).T
        out = np.empty(len(on))
        summed = np.zeros(len(on), dtype=bool)
        if sums is not None:
            q, mid, half, S, G, E = sums
            lo, hi = ctx.t.searchsorted(on, side="left"), ctx.t.searchsorted(off, side="right")  # (_rows_within's)
            summed = (off - on >= 2 * BOX_SUMS_NARROWEST * half) & (hi > lo)
            lo, hi = lo[summed], hi[summed]
            A = _legendre_in_time(0.5 * (on + off)[summed] - mid, 0.5 * (off - on)[summed], half, cls.BOX_DEGREE)
            M = np.zeros((len(A), A.shape[1] * q, A.shape[1] * q))  # A ⊗ I_q: P_k times carrier column a
            for a in range(q):
                M[:, a::q, a::q] = A
            Mt = np.swapaxes(M, 1, 2)
            ZtZ = M @ (S[hi] - S[lo]) @ Mt
            norms = np.sqrt(np.maximum(np.diagonal(ZtZ, axis1=1, axis2=2), 0.0))
            out[summed] = _gram_score(ZtZ, (G[hi] - G[lo]) @ Mt, (M @ (E[hi] - E[lo])[:, :, None])[:, :, 0], norms,
                                      self.Qe) / self.sigma2
        for i in np.flatnonzero(~summed):  # (narrow: few readings of their own)
            out[i] = self.score_on(*cls._box_rows(ctx, on[i], off[i]))
        return out

    def passes(self, cls, ctx, closest, t_pass: float) -> np.ndarray:
        """The scores of the passes with closest approaches `closest`, each taking `t_pass` (`_pass_rows`): the
        readings each reaches, padded to the longest with zero rows, in one stack."""
        Z = self._carrier_columns(cls, ctx)
        closest = np.asarray(closest, dtype=float)
        if Z is None:
            return np.array([self.score_on(*cls._pass_rows(ctx, c, t_pass)) for c in closest])
        t, reach = ctx.t, cls.PASS_REACH * t_pass
        lo, hi = t.searchsorted(closest - reach, side="left"), t.searchsorted(closest + reach, side="right")
        longest, per = max(int(np.max(hi - lo)), 1), Z.shape[1]
        chunk = max(1, MEMO_FLOATS // (longest * per * (self.Q.shape[1] + 3 * Z.shape[2] + 1)))  # (a memory's worth)
        if len(closest) > chunk:
            return np.concatenate([self.passes(cls, ctx, closest[i:i + chunk], t_pass)
                                   for i in range(0, len(closest), chunk)])
        rows = lo[:, None] + np.arange(longest)
        within = rows < hi[:, None]
        rows = np.minimum(rows, len(t) - 1)
        profile = cls.pass_profile((t[rows] - closest[:, None]) / t_pass) * within[:, :, None]  # B × L × k
        Zb = (profile[:, :, None, :, None] * Z[rows][:, :, :, None, :]).reshape(len(closest), -1, profile.shape[2]
                                                                               * Z.shape[2])
        r = (rows[:, :, None] * per + np.arange(per)).reshape(len(closest), -1)  # their residuals
        Zt = np.swapaxes(Zb, 1, 2)
        ZtZ = Zt @ Zb
        norms = np.sqrt(np.maximum(np.diagonal(ZtZ, axis1=1, axis2=2), 0.0))
        return _gram_score(ZtZ, np.swapaxes(self.Q[r], 1, 2) @ Zb, (Zt @ self.e[r][:, :, None])[:, :, 0], norms,
                           self.Qe) / self.sigma2


@lru_cache(maxsize=None)
def _legendre_powers(degree: int) -> tuple:
    """(L, C, j): L[k, j] the coefficient of u^j in the Legendre polynomial P_k(u), C[j, m] = binomial(j, m), j."""
    L = np.zeros((degree + 1, degree + 1))
    for k in range(degree + 1):
        c = np.polynomial.legendre.leg2poly(np.eye(degree + 1)[k])
        L[k, :len(c)] = c
    j = np.arange(degree + 1)
    return L, np.array([[comb(a, b) for b in j] for a in j], dtype=float), j


def _legendre_in_time(centre: np.ndarray, half_width: np.ndarray, half_span: float, degree: int) -> np.ndarray:
    """A[b, k, m]: P_k(u) = Σ_m A[b, k, m] τ^m for boxes b, u = −1…1 across a box (its centre and half-width from
    the recording's middle), τ = −1…1 across the recording (its half span): u = (τ − c)/h,
    u^j = Σ_m C(j, m) (−c)^(j−m) τ^m / h^j."""
    L, C, j = _legendre_powers(degree)
    c, h = (centre / half_span)[:, None, None], (half_width / half_span)[:, None, None]
    return L @ (C * (-c) ** np.maximum(j[:, None] - j[None, :], 0) / h ** j[:, None])


def _evaluate(cls, data, model, state, sigma, n_candidates) -> dict:
    """Score test, absorption check, refit, likelihood ratio and held-out validation of one candidate."""
    vector, fixed = MODELS[model]
    base = state["result"]
    e = np.asarray(base["residuals"])
    n = len(e)
    ctx = _context(data, base, _features(state["features"]))
    if state.get("_basis", (None,))[0] is not base:  # one QR per round's base fit, not per candidate
        J = np.asarray(base["jacobian"])
        J = J[:, np.any(J != 0, axis=0)]
        state["_basis"] = (base, np.linalg.qr(J)[0], J.shape[1])
    Q, columns = state["_basis"][1:]
    sigma2 = e @ e / (n - columns)

    def new_part(feats):
        """The candidate's columns orthogonal to the base Jacobian: (score, new dimensions, singular values,
        an orthonormal basis of the new part — the candidate's signature in the residuals)."""
        Z = _project(base, feats, vector)
        norms = np.linalg.norm(Z, axis=0)
        if cls.signal_features and not fixed:
            # Measured against the part not affine in the signal: offset and full matrix hold any affine
            # part, so about a hard iron of several fields most of s_k·s_e or s_k³ is affine and the new part
            # looked < 5 % of the whole though it was all of what the base could not hold (cross_axis).
            norms = np.maximum(np.linalg.norm(_project(base, _non_affine(feats, ctx.signal), vector), axis=0),
                               1e-6 * norms)
        norms[norms == 0] = 1.0
        R = (Z - Q @ (Q.T @ Z)) / norms
        # singular values and left vectors from the p × p Gram matrix: an SVD of the N × p matrix costs
        # 10× more, and this runs for every alternative of a box search
        s2, V = np.linalg.eigh(R.T @ R)
        s2, V = s2[::-1], V[:, ::-1]
        s = np.sqrt(np.clip(s2, 0.0, None))
        new = s >= ABSORBED
        U = (R @ V[:, new]) / s[new]
        return ((float(np.sum((U.T @ e) ** 2) / sigma2) if new.any() else 0.0), int(new.sum()), s, U)

    Qe = Q.T @ e
    per_reading = n // len(data.m)

    def score_on(feats, rows=None):
        """new_part's score; with `rows`, for features given on those readings only (zero elsewhere, a box in
        time): the same Gram matrices from products over those rows, R'R = (Z'Z − W'W) and R'e = Z'e − W'Q'e
        with W = Q'Z, without forming the N × p new part."""
        if rows is None or (cls.signal_features and not fixed):  # (the latter's norms need every reading)
            return new_part(feats if rows is None else scatter_rows(len(data.m), feats, rows))[0]
        return _rows_score(base, vector, Q, e, Qe, feats, _residual_rows(rows, per_reading), rows) / sigma2

    if not (cls.signal_features and not fixed):
        events = _EventScores(base, vector, Q, e, Qe, sigma2, score_on)
        score_on.boxes, score_on.passes = events.boxes, events.passes

    profiled, ctxs, form, taken = {}, _forms(cls, ctx), "hard_iron", {}
    projected = {f: {} for f in ctxs}  # a profile's projected grid, for the profile on the kept residuals (below)
    if cls.linear and not fixed:  # exactly absorbed by the full matrix; its first-order features are not
        # (one of three directions looked new on a real recording with a 4 % temperature scale error)
        feats, tried, score, dims, singular, signature = cls.features(ctx), 1, 0.0, 0, np.zeros(0), None
    elif cls.profile_name:  # its parameter is counted as a parameter (below), not as alternatives tried
        value, form, feats, taken = _profile(cls, ctxs, base, Q, e, vector, projected)
        # at its null value (a temperature's lag of 0) the candidate is its plain form: no parameter to count
        tried, profiled = len(ctxs), ({} if value == cls.profile_null else {cls.profile_name: value})
        score, dims, singular, signature = new_part(feats)
    else:
        found = {form: cls.search(c, score_on) for form, c in ctxs.items()}
        taken = {form: score_on(f) * sigma2 for form, (f, _) in found.items()}  # as the profile's: the part of e
        form = max(taken, key=taken.get)
        feats, tried = found[form][0], sum(n for _, n in found.values())
        score, dims, singular, signature = new_part(feats)
    row = {"effect": cls.name, "regime": cls.regime, "n_params": int(feats.shape[1]),
           **_score_fields(score, dims, singular, tried), **cls.describe(ctx, feats)}
    extras = cls.profiled_extras(ctxs[form], profiled[cls.profile_name]) if profiled else {}
    row.update(_profiled_row(profiled), **extras, **_offset_kind(form, taken, e))
    if dims == 0:
        row.update(lr=0.0, lr_pvalue=1.0, delta_aic=0.0, delta_bic=0.0, significant=False,
                   heldout_gap_before=None, heldout_gap_after=None,
                   note="absorbed by the model's parameters, the base's and the effects already accepted "
                        "(cannot be told apart from them)")
        return row
    all_feats = _features(state["features"] + [feats])
    try:
        fit = _fit(data, state["start"], fixed, all_feats,
                   start_terms=np.concatenate([state["terms"], np.zeros(feats.shape[1])]))
        if getattr(cls, "step_at_ends", False):
            feats, fit = _step_at_ends(cls, data, ctx, state, fixed, feats, fit, e)
            score, dims, singular, signature = new_part(feats)
            row.update(_score_fields(score, dims, singular, tried), **cls.describe(ctx, feats))
        held_feats, regime = feats, _settled_regime(cls, data, profiled)
        if cls.signal_features:
            feats, fit, value = _at_own_signal(cls, data, fixed, state, feats, fit, ctxs[form].scale, sigma,
                                               profiled.get(cls.profile_name), form)
            row.update(_profiled_row({cls.profile_name: value} if profiled else {}))
            held_feats = feats
        elif cls.profile_name:
            # The held-out readings choose nothing: a lag or time constant picked on all the readings had let a
            # made-up temperature's lag fit the recording's own slow wander in the held-out quarter too.
            keep = np.repeat(~_held_regime(data, state, regime)[1], per_reading)
            value = _profile_value(cls, ctxs[form], base, Q, e, vector, keep, projected[form])[0]
            row[f"{cls.profile_name}_without_heldout"] = _profiled_row({"v": value})["v"]
            held_feats = cls.features_at(ctxs[form], value)
        elif row.get("closest_s") is None and cls.searched_times(row) and _event_block(feats, data,
                                                                                       state["correlation"]) is None:
            # Nor do they place a long box: edges searched on every reading had put boxes over a third of a short
            # recording of 1/f or AR(1) noise where the held-out blocks' wander lay, and their held-out tests
            # confirmed them (10 of 60 simulations; refined on the training blocks, 5). A short event (its own
            # blocks) and a pass keep their placement: a held-out block can hold a pass's whole core (a second-long
            # one, placed from its tails, was missed). The held-out readings of a block an edge may lie in are not
            # judged: a true step's edge within one, placed at its border, had failed on the block's readings
            # before the step.
            held_feats, row["_heldout_unplaced"] = _placed_without_heldout(cls, data, state, regime, ctxs[form],
                                                                           feats, base, vector, Q, e, sigma2)
            row.update({f"{k}_without_heldout": v for k, v in cls.describe(ctxs[form], held_feats).items()})
            row["_heldout_features"] = held_feats
        validated = _validate(data, model, state, held_feats, regime, sigma,
                              others=np.asarray(fit["parameters"])[12 if vector else 9:][:len(state["terms"])],
                              placed=feats, unplaced=row.get("_heldout_unplaced"))
    except _core.Error as err:  # a candidate nearly inside the model can leave the solver no valid step
        row.update(lr=0.0, lr_pvalue=1.0, delta_aic=0.0, delta_bic=0.0, significant=False,
                   heldout_gap_before=None, heldout_gap_after=None,
                   note=f"not judged: the refit with it failed ({err})")
        return row
    # ΔAIC/ΔBIC (which candidate fits best) from the plain likelihood ratio; the p-value (is it real)
    # from the whitened one, so that slow correlated noise is not taken for a systematic effect.
    e1 = np.asarray(fit["residuals"])
    lr = max(0.0, n * np.log(float(e @ e) / float(e1 @ e1)))
    lr_whitened = _whitened_lr(e, e1, data, wander=_round_wander(data, state))
    k = dims + len(profiled) + len(extras)  # a profiled parameter is fitted too: it pays like a coefficient
    # So does a time the search placed (an event's edges): in the p-value the alternatives tried pay for it
    # (Bonferroni); left out of ΔBIC, a box's free edges had won ties against a drift's law, whose time constant
    # pays (a gain drifting over the whole recording named a magnet).
    searched = cls.searched_times(row)
    row.update(lr=lr, lr_whitened=lr_whitened, searched_times=searched, fitted_parameters=k,
               lr_pvalue=min(1.0, float(stats.chi2.sf(lr_whitened, k)) * tried),
               delta_aic=-lr + 2 * (k + searched), delta_bic=-lr + (k + searched) * np.log(n),
               coefficients=np.asarray(fit["parameters"])[-feats.shape[1]:].tolist(),
               standard_errors=np.asarray(fit["standard_errors"])[-feats.shape[1]:].tolist())
    row.update(validated)
    row["distortion"] = _distortion(ctx.signal, state["features"] + [feats],
                                    state["signal_blocks"] + [cls.signal_features], np.asarray(fit["parameters"]),
                                    12 if vector else 9)
    row["hidden_change"] = _hidden_change(data.m, state["features"] + [feats],
                                          state["signal_blocks"] + [cls.signal_features],
                                          np.asarray(fit["parameters"]), 12 if vector else 9)
    if state["features"]:  # beside the effects found: does its fit cancel one of theirs, or make one unphysical?
        other = _cancelling(fit, state["features"] + [feats], vector, new=1)
        if other is not None:
            row["cancels"] = state["effects"][other]
        made = _made_unphysical(fit, state, vector)
        if made:
            row["makes_unphysical"] = dict(zip(("effect", "reason"), made))
    row["unmet"] = _unmet(row, n_candidates, state["alpha"])
    row["significant"] = not row["unmet"]
    flag = _implausible(row, sigma, state["sigma_bound"], cls, vector, state["period"], state["undetermined"])
    if flag:
        row[flag[0]], row["note"], row["significant"] = flag[1], flag[2], False
    row["_fit"], row["_features"], row["_signature"] = fit, feats, signature
    row["_explained"] = e - e1  # what it takes out of the round's residuals
    row["_signal_features"] = cls.signal_features
    row["_law_in_time"] = bool(getattr(cls, "law_in_time", False))
    return row


SETTLED = 0.05  # a settling that makes less than this share of its change within the held-out last quarter has
                # settled before it (a time constant under ≈ the span / 3.2): the quarter shows nothing of it


def _settled_regime(cls, data: _Data, profiled: dict) -> str:
    """The held-out regime of a candidate: its own, but for a law in time that settles (a warm-up making less than
    SETTLED of its change in the last quarter in time) interleaved blocks of time, as an event's: the last quarter
    shows nothing of it (a 20 s warm-up beside a step: ΔBIC −8157, held-out gap 0.0107 → 0.0086, refused; a 44 s
    one over 300 s, found first beside a step: ΔBIC −8446, 0.0147 → 0.0108, not confirmed)."""
    tau = profiled.get(getattr(cls, "profile_name", "")) if getattr(cls, "law_in_time", False) else None
    if tau is not None and np.isfinite(tau) and tau > 0 and data.t is not None:
        x = np.ptp(data.t) / tau
        if np.exp(-(1 - HELDOUT_FRACTION) * x) - np.exp(-x) < SETTLED:
            return "events"
    return cls.regime


def _score_fields(score: float, dims: int, singular: np.ndarray, tried: int) -> dict:
    """A candidate's new part: its score, the score's p-value over the `tried` alternatives (Bonferroni), and how
    much of it the model's parameters already hold."""
    return {"new_dimensions": dims, "absorbed": dims == 0, "alternatives": tried, "score": score,
            "score_pvalue": min(1.0, float(stats.chi2.sf(score, max(dims, 1))) * tried),
            "absorbed_fraction": float(1 - singular.min()) if len(singular) else 1.0}


def _step_at_ends(cls, data, ctx, state, fixed, feats, fit, e) -> tuple:
    """A box with both edges inside the recording is tried as a step too — each edge in turn moved to the recording's
    end (the off edge) or start (the on edge), the other kept, refitted — and the step is taken (of two, the closer
    fit) unless the box's edge pays BIC's price: under the residuals' correlation (`_whitened_lr`) for an edge within
    the recording's first or last grid cell of the search (`cls.GRID`) — the search moves such an edge inside for
    BIC's price in the plain ratio, which the recording's own correlated wander pays (a blind check: steps that stayed,
    on a phone's 120 s log, "came back at t = 119.2 s", or "jumped at 2.81 s and came back at 61.92 s") —, in the plain
    ratio for one farther in: the search scores the edges at the base fit, which the step itself distorts (another: a
    vehicle's 10 % step that stayed was put in a box ending 17 s early, its whitened ratio 13 for the leftover step,
    and a magnet's free course in time named instead). Returns (features, fit)."""
    span = cls.span(ctx, feats)
    t0, t1 = float(np.min(ctx.t)), float(np.max(ctx.t))
    if span is None or not t1 > t0 or span[0] <= t0 or span[1] >= t1:
        return feats, fit
    cell = (t1 - t0) / cls.GRID
    if span[0] < t0 + cell and span[1] > t1 - cell:  # (a box over nearly all of it: the gaps at its ends are its own)
        return feats, fit
    box = np.asarray(fit["residuals"])
    best, rss = (feats, fit), None
    for on, off, near in ((t0, span[1], span[0] < t0 + cell), (span[0], t1, span[1] > t1 - cell)):
        trial = cls._box(ctx, on, off)
        try:
            step = _fit(data, state["start"], fixed, _features(state["features"] + [trial]),
                        start_terms=np.concatenate([state["terms"], np.zeros(trial.shape[1])]))
        except _core.Error:
            continue
        residuals = np.asarray(step["residuals"])
        if near:
            edge = _whitened_lr(residuals, box, data, wander=_round_wander(data, state))
        else:
            edge = len(e) * np.log(float(residuals @ residuals) / float(box @ box))
        if edge < np.log(len(e)) and (rss is None or residuals @ residuals < rss):
            best, rss = (trial, step), float(residuals @ residuals)
    return best


# Beside an effect already found, a held-out fall within the fits' parameter noise (`_gain_unresolved`) confirms
# a candidate only when it takes at least this share of the gap: in the blind checks the 8 false effects accepted
# so took 10–43 % of it; a true temperature offset beside a magnet, extrapolated to the hottest quarter, took 93 %.
UNRESOLVED_GAIN = 0.5


def _beside(row: dict, data, directions: np.ndarray, sigma: float, accepted: list) -> None:
    """A significant row beside the effects `accepted`: not significant when its held-out gap's fall is within what
    the two fits' parameter noise alone can make (`_gain_unresolved`) and under UNRESOLVED_GAIN of the gap."""
    leverage = _row_leverage(data, row["_fit"], row, directions)
    if not (_gain_unresolved(row, leverage, sigma)
            and row["heldout_gap_after"] > (1 - UNRESOLVED_GAIN) * row["heldout_gap_before"]):
        return
    row.update(significant=False, heldout_leverage=leverage, heldout_gain_unresolved=True,
               unmet=list(row["unmet"]) + ["heldout_resolved"],
               note=f"not confirmed beside {', '.join(accepted)}: its held-out gap's fall "
                    f"{row['heldout_gap_before']:.3g} → {row['heldout_gap_after']:.3g} is within what the "
                    "two fits' parameter noise alone can make" if np.isfinite(leverage) else
                    f"not confirmed beside {', '.join(accepted)}: the other readings do not determine "
                    "every parameter its held-out readings depend on, so its held-out test tests nothing")


def _judged(feats: np.ndarray, held: np.ndarray, block: int | None) -> np.ndarray:
    """The held-out readings a candidate's gaps are measured on: where it acts for a short event (its own
    `block`s), every held-out reading otherwise."""
    return _where_it_acts(feats, held) if block is not None else held


def _row_leverage(data, result: dict, row: dict, directions: np.ndarray) -> float:
    """`_heldout_leverage` of a judged row's held-out readings (its regime, its own blocks for a short event), on
    those it was judged on, for the fit `result`."""
    held = _heldout(row["heldout"], data, directions, row.get("heldout_block"))
    unplaced = row.get("_heldout_unplaced")
    judged = held if unplaced is None else held & ~unplaced
    return _heldout_leverage(data, result, held, _judged(row.get("_heldout_features", row["_features"]), judged,
                                                         row.get("heldout_block")))


def _gain_unresolved(row: dict, leverage: float, sigma: float) -> bool:
    """Whether a row's held-out gap fell by less than 2√2 σ √leverage. The noise in a fit's parameters moves its
    prediction of every held-out reading alike, by σ √leverage (`_heldout_leverage`): the two fits' held-out
    gaps differ by up to √2 of that from their parameters' noise alone."""
    return bool(row["heldout_gap_before"] - row["heldout_gap_after"] < 2 * np.sqrt(2) * sigma * np.sqrt(leverage))


def _unmet(row: dict, n_candidates: int, alpha: float) -> list:
    """The acceptance tests a judged row fails ("in_sample", "bic", "heldout_p", "heldout_gain"; none: the
    evidence accepts it): strong in-sample evidence (whitened LR, Bonferroni over the candidates, and BIC),
    confirmed on held-out readings (the improvement's block test and at least MIN_GAIN of the gap).
    "Significant in sample, not confirmed held out" is half of what a real recording's own slow disturbances
    leave undetected (bench/RESULTS.md)."""
    unmet = []
    if not row["lr_pvalue"] * n_candidates < alpha:
        unmet.append("in_sample")
    if not row["delta_bic"] < 0:
        unmet.append("bic")
    if not row["heldout_pvalue"] < HELDOUT_ALPHA:
        unmet.append("heldout_p")
    if not row["heldout_gap_after"] < (1 - MIN_GAIN) * row["heldout_gap_before"]:
        unmet.append("heldout_gain")
    return unmet


def refused(row: dict) -> bool:
    """Whether a ranking row was refused by `_implausible` (degenerate, unphysical, or its field error rises)."""
    return bool(row.get("degenerate") or row.get("unphysical") or row.get("field_error_rises"))


def _implausible(row: dict, sigma: float, sigma_bound: bool, cls, vector: bool = False, period: float = 0.0,
                 undetermined: bool = False):
    """Why a candidate's fit cannot be an effect (`cls`'s) whatever its evidence, as (the row's flag, its value,
    a note), or None. `undetermined`: the base calibration's data leave some of it undetermined (poor coverage)."""
    floor, before, after = row["heldout_noise_floor"], row["field_error_before"], row["field_error_after"]
    # With the base undetermined, what the noise leaves held out includes its correlated part (`_noise_shown`)
    shown_floor = floor * max(1.0, row.get("heldout_noise_shown") or 1.0)
    if row["hidden_change"] > MAX_HIDDEN_CHANGE:  # (first: such a fit's held-out error is no evidence either way)
        return "degenerate", "changes the readings more than they vary", (
            f"not accepted: its fit changes the readings by {row['hidden_change']:.3g}× as much as they vary (RMS about "
            "their mean), which they do not show: the base calibration takes the change back (the two cancel — the "
            "data determine their sum, not each; a base its readings do not determine, poor coverage, lets them)")
    # (a σ that holds the model's misses is no floor: a right model goes below it)
    # (features of the signal alone, or computed from it — hysteresis' loop, held out in time, follows the signal's
    # course: with the base undetermined it takes up the noise along the open direction as a cubic does)
    if (not sigma_bound and undetermined and (cls.regime == "orientation" or cls.signal_features)
            and after < UNDETERMINED_FLOOR_FRACTION * shown_floor):
        noise = (f"σ {sigma:.3g}" if shown_floor == floor else
                 f"σ {sigma:.3g} and the correlated noise its fit leaves, {shown_floor / floor:.3g} σ in all,")
        return "degenerate", "below the noise held out, the base undetermined", (
            f"not accepted: held out, its fit gives a field error of {after:.3g}, {after / shown_floor:.2f} of what "
            f"the readings' noise alone leaves there ({shown_floor:.3g}, {noise} through the calibration). With a base "
            "calibration its readings do not determine (poor coverage), features taken from the signal take up the "
            "noise along the direction the readings leave open, and predict each reading partly from itself")
    if not sigma_bound and after < NOISE_FLOOR_FRACTION * floor:
        coefficients = row["coefficients"]
        return "degenerate", "below the noise held out", (
            f"not accepted: held out, its fit gives a field error of {after:.3g}, {after / floor:.2f} of what the "
            f"readings' noise alone leaves there ({floor:.3g}, σ {sigma:.3g} through the calibration). No model "
            "predicts better than the noise: its features rebuild each reading from itself (a degenerate fit"
            + (", coefficients " + ", ".join(f"{c:.3g}" for c in coefficients) if len(coefficients) <= 6 else "")
            + "), or the noise σ is overestimated")
    if row["distortion"] > MAX_DISTORTION:
        return "degenerate", "changes the readings more than the signal", (
            f"not accepted: with it, the model's signal-dependent effects change the readings by "
            f"{row['distortion']:.3g}× the signal (RMS) — no sensor's non-linearity; their features, taken from "
            "the fit's own signal, stand in for the signal (a degenerate fit)")
    if row.get("makes_unphysical"):
        made = row["makes_unphysical"]
        return "degenerate", f"makes {made['effect']} unphysical", (
            f"not accepted: fitted beside it, {made['effect']} turns unphysical — {made['reason']} (the two trade "
            "terms: the data determine their sum, not each)")
    if row.get("cancels"):
        return "degenerate", f"cancels {row['cancels']}", (
            f"not accepted: fitted beside {row['cancels']}, its change to the readings and {row['cancels']}'s are each "
            f"over {CANCELLING:g}× what both make together — they cancel: the data determine their difference, not "
            f"each (sizes that grow together without bound)")
    reason = cls.unphysical(row["coefficients"], row["standard_errors"], vector=vector, period=period)
    if reason:
        return "unphysical", reason, f"not accepted as {cls.name}: {reason}"
    # Its residuals fell only in reading units: a fit can lower them by changing its own gain (the residual
    # is the field error over it) while the calibrated field departs further from the truth.
    if row["significant"] and after > before:
        return "field_error_rises", True, ("not accepted: held out, it lowers the residuals but raises the "
                                           f"calibrated field's error {before:.3g} → {after:.3g}")
    return None


def _distortion(signal: np.ndarray, blocks: list, signal_dependent: list, parameters: np.ndarray, lo: int) -> float:
    """The largest change that one signal-dependent block of a fit makes to the readings, RMS over the
    readings, in units of the signal's RMS (0 without such blocks)."""
    size = np.linalg.norm(signal)
    return max((float(np.linalg.norm(change) / size) for change in
                _block_changes(blocks, signal_dependent, parameters, lo, dependent=True)), default=0.0)


def _block_changes(blocks: list, signal_dependent: list, parameters: np.ndarray, lo: int, dependent: bool):
    """Each block's change to the readings (N × 3: its coefficients, from `parameters[lo:]` in the blocks' order,
    times its features), of the blocks whose `signal_dependent` flag is `dependent`."""
    for feats, flag in zip(blocks, signal_dependent):
        p = feats.shape[1]
        if flag == dependent:
            yield np.einsum("p,npk->nk", parameters[lo:lo + p], feats)
        lo += p


def _hidden_change(readings: np.ndarray, blocks: list, signal_dependent: list, parameters: np.ndarray,
                   lo: int) -> float:
    """The change that the blocks of a fit not built from its own signal (`signal_dependent` False: a course in time,
    temperature or current, or a gain or rotation of the signal that follows one) make together to the readings, RMS
    about its mean, in units of the readings' own RMS about theirs (0 without such blocks). The readings hold the
    field's course and the effects': effects whose course is larger than theirs are cancelled by the field's — by the
    base calibration, fitted to take it back. (Together: two such blocks that cancel each other are `_cancelling`'s.)
    A one-axis turntable's null recording: a sensor-fixed interference at the turning's frequency, 7.2× the readings'
    variation, with a base ellipsoid flattened to cancel it, had been named (a blind check)."""
    change = sum(_block_changes(blocks, signal_dependent, parameters, lo, dependent=False), np.zeros_like(readings))
    size = np.linalg.norm(readings - readings.mean(axis=0))
    return float(np.linalg.norm(change - change.mean(axis=0)) / size) if size > 0 else 0.0


def _non_affine(feats: np.ndarray, signal: np.ndarray) -> np.ndarray:
    """Each feature column (N × p × 3) less its least-squares affine function of the signal."""
    X = np.column_stack([np.ones(len(signal)), signal])
    flat = feats.reshape(len(feats), -1)
    coef, *_ = np.linalg.lstsq(X, flat, rcond=None)
    return (flat - X @ coef).reshape(feats.shape)


def _profiled_row(profiled: dict) -> dict:
    """A profiled parameter for the ranking row (None for ∞: saturation's cubic limit)."""
    return {k: (float(v) if np.isfinite(v) else None) for k, v in profiled.items()}


def _profile(cls, ctxs: dict, result: dict, Q: np.ndarray, e: np.ndarray, vector: bool, projected=None):
    """A profiled candidate's parameter and form: for each form's context (`_forms`), the value whose features,
    fitted together with the columns of the orthonormal basis Q (the rest of the model, linearised at `result`),
    take most off the residuals e (`_profile_value`), and the form that takes most. `projected`: a dict per form
    to keep the grid's projected features in (`_profile_value`). Returns (value, form, features, the part of e
    each form takes)."""
    found = {form: _profile_value(cls, ctx, result, Q, e, vector, projected=(projected or {}).get(form))
             for form, ctx in ctxs.items()}
    form = max(found, key=lambda f: found[f][1])
    value = found[form][0]
    return value, form, cls.features_at(ctxs[form], value), {f: g for f, (_, g) in found.items()}


def _taken_by(R: np.ndarray, e: np.ndarray) -> float:
    """‖R c‖², c the least-squares coefficients of e on R's columns: the part of e they take, as numpy's lstsq
    gives it. Through the normal equations of the unit-norm columns and their eigenvalues (half lstsq's time on
    the profiles' tall, narrow problems, some 10⁵ per diagnosis run) when those resolve it: eigenvalues within 1e8
    (they square R's condition number: the weakest direction's part then within ~4e-8 of lstsq's), column norms
    within 1e5 and fewer than 4e6 residuals (R's singular values then within 1e9 of each other, above lstsq's cut at
    eps·N of the largest: it keeps every direction too). Else, and for a column that is not finite, lstsq itself.
    Zero columns take nothing, as in lstsq."""
    if R.shape[1] == 0:
        return 0.0
    G, b = R.T @ R, R.T @ e
    d = np.diagonal(G)
    if np.all(np.isfinite(d)) and len(R) < 4e6:
        used = d > 0
        if not used.any():
            return 0.0
        if not used.all():
            G, b, d = G[np.ix_(used, used)], b[used], d[used]
        if len(d) == 1:
            return float(b[0] ** 2 / d[0])
        norms = np.sqrt(d)
        if norms.min() > 1e-5 * norms.max():
            lam, V = np.linalg.eigh(G / np.outer(norms, norms))
            if lam[0] > 1e-8 * lam[-1]:
                return float(np.sum((V.T @ (b / norms)) ** 2 / lam))
    coef, *_ = np.linalg.lstsq(R, e, rcond=None)
    return float(np.sum((R @ coef) ** 2))


def _profile_value(cls, ctx, result: dict, Q: np.ndarray, e: np.ndarray, vector: bool, keep=None, projected=None):
    """The profiled parameter: its grid (`cls.profile_grid`), then a bounded search in log between
    the best point's neighbours. Each step is a linear refit, so the profile costs projections, not solver runs.
    `keep` (a mask of the residuals): chosen on those alone. `projected` (a dict, or None): the grid's features
    projected at `result`, kept there and taken from there — the profile on the kept residuals runs over the same
    grid as the one on all of them. Returns (value, the part of e its features take)."""
    from scipy.optimize import minimize_scalar

    if keep is not None:  # (an SVD: an accepted event's columns can vanish on the kept rows, leaving Q[keep] short of rank)
        U, singular, _ = np.linalg.svd(Q[keep], full_matrices=False)
        Q, e = U[:, singular > 1e-10 * singular.max()], e[keep]

    known = {}  # gains by value: the null value may be on the grid (a drift's ∞)

    def gain(value, on_grid=False):
        if value not in known:
            Z = projected.get(value) if on_grid and projected is not None else None
            if Z is None:
                Z = _project(result, cls.features_at(ctx, value), vector)
                if on_grid and projected is not None and (len(projected) + 1) * Z.size <= MEMO_FLOATS:
                    projected[value] = Z
            Z = Z if keep is None else Z[keep]
            known[value] = _taken_by(Z - Q @ (Q.T @ Z), e)
        return known[value]

    grid = np.asarray(cls.profile_grid(ctx), dtype=float)
    gains = [gain(v, on_grid=True) for v in grid]
    i = int(np.argmax(gains))
    value, best_gain = grid[i], gains[i]
    if np.isfinite(value) and value != 0 and len(grid) > 1:  # (a one-point grid: nothing to refine)
        sign = np.sign(value)  # a grid may run both ways (a temperature's lag or lead): refine on the value's side
        side = np.sort(sign * grid[np.isfinite(grid) & (np.sign(grid) == sign)])
        j = int(np.searchsorted(side, sign * value))
        ratio = side[1] / side[0] if len(side) > 1 else 2.0
        lo = side[j - 1] if j > 0 else sign * value  # the grid's first value is a bound (saturation: the readings' reach)
        hi = side[j + 1] if j + 1 < len(side) else (sign * value * ratio if cls.profile_open_end else sign * value)
        best = minimize_scalar(lambda x: -gain(sign * np.exp(x)), bounds=(np.log(lo), np.log(hi)), method="bounded",
                               options={"xatol": cls.profile_xatol})
        if -best.fun > best_gain:
            value, best_gain = float(sign * np.exp(best.x)), -best.fun
    if cls.profile_null is not None:  # the parameter pays for itself (BIC's price, in the residual's variance) or stays null
        null_gain = gain(cls.profile_null)
        if best_gain - null_gain < _bic_price(e):
            value, best_gain = cls.profile_null, null_gain
    return value, best_gain


SIGNAL_ITERATIONS = 20  # at most (a 1.5 % cubic about a hard iron of 4.4 fields: 10 steps to one noise variance)


def _at_own_signal(cls, data: _Data, fixed, state: dict, feats: np.ndarray, fit: dict, scale: float, sigma: float,
                   value=None, form: str = "hard_iron"):
    """A candidate non-linear in the signal (s³, s·s_easy) has its features computed from the base fit's
    estimate of the signal, s = b + W h. The base fit, without the effect, absorbs the effect's constant and
    linear parts into b and W (a cubic per axis about a hard iron b adds c b³ to the offset and 3c b² to the
    scale): the features are then evaluated at a shifted and scaled signal, and a shifted cubic holds a
    square the fit cannot represent (a 1.5 % cubic with a hard iron of 4.4× the field left 0.3–0.5 µT, taken
    for coloured noise). The fit that models the effect estimates b and W free of it: the features are
    recomputed at its signal (its readings less the modelled effect, calibrated onto the sphere) and
    refitted, until the residual sum of squares falls by less than one noise variance — the true signal is
    a fixed point, reproducing itself. A step that does not lower it is not taken (the guard against
    divergence). `scale` stays the first one, so the coefficients keep their units. Features exact only at
    the fit's own coefficients (cross_axis' 1/(1 + s_e/H_k)) get them (`ctx.coefficients`), and the iteration
    ends at a fit whose coefficients leave the range they describe (`holds`); a profiled
    parameter (saturation's limit, `value`) is profiled again at each fit, its features less the candidate's
    modelled part (linearised) taken as the residuals to explain. `form`: what the transducer sees (`_forms`).
    Returns the features, their fit and the profiled value."""
    everything = np.arange(len(data.m))
    field_error = lambda f, feats: _downstream(f, data, _features(state["features"] + [feats]), everything)[  # noqa: E731
        "field_error"]
    rss, error = float(np.sum(np.square(fit["residuals"]))), field_error(fit, feats)
    for _ in range(SIGNAL_ITERATIONS):
        ctx = _forms(cls, _context(data, fit, _features(state["features"] + [feats])))[form]
        ctx.scale = scale
        p = feats.shape[1]
        ctx.coefficients = np.asarray(fit["parameters"])[-p:]
        if not cls.holds(ctx, ctx.coefficients):
            break  # beyond what its exact features describe (refits there chased a degenerate fit without converging)
        if cls.profile_name:
            J = np.asarray(fit["jacobian"])
            Z = J[:, -p:]  # ∂r/∂c: the candidate's part of the fit, linearised
            rest = J[:, :-p][:, np.any(J[:, :-p] != 0, axis=0)]
            candidate, _, new, _ = _profile(cls, {form: ctx}, fit, np.linalg.qr(rest)[0],
                                            np.asarray(fit["residuals"]) - Z @ ctx.coefficients,
                                            data.reference is not None)
        else:
            candidate, new = value, cls.features(ctx)
        # from this fit: its coefficients belong with its offset and matrix
        here = Calibration(offset=fit["offset"], matrix=fit["matrix"], field_norm=state["start"].field_norm,
                           units=state["start"].units, model=state["start"].model)
        terms = np.asarray(fit["parameters"])[-(len(state["terms"]) + feats.shape[1]):]
        try:
            trial = _fit(data, here, fixed, _features(state["features"] + [new]), start_terms=terms)
        except _core.Error:
            break
        r, e = float(np.sum(np.square(trial["residuals"]))), field_error(trial, new)
        # Both must fall: features taken from the fit's own signal can also subtract part of the signal and
        # shrink what is left, which lowers the residuals in reading units (Sampson) while the corrected
        # field departs further from |h| = H (the QMC5883L recording: held-out gap → 0, field error 28 → 75).
        if not (r < rss and e <= error):
            break
        feats, fit, gain, rss, error, value = new, trial, rss - r, r, e, candidate
        if gain < sigma ** 2:
            break
    return feats, fit, value


def _exact_move(data: _Data, state: dict, model: str, cls, iterations: int = 3):
    """Model an accepted move of the reference (a misalignment's rotation, a time offset's delay) exactly.
    Its features are first order in the move, R(θ)r ≈ r + θ × r, which leaves ½ θ × (θ × r): a symmetric
    term that a later round would take for non_orthogonality (a delay leaves ½ δ² d²m/dt²). Instead the
    reference is moved by the fitted parameters and the features stay as corrections around that move (a
    few Gauss–Newton steps). Returns the data with the moved reference, the move applied to it and the
    block's slice of the terms (later rounds refit the block: its remainder is folded in at the end)."""
    fixed = MODELS[model][1]
    block = _block(state, len(state["features"]) - 1)
    lo = block.start
    original, total = data.reference, np.zeros(block.stop - block.start)
    for _ in range(iterations):
        total = cls.compose(total, state["terms"][block])
        data = replace(data, reference=cls.move_reference(original, data.t, total))
        state["features"][-1] = state["validated"][-1] = cls.features(_context(data, state["result"]))
        terms = state["terms"].copy()
        terms[lo:] = 0.0
        state["result"] = _fit(data, state["start"], fixed, _features(state["features"]), start_terms=terms)
        state["terms"] = np.asarray(state["result"]["parameters"])[12:]
    return data, total, block


def _richer_shape(data: _Data, model: str, state: dict, cls, row: dict) -> None:
    """An accepted effect whose shape was tested in a low-order form (a disturbance's time profile)
    gets the richer form with the lowest BIC on all the readings (`cls.shapes`): the acceptance stands
    on the low-order test; the richer shape only keeps later candidates from fitting what it left. Later
    held-out fits keep the low-order form (`state["validated"]`): a quintic fitted on a sliver of its
    box and extrapolated over a held-out quarter would make those tests meaningless."""
    fixed = MODELS[model][1]
    lo = len(state["terms"]) - row["_features"].shape[1]
    n = len(np.asarray(state["result"]["residuals"]))

    def bic(result, p):
        e = np.asarray(result["residuals"])
        return n * np.log(float(e @ e)) + p * np.log(n)

    best, best_bic = None, bic(state["result"], row["_features"].shape[1])
    for feats in cls.shapes(_context(data, state["result"]), row["_features"]):
        terms = np.concatenate([state["terms"][:lo], np.zeros(feats.shape[1])])
        try:
            fit = _fit(data, state["start"], fixed, _features(state["features"][:-1] + [feats]), start_terms=terms)
        except _core.Error:
            continue
        if bic(fit, feats.shape[1]) < best_bic:
            best, best_bic = (feats, fit), bic(fit, feats.shape[1])
    if best is None:
        return
    feats, fit = best
    row["_validated"] = row.get("_validated", row["_features"])
    row["_features"], row["_fit"], row["shape_terms"] = feats, fit, int(feats.shape[1])
    row["n_params"] = int(feats.shape[1])
    state["features"][-1] = feats
    state["result"] = fit
    state["terms"] = np.asarray(fit["parameters"])[12 if data.reference is not None else 9:]


def _with(state: dict, row: dict, vector: bool) -> dict:
    """A copy of `state` with the candidate of `row` added (its features and its fit)."""
    return dict(state, features=state["features"] + [row["_features"]], result=row["_fit"], train_fits={},
                signal_blocks=state["signal_blocks"] + [row["_signal_features"]],
                effects=state["effects"] + [row["effect"]],
                validated=state["validated"] + [row.get("_validated", row["_features"])],
                terms=np.asarray(row["_fit"]["parameters"])[12 if vector else 9:])


def _with_episode(data: _Data, model: str, state: dict, row: dict, i: int, columns: list) -> dict:
    """A copy of `state` with a further episode of the event whose block is the i-th (a magnet carried past again, a
    device switched on again), refitted: the episode's columns join that block after its validated ones, so the
    leading columns stay the validated form (`_validated_terms`; an episode is kept in its first-order form) and
    every block stays one effect's. `columns` (each episode's columns in the block) gets the new one's."""
    fixed = MODELS[model][1]
    full, low, new = state["features"][i], state["validated"][i], row["_features"]
    k, w = low.shape[1], new.shape[1]
    columns[:] = [np.where(c >= k, c + w, c) for c in columns] + [k + np.arange(w)]
    at = _block(state, i).start + k  # where the episode's terms go
    terms = np.asarray(row["_fit"]["parameters"])[-(len(state["terms"]) + w):]  # the row's: [blocks…, episode]
    terms = np.concatenate([terms[:at], terms[-w:], terms[at:-w]])
    feats = list(state["features"])
    feats[i] = np.concatenate([full[:, :k], new, full[:, k:]], axis=1)
    validated = list(state["validated"])
    validated[i] = np.concatenate([low, new], axis=1)
    fit = _fit(data, state["start"], fixed, _features(feats), start_terms=terms)
    return dict(state, features=feats, validated=validated, result=fit, train_fits={},
                terms=np.asarray(fit["parameters"])[-len(terms):])


# An accepted event's episodes: what each says of itself (its times, its evidence when it was added)
EPISODE_KEYS = ("on_s", "off_s", "closest_s", "passage_s", "frequency_hz", "rate_hz_per_s", "searched_times",
                "delta_bic", "lr_pvalue",
                "heldout_pvalue", "heldout_gap_before", "heldout_gap_after")


def _episode(row: dict) -> dict:
    return {k: row.get(k) for k in EPISODE_KEYS}


def _span(row: dict) -> tuple:
    """An event's time span: a box's edges (the recording's ends where None), a pass's closest approach ± 2 passage
    times (its main lobes)."""
    if row.get("closest_s") is not None:
        return row["closest_s"] - 2 * row["passage_s"], row["closest_s"] + 2 * row["passage_s"]
    return (-np.inf if row.get("on_s") is None else row["on_s"], np.inf if row.get("off_s") is None else row["off_s"])


def _overlaps(row: dict, event: dict) -> bool:
    """Whether a candidate episode overlaps in time an episode of the accepted event's row: it is then what the
    found episode's shape leaves (a magnet's course inside its own box, a pass's tail), not another occurrence —
    three magnets had come out as three nested boxes, each sized only in the sum."""
    if row.get("frequency_hz") is not None:  # a line: the same one within the recording's resolution
        return any(abs(row["frequency_hz"] - e["frequency_hz"]) < 2 * row["resolution_hz"]
                   for e in event.get("episodes") or [event])
    a, b = _span(row)
    return any(a < d and c < b for c, d in map(_span, event.get("episodes") or [event]))


def _block(state: dict, i: int) -> slice:
    """The terms of the i-th modelled effect (its slice of `state["terms"]`)."""
    lo = sum(f.shape[1] for f in state["features"][:i])
    return slice(lo, lo + state["features"][i].shape[1])


def _price(cls, row: dict, width: int) -> int:
    """What an accepted effect's block pays in BIC, in parameters: its terms, its profiled parameter (a lag, a time
    constant) and every time its search placed (each episode's edges)."""
    return (width + (1 if cls.profile_name and cls.profile_name in row else 0)
            + sum(cls.searched_times(e) for e in row.get("episodes") or [row]))


def _without(data: _Data, model: str, state: dict, i: int) -> dict:
    """A copy of `state` with the i-th modelled effect taken out, refitted."""
    block = _block(state, i)
    rest = state["features"][:i] + state["features"][i + 1:]
    terms = np.delete(state["terms"], np.arange(block.start, block.stop))
    fit = _fit(data, state["start"], MODELS[model][1], _features(rest) if rest else None,
               start_terms=terms if rest else None)
    drop = lambda blocks: blocks[:i] + blocks[i + 1:]  # noqa: E731
    return dict(state, features=rest, signal_blocks=drop(state["signal_blocks"]), validated=drop(state["validated"]),
                effects=drop(state["effects"]), result=fit, train_fits={},
                terms=np.asarray(fit["parameters"])[12 if MODELS[model][0] else 9:])


def _reprofile(data: _Data, model: str, state: dict, modelled: list, last_rows: dict, names: dict, sigma: float,
               n_candidates: int) -> list:
    """Place again what each earlier effect's search placed (a step's edges, a drift's time constant, a
    temperature's lag) with the effects accepted after it modelled: the search placed them against residuals that
    still held those. A drift taken as a step's slope had put the step 13 s late, and a magnet was then invented
    to fill the hole; a current switched on at the end had made a step that stays "come back". Each earlier
    effect is taken out, searched again against the rest, and put back where it was when the new placement gains
    more in BIC than a parameter's price (a time constant moved by 0.004 s, an edge by 0.4 s away from the truth,
    had been "placed again" for gains of 0.0004 and 1); then every effect again while one moved (at most three
    turns). An event with several episodes, a richer time profile or a move of the reference stays as it is, and so does one that is not significant against
    the rest (`_prune` weighs it). An effect of a family (`KIN`: the cubic, saturation, its knee) is weighed against
    its kin too. Returns the names placed again (their rows replaced, the first placement kept in `replaced`)."""
    changed = []
    for turn in range(3):  # until nothing moves (a step placed again can move the drift placed before it)
        moved = False
        for i in range(len(modelled)):
            if turn == 0 and i == len(modelled) - 1 and not moved:
                continue  # (the effect just accepted was searched against the rest as it is)
            if _placed_again(data, model, state, modelled, i, last_rows, names, sigma, n_candidates, changed):
                moved = True
                changed.append(modelled[i])  # (its kin, when that took its place)
        if not moved:
            break
    return list(dict.fromkeys(changed))


PLACEMENT_KEYS = ("on_s", "off_s", "closest_s", "passage_s", "frequency_hz", "rate_hz_per_s", "offset_kind")


def _placement(cls, row: dict) -> tuple:
    """What a search placed in a row (an event's times, a line's frequency, the profiled parameter, the offset's
    form), to 6 significant digits."""
    keys = PLACEMENT_KEYS + ((cls.profile_name,) if cls.profile_name else ())
    row = dict(row)
    if row.get("on_s") is None and row.get("off_s") is not None and row.get("closest_s") is None:
        row.update(on_s=row["off_s"], off_s=None)  # a box from the start is the step at its end (the offset holds it)
    return tuple((k, v if not isinstance(v, float) else float(f"{v:.6g}")) for k in keys if (v := row.get(k)) is not None)


# Effects of one family, each the other's stand-in when found while another effect was unmodelled: a tanh
# saturation found beside an unmodelled drift came out as the per-axis cubic ([-2.37, -2.35, -2.38] %: three
# coefficients for saturation's one).
KIN = {"nonlinearity_cubic": ("saturation", "saturation_knee"), "saturation": ("nonlinearity_cubic", "saturation_knee"),
       "saturation_knee": ("nonlinearity_cubic", "saturation")}


def _placed_again(data: _Data, model: str, state: dict, modelled: list, i: int, last_rows: dict, names: dict,
                  sigma: float, n_candidates: int, changed: list) -> bool:
    """`_reprofile`'s step for the i-th modelled effect: whether a new placement, or one of its kin (`KIN`) not yet
    modelled, replaced it (`state`, `modelled` and `last_rows` updated)."""
    vector, fixed = MODELS[model]
    lo = 12 if vector else 9
    name = modelled[i]
    cls, old = names[name], last_rows[name]
    if cls.moves_reference or "episodes" in old or "shape_terms" in old:
        return False
    placeable = bool(cls.profile_name or cls.regime == "events")
    options = ([cls] if placeable else []) + [names[k] for k in KIN.get(name, ()) if k in names and k not in modelled]
    if not options:
        return False
    e0 = np.asarray(state["result"]["residuals"])
    n, best = len(e0), None
    try:
        rest = _without(data, model, state, i)
    except _core.Error:
        return False
    for option in options:
        try:
            row = _evaluate(option, data, model, rest, sigma, n_candidates)
            if "_fit" not in row or not row["significant"]:  # (one that no longer stands is for _prune to weigh)
                continue
            feats = rest["features"][:i] + [row["_features"]] + rest["features"][i:]
            at, width = _block(state, i).start, row["_features"].shape[1]
            new_terms = np.asarray(row["_fit"]["parameters"])[lo:]  # [the rest's…, its own]: its own go back to i
            fit = _fit(data, state["start"], fixed, _features(feats),
                       start_terms=np.concatenate([new_terms[:at], new_terms[-width:], new_terms[at:-width]]))
        except _core.Error:
            continue
        e1 = np.asarray(fit["residuals"])
        gain = (n * np.log(float(e0 @ e0) / float(e1 @ e1))
                - (_price(option, row, width) - _price(cls, old, state["features"][i].shape[1])) * np.log(n))
        moved = option is not cls or _placement(cls, row) != _placement(cls, old)  # (a refit's rounding: not)
        # a new placement pays as a parameter would (a search's own scatter moves it a little); a kin, by BIC
        if gain > (np.log(n) if option is cls else 0.0) and moved and (best is None or gain > best[0]):
            best = (gain, option, row, feats, fit)
    if best is None:
        return False
    gain, option, row, feats, fit = best
    first = old.get("replaced") or {k: old.get(k) for k in PLACEMENT_KEYS + (cls.profile_name,) if k and k in old}
    # (the effects found after it, or for the last one found, those placed again before it)
    after = modelled[i + 1:] or [a for a in changed if a != name]
    row["replaced"] = dict(first, modelled=list(dict.fromkeys(first.get("modelled", []) + after)),
                           delta_bic_gain=float(gain) + first.get("delta_bic_gain", 0.0))
    row["step"] = old["step"]
    if option is cls:
        for key in ("_rivals", "confounded_with", "found_with"):
            if key in old:
                row[key] = old[key]
    else:  # its kin takes its place: the row it leaves says so
        row["replaced"]["effect"] = row["replaced"].get("effect", name)
        old.pop("step")
        old.update(significant=False, unmet=list(old.get("unmet", [])) + ["replaced"],
                   note=f"accepted in round {row['step']}, but with {', '.join(row['replaced']['modelled'])} modelled "
                        f"{option.name} fits better in its place (ΔBIC {-gain:+.1f}): replaced")
        modelled[i] = option.name
    put = lambda blocks, block: blocks[:i] + [block] + blocks[i:]  # noqa: E731
    state.update(features=feats, validated=put(rest["validated"], row.get("_validated", row["_features"])),
                 signal_blocks=put(rest["signal_blocks"], row["_signal_features"]),
                 effects=put(rest["effects"], option.name), result=fit, train_fits={},
                 terms=np.asarray(fit["parameters"])[lo:])
    last_rows[option.name] = row
    return True


def _prune(data: _Data, model: str, state: dict, accepted: list, last_rows: dict, names: dict) -> list:
    """Effects accepted early that no longer pay BIC's price once the later ones are modelled (a settling offset
    taken first for what an offset step and a passing magnet then explain): each is refitted out, the one
    whose removal BIC favours most first, until every one left pays. `state` is updated to the model without
    them; returns their names. A move of the reference stays (it has moved the reference itself)."""
    systematic = [a for a in accepted if a not in NOISE_CANDIDATES]
    dropped = []
    while len(systematic) > 1:
        e1 = np.asarray(state["result"]["residuals"])
        n, rss = len(e1), float(e1 @ e1)
        worst = None
        for i, name in enumerate(systematic):
            cls = names[name]
            if cls.moves_reference:
                continue
            try:
                rest = _without(data, model, state, i)
            except _core.Error:
                continue
            e0 = np.asarray(rest["result"]["residuals"])
            lr = max(0.0, n * np.log(float(e0 @ e0) / rss))
            delta_bic = -lr + _price(cls, last_rows[name], state["features"][i].shape[1]) * np.log(n)
            if delta_bic > 0 and (worst is None or delta_bic > worst[1]):
                worst = (i, delta_bic, rest)
        if worst is None:
            break
        i, delta_bic, rest = worst
        name = systematic.pop(i)
        last_rows[name]["pruned_delta_bic"] = float(delta_bic)
        dropped.append(name)
        state.update(rest)
    return dropped


def _hopeful(rows: list, state: dict, names: dict, n_candidates: int) -> list:
    """The round's candidates that passed every in-sample test but not the held-out one, strongest (ΔBIC) first."""
    return sorted([r for r in rows if "_fit" in r and not r["significant"] and r["delta_bic"] < 0
                   and r["lr_pvalue"] * n_candidates < state["alpha"] and not names[r["effect"]].moves_reference
                   and not refused(r)],
                  key=lambda r: r["delta_bic"])


def _plain_differs(row: dict, cls) -> bool:
    """Whether a row of a law in time was profiled (a drift's time constant), so its plain form is another."""
    return bool(getattr(cls, "law_in_time", False) and row.get(cls.profile_name) is not None)


def _plain(row: dict, cls, data: _Data, model: str, state: dict) -> dict | None:
    """A law in time's `row` in its plain form (a drift linear: its profiled parameter at `profile_null`), fitted
    beside the effects of `state`; None when the row has no profile or the fit fails."""
    if not _plain_differs(row, cls):
        return None
    plain = cls.features_at(_context(data, state["result"], _features(state["features"])), cls.profile_null)
    try:
        fit = _fit(data, state["start"], MODELS[model][1], _features(state["features"] + [plain]),
                   start_terms=np.concatenate([state["terms"], np.zeros(plain.shape[1])]))
    except _core.Error:
        return None
    kept = {k: v for k, v in row.items() if k not in (cls.profile_name, "_validated")}
    return kept | {"_features": plain, "_fit": fit}


def _with_the_rest_placed_again(data: _Data, model: str, state: dict, rows: list, pool: list, accepted: list,
                                last_rows: dict, sigma: float, n_candidates: int):
    """The strongest candidate that failed only its held-out test, judged again once the effects found are placed
    again with it modelled: a step found first beside a drift against it was a box that "came back", which took
    part of the drift, and the drift extrapolated from the rest then missed the held-out quarter. The candidate is
    added on trial (as found, then in its plain form: a drift linear), the effects found are placed again
    (`_reprofile`), and the candidate is searched and judged against them. Returns (the state without it, the
    effects' order, their rows, its row) when it now passes, else None; nothing is changed."""
    vector = MODELS[model][0]
    names = {c.name: c for c in pool}
    hopeful = _hopeful(rows, state, names, n_candidates)
    if not hopeful or names[hopeful[0]["effect"]].regime == "events" and hopeful[0]["effect"] in accepted:
        return None
    first, cls = hopeful[0], names[hopeful[0]["effect"]]
    # and in its plain form: a linear drift beside a box that took its middle had profiled as a settling one, and
    # the box, placed again beside that, stayed where it was
    for row in [first] + [r for r in [_plain(first, cls, data, model, state)] if r is not None]:
        trial, order = _with(state, row, vector), accepted + [row["effect"]]
        if hasattr(cls, "shapes"):
            _richer_shape(data, model, trial, cls, dict(row))
        trial_rows = {k: dict(v) for k, v in last_rows.items()}  # (a kin's swap changes the rows it leaves)
        trial_rows[row["effect"]] = dict(row, step=len(order))
        try:
            if not _reprofile(data, model, trial, order, trial_rows, names, sigma, n_candidates) \
                    or row["effect"] not in order:
                continue
            i = order.index(row["effect"])
            rest = _without(data, model, trial, i)
            again = _evaluate(cls, data, model, rest, sigma, n_candidates)
        except _core.Error:
            continue
        if again["significant"]:
            trial_rows.pop(row["effect"])
            return rest, order[:i] + order[i + 1:], trial_rows, again
    return None


def _together(data: _Data, model: str, state: dict, rows: list, pool: list, accepted: list, sigma: float,
              n_candidates: int):
    """Two large effects at once (a magnet passing while an offset jumps): each one's held-out test can fail
    while the other is unmodelled (its residuals are long and correlated, leaving few blocks to test on).
    When no candidate is significant, the strongest one that passed every in-sample test is added on
    trial; if a second candidate is then significant, the first is searched and judged again with only
    the second modelled. The second is the strongest other effect or, for an event, another episode of it (a
    magnet carried past twice), tried in order of ΔBIC. Both are kept when both pass; returns their rows in the
    order to add them (each `found_with` the other, or both `episodes_together`), else None."""
    vector = MODELS[model][0]
    names = {c.name: c for c in pool}
    hopeful = _hopeful(rows, state, names, n_candidates)
    if not hopeful:
        return None
    first = dict(hopeful[0])
    trial = _with(state, first, vector)
    if hasattr(names[first["effect"]], "shapes"):
        _richer_shape(data, model, trial, names[first["effect"]], first)
    others = [c for c in pool if c.name not in NOISE_CANDIDATES and c.name not in accepted
              and c.name != first["effect"] and not c.moves_reference]
    winners = sorted([r for r in (_evaluate(c, data, model, trial, sigma, n_candidates) for c in others)
                      if r["significant"]], key=lambda r: r["delta_bic"])[:1]
    if names[first["effect"]].regime == "events":  # or the same event twice (a magnet carried past and back)
        episode = _evaluate(names[first["effect"]], data, model, trial, sigma, n_candidates)
        if episode["significant"] and not _overlaps(episode, first):
            winners = sorted(winners + [episode], key=lambda r: r["delta_bic"])
    for second in winners:  # the strongest other effect, or another episode: the first pair that holds
        pair = _pair(data, model, state, names, first, dict(second, _rivals=[]), sigma, n_candidates)
        if pair:
            return pair
    return None


def _pair(data: _Data, model: str, state: dict, names: dict, first: dict, second: dict, sigma: float,
          n_candidates: int):
    """`_together`'s second candidate, found with the first modelled, refitted alone; the first searched again
    beside it. Both rows when the first is then significant, else None."""
    vector, fixed = MODELS[model]
    feats = second["_features"]
    try:
        second["_fit"] = _fit(data, state["start"], fixed, _features(state["features"] + [feats]),
                              start_terms=np.concatenate([state["terms"], np.zeros(feats.shape[1])]))
    except _core.Error:
        return None
    given = _with(state, second, vector)
    if hasattr(names[second["effect"]], "shapes"):
        _richer_shape(data, model, given, names[second["effect"]], second)
    again = _evaluate(names[first["effect"]], data, model, given, sigma, n_candidates)
    if not again["significant"] or _cancelling(again["_fit"], state["features"] + [feats, again["_features"]], vector,
                                               new=2) is not None:
        return None
    again["_rivals"] = []
    if again["effect"] == second["effect"]:  # two episodes of one event: `accept` makes them one block
        second["episodes_together"] = again["episodes_together"] = True
    else:
        second["found_with"], again["found_with"] = again["effect"], second["effect"]
    return second, again


CANCELLING = 3.0  # effects of one fit whose changes are each this many times their sum: they cancel


def _cancelling(fit: dict, blocks: list, vector: bool, new: int | None = None) -> int | None:
    """Which block cancels a new one: of the fit's last blocks (`blocks`, in order; the last `new` of them just added,
    default all), the index of the largest other block when a new one and it each change the residuals by CANCELLING
    times as much as every block does together — the data determine their difference, not each —, else None. The
    changes are taken apart from what the base model's offset and matrix hold: a non-linearity about a hard iron of
    several fields is mostly affine, and the base takes that part whatever the blocks do. (A blind check's warm-up
    that only rose made temp_offset and offset_drift "found together", each ~30 % of the field and ten times a truth
    of 1e-3 G/°C; a quadratic's x term of 0.7 % grew to 31 %, a cross-axis error of 22 % of the field cancelling it,
    the residuals at 0.99 σ.)"""
    parameters, hi = np.asarray(fit["parameters"]), len(fit["parameters"])
    J = np.asarray(fit["jacobian"])[:, :12 if vector else 9]
    Q = np.linalg.qr(J[:, np.any(J != 0, axis=0)])[0]
    changes = []
    for feats in reversed(blocks):
        c = _project(fit, feats, vector) @ parameters[hi - feats.shape[1]:hi]
        changes.append(c - Q @ (Q.T @ c))
        hi -= feats.shape[1]
    changes.reverse()
    line = CANCELLING * float(np.linalg.norm(sum(changes)))
    size = [float(np.linalg.norm(c)) for c in changes]
    new = len(blocks) if new is None else new
    for i in range(len(blocks) - new, len(blocks)):
        others = [j for j in range(len(blocks)) if j != i]
        other = max(others, key=lambda j: size[j]) if others else None
        if other is not None and size[i] > line and size[other] > line:
            return other
    return None


_CANDIDATE_CLASSES = {c.name: c for c in CANDIDATES}  # (once: _made_unphysical runs for every candidate judged)


def _made_unphysical(fit: dict, state: dict, vector: bool) -> tuple | None:
    """An effect found before whose terms, fitted again beside a candidate (`fit`), turn unphysical by its own rule
    (its class's `unphysical`) where in the model without the candidate they were not: (its name, the reason), else
    None. (A cubic injected at 8.5 % into a real hand-held recording: a quadratic found, then a cross-axis error of
    79 % of the field beside it, which took the quadratic on x to −67 %.)"""
    lo = 12 if vector else 9
    now, was = ([np.asarray(f[k])[lo:] for k in ("parameters", "standard_errors")] for f in (fit, state["result"]))
    for i, name in enumerate(state["effects"]):
        cls, block = _CANDIDATE_CLASSES[name], _block(state, i)
        reason = cls.unphysical(now[0][block], now[1][block], vector=vector, period=state["period"])
        if reason and not cls.unphysical(was[0][block], was[1][block], vector=vector, period=state["period"]):
            return name, reason
    return None


def _second_shape(row: dict, cls, accepted: list) -> None:
    """A sensor has one compression curve: a second shape of it (`saturation` beside `saturation_knee`, or the other
    way) beside one found is refused as unphysical — it shapes what the first one's form leaves (a review's knee about
    a hard iron of three fields came out as a knee, a 13 % tanh and a cubic)."""
    first = next((a.name for a in accepted if issubclass(a, _Compression)), None)
    if first and issubclass(cls, _Compression) and not refused(row):
        reason = f"a second shape of the compression {first} describes: one sensor has one compression curve"
        row.update(unphysical=reason, significant=False, note=f"not accepted as {cls.name}: {reason}")


def _law_inside_event(event: dict, other: dict, logging_noise: dict | None = None) -> bool:
    """Whether `event` and `other` take out the same departure — the changes their fits make to the residuals agree
    to a cosine of SAME_DEPARTURE — with `other` at least CONFOUND_SHARE of the event's ΔBIC: `event` a free course in
    time (a magnet passing, a step) and `other` driven by a logged temperature or current, or a drift's law in time —
    the course fits whatever the logged quantity drives, or the law, and noise besides; or `event` a drift's law and
    `other` driven by a logged quantity, while the law's lead is within what the logging's noise and resolution
    (`logging_noise`: their share of each logged quantity's variance) could cost it, LOGGING_MARGIN over — a warm-up
    the temperature drives, whose thermometer's 0.02 °C of noise left it behind the smooth law (a blind check's 0.5 µT
    over 10 °C named offset_drift alone), where an S-curve warm-up logged exactly is the data's choice (229 ahead)."""
    if "_explained" not in event or "_explained" not in other:
        return False
    if event["regime"] == "events":
        if not (other["regime"] in LOGGED_REGIMES or other.get("_law_in_time")):
            return False
    else:
        if not (event.get("_law_in_time") and other["regime"] in LOGGED_REGIMES):
            return False
        n = other["_explained"].size  # (lr = n ln(|e|²/|e1|²): what it explains, in its residuals' variances)
        explained = n * float(np.expm1(min(other.get("lr", 0.0) / n, 700.0)))
        allowance = LOGGING_MARGIN * explained * (logging_noise or {}).get(other["regime"], 0.0)
        if not other["delta_bic"] - event["delta_bic"] <= CONFOUND_BIC + allowance:
            return False
    if not other["delta_bic"] <= CONFOUND_SHARE * event["delta_bic"]:
        return False
    a, b = event["_explained"], other["_explained"]
    norms = float(np.linalg.norm(a) * np.linalg.norm(b))
    return norms > 0 and float(a @ b) / norms >= SAME_DEPARTURE


def _logging_noise(x: np.ndarray | None, t: np.ndarray) -> float:
    """The share of a logged quantity's variance that its logging's noise or resolution takes: the larger of its
    sample-to-sample scatter (robust, in time order) and its smallest step's rounding (q²/12), over its variance."""
    if x is None or not np.ptp(x) > 0:
        return 0.0
    steps = np.diff(np.asarray(x, float)[np.argsort(t, kind="stable")])
    scatter = 1.4826 * float(np.median(np.abs(steps - np.median(steps)))) / np.sqrt(2.0)
    moved = np.abs(steps[steps != 0])
    resolution = float(moved.min()) if moved.size else 0.0
    return max(scatter ** 2, resolution ** 2 / 12.0) / float(np.var(x))


def _rivals(winner: dict, rows: list, key: str = "significant", logging_noise: dict | None = None) -> list:
    """Candidates of the same round that explain the data about as well as the winner: significant themselves
    (`key` of the row, True) with ΔBIC within CONFOUND_BIC of it either way; or, beside an event, a candidate
    driven by a logged quantity or a drift's law that takes out the same departure (`_law_inside_event`), strong
    in sample (its own held-out quarter, the hottest or the last, is harder to predict than an event's interleaved
    blocks). Whether they are the same explanation is settled in the next round (`_collapsed`)."""
    out = []
    for r in rows:
        if r is winner or not r["delta_bic"] < 0 or refused(r):
            continue
        close = r.get(key) and abs(r["delta_bic"] - winner["delta_bic"]) < CONFOUND_BIC
        same = not {"in_sample", "bic"} & set(r.get("unmet", [])) and _law_inside_event(winner, r, logging_noise)
        if not (close or same):
            continue
        overlap = np.linalg.svd(winner["_signature"].T @ r["_signature"], compute_uv=False)
        if overlap.size and overlap.min() >= NESTED and winner["_signature"].shape[1] != r["_signature"].shape[1]:
            continue  # one is a special case of the other: the next round tests the extra terms themselves
        out.append({"effect": r["effect"], "regime": r["regime"],
                    "delta_bic_difference": float(r["delta_bic"] - winner["delta_bic"]),
                    "signature_correlation": float(overlap[0]) if overlap.size else 0.0,
                    "same_departure": bool(same)})
    return out


def _collapsed(data: _Data, winner: dict, rows: list) -> list:
    """The winner's rivals whose evidence collapsed once the winner was modelled — in the round straight
    after it: absorbed, or ΔBIC ≥ 0. They explained the same thing; this recording cannot tell them
    apart. (A rival that still improves the fit is a second effect, whatever later rounds do.)"""
    now = {r["effect"]: r for r in rows}
    out = []
    for rival in winner.get("_rivals", []):
        row = now.get(rival["effect"])
        # (one that took out the same departure as an event has collapsed when it is no longer significant: what it
        # still takes is the course's noise it would fit too)
        gone = row is not None and (row.get("absorbed") or row["delta_bic"] >= 0
                                    or (rival.get("same_departure") and not row.get("significant")))
        if not gone:
            continue
        rival = dict(rival)
        if {winner["regime"], rival["regime"]} == {"temperature", "time"} and getattr(data, "temp", None) is not None \
                and np.ptp(data.temp) > 0:
            rival["temperature_time_correlation"] = float(np.corrcoef(data.temp, data.t)[0, 1])
        out.append(rival)
    return out


def _block_correlation(result: dict, lo: int, size: int) -> np.ndarray:
    """The correlation between a block's parameters (lo … lo + size of the fit's), from the fit's Jacobian: a
    magnitude determines an eddy current's differences between the axes, not their common part, so each axis's own
    error (a blind check: 0.2–0.8 ms quoted for lags found within 0.03 ms) holds the common part's."""
    J = np.asarray(result.get("jacobian", []), dtype=float)
    if J.ndim != 2 or J.shape[1] < lo + size:
        return np.eye(size)
    C = np.linalg.pinv(J.T @ J)[lo:lo + size, lo:lo + size]
    d = np.sqrt(np.clip(np.diag(C), 1e-300, None))
    return np.clip(C / np.outer(d, d), -1.0, 1.0)


def _validated_terms(state: dict) -> np.ndarray:
    """Start values for the held-out fits' terms: each accepted block's own, its leading ones where the
    block was fitted in a richer form (the low-order terms lead: Legendre P0–P2 of the same box, a pass's
    first-order profiles)."""
    out, lo = [], 0
    for full, low in zip(state["features"], state["validated"]):
        out.append(state["terms"][lo:lo + low.shape[1]])
        lo += full.shape[1]
    return np.concatenate(out) if out else np.zeros(0)


def _held_regime(data, state, regime, block=None):
    """The held-out regime and readings of a candidate of `regime` (`_heldout`)."""
    held = _heldout(regime, data, state["directions"], block)
    side = {"temperature": data.temp, "current": data.current}.get(regime)
    if side is not None and np.ptp(side[~held]) < 0.5 * np.ptp(side):
        # A regressor with few values (motors off or at one throttle): its top quarter is all the fit would
        # learn the effect from. Interleaved blocks of time hold out some of every level instead.
        regime = "events"
        held = _heldout(regime, data, state["directions"])
    return regime, held


def _in_sample_length(fit: dict, data: _Data, rows: np.ndarray) -> int:
    """The correlation length of a fit's residuals on the readings `rows` (mask), in time order (per reading: the
    mean of its residuals), in residuals: readings × residuals per reading (3 against reference vectors)."""
    e = np.asarray(fit["residuals"])
    per_reading = len(e) // int(rows.sum())
    e = e.reshape(-1, per_reading).mean(axis=1)
    return per_reading * _correlation_length(e[np.argsort(data.t[rows], kind="stable")])


def _noise_shown(fit: dict, data: _Data, rows: np.ndarray, sigma: float) -> float:
    """The noise a fit's residuals on `rows` show, in σ: their RMS when they are correlated in time (Ljung–Box
    p < 0.01), else 1. σ is the white part (third differences); a correlated noise's slow part (an AR(1) of φ 0.9,
    a 1/f: a blind check's level drives, σ 0.5 of the noise's RMS) adds as much to each held-out reading's error as
    to the residuals in sample. The fit with the candidate: its residuals hold no misses of it, which a right model
    goes below (the base's residuals held them, and a right cubic on a tumble of poor coverage was refused); white
    residuals (an effect modelled, white noise) leave the floor at σ's, whatever their RMS's sampling error."""
    e = np.asarray(fit["residuals"])
    per_reading = len(e) // int(rows.sum())
    series = e.reshape(-1, per_reading).mean(axis=1)[np.argsort(data.t[rows], kind="stable")]
    white = _whiteness(series)
    if not white or white[0]["pvalue"] >= 0.01:
        return 1.0
    return float(np.sqrt(np.mean(e ** 2)) / sigma)


def _held_for(data, state, feats, regime):
    """The held-out regime, readings and short event's block (`_event_block`, None otherwise) of a candidate of
    `regime` with features `feats`."""
    block = _event_block(feats, data, state["correlation"]) if regime == "events" else None
    return _held_regime(data, state, regime, block) + (block,)


def _validate(data, model, state, feats, regime, sigma, others=None, placed=None, unplaced=None) -> dict:
    """Fit with and without the candidate on all but a held-out regime; judge on the held-out part but `unplaced`
    (a mask: readings whose side of an event's edge the rest leaves open). `placed`: an event as placed on every
    reading, whose span sets its held-out blocks (default `feats`). `others`: the
    accepted effects' terms as the fit with the candidate on every reading has them, the start of the fit with it
    on the rest. A term the rest does not determine stays at its start (a step inside the held-out quarter), and
    there the fit without the candidate has it from the fit without, the fit with from the fit with: from the fit
    without, a step had kept the part of a drift it took while the drift was unmodelled, the drift's extrapolation
    added that part again, and the drift failed its held-out test."""
    vector, fixed = MODELS[model]
    regime, held, block = _held_for(data, state, feats if placed is None else placed, regime)
    key = (regime, block)
    terms = _validated_terms(state)
    base_feats = _features(state["validated"])
    if key not in state["train_fits"]:  # the fit without it and its held-out residuals: once per held-out part
        before = _fit(data, state["start"], fixed, base_feats, ~held, start_terms=terms)
        state["train_fits"][key] = (before, _residuals(before, data, base_feats, held),
                                    _downstream(before, data, base_feats, held), {})
    before, e0, downstream_before, floors = state["train_fits"][key]
    if sigma not in floors:
        floors[sigma] = _noise_floor(before, data, base_feats, held, sigma)
    all_feats = _features(state["validated"] + [feats])
    after = _fit(data, state["start"], fixed, all_feats, ~held,
                 start_terms=np.concatenate([terms if others is None else _validated_terms(dict(state, terms=others)),
                                             np.zeros(feats.shape[1])]))
    judged = held if unplaced is None or not unplaced[held].any() else held & ~unplaced
    confirms_nothing = not judged.any()
    if confirms_nothing:  # an event's edges may lie in every held-out block: they confirm nothing (judged unchanged)
        judged, after, all_feats = held, before, base_feats
    floor = floors[sigma]
    if judged is not held:  # (the field errors too on the readings judged: the unplaced ones' say nothing)
        e0 = _residuals(before, data, base_feats, judged)
        downstream_before = _downstream(before, data, base_feats, judged)
        floor = _noise_floor(before, data, base_feats, judged, sigma)
    e1 = _residuals(after, data, all_feats, judged)
    # A short event's gaps where it acts: a magnet's second-long pass in ten minutes takes most of the departure
    # within its reach, and next to nothing of the whole held-out part's, where the noise alone had left a gap of 0
    # before and after.
    within = _judged(feats, judged, block)
    g0, g1 = (_residuals(fit, data, f, within) for fit, f in ((before, base_feats), (after, all_feats)))
    return {"heldout": regime, "heldout_n": int(held.sum()), "heldout_block": block,
            "heldout_n_unplaced": int(held.sum() if confirms_nothing else (held & ~judged).sum()),
            "heldout_n_judged": int(within.sum()),
            "heldout_noise_floor": floor,
            "heldout_noise_shown": _noise_shown(after, data, ~held, sigma),
            "heldout_gap_before": _gap(g0, sigma), "heldout_gap_after": _gap(g1, sigma),
            "heldout_rms_before": float(np.sqrt(np.mean(g0 ** 2))),
            "heldout_rms_after": float(np.sqrt(np.mean(g1 ** 2))),
            "heldout_pvalue": _event_pvalue(e0, e1, (g0, g1) if block is not None else None,
                                            _in_sample_length(after, data, ~held)),
            **{f"{k}_before": v for k, v in downstream_before.items()},
            **{f"{k}_after": v for k, v in _downstream(after, data, all_feats, judged).items()}}


def _ar_fit(series: np.ndarray, max_order: int):
    """AR(p) of a series by least squares, p by AIC up to `max_order`: (p, coefficients, RSS per order,
    the predicted part of the series, the lag matrix). One QR of the lag matrix gives every order's RSS
    (nested regressions: RSS_p = |y|² − Σ_{k≤p} (qₖᵀy)²)."""
    n = len(series)
    y = series[max_order:]
    lagged = np.column_stack([series[max_order - k:n - k] for k in range(1, max_order + 1)])
    Q, R = np.linalg.qr(lagged)
    qy = Q.T @ y
    rss = np.maximum(float(y @ y) - np.concatenate([[0.0], np.cumsum(qy ** 2)]), 1e-300)
    aic = len(y) * np.log(rss / len(y)) + 2 * np.arange(max_order + 1)
    order = int(np.argmin(aic))
    coefs = np.linalg.solve(R[:order, :order], qy[:order]) if order else np.zeros(0)
    return order, coefs, rss.tolist(), y, lagged


def _whitened_lr(e0: np.ndarray, e1: np.ndarray, data: _Data, max_order: int = 30, wander=None) -> float:
    """Likelihood ratio of the base (residuals e0) and augmented (e1) fits under the augmented fit's
    noise model: an AR(p) of e1 in time order whitens both. With white residuals this is n·log(RSS0/RSS1);
    with correlated noise, a candidate that only follows its slow wander gains little once whitened
    (the plain ratio assumes independent residuals and would call such a fit significant). With `wander`
    (`_wander_basis`), also under a wandering offset (`_wander_lr`): the smaller of the two."""
    if wander is not None:
        return min(_whitened_lr(e0, e1, data, max_order), _wander_lr(e0, e1, wander))
    order = np.argsort(data.t, kind="stable")
    k = 3 if data.reference is not None else 1
    a0, a1 = e0.reshape(-1, k)[order], e1.reshape(-1, k)[order]
    n = len(a1)
    if n < 10 * max_order:
        return max(0.0, e0.size * np.log(float(e0 @ e0) / float(e1 @ e1)))
    p, c, *_ = _ar_fit(a1.mean(axis=1), max_order)
    if p:
        from scipy.signal import lfilter

        whiten = np.concatenate([[1.0], -c])
        a0, a1 = lfilter(whiten, [1.0], a0, axis=0)[p:], lfilter(whiten, [1.0], a1, axis=0)[p:]
    return max(0.0, a1.size * np.log(float(np.sum(a0 ** 2)) / float(np.sum(a1 ** 2))))


def _round_wander(data: _Data, state: dict):
    """The wandering offset's design (`_wander_basis`) for the round's base fit, `state["result"]`: made once per base."""
    if state.get("_wander", (None,))[0] is not state["result"]:
        state["_wander"] = (state["result"], _wander_basis(data, state["result"]))
    return state["_wander"][1]


# The sensor's offset wandering slowly in time (1/f noise of the offset, a part warming): each axis's offset a random
# walk through WANDER_KNOTS times (piecewise linear between them, the event search's own grid), its step variance
# chosen by maximum likelihood. The AR noise model sees only the magnitude's series, in which the turning sensor
# mixes the three axes' wander: an offset step fitted its slow excursions in 5 of 8 simulations with 1/f noise as
# large as the white noise (whitened LR 49 for 3 terms, 599 boxes tried). (A knot per 100 readings protected
# 20 000 readings better, a step in 1 of 6 such simulations against 3, but changed the QMC5883L recording's
# diagnosis, a cubic added: not taken without knowing why.)
WANDER_KNOTS = 32


def _wander_basis(data: _Data, result: dict):
    """The wandering offset's design in the residuals of `result`: (H, S, s, V). H (sparse) is each residual's offset
    Jacobian times the hat functions of its time, S the knots' values from the walk's steps (the offset at knot j
    the sum of the steps before it; its level at the first knot is the base's offset): Z = H S is the residuals'
    change for unit steps, Z'Z = V diag(s) V'. Z itself is dense (every later knot depends on a step), H has six
    entries per reading. (Axes weighted by their noise, `_fit`: a walk as strong on each in its weighted units.)"""
    from scipy import sparse

    J = np.asarray(result["jacobian"])[:, :3]  # θ = [b, …]: the offset's columns
    t = np.asarray(data.t, dtype=float)
    per_reading, k = len(J) // len(t), WANDER_KNOTS
    knots = np.quantile(t, np.linspace(0, 1, k))
    knots = knots + np.arange(k) * 1e-9 * max(float(np.ptp(t)), 1.0)  # (distinct knots where times repeat)
    i = np.clip(np.searchsorted(knots, t, side="right") - 1, 0, k - 2)
    w = np.clip((t - knots[i]) / (knots[i + 1] - knots[i]), 0.0, 1.0)
    rows = np.repeat(np.arange(len(J)), 6)
    reading = np.arange(len(J)) // per_reading
    cols = (np.arange(3)[None, :, None] * k + np.stack([i, i + 1], axis=1)[reading][:, None, :]).reshape(-1)
    vals = (J[:, :, None] * np.stack([1.0 - w, w], axis=1)[reading][:, None, :]).reshape(-1)
    H = sparse.csr_matrix((vals, (rows, cols)), shape=(len(J), 3 * k))
    steps = np.tril(np.ones((k, k)), -1)[:, :k - 1]
    S = np.kron(np.eye(3), steps)
    s, V = np.linalg.eigh(S.T @ (H.T @ H).toarray() @ S)
    return H, S, np.clip(s, 0.0, None), V


def _wander_lr(e0: np.ndarray, e1: np.ndarray, basis) -> float:
    """Likelihood ratio of the base (residuals e0) and augmented (e1) fits when the noise is white plus a wandering
    offset (`_wander_basis`) whose strength τ (step variance over the noise variance) maximises the augmented
    fit's likelihood (0: none). Under Σ = σ²(I + τ Z Z'), e'Σ⁻¹e σ² = e'e − Σ_k τ c_k² / (1 + τ s_k), c = V'Z'e.
    The fits' residuals are scored under Σ as they are, not re-estimated under it (a review: then no exact
    likelihood ratio). Re-estimated (generalised least squares, τ profiled), the random walk took in a linear offset
    drift in 1/f noise (found in 0 of 3 simulations, 3 of 3 so) and confirmed less (a step named in 3 of 12
    simulations with 1/f noise, 2 of 12 so)."""
    H, S, s, V = basis
    n = len(e1)
    c0, c1 = V.T @ (S.T @ (H.T @ e0)), V.T @ (S.T @ (H.T @ e1))

    def quad(c, e, tau):  # for every τ (a column) at once
        return np.maximum(float(e @ e) - np.sum(tau * c ** 2 / (1.0 + tau * s), axis=-1), 1e-300)

    positive = s[s > s.max() * 1e-12]
    # from a wander far under the noise to one far over it, whatever the recording's length (Z'Z grows with N); none
    # when there is no offset to wander (held at its start): τ 0, the plain ratio
    taus = np.concatenate([[0.0], np.geomspace(1e-4 / positive.max(), 1e4 / positive.min(), 61)
                           if positive.size else []])[:, None]
    nll = n * np.log(quad(c1, e1, taus)) + np.sum(np.log1p(taus * s), axis=-1)
    tau = taus[int(np.argmin(nll))]
    return max(0.0, float(n * np.log(quad(c0, e0, tau) / quad(c1, e1, tau))))


def _colored_noise(data, state, sigma, n_candidates, max_order: int = 30) -> dict:
    """AR(p) model of the residual series (order by AIC up to `max_order`: white noise on top of
    correlated noise is an ARMA process, whose AR form needs many lags), judged by one-step prediction
    of the last quarter in time."""
    vector = data.reference is not None
    e = np.asarray(state["result"]["residuals"])
    series = e.reshape(-1, 3).mean(axis=1) if vector else e
    series = series[np.argsort(data.t, kind="stable")]
    n = len(series)
    row = {"effect": "colored_noise", "regime": "time", "n_params": 0, "new_dimensions": 0, "absorbed": False,
           "alternatives": 1}
    if n < 10 * max_order:
        row.update(lr=0.0, lr_pvalue=1.0, delta_aic=0.0, delta_bic=0.0, significant=False,
                   heldout_gap_before=None, heldout_gap_after=None, note="too few readings for an AR model")
        return row
    order, coefs, rss, y, lagged = _ar_fit(series, max_order)
    lr = len(y) * np.log(rss[0] / rss[order]) if order else 0.0
    split = int(round(n * (1 - HELDOUT_FRACTION)))
    train_y, train_x = y[:split - max_order], lagged[:split - max_order, :max(order, 1)]
    c, *_ = np.linalg.lstsq(train_x, train_y, rcond=None) if order else (np.zeros(1), None, None, None)
    test_y, test_x = y[split - max_order:], lagged[split - max_order:, :max(order, 1)]
    innovations = test_y - (test_x @ c if order else 0.0)
    scale = np.sqrt(3.0) if vector else 1.0  # the mean of three axes has σ/√3
    # Modelled, the correlated noise joins the noise model: its variance (from the training part) is
    # expected in the held-out residuals too.
    correlated = max(np.mean((train_y * scale) ** 2) - sigma ** 2, 0.0) if order else 0.0
    row.update(n_params=order, new_dimensions=order, order=order, coefficients=coefs.tolist(), lr=lr,
               lr_pvalue=float(stats.chi2.sf(lr, order)) if order else 1.0,
               delta_aic=-lr + 2 * order, delta_bic=-lr + order * np.log(len(y)),
               heldout="time", heldout_n=int(len(test_y)),
               heldout_gap_before=_gap(test_y * scale, sigma),
               heldout_gap_after=_gap(test_y * scale, np.sqrt(sigma ** 2 + correlated)),
               heldout_rms_before=float(np.sqrt(np.mean(test_y ** 2))),
               heldout_rms_after=float(np.sqrt(np.mean(innovations ** 2))),
               heldout_pvalue=_improvement_pvalue(test_y, innovations))
    row["unmet"] = _unmet(row, n_candidates, state["alpha"])
    row["significant"] = bool(order > 0 and not row["unmet"])
    return row


def _lattice_step(values: np.ndarray) -> float:
    """The ADC step when (99.9 % of) a column's values lie on one grid (0 otherwise): the smallest gap
    between its distinct values. Continuous readings have a tiny smallest gap, so a span of billions of
    "steps" and fractional multiples; an ADC spans at most 2^24 LSB. (Not "most values repeat": 600
    readings of a 16-bit sensor turned by hand hit ~500 distinct levels and are on a grid all the same.)"""
    u = np.unique(values)
    if len(u) < 3:
        return 0.0
    step = float(np.min(np.diff(u)))
    if (u[-1] - u[0]) / step > 2 ** 24:
        return 0.0
    # Printed with few decimals, the smallest gap is the step give or take the print's last digit (a blind check's
    # 0.015478 G steps written with 6 decimals: k off by up to 0.0097, no grid, σ 0 and the diagnosis stopped): the
    # step refitted over every level (the print's own rounding then moves k by under 1e-4).
    levels = np.round((u - u[0]) / step)
    step = float(np.sum(levels * (u - u[0])) / np.sum(levels ** 2))
    k = (values - u[0]) / step
    on_grid = np.abs(k - np.round(k)) < max(1e-3, 1e-9 * np.max(k))
    return step if np.mean(on_grid) > 0.999 else 0.0


def _quantization(data, state, sigma, n_candidates, noise_given: bool) -> dict:
    """Readings on a lattice: the quantisation noise q²/12 belongs in the noise model. Only a given
    noise σ (a datasheet noise density) can show it: a σ estimated from the readings already holds it."""
    steps = _axis_steps(data.m)
    row = {"effect": "quantization", "regime": "noise", "n_params": 1, "new_dimensions": int(steps.all()),
           "absorbed": False, "alternatives": 1, "steps": steps.tolist()}
    e = np.asarray(state["result"]["residuals"])
    if not steps.all():
        row.update(lr=0.0, lr_pvalue=1.0, delta_aic=0.0, delta_bic=0.0, significant=False,
                   heldout_gap_before=None, heldout_gap_after=None, note="readings are not on a lattice")
        return row
    # each residual's rounding variance: an axis weighted by σ/σ_axis (`_fit`) has its step weighted alike
    w = state["result"].get("axis_weights")
    if w is None:
        q2 = np.full(len(e), np.mean(steps ** 2) / 12.0)
    elif data.reference is not None:
        q2 = np.tile((w * steps) ** 2 / 12.0, len(e) // 3)
    else:  # a magnitude's weighted residual moves by ∂r/∂m = −∂r/∂b with each axis's rounding
        q2 = (np.asarray(state["result"]["jacobian"])[:, :3] ** 2) @ (steps ** 2 / 12.0)
    loglik = lambda var: -0.5 * float(np.sum(np.log(var) + e ** 2 / var))  # noqa: E731 - Gaussian, known variances
    lr = max(0.0, 2 * (loglik(sigma ** 2 + q2) - loglik(np.full(len(e), sigma ** 2))))
    n = len(e)
    held = _heldout("time", data, state["directions"])
    eh = _residuals(state["result"], data, _features(state["features"]), held)
    before, after = _gap(eh, sigma), _gap(eh, np.sqrt(sigma ** 2 + float(np.mean(q2))))
    row.update(lr=lr, lr_pvalue=float(stats.chi2.sf(lr, 1)), delta_aic=-lr + 2, delta_bic=-lr + np.log(n),
               heldout="time", heldout_n=int(held.sum()), heldout_gap_before=before, heldout_gap_after=after,
               heldout_pvalue=0.0 if after < before else 1.0, noise_given=noise_given)
    row["unmet"] = _unmet(row, n_candidates, state["alpha"])  # (its held-out p says only whether the gap fell)
    row["significant"] = bool(noise_given and not row["unmet"])
    return row


UNEXPLAINED = 0.25        # the remaining gap² above this share of the base model's: most of the departure is left
UNEXPLAINED_RMS = 1.5     # … and the remaining residuals above this many σ RMS (their variance 2.25 × the noise)


def _unexplained(before: dict, after: dict, accepted: list) -> dict:
    """How much of the base model's departure the effects found leave: the share of gap² (the residual
    variance above the noise) that remains. colored_noise describes correlated residuals without taking them
    off, so a recording it alone "explains" keeps all of its gap: what makes that noise is not among the
    candidates' effects. `left`: share above UNEXPLAINED and residuals above UNEXPLAINED_RMS σ."""
    share = after["gap"] ** 2 / before["gap"] ** 2 if before["gap"] > 0 else 0.0
    return {"share": float(share), "rms_over_sigma": after["rms_z"],
            "left": bool(share > UNEXPLAINED and after["rms_z"] > UNEXPLAINED_RMS),
            "as_noise": "colored_noise" in accepted}


def _noise_check(e: np.ndarray, sigma: float, n_params: int, alpha: float) -> dict:
    """Do the residuals exceed a given σ? χ² of the residuals / σ on their degrees of freedom: without it,
    a σ below the sensor's noise leaves every candidate's gain inside the gap and "no effect" reads as
    "explained to the noise"."""
    chi2 = float(e @ e) / sigma ** 2
    pvalue = float(stats.chi2.sf(chi2, max(e.size - n_params, 1)))
    rms = float(np.sqrt(np.mean(e ** 2)))
    return {"residual_rms": rms, "rms_over_sigma": rms / sigma, "pvalue": pvalue, "exceeds": pvalue < alpha}


HAND_TURN_DEG_S = (6.0, 720.0)  # a hand turning a sensor through its orientations: a full turn in a minute at the
                               # slowest, two turns a second at the fastest


NOISE_OVERSTATED = 0.85  # the residuals left, and their own differences, below this share of σ: σ held an effect


def _noise_overstated(data: _Data, e: np.ndarray, sigma: float, remaining: dict) -> str | None:
    """A CAVEAT when the estimated σ held what an effect found then took out (the readings' differences held a
    delay's error, ∝ the turn rate: σ 0.071 for 0.05, the residuals left 0.81 σ): every candidate was judged
    against too large a noise, so a further effect may have been missed. Said with the σ the residuals left give,
    to give as noise_sigma; not refitted."""
    if not remaining["overall"]["rms_z"] < NOISE_OVERSTATED:
        return None
    per_reading = len(e) // len(data.m)
    order = np.argsort(data.t, kind="stable") if data.t is not None else np.arange(len(data.m))
    left = _difference_noise(e.reshape(len(data.m), per_reading)[order], 3, mixture=True)
    if not left < NOISE_OVERSTATED * sigma:
        return None
    # (axes weighted: the residuals are in σ̄'s units, so each axis's σ scales alike — three values keep the weights)
    given = f"{left:.4g}" if data.axis_weights is None else ",".join(f"{v:.4g}" for v in left / data.axis_weights)
    return (f"noise σ: the residuals left scatter {remaining['overall']['rms_z']:.2f} σ and their third differences "
            f"give {left:.4g} for the σ {sigma:.4g} estimated before the effects found were modelled: σ held part of "
            f"them, and every candidate was judged against too large a noise (a further, smaller effect may have been "
            f"missed). Run again with noise_sigma={given if data.axis_weights is None else '[' + given + ']'} "
            f"(--noise-sigma {given})")


def _time_unit_caveat(data: _Data, directions: np.ndarray, sigma: float) -> str | None:
    """Times in ms (or µs) taken for seconds: a period of ≥ 1 s while the field direction turns only a little
    from one reading to the next means a hand-turned sensor turning slower than a hand does; the same turns
    per ms (µs) would be a hand's. Every time-scaled result (a delay, a drift rate, an event's time) is
    then off by the factor. Only a turn well above the noise's counts: the noise alone turns the direction
    of a still sensor (positions held at 1 Hz) by a median 1.18 √2 σ/H."""
    dt = np.diff(data.t)
    moving = dt > 0
    if not moving.any() or np.median(dt[moving]) < 1.0:
        return None
    turn = np.degrees(np.arccos(np.clip(np.sum(directions[1:] * directions[:-1], axis=1), -1, 1)))
    if np.median(turn[moving]) < 3 * np.degrees(1.18 * np.sqrt(2) * sigma / data.field_norm):
        return None
    rate = float(np.median(turn[moving] / dt[moving]))  # degrees per unit of t
    lo, hi = HAND_TURN_DEG_S
    for factor, unit, ways in ((1e-3, "ms", "`t [ms]` or `time_ms`"), (1e-6, "µs", "`t [us]` or `time_us`")):
        if lo <= rate / factor <= hi:
            return (f"t: readings {np.median(dt[moving]):.4g} s apart whose field direction turns {rate:.3g}°/s "
                    f"(a full turn in {360 / rate / 60:.3g} min) — slower than a hand turns a sensor; in {unit} it "
                    f"would be {rate / factor:.3g}°/s, a hand's. If t is in {unit}, every time here (delays, drift "
                    f"rates, event times) is off by {1 / factor:.0f}×: name the column {ways} (or give t in seconds)")
    return None


def _side(values, n: int, name: str, what: str):
    """A side regressor (temperature, current) checked: None when absent or constant (a constant carries no
    information: the hard iron holds it)."""
    if values is None:
        return None
    values = np.asarray(values, dtype=float)
    if values.shape != (n,):
        raise ValueError(f"{name}: need {n} {what}, got shape {values.shape}")
    if not np.all(np.isfinite(values)):
        bad = np.flatnonzero(~np.isfinite(values))
        raise ValueError(f"{name}: {len(bad)} of the {n} {what} are not finite (row {bad[0]}: {values[bad[0]]}); "
                         f"fill them in, or leave {name} out")
    return values if np.ptp(values) > 0 else None


def _spread_ticks(t: np.ndarray) -> np.ndarray:
    """Times in order (non-decreasing) with runs of equal values: each run spread evenly from its tick to
    the next one (the last run over the median tick)."""
    ticks, start, count = np.unique(t, return_index=True, return_counts=True)
    step = np.diff(ticks)
    step = np.append(step, np.median(step) if len(step) else 1.0)
    within = np.arange(len(t)) - np.repeat(start, count)
    return t + within * np.repeat(step / count, count)


LOGGED_TWICE = 0.9  # share of the ties of t that repeat their readings too: the lines were logged twice


def _prepare(samples, t, temp, reference, down, field_norm, units, source, current=None) -> _Data:
    m = as_samples(samples)
    n = len(m)
    if n < 50:  # (before the screens, which need readings: an empty array had raised an IndexError)
        raise ValueError(f"{source}: {n} readings, the diagnosis needs at least 50")
    t = np.arange(n, dtype=float) if t is None else np.asarray(t, dtype=float)
    if t.shape != (n,):
        raise ValueError(f"t: need {n} finite times, got shape {t.shape}")
    if not np.all(np.isfinite(t)):
        bad = np.flatnonzero(~np.isfinite(t))
        raise ValueError(f"t: {len(bad)} of {n} times are not finite (row {bad[0]}: {t[bad[0]]})")
    if n and np.all(m == m[0]):  # (every axis would pile up at one value: taken for a clipping rail, 0 left)
        raise ValueError(f"{source}: all {n} readings are the same (a sensor that is stuck, not updating, or was "
                         "never turned)")
    if n > 1 and np.ptp(t) == 0:  # else every reading would be spread over a made-up tick of 1 s
        raise ValueError(f"t: all {n} times are {t[0]:.6g} (a clock that did not run?); give the times in seconds, "
                         "or leave t out to take the row number")
    temp, current = _side(temp, n, "temp", "temperatures"), _side(current, n, "current", "currents")
    if reference is not None:
        reference = as_samples(reference, "reference")
        if len(reference) != n:
            raise ValueError(f"reference: {len(reference)} rows, samples have {n}")
    if down is not None:
        down = as_samples(down, "gravity")
        if len(down) != n or np.any(np.linalg.norm(down, axis=1) == 0):
            raise ValueError(f"gravity: need {n} non-zero vectors (the accelerometer), got {len(down)}")
    norms = None
    if field_norm is not None and np.ndim(field_norm) > 0:  # each reading's own |field| (a field that changes)
        if reference is not None:
            raise ValueError("field_norm: the vector models take each reading's field from the reference vectors; "
                             "give one |field| per reading only to the magnitude models (ellipsoid, scale)")
        norms = as_field_norms(field_norm, n, "field_norm")
    notes = []
    rows = np.arange(n)  # each reading's row in the input, for the notes

    def take(keep):  # every per-reading array keeps the same readings
        nonlocal m, t, rows, temp, reference, down, current, norms
        m, t, rows, temp, reference, down, current, norms = (
            None if a is None else a[keep] for a in (m, t, rows, temp, reference, down, current, norms))

    copied = repeated_blocks(m if temp is None else np.column_stack([m, temp]))
    if copied.any():  # the copies add no information, yet would double the evidence and fake a jump where they join
        take(~copied)
        notes.append(f"{repeated_words(copied)} and were left out")
    back = np.flatnonzero(np.diff(t) < 0)  # differences, runs and time blocks all need time order
    if len(back) > CLOCK_JUMPS * n:
        take(np.argsort(t, kind="stable"))
        notes.append(f"t went backwards at {len(back)} of {n} rows: the rows were not in time order and were "
                     "sorted by t")
    elif len(back):
        dt = np.diff(t)
        step = float(np.median(dt[dt > 0])) if np.any(dt > 0) else 0.0
        t = t.copy()
        for i in back:  # the rows after a jump continue one ordinary step after the row before it
            t[i + 1:] += t[i] - t[i + 1] + step
        notes.append(f"t went backwards at row{'s' if len(back) > 1 else ''} "
                     f"{', '.join(str(i + 1) for i in back[:5])}{', …' if len(back) > 5 else ''} (a counter "
                     "wrap or a clock reset in a log written in time order): the rows after each jump were "
                     "taken to follow it, one ordinary step later")
    # Rows that repeat the row before, time and readings, when nearly every tie of t is one: lines logged twice, not a
    # coarse clock's ticks (a blind check's every 7th row logged twice had been said to be both those ticks and
    # sample-and-hold copies); a coarse clock's rows in one tick differ, a still sensor's within it only at times.
    tie = np.diff(t) == 0
    twice = np.concatenate([[False], tie & np.all(m[1:] == m[:-1], axis=1)])
    if twice.any() and twice.sum() >= LOGGED_TWICE * tie.sum():
        take(~twice)
        notes.append(f"{int(twice.sum())} of {n} rows repeat the row before them exactly, time and readings (lines "
                     "logged twice) and were left out")
    ties = np.diff(t) == 0
    if ties.any():  # a clock coarser than the sample rate (whole seconds at 50 Hz): spread each tick's rows
        t = _spread_ticks(t)
        notes.append(f"t repeats at {int(ties.sum())} of {n} rows (a clock coarser than the readings): the rows "
                     "of each tick were spread evenly over it")
    copies = held_copies(m)  # sample and hold: the copies carry no new information, make the noise look
    if copies is not None:    # correlated and shrink the third differences the noise σ comes from
        keep = ~copies
        take(keep)
        notes.append(f"{int(copies.sum())} of {n} readings ({100 * copies.mean():.0f} %) repeat the previous one "
                     "exactly (sample and hold: the logger ran faster than the sensor) and were left out")
    sigma = estimate_noise(m) if len(m) >= 20 and np.isfinite(m).all() else 0.0
    clipping = _clipping(m, sigma) if np.isfinite(m).all() else []
    if clipping:  # hard saturation: what the range cut, and what the cut biased, carry no field to model
        on_rail, near = np.zeros(len(m), dtype=bool), np.zeros(len(m), dtype=bool)
        for c in clipping:
            column = m[:, "xyz".index(c["axis"])]
            # a blurred rail's readings spread ± RAIL_BAND/2 σ about it: those and CLIP_MARGIN σ more inward
            reach = (RAIL_BAND / 2 if c["noisy"] else 0.0) * sigma
            on_rail |= np.abs(column - c["rail"]) <= reach
            near |= np.abs(column - c["rail"]) <= reach + CLIP_MARGIN * sigma
        keep = ~near
        clipped = "; ".join(f"{c['axis']} at {c['rail']:.6g}{' ' + units if units else ''} ({c['readings']} readings, "
                            f"{100 * c['fraction']:.1f} %{', blurred by the noise' if c['noisy'] else ''})"
                            for c in clipping)
        # (counted once: a reading on two rails had been counted twice, "the -258 within 3 σ")
        notes.append(f"the sensor's range clips the readings ({clipped}): those and the {int((near & ~on_rail).sum())} "
                     f"within {CLIP_MARGIN:g} σ of the rail (the cut noise biases them inwards) were left out")
        take(keep)
    if np.isfinite(m).all():
        # Glitches (0,0,0, ADC rails, spikes of ≤ 3 readings) are bad readings, not sensor physics: left
        # out as calibrate leaves them out. Longer stretches off the model stay: they are what the
        # candidates (a moving dipole, a drift, saturation) explain.
        # (judged on the readings less what follows a logged current's or temperature's fast changes: a motor's
        # current jittering by amperes had made its readings "glitches")
        followed = _follows_logged(m, _logged(temp, current))
        glitches = find_outliers(m if followed is None else followed[0], reference, field_norms=norms)
        if len(glitches):
            keep = np.ones(len(m), dtype=bool)
            keep[glitches.rows] = False
            notes.append(replace(glitches, rows=np.sort(rows[glitches.rows])).messages(len(keep))[0].replace(
                "; outliers='keep' (--outliers keep) keeps them", " (glitches, not sensor physics)"))
            take(keep)
    one = float(np.mean(norms)) if norms is not None else float(field_norm) if field_norm else 0.0
    return _Data(m, t, temp, reference, down, one, units, source, notes, current, clipping, norms)


def quantization_step(samples) -> float:
    """RMS over axes of the readings' grid step (an ADC's LSB, see `_lattice_step`), or 0 when an axis is
    not on a grid."""
    steps = _axis_steps(as_samples(samples))
    return float(np.sqrt(np.mean(np.square(steps)))) if steps.all() else 0.0


def _axis_steps(m: np.ndarray) -> np.ndarray:
    """Each axis's grid step (`_lattice_step`; 0: not on a grid)."""
    return np.array([_lattice_step(axis) for axis in m.T])


def _check_options(noise_sigma, candidates, alpha, max_effects):
    """The options checked before any fit, each error naming its option. Returns the candidate names as a
    list (one name, or names separated by commas, may come as a string)."""
    if noise_sigma is not None:
        noise_values(noise_sigma)
    if not (isinstance(alpha, (int, float, np.integer, np.floating)) and 0 < alpha < 1):
        raise ValueError(f"alpha: need a significance level between 0 and 1 (0.01 for 1 %), got {alpha!r}")
    if isinstance(max_effects, (bool, np.bool_)) or not isinstance(max_effects, (int, np.integer)) or max_effects < 0:
        raise ValueError(f"max_effects: need a whole number ≥ 0 (how many effects to add), got {max_effects!r}")
    if candidates is None:
        return None
    if isinstance(candidates, str):  # list("temp_scale") would be its letters
        candidates = [c.strip() for c in candidates.split(",") if c.strip()]
    elif not isinstance(candidates, (list, tuple, set, frozenset, np.ndarray)) or \
            not all(isinstance(c, str) for c in candidates):
        raise ValueError(f"candidates: need effect names (a list of strings, or one string of names separated by "
                         f"commas), got {candidates!r}")
    return list(candidates)


def usable_regressors(temp, current) -> tuple:
    """({"temp": …, "current": …}, {name: how many missing or non-finite values left it out}, {name: how many were
    filled in}). A temperature's blank cells (a thermometer logged at a lower rate than the magnetometer on the same
    lines, a read it missed) are interpolated from the readings beside them, in row order, when every run of them is
    short (`_short_gaps`): a temperature cannot change much within one. Otherwise, and for a current (which may switch
    within a gap), a column that holds one is left out (None): it costs that column, not the diagnosis."""
    side, missing, filled = {"temp": temp, "current": current}, {}, {}
    for name, values in side.items():
        if values is None:
            continue
        given = np.asarray(values, dtype=float)
        bad = ~np.isfinite(given)
        if not bad.any():
            continue
        if name == "temp" and _short_gaps(bad):
            rows = np.arange(given.size)
            side[name] = np.interp(rows, rows[~bad], given[~bad])
            filled[name] = int(bad.sum())
        else:
            missing[name] = int(bad.sum())
            side[name] = None
    return side, missing, filled


def _short_gaps(bad: np.ndarray) -> bool:
    """Whether a column's missing values can be filled from those beside them: ten or more given, and every run of
    missing ones at most 10 long or, where ten runs or more show the column's own sampling, twice their median + 1 (a
    thermometer read once per ten lines leaves runs of 9; one disconnected for minutes, among them or alone, a run no
    interpolation knows). A run at either end holds its neighbour's value."""
    if np.count_nonzero(~bad) < 10:
        return False
    runs = np.array([last - first + 1 for first, last in index_runs(bad)])
    sampling = 2 * np.median(runs) + 1 if len(runs) >= 10 else 0
    return bool(runs.max() <= max(10, sampling))


def screened_temperature(temp) -> tuple:
    """(temp, [note]): readings that leave the temperature's course farther than a temperature can, or hold one value
    and jump out of it (fluxcal.drift's temperature_glitches and temperature_holds: a DS18B20's 85 °C, −127 °C
    disconnected, a thermometer stuck), interpolated from the readings beside them, and said (a blind check's 15
    error codes among 6000 readings made a 3 s thermal lag and a colored_noise that the clean log had not)."""
    if temp is None or np.size(temp) < 10 or not np.all(np.isfinite(np.asarray(temp, dtype=float))):
        return temp, []
    from ..drift import temperature_glitches, temperature_holds

    given = np.asarray(temp, dtype=float)
    rows = set(temperature_glitches(given).tolist())
    rows |= {i for a, b in temperature_holds(given) for i in range(a, b + 1)}
    if not rows or len(rows) > given.size // 2:
        return temp, []
    bad = np.array(sorted(rows))
    kept = np.setdiff1d(np.arange(given.size), bad)
    screened = given.copy()
    screened[bad] = np.interp(bad, kept, given[kept])
    shown = ", ".join(f"row {i}: {given[i]:g} °C" for i in bad[:4]) + (", …" if bad.size > 4 else "")
    return screened, [f"{bad.size} temperature reading(s) leave its course farther than a temperature can ({shown}): "
                      "a thermometer's error code or a stuck reading, interpolated from the readings beside them"]


def recording_inputs(rec, t, temp, current, gravity, units: str) -> tuple:
    """(readings, t, temp, current, gravity, units, source) of a Recording, each one given explicitly first."""
    return (rec.samples(), rec.time() if t is None else t, rec.temperature() if temp is None else temp,
            rec.current() if current is None else current, rec.acceleration() if gravity is None else gravity,
            units or rec.field_units(), rec.source)


def _row_copy(row: dict) -> dict:
    """A candidate's row as evaluated, kept apart from the changes later rounds make to it (they set its keys, and
    grow its lists and dicts; the arrays it holds are not changed)."""
    return {k: dict(v) if isinstance(v, dict) else list(v) if isinstance(v, list) else v for k, v in row.items()}


def _search(data: _Data, model: str, pool: list, names: dict, state: dict, sigma: float, n_candidates: int,
            max_effects: int, noise_sigma, logging_noise: dict, bar=None, first: str | None = None,
            plain: bool = False, round0: list | None = None) -> dict:
    """The greedy search from the base model `state`: each round the most significant candidate is added (or another
    episode of an event found), the effects found are placed again, and the noise models are tried when none is
    left; then those no longer paying BIC's price are pruned. `first`: the candidate to take in the first round
    whatever its held-out test (`_in_another_order`), a law in time in its `plain` form (a drift linear) when asked.
    `round0`: the first round's rows as another search from the same base model evaluated them (`round0` of its
    result, copied here): `_in_another_order`'s searches start from the same base, and evaluating every candidate
    on it again was a third of their time.
    Returns {data, state, accepted, last_rows, moves, first_rows, round0}
    (`first_rows`: the first round's candidates)."""
    vector = MODELS[model][0]
    state, accepted, last_rows, first_rows, taken = dict(state), [], {}, [], []
    previous_winner, moves = None, []
    by_base = set()  # candidates the base model's own parameters absorb (before any effect is accepted)

    def accept(w):
        nonlocal data
        if w["effect"] in accepted:  # a further episode of an event found: its block grows
            found, i = last_rows[w["effect"]], accepted.index(w["effect"])  # (noise models come after the search)
            columns = found.setdefault("_columns", [np.arange(state["features"][i].shape[1])])
            found.setdefault("episodes", [_episode(found)]).append(_episode(w))
            state.update(_with_episode(data, model, state, w, i, columns))
            return
        accepted.append(w["effect"])
        taken.append(w["effect"])
        state.update(_with(state, w, vector))
        if hasattr(names[w["effect"]], "shapes") and "shape_terms" not in w:
            _richer_shape(data, model, state, names[w["effect"]], w)
        if vector and names[w["effect"]].moves_reference:
            data, applied, block = _exact_move(data, state, model, names[w["effect"]])
            moves.append((w, names[w["effect"]], applied, block))
        w["step"] = len(accepted)
        last_rows[w["effect"]] = w
        for name in [w["effect"]] + _reprofile(data, model, state, accepted, last_rows, {c.name: c for c in pool},
                                               sigma, n_candidates):
            last_rows[name]["heldout_leverage"] = _row_leverage(data, state["result"], last_rows[name],
                                                                state["directions"])

    for _round in range(max_effects + 1):
        rows = []
        systematic = [c for c in pool if c.name not in NOISE_CANDIDATES and c.name not in accepted]
        if _round == 0 and round0 is not None:  # (the same base model: the same rows)
            rows = [_row_copy(r) for r in round0]
            by_base.update(r["effect"] for r in rows if r.get("absorbed"))
            systematic = []
        for cls in systematic:
            rows.append(_evaluate(cls, data, model, state, sigma, n_candidates))
            _second_shape(rows[-1], cls, [names[a] for a in accepted])
            if rows[-1].get("absorbed"):
                if not accepted:
                    by_base.add(cls.name)
                elif cls.name not in by_base:  # which effects found took it (a delay taken by an eddy term)
                    rows[-1]["absorbed_after"] = list(accepted)
            if bar:
                bar.update(1)
        if _round == 0 and round0 is None:
            round0 = [_row_copy(r) for r in rows]
        # An event found may recur (a magnet carried past again), and an interference at one frequency have others
        # beside it (`recurs`: another line): another episode of it competes with the rest, and joins its block
        # (each episode counts against max_effects).
        episodes = [dict(_evaluate(names[a], data, model, state, sigma, n_candidates), episode=True) for a in accepted
                    if (names[a].regime == "events" or names[a].recurs) and not names[a].moves_reference]
        rows += [r for r in episodes if not _overlaps(r, last_rows[r["effect"]])]
        candidates = [r for r in rows if not r.get("episode")]
        if previous_winner is not None:
            rivals = _collapsed(data, previous_winner, candidates)
            if rivals:
                previous_winner["confounded_with"] = rivals
            previous_winner = None
        winners = _special_case_first(sorted([r for r in rows if r["significant"]], key=lambda r: r["delta_bic"]),
                                      data, state)
        if _round == 0:
            first_rows = candidates
            if first is not None:  # (taken whatever its held-out test: `_in_another_order` judges it at the end)
                winners = [(plain and _plain(r, names[first], data, model, state)) or r
                           for r in candidates if r["effect"] == first]
        if accepted:  # beside an effect found, a small held-out fall the fits' own parameter noise can make
            for r in winners:   # confirms nothing
                _beside(r, data, state["directions"], sigma, accepted)
            winners = [r for r in winners if r["significant"]]
        for r in candidates:
            last_rows[r["effect"]] = r
        added = len(accepted) + sum(len(last_rows[a].get("episodes", [0])) - 1 for a in accepted)
        if winners and added < max_effects:
            w = previous_winner = winners[0]
            w["_rivals"] = [] if w.get("episode") else _rivals(w, candidates, logging_noise=logging_noise)
            accept(w)
            continue
        placed = (_with_the_rest_placed_again(data, model, state, candidates, pool, accepted, last_rows, sigma,
                                              n_candidates) if accepted and added < max_effects else None)
        if placed:
            rest, order, placed_rows, w = placed
            _beside(w, data, state["directions"], sigma, order)  # (as a winner beside effects found is judged)
            if w["significant"]:
                state.update(rest)
                accepted[:] = order
                last_rows.update(placed_rows)
                w["_rivals"] = []
                accept(w)
                continue
        pair = (_together(data, model, state, candidates, pool, accepted, sigma, n_candidates)
                if added + 2 <= max_effects else None)
        if pair:
            for w in pair:
                accept(w)
            continue
        # No systematic effect left: is the rest correlated noise or quantisation?
        for name in NOISE_CANDIDATES:
            if name in [c.name for c in pool]:
                r = (_colored_noise(data, state, sigma, n_candidates) if name == "colored_noise"
                     else _quantization(data, state, sigma, n_candidates, noise_sigma is not None))
                last_rows[name] = r
                if bar:
                    bar.update(1)
        noise_winners = sorted([last_rows[n] for n in NOISE_CANDIDATES if n in last_rows and last_rows[n]["significant"]],
                               key=lambda r: r["delta_bic"])
        for w in noise_winners:
            if added < max_effects:
                accepted.append(w["effect"])
                w["step"] = len(accepted)
                added += 1
        break

    pruned = _prune(data, model, state, accepted, last_rows, names)
    accepted[:] = [a for a in accepted if a not in pruned]
    for name in pruned:
        r = last_rows[name]
        r["note"] = (f"accepted in round {r.pop('step')}, but with {', '.join(a for a in accepted if a not in NOISE_CANDIDATES)} "
                     f"modelled it no longer pays BIC's price (ΔBIC {r['pruned_delta_bic']:+.1f} for keeping it): left out")
        r["unmet"] = list(r.get("unmet", [])) + ["pruned"]
        r.pop("confounded_with", None)
        for other in last_rows.values():
            if other.get("found_with") == name:
                other.pop("found_with")
    for step, name in enumerate(accepted, start=1):
        last_rows[name]["step"] = step
    return {"data": data, "state": state, "accepted": accepted, "last_rows": last_rows, "moves": moves,
            "first_rows": first_rows, "first": taken[0] if taken else None, "round0": round0}


def _special_case_first(winners: list, data: _Data, state: dict) -> list:
    """The winners, a special case of the first (its signature inside the first's, fewer parameters) put ahead of it
    when the first's extra terms are not significant over it: the whitened likelihood ratio of the two fits, at the
    search's α. ΔBIC, from the plain ratio, ranks the winners, and correlated noise pays a general form's extra terms
    too: a blind check's saturation (AR(1) noise, φ 0.65) was named a cubic, ΔBIC −308 against −289, though the
    cubic's extra terms' whitened ratio was 3.9. Nested forms are no rivals (`_rivals`), so nothing else chose."""
    top = winners[0] if winners else None
    for r in winners[1:]:
        if (r.get("episode") or top.get("episode") or r.get("_signature") is None or top.get("_signature") is None
                or not r.get("fitted_parameters", 0) < top.get("fitted_parameters", 0)):
            continue
        overlap = np.linalg.svd(top["_signature"].T @ r["_signature"], compute_uv=False)
        if not (overlap.size and overlap.min() >= NESTED):
            continue
        lr = _whitened_lr(np.asarray(r["_fit"]["residuals"]), np.asarray(top["_fit"]["residuals"]), data,
                          wander=_round_wander(data, state))
        if not stats.chi2.sf(lr, top["fitted_parameters"] - r["fitted_parameters"]) < state["alpha"]:
            r["special_case_of"] = {"effect": top["effect"], "extra_terms_lr_whitened": float(lr)}
            return [r] + [w for w in winners if w is not r]
    return winners


ANOTHER_ORDER_P = 1e-6  # a test of the residuals the search left below this: they still depart (report.SHAPE_P)
ANOTHER_ORDERS = 2      # searches with another first-round candidate taken first (a drift as found, plain), at most


def _time_course(cls) -> bool:
    """An effect with a course in time of its own (a drift's law, a step, a magnet passing; not one held out on later
    time for another reason: a lag, a line, hysteresis)."""
    return bool(getattr(cls, "law_in_time", False) or cls.regime == "events")


def _search_bic(found: dict, names: dict) -> float:
    """BIC of a search's final model (its effects' prices, `_price`; the base model's parameters are common)."""
    e = np.asarray(found["state"]["result"]["residuals"])
    modelled = [a for a in found["accepted"] if a not in NOISE_CANDIDATES]
    price = sum(_price(names[a], found["last_rows"][a], f.shape[1])
                for a, f in zip(modelled, found["state"]["features"]))
    return float(len(e) * np.log(float(e @ e)) + price * np.log(len(e)))


def _in_another_order(found: dict, model: str, names: dict, sigma: float, n_candidates: int, search) -> dict:
    """The greedy search takes the strongest effect first, and what it takes first can absorb part of another with a
    course in time: a drift and a step against it came out as a box that "came back" beside the step (residuals left
    at 1.5–2.1 σ), the drift then failing its held-out test; a warm-up and a step against it, each failing its
    held-out test while the other was unmodelled, left nothing found and 3.65 σ. When the search took a course in time
    first, or nothing, and the residuals it left still depart
    (a test at p < ANOTHER_ORDER_P), each other first-round candidate with a course in time that BIC favoured (its
    likelihood ratio, whitened by residuals the first effect still held, and its held-out test are judged at the
    end; one found later too: a drift found second had been profiled as a warm-up beside the box) — at most
    ANOTHER_ORDERS, laws in time before events, each by ΔBIC — is taken first in another search (`search`,
    `first=`); that search's model replaces this one when it fits better by more than a parameter's BIC price, leaves
    no larger residuals, and the candidate, searched again with the rest modelled, passes every test there. Its row
    then says so (`another_order`: the first search's first effect, effects, residual RMS in σ and the ΔBIC)."""
    vector = MODELS[model][0]
    data, first = found["data"], found["first"]
    if first is not None and not _time_course(names[first]):  # (or none found: each failed its held-out test)
        return found
    e = np.asarray(found["state"]["result"]["residuals"])
    remaining = _where(data, e, sigma, _field_directions(data, found["state"]["result"]), vector)
    if not any(t["pvalue"] < ANOTHER_ORDER_P for t in remaining["tests"]):
        return found
    others = sorted([r for r in found["first_rows"] if r["effect"] != first and "_fit" in r and r["delta_bic"] < 0
                     and not refused(r) and not r.get("absorbed") and not names[r["effect"]].moves_reference
                     and _time_course(names[r["effect"]])],
                    key=lambda r: (not getattr(names[r["effect"]], "law_in_time", False), r["delta_bic"])
                    )[:ANOTHER_ORDERS]
    # a law in time as found, then in its plain form: its profile was fitted to residuals that held the effect
    # taken first (a linear drift bent into a warm-up beside the box; a warm-up made linear kept the box)
    tries = [(r["effect"], plain) for r in others
             for plain in ((False, True) if _plain_differs(r, names[r["effect"]]) else (False,))][:ANOTHER_ORDERS]
    bic, n = _search_bic(found, names), len(e)
    for name, plain in tries:
        tried = search(first=name, plain=plain, round0=found["round0"])
        order = [a for a in tried["accepted"] if a not in NOISE_CANDIDATES]
        e1 = np.asarray(tried["state"]["result"]["residuals"])
        delta = _search_bic(tried, names) - bic
        if name not in order or not delta < -np.log(n) or not float(e1 @ e1) <= float(e @ e):
            continue
        try:
            again = _evaluate(names[name], tried["data"], model, _without(tried["data"], model, tried["state"],
                                                                          order.index(name)), sigma, n_candidates)
        except _core.Error:
            continue
        if again["significant"]:
            _beside(again, tried["data"], tried["state"]["directions"], sigma, [a for a in order if a != name])
        if not again["significant"]:
            continue
        old = tried["last_rows"][name]
        again.update({k: old[k] for k in ("step", "replaced", "_rivals", "confounded_with", "found_with",
                                          "heldout_leverage") if k in old})
        again["another_order"] = {"first": first, "accepted": list(found["accepted"]),
                                  "rms_z": float(np.sqrt(np.mean((e / sigma) ** 2))), "delta_bic": float(delta)}
        tried["last_rows"][name] = again
        return tried
    return found


def diagnose(samples, t=None, temp=None, reference=None, gravity=None, field_norm=None, model: str | None = None,
             noise_sigma=None, candidates=None, alpha: float = 0.01, max_effects: int = 3,
             progress: bool = False, units: str = "", source: str = "samples", current=None,
             _reestimated: tuple | None = None) -> Diagnosis:
    """Diagnose the gap between `samples` (N×3 readings, or a Recording) and the base `model`.

    t (s; default the row number), temp (°C), current (A drawn near the sensor: motors, a heater),
    reference (N×3 true field per reading, sensor frame: the vector models): the regressors. gravity (N×3
    accelerometer or any down/up vector, sensor frame; with reference vectors it adds the heading error to
    the downstream errors, and lets a moving magnet be fitted in the world's north, east and down — down
    as `gravity` points: a vector pointing up turns east and down round). field_norm: the known |h| (default: the
    fitted ellipsoid's own scale), or each reading's (N values: a field that changes while the sensor turns, logged
    by a scalar magnetometer or an observatory; the magnitude models then fit each |h| to its own); with a Recording,
    a column's name ("F", in the readings' unit when both state a field unit).
    model: "ellipsoid" (default without reference), "scale", "vector" (default with one), "vector_scale".
    noise_sigma: white-noise σ of the readings, one for every axis, or three (x, y, z: a datasheet's per axis;
    each axis is weighted by its own, `Diagnosis.axis_noise`) (default: estimated, see estimate_noise; against
    reference vectors each axis's own when their noise differs — not for the magnitude models, whose readings'
    differences per axis also hold the turn). candidates:
    effect names to try (default all whose regressors are present). alpha: significance level
    (Bonferroni-corrected over the candidates). max_effects: how many effects to add greedily.
    """
    arguments = dict(locals())  # (for a second pass at a σ the first pass showed overstated: _overstated_by)
    from ..io.recording import Recording
    from ..pipeline import calibrate

    candidates = _check_options(noise_sigma, candidates, alpha, max_effects)
    gravity_given = gravity is not None
    unusable = []
    field_norm = field_norm_given(samples, field_norm)  # (a Recording's column: before it is taken apart)
    if isinstance(samples, Recording):
        samples, t, temp, current, gravity, units, source = recording_inputs(samples, t, temp, current, gravity, units)
        side, missing, filled = usable_regressors(temp, current)
        unusable = [f"its {name} column has {n} missing or non-finite values and was not used (fill them in to try "
                    f"the {name} candidates)" for name, n in missing.items()]
        unusable += [f"its {name} column has {n} missing or non-finite values, in short runs: interpolated from the "
                     f"readings beside them" for name, n in filled.items()]
        temp, current = side["temp"], side["current"]
    elif not units:  # a DataFrame's unit in its columns' names (mx [nT]), as calibrate takes it
        units = samples_units(samples)
    temp, said = screened_temperature(temp)
    unusable += said
    for name, values in (("temperature", temp), ("current", current)):
        if values is not None and np.size(values) > 1 and np.ptp(np.asarray(values, dtype=float)) == 0:
            unusable.append(f"its {name} column is constant ({float(np.asarray(values)[0]):g}): a stuck sensor or "
                            f"logging channel? (a constant carries nothing: its candidates were not tried)")
    model = model or ("vector" if reference is not None else "ellipsoid")
    if model not in MODELS:
        raise ValueError(f"model: {model!r} is not one of {', '.join(MODELS)}")
    vector, fixed = MODELS[model]
    if vector and reference is None:
        raise ValueError(f"model {model!r} needs reference vectors (the true field per reading: reference=, "
                         "--reference rx,ry,rz, or the attitude and local-field columns of an airborne log)")
    if gravity_given and not vector:
        warnings.warn(f"gravity: not used by the {model!r} model (the heading error and a magnet's north, east and "
                      "down need reference vectors: give reference=)", stacklevel=2)
    timestamps = t is not None
    data = _prepare(samples, t, temp, reference if vector else None, gravity if vector else None, field_norm,
                    units, source, current)
    data.notes += unusable
    if len(data.m) < 50:
        raise ValueError(f"{source}: {len(data.m)} readings, the diagnosis needs at least 50")

    refused_start = None  # (why calibrate refuses these readings, when the base starts without it)
    if vector:
        start = calibrate(data.m, reference=data.reference, units=units)
        data.field_norm = float(np.mean(np.linalg.norm(data.reference, axis=1)))
    else:
        given = data.field_norms if data.field_norms is not None else data.field_norm or None
        try:
            start = calibrate(data.m, field_norm=given, units=units, shape="sym")  # the full base's start
        except _core.Error as exc:  # (a near-planar drive: the full refinement runs away where a simpler shape holds)
            start, refused_start = _undetermined_start(data, given, units, exc)
        # (each reading's own: their mean over every reading diagnosed, not over those the start's screen kept)
        data.field_norm = start.field_norm if data.field_norms is None else float(np.mean(data.field_norms))
    if fixed:  # a scale-only model starts from the diagonal of the full fit's W = A⁻¹
        W = np.linalg.inv(start.matrix)
        start = Calibration(offset=start.offset, matrix=np.diag(1.0 / np.diag(W)), field_norm=start.field_norm,
                            units=units, model=model)
    base = _fit(data, start, fixed, None)
    axes = axis_noise = None
    if noise_sigma is None:
        sigma, noise_source, sigma_bound, axes = _noise(data, base)
        if _reestimated is not None:
            sigma, words = _reestimated
            noise_source = words + " (first " + noise_source + ")"
        step = quantization_step(data.m)
        if sigma < step / np.sqrt(12.0):  # rounding alone leaves LSB/√12 even when the noise is below 1 LSB
            sigma = step / np.sqrt(12.0)
            noise_source += f", raised to the quantization floor {step:.4g}/√12 (readings on a {step:.4g} grid)"
            # (then the axes' "noise" is rounding, as large on each axis that moves: an axis that moves slowly
            # rounds to a course in time, not to noise — weighted by it, a step was named at a 1 µT grid)
            axes = None
    else:
        given = noise_values(noise_sigma)
        sigma, noise_source, sigma_bound = float(np.sqrt(np.mean(given ** 2))), "given", False
        if np.ptp(given) > 0:  # (a datasheet's σ per axis: weighted as estimated ones are)
            axes, noise_source = (sigma / given, given / sigma, None), "given per axis"
    if axes is not None:  # weighted from here on: the base refitted with them
        data.axis_weights, axis_noise = axes[0], (sigma * axes[1]).tolist()
        base = _fit(data, start, fixed, None)
        values = f"σ x, y, z {', '.join(f'{v:.4g}' for v in axis_noise)}{' ' + data.units if data.units else ''}"
        noise_source += (f" ({values}, σ their RMS)" if axes[2] is None else
                         f"; the axes' noise differs ({values}, in the ratios of their residuals' third differences; "
                         f"equal rejected at p {axes[2]:.2g}, Brown–Forsythe)")
        noise_source += (": each axis's residuals are weighted by σ/σ_axis in every fit and test" if vector else
                         ": each reading's residual is its distance to the ellipsoid with each axis scaled by "
                         "σ/σ_axis (its noise σ in every direction), in every fit and test")
    if data.notes:
        noise_source += "; " + "; ".join(data.notes)
    if not sigma > 0:
        raise ValueError(f"{source}: the noise σ is zero (readings constant or repeated?); give noise_sigma (--noise-sigma)")

    names = {c.name: c for c in CANDIDATES}
    wanted = list(names) if candidates is None else candidates
    unknown = [w for w in wanted if w not in names]
    if unknown:
        raise ValueError(f"candidates: unknown effect(s) {', '.join(unknown)}; known: {', '.join(names)}")
    have = {"t": True, "timestamps": timestamps, "temp": data.temp is not None, "current": data.current is not None}
    pool = [names[w] for w in wanted if all(have.get(r, False) for r in names[w].needs)]
    skipped = [w for w in wanted if names[w] not in pool]
    # A rotation or a delay of the field leaves every magnitude unchanged: against a magnitude model its
    # columns are numerical dust that, normalised, would fit leftovers of other effects.
    invisible = [c.name for c in pool if c.needs_reference and not vector]
    pool = [c for c in pool if c.name not in invisible]

    directions = _field_directions(data, base)
    caveats = [f"the base calibration: {w} — what its data do not determine, an effect can stand in for (and "
               "an effect can hide in it)" for w in start.summary.get("warnings", [])
               if "poor coverage" in w or "not identifiable" in w]
    if refused_start:
        caveats.insert(0, refused_start)
    undetermined = bool(caveats)  # (before any other caveat joins them)
    if timestamps and (unit := _time_unit_caveat(data, directions, sigma)):
        caveats.append(unit)
        warnings.warn(unit, stacklevel=2)
    e0 = np.asarray(base["residuals"])
    where = _where(data, e0, sigma, directions, vector)
    state = {"start": start, "result": base, "features": [], "signal_blocks": [], "effects": [], "validated": [],
             "terms": np.zeros(0), "train_fits": {}, "sigma_bound": sigma_bound, "undetermined": undetermined,
             # the base residuals' correlation length in readings (`_event_block`)
             "correlation": _in_sample_length(base, data, np.ones(len(data.m), bool)) // (len(e0) // len(data.m)),
             "directions": directions, "alpha": alpha,
             # the readings' median time step (an eddy lag of half a sample or more on every axis is a delay)
             "period": float(np.median(np.diff(np.sort(data.t)))) if data.t is not None and len(data.t) > 1 else 0.0}
    # (each round tries at most this many: an accepted event leaves the pool's systematic candidates and adds one
    # episode candidate; the noise models are counted though tried last)
    n_candidates = max(len(pool), 1)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(pool) * (max_effects + 1), desc="diagnose", unit="candidate", leave=False,
                   disable=None)  # None: no bar when stderr is no terminal (a log file filled with \r lines)
    logging_noise = {"temperature": _logging_noise(data.temp, data.t), "current": _logging_noise(data.current, data.t)}
    search = partial(_search, data, model, pool, names, state, sigma, n_candidates, max_effects, noise_sigma,
                     logging_noise, bar)
    found = _in_another_order(search(), model, names, sigma, n_candidates, search)
    if bar:
        bar.close()
    data, state, accepted, last_rows, moves = (found[k] for k in ("data", "state", "accepted", "last_rows", "moves"))
    # (before the rows are finished: a second pass at a σ the first showed overstated makes them again)
    if noise_sigma is None and _reestimated is None and (again := _overstated_by(last_rows, names, sigma)):
        return diagnose(**{**arguments, "_reestimated": again})
    modelled = [a for a in accepted if a not in NOISE_CANDIDATES]  # in the order of state["features"]
    moves = [(w, cls, applied, _block(state, modelled.index(w["effect"]))) for w, cls, applied, _ in moves]
    for w, cls, applied, block in moves:  # the whole move: the one applied, then the block's remainder
        w.update(cls.describe_move(cls.compose(applied, np.asarray(state["result"]["parameters"])[12:][block])))
    # Later rounds refit every accepted block: an accepted effect's coefficients are the final model's.
    params, errors = (np.asarray(state["result"][k]) for k in ("parameters", "standard_errors"))
    lo = 12 if vector else 9
    for name, feats in zip([a for a in accepted if a not in NOISE_CANDIDATES], state["features"]):
        if not (vector and names[name].moves_reference):  # a move's block is a remainder, folded in above
            last_rows[name].update(coefficients=params[lo:lo + feats.shape[1]].tolist(),
                                   standard_errors=errors[lo:lo + feats.shape[1]].tolist())
            if name == "eddy_current":  # (its report gives differences between the axes: their errors need this)
                last_rows[name]["correlation"] = _block_correlation(state["result"], lo, feats.shape[1]).tolist()
        row = last_rows[name]
        for i, columns in enumerate(row.get("_columns", [np.arange(feats.shape[1])])):  # each episode's own
            episode = row["episodes"][i] if "episodes" in row else row
            if name == "moving_dipole":
                episode.update(_disturbance(data, state["result"], feats[:, columns], params[lo + columns]))
            if name == "offset_step":
                episode.update(_jump({**episode, "coefficients": params[lo + columns]}))
            if names[name].recurs:  # each line's own sin and cos terms
                episode["line_coefficients"] = params[lo + columns].tolist()
            if i == 0 and episode is not row:  # the row's own fields: its first episode's
                row.update({k: v for k, v in episode.items() if k not in EPISODE_KEYS})
        lo += feats.shape[1]
    for name in accepted:  # a held-out test that cannot be trusted: said, not hidden
        r = last_rows[name]
        if r.get("heldout_leverage") is None or r.get("heldout_gap_before") is None:
            continue
        floor = sigma * np.sqrt(r["heldout_leverage"])
        r["heldout_gain_unresolved"] = _gain_unresolved(r, r["heldout_leverage"], sigma)
        if r["heldout_gain_unresolved"]:
            why = (f"the fits on the rest predict them with an error of {floor:.3g} from the noise in their "
                   f"parameters alone (leverage {r['heldout_leverage']:.2g}), and the gap's fall "
                   f"{r['heldout_gap_before']:.3g} → {r['heldout_gap_after']:.3g} is within twice what two such "
                   f"errors can make ({2 * np.sqrt(2) * floor:.3g})") if np.isfinite(floor) else \
                  ("the rest does not determine every parameter they depend on (it cannot tell some of the "
                   "effects' terms apart), so the held-out fits leave part of their prediction at their starting "
                   f"values: the gap's fall {r['heldout_gap_before']:.3g} → {r['heldout_gap_after']:.3g} does not "
                   "test the effect")
            caveats.append(f"{name}: its held-out test may not be trusted — held out ({r['heldout']}, "
                           f"{r['heldout_n']} readings), {why}. The recording "
                           f"({len(data.m)} readings{f' over {np.ptp(data.t):.3g} s' if timestamps else ''}) may be "
                           "too short or cover too little: effects of a similar shape over it (a drift, a step, a "
                           "passing magnet) are not ruled out")
    # Events recur (a heater or a radio cycling) and the search models their episodes, but it stops (max_effects),
    # leaves effects out after it (pruning) and keeps episodes apart in time: with every accepted effect modelled, is
    # the same kind of event significant again? Said, not modelled.
    for name in [a for a in accepted if names[a].regime == "events"]:
        again = _evaluate(names[name], data, model, state, sigma, n_candidates)
        if again["significant"]:
            _beside(again, data, directions, sigma, accepted)  # as the search judged its episodes
        if again["significant"]:
            episode = _episode(again)
            last_rows[name]["another_episode"] = episode
            at = time_words(data.t, timestamps)
            when = "from " + " to ".join("the recording's " + edge if v is None else at(v)
                                         for v, edge in ((episode["on_s"], "start"), (episode["off_s"], "end")))
            if episode["closest_s"] is not None:  # a pass: its closest approach, not the times its features reach
                when = (f"a pass closest at {at(episode['closest_s'])} (passage time "
                        f"{episode['passage_s']:.3g}{' s' if timestamps else ' rows'})")
            found = len(last_rows[name].get("episodes", [0]))
            caveats.append(f"{name}: {'a second' if found == 1 else 'a further'} episode, {when}, is significant with "
                           f"{'the first' if found == 1 else f'the {found} found'} modelled (ΔBIC "
                           f"{episode['delta_bic']:.1f}, held-out gap {episode['heldout_gap_before']:.3g} → "
                           f"{episode['heldout_gap_after']:.3g}); not modelled ("
                           + ("it overlaps the episodes found in time: what their shapes leave, or a second jump "
                              "inside a box" if _overlaps(again, last_rows[name]) else
                              "the search stopped before it: max_effects, or an effect left out since")
                           + "), so the effects found after it may stand in for it")
    # Significant in the last round but not modelled: the max_effects limit stopped the greedy search.
    for name, r in last_rows.items():
        r["significant_not_modelled"] = bool(r.get("significant")) and name not in accepted and "pruned_delta_bic" not in r
    ranking = [last_rows[name] for name in accepted]
    # The rest: systematic effects before noise models (the order in which they are tried), each by ΔBIC.
    rest = sorted([r for name, r in last_rows.items() if name not in accepted],
                  key=lambda r: (r.get("absorbed", False), r["effect"] in NOISE_CANDIDATES, r["delta_bic"]))
    ranking += rest
    for r in ranking:
        for key in ("_fit", "_features", "_signature", "_explained", "_rivals", "_signal_features",
                    "_law_in_time", "_columns", "_heldout_features", "_heldout_unplaced"):
            r.pop(key, None)
        r.setdefault("significant", False)
        r["significant"] = r["effect"] in accepted
        if r.get("heldout_leverage") is not None and not np.isfinite(r["heldout_leverage"]):
            r["heldout_leverage_undetermined"] = True

    final = state["result"]
    e_final = np.asarray(final["residuals"])
    final_dirs = _field_directions(data, final)
    remaining = _where(data, e_final, sigma, final_dirs, vector)
    if noise_sigma is None and accepted and (lower := _noise_overstated(data, e_final, sigma, remaining)):
        caveats.append(lower)
    if noise_sigma is not None:  # an estimated σ comes from these readings; a given one may not fit them
        remaining["noise_check"] = _noise_check(e_final, sigma, len(final["parameters"]) - len(fixed), alpha)
    remaining["unexplained"] = _unexplained(where["overall"], remaining["overall"], accepted)
    remaining["skipped_candidates"] = skipped
    remaining["invisible_candidates"] = invisible
    base_cal = Calibration(offset=base["offset"], matrix=base["matrix"], field_norm=data.field_norm, units=units,
                           model=model)
    series = {"t": data.t, "timestamps": timestamps, "temp": data.temp, "current": data.current, "directions": directions, "residual_before": e0,
              "residual_after": e_final, "vector": vector, "field_norms": data.field_norms}
    d = Diagnosis(model=model, noise_sigma=sigma, noise_source=noise_source, units=units, source=source,
                  ranking=ranking, accepted=accepted, where=where, remaining=remaining, base=base_cal,
                  series=series, caveats=caveats, clipping=data.clipping, axis_noise=axis_noise)
    _line_bounds(d)
    return d


def _overstated_by(rows: dict, names: dict, sigma: float) -> tuple | None:
    """(σ, words) when a candidate whose features are functions of time, temperature or current alone (`exogenous`)
    is strong in sample and, held out, predicts the readings better than the estimated σ lets any model — refused as
    "below the noise", or with no gap above that σ left to close: the σ held the effect itself (a line 15–20× the
    noise at a fifth of the sampling rate, a tumble logged at 1–2 Hz whose turning hides it from the readings'
    differences: σ 2.2–6.6× the truth, the line refused as degenerate — a blind check). The σ its held-out field error
    gives (σ × error / the noise floor there; an upper bound: it holds whatever else the model misses) is then taken
    for a second pass, when under OVERSTATED × σ. Such features cannot rebuild a held-out reading from itself, so a
    held-out error below the noise is no degenerate fit of theirs. None otherwise."""
    best = None
    for name, r in rows.items():
        if not (getattr(names.get(name), "exogenous", False) and r.get("field_error_after") is not None
                and r.get("heldout_noise_floor")) or r.get("degenerate") not in (None, "below the noise held out"):
            continue  # (a fit refused as degenerate otherwise — cancelled by the base or by an effect found, or
            # making one unphysical — measures no noise)
        unmet = set(r.get("unmet") or ())
        below = r.get("degenerate") == "below the noise held out" or (
            unmet == {"heldout_gain"} and not r.get("heldout_gap_before"))
        if below and not unmet & {"in_sample", "bic"}:
            estimate = sigma * float(r["field_error_after"]) / float(r["heldout_noise_floor"])
            if estimate < OVERSTATED * sigma and (best is None or estimate < best[0]):
                best = (estimate, name, float(r["delta_bic"]))
    if best is None:
        return None
    estimate, name, delta_bic = best
    return estimate, (f"re-estimated from {name}'s held-out field error (its features are functions of time, "
                      f"temperature or current alone, and held out it predicted the readings to {estimate:.4g}: "
                      f"under the {sigma:.4g} first estimated, which held the effect itself; ΔBIC {delta_bic:.1f}; "
                      "an upper bound on the noise)")


OVERSTATED = 0.8  # a second pass when a candidate's held-out error puts the noise under this × the σ estimated


def _line_bounds(d) -> None:
    """Each line's (periodic_interference's, and each of its episodes') frequency and drift rate bounds
    (report.line_standard_errors) into its row: `frequency_se_hz`, `rate_se_hz_per_s` (JSON readers had the
    text's ± only)."""
    from .report import line_standard_errors

    for r in d.ranking:
        if r["effect"] != "periodic_interference" or not r.get("frequency_hz"):
            continue
        if r.get("line_coefficients") is None and r.get("coefficients") is None:
            continue  # (absorbed by the base before any fit — a one-axis turntable's turning rate: no line fitted)
        for line in [r] + list(r.get("episodes") or []):
            if line.get("frequency_hz"):
                se_f, se_rate = line_standard_errors(d, {**r, **line})
                line["frequency_se_hz"], line["rate_se_hz_per_s"] = se_f, se_rate
