// drift.hpp: piecewise polynomial drift, F-test order, continuity, errors.
#include <fluxcal/drift.hpp>

#include <gtest/gtest.h>

#include "errors.hpp"
#include "foct_law.hpp"

#include <cmath>
#include <limits>
#include <random>

namespace {

struct Data {
  Eigen::VectorXd temp, w;
};

Data make(int n, double sigma, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal(0.0, sigma);
  Data d;
  d.temp = Eigen::VectorXd::LinSpaced(n, -20.0, 50.0);
  d.w.resize(n);
  for (int i = 0; i < n; ++i) d.w[i] = foct_drift_law(d.temp[i]) + normal(rng);
  return d;
}

TEST(Drift, RecoversOrdersAndCoefficients) {
  const Data d = make(30000, 0.02, 5);
  fluxcal::DriftOptions options;
  options.significance = 0.01;
  const auto m = fluxcal::fit_drift(d.temp, d.temp, d.w, options);
  ASSERT_EQ(m.segments.size(), 3u);
  EXPECT_EQ(m.segments[0].order, 2);
  EXPECT_EQ(m.segments[1].order, 1);
  EXPECT_EQ(m.segments[2].order, 3);
  EXPECT_NEAR(m.segments[0].coefficients[2], 0.004, 2e-4);
  EXPECT_NEAR(m.segments[1].coefficients[1], -0.03, 1e-3);
  const Eigen::VectorXd wc = m.compensate(d.w, d.temp, d.temp);
  EXPECT_NEAR(wc.cwiseAbs().maxCoeff(), 0.0, 0.12);  // noise (σ = 0.02) only: ≈ 5 σ at most
  EXPECT_LT(std::sqrt(wc.squaredNorm() / wc.size()), 0.021);
}

TEST(Drift, ExactPolynomialWithContinuity) {
  const Data d = make(3000, 0.0, 1);
  fluxcal::DriftOptions options;
  options.order = 3;
  options.continuous = true;
  options.whiten = false;
  const auto m = fluxcal::fit_drift(d.temp, d.temp, d.w, options);
  Eigen::VectorXd probe(2), probe_hi(2);
  probe << -1e-12, 29.999999999999;
  probe_hi << 0.0, 30.0;
  const Eigen::VectorXd lo = m.evaluate(probe, probe), hi = m.evaluate(probe_hi, probe_hi);
  EXPECT_NEAR(lo[0], hi[0], 1e-9);
  EXPECT_NEAR(lo[1], hi[1], 1e-9);
  EXPECT_NEAR((m.evaluate(d.temp, d.temp) - d.w).cwiseAbs().maxCoeff(), 0.0, 1e-9);
}

TEST(Drift, BadInput) {
  const Data d = make(3000, 0.01, 2);
  Eigen::VectorXd outside(1);
  outside << 60.0;
  const auto m = fluxcal::fit_drift(d.temp, d.temp, d.w);
  EXPECT_THROW(m.evaluate(outside, outside), fluxcal::Error);
  fluxcal::DriftOptions options;
  // the last two ranges have no samples: the ranges are made to cover the data (outer edge at the hottest
  // sample, the empty ranges dropped), and the summary says so
  options.breakpoints = {-20.0, 0.0, 30.0, 80.0, 90.0};
  const auto covered = fluxcal::fit_drift(d.temp, d.temp, d.w, options);
  ASSERT_EQ(covered.segments.size(), 3u);
  EXPECT_EQ(covered.segments.back().hi, d.temp.maxCoeff());
  ASSERT_FALSE(covered.summary.warnings.empty());
  EXPECT_NE(covered.summary.warnings.front().find("adjusted to the data"), std::string::npos);
  options.breakpoints = {0.0, -20.0};
  EXPECT_THROW(fluxcal::fit_drift(d.temp, d.temp, d.w, options), fluxcal::Error);
}

}  // namespace

TEST(Drift, EvaluateRefusesGapsAndUnsortedRanges) {
  auto segment = [](double lo, double hi, double c) {
    fluxcal::DriftSegment s;
    s.lo = lo;
    s.hi = hi;
    s.coefficients = Eigen::VectorXd::Constant(1, c);
    return s;
  };
  const Eigen::VectorXd t = Eigen::VectorXd::Constant(1, 5.0);
  fluxcal::DriftModel gap, unsorted, good;
  gap.segments = {segment(-20.0, 0.0, 1.0), segment(10.0, 30.0, 2.0)};  // T = 5 took the first polynomial
  unsorted.segments = {segment(0.0, 30.0, 2.0), segment(-20.0, 0.0, 1.0)};
  good.segments = {segment(-20.0, 0.0, 1.0), segment(0.0, 30.0, 2.0)};
  EXPECT_THROW(gap.evaluate(t, t), fluxcal::Error);
  EXPECT_THROW(unsorted.evaluate(t, t), fluxcal::Error);
  EXPECT_EQ(good.evaluate(t, t)[0], 2.0);
}

