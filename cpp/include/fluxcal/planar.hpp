// fluxcal/planar.hpp — the 2-D calibration of a magnetometer that only turns about one axis (a vehicle's
// heading, a biaxial compass): the two axes of the turning plane.
//
// Model, in the plane's two coordinates u (N×2 readings, one row a reading):
//     h = A (u − b),   |h_k| = H_k   (the horizontal field: one value, one per reading, or unknown)
// A symmetric positive definite (a_xx, a_xy, a_yy) and b the hard-iron offset: five parameters, as many as an
// ellipse has, so a full turn determines them all. A magnitude cannot see a rotation of h, so A is symmetric
// (fluxcal's convention, as the 3-D fits'): the rotation part of the soft iron stays a constant heading offset.
// Shapes with fewer parameters (PlanarShape): a circle (A = a I) and per-axis gains (A diagonal, TWOSTEP 2-D's
// model; it cannot map a rotated ellipse to a circle).
//
// The fit (fit_planar):
//   1. Two starts: the direct ellipse fit (Halir & Flusser 1998, "Numerically stable direct least squares fitting
//      of ellipses": an ellipse whatever the noise) and twostep_2d (twostep.hpp). Each is scaled to the targets and
//      the one with the lower cost is refined; the other only when that refinement does not converge.
//   2. Levenberg–Marquardt on the Sampson residual of each reading (reading units)
//          r_k = (|h_k| − H_k) · |h_k| / |A h_k|
//      its first-order distance to the ellipse |A (u − b)| = H_k: maximum likelihood for isotropic Gaussian
//      noise, as refine.hpp's magnitude model. Each iteration is one pass over the readings accumulating the
//      k×k JᵀJ and Jᵀr (k ≤ 5), so nothing of size N×k is stored.
//   3. Noise bias: the tangential noise lengthens |h| by ≈ σ_t²/(2H), σ_t² = σ²‖A‖_F²/2, so fitting |h| to H
//      shrinks A; one more solve with each target raised by σ̂²‖A‖_F²/(4 H_k), σ̂² from step 2.
//   4. Covariance σ̂²(JᵀJ)⁻¹ at the solution (σ̂² the mean squared Sampson residual over N − k), through the
//      eigen-decomposition of the column-scaled JᵀJ (a near-null direction gives a huge standard error, not a
//      failed factorisation). Readings correlated in time (a sensor's own filter, a vehicle's slow wander) make
//      it too narrow: with AR(1) noise of φ 0.9 the offset lay more than 4 of its errors off in 13 of 20 logs.
//      When the Sampson residuals, rows in time order, fail a Ljung–Box test and the sandwich widens an error
//      (or it widens one ≥ 1.5× with ≥ 10 readings per parameter), the covariance is the prewhitened Newey–West
//      sandwich over the scores J_kᵀ r_k, as refine.hpp's (PlanarOptions::serial_correlation). Whether a
//      parameter is determined is judged on the independent one.
// Without a field magnitude the scale is relative (as fluxcal.calibrate without a field norm): det A = 1 and
// field_norm is the fitted ellipse's geometric-mean radius; the covariance is carried to those parameters by the
// delta method.
//
// Finding the plane of N×3 readings, choosing the shape by BIC across shapes and the wording of the warnings a
// vehicle's log needs (a tilt while turning, a total field given for the horizontal one) are in the Python layer
// (python/fluxcal/planar.py): they judge a log, not solve for a calibration.
#pragma once

#include "fluxcal/twostep.hpp"  // Readings2D, Readings2DRef
#include "fluxcal/types.hpp"

#include <Eigen/Core>

#include <optional>
#include <string>
#include <vector>

