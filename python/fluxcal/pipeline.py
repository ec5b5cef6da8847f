"""fluxcal.calibrate: one call that picks the right solver for the data it is given."""
from __future__ import annotations

from ._arrays import as_samples, held_copies
from .calibration import Calibration
from .ellipsoid import fit_ellipsoid
from .refine import fit_vector, refine

METHODS = ("auto", "vector", "als", "ls", "als+refine")


def calibrate(samples, method: str = "auto", field_norm: float | None = None, reference=None,
              units: str | None = None, loss: str = "none", **settings) -> Calibration:
    """Calibrate a three-axis magnetometer.

    method "auto": with `reference` (true field per reading, sensor frame) the vector fit
    (fluxcal.fit_vector, a full 3×3 matrix); otherwise the consistent ellipsoid fit (ALS) refined by
    maximum likelihood (fluxcal.refine) — the estimate that reaches the Cramér–Rao bound. The result's
    summary says what ran ("method") and whether the data determine every parameter
    ("identifiable"); when they do not (yaw-only turns, small tilts), the summary warns and names the
    remedy instead of passing a confident 3-D answer off as one. Other methods: "vector", "als",
    "ls", "als+refine". `loss` ("none", "huber", "cauchy") applies to the refinement.
    """
    if method not in METHODS:
        raise ValueError(f"method: {method!r} is not one of {', '.join(METHODS)}")
    if units is None:
        units = getattr(samples, "field_units", lambda: "")()
    m = as_samples(samples)
    if method == "vector" or (method == "auto" and reference is not None):
        if reference is None:
            raise ValueError("reference: the vector method needs the true field of each reading")
        cal = fit_vector(m, reference, units=units, loss=loss, **settings)
    elif method in ("ls", "als"):
        cal = fit_ellipsoid(m, field_norm=field_norm, units=units, method=method)
        cal.summary["method"] = method
    else:
        start = fit_ellipsoid(m, field_norm=field_norm, units=units, method="als")
        cal = refine(start, m, loss=loss, **settings)
        cal.summary["method"] = "als+refine"
        cal.summary["coverage_ratio"] = start.summary["coverage_ratio"]
        cal.summary["warnings"] = list(start.summary["warnings"]) + [
            w for w in cal.summary["warnings"] if w not in start.summary["warnings"]]
        if start.summary.get("noise_sigma"):
            cal.summary["als_noise_sigma"] = start.summary["noise_sigma"]
    copies = held_copies(m)
    if copies is not None:
        cal.summary["warnings"] = list(cal.summary["warnings"]) + [
            f"{int(copies.sum())} of {len(m)} readings ({100 * copies.mean():.0f} %) repeat the previous one exactly "
            "in regular runs (sample and hold: the logger ran faster than the sensor); the standard errors count "
            "them as independent readings and are too small by about √(run length) — record at the sensor's "
            "rate or drop the copies"]
    return cal
