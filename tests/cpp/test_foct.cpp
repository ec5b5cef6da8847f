// foct.hpp: seed 001 end to end on a simulated FOCT (chamber cycle, thermal lag, AR noise, drift of
// orders 2 / 1 / 3 over −20…0 / 0…30 / 30…50 °C), the helpers it adds, and its errors.
#include <fluxcal/foct.hpp>

#include <gtest/gtest.h>

#include "errors.hpp"
#include "foct_law.hpp"

#include <algorithm>
#include <cmath>
#include <random>
#include <string>

namespace {

struct Foct {
  Eigen::VectorXd zero_bias, temp, temp_outside, truth;
};

// Holds of 1200 s every 5 °C from −20 to 50 °C, 600 s linear ramps, 1 Hz; the device lags the chamber
// by 60 s (first order); zero bias = foct_drift_law(device) + AR(a1, a2) noise with σ = 0.05 (as fluxcal.sim.foct;
// a1 = a2 = 0: white noise, the same draws).
Foct simulate(unsigned seed, double a1 = 0.5, double a2 = -0.2) {
  std::vector<double> chamber;
  for (int level = 0; level < 15; ++level) {
    const double t = -20.0 + 5.0 * level;
    chamber.insert(chamber.end(), 1200, t);
    if (level < 14)
      for (int k = 1; k <= 600; ++k) chamber.push_back(t + 5.0 * k / 601.0);
  }
  const Eigen::Index n = static_cast<Eigen::Index>(chamber.size());
  Foct s;
  s.temp_outside = Eigen::Map<const Eigen::VectorXd>(chamber.data(), n);
  s.temp.resize(n);
  s.truth.resize(n);
  s.zero_bias.resize(n);
  const double alpha = 1.0 - std::exp(-1.0 / 60.0);
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal(0.0, 0.05);
  double device = chamber[0], y1 = 0.0, y2 = 0.0;
  for (int k = 0; k < 1000; ++k) {  // burn-in: stationary noise from the first sample
    const double y = a1 * y1 + a2 * y2 + normal(rng);
    y2 = y1;
    y1 = y;
  }
  for (Eigen::Index i = 0; i < n; ++i) {
    device = alpha * chamber[static_cast<std::size_t>(i)] + (1.0 - alpha) * device;
    s.temp[i] = std::clamp(device, -20.0, 50.0);
    s.truth[i] = foct_drift_law(s.temp[i]);
    const double y = a1 * y1 + a2 * y2 + normal(rng);
    y2 = y1;
    y1 = y;
    s.zero_bias[i] = s.truth[i] + y;
  }
  return s;
}

using fluxcal_test::error_message;  // errors.hpp

TEST(Foct, RecoversTheGeneratingOrdersAndRemovesTheDrift) {
  for (unsigned seed : {2016u, 7u}) {
    const Foct s = simulate(seed);
    fluxcal::FoctOptions options;
    options.rated = 1000.0;
    const auto fit = fluxcal::fit_foct(s.zero_bias, s.temp, options);
    EXPECT_EQ(fit.orders, (std::vector<int>{2, 1, 3})) << "seed " << seed;
    EXPECT_GE(fit.drift_reduction, 10.0) << "seed " << seed;
    EXPECT_NEAR(fit.drift_reduction, fit.drift_span_before / fit.drift_span_after, 1e-9 * fit.drift_reduction);
    // The law spans 1.4 … −2.1 A over the holds; after compensation only noise averages remain.
    EXPECT_GT(fit.drift_span_before, 3.0);
    EXPECT_LT(fit.drift_span_after, 0.01);
    // Against the truth: the fitted drift follows the law to a few mA over the whole span.
    const Eigen::VectorXd f = s.zero_bias - fit.compensated;
    EXPECT_LT((f - s.truth).cwiseAbs().maxCoeff(), 0.02) << "seed " << seed;
    // The AR model is of the noise about the drift: the generating AR(0.5, −0.2) within 4 asymptotic
    // standard errors, white residuals over 20 lags (it used to model the drift too: AR(10), rejected).
    const double se = std::sqrt((1.0 - 0.2 * 0.2) / static_cast<double>(s.zero_bias.size()));
    ASSERT_GE(fit.ar.order, 2) << "seed " << seed;
    EXPECT_FALSE(fit.ar.order_at_maximum) << "seed " << seed;
    EXPECT_NEAR(fit.ar.coefficients[0], 0.5, 4.0 * se) << "seed " << seed;
    EXPECT_NEAR(fit.ar.coefficients[1], -0.2, 4.0 * se) << "seed " << seed;
    EXPECT_EQ(fit.ar.whiteness.lags, 20);
    EXPECT_TRUE(fit.ar.whiteness.white) << "seed " << seed;
    EXPECT_NEAR(std::sqrt(fit.ar.sigma2), 0.05, 0.002) << "seed " << seed;
    // L is the drift plus the filtered noise: it follows the truth closer than the raw zero bias does.
    EXPECT_LT((fit.filtered - s.truth).norm(), (s.zero_bias - s.truth).norm()) << "seed " << seed;
    EXPECT_EQ(fit.q, fit.ar.sigma2);
    EXPECT_EQ(fit.r, fit.ar.sigma2);
    ASSERT_TRUE(fit.accuracy_drift.has_value());
    EXPECT_TRUE(fit.accuracy_drift->met);
    ASSERT_EQ(fit.accuracy->points.size(), 5u);
    EXPECT_EQ(fit.accuracy->points[0].limit_percent, 0.75);
    EXPECT_EQ(fit.filtered.size(), s.zero_bias.size());
    EXPECT_NEAR(fit.residual.cwiseAbs().maxCoeff(), fit.accuracy->max_abs_residual, 0.0);
    EXPECT_TRUE(fit.summary.converged);
    EXPECT_EQ(fit.summary.samples, static_cast<std::size_t>(s.zero_bias.size()));
    EXPECT_NE(fit.summary.message.find("drift orders 2 1 3"), std::string::npos) << fit.summary.message;
  }
}

TEST(Foct, NoiseThatIsNotWhiteAboutTheDriftIsStillFlagged) {
  // An unmodelled 0.1 A step in the 0…30 °C range, or a correlation at lag 15 (beyond max_order 10):
  // the AR model of the noise about the drift cannot whiten either and the S3.3 check must say so.
  const Foct s = simulate(2016);
  const Eigen::Index n = s.zero_bias.size();
  Eigen::VectorXd step = s.zero_bias, seasonal = s.zero_bias;
  for (Eigen::Index i = n / 2 + 300; i < n; ++i) step[i] += 0.1;
  std::mt19937_64 rng(99);
  std::normal_distribution<double> normal(0.0, 0.03);
  Eigen::VectorXd e = Eigen::VectorXd::Zero(n);
  for (Eigen::Index i = 0; i < n; ++i) e[i] = normal(rng) + (i >= 15 ? 0.3 * e[i - 15] : 0.0);
  seasonal += e;
  for (const Eigen::VectorXd* w : {&step, &seasonal}) {
    const auto fit = fluxcal::fit_foct(*w, s.temp);
    EXPECT_FALSE(fit.ar.whiteness.white) << fit.summary.message;
    const auto& warnings = fit.summary.warnings;
    EXPECT_TRUE(std::any_of(warnings.begin(), warnings.end(), [](const std::string& m) {
      return m.find("residuals are not white") != std::string::npos;
    }));
  }
}

TEST(Foct, WhiteNoiseAboutTheDriftGivesTheDriftModelWithoutAKalmanFilter) {
  // White noise about the drift (seeds 2 and 3: AIC chooses order 0; it used to stop the pipeline, the
  // filter needing p ≥ 1): nothing to predict, so no filter, L = the drift model + the noise mean, and a
  // drift model as good as with coloured noise. drift_input filtered has no noisy L to refit.
  for (unsigned seed : {2u, 3u}) {
    const Foct s = simulate(seed, 0.0, 0.0);
    fluxcal::FoctOptions options;
    options.rated = 1000.0;
    const auto fit = fluxcal::fit_foct(s.zero_bias, s.temp, options);
    ASSERT_EQ(fit.ar.order, 0) << "seed " << seed;
    EXPECT_TRUE(fit.ar.whiteness.white) << "seed " << seed;
    EXPECT_FALSE(fit.kalman_filter);
    EXPECT_EQ(fit.q, 0.0);
    EXPECT_EQ(fit.r, 0.0);
    EXPECT_EQ(fit.notes, (std::vector<std::string>{fluxcal::kWhiteNoiseNote}));
    EXPECT_EQ(fit.summary.message.rfind(std::string("FOCT drift compensation: ") + fluxcal::kWhiteNoiseNote, 0), 0u)
        << fit.summary.message;
    EXPECT_TRUE(fit.summary.warnings.empty()) << fit.summary.warnings.front();
    EXPECT_EQ(fit.orders, (std::vector<int>{2, 1, 3})) << "seed " << seed;
    EXPECT_GE(fit.drift_reduction, 10.0) << "seed " << seed;
    const Eigen::VectorXd f = s.zero_bias - fit.compensated;
    EXPECT_LT((f - s.truth).cwiseAbs().maxCoeff(), 0.02) << "seed " << seed;
    // No filter: what the user gets is the compensated zero bias, and the class check judges it (L − f, the
    // noise mean, was a constant ≈ 0 whatever the noise: a check that could not fail).
    EXPECT_EQ(fit.residual, fit.compensated);
    EXPECT_GT(fit.residual.maxCoeff() - fit.residual.minCoeff(), 0.1);
    ASSERT_TRUE(fit.accuracy_drift.has_value());
    EXPECT_TRUE(fit.accuracy_drift->met);

    fluxcal::FoctOptions filtered = options;
    filtered.drift_input = fluxcal::DriftInput::filtered;
    const auto refit = fluxcal::fit_foct(s.zero_bias, s.temp, filtered);
    EXPECT_EQ(refit.drift_input, fluxcal::DriftInput::zero_bias);
    EXPECT_EQ(refit.notes, (std::vector<std::string>{fluxcal::kWhiteNoiseNote, fluxcal::kWhiteNoiseNoRefit}));
    EXPECT_EQ(refit.compensated, fit.compensated);
    EXPECT_EQ(refit.filtered, fit.filtered);
  }
  // A white series with no drift at all (the old "AIC chose AR order 0" error case) is handled alike.
  std::mt19937_64 rng(0);
  std::normal_distribution<double> normal(0.0, 0.05);
  Eigen::VectorXd white(3000);
  for (Eigen::Index i = 0; i < white.size(); ++i) white[i] = normal(rng);
  const auto flat = fluxcal::fit_foct(white, Eigen::VectorXd::LinSpaced(white.size(), -20.0, 50.0));
  EXPECT_EQ(flat.ar.order, 0);
  EXPECT_FALSE(flat.kalman_filter);
  EXPECT_EQ(flat.notes, (std::vector<std::string>{fluxcal::kWhiteNoiseNote}));
  EXPECT_EQ(flat.orders, (std::vector<int>{0, 0, 0}));
  // An AR order fixed at 0 says the noise is white: no filter either, and Ljung–Box says when it is not.
  fluxcal::FoctOptions fixed;
  fixed.ar.order = 0;
  const auto forced = fluxcal::fit_foct(simulate(2).zero_bias, simulate(2).temp, fixed);
  EXPECT_FALSE(forced.kalman_filter);
  EXPECT_EQ(forced.notes, (std::vector<std::string>{fluxcal::kWhiteNoiseFixedNote}));
  EXPECT_FALSE(forced.ar.whiteness.white);
  EXPECT_TRUE(std::any_of(forced.summary.warnings.begin(), forced.summary.warnings.end(),
                          [](const std::string& m) { return m.find("residuals are not white") != std::string::npos; }));
}

TEST(Foct, CompensatesNewData) {
  const Foct train = simulate(11), fresh = simulate(12);
  const auto fit = fluxcal::fit_foct(train.zero_bias, train.temp);
  // On the training data compensate() is exactly what the fit reported.
  EXPECT_EQ((fit.compensate(train.zero_bias, train.temp) - fit.compensated).cwiseAbs().maxCoeff(), 0.0);
  const Eigen::VectorXd wc = fit.compensate(fresh.zero_bias, fresh.temp);
  EXPECT_LT(fluxcal::drift_span(wc, fresh.temp), 0.1 * fluxcal::drift_span(fresh.zero_bias, fresh.temp));
  Eigen::VectorXd hot = fresh.temp;
  hot[3] = 61.0;
  EXPECT_NE(error_message([&] { fit.compensate(fresh.zero_bias, hot); }).find("outside every range"), std::string::npos);
}

TEST(Foct, TemperatureDifferenceRegressor) {
  const Foct s = simulate(5);
  fluxcal::FoctOptions options;
  options.regressor = fluxcal::DriftRegressor::difference;
  options.drift.max_order = 2;
  const auto fit = fluxcal::fit_foct(s.zero_bias, s.temp, s.temp_outside, options);
  EXPECT_EQ(fit.regressor, fluxcal::DriftRegressor::difference);
  const Eigen::VectorXd diff = s.temp - s.temp_outside;
  EXPECT_EQ((fit.compensated - fit.drift.compensate(s.zero_bias, s.temp, diff)).cwiseAbs().maxCoeff(), 0.0);
  EXPECT_EQ((fit.compensate(s.zero_bias, s.temp, s.temp_outside) - fit.compensated).cwiseAbs().maxCoeff(), 0.0);
  EXPECT_NE(error_message([&] { fit.compensate(s.zero_bias, s.temp); }).find("temp_outside"), std::string::npos);
  EXPECT_EQ((fluxcal::compensate_zero_bias(fit.drift, fit.regressor, s.zero_bias, s.temp, s.temp_outside) -
             fit.compensated).cwiseAbs().maxCoeff(), 0.0);
  for (int m : fit.orders) EXPECT_LE(m, 2);
  // The difference is not the temperature that picks the range: with the device in range it can still leave what
  // the range's polynomial saw (as fluxcal.drift refuses; a model fitted over −1 … 7 °C gave −1.32 A at 20 °C).
  const fluxcal::DriftSegment& seg = fit.drift.segments.front();
  ASSERT_TRUE(std::isfinite(seg.x_lo) && seg.x_hi > seg.x_lo);
  Eigen::Index i = 0;
  while (!(s.temp[i] >= seg.lo && s.temp[i] < seg.hi)) ++i;
  Eigen::VectorXd outside = s.temp_outside;
  outside[i] = s.temp[i] - (seg.x_hi + 0.005 * (seg.x_hi - seg.x_lo));  // within the margin: evaluated
  EXPECT_NO_THROW(fit.compensate(s.zero_bias, s.temp, outside));
  outside[i] = s.temp[i] - (seg.x_hi + 0.05 * (seg.x_hi - seg.x_lo));
  const std::string said = error_message([&] { fit.compensate(s.zero_bias, s.temp, outside); });
  EXPECT_NE(said.find("regressor: sample " + std::to_string(i)), std::string::npos) << said;
  EXPECT_NE(said.find("was fitted over"), std::string::npos) << said;
}

TEST(Foct, GivenNoiseVariancesAndSteadyState) {
  const Foct s = simulate(3);
  fluxcal::FoctOptions options;
  options.q = 2e-3;
  options.r = 1e-3;
  options.kalman.steady_state = true;
  const auto fit = fluxcal::fit_foct(s.zero_bias, s.temp, options);
  EXPECT_EQ(fit.q, 2e-3);
  EXPECT_EQ(fit.r, 1e-3);
  EXPECT_TRUE(fit.steady_state);
  EXPECT_EQ(fit.orders, (std::vector<int>{2, 1, 3}));
  options.q.reset();  // R alone given: Q from the AR fit
  const auto fit_r = fluxcal::fit_foct(s.zero_bias, s.temp, options);
  EXPECT_EQ(fit_r.q, fit_r.ar.sigma2);
  EXPECT_EQ(fit_r.r, 1e-3);
}

TEST(Foct, DcGainIsTheSteadyStateResponseToAConstant) {
  Eigen::VectorXd a(2);
  a << 0.5, -0.2;
  fluxcal::KalmanOptions options;
  options.steady_state = true;
  const fluxcal::ArKalman kalman(a, 0.0025, 0.0025, options);
  const double gain = fluxcal::kalman_dc_gain(kalman);
  const Eigen::VectorXd out = kalman.filter(Eigen::VectorXd::Ones(400)).filtered;
  EXPECT_NEAR(out[399], gain, 1e-12);
  // With R → 0 the filter passes the measurement through: gain → 1.
  EXPECT_NEAR(fluxcal::kalman_dc_gain(fluxcal::ArKalman(a, 0.0025, 0.0)), 1.0, 1e-12);
}

TEST(Foct, LevelMeansAndDriftSpan) {
  Eigen::VectorXd temp(6), values(6);
  // 2.5 and 7.5 °C round half to even: to levels 0 and 10; −0.4 joins level 0 (−0 = +0).
  temp << -0.4, 2.5, 7.5, 9.0, 12.4, 4.9;
  values << 1.0, 2.0, 3.0, 5.0, 7.0, 10.0;
  const auto levels = fluxcal::level_means(values, temp);
  ASSERT_EQ(levels.size(), 3u);
  EXPECT_EQ(levels[0].level, 0.0);
  EXPECT_FALSE(std::signbit(levels[0].level));
  EXPECT_EQ(levels[0].samples, 2u);
  EXPECT_DOUBLE_EQ(levels[0].mean, 1.5);
  EXPECT_EQ(levels[1].level, 5.0);
  EXPECT_DOUBLE_EQ(levels[1].mean, 10.0);
  EXPECT_EQ(levels[2].level, 10.0);
  EXPECT_DOUBLE_EQ(levels[2].mean, 5.0);
  EXPECT_DOUBLE_EQ(fluxcal::drift_span(values, temp), 8.5);
  EXPECT_NE(error_message([&] { fluxcal::drift_span(values, temp, 0.0); }).find("level_step"), std::string::npos);
  EXPECT_NE(error_message([&] { fluxcal::drift_span(values, temp.head(5)); }).find("temp: 5 samples"), std::string::npos);
}

TEST(Foct, Accuracy) {
  Eigen::VectorXd residual(3);
  residual << 0.001, -0.006, 0.002;
  const auto acc = fluxcal::zero_bias_accuracy(residual, 1000.0, "0.2S");
  EXPECT_EQ(acc.max_abs_residual, 0.006);
  ASSERT_EQ(acc.points.size(), 5u);
  // At 1 % of 1000 A the residual 6 mA is 0.06 % (limit 0.75 %).
  EXPECT_EQ(acc.points[0].percent_rated, 1);
  EXPECT_NEAR(acc.points[0].ratio_error_percent, 0.06, 1e-15);
  EXPECT_TRUE(acc.met);
  const auto bad = fluxcal::zero_bias_accuracy(residual * 100.0, 1000.0, "0.5S");  // 0.6 A: 6 % at 1 %
  EXPECT_FALSE(bad.met);
  EXPECT_FALSE(bad.points[0].met);
  EXPECT_TRUE(bad.points[4].met);  // 0.6 A of 1200 A: 0.05 %
  EXPECT_EQ(bad.points[4].limit_percent, 0.5);
  EXPECT_NE(error_message([&] { fluxcal::zero_bias_accuracy(residual, 1000.0, "0.1"); }).find("accuracy_class"),
            std::string::npos);
  EXPECT_NE(error_message([&] { fluxcal::zero_bias_accuracy(residual, 0.0); }).find("rated"), std::string::npos);
}

TEST(Foct, BadInput) {
  const Foct s = simulate(2);
  auto message = [&](const Eigen::VectorXd& w, const Eigen::VectorXd& t, const fluxcal::FoctOptions& o = {}) {
    return error_message([&] { fluxcal::fit_foct(w, t, o); });
  };
  Eigen::VectorXd w = s.zero_bias, t = s.temp;
  w[5] = std::nan("");
  EXPECT_NE(message(w, s.temp).find("zero_bias: sample 5 is nan"), std::string::npos) << message(w, s.temp);
  t[9] = INFINITY;
  EXPECT_NE(message(s.zero_bias, t).find("temp: sample 9 is inf"), std::string::npos);
  EXPECT_NE(message(s.zero_bias, s.temp.head(100)).find("temp: 100 samples"), std::string::npos);
  EXPECT_NE(message(s.zero_bias.head(30), s.temp.head(30)).find("zero_bias: 30 samples, need at least 42"),
            std::string::npos)
      << message(s.zero_bias.head(30), s.temp.head(30));
  EXPECT_NE(message(Eigen::VectorXd::Constant(1000, 0.3), Eigen::VectorXd::LinSpaced(1000, -20, 50)).find(
                "zero_bias: constant"),
            std::string::npos);
  fluxcal::FoctOptions o;
  o.regressor = fluxcal::DriftRegressor::difference;
  EXPECT_NE(message(s.zero_bias, s.temp, o).find("temp_outside: needed"), std::string::npos);
  Eigen::VectorXd outside = s.temp_outside.head(10);
  EXPECT_NE(error_message([&] { fluxcal::fit_foct(s.zero_bias, s.temp, outside, o); }).find("temp_outside: 10 samples"),
            std::string::npos);
  o = {};
  o.r = -1.0;
  EXPECT_NE(message(s.zero_bias, s.temp, o).find("r: measurement variance"), std::string::npos);
  o = {};
  o.q = 0.0;
  EXPECT_NE(message(s.zero_bias, s.temp, o).find("q: process variance"), std::string::npos);
  o = {};
  o.rated = -5.0;
  EXPECT_NE(message(s.zero_bias, s.temp, o).find("rated"), std::string::npos);
  o.rated = 1000.0;
  o.accuracy_class = "1S";
  EXPECT_NE(message(s.zero_bias, s.temp, o).find("accuracy_class: '1S'"), std::string::npos);
}

}  // namespace

