"""Non-invasive current measurement of multicore cables (seed 000: Song et al. 2017), on the C++ core
(cpp/include/fluxcal/cable.hpp).

    ring = fluxcal.cable.Ring([0, 90, 180, 270], 0.010)          # 4 biaxial sensors on a 10 mm radius
    b = ring.field([[-2e-3, 0], [2e-3, 0]], [5.0, -5.0])          # (4, 2): radial, tangential in tesla
    sol = ring.solve(b, n_conductors=2)                            # .positions (m), .currents (A)
    sol.covariance, sol.well_conditioned

Calibration (the paper's procedure): turn the ring about the cable (5 × 72°) with known reference
currents; the model gives the true field at each sensor; TWOSTEP 2-D (fluxcal.twostep_2d) per sensor;
compensation (eq. 19) h = (ĥ − b) ⊘ γ of every later reading — `calibrate_ring`. The ordinary
least-squares ellipse calibration the paper compares against is `calibrate_ring(..., method="least_squares")`.
SI units throughout: metres, amperes, tesla, degrees only where a name says `_deg`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import re

import numpy as np

from . import _core
from ._arrays import as_number, set_options
from ._saved import load_json_object
from .bounds import few_dof_words
from .io.columns import LARGE_CURRENT_UNITS
from .twostep import TwoStep2D, twostep_2d

#: μ0/(2π) in T·m/A (the core's constant).
MU0_OVER_2PI = 1.25663706127e-6 / (2.0 * np.pi)


def _positions(positions_m) -> np.ndarray:
    arr = np.asarray(positions_m, dtype=float)
    if arr.ndim == 1 and arr.size == 2:
        arr = arr.reshape(1, 2)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise ValueError(f"positions_m: shape {arr.shape}, expected (n_conductors, 2) with (x, y) in metres")
    return np.ascontiguousarray(arr)


def _currents(currents_a, positions: np.ndarray, snapshots: bool) -> np.ndarray:
    """Currents (n,) — or (snapshots, n) where `snapshots` — one per conductor of `positions`."""
    cur = np.asarray(currents_a, dtype=float)
    if cur.ndim == 0:
        cur = cur.reshape(1)
    if cur.ndim > (2 if snapshots else 1) or cur.shape[-1] != len(positions):
        raise ValueError(f"currents_a: shape {cur.shape}, expected ({len(positions)},)"
                         + (f" or (snapshots, {len(positions)})" if snapshots else "")
                         + f" for {len(positions)} conductor(s)")
    return cur


@dataclass
class CableSolution:
    """Conductor positions (n, 2) in metres, currents (n,) — or (snapshots, n) for several snapshots —
    in amperes, the covariance of [x0, y0, x1, y1, …, currents of snapshot 0, …, then bx, by when a background
    was fitted] (m, A, T), whether the geometry determines them (`well_conditioned`) and whether the readings fit
    the model to within a few noise σ (`fits_model`, and `misfit_p` the test's p when σ's degrees of freedom were
    given, else NaN; see cable.hpp). `background_t`: the uniform field (bx, by)
    in the cable's frame, tesla, when `fit_background` was asked (else None)."""

    positions: np.ndarray
    currents: np.ndarray
    covariance: np.ndarray
    standard_errors: np.ndarray
    well_conditioned: bool
    fits_model: bool = True
    misfit_p: float = float("nan")
    noise_sigma: float = 0.0
    fisher_condition: float = 0.0
    residuals: np.ndarray = None
    starts_tried: int = 0
    summary: dict = field(default_factory=dict)
    background_t: np.ndarray | None = None

    @property
    def background_sigma(self) -> np.ndarray | None:
        """Standard errors of the background field (bx, by), tesla, or None without one."""
        return None if self.background_t is None else self.standard_errors[-2:]

    @property
    def position_sigma(self) -> np.ndarray:
        """Standard errors of the positions, (n, 2) metres."""
        n = self.positions.shape[0]
        return self.standard_errors[: 2 * n].reshape(n, 2)


class Ring:
    """A ring of biaxial sensors around a cable: sensor i at `angles_deg[i]` on `radius_m`, its x axis
    radial and y tangential unless `axis_angles_deg` turns it; conductors must lie within
    `bore_radius_m` (default 0.4 × radius: the paper's 8 mm hole with sensors at ~10 mm)."""

    def __init__(self, angles_deg=(0.0, 90.0, 180.0, 270.0), radius_m: float = 0.010, axis_angles_deg=None,
                 bore_radius_m: float | None = None):
        self.angles_deg = np.atleast_1d(np.asarray(angles_deg, dtype=float)).copy()
        if self.angles_deg.ndim != 1:
            raise ValueError(f"angles_deg: shape {self.angles_deg.shape}, expected one angle per sensor (n_sensors,)")
        self.radius_m = as_number(radius_m, "radius_m")
        self.axis_angles_deg = (np.zeros_like(self.angles_deg) if axis_angles_deg is None
                                else np.atleast_1d(np.asarray(axis_angles_deg, dtype=float)).copy())
        self.bore_radius_m = 0.4 * self.radius_m if bore_radius_m is None else float(bore_radius_m)
        if self.axis_angles_deg.shape != self.angles_deg.shape:
            raise ValueError(f"axis_angles_deg: {self.axis_angles_deg.size} values for {self.angles_deg.size} sensors")
        # let the core check the rest (finite, radius > 0, bore < radius, distinct angles)
        _core.cable_field(*self._args(), np.zeros((1, 2)), np.zeros(1))

    def _args(self):
        return (np.radians(self.angles_deg), self.radius_m, np.radians(self.axis_angles_deg), self.bore_radius_m)

    @property
    def n_sensors(self) -> int:
        return self.angles_deg.size

    def __repr__(self):
        axes = f", axis_angles_deg={self.axis_angles_deg.tolist()}" if np.any(self.axis_angles_deg) else ""
        return (f"Ring(angles_deg={self.angles_deg.tolist()}, radius_m={self.radius_m}{axes}, "
                f"bore_radius_m={self.bore_radius_m})")

    def subset(self, keep) -> "Ring":
        """The ring of the sensors `keep` (a boolean mask or indices) only: a dead sensor left out."""
        keep = np.arange(self.n_sensors)[keep]
        return Ring(self.angles_deg[keep], self.radius_m, self.axis_angles_deg[keep], self.bore_radius_m)

    def rotated(self, angle_deg: float) -> "Ring":
        """The ring turned by `angle_deg` counter-clockwise about the cable (sensors and axes together)."""
        return Ring(self.angles_deg + angle_deg, self.radius_m, self.axis_angles_deg, self.bore_radius_m)

    def field(self, positions_m, currents_a) -> np.ndarray:
        """Field at every sensor in its axes (radial, tangential for the default axes), tesla: (n_sensors, 2)
        for currents (n,), or (snapshots, n_sensors, 2) for currents (snapshots, n)."""
        pos = _positions(positions_m)
        cur = _currents(currents_a, pos, snapshots=True)
        if cur.ndim == 2:
            return np.stack([self.field(pos, c) for c in cur])
        return np.asarray(_core.cable_field(*self._args(), pos, cur))

    def jacobian(self, positions_m, currents_a) -> np.ndarray:
        """∂(readings, sensor-major x0, y0, x1, …)/∂(x0, y0, …, I0, …): (2·n_sensors, 3n)."""
        pos = _positions(positions_m)
        return np.asarray(_core.cable_field_jacobian(*self._args(), pos, _currents(currents_a, pos, snapshots=False)))

    def solve(self, readings, n_conductors: int = 2, zero_sum_currents: bool = False, initial_positions=None,
              initial_currents=None, search_again: bool = True, fit_background: bool = False,
              **settings) -> CableSolution:
        """Conductor positions and currents from readings (n_sensors, 2) — one snapshot — or
        (snapshots, n_sensors, 2) sharing the positions (AC waveforms), tesla in each sensor's axes.

        settings (defaults in cable.hpp): grid_points=9, starts=6, max_iterations=100, noise_sigma=1e-8 (T;
        ≤ 0 = estimate from the residuals), max_position_sigma=1e-4 (m), max_current_relative_sigma=0.05,
        misfit_ratio=5, noise_sigma_dof=0 (the degrees of freedom behind noise_sigma, e.g. a calibration's
        repeats': a misfit is then also an F test's p below misfit_alpha=1e-3; inf: σ exact, χ²), relative_sigma
        (n_sensors,) each sensor's σ relative to noise_sigma (its residuals weighted by the inverse; default all 1),
        refiner="automatic" ("ceres", or "dense": fluxcal's dense Levenberg–Marquardt on the same residuals;
        "automatic" = dense for a warm start, Ceres for the multi-start from the grid).
        `initial_positions` (n, 2) warm-starts the solver (no grid). search_again: when the default starts
        leave a misfit, search again from 4× the starts on a 15×15 grid (a local minimum, not the model, is
        then to blame; off where a misfit is expected, e.g. a diagnosis's start). fit_background: fit a uniform field
        (the Earth's, a busbar's far off) in the cable's frame, shared by the snapshots, beside the conductors
        (`background_t`). Raises ValueError on NaN readings, too few sensors for the unknowns, or a start outside the
        bore."""
        arr = np.asarray(readings, dtype=float)
        single = arr.ndim == 2
        if single:
            arr = arr[None]
        if arr.ndim != 3 or arr.shape[1:] != (self.n_sensors, 2) or arr.shape[0] == 0:
            raise ValueError(f"readings: shape {np.shape(readings)}, expected ({self.n_sensors}, 2) or "
                             f"(snapshots, {self.n_sensors}, 2) for this ring of {self.n_sensors} biaxial sensors")
        options = _core.CableSolveOptions()
        if isinstance(n_conductors, bool) or not float(n_conductors).is_integer() or n_conductors < 1:
            raise ValueError(f"n_conductors: {n_conductors!r} is not a whole number of conductors ≥ 1")
        options.n_conductors = int(n_conductors)
        options.zero_sum_currents = bool(zero_sum_currents)
        options.fit_background = bool(fit_background)
        if initial_positions is not None:
            options.initial_positions = _positions(initial_positions)
        if initial_currents is not None:
            options.initial_currents = np.atleast_2d(np.asarray(initial_currents, dtype=float))
            if not np.all(np.isfinite(options.initial_currents)):
                raise ValueError("initial_currents: not finite (NaN or Inf)")
        if isinstance(settings.get("refiner"), str):
            names = _core.CableRefiner.__members__
            if settings["refiner"] not in names:
                raise ValueError(f"refiner: {settings['refiner']!r} is not one of {', '.join(names)}")
            settings = {**settings, "refiner": names[settings["refiner"]]}
        set_options(options, settings, "Ring.solve")
        flat = arr.reshape(arr.shape[0], -1)
        r = _core.solve_cable(*self._args(), flat, options)
        if (search_again and not r["fits_model"] and initial_positions is None
                and not {"starts", "grid_points"} & set(settings)):
            # a misfit from the default starts may be a local minimum (3 of 150 random two-core cables
            # on the paper's ring): search again from a finer grid and more starts before blaming the model
            options.grid_points, options.starts = 15, 4 * options.starts
            again = _core.solve_cable(*self._args(), flat, options)
            weights = np.repeat(1.0 / np.asarray(options.relative_sigma, float), 2) if len(options.relative_sigma) else 1.0
            cost = lambda run: float(np.sum((np.asarray(run["residuals"]) * weights) ** 2))  # noqa: E731 - what both minimised
            if cost(again) < cost(r):
                r = again
            r["summary"]["warnings"] = list(r["summary"]["warnings"]) + [
                f"the default starts left a misfit: searched again from {options.starts} starts on a "
                f"{options.grid_points}×{options.grid_points} grid" + (" (better: taken)" if r is again else " (no better)")]
        if not options.noise_sigma > 0:  # σ from these readings' own residuals: its few degrees of freedom said
            dof = arr.size - np.shape(r["covariance"])[0]
            r["summary"]["noise_sigma_dof"] = int(dof)
            said = few_dof_words(dof, "these readings' residuals",
                                 "give noise_sigma (a calibration's scatter, the datasheet's) for intervals of their own",
                                 below=30)  # (a ring's snapshots: said under 30 since before, the README's)
            if said:
                r["summary"]["warnings"] = list(r["summary"]["warnings"]) + [said]
        silent = silent_sensors(arr)
        if silent.any():
            r["summary"]["warnings"] = [f"{'; '.join(silent_words(arr, silent))}: solved as readings; leave them "
                                        "out (Ring.subset)"] + list(r["summary"]["warnings"])
        clipped = clipped_readings(arr)
        if clipped.any():
            r["summary"]["warnings"] = [clipped_words(arr, clipped)] + list(r["summary"]["warnings"])
        currents = np.asarray(r["currents"])
        return CableSolution(positions=np.asarray(r["positions"]), currents=currents[0] if single else currents,
                             covariance=np.asarray(r["covariance"]), standard_errors=np.asarray(r["standard_errors"]),
                             well_conditioned=bool(r["well_conditioned"]), fits_model=bool(r["fits_model"]),
                             misfit_p=r["misfit_p"], noise_sigma=r["noise_sigma"],
                             fisher_condition=r["fisher_condition"],
                             residuals=np.asarray(r["residuals"]).reshape(arr.shape), starts_tried=r["starts_tried"],
                             summary=r["summary"],
                             background_t=None if r["background"] is None else np.asarray(r["background"]))


