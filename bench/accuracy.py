"""Accuracy of fluxcal's solvers against peers (magyc) on simulations and on real recordings.

    python bench/accuracy.py [--runs 50] [--seed 2026] [--data ../shared/data/real] [--no-magyc]

(a) Simulations (fluxcal.sim): seeded sensors with symmetric soft iron I + E, |E_ij| <= 0.10, an offset
    of random direction and length up to 0.5 |field|, white noise sigma = 1 % or 5 % of |field|, N = 300
    or 3000 orientations drawn uniformly over the sphere. For every method: RMS over --runs of the offset
    error |b^ - b| / |field| and of the matrix error ||P^ - P||_F / ||P||_F, where P is the symmetric
    polar factor sqrtm(A^T A) of the correction (the part of A a magnitude-only fit can identify) and the
    truth is Simulation.true_calibration(); "shape" is the same error after scaling both matrices to
    det = 1 (blind to the overall scale). The Cramer-Rao bound (fluxcal.crlb with the known |field|) is
    shown as sqrt(trace) on the same scale.
    fluxcal is given the known |field| (field_norm=H). magyc methods whose output scale is arbitrary
    (ellipsoid_fit, ellipsoid_fit_fang, sphere_fit) have their matrix scaled so that the mean |h| over
    the fitted readings equals the known |field| (marked *; that normalisation itself is biased upward by
    about sigma^2/H^2: 0.01 % at 1 % noise, 0.25 % at 5 %). twostep_hsi is given the known |field| and the
    true sigma. magyc's estimates (hard iron HI, forward soft iron SI, correction inv(SI)(m - HI)) are
    converted to fluxcal's h = A (m - b): b = HI, A = inv(SI); magyc's corrected arrays are not used.

(b) Real recordings (--data): fit on the FIRST half of each recording, apply to the held-out SECOND
    half, report std(|h|) / mean(|h|) there (the "held-out spread"; scale- and rotation-free). SAP6
    (24 static shots per unit): fit on all 24 (in-sample spread) and leave-one-out (fit on 23, correct the
    one left out; spread of the 24 left-out magnitudes). Airborne: also the IGRF vector fit
    (fluxcal.calibrate with reference=attitude.reference_vectors(...)) and how far each fit misses the
    IGRF |B| on the held-out half.
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import math
import platform
import sys
import time
from pathlib import Path

import numpy as np
from scipy.linalg import polar

import fluxcal
from fluxcal import attitude, sim
from fluxcal.bounds import magnitude_jacobian

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _magyc_worker import MagycUnavailable, MagycWorker  # noqa: E402
from _timing import table  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO.parent / "shared" / "data" / "real"
FIELD = np.array([20.0, 1.0, 45.0])  # µT, world frame; |field| = 49.25
CONFIGS = [(300, 0.01), (300, 0.05), (3000, 0.01), (3000, 0.05)]
SOFT_IRON, OFFSET = 0.10, 0.50
TARGETS = {"phone": 1.31, "handheld": 3.11, "qmc": 3.13, "qmc_nostatic": 3.13}
FLUXCAL_METHODS = [("fluxcal fit_ellipsoid ls", "ls"), ("fluxcal fit_ellipsoid als", "als"),
                   ("fluxcal calibrate (als+refine)", "auto")]
MAGYC_METHODS = ["ellipsoid_fit", "ellipsoid_fit_fang", "twostep_hsi", "sphere_fit"]
ARBITRARY_SCALE = {"ellipsoid_fit", "ellipsoid_fit_fang", "sphere_fit"}
DIAG = "ellipsoid_fit SI-as-correction"  # diagnostic reading of magyc's ellipsoid_fit output
_FROB_W = np.array([1.0, 2.0, 2.0, 1.0, 2.0, 1.0])  # a00 a01 a02 a11 a12 a22 in ||.||_F^2


# ----------------------------------------------------------------------------------------- helpers
def sym_part(A):
    """Symmetric polar factor sqrtm(A^T A): what |A x| depends on."""
    return polar(np.asarray(A, dtype=float), side="right")[1]


def magyc_to_fluxcal(res: dict, diagnostic: bool = False):
    """(b, A) in fluxcal's convention h = A (m - b) from magyc's (HI, SI), or None if it failed."""
    if res is None or res.get("error") or res.get("hard_iron") is None:
        return None
    b = np.array(res["hard_iron"], dtype=float)
    if res["method"] == "sphere_fit":
        A = np.eye(3)
    else:
        SI = np.array(res["soft_iron"], dtype=float)
        if not np.all(np.isfinite(SI)):
            return None
        try:
            A = SI if diagnostic else np.linalg.inv(SI)
        except np.linalg.LinAlgError:
            return None
    if not (np.all(np.isfinite(b)) and np.all(np.isfinite(A))):
        return None
    return b, A


def scale_to(b, A, m, H):
    """A scaled so that mean |A (m - b)| = H over the readings m."""
    r = np.linalg.norm((m - b) @ A.T, axis=1).mean()
    return A * (H / r)


def spread(b, A, m) -> float:
    r = np.linalg.norm((m - b) @ A.T, axis=1)
    return 100.0 * r.std() / r.mean()


def fluxcal_fit(m, how: str, field_norm=None):
    if how in ("ls", "als"):
        return fluxcal.fit_ellipsoid(m, field_norm=field_norm, method=how)
    return fluxcal.calibrate(m, field_norm=field_norm)


def rms(values) -> float:
    v = np.asarray([x for x in values if np.isfinite(x)], dtype=float)
    return float(np.sqrt(np.mean(v**2))) if len(v) else float("nan")


def fmt(x, spec=".3f", width=8) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return f"{'NaN' if isinstance(x, float) else '—':>{width}}"
    return f"{x:{width}{spec}}"


def run_magyc(worker, arrays, jobs, notes: list[str]):
    """Results keyed by (data, method); {} when magyc is not there."""
    if worker is None or not worker.available or not jobs:
        return {}
    try:
        res = worker.run(arrays, jobs)
    except MagycUnavailable as exc:
        notes.append(f"magyc: unavailable ({exc})")
        return {}
    out = {}
    for r in res:
        out[(r["data"], r["method"])] = r
        for w in r["warnings"]:
            notes.append(f"magyc {r['method']} warned: {w}")
        if r["error"]:
            notes.append(f"magyc {r['method']} raised: {r['error']}")
    return out


def summarise_notes(notes: list[str], limit: int = 12):
    counts: dict[str, int] = {}
    for n in notes:
        counts[n] = counts.get(n, 0) + 1
    for n, c in list(counts.items())[:limit]:
        print(f"  - {n}" + (f"  (×{c})" if c > 1 else ""))
    if len(counts) > limit:
        print(f"  - … {len(counts) - limit} more distinct notes")


# ----------------------------------------------------------------------------------- simulations
def crlb_terms(truth, clean, sigma):
    J = magnitude_jacobian(truth, clean)
    C = sigma**2 * np.linalg.inv(J.T @ J)
    d = np.diag(C)
    return float(d[:3].sum()), float(_FROB_W @ d[3:])


def sim_errors(b, A, truth, H):
    P, Pt = sym_part(A), truth.matrix
    off = np.linalg.norm(b - truth.offset) / H
    mat = np.linalg.norm(P - Pt) / np.linalg.norm(Pt)
    Pn, Ptn = P / np.cbrt(np.linalg.det(P)), Pt / np.cbrt(np.linalg.det(Pt))
    shape = np.linalg.norm(Pn - Ptn) / np.linalg.norm(Ptn)
    return 100 * off, 100 * mat, 100 * shape


def part_sim(runs: int, seed: int, worker) -> dict:
    H = float(np.linalg.norm(FIELD))
    print(f"\n## (a) Simulations: {runs} seeded runs per set, |field| = {H:.2f}, soft iron ±{SOFT_IRON:.0%}, "
          f"offset up to {OFFSET:.0%} of |field|, uniform orientations\n")
    results = {}
    sims, arrays, jobs = {}, {}, []
    for ci, (n, rel_sigma) in enumerate(CONFIGS):
        for r in range(runs):
            rng = np.random.default_rng((seed, ci, r))
            sensor = sim.random_sensor(H, rng, soft_iron=SOFT_IRON, offset=OFFSET, noise=rel_sigma)
            s = sim.simulate(sim.uniform(n, rng), sensor, FIELD, rng=rng)
            key = f"c{ci}r{r}"
            sims[key] = (s, rel_sigma * H)
            arrays[key] = s.readings
            for meth in MAGYC_METHODS:
                jobs.append({"data": key, "method": meth, "ref_norm": H, "noise_std": rel_sigma * H})
    notes: list[str] = []
    t0 = time.perf_counter()
    mres = run_magyc(worker, arrays, jobs, notes)
    t_magyc = time.perf_counter() - t0
    t0 = time.perf_counter()
    for ci, (n, rel_sigma) in enumerate(CONFIGS):
        acc: dict[str, list] = {}
        fails: dict[str, int] = {}
        crlb_off, crlb_mat = [], []

        def add(name, val):
            if val is None or not all(np.isfinite(val)):
                fails[name] = fails.get(name, 0) + 1
                acc.setdefault(name, [])
            else:
                acc.setdefault(name, []).append(val)

        for r in range(runs):
            key = f"c{ci}r{r}"
            s, sigma = sims[key]
            truth = s.true_calibration()
            m = s.readings
            to, tm = crlb_terms(truth, s.clean, sigma)
            crlb_off.append(to / H**2)
            crlb_mat.append(tm / np.linalg.norm(truth.matrix) ** 2)
            for label, how in FLUXCAL_METHODS:
                try:
                    cal = fluxcal_fit(m, how, field_norm=H)
                    add(label, sim_errors(cal.offset, cal.matrix, truth, H))
                except ValueError as exc:
                    notes.append(f"{label} raised: {exc}")
                    add(label, None)
            for meth in MAGYC_METHODS + ([DIAG] if mres else []):
                if not mres:
                    break
                base = "ellipsoid_fit" if meth == DIAG else meth
                est = magyc_to_fluxcal(mres.get((key, base)), diagnostic=(meth == DIAG))
                label = f"magyc {meth}" + ("*" if base in ARBITRARY_SCALE else "")
                if est is None:
                    add(label, None)
                    continue
                b, A = est
                if base in ARBITRARY_SCALE:
                    A = scale_to(b, A, m, H)
                add(label, sim_errors(b, A, truth, H))
        c_off = 100 * math.sqrt(np.mean(crlb_off))
        c_mat = 100 * math.sqrt(np.mean(crlb_mat))
        rows = [["Cramér–Rao bound (sqrt trace)", fmt(c_off, ".4f"), "1.00", fmt(c_mat, ".4f"), "1.00", "—", "—"]]
        for label, vals in acc.items():
            v = np.array(vals) if vals else np.full((0, 3), np.nan)
            e_off, e_mat, e_shape = (rms(v[:, j]) if len(v) else float("nan") for j in range(3))
            rows.append([label, fmt(e_off, ".4f"), fmt(e_off / c_off, ".2f", 6), fmt(e_mat, ".4f"),
                         fmt(e_mat / c_mat, ".2f", 6), fmt(e_shape, ".4f"), f"{fails.get(label, 0)}/{runs}"])
        results[(n, rel_sigma)] = rows
        print(f"### N = {n}, σ = {rel_sigma:.0%} of |field|\n")
        table(["method", "offset err %", "× CRLB", "matrix err %", "× CRLB", "shape err %", "failed"], rows)
        print()
    print(f"(fluxcal + CRLB: {time.perf_counter() - t0:.1f} s; magyc worker: {t_magyc:.1f} s)")
    if worker is not None and not worker.available:
        print(f"magyc: unavailable ({worker.reason})")
    print("* scale arbitrary in the method: matrix scaled to mean |h| = |field| on the fitted readings.")
    print(f"{DIAG}: diagnostic only — magyc's returned soft_iron used as the correction A itself (not inverted).")
    if notes:
        print("notes:")
        summarise_notes(notes)
    return results


# ------------------------------------------------------------------------------------- real data
def load_real(data: Path) -> dict:
    sets = {}
    x = np.loadtxt(data / "phone_acc_mag.csv", delimiter=",", skiprows=1, usecols=(3, 4, 5))
    sets["phone"] = {"m": x, "H": None, "label": "phone (mx,my,mz)"}
    x = np.loadtxt(data / "handheld_set1.csv", delimiter=",", skiprows=1)
    sets["handheld"] = {"m": x, "H": 0.47, "label": "handheld (x,y,z; H = 0.47 G)"}
    x = np.loadtxt(data / "qmc5883l_filtered.csv", delimiter=",", skiprows=3)
    sets["qmc"] = {"m": x, "H": None, "label": "QMC5883L, as recorded"}
    # same held-out half; the first 60 s (3000 rows at 50 Hz, static) left out of the fitted half
    sets["qmc_nostatic"] = {"m": x, "H": None, "drop": 3000, "label": "QMC5883L, static 60 s dropped"}
    a = np.loadtxt(data / "airborne_flt1002_02.tsv")
    sets["airborne"] = {"m": a[:, 1:4], "pry": a[:, 4:7], "igrf": a[:, 7:10], "H": None,
                        "label": "airborne"}
    return sets


def part_real(data: Path, worker, gap_reps: int = 200) -> dict:
    print(f"\n## (b) Real recordings ({data})\n")
    print("Fit on the first half, held-out spread std(|h|)/mean(|h|) in % on the second half.\n")
    sets = load_real(data)
    arrays, jobs, split = {}, [], {}
    for name, d in sets.items():
        m = d["m"]
        n = len(m) // 2
        fit, held = m[d.get("drop", 0):n], m[n:]
        if name == "airborne":
            d["H"] = float(np.linalg.norm(d["igrf"][:n], axis=1).mean())
        # twostep needs |field|: the known one, else a crude peer-side guess (scale does not change spread)
        ref = d["H"] or float(np.linalg.norm(fit - fit.mean(0), axis=1).mean())
        d["ref_norm"] = ref
        split[name] = (fit, held, n)
        arrays[name] = fit
        for meth in MAGYC_METHODS:
            jobs.append({"data": name, "method": meth, "ref_norm": ref, "noise_std": 0.002 * ref})
    notes: list[str] = []
    mres = run_magyc(worker, arrays, jobs, notes)

    held_rows, in_rows, est, fits = [], [], {}, {}
    labels = [lab for lab, _ in FLUXCAL_METHODS]
    if mres:
        labels += [f"magyc {m}" for m in MAGYC_METHODS] + [f"magyc {DIAG}"]
    for label in labels:
        hr, ir = [label], [label]
        for name, d in sets.items():
            fit, held, n = split[name]
            b = A = None
            if label.startswith("fluxcal"):
                how = dict(FLUXCAL_METHODS)[label]
                try:
                    cal = fluxcal_fit(fit, how, field_norm=d["H"] if name == "airborne" else None)
                    b, A = cal.offset, cal.matrix
                    fits[(name, label)] = (b, A)
                    if name == "airborne":
                        est[(name, label)] = cal
                except ValueError as exc:
                    notes.append(f"{label} on {name} raised: {exc}")
            else:
                meth = label.split(" ", 1)[1]
                base = "ellipsoid_fit" if meth == DIAG else meth
                e = magyc_to_fluxcal(mres.get((name, base)), diagnostic=(meth == DIAG))
                if e is not None:
                    b, A = e
                    if base in ARBITRARY_SCALE:
                        A = scale_to(b, A, fit, d["ref_norm"])
                    est[(name, label)] = (b, A)
                    fits[(name, label)] = (b, A)
                else:
                    est[(name, label)] = None
            hr.append(fmt(spread(b, A, held)) if b is not None else "failed")
            ir.append(fmt(spread(b, A, fit)) if b is not None else "failed")
        held_rows.append(hr)
        in_rows.append(ir)
    # references
    raw = ["uncalibrated ‖m − mean(m)‖"] + [fmt(spread(split[k][0].mean(0), np.eye(3), split[k][1])) for k in sets]
    tgt = ["best peer (ANCHORS.md)"] + [fmt(TARGETS[k], ".2f") if k in TARGETS else "—" for k in sets]
    P = np.loadtxt(data / "qmc5883l_reference_params.csv")
    M, c = P[:9].reshape(3, 3), P[9:]
    auth = []
    for k in sets:
        if k.startswith("qmc"):
            h = split[k][1] @ M.T + c
            r = np.linalg.norm(h, axis=1)
            auth.append(fmt(100 * r.std() / r.mean()))
        else:
            auth.append("—")
    header = ["method"] + [sets[k]["label"] for k in sets]
    print("### Held-out spread (%), fit on the first half\n")
    table(header, held_rows + [tgt, ["QMC author's calibration (h = M m + c)"] + auth, raw])
    print("\n### In-sample spread (%) on the fitted first half\n")
    table(header, in_rows)
    print("\nmagyc methods with an arbitrary scale are scaled to the field norm; the spread does not depend on it."
          "\ntwostep_hsi got |field| = the known norm (handheld 0.47 G, airborne mean |IGRF|) or, where none is"
          "\nknown, the mean distance of the fitted readings from their mean (scale only); noise_std = 0.2 % of it."
          "\nQMC author's calibration (qmc5883l_reference_params.csv, h = M m + c) was fitted by its author, "
          "\nprobably on the whole recording, so it is not a held-out number.")

    out = {"held": held_rows, "in": in_rows, "tgt": tgt}
    out["airborne"] = airborne(sets["airborne"], split["airborne"], est, notes)
    out["gap"] = part_gap(split, fits, worker, notes, reps=gap_reps)
    out["sap6"] = part_sap6(data / "sap6", worker, notes)
    if notes:
        print("\nnotes (real data):")
        summarise_notes(notes, limit=20)
    if worker is not None and not worker.available:
        print(f"magyc: unavailable ({worker.reason})")
    return out


def airborne(d, split, est, notes):
    fit, held, n = split
    igrf, pry = d["igrf"], d["pry"]
    r_all = attitude.reference_vectors(igrf, pry[:, 0], pry[:, 1], pry[:, 2])  # default "aerospace"
    r_fit, r_held = r_all[:n], r_all[n:]
    B_held = np.linalg.norm(igrf[n:], axis=1)
    vec = fluxcal.calibrate(fit, reference=r_fit)
    print(f"\n### Airborne: vector fit against IGRF and what the magnitude-only fits miss (held-out half, "
          f"{len(held)} rows; fit half {len(fit)} rows, mean |IGRF| {d['H']:.0f} nT)\n")
    rows = []

    def row(label, b, A, vector=False):
        h = (held - b) @ A.T
        hn = np.linalg.norm(h, axis=1)
        miss = hn - B_held
        dv = np.sqrt(np.mean(np.sum((h - r_held) ** 2, axis=1))) if vector else None
        rows.append([label, fmt(100 * hn.std() / hn.mean()), fmt(float(np.sqrt(np.mean(miss**2))), ".1f"),
                     fmt(float(miss.mean()), ".1f"), fmt(float(np.linalg.norm(b - vec.offset)), ".0f"),
                     fmt(dv, ".1f") if vector else "—"])

    row("uncalibrated (b = 0, A = I)", np.zeros(3), np.eye(3), vector=True)
    row("fluxcal calibrate(reference=IGRF) → vector", vec.offset, vec.matrix, vector=True)
    for (name, label), e in est.items():
        if name != "airborne":
            continue
        if e is None:
            rows.append([label, "failed", "—", "—", "—", "—"])
        elif isinstance(e, tuple):
            row(label + ("*" if ("ellipsoid_fit" in label or "sphere_fit" in label) else ""), *e)
        else:
            row(label + f" (field_norm {d['H']:.0f})", e.offset, e.matrix)
    table(["method", "spread %", "RMS(‖h‖−‖B‖) nT", "mean(‖h‖−‖B‖) nT", "‖b − b_vector‖ nT",
           "RMS ‖h − r‖ nT"], rows)
    print(f"\nvector fit summary: method {vec.summary.get('method')}, noise σ "
          f"{vec.summary.get('noise_sigma')}, warnings {vec.summary.get('warnings')}")
    mag = est.get(("airborne", "fluxcal calibrate (als+refine)"))
    if mag is not None:
        print(f"magnitude-only calibrate() on the airborne half says: identifiable = "
              f"{mag.summary.get('identifiable')}; warnings:")
        for w in mag.summary.get("warnings", []):
            print(f"  - {w}")
    return rows


def part_gap(split, fits, worker, notes, reps: int = 200, seed: int = 2026) -> dict:
    """Is the held-out difference between fluxcal and the best peer larger than what the recording
    itself can resolve? Two circular block bootstraps (block length by Politis & White 2004, arch's
    optimal_block_length, on the |h| series so the disturbance's time correlation is kept):
    (1) the held-out half resampled, both calibrations fixed — the judging noise;
    (2) the fitted half resampled and both methods refitted (fluxcal ALS in-process, magyc Fang in its
    venv), judged on the fixed held-out half — the fitting noise. Prints the difference
    fluxcal − peer in points of spread with its 95 % percentile interval."""
    try:
        from arch.bootstrap import CircularBlockBootstrap, optimal_block_length
    except ImportError:
        print("\n(gap bootstrap skipped: arch is not installed — pip install '.[bench]')")
        return {}

    ours_label, peer = "fluxcal fit_ellipsoid als", "ellipsoid_fit_fang"
    peer_label = f"magyc {peer}"
    names = [k for k in ("phone", "handheld", "qmc") if (k, ours_label) in fits and (k, peer_label) in fits]
    if reps <= 0 or not names:
        print("\n(gap bootstrap skipped: " + ("--gap-reps 0" if reps <= 0 else "no magyc Fang fit") + ")")
        return {}

    def block(series) -> int:
        return max(1, int(np.ceil(optimal_block_length(series)["circular"].iloc[0])))

    def spread_of(r) -> float:
        return 100.0 * r.std() / r.mean()

    rows, out = [], {}
    for k, name in enumerate(names):
        fit, held, _ = split[name]
        (bo, Ao), (bp, Ap) = fits[(name, ours_label)], fits[(name, peer_label)]
        ho, hp = (np.linalg.norm((held - b) @ A.T, axis=1) for b, A in ((bo, Ao), (bp, Ap)))
        diff = spread_of(ho) - spread_of(hp)
        # (1) judging noise: the same resampled held-out rows for both calibrations
        lb = block(hp / hp.mean())
        cbb = CircularBlockBootstrap(lb, np.arange(len(held)), seed=seed + k)
        d1 = np.array([spread_of(ho[i]) - spread_of(hp[i]) for (i,), _ in cbb.bootstrap(max(reps, 1000))])
        # (2) fitting noise: refit both on resampled fitted halves
        lf = block(np.linalg.norm((fit - bo) @ Ao.T, axis=1))
        cbb = CircularBlockBootstrap(lf, np.arange(len(fit)), seed=seed + 100 + k)
        idx = [i for (i,), _ in cbb.bootstrap(reps)]
        arrays = {f"r{j}": fit[i] for j, i in enumerate(idx)}
        jobs = [{"data": f"r{j}", "method": peer, "ref_norm": 1.0, "noise_std": 0.002} for j in range(reps)]
        pres = run_magyc(worker, arrays, jobs, notes)
        d2, so, sp = [], [], []
        for j, i in enumerate(idx):
            e = magyc_to_fluxcal(pres.get((f"r{j}", peer)))
            try:
                cal = fluxcal.fit_ellipsoid(fit[i], method="als")
            except ValueError as exc:
                notes.append(f"gap bootstrap: ALS raised {exc}")
                continue
            if e is None:
                continue
            so.append(spread(cal.offset, cal.matrix, held))
            sp.append(spread(*e, held))
            d2.append(so[-1] - sp[-1])
        d2 = np.array(d2)
        q1, q2 = np.percentile(d1, [2.5, 97.5]), np.percentile(d2, [2.5, 97.5]) if len(d2) else (np.nan, np.nan)
        rows.append([name, f"{diff:+.3f}", f"{lb}", f"[{q1[0]:+.3f}, {q1[1]:+.3f}]", f"{lf}",
                     f"{len(d2)}", f"[{q2[0]:+.3f}, {q2[1]:+.3f}]",
                     f"{np.std(so):.3f} / {np.std(sp):.3f}", f"{np.mean(d2 < 0):.2f}"])
        out[name] = {"diff": diff, "judge_ci": list(q1), "fit_ci": list(q2), "fit_runs": len(d2),
                     "p_fluxcal_better": float(np.mean(d2 < 0))}
    print("\n### Is the gap to the best peer resolvable? fluxcal ALS − magyc Fang, held-out spread (points)\n")
    table(["recording", "difference", "block (held)", "95 % judging noise", "block (fit)", "refits",
           "95 % fitting noise", "sd of each (fluxcal / Fang)", "share fluxcal better"], rows)
    print("\nCircular block bootstrap (arch), block lengths by Politis & White on the |h| series. 'judging':"
          "\nthe held-out half resampled, calibrations fixed; 'fitting': the fitted half resampled, both refitted,"
          "\njudged on the whole held-out half. An interval holding 0 means the recording cannot rank the two.")
    return out


def part_sap6(folder: Path, worker, notes) -> dict:
    units = sorted(p.stem for p in folder.glob("*.json"))
    print("\n### SAP6 (24 static shots per unit, µT): spread (%) fitted on all 24, and leave-one-out\n")
    data, cfg = {}, {}
    arrays, jobs = {}, []
    for u in units:
        m = np.array(json.loads((folder / f"{u}.json").read_text())["mag"], dtype=float)
        c = json.loads((folder / f"{u}.cfg").read_text())["calib"]["mag"]
        data[u], cfg[u] = m, c
        H = float(c["field_avg"])
        for k in range(-1, len(m)):  # -1: all shots; k: all but shot k
            key = f"{u}_all" if k < 0 else f"{u}_loo{k}"
            arrays[key] = m if k < 0 else np.delete(m, k, axis=0)
            for meth in MAGYC_METHODS:
                jobs.append({"data": key, "method": meth, "ref_norm": H, "noise_std": 0.002 * H})
    mres = run_magyc(worker, arrays, jobs, notes)
    labels = [lab for lab, _ in FLUXCAL_METHODS]
    if mres:
        labels += [f"magyc {m}" for m in MAGYC_METHODS]
    rows_all, rows_loo = [], []
    for label in labels:
        ra, rl = [label], [label]
        for u in units:
            m, H = data[u], float(cfg[u]["field_avg"])

            def fit_one(x, key):
                if label.startswith("fluxcal"):
                    try:
                        cal = fluxcal_fit(x, dict(FLUXCAL_METHODS)[label], field_norm=H)
                        return cal.offset, cal.matrix
                    except ValueError as exc:
                        notes.append(f"SAP6 {label} raised: {exc}")
                        return None
                meth = label.split(" ", 1)[1]
                e = magyc_to_fluxcal(mres.get((key, meth)))
                if e is None:
                    return None
                b, A = e
                return (b, scale_to(b, A, x, H)) if meth in ARBITRARY_SCALE else (b, A)

            e = fit_one(m, f"{u}_all")
            ra.append(fmt(spread(*e, m), ".3f") if e else "failed")
            mags = []
            for k in range(len(m)):
                e = fit_one(np.delete(m, k, axis=0), f"{u}_loo{k}")
                mags.append(np.linalg.norm(e[1] @ (m[k] - e[0])) if e else np.nan)
            mags = np.array(mags)
            nf = int(np.sum(~np.isfinite(mags)))
            ok = mags[np.isfinite(mags)]
            rl.append((fmt(100 * ok.std() / ok.mean(), ".3f") if len(ok) > 2 else "failed") + (f" ({nf} failed)" if nf else ""))
        rows_all.append(ra)
        rows_loo.append(rl)
    maker = ["maker's calibration (.cfg field_std/field_avg)"] + [
        fmt(100 * cfg[u]["field_std"] / cfg[u]["field_avg"], ".3f") for u in units]
    raw = ["uncalibrated ‖m − mean(m)‖"] + [fmt(spread(data[u].mean(0), np.eye(3), data[u]), ".2f") for u in units]
    print("Fitted on all 24 shots (in-sample):\n")
    table(["method"] + units, rows_all + [maker, raw])
    print("\nLeave-one-out (24 fits on 23 shots each; spread of the 24 left-out |h|):\n")
    table(["method"] + units, rows_loo)
    print("\nThe maker's number is in-sample and its model adds radial-basis (nonlinear) terms.")
    return {"all": rows_all, "loo": rows_loo}


# ----------------------------------------------------------------------------------------- main
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=50, help="seeded runs per simulated set (default 50)")
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--data", type=Path, default=DEFAULT_DATA, help="folder of the real recordings")
    ap.add_argument("--no-magyc", action="store_true", help="skip the peer (magyc) even if it is installed")
    ap.add_argument("--gap-reps", type=int, default=200,
                    help="block-bootstrap refits per recording for the fluxcal-vs-peer gap (default 200; 0 skips)")
    ap.add_argument("--skip-sim", action="store_true")
    ap.add_argument("--skip-real", action="store_true")
    args = ap.parse_args(argv)

    t_start = time.perf_counter()
    print(f"# fluxcal accuracy against peers — {_dt.date.today().isoformat()}")
    print(f"fluxcal {fluxcal.__version__}, NumPy {np.__version__}, Python {platform.python_version()}")
    worker = None
    if args.no_magyc:
        print("magyc: unavailable (skipped by --no-magyc)")
    else:
        worker = MagycWorker()
        if worker.available:
            v = worker.versions
            print(f"magyc {v['magyc']} (NumPy {v['numpy']}, Python {v['python']}) in {worker.python}")
        else:
            print(f"magyc: unavailable ({worker.reason})")
    if not args.skip_sim:
        part_sim(args.runs, args.seed, worker)
    if not args.skip_real:
        if args.data.is_dir():
            part_real(args.data, worker, gap_reps=args.gap_reps)
        else:
            print(f"\n(b) skipped: no real recordings at {args.data}")
    print(f"\ntotal {time.perf_counter() - t_start:.0f} s")
    print("\nreproduce:")
    print("  python3 -m venv build/bench-venv && build/bench-venv/bin/pip install \"numpy<2\" magyc   # peer venv, once")
    print("  .venv/bin/pip install arch   # the bench extra: block bootstrap of the gap to the peer, once")
    print(f"  .venv/bin/python bench/accuracy.py --runs {args.runs} --seed {args.seed} --gap-reps {args.gap_reps}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
