// kalman.hpp and fixed_kalman.hpp: the double filter's properties and the fixed-point filter against
// golden vectors of its bit-exact Python integer model (fluxcal.oracle.kalman).
#include <fluxcal/fixed_kalman.hpp>
#include <fluxcal/kalman.hpp>

#include <gtest/gtest.h>

#include "errors.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <random>

#include "fixed_kalman_golden.inc"

namespace {

TEST(Kalman, TimeVaryingConvergesToSteadyState) {
  Eigen::VectorXd a(3);
  a << 0.6, -0.3, 0.2;
  const fluxcal::ArKalman tv(a, 0.5, 0.3);
  fluxcal::KalmanOptions options;
  options.steady_state = true;
  const fluxcal::ArKalman ss(a, 0.5, 0.3, options);
  std::mt19937_64 rng(1);
  std::normal_distribution<double> normal;
  Eigen::VectorXd y(3000);
  for (auto& v : y) v = normal(rng);
  const auto r1 = tv.filter(y), r2 = ss.filter(y);
  EXPECT_NEAR((r1.gain - r2.gain).cwiseAbs().maxCoeff(), 0.0, 1e-10);
  // Once the gain has converged the two outputs coincide.
  EXPECT_NEAR((r1.filtered.tail(1000) - r2.filtered.tail(1000)).cwiseAbs().maxCoeff(), 0.0, 1e-9);
  // The stationary covariance solves P = A P Aᵀ + Q e1 e1ᵀ.
  const Eigen::MatrixXd p = fluxcal::ar_stationary_covariance(a, 0.5);
  Eigen::MatrixXd A = Eigen::MatrixXd::Zero(3, 3);
  A.row(0) = a.transpose();
  A(1, 0) = A(2, 1) = 1.0;
  Eigen::MatrixXd rhs = A * p * A.transpose();
  rhs(0, 0) += 0.5;
  EXPECT_NEAR((rhs - p).cwiseAbs().maxCoeff(), 0.0, 1e-12);
}

// The filter is linear: readings of 1e300 filter to 1e300 × the same outputs, and the innovations' RMS is
// 1e300 × theirs too (it came back inf from the plain sum of squares).
TEST(Kalman, HugeReadingsFilterAsSmallOnes) {
  Eigen::VectorXd a(1);
  a << 0.5;
  const fluxcal::ArKalman f(a, 1.0, 0.5);
  std::mt19937_64 rng(2);
  std::normal_distribution<double> normal;
  Eigen::VectorXd y(300);
  for (auto& v : y) v = normal(rng);
  const auto small = f.filter(y), big = f.filter(y * 1e300);
  EXPECT_NEAR((big.filtered / 1e300 - small.filtered).cwiseAbs().maxCoeff(), 0.0, 1e-12);
  ASSERT_TRUE(std::isfinite(big.summary.residual_rms));
  EXPECT_NEAR(big.summary.residual_rms / 1e300, small.summary.residual_rms, 1e-12 * small.summary.residual_rms);
}

TEST(Kalman, StationaryCovarianceWithPolesNearOne) {
  // Four poles at 0.99 (the coefficients of (1 − 0.99 z⁻¹)⁴ as NumPy rounds them): doubling gave NaN.
  Eigen::VectorXd a(4);
  a << 3.96, -5.8805999999999994, 3.8811959999999996, -0.96059600999999994;
  const Eigen::MatrixXd p = fluxcal::ar_stationary_covariance(a, 1.0);
  ASSERT_TRUE(p.allFinite());
  // γ0 of these float coefficients, from exact rational arithmetic (fluxcal.oracle.kalman).
  EXPECT_NEAR(p(0, 0) / 15703755854097.92 - 1.0, 0.0, 1e-13);
  Eigen::MatrixXd A = Eigen::MatrixXd::Zero(4, 4);
  A.row(0) = a.transpose();
  for (int i = 1; i < 4; ++i) A(i, i - 1) = 1.0;
  Eigen::MatrixXd rhs = A * p * A.transpose();
  rhs(0, 0) += 1.0;
  EXPECT_LT((rhs - p).cwiseAbs().maxCoeff(), 1e-9 * p(0, 0));
  EXPECT_NO_THROW(fluxcal::ArKalman(a, 1.0, 1.0).steady_state_gain());
}

TEST(Kalman, SteadyGainOfASlowRandomWalk) {
  // Local level with q/r = 1e-8: the recursion converges at the rate 1 − K ≈ 1 − 1e-4 and gave up
  // after 10⁵ steps; doubling needs a few dozen.
  const fluxcal::ArKalman k(Eigen::VectorXd::Constant(1, 1.0), 1e-8, 1.0);
  Eigen::MatrixXd m;
  int iterations = 0;
  const Eigen::VectorXd gain = k.steady_state_gain(&m, &iterations);
  const double exact = (1e-8 + std::sqrt(1e-16 + 4e-8)) / 2.0;  // m² = q (m + r)
  EXPECT_NEAR(m(0, 0) / exact - 1.0, 0.0, 1e-10);
  EXPECT_NEAR(gain[0] / (exact / (exact + 1.0)) - 1.0, 0.0, 1e-10);
  EXPECT_LT(iterations, 60);
}

TEST(Kalman, FromArFit) {
  fluxcal::ArResult fit;
  fit.order = 2;
  fit.coefficients = Eigen::Vector2d(0.5, -0.2);
  fit.sigma2 = 0.3;
  const auto k = fluxcal::ArKalman::from_ar(fit);
  EXPECT_EQ(k.order(), 2);
  EXPECT_EQ(k.q(), 0.3);
  EXPECT_EQ(k.r(), 0.3);  // R defaults to σ²
  EXPECT_EQ(fluxcal::ArKalman::from_ar(fit, 0.01).r(), 0.01);
  EXPECT_EQ(fluxcal::ArKalman::from_ar(fit, 0.0).r(), 0.0);
  fit.order = 0;
  fit.coefficients.resize(0);
  EXPECT_THROW(fluxcal::ArKalman::from_ar(fit), fluxcal::Error);
}

// A gap in time: the filter starts again from x = 0, P = P0, so the output after a break is the output of a
// filter run on the stretch alone.
TEST(Kalman, StartsAgainAfterEachBreak) {
  std::mt19937_64 rng(5);
  std::normal_distribution<double> normal(0.0, 1.0);
  Eigen::VectorXd y(600);
  for (Eigen::Index t = 0; t < y.size(); ++t) y[t] = normal(rng) + (t ? 0.8 * y[t - 1] : 0.0);
  for (const bool steady : {false, true}) {
    fluxcal::KalmanOptions options;
    options.steady_state = steady;
    const fluxcal::ArKalman k(Eigen::Vector2d(0.8, -0.1), 1.0, 0.5, options);
    const auto whole = k.filter(y, {250, 400});
    const auto alone = k.filter(y.segment(250, 150));
    EXPECT_NEAR((whole.filtered.segment(250, 150) - alone.filtered).cwiseAbs().maxCoeff(), 0.0, 1e-12);
    EXPECT_GT((whole.filtered.head(400) - k.filter(y).filtered.head(400)).cwiseAbs().maxCoeff(), 1e-3);
  }
  EXPECT_ERROR_SAYS(fluxcal::ArKalman(Eigen::Vector2d(0.8, -0.1), 1.0, 0.5).filter(y, {600}), "breaks: break 0");
}

TEST(Kalman, BadInput) {
  EXPECT_THROW(fluxcal::ArKalman(Eigen::VectorXd(), 1.0, 1.0), fluxcal::Error);
  EXPECT_THROW(fluxcal::ArKalman(Eigen::VectorXd::Constant(1, 0.5), -1.0, 1.0), fluxcal::Error);
  EXPECT_THROW(fluxcal::ar_stationary_covariance(Eigen::VectorXd::Constant(1, 1.2), 1.0), fluxcal::Error);
}

TEST(FixedKalman, GoldenVectorsOfTheIntegerModel) {
  ASSERT_EQ(kGoldenCases.size(), 3u);
  for (const auto& g : kGoldenCases) {
    SCOPED_TRACE(g.name);
    fluxcal::FixedArKalmanCoefficients<8> c;
    c.order = g.order;
    c.format = {g.signal_frac_bits, g.coef_frac_bits, g.cov_frac_bits};
    c.steady_state = g.steady_state;
    c.q = g.q;
    c.r = g.r;
    for (int i = 0; i < g.order; ++i) {
      c.a[i] = g.a[i];
      c.gain[i] = g.gain[i];
    }
    std::copy(g.p0.begin(), g.p0.end(), c.p0);  // the exported layout: row-major, stride order
    fluxcal::FixedArKalman<8> f;
    ASSERT_TRUE(f.configure(c));
    std::vector<std::int32_t> out(g.input.size());
    f.filter(g.input.data(), out.data(), static_cast<long>(out.size()));
    EXPECT_EQ(out, g.output);
    EXPECT_EQ(f.overflowed(), g.overflowed);
  }
}

// The coefficients as an exported C header holds them (name_a[n], name_gain[n], name_p0[n*n] row-major
// with stride n), loaded by plain copies into a filter of MaxOrder M.
template <int M>
void run_exported(const GoldenCase& g, std::vector<std::int32_t>& out, std::vector<std::int32_t>& cov, bool& overflowed) {
  fluxcal::FixedArKalmanCoefficients<M> c;
  c.order = g.order;
  c.format = {g.signal_frac_bits, g.coef_frac_bits, g.cov_frac_bits};
  c.steady_state = g.steady_state;
  c.q = g.q;
  c.r = g.r;
  ASSERT_LE(g.a.size() * sizeof(std::int32_t), sizeof c.a);
  ASSERT_LE(g.p0.size() * sizeof(std::int32_t), sizeof c.p0);
  std::memcpy(c.a, g.a.data(), g.a.size() * sizeof(std::int32_t));
  std::memcpy(c.gain, g.gain.data(), g.gain.size() * sizeof(std::int32_t));
  std::memcpy(c.p0, g.p0.data(), g.p0.size() * sizeof(std::int32_t));
  fluxcal::FixedArKalman<M> f;
  ASSERT_TRUE(f.configure(c));
  for (int i = 0; i < g.order; ++i)
    for (int j = 0; j < g.order; ++j) EXPECT_EQ(f.covariance(i, j), g.p0[static_cast<std::size_t>(i * g.order + j)]);
  out.assign(g.input.size(), 0);
  f.filter(g.input.data(), out.data(), static_cast<long>(out.size()));
  cov.clear();
  for (int i = 0; i < g.order; ++i)
    for (int j = 0; j < g.order; ++j) cov.push_back(f.covariance(i, j));
  overflowed = f.overflowed();
}

TEST(FixedKalman, ExportedLayoutLoadsIntoAnyMaxOrder) {
  int checked = 0;
  for (const auto& g : kGoldenCases) {
    SCOPED_TRACE(g.name);
    std::vector<std::int32_t> exact, exact_cov, out, cov;
    bool exact_of = false, of = false;
    if (g.order == 3) {
      run_exported<3>(g, exact, exact_cov, exact_of);
      run_exported<4>(g, out, cov, of);
      EXPECT_EQ(out, exact);
      EXPECT_EQ(cov, exact_cov);
      EXPECT_EQ(of, exact_of);
    } else if (g.order == 1) {
      run_exported<1>(g, exact, exact_cov, exact_of);
    } else {
      continue;
    }
    run_exported<8>(g, out, cov, of);  // MaxOrder > order
    EXPECT_EQ(out, exact);
    EXPECT_EQ(cov, exact_cov);
    EXPECT_EQ(of, exact_of);
    EXPECT_EQ(exact, g.output);  // and both are the integer model's output
    EXPECT_EQ(exact_of, g.overflowed);
    ++checked;
  }
  EXPECT_EQ(checked, 3);
}

TEST(FixedKalman, SaturatesWithStickyFlag) {
  fluxcal::FixedArKalmanCoefficients<2> c;
  c.order = 1;
  c.format = {30, 30, 30};
  c.steady_state = true;
  c.a[0] = 1 << 30;         // a = 1.0
  c.gain[0] = 1 << 29;      // K = 0.5
  fluxcal::FixedArKalman<2> f;
  ASSERT_TRUE(f.configure(c));
  const std::int32_t big = std::numeric_limits<std::int32_t>::max() - 1;  // one below the rail
  std::int32_t last = 0;
  for (int i = 0; i < 100; ++i) last = f.step(big);
  EXPECT_FALSE(f.overflowed());  // tracking +full scale from below stays in range
  EXPECT_GT(last, big - 100);
  f.step(big + 1);  // a sample at the rail: what a saturated conversion leaves, flagged though nothing saturates here
  EXPECT_TRUE(f.overflowed());
  f.clear_overflow();
  last = f.step(std::numeric_limits<std::int32_t>::min());  // innovation ≈ −2 full scales
  EXPECT_TRUE(f.overflowed());
  EXPECT_GT(last, 0);  // clamped innovation: the output moved down by half the range, no wrap
  f.reset();
  EXPECT_TRUE(f.overflowed());  // sticky across reset
  f.clear_overflow();
  EXPECT_FALSE(f.overflowed());
  c.order = 3;  // more than MaxOrder
  EXPECT_FALSE(f.configure(c));
}

}  // namespace

