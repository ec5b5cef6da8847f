"""The magnetometer's axes turned onto the accelerometer's, from the dip (cpp/include/fluxcal/alignment.hpp).

A calibration from field magnitudes (`calibrate`, `twostep`) is right up to a rotation: it cannot see how the
magnetometer's axes sit against the accelerometer's, and a tilt-compensated compass is off by that rotation.
At rest the angle between gravity and the Earth field is the same in every attitude, so readings of a turned
device fix the rotation R (magnetometer frame → accelerometer frame) and the dip δ together (dot-product
invariance):

    from fluxcal.alignment import align_to_gravity
    a = align_to_gravity(cal.apply(mag), acc)      # calibrated field, accelerometer rows (any units)
    print(a.rotation_deg, a.dip_deg, a.dip_se_deg, a.identifiable)
    aligned = a.calibration(cal)                   # h = R A (m − b): the field in the accelerometer's axes

The accelerometer reads the specific force (at rest +1 g up; `acc_measures="gravity"` for one that reports the
down direction), so down = −f/|f|; readings whose |f| departs
from the median by more than `max_dynamic` (5 %) are left out as moving. Least squares on the dip each reading
shows, atan2(d·Rĥ, |d × Rĥ|) − δ, is the maximum-likelihood estimate for direction noise (its variance is the same
for every reading at any dip, and unlike the cosine d·Rĥ − sin δ its fit is not biased by attitudes spread
unevenly, as a hand turn's are); `covariance` is σ̂² H⁻¹ JᵀJ H⁻¹ of (small rotations about the accelerometer's x,
y, z; δ), radians², H the cost's Hessian — σ̂²(JᵀJ)⁻¹ where the attitudes are spread, and honest where they barely
move about one axis (a probe rolled about its length: the noise in J had lent JᵀJ information there that the data do
not hold, SEs of 0.5° for errors of 30°).
Readings correlated in time (a slow hand turn logged at 100 Hz) make that too small, as for any least-squares
fit that counts them as independent: as `fluxcal.refine`, when the dip residuals fail a Ljung–Box test and the
Newey–West sandwich (AR(1)-prewhitened, over the scores J_kᵀe_k) widens an error, or when it widens one ≥ 1.5×,
the covariance is the sandwich and a warning says so (serial_correlation="independent" when the rows are not in
time order; then nothing can see the correlation).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import _core
from ._arrays import as_samples, as_specific_force, require_calibration, set_options
from .calibration import Calibration
from .refine import serial_correlation_mode


@dataclass
class Alignment:
    """R (magnetometer → accelerometer frame, h_acc = R h) and the dip, with their uncertainty."""

    rotation: np.ndarray
    dip_deg: float
    covariance: np.ndarray            # (rotation about x, y, z; dip), radians²
    identifiable: bool
    readings_used: int
    residual_rms_deg: float           # RMS of the dip each reading shows less δ: the direction noise
    summary: dict = field(default_factory=dict)

    @property
    def rotation_vector_deg(self) -> np.ndarray:
        """R as axis × angle (degrees, accelerometer frame)."""
        from scipy.spatial.transform import Rotation

        return np.degrees(Rotation.from_matrix(self.rotation).as_rotvec())

    @property
    def rotation_deg(self) -> float:
        """The angle of R (degrees)."""
        return float(np.linalg.norm(self.rotation_vector_deg))

    @property
    def rotation_se_deg(self) -> np.ndarray:
        """Standard errors of small rotations about the accelerometer's x, y, z (degrees)."""
        return np.degrees(np.sqrt(np.maximum(np.diag(self.covariance)[:3], 0.0)))

    @property
    def dip_se_deg(self) -> float:
        return float(np.degrees(np.sqrt(max(self.covariance[3, 3], 0.0))))

    def apply(self, field) -> np.ndarray:
        """Calibrated fields (N×3, magnetometer axes) in the accelerometer's axes."""
        return as_samples(field, "field") @ self.rotation.T

    def calibration(self, cal: Calibration) -> Calibration:
        """`cal` with R folded into its matrix, h = R A (m − b): its output in the accelerometer's axes. An
        alignment the data did not determine, or that did not converge, makes the result so too (its summary's
        identifiable / converged, with the reason among the warnings): export-c refuses it, calibrate exits 3."""
        require_calibration(cal, "cal")
        summary = {**cal.summary, "alignment": self.to_dict()}
        if not self.identifiable or not self.summary.get("converged", True):
            summary["warnings"] = list(cal.summary.get("warnings", [])) + [
                f"alignment to the accelerometer: {w}" for w in self.summary.get("warnings", [])
                if "identif" in w or "converge" in w]
            summary["identifiable"] = bool(cal.summary.get("identifiable", True)) and self.identifiable
            summary["converged"] = bool(cal.summary.get("converged", True)) and bool(self.summary.get("converged"))
        return Calibration(offset=cal.offset.copy(), matrix=self.rotation @ cal.matrix, field_norm=cal.field_norm,
                           units=cal.units, model=cal.model, summary=summary, field_units=cal.field_units,
                           metadata={**cal.metadata, "frame": "accelerometer axes (fluxcal.alignment)"})

    def to_dict(self) -> dict:
        return {"rotation": self.rotation.tolist(), "rotation_deg": self.rotation_deg,
                "rotation_vector_deg": self.rotation_vector_deg.tolist(),
                "rotation_se_deg": self.rotation_se_deg.tolist(), "dip_deg": self.dip_deg,
                "dip_se_deg": self.dip_se_deg, "identifiable": self.identifiable,
                "readings_used": self.readings_used, "residual_rms_deg": self.residual_rms_deg,
                "warnings": list(self.summary.get("warnings", []))}


