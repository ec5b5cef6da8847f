"""Gross outliers in magnetometer readings: I²C glitches that read 0,0,0, values stuck at an ADC rail,
spikes. A few of them wreck an ellipsoid fit (0.5 % zero rows make the least-squares matrix indefinite),
so `fluxcal.calibrate` screens for them before fitting, leaves them out, and says which rows and why.

A reading is off the ellipsoid when its distance from it, |h|/median|h| − 1 (with each reading's |field|,
(|h| − s·|field|)/(s·mean |field|), s the median |h|/|field|), over its noise scale (|Aᵀĥ|, or with axes of unequal
noise — equal variances rejected by a likelihood ratio — √Σₖ vₖ (Aᵀĥ)ₖ²) and √(1 ∓ its leverage) in the fit, lies further
from the median than the two-sided quantile at α/N (Bonferroni: with Gaussian noise a whole recording is flagged
wrongly with probability α) times the robust σ, 1.4826 · MAD — Student's t quantile, the robust σ being estimated
from few readings' residuals (_threshold), normal from a few thousand on. A reading of exactly 0,0,0 is suspect
before it is judged, so its line is at α over the number of such readings. Outliers distort a
fit of all readings and can hide each other (0.5 % zero rows and a few spikes raised the robust σ of
an ALS fit's distances 16×, so nothing stood out), so the distances come from the least-median-of-
squares fit (Rousseeuw 1984) over the ALS fit of all readings and 64 LS fits of random 20-reading
subsets, refitted (ALS) on the readings it accepts until the verdicts stop changing.

Left out are the readings off the ellipsoid that read exactly 0,0,0 or sit at an ADC rail, and those
in runs of at most GLITCH_RUN consecutive flagged readings (with at most one neighbour each side above half the
threshold: a glitch's neighbours are ordinary, and noise puts one of them there now and then). A longer
stretch off the ellipsoid (a magnet passing, the offset drifting, the field changing) is kept and reported: it is the sensor or its surroundings, not a bad
reading, and `fluxcal diagnose` is the tool for it. Rows must be in time order for this distinction.

With reference vectors (the true field of each reading in the sensor frame) the readings are judged
against the vector model m = W r + b instead: it is linear, so the least-median start is the best of the
least-squares fit and the subset fits. A first verdict takes each axis' robust σ; then, refitted on the
accepted readings, a reading's distance is the Mahalanobis distance of its residual with their
covariance (the axes' noise may be correlated), judged by Hotelling's T² at α/N and reported as the
normal deviate of the same tail probability, so thresholds and messages read as the ellipsoid's.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy import special, stats

from ._arrays import as_samples, changing_field, past_range
from .ellipsoid import fit_ellipsoid
from .twostep import twostep

SUBSET = 20      # readings per LMedS subset: 10 % contamination leaves a clean subset 12 % of the time
SUBSETS = 64     # so 64 subsets miss a clean one with probability 3e-4
MIN_SAMPLES = 40
# The robust σ (1.4826 · MAD) scatters like the standard deviation of this share of the readings (its asymptotic
# efficiency at the normal, 2 (2 q φ(q))² with q = Φ⁻¹(¾): 0.37), less the fitted parameters: see _threshold.
_Q = stats.norm.ppf(0.75)
MAD_DOF_SHARE = 2 * (2 * _Q * stats.norm.pdf(_Q)) ** 2
GLITCH_RUN = 3   # a glitch lasts a sample or a short burst; a longer stretch off the ellipsoid is a
                 # disturbance or a drift of the sensor, which the calibration keeps and diagnose explains
NOISE_FACTOR = 2.0  # a fit whose distances scatter less than this × the white noise explains the readings
SCORED = 400     # readings the subset fits are scored on (the median needs no more to rank them)
VECTOR_MODEL = "the reference-vector model"
# As the C++ fits' check (cpp/src/quadric.hpp kDominating, kDominatingShare): a reading this many times farther from
# the readings' median than the median reading is off any sensor's ellipsoid, when at most this share lie so far.
DOMINATING = 10.0
DOMINATING_SHARE = 0.01
# A reading whose |h| is off the ellipsoid's by more than this share of the field is no disturbance a calibration
# absorbs, in a stretch or alone: left out. A burst of 20 garbage readings at 2–5× the field (an I²C hiccup of
# 0.4 s) was kept as a "stretch" and the fit then failed; a slow drift or a passing magnet keeps its readings
# within it, and a calibration's residuals are a few % of the field.
GROSS = 0.5
# Readings off the model, not 0,0,0 or at a rail, beyond this share are said to be more than glitches: a bus's
# glitches are rare (the real recordings: 0 to 2 in 22745), while a log of two sessions whose offset moved by 20 % of
# the field, in no time order, had 9 % "left out" and the rest fitted 4 % of the field off the truth.
MANY_OUTLIERS = 0.02


@dataclass
class Outliers:
    """Rows left out (indices into the readings given), and how they were judged."""
    rows: np.ndarray
    threshold: float = 0.0           # in robust σ
    robust_sigma: float = 0.0        # of the relative radial distance (_distances) (the vector
                                     # model: the RMS residual σ over axes, in the readings' units)
    largest: float = 0.0             # the largest flagged distance, in robust σ
    kinds: dict = field(default_factory=dict)  # "zero" / "rail": how many of the rows look like that
    screened: bool = True            # False: too few readings (< MIN_SAMPLES) or NaN, nothing judged
    stretches: list = field(default_factory=list)  # (first, last, largest σ) of longer runs off the model, kept
    model: str = "the ellipsoid"     # what the readings were judged against
    zero_threshold: float = 0.0      # in robust σ, the line for readings of exactly 0,0,0 (0: `threshold`'s)
    zeros_within: int = 0            # of the rows, 0,0,0 readings within `threshold` (left out by `zero_threshold`)

    def __len__(self) -> int:
        return len(self.rows)

    def to_dict(self) -> dict:
        return {"screened": self.screened, "rows": self.rows.tolist(), "count": len(self.rows),
                "threshold_sigma": self.threshold, "zero_threshold_sigma": self.zero_threshold or self.threshold,
                "robust_sigma": self.robust_sigma, "largest_sigma": self.largest, "kinds": dict(self.kinds),
                "stretches_kept": [list(s) for s in self.stretches]}

    def messages(self, n: int) -> list:
        """The warnings for calibrate's summary: what was left out, and which stretches were kept."""
        out = []
        if len(self.rows):
            shown = ", ".join(str(r) for r in self.rows[:8]) + (", …" if len(self.rows) > 8 else "")
            kinds = "".join(f"; {k} {what}" for what, k in (
                ("read exactly 0,0 in the plane (glitches)" if self.model.startswith("the ellipse ") or
                 self.model == "the ellipse" else "read exactly 0,0,0 (glitches)", self.kinds.get("zero", 0)),
                ("sit at a column's extreme value, repeated (ADC rail)", self.kinds.get("rail", 0)),
                ("lie past any sensor's range (their squares overflow)", self.kinds.get("overflow", 0)),
                (f"are off |h| by more than {GROSS:.0%} of the field (garbage, or a magnet at the sensor: no "
                 "calibration absorbs them, in a stretch or alone)", self.kinds.get("gross", 0)),
                (f"lie more than {DOMINATING:g}× farther from the readings' median than the median reading (spikes, "
                 "judged before the plane was found)", self.kinds.get("far", 0))) if k)
            largest = f" (up to {self.largest:.3g})" if self.largest > 0 else ""  # (none but readings past range)
            plain = len(self.rows) - sum(self.kinds.get(k, 0) for k in ("zero", "rail", "overflow", "gross", "far"))
            many = (f"; glitches are rarely so many ({100 * plain / n:.1f} % of the readings): a second group of "
                    "readings (an offset that moved within the log, two sessions in one file) or a disturbance would "
                    f"look so, and the fit of the rest may be biased by it — {self._cause_tool()}"
                    if plain > MANY_OUTLIERS * n else "")
            zero_line = (f"; exact zeros, suspect before they are measured, are judged at "
                         f"{self.zero_threshold:.1f} σ" if self.zeros_within else "")
            judged = (f"that lie more than {self.threshold:.1f} robust σ{largest} off {self.model} (rows {shown}"
                      f"{kinds}{zero_line})"
                      if self.threshold > 0 else  # (too few readings for the robust fits: the far-reading rule only)
                      f"more than {DOMINATING:g}× farther from the readings' median than the median reading (rows "
                      f"{shown}; under {MIN_SAMPLES} readings, too few for the robust screen, only such are judged)")
            out.append(f"left out {len(self.rows)} of {n} readings {judged}; outliers='keep' (--outliers keep) keeps "
                       f"them{many}")
        if self.stretches:
            shown = ", ".join(f"{a}–{b} (up to {z:.0f} σ)" for a, b, z in self.stretches[:4])
            out.append(f"rows {shown}{', …' if len(self.stretches) > 4 else ''} lie off {self.model} for a stretch "
                       f"of more than {GLITCH_RUN} readings: a disturbance or a drift rather than glitches, kept in "
                       f"the fit; {self._cause_tool()}")
        return out

    def _cause_tool(self) -> str:
        """Where to look for the cause: diagnose takes a 3-D log, not a planar one (it refuses yaw-only readings)."""
        return ("calibrate --planar --plot shows them against the heading" if self.model.startswith("the ellipse")
                else "fluxcal diagnose looks for the cause")


