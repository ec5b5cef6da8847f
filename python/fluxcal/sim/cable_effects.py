"""Cable effects the ring's model leaves out: each one both simulates and, in the cable diagnosis
(`fluxcal.diagnose.diagnose_cable`), is a candidate model term — the pattern of `fluxcal.sim.effects`.

The ring's model (`fluxcal.cable.Ring.field`) takes the conductors as straight, infinitely long lines
parallel to the ring's axis, and the sensors exactly where the drawing puts them. A real cable and ring
depart from that:

  helical_lay             the cores of a multicore cable are twisted with a lay length L (10–40× the pitch
                          circle diameter, manufacturers' practice for multicore cables): near the ring a
                          core is not where it crosses the sensor plane, but spread over angle
  finite_length           a bench rig: straight cores of finite length, the circuit closing a distance ℓ
                          either side of the ring (cross pieces to the cable's centre, and leads to a
                          return wire when the cores' currents do not sum to zero)
  sensor_position_error   each sensor's angle, radius and axis angle off the drawing (PCB assembly:
                          ≈ 0.5°, 0.1–0.2 mm, 1°)
  cable_tilt              the cable not square to the ring (2–5°): each core's in-plane field changes by
                          τ²/2 with the direction from the core (a second harmonic fixed to the cable)
  z_leakage               each in-plane axis reads a fraction k_z of the field along the ring's axis B_z:
                          the Earth's (constant, an offset the per-sensor calibration removes) and the
                          cable field's share when the cable is tilted by τ in direction ψ
  sensor_coupling         each sensor's two axes coupled (not at right angles, crosstalk, iron near it)
  sensor_nonlinearity     each sensor axis's reading bends with the field (an AMR bridge compressing towards its
                          range): cubic in the current, which the calibration at one current cannot fold away
  background_field        a field that does not follow the currents and stays in the cable (lab) frame as the
                          ring turns: the Earth's, a magnet's, a neighbouring conductor on another circuit
  background_gradient     that field's change across the ring: a source near it
  nearby_iron             iron near the ring (a steel plate, a tray, an enclosure) magnetised by the cores: a field
                          that follows the currents but stays in the cable (lab) frame as the ring turns

Simulation (exact): `EffectRig` is a `fluxcal.sim.cable.CableRig` whose true field comes from the effects:
Biot–Savart of discretised conductor paths (closed-form field of a finite straight segment, vectorised
NumPy) at the sensors where they really are, in their real axes, plus k_z B_z. `cable_trial(names, seed)`
simulates a calibration run and a diagnosis recording with the named effects withheld from the model.

Candidate (first order in its coefficients): `features(ctx, alternative)` is the effect on the readings
per unit coefficient, (K snapshots, M sensors, 2 axes, p) in tesla, at the fitted conductor positions
`ctx.positions` and the currents `ctx.currents` — linear in the currents, so the diagnosis can also ask
for them per ampere of each conductor — with `ctx.field_lab` the field at the sensors in the cable frame
(complex, including `ctx.extra`, what effects already found add) and `ctx.net_current` whether the
recording's cores carry a net current (see `fluxcal.diagnose.cable._context`). Where an effect has a
non-linear parameter (the lay length, the tilt direction), `alternatives(ctx)` lists trial values and
`search(ctx, score)` returns the best-scoring one and how many were tried (the diagnosis pays for the
choice in its p-value, as in `fluxcal.sim.effects`); `refinable` effects then have it fitted with the
positions (`encode`/`decode` map it to the fit's variable). Each class's docstring states its typical
magnitudes (`typical`) and the approximation of its candidate; tests/python/test_diagnose_cable.py checks
the candidates against the exact simulation. SI units: metres, amperes, tesla; degrees only where a name
says `_deg`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.special import ive, k0e, k1e

from ..cable import MU0_OVER_2PI, Ring
from .cable import CableRig, reference_currents
from .effects import Effect

MU0_OVER_4PI = MU0_OVER_2PI / 2.0


# ---------------------------------------------------------------- geometry and Biot–Savart

def segment_field(points, starts, ends, currents) -> np.ndarray:
    """Field (P, 3) in tesla at `points` (P, 3) of straight segments `starts` → `ends` (S, 3) carrying
    `currents` (S,) amperes. Closed form B = μ0I/4π · (a × b)(|a| + |b|) / (|a||b|(|a||b| + a·b)) with
    a, b the vectors from the point to the ends; where a·b < 0 (a long segment seen from its side) the
    same value as (a × b)(|a| + |b|)(|a||b| − a·b) / (|a||b| |a × b|²), which does not cancel."""
    p = np.asarray(points, float)
    a = np.asarray(starts, float)[None] - p[:, None]
    b = np.asarray(ends, float)[None] - p[:, None]
    na, nb = np.linalg.norm(a, axis=-1), np.linalg.norm(b, axis=-1)
    ab = np.sum(a * b, axis=-1)
    c = np.cross(a, b)
    c2 = np.sum(c * c, axis=-1)
    nab = na * nb
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(ab >= 0, (na + nb) / (nab * (nab + ab)),
                     (na + nb) * (nab - ab) / (nab * np.where(c2 > 0, c2, 1.0)))
    return MU0_OVER_4PI * np.einsum("ps,psk->pk", f * np.asarray(currents, float)[None], c)


def sensor_points(ring: Ring, rotation_deg: float = 0.0, angle_error_deg=None, radius_error_m=None,
                  axis_error_deg=None):
    """Where the sensors of `ring` turned by `rotation_deg` are, as complex numbers x + iy (M,) in the
    cable frame, and the direction of each sensor's x axis (M,) in radians; optionally each sensor off
    the drawing by an angle (its axes turn with it), a radius and an axis angle."""
    m = ring.n_sensors
    zero = np.zeros(m)
    theta = np.radians(ring.angles_deg + rotation_deg + (zero if angle_error_deg is None else angle_error_deg))
    radius = ring.radius_m + (zero if radius_error_m is None else np.asarray(radius_error_m, float))
    axis = theta + np.radians(ring.axis_angles_deg + (zero if axis_error_deg is None else axis_error_deg))
    return radius * np.exp(1j * theta), axis


def straight_unit_fields(points, positions) -> np.ndarray:
    """The ring model: field of infinite straight conductors along +z at `positions` (n, 2), 1 A each,
    at `points` (…) complex: (…, n) complex Bx + iBy. Same physics as `Ring.field`:
    B = μ0/(2π) · i / conj(s − p)."""
    w = np.asarray(points)[..., None] - (positions[:, 0] + 1j * positions[:, 1])
    return MU0_OVER_2PI * 1j / np.conj(w)


def to_axes(b_complex, axis_rad) -> np.ndarray:
    """Complex lab fields (…) → readings (…, 2) along the sensor axes at angle `axis_rad` (broadcast)."""
    r = b_complex * np.exp(-1j * np.asarray(axis_rad))
    return np.stack([r.real, r.imag], axis=-1)


def _paths_field(points, paths) -> np.ndarray:
    """In-plane field (P, n) complex Bx + iBy, cable frame, per ampere in each conductor's closed path at
    `points` (P,) complex; `paths` is a list (one per conductor) of (starts, ends) arrays."""
    pts = np.column_stack([np.real(points), np.imag(points), np.zeros(len(points))])
    out = [segment_field(pts, s, e, np.ones(len(s)))[:, :2] for s, e in paths]
    b = np.stack(out, axis=-1)  # (P, 2, n)
    return b[:, 0] + 1j * b[:, 1]  # (P, n) complex


# ---------------------------------------------------------------- the effects

class CableEffect(Effect):
    """A cable effect. Simulation, by `kind`: "conductors" — `unit_fields(points, positions)`, the complex
    field (P, n) per ampere of each conductor; "sensors" — `sensors(ring, rotation_deg)`, where the sensors
    are and their axes; "readings" — `readings(field_lab, axis_rad)`, what the transducer adds; "background" —
    `field(points, ring)`, a field of its own that the currents do not make.
    Candidate: `features(ctx, alternative)`, `alternatives`, `search`, `regime` (held out: "rotation",
    "current" or "time")."""

    kind = "conductors"  # "conductors", "sensors", "readings" or "background"
    regime = "rotation"
    refinable = False  # the non-linear parameter (the alternative) is refined with the positions in a fit
    relinearised_at = None  # a first-order term: coefficients → the alternative to linearise at next (a fit's steps)
    follows_current = True  # the features scale with the currents (False: a field of its own, at any current)
    affine = True  # the features are affine in the currents (False: a sensor's bend, cubic; held at the reference)

    @staticmethod
    def encode(alternative) -> float:
        return float(alternative)

    @staticmethod
    def decode(value) -> float:
        return float(value)

    @classmethod
    def alternatives(cls, ctx) -> list:
        return [None]

    @classmethod
    def not_applicable(cls, ctx) -> str | None:
        """Why the candidate cannot act on this cable (the report's note), or None."""
        return None

    @classmethod
    def unphysical(cls, coefficients, alternative=None) -> str:
        """Why fitted coefficients (and the fitted non-linear parameter, `alternative`) cannot be this effect (its
        physics forbids them), or ""."""
        return ""

    @classmethod
    def interpret(cls, coefficients) -> dict:
        """What the fitted coefficients mean physically (the report's numbers), or {}."""
        return {}

    @classmethod
    def field_share(cls, ctx, feats, coefficients) -> dict:
        """What the fitted term's field is beside the cores' (the report's numbers), or {}."""
        return {}

    @classmethod
    def search(cls, ctx, score):
        alts = cls.alternatives(ctx)
        scores = [score(cls.features(ctx, a)) for a in alts]
        return alts[int(np.argmax(scores))], len(alts)

    @classmethod
    def describe(cls, alternative) -> dict:
        """What the chosen alternative means, for the report."""
        return {}


def helix_paths(positions, lay_length_m: float, turns: int = 20, per_turn: int = 128, near_turns: int = 3,
                far_per_turn: int = 32, far_m: float = 1e5, fine_m: float = 2.5e-4) -> list:
    """Closed current paths of cores twisted about their centroid with lay length L (right-handed; the
    in-plane field at z = 0 does not depend on the hand): each core a polyline of `per_turn` chords per
    turn within `near_turns` of the sensor plane (and no longer than max(`fine_m`, |z|/16)) and
    `far_per_turn` beyond, to ±`turns`·L; then radial
    chords back to the lay axis and straight lines along it to ±`far_m` (beyond ±turns·L the helix
    averages to a current on its axis). Chord vertices sit at the helix radius × (1 + ⅔(1 − cos Δφ/2)) so
    that the chords carry the current at the helix's mean radius (the sag error falls from O(Δφ²) to
    O(Δφ⁴))."""
    pos = np.asarray(positions, float)
    c = pos.mean(axis=0)
    k = 2 * np.pi / lay_length_m
    # chords no longer than L/per_turn, nor than max(fine_m, |z|/16) near the sensor plane (where a
    # sensor ~1 cm away sees the path's shape), then far_per_turn per turn beyond near_turns
    zp, h_max = [0.0], lay_length_m / per_turn
    while zp[-1] < near_turns * lay_length_m:
        zp.append(zp[-1] + min(h_max, max(fine_m, zp[-1] / 16.0)))
    z_far = np.linspace(zp[-1], max(turns * lay_length_m, zp[-1]),
                        max((turns - near_turns) * far_per_turn, 1) + 1)[1:]
    zp = np.concatenate([zp, z_far])
    z = np.concatenate([-zp[::-1], zp[1:]])
    dphi = k * np.diff(z)
    chord_sag = 1.0 - np.cos(dphi / 2.0)
    # a vertex takes the mean sag of its two chords
    sag = 1.0 + (2.0 / 3.0) * 0.5 * (np.concatenate([[chord_sag[0]], chord_sag])
                                     + np.concatenate([chord_sag, [chord_sag[-1]]]))
    ends = z[-1]
    paths = []
    for p in pos:
        d = (p - c)[0] + 1j * (p - c)[1]
        xy = (c[0] + 1j * c[1]) + sag * d * np.exp(1j * k * z)
        path = np.column_stack([xy.real, xy.imag, z])
        far_lo, axis_lo = [c[0], c[1], -far_m], [c[0], c[1], -ends]
        axis_hi, far_hi = [c[0], c[1], ends], [c[0], c[1], far_m]
        # along the axis from −far, out to the helix, along it, back to the axis, along the axis to +far
        points = np.vstack([far_lo, axis_lo, path, axis_hi, far_hi])
        starts, stops = points[:-1], points[1:]
        paths.append((starts, stops))
    return paths


def _scaled_k_pairs(y: np.ndarray) -> tuple:
    """kve(m − 1, y[i]) and kve(m, y[i]) of each term i = m − 1 (y: terms × …): from orders 0 and 1 up the recurrence
    K_{j+1} = K_{j−1} + (2j/y) K_j (stable upwards for K; the same for the scaled kve, one factor e^y at a given y),
    term i's row carried up to its own order. scipy's kve at three orders per term was nearly all of the helix
    series' time, and the series most of a lay candidate's."""
    lower, upper = k0e(y), k1e(y)
    below, at = np.empty_like(lower), np.empty_like(upper)
    below[0], at[0] = lower[0], upper[0]
    for j in range(1, len(y)):  # rows j…: K_j and K_{j+1}
        lower, upper = upper[1:], lower[1:] + (2 * j / y[j:]) * upper[1:]
        below[j], at[j] = lower[0], upper[0]
    return below, at


def helix_series_unit_fields(points, positions, lay_length_m: float, terms: int | None = None) -> np.ndarray:
    """The exact in-plane field at z = 0 (outside the helix radius) of infinite helical cores twisted about
    their centroid, 1 A each: complex (P, n). The helix's multipole series (modified Bessel functions;
    e.g. Hagel et al. 1994), for a core at radius a, angle φ_j about the lay axis and k = 2π/L:
      B_φ = μ0I/(2πr) + (μ0 I k a / (π r)) Σ_m m I_m'(mka) K_m(mkr) cos m(φ − φ_j)
      B_r =             (μ0 I k² a / π)   Σ_m m I_m'(mka) K_m'(mkr) sin m(φ − φ_j)
    which tends to the straight conductor's multipoles as k → 0. Used by the candidate (fast); the
    simulation uses the segment sum (tests hold the two equal)."""
    pos = np.asarray(positions, float)
    c = pos.mean(axis=0)
    s = np.asarray(points) - (c[0] + 1j * c[1])
    r, phi = np.abs(s), np.angle(s)
    k = 2 * np.pi / lay_length_m
    d = (pos[:, 0] - c[0]) + 1j * (pos[:, 1] - c[1])
    a, phj = np.abs(d), np.angle(d)
    if terms is None:  # terms fall as (a/r)^m: enough for 1e-12, at most 60
        ratio = float(np.max(a) / np.min(r))
        terms = int(np.clip(np.ceil(np.log(1e-12) / np.log(max(ratio, 1e-3))), 2, 60))
    m = np.arange(1, terms + 1)[:, None, None]
    x = m * k * a[None, None, :]                            # (terms, 1, n)
    y = m * k * r[None, :, None]                            # (terms, P, 1)
    ip = 0.5 * (ive(m - 1, x) + ive(m + 1, x))              # I_m'(x) e^{-x}
    below, km = _scaled_k_pairs(y)                          # K_{m−1}(y) e^{y}, K_m(y) e^{y}
    kp = -below - (m / y) * km                              # K_m'(y) e^{y}
    scale = np.exp(x - y)
    chi = m * (phi[None, :, None] - phj[None, None, :])
    mono = MU0_OVER_2PI / r[:, None]
    b_phi = mono + (2 * MU0_OVER_2PI * k * a / r[:, None]) * np.sum(m * ip * km * scale * np.cos(chi), axis=0)
    b_r = (2 * MU0_OVER_2PI * k * k * a) * np.sum(m * ip * kp * scale * np.sin(chi), axis=0)
    out = (b_r + 1j * b_phi) * np.exp(1j * phi)[:, None]   # (P, n)
    on_axis = a == 0  # a core on the lay axis is straight
    if on_axis.any():
        out[:, on_axis] = straight_unit_fields(points, pos[on_axis])
    return out


@dataclass
class HelicalLay(CableEffect):
    """Cores twisted about the cable's centre (the centroid of the cores at the sensor plane) with lay
    length `lay_length_m`. Typical: 10–40× the pitch circle diameter D of a multicore cable; for the
    paper's two cores 4 mm apart, L = 40–160 mm, and the field at the 10 mm ring changes by 3–14 % RMS
    (k = 2π/L, kR = 0.4–1.6: the ring sees the cores' helical spread, not a small correction).

    Candidate: the change of the ring's readings from straight to twisted cores, Δ(L_ref) — the helix's
    multipole series at the fitted positions and currents — times a coefficient c. The effect is not one
    shape scaled: from L_ref = L to √2·L its shape changes by 7–20 % (and c ≈ (L_ref/L)^1.2–1.4, not the
    small-kR (L_ref/L)²), so a grid of L_ref alone would leave that much. The reference lay is therefore
    searched on a grid of L/D (√2 steps, refined by the score test) and then fitted with the positions as
    a non-linear parameter (`refinable`); c ≈ 1 then confirms the model (the check against the exact
    segment sum is in tests/python/test_diagnose_cable.py). Handedness does not change the in-plane field
    at the sensor plane (a mirror argument), so it is neither simulated nor a parameter."""

    lay_length_m: float
    turns: int = 20
    per_turn: int = 128
    name = "helical_lay"
    n_params = 1
    regime = "rotation"
    kind = "conductors"
    refinable = True
    LAY_RATIOS = 5.0 * np.sqrt(2.0) ** np.arange(12)  # L / pitch-circle diameter: 5 … 226
    PROFILE = tuple(5.0 * 2.0 ** np.arange(7))  # the diagnosis's coarse profile: 5 … 320 (then fitted)
    profile = True
    REFINE = 3  # levels of refinement of the best ratio, each √2^(1/2^level)

    def unit_fields(self, points, positions) -> np.ndarray:
        return _paths_field(np.asarray(points).ravel(), helix_paths(positions, self.lay_length_m, self.turns,
                                                                    self.per_turn)).reshape(np.shape(points) + (-1,))

    @staticmethod
    def pitch_diameter(positions) -> float:
        pos = np.asarray(positions, float)
        return 2.0 * float(np.max(np.linalg.norm(pos - pos.mean(axis=0), axis=1)))

    _last_delta = (None, None)  # (key, Δ): the diagnosis asks again at once, per ampere of each core in turn

    @classmethod
    def delta_unit(cls, ctx, lay_length_m) -> np.ndarray:
        """Δ per unit current of each core: (R rotations, M, 2, n) real, sensor axes; read-only, since a repeated
        question gets the same array."""
        pts = ctx.points  # (R, M) complex
        key = (np.asarray(ctx.positions, float).tobytes(), float(lay_length_m), pts.tobytes(), pts.shape,
               np.asarray(ctx.axes).tobytes())
        last_key, last = cls._last_delta
        if key == last_key:
            return last
        twisted = helix_series_unit_fields(pts.ravel(), ctx.positions, lay_length_m).reshape(pts.shape + (-1,))
        straight = straight_unit_fields(pts, ctx.positions)
        delta = to_axes(twisted - straight, ctx.axes[..., None]).transpose(0, 1, 3, 2)
        delta.flags.writeable = False  # shared by the next caller with the same question
        cls._last_delta = (key, delta)
        return delta

    @classmethod
    def features(cls, ctx, alternative=None):
        ratio = 20.0 if alternative is None else alternative
        lay = ratio * cls.pitch_diameter(ctx.positions)
        delta = cls.delta_unit(ctx, lay)[ctx.rot_index]  # (K, M, 2, n)
        return np.einsum("kman,kn->kma", delta, ctx.currents)[..., None]

    @classmethod
    def alternatives(cls, ctx):
        return list(cls.LAY_RATIOS)

    @classmethod
    def not_applicable(cls, ctx) -> str | None:
        if cls.pitch_diameter(ctx.positions) <= 0:
            return "one conductor: a lay twists cores about each other"
        return None

    @classmethod
    def unphysical(cls, coefficients, alternative=None) -> str:
        # c scales the twist's change of the field, ≈ 1 once the lay is fitted: a negative c is the change
        # reversed, which no lay makes (a cable end or a tilt taken for a helix did it in the blind checks)
        c = float(np.ravel(coefficients)[0])
        if c <= 0:
            return f"the twist's field change reversed (coefficient {c:.3g}): no lay makes it"
        if alternative is not None and alternative < cls.LAY_RATIOS[0]:
            # (what a first-order candidate leaves of a sensor 0.8 mm off a 12 mm ring was fitted as a 2 pitch-diameter
            # lay in a blind check: the fit ran to the bound)
            return (f"a lay of {alternative:.2g} pitch diameters, shorter than any cable's ({cls.LAY_RATIOS[0]:g} and "
                    "more; 10–40 is usual)")
        return ""

    @classmethod
    def search(cls, ctx, score):
        """The grid of lay ratios, then the best one refined by halving the (log) step REFINE times."""
        if cls.pitch_diameter(ctx.positions) <= 0:
            return None, 1
        ratios = list(cls.LAY_RATIOS)
        scores = [score(cls.features(ctx, r)) for r in ratios]
        best, value, tried = ratios[int(np.argmax(scores))], max(scores), len(ratios)
        step = np.sqrt(2.0)
        for _ in range(cls.REFINE):
            step = np.sqrt(step)
            for trial in (best / step, best * step):
                s = score(cls.features(ctx, trial))
                tried += 1
                if s > value:
                    best, value = trial, s
        return best, tried

    @staticmethod
    def encode(alternative) -> float:
        return float(np.log(alternative))

    @staticmethod
    def decode(value) -> float:
        # kept within 2–2000 pitch diameters: shorter is not a cable, longer changes the field < 2e-4
        return float(np.exp(np.clip(value, np.log(2.0), np.log(2000.0))))

    @classmethod
    def describe(cls, alternative) -> dict:
        return {"reference_lay_over_pitch_diameter": None if alternative is None else float(alternative)}

    @classmethod
    def typical(cls, positions, rng):
        return cls(float(rng.uniform(10.0, 40.0)) * cls.pitch_diameter(positions))


@dataclass
class FiniteLength(CableEffect):
    """A bench rig: the cores run straight from `near_m` before the sensor plane (the source end) to
    `far_m` beyond it; at each end every core joins the cable's centre (cross pieces), and a net current
    returns through a straight wire `return_offset_m` from the cable's centre at `return_angle_deg`
    (leads at both ends). Each core's current thus flows in its own closed loop. Typical: ℓ = 0.1–0.25 m
    either side (a cable clamped on a bench, shorted at one end), return wire 0.15–0.3 m away.

    Candidate, to first order in (r/ℓ)² (r: sensor–core distances): the truncated cores lose
    −(μ0/8π) S Σ_j I_j ẑ×(s − p_j) and the cross pieces add −(μ0/4π) S ẑ×Σ_j I_j (p_j − p̄), with
    S = 1/ℓ_near² + 1/ℓ_far² the coefficient (1/m²). Their sum's part from the cores' own currents is
    a uniform field fixed to the cable, −(μ0/8π) S ẑ×Σ I_j (p_j − p̄): not something moving the cores can
    make, so it is identifiable (the trials' geometry: two cores carrying ±I, go and return through the
    ring). The part ∝ the net current Σ I_j (a field ∝ ẑ×s, with a curl) is cancelled by the leads'
    field — the in-plane field at the sensor plane is curl-free — and what the net current leaves is the
    return wire's nearly uniform field: four more coefficients (x, y and their gradient, per ampere of
    net current) when the recording has a net current."""

    near_m: float
    far_m: float
    return_offset_m: float = 0.2
    return_angle_deg: float = 0.0
    name = "finite_length"
    n_params = 1
    regime = "current"
    kind = "conductors"

    def paths(self, positions) -> list:
        pos = np.asarray(positions, float)
        c = pos.mean(axis=0)
        q = c + self.return_offset_m * np.array([np.cos(np.radians(self.return_angle_deg)),
                                                 np.sin(np.radians(self.return_angle_deg))])
        lo, hi = -self.near_m, self.far_m
        out = []
        for p in pos:
            # core → cross piece → lead → return wire → lead → cross piece: a closed loop
            corners = np.array([[p[0], p[1], lo], [p[0], p[1], hi], [c[0], c[1], hi], [q[0], q[1], hi],
                                [q[0], q[1], lo], [c[0], c[1], lo], [p[0], p[1], lo]])
            out.append((corners[:-1], corners[1:]))
        return out

    def unit_fields(self, points, positions) -> np.ndarray:
        return _paths_field(np.asarray(points).ravel(), self.paths(positions)).reshape(np.shape(points) + (-1,))

    @classmethod
    def features(cls, ctx, alternative=None):
        pos = ctx.positions
        p = pos[:, 0] + 1j * pos[:, 1]
        pbar = p.mean()
        s = ctx.points[ctx.rot_index]  # (K, M) complex
        cur = ctx.currents  # (K, n)
        # −(μ0/8π) S ẑ×Σ I_j (p_j − p̄), uniform; ẑ × v = i v for complex in-plane vectors
        uniform = -(MU0_OVER_4PI / 2.0) * 1j * (cur @ (p - pbar))[:, None] * np.ones_like(s)
        cols = [to_axes(uniform, ctx.axes[ctx.rot_index])]
        net = cur.sum(axis=1)
        has_net = getattr(ctx, "net_current", None)  # the recording's, when ctx holds per-ampere currents
        if has_net is None:
            has_net = np.max(np.abs(net)) > 1e-6 * np.max(np.abs(cur))
        if has_net:
            # the return wire: a uniform field and its gradient per ampere of net current (a 2-D field
            # B = conj(g(s)), g analytic: g = α and g = α s, cable frame)
            r0 = np.abs(s).mean()
            for column in (np.ones_like(s), 1j * np.ones_like(s), np.conj(s) / r0, -1j * np.conj(s) / r0):
                cols.append(to_axes(1e-7 * net[:, None] * column, ctx.axes[ctx.rot_index]))
        return np.stack(cols, axis=-1)

    @classmethod
    def interpret(cls, coefficients) -> dict:
        """S = 1/ℓ_near² + 1/ℓ_far² as the distance ℓ = √(2/S) at which the circuit closes either side of the ring,
        were it symmetric."""
        S = float(np.ravel(coefficients)[0])
        return {"closing_distance_m": float(np.sqrt(2.0 / S))} if S > 0 else {}

    @classmethod
    def typical(cls, positions, rng):
        return cls(float(rng.uniform(0.1, 0.25)), float(rng.uniform(0.1, 0.25)), float(rng.uniform(0.15, 0.3)),
                   float(rng.uniform(0, 360)))


@dataclass
class SensorPositionError(CableEffect):
    """Each sensor off the drawing: `angle_deg` along the ring (its axes turn with it), `radius_m` and
    `axis_deg` (its axes turned about its own normal), all (M,). Typical (PCB assembly): ±0.3–0.7°,
    ±0.1–0.2 mm, ±0.5–1.5°.

    Candidate: the derivative of every sensor's reading with respect to its own angle, radius and axis
    angle (per degree, millimetre, degree) at the fitted positions: 3M coefficients (analytic derivatives
    of the straight-conductor field). A common turn of all sensors is a turn of the cable, a common radius the
    ring scaled: the angles and radii are taken against their mean. The diagnosis fits it again linearised where
    its first fit moved the sensors (`relinearised_at`), so that a large displacement leaves no second-order
    remainder."""

    angle_deg: np.ndarray
    radius_m: np.ndarray
    axis_deg: np.ndarray
    name = "sensor_position_error"
    n_params = 12  # 3 per sensor of the 4-sensor ring (the diagnosis counts the features it gets)
    regime = "rotation"
    kind = "sensors"

    def sensors(self, ring, rotation_deg):
        return sensor_points(ring, rotation_deg, self.angle_deg, self.radius_m, self.axis_deg)

    @classmethod
    def features(cls, ctx, alternative=None):
        """The derivatives (3M columns), at the drawing's positions or, with `alternative` a displacement (M, 3: °,
        mm, °, as the coefficients), at the sensors so moved, with one more column: the reading there less the
        drawing's and the derivatives' share of the displacement — its coefficient 1, the coefficients then the
        whole displacement (a re-linearisation; `relinearised_at`)."""
        if alternative is None:
            return cls._derivatives(ctx, ctx.points, ctx.axes)[0]
        d = np.asarray(alternative, float).reshape(-1, 3)
        deg = np.pi / 180.0
        points = ctx.points * np.exp(1j * deg * d[:, 0]) * (1.0 + 1e-3 * d[:, 1] / np.abs(ctx.points))
        axes = ctx.axes + deg * (d[:, 0] + d[:, 2])
        derivs, moved = cls._derivatives(ctx, points, axes)
        drawn = cls._derivatives(ctx, ctx.points, ctx.axes)[1]
        return np.concatenate([derivs, (moved - drawn - derivs @ d.ravel())[..., None]], axis=-1)

    @staticmethod
    def _derivatives(ctx, points, axes):
        """Each reading's derivatives (K, M, 2, 3M) with respect to its sensor's angle, radius and axis angle, and
        the readings (K, M, 2), for sensors at `points` (R, M) with x axes at `axes` (R, M)."""
        pos = ctx.positions
        w = points[..., None] - (pos[:, 0] + 1j * pos[:, 1])  # (R, M, n)
        unit = MU0_OVER_2PI * 1j / np.conj(w)
        slope = -MU0_OVER_2PI * 1j / np.conj(w) ** 2  # dB/ds along u: slope · conj(u)
        cur = ctx.currents
        # the field the sensors sit in: the conductors' plus what accepted terms add (ctx.extra, a uniform
        # field to first order: its gradient is left out)
        b = np.einsum("kmn,kn->km", unit[ctx.rot_index], cur) + getattr(ctx, "extra", 0.0)
        g = np.einsum("kmn,kn->km", slope[ctx.rot_index], cur)
        sk = points[ctx.rot_index]
        rhat = sk / np.abs(sk)
        axes = axes[ctx.rot_index]
        deg = np.pi / 180.0
        d_angle = (g * np.conj(1j * sk) - 1j * b) * deg           # position moves along the ring, axes turn
        d_radius = g * np.conj(rhat) * 1e-3                         # per millimetre
        d_axis = -1j * b * deg                                      # axes turn about the normal
        m = points.shape[1]
        derivs = to_axes(np.stack([d_angle, d_radius, d_axis], axis=-1), axes[..., None])  # (K, M, 3, 2)
        out = np.zeros(b.shape + (2, m, 3))
        out[:, np.arange(m), :, np.arange(m), :] = derivs.transpose(1, 0, 3, 2)  # sensor i moves only itself
        # a common turn of the sensors is the cores turned the other way, a common radius the ring scaled (the cores'
        # positions and the gains with it): both are taken against their mean (left free, the fit had turned all six
        # sensors −1.4° and moved them 0.28 mm in, and the cores 0.06 mm off with them)
        out[..., :2] -= out[..., :2].mean(axis=-2, keepdims=True)
        return out.reshape(b.shape + (2, 3 * m)), to_axes(b, axes)

    @staticmethod
    def relinearised_at(coefficients):
        """Where to linearise next: the fitted displacement (M, 3). A first-order fit of 0.8 mm on a 12 mm ring
        left a remainder (4 nT, 0.3 σ per reading, thousands of readings) that a lay, then a near circuit and a
        0.58° tilt, took up."""
        c = np.array(coefficients, float)[:3 * (len(coefficients) // 3)].reshape(-1, 3)
        c[:, :2] -= c[:, :2].mean(axis=0)  # (a common angle or radius does nothing: their columns are centred)
        return c

    @classmethod
    def interpret(cls, coefficients) -> dict:
        """The sensor most out of place, against the others (their median: a common angle is the conductors turned,
        a common radius the gains, which the fit cannot tell from it — the JSON's raw radii read −0.29 mm on five
        sensors and +0.47 on the one 0.76 mm out): along the ring (°), radially (mm), its axes turned (°)."""
        c = SensorPositionError.relinearised_at(coefficients)  # (re-linearised: the remainder's coefficient last)
        if len(c) < 3:
            return {}
        off = c - np.median(c, axis=0)
        out = {}
        for j, key in enumerate(("position_angle", "position_radius", "position_axis")):
            i = int(np.argmax(np.abs(off[:, j])))
            out[f"{key}_sensor"], out[key] = i, float(off[i, j])
        return out

    @classmethod
    def typical(cls, n_sensors, rng):
        sign = lambda: rng.choice([-1.0, 1.0], n_sensors)  # noqa: E731
        return cls(sign() * rng.uniform(0.3, 0.7, n_sensors), sign() * rng.uniform(0.1e-3, 0.2e-3, n_sensors),
                   sign() * rng.uniform(0.5, 1.5, n_sensors))


@dataclass
class CableTilt(CableEffect):
    """The cable not square to the ring: its cores, straight and parallel, run along (tan τ cos ψ,
    tan τ sin ψ, 1) in the cable frame (`tilt_rad` τ towards `tilt_direction_deg` ψ). Each core's in-plane
    field at a sensor is the straight one times r² / (n (r² − (t·r)²/n²)), n² = 1 + tan²τ, t = tan τ (cos ψ,
    sin ψ) and r the sensor's offset from where the core crosses the sensor plane (exact for an infinite
    line). Typical: 2–5° (a cable clamped on a bench, a ring slipped on a conductor bar): the field changes
    by τ²/2, 0.06–0.4 %, tens of times the paper's noise at 10 A.

    Candidate, to second order in τ: the factor is 1 + c₁ cos 2φ + c₂ sin 2φ with φ the direction of r from
    the core and (c₁, c₂) = τ²/2 (cos 2ψ, sin 2ψ): two coefficients, linear. It turns with the cable, not
    with the ring, so the ring's turns tell it from the sensors' own errors. What a tilted cable also puts
    along the ring's axis, B_z, reaches the readings only through a sensor's z leakage (z_leakage)."""

    tilt_rad: float
    tilt_direction_deg: float = 0.0
    name = "cable_tilt"
    n_params = 2
    regime = "rotation"
    kind = "conductors"

    def unit_fields(self, points, positions) -> np.ndarray:
        pos = np.asarray(positions, float)
        w = np.asarray(points)[..., None] - (pos[:, 0] + 1j * pos[:, 1])
        t = np.tan(self.tilt_rad) * np.exp(1j * np.radians(self.tilt_direction_deg))
        n2 = 1.0 + abs(t) ** 2
        along = np.real(w * np.conj(t))  # t·r
        r2 = np.abs(w) ** 2
        return straight_unit_fields(points, pos) * (r2 / (np.sqrt(n2) * (r2 - along ** 2 / n2)))

    @classmethod
    def features(cls, ctx, alternative=None):
        pos = ctx.positions
        w = ctx.points[ctx.rot_index][..., None] - (pos[:, 0] + 1j * pos[:, 1])  # (K, M, n)
        unit = MU0_OVER_2PI * 1j / np.conj(w)
        turn = w ** 2 / np.abs(w) ** 2  # e^{2iφ}
        axes = ctx.axes[ctx.rot_index]
        cols = [to_axes(np.einsum("kmn,kn->km", unit * part, ctx.currents), axes) for part in (turn.real, turn.imag)]
        return np.stack(cols, axis=-1)

    @classmethod
    def interpret(cls, coefficients) -> dict:
        c = complex(*np.ravel(coefficients)[:2])  # tan²τ / 2 · e^{2iψ}
        return {"tilt_deg": float(np.degrees(np.arctan(np.sqrt(2.0 * abs(c))))),
                "tilt_direction_deg": float(np.mod(np.degrees(np.angle(c)) / 2.0, 180.0))}

    @classmethod
    def typical(cls, n_sensors, rng):
        return cls(float(np.radians(rng.uniform(2.0, 5.0))), float(rng.uniform(0.0, 360.0)))


@dataclass
class CableZLeakage(CableEffect):
    """Each in-plane axis of sensor i reads k[i, axis] × B_z, the field along the ring's axis: the Earth's
    `earth_z_t` (constant: the per-sensor calibration's offset removes it) plus the cable field's share
    when the cable is tilted by `tilt_rad` towards `tilt_direction_deg` (cable frame): B_z = τ t̂·B.
    Typical: k_z ±1–2 % (biaxial AMR / Hall packages), τ = 2–4° (a cable that is not square to the ring
    on a bench). (`fluxcal.sim.effects.ZLeakage` is the three-axis sensor's simulation-only version.)

    Candidate: per sensor axis, the tilt share B_z = t̂(ψ)·B of the fitted field in the cable frame, 2M
    coefficients k·τ (exact: the effect is linear in them); the tilt direction ψ is searched on a 15° grid
    over 180° (the sign goes into k), then fitted with the positions. The Earth's constant B_z is an
    offset, the calibration's: with the ring never turned, the tilt share is a fixed mix of each sensor's
    radial and tangential field, partly a gain — the turns of the ring are what tell it apart."""

    k: np.ndarray
    tilt_rad: float
    tilt_direction_deg: float = 0.0
    earth_z_t: float = 40e-6
    name = "z_leakage"
    n_params = 8  # 2 per sensor of the 4-sensor ring
    regime = "rotation"
    kind = "readings"
    refinable = True
    DIRECTIONS = np.arange(0.0, 180.0, 15.0)

    def readings(self, field_lab, axis_rad):
        """k ⊙ B_z (…, M, 2) for the true cable field `field_lab` (…, M) complex."""
        t = np.exp(1j * np.radians(self.tilt_direction_deg))
        bz = self.earth_z_t + self.tilt_rad * np.real(field_lab * np.conj(t))
        return np.asarray(self.k) * bz[..., None]

    @classmethod
    def features(cls, ctx, alternative=None):
        psi = 0.0 if alternative is None else alternative
        t = np.exp(1j * np.radians(psi))
        bz = np.real(ctx.field_lab * np.conj(t))  # (K, M)
        k, m = bz.shape
        out = np.zeros((k, m, 2, m, 2))
        for a in range(2):  # sensor i's axis a reads only its own B_z
            out[:, np.arange(m), a, np.arange(m), a] = bz
        return out.reshape(k, m, 2, 2 * m)

    @classmethod
    def alternatives(cls, ctx):
        return list(cls.DIRECTIONS)

    @staticmethod
    def encode(alternative) -> float:
        return float(np.radians(alternative))

    @staticmethod
    def decode(value) -> float:
        return float(np.degrees(value))

    @classmethod
    def describe(cls, alternative) -> dict:
        return {"tilt_direction_deg": None if alternative is None else float(np.mod(alternative, 180.0))}

    @classmethod
    def typical(cls, n_sensors, rng):
        return cls(rng.choice([-1.0, 1.0], (n_sensors, 2)) * rng.uniform(0.01, 0.02, (n_sensors, 2)),
                   float(np.radians(rng.uniform(2.0, 4.0))), float(rng.uniform(0.0, 360.0)))


@dataclass
class SensorCoupling(CableEffect):
    """Each sensor's two axes coupled: its x axis also reads c_x × the field along its y axis, and its y axis c_y ×
    the field along its x (`coupling` (M, 2)): axes not at right angles (an x axis tilted ε towards y: c_x = sin ε,
    c_y = 0), each axis turned on its own on the package, or crosstalk between the two channels. Typical (AMR and
    Hall packages, a board's assembly): ±0.5–2 % per axis (0.3–1.1°).

    Candidate: per sensor axis, the field along its other axis at the fitted positions: 2M linear coefficients. An
    equal and opposite pair c_x = −c_y is a turn of the sensor's axes, which sensor_position_error also holds (its
    axis angle); c_x ≠ −c_y is this effect's own, which a per-axis gain and offset cannot take (the calibration's
    TWOSTEP then leaves |h| varying with twice the angle of the field at the sensor)."""

    coupling: np.ndarray
    name = "sensor_coupling"
    n_params = 8  # 2 per sensor of the 4-sensor ring
    regime = "rotation"
    kind = "readings"

    def readings(self, field_lab, axis_rad):
        """c ⊙ (the field along the other axis) (…, M, 2) for the true cable field `field_lab` (…, M) complex."""
        return np.asarray(self.coupling) * to_axes(field_lab, axis_rad)[..., ::-1]

    @classmethod
    def features(cls, ctx, alternative=None):
        h = to_axes(ctx.field_lab, ctx.axes[ctx.rot_index])  # (K, M, 2) in each sensor's axes
        k, m, _ = h.shape
        out = np.zeros((k, m, 2, m, 2))
        for a in range(2):  # sensor i's axis a reads its own other axis's field
            out[:, np.arange(m), a, np.arange(m), a] = h[..., 1 - a]
        return out.reshape(k, m, 2, 2 * m)

    @classmethod
    def interpret(cls, coefficients) -> dict:
        """The largest coupling: its sensor (the diagnosed ring's numbering; the diagnosis renumbers it as the
        recording's), axis, c and the axis's tilt asin c."""
        c = np.ravel(coefficients)
        if not c.size:
            return {}
        k = int(np.argmax(np.abs(c)))
        pair = c[2 * (k // 2):2 * (k // 2) + 2]
        return {"coupling_sensor": k // 2, "coupling_axis": "xy"[k % 2], "coupling": float(c[k]),
                "coupling_deg": float(np.degrees(np.arcsin(np.clip(c[k], -1.0, 1.0)))),
                "coupling_pair": pair.tolist()}

    @classmethod
    def typical(cls, n_sensors, rng):
        return cls(rng.choice([-1.0, 1.0], (n_sensors, 2)) * rng.uniform(0.005, 0.02, (n_sensors, 2)))


@dataclass
class SensorNonlinearity(CableEffect):
    """Each sensor axis's reading bends with the field along it: h_a + c_a h_a³ / B_NONLINEAR² (`cubic` (M, 2), c_a
    the share added at B_NONLINEAR = 100 µT): an AMR bridge compresses towards its range (c < 0), a Hall sensor's
    or an amplifier's stage bends either way. Typical: −0.1 … −0.4 % at 100 µT (0.6–2.5 % at the paper ring's 250 µT
    at 10 A). The calibration at one current folds the bend at its field into the gains: what is left is cubic in
    the current, which no term linear in it (a tilt, a lay) follows across current levels.

    Candidate: per sensor axis, h_a³ / B_NONLINEAR² at the fitted positions and reference currents: 2M linear
    coefficients (not with currents fitted per snapshot: every other term is affine in them)."""

    cubic: np.ndarray
    name = "sensor_nonlinearity"
    n_params = 8  # 2 per sensor of the 4-sensor ring
    regime = "current"
    kind = "readings"
    B_NONLINEAR = 1e-4  # T: the field at which c is the share added
    affine = False

    def readings(self, field_lab, axis_rad):
        """c ⊙ h³ / B² (…, M, 2) for the true cable field `field_lab` (…, M) complex."""
        return np.asarray(self.cubic) * to_axes(field_lab, axis_rad) ** 3 / self.B_NONLINEAR ** 2

    @classmethod
    def not_applicable(cls, ctx) -> str | None:
        if ctx.fit_currents:
            return "it needs the reference currents (a bend cubic in the current does not follow currents fitted per snapshot)"
        return None

    @classmethod
    def features(cls, ctx, alternative=None):
        h = to_axes(ctx.field_lab, ctx.axes[ctx.rot_index])  # (K, M, 2) in each sensor's axes
        k, m, _ = h.shape
        out = np.zeros((k, m, 2, m, 2))
        for a in range(2):
            out[:, np.arange(m), a, np.arange(m), a] = h[..., a] ** 3 / cls.B_NONLINEAR ** 2
        return out.reshape(k, m, 2, 2 * m)

    @classmethod
    def interpret(cls, coefficients) -> dict:
        """The largest bend: its sensor (the diagnosed ring's numbering; the diagnosis renumbers it), axis and c."""
        c = np.ravel(coefficients)
        if not c.size:
            return {}
        k = int(np.argmax(np.abs(c)))
        return {"nonlinearity_sensor": k // 2, "nonlinearity_axis": "xy"[k % 2], "nonlinearity_at_100ut": float(c[k]),
                "nonlinearity_median_at_100ut": float(np.median(c))}

    @classmethod
    def typical(cls, n_sensors, rng):
        return cls(-rng.uniform(0.001, 0.004, (n_sensors, 2)))


@dataclass
class BackgroundField(CableEffect):
    """A field at the ring that does not follow the cable's currents and stays put in the cable (lab) frame while
    the ring turns: the Earth's in-plane field, a magnet's, a neighbouring cable or busbar on another circuit.
    `field_t` is its complex value (Bx + iBy, cable frame) at the ring's centre and `gradient_t` its change across
    the ring's radius R: B(z) = field_t + gradient_t · z̄ / R at the point z = x + iy (a current-free field is the
    conjugate of an analytic function of z; a conductor at distance d is this to first order in R/d, its gradient
    R/d of its field). Typical: 20–50 µT (the Earth's horizontal field, recorded without subtracting a
    zero-current snapshot); a neighbouring 10 A conductor 50 mm away: 40 µT.

    Candidate: the uniform field, 2 coefficients (tesla; `background_gradient` is its gradient, tried after it).
    It does not scale with the currents (`follows_current` False): the diagnosis holds it apart from the
    per-ampere terms, and needs the reference currents for it. Fixed to the ring instead, it would be the
    per-sensor calibration's offsets; the ring's turns tell the two apart."""

    field_t: complex
    gradient_t: complex = 0.0
    conductors: tuple = ()  # exact: (position x + iy in the cable frame, metres; current, A) of lines along the cable
    name = "background_field"
    n_params = 2
    regime = "rotation"
    kind = "background"
    follows_current = False

    def field(self, points, ring: Ring) -> np.ndarray:
        """The field (P,) complex, cable frame, at `points` (P,) complex."""
        z = np.asarray(points)
        out = self.field_t + self.gradient_t * np.conj(z) / ring.radius_m
        for where, current in self.conductors:
            out = out + MU0_OVER_2PI * current * 1j / np.conj(z - where)
        return out

    @classmethod
    def not_applicable(cls, ctx) -> str | None:
        if ctx.fit_currents:
            return ("it needs the reference currents (with currents fitted per snapshot, a field that does not "
                    "follow them is not told apart here)")
        return None

    @classmethod
    def shapes(cls, z):
        """The field's unit shapes at the points z (in ring radii), complex, cable frame."""
        return [np.ones_like(z), 1j * np.ones_like(z)]

    @classmethod
    def features(cls, ctx, alternative=None):
        z = ctx.points[ctx.rot_index] / ctx.ring.radius_m  # (K, M) in ring radii
        return np.stack([to_axes(b, ctx.axes[ctx.rot_index]) for b in cls.shapes(z)], axis=-1)

    @classmethod
    def interpret(cls, coefficients) -> dict:
        b = complex(*np.ravel(coefficients)[:2])
        return {"background_t": float(abs(b)), "background_direction_deg": float(np.mod(np.degrees(np.angle(b)), 360))}

    @classmethod
    def typical(cls, n_sensors, rng):
        return cls(rng.uniform(20e-6, 50e-6) * np.exp(1j * rng.uniform(0, 2 * np.pi)))


class BackgroundGradient(BackgroundField):
    """The change across the ring of a field that does not follow the currents (`BackgroundField`'s gradient_t):
    a source near the ring, a neighbouring conductor rather than the Earth. Candidate: B = g · z̄ / R, 2
    coefficients (tesla across the ring's radius), tried once the uniform part is found (alone it stands in
    for nothing a uniform field leaves). Simulated by `BackgroundField`; `typical` gives a neighbouring 5–20 A
    conductor 40–100 mm from the cable's axis."""

    name = "background_gradient"
    after = "background_field"  # tried once that is found: a term of a field's expansion, not a field of its own

    @classmethod
    def not_applicable(cls, ctx) -> str | None:
        if cls.after not in getattr(ctx, "accepted", ()):
            return f"tried once {cls.after} is found (its next term: alone, it stood in for other effects)"
        return super().not_applicable(ctx)

    @classmethod
    def shapes(cls, z):
        return [np.conj(z), 1j * np.conj(z)]

    @classmethod
    def interpret(cls, coefficients) -> dict:
        g = complex(*np.ravel(coefficients)[:2])
        return {"background_gradient_t": float(abs(g))}

    @classmethod
    def typical(cls, n_sensors, rng):
        d = rng.uniform(0.040, 0.100) * np.exp(1j * rng.uniform(0, 2 * np.pi))
        return BackgroundField(0.0, conductors=((d, rng.choice([-1.0, 1.0]) * rng.uniform(5.0, 20.0)),))


class BackgroundCurvature(BackgroundGradient):
    """The next term of a field that does not follow the currents: B = q · z̄² / R² (2 coefficients, tesla at the
    ring's radius). A conductor at distance d puts (R/d)² of its field here: 9 % at 3 ring radii, µT where the
    noise is tenths of one. Tried once the gradient is found; simulated as a conductor (`BackgroundGradient`)."""

    name = "background_curvature"
    after = "background_gradient"

    @classmethod
    def shapes(cls, z):
        return [np.conj(z) ** 2, 1j * np.conj(z) ** 2]

    @classmethod
    def interpret(cls, coefficients) -> dict:
        return {"background_curvature_t": float(abs(complex(*np.ravel(coefficients)[:2])))}


IRON_TERMS = 4  # of the outside sources' series: a plate 2 ring radii away left 3.7 σ after three


@dataclass
class NearbyIron(CableEffect):
    """Iron near the ring — a steel plate, a cable tray, an enclosure's wall, a bench's frame — magnetised by the
    cores' own field: a field that follows the currents yet stays put in the cable (lab) frame as the ring turns,
    its sources outside the ring. Simulated as a permeable plane `distance_m` from the cable's axis, its normal
    towards `direction_deg` (cable frame): each core's image in the plane, carrying `factor` × its current
    ((μr − 1)/(μr + 1), about 1 for steel). Typical: a plate 2–5 ring radii away, factor 0.5–1.

    Candidate: per core j, the first IRON_TERMS terms of a field from sources outside the ring, I_j · c_nj · z̄ⁿ/Rⁿ
    (n = 0 … 3; 8 coefficients per core, tesla per 10 MA: the scale of the other terms) — any iron's, to (R/d)⁴ for
    a part d away. Sources inside the ring (a lay, a tilt) are the other harmonics (1/z̄ⁿ); a sensor's errors
    turn with the ring; a field of its own (background_field) does not follow the currents. A finite bench rig's
    field (finite_length) is a special case, tried first with its one coefficient. The fit is not held to the
    calibration run: a jig away from the iron, as the blind check that found the defect (an iron plate 3 ring
    radii away had been named z_leakage, a 2.7° tilt and a sensor position error, all confidently)."""

    distance_m: float
    direction_deg: float = 0.0
    factor: float = 1.0
    name = "nearby_iron"
    n_params = 2 * IRON_TERMS
    regime = "rotation"
    kind = "conductors"
    surroundings = True  # not in the calibration run (cable_trial), as a background field
    contains = ("finite_length",)  # a special case, preferred when it explains the recording (diagnose's _specific_first)

    def images(self, positions) -> np.ndarray:
        """The cores' images in the plane (n,) complex, cable frame."""
        p = np.asarray(positions, float)
        z = p[:, 0] + 1j * p[:, 1]
        normal = np.exp(1j * np.radians(self.direction_deg))
        return z + 2.0 * (self.distance_m - np.real(z * np.conj(normal))) * normal

    def unit_fields(self, points, positions) -> np.ndarray:
        pts = np.asarray(points)
        direct = straight_unit_fields(pts, np.asarray(positions, float))
        w = self.images(positions)
        return direct + self.factor * MU0_OVER_2PI * 1j / np.conj(pts[..., None] - w)

    @classmethod
    def features(cls, ctx, alternative=None):
        z = ctx.points[ctx.rot_index] / ctx.ring.radius_m  # (K, M) in ring radii
        powers = [np.conj(z) ** n for n in range(IRON_TERMS)]
        axes = ctx.axes[ctx.rot_index]
        cols = []
        for j in range(ctx.currents.shape[1]):
            for n in range(IRON_TERMS):
                for unit in (1.0, 1j):
                    cols.append(to_axes(1e-7 * ctx.currents[:, j, None] * unit * powers[n], axes))
        return np.stack(cols, axis=-1)

    @classmethod
    def field_share(cls, ctx, feats, coefficients) -> dict:
        """Its field at the sensors against the cores' (RMS over the recording)."""
        added = feats @ np.asarray(coefficients, float)
        cores = to_axes(ctx.field_lab, ctx.axes[ctx.rot_index])
        return {"iron_field_share": float(np.sqrt(np.mean(added ** 2) / max(np.mean(cores ** 2), 1e-300)))}

    @classmethod
    def typical(cls, positions, rng, radius_m: float = 0.01):
        return cls(float(rng.uniform(2.0, 5.0)) * radius_m, float(rng.uniform(0, 360)), float(rng.uniform(0.5, 1.0)))


CABLE_CANDIDATES = (HelicalLay, FiniteLength, SensorPositionError, CableTilt, CableZLeakage, SensorCoupling,
                    SensorNonlinearity, BackgroundField, BackgroundGradient, BackgroundCurvature, NearbyIron)
"""The cable candidates by name: helical_lay, finite_length, sensor_position_error, cable_tilt, z_leakage,
sensor_coupling, sensor_nonlinearity, background_field, background_gradient, background_curvature, nearby_iron."""


# ---------------------------------------------------------------- a rig with effects

@dataclass
class EffectRig(CableRig):
    """A `CableRig` whose true field comes from `effects` (instances of the classes above): `ideal` is the
    field the sensors really see, `nominal` what the ring's model says (straight infinite cores, sensors
    on the drawing). `read` adds the sensor errors of `errors` as CableRig does (gain, hard iron, drift
    wire, moving iron, noise; the in-plane Earth field is taken as removed), and k_z B_z of a
    `CableZLeakage` effect."""

    effects: list = field(default_factory=list)
    _cache: dict = field(default_factory=dict, repr=False)  # per rotation: the sensors' unit fields and axes
    without_background: bool = False  # the calibration run: a background field is not there (see cable_trial)

    def _one(self, kind):
        found = [e for e in self.effects if e.kind == kind]
        if len(found) > 1:
            raise ValueError(f"effects: {len(found)} effects of kind {kind!r} ({', '.join(e.name for e in found)}); "
                             f"one at a time")
        return found[0] if found else None

    def true_fields(self, rotation_deg, currents_a):
        """(n_rot, M) complex lab field at the real sensors and (n_rot, M) their x-axis directions."""
        conductors, sensors = self._one("conductors"), self._one("sensors")
        if self.without_background and getattr(conductors, "surroundings", False):
            conductors = None  # (iron in the room, not at the calibration's jig)
        background = None if self.without_background else self._one("background")
        fields, axes = [], []
        cur = np.asarray(currents_a, float)
        for rot in np.atleast_1d(np.asarray(rotation_deg, float)):
            key = (float(rot), tuple(id(e) for e in self.effects), np.asarray(self.positions_m, float).tobytes(),
                   conductors is None)
            if key not in self._cache:  # the segment sums are the cost: once per rotation
                pts, ax = (sensors.sensors(self.ring, rot) if sensors else sensor_points(self.ring, rot))
                unit = (conductors.unit_fields(pts, self.positions_m) if conductors
                        else straight_unit_fields(pts, np.asarray(self.positions_m, float)))
                self._cache[key] = (unit, ax)
            unit, ax = self._cache[key]
            fields.append(unit @ cur)
            axes.append(ax)
            if background is not None:
                pts = sensors.sensors(self.ring, rot)[0] if sensors else sensor_points(self.ring, rot)[0]
                fields[-1] = fields[-1] + background.field(pts, self.ring)
        return np.array(fields), np.array(axes)

    def ideal(self, rotation_deg, currents_a) -> np.ndarray:
        b, ax = self.true_fields(rotation_deg, currents_a)
        return to_axes(b, ax)

    def nominal(self, rotation_deg, currents_a) -> np.ndarray:
        """What the ring's model says: (n_rot, M, 2)."""
        rot = np.atleast_1d(np.asarray(rotation_deg, dtype=float))
        return np.stack([self.ring.rotated(a).field(self.positions_m, currents_a) for a in rot])

    def read(self, rotation_deg, currents_a, rng=None, repeats: int = 1) -> np.ndarray:
        rot = np.atleast_1d(np.asarray(rotation_deg, dtype=float))
        e = self.errors
        b, ax = self.true_fields(rot, currents_a)
        h = to_axes(b, ax)
        h = h + np.einsum("mij,rmj->rmi", e.ferro, h)
        clean = e.gain * (h + e.wire_field() + e.hard_iron)
        leak = self._one("readings")
        if leak is not None:
            clean = clean + leak.readings(b, ax)
        clean = np.repeat(clean, repeats, axis=0)
        if rng is not None:
            clean = clean + rng.standard_normal(clean.shape) * e.noise_sigma[None, :, None]
        return clean


def make_effect(name: str, rig: CableRig, rng):
    """An effect of the named class at a typical magnitude for `rig`."""
    by_name = {c.name: c for c in CABLE_CANDIDATES}
    if name not in by_name:
        raise ValueError(f"names: unknown cable effect {name!r}; known: {', '.join(by_name)}")
    cls = by_name[name]
    if cls in (HelicalLay, FiniteLength):
        return cls.typical(rig.positions_m, rng)
    if cls is NearbyIron:
        return cls.typical(rig.positions_m, rng, rig.ring.radius_m)
    return cls.typical(rig.ring.n_sensors, rng)


#: The diagnosis recording of `cable_trial`: the ring turned in 45° steps; at each step three current
#: levels in three patterns — go and return through the ring (I, −I), and each core alone (I, 0), (0, I)
#: with the current returning outside the ring — both polarities, two snapshots each.
TRIAL_ROTATIONS_DEG = np.arange(0.0, 360.0, 45.0)
TRIAL_LEVELS_A = (2.0, 5.0, 10.0)
TRIAL_PATTERNS = ((1.0, -1.0), (1.0, 0.0), (0.0, 1.0))


def cable_trial(names, seed: int, rotations_deg=TRIAL_ROTATIONS_DEG, levels_a=TRIAL_LEVELS_A,
                patterns=TRIAL_PATTERNS, repeats: int = 2, calibration_repeats: int = 50,
                calibration_current_a: float = 5.0, effects=None):
    """Withheld-effect trial of the cable diagnosis: the paper's rig (4 sensors on 10 mm, the paper's
    sensor errors and noise σ 1–2e-8 T, cores of PAPER_POSITIONS_M) with the named effects at typical
    magnitudes (or `effects`, instances), calibrated as the paper does (5 × 72°, ±5 A equal and opposite,
    `calibration_repeats` snapshots each) against the ring's model — which knows nothing of the effects —
    then recorded at `rotations_deg` × `levels_a` × `patterns` × both polarities × `repeats` (in that
    order in time). Returns (keyword arguments of `diagnose_cable`, the rig)."""
    from ..cable import calibrate_ring
    from .cable import paper_rig

    rng = np.random.default_rng(seed)
    base = paper_rig(rng)
    rig = EffectRig(ring=base.ring, positions_m=base.positions_m, errors=base.errors)
    rig.effects = list(effects) if effects is not None else [make_effect(n, rig, rng) for n in names]
    cal_raw, cal_truth = [], []
    # a background field is not in the calibration run (a jig away from it, or each pose's zero-current reading
    # subtracted): the per-sensor calibration's model has no place for it
    rig.without_background = True
    for rot in (72.0 * np.arange(5)):
        for cur in reference_currents(calibration_current_a):
            cal_raw.append(rig.read([rot], cur, rng, repeats=calibration_repeats))
            cal_truth.append(np.repeat(rig.nominal([rot], cur), calibration_repeats, axis=0))
    rig.without_background = False
    calibration = calibrate_ring(np.concatenate(cal_raw), np.concatenate(cal_truth))
    raw, rots, curs = [], [], []
    for rot in np.atleast_1d(rotations_deg):
        for level in levels_a:
            for pattern in patterns:
                for sign in (1.0, -1.0):
                    cur = sign * level * np.asarray(pattern, float)
                    raw.append(rig.read([rot], cur, rng, repeats=repeats))
                    rots += [rot] * repeats
                    curs += [cur] * repeats
    kwargs = {"readings": np.concatenate(raw), "ring": rig.ring, "currents": np.array(curs),
              "rotations_deg": np.array(rots), "positions": np.asarray(rig.positions_m, float),
              "calibration": calibration}
    return kwargs, rig