# A largest |reading| met this many times as often as the levels just below it is a rail: a sensor clipped at its
# range. (A quantised sine dwells longest at its peak too, ~2.4× the level below: 4 leaves that alone.)
RAIL_RATIO = 4.0
RAIL_LEVELS = 5  # the levels below the top whose mean count is the yardstick


def _on_rail(values: np.ndarray, least: int) -> bool:
    """Whether the largest of `values` (|readings|, finite) repeats at least `least` times and RAIL_RATIO× as often
    as the RAIL_LEVELS distinct values below it (1 each where there are none: a constant channel is no evidence)."""
    levels, counts = np.unique(values, return_counts=True)
    if len(levels) < 2:
        return False
    below = counts[-1 - RAIL_LEVELS:-1]
    return bool(counts[-1] >= least and counts[-1] >= RAIL_RATIO * below.mean())


def clipped_readings(readings) -> np.ndarray:
    """The readings ((snapshots, n_sensors, 2), or (n_sensors, 2)) that sit on a rail: a sensor's axis clipped at its
    range reads the same extreme value again and again — across the sensors when they share a range (the largest
    |reading| of the whole recording, met RAIL_RATIO× as often as the values below it), or across the snapshots in
    one axis (its own largest, in at least 3 snapshots of an axis that takes 3 or more values). Returns a boolean mask
    of the readings' shape. A clipped reading is no misfit the solver can see: two sensors clipped alike on the
    paper's ring fitted conductors 1.4 mm apart at 140 A for 100 A, well conditioned, within the noise."""
    arr = np.asarray(readings, dtype=float)
    size = np.abs(arr.reshape(-1, arr.shape[-2], 2))
    mask = np.zeros(size.shape, dtype=bool)
    finite = np.isfinite(size)
    if not finite.any():
        return mask.reshape(arr.shape)
    top = np.max(size[finite])
    if _on_rail(size[finite], 2):
        mask |= size == top
    for i in range(size.shape[1]):
        for a in range(2):
            column = size[:, i, a]
            ok = np.isfinite(column)
            if ok.sum() >= 3 and len(np.unique(column[ok])) >= 3 and _on_rail(column[ok], 3):
                mask[:, i, a] |= column == np.max(column[ok])
    return mask.reshape(arr.shape)


def silent_sensors(readings) -> np.ndarray:
    """The sensors of `readings` ((snapshots, n_sensors, 2), or (n_sensors, 2)) that read nothing of the field: exactly
    0.0 on both axes in every snapshot while others read a field (a sensor that does not answer: a failed bus read
    returns zeros), or the same value on both axes in every one of three or more snapshots while most others changed
    (frozen_sensors). No field a sensor measures reads 0.0 to the last digit on two axes; solved as a reading, such
    a sensor had a three-core cable carry 319 A for 100 A, and the diagnosis found no significant effect. Boolean
    (n_sensors,); silent_words says which is which."""
    arr = np.asarray(readings, dtype=float).reshape(-1, np.shape(readings)[-2], 2)
    zero = (arr == 0.0).all(axis=(0, 2))
    return (zero & bool(np.any(arr[:, ~zero][np.isfinite(arr[:, ~zero])] != 0.0))) | frozen_sensors(arr)


def frozen_sensors(readings) -> np.ndarray:
    """The sensors of `readings` ((snapshots, n_sensors, 2)) whose two axes read the same finite values, to the last
    digit, in all of three or more snapshots while most of the other sensors' readings changed (a sensor stuck on
    its last reading — a hung bus, a frozen register —, or clipped on both axes): noise alone makes a live sensor's
    readings differ, so it reads nothing of these snapshots. A ring whose sensors all hold still (a steady current
    under a coarse quantum) names none. Boolean (n_sensors,)."""
    arr = np.asarray(readings, dtype=float)
    frozen = np.zeros(arr.shape[1], dtype=bool)
    if arr.ndim != 3 or len(arr) < 3:
        return frozen
    finite = np.isfinite(arr).all(axis=(0, 2))
    still = finite & (arr == arr[:1]).all(axis=(0, 2)) & ~(arr == 0.0).all(axis=(0, 2))
    for i in np.nonzero(still)[0]:
        others = finite & (np.arange(arr.shape[1]) != i)
        changed = ~(arr[:, others] == arr[:1, others]).all(axis=(0, 2))
        frozen[i] = others.sum() >= 2 and changed.sum() > others.sum() / 2
    return frozen


SILENT_WORDS = "read exactly 0 on both axes in every snapshot (a sensor that does not answer: dead?)"


def silent_words(readings, silent) -> list:
    """What a silent_sensors mask says, a phrase per kind: the sensors reading 0, and those frozen on one value."""
    arr = np.asarray(readings, dtype=float).reshape(-1, np.shape(readings)[-2], 2)
    frozen = np.asarray(silent) & ~(arr == 0.0).all(axis=(0, 2))
    named = lambda mask: ", ".join(map(str, np.nonzero(mask)[0]))  # noqa: E731
    said = [f"sensor(s) {named(silent & ~frozen)} {SILENT_WORDS}"] if (silent & ~frozen).any() else []
    if frozen.any():
        said.append(f"sensor(s) {named(frozen)} read the same value on both axes in all {len(arr)} snapshots while "
                    "the others changed (stuck on its last reading, or clipped on both axes: dead?)")
    return said


def clipped_words(readings, mask, unit_t: float = 1e-6, unit: str = "µT") -> str:
    """What a clipped_readings mask says, naming the sensors' axes, the rail and how often."""
    arr = np.asarray(readings, dtype=float).reshape(-1, mask.shape[-2], 2)
    m = mask.reshape(arr.shape)
    named = []
    for i, a in zip(*np.nonzero(m.any(axis=0))):
        values = np.unique(np.abs(arr[:, i, a][m[:, i, a]]))
        named.append(f"sensor {i} {'xy'[a]} ({'/'.join(f'±{v / unit_t:.6g}' for v in values)} {unit}, "
                     f"{int(m[:, i, a].sum())} of {arr.shape[0]} snapshot(s))")
    return (f"readings on a rail: {', '.join(named)} read the same extreme value far more often than any value below "
            "it — clipped at the sensor's range? A clipped reading is no misfit the solver can see (another geometry "
            "fits it: 140 A for 100 A on the paper's ring, within the noise): lower the current, use a wider range, or "
            "leave those sensors out")


def propagated_covariance(ring: Ring, solution: CableSolution, noise_var, shared=(), relative_sigma=None) -> np.ndarray:
    """The covariance of `solution`'s parameters (as its own: positions, each snapshot's currents, the background)
    from `ring` (as solved: rotated) when each reading's error is independent noise of variance `noise_var`
    ((n_sensors, 2), tesla²) plus errors the snapshots solved together share: `shared`, pairs (G, Σ) — the readings
    move by G[s] δc (G: (snapshots, n_sensors, 2, p)), δc ~ (0, Σ) (p × p): a calibration's own gains and offsets, the
    zero snapshots' mean. The estimate moves by A_s δy_s, A_s = C J_sᵀ W (C its covariance per unit σ², W its weights,
    `relative_sigma`'s): a sandwich. (As independent noise of the solver's σ, a calibration's errors — common to every
    snapshot — had left a newcomer's currents 1.3× their ±, and the zero snapshots' mean 1.7×.) The solver's own
    covariance where it is undetermined (inf)."""
    n = solution.positions.shape[0]
    currents = np.atleast_2d(solution.currents)
    snapshots, m = currents.shape[0], ring.n_sensors
    C = solution.covariance / solution.noise_sigma ** 2
    if not np.all(np.isfinite(C)):
        return solution.covariance
    J = np.zeros((snapshots, 2 * m, C.shape[0]))
    reach = float(np.max(np.hypot(*solution.positions.T)))
    if reach >= ring.bore_radius_m and reach < ring.radius_m:  # a conductor ended on the bore's edge, a hair past it:
        # the derivatives are the field's, the bore only the solver's bound
        ring = Ring(ring.angles_deg, ring.radius_m, ring.axis_angles_deg, 0.5 * (reach + ring.radius_m))
    for k in range(snapshots):
        Jk = ring.jacobian(solution.positions, currents[k])
        J[k, :, :2 * n] = Jk[:, :2 * n]
        J[k, :, 2 * n + n * k:2 * n + n * (k + 1)] = Jk[:, 2 * n:]
    if solution.background_t is not None:
        axis = np.radians(ring.angles_deg + ring.axis_angles_deg)
        J[:, :, -2:] = np.stack([_in_axes(np.ones(m), axis), _in_axes(np.full(m, 1j), axis)], axis=-1).reshape(2 * m, 2)
    w2 = 1.0 if relative_sigma is None else np.repeat(1.0 / np.asarray(relative_sigma, float) ** 2, 2)[:, None]
    A = np.einsum("pq,krq->kpr", C, J * w2)  # (snapshots, parameters, readings)
    out = np.einsum("kpr,r,kqr->pq", A, np.asarray(noise_var, float).ravel(), A)
    for G, sigma in shared:
        moved = np.einsum("kpr,krc->pc", A, np.asarray(G, float).reshape(snapshots, 2 * m, -1))
        out += moved @ sigma @ moved.T
    return out