TEST(Drift, PolynomialRefusesNegativeOrderAndLengthMismatch) {
  Eigen::VectorXd x = Eigen::VectorXd::LinSpaced(10, 0.0, 9.0), w = 2.0 * Eigen::VectorXd::LinSpaced(20, 0.0, 19.0);
  EXPECT_THROW(fluxcal::fit_polynomial(x, w.head(10), -1), fluxcal::Error);  // segfault before
  EXPECT_THROW(fluxcal::fit_polynomial(x, w, 1), fluxcal::Error);           // fitted 10 rows against 20
  EXPECT_NEAR(fluxcal::fit_polynomial(x, w.head(10), 1)[1], 2.0, 1e-12);
}

// Options are checked on entry, each message naming the field (max_order used to be called "order").
TEST(DriftOptions, BadValuesAreNamed) {
  const Data d = make(3000, 0.01, 2);
  fluxcal::DriftOptions o;
  o.whiten_max_order = -1;
  EXPECT_ERROR_SAYS(fluxcal::fit_drift(d.temp, d.temp, d.w, o), "DriftOptions::whiten_max_order: -1");
  o = {};
  o.max_order = 13;
  EXPECT_ERROR_SAYS(fluxcal::fit_drift(d.temp, d.temp, d.w, o), "DriftOptions::max_order: 13, need 0 … 12");
  o = {};
  o.max_order = -1;
  EXPECT_ERROR_SAYS(fluxcal::fit_drift(d.temp, d.temp, d.w, o), "DriftOptions::max_order: -1");
  o = {};
  o.order = -2;
  EXPECT_ERROR_SAYS(fluxcal::fit_drift(d.temp, d.temp, d.w, o), "DriftOptions::order: -2");
  o = {};
  o.significance = std::nan("");
  EXPECT_ERROR_SAYS(fluxcal::fit_drift(d.temp, d.temp, d.w, o), "DriftOptions::significance: nan");
  o = {};
  o.min_samples = -4;
  EXPECT_ERROR_SAYS(fluxcal::fit_drift(d.temp, d.temp, d.w, o), "DriftOptions::min_samples: -4");
  o = {};
  o.breakpoints = {0.0, std::nan("")};
  EXPECT_ERROR_SAYS(fluxcal::fit_drift(d.temp, d.temp, d.w, o), "DriftOptions::breakpoints: not strictly ascending");
}

// A zero bias whose squares overflow: order 0 "converged" with an infinite SSE before.
TEST(Drift, HugeZeroBiasIsNamed) {
  const Data d = make(3000, 0.01, 2);
  EXPECT_ERROR_SAYS(fluxcal::fit_drift(d.temp, d.temp, d.w * 1e300), "zero_bias: values up to");
}