// fit_foct checks its nested options on entry, each message naming the struct and field.
TEST(FoctOptions, BadNestedValuesAreNamed) {
  const Foct s = simulate(2);
  fluxcal::FoctOptions o;
  o.ar.init_samples = -5;
  EXPECT_ERROR_SAYS(fluxcal::fit_foct(s.zero_bias, s.temp, o), "ArOptions::init_samples: -5");
  o = {};
  o.kalman.riccati_tolerance = std::nan("");
  EXPECT_ERROR_SAYS(fluxcal::fit_foct(s.zero_bias, s.temp, o), "KalmanOptions::riccati_tolerance: nan");
  o = {};
  o.preprocess.threshold = -1.0;
  EXPECT_ERROR_SAYS(fluxcal::fit_foct(s.zero_bias, s.temp, o), "PreprocessOptions::threshold: -1");
  o = {};
  o.drift.whiten_max_order = -1;
  EXPECT_ERROR_SAYS(fluxcal::fit_foct(s.zero_bias, s.temp, o), "DriftOptions::whiten_max_order: -1");
  o = {};
  o.regressor = static_cast<fluxcal::DriftRegressor>(9);  // was taken for `difference`
  EXPECT_ERROR_SAYS(fluxcal::fit_foct(s.zero_bias, s.temp, o), "FoctOptions::regressor: 9");
  o = {};
  o.drift_input = static_cast<fluxcal::DriftInput>(2);
  EXPECT_ERROR_SAYS(fluxcal::fit_foct(s.zero_bias, s.temp, o), "FoctOptions::drift_input: 2");
}