def placement_shared_errors(ring: Ring, solution: CableSolution, position_sigma_m: float = 0.0,
                            axis_sigma_deg: float = 0.0) -> tuple:
    """(G, Σ) for propagated_covariance: each sensor's placement tolerance — its position off by (δr, δt) along and
    across the ring's radius, σ `position_sigma_m` each, its axes turned by δα, σ `axis_sigma_deg` — the same draw
    in every snapshot (the sensor stays where it was mounted). A ring of few sensors absorbs such an error into the
    conductors' positions without a misfit: on the paper's 4 sensors, one 0.25 mm out of place left the currents 9 %
    off with ± 7–11× too small and nothing said (a blind check). `ring` as solved (rotated), at the solution's
    positions, currents and background. The reading moves by ∂B/∂p·δp along its axis, and by −i B e^{−iφ} δα."""
    sigma_p = as_number(position_sigma_m, "position_sigma_m")
    sigma_a = np.radians(as_number(axis_sigma_deg, "axis_sigma_deg"))
    if sigma_p < 0 or sigma_a < 0:
        raise ValueError(f"position_sigma_m {sigma_p:g}, axis_sigma_deg {np.degrees(sigma_a):g}: need ≥ 0")
    currents = np.atleast_2d(solution.currents)
    theta = np.radians(ring.angles_deg)
    phi = np.radians(ring.angles_deg + ring.axis_angles_deg)
    d = ring.radius_m * np.exp(1j * theta)[:, None] - (solution.positions[:, 0] + 1j * solution.positions[:, 1])[None]
    k = MU0_OVER_2PI * currents[:, None, :]  # (snapshots, 1, n)
    b = np.sum(1j * k / np.conj(d)[None], axis=-1)  # B = Σ i μ0 I / (2π conj(p − c)): (snapshots, sensors)
    if solution.background_t is not None:
        b = b + complex(*solution.background_t)
    slope = np.sum(-1j * k / np.conj(d)[None] ** 2, axis=-1)  # dB = slope · conj(δp)
    m = ring.n_sensors
    G = np.zeros(b.shape + (2, m, 3))
    for i in range(m):
        G[:, i, :, i, 0] = _in_axes(slope[:, i] * np.exp(-1j * theta[i]), phi[i])  # radial δr
        G[:, i, :, i, 1] = _in_axes(slope[:, i] * -1j * np.exp(-1j * theta[i]), phi[i])  # along the ring δt
        G[:, i, :, i, 2] = _in_axes(-1j * b[:, i], phi[i])  # the axes turned δα
    sigma = np.diag(np.tile([sigma_p ** 2, sigma_p ** 2, sigma_a ** 2], m))
    return G.reshape(b.shape + (2, 3 * m)), sigma


def calibration_shared_errors(calibration: "RingCalibration", fields, offsets: bool = True) -> tuple:
    """(G, Σ) for propagated_covariance: the error a calibration's own (γ, b) leave in compensated readings of
    `fields` ((snapshots, n_sensors, 2), tesla: the compensated readings), δh = −(δb + h δγ)/γ per sensor axis, the
    same draw in every snapshot; `offsets` False where they cancel (zero snapshots subtracted). Σ per sensor, and
    across the sensors what a reference meter's scatter per pose left shared (`reference_covariance`)."""
    h = np.asarray(fields, float)
    m = calibration.offsets.shape[0]
    G = np.zeros(h.shape + (m, 2, 2))  # … → (sensor, axis, [γ, b])
    for i in range(m):
        for a in range(2):
            G[:, i, a, i, a, 0] = -h[:, i, a] / calibration.gains[i, a]
            if offsets:
                G[:, i, a, i, a, 1] = -1.0 / calibration.gains[i, a]
    sigma = np.zeros((m, 2, 2, m, 2, 2))
    if calibration.reference_covariance is not None:  # a reference meter's error per pose: the same at every sensor
        sigma[:] = calibration.reference_covariance.reshape(m, 2, 2, m, 2, 2)
    for i in range(m):
        if calibration.sensor_covariance is not None:  # the axes' correlation too
            sigma[i, :, :, i, :, :] = calibration.sensor_covariance[i].reshape(2, 2, 2, 2)
        else:
            for a in range(2):
                sigma[i, a, :, i, a, :] = calibration.covariance[i, a]
    return G.reshape(h.shape + (-1,)), sigma.reshape(4 * m, 4 * m)


def ac_currents(phasors, times_s, frequency_hz: float = 50.0) -> np.ndarray:
    """Instantaneous currents (len(times), n) of AC conductors: `phasors` (n,) complex amplitudes (peak,
    A) of the fundamental, or (harmonics, n) for harmonics 1, 2, …: i(t) = Re Σ_h P_h e^{j h ω t}."""
    p = np.atleast_2d(np.asarray(phasors, dtype=complex))
    t = np.asarray(times_s, dtype=float)[:, None, None]
    h = np.arange(1, p.shape[0] + 1)[None, :, None]
    return np.real((p[None] * np.exp(1j * 2 * np.pi * frequency_hz * h * t)).sum(axis=1))


# ---- calibration -----------------------------------------------------------------------------------

