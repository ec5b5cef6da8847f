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
from the median by more than `max_dynamic` (5 %) are left out as moving. Least squares on the dip residual
d·Rĥ − sin δ is the maximum-likelihood estimate for direction noise (its variance is the same for every
reading); `covariance` is σ̂²(JᵀJ)⁻¹ of (small rotations about the accelerometer's x, y, z; δ), radians².
Readings correlated in time (a slow hand turn logged at 100 Hz) make that too small, as for any least-squares
fit that counts them as independent: when the dip residuals of consecutive rows correlate (lag-1 ρ > 0.2) the
covariance is widened by the AR(1) factor (1 + ρ)/(1 − ρ) — what it is for regressors that change slowly
against the noise — and a warning says so (serial_correlation="independent" when the rows are not in time order).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import _core
from ._arrays import as_samples, as_specific_force, require_calibration, set_options
from .calibration import Calibration


@dataclass
class Alignment:
    """R (magnetometer → accelerometer frame, h_acc = R h) and the dip, with their uncertainty."""

    rotation: np.ndarray
    dip_deg: float
    covariance: np.ndarray            # (rotation about x, y, z; dip), radians²
    identifiable: bool
    readings_used: int
    residual_rms_deg: float           # RMS of d·Rĥ − sin δ, as an angle (divided by cos δ)
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


SERIAL_LIMIT = 0.2  # lag-1 autocorrelation of the dip residuals above which the covariance is widened, when it is
# also significant (above 2/√pairs: independent readings pass it 2.5 % of the time; 24 shots reach 0.2 by chance)


def _lag1(residuals: np.ndarray) -> tuple[float, int]:
    """Lag-1 autocorrelation over consecutive rows both kept (NaN: left out as moving), and how many pairs."""
    e = residuals - np.nanmean(residuals)
    pairs = np.isfinite(e[1:]) & np.isfinite(e[:-1])
    if pairs.sum() < 10:
        return 0.0, int(pairs.sum())
    return float(np.sum(e[1:][pairs] * e[:-1][pairs]) / np.nansum(e ** 2)), int(pairs.sum())


def align_to_gravity(field, specific_force, serial_correlation: str = "automatic",
                     acc_measures: str = "specific_force", **settings) -> Alignment:
    """R and the dip from calibrated fields `field` (N×3, e.g. `cal.apply(m)`) and the accelerometer's rows
    `specific_force` (N×3, the same instants, in time order; any unit; `acc_measures="gravity"` for an instrument
    that reports the down direction, as the SAP6 survey units do). `serial_correlation`: "automatic" widens the
    covariance when consecutive rows' residuals correlate (module docstring), "independent" never.

    settings (defaults in alignment.hpp): max_dynamic=0.05, max_iterations=50, tolerance=1e-12,
    noise_bias_correction=True (the dip's ≈ −σ² tan δ), max_se_deg=1.0 (an axis known worse is "not determined":
    identifiable False, with a warning naming it). ValueError on NaN, rows that differ, fewer than 8 readings at
    rest."""
    if serial_correlation not in ("automatic", "independent"):
        raise ValueError(f"serial_correlation: {serial_correlation!r}, need 'automatic' or 'independent'")
    h = as_samples(field, "field")
    f = as_specific_force(specific_force, acc_measures, "specific_force")
    options = set_options(_core.AlignmentOptions(), settings, "align_to_gravity")
    r = _core.align_to_gravity(h, f, options)
    dip, covariance, summary = float(r["dip"]), np.asarray(r["covariance"]), dict(r["summary"])
    identifiable = bool(r["identifiable"])
    rho, pairs = _lag1(np.asarray(r["residuals"])) if serial_correlation == "automatic" else (0.0, 0)
    if rho > max(SERIAL_LIMIT, 2 / np.sqrt(max(pairs, 1))):
        factor = (1 + rho) / (1 - rho) if rho < 1 else np.inf
        covariance = covariance * factor
        summary["warnings"] = list(summary["warnings"]) + [
            f"readings are correlated in time (lag-1 autocorrelation {rho:.2f} of the dip residuals): standard "
            f"errors widened {np.sqrt(factor):.3g}x (AR(1)); rows must be in time order "
            "(serial_correlation='independent' when they are not)"]
        se_deg = np.degrees(np.sqrt(np.maximum(np.diag(covariance), 0.0)))
        widened_out = [name for name, se in zip(("the rotation about x", "the rotation about y",
                                                 "the rotation about z", "the dip"), se_deg)
                       if se > options.max_se_deg] if identifiable else []
        if widened_out:
            identifiable = False
            summary["warnings"].append(f"not identifiable: {', '.join(widened_out)} not determined to "
                                       f"{options.max_se_deg:g}° once the standard errors are widened for the "
                                       "correlation in time (more readings, or turns about more axes)")
        rotation_deg = float(np.degrees(np.linalg.norm(np.asarray(r["rotation_vector"]))))
        summary["message"] = (f"magnetometer to accelerometer: {rotation_deg:.6g}° rotation, dip "
                              f"{np.degrees(dip):.6g}° (±{se_deg[3]:.6g}°), {int(r['readings_used'])} static readings")
    summary["serial_correlation"] = {"lag1": rho, "mode": serial_correlation}
    return Alignment(rotation=np.asarray(r["rotation"]), dip_deg=float(np.degrees(dip)), covariance=covariance,
                     identifiable=identifiable, readings_used=int(r["readings_used"]),
                     residual_rms_deg=float(np.degrees(r["residual_rms"] / max(np.cos(dip), 1e-12))),
                     summary=summary)