namespace fluxcal {

/// The matrix A a planar fit may have (as refine's Shape in 3-D: fewer parameters cost nothing when the sensor has
/// no coupling between its axes).
enum class PlanarShape {
  circle,     ///< A = a I: offset and one gain (3 parameters: b_x b_y a)
  diagonal,   ///< A = diag(a_xx, a_yy): per-axis gains, TWOSTEP 2-D's model (4: b_x b_y a_xx a_yy)
  symmetric,  ///< A symmetric: gains and the coupling of the axes (5: b_x b_y a_xx a_xy a_yy)
};

/// A planar calibration to start from: h = matrix (reading − offset).
struct PlanarStart {
  Eigen::Vector2d offset = Eigen::Vector2d::Zero();
  Eigen::Matrix2d matrix = Eigen::Matrix2d::Identity();  ///< positive definite (it is projected onto the shape)
};

struct PlanarOptions {
  PlanarShape shape = PlanarShape::symmetric;
  /// The horizontal field's magnitude H, one value for every reading (field units). 0: not known — the scale is
  /// relative (det A = 1, field_norm the fitted mean radius). Ignored by the overload that takes field_norms.
  double field_norm = 0.0;
  /// Levenberg–Marquardt iterations at most, for each of the two solves (before and after the noise bias).
  int max_iterations = 100;
  /// Converged when no parameter (normalised units, O(1)) changes by more than this times max(1, |parameters|).
  double tolerance = 1e-10;
  /// The second solve with the targets raised by the noise's bias of |h| (step 3 above).
  bool noise_bias_correction = true;
  /// A parameter counts as determined when its standard error is below this fraction of its scale: the mean
  /// reading-space radius |u − b| for the offset, ‖A‖_F/√2 for matrix entries (refine's determined_tolerance).
  double determined_tolerance = 0.01;
  /// Throw Error when the fitted ellipse's mean radius is not above this many times the residual σ: readings
  /// scattered about a point give about 2, a sensor that turned 50 and more. 0: never.
  double min_radius_over_noise = 3.0;
  /// Standard errors for readings correlated in time (step 4 above; refine.hpp's rule): `automatic` takes the
  /// Newey–West sandwich when the residuals fail the Ljung–Box test at serial_correlation_alpha and it widens an
  /// error, or when it widens one ≥ 1.5× with ≥ 10 readings per parameter; `independent` never (rows not in time
  /// order); `newey_west` always.
  SerialCorrelation serial_correlation = SerialCorrelation::automatic;
  double serial_correlation_alpha = 0.01;  ///< in (0, 1); strict, so that white noise keeps σ̂²(JᵀJ)⁻¹
  /// A start for the refinement instead of step 1's two (reading units; any scale of A): another fit of the same
  /// sensor, such as a whole log's for each of its parts. Step 1's starts are still tried when the refinement from
  /// it does not converge. result.start says "given".
  std::optional<PlanarStart> start;
  /// Units of the readings, carried into the result ("" = not stated).
  std::string units;
};

/// A planar calibration h = A (u − b) and how its fit went. Summary: iterations (both solves) and converged (the
/// last solve's); cost = the mean squared Sampson residual (reading units²); residual_rms the RMS of |h| − H_k and
/// norm_mean, norm_std_over_mean those of |h|/H_k × the mean H (relative scale: of |h| against field_norm);
/// condition_number that of the column-scaled JᵀJ; coverage_ratio the readings' thinnest/widest spread; warnings
/// when the fit did not converge or the data do not determine every parameter.
struct PlanarResult {
  Eigen::Vector2d offset = Eigen::Vector2d::Zero();      ///< b, reading units
  Eigen::Matrix2d matrix = Eigen::Matrix2d::Identity();  ///< A, symmetric positive definite
  double field_norm = 1.0;  ///< |h| the matrix maps to: the mean H_k, or (relative) the fitted mean radius
  PlanarShape shape = PlanarShape::symmetric;
  bool relative_scale = false;  ///< no field magnitude given: det A = 1
  /// (b_x, b_y, then a; a_xx, a_yy; or a_xx, a_xy, a_yy), in the order of parameter_names.
  Eigen::VectorXd parameters;
  std::vector<std::string> parameter_names;
  /// Of the parameters: σ̂²(JᵀJ)⁻¹, or the Newey–West sandwich for readings correlated in time (delta method for
  /// the relative scale).
  Eigen::MatrixXd covariance;
  Eigen::VectorXd standard_errors;   ///< sqrt of its diagonal
  std::vector<bool> determined;      ///< per parameter (PlanarOptions::determined_tolerance), independent errors
  /// The residuals' lag-1 autocorrelation and Ljung–Box p, the Newey–West lags (0: independent readings assumed),
  /// the widening, and the independent-readings standard errors.
  SerialCorrelationReport serial_correlation;
  bool identifiable = false;         ///< every parameter determined
  double sigma = 0.0;                ///< σ̂: the RMS Sampson residual over N − k (reading units)
  /// The minimised sum of squared Sampson residuals (reading units²; against the targets raised by the noise's bias
  /// with noise_bias_correction): what a BIC across shapes compares.
  double rss = 0.0;
  double mean_radius = 0.0;          ///< mean |u − b| (reading units)
  double fisher_condition = 0.0;     ///< condition number of the column-scaled JᵀJ (inf: singular)
  std::string start;                 ///< "direct ellipse fit" or "twostep_2d": where the refinement began
  Eigen::VectorXd residuals;         ///< each reading's Sampson residual (reading units), against its H_k
  std::string units;                 ///< units of the readings
  Summary summary;

  /// Corrected field of one reading.
  Eigen::Vector2d apply(const Eigen::Vector2d& reading) const { return matrix * (reading - offset); }
  /// Corrected field of every row.
  Readings2D apply_rows(const Readings2DRef& readings) const;
};

/// The planar calibration of N ≥ 10 readings in the plane (N×2), with options.field_norm one horizontal field
/// magnitude (0: relative scale). Throws Error on NaN/Inf (naming the row), too few readings, readings that trace
/// no ellipse (on a line, at a few places, or scattered about their ellipse beyond options.min_radius_over_noise),
/// and options out of range. A fit that does not converge is reported (converged = false, a warning), not thrown.
PlanarResult fit_planar(const Readings2DRef& readings, const PlanarOptions& options = {});

/// As above with each reading's own horizontal field magnitude (`field_norms`, N values > 0; a field that changes
/// along a long drive). options.field_norm is not used; field_norm is the mean of field_norms.
PlanarResult fit_planar(const Readings2DRef& readings, const SeriesRef& field_norms, const PlanarOptions& options = {});

}  // namespace fluxcal