@dataclass
class RingCalibration:
    """Per-sensor offsets b (n_sensors, 2) and gains γ (n_sensors, 2) in each sensor's axes;
    compensation (eq. 19) h = (ĥ − b) ⊘ γ. `method` is "twostep" or "least_squares"."""

    offsets: np.ndarray
    gains: np.ndarray
    method: str = "twostep"
    sensors: list = field(default_factory=list)  # the TwoStep2D of each sensor
    # What the calibration recording says about its own accuracy, per sensor and axis (None when not known,
    # e.g. a calibration saved before they existed): the readings' scatter about γ h + b (noise and anything the
    # model leaves, tesla) and the covariance of (γ, b): TWOSTEP's (from the magnitudes it fits; the linear
    # one on the true field vectors was 0.66–0.87 of a blind check's Monte-Carlo spread) — with repeats, at their
    # σ per axis (_magnitude_sandwich; `sensors` keep TWOSTEP's own σ̂²(JᵀJ)⁻¹) — or for least squares the
    # linear one on the true fields.
    residual_sigma: np.ndarray | None = None  # (n_sensors, 2)
    covariance: np.ndarray | None = None      # (n_sensors, 2, 2, 2): [sensor, axis] → Cov(γ, b)
    # TWOSTEP's whole per-sensor covariance of (γx, bx, γy, by), the axes' correlation too (the magnitudes tie them:
    # without it the currents' ± read at 20× the calibration's field were a further 10 % small); None otherwise
    sensor_covariance: np.ndarray | None = None  # (n_sensors, 4, 4)
    # The scatter of consecutive repeated readings (the same true field), tesla: the noise alone, without what the
    # model misses (axis coupling, crosstalk), which residual_sigma holds too. None without ≥ 10 degrees of freedom.
    repeat_sigma: np.ndarray | None = None    # (n_sensors, 2)
    # ... and its degrees of freedom (the readings less the poses), for the solver's misfit test; None when not saved
    repeat_dof: np.ndarray | None = None      # (n_sensors, 2)
    # The lack-of-fit test's p per sensor and axis (its residuals between the poses against their scatter within):
    # below LACK_OF_FIT_P its model missed (a field that does not follow the currents, an axis misaligned), and its
    # residual_sigma and covariance hold that miss, not the noise. None without repeats.
    lack_of_fit_p: np.ndarray | None = None   # (n_sensors, 2)
    # The reference's relative error per pose that calibrate_ring found beyond the sensors' noise (one meter reading
    # of the currents per pose: the same error at every sensor of the pose; _reference_scatter), as a standard
    # deviation, and the covariance it leaves across the sensors' (γx, bx, γy, by) — its diagonal blocks are in
    # sensor_covariance, the others tie the sensors' errors (calibration_shared_errors). None when none was found.
    reference_scatter: float | None = None
    reference_covariance: np.ndarray | None = None  # (n_sensors, 4, n_sensors, 4)
    # calibrate_ring_in_field's: the field that did not follow the currents in the calibration run, tesla in the cable
    # frame — {"terms_t": [[re, im] of b₀, b₁, …]}, B(z) = Σ bₙ (z̄/R)ⁿ: b₀ at the ring's centre, b₁ its change
    # across the radius, … — or None
    background: dict | None = None

    def apply(self, readings) -> np.ndarray:
        """Compensated readings, same shape as `readings` (…, n_sensors, 2)."""
        r = np.asarray(readings, dtype=float)
        if r.shape[-2:] != self.offsets.shape:
            raise ValueError(f"readings: shape {r.shape}, expected (…, {self.offsets.shape[0]}, 2)")
        return (r - self.offsets) / self.gains

    def field_sigma(self, readings) -> float | None:
        """The σ (tesla) of a compensated reading of `readings` (…, n_sensors, 2, raw) as the solver should take
        it: the calibration's scatter divided by the gain — its repeated readings' (the noise) when it has them,
        else its residuals' (which hold what its model missed, and a reference meter's scatter: 5× the noise had
        hidden a 1 % current error) — and the error its own (γ, b) carry at these fields, δh = −(δb + h δγ)/γ
        (which grows with the current: a calibration at 5 A read at 100 A). RMS over the sensors and axes; None
        without the calibration's statistics."""
        per_sensor = self.sensor_sigma(readings, repeats=self.repeat_sigma is not None)
        return None if per_sensor is None else float(np.sqrt(np.mean(per_sensor ** 2)))

    def field_sigma_dof(self, readings, snapshots_solved_together: int = 1) -> float | None:
        """The degrees of freedom behind `sensor_sigma(readings, repeats=True)`, for the solver's misfit test
        (`noise_sigma_dof`, with each sensor weighted by its σ: `relative_sigma`). Per sensor, Satterthwaite's, of its
        repeats' scatter (their dof) and of the error the calibration's own (γ, b) leave: two numbers per axis, the
        same in every snapshot, so one draw per axis in one snapshot and two in several (counted as one per reading,
        they gave 2 % false misfits at p < 1e-3 for a ring calibrated at 5 A and read at 100 A in 10 snapshots); over
        the sensors, which weigh alike in the weighted test, M² / Σ 1/νᵢ. None without the repeats' dof (a calibration
        without repeats, whose residual scatter holds its model's misses, or saved before it kept them): the ratio
        rule alone then."""
        if self.repeat_dof is None or self.repeat_sigma is None:
            return None
        if int(snapshots_solved_together) < 1:
            raise ValueError(f"snapshots_solved_together: {snapshots_solved_together}, need ≥ 1")
        noise, own = self._variances(readings, repeats=True)
        if noise is None:
            return None
        noise, own = np.mean(noise, axis=-1), np.mean(own, axis=-1)  # per sensor, as sensor_sigma
        per_sensor = (noise + own) ** 2 / (noise ** 2 / np.sum(self.repeat_dof, axis=-1)
                                           + own ** 2 / (2 * min(int(snapshots_solved_together), 2)))
        return float(len(per_sensor) ** 2 / np.sum(1.0 / per_sensor))

    def background_in_axes(self, ring: "Ring", rotation_deg: float) -> np.ndarray:
        """The calibration run's field that does not follow the currents (`background`, calibrate_ring_in_field's)
        in each sensor's axes with the ring turned by `rotation_deg`: (n_sensors, 2) tesla, to take off compensated
        readings taken where the ring was calibrated. ValueError without one."""
        if self.background is None:
            raise ValueError("this ring calibration has no background field (`cable calibrate --method in_field` "
                             "fits one)")
        theta = np.radians(ring.angles_deg + rotation_deg)
        field = sum(complex(*b) * np.exp(-1j * n * theta) for n, b in enumerate(self.background["terms_t"]))
        return _in_axes(field, theta + np.radians(ring.axis_angles_deg))

    def sensor_sigma(self, readings=None, repeats: bool = False) -> np.ndarray | None:
        """`field_sigma` per sensor (n_sensors,), RMS over its two axes: the calibration's scatter divided by the
        gain, plus — with `readings` (…, n_sensors, 2, raw) — what its own (γ, b) errors leave at those fields
        (without: the scatter alone, for a fit that refines γ and b itself). `repeats`: the scatter of its repeated
        readings instead (the noise without the model's misses; None when the run had no repeats). None without
        the statistics."""
        scatter, own = self._variances(readings, repeats)
        return None if scatter is None else np.sqrt(np.mean(scatter + own, axis=-1))

    def noise_variance(self) -> np.ndarray | None:
        """(n_sensors, 2) the variance (tesla²) of a compensated reading's own noise: its repeated readings' scatter
        over the gain, else its residuals'; None without the statistics."""
        return self._variances(None, repeats=self.repeat_sigma is not None)[0]

    def _variances(self, readings, repeats: bool):
        """Per sensor and axis, the variances (tesla²) of a compensated reading: the scatter's (the repeats' or the
        residuals'), and what the calibration's own (γ, b) errors leave at `readings` (0 without) — (None, None)
        without the statistics."""
        scatter = self.repeat_sigma if repeats else self.residual_sigma
        if scatter is None or self.covariance is None:
            return None, None
        own = np.zeros_like(self.gains)
        if readings is not None:
            h = self.apply(readings).reshape(-1, *self.offsets.shape)
            x = np.stack([h, np.ones_like(h)], axis=-1)  # [h, 1] per reading, sensor, axis
            own = np.mean(np.einsum("nsai,saij,nsaj->nsa", x, self.covariance, x), axis=0) / self.gains ** 2
        return (scatter / self.gains) ** 2, own

    def subset(self, keep) -> "RingCalibration":
        """The calibration of the sensors `keep` (a boolean mask or indices) only."""
        keep = np.arange(self.offsets.shape[0])[keep]
        stats = {} if self.residual_sigma is None or self.covariance is None else {
            "residual_sigma": self.residual_sigma[keep], "covariance": self.covariance[keep]}
        for name in ("repeat_sigma", "repeat_dof", "lack_of_fit_p", "sensor_covariance"):
            if getattr(self, name) is not None:
                stats[name] = getattr(self, name)[keep]
        if self.reference_covariance is not None:
            stats.update(reference_scatter=self.reference_scatter,
                         reference_covariance=self.reference_covariance[np.ix_(keep, range(4), keep, range(4))])
        return RingCalibration(self.offsets[keep], self.gains[keep], self.method,
                               [self.sensors[k] for k in keep] if self.sensors else [], background=self.background,
                               **stats)

    def to_dict(self) -> dict:
        d = {"method": self.method, "offsets": self.offsets.tolist(), "gains": self.gains.tolist()}
        if self.residual_sigma is not None and self.covariance is not None:
            d.update(residual_sigma=self.residual_sigma.tolist(), covariance=self.covariance.tolist())
        for name in ("repeat_sigma", "repeat_dof", "lack_of_fit_p", "sensor_covariance", "reference_covariance"):
            if getattr(self, name) is not None:
                d[name] = getattr(self, name).tolist()
        if self.reference_scatter is not None:
            d["reference_scatter"] = self.reference_scatter
        if self.background is not None:
            d["background"] = self.background
        return d

    def __post_init__(self):
        self.offsets, self.gains = np.asarray(self.offsets, float), np.asarray(self.gains, float)
        if self.offsets.ndim != 2 or self.offsets.shape[1] != 2 or self.gains.shape != self.offsets.shape:
            raise ValueError(f"ring calibration: offsets {self.offsets.shape} and gains {self.gains.shape}, need "
                             "both (n_sensors, 2)")  # (1, 2) gains broadcast sensor 0's to every sensor
        if not (np.all(np.isfinite(self.offsets)) and np.all(np.isfinite(self.gains)) and np.all(self.gains != 0)):
            raise ValueError("ring calibration: offsets and gains must be finite and the gains non-zero")

    @classmethod
    def from_dict(cls, d: dict, source: str = "ring calibration") -> "RingCalibration":
        missing = [k for k in ("offsets", "gains") if not isinstance(d, dict) or k not in d]
        if missing:  # a magnetometer calibration given instead raised KeyError: 'offsets'
            raise ValueError(f"{source}: not a ring calibration (no {' or '.join(missing)}; `fluxcal cable "
                             "calibrate -o` writes one)")
        try:
            stats = {k: np.asarray(d[k], float) for k in ("residual_sigma", "covariance", "repeat_sigma", "repeat_dof",
                                                              "lack_of_fit_p", "sensor_covariance",
                                                              "reference_covariance") if k in d}
            if "reference_scatter" in d:
                stats["reference_scatter"] = float(d["reference_scatter"])
            return cls(offsets=np.asarray(d["offsets"], float), gains=np.asarray(d["gains"], float),
                       method=d.get("method", "twostep"), background=d.get("background"), **stats)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{source}: {str(exc).removeprefix('ring calibration: ')}") from None

    @classmethod
    def load(cls, path) -> "RingCalibration":
        return cls.from_dict(load_json_object(path, "a ring calibration"), str(path))


LACK_OF_FIT_P = 1e-4  # the calibration's residuals beyond its repeats' scatter: a sensor effect its model lacks


