// fluxcal/twostep.hpp — TWOSTEP calibration from field magnitudes: the 2-D form with a known field
// magnitude per reading (seed 000: Song et al. 2017, eqs. 6–19) and the 3-D form with a symmetric
// soft-iron matrix (Alonso & Shuster 2002, "Complete linear attitude-independent magnetometer
// calibration", J. Astronaut. Sci. 50(4); Gebre-Egziabher et al. 2006, J. Aerosp. Eng. 19(2):87).
//
// Both are "two-step" estimators: a pseudo-linear least-squares first step in a redundant
// parametrisation (closed form, one pass over the data), a second step that maps it back to the
// physical parameters, then an iterated refinement of the physical parameters on the full model.
//
// ---- 2-D (biaxial sensor, seed 000) ----------------------------------------------------------------
// Model (eq. 6): h_k² = (ĥx − bx)²/γx² + (ĥy − by)²/γy², with ĥ the reading, b the offset (hard iron
// and zero drift, reading units), γ the per-axis gain (scale factor and soft iron merged; reading
// units per field unit) and h_k the true field magnitude of reading k, known (from the reference
// current and the geometry) and allowed to differ between readings. With r = (γx/γy)² it expands to
//   z_k = ĥx² = [2ĥx, 2ĥy, −ĥy², −1, h_k²] · x,   x = (bx, r·by, r, bx² + r·by², γx²)
// (first step, eqs. 7–17). The paper prints z = ĥx² with the row [−2ĥx, −2ĥy, ĥy², 1, h²] and
// x5 = −γx²: those signs are inconsistent (they give z = −ĥx²); the row above is the derived one.
// Second step: bx = x1, by = x2/x3, γx² = x5, γy² = x5/x3. When every h_k is the same (within 1e-6)
// the h² column duplicates the constant one and x4, x5 are not separable; the first step then uses
// x4 = x1² + x2²/x3 (the known-radius ellipse): z = [2ĥx, 2ĥy, −ĥy², 1]·(x1, x2, x3, γx²h² − x4).
// The first step is not the maximum-likelihood estimate (it ignores x4's dependence on x1..x3 and
// weights the readings algebraically); the refinement (default on) is Gauss–Newton on
//   e_k = √((ĥx − bx)²/γx² + (ĥy − by)²/γy²) − h_k
// over (bx, by, γx, γy), which for white reading noise reaches the Cramér–Rao bound. Noise biases |h| upwards by
// σ²/(2h), the gains with it; noise_bias_correction (default on) takes the O(σ²) bias off (the option's comment).
// Compensation (eq. 19): h = (ĥ − b) ⊘ γ per axis; the frame change C_w→b of eq. 19 (sensor x/y to
// radial/tangential) belongs to the application.
//
// ---- 3-D (Alonso & Shuster 2002) ---------------------------------------------------------------------
// Model: B_k = (I + D)⁻¹ (O_k H_k + b + ε_k), D symmetric, |H_k| = H known (constant, or per reading), ε_k white with
// covariance Σ_ε. With E = 2D + D², c = (I + D) b and
//   z_k = |B_k|² − H² = −B_kᵀ E B_k + 2 cᵀ B_k − |b|² + v_k,   v_k = 2(O_k H_k)ᵀε_k + |ε_k|²,  E[v_k] = μ = tr Σ_ε
// the first step is A&S's centred estimate: subtracting the means removes the |b|² term (and μ) and
// leaves a linear least-squares problem in (c, E). With a constant |H| the centring also removes H²
// and the centred problem has a null direction (E → λ(I + E) − I, c → λc: every λ fits equally, λ = 0
// trivially); fluxcal fixes it by tr E = 0 and recovers the scale from H in the second step, which
// makes the first step the trace-normalised algebraic ellipsoid fit. The iterated second step is
// A&S's Fisher scoring on the full model (|b|² tied to c and E), in two parts. First on Σ (|A(m_k − o)|² − H² −
// μ)², each v_k's variance taken as the same 4H²σ_ε² — run on the 35 moments of the readings: one pass over the data,
// then each iteration costs O(1). Then, from there (from the first step when that ran off), on v_k over its own σ_k: 4σ²|A²(m_k − o)|² for reading noise σ
// (the Sampson distance, first-order maximum likelihood), σ_k's dependence on the parameters in the Jacobian — two
// passes over the readings an iteration. Held at an iterate, or the same for all, the weights let the fit shrink an
// axis the readings see little of (its noise shrinks with it): on a ±20° band of tilts a blind check found the offset
// along it 7× the Cramér–Rao bound off, not falling with more readings; so, at the bound. μ is the noise mean of
// that fit: Σ_ε = σ²A², E[v_k] = σ² tr A², and weighted by 1/σ_k², whose noise is correlated with v_k's, the mean
// comes to −σ² tr A²/3 (the |h|² a reading pushed outwards weighs less) — from options.noise_sigma when given, else
// from the weighted residual variance (w_k var v_k = (4/3) σ² tr A², w_k = (tr A²/3)/|A²(m_k − o)|² up to scale). It
// removes the O(σ²/H²) scale bias as refine's noise_bias_correction does (the two agree to 2e-5 of the scale at σ =
// 1–5 % of the field). The offset is unbiased to that order.
// With each reading's own |H_k| (A&S's general case) the centring leaves H_k² − mean H² in z_k: the first step
// fits it with a free coefficient beside the trace-normalised quadric, and the second step's objective is
// Σ (|A(m_k − o)|² − H_k² − μ)²/H_k², each reading weighted by the inverse of its v_k's variance (∝ H_k², as A&S
// weigh; the first step is not weighted), its sums from one more pass over the readings. One reading far off its
// H_k (a glitch in field_norms) weighs heavily when its H_k is low: the Summary warns of a reading more than 10
// times the RMS off (fluxcal.calibrate's outlier screen leaves such readings out).
// Result in fluxcal's convention h = A (m − o): A = I + D (symmetric positive definite),
// o = (I + D)⁻¹ b.
#pragma once

