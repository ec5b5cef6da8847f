"""Fleet calibration: every recording in a folder calibrated as one Dask task, plus a fleet summary.

    from fluxcal.batch import calibrate_fleet
    result = calibrate_fleet("recordings/", "calibrations/", workers=4)       # a local Dask cluster
    result = calibrate_fleet("recordings/", "calibrations/", scheduler="tcp://host:8786")
    print(result.report())

Each recording `<unit>.csv` gives `<out>/<unit>.json` (fluxcal.Calibration, written atomically). A unit
that cannot be calibrated (unreadable file, NaN, planar readings, ...) is recorded with its message in
`<out>/failures.json` and does not stop the batch. Re-running skips every unit whose calibration exists,
is valid, and was made from the same recording bytes with the same settings. The fleet summary
(`fleet_summary.csv`, one row per unit; `fleet_summary.json`, distributions and outlier units) is
rewritten from all units, calibrated now or before.

With a remote scheduler the workers need fluxcal installed and must see the same paths (a shared file
system): tasks receive absolute paths and write the calibrations themselves. The local cluster starts
its workers as new processes, so a script calling calibrate_fleet needs the usual
`if __name__ == "__main__":` guard. Dask costs a few milliseconds per task: for small recordings (a few
hundred readings, ~1 ms to calibrate) a plain loop over calibrate_unit is faster on one machine;
bench/batch.py measures where the cluster pays off.
"""
from __future__ import annotations

import argparse
import csv
import hashlib
import importlib
import json
import logging
import math
import numbers
import os
import sys
import time
import uuid
from collections import Counter
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from ._arrays import as_number
from .calibration import TESLA_PER_UNIT

DEFAULT_PATTERN = "*.csv"
OUTLIER_K = 5.0
"""Default outlier threshold in robust standard deviations (1.4826·MAD). 5 rather than the usual 3.5:
a fleet of thousands of units times a dozen quantities would flag about one good value in 2000 at 3.5
for a Gaussian spread, at 5 about one in two million."""
MIN_UNITS_FOR_OUTLIERS = 5  # below this a median/MAD says little about "the fleet"
SUMMARY_FILES = ("fleet_summary.csv", "fleet_summary.json", "failures.json")

# The per-unit quantities whose fleet distribution is summarised and screened for outliers.
QUANTITIES = ("offset_x", "offset_y", "offset_z", "offset_norm", "scale_1", "scale_2", "scale_3", "field_norm",
              "norm_std_over_mean", "held_out_spread", "held_out_rms", "residual_rms", "direction_coverage")
DEFINITIONS = {
    "offset_x, offset_y, offset_z": "offset b of h = A (m - b), reading units",
    "offset_norm": "|b|, reading units",
    "scale_1, scale_2, scale_3": "singular values of the sensor gain W = A^-1, largest first (dimensionless "
                                 "when field_norm was given: 1 = nominal gain; otherwise det W = 1 and the overall "
                                 "gain is field_norm, the fitted mean radius)",
    "field_norm": "|h| the calibration maps to: the given --field-norm, or the fitted mean radius (reading units)",
    "norm_std_over_mean": "residual spread: std/mean of |h| after correction",
    "held_out_spread": "std/mean of |h| on the second half of the readings, corrected by the same fit made on the "
                       "first half (as `fluxcal calibrate` reports it; the accuracy a fleet's units compare by: the "
                       "whole fit's spread is of the readings it was fitted to); empty when the first half alone "
                       "cannot be fitted (its reason in warnings)",
    "held_out_rms": "vector fit (reference vectors): RMS of |h - r| on the second half, fitted on the first, field units",
    "residual_rms": "RMS of the fit residuals, field units",
    "direction_coverage": "fraction of the 96 direction bins the readings visit",
}
CSV_COLUMNS = ("unit", "status", "method", "shape", "units", "samples", "offset_x", "offset_y", "offset_z", "offset_norm",
               "scale_1", "scale_2", "scale_3", "field_norm", "norm_std_over_mean", "held_out_spread",
               "held_out_rms", "residual_rms",
               "direction_coverage", "coverage_ratio", "identifiable", "noise_sigma", "outlier", "source",
               "warnings", "error")

log = logging.getLogger(__name__)


def _read(path, bad_lines: str = "error"):
    """The one reader of the batch: any recording format fluxcal reads (by content)."""
    from .io import read_recording
    from .io.csv import quiet_skipped

    with quiet_skipped():  # (each unit keeps the lines it skipped with its warnings)
        return read_recording(path, bad_lines=bad_lines)