def _distances(cal, m: np.ndarray, norms=None, axis_noise=None) -> np.ndarray:
    """|h|/median|h| − 1; with each reading's |field| (`norms`), (|h| − s·|field|)/(s·mean |field|) with s the median
    |h|/|field|: a spike in either stands out. Each divided by its noise scale |Aᵀĥ| over the median's (with the axes'
    relative noise variances `axis_noise`, √Σₖ vₖ (Aᵀĥ)ₖ²). (Not |h|/|field| − 1: the noise adds to the readings, so
    its share of a low |field| is larger, and along an orbit, |F| 22–47 µT, the equator's noise was taken for a
    disturbance.)"""
    distance, gain = _raw_distances(cal, m, norms, axis_noise)
    return distance / (gain / np.median(gain))


def _raw_distances(cal, m: np.ndarray, norms=None, axis_noise=None, squared_gradient=False) -> tuple:
    """(`_distances` before each is divided by its noise scale, that scale; or with `squared_gradient` the squared
    components of Aᵀĥ, N × dim, in its place)."""
    h = cal.apply(m)
    radius = np.linalg.norm(h, axis=1)
    # Each distance over its own noise scale: the noise adds to the readings, and |h| sees it through A along ĥ, so
    # its share is |Aᵀĥ| — ±20 % soft iron makes it 1.5× larger in some directions than others, and judged by one
    # σ those directions' noise alone passed the Bonferroni line in 8 of 100 clean recordings (α = 1 %).
    with np.errstate(invalid="ignore", divide="ignore"):
        g2 = ((h / radius[:, None]) @ cal.matrix) ** 2
    if norms is None:
        distance = radius / np.median(radius) - 1.0
    else:
        s = np.median(radius / norms)
        distance = (radius - s * norms) / (s * np.mean(norms))
    if squared_gradient:
        return distance, g2
    with np.errstate(invalid="ignore"):
        gain = np.sqrt(g2 @ (np.ones(m.shape[1]) if axis_noise is None else axis_noise))
    ok = np.isfinite(gain) & (gain > 0) & np.all(np.isfinite(cal.matrix))
    return distance, np.where(ok, gain, np.median(gain[ok]) if ok.any() else 1.0)


