"""Simulation of the cable-current ring (seed 000, Song et al. 2017, §3.1) and of the effects its
authors name as unmodelled.

    rig = sim.cable.paper_rig(rng)                       # 4 sensors, the paper's error magnitudes
    raw = rig.read(rotation_deg=72.0, currents_a=[5, -5], rng=rng)   # (4, 2) raw readings, tesla

Every reading of sensor i, in its own axes (x radial, y tangential at rotation 0):
    ĥ = γ ⊙ ((I + K) (h_cable + h_earth) + h_wire + b_hard) + k_z B_z + noise
  h_cable   Biot–Savart field of the cable's conductors (fluxcal.cable.Ring.field)
  h_earth   the Earth's horizontal field, fixed in the lab: it turns in the sensor frame as the ring turns
  h_wire    the paper's "thin wire with 1 mA near each sensor" (zero drift): fixed to the ring, a
            constant field in the sensor frame
  b_hard    hard iron (the paper's 0.0035, read as gauss: 3.5e-7 T)
  γ         scale factor r ∈ [1, 1.02] times (1 + soft iron) per axis (the paper's merged γ)
  K         ferromagnetic parts moving with the ring: a small full 2×2 matrix (its off-diagonal part is
            what the per-axis model cannot absorb)
  k_z B_z   z-axis leakage: B_z = Earth's vertical field + tilt × the cable field's lab-x component (a
            cable not perpendicular to the ring)
  noise     white, σ per sensor in [1e-8, 2e-8] T (the paper's [0.0001, 0.0002], read as gauss)
Units: the paper gives no units for b, σ or the field; reading them as gauss (1e-4 T) makes the
paper's numbers consistent (hard iron 0.0035 + the 1 mA wire's field 0.0015 = its "true" b of 0.005).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..cable import MU0_OVER_2PI, Ring

GAUSS = 1e-4  # tesla


@dataclass
class CableSensorErrors:
    """Per-sensor error terms of a ring of M biaxial sensors (see the module docstring)."""

    gain: np.ndarray          # (M, 2) γ: scale factor × (1 + soft iron)
    hard_iron: np.ndarray     # (M, 2) tesla, sensor axes
    wire_offset_m: np.ndarray  # (M, 2) position of the 1 mA drift wire relative to the sensor, sensor axes
    wire_current_a: float = 1e-3
    noise_sigma: np.ndarray = None  # (M,) tesla
    ferro: np.ndarray = None        # (M, 2, 2) K, moving with the ring
    z_leakage: np.ndarray = None    # (M, 2) k_z per axis

    def __post_init__(self):
        m = self.gain.shape[0]
        if self.noise_sigma is None:
            self.noise_sigma = np.zeros(m)
        if self.ferro is None:
            self.ferro = np.zeros((m, 2, 2))
        if self.z_leakage is None:
            self.z_leakage = np.zeros((m, 2))

    def wire_field(self) -> np.ndarray:
        """(M, 2) field of each drift wire at its sensor, sensor axes (a wire along +z at offset δ)."""
        d = -self.wire_offset_m  # sensor − wire
        q = (d**2).sum(axis=1, keepdims=True)
        return MU0_OVER_2PI * self.wire_current_a * np.column_stack([-d[:, 1], d[:, 0]]) / q

    def true_offset(self) -> np.ndarray:
        """The offset b of TWOSTEP's model ĥ = γ ⊙ h + b: γ ⊙ (hard iron + wire field), reading units."""
        return self.gain * (self.hard_iron + self.wire_field())