# -- one unit (runs on a worker) ---------------------------------------------------------------------
def _digest(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _status(cal) -> str:
    # Fits without a refinement ("als", "ls") carry no identifiability verdict: taken as identifiable.
    if cal.summary.get("converged", True) is False:  # an intermediate iterate (export-c refuses it)
        return "not_converged"
    return "ok" if cal.summary.get("identifiable", True) else "not_identifiable"


def unit_row(unit: str, source, cal) -> dict:
    """The fleet-summary row of one calibrated unit."""
    s = cal.summary
    gains = np.linalg.svd(np.linalg.inv(cal.matrix), compute_uv=False)  # sorted largest first
    return {
        "unit": unit, "status": _status(cal), "method": s.get("method", cal.model),
        "shape": s.get("shape", ""), "units": cal.units,
        "samples": s.get("samples"),
        "offset_x": float(cal.offset[0]), "offset_y": float(cal.offset[1]), "offset_z": float(cal.offset[2]),
        "offset_norm": float(np.linalg.norm(cal.offset)),
        "scale_1": float(gains[0]), "scale_2": float(gains[1]), "scale_3": float(gains[2]),
        "field_norm": cal.field_norm, "norm_std_over_mean": s.get("norm_std_over_mean"),
        # (a text when the first half alone cannot be fitted: said in the warnings instead)
        **{k: s[k] if isinstance(s.get(k), (int, float)) else None for k in ("held_out_spread", "held_out_rms")},
        "residual_rms": s.get("residual_rms"), "direction_coverage": s.get("direction_coverage"),
        "coverage_ratio": s.get("coverage_ratio"), "identifiable": s.get("identifiable"),
        "noise_sigma": s.get("noise_sigma"), "outlier": "", "source": str(source),
        "warnings": "; ".join(s.get("warnings", [])), "error": "",
    }


def failure_row(unit: str, source, error: str) -> dict:
    row = dict.fromkeys(CSV_COLUMNS, "")
    row.update(unit=unit, status="failed", source=str(source), error=error)
    return row


def _message(path, exc: BaseException) -> str:
    text = str(exc) or type(exc).__name__
    # Readers already name the file; solver errors name only "samples": say which recording it was.
    return text if str(path) in text else f"{path}: {text}"


def calibrate_unit(path, out_path, method: str = "auto", field_norm: float | None = None,
                   bad_lines: str = "error", field_units: str | None = None) -> dict:
    """Read one recording, calibrate it and write its calibration atomically. Never raises for a bad
    unit: returns {"unit", "source", "status", "row" | "error", "seconds"}. `field_units` names `field_norm`'s unit,
    which the corrected field h is then in whatever the readings' (as `fluxcal calibrate --field-units`)."""
    from .pipeline import calibrate

    path, out_path = Path(path), Path(out_path)
    unit, start = path.stem, time.perf_counter()
    try:
        digest = _digest(path)
        rec = _read(path, bad_lines)
        units = rec.field_units()
        # as `fluxcal calibrate FILE` does: a simulation's stated field norm, the vector fit when the recording
        # carries attitude and the local field (the airborne layout)
        given = field_norm if field_norm is not None else rec.stated_field_norm()
        reference = rec.reference_field() if method == "auto" else None
        cal = calibrate(rec.samples(), method=method, field_norm=None if reference is not None else given,
                        reference=reference, units=units)
        if reference is not None and rec.reference_units() != units:
            cal.field_units = rec.reference_units()
        elif field_units and field_norm is not None and reference is None:
            from .cli import judge_field_again
            from .io.columns import unit_name

            cal.field_units = unit_name(field_units)
            judge_field_again(cal, units, field_units)  # (the solver judged the norm in the readings' unit)
        elif given is not None and reference is None and units not in TESLA_PER_UNIT:
            cal.field_units = ""  # counts fitted to a norm given without its unit (as calibrate: not stated)
        _held_out(cal, rec.samples(), reference, given, method)
        if "skipped_lines" in rec.metadata:  # --bad-lines skip: what was left out, kept with the calibration
            cal.metadata["skipped_lines"] = rec.metadata["skipped_lines"]
            cal.summary.setdefault("warnings", []).append(f"skipped {rec.metadata['skipped_lines']}")
        cal.metadata.update(unit=unit, source=str(path), source_sha256=digest, columns=",".join(rec.mag_names()),
                            batch_settings=_settings(method, field_norm, bad_lines, field_units))
        tmp = out_path.with_name(f".{out_path.name}.{os.getpid()}.tmp")
        try:
            cal.save(tmp)
            os.replace(tmp, out_path)  # a reader never sees a half-written calibration
        finally:
            tmp.unlink(missing_ok=True)
        return {"unit": unit, "source": str(path), "status": _status(cal), "row": unit_row(unit, path, cal),
                "seconds": time.perf_counter() - start}
    except Exception as exc:  # one bad unit must not stop the fleet
        return {"unit": unit, "source": str(path), "status": "failed", "error": _message(path, exc)
                + _set_aside(out_path), "seconds": time.perf_counter() - start}


def _held_out(cal, raw, reference, field_norm, method: str) -> None:
    """The held-out check `fluxcal calibrate` prints, in the unit's summary: the same fit on the first half of the
    readings, judged on the second (held_out_spread for a magnitude fit, held_out_rms for a vector fit); when the
    first half alone cannot be fitted, why, among the warnings."""
    from .cli import _held_out_rms, _held_out_spread

    if reference is None and len(raw) >= 80 and method in ("auto", "als+refine"):
        value, note = _held_out_spread(raw, cal, field_norm, {})
        key = "held_out_spread"
    elif reference is not None and len(raw) >= 40:
        value, note = _held_out_rms(raw, reference, cal.units, cal, cal.summary.get("outliers", {}).get("rows", []))
        key = "held_out_rms"
    else:
        return
    if isinstance(value, str):
        cal.summary.setdefault("warnings", []).append(f"held-out check: {value}")
        return
    cal.summary[key] = value
    if note:
        cal.summary["held_out_note"] = note


def _set_aside(out_path: Path) -> str:
    """Moves a failed unit's earlier calibration (of other bytes or settings) to .stale, so that it cannot pass
    for this run's; returns what to add to the unit's error ("" when there was none)."""
    if not out_path.exists():
        return ""
    stale = out_path.with_name(f"{out_path.name}.stale")
    try:
        os.replace(out_path, stale)
    except OSError as exc:  # one unit's file must not stop the fleet: said instead
        return f" (the previous {out_path.name}, of another recording or settings, could not be moved aside: {exc})"
    return f" (the previous {out_path.name}, of another recording or settings, moved to {stale.name})"


def _settings(method, field_norm, bad_lines: str = "error", field_units: str | None = None) -> dict:
    return {"method": method, "field_norm": None if field_norm is None else as_number(field_norm, "field_norm"),
            "bad_lines": bad_lines, **({"field_units": field_units} if field_units else {})}


def _already_done(json_path: Path, source: Path, settings: dict):
    """The existing calibration of a unit if it is valid and made from this recording with these
    settings, else None (and why)."""
    from .calibration import Calibration

    if not json_path.exists():
        return None, "new"
    try:
        cal = Calibration.load(json_path)
    except (ValueError, OSError):
        return None, "invalid"
    made_with = cal.metadata.get("batch_settings")
    if isinstance(made_with, dict):
        made_with = {"bad_lines": "error", **made_with}  # calibrations from before the setting read strictly
    if cal.metadata.get("source_sha256") != _digest(source) or made_with != settings:
        return None, "stale"
    return cal, "done"


# -- fleet statistics ---------------------------------------------------------------------------------
def robust_spread(values) -> tuple[float, float, float]:
    """(median, MAD, robust σ). Robust σ = 1.4826·MAD (the Gaussian σ); when over half the values are
    identical (MAD 0) it falls back to 1.2533·mean absolute deviation (also σ for a Gaussian)."""
    x = np.asarray(values, dtype=float)
    if x.size == 0 or not np.all(np.isfinite(x)):  # NumPy gave NaN with a warning, or a NaN spread
        raise ValueError(f"values: {'empty' if x.size == 0 else 'NaN or infinite values'}; a spread needs finite numbers")
    median = float(np.median(x))
    mad = float(np.median(np.abs(x - median)))
    sigma = 1.4826 * mad if mad > 0 else 1.2533 * float(np.mean(np.abs(x - median)))
    return median, mad, sigma


def distribution(values) -> dict:
    x = np.asarray(values, dtype=float)
    median, mad, sigma = robust_spread(x)
    p = np.percentile(x, [5, 25, 75, 95])
    return {"n": int(x.size), "median": median, "mad": mad, "robust_sigma": sigma, "p5": float(p[0]),
            "p25": float(p[1]), "p75": float(p[2]), "p95": float(p[3]), "min": float(x.min()), "max": float(x.max())}


def majority_units(rows: list) -> tuple[str, str]:
    """The units most of `rows` are in, and, when two or more units are as common, the tie said ("nT 2, uT 2"; the
    first of them in the rows' order is taken), else ""."""
    counts = Counter(r["units"] for r in rows).most_common()
    if not counts:
        return "", ""
    top = [(u, n) for u, n in counts if n == counts[0][1]]
    return counts[0][0], (", ".join(f"{u or 'unstated'} {n}" for u, n in top) if len(top) > 1 else "")


def fleet_statistics(rows: list, outlier_k: float = OUTLIER_K) -> tuple[dict, list]:
    """Distributions of QUANTITIES over the identifiable units in the fleet's (most common) units, and
    the outliers: |x − median| > outlier_k·robust σ, per quantity, each with its reason."""
    ok = [r for r in rows if r["status"] == "ok"]
    outliers = []
    fleet_units, tie = majority_units(ok)
    named = lambda u: u or "unstated units"  # noqa: E731
    for r in ok:
        if r["units"] != fleet_units:
            reason = (f"readings in {named(r['units'])}, left out of the distributions: the fleet's units tie ({tie}) "
                      f"and the distributions are of those in {named(fleet_units)}, the first in order" if tie else
                      f"readings in {named(r['units'])}, the fleet's are in {named(fleet_units)}: left out of the "
                      "distributions")
            outliers.append({"unit": r["unit"], "quantity": "units", "value": r["units"], "reason": reason})
    same = [r for r in ok if r["units"] == fleet_units]
    dist = {}
    for q in QUANTITIES:
        # (r.get: rows written before a quantity was added lack it)
        values = np.array([r[q] for r in same if r.get(q) is not None and np.isfinite(r[q])], dtype=float)
        if values.size == 0:
            continue
        dist[q] = d = distribution(values)
        if len(same) < MIN_UNITS_FOR_OUTLIERS or d["robust_sigma"] == 0:
            continue
        limit = outlier_k * d["robust_sigma"]
        for r in same:
            value = r.get(q)
            if value is None or not np.isfinite(value) or abs(value - d["median"]) <= limit:
                continue
            deviation = (value - d["median"]) / d["robust_sigma"]
            outliers.append({
                "unit": r["unit"], "quantity": q, "value": value, "median": d["median"],
                "robust_sigma": d["robust_sigma"], "deviation_sigmas": deviation,
                "reason": f"{q} = {value:.6g} is {abs(deviation):.1f} robust σ {'above' if deviation > 0 else 'below'} "
                          f"the fleet median {d['median']:.6g} (limit {outlier_k:g}·1.4826·MAD = {limit:.4g})"})
    return dist, outliers


# -- the batch ----------------------------------------------------------------------------------------
@dataclass
class FleetResult:
    directory: Path
    out_dir: Path
    rows: list                      # one dict per unit (CSV_COLUMNS), sorted by unit
    summary: dict                   # what fleet_summary.json holds
    skipped: int = 0                # units whose calibration was already done
    calibrated: int = 0             # tasks run in this call
    seconds: float = 0.0            # from the first submission to the last result
    startup_seconds: float = 0.0    # starting the local cluster / connecting to the scheduler
    workers: int = 0
    files: list = field(default_factory=list)
    left_out: dict = field(default_factory=dict)  # files the pattern did not take: {".tsv": 1, …} (_left_out)

    @property
    def failures(self) -> list:
        return [r for r in self.rows if r["status"] == "failed"]

    def report(self) -> str:
        c = self.summary["counts"]
        rate = f", {self.calibrated / self.seconds:.1f} units/s" if self.calibrated and self.seconds > 0 else ""
        lines = [f"fleet calibration of {self.directory} -> {self.out_dir}",
                 f"  units {c['units']}: {c['ok']} ok, {c['not_identifiable']} not identifiable, {c['failed']} failed; "
                 f"{self.calibrated} calibrated now, {self.skipped} skipped (already done)"]
        if self.left_out:  # not silently: a .tsv beside the .csv files looked calibrated and was not
            lines.append(f"  note: {_left_out_words(self.left_out, self.summary['settings']['pattern'])}")
        lines.append(f"  {self.seconds:.2f} s on {self.workers} worker{'s' * (self.workers != 1)}{rate} "
                     f"(+ {self.startup_seconds:.2f} s to start or reach the cluster)")
        dist = self.summary["distribution"]
        if dist:
            units = self.summary["fleet_units"]
            covered = max(d["n"] for d in dist.values())  # (a blind check read 3 of 8 units' statistics as the fleet's)
            lines.append(f"  {'quantity':<20}{'median':>13}{'robust σ':>13}{'p5':>13}{'p95':>13}  ({units or 'units not stated'}"
                         f"; {covered} of {c['units']} units: those ok in these units)")
            for q, d in dist.items():
                lines.append(f"  {q:<20}{d['median']:>13.6g}{d['robust_sigma']:>13.4g}{d['p5']:>13.6g}{d['p95']:>13.6g}")
        k = self.summary["settings"]["outlier_k"]
        outliers = self.summary["outliers"]
        lines.append(f"outliers (|x - median| > {k:g}·1.4826·MAD): {len({o['unit'] for o in outliers}) or 'none'}"
                     + (f" (by value not judged: {covered} units, fewer than {MIN_UNITS_FOR_OUTLIERS})"
                        if dist and covered < MIN_UNITS_FOR_OUTLIERS else ""))
        lines += [f"  {o['unit']}: {o['reason']}" for o in outliers]
        for r in self.rows:
            if r["status"] in ("not_identifiable", "not_converged"):
                lines.append(f"{r['status'].replace('_', ' ')}: {r['unit']}: {r['warnings'] or 'the data do not determine every parameter'}")
        if self.failures:
            lines.append(f"failed: {len(self.failures)} (listed in {self.out_dir / 'failures.json'})")
            lines += [f"  {r['unit']}: {r['error']}" for r in self.failures]
        lines.append("wrote " + ", ".join(str(f) for f in self.files))
        return "\n".join(lines)


def _is_ours(path: Path) -> bool:
    """Whether `path` is a summary file this module wrote (not a recording that happens to share its name)."""
    try:
        if path.suffix == ".csv":
            with path.open() as f:
                return f.readline().rstrip("\n") == ",".join(CSV_COLUMNS)
        data = json.loads(path.read_text())
        return isinstance(data, list) or (isinstance(data, dict) and "counts" in data)
    except (OSError, ValueError):
        return False


def _is_calibration(path: Path) -> bool:
    """Whether `path` is a calibration fluxcal wrote (<unit>.json, or a .json.stale set aside): with the output
    folder the recordings' own, --pattern '*' had taken an earlier run's as recordings ("unit1.csv and unit1.json
    would both be unit 'unit1'")."""
    if not path.name.endswith((".json", ".json.stale")):
        return False
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return False
    return isinstance(data, dict) and "fluxcal_version" in data and {"offset", "matrix"} <= set(data)


def _left_out(directory: Path, out_dir: Path, pattern: str, taken) -> dict:
    """The files of `directory` that `pattern` did not take, counted by extension ({".tsv": 1, ".txt": 1}): not
    hidden ones, the batch's own summaries, nor (when the output folder is the recordings' own) the calibrations it
    writes beside them."""
    taken = {p.name for p in taken}
    units = {Path(name).stem for name in taken}
    own = set(SUMMARY_FILES) | ({f"{u}.json" for u in units} | {f"{u}.json.stale" for u in units}
                                if out_dir == directory else set())
    counts = Counter(p.suffix.lower() or "(no extension)" for p in directory.iterdir()
                     if p.is_file() and not p.name.startswith(".") and p.name not in taken | own)
    return dict(sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))