# A rotation from the magnetometer's axes to the accelerometer's beyond this is a labelling, not a mounting error (a
# blind check: a mirrored axis in the southern hemisphere came back as a 178.8° turn, identifiable, with no word)
LABELLED_TURN_DEG = 90.0


def align_to_gravity(field, specific_force, serial_correlation: str = "automatic",
                     acc_measures: str = "specific_force", **settings) -> Alignment:
    """R and the dip from calibrated fields `field` (N×3, e.g. `cal.apply(m)`) and the accelerometer's rows
    `specific_force` (N×3, the same instants, in time order; any unit; `acc_measures="gravity"` for an instrument
    that reports the down direction, as the SAP6 survey units do). `serial_correlation`: "automatic" takes the
    Newey–West covariance when the readings are correlated in time (module docstring), "independent" never,
    "newey_west" always; summary["serial_correlation"] says what the residuals showed (lag-1, Ljung–Box p,
    Newey–West lags, 0 = independent readings assumed, and the widening).

    settings (defaults in alignment.hpp): max_dynamic=0.05 (≤ 0: every reading kept), max_iterations=50,
    tolerance=1e-12, noise_bias_correction=True (the dip's ≈ −σ²/2 · tan δ), max_se_deg=1.0 (an axis known worse is "not determined":
    identifiable False, with a warning naming it). ValueError on NaN, rows that differ, fewer than 8 readings at
    rest."""
    h = as_samples(field, "field")
    f = as_specific_force(specific_force, acc_measures, "specific_force")
    for name, rows in (("field", h), ("specific_force", f)):
        # (a blind check: 50 identical readings came back identifiable, every standard error 0)
        if len(rows) > 1 and np.all(np.ptp(rows, axis=0) == 0):
            raise ValueError(f"{name}: all {len(rows)} readings are the same ({', '.join(f'{v:g}' for v in rows[0])}): "
                             "one attitude, or a sensor that did not update — align_to_gravity needs readings of the "
                             "device at rest in several attitudes")
    options = set_options(_core.AlignmentOptions(), {**settings, "serial_correlation":
                                                     serial_correlation_mode(serial_correlation)}, "align_to_gravity")
    r = _core.align_to_gravity(h, f, options)
    dip, summary = float(r["dip"]), dict(r["summary"])
    summary["serial_correlation"] = {**r["serial_correlation"], "mode": options.serial_correlation.name}
    result = Alignment(rotation=np.asarray(r["rotation"]), dip_deg=float(np.degrees(dip)),
                       covariance=np.asarray(r["covariance"]), identifiable=bool(r["identifiable"]),
                       readings_used=int(r["readings_used"]),
                       residual_rms_deg=float(np.degrees(r["residual_rms"])),
                       summary=summary)
    if result.rotation_deg > LABELLED_TURN_DEG:
        summary["warnings"] = list(summary.get("warnings", [])) + [
            f"R turns the magnetometer's axes by {result.rotation_deg:.0f}° onto the accelerometer's: no mounting error "
            "is that large — the axes are labelled differently (two swapped, or signs reversed; a mirror image, one "
            "axis reversed, reads as a turn of about 180° with the dip's sign changed, which no rotation undoes): check "
            "the axes' order and signs against the datasheets"]
    return result
