// fluxcal/foct.hpp — seed 001 end to end: temperature-drift compensation of a fibre-optic current
// transformer's zero bias: fluxcal.drift.fit_pipeline's core steps (below) with its defaults, equal to it on a clean
// log. Not here (Python only): the history checks that refit or warn — a zero step or ageing taken out, a thermal
// lag or hysteresis named, spikes and a frozen readout found, the temperature's unit hint — so on a log with those
// the two differ (a blind check: a 0.02 A step left in, orders [1,1,1] for [2,2,3], with only a warning that the
// residuals are not white). Fit such logs with fit_pipeline and export its model (export-c).
//
//   1. preprocess(zero_bias)                          S2: zero-mean, stationarity, normality (diagnostics)
//   2. f1 = fit_drift(zero_bias, temp | temp − temp_outside)
//                                                      S5 on the zero bias: piecewise polynomial, F-test
//                                                      orders, GLS with an AR noise model
//      noise = zero_bias − f1 − mean; fit_ar(noise)    S3: AR(p) of the noise by AIC, RLS, Ljung–Box over
//                                                      2 max_order lags (S2.3 removes the trend first: here
//                                                      the trend is the drift)
//   3. ArKalman on that AR model                      S4: Q = σ², R = σ² (or given q / r)
//      filtered = f1 + mean + filter(noise)           the drift is a known input: L follows it without lag
//      p = 0 (white noise about the drift): no filter, filtered = f1 + mean (kWhiteNoiseNote)
//   4. the drift model is f1 (DriftInput::filtered: fit_drift of L, as seed 001 writes it; see DriftInput;
//      not with p = 0, where L is f1 + mean and has nothing to refit)
//   5. compensated = zero_bias − f(T); drift span before / after (peak-to-peak of the per-level means)
//      and, with a rated current, the IEC 61869 ratio-error verdicts of the residual (L − f with a Kalman
//      filter; without one, the compensated zero bias, which is then what the user gets).
//
//   fluxcal::FoctOptions options;                      // defaults = fit_pipeline's
//   options.rated = 1000.0;                            // A: also check the 0.2S accuracy
//   const auto fit = fluxcal::fit_foct(zero_bias, temp, options);
//   fit.drift_reduction, fit.orders, fit.summary.warnings
//   Eigen::VectorXd wc = fit.compensate(new_zero_bias, new_temp);   // W_c = W − f(T)
//
// Every step is the existing solver (timeseries.hpp, kalman.hpp, drift.hpp); this file only chains
// them and adds what Python computed itself: the per-level means and drift span, the accuracy verdicts
// (and the filter's DC gain, a helper the pipeline no longer needs).
#pragma once

#include "fluxcal/drift.hpp"
#include "fluxcal/kalman.hpp"
#include "fluxcal/timeseries.hpp"

#include <Eigen/Dense>

#include <optional>
#include <string>
#include <vector>