def calibrate_ring(readings, true_fields, method: str = "twostep") -> RingCalibration:
    """Calibrate every sensor of a ring from K calibration readings (K, n_sensors, 2) and the true field
    of each (K, n_sensors, 2; from the model at the known rotation and reference currents).

    method="twostep": TWOSTEP 2-D per sensor with the true magnitude of every reading (eqs. 7–18,
    refined). method="least_squares": the ordinary ellipse fit, which knows one field magnitude only
    (the RMS of the true magnitudes) — the method the paper compares against."""
    r = np.asarray(readings, dtype=float)
    h = np.asarray(true_fields, dtype=float)
    if r.ndim != 3 or r.shape[2] != 2 or h.shape != r.shape:
        raise ValueError(f"readings {r.shape} and true_fields {h.shape}: expected the same shape (K, n_sensors, 2)")
    norms = np.linalg.norm(h, axis=2)
    fits: list[TwoStep2D] = []
    refined = []  # per sensor: its fit is TWOSTEP's magnitude least squares (not the ellipse fallback's)
    for i in range(r.shape[1]):
        # a sensor's readings that are not numbers (a dropout, a glitch logged as nan) are left out of its own fit;
        # a sensor with none is dead: the others' calibration cannot stand in for it
        finite = np.isfinite(r[:, i]).all(axis=1)
        if (~finite).any() and finite.sum() < 5:
            raise ValueError(f"sensor {i}: {int((~finite).sum())} of {len(finite)} calibration readings are not finite "
                             "(a dead sensor?): it cannot be calibrated; repair it, or leave its columns out of the "
                             "ring (ring_angles_deg without it) for a ring of the others")
        dropped = np.nonzero(~finite)[0]
        m, norm = r[finite, i], norms[finite, i]  # this sensor's readings and their true |field|
        u = h[finite, i] / np.where(norm > 0, norm, 1.0)[:, None]
        if np.linalg.eigvalsh(u.T @ u / len(u))[0] < 1e-6:  # ±one direction: currents scale it, never turn it
            raise ValueError(f"true_fields: the field at sensor {i} never changes direction (its readings lie on a "
                             "line: one rotation of the ring?); turn the ring about the cable between readings "
                             "(the paper uses 5 × 72°)")
        if len(m) >= 3 and (m == m[0]).all():  # a field that turns read as one value: nothing to fit
            raise ValueError(f"sensor {i}: reads {m[0, 0]:.6g}, {m[0, 1]:.6g} in all {len(m)} calibration readings while "
                             "the field at it turns (stuck on its last reading, not answering, or clipped on both "
                             "axes: dead?): it cannot be calibrated; repair it, or leave its columns out of the ring "
                             "(ring_angles_deg without it) for a ring of the others")
        if len(m) < 5:  # (not the first step's failure, which the fallback below is for)
            raise ValueError(f"sensor {i}: {len(m)} calibration readings, need at least 5 for its offset and gains "
                             "(the paper takes 5 rotations × both current directions × repeats)")
        if method == "twostep":
            try:
                fits.append(twostep_2d(m, norm))
                refined.append(True)
            except ValueError as exc:
                if "first step" not in str(exc):  # bad input (a NaN), a run-away: its own message says what
                    raise ValueError(f"sensor {i}: {exc}") from None
                arc = _turned_deg(u)
                if arc < 180.0:  # too short an arc leaves the first step to the noise, whatever the model
                    raise ValueError(f"sensor {i}: {exc}. The field at this sensor turned through only {arc:.0f}° "
                                     "in the calibration run: turn the ring about the cable through a full circle "
                                     "(the paper uses 5 × 72°), or calibrate at several currents") from None
                fit = _sampson_fit(m, norm, str(exc))
                if fit is None:
                    raise ValueError(f"sensor {i}: {exc}. Here the magnitudes are the ring model's (straight "
                                     "conductors at the given positions with the reference currents): a calibration "
                                     "run the model does not describe gives this — a field that does not follow the "
                                     "currents (the Earth's, a neighbouring conductor: `cable calibrate --method "
                                     "in_field`, calibrate_ring_in_field, fits it from each rotation's currents "
                                     "reversed; or subtract each pose's zero-current reading), a cable's lay, its end or a "
                                     "bend near the ring, iron nearby, a wrong ring_radius_m — or magnitudes that hardly change "
                                     "across the run "
                                     f"(here by {100 * (np.ptp(norm) / np.mean(norm)):.3g} %: calibrate at "
                                     "positions off the ring's centre); `fluxcal diagnose RUN.csv --model cable` says "
                                     "which") from None
                fits.append(fit)
                refined.append(False)
        elif method == "least_squares":
            fits.append(twostep_2d(m, np.full(len(m), np.sqrt(np.mean(norm ** 2))), refine=False))
        else:
            raise ValueError(f"method: {method!r}, expected 'twostep' or 'least_squares'")
        if len(dropped):
            shown = ", ".join(map(str, dropped[:8])) + (", …" if len(dropped) > 8 else "")
            fits[-1].summary["warnings"] = list(fits[-1].summary.get("warnings", [])) + [
                f"{len(dropped)} of {len(finite)} readings not finite, left out of this sensor's fit (row{'s' if len(dropped) > 1 else ''} {shown})"]
    offsets, gains = np.array([f.offset for f in fits]), np.array([f.gain for f in fits])
    residual_sigma, covariance = _calibration_errors(r, h, offsets, gains, linear=method != "twostep")
    repeat_sigma, repeat_dof, lack_of_fit = _repeat_scatter(r, h, r - (h * gains + offsets))
    reference = None
    if method == "twostep" and repeat_sigma is not None:
        reference = _reference_scatter(r, h, offsets, gains, repeat_sigma, repeat_dof)
    if reference is not None:  # the model's misses judged beyond the reference's error (which it found, and carries)
        lack_of_fit = _repeat_scatter(r, h, reference["residuals"])[2]
    for i in [] if lack_of_fit is None else np.nonzero(np.min(lack_of_fit, axis=1) < LACK_OF_FIT_P)[0]:
        ratio = float(np.max(residual_sigma[i] / repeat_sigma[i]))
        fits[i].summary["warnings"] = list(fits[i].summary.get("warnings", [])) + [
            f"its readings miss the calibration's model (an offset and a gain per axis) by more than its repeated "
            f"readings scatter (residual σ {ratio:.3g}× theirs, lack-of-fit p {np.min(lack_of_fit[i]):.2g}): a field "
            "that does not follow the currents (the Earth's on a bench, a neighbouring conductor's: method 'in_field'), "
            "an axis misaligned, crosstalk between the axes or iron near the sensor, which the model lacks (`fluxcal "
            "diagnose RECORDING.csv --model cable --calibration …` names it against the repeats' σ), a drift "
            "between the poses"
            + (", or the least-squares fit's one field magnitude (method='twostep' knows each reading's)"
               if method == "least_squares" else "")]
    whole = shared = None
    if method == "twostep":
        own = [np.asarray(f.covariance, float) for f in fits]
        moved = np.zeros((len(fits), 4, 0 if reference is None else int(reference["pose"].max()) + 1))
        for i in range(len(fits)) if repeat_sigma is not None else []:
            # With the repeats' σ per axis, each magnitude residual gets its own variance (_magnitude_sandwich). Not
            # without repeats (the magnitude residuals alone do not tell the axes' noise apart: one σ̂, as TWOSTEP's),
            # nor where the lack-of-fit test says the model missed (the residuals then hold more than the repeats'
            # noise, which TWOSTEP's σ̂ keeps), nor for the ellipse fallback's fit (another estimator) or a covariance
            # the data do not determine (inf).
            if refined[i] and np.min(lack_of_fit[i]) >= LACK_OF_FIT_P and np.all(np.isfinite(own[i])):
                finite = np.isfinite(r[:, i]).all(axis=1)
                per_pose = None if reference is None else (
                    reference["tau2"], reference["pose"][finite], norms[finite, i], moved.shape[2])
                own[i], response = _magnitude_sandwich(r[finite, i], fits[i].offset, fits[i].gain, repeat_sigma[i],
                                                       per_pose)
                if response is not None:
                    moved[i] = response[TWOSTEP_ORDER]
        covariance = np.array([_axis_blocks(c) for c in own])
        whole = np.array([c[np.ix_(TWOSTEP_ORDER, TWOSTEP_ORDER)] for c in own])
        if reference is not None:  # the one meter's error moves every sensor's (γ, b): their errors are correlated
            shared = reference["tau2"] * np.einsum("ipk,jqk->ipjq", moved, moved)
            words = (f"the reference current's readings scatter by about {100 * np.sqrt(reference['tau2']):.2g} % from "
                     f"pose to pose beyond the sensors' noise (p {reference['p']:.2g}; the same error at every sensor "
                     "of a pose): included in the calibration's uncertainty, shared between the sensors; a steadier "
                     "reference (a better meter, or the current read at every repeat and averaged over the pose) or "
                     "more poses shrink it")
            for i in np.nonzero(moved.any(axis=(1, 2)))[0]:
                fits[i].summary["warnings"] = list(fits[i].summary.get("warnings", [])) + [words]
    return RingCalibration(offsets=offsets, gains=gains, method=method, sensors=fits, residual_sigma=residual_sigma,
                           covariance=covariance, repeat_sigma=repeat_sigma, repeat_dof=repeat_dof,
                           lack_of_fit_p=lack_of_fit, sensor_covariance=whole,
                           reference_scatter=None if shared is None else float(np.sqrt(reference["tau2"])),
                           reference_covariance=shared)


def calibrate_ring_in_field(readings, true_fields, ring: Ring, rotations_deg, order: int = 3) -> RingCalibration:
    """Calibrate every sensor of a ring in a field that does not follow the currents and stays put while the ring
    turns (the Earth's, a neighbouring conductor's: a calibration run in a switch room), from a run that reverses
    the currents at each rotation (the paper's ±I at 5 × 72°). TWOSTEP cannot: |h + B| is not the model's |h|.

    Each pose (consecutive readings with the same true fields and rotation) is averaged; a pose and the pose at the
    same rotation with the true fields reversed give, per sensor axis, half their difference γ h (offset and field
    gone: γ by least squares over the pairs) and half their sum b + γ B, B the field in the sensor's axes at that
    rotation: b (fixed to the ring) and B (fixed to the room: B(z) = Σₙ bₙ (z̄/R)ⁿ, n ≤ `order`: 0 uniform, 1 its
    gradient, 2, 3 — a neighbouring conductor 4–5 ring radii away leaves µT in its third term) by linear least
    squares over all pairs and sensors — the ring's turns tell them apart (a term that turns n + 1 times per turn is
    an offset to rotations n + 1 apart: 5 × 72° determine order ≤ 3). Statistics as calibrate_ring's linear ones,
    about γ (h + B) + b; `background` holds the bₙ (tesla, cable frame).
    readings, true_fields: (K, n_sensors, 2); rotations_deg: (K,) the ring's turn of each reading."""
    r = np.asarray(readings, dtype=float)
    h = np.asarray(true_fields, dtype=float)
    rot = np.asarray(rotations_deg, dtype=float).ravel()
    if r.ndim != 3 or r.shape[2] != 2 or h.shape != r.shape or r.shape[1] != ring.n_sensors:
        raise ValueError(f"readings {r.shape} and true_fields {h.shape}: expected the same shape (K, "
                         f"{ring.n_sensors}, 2) for this ring")
    if rot.shape != (len(r),) or not np.all(np.isfinite(rot)):
        raise ValueError(f"rotations_deg: need {len(r)} finite rotations, one per reading")
    if not (np.all(np.isfinite(r)) and np.all(np.isfinite(h))):
        raise ValueError("readings, true_fields: not finite (NaN or Inf); leave those readings out")
    start, run = consecutive_runs(rot, near=h)
    counts = np.bincount(run)[:, None, None]
    poses, fields, angles = run_sums(r, run) / counts, run_sums(h, run) / counts, rot[start]
    # (currents logged per reading jitter: a pose and its reversal agree to POSE_RTOL, not exactly)
    pairs = [(g, j) for g in range(len(poses)) for j in range(g + 1, len(poses))
             if np.isclose(angles[g], angles[j])
             and np.allclose(fields[j], -fields[g], atol=POSE_RTOL * np.abs(fields[g]).max(), rtol=0)]
    turns = np.unique(np.round(np.mod([angles[g] for g, _ in pairs], 360.0), 9))
    if len(turns) < 3:
        raise ValueError(f"readings: {len(pairs)} pairs of poses with the currents reversed at the same rotation, at "
                         f"{len(turns)} rotations; a calibration in a field that does not follow the currents needs "
                         "each rotation's currents reversed (±I) at 3 rotations or more (the paper: 5 × 72°)")
    first, second = map(list, zip(*pairs))
    h_pairs = (fields[first] - fields[second]) / 2.0  # ≈ the first pose's field: exactly when reversed exactly
    half_diff = (poses[first] - poses[second]) / 2.0  # γ ⊙ h_pairs
    gains = np.sum(half_diff * h_pairs, axis=0) / np.sum(h_pairs ** 2, axis=0)
    # b + γ ⊙ B, less what the pair's currents did not cancel
    half_sum = (poses[first] + poses[second]) / 2.0 - gains * (fields[first] + fields[second]) / 2.0
    m = ring.n_sensors
    theta = np.radians(ring.angles_deg[None] + np.asarray(angles[first])[:, None])  # (P, M)
    z = np.exp(1j * theta)  # the sensors' places in ring radii, cable frame
    axis = theta + np.radians(ring.axis_angles_deg)[None]
    shapes = [unit * np.conj(z) ** n for n in range(order + 1) for unit in (1.0, 1j)]
    in_axes = [_in_axes(b, axis) for b in shapes]
    columns = np.zeros((len(pairs), m, 2, 2 * m + len(shapes)))
    for i in range(m):
        for a in range(2):
            columns[:, i, a, 2 * i + a] = 1.0
    for j, b in enumerate(in_axes):
        columns[..., 2 * m + j] = gains[None] * b
    A = columns.reshape(-1, columns.shape[-1])
    if np.linalg.matrix_rank(A) < A.shape[1]:
        raise ValueError(f"readings: the offsets and a field of order {order} cannot be told apart at {len(turns)} "
                         "rotations (a term turning n + 1 times per turn is an offset at rotations 360°/(n + 1) apart): "
                         "turn the ring to more rotations, or give a lower order")
    solution = np.linalg.lstsq(A, half_sum.ravel(), rcond=None)[0]
    offsets = solution[:2 * m].reshape(m, 2)
    terms = solution[2 * m:].reshape(-1, 2)
    cal = RingCalibration(offsets=offsets, gains=gains, method="in_field", background={"terms_t": terms.tolist()})
    # every reading's field in its sensor's axes: the true one and the room's
    total = h + np.stack([cal.background_in_axes(ring, a) for a in rot])
    cal.residual_sigma = _calibration_errors(r, total, offsets, gains, linear=False)[0]
    cal.repeat_sigma, cal.repeat_dof, cal.lack_of_fit_p = _repeat_scatter(r, total, r - (total * gains + offsets))
    # (γ, b) as they were estimated: γ from the pairs' half differences alone, b with the room's field from their half
    # sums, each pair's noise that of its two poses' means. The linear model's covariance about γ (h + B) + b counted
    # the room's field's change across the rotations as information on γ, which it is not here, and its σ had the
    # pairs' 4 dof: the gains' errors over their SEs had a spread of 1.55 (a uniform 36 µT) to 2 (a busbar).
    per_pair = (1.0 / counts[first] + 1.0 / counts[second])[:, :, 0] / 4.0  # (P, 1): a half sum's or difference's σ²/σ²
    if cal.repeat_sigma is not None:  # the noise, from many dof; the lack-of-fit test says when the model missed
        noise = cal.repeat_sigma[None] ** 2 * per_pair[..., None]
    else:  # the pairs' own scatter about γ h (P − 1 dof per sensor axis)
        noise = np.broadcast_to(np.sum((half_diff - gains * h_pairs) ** 2, axis=0) / max(len(pairs) - 1, 1),
                                half_diff.shape)
    cal.covariance = np.zeros((m, 2, 2, 2))
    cal.covariance[..., 0, 0] = np.sum(noise * h_pairs ** 2, axis=0) / np.sum(h_pairs ** 2, axis=0) ** 2
    inverse = np.linalg.pinv(A.T @ A)
    sandwich = inverse @ (A.T * noise.ravel()) @ A @ inverse
    cal.covariance[..., 1, 1] = np.diag(sandwich)[:2 * m].reshape(m, 2)
    # each term's standard error (its real and imaginary parts): whether a term of 1–2 nT means anything
    cal.background["terms_sigma_t"] = np.sqrt(np.diag(sandwich)[2 * m:]).reshape(-1, 2).tolist()
    return cal


