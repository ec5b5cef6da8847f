"""Live calibration from a serial port: the ellipsoid fit follows the readings as they arrive.

Each record adds its reading to the constant-size sufficient statistics of the ellipsoid fit
(fluxcal.EllipsoidMoments: O(1) per record); a few times a second the fit is solved from them
(constant time too) and the display shows which of the 96 direction bins (fluxcal.coverage: cube
sphere, 6 faces × 4 × 4 cells) the corrected readings have not reached yet, a progress bar of the
bins covered, and the quality: std/mean of |h| after the current fit. The session ends when coverage
and quality meet the thresholds, at the duration, or on Ctrl-C; the calibration written is then
fitted on all readings kept (fluxcal.calibrate: adjusted least squares refined by maximum likelihood),
and the raw recording is written as it arrives when asked (the Recorder's writer, flushed per record).
"""
from __future__ import annotations

import math
import numbers
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from . import _core
from .coverage import N_DIRECTION_BINS
from .ellipsoid import EllipsoidMoments
from .calibration import json_path
from .outliers import GLITCH_RUN, _runs
from .io.serial import Recorder, add_stream_arguments, check_output, decoder_from_args, stream_units

FACES = ("+X", "-X", "+Y", "-Y", "+Z", "-Z")
MAG = ("mx", "my", "mz")
# An ADC rail (a saturated axis: ±32767 counts, ±4912 µT) without knowing the sensor's range: an axis' extreme
# value, read at least RAIL_REPEATS times, by more readings than lie within RAIL_BAND of the span (at least
# RAIL_STEPS of its quantisation steps) inside it (a turning sensor's axis approaches its extreme gradually: the
# readings beyond a rail pile up on it), in varied directions (the other axes of the pile spread over more than
# RAIL_SPREAD of their span: not one direction held still), on an axis of at least RAIL_LEVELS distinct values
# (not a sensor lying still). On simulated quantised recordings this finds a rail that clips 2 % of the readings,
# and none where there is none, also with the sensor held at an axis' extreme.
RAIL_REPEATS, RAIL_BAND, RAIL_STEPS, RAIL_SPREAD, RAIL_LEVELS = 5, 0.01, 4, 0.05, 20


def find_rails(readings) -> np.ndarray:
    """2×3 array: the low (row 0) and high (row 1) rail of each axis of `readings` (N×3), NaN where none."""
    m = np.asarray(readings, dtype=float).reshape(-1, 3)
    rails = np.full((2, 3), np.nan)
    if len(m) < RAIL_REPEATS:
        return rails
    lo, hi = m.min(axis=0), m.max(axis=0)
    span = hi - lo
    for axis in range(3):
        if not span[axis] > 0:
            continue
        v, others, levels = m[:, axis], [k for k in range(3) if k != axis], None
        for side, extreme in enumerate((lo[axis], hi[axis])):
            at = v == extreme
            piled = int(at.sum())
            if piled < RAIL_REPEATS:
                continue
            if levels is None:
                levels = np.unique(v)
                if len(levels) < RAIL_LEVELS:
                    break
            width = max(RAIL_BAND * span[axis], RAIL_STEPS * np.min(np.diff(levels)))
            if piled <= np.count_nonzero(np.abs(v - extreme) <= width) - piled:
                continue
            if not np.any(np.ptp(m[at][:, others], axis=0) > RAIL_SPREAD * span[others]):
                continue
            rails[side, axis] = extreme
    return rails


def direction_bins(fields) -> np.ndarray:
    """Bin (0 … 95, −1 for a zero or non-finite vector) of each row of `fields`: the cube-sphere bins of
    cpp/include/fluxcal/coverage.hpp (direction_bin), vectorised so that the live display can say which
    bins are empty; tests hold it equal to fluxcal._core.direction_bin."""
    v = np.asarray(fields, dtype=float).reshape(-1, 3)
    a = np.abs(v)
    axis = np.where((a[:, 0] >= a[:, 1]) & (a[:, 0] >= a[:, 2]), 0, np.where(a[:, 1] >= a[:, 2], 1, 2))
    rows = np.arange(len(v))
    big, u, w = v[rows, axis], v[rows, (axis + 1) % 3], v[rows, (axis + 2) % 3]
    mag = np.abs(big)
    tm = 0.41421356237309503 * mag  # tan(π/8): equal-angle cells
    cu = (u >= -tm).astype(int) + (u >= 0) + (u >= tm)
    cw = (w >= -tm).astype(int) + (w >= 0) + (w >= tm)
    bins = (2 * axis + (big < 0)) * 16 + cu * 4 + cw
    bins[~((mag > 0) & np.all(np.isfinite(v), axis=1))] = -1  # any non-finite component, as the core
    return bins


