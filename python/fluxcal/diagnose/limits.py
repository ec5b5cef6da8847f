"""Detection limits: how large each candidate effect must be before this recording's diagnosis confirms it.

A real recording carries its own departures from the model (slow noise, a magnet it passed, a phone's ~1 % of
the field), and they hide small effects: a diagnosis that finds nothing does not say there is nothing. The
limit is measured on the recording itself. Each candidate is added to it (`fluxcal.sim.inject`: the effect's
typical shape, seeded, its size times a strength) and the recording is diagnosed with that candidate alone, at
strengths doubling from the typical size down, or up, until the candidate is confirmed for most of the shapes
(seeds) and not below. The limit is the added change's largest size over the recording (in % of the field and
in the readings' units; a delay in ms), between the last size not confirmed and the first confirmed.

Alone, a candidate meets the same tests as in the full diagnosis (the likelihood ratio with the full run's
Bonferroni count, ΔBIC, the held-out test), but no other candidate competes for the departure, so the limit is
a lower bound; at the limit the full diagnosis is run once more (on the first shape confirmed alone) and the
row says what it named.

    limits = fluxcal.detection_limits(recording)   # or (samples, t=..., temp=..., reference=...)
    print(limits.text())
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._arrays import as_samples
from ..sim.effects import CANDIDATES
from ..sim.inject import inject, injectable
from .core import NOISE_CANDIDATES, _jsonable, diagnose, recording_inputs, usable_regressors

STRENGTHS = 2.0 ** np.arange(-7, 6)  # times each effect's typical size: 1/128 … 32
START = 7                            # STRENGTHS[START] = 1: the typical size first
MADE_UP = {"temp": "temperature", "current": "current"}
NEEDS = {c.name: set(c.needs) for c in CANDIDATES}  # each candidate's regressors


@dataclass
class DetectionLimits:
    """Per candidate (`rows`, in the full diagnosis' order of names): `effect`; `status` "limit" (confirmed from
    `found_at` on, not at `not_at`: sizes in % of the field, `found_at_units`/`not_at_units` in the readings'
    units, or ms for a delay; `not_at` None when confirmed at the smallest size tried), "in_recording" (the
    candidate alone is confirmed on the untouched recording, with a made-up regressor for most of the shapes: no
    limit to give), "absorbed" (the base model's parameters take it whole), "not_found" (not confirmed up to
    `not_at`, the largest size tried below one that makes the calibration fail — `refused` then says why), or
    "not_tried" (`reason`); `strength` the effect's size at the limit against its typical one; `seeds_found` how
    many shapes were confirmed there; `full_run` what the full diagnosis (the recording's own regressors, and the
    made-up one this candidate needs) accepted at that size, on the first shape confirmed alone; `made_up` the
    regressors the recording lacks (or whose column has `missing` values) and the injection made up; `bonferroni`
    the count its tests were corrected for. `field`: the field's size in the readings' units; `bonferroni`: the
    full run's number of candidates."""

    source: str
    units: str
    field: float
    seeds: int
    bonferroni: int
    rows: list = field(default_factory=list)

    def row(self, effect: str) -> dict:
        return next(r for r in self.rows if r["effect"] == effect)

    def to_dict(self) -> dict:
        return {"source": self.source, "units": self.units, "field": self.field, "seeds": self.seeds,
                "bonferroni": self.bonferroni, "rows": self.rows}

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2, default=_jsonable) + "\n"

    def save_json(self, path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(self.to_json())
        return path

    def text(self) -> str:
        unit = f" {self.units}" if self.units else ""
        lines = [f"DETECTION LIMITS — {self.source}: each candidate added to the recording at doubling sizes, "
                 f"{self.seeds} shape(s) each, diagnosed alone (Bonferroni over the {self.bonferroni} candidates the full "
                 f"run tries, and those a made-up regressor adds); confirmed when most shapes are. Sizes: the largest change the effect makes to a "
                 f"reading, % of the field ({self.field:.4g}{unit})",
                 f"  {'effect':<20} {'confirmed from':<26} {'not at':<22} in the full diagnosis at that size"]

        def size(r, key):
            if r["effect"] == "time_offset":
                return f"{r[key]:.3g} ms"
            return f"{r[key]:.3g} % ({r[key + '_units']:.3g}{unit})"

        for r in self.rows:
            status = r["status"]
            if status == "limit":
                lines.append(f"  {r['effect']:<20} {size(r, 'found_at'):<26} "
                             f"{size(r, 'not_at') if r['not_at'] is not None else '(smallest tried)':<22} "
                             f"{_full_run_words(r)}")
            elif status == "not_found":
                why = "the largest tried" if "refused" not in r else f"where {_first_clause(r['refused'])}"
                lines.append(f"  {r['effect']:<20} not confirmed up to {size(r, 'not_at')}, {why}")
            elif status == "in_recording":
                lines.append(f"  {r['effect']:<20} confirmed in the untouched recording itself"
                             + (f" (with the made-up {' and '.join(MADE_UP[k] for k in r['made_up'])}: its own "
                                "departure passes for this effect)" if r["made_up"] else "") + ": no limit to give")
            elif status == "absorbed":
                lines.append(f"  {r['effect']:<20} absorbed by the base model's own parameters: no size shows it")
            else:
                lines.append(f"  {r['effect']:<20} not tried: {r['reason']}")
        made = sorted({k for r in self.rows for k in r.get("made_up", [])})
        if made:
            why = [f"its {MADE_UP[k]} column has {n} missing values" for k, n in sorted(
                {k: n for r in self.rows for k, n in r.get("missing", {}).items()}.items())]
            absent = [MADE_UP[k] for k in made if not any(k in r.get("missing", {}) for r in self.rows)]
            if absent:
                why.insert(0, f"the recording has no {' or '.join(absent)} column")
            lines.append(f"  ({'; '.join(why)}: made up for the candidates that need it — a temperature rising and "
                         "falling ±10 °C, a current stepping between throttle settings up to 20 A — so their limits "
                         "say what logging one would show)")
        lines.append("  A candidate alone has no rival for the departure: the full diagnosis may name another effect "
                     "at the same size (last column), so these are lower bounds.")
        return "\n".join(lines)


def _first_clause(message: str) -> str:
    """"samples: the readings lie nearly in one plane (…); turn …" → "the readings lie nearly in one plane"."""
    text = message.split(": ", 1)[-1]
    return text.split(" (")[0].split(";")[0][:100]


def _full_run_words(r: dict) -> str:
    found = r.get("full_run") or []
    if not found:
        return "nothing found"
    if found[0] == r["effect"]:
        return "found first"
    if r["effect"] in found:
        return f"found after {', '.join(found[:found.index(r['effect'])])}"
    return f"named {', '.join(found)} instead"


def detection_limits(samples, t=None, temp=None, current=None, reference=None, gravity=None, field_norm=None,
                     model: str | None = None, noise_sigma=None, alpha: float = 0.01,
                     names=None, seeds: int = 3, units: str = "", source: str = "samples",
                     progress: bool = False, diagnosis=None) -> DetectionLimits:
    """The detection limit of every candidate `names` (default: every one `inject` can add) in this recording
    (N×3 readings or a Recording; the regressors and options as for `fluxcal.diagnose`). `seeds`: shapes per
    size (the limit needs most of them confirmed). `diagnosis`: the recording's own full diagnosis with these
    options, when already made (else it is made here). See the module's text for the method."""
    from ..io.recording import Recording
    from ..pipeline import calibrate

    if isinstance(samples, Recording):
        samples, t, temp, current, gravity, units, source = recording_inputs(samples, t, temp, current, gravity, units)
    m = as_samples(samples)
    if isinstance(seeds, (bool, np.bool_)) or not isinstance(seeds, (int, np.integer)) or seeds < 1:
        raise ValueError(f"seeds: need a whole number ≥ 1 (shapes per size), got {seeds!r}")
    options = {"reference": reference, "gravity": gravity if reference is not None else None,
               "field_norm": field_norm, "model": model, "noise_sigma": noise_sigma, "units": units}
    # A regressor column with a blank cell is not used (as by the diagnosis): said, and made up in its place.
    own, missing = usable_regressors(temp, current)[:2]
    full = diagnosis or diagnose(m, t=t, **own, alpha=alpha, source=source, **options)
    possible = injectable(reference is not None)
    wanted = possible if names is None else list(names)
    known = list(NEEDS)
    unknown = [w for w in wanted if w not in known]
    if unknown:
        raise ValueError(f"names: unknown effect(s) {', '.join(unknown)}; known: {', '.join(known)}")
    # (each reading's |field| is the magnitude models' (the vector models refuse it): a reference beside it is left
    # to the injections)
    cal = calibrate(m, field_norm=field_norm, reference=None if np.ndim(field_norm) > 0 else reference)
    field_size = float(np.median(np.linalg.norm(m - np.asarray(cal.offset), axis=1)))
    tried = {r["effect"] for r in full.ranking}
    skipped = set(full.remaining["skipped_candidates"])
    # what the base model's own parameters take whole (a rotation against a full matrix): no size shows it
    absorbed = {r["effect"] for r in full.ranking if r.get("absorbed") and not r.get("absorbed_after")}
    inject_t = np.arange(len(m), dtype=float) if t is None else np.asarray(t, dtype=float)
    # gravity always: a magnet's field is fixed in the world, its attitude from the down direction
    inject_kw = {"t": inject_t, "reference": reference, "gravity": gravity, "field_norm": field_norm,
                 "temp": own["temp"], "current": own["current"], "calibration": cal}  # calibrated once, not per shape

    available = {"t"} | ({"timestamps"} if t is not None else set()) | {key for key in own if own[key] is not None}

    def bonferroni(made_up) -> int:
        """The full run's count of candidates, with those the made-up regressors let it try."""
        extra = [c for c in skipped if made_up and NEEDS[c] & set(made_up)
                 and NEEDS[c] <= available | set(made_up)]
        return max(len(full.ranking) + len(extra), 1)

    def run(readings, kwargs, candidates, k=1, made_up=()):
        """A diagnosis of `readings` as the user's: the recording's clock (None: row numbers), its own
        regressors, and those made up only for the candidate that needs them."""
        side = {key: kwargs.get(key) if own[key] is not None or key in made_up else None for key in ("temp", "current")}
        return diagnose(readings, candidates=candidates, alpha=alpha / k, source=source, t=t, **side, **options)

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(wanted), desc="detection limits", unit="candidate", leave=False,
                   disable=None)  # None: no bar when stderr is no terminal
    rows = []
    for name in wanted:
        made_up = [key for key in ("temp", "current") if own[key] is None and key in NEEDS[name]]
        row = {"effect": name, "made_up": made_up, "missing": {k: missing[k] for k in made_up if missing.get(k)}}
        if name in NOISE_CANDIDATES:
            row.update(status="not_tried", reason="a noise, not an effect with a size")
        elif name not in possible:
            row.update(status="not_tried", reason=(
                "a rotation or a delay of the field: it needs reference vectors" if name in ("misalignment", "time_offset")
                else "not added to recordings (a full soft-iron matrix absorbs it)"))
        elif name not in tried and not made_up:
            row.update(status="not_tried", reason="the full diagnosis does not try it on this recording (see its "
                                                   "'not tried' lines)")
        elif name in absorbed:
            row.update(status="absorbed")
        else:
            k = bonferroni(made_up)
            row["bonferroni"] = k
            # The untouched recording with the effect's regressors (its own, or made up as for each shape: a
            # made-up temperature that happens to follow the recording's own departure is one shape in many)
            shapes = range(seeds if made_up else 1)
            confirmed = sum(name in run(m, inject(m, [name], seed, strength=0.0, **inject_kw).kwargs, [name], k,
                                        made_up).accepted for seed in shapes)
            if confirmed >= len(shapes) // 2 + 1:
                row.update(status="in_recording")
            else:
                row.update(_bisect(name, m, inject_kw, lambda x, kw, c, full_run=False: run(
                    x, kw, c, 1 if full_run else k, made_up), seeds, field_size))
        rows.append(row)
        if bar:
            bar.update(1)
    if bar:
        bar.close()
    return DetectionLimits(source=source, units=units, field=field_size, seeds=seeds, bonferroni=bonferroni(()),
                           rows=rows)