# Consecutive readings whose true fields differ by less than this fraction of the field hold one pose: currents logged
# per reading jitter by a meter's 0.1 %, while a new pose (a turn, a reversal, another level) changes them by tens of %
POSE_RTOL = 0.02


def consecutive_runs(*keys, near=None, rtol: float = POSE_RTOL) -> tuple:
    """Runs of consecutive rows whose `keys` (each (K, …)) are all equal and, when given, whose `near` values (K, …:
    true fields, currents) differ from the run's first row by at most `rtol` of its largest (and of 0.1 % of the
    largest of all, for a 0 A that jitters) — a pose held, readings repeated: (start (K,) bool, each run's first
    row; run (K,) each row's run number). (Against the row before, a ramp of 1.35 % steps had chained into one
    pose.)"""
    k = len(keys[0]) if keys else len(near)
    start = np.zeros(k, bool)
    start[0] = True
    if keys:
        key = np.column_stack([np.asarray(v, dtype=float).reshape(len(v), -1) for v in keys])
        start[1:] |= np.any(key[1:] != key[:-1], axis=1)
    if near is not None:
        v = np.asarray(near, dtype=float).reshape(k, -1)
        floor = 1e-3 * np.abs(v).max()
        first = 0
        for row in range(1, k):
            if not start[row]:
                start[row] = np.abs(v[row] - v[first]).max() > max(rtol * np.abs(v[first]).max(), floor)
            if start[row]:
                first = row
    return start, np.cumsum(start) - 1


def run_sums(values, run) -> np.ndarray:
    """Per run (`consecutive_runs`'), the sum of `values` (K, …) over its rows: (runs, …)."""
    v = np.asarray(values, dtype=float)
    sums = [np.bincount(run, weights=column) for column in v.reshape(len(v), -1).T]
    return np.stack(sums, axis=-1).reshape((-1,) + v.shape[1:])


def _in_axes(field, axis_rad) -> np.ndarray:
    """Complex fields (…, cable frame) → readings (…, 2) along sensor axes at `axis_rad` (broadcast)."""
    turned = field * np.exp(-1j * np.asarray(axis_rad))
    return np.stack([turned.real, turned.imag], axis=-1)


def _repeat_scatter(readings: np.ndarray, true_fields: np.ndarray, residuals: np.ndarray):
    """Per sensor and axis: the pooled scatter of consecutive readings that hold a pose (true fields within
    POSE_RTOL of each other: a pose and its currents held, or logged per reading) about the model — the noise alone —
    its degrees of freedom, and the lack-of-fit test's p that the residuals `residuals` (readings less the fitted
    model) scatter more than that between the poses: (σ, dof, p), each (n_sensors, 2), or (None, None, None) with
    fewer than 10 degrees of freedom or 3 poses. Within a pose the smaller of the readings' own scatter and the residuals' is taken: a current that jitters
    and is logged so moves the readings, which the model follows; a steady current read by a meter that scatters
    (a clamp meter's 0.1 %: 5× the sensors' noise) moves the model, which the readings do not. (A blind check's ±1° axis misalignment put 2.5× the noise into the residual scatter;
    judged against that, the diagnosis found the coupling in 2 rigs of 20, against 20 of 20 with a σ from repeats.)"""
    group = consecutive_runs(near=true_fields)[1]
    finite = np.isfinite(readings)
    counts = run_sums(finite, group)  # (runs, n_sensors, 2): each axis's finite readings per pose
    dof = np.sum(np.maximum(counts - 1, 0), axis=0)
    poses = np.sum(counts > 0, axis=0)
    if dof.min() < 10 or poses.min() < 3:
        return None, None, None
    from scipy.stats import f as f_distribution

    from .diagnose.core import _lattice_step

    def scatter(values):
        means = run_sums(np.where(finite, values, 0.0), group) / np.maximum(counts, 1)
        return np.sum(np.where(finite, values - means[group], 0.0) ** 2, axis=0)

    within_residuals = scatter(residuals)
    within = np.minimum(scatter(readings), within_residuals)
    misfit = np.sum(np.where(finite, residuals, 0.0) ** 2, axis=0) - within_residuals  # between the poses
    # readings on an ADC's grid repeat exactly when the noise is below its step: the scatter is at least step/√12
    # (a coarse ring's repeats gave 4e-21 T, and every test of the diagnosis then "departed" at 10²⁷)
    steps = np.array([[_lattice_step(readings[finite[:, i, a], i, a]) for a in range(readings.shape[2])]
                      for i in range(readings.shape[1])])
    if not steps.all():  # an axis with few levels may skip steps (gaps of 2 and 4 LSB): the ring's common grid
        steps = np.where(steps > 0, steps, _lattice_step(readings[finite]))
    floor = steps / np.sqrt(12.0)
    sigma = np.maximum(np.sqrt(within / dof), floor)
    # the poses' misfit against the residuals' own scatter within a pose (a meter's scatter is in both)
    sigma_residuals = np.maximum(np.sqrt(within_residuals / dof), floor)
    ratio = ((np.maximum(misfit, 0.0) / np.maximum(poses - 2, 1))
             / np.maximum(sigma_residuals ** 2, np.finfo(float).tiny))
    # (on the floor a pose's repeats share its rounding, which their mean then keeps: no test of the model there)
    return sigma, dof.astype(float), np.where(sigma > floor, f_distribution.sf(ratio, np.maximum(poses - 2, 1), dof), 1.0)


# A reference current read once per pose by a meter that scatters: the same relative error at every sensor of the pose.
# Its variance is carried only when the poses' residuals share it beyond the noise at this p (else the calibration's
# covariance is the noise's alone, as without a meter's scatter: 1 % of calibrations with a steady reference get a
# small term; 0.02 % per pose at 5× the sensors' noise had left the currents' ± at 0.7 of their spread, found by the
# per-sensor lack-of-fit test in 1 rig of 10).
REFERENCE_SCATTER_P = 0.01


