// fluxcal/timeseries.hpp — statistical pre-processing and AR(p) noise models (seed 001, S2–S3).
//
//   zero_mean            x − mean(x)
//   reverse_arrangement  stationarity test on the means of l sub-series:
//                        A = #{i<j : μi > μj}, E[A] = l(l−1)/4, Var[A] = l(2l+5)(l−1)/72,
//                        u = (A − E[A])/σ_A, stationary when |u| < threshold (1.96 by default)
//   difference           x[k] − x[k−1], repeated `order` times
//   remove_trend         x minus its least-squares polynomial in the sample index
//   normality            sample skewness, kurtosis (not excess: 3 for a normal law), Jarque–Bera
//   fit_ar               y_k = a1 y_{k−1} + … + ap y_{k−p} + r_k, no constant; order by AIC
//                        n ln σ̂²_p + 2p on one common sample of n = N − max_order rows (what
//                        statsmodels' ar_select_order(ic='aic', trend='n') does), coefficients by
//                        recursive least squares started from batch least squares on the first rows;
//                        with `breaks` (gaps in time) no row's lags reach back across a gap
//   ljung_box            Q = n(n+2) Σ_{k=1..h} ρ_k²/(n−k) against χ²(h − model_df)
//   preprocess           seed 001 S2 in one call: zero-mean, reverse-arrangement test of the once-
//                        differenced series, a second difference plus trend removal when it fails,
//                        skewness/kurtosis of the result
//
// Everything streams over the series in O(N p²) time and O(p²) memory beyond the input, so 10⁶ and
// more samples are fine.
#pragma once

#include "fluxcal/types.hpp"

#include <Eigen/Dense>

#include <string>
#include <vector>