AXIS_NOISE_ALPHA = 0.01  # the axes' noise is taken as unequal when equal variances are rejected at this level
AXIS_NOISE_SE = 0.5      # … each axis' own where its log-variance is known to this standard error (±65 % in variance)


def _axis_noise(cal, m: np.ndarray, keep: np.ndarray, norms=None, leverage=None) -> np.ndarray | None:
    """Each axis' noise variance over their mean, by maximum likelihood from the distances of the readings `keep`
    (one's variance is Σₖ vₖ (Aᵀĥ)ₖ², Gaussian), or None when the likelihood ratio against equal variances stays within
    χ²(dim − 1) at AXIS_NOISE_ALPHA. A sensor's axes need not be equally noisy (a z axis of a separate die, twice
    the others' σ): judged by one σ, a noisy axis's ordinary readings passed the Bonferroni line — one or more
    "glitches" in 3 of 5 clean 3000-reading recordings at σ_z = 2σ_x, 5 of 5 at 3σ_x, against α = 1 %.
    `leverage`: `_leverage_scale(cal, m, keep)` when the caller has it."""
    from scipy.optimize import minimize

    d, g2 = _raw_distances(cal, m[keep], None if norms is None else norms[keep], squared_gradient=True)
    leverage = _leverage_scale(cal, m, keep) if leverage is None else leverage
    d = d / leverage[keep]  # (the fit pulls toward its own readings: by √(1 − leverage))
    ok = np.isfinite(d) & np.all(np.isfinite(g2), axis=1) & (g2.sum(axis=1) > 0)
    dim = m.shape[1]
    if ok.sum() < 10 * dim:
        return None
    d, g2 = d[ok] - np.median(d[ok]), g2[ok]

    def deviance(log_v):  # −2 log L (constants dropped) and its gradient in log v
        v = g2 @ np.exp(log_v)
        r = d * d / v
        return float(np.sum(np.log(v) + r)), np.exp(log_v) * (g2.T @ ((1.0 - r) / v))
    equal = np.log(np.mean(d * d / g2.sum(axis=1)))
    at_equal = deviance(np.full(dim, equal))[0]
    # (bounded at 100× the equal variance either way: an axis the readings barely turn through is not determined)
    best = minimize(deviance, np.full(dim, equal), jac=True, method="L-BFGS-B",
                    bounds=[(equal - np.log(100.0), equal + np.log(100.0))] * dim)
    if not np.isfinite(best.fun) or at_equal - best.fun <= stats.chi2.isf(AXIS_NOISE_ALPHA, dim - 1):
        return None
    v = np.exp(best.x)
    # An axis the readings barely turn through (a level turn's z) leaves its variance undetermined, free to reach a
    # bound and hide a spike along it: it keeps the equal variance unless its log-variance's standard error (Fisher
    # information ½ Σᵢ wᵢₖ wᵢₗ, wᵢₖ = vₖ (Aᵀĥ)ᵢₖ² / vᵢ) is within AXIS_NOISE_SE.
    w = g2 * v / (g2 @ v)[:, None]
    with np.errstate(all="ignore"):
        se = np.sqrt(np.abs(np.diag(np.linalg.pinv(0.5 * w.T @ w))))
    v = np.where(se <= AXIS_NOISE_SE, v, np.exp(equal))
    return v / v.mean()


def _subset_quadrics(m: np.ndarray, rng, change=None):
    """Least-squares quadrics x'Mx + 2v'x + d = 0 through SUBSETS random subsets of SUBSET readings, all
    at once (a batched SVD; the readings centred and scaled first for conditioning). Returns the
    centres (k×D) and shape matrices (k×D×D, |S^½ (x − c)| = 1 on the quadric) of those that are
    ellipsoids (ellipses for D = 2 columns), in the readings' units. With `change` (each reading's (H_k/H̄)² − 1, a
    field that changes) the quadric has a term in it, x'Mx + 2v'x + d + e·change = 0, and |S^½ (x − c)| = H_k/H̄
    instead."""
    # (robustly: a mean and a std had taken the scale of one reading of 1e16, and no subset was an ellipsoid)
    mu = np.median(m, axis=0)
    scale = float(np.median(np.linalg.norm(m - mu, axis=1))) or 1.0
    rows = rng.integers(0, len(m), (SUBSETS, SUBSET))  # a repeated reading only weakens a subset
    x = (m[rows] - mu) / scale
    dim = m.shape[1]
    pairs = [(i, i) for i in range(dim)] + [(i, j) for i in range(dim) for j in range(i + 1, dim)]
    columns = ([x[..., i] * x[..., j] * (1 if i == j else 2) for i, j in pairs] + [2 * x[..., i] for i in range(dim)]
               + [np.ones_like(x[..., 0])])
    design = np.stack(columns + ([] if change is None else [change[rows]]), axis=-1)
    p = np.linalg.svd(design, full_matrices=False)[2][:, -1, :]  # the null direction of each subset's design
    M = np.zeros((len(p), dim, dim))
    for c, (i, j) in enumerate(pairs):
        M[:, i, j] = M[:, j, i] = p[:, c]
    v, d = p[:, len(pairs):len(pairs) + dim], p[:, len(pairs) + dim]
    ok = np.abs(np.linalg.det(M)) > 1e-12
    M, v, d = M[ok], v[ok], d[ok]
    centre = -np.linalg.solve(M, v[..., None])[..., 0]
    k = np.einsum("ni,nij,nj->n", centre, M, centre) - d
    S = M / k[:, None, None]
    ellipsoid = np.all(np.linalg.eigvalsh(S) > 0, axis=1)
    return centre[ellipsoid] * scale + mu, S[ellipsoid] / scale ** 2