namespace fluxcal {

/// The polynomial variable of the drift model (segments are always chosen by the device temperature).
enum class DriftRegressor {
  temperature,  ///< the device's own temperature T ("temp" in Python)
  difference,   ///< the inside/outside difference T − T_outside (seed 001 figs. 3–4)
};

/// The series the drift model (S5) is fitted to.
enum class DriftInput {
  /// The zero bias itself, by generalised least squares with an AR noise model (drift.whiten): the
  /// regression model drift(T) + AR noise is exact for it. The default.
  zero_bias,
  /// The Kalman output L (seed 001 as written), refitted after the first fit to the zero bias: L is that
  /// drift plus the filtered noise, so it follows the drift without lag. (L used to be the filtered
  /// zero bias itself, which lagged the drift on temperature ramps, a deterministic error the F-test
  /// read as an extra order: order 4 for the true 3 in the top range in 26 of 40 seeds at σ = 0.01 A.)
  filtered,
};

struct FoctOptions {
  PreprocessOptions preprocess;   ///< S2; fit_pipeline's `subseries` is preprocess.subseries (20)
  ArOptions ar;                   ///< S3; fit_pipeline's `ar_max_order` is ar.max_order (10); whiteness_lags
                                  ///< 0 = max(10, 2 max_order) here (the correlation AIC could not model)
  /// Process variance Q; unset = the AR residual variance σ².
  std::optional<double> q;
  /// Measurement variance R; unset = σ² (an AR fit cannot separate it, see ArKalman::from_ar).
  std::optional<double> r;
  KalmanOptions kalman;           ///< S4; fit_pipeline's `steady_state` is kalman.steady_state (false)
  DriftRegressor regressor = DriftRegressor::temperature;
  DriftInput drift_input = DriftInput::zero_bias;  ///< what S5 fits (see DriftInput)
  /// S5: breakpoints {−20, 0, 30, 50}, max_order 4, significance 0.05, continuous false, whiten true.
  DriftOptions drift;
  /// Width of the temperature levels whose means give the drift span (°C; Python fixes 5).
  double level_step = 5.0;
  /// Rated primary current; set it to get the accuracy verdicts (unset = no verdict).
  std::optional<double> rated;
  std::string accuracy_class = "0.2S";  ///< "0.2S" or "0.5S" (IEC 61869-2)
  /// Gaps in time (see Breaks; fluxcal.timeseries.find_breaks finds them in a time column): S2's differences,
  /// the drift's whitening, the AR model and the Kalman filter do not reach across them (the filter starts
  /// again after each). Set here, not in preprocess, ar or drift (an error there: they must agree).
  Breaks breaks;
};

/// Mean of `values` over the samples whose temperature rounds (half to even, as NumPy) to one multiple
/// of `step`: the chamber's hold levels. Ascending by level.
struct LevelMean {
  double level = 0.0;
  double mean = 0.0;
  std::size_t samples = 0;
};
std::vector<LevelMean> level_means(const SeriesRef& values, const SeriesRef& temp, double step = 5.0);

/// Peak-to-peak of the per-level means: the zero-bias drift over the temperature span, noise averaged.
double drift_span(const SeriesRef& values, const SeriesRef& temp, double step = 5.0);

/// A play operator (backlash) per half-width r ≥ 0: y_0 = x_0, y_k = clamp(y_{k−1}, x_k − r, x_k + r) — the
/// output moves only once the input has pushed it r away: a dead band, the simplest hysteresis (a sensing
/// coil's adhesive that follows the temperature late by r either way). One column per half-width; `name` is the
/// input's in errors (x must be finite).
Eigen::MatrixXd play(const SeriesRef& x, const Eigen::Ref<const Eigen::VectorXd>& half_widths,
                     const std::string& name = "x");

/// Output per unit constant input of the steady-state filter: e1ᵀ (I − F)⁻¹ K with F = (I − K e1ᵀ) A.
/// A slow drift passes the filter (which expects a zero-mean AR signal) scaled by this gain (< 1); fit_foct
/// keeps the drift out of the filter, so it does not need it.
double kalman_dc_gain(const ArKalman& kalman);

struct AccuracyPoint {
  int percent_rated = 0;             ///< 1, 5, 20, 100, 120
  double ratio_error_percent = 0.0;  ///< 100 · max|residual| / (percent_rated/100 · rated)
  double limit_percent = 0.0;        ///< IEC 61869-2 limit of the class at this current
  bool met = false;
};

struct AccuracyResult {
  std::string accuracy_class;
  double rated = 0.0;
  double max_abs_residual = 0.0;
  std::vector<AccuracyPoint> points;
  bool met = false;  ///< every point within its limit
};

/// The ratio error a residual zero bias causes at 1/5/20/100/120 % of rated current against the limits
/// of `accuracy_class` ("0.2S" or "0.5S"). Throws Error for an unknown class, rated ≤ 0 or a
/// residual that is empty or not finite.
AccuracyResult zero_bias_accuracy(const SeriesRef& residual, double rated, const std::string& accuracy_class = "0.2S");

/// W − f(x) with x = temp or temp − temp_outside as `regressor` says (temp_outside is needed for
/// DriftRegressor::difference and ignored otherwise). Throws Error for mismatched lengths, NaN/Inf, a
/// temperature outside every range of the model, or a difference beyond what its range was fitted over by
/// more than kDriftEdgeMargin of that span (DriftModel::require_fitted_x).
Eigen::VectorXd compensate_zero_bias(const DriftModel& drift, DriftRegressor regressor, const SeriesRef& zero_bias,
                                     const SeriesRef& temp, const SeriesRef* temp_outside = nullptr);
inline Eigen::VectorXd compensate_zero_bias(const DriftModel& drift, DriftRegressor regressor,
                                            const SeriesRef& zero_bias, const SeriesRef& temp,
                                            const SeriesRef& temp_outside) {
  return compensate_zero_bias(drift, regressor, zero_bias, temp, &temp_outside);
}

/// FoctResult::notes when the noise about the drift is white (AR order 0; fluxcal.drift.WHITE_NOISE_NOTE and
/// WHITE_NOISE_NO_REFIT, word for word): nothing in it is predictable from its past, so there is no state
/// for a Kalman filter and its best estimate of the noise is 0.
inline constexpr const char* kWhiteNoiseNote =
    "noise about the drift is white (AIC order 0): no Kalman filter; L = the drift model";
inline constexpr const char* kWhiteNoiseFixedNote =
    "noise about the drift is white (AR order fixed at 0): no Kalman filter; L = the drift model";
inline constexpr const char* kWhiteNoiseNoRefit =
    "drift_input 'filtered' has nothing to refit (L is the drift model): the model is the fit to the zero bias";
/// FoctResult::notes' first note when FoctOptions::breaks is set (fluxcal.drift.gaps_note, word for word).
std::string gaps_note(std::size_t gaps);

struct FoctResult {
  PreprocessResult preprocess;  ///< S2 (diagnostics of the zero bias)
  ArResult ar;                  ///< S3, of the noise: zero_bias − the first drift model − its mean
  /// The Kalman filter ran: false when the AR order is 0 (white noise about the drift; q, r, steady_state
  /// are then 0 / false and filtered = f1 + mean).
  bool kalman_filter = false;
  double q = 0.0;               ///< Kalman process variance used
  double r = 0.0;               ///< Kalman measurement variance used
  bool steady_state = false;    ///< the filter ran with its steady-state gain
  DriftRegressor regressor = DriftRegressor::temperature;
  /// What the drift model was fitted to: options.drift_input, except zero_bias when the noise is white.
  DriftInput drift_input = DriftInput::zero_bias;
  /// What the pipeline did differently and why (kWhiteNoiseNote …); empty on the usual path.
  std::vector<std::string> notes;
  DriftModel drift;             ///< S5
  std::vector<int> orders;      ///< drift polynomial order of each temperature range
  Eigen::VectorXd filtered;     ///< L = first drift model + noise mean + filter(noise)
  Eigen::VectorXd compensated;  ///< zero_bias − f
  Eigen::VectorXd residual;     ///< filtered − f (no filter: compensated): what the sample-by-sample verdict checks
  double drift_span_before = 0.0;  ///< drift_span(zero_bias)
  double drift_span_after = 0.0;   ///< drift_span(compensated)
  double drift_reduction = 0.0;    ///< before / after; NaN with one temperature level (both spans 0)
  /// With options.rated: the verdict on `residual` (drift residual plus what noise the filter leaves) …
  std::optional<AccuracyResult> accuracy;
  /// … and on the drift alone (the per-level means of `compensated`).
  std::optional<AccuracyResult> accuracy_drift;
  /// warnings: preprocessing, AR fit, with DriftInput::filtered the first drift fit's (to the zero bias,
  /// prefixed "drift fit to the zero bias: "; Python's report["warnings"] lists only these), Kalman filter,
  /// drift model (Python keeps those in the model's summary), in that order.
  Summary summary;