def coverage_map(seen) -> str:
    """The 96 bins as six 4×4 faces, '#' seen and '.' empty (rows: first in-face axis, columns: second;
    faces +X -X +Y -Y +Z -Z: the direction of the field in the sensor frame)."""
    seen = np.asarray(seen, dtype=bool).reshape(6, 4, 4)
    lines = ["  ".join(f"{f:^4}" for f in FACES)]
    for row in range(4):
        lines.append("  ".join("".join("#" if seen[face, row, col] else "." for col in range(4)) for face in range(6)))
    return "\n".join(lines)


def missing_text(seen) -> str:
    """Which faces still have empty bins, fullest gaps first: "missing: -Z 12/16, +Y 3/16"."""
    empty = (~np.asarray(seen, dtype=bool)).reshape(6, 16).sum(axis=1)
    if not empty.any():
        return "all 96 directions seen"
    order = np.argsort(-empty, kind="stable")
    return "missing: " + ", ".join(f"{FACES[f]} {empty[f]}/16" for f in order if empty[f])


@dataclass
class LiveState:
    records: int
    coverage: float = 0.0          # fraction of the 96 bins the corrected readings reach
    spread: float = float("nan")   # std/mean of |h| after the current fit
    seen: np.ndarray | None = None
    calibration: object = None
    error: str = ""                # why there is no fit yet (too few readings, planar so far, ...)
    zeros: int = 0                 # readings of exactly 0,0,0 left out
    rails: int = 0                 # readings with an axis at an ADC rail left out (see find_rails)


def _short_runs(mask: np.ndarray) -> np.ndarray:
    """The True runs of `mask` no longer than calibrate's glitches (outliers.GLITCH_RUN; a run still open at the
    end counts as short)."""
    out = np.zeros_like(mask, dtype=bool)
    for first, last in _runs(mask):
        if last - first < GLITCH_RUN:
            out[first:last + 1] = True
    return out


def _moments_of(readings: np.ndarray) -> tuple:
    """(the ellipsoid moments of `readings`, normalised by their own centre and scale; that scale)."""
    centre, scale = _core.normalisation(readings)
    moments = EllipsoidMoments(centre, scale)
    moments.add(readings)
    return moments, scale