def _left_out_words(left_out: dict, pattern: str, none_taken: bool = False) -> str:
    """What the pattern left out, and the --pattern that takes it."""
    n = sum(left_out.values())
    kinds = ", ".join(f"{count} {ext}" for ext, count in left_out.items())
    named = [ext for ext in left_out if ext.startswith(".")][:3]
    only = f"--pattern {' or '.join(repr('*' + ext) for ext in named)} for those alone, or " if named else ""
    take = f"{only}--pattern '*' for every file (one that is no recording fails alone, listed)"
    if none_taken:
        return f"the folder holds {kinds} file{'s' * (n != 1)}; to calibrate {'them' if n != 1 else 'it'}: {take}"
    return (f"{n} file{'s' * (n != 1)} of the folder {'do' if n != 1 else 'does'} not match --pattern {pattern!r} "
            f"and {'were' if n != 1 else 'was'} left out ({kinds}); to calibrate {'them' if n != 1 else 'it'}: {take}")


def _recordings(directory: Path, out_dir: Path, pattern: str) -> list:
    # never read a summary back as a recording: this run's, or an earlier run's left in the recordings' folder
    ours = {p for d in (out_dir, directory) for p in (d / name for name in SUMMARY_FILES) if _is_ours(p)}
    paths = sorted(p for p in directory.glob(pattern) if p.is_file() and p not in ours
                   and not (out_dir == directory and _is_calibration(p)))  # (a run's own <unit>.json, read again)
    if not paths:
        left_out = _left_out(directory, out_dir, pattern, [])
        raise ValueError(f"{directory}: no recordings matching {pattern!r}"
                         + (f"; {_left_out_words(left_out, pattern, none_taken=True)}" if left_out else
                            " (the folder holds no files)"))
    reserved = [p.name for p in paths if p.stem in {Path(n).stem for n in SUMMARY_FILES}]
    if reserved:  # <unit>.json would be overwritten by the summary (or the summary would overwrite the recording)
        raise ValueError(f"{directory}: {', '.join(reserved)}: unit names fleet_summary and failures are the batch's "
                         "own summary files; rename the recording(s)")
    seen = {}
    for p in paths:
        if p.stem in seen:
            raise ValueError(f"{directory}: {seen[p.stem].name} and {p.name} would both be unit {p.stem!r}; "
                             f"rename one or narrow --pattern")
        seen[p.stem] = p
    return paths