  /// W − f for new data (compensate_zero_bias with this model and regressor).
  Eigen::VectorXd compensate(const SeriesRef& zero_bias, const SeriesRef& temp,
                             const SeriesRef* temp_outside = nullptr) const {
    return compensate_zero_bias(drift, regressor, zero_bias, temp, temp_outside);
  }
  Eigen::VectorXd compensate(const SeriesRef& zero_bias, const SeriesRef& temp, const SeriesRef& temp_outside) const {
    return compensate_zero_bias(drift, regressor, zero_bias, temp, temp_outside);
  }
};

/// Seed 001 end to end (file comment). Throws Error naming the input for NaN/Inf, mismatched lengths,
/// too few samples (2 subseries + 2 for the stationarity test, 2 max_order + 3 for the AR fit), a
/// constant series, a missing temp_outside for the difference regressor, bad q / r /
/// rated / accuracy_class, or a temperature range with too few samples.
FoctResult fit_foct(const SeriesRef& zero_bias, const SeriesRef& temp, const SeriesRef* temp_outside,
                    const FoctOptions& options = {});
inline FoctResult fit_foct(const SeriesRef& zero_bias, const SeriesRef& temp, const SeriesRef& temp_outside,
                           const FoctOptions& options = {}) {
  return fit_foct(zero_bias, temp, &temp_outside, options);
}
inline FoctResult fit_foct(const SeriesRef& zero_bias, const SeriesRef& temp, const FoctOptions& options = {}) {
  return fit_foct(zero_bias, temp, nullptr, options);
}

}  // namespace fluxcal