class LiveFit:
    """Readings in, current fit and coverage out. add() is O(1) (moments update), except when the readings
    have spread `regrow` times beyond the normalisation in use: then the moments are rebuilt from every
    reading kept (a few times per session, as the spread only grows); state() solves the fit from the
    moments (constant time) and bins the corrected readings kept so far (one vectorised pass).

    Left out of the fit (and counted; the recording keeps them): readings of exactly 0,0,0, and readings with
    an axis at an ADC rail (find_rails). Rails are judged on all readings in state(): when they change (a rail
    appears, or the axis later reads beyond a value taken for one) the moments are rebuilt from the readings
    kept; add() leaves out a reading at a rail already known."""

    def __init__(self, field_norm: float | None = None, units: str = "", warmup: int = 20, regrow: float = 4.0):
        if field_norm is not None and not (isinstance(field_norm, numbers.Real) and math.isfinite(field_norm)
                                           and field_norm > 0):
            raise ValueError(f"field_norm: {field_norm!r} must be a positive field magnitude (None: the fitted radius)")
        if not (isinstance(warmup, numbers.Integral) and warmup >= 1):
            raise ValueError(f"warmup: {warmup!r} must be a whole number of readings ≥ 1")
        if not (isinstance(regrow, numbers.Real) and regrow > 1):
            raise ValueError(f"regrow: {regrow!r} must be a factor > 1")
        self.field_norm, self.units, self.warmup = field_norm, units, warmup
        self.regrow = regrow  # renormalise when the readings spread this many times the scale in use
        self._readings = np.empty((1024, 3))  # every reading but 0,0,0, in order
        self._railed = np.zeros(1024, dtype=bool)  # at a rail: left out of the fit
        self._far = np.zeros(1024, dtype=bool)  # a glitch far off every other reading: left out of the live fit only
        self.far = 0
        self._n = 0
        self.count = 0  # readings in the fit
        self.zeros = 0  # readings of exactly 0,0,0 left out
        self.rails = 0  # readings at a rail left out
        self.rail_values = np.full((2, 3), np.nan)  # low and high rail of each axis (NaN: none)
        self._moments = None
        self._scale = 0.0
        self._lo, self._hi = np.full(3, np.inf), np.full(3, -np.inf)  # bounding box of the readings

    @property
    def readings(self) -> np.ndarray:
        """The readings in the fit (not 0,0,0, not at a rail), in order."""
        if not self.rails:
            return self._readings[:self._n]
        return self._readings[:self._n][~self._railed[:self._n]]

    @property
    def _fit_readings(self) -> np.ndarray:
        """The readings the live fit uses: `readings` without the glitches _update_far found (one bit flip, an
        overflow code, made every live fit of the session fail). The calibration written is fitted on `readings`,
        whose outliers calibrate() screens itself, as `fluxcal calibrate` does on the raw recording."""
        keep = ~(self._railed[:self._n] | self._far[:self._n])
        return self._readings[:self._n][keep]

    def rail_text(self) -> str:
        """Which axes sit at which rail: "mx at 4912, mz at -4912"."""
        return ", ".join(f"{MAG[axis]} at {self.rail_values[side, axis]:g}" for axis in range(3) for side in (0, 1)
                         if np.isfinite(self.rail_values[side, axis]))

    def add(self, reading) -> None:
        reading = np.asarray(reading, dtype=float)
        if reading.shape != (3,) or not np.all(np.isfinite(reading)):
            # refused before it reaches the moments: one NaN made every later fit of the session fail
            raise ValueError(f"reading: {reading.tolist()} is not three finite numbers; not added (the fit keeps "
                             "its readings)")
        if not reading.any():  # exactly 0,0,0: an I²C glitch, not a field (calibrate() leaves them out too)
            self.zeros += 1
            return
        if self._n == len(self._readings):
            self._readings = np.concatenate([self._readings, np.empty_like(self._readings)])
            self._railed = np.concatenate([self._railed, np.zeros_like(self._railed)])
            self._far = np.concatenate([self._far, np.zeros_like(self._far)])
        row = self._readings[self._n]
        row[:] = reading
        self._n += 1
        if np.any(self.rail_values == row):  # at a rail already known: left out
            self._railed[self._n - 1] = True
            self.rails += 1
            return
        self.count += 1
        self._lo, self._hi = np.minimum(self._lo, row), np.maximum(self._hi, row)
        if self._moments is None:
            if self.count >= self.warmup:  # the first readings set the normalisation of the sums
                self._renormalise()
        elif 0.5 * np.max(self._hi - self._lo) > self.regrow * self._scale:
            # a sensor that lay still through the warm-up: its noise was the scale, far too small for a
            # turning sensor's sums; re-derive it from every reading kept (a few times at most: it grows)
            self._renormalise()
        else:
            self._moments.add(row[None])

    def _update_rails(self) -> None:
        """Judge the rails on every reading; when they changed, mark the readings at them and rebuild the fit."""
        rails = find_rails(self._readings[:self._n])
        if np.array_equal(rails, self.rail_values, equal_nan=True):
            return
        self.rail_values = rails
        railed = np.any(self._readings[:self._n, None, :] == rails[None], axis=(1, 2))
        self._railed[:self._n] = railed
        self._far[:self._n] &= ~railed
        self.rails = int(railed.sum())
        self._rebuild()

    def _rebuild(self) -> None:
        """After the marks (rails, glitches) changed: the counts, the range and the moments of the readings kept."""
        self.far = int(self._far[:self._n].sum())
        self.count = self._n - self.rails - self.far
        kept = self._fit_readings
        self._lo, self._hi = (kept.min(axis=0), kept.max(axis=0)) if len(kept) else (np.full(3, np.inf),
                                                                                     np.full(3, -np.inf))
        self._moments = None
        if self.count >= self.warmup:
            self._renormalise()

    def _renormalise(self) -> None:
        self._moments, self._scale = _moments_of(self._fit_readings)

    FAR = 4.0  # a reading farther than FAR × the spread of the bulk from its median is a glitch, not a direction

    def _update_far(self) -> None:
        """Mark readings far outside the bulk of all others in runs of at most outliers.GLITCH_RUN (a bit flip:
        4000.5 among readings of radius 50; an overflow code -4096), as calibrate's outlier screen does; when the marks change,
        rebuild the moments without them. The bulk's size is the larger of the median distance from the median
        and the 1-99 % range. A sensor held in a small cap and then turned keeps the readings of the turn: they
        come in a longer run (a review: 24 readings of a quick turn after 3000 at rest had been dropped for good)."""
        n = self._n
        if n < self.warmup:
            return
        ok = ~self._railed[:n]
        m = self._readings[:n]
        centre = np.median(m[ok], axis=0)
        r = np.linalg.norm(m - centre, axis=1)
        lo, hi = np.percentile(m[ok], [1, 99], axis=0)
        size = max(float(np.median(r[ok])), 0.5 * float(np.max(hi - lo)))
        far = _short_runs(ok & (r > self.FAR * size)) if size > 0 else np.zeros(n, dtype=bool)
        if np.array_equal(far, self._far[:n]):
            return
        self._far[:n] = far
        self._rebuild()

    def _off_the_shell(self, cal):
        """The fit again without glitches near the bulk that _update_far keeps: readings off the fitted shell by more
        than calibrate's outlier line (outliers._threshold, robust σ of |h|) in runs of at most GLITCH_RUN (a UART
        dropping a byte: four readings at 1.3–1.8× the field had held a blind check's live |h| spread at 3.1–3.9 %
        against 0.8 % without them, so the session never stopped; the calibration written, screened by calibrate(),
        met every threshold). Not kept between calls: judged on each fit (a longer run, a magnet, stays)."""
        from .outliers import _robust_z, _threshold

        kept = self._fit_readings
        z, sigma = _robust_z(np.linalg.norm(cal.apply(kept), axis=1))
        off = _short_runs(z > _threshold(len(kept), 0.01, 9)) if sigma > 0 else np.zeros(len(kept), dtype=bool)
        if not off.any() or off.sum() > 0.05 * len(kept):
            return cal
        return _moments_of(kept[~off])[0].fit(field_norm=self.field_norm, units=self.units)

    def state(self) -> LiveState:
        self._update_rails()
        self._update_far()
        state = LiveState(records=self.count, seen=np.zeros(N_DIRECTION_BINS, dtype=bool), zeros=self.zeros,
                          rails=self.rails)
        if self._moments is None:
            state.error = f"{self.count} readings, fitting from {self.warmup}"
            return state
        try:
            cal = self._moments.fit(field_norm=self.field_norm, units=self.units)
            cal = self._off_the_shell(cal)
        except ValueError as exc:  # e.g. all readings so far in one plane
            state.error = str(exc)
            return state
        bins = direction_bins(cal.apply(self._fit_readings))
        state.seen[bins[bins >= 0]] = True
        state.coverage = float(state.seen.mean())
        state.spread = float(cal.summary["norm_std_over_mean"])
        state.calibration = cal
        return state