@dataclass
class CableRig:
    """A ring around a cable with its sensor errors and the lab it sits in."""

    ring: Ring
    positions_m: np.ndarray  # (N, 2) conductors
    errors: CableSensorErrors
    earth_field_t: np.ndarray = field(default_factory=lambda: np.zeros(3))  # lab frame (x east, y, z along the cable)
    cable_tilt_rad: float = 0.0

    def ideal(self, rotation_deg, currents_a) -> np.ndarray:
        """The true cable field (n_rot, M, 2) at each rotation (no errors, no Earth field)."""
        rot = np.atleast_1d(np.asarray(rotation_deg, dtype=float))
        return np.stack([self.ring.rotated(a).field(self.positions_m, currents_a) for a in rot])

    def earth_in_sensor_axes(self, rotation_deg) -> np.ndarray:
        """(n_rot, M, 2) the lab-fixed horizontal Earth field in each sensor's axes."""
        rot = np.atleast_1d(np.asarray(rotation_deg, dtype=float))
        a = np.radians(self.ring.angles_deg + self.ring.axis_angles_deg)[None, :] + np.radians(rot)[:, None]
        ex, ey = self.earth_field_t[0], self.earth_field_t[1]
        return np.stack([ex * np.cos(a) + ey * np.sin(a), -ex * np.sin(a) + ey * np.cos(a)], axis=-1)

    def read(self, rotation_deg, currents_a, rng=None, repeats: int = 1) -> np.ndarray:
        """Raw readings (n_rot · repeats, M, 2) at each rotation (outer) with `repeats` noisy samples
        (inner); (M, 2) for a scalar rotation and one repeat."""
        scalar = np.ndim(rotation_deg) == 0 and repeats == 1
        rot = np.atleast_1d(np.asarray(rotation_deg, dtype=float))
        e = self.errors
        h_cable = self.ideal(rot, currents_a)
        h = h_cable + self.earth_in_sensor_axes(rot)
        h = h + np.einsum("mij,rmj->rmi", e.ferro, h)
        # B_z: the Earth's vertical field + the tilt's share of the cable field (lab x component)
        a = np.radians(self.ring.angles_deg + self.ring.axis_angles_deg)[None, :] + np.radians(rot)[:, None]
        cable_lab_x = h_cable[..., 0] * np.cos(a) - h_cable[..., 1] * np.sin(a)
        bz = self.earth_field_t[2] + self.cable_tilt_rad * cable_lab_x
        clean = e.gain * (h + e.wire_field() + e.hard_iron) + e.z_leakage * bz[..., None]
        clean = np.repeat(clean, repeats, axis=0)
        if rng is not None:
            clean = clean + rng.standard_normal(clean.shape) * e.noise_sigma[None, :, None]
        return clean[0] if scalar else clean


def paper_errors(n_sensors: int, rng, soft_iron: float = 0.02, hard_iron_t: float = 0.0035 * GAUSS,
                 noise_range_t=(0.0001 * GAUSS, 0.0002 * GAUSS), ferro: float = 0.0, z_leakage: float = 0.0,
                 wire_field_t: float = 0.0015 * GAUSS) -> CableSensorErrors:
    """The paper's sensor errors: hard iron 0.0035 G per axis, a 1 mA wire placed to add `wire_field_t`
    per axis (0.0015 G: the paper's true b of 0.005), gain r ∈ [1, 1.02] × (1 + soft_iron) per axis (the
    paper's merged factors 1.0302/1.0296 need ~2 % soft iron on top of r), noise σ ∈ [1e-4, 2e-4] G per
    sensor; optionally moving ferromagnetic parts (random full K with entries ~ `ferro`) and z leakage
    (k_z ~ `z_leakage`)."""
    m = n_sensors
    r = rng.uniform(1.0, 1.02, size=(m, 2))
    gain = r * (1.0 + soft_iron)
    # a wire along +z at δ gives μ0I/(2π|δ|²)·(−δy... ) at the sensor; put it where it adds +w on both axes
    target = np.array([wire_field_t, wire_field_t])
    dist = MU0_OVER_2PI * 1e-3 / np.linalg.norm(target)
    # field at the sensor from a wire at δ: k (δy, −δx)/|δ|² (d = −δ); want its direction along target
    direction = target / np.linalg.norm(target)
    delta = dist * np.array([-direction[1], direction[0]])
    wires = np.tile(delta, (m, 1))
    return CableSensorErrors(gain=gain, hard_iron=np.full((m, 2), hard_iron_t), wire_offset_m=wires,
                             noise_sigma=rng.uniform(*noise_range_t, size=m),
                             ferro=ferro * rng.standard_normal((m, 2, 2)),
                             z_leakage=z_leakage * rng.standard_normal((m, 2)))


#: The paper's cable as assumed here: two conductors 4 mm apart, off-centre in the 8 mm bore.
PAPER_POSITIONS_M = np.array([[-1.7e-3, 0.4e-3], [2.3e-3, 0.1e-3]])


def paper_rig(rng, ring: Ring | None = None, positions_m=None, earth_field_t=None, cable_tilt_rad: float = 0.0,
              **errors) -> CableRig:
    """The paper's setup (assumptions where it is silent): 4 sensors at 90° on a 10 mm radius, the cable
    of PAPER_POSITIONS_M, the sensor errors of `paper_errors(**errors)`, no Earth field unless given."""
    ring = ring or Ring([0, 90, 180, 270], 0.010)
    pos = PAPER_POSITIONS_M if positions_m is None else np.asarray(positions_m, float)
    return CableRig(ring=ring, positions_m=pos, errors=paper_errors(ring.n_sensors, rng, **errors),
                    earth_field_t=np.zeros(3) if earth_field_t is None else np.asarray(earth_field_t, float),
                    cable_tilt_rad=cable_tilt_rad)
