// fluxcal/ellipsoid.hpp — integrated calibration of a three-axis magnetometer by ellipsoid fitting
// (seed 004: Luo et al. 2022).
//
// In a uniform field of magnitude H the readings m of a sensor with offset b and linear distortion W
// lie on the ellipsoid (m − b)ᵀ Q (m − b) = H², Q = AᵀA, A = W⁻¹. The fit finds the general quadric
//   uᵀ M u + 2 vᵀ u + k = 0   (10 coefficients)
// that minimises the algebraic residual Σ (uᵀMu + 2vᵀu + k)² subject to trace(M) = 1. That constraint is
// invariant under rotation, translation and scaling of the data, so the estimate does not depend on
// the coordinates the readings come in. The data are first normalised (u = (m − c)/s, c and s from a
// strided subsample) so the moment sums stay well conditioned even for raw ADC counts.
//
// From magnitudes alone A is known only up to a rotation; fluxcal reports the symmetric A.
// Without a known field norm the scale is the fitted mean radius: the geometric mean of the
// semi-axes (the radius of the sphere with the ellipsoid's volume), so det(A) = 1.
#pragma once

#include "fluxcal/types.hpp"

#include <Eigen/Core>

#include <array>

namespace fluxcal {

/// Which algebraic estimator fits the quadric.
enum class EllipsoidMethod {
  /// Ordinary least squares (trace(M) = 1). Biased by noise: the offset and shape shrink toward
  /// the noise-free ellipsoid only as σ → 0 (a relative bias of order σ²/H²).
  ordinary,
  /// Adjusted least squares (Markovsky, Kukush & Van Huffel 2004): each moment of the noisy readings
  /// is replaced by an unbiased estimate of the noise-free moment (Hermite polynomials in σ²), with
  /// σ² estimated so the adjusted scatter becomes singular. Consistent for isotropic, independent
  /// Gaussian noise on each axis; also returns that noise estimate.
  adjusted,
};

struct EllipsoidOptions {
  /// Estimator of the quadric (see EllipsoidMethod).
  EllipsoidMethod method = EllipsoidMethod::ordinary;
  /// Known field magnitude |h| (e.g. from IGRF). 0 = use the fitted mean radius.
  double field_norm = 0.0;
  /// Units of the readings, carried into the Calibration ("" = not stated).
  std::string units;
  /// Reject the data as planar when the thinnest/widest spread of the readings is below this.
  double planar_ratio = 0.02;
  /// Warn about poor coverage when the thinnest/widest spread is below this ...
  double poor_coverage_ratio = 0.3;
  /// ... or when fewer than this fraction of direction bins hold a corrected reading (coverage.hpp), of the
  /// fraction N readings spread evenly would fill, 1 − (1 − 1/96)^N (30 readings: about 27 %).
  double poor_direction_coverage = 0.5;
  /// Residual statistics and direction coverage from a second pass over the samples (exact) rather
  /// than from the moments (first order in the residual, no direction coverage; free).
  bool exact_statistics = true;
  /// Direction coverage looks at an evenly strided subsample of at most this many readings (0 = all).
  Eigen::Index coverage_rows = 16384;
};

struct EllipsoidResult {
  Calibration calibration;
  Summary summary;
  /// Quadric coefficients [M11 M22 M33 M12 M13 M23 v1 v2 v3 k] in normalised coordinates.
  Eigen::Matrix<double, 10, 1> quadric;
  /// Adjusted fit only: the estimated noise standard deviation per axis, in reading units (else 0).
  double noise_sigma = 0.0;
};

/// Sufficient statistics of the fit: the 35 moments Σ uˣ vʸ wᶻ (x+y+z ≤ 4) of the normalised readings.
/// Constant size; add samples one by one or in blocks; merge partial sums (threads, streams).
class EllipsoidMoments {
 public:
  static constexpr int kMoments = 35;

  /// `centre` and `scale` define the normalisation u = (m − centre)/scale; any values near the data's
  /// centre and radius keep the sums well conditioned (the fit does not depend on them).
  EllipsoidMoments(const Eigen::Vector3d& centre, double scale);

  void add(const Eigen::Vector3d& reading);
  void add_rows(const SamplesRef& readings);
  /// Adds the sums of `other`, which must share this normalisation.
  void merge(const EllipsoidMoments& other);

  std::size_t count() const { return static_cast<std::size_t>(sums_[0]); }
  const Eigen::Vector3d& centre() const { return centre_; }
  double scale() const { return scale_; }
  /// Σ dᵢdᵢᵀ for the design row d = [u², v², w², 2uv, 2uw, 2vw, 2u, 2v, 2w, 1] (normalised).
  /// With `noise_variance` > 0 (per axis, normalised units: (σ/scale)²) every moment is replaced by
  /// its unbiased estimate for noise-free readings — the adjusted scatter of the ALS fit.
  Eigen::Matrix<double, 10, 10> scatter(double noise_variance = 0.0) const;
  /// True when every sum is finite (a NaN or Inf reading poisons them all).
  bool finite() const;

 private:
  Eigen::Vector3d centre_;
  double scale_;
  double inv_scale_;
  std::array<double, kMoments> sums_{};  // order: count, then degree 1..4 (see ellipsoid.cpp)
};

/// Normalisation (centre, scale) from a strided subsample of at most `max_rows` rows: the midrange
/// and the largest half-range. Costs O(max_rows), not a pass over the data; max_rows ≤ 0 looks at every row.
std::pair<Eigen::Vector3d, double> normalisation(const SamplesRef& samples, Eigen::Index max_rows = 1024);

/// Fits the ellipsoid to N×3 readings (N ≥ 9). Throws Error on NaN/Inf, too few rows, planar
/// readings, or readings that do not lie on an ellipsoid.
EllipsoidResult fit_ellipsoid(const SamplesRef& samples, const EllipsoidOptions& options = {});

/// Fits the ellipsoid from accumulated moments (streaming use). Residual statistics come from the
/// moments.
EllipsoidResult fit_ellipsoid(const EllipsoidMoments& moments, const EllipsoidOptions& options = {});

}  // namespace fluxcal