// Every temperature in one level (a lab log at 23–26 °C): both spans are 0, so the reduction is NaN and the
// message says why, rather than "reduced 0x" (a blind check).
TEST(Foct, OneTemperatureLevelHasNoReduction) {
  const int n = 3000;
  Eigen::VectorXd temp(n), zero_bias(n);
  std::mt19937 rng(3);
  std::normal_distribution<double> g(0.0, 1.0);
  for (int k = 0; k < n; ++k) {
    temp[k] = 24.5 + 1.4 * std::sin(2 * 3.14159265358979 * k / 8640.0) + 0.02 * g(rng);
    zero_bias[k] = 0.02 + 0.01 * (temp[k] - 25.0) + 0.002 * g(rng);
  }
  const auto fit = fluxcal::fit_foct(zero_bias, temp);
  EXPECT_TRUE(std::isnan(fit.drift_reduction));
  EXPECT_NE(fit.summary.message.find("one temperature level"), std::string::npos) << fit.summary.message;
}

TEST(Foct, PlayOperatorIsADeadBand) {
  // Up 0 → 3, back to 1, up to 2: a band of ±1 follows 1 behind on the way up, holds at 2 until the input
  // falls below 1, and holds again on the way back up while the input stays within 1 of it.
  Eigen::VectorXd x(8);
  x << 0.0, 1.0, 2.0, 3.0, 2.0, 1.0, 1.5, 2.0;
  Eigen::VectorXd widths(2);
  widths << 0.0, 1.0;
  const Eigen::MatrixXd y = fluxcal::play(x, widths);
  EXPECT_EQ(y.col(0), x);  // no band: the input itself
  Eigen::VectorXd expected(8);
  expected << 0.0, 0.0, 1.0, 2.0, 2.0, 2.0, 2.0, 2.0;
  EXPECT_EQ(y.col(1), expected);
  x[4] = std::nan("");
  EXPECT_NE(error_message([&] { fluxcal::play(x, widths, "temp"); }).find("temp"), std::string::npos);
  widths[1] = -1.0;
  x[4] = 2.0;
  EXPECT_NE(error_message([&] { fluxcal::play(x, widths); }).find("not ≥ 0"), std::string::npos);
}