def _write_atomic(path: Path, text: str) -> Path:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def _csv_text(rows) -> str:
    import io

    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=CSV_COLUMNS, lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in CSV_COLUMNS})
    return buf.getvalue()


def _connect(workers, scheduler, dashboard_address):
    """A Dask client and the cluster it owns (None for a remote scheduler)."""
    from dask.distributed import Client, LocalCluster

    if scheduler:
        try:
            return Client(scheduler, timeout="10s"), None
        except (OSError, TimeoutError) as exc:
            raise ValueError(f"scheduler {scheduler}: cannot connect ({exc})") from None
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                           dashboard_address=dashboard_address, silence_logs=logging.ERROR)
    return Client(cluster), cluster


def calibrate_fleet(directory, out_dir, workers: int | None = None, scheduler: str | None = None,
                    method: str = "auto", field_norm: float | None = None, pattern: str = DEFAULT_PATTERN,
                    progress: bool = True, outlier_k: float = OUTLIER_K,
                    dashboard_address: str | None = None, bad_lines: str = "error",
                    field_units: str | None = None) -> FleetResult:
    """Calibrate every recording of `directory` matching `pattern`, one Dask task each, into `out_dir`.

    `scheduler` (an address such as "tcp://host:8786") uses an existing Dask cluster; otherwise a
    LocalCluster of `workers` single-threaded processes (default: one per core) is started and closed.
    `method` and `field_norm` go to fluxcal.calibrate, `bad_lines` ("error", "skip") to the reader; `field_units` names
    field_norm's unit (a field unit: uT, nT, G, mG…), each unit's corrected field then in it whatever its readings'.
    Outliers: |x − median| > outlier_k·1.4826·MAD.
    Raises ValueError for a missing or empty directory and bad settings; a unit's own failure is
    recorded, never raised.
    """
    from .pipeline import METHODS

    directory, out_dir = Path(directory).resolve(), Path(out_dir).resolve()
    if not directory.is_dir():
        what = "a file, not a folder of recordings" if directory.exists() else "no such directory"
        raise ValueError(f"{directory}: {what}")
    if method not in METHODS or method == "vector":
        raise ValueError(f"method: {method!r} is not one of {', '.join(m for m in METHODS if m != 'vector')} "
                         f"(the vector fit needs reference fields a recording folder does not give)")
    if field_norm is not None and not (math.isfinite(field_norm) and field_norm > 0):
        raise ValueError(f"field_norm: {field_norm} must be a positive number")
    if field_units is not None:
        from .io.columns import unit_name

        if field_norm is None:
            raise ValueError("field_units: names the unit of field_norm (--field-norm), which is not given")
        if unit_name(field_units) not in TESLA_PER_UNIT:
            raise ValueError(f"field_units: {field_units!r} is not a magnetic-field unit (uT, nT, G, mG, T, …)")
        field_units = unit_name(field_units)  # (µT and uT one setting: a re-run does not redo every unit)
    if method == "twostep" and field_norm is None:  # else every unit would fail alike
        raise ValueError("field_norm: method 'twostep' needs the known field magnitude (--field-norm)")
    if not (isinstance(outlier_k, numbers.Real) and math.isfinite(outlier_k) and outlier_k > 0):
        raise ValueError(f"outlier_k: {outlier_k!r} must be a positive number of robust σ")
    if bad_lines not in ("error", "skip"):
        raise ValueError(f"bad_lines: {bad_lines!r} is not one of error, skip")
    if workers is not None and workers < 1:
        raise ValueError(f"workers: {workers} must be at least 1")
    if scheduler and workers is not None:
        raise ValueError("workers: the number of workers is the remote scheduler's; give --workers or --scheduler")
    paths = _recordings(directory, out_dir, pattern)
    out_dir.mkdir(parents=True, exist_ok=True)

    settings = _settings(method, field_norm, bad_lines, field_units)
    rows, todo, why = {}, [], Counter()
    for p in paths:
        cal, state = _already_done(out_dir / f"{p.stem}.json", p, settings)
        why[state] += 1
        if cal is None:
            todo.append(p)
        else:
            rows[p.stem] = unit_row(p.stem, p, cal)

    n_workers, startup, seconds = 0, 0.0, 0.0
    if todo:
        from dask.distributed import as_completed
        from tqdm import tqdm

        start = time.perf_counter()
        client, cluster = _connect(workers, scheduler, dashboard_address)
        try:
            if cluster is None:
                try:  # a remote scheduler without workers would leave every task waiting
                    client.wait_for_workers(1, timeout=60)
                except TimeoutError:
                    raise ValueError(f"scheduler {scheduler}: no workers joined within 60 s") from None
            n_workers = len(client.scheduler_info()["workers"])
            startup = time.perf_counter() - start
            # By module name, so workers import it even when this file runs as __main__ (python -m).
            task = importlib.import_module("fluxcal.batch").calibrate_unit
            # A fresh key per submission: a scheduler that still remembers an earlier run must not
            # hand back that run's result instead of writing this one.
            # client.map: one message to the scheduler for all tasks instead of one per task.
            submitted = client.map(task, [str(p) for p in todo], [str(out_dir / f"{p.stem}.json") for p in todo],
                                   method=method, field_norm=field_norm, bad_lines=bad_lines, field_units=field_units,
                                   key=[f"fluxcal-calibrate-{p.stem}-{uuid.uuid4().hex}" for p in todo])
            futures = dict(zip(submitted, todo))
            failed = 0
            with tqdm(total=len(futures), desc="calibrating", unit="unit", disable=not progress,
                      file=sys.stderr) as bar:
                for future in as_completed(futures):
                    p = futures.pop(future)
                    try:
                        record = future.result()
                    except Exception as exc:  # the task itself died (worker killed, lost): still one unit
                        record = {"unit": p.stem, "source": str(p), "status": "failed",
                                  "error": _message(p, exc) + " (the worker running it failed)"
                                  + _set_aside(out_dir / f"{p.stem}.json")}
                    if record["status"] == "failed":
                        failed += 1
                        rows[p.stem] = failure_row(p.stem, p, record["error"])
                    else:
                        rows[p.stem] = record["row"]
                    bar.set_postfix(failed=failed, refresh=False)
                    bar.update()
            seconds = time.perf_counter() - start - startup  # without closing the cluster
        finally:
            client.close()
            if cluster is not None:
                cluster.close()

    ordered = [rows[p.stem] for p in paths]
    dist, outliers = fleet_statistics(ordered, outlier_k)
    flagged = {}
    for o in outliers:
        flagged.setdefault(o["unit"], []).append(o["quantity"])
    for r in ordered:
        r["outlier"] = ",".join(flagged.get(r["unit"], []))
    status = Counter(r["status"] for r in ordered)
    failures = [{"unit": r["unit"], "source": r["source"], "error": r["error"]} for r in ordered if r["status"] == "failed"]
    summary = {
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "directory": str(directory), "out_dir": str(out_dir),
        "settings": {**settings, "pattern": pattern, "outlier_k": outlier_k},
        "counts": {"units": len(ordered), "ok": status["ok"], "not_identifiable": status["not_identifiable"],
                   "not_converged": status["not_converged"],
                   "failed": status["failed"], "calibrated_now": len(todo), "skipped": why["done"],
                   "recalibrated_stale": why["stale"], "recalibrated_invalid": why["invalid"]},
        "fleet_units": majority_units([r for r in ordered if r["status"] == "ok"])[0],
        "definitions": DEFINITIONS,
        "outlier_rule": f"|x - median| > {outlier_k:g} * 1.4826 * MAD per quantity, over the identifiable units "
                        f"(at least {MIN_UNITS_FOR_OUTLIERS}); MAD 0 falls back to 1.2533 * mean |x - median|",
        "distribution": dist,
        "outliers": outliers,
        "not_identifiable": [r["unit"] for r in ordered if r["status"] == "not_identifiable"],
        "failures": failures,
    }
    files = [_write_atomic(out_dir / "fleet_summary.csv", _csv_text(ordered)),
             _write_atomic(out_dir / "fleet_summary.json", json.dumps(summary, indent=2) + "\n"),
             _write_atomic(out_dir / "failures.json", json.dumps(failures, indent=2) + "\n")]
    return FleetResult(directory=directory, out_dir=out_dir, rows=ordered, summary=summary, skipped=why["done"],
                       calibrated=len(todo), seconds=seconds, startup_seconds=startup, workers=n_workers, files=files,
                       left_out=_left_out(directory, out_dir, pattern, paths))


