// Internal (not installed): standard errors when the readings are correlated in time — the residuals' test
// and the prewhitened Newey–West sandwich, shared by refine and the alignment.
#pragma once

#include "fluxcal/types.hpp"

#include <string>

namespace fluxcal::detail {

/// F⁻¹ of an information matrix F through the eigen-decomposition of the column-scaled F: near-null directions get a
/// huge (not infinite) variance, so undetermined parameters show up as such instead of as a failed factorisation.
struct ScaledInverse {
  Eigen::MatrixXd inverse;
  double condition = 0.0;  ///< of the column-scaled F (inf: singular)
  bool singular = false;   ///< an eigenvalue at the floor (1e-300 of the largest): no sandwich is defined
};
ScaledInverse scaled_inverse(const Eigen::MatrixXd& F);

/// Long-run covariance of the scores (N×p, rows in time order), prewhitened; `lags` gets the bandwidth.
Eigen::MatrixXd prewhitened_long_run(const Eigen::MatrixXd& scores, int& lags);

/// Tests `residuals` (N×k, k per reading, time order) for correlation in time (Ljung–Box, Bonferroni over the
/// k columns) and, as `mode` says, replaces `covariance` (the independent-readings one: σ̂² F⁻¹, or TWOSTEP's HC2
/// sandwich; F⁻¹ = `Finv`) by the Newey–West sandwich F⁻¹ S F⁻¹ · N/(N − p), S the prewhitened long-run covariance of the `scores` g_i = Σ_a J_ia r_ia (N×p).
/// Fills `report`; returns the warning to give when the sandwich was taken, else "". `singular`: F had an
/// undetermined direction (no sandwich). Throws Error when alpha is not in (0, 1).
std::string correct_for_serial_correlation(Eigen::MatrixXd& covariance, SerialCorrelationReport& report,
                                           const Eigen::MatrixXd& residuals, const Eigen::MatrixXd& scores,
                                           const Eigen::MatrixXd& Finv, bool singular, SerialCorrelation mode,
                                           double alpha);

}  // namespace fluxcal::detail