namespace {

// The drift's standard error at each sample: the covariance's quadratic form, by hand.
TEST(Drift, StandardErrorsAreTheCovariancesQuadraticForm) {
  Data d = make(6000, 0.02, 11);
  for (Eigen::Index i = 0; i < d.w.size(); ++i)  // a quadratic drift in every range: order 2 leaves white noise
    d.w[i] += 0.02 + 1e-3 * d.temp[i] + 2e-5 * d.temp[i] * d.temp[i] - foct_drift_law(d.temp[i]);
  fluxcal::DriftOptions options;
  options.order = 2;
  const auto m = fluxcal::fit_drift(d.temp, d.temp, d.w, options);
  ASSERT_EQ(m.noise_ar.size(), 0);  // white noise, found so by AIC: σ̂²(VᵀV)⁻¹, checked against the normal equations
  for (const auto& seg : m.segments) {
    ASSERT_EQ(seg.covariance.rows(), 3);
    EXPECT_TRUE(seg.standard_errors.isApprox(seg.covariance.diagonal().cwiseSqrt()));
  }
  // segment 1 (0 … 30 °C): σ̂²(VᵀV)⁻¹ from its own samples
  std::vector<double> xs, ws;
  for (Eigen::Index i = 0; i < d.temp.size(); ++i)
    if (d.temp[i] >= 0.0 && d.temp[i] < 30.0) xs.push_back(d.temp[i]), ws.push_back(d.w[i]);
  Eigen::MatrixXd v(static_cast<Eigen::Index>(xs.size()), 3);
  for (Eigen::Index i = 0; i < v.rows(); ++i) v.row(i) << 1.0, xs[i], xs[i] * xs[i];
  const auto& seg = m.segments[1];
  const Eigen::VectorXd w = Eigen::Map<const Eigen::VectorXd>(ws.data(), v.rows());
  const double sigma2 = (w - v * seg.coefficients).squaredNorm() / static_cast<double>(v.rows() - 3);
  const Eigen::MatrixXd expected = sigma2 * (v.transpose() * v).inverse();
  EXPECT_LT((seg.covariance - expected).norm(), 1e-6 * expected.norm());
  const Eigen::Vector3d probe(-10.0, 12.5, 40.0);
  const Eigen::VectorXd se = m.standard_error(probe, probe);
  const Eigen::Vector3d at(1.0, 12.5, 12.5 * 12.5);
  EXPECT_NEAR(se[1], std::sqrt(at.dot(seg.covariance * at)), 1e-12);
  // a model made by hand has no covariance: said, not zero
  fluxcal::DriftModel bare = m;
  bare.segments[0].covariance.resize(0, 0);
  EXPECT_ERROR_SAYS(bare.standard_error(probe, probe), "no 3×3 covariance");
}

// whiten = false with the temperature cycling every 50 samples under AR(1) 0.9 noise: each range's rows come from
// separate visits, and the Newey–West sandwich of each range's scores made the errors 4–20× the exact ones (a
// review). Now least squares' sandwich under an AR model of the residuals in time order: against the exact
// (VᵀV)⁻¹ VᵀΣV (VᵀV)⁻¹ under the true noise, Σ_ij = σ² φ^|i−j| / (1 − φ²).
TEST(Drift, UnwhitenedErrorsFollowTheNoiseAcrossRanges) {
  const int n = 1500;
  const double phi = 0.9, sigma = 0.01, pi = std::acos(-1.0);
  std::mt19937_64 rng(21);
  std::normal_distribution<double> normal(0.0, sigma);
  Eigen::VectorXd temp(n), w(n);
  double noise = 0.0;
  for (int i = 0; i < n; ++i) {
    noise = phi * noise + normal(rng);
    temp[i] = 15.0 + 35.0 * std::sin(2.0 * pi * i / 50.0);
    w[i] = 0.02 + 1e-3 * temp[i] + 2e-5 * temp[i] * temp[i] + noise;
  }
  fluxcal::DriftOptions options;
  options.order = 2;
  options.whiten = false;
  for (const bool continuous : {false, true}) {
    options.continuous = continuous;
    const auto m = fluxcal::fit_drift(temp, temp, w, options);
    ASSERT_EQ(m.noise_ar.size(), 0);
    if (continuous) continue;  // (its exact covariance needs the constraints: the Python tests check its spread)
    for (const auto& seg : m.segments) {
      std::vector<int> idx;
      for (int i = 0; i < n; ++i)
        if (temp[i] >= seg.lo && (temp[i] < seg.hi || (seg.hi == m.segments.back().hi && temp[i] <= seg.hi)))
          idx.push_back(i);
      const Eigen::Index r = static_cast<Eigen::Index>(idx.size());
      Eigen::MatrixXd v(r, 3), sigma_v(r, 3);
      for (Eigen::Index a = 0; a < r; ++a) v.row(a) << 1.0, temp[idx[a]], temp[idx[a]] * temp[idx[a]];
      for (Eigen::Index a = 0; a < r; ++a) {
        sigma_v.row(a).setZero();
        for (Eigen::Index b = 0; b < r; ++b)
          sigma_v.row(a) += std::pow(phi, std::abs(idx[a] - idx[b])) * v.row(b);
      }
      sigma_v *= sigma * sigma / (1.0 - phi * phi);
      const Eigen::MatrixXd p = (v.transpose() * v).inverse();
      const Eigen::VectorXd exact = (p * v.transpose() * sigma_v * p).diagonal().cwiseSqrt();
      for (Eigen::Index j = 0; j < 3; ++j) {
        EXPECT_GT(seg.standard_errors[j] / exact[j], 0.75) << "range " << seg.lo << " coefficient " << j;
        EXPECT_LT(seg.standard_errors[j] / exact[j], 1.33) << "range " << seg.lo << " coefficient " << j;
      }
    }
  }
}

// Near a random walk the errors are too small whatever the sandwich (least squares understates the memory): the
// fit says they are lower bounds, whether the whitening model was dropped or no whitening was asked for.
TEST(Drift, ErrorsNearAUnitRootAreSaidToBeLowerBounds) {
  Data d = make(3000, 0.0, 3);
  std::mt19937_64 rng(4);
  std::normal_distribution<double> normal(0.0, 0.002);
  double walk = 0.0;
  for (Eigen::Index i = 0; i < d.w.size(); ++i) d.w[i] += (walk += normal(rng));
  for (const bool whiten : {true, false}) {
    fluxcal::DriftOptions options;
    options.whiten = whiten;
    const auto m = fluxcal::fit_drift(d.temp, d.temp, d.w, options);
    bool said = false;
    for (const auto& s : m.summary.warnings) {
      said = said || s.find("standard errors are lower bounds") != std::string::npos;
      EXPECT_EQ(s.find("Newey"), std::string::npos) << s;
    }
    EXPECT_TRUE(said) << "whiten " << whiten;
  }
}

}  // namespace