# Once the live fit meets the thresholds, the calibration that will be written is computed from the readings so far
# (at most this often) and must meet them too, identifiable: the live fit alone had stopped a ±15° band "done" with
# a calibration that did not determine a22, and said coverage ≥ 30 % met beside the 25 % it printed (a blind check)
CHECK_EVERY_S = 1.0


class LiveSession:
    """Feeds a LiveFit from the Recorder's records, refreshes the display and says when to stop.

    `mag_index`: where mx, my, mz are in a record. `decoder` (the Recorder's): where they are is looked up in its
    columns whenever those change — a header the device prints at start-up names them (decoder_from_args with
    header_columns, as `fluxcal record` takes it): `seq,mx[uT],my[uT],mz[uT]` puts mx second."""

    def __init__(self, fit: LiveFit, mag_index=None, min_coverage: float = 0.9, max_spread: float = 0.03,
                 min_records: int = 200, refresh_s: float = 0.25, show: bool = True, clock=time.monotonic,
                 decoder=None):
        if mag_index is None and decoder is None:
            raise ValueError("LiveSession: give mag_index (where mx, my, mz are in a record) or the decoder")
        self.fit, self.decoder = fit, decoder
        self._names = None  # the decoder's column names mag_index was found in
        self.mag_index = list(mag_index) if mag_index is not None else self._find_mag()
        self.min_coverage, self.max_spread, self.min_records = min_coverage, max_spread, min_records
        self.refresh_s, self.clock = refresh_s, clock
        self.state = LiveState(records=0)
        self.met = False
        self.held_back = ""  # why the calibration does not meet what the live fit does (said once per reason)
        self._last_check = -float("inf")
        self._last = -float("inf")
        self._last_map, self._last_missing = -float("inf"), ""
        self.bar = tqdm(total=N_DIRECTION_BINS, desc="direction bins", file=sys.stderr, disable=not show,
                        mininterval=0.2, dynamic_ncols=True,
                        bar_format="{desc}: {percentage:3.0f}%|{bar}| {n}/{total} [{elapsed}{postfix}]")

    def _find_mag(self) -> list:
        """mx, my, mz's places among the decoder's columns (and the unit a header printed for them, for the fit)."""
        self._names = self.decoder.names
        missing = [m for m in MAG if m not in self._names]
        if missing:  # (a header names the columns only when it holds all three)
            raise ValueError(f"live calibration needs columns mx,my,mz; {', '.join(missing)} not among "
                             f"{','.join(self._names)}")
        self.fit.units = self.fit.units or getattr(self.decoder, "units", {}).get("mx", "")
        return [self._names.index(m) for m in MAG]

    def on_record(self, t_host: float, values) -> bool:
        if self.decoder is not None and self.decoder.names is not self._names:  # the device's header named them
            self.mag_index = self._find_mag()
        self.fit.add([values[j] for j in self.mag_index])
        now = self.clock()
        if now - self._last < self.refresh_s:
            return False
        self._last = now
        return self.refresh()

    def refresh(self) -> bool:
        """Refit, update the display; True when the thresholds are met."""
        s = self.state = self.fit.state()
        live = (s.calibration is not None and s.records >= self.min_records and s.coverage >= self.min_coverage
                and s.spread <= self.max_spread)
        if not live:
            self.met = False
        elif (now := self.clock()) - self._last_check >= CHECK_EVERY_S:
            self._last_check = now
            self.met = self._calibration_meets()
        self.bar.n = int(round(s.coverage * N_DIRECTION_BINS))
        quality = f"|h| std/mean {100 * s.spread:.2f} %" if s.calibration is not None else s.error[:50]
        zeros = f", {s.zeros} of 0,0,0 left out" if s.zeros else ""
        zeros += f", {s.rails} at a rail left out" if s.rails else ""
        self.bar.set_postfix_str(f"{quality}, {s.records} records{zeros}", refresh=False)
        self.bar.refresh()
        missing = missing_text(s.seen) if s.calibration is not None else ""
        now = self.clock()
        if missing and not self.bar.disable and missing != self._last_missing and now - self._last_map >= 2.0:
            self.bar.write(missing)  # which way to turn the sensor next
            self._last_map, self._last_missing = now, missing
        return self.met

    def close(self) -> None:
        self.bar.close()

    def _calibration_meets(self) -> bool:
        """The calibration of the readings so far (as the one written: calibrate() without the outliers it screens)
        meets the thresholds and is identifiable; what it misses is said once."""
        from .pipeline import calibrate

        try:
            cal = calibrate(self.fit.readings, field_norm=self.fit.field_norm, units=self.fit.units)
        except ValueError as exc:
            why = str(exc)
        else:
            if self.met_by(cal):
                return True
            s = cal.summary
            why = (next((w for w in s.get("warnings", []) if "identif" in w), "not identifiable")
                   if not s.get("identifiable", True) else
                   f"coverage {100 * s['direction_coverage']:.0f} %, |h| std/mean {100 * s['norm_std_over_mean']:.2f} %")
        if why != self.held_back and not self.bar.disable:
            self.bar.write(f"the live fit meets the thresholds, the calibration not yet: {why[:160]} — keep turning")
        self.held_back = why
        return False

    def met_by(self, cal) -> bool:
        """Whether the calibration written meets the thresholds, identifiable (the numbers printed beside the
        verdict). A session that stopped "done" stopped on this same calibration (_calibration_meets)."""
        return not self.unmet_by(cal)

    def unmet_by(self, cal) -> list:
        """The thresholds the calibration written misses, each with its value (empty when met_by): "coverage 89.6 %
        < 90 %" — a verdict "NOT met" beside a coverage printed rounded to 90 % had named none."""
        s, out = cal.summary, []
        if not s["samples"] >= self.min_records:
            out.append(f"{s['samples']} records < {self.min_records}")
        if not s["direction_coverage"] >= self.min_coverage:
            out.append(f"coverage {100 * s['direction_coverage']:.1f} % < {100 * self.min_coverage:.0f} %")
        if not s["norm_std_over_mean"] <= self.max_spread:  # (NaN: not met)
            out.append(f"|h| std/mean {100 * s['norm_std_over_mean']:.3f} % > {100 * self.max_spread:.2f} %")
        if not s.get("identifiable", True):
            out.append("not identifiable")
        return out

    def thresholds_text(self) -> str:
        return (f"coverage ≥ {100 * self.min_coverage:.0f} %, |h| std/mean ≤ {100 * self.max_spread:.2f} %, "
                f"≥ {self.min_records} records, identifiable")