def _reference_scatter(readings, true_fields, offsets, gains, sigma, dof) -> dict | None:
    """The reference's relative error per pose, ε_p ~ (0, τ²), the same at every sensor (the currents read once per
    pose by a meter that scatters), from the readings' residuals about the fitted γ h + b and their repeats' σ per
    axis (`sigma`, `dof`: _repeat_scatter's). Each sensor axis's pose mean is, to first order, r̄_p = −γ h̄_p ε_p +
    δγ h̄_p + δb + noise (variance σ² / c_p): one linear weighted least squares of the ε_p shared by all the sensors,
    with each axis's own line (δγ, δb) taken off (a scale common to every pose is a gain: one direction less). Per
    axis, not on TWOSTEP's magnitudes: there the offsets and gains absorb much of a pattern of ε, which then corrected
    the residuals so poorly that the lack-of-fit test flagged more rigs than without it. The sum of squares the ε_p
    explain is F-tested against the repeats' scatter and against what the ε_p leave (p: the larger); τ² by the
    method of moments, (SS − its dof × what is left per dof, at least the noise's) / tr F, F the ε's information.
    Returns dict(tau2, p, pose (K,) each reading's pose, residuals: the readings less the fit with the ε_p, for the
    lack-of-fit test) when p is below REFERENCE_SCATTER_P, else None."""
    from scipy.stats import f as f_distribution

    pose = consecutive_runs(near=true_fields)[1]
    finite = np.isfinite(readings)
    counts = run_sums(finite, pose)  # (poses, n_sensors, 2)
    residuals = readings - (true_fields * gains + offsets)
    mean = lambda x: run_sums(np.where(finite, x, 0.0), pose) / np.maximum(counts, 1)  # noqa: E731 - per pose
    r, h = mean(residuals), mean(true_fields)
    w = counts / sigma ** 2  # the pose means' inverse variances (0 where a pose lacks the axis)
    if not np.all(np.isfinite(w)):
        return None
    n_poses = len(r)
    info, g, lines = np.zeros((n_poses, n_poses)), np.zeros(n_poses), []
    rss, rss_dof = 0.0, 0
    for i, a in np.ndindex(*r.shape[1:]):
        x = np.column_stack([h[:, i, a], np.ones(n_poses)])
        wi = w[:, i, a]
        off_line = np.eye(n_poses) - x @ np.linalg.pinv(x.T @ (wi[:, None] * x)) @ (x.T * wi)  # (δγ, δb) taken off
        d = -gains[i, a] * h[:, i, a]  # ∂r̄_p/∂ε_p
        e = off_line @ r[:, i, a]
        rss, rss_dof = rss + e @ (wi * e), rss_dof + int(np.sum(wi > 0)) - 2
        info += d[:, None] * (wi[:, None] * off_line) * d[None, :]
        g += d * wi * e
        lines.append((i, a, x, wi, d))
    lam, u = np.linalg.eigh(info)
    keep = lam > 1e-9 * lam.max()  # (the common scale's direction is null)
    dof_meter = int(keep.sum())
    dof_left = rss_dof - dof_meter
    if dof_meter == 0 or dof_left < dof_meter:  # too few sensors to tell a shared error from each one's own miss
        return None
    z = u[:, keep].T @ g / lam[keep]
    explained = float(z @ (lam[keep] * z))
    # against the repeats' noise (their σ² pooled over the sensors and axes), and against what the ε leave (a model
    # miss, which the ε would share in, not be the cause of: a simulated rig's left 2× the noise, the ε 50×)
    left = max((rss - explained) / dof_left, 1.0)
    p_meter = max(f_distribution.sf(explained / dof_meter, dof_meter, float(np.sum(dof))),
                  f_distribution.sf(explained / dof_meter / left, dof_meter, dof_left))
    tau2 = max(explained - dof_meter * left, 0.0) / float(lam[keep].sum())
    if p_meter >= REFERENCE_SCATTER_P or tau2 <= 0.0:
        return None
    epsilon = u[:, keep] @ z
    for i, a, x, wi, d in lines:  # each reading less the ε_p's part and its axis's refitted line
        line = np.linalg.pinv(x.T @ (wi[:, None] * x)) @ (x.T @ (wi * (r[:, i, a] - d * epsilon)))
        residuals[:, i, a] -= (-gains[i, a] * epsilon[pose] + line[0]) * true_fields[:, i, a] + line[1]
    return {"tau2": tau2, "p": float(p_meter), "pose": pose, "residuals": residuals}


def _sampson_fit(readings: np.ndarray, norms: np.ndarray, why: str) -> TwoStep2D | None:
    """TWOSTEP 2-D's model (offset, per-axis gain) by maximum likelihood without its closed-form first step: the
    planar core's diagonal fit (`fluxcal::fit_planar`, Sampson residual, each reading's own |field|, from a direct
    ellipse fit). For a calibration run whose magnitudes hardly change (a jig symmetric about the ring's centre: 8 %
    across the run), the first step's h² column is nearly the constant one and noise can drive its γ² below 0 (a
    newcomer's symmetric jig refused in 1–3 of 30 rigs whose data determine the gains to 0.1 %). None when it does
    not converge, or when |h|/|field| scatters more after it than TWOSTEP's misfit warning allows (readings that do
    not belong to the magnitudes: the first step's failure was the model's, which the message says)."""
    options = _core.PlanarOptions()
    options.shape = _core.PlanarShape.diagonal
    options.serial_correlation = _core.SerialCorrelation.independent
    options.min_radius_over_noise = 0.0
    try:
        r = _core.fit_planar(np.ascontiguousarray(readings), np.ascontiguousarray(norms), options)
    except ValueError:
        return None
    if not r["summary"]["converged"] or r["summary"]["norm_std_over_mean"] > _core.TwoStep2DOptions().misfit_spread:
        return None
    a = np.diag(np.asarray(r["matrix"], dtype=float))  # h = diag(a) (ĥ − b): γ = 1/a
    to_gain = np.diag([1.0, 1.0, -1.0 / a[0] ** 2, -1.0 / a[1] ** 2])
    covariance = to_gain @ np.asarray(r["covariance"], dtype=float) @ to_gain.T
    se = np.sqrt(np.maximum(np.diag(covariance), 0.0))
    summary = dict(r["summary"])
    failed = (re.search(r"γ[xy]² = \S+ ≤ 0", why) or [why])[0]
    summary["warnings"] = list(summary.get("warnings", [])) + [
        f"TWOSTEP's first step failed ({failed}, with |field| changing by "
        f"{100 * np.ptp(norms) / np.mean(norms):.3g} % over the run); the offset and gains are the maximum-likelihood "
        "fit of the same model from a direct ellipse fit instead (Sampson residual against each reading's |field|)"]
    return TwoStep2D(offset=r["offset"], gain=1.0 / a, units=r["units"], summary=summary, offset_se=se[:2],
                     gain_se=se[2:], covariance=covariance)


def _turned_deg(directions: np.ndarray) -> float:
    """The arc (degrees) the unit field directions (K, 2) cover: 360° less the widest gap between them."""
    angles = np.sort(np.degrees(np.arctan2(directions[:, 1], directions[:, 0])))
    gaps = np.diff(np.concatenate([angles, angles[:1] + 360.0]))
    return float(360.0 - gaps.max())


TWOSTEP_ORDER = [2, 0, 3, 1]  # TWOSTEP's (bx, by, γx, γy) → (γx, bx, γy, by)


def _axis_blocks(covariance: np.ndarray) -> np.ndarray:
    """A TWOSTEP covariance over (bx, by, γx, γy) as RingCalibration keeps it: per axis, Cov(γ, b) (2, 2, 2)."""
    c = np.asarray(covariance, dtype=float)
    return np.array([[[c[2 + a, 2 + a], c[2 + a, a]], [c[a, 2 + a], c[a, a]]] for a in (0, 1)])


def _calibration_errors(readings, true_fields, offsets, gains, linear: bool = True):
    """Per sensor and axis: the RMS of the readings about γ h + b (dof K − 2) and σ² (XᵀX)⁻¹ of (γ, b), X = [h, 1],
    the linear model's covariance at the fitted values (the known true fields make each axis a straight line; None
    without `linear`: a fit that brings its own)."""
    e = readings - (true_fields * gains + offsets)
    finite = np.isfinite(e)  # (a sensor's readings that are not numbers were left out of its fit)
    k = finite.sum(axis=0)
    sigma = np.sqrt(np.sum(np.where(finite, e, 0.0) ** 2, axis=0) / np.maximum(k - 2, 1))
    if not linear:
        return sigma, None
    x = np.stack([true_fields, np.ones_like(true_fields)], axis=-1) * finite[..., None]  # (K, sensors, axes, 2)
    xtx = np.einsum("ksai,ksaj->saij", x, x)
    covariance = sigma[..., None, None] ** 2 * np.linalg.pinv(xtx)
    return sigma, covariance


def _magnitude_sandwich(readings, offset, gain, sigma, reference=None) -> tuple:
    """The covariance of (bx, by, γx, γy) (TWOSTEP's order) of the magnitude least squares min Σ (|(ĥ − b) ⊘ γ| − h_k)²
    at (b, γ) from `readings` (N, 2) whose axes have the noise σ `sigma` (2,), tesla: the sandwich
    (JᵀJ)⁻¹ (Σ v_k J_kᵀJ_k) (JᵀJ)⁻¹, J_k = ∂e_k/∂(b, γ), with each residual's own variance
    v_k = Σ_a σ_a² (f_a / (γ_a |f|))², f = (ĥ_k − b) ⊘ γ: only the noise along the field enters |f|, so a reading
    along the noisy axis scatters more. (TWOSTEP's σ̂²(JᵀJ)⁻¹ pools one σ̂ over all readings: at σy = 3σx its
    standard errors were 0.79–1.42 of the Monte-Carlo spread, the two axes' with opposite signs.)
    `reference` (τ², pose (N,) each reading's pose number, h_k (N,), n_poses), from _reference_scatter: the h_k carry
    a relative error ε_p ~ (0, τ²) per pose, which e_k holds as −h_k ε_p — the middle term gains τ² Σ_p y_p y_pᵀ,
    y_p = Σ_{k in p} h_k J_k. Returns (the covariance, L (4, n_poses): the estimate moves by L ε, so that two sensors'
    estimates share τ² L_i L_jᵀ; None without `reference`)."""
    f = (np.asarray(readings, float) - offset) / gain
    m = np.linalg.norm(f, axis=1)
    along = f / gain / m[:, None]  # ∂e_k/∂ĥ_a
    J = -np.column_stack([along, f ** 2 / gain / m[:, None]])
    v = along ** 2 @ (np.asarray(sigma, float) ** 2)
    scale = 1.0 / np.linalg.norm(J, axis=0)  # the offsets' and gains' columns differ by ~|h|: scale before inverting
    Js = J * scale
    bread = np.linalg.inv(Js.T @ Js)
    middle = Js.T @ (v[:, None] * Js)
    if reference is None:
        return bread @ middle @ bread * np.outer(scale, scale), None
    tau2, pose, norms, n_poses = reference
    y = np.stack([np.bincount(pose, Js[:, j] * norms, minlength=n_poses) for j in range(4)])
    return bread @ (middle + tau2 * y @ y.T) @ bread * np.outer(scale, scale), bread @ y * scale[:, None]


def calibration_fields(ring: Ring, positions_m, currents_a, rotations_deg) -> np.ndarray:
    """True fields (len(rotations) · len(currents), n_sensors, 2) at each rotation of the ring (outer) and
    each set of reference currents (inner; `currents_a` (c, n) or (n,))."""
    cur = np.atleast_2d(np.asarray(currents_a, dtype=float))
    return np.concatenate([ring.rotated(a).field(positions_m, cur) for a in np.atleast_1d(rotations_deg)])


# ---- recordings (CLI) ------------------------------------------------------------------------------
# A ring recording is a fluxcal CSV with one row per snapshot: `rotation_deg` (the ring's turn, optional),
# the reference currents `i0`, `i1`, … (calibration recordings), and the readings `s<k>_x`, `s<k>_y` of
# every sensor k (tesla). Metadata lines carry the ring (`ring_angles_deg`, `ring_radius_m`) and, for a
# calibration, the conductor positions (`positions_m`: x0 y0 x1 y1 …).

def _floats(text, key: str = "value", path="") -> np.ndarray:
    try:
        return np.array([float(v) for v in str(text).replace(",", " ").split()])
    except ValueError:
        raise ValueError(f"{path}: {key}: {str(text)!r} is not a list of numbers") from None


_LENGTH_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6, "µm": 1e-6}