TEST(Kalman, StationaryCovarianceRefusesEmptyOrNaNInput) {
  EXPECT_THROW(fluxcal::ar_stationary_covariance(Eigen::VectorXd(), 1.0), fluxcal::Error);  // segfault before
  EXPECT_THROW(fluxcal::ar_stationary_covariance(Eigen::VectorXd::Constant(1, 0.5), std::nan("")), fluxcal::Error);
}

// The saturating add is portable C++ (no compiler builtin): exact inside int64, clamped and flagged
// at either end.
TEST(FixedPoint, SaturatingAddAtTheEdges) {
  using fluxcal::fixed::add64;
  constexpr std::int64_t hi = std::numeric_limits<std::int64_t>::max(), lo = std::numeric_limits<std::int64_t>::min();
  bool of = false;
  EXPECT_EQ(add64(hi - 1, 1, of), hi);
  EXPECT_EQ(add64(lo + 1, -1, of), lo);
  EXPECT_EQ(add64(-5, 3, of), -2);
  EXPECT_FALSE(of);
  EXPECT_EQ(add64(hi, 1, of), hi);
  EXPECT_TRUE(of);
  of = false;
  EXPECT_EQ(add64(lo, -1, of), lo);
  EXPECT_TRUE(of);
  of = false;
  EXPECT_EQ(add64(hi, lo, of), -1);  // opposite signs never overflow
  EXPECT_FALSE(of);
}

