#include "fluxcal/foct.hpp"

#include "checks.hpp"
#include "linalg.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <initializer_list>
#include <map>
#include <sstream>
#include <utility>

namespace fluxcal {

namespace {

// IEC 61869-2 ratio-error limits (± %) at 1 / 5 / 20 / 100 / 120 % of rated current.
constexpr int kCurrentPoints[5] = {1, 5, 20, 100, 120};
struct ClassLimits {
  const char* name;
  double limits[5];
};
constexpr ClassLimits kClasses[] = {{"0.2S", {0.75, 0.35, 0.2, 0.2, 0.2}}, {"0.5S", {1.5, 0.75, 0.5, 0.5, 0.5}}};

const ClassLimits& class_limits(const std::string& accuracy_class) {
  for (const auto& c : kClasses)
    if (accuracy_class == c.name) return c;
  std::string known;
  for (const auto& c : kClasses) known += (known.empty() ? "" : ", ") + std::string(c.name);
  throw Error("accuracy_class: '" + accuracy_class + "' is not one of " + known);
}

// The steps report a bad series as "series: …"; in the pipeline that series is the zero bias.
template <class Step>
auto naming_zero_bias(Step&& step) -> decltype(step()) {
  try {
    return step();
  } catch (const Error& e) {
    const std::string message = e.what(), generic = "series:";
    if (message.compare(0, generic.size(), generic) == 0) throw Error("zero_bias:" + message.substr(generic.size()));
    throw;
  }
}

std::string number(double v) {
  std::ostringstream o;
  o << v;
  return o.str();
}

}  // namespace

std::vector<LevelMean> level_means(const SeriesRef& values, const SeriesRef& temp, double step) {
  check_series(values, "values", 1, "for level means");
  check_series(temp, "temp", 0, "");
  if (temp.size() != values.size())
    throw Error("temp: " + std::to_string(temp.size()) + " samples, values has " + std::to_string(values.size()));
  if (!(std::isfinite(step) && step > 0.0)) throw Error("level_step: " + number(step) + " must be > 0");
  // std::map orders the levels; −0 and +0 compare equal, so they share a level (as np.unique merges them).
  std::map<double, std::pair<double, std::size_t>> sums;
  for (Eigen::Index i = 0; i < values.size(); ++i) {
    auto& s = sums[std::nearbyint(temp[i] / step) * step];  // nearbyint: half to even, like np.round
    s.first += values[i];
    ++s.second;
  }
  std::vector<LevelMean> out;
  out.reserve(sums.size());
  for (const auto& [level, s] : sums) out.push_back({level + 0.0, s.first / static_cast<double>(s.second), s.second});
  return out;
}

double drift_span(const SeriesRef& values, const SeriesRef& temp, double step) {
  const auto means = level_means(values, temp, step);
  const auto [lo, hi] = std::minmax_element(means.begin(), means.end(),
                                            [](const LevelMean& a, const LevelMean& b) { return a.mean < b.mean; });
  return hi->mean - lo->mean;
}

Eigen::MatrixXd play(const SeriesRef& x, const Eigen::Ref<const Eigen::VectorXd>& half_widths,
                     const std::string& name) {
  check_series(x, name, 1, "for a play operator");
  for (double r : half_widths)
    if (!(r >= 0.0)) throw Error("play: half-width " + detail::num(r) + " of " + name + " is not ≥ 0");
  Eigen::MatrixXd out(x.size(), half_widths.size());
  for (Eigen::Index j = 0; j < half_widths.size(); ++j) {
    const double r = half_widths[j];
    double state = x[0];
    for (Eigen::Index k = 0; k < x.size(); ++k) {
      state = std::clamp(state, x[k] - r, x[k] + r);
      out(k, j) = state;
    }
  }
  return out;
}

double kalman_dc_gain(const ArKalman& kalman) {
  const Eigen::Index n = kalman.order();
  Eigen::MatrixXd a = Eigen::MatrixXd::Zero(n, n);
  a.row(0) = kalman.coefficients().transpose();
  for (Eigen::Index i = 1; i < n; ++i) a(i, i - 1) = 1.0;
  const Eigen::VectorXd k = kalman.steady_state_gain();
  Eigen::MatrixXd ikc = Eigen::MatrixXd::Identity(n, n);
  ikc.col(0) -= k;  // I − K e1ᵀ
  const Eigen::MatrixXd f = ikc * a;
  const double gain = detail::PartialPivLu(Eigen::MatrixXd::Identity(n, n) - f).solve(k)[0];
  if (!(std::isfinite(gain) && gain > 0.0))
    throw Error("kalman: DC gain " + number(gain) + " is not > 0, the steady-state filter does not pass a constant");
  return gain;
}

AccuracyResult zero_bias_accuracy(const SeriesRef& residual, double rated, const std::string& accuracy_class) {
  const ClassLimits& limits = class_limits(accuracy_class);
  if (!(std::isfinite(rated) && rated > 0.0)) throw Error("rated: " + number(rated) + " must be > 0");
  check_series(residual, "residual", 1, "for an accuracy verdict");
  AccuracyResult res;
  res.accuracy_class = accuracy_class;
  res.rated = rated;
  res.max_abs_residual = residual.cwiseAbs().maxCoeff();
  res.met = true;
  for (int i = 0; i < 5; ++i) {
    AccuracyPoint p;
    p.percent_rated = kCurrentPoints[i];
    p.ratio_error_percent = 100.0 * res.max_abs_residual / (kCurrentPoints[i] / 100.0 * rated);
    p.limit_percent = limits.limits[i];
    p.met = p.ratio_error_percent <= p.limit_percent;
    res.met = res.met && p.met;
    res.points.push_back(p);
  }
  return res;
}

namespace {

// The drift model's polynomial variable; `storage` keeps the difference alive while the view is used.
SeriesRef regressor_values(DriftRegressor regressor, const SeriesRef& temp, const SeriesRef* temp_outside,
                           Eigen::VectorXd& storage) {
  // an out-of-range value (a cast int) would otherwise be taken for `difference`
  detail::require_enum("regressor", regressor, 2, "temperature, difference (0 … 1)");
  if (regressor == DriftRegressor::temperature) return temp;  // temp_outside is not used (as in Python)
  if (!temp_outside) throw Error("temp_outside: needed for the inside/outside temperature difference regressor");
  check_series(*temp_outside, "temp_outside", 0, "");
  if (temp_outside->size() != temp.size())
    throw Error("temp_outside: " + std::to_string(temp_outside->size()) + " samples, temp has " +
                std::to_string(temp.size()));
  storage = temp - *temp_outside;
  return storage;
}

}  // namespace

Eigen::VectorXd compensate_zero_bias(const DriftModel& drift, DriftRegressor regressor, const SeriesRef& zero_bias,
                                     const SeriesRef& temp, const SeriesRef* temp_outside) {
  check_series(zero_bias, "zero_bias", 0, "");
  check_series(temp, "temp", 0, "");
  if (temp.size() != zero_bias.size())
    throw Error("temp: " + std::to_string(temp.size()) + " samples, zero_bias has " + std::to_string(zero_bias.size()));
  Eigen::VectorXd storage;
  const SeriesRef x = regressor_values(regressor, temp, temp_outside, storage);
  Eigen::VectorXd out = drift.compensate(zero_bias, temp, x);
  if (regressor == DriftRegressor::difference) drift.require_fitted_x(temp, x, kDriftEdgeMargin);
  return out;
}

std::string gaps_note(std::size_t gaps) {
  return std::to_string(gaps) + (gaps == 1 ? " gap" : " gaps") +
         " in time: the whitening, the AR model and the Kalman filter do not reach across them, the filter "
         "starts again after each";
}

FoctResult fit_foct(const SeriesRef& zero_bias, const SeriesRef& temp, const SeriesRef* temp_outside,
                    const FoctOptions& options) {
  // Inputs and options first, so a bad call fails before any work. (q, r, rated, level_step keep the
  // words of fluxcal.drift.fit_pipeline, which tests/python/test_foct_pipeline.py holds them to.)
  detail::check(options.preprocess);
  detail::check(options.ar);
  detail::check(options.kalman);
  detail::check(options.drift);
  detail::require_enum("FoctOptions::regressor", options.regressor, 2, "temperature, difference (0 … 1)");
  detail::require_enum("FoctOptions::drift_input", options.drift_input, 2, "zero_bias, filtered (0 … 1)");
  if (!options.ar.breaks.empty() || !options.drift.breaks.empty() || !options.preprocess.breaks.empty())
    throw Error("FoctOptions::" +
                std::string(!options.ar.breaks.empty() ? "ar" : !options.drift.breaks.empty() ? "drift" : "preprocess") +
                ".breaks: set FoctOptions::breaks instead (the drift, the AR model and the filter share the gaps)");
  const int ar_order = options.ar.order >= 0 ? options.ar.order : options.ar.max_order;
  const Eigen::Index need = std::max<Eigen::Index>(2 * static_cast<Eigen::Index>(options.preprocess.subseries) + 2,
                                                   2 * static_cast<Eigen::Index>(ar_order) + 3);
  check_series(zero_bias, "zero_bias", need,
               "(the stationarity test on " + std::to_string(options.preprocess.subseries) +
                   " sub-series and an AR model of order up to " + std::to_string(ar_order) + ")");
  check_series(temp, "temp", 0, "");
  if (temp.size() != zero_bias.size())
    throw Error("temp: " + std::to_string(temp.size()) + " samples, zero_bias has " + std::to_string(zero_bias.size()));
  if (!((zero_bias.array() != zero_bias[0]).any()))
    throw Error("zero_bias: constant (every sample equals " + number(zero_bias[0]) + "), there is nothing to model");
  if (options.q && !(std::isfinite(*options.q) && *options.q > 0.0))
    throw Error("q: process variance " + number(*options.q) + " must be > 0");
  if (options.r && !(std::isfinite(*options.r) && *options.r >= 0.0))
    throw Error("r: measurement variance " + number(*options.r) + " must be ≥ 0");
  if (options.rated) {
    if (!(std::isfinite(*options.rated) && *options.rated > 0.0))
      throw Error("rated: " + number(*options.rated) + " must be > 0");
    class_limits(options.accuracy_class);
  }
  if (!(std::isfinite(options.level_step) && options.level_step > 0.0))
    throw Error("level_step: " + number(options.level_step) + " must be > 0");
  check_breaks(options.breaks, zero_bias.size(), "FoctOptions::breaks");
  Eigen::VectorXd difference_storage;
  const SeriesRef x = regressor_values(options.regressor, temp, temp_outside, difference_storage);

  FoctResult res;
  Summary& sum = res.summary;
  // S2 (diagnostics of the zero bias).
  PreprocessOptions preprocess_options = options.preprocess;
  preprocess_options.breaks = options.breaks;
  res.preprocess = naming_zero_bias([&] { return preprocess(zero_bias, preprocess_options); });
  // S2.3 removes the trend before the AR model; here the trend is the temperature drift, so S3 fits the
  // zero bias minus a first drift model (S5 on the zero bias, GLS): the noise. Fitted to the zero bias
  // itself the AR model also had to describe the drift (AIC went to max_order, Ljung–Box rejected it).
  DriftOptions drift_options = options.drift;
  drift_options.breaks = options.breaks;
  const DriftModel first = fit_drift(temp, x, zero_bias, drift_options);
  const Eigen::VectorXd drift_first = first.evaluate(temp, x);
  const Eigen::VectorXd about_drift = zero_bias - drift_first;
  double noise_mean = 0.0;
  const Eigen::VectorXd noise = zero_mean(about_drift, &noise_mean);
  if (!options.breaks.empty()) res.notes.push_back(gaps_note(options.breaks.size()));
  ArOptions ar_options = options.ar;
  // Ljung–Box over twice the largest order AIC may take, so correlation beyond max_order is tested too.
  if (ar_options.whiteness_lags <= 0) ar_options.whiteness_lags = std::max(10, 2 * ar_order);
  ar_options.breaks = options.breaks;
  res.ar = naming_zero_bias([&] { return fit_ar(noise, ar_options); });

  // S4. The drift is a known input of the state-space model: the filter runs on the noise only and L adds
  // the drift back, so L follows the drift without lag or DC-gain loss on the temperature ramps.
  res.drift_input = options.drift_input;
  KalmanResult run;
  res.kalman_filter = res.ar.order > 0;
  if (res.kalman_filter) {
    // Q (and R unless given) from the AR fit, or both as given.
    const ArKalman kalman = options.q ? ArKalman(res.ar.coefficients, *options.q,
                                                 options.r.value_or(res.ar.sigma2), options.kalman)
                                      : ArKalman::from_ar(res.ar, options.r.value_or(-1.0), options.kalman);
    res.q = kalman.q();
    res.r = kalman.r();
    res.steady_state = options.kalman.steady_state;
    run = kalman.filter(noise, options.breaks);
    res.filtered = (drift_first.array() + noise_mean + run.filtered.array()).matrix();
  } else {
    // White noise about the drift: nothing in it is predictable from its past, so there is no state to
    // track and the best estimate of the noise is 0: L = f1 + mean, the drift model (q = r = 0, unused).
    res.filtered = (drift_first.array() + noise_mean).matrix();
    res.notes.push_back(options.ar.order == 0 ? kWhiteNoiseFixedNote : kWhiteNoiseNote);
    if (res.drift_input == DriftInput::filtered) {  // a refit to a noiseless L is degenerate
      res.notes.push_back(kWhiteNoiseNoRefit);
      res.drift_input = DriftInput::zero_bias;
    }
  }

  // S5 and compensation.
  res.regressor = options.regressor;
  // DriftInput::filtered refits S5 on L (seed 001 as written); by default the first model is the model.
  res.drift = res.drift_input == DriftInput::zero_bias ? first : fit_drift(temp, x, res.filtered, drift_options);
  for (const auto& seg : res.drift.segments) res.orders.push_back(seg.order);
  const Eigen::VectorXd f = res.drift.evaluate(temp, x);
  res.compensated = zero_bias - f;
  // What the user gets, less the drift model: the Kalman output, or with no filter (white noise) the
  // compensated zero bias itself (L − f would be a constant, and the class check could not fail)
  res.residual = res.kalman_filter ? Eigen::VectorXd(res.filtered - f) : res.compensated;
  res.drift_span_before = drift_span(zero_bias, temp, options.level_step);
  res.drift_span_after = drift_span(res.compensated, temp, options.level_step);
  // One temperature level (every sample in one level_step bin): both spans are 0 and say nothing: NaN.
  res.drift_reduction = level_means(zero_bias, temp, options.level_step).size() < 2
                            ? std::numeric_limits<double>::quiet_NaN()
                            : res.drift_span_before / std::max(res.drift_span_after, 1e-300);
  if (options.rated) {
    res.accuracy = zero_bias_accuracy(res.residual, *options.rated, options.accuracy_class);
    const auto levels = level_means(res.compensated, temp, options.level_step);
    Eigen::VectorXd means(static_cast<Eigen::Index>(levels.size()));
    for (std::size_t i = 0; i < levels.size(); ++i) means[static_cast<Eigen::Index>(i)] = levels[i].mean;
    res.accuracy_drift = zero_bias_accuracy(means, *options.rated, options.accuracy_class);
  }

  sum.samples = static_cast<std::size_t>(zero_bias.size());
  sum.residual_rms = std::sqrt(res.residual.squaredNorm() / static_cast<double>(res.residual.size()));
  sum.cost = res.drift.summary.cost;
  sum.condition_number = res.drift.summary.condition_number;
  sum.converged = true;
  // Warnings: S2's, S3's, the first drift fit's when the model is a refit to L (otherwise they are the model's,
  // below), the filter's and the drift model's.
  sum.warnings = res.preprocess.summary.warnings;
  sum.warnings.insert(sum.warnings.end(), res.ar.summary.warnings.begin(), res.ar.summary.warnings.end());
  if (res.drift_input == DriftInput::filtered)
    for (const std::string& w : first.summary.warnings) sum.warnings.push_back("drift fit to the zero bias: " + w);
  for (const Summary* part : {&run.summary, &res.drift.summary})
    sum.warnings.insert(sum.warnings.end(), part->warnings.begin(), part->warnings.end());
  std::ostringstream msg;
  msg << "FOCT drift compensation: ";
  if (res.kalman_filter)
    msg << "AR(" << res.ar.order << ") noise model and Kalman filter";
  else
    for (std::size_t i = 0; i < res.notes.size(); ++i) msg << (i ? "; " : "") << res.notes[i];
  msg << ", drift orders";
  for (int m : res.orders) msg << " " << m;
  msg << " in " << (res.regressor == DriftRegressor::temperature ? "temp" : "temp - temp_outside") << ", drift span "
      << res.drift_span_before << " -> " << res.drift_span_after;
  if (std::isnan(res.drift_reduction))
    msg << " (one temperature level: no span to compare)";
  else
    msg << " (reduced " << res.drift_reduction << "x)";
  if (res.accuracy_drift)
    msg << ", class " << options.accuracy_class << (res.accuracy_drift->met ? " met" : " NOT met") << " by the drift";
  sum.message = msg.str();
  return res;
}

}  // namespace fluxcal