def _metres(text, key: str, path) -> float:
    """A ring file's length (its key ends in _m): a number in metres, or with its unit ("10 mm"), converted; a
    ValueError naming the key otherwise (a blind check's `ring_radius_m: 10 mm` had given "could not convert string
    to float: '10 mm'")."""
    hit = re.fullmatch(r"\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([a-zµμ]*)\s*", str(text))
    unit = hit[2].replace("\u03bc", "\u00b5") if hit else None
    if not hit or (unit and unit not in _LENGTH_UNITS):
        raise ValueError(f"{path}: {key}: {str(text)!r} is not a length (a number in metres, or with its unit: 10 mm)")
    return float(hit[1]) * _LENGTH_UNITS.get(unit or "m")


def write_ring_csv(path, ring: Ring, readings, rotations_deg=None, currents_a=None, positions_m=None,
                   metadata=None):
    """Write snapshots (K, n_sensors, 2) with their rotations (K,) and reference currents (K, n)."""
    from .io import write_csv

    r = np.asarray(readings, float)
    cols = {}
    if rotations_deg is not None:
        cols["rotation_deg"] = np.asarray(rotations_deg, float)
    if currents_a is not None:
        cur = np.atleast_2d(np.asarray(currents_a, float))
        for j in range(cur.shape[1]):
            cols[f"i{j}"] = cur[:, j]
    for k in range(r.shape[1]):
        cols[f"s{k}_x"], cols[f"s{k}_y"] = r[:, k, 0], r[:, k, 1]
    units = {n: ("T" if n.startswith("s") else "A" if n.startswith("i") else "deg") for n in cols}
    meta = {"ring_angles_deg": " ".join(f"{a:.10g}" for a in ring.angles_deg), "ring_radius_m": f"{ring.radius_m:.10g}",
            "ring_bore_radius_m": f"{ring.bore_radius_m:.10g}"}
    if np.any(ring.axis_angles_deg != 0.0):
        meta["ring_axis_angles_deg"] = " ".join(f"{a:.10g}" for a in ring.axis_angles_deg)
    if positions_m is not None:
        meta["positions_m"] = " ".join(f"{v:.10g}" for v in np.ravel(positions_m))
    meta.update(metadata or {})
    return write_csv(path, cols, units=units, metadata=meta, fmt="%.12g")


RING_CURRENT_UNITS = LARGE_CURRENT_UNITS  # a cable's currents may be stated in kA
ANGLE_UNITS = {"deg": 1.0, "degree": 1.0, "degrees": 1.0, "°": 1.0, "rad": 180.0 / np.pi}
RING_FORMAT = ("comment lines '# ring_angles_deg: 0 90 180 270' and '# ring_radius_m: 0.01' "
               "(optionally ring_axis_angles_deg, ring_bore_radius_m, positions_m: x0 y0 x1 y1 … in metres) "
               "above a header of s0_x, s0_y, s1_x, … (each sensor's radial and tangential reading, sensors "
               "numbered from s0 in ring_angles_deg's order), optionally i0, i1, … (reference currents), "
               "rotation_deg (the ring's turn) and t (s); units in the header (s0_x[uT]) or a '# units:' line "
               "(fields default to T, currents to A)")


def _unit_key(unit: str) -> str:
    return unit.strip().strip("[]()").lower()


def _column_scale(path, name: str, unit: str, table: dict, default: str, what: str) -> float:
    """The factor that takes column `name` from its stated `unit` to SI; ValueError naming it otherwise."""
    if not unit:
        return 1.0
    key = _unit_key(unit)
    if key in table:
        return table[key]
    raise ValueError(f"{path}: column {name}: unit {unit!r} is not {what} ({', '.join(sorted(table))}; none: "
                     f"{default})")


def read_ring_csv(path, bad_lines: str = "error") -> dict:
    """Read a ring recording (any table format fluxcal reads; see RING_FORMAT): dict with ring, readings
    (K, n_sensors, 2) in tesla, rotations_deg (K,) (zeros when absent), currents_a (K, n) or None,
    positions_m (n, 2) or None, t_s (K,) or None, skipped_lines (what bad_lines="skip" left out, or None). Columns
    in other units (uT, mA, rad) are converted by the units the file states. bad_lines: "error" (a garbled or
    truncated line stops the read with its line and column) or "skip" (its snapshot is left out and listed)."""
    from .calibration import TESLA_PER_UNIT
    from .io import read_recording
    from .io.columns import TIME_UNITS, unit_name

    rec = read_recording(path, bad_lines=bad_lines)
    meta = rec.metadata
    if "ring_angles_deg" not in meta or "ring_radius_m" not in meta:
        raise ValueError(f"{path}: no ring_angles_deg / ring_radius_m metadata lines: not a ring recording? "
                         f"A ring recording has {RING_FORMAT} (`fluxcal cable simulate` writes one)")
    ring = Ring(_floats(meta["ring_angles_deg"], "ring_angles_deg", path),
                _metres(meta["ring_radius_m"], "ring_radius_m", path),
                axis_angles_deg=_floats(meta["ring_axis_angles_deg"], "ring_axis_angles_deg", path)
                if "ring_axis_angles_deg" in meta else None,
                bore_radius_m=_metres(meta["ring_bore_radius_m"], "ring_bore_radius_m", path)
                if "ring_bore_radius_m" in meta else None)
    sensors = sorted({int(n[1:].split("_")[0]) for n in rec.columns if re.fullmatch(r"s\d+_[xy]", n)})
    extra = [f"s{k}" for k in sensors if k >= ring.n_sensors]
    if extra:
        numbering = " (sensors are numbered from s0)" if "s0_x" not in rec.columns else ""
        raise ValueError(f"{path}: columns of sensors {', '.join(extra)} beyond the ring's {ring.n_sensors} "
                         f"(ring_angles_deg){numbering}")
    names = [(f"s{k}_x", f"s{k}_y") for k in range(ring.n_sensors)]
    missing = [n for pair in names for n in pair if n not in rec.columns]
    if missing:
        raise ValueError(f"{path}: no column {', '.join(missing)} for the ring's {ring.n_sensors} sensors")
    tesla = {u.lower(): v for u, v in TESLA_PER_UNIT.items()}

    def field(name):
        unit = rec.units.get(name, "")
        return rec.columns[name] * _column_scale(path, name, unit_name(unit) if unit else "", tesla, "T",
                                                 "a field unit")

    readings = np.stack([np.column_stack([field(x), field(y)]) for x, y in names], axis=1)
    k = readings.shape[0]
    cur_names = sorted((n for n in rec.columns if n[0] == "i" and n[1:].isdigit()), key=lambda n: int(n[1:]))
    stray = [n for n in rec.columns if n not in cur_names and _unit_key(rec.units.get(n, "")) in RING_CURRENT_UNITS]
    if stray:  # a current column under another name would be silently unused: the currents then fitted
        raise ValueError(f"{path}: column(s) {', '.join(stray)} hold currents ({rec.units[stray[0]]}), but reference "
                         "currents are read from columns named i0, i1, … (one per conductor): rename them")
    currents = (np.column_stack([rec.columns[n] * _column_scale(path, n, rec.units.get(n, ""), RING_CURRENT_UNITS, "A",
                                                                "a current unit") for n in cur_names])
                if cur_names else None)
    rotations = rec.columns.get("rotation_deg", np.zeros(k)) * _column_scale(
        path, "rotation_deg", rec.units.get("rotation_deg", ""), ANGLE_UNITS, "deg", "an angle unit")
    if not np.all(np.isfinite(rotations)):
        row = int(np.argmax(~np.isfinite(rotations)))
        raise ValueError(f"{path}: rotation_deg of snapshot {row} (file line {rec.line_numbers[row]}) is not a number")
    positions = _floats(meta["positions_m"], "positions_m", path) if "positions_m" in meta else None
    if positions is not None:
        if positions.size % 2:
            raise ValueError(f"{path}: positions_m holds {positions.size} numbers; it needs x y pairs")
        positions = positions.reshape(-1, 2)
        wanted = [f"i{j}" for j in range(len(positions))]
        if cur_names and cur_names != wanted:  # (a missing i1 had surfaced as a shape error further on)
            missing = [n for n in wanted if n not in cur_names]
            others = [n for n in rec.columns if n not in {c for pair in names for c in pair} | set(cur_names)
                      | {"rotation_deg", "t"}]
            raise ValueError(f"{path}: positions_m gives {len(positions)} conductors, the reference currents are "
                             f"{', '.join(cur_names)}" + (f": column {', '.join(missing)} missing" if missing else "")
                             + " (one current column i0, i1, … per conductor, in positions_m's order)"
                             + (f"; columns not used: {', '.join(others)} — is one of them a current?" if others else ""))
    bore_note = None
    reach = float(np.max(np.hypot(*positions.T))) if positions is not None else 0.0
    if "ring_bore_radius_m" not in meta and ring.bore_radius_m <= reach < ring.radius_m:
        # the stated conductors lie beyond the default bore (0.4 × radius): the solver's bound would clamp them
        # to its edge (a blind check's off-centre cable, "ended on the bore's edge" for every snapshot)
        wider = reach + 0.25 * (ring.radius_m - reach)
        bore_note = (f"positions_m puts a conductor {1e3 * reach:.3g} mm from the ring's centre, beyond the default "
                     f"bore ({1e3 * ring.bore_radius_m:.3g} mm, 0.4 × ring_radius_m): the bore taken as "
                     f"{1e3 * wider:.3g} mm (ring_bore_radius_m sets it)")
        ring = Ring(ring.angles_deg, ring.radius_m, ring.axis_angles_deg, wider)
    t = rec.columns.get("t")
    if t is not None:
        t = t * _column_scale(path, "t", rec.units.get("t", ""), TIME_UNITS, "s", "a time unit")
    used = {n for pair in names for n in pair} | set(cur_names) | {"rotation_deg", "t"}
    return {"ring": ring, "readings": readings, "rotations_deg": np.asarray(rotations, float), "currents_a": currents,
            "positions_m": positions, "t_s": None if t is None else np.asarray(t, float),
            "unused_columns": [n for n in rec.columns if n not in used],
            "skipped_lines": rec.metadata.get("skipped_lines"), "line_numbers": rec.line_numbers,
            "current_names": cur_names, "rotations_given": "rotation_deg" in rec.columns, "bore_note": bore_note}


def ring_columns_note(data: dict) -> str | None:
    """A line for the command line when a ring recording has columns it does not use (a current named IA is
    not a reference current: the currents would be fitted without a word)."""
    if not data["unused_columns"]:
        return None
    return (f"columns not used: {', '.join(data['unused_columns'])} (reference currents are read from i0, i1, …, "
            "the ring's turn from rotation_deg, times from t)")