def add_live_parser(subparsers):
    p = subparsers.add_parser(
        "live", help="calibrate live from a serial port: coverage display, stop when good enough",
        description="Fit the magnetometer while it is turned: shows the direction bins still empty, a progress "
                    "bar and the current |h| std/mean; stops when coverage and quality meet the thresholds, at "
                    "--duration or on Ctrl-C, and writes the calibration (fitted on every reading kept). "
                    "Exit status 0 when the thresholds were met, 1 when the calibration was written without "
                    "meeting them, 2 on a bad argument, a port that cannot be opened, too few readings or a "
                    "--raw file that could not be written (the calibration is written all the same).")
    add_stream_arguments(p)
    p.add_argument("-o", "--output", required=True, help="calibration JSON to write")
    p.add_argument("--raw", default=None, help="also write every record to this recording CSV as it arrives (an "
                                               "existing non-empty file is refused unless --overwrite)")
    p.add_argument("--overwrite", action="store_true", help="replace the --raw file when it exists (default: refuse)")
    p.add_argument("--min-coverage", type=float, default=0.9,
                   help="fraction of the 96 direction bins to reach (default 0.9; a hand-turned full recording "
                        "reaches 0.9-1.0)")
    p.add_argument("--max-spread", type=float, default=0.03,
                   help="largest std/mean of |h| after the fit (default 0.03: cheap MEMS sensors reach 1.3-2.7 %%)")
    p.add_argument("--min-records", type=int, default=200, help="fewest records before stopping (default 200)")
    p.add_argument("--field-norm", type=float, default=None, help="known |field| in the units of h")
    p.add_argument("--quiet", action="store_true",
                   help="no live progress bar or coverage display while recording (the summary at the end still "
                        "prints, its coverage map included)")
    p.add_argument("--warn-after", type=float, default=5.0, metavar="S",
                   help="warn on stderr when no good record has come after S seconds (default 5), as record does")
    p.set_defaults(run=cmd_live)
    return p


