// fluxcal/refine.hpp — maximum-likelihood joint refinement of a calibration (Ceres).
//
// Magnitude model (no direction reference): readings m = W h + b + e, |h| = H known, e ~ N(0, σ²I).
// Parameters θ = [b (3), A (6: a00 a01 a02 a11 a12 a22)], A symmetric, h = A (m − b). The residual of
// reading i is its first-order geometric distance to the ellipsoid |A (m − b)| = H (Sampson):
//     r_i = (|h_i| − H) · |h_i| / |A h_i|      (reading units)
// so least squares on r is maximum likelihood for isotropic Gaussian noise on the readings, and
// σ̂² = Σr²/(N − 9) estimates the noise.
//
// Vector model (each reading has its true field r_i in the sensor frame, e.g. IGRF rotated by an
// attitude): m_i = W r_i + b + e_i. Parameters θ = [b (3), W (9, row-major)]; residual m_i − W r_i − b.
// The correction reported is A = W⁻¹ (full, not symmetric: the reference fixes the rotation).
//
// Both return the covariance of θ, σ̂² (JᵀJ)⁻¹ at the solution, standard errors, whether the data
// determine each parameter, and the condition number of the (column-scaled) Fisher information JᵀJ.
// Readings logged while the sensor turns are rarely independent: slow disturbances and model misfit
// along a smooth path make the residuals correlated in time, and σ̂² (JᵀJ)⁻¹ then understates the
// uncertainty several-fold. When the residuals fail a Ljung–Box test (taking the rows in time order),
// the covariance is the Newey–West sandwich F⁻¹ S F⁻¹, S the Bartlett-weighted long-run covariance of
// the per-reading scores g_i = J_iᵀ r_i (× N/(N − p)), its bandwidth Politis & White's automatic block
// length; it also switches when the sandwich widens an error ≥ 1.5× (RefineOptions::serial_correlation).
// (The covariance comes from an eigen-decomposition of JᵀJ rather than ceres::Covariance: the same
// matrix, a 9×9 problem instead of an SVD of the N×9 Jacobian, and near-singular cases are reported
// as undetermined parameters instead of a failed computation.)
#pragma once

#include "fluxcal/types.hpp"

#include <string>
#include <vector>