// The rescaling shift floors without shifting a negative value (implementation-defined before C++20):
// against floor division on both signs, at the ends of int64 and across every shift the filter uses.
TEST(FixedPoint, FloorShiftIsFloorDivisionOnBothSigns) {
  using fluxcal::fixed::floor_shift;
  constexpr std::int64_t hi = std::numeric_limits<std::int64_t>::max(), lo = std::numeric_limits<std::int64_t>::min();
  EXPECT_EQ(floor_shift(-1, 1), -1);
  EXPECT_EQ(floor_shift(-3, 1), -2);
  EXPECT_EQ(floor_shift(-4, 2), -1);
  EXPECT_EQ(floor_shift(-5, 2), -2);
  EXPECT_EQ(floor_shift(lo, 62), -2);
  EXPECT_EQ(floor_shift(hi, 62), 1);
  for (int s = 1; s <= 30; ++s) {
    const auto d = static_cast<long double>(std::int64_t{1} << s);
    for (std::int64_t v : {std::int64_t{-7}, std::int64_t{-1} << 40, lo + 1, std::int64_t{-123456789}, std::int64_t{99}}) {
      EXPECT_EQ(floor_shift(v, s), static_cast<std::int64_t>(std::floor(static_cast<long double>(v) / d))) << v << " >> " << s;
    }
  }
}

TEST(KalmanOptions, BadValuesAreNamed) {
  const Eigen::VectorXd a = Eigen::VectorXd::Constant(1, 0.5);
  fluxcal::KalmanOptions o;
  o.initial_variance = std::nan("");
  EXPECT_ERROR_SAYS(fluxcal::ArKalman(a, 1.0, 1.0, o), "KalmanOptions::initial_variance: nan");
  o = {};
  o.riccati_max_iterations = 0;
  EXPECT_ERROR_SAYS(fluxcal::ArKalman(a, 1.0, 1.0, o), "KalmanOptions::riccati_max_iterations: 0, need ≥ 1");
  o = {};
  o.riccati_tolerance = -1e-9;
  EXPECT_ERROR_SAYS(fluxcal::ArKalman(a, 1.0, 1.0, o), "KalmanOptions::riccati_tolerance: -1e-09");
}