@dataclass
class Quadric:
    """An ellipsoid (or an ellipse, 2 columns) as the screen judges readings against it: h = A (m − b)."""
    offset: np.ndarray
    matrix: np.ndarray

    def apply(self, m: np.ndarray) -> np.ndarray:
        return (np.asarray(m, dtype=float) - self.offset) @ self.matrix.T


def _leverage_scale(cal, m: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """√(1 − h) for the readings the fit `cal` was fitted to (`keep`), √(1 + h) for the others, h each reading's
    leverage in the linearised fit of the distances (_distances: Sampson's, |h| − R over |Aᵀĥ|) to the offset and
    the symmetric matrix, as the vector model's _vector_z: a fit pulls toward the readings it takes, and a reading
    left out of it lies off it by its own noise and the fit's error. Without this, a reading of a sparse direction,
    flagged by the least-median start (a 20-reading fit), was refitted without and then lay off by
    √((1 + h)/(1 − h̄)), 1.4× its noise at h = 0.4 of 45 readings of a sphere (h̄ = 9/45): 14 of 400 clean
    simulations left such a reading out (3.5 %, α = 1 %), all within the line when fitted with it; with this, 2.
    The Jacobian is taken where the reading's direction meets the ellipsoid (x R/|h|), so a spike's leverage is its
    direction's, not one its distance blows up."""
    x = np.asarray(m, dtype=float) - cal.offset
    h = x @ cal.matrix.T
    radius = np.linalg.norm(h, axis=1)
    ok = np.isfinite(radius) & (radius > 0)
    if not ok.any():
        return np.ones(len(m))
    safe = np.where(ok, radius, 1.0)[:, None]
    u = np.where(ok[:, None], h / safe, 0.0)                       # ĥ
    x = np.where(ok[:, None], x * (np.median(radius[ok]) / safe), 0.0)  # on the ellipsoid, in the reading's direction
    g = u @ cal.matrix                                             # ∇|h| with respect to the reading: Aᵀĥ
    slope = np.linalg.norm(g, axis=1)
    slope = np.where(slope > 0, slope, 1.0)
    dim = m.shape[1]
    columns = [g[:, j] for j in range(dim)] + [u[:, j] * x[:, k] + (u[:, k] * x[:, j] if j != k else 0.0)
                                               for j in range(dim) for k in range(j, dim)]
    J = np.column_stack(columns) / slope[:, None]
    J /= np.maximum(np.linalg.norm(J[keep], axis=0), 1e-300)  # (unit columns: offsets and gains differ in scale)
    lev = _row_quadratic(J, np.linalg.pinv(J[keep].T @ J[keep]))
    return np.sqrt(np.where(keep, np.maximum(1.0 - lev, 1e-12), 1.0 + lev))


def _robust_z(e: np.ndarray):
    centre = np.median(e)
    sigma = 1.4826 * np.median(np.abs(e - centre))
    return np.abs(e - centre) / max(sigma, 1e-300), sigma


def _try_fit(m: np.ndarray, method: str, norms=None):
    """The ALS (`method`) ellipsoid of the readings, or with each reading's |field| changing, TWOSTEP with them (the
    ellipsoid's quadric takes the change for the shape: on a slow tumble along an orbit it was none); None when the
    fit fails or is no ellipsoid."""
    try:
        if norms is not None and changing_field(norms):
            cal = twostep(m, norms, standard_errors=False)
        else:
            cal = fit_ellipsoid(m, method=method)
    except (ValueError, RuntimeError):
        return None
    w = np.linalg.eigvalsh(0.5 * (cal.matrix + cal.matrix.T))
    return cal if np.all(np.isfinite(cal.matrix)) and w.min() > 0 else None


def _lmeds_start(m: np.ndarray, rng, best=None, norms=None):
    """The fit with the least median absolute distance: `best` (the ALS fit of all readings), or the quadric
    through one of the random subsets (scored on at most SCORED readings: the median needs no more). With each
    reading's |field| (`norms`, changing) the distances are as _distances takes them. Returns `best`, a Quadric or
    None."""
    chosen = np.arange(len(m)) if len(m) <= SCORED else rng.choice(len(m), SCORED, replace=False)
    scored = m[chosen]
    changing = norms is not None and changing_field(norms)
    relative = norms[chosen] / np.mean(norms) if changing else 1.0

    def score(radii, slopes):
        """k × n radii and |∇radius| → k scores: the median absolute distance off each quadric in the readings'
        units (radius − its median, over its slope: Sampson's). Not relative to the quadric's radius: every
        reading is nearly equally far from a centre 45 000 µT away, and a subset's huge ellipsoid so centred had
        scored 0.1 % against a right fit's 0.5 % (a burst of readings at 100× the field in a hand turn)."""
        s = np.median(radii / relative, axis=1, keepdims=True)
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.nan_to_num(np.median(np.abs(radii - s * relative) / slopes, axis=1), nan=np.inf)

    if best is not None:
        h = best.apply(scored)
        radius = np.linalg.norm(h, axis=1)
        best_score = score(radius[None], np.linalg.norm(h @ best.matrix, axis=1)[None] / radius[None])[0]
    else:
        best_score = np.inf
    centres, shapes = _subset_quadrics(m, rng, (norms / np.mean(norms)) ** 2 - 1.0 if changing else None)
    if len(centres):
        d = scored[None, :, :] - centres[:, None, :]
        Sd = d @ shapes
        radii = np.sqrt(np.sum(Sd * d, axis=2))
        scores = score(radii, np.linalg.norm(Sd, axis=2) / radii)
        j = int(np.argmin(scores))
        if scores[j] < best_score:
            w, V = np.linalg.eigh(shapes[j])
            best = Quadric(offset=centres[j], matrix=(V * np.sqrt(w)) @ V.T)
    return best


# A column's extreme value met this many times, at least, and as often as a rail is (cable.RAIL_RATIO× the levels
# below it): a saturated axis, said (a blind check: 195 of 400 planar readings at ±18000 gave an 11 % gain error,
# exit 0, and no word of a rail)
RAIL_LEAST = 5


def rail_values(columns: dict) -> list:
    """[(name, value)] of the columns (name → values) whose largest or smallest value repeats as a saturated axis's
    does (cable._on_rail's rule: RAIL_RATIO× as often as the values just inside it, and RAIL_LEAST times)."""
    from .cable import _on_rail

    found = []
    for name, values in columns.items():
        v = np.asarray(values, dtype=float)
        v = v[np.isfinite(v)]
        for sign in (1.0, -1.0):
            if v.size and _on_rail(sign * v, max(RAIL_LEAST, int(0.01 * v.size))):
                found.append((name, sign * float(np.max(sign * v))))
    return found


def one_stretch(hit: np.ndarray) -> bool:
    """Whether the rows `hit` (a mask in time order) lie in one stretch of time (spanning under RAIL_SPREAD× their
    count): a sensor held still, whose rail — or rest at an axis's extreme on a coarse grid — is one pose."""
    rows = np.flatnonzero(hit)
    return bool(rows.size) and rows[-1] - rows[0] + 1 < RAIL_SPREAD * rows.size


RAIL_SPREAD = 2.0
RAIL_TURNING = 0.05  # the other axes moving over more than this share of their span within the stretch: a turn


def held_still(m: np.ndarray, hit: np.ndarray, axis: int) -> bool:
    """Whether the readings `hit` at a rail of `axis` are one pose: within one stretch of time (`one_stretch`) with the
    other axes still — the middle 80 % of each within RAIL_TURNING of its span there (live's find_rails' rule, its
    ends aside: a rest's last readings as the turn begins). A hand turn passes through the saturating directions in
    one stretch too, its other axes sweeping (a blind check's clipped x, 55 readings in a row, was called "held
    still" and kept while the outlier screen left 50 of them out)."""
    if not one_stretch(hit):
        return False
    others = [k for k in range(m.shape[1]) if k != axis]
    lo, hi = np.percentile(m[hit][:, others], [10, 90], axis=0)
    return not np.any(hi - lo > RAIL_TURNING * np.ptp(m[:, others], axis=0))


def rail_words(columns: dict, found=None, applied: bool = False) -> str | None:
    """A warning naming the columns (name → values) on a rail (`rail_values`, or `found` when the caller has them),
    with how many readings sit there and what that does to a calibration fitted to them (`applied`: to their corrected
    field, `fluxcal apply`'s); None when none is."""
    said = []
    for name, top in rail_values(columns) if found is None else found:
        v = np.asarray(columns[name], dtype=float)
        said.append(f"{name} at {top:g} in {int(np.sum(v == top))} of {int(np.sum(np.isfinite(v)))} readings")
    if not said:
        return None
    said = (f"readings on a rail: {'; '.join(said)} — the same extreme value far more often than any value beside it: "
            "a sensor axis saturated at its range? ")
    if applied:  # (a blind check's held-out log: 265 such rows corrected 2.7 µT off, the rest 0.14, nothing said)
        return said + "Their corrected field is not the field (the axis read its limit): they are written; leave them out"
    return said + ("Its readings bias the calibration (an axis clipped on half its readings read 11 % off in gain): use a "
                   "wider range, or leave those readings out")


def _at_rail(m: np.ndarray) -> np.ndarray:
    """Readings with a value at its column's minimum or maximum when that extreme is hit more than once
    (an ADC rail)."""
    at_rail = np.zeros(len(m), dtype=bool)
    for column in np.ascontiguousarray(m.T):  # a column at a time: NumPy's axis-0 reductions of N×3 are slow
        for extreme in (column.min(), column.max()):
            hit = column == extreme
            if np.count_nonzero(hit) >= 2:
                at_rail |= hit
    return at_rail


def _row_quadratic(A: np.ndarray, M: np.ndarray) -> np.ndarray:
    """a_i M a_iᵀ for every row a_i of A (leverages, Mahalanobis distances); the row sums as a product
    with ones, 3× faster than einsum or sum(axis=1) on N × 4."""
    return ((A @ M) * A) @ np.ones(A.shape[1])


def _spans(gram: np.ndarray) -> bool:
    """Whether the columns behind the Gram matrix XᵀX are independent: its condition, columns scaled to unit
    norm, below 1e12 (X's below 1e6). A reference that does not turn, or a constant column, fails."""
    d = np.sqrt(np.diag(gram))
    if not np.all(d > 0):
        return False
    w = np.linalg.eigvalsh(gram / np.outer(d, d))
    return bool(w[0] > 1e-12 * w[-1])


def _squares_representable(a: np.ndarray) -> bool:
    """Whether `a` is finite and a sum of its squares is a finite, normal double, as the fits require
    (fluxcal's C++ checks): otherwise the screen's statistics would overflow or underflow, with NumPy
    warnings before the fit's clear error."""
    largest = float(np.max(np.abs(a))) if a.size else 0.0
    square = largest * largest
    return bool(np.isfinite(square * a.size) and (largest == 0.0 or square >= np.finfo(float).tiny))


def find_outliers(samples, reference=None, alpha: float = 0.01, seed: int = 0, field_norms=None,
                  ellipse=None) -> Outliers:
    """Gross outliers of `samples` (N×3 readings of a turning magnetometer), judged against the ellipsoid,
    or with `reference` (the true field of each reading, sensor frame) against the vector model
    m = W r + b; see the module doc. With `field_norms` (each reading's |field|, logged beside it) the fits take
    them (TWOSTEP when they change) and a reading's distance is (|h| − s·|field|)/(s·mean |field|): a glitch in that
    log is left out with its reading. `ellipse`: samples are N×2 (a planar calibration's plane coordinates), judged
    against the ellipse that `ellipse(readings, field_norms)` fits (an object with offset, matrix and apply, or None
    when it fails), in place of the ALS ellipsoid."""
    m = as_samples(samples, columns=3 if ellipse is None else 2)  # NaN is let through: the fit names the row
    n = len(m)
    if reference is not None:
        return _vector_outliers(m, as_samples(reference, "reference"), alpha, seed)
    fit = (lambda x, norms: _try_fit(x, "als", norms)) if ellipse is None else ellipse
    model = "the ellipsoid" if ellipse is None else "the ellipse"
    dim = m.shape[1]
    parameters = dim + dim * (dim + 1) // 2  # centre and symmetric matrix: the ellipsoid's 9, the ellipse's 5
    threshold = _threshold(n, alpha, parameters)
    # Readings of exactly 0,0,0 (0,0 in the plane: an I²C glitch) are suspect before their distance is seen, so only
    # they are tested, not all n: their line is at α/(2k), k of them, not α/(2n). At the n-reading line, 45 clean
    # readings and a 0,0,0 one whose |h| happened to be within 3–6 σ of the ellipsoid's kept it in 1–2 % of
    # simulations, and on a plane that reading, off it along the normal, tilted it by 5°.
    zero = ~m.any(axis=1) if m.ndim == 2 else np.zeros(n, dtype=bool)
    zero_threshold = _threshold(n, alpha, parameters, max(int(zero.sum()), 1))
    line = np.where(zero, zero_threshold, threshold)  # (zero_threshold ≤ threshold: it tests fewer readings)
    none = Outliers(np.zeros(0, dtype=int), threshold, screened=False, model=model, zero_threshold=zero_threshold)
    huge = past_range(m)
    if huge.any() and n - huge.sum() >= MIN_SAMPLES:  # readings past any sensor's range (1e300): left out first
        kept = np.flatnonzero(~huge)
        inner = find_outliers(m[kept], None, alpha, seed, None if field_norms is None else field_norms[kept], ellipse)
        return replace(inner, rows=np.sort(np.concatenate([np.flatnonzero(huge), kept[inner.rows]])), screened=True,
                       kinds={**inner.kinds, "overflow": int(huge.sum())},
                       stretches=[(int(kept[a]), int(kept[b]), z) for a, b, z in inner.stretches])
    if n < MIN_SAMPLES and n >= 10 and np.isfinite(m).all():
        # too few for the robust fits; a reading 10× farther out than the median one is still no reading of a
        # turned sensor (one spike in 35 readings left the fit 'dominated', with remedies that could not work)
        far = far_readings(m)
        return replace(none, rows=far, screened=bool(len(far)), threshold=0.0)
    if n < MIN_SAMPLES or not _squares_representable(m):
        return none  # too few to judge, NaN or out of scale: the fit itself names the problem
    start = fit(m, field_norms)
    quick = _fits_to_the_noise(m, start, line, field_norms)
    if quick is not None:
        return Outliers(np.zeros(0, dtype=int), threshold, quick, model=model, zero_threshold=zero_threshold)
    cal = _lmeds_start(m, np.random.default_rng(seed), start, field_norms)
    if cal is None:
        return none  # no subset fits an ellipsoid: the fit itself will say why
    z, sigma = _robust_z(_distances(cal, m, field_norms))
    for _ in range(3):  # refit on the accepted readings and judge everything again, until nothing changes
        keep = z <= line
        refit = fit(m[keep], None if field_norms is None else field_norms[keep])
        if refit is None:
            break
        leverage = _leverage_scale(refit, m, keep)
        axes = _axis_noise(refit, m, keep, field_norms, leverage)
        z_new, sigma = _robust_z(_distances(refit, m, field_norms, axes) / leverage)
        changed = np.any((z_new > line) != (z > line))
        z = z_new
        if not changed:
            break
    out = _verdicts(m, z, threshold, float(sigma), model if field_norms is None else f"{model} (each against its own "
                    "|field|)", line=line)
    within = int(np.sum(zero[out.rows] & (z[out.rows] <= threshold)))
    return replace(out, zero_threshold=zero_threshold, zeros_within=within)


def _threshold(n: int, alpha: float, parameters: int, tests: int | None = None) -> float:
    """The line in robust σ that n clean readings all stay within with probability 1 − α (Bonferroni at α/n,
    two-sided): Student's t quantile with ν = MAD_DOF_SHARE · (n − parameters) in place of the normal one, since
    the σ a reading is divided by is itself estimated, from n readings' residuals off a fit of `parameters`.
    `tests`: the readings judged (default n), for readings suspect before they are measured (0,0,0).
    The MAD's σ scatters by 1.17/√n (18 % at 45 readings), so the normal line took the largest reading of every
    recording whose σ came out small for an outlier: clean simulated logs (σ 0.2–1 % of the field) had rows left out
    in 7 % (ellipse of a level turn, 45 readings), 6 % (60), 2–3 % (100–300) and 22 % (ellipsoid, 45), 12 % (60),
    6 % (100), 2 % (300) of 400 each, against α = 1 % — and iid normal numbers judged by their own MAD in 6.4 % (45)
    and 1.8 % (300), so it is the σ's scatter, not the fits. The t line is 4.85 robust σ at 45 readings of an ellipse
    (normal 3.69), 5.0 of an ellipsoid, 4.3 at 300 (4.15), 4.9 at 10 000 (normal 4.89). With it and
    the leverage (_leverage_scale): 0–0.75 % (ellipse), 0.5–1 % (ellipsoid) at 45–300 readings; spikes at 3× and
    10× the field still all found."""
    if n <= 0:
        return 0.0
    nu = MAD_DOF_SHARE * (n - parameters)
    tail = alpha / (2 * (n if tests is None else tests))
    return float(stats.t.isf(tail, max(nu, 1.0)))  # (ν < 1: too few to judge, and find_outliers does not)


def far_readings(m: np.ndarray) -> np.ndarray:
    """The rows of the few readings (at most DOMINATING_SHARE, at least one) more than DOMINATING times the median
    reading's distance from the readings' median (per axis); none when more lie that far (a second group of
    readings, not outliers)."""
    distance = np.linalg.norm(m - np.median(m, axis=0), axis=1)
    typical = float(np.median(distance))
    far = np.flatnonzero(distance > DOMINATING * typical) if typical > 0 else np.zeros(0, dtype=int)
    return far if len(far) <= max(1, int(DOMINATING_SHARE * len(m))) else np.zeros(0, dtype=int)


def _verdicts(m: np.ndarray, z: np.ndarray, threshold: float, sigma: float, model: str = "the ellipsoid",
              gross: float | None = GROSS, line: np.ndarray | None = None) -> Outliers:
    """From each reading's distance off the model (`z`, robust σ) to the rows left out: flagged readings that
    cannot be real (0,0,0, at a rail, or off by more than `gross` of the field: GROSS) or lie in a run of at most
    GLITCH_RUN; longer runs are kept as stretches. `gross` None: not judged (the vector model's σ is not a share
    of the field). `line`: each reading's own threshold (lower for 0,0,0 readings), default `threshold`."""
    flagged = z > (threshold if line is None else line)
    zero, rail = ~m.any(axis=1), _at_rail(m)
    impossible = zero | rail
    if gross is not None:
        impossible |= flagged & (z * sigma > gross)
    drop, stretches = flagged & impossible, []
    # A run's extent is where the distance stays above half the threshold (hysteresis): a glitch's
    # neighbours are ordinary readings, a disturbance's rise and fall above the noise too. A glitch's flagged
    # readings span at most GLITCH_RUN, with at most one more reading each side in the run (a clean reading 3σ off,
    # 1 in 40, beside a 3-reading burst had made it a "stretch" of 4, kept: a blind check's 11 in 100); noise
    # correlated in time rises and falls over several readings and stays a stretch
    for first, last in _runs(z > threshold / 2):
        if not flagged[first:last + 1].any():
            continue
        marked = first + np.flatnonzero(flagged[first:last + 1])
        if marked[-1] - marked[0] + 1 <= GLITCH_RUN and marked[0] - first <= 1 and last - marked[-1] <= 1:
            drop[first:last + 1] |= flagged[first:last + 1]
        elif (flagged & ~drop)[first:last + 1].any():  # not a run of 0,0,0 or rail readings, all left out
            stretches.append((int(first), int(last), float(z[first:last + 1].max())))
    rows = np.flatnonzero(drop)
    far = impossible & ~zero & ~rail
    kinds = {"zero": int(zero[rows].sum()), "rail": int(np.sum(rail[rows] & ~zero[rows]))} if len(rows) else {}
    if far[rows].any():
        kinds["gross"] = int(far[rows].sum())
    return Outliers(rows, threshold, sigma, float(z[rows].max()) if len(rows) else 0.0, kinds,
                    stretches=stretches, model=model)


def _vector_outliers(m: np.ndarray, r: np.ndarray, alpha: float, seed: int) -> Outliers:
    """The vector model's screen (see the module doc). robust_sigma: the RMS over axes of the residual σ
    of the accepted readings, in the readings' units."""
    n = len(m)
    threshold = float(stats.norm.isf(alpha / (2 * n))) if n else 0.0
    none = Outliers(np.zeros(0, dtype=int), threshold, screened=False, model=VECTOR_MODEL)
    X = np.column_stack([r, np.ones(n)]) if r.shape == m.shape and m.ndim == 2 else None
    if n < MIN_SAMPLES or X is None or not (_squares_representable(m) and _squares_representable(r)) \
            or not _spans(X.T @ X):
        return none  # too few, NaN, out of scale, or a reference that does not turn: the fit names the problem
    rng = np.random.default_rng(seed)
    scored = rng.choice(n, min(n, SCORED), replace=False)
    subsets = rng.integers(0, n, (SUBSETS, SUBSET))
    fits = np.concatenate([np.linalg.solve(X.T @ X, X.T @ m)[None],
                           np.linalg.pinv(X[subsets]) @ m[subsets]])  # k × 4 × 3
    scores = np.median(np.sum((m[scored][None] - X[scored][None] @ fits) ** 2, axis=2), axis=1)
    e = m - X @ fits[int(np.argmin(scores))]
    e = e - np.median(e, axis=0)
    # first verdict per axis (MAD), then Mahalanobis distances with the accepted readings' covariance: the
    # noise of the three axes may be correlated (one ADC, one reference error), which per-axis σ misses
    chi2 = np.sum((e / np.maximum(1.4826 * np.median(np.abs(e), axis=0), 1e-300)) ** 2, axis=1)
    z, sigma = _normal_deviates(chi2, stats.chi2, (3,), threshold), 0.0
    for _ in range(5):  # refit on the accepted readings and judge everything again, until nothing changes
        keep = z <= threshold
        if keep.sum() < SUBSET or not _spans((X.T * keep) @ X):
            break
        z_new, sigma = _vector_z(m, X, keep, threshold)
        changed = np.any((z_new > threshold) != (z > threshold))
        z = z_new
        if not changed:
            break
    return _verdicts(m, z, threshold, sigma, VECTOR_MODEL, gross=None)


def _normal_deviates(statistic: np.ndarray, dist, shapes: tuple, threshold: float) -> np.ndarray:
    """The normal deviate whose two-sided tail is the upper tail of `statistic` under `dist` (a SciPy
    distribution with its `shapes`; not frozen: freezing builds a docstring, 1.5 ms of a 1000-reading
    screen), for the readings beyond half the deviate `threshold` — all `_verdicts` looks at; the
    rest get 0 (the tail function costs ~1 µs a reading). Where the tail underflows, √statistic: far
    beyond any threshold either way, and finite for the messages."""
    z = np.zeros(len(statistic))
    far = statistic > dist.isf(2 * stats.norm.sf(threshold / 2), *shapes)
    z_far = -special.ndtri_exp(np.log(0.5) + dist.logsf(statistic[far], *shapes))
    z[far] = np.where(np.isfinite(z_far), z_far, np.sqrt(statistic[far]))
    return z


def _vector_z(m: np.ndarray, X: np.ndarray, keep: np.ndarray, threshold: float):
    """Each reading's residual off the least-squares fit of the `keep` readings as a Mahalanobis distance
    with their residual covariance (ν = n_keep − 4 degrees of freedom), its variance scaled by leverage
    (1 − h for a fitted reading, 1 + h for one left out), and turned into the normal deviate of the same
    tail probability under Hotelling's T² (3 dimensions): the ellipsoid's `threshold` then applies.
    Returns (z, RMS over axes of the residual σ)."""
    w = keep.astype(float)  # the accepted readings as weights 0/1: products instead of copies
    nu = int(keep.sum()) - 4
    G = np.linalg.inv((X.T * w) @ X)
    e = m - X @ (G @ ((X.T * w) @ m))
    S = (e.T * w) @ e / nu
    h = _row_quadratic(X, G)
    t2 = _row_quadratic(e, np.linalg.pinv(S)) / np.where(keep, 1 - h, 1 + h)
    f = t2 * (nu - 2) / (3 * nu)  # T² ν−p+1 / (p ν) ~ F(p, ν−p+1)
    return _normal_deviates(f, stats.f, (3, nu - 2), threshold), float(np.sqrt(np.mean(np.diag(S))))


def _fits_to_the_noise(m: np.ndarray, cal, threshold: float, norms=None):
    """The robust σ of the ALS fit `cal`'s distances when that fit explains the readings to their noise (σ within
    NOISE_FACTOR of the white noise that third differences show) and no reading stands out: outliers
    would have distorted it, so the least-median search is not needed. Else None. Only saves time: the
    search would return this fit."""
    from .diagnose.core import time_series_noise  # here: diagnose imports this module

    if cal is None:
        return None
    # no yardstick when consecutive readings differ about as much as any two (rows in random orientations or out of
    # time order: an ALS fit that one spike at 10× the field had distorted by 20 % of the field passed as
    # "explained to the noise"), or when motion is in the differences (steady)
    noise = time_series_noise(m, steady=True)
    if noise is None:
        return None
    z, sigma = _robust_z(_distances(cal, m, norms) / _leverage_scale(cal, m, np.ones(len(m), dtype=bool)))
    radius = np.median(np.linalg.norm(m - cal.offset, axis=1))
    if np.any(z > threshold) or not sigma <= NOISE_FACTOR * noise / radius:  # (threshold: one, or each reading's)
        return None
    return float(sigma)


def _runs(mask: np.ndarray) -> list:
    """(first, last) index of each run of consecutive True values."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1))