namespace fluxcal {

// SeriesRef (types.hpp): read-only view of a series; a matrix of more than one column is an Error.

/// Gaps in time: the samples that each begin a new stretch of evenly spaced samples (the step before
/// them is not the sampling interval: a recorder paused between temperature holds, a lost sample).
/// Ascending, each in 1 … N − 1. An AR model's lags, a whitening filter and a Kalman filter's state do
/// not reach across them: splicing two stretches would model the jump between them as noise.
using Breaks = std::vector<Eigen::Index>;

/// Throws Error unless `breaks` are strictly ascending sample indices in 1 … n − 1.
void check_breaks(const Breaks& breaks, Eigen::Index n, const std::string& name);

/// The first sample of the stretch that holds sample t.
Eigen::Index stretch_start(const Breaks& breaks, Eigen::Index t);

/// The rows an AR model with `lags` lags regresses on a series of n samples: every sample at least `lags`
/// samples after the start of its stretch.
Eigen::Index regressed_rows(Eigen::Index n, const Breaks& breaks, int lags);

/// Throws Error unless `series` is finite and has at least `min_length` samples.
void check_series(const SeriesRef& series, const std::string& name, Eigen::Index min_length,
                  const std::string& purpose);

/// x − mean(x). `mean` (optional) receives the mean that was removed.
Eigen::VectorXd zero_mean(const SeriesRef& x, double* mean = nullptr);

/// x[k] − x[k−1], applied `order` times (N − order samples remain).
Eigen::VectorXd difference(const SeriesRef& x, int order = 1);

/// The first differences of each stretch between `breaks`, one after the other (each stretch gives one
/// fewer); `shifted` (optional) receives the breaks of the result.
Eigen::VectorXd difference_within(const SeriesRef& x, const Breaks& breaks, Breaks* shifted = nullptr);

/// x minus its least-squares polynomial of `degree` in the sample index (degree 1: a straight line).
Eigen::VectorXd remove_trend(const SeriesRef& x, int degree = 1);

struct ReverseArrangementResult {
  int subseries = 0;        ///< l
  long long arrangements = 0;  ///< A = number of pairs i < j with μi > μj
  double expected = 0.0;    ///< E[A] = l(l−1)/4
  double variance = 0.0;    ///< Var[A] = l(2l+5)(l−1)/72
  double u = 0.0;           ///< (A − E[A]) / σ_A
  bool stationary = false;  ///< |u| < threshold
  Eigen::VectorXd means;    ///< μ1 … μl
};

/// Reverse-arrangement test on the means of `subseries` consecutive sub-series (sub-series k holds
/// samples [k N / l, (k+1) N / l)). Needs l ≥ 3 and N ≥ 2 l.
ReverseArrangementResult reverse_arrangement(const SeriesRef& x, int subseries = 20, double threshold = 1.96);

struct NormalityResult {
  double skewness = 0.0;     ///< m3 / m2^1.5 (biased moments, as scipy.stats.skew)
  double kurtosis = 0.0;     ///< m4 / m2² (3 for a normal law; not the excess)
  double jarque_bera = 0.0;  ///< N/6 (S² + (K − 3)²/4)
  double p_value = 0.0;      ///< P(χ²(2) > JB) = exp(−JB/2)
  bool normal = false;       ///< p_value > significance
};

NormalityResult normality(const SeriesRef& x, double significance = 0.05);

struct LjungBoxResult {
  int lags = 0;            ///< h
  int model_df = 0;        ///< degrees of freedom taken by the model (the AR order)
  double statistic = 0.0;  ///< Q
  double p_value = 0.0;    ///< P(χ²(h − model_df) > Q); NaN when h ≤ model_df
  bool white = false;      ///< p_value > significance
};

/// Ljung–Box portmanteau test of `x` (autocorrelations of the demeaned series, as statsmodels'
/// acorr_ljungbox). Needs 0 < lags < N. With `breaks` (gaps in time, see Breaks) a lag-k product pairs
/// two samples of one stretch only, and n − k becomes the number of such pairs; a lag no stretch is long
/// enough for is left out (`lags` then counts the lags tested).
LjungBoxResult ljung_box(const SeriesRef& x, int lags, int model_df = 0, double significance = 0.05,
                         const Breaks& breaks = {});

struct ArOptions {
  /// Largest order AIC may choose (orders 0 … max_order are scored on the common sample).
  int max_order = 10;
  /// Fixed order instead of AIC (−1 = choose by AIC).
  int order = -1;
  /// Regression rows of the batch least-squares start of the recursive least squares (raised to
  /// 2 p when smaller, so the start is determined).
  int init_samples = 20;
  /// RLS forgetting factor λ ∈ (0, 1]; 1 = every row weighs the same (then the result is the batch
  /// least-squares solution, up to rounding).
  double forgetting = 1.0;
  /// Ljung–Box lags for the residual whiteness check (0 = max(10, 2p), at most (N − p)/2).
  int whiteness_lags = 0;
  double significance = 0.05;  ///< of the whiteness check
  /// Gaps in time (see Breaks): a row is regressed only when its lags lie in its own stretch, so each
  /// stretch loses its first p rows (AIC: its first max_order rows) instead of splicing across the gap.
  Breaks breaks;
};

struct ArResult {
  int order = 0;                 ///< p
  Eigen::VectorXd coefficients;  ///< a1 … ap
  double sigma2 = 0.0;           ///< residual variance SSR / (N − p) (statsmodels AutoReg's sigma2)
  /// Covariance of the coefficients: σ̂²(XᵀX)⁻¹ over the regression rows (statsmodels AutoReg's cov_params) when
  /// forgetting = 1; with λ < 1 the weighted fit's sandwich σ̂² P (Σ w_t² x_t x_tᵀ) P, w_t = λ^(T−t), P = (Σ w_t x_t x_tᵀ)⁻¹
  /// — the spread of the final estimate over a memory of about 1/(1 − λ) rows.
  Eigen::MatrixXd covariance;
  Eigen::VectorXd standard_errors;  ///< √diag(covariance)
  Eigen::VectorXd aic;           ///< AIC(p) = n ln σ̂²_p + 2p for p = 0 … max_order (common sample)
  bool order_at_maximum = false; ///< AIC chose max_order: the noise may have longer memory
  Eigen::VectorXd residuals;     ///< r_k for k = p … N−1 (with breaks: of each stretch's rows from its p-th on)
  LjungBoxResult whiteness;      ///< of the residuals, model_df = p
  Summary summary;
};

/// AR(p) fit of a (zero-mean) series. Needs N > 2 max_order + 2 (or 2 order + 2 for a fixed order)
/// finite samples, not all equal, and with breaks more than max_order + 2 rows whose lags stay in their
/// stretch.
ArResult fit_ar(const SeriesRef& y, const ArOptions& options = {});

struct PreprocessOptions {
  int subseries = 20;        ///< l of the reverse-arrangement test
  double threshold = 1.96;   ///< |u| below it: stationary (1.96 = 5 % two-sided)
  int trend_degree = 1;      ///< polynomial removed after the second difference (S2.3)
  double significance = 0.05;  ///< of the normality check
  /// Gaps in time (see Breaks): differences are taken within each stretch (a difference across a gap is
  /// the jump between two stretches, not a step of the series).
  Breaks breaks;
};

struct PreprocessResult {
  double mean = 0.0;                       ///< removed by the zero-mean step (S2.1)
  Eigen::VectorXd series;                  ///< the stationary series (differenced once, or twice and detrended)
  int differences = 1;                     ///< 1 or 2
  ReverseArrangementResult stationarity;   ///< of the once-differenced series (S2.2)
  /// Of the twice-differenced, detrended series when `differences` = 2 (its stationarity is reported,
  /// not enforced: a series that fails it has a drift S2 cannot remove).
  ReverseArrangementResult stationarity_after;
  NormalityResult normality;               ///< of `series` (S2.4)
  Summary summary;                         ///< warnings when the final series is still not stationary / not normal
};

/// Seed 001 S2 on a raw series. Needs enough samples for l sub-series of the twice-differenced series
/// (N ≥ 2 l + 2) and a non-constant series.
PreprocessResult preprocess(const SeriesRef& x, const PreprocessOptions& options = {});

/// P(χ²(df) > x) (regularised upper incomplete gamma Q(df/2, x/2)).
double chi2_sf(double x, double df);
/// P(F(1, df) > x) (regularised incomplete beta I_{df/(df+x)}(df/2, 1/2)).
double f1_sf(double x, double df);
/// P(F(d1, d2) > x) (I_{d2/(d2+d1 x)}(d2/2, d1/2)); d2 = +inf gives the χ² limit P(χ²(d1) > d1 x).
double f_sf(double x, double d1, double d2);

}  // namespace fluxcal