#include "fluxcal/types.hpp"

#include <Eigen/Core>

#include <string>
#include <vector>

namespace fluxcal {

// ---- 2-D ---------------------------------------------------------------------------------------------

/// N×2 readings (ĥx, ĥy), one row a reading, row-major (a C-contiguous NumPy array maps without a copy).
using Readings2D = Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor>;
using Readings2DRef = RowsRef<2>;  // another width throws Error (types.hpp)

struct TwoStep2DOptions {
  /// Refine (bx, by, γx, γy) by Gauss–Newton on the magnitude residual after the closed form.
  bool refine = true;
  /// Gauss–Newton iterations at most (per pass; the noise-bias correction runs a second pass).
  int max_iterations = 50;
  /// Noise lengthens the corrected magnitudes (E|h + ε| ≈ h + σ²/2h), which shrinks a fit aimed at h_k and raises
  /// the gains by σ²/(2h²) of the field (3e-4 at 3 % noise: several standard errors at 10^5 readings). With this on,
  /// after the refinement each target is raised to the Rice mean E|h_k + ε| (σ from the residuals, across the
  /// reading's direction) less the Sampson normaliser's move, the fit solved again, and the Jacobian's move with
  /// the noise taken off (−F⁻¹σ²Σ∂J/∂n). Needs refine; not applied when a gain is poorly determined.
  bool noise_bias_correction = true;
  /// Stop when no parameter (in normalised units, O(1)) changes by more than this.
  double tolerance = 1e-12;
  /// Units of the readings, carried into the result ("" = not stated).
  std::string units;
  /// Warn when |h|/h_k scatters by more than this (std/mean) after the fit: readings and field_norms that
  /// do not belong together (shuffled, another run's) can still give a converged fit.
  double misfit_spread = 0.05;
  /// Warn when a gain's standard error exceeds this fraction of the gain: an arc too short, or a field that
  /// never had a component along one axis, leaves the data unable to fix it.
  double poorly_determined = 0.02;
  /// With one field magnitude and a short arc the magnitude objective falls towards infinite offsets and gains
  /// (every corrected reading then the same vector of length h): a refinement that has not converged and has
  /// grown a gain by more than this factor over the first step's throws Error instead of returning the iterate.
  double runaway_factor = 10.0;
};

/// Offset and gains of a biaxial sensor, and how the fit went.
/// Summary: cost is the mean squared magnitude residual (|h| − h_k)² after refinement, or the first
/// step's mean algebraic residual (normalised units) without it; residual_rms is the RMS of
/// |h| − h_k; norm_mean and norm_std_over_mean are the mean and std/mean of |h|/h_k (ideally 1, 0);
/// condition_number is that of the first step's (column-scaled) normal matrix; coverage_ratio is the
/// thinnest/widest spread of the readings.
struct TwoStep2DResult {
  Eigen::Vector2d offset = Eigen::Vector2d::Zero();  ///< b, reading units
  Eigen::Vector2d gain = Eigen::Vector2d::Ones();    ///< γ, reading units per field unit
  bool constant_field = false;  ///< every h_k equal: the first step used the known-radius form
  /// Covariance of (bx, by, γx, γy): σ̂²(JᵀJ)⁻¹ of the magnitude residuals |(ĥ − b) ⊘ γ| − h_k at the result
  /// (σ̂² their mean square over N − 4); for white reading noise about the Cramér–Rao bound. Infinite when
  /// the data do not determine it. offset_se and gain_se are the square roots of its diagonal.
  Eigen::Matrix4d covariance = Eigen::Matrix4d::Zero();
  Eigen::Vector2d offset_se = Eigen::Vector2d::Zero();
  Eigen::Vector2d gain_se = Eigen::Vector2d::Zero();
  std::string units;            ///< units of the readings
  Summary summary;

