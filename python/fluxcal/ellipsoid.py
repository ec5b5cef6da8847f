"""Ellipsoid-fit integrated calibration of a three-axis magnetometer (seed 004), on the C++ core."""
from __future__ import annotations

import numpy as np

from . import _core
from ._arrays import as_samples, positive_field_norm, samples_units, set_options, units_text
from .calibration import Calibration


METHODS = {"ls": _core.EllipsoidMethod.ordinary, "als": _core.EllipsoidMethod.adjusted}


def _calibration(result: dict, metadata: dict | None = None) -> Calibration:
    summary = dict(result["summary"])
    if result.get("noise_sigma"):
        summary["noise_sigma"] = result["noise_sigma"]
    return Calibration(offset=result["offset"], matrix=result["matrix"], field_norm=result["field_norm"],
                       units=result["units"], model=result["model"], summary=summary,
                       metadata=dict(metadata or {}))


def _options(field_norm, units, method="ls", **settings):
    options = _core.EllipsoidOptions()
    if method not in METHODS:
        raise ValueError(f"method: {method!r} is not one of {', '.join(METHODS)}")
    options.method = METHODS[method]
    if np.size(field_norm) > 1:
        raise ValueError(f"field_norm: {np.size(field_norm)} values; the ellipsoid fit takes one |field| (each "
                         "reading's own: fluxcal.calibrate, refine or twostep)")
    options.field_norm = 0.0 if field_norm is None else positive_field_norm(field_norm)
    options.units = units_text(units)
    return set_options(options, settings, "fit_ellipsoid")


def fit_ellipsoid(samples, field_norm: float | None = None, units: str | None = None, method: str = "ls",
                  **settings) -> Calibration:
    """Fit h = A (m − b) to N×3 readings taken in a uniform field (N ≥ 9).

    method: "ls" — ordinary algebraic least squares (fast; biased by noise, by a relative σ²/H²);
    "als" — adjusted least squares (Markovsky et al. 2004), consistent under isotropic Gaussian noise,
    and reports the estimated noise σ per axis as summary["noise_sigma"].
    field_norm: the known |h| (e.g. from IGRF, in the units you want h in); None uses the fitted mean
    radius (geometric mean of the semi-axes, so det A = 1). A is symmetric. `samples` may be a
    `fluxcal.io.Recording`, whose units are then carried. Raises ValueError on NaN/Inf, too few rows,
    planar readings, or readings that do not lie on an ellipsoid.

    settings (defaults in cpp/include/fluxcal/ellipsoid.hpp): planar_ratio=0.02 (reject below this
    thinnest/widest spread), poor_coverage_ratio=0.3 and poor_direction_coverage=0.5 (warn below; the bins judged against what
    N readings spread evenly would fill, 1 − (1 − 1/96)^N),
    exact_statistics=True (residual statistics and coverage from a pass over the samples).
    """
    if units is None:
        units = samples_units(samples)
    arr = as_samples(samples)
    return _calibration(_core.fit_ellipsoid(arr, _options(field_norm, units, method, **settings)))


class EllipsoidMoments:
    """Streaming ellipsoid fit: constant-size sufficient statistics, updated block by block.

    The normalisation (centre, scale) only keeps the sums well conditioned; take it from the first
    block (`EllipsoidMoments.from_first(block)`) or from what you know of the sensor.
    """

    def __init__(self, centre, scale: float):
        self._m = _core.EllipsoidMoments(np.asarray(centre, dtype=float).reshape(3), float(scale))

    @classmethod
    def from_first(cls, block) -> "EllipsoidMoments":
        centre, scale = _core.normalisation(as_samples(block))
        return cls(centre, scale)

    def add(self, block) -> None:
        self._m.add_rows(as_samples(block))

    @property
    def count(self) -> int:
        return self._m.count

    def fit(self, field_norm: float | None = None, units: str = "") -> Calibration:
        return _calibration(self._m.fit(_options(field_norm, units)))
