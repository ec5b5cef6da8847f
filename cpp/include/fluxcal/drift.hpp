// fluxcal/drift.hpp — piecewise polynomial temperature-drift model (seed 001, S5).
//
// Within each temperature range [lo, hi] the drift is Y = T A + e with T the Vandermonde matrix
// [1 x x² … x^m] of the regressor x (the device temperature or the inside/outside difference).
// Columns are balanced by their maximum |value| before least squares (same SSE, far smaller
// condition number), A solved by a column-pivoted QR. The order m rises from 0 while the F-test
//   F = (SSE_m − SSE_{m+1}) / (SSE_{m+1} / (N − m − 2))  >  F(1, N − m − 2; significance)
// says the next power is significant — or, when it is not, the next two together (F(2, N − m − 3) at the significance
// squared: a drift even about the range's middle has no linear term) — up to max_order and one below the regressor's separate levels
// (values within 5 % of the range's width are one level: two temperature holds determine a line). Optionally the segments are refitted jointly
// with equality constraints so the drift is continuous at the breakpoints. A sample belongs to the
// range [lo, hi) of its selecting temperature (the last range includes hi). A random-walk-like noise (its
// AR coefficients summing above 0.98) is not used to weight the fit: it would leave each range's level
// to the rows at its edges.
#pragma once

#include "fluxcal/timeseries.hpp"

#include <Eigen/Dense>

#include <limits>

#include <vector>

namespace fluxcal {

struct DriftOptions {
  /// Range edges of the selecting temperature, ascending: k + 1 edges make k ranges. fit_drift makes them
  /// cover the data: the outer edges move to the coldest and hottest sample, inner edges outside the data
  /// go, and a range with fewer than min_samples samples joins its thinner neighbour (the summary says so).
  std::vector<double> breakpoints = {-20.0, 0.0, 30.0, 50.0};
  int max_order = 4;
  double significance = 0.05;  ///< of the F-test (seed 001: 0.05 or 0.01)
  /// Fixed order for every segment (−1 = choose by F-test).
  int order = -1;
  bool continuous = false;     ///< refit with continuity of the drift at the inner breakpoints
  /// Fewest samples a range must hold (it needs at least order + 2 anyway).
  int min_samples = 10;
  /// Generalised least squares for correlated noise: pre-fit every range at its highest order, fit
  /// an AR model (order by AIC ≤ whiten_max_order) to the residual, and run the fits and F-tests on
  /// rows whitened by that AR filter. Without it the F-test assumes white noise and, on AR noise
  /// (and on Kalman-smoothed data even more), keeps too many orders.
  bool whiten = true;
  /// Cost O(N · whiten_max_order²) for N samples: keep it to tens (10 000 samples at 5 000 takes minutes).
  int whiten_max_order = 10;
  /// Gaps in time (see Breaks): the whitening filter does not reach across them (a stretch's first p rows
  /// are not whitened, as a range's first rows are not), and its AR model is fitted within the stretches.
  Breaks breaks;
};

/// Beyond the values a range was fitted over, the share of their span still evaluated: a later log at the same
/// holds reads a little beyond the fit's extremes half the time (fluxcal.drift.EDGE_MARGIN).
constexpr double kDriftEdgeMargin = 0.01;

struct DriftSegment {
  double lo = 0.0, hi = 0.0;
  int order = 0;
  Eigen::VectorXd coefficients;  ///< c0 … cm of f(x) = Σ c_i x^i (unbalanced, in data units)
  std::size_t samples = 0;
  double sse = 0.0;
  double residual_rms = 0.0;
  double condition_number = 0.0;  ///< of the balanced Vandermonde matrix
  std::vector<double> f_statistics;  ///< F of each step tested: m → m+1, and m → m+2 (2 dof) after one that fails
  /// Covariance of the coefficients (data units), at the chosen order: generalised least squares' σ̂²(VᵀΣ⁻¹V)⁻¹
  /// with the AR noise model's Σ when the fit was whitened; σ̂²(VᵀV)⁻¹ when AIC found the noise white; when no
  /// model whitened it (whiten off, a noise near a random walk) least squares' sandwich under an AR model (by AIC)
  /// of the residuals in time order across the ranges, fitted for the errors alone — the prewhitened Newey–West
  /// sandwich only when none can be fitted. Of a continuous refit, its block of the constrained least squares'
  /// sandwich under the AR model (or as above). Conditional on the order the F-tests chose (the model's uncertainty
  /// at that order, not the order's). The AR model they rest on summing above 0.95 (or a noise near a random walk)
  /// makes them lower bounds, and summary.warnings says so.
  Eigen::MatrixXd covariance;
  Eigen::VectorXd standard_errors;  ///< √diag(covariance)
  /// The regressor's values the polynomial was fitted over (the inside–outside difference is not the temperature
  /// that selects the range, so it can leave them while the temperature stays in range); NaN when not known.
  double x_lo = std::numeric_limits<double>::quiet_NaN(), x_hi = std::numeric_limits<double>::quiet_NaN();
};

struct DriftModel {
  std::vector<DriftSegment> segments;
  Eigen::VectorXd noise_ar;  ///< AR coefficients used for whitening (empty: none)
  Summary summary;
  /// The note that the ranges were adjusted to the data (also the first of summary.warnings), empty when they
  /// were used as given: a note on how the ranges were set, not on the model's validity.
  std::string range_note;
  /// The drift f(x) of each sample; `select` decides the segment. Throws Error for a sample whose
  /// selecting temperature is outside every range.
  Eigen::VectorXd evaluate(const SeriesRef& select, const SeriesRef& x) const;
  /// The standard error of f(x) of each sample, √(vᵀ C v) with v = (1, x, …, x^m) and C the segment's covariance
  /// (the drift's uncertainty, which compensation adds to each sample's own noise). Throws Error as evaluate does,
  /// and for a segment without a covariance (a model built by hand).
  Eigen::VectorXd standard_error(const SeriesRef& select, const SeriesRef& x) const;
  /// W − f(x).
  Eigen::VectorXd compensate(const SeriesRef& w, const SeriesRef& select, const SeriesRef& x) const;
  /// Throws Error naming the first sample whose x lies beyond what its range's polynomial was fitted over
  /// (DriftSegment::x_lo … x_hi) by more than `margin` of that span: the polynomials are not extrapolated.
  /// Segments without x_lo/x_hi are not checked.
  void require_fitted_x(const SeriesRef& select, const SeriesRef& x, double margin) const;
};

/// Fit the drift of `w` (e.g. the Kalman-filtered zero bias) in the regressor `x`, segments chosen by
/// the temperature `select` (pass the same series twice for the device temperature).
DriftModel fit_drift(const SeriesRef& select, const SeriesRef& x, const SeriesRef& w, const DriftOptions& options = {});

/// Polynomial least squares of one order with balanced columns; returns coefficients in data units.
Eigen::VectorXd fit_polynomial(const SeriesRef& x, const SeriesRef& w, int order, double* sse = nullptr,
                               double* condition = nullptr);

}  // namespace fluxcal