def _bisect(name, m, inject_kw, run, seeds: int, field_size: float) -> dict:
    """Walk the strengths from the typical size down while most shapes are confirmed, or up until they are. A
    size at which most shapes make the calibration itself fail is too large: the walk goes down from it, or stops
    going up there."""
    majority = seeds // 2 + 1
    refused = {}  # strength index → (how many shapes failed, the first message)

    def trial(i):
        found, sizes, first = 0, [], None
        for seed in range(seeds):
            inj = inject(m, [name], seed, strength=float(STRENGTHS[i]), **inject_kw)
            try:
                if name in run(inj.readings, inj.kwargs, [name]).accepted:
                    found, first = found + 1, first or inj
            except ValueError as error:  # so large an effect that the calibration itself fails: not confirmed
                count, message = refused.get(i, (0, str(error)))
                refused[i] = (count + 1, message)
            sizes.append(abs(inj.effects[0].delta) * 1e3 if name == "time_offset"
                         else float(np.max(np.linalg.norm(inj.readings - m, axis=1))))
        return found, float(np.median(sizes)), first

    def too_large(i):
        return refused.get(i, (0, ""))[0] >= majority

    results = {}
    i = START
    results[i] = trial(i)
    step = -1 if results[i][0] >= majority or too_large(i) else 1
    while 0 <= i + step < len(STRENGTHS) and not (step == 1 and too_large(i)):
        i += step
        results[i] = trial(i)
        confirmed_here = results[i][0] >= majority
        if (step == 1 and confirmed_here) or (step == -1 and not confirmed_here and not too_large(i)):
            break
    confirmed = sorted(j for j, r in results.items() if r[0] >= majority)
    missed = sorted(j for j, r in results.items() if r[0] < majority)
    scale = 1.0 if name == "time_offset" else 100.0 / field_size

    def sized(prefix, j):
        if j is None:
            return {prefix: None, prefix + "_units": None}
        return {prefix: results[j][1] * scale, prefix + "_units": results[j][1]}

    if not confirmed:
        largest = max((j for j in missed if not too_large(j)), default=missed[0])
        row = {"status": "not_found", "strength": float(STRENGTHS[largest]), **sized("not_at", largest)}
        if largest + 1 in refused or largest in refused:
            row["refused"] = refused.get(largest + 1, refused.get(largest))[1]
        return row
    at = confirmed[0]
    below = max([j for j in missed if j < at], default=None)
    inj = results[at][2]  # the first shape confirmed alone
    return {"status": "limit", "strength": float(STRENGTHS[at]), "seeds_found": results[at][0],
            **sized("found_at", at), **sized("not_at", below),
            "full_run": list(run(inj.readings, inj.kwargs, None, full_run=True).accepted)}