namespace fluxcal {

enum class Loss {
  none,    ///< plain least squares (maximum likelihood under Gaussian noise)
  huber,   ///< quadratic below loss_scale, linear above
  cauchy,  ///< log(1 + (r/loss_scale)²): strong down-weighting of outliers
};

/// The soft-iron matrix the magnitude model may fit (MATLAB magcal's 'eye' / 'diag' / 'sym'). Fewer
/// parameters cost nothing when the sensor has no cross-axis coupling, and are better determined by few
/// readings or a thin coverage.
enum class Shape {
  sphere,     ///< A = a I: offset and one scale (4 parameters: b0 b1 b2 a)
  diagonal,   ///< A = diag(a00, a11, a22): offset and axis scales (6: b0 b1 b2 a00 a11 a22)
  symmetric,  ///< A symmetric: offset, scales and soft-iron coupling (9: b0 b1 b2 a00 a01 a02 a11 a12 a22)
};

struct RefineOptions {
  Loss loss = Loss::none;
  /// Magnitude model only (refine): the matrix's shape; the start is projected onto it (off-diagonal
  /// terms dropped; for a sphere, a = the mean of A's eigenvalues). The vector model's W is always full.
  Shape shape = Shape::symmetric;
  /// Residual size (reading units) where the robust loss bends; 0 = 3 × a robust estimate of the noise
  /// (1.4826 · median |r| at the start).
  double loss_scale = 0.0;
  int max_iterations = 100;
  double function_tolerance = 1e-14;
  double gradient_tolerance = 1e-14;
  double parameter_tolerance = 1e-12;
  /// A parameter counts as determined when its standard error (for independent readings: a property of
  /// the Fisher information, i.e. the coverage) is below this fraction of its scale:
  /// the mean reading-space radius |m − b| for offsets, the gain ‖A‖_F/√3 (or ‖W‖_F/√3) for
  /// matrix entries.
  double determined_tolerance = 0.01;
  std::string units;  ///< carried into the Calibration (default: the start's units)
  /// Magnitude model: remove the second-order noise bias. Noise on the readings makes |h| exceed H
  /// on average by ≈ σ²‖A‖_F²/(3H) (the two tangential components), so fitting |h| to H shrinks A by
  /// ~σ²/H² (0.25 % at σ = 5 %). With this on, a second solve fits each reading's |h| to H + σ̂²(tr A² − ûᵀA²û)/(2H),
  /// û its direction (the noise across it lengthens it; over all directions the mean is σ̂²‖A‖_F²/(3H)), less the
  /// move of the Sampson normaliser, σ̂ from the first; without a robust loss the Jacobian's move with the noise is
  /// then taken off too (−F⁻¹σ̂²Σ∂J/∂n, refine.cpp). The Calibration still reports H.
  bool noise_bias_correction = true;
  SerialCorrelation serial_correlation = SerialCorrelation::automatic;
  /// Significance of the Ljung–Box test (20 lags, or N/5 when fewer) that switches `automatic` to
  /// Newey–West. Strict, so that white noise keeps the exact independent-readings covariance. In (0, 1).
  double serial_correlation_alpha = 0.01;
};

struct RefineResult {
  Calibration calibration;
  Summary summary;
  Eigen::VectorXd parameters;               ///< θ, in the order of parameter_names
  std::vector<std::string> parameter_names;  ///< "b0".."b2", then "a00".. or "w00"..
  Eigen::MatrixXd covariance;               ///< σ̂² (JᵀJ)⁻¹ or Newey–West; huge on the diagonal where undetermined
  Eigen::VectorXd standard_errors;          ///< sqrt of the covariance diagonal
  std::vector<bool> determined;             ///< per parameter (see RefineOptions::determined_tolerance)
  bool identifiable = false;                ///< every parameter determined (judged with the covariance)
  /// σ̂ from all final residuals (reading units), outliers included: with a robust loss the covariance uses the
  /// loss's own variance (robust), so this reads larger than the noise when there are outliers
  double noise_sigma = 0.0;
  double fisher_condition = 0.0;            ///< condition number of the column-scaled JᵀJ
  std::string solver_report;                ///< Ceres' brief report
  SerialCorrelationReport serial_correlation;  ///< empty for refine_terms (the diagnosis whitens itself)
  /// refine_terms only: the residuals at the solution (N magnitude, 3N vector: reading-major) and their
  /// Jacobian over all parameters (zero columns for fixed ones) — what score tests need.
  Eigen::VectorXd residuals;
  Eigen::MatrixXd jacobian;
};

/// Magnitude model, starting from `start` (offset, matrix — made symmetric by its polar factor — and
/// the known field norm start.field_norm). Needs ≥ 10 finite readings. A start whose correction maps the readings
/// beyond 5× either way from start.field_norm (a Calibration given only a file's offset and matrix keeps
/// field_norm 1) has its matrix scaled to field_norm first, with a warning; so does the overload below.
RefineResult refine(const Calibration& start, const SamplesRef& samples, const RefineOptions& options = {});

/// Magnitude model with the true field magnitude of each reading (`field_norms`, N values > 0): a field that
/// changes while the sensor turns, logged by a scalar magnetometer beside it or by an observatory (its F).
/// Fitting every |h_i| to one H would put that change into the offset and matrix. The Calibration's
/// field_norm is the mean of field_norms; the summary's |h| statistics are of |h_i| − field_norms(i).
RefineResult refine(const Calibration& start, const SamplesRef& samples, const SeriesRef& field_norms,
                    const RefineOptions& options = {});

/// Vector model: `reference` holds the true field of each reading in the sensor frame (N×3, the
/// same units as the corrected field h). Starts from `start` (A⁻¹ and b). Needs ≥ 5 readings whose
/// reference directions span 3-D.
RefineResult refine_vector(const Calibration& start, const SamplesRef& samples, const SamplesRef& reference,
                           const RefineOptions& options = {});

/// Linear least-squares vector calibration (closed form, one pass): m = W r + b fitted by least
/// squares, A = W⁻¹. Covariance σ̂² (XᵀX)⁻¹ per output axis. Use refine_vector for a robust loss.
RefineResult fit_vector(const SamplesRef& samples, const SamplesRef& reference, const RefineOptions& options = {});

/// The models of the sim-to-real diagnosis (fluxcal.diagnose): the magnitude model (no `reference`) or
/// the vector model with extra terms. Reading i is modelled as m_i = (base model)_i + Σ_j c_j f_ij, where
/// f_ij (a 3-vector) is the change term j makes to reading i per unit coefficient; `features` is N × 3p,
/// column 3j + k = axis k of term j. A physical effect enters through its exact (when linear in its
/// parameters) or first-order effect on the readings. θ = [b, A (6) or W (9), c_0 … c_{p−1}], names
/// "c0", "c1", …; `fixed` names base parameters held at their start value (e.g. {"a01", "a02", "a12"}
/// for a scale-only model). Plain least squares without the noise-bias correction, so that nested
/// models are compared at the same target |h| = H. The result holds the residuals and their Jacobian.
RefineResult refine_terms(const Calibration& start, const SamplesRef& samples, const Eigen::Ref<const Eigen::MatrixXd>& features,
                          const Eigen::VectorXd& start_terms, const std::vector<std::string>& fixed = {},
                          const RefineOptions& options = {}, const SamplesRef* reference = nullptr);
/// The magnitude model of refine_terms with the true field magnitude of each reading (`field_norms`, N values
/// > 0), as refine takes them: the diagnosis of a recording whose field changed while the sensor turned. The start's
/// offset and matrix are taken as given (fixed parameters keep them), its field_norm is not used (their mean is).
RefineResult refine_terms(const Calibration& start, const SamplesRef& samples, const SeriesRef& field_norms,
                          const Eigen::Ref<const Eigen::MatrixXd>& features, const Eigen::VectorXd& start_terms,
                          const std::vector<std::string>& fixed = {}, const RefineOptions& options = {});
/// The vector model of refine_terms: reference vectors given by reference, not by pointer.
inline RefineResult refine_terms(const Calibration& start, const SamplesRef& samples,
                                 const Eigen::Ref<const Eigen::MatrixXd>& features, const Eigen::VectorXd& start_terms,
                                 const std::vector<std::string>& fixed, const RefineOptions& options,
                                 const SamplesRef& reference) {
  return refine_terms(start, samples, features, start_terms, fixed, options, &reference);
}

}  // namespace fluxcal