# -- command line ----------------------------------------------------------------------------------
def add_batch_parser(subparsers):
    """`fluxcal batch DIR -o OUTDIR [--workers N] [--scheduler ADDRESS] ...` for cli.build_parser."""
    from .cli import positive_int, positive_number
    from .pipeline import METHODS

    b = subparsers.add_parser("batch", help="calibrate every recording in a folder on a Dask cluster (fleet)")
    b.add_argument("directory", help="folder of recordings, one unit per file (unit name = file name stem)")
    b.add_argument("-o", "--output", required=True, help="folder for <unit>.json and the fleet summary")
    b.add_argument("--workers", type=positive_int, default=None,
                   help="worker processes of the local Dask cluster (default: one per core)")
    b.add_argument("--scheduler", default=None, help="address of an existing Dask scheduler (tcp://host:8786)")
    b.add_argument("--method", default="auto", choices=[m for m in METHODS if m != "vector"],
                   help="auto = consistent ellipsoid fit (ALS) + maximum-likelihood refinement (default)")
    b.add_argument("--field-norm", type=positive_number, default=None, help="known |field| in the units of h")
    b.add_argument("--field-units", default=None,
                   help="the unit of --field-norm and so of every unit's corrected field h (default: each unit's readings' "
                        "unit — a fleet logged in nT and in uT needs it, e.g. --field-norm 48.2 --field-units uT)")
    b.add_argument("--pattern", default=DEFAULT_PATTERN, help=f"recordings to take (glob, default {DEFAULT_PATTERN})")
    b.add_argument("--outlier-k", type=positive_number, default=OUTLIER_K,
                   help=f"flag |x - median| > k·1.4826·MAD (default {OUTLIER_K:g})")
    b.add_argument("--dashboard", default=None, metavar="ADDRESS",
                   help="serve the Dask dashboard of the local cluster here (e.g. :8787); off by default")
    b.add_argument("--no-progress", action="store_true", help="no progress bar")
    b.add_argument("--bad-lines", default="error", choices=["error", "skip"],
                   help="text recordings: a line that does not parse fails its unit (error) or is left out (skip)")
    b.set_defaults(run=cmd_batch)
    return b


