// fluxcal/alignment.hpp — the magnetometer's axes turned onto the accelerometer's, from the dip.
//
// A magnetometer calibrated from field magnitudes (an ellipsoid fit, TWOSTEP) is right up to a rotation: the
// magnitude does not see how its axes sit against the accelerometer's, and a compass's heading is off by that
// rotation. At rest the angle between gravity and the Earth field — 90° + the dip — is the same in every
// attitude (dot-product invariance: Li & Li 2012, IEEE Trans. Instrum. Meas. 61(4); Wu & Shi 2015), so the
// readings of a turned device fix the rotation R from the magnetometer's frame to the accelerometer's and the
// dip δ together. Least squares on the dip each reading shows,
//   e_k = atan2(d_kᵀ v_k, |d_k × v_k|) − δ,   v_k = R ĥ_k,   d_k = −f_k/|f_k|,   ĥ_k = h_k/|h_k|
// (down: an accelerometer at rest reads the specific force, up; ĥ_k the calibrated field's direction). With direction
// noise σ_h (magnetometer) and σ_f (accelerometer) radians per axis every e_k has the variance σ_h² + σ_f² at any
// dip, so this is the maximum-likelihood estimate; its covariance is the sandwich σ̂² H⁻¹ JᵀJ H⁻¹ with H the cost's
// Hessian (σ̂²(JᵀJ)⁻¹, Cramér–Rao at the solution, where the attitudes are spread: H = JᵀJ there; where they barely
// move about one axis the noise in J lends JᵀJ curvature the cost does not have, and H takes it back). (The
// cosine d_kᵀv_k − sin δ loses its first-order noise towards the poles, and its Jacobian's noise correlates with
// its own: least squares on it was biased by 1–2° on a hand turn's uneven attitudes, 3.7° at a dip of 85°. On the
// angle that correlation cancels to first order.)
// Start: the homogeneous linear fit d_kᵀ M ĥ_k = s (10 unknowns, the smallest singular vector), M projected on
// the nearest rotation, and R = I; then damped Gauss–Newton on R = exp([θ]×) R₀ and δ from each, stepping only
// along directions the data determine; R = I's fit is kept unless the linear start's is clearly better (half
// the cost, or identifiable where R = I's is not); the dip's noise bias (≈ −(σ_h² + σ_f²)/2 · tan δ) removed.
// Readings correlated in time get the Newey–West covariance (as refine.hpp).
// Readings whose dip residual is more than 5 robust SDs off (a spike, a knock) are left out and the fit run again.
// What it cannot see: a rotation about the vertical when the device was only turned about the vertical (the
// heading offset of a compass turned level), or any axis the attitudes never moved about — its standard
// error then says so, the result is flagged not identifiable, and that rotation is left as mounted (R = I).
// Nor, when every tilt was about one body axis n, which of two answers is right: R or R turned 180° about n,
// with the dip negated, fit equally; the one nearer the axes as mounted is returned, flagged not identifiable.
#pragma once

#include <fluxcal/types.hpp>

#include <string>
#include <vector>

namespace fluxcal {

struct AlignmentOptions {
  /// Leave out readings whose |f| departs from the median |f| by more than this fraction: the device was
  /// accelerating, and f was not gravity. ≤ 0 keeps every reading.
  double max_dynamic = 0.05;
  /// Gauss–Newton iterations at most.
  int max_iterations = 50;
  /// Stop when the step (radians) is below this.
  double tolerance = 1e-12;
  /// A rotation axis or the dip whose standard error (degrees) exceeds this is "not determined": the
  /// attitudes did not move about that axis.
  double max_se_deg = 1.0;
  /// Remove the dip's noise bias, ≈ −(σ_h² + σ_f²)/2 · tan δ (noise across the plane of the two directions only
  /// widens the angle between them), σ_h² + σ_f² from the residuals.
  bool noise_bias_correction = true;
  /// Readings correlated in time (a slow hand turn logged fast) make σ̂²(JᵀJ)⁻¹ too small. `automatic`: the
  /// prewhitened Newey–West sandwich when the dip residuals fail a Ljung–Box test at serial_correlation_alpha
  /// and it widens an error, or when it widens one ≥ 1.5× (as RefineOptions; rows in time order).
  SerialCorrelation serial_correlation = SerialCorrelation::automatic;
  double serial_correlation_alpha = 0.01;
};

struct AlignmentResult {
  /// R: the magnetometer's calibrated frame onto the accelerometer's, h_acc = R h.
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  /// The same rotation as a rotation vector (axis × angle, radians, accelerometer frame).
  Eigen::Vector3d rotation_vector = Eigen::Vector3d::Zero();
  /// Dip of the field below the horizontal (radians, positive down).
  double dip = 0.0;
  /// Covariance of (small rotation about the accelerometer's x, y, z; dip), radians²: σ̂² H⁻¹ JᵀJ H⁻¹ (above).
  Eigen::Matrix4d covariance = Eigen::Matrix4d::Zero();
  /// Standard errors: about x, y, z and of the dip (radians).
  Eigen::Vector4d standard_errors = Eigen::Vector4d::Zero();
  /// RMS of the residuals (radians: the direction noise σ_h² + σ_f², square-rooted) and how many readings were
  /// kept as static.
  double residual_rms = 0.0;
  std::size_t readings_used = 0;
  /// Per input row: the dip it shows less δ at the fit (radians), NaN for a row left out (moving, an outlier).
  Eigen::VectorXd residuals;
  /// The residuals' test for correlation in time and what the covariance did about it.
  SerialCorrelationReport serial_correlation;
  /// False when some axis or the dip is not determined (standard error above max_se_deg).
  bool identifiable = false;
  /// Summary: samples (used), iterations, converged, message, warnings.
  Summary summary;
};

/// R and δ from calibrated fields `field` (N×3, any unit) and accelerometer readings `specific_force` (N×3,
/// any unit, same rows). Throws Error for NaN, mismatched rows, fewer than 8 static readings, zero vectors.
AlignmentResult align_to_gravity(const SamplesRef& field, const SamplesRef& specific_force,
                                 const AlignmentOptions& options = {});

}  // namespace fluxcal