  /// Compensated field of one reading (eq. 19): (ĥ − b) ⊘ γ.
  Eigen::Vector2d apply(const Eigen::Vector2d& reading) const { return (reading - offset).cwiseQuotient(gain); }
  /// Compensated field of every row.
  Readings2D apply_rows(const Readings2DRef& readings) const;
  /// The reading a true field h would produce (the forward model ĥ = γ ⊙ h + b, without noise).
  Eigen::Vector2d reading(const Eigen::Vector2d& field) const { return gain.cwiseProduct(field) + offset; }
};

/// TWOSTEP for a biaxial sensor from N ≥ 5 readings and the true field magnitude of each
/// (`field_norms`, N values > 0, field units). Throws Error on NaN/Inf, too few readings, a length
/// mismatch, non-positive magnitudes, a rank-deficient first step (the field never changed direction,
/// or readings on a line) or a first step that gives γ² ≤ 0 (readings and magnitudes inconsistent).
/// A refinement that does not converge is reported in the Summary (converged = false, a warning), unless it
/// ran away (options.runaway_factor): then Error, naming the coverage.
TwoStep2DResult twostep_2d(const Readings2DRef& readings, const SeriesRef& field_norms,
                           const TwoStep2DOptions& options = {});

// ---- 3-D ---------------------------------------------------------------------------------------------

struct TwoStepOptions {
  /// Known field magnitude |H| (e.g. from IGRF), required > 0, in the units h should come out in.
  double field_norm = 0.0;
  /// Fisher-scoring iterations of the second step at most; 0 returns the centred first step.
  int max_iterations = 50;
  /// Stop when no parameter (normalised units, O(1)) changes by more than this.
  double tolerance = 1e-10;
  /// Standard deviation of the reading noise per axis (reading units), for the noise mean μ.
  /// < 0: estimate μ from the residuals (default); 0: no noise-mean correction. With it (≠ 0), once the second step
  /// has converged, the noise's O(σ²) bias is taken off as refine's noise_bias_correction does: each reading's own
  /// noise mean μ_k along its normal and the fit solved again (on partial coverage too), then the Jacobian's move
  /// with the noise (F⁻¹ 2σ² Σ∂J_k/∂n̂) where every parameter's standard error is below 10 × determined_tolerance
  /// of its scale — at σ 2 % the scale agrees with refine's to 1e-6.
  double noise_sigma = -1.0;
  /// Units of the readings, carried into the Calibration ("" = not stated).
  std::string units;
  /// Reject the readings as planar when their thinnest/widest spread is below this.
  double planar_ratio = 0.02;
  /// Warn about poor coverage below this thinnest/widest spread ...
  double poor_coverage_ratio = 0.3;
  /// ... or when fewer than this fraction of direction bins hold a corrected reading (coverage.hpp), of the
  /// fraction N readings spread evenly would fill, 1 − (1 − 1/96)^N (30 readings: about 27 %).
  double poor_direction_coverage = 0.5;
  /// Direction coverage looks at an evenly strided subsample of at most this many readings (0 = all).
  Eigen::Index coverage_rows = 16384;
  /// On a cap of directions the second step's objective falls towards an infinite offset and a vanishing A (and
  /// a few far outliers can run it away on a full sphere): a second step that has not converged and whose misfit
  /// in the readings' units, the RMS of (|h| − H′)/|Aᵀĥ| (H′² = H² + μ, its own radius), grew by more than this
  /// factor over the first step's throws Error, naming the first step's coverage and its farthest reading,
  /// instead of returning the iterate. inf: never.
  double runaway_misfit = 1.1;
  /// The second step's covariance (TwoStepResult::covariance); false skips its pass over the readings.
  bool standard_errors = true;
  /// As RefineOptions: a parameter is determined when its independent-readings standard error is below this
  /// fraction of its scale (the readings' mean radius |m − o| for offsets, the gain ‖A‖_F/√3 for matrix entries).
  double determined_tolerance = 0.01;
  /// Readings correlated in time: automatic (Newey–West when the residuals fail the Ljung–Box test at
  /// serial_correlation_alpha and it widens an error, or it widens one ≥ 1.5×), independent, or newey_west.
  SerialCorrelation serial_correlation = SerialCorrelation::automatic;
  double serial_correlation_alpha = 0.01;
};

/// Calibration (model "twostep", A symmetric) and Summary: iterations and converged of the second
/// step; cost = its objective over N: the mean squared Sampson distance (|h_k|² − H_k² − μ_k)/(2|Aᵀh_k|) (μ_k each
/// reading's noise mean, or one μ for all where the noise-bias correction is not applied) of the
/// readings from the ellipsoid, in the readings' units squared (with max_iterations = 0, the first step's mean
/// ((|h|² − H²)/H²)²); residual_rms, norm_mean and
/// norm_std_over_mean of |h| from a pass over the samples (exact_statistics); condition_number of the
/// (column-scaled) Fisher matrix, or of the first step's normal matrix when max_iterations = 0.
/// With the second step (max_iterations > 0) and options.standard_errors, A&S's error covariance of the second step,
/// carried by the delta method (o = centre + scale·q, A = (H/scale) N^½) to refine's magnitude-model parameters: from
/// 30 readings the HC2 sandwich F⁻¹ Σ g_k g_kᵀ/(1 − h_kk) F⁻¹ of the scores g_k (F the scoring's Fisher information,
/// h_kk the readings' leverages) — the residuals' variance follows |Aᵀĥ|² around the ellipsoid, so one σ̂² fits them
/// only for a near-spherical A — below, σ̂² F⁻¹ with σ̂² = Σ r_k²/(N − 9) of the Sampson residuals (μ is no free
/// parameter: N's scale absorbs it); the Newey–West sandwich for readings correlated in time. `determined` and
/// `identifiable` are judged on the independent-readings errors (serial_correlation.standard_errors_independent: the
/// sandwich's from 30 readings). 9 readings fit exactly: no covariance, identifiable false, a warning. Residuals above 5 % of the field are
/// said to be a misfit (in the not-identifiable warning, or alone).
struct TwoStepResult {
  Calibration calibration;
  Summary summary;
  Eigen::VectorXd parameters;               ///< [o0 o1 o2 a00 a01 a02 a11 a12 a22], as parameter_names
  std::vector<std::string> parameter_names;  ///< "b0".."b2", "a00".."a22" (refine's names)
  Eigen::MatrixXd covariance;               ///< of parameters; empty for the first step alone
  Eigen::VectorXd standard_errors;          ///< sqrt of its diagonal
  std::vector<bool> determined;             ///< per parameter (options.determined_tolerance)
  bool identifiable = false;                ///< every parameter determined (false when no covariance was computed)
  /// (summary.condition_number is the column-scaled Fisher matrix's)
  SerialCorrelationReport serial_correlation;  ///< the residuals' test and the Newey–West widening
};

/// TWOSTEP for a three-axis sensor in a field of known constant magnitude (N ≥ 9 readings).
/// Throws Error on a missing field_norm, NaN/Inf, too few rows, planar readings (rank-deficient first
/// step), readings that do not lie on an ellipsoid, or a result that is not positive definite.
/// A second step that does not converge is reported (converged = false, a warning), not thrown, unless it ran
/// away from the readings (options.runaway_misfit): then Error, naming the coverage.
TwoStepResult twostep(const SamplesRef& samples, const TwoStepOptions& options);

/// TWOSTEP with the true field magnitude of each reading (`field_norms`, N values > 0), as Alonso & Shuster wrote it
/// for a spacecraft along its orbit (z_k = |B_k|² − |H_k|², the reference field's magnitude at each position), or
/// for a field logged by a scalar magnetometer beside the sensor. The first step fits the change with its own
/// coefficient (when (H_k/H̄)² has a standard deviation above 1e-6), the second step each |h_k| to its H_k.
/// options.field_norm is not used: the Calibration's field_norm is the mean of field_norms, and the Summary's |h|
/// statistics are of |h_k| − H_k. Throws Error as the one-magnitude form, and on field_norms of another length or
/// with a value that is not positive and finite.
TwoStepResult twostep(const SamplesRef& samples, const SeriesRef& field_norms, const TwoStepOptions& options = {});

}  // namespace fluxcal