def cmd_batch(args) -> int:
    """0 when the batch ran and gave at least one usable ("ok") calibration, even if some units failed (they are
    listed); 1 when none did — every unit failed, or what was calibrated is not identifiable or did not converge
    (a script must notice, as `calibrate` exits 3 for one such file); bad arguments raise ValueError, which the
    command line turns into exit status 2."""
    result = calibrate_fleet(args.directory, args.output, workers=args.workers, scheduler=args.scheduler,
                             method=args.method, field_norm=args.field_norm, pattern=args.pattern,
                             progress=not args.no_progress, outlier_k=args.outlier_k,
                             dashboard_address=args.dashboard, bad_lines=args.bad_lines, field_units=args.field_units)
    print(result.report())
    if result.failures and len(result.failures) == len(result.rows):
        print(f"error: all {len(result.rows)} units failed; nothing was calibrated (exit 1)")
        return 1
    if not any(r["status"] == "ok" for r in result.rows):
        counts = Counter(r["status"].replace("_", " ") for r in result.rows)
        print(f"error: no unit gave a usable calibration ({', '.join(f'{n} {s}' for s, n in counts.items())}) "
              "(exit 1)")
        return 1
    if result.failures:
        print(f"note: {len(result.failures)} of {len(result.rows)} units failed; the batch itself ran (exit 0)")
    return 0


def main(argv=None) -> int:
    """`python -m fluxcal.batch DIR -o OUT ...`: the same command without the fluxcal front end."""
    parser = argparse.ArgumentParser(prog="fluxcal")
    add_batch_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["batch", *(sys.argv[1:] if argv is None else argv)])
    try:
        return args.run(args)
    except (ValueError, FileNotFoundError) as exc:
        print(f"fluxcal batch: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