def _same_file(a, b) -> bool:
    a, b = Path(a), Path(b)
    if a.exists() and b.exists():
        return os.path.samefile(a, b)  # also through links
    return a.resolve() == b.resolve()


def cmd_live(args) -> int:
    from .pipeline import calibrate

    if not 0 < args.min_coverage <= 1:
        raise ValueError(f"--min-coverage: {args.min_coverage} is not a fraction in (0, 1]")
    if not args.max_spread > 0:
        raise ValueError(f"--max-spread: {args.max_spread} is not positive")
    if args.raw and _same_file(args.raw, args.output):
        raise ValueError(f"--raw {args.raw} and -o {args.output} are the same file: the calibration would replace "
                         "the recording; name two files")
    check_output(args.output, "-o")  # written at the end: a bad path must not cost the session
    json_path(args.output, "-o")  # (nor a name that says another format)
    if args.raw:
        check_output(args.raw, "--raw", args.overwrite)
    # without --columns, a header the device prints at start-up names the columns, as for `fluxcal record`
    decoder = decoder_from_args(args, header_columns=True)
    missing = [m for m in MAG if m not in decoder.names]
    if missing:
        raise ValueError(f"--columns: live calibration needs columns mx,my,mz; {', '.join(missing)} not among "
                         f"{','.join(decoder.names)}")
    units = stream_units(decoder)
    mag_units = {units.get(m, "") for m in MAG}
    if len(mag_units) > 1:
        raise ValueError(f"--columns: mx, my, mz have different units ({', '.join(sorted(mag_units))})")
    unit = mag_units.pop()
    session = LiveSession(LiveFit(args.field_norm, unit), None, args.min_coverage, args.max_spread,
                          args.min_records, show=not args.quiet, decoder=decoder)
    recorder = Recorder(args.port, args.baud, decoder, output=args.raw, duration=args.duration, units=units,
                        metadata={"format": args.format, "purpose": "fluxcal live calibration"},
                        on_record=session.on_record, hold_ctrl_c=True,  # Ctrl-C twice must not cost the calibration
                        warn_after=args.warn_after,  # (a baud mismatch had shown "0 records" until the end, unsaid)
                        warn=lambda text: tqdm.write(f"fluxcal live: warning: {text}", file=sys.stderr))
    try:
        stats = recorder.run()
        session.refresh()  # the last records, and the state after a stop by duration or Ctrl-C
    finally:
        session.close()
    state = session.state
    print(stats.report())
    if stats.write_error:  # the readings received are still in memory: calibrate from them
        print(f"fluxcal live: error: {stats.write_error}", file=sys.stderr, flush=True)
    if state.calibration is not None:  # (without a fit no reading has a direction: an all-empty map read as "nothing")
        print(coverage_map(state.seen))
        print(missing_text(state.seen))
    else:
        print(f"no live fit, so no map of directions: {state.error}")
    if session.fit.zeros:
        print(f"left out {session.fit.zeros} readings of exactly 0,0,0 (sensor glitches; they stay in the raw "
              "recording)")
    if session.fit.rails:
        print(f"left out {session.fit.rails} readings with an axis at an ADC rail ({session.fit.rail_text()}: its "
              "extreme value, repeated: the sensor saturated; they stay in the raw recording)")
    # kv lines, a csv header: as the device printed it
    printed = {getattr(decoder, "units", {}).get(m, "") for m in MAG} - {""}
    if not unit and len(printed) > 1:
        kept = f"; the raw records are in {args.raw}" if args.raw else ""
        raise ValueError(f"{args.port}: the device printed mx, my, mz in different units ({', '.join(sorted(printed))})"
                         f"; not calibrated (no conversion): set the device to one unit for all three axes{kept}")
    unit = unit or getattr(decoder, "units", {}).get("mx", "")
    readings = session.fit.readings
    if len(readings) < 9:
        raise ValueError(f"{args.port}: {len(readings)} good readings, need at least 9 to calibrate"
                         + (f" (raw records in {args.raw})" if args.raw else ""))
    cal = calibrate(readings, field_norm=args.field_norm, units=unit)
    met = session.met_by(cal)
    cal.metadata.update(source=f"serial port {args.port} at {args.baud} baud (fluxcal live)",
                        records=stats.records, rejected=stats.rejected_text(), reconnects=stats.reconnects,
                        stopped=stats.stopped, thresholds=session.thresholds_text(), thresholds_met=met,
                        live_coverage=state.coverage, live_spread=state.spread, zeros_left_out=session.fit.zeros,
                        rails_left_out=session.fit.rails, rails=session.fit.rail_text())
    if args.raw:
        cal.metadata["recording"] = str(args.raw)
    cal.save(args.output)
    s = cal.summary
    unmet = session.unmet_by(cal)
    verdict = "met" if met else "NOT met" + (": " + "; ".join(unmet) if unmet else "")
    print(f"Calibration from {len(readings)} readings ({s.get('method', cal.model)}): offset "
          f"{np.array2string(cal.offset, precision=6)} {unit}".rstrip()
          + f", |h| std/mean {100 * s['norm_std_over_mean']:.3f} %, coverage "
          f"{100 * s['direction_coverage']:.0f} % of directions; thresholds ({session.thresholds_text()}) "
          f"{verdict}. Wrote {args.output}" + (f" and the recording {args.raw}." if args.raw else "."))
    for warning in s.get("warnings", []):
        print(f"warning: {warning}")
    if stats.write_error:
        return 2
    return 0 if met else 1
