// timeseries.hpp: AR(p) by AIC and RLS, the statistical tests and their distributions.
#include <fluxcal/timeseries.hpp>

#include <gtest/gtest.h>

#include "errors.hpp"

#include <cmath>
#include <limits>
#include <random>

namespace {

Eigen::VectorXd ar_series(const std::vector<double>& a, int n, unsigned seed, double sigma = 1.0) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal(0.0, sigma);
  const int burn = 1000, p = static_cast<int>(a.size());
  Eigen::VectorXd y = Eigen::VectorXd::Zero(n + burn);
  for (int t = 0; t < n + burn; ++t) {
    double v = normal(rng);
    for (int i = 0; i < p && t - 1 - i >= 0; ++i) v += a[i] * y[t - 1 - i];
    y[t] = v;
  }
  return y.tail(n);
}

TEST(TimeSeries, ArRecoversOrderAndCoefficients) {
  const std::vector<double> a = {0.6, -0.3, 0.2};
  const Eigen::VectorXd y = ar_series(a, 200000, 7);
  fluxcal::ArOptions options;
  options.max_order = 8;
  const auto r = fluxcal::fit_ar(y, options);
  ASSERT_EQ(r.order, 3);
  for (int i = 0; i < 3; ++i) EXPECT_NEAR(r.coefficients[i], a[i], 0.01);  // se ≈ 1/√N ≈ 2e-3
  EXPECT_NEAR(r.sigma2, 1.0, 0.01);
  EXPECT_FALSE(r.order_at_maximum);
  EXPECT_TRUE(r.whiteness.white);
  EXPECT_EQ(r.aic.size(), 9);
}

TEST(TimeSeries, RlsWithoutForgettingIsBatchLeastSquares) {
  const Eigen::VectorXd y = ar_series({0.5, -0.4}, 5000, 3);
  fluxcal::ArOptions options;
  options.order = 2;
  const auto r = fluxcal::fit_ar(y, options);
  Eigen::MatrixXd x(y.size() - 2, 2);
  for (Eigen::Index t = 2; t < y.size(); ++t) x.row(t - 2) << y[t - 1], y[t - 2];
  const Eigen::VectorXd batch = x.colPivHouseholderQr().solve(y.tail(y.size() - 2));
  EXPECT_NEAR((r.coefficients - batch).cwiseAbs().maxCoeff(), 0.0, 1e-10);
  // and its covariance is batch least squares' σ̂²(XᵀX)⁻¹, σ̂² = SSR/(N − p)
  const double sigma2 = (y.tail(y.size() - 2) - x * batch).squaredNorm() / static_cast<double>(x.rows());
  const Eigen::MatrixXd expected = sigma2 * (x.transpose() * x).inverse();
  EXPECT_LT((r.covariance - expected).norm(), 1e-8 * expected.norm());
  EXPECT_TRUE(r.standard_errors.isApprox(expected.diagonal().cwiseSqrt(), 1e-8));
}

// Gaps in time: the fit with breaks is the batch fit of the stacked rows of each stretch, and it is what a
// series that was never spliced gives (the same stretches fitted by hand).
TEST(TimeSeries, ArWithBreaksFitsEachStretchsRows) {
  const Eigen::VectorXd y = ar_series({0.9, -0.3}, 3000, 11);
  fluxcal::ArOptions options;
  options.order = 2;
  options.breaks = {700, 701, 1500};  // a one-sample stretch (700) gives no row
  const auto r = fluxcal::fit_ar(y, options);
  std::vector<Eigen::Index> starts = {0, 700, 701, 1500, 3000};
  Eigen::MatrixXd x(698 + 0 + 797 + 1498, 2);  // stretches of 700, 1, 799 and 1500 samples
  Eigen::VectorXd target(x.rows());
  Eigen::Index row = 0;
  for (std::size_t s = 0; s + 1 < starts.size(); ++s)
    for (Eigen::Index t = starts[s] + 2; t < starts[s + 1]; ++t, ++row) {
      x.row(row) << y[t - 1], y[t - 2];
      target[row] = y[t];
    }
  ASSERT_EQ(row, x.rows());
  const Eigen::VectorXd batch = x.colPivHouseholderQr().solve(target);
  EXPECT_NEAR((r.coefficients - batch).cwiseAbs().maxCoeff(), 0.0, 1e-10);
  EXPECT_EQ(r.residuals.size(), x.rows());
  options.breaks = {5, 3};
  EXPECT_ERROR_SAYS(fluxcal::fit_ar(y, options), "ArOptions::breaks: break 1 at sample 3");
}

TEST(TimeSeries, MaximumOrderIsReported) {
  const Eigen::VectorXd y = ar_series({0.3, 0.2, 0.1, 0.1, 0.1, 0.1, 0.05}, 20000, 4);
  fluxcal::ArOptions options;
  options.max_order = 3;
  const auto r = fluxcal::fit_ar(y, options);
  EXPECT_EQ(r.order, 3);
  EXPECT_TRUE(r.order_at_maximum);
  EXPECT_FALSE(r.summary.warnings.empty());
}

TEST(TimeSeries, Distributions) {
  EXPECT_NEAR(fluxcal::chi2_sf(3.841458820694124, 1), 0.05, 1e-12);
  EXPECT_NEAR(fluxcal::chi2_sf(18.307038053275146, 10), 0.05, 1e-12);
  EXPECT_NEAR(fluxcal::chi2_sf(2.0, 2), std::exp(-1.0), 1e-14);
  EXPECT_NEAR(fluxcal::f1_sf(161.44763879758855, 1), 0.05, 1e-10);   // F(1,1) upper 5 %
  EXPECT_NEAR(fluxcal::f1_sf(3.8414588206941245 * 1.0000000, 1e8), 0.05, 1e-6);  // → χ²(1)
  EXPECT_NEAR(fluxcal::f1_sf(6.607890972, 50), 0.0132, 1e-3);
  // F(d1, d2) against SciPy's f.sf; d2 = inf is the χ²(d1) limit
  EXPECT_NEAR(fluxcal::f_sf(1.3, 7, 200), 0.2519774548904117, 1e-12);
  EXPECT_NEAR(fluxcal::f_sf(3.0, 1, 5), 0.1438108087116039, 1e-12);
  EXPECT_NEAR(fluxcal::f_sf(0.5, 20, 20), 0.9352338272090371, 1e-12);
  EXPECT_NEAR(fluxcal::f_sf(2.0, 30, std::numeric_limits<double>::infinity()), 0.0009206823961486636, 1e-15);
  EXPECT_EQ(fluxcal::f_sf(3.0, 1, 5), fluxcal::f1_sf(3.0, 5));
}

TEST(TimeSeries, ReverseArrangement) {
  Eigen::VectorXd rising = Eigen::VectorXd::LinSpaced(400, 0.0, 1.0);
  const auto r = fluxcal::reverse_arrangement(rising, 20);
  EXPECT_EQ(r.arrangements, 0);
  EXPECT_DOUBLE_EQ(r.expected, 95.0);
  EXPECT_NEAR(r.variance, 20.0 * 45.0 * 19.0 / 72.0, 1e-12);
  EXPECT_FALSE(r.stationary);
  const auto w = fluxcal::reverse_arrangement(ar_series({}, 4000, 9), 20);
  EXPECT_TRUE(w.stationary);
}

TEST(TimeSeries, NormalityAndLjungBox) {
  const Eigen::VectorXd e = ar_series({}, 20000, 10);
  const auto n = fluxcal::normality(e);
  EXPECT_NEAR(n.skewness, 0.0, 0.05);
  EXPECT_NEAR(n.kurtosis, 3.0, 0.1);
  EXPECT_TRUE(fluxcal::ljung_box(e, 10).white);
  EXPECT_FALSE(fluxcal::ljung_box(ar_series({0.3}, 20000, 10), 10).white);
}

TEST(TimeSeries, LjungBoxPairsSamplesOfOneStretchOnly) {
  // White noise in 10-sample stretches, each starting with the previous one's last sample: joined, lag 1
  // sees the repeats; within the stretches it is white, and lags of a whole stretch have no pair.
  Eigen::VectorXd x = ar_series({}, 3000, 12);
  fluxcal::Breaks breaks;
  for (Eigen::Index b = 10; b < 3000; b += 10) {
    breaks.push_back(b);
    x[b] = x[b - 1];
  }
  EXPECT_FALSE(fluxcal::ljung_box(x, 8).white);
  const auto within = fluxcal::ljung_box(x, 12, 0, 0.05, breaks);
  EXPECT_TRUE(within.white);
  EXPECT_EQ(within.lags, 9);
}

TEST(TimeSeries, PreprocessDifferencesOnceOrTwice) {
  std::mt19937_64 rng(3);
  std::normal_distribution<double> normal;
  const int n = 4000;
  // A random walk: its first difference is white, one difference suffices.
  Eigen::VectorXd walk(n);
  double level = 5.0;
  for (auto& v : walk) v = (level += normal(rng));
  const auto r1 = fluxcal::preprocess(walk);
  EXPECT_EQ(r1.differences, 1);
  EXPECT_TRUE(r1.stationarity.stationary);
  EXPECT_NEAR(r1.mean, walk.mean(), 1e-12);
  ASSERT_EQ(r1.series.size(), n - 1);
  EXPECT_NEAR(r1.series[10], walk[11] - walk[10], 1e-12);
  // A quadratic trend on an integrated noise: the first difference rises (not stationary), the second
  // difference minus its line is stationary.
  Eigen::VectorXd quad(n);
  double noise = 0.0;
  for (int i = 0; i < n; ++i) {
    const double t = static_cast<double>(i) / n;
    quad[i] = 300.0 * t * t + (noise += 0.01 * normal(rng));
  }
  const auto r2 = fluxcal::preprocess(quad);
  EXPECT_FALSE(r2.stationarity.stationary);
  EXPECT_LT(r2.stationarity.u, -1.96);  // rising means: few reverse arrangements
  EXPECT_EQ(r2.differences, 2);
  EXPECT_TRUE(r2.stationarity_after.stationary);
  EXPECT_EQ(r2.series.size(), n - 2);
  EXPECT_TRUE(r2.summary.warnings.empty());
  // A pure line has constant differences: nothing left to model.
  Eigen::VectorXd line(100);
  for (int i = 0; i < 100; ++i) line[i] = 0.5 * i;
  EXPECT_THROW(fluxcal::preprocess(line), fluxcal::Error);
  EXPECT_THROW(fluxcal::preprocess(Eigen::VectorXd::Constant(100, 1.5)), fluxcal::Error);
  EXPECT_THROW(fluxcal::preprocess(walk.head(41)), fluxcal::Error);  // 20 sub-series need 42 samples
}

TEST(TimeSeries, BadInput) {
  fluxcal::ArOptions options;
  EXPECT_THROW(fluxcal::fit_ar(Eigen::VectorXd::Ones(1000), options), fluxcal::Error);   // constant
  EXPECT_THROW(fluxcal::fit_ar(Eigen::VectorXd::LinSpaced(10, 0, 1), options), fluxcal::Error);  // short
  Eigen::VectorXd y = ar_series({0.5}, 100, 1);
  y[3] = std::nan("");
  try {
    fluxcal::fit_ar(y, options);
    FAIL() << "NaN accepted";
  } catch (const fluxcal::Error& e) {
    EXPECT_NE(std::string(e.what()).find("sample 3"), std::string::npos);
  }
  options.forgetting = 1.5;
  EXPECT_THROW(fluxcal::fit_ar(ar_series({0.5}, 100, 1), options), fluxcal::Error);
  // A threshold ≤ 0 had been taken (every series "not stationary").
  EXPECT_ERROR_SAYS(fluxcal::reverse_arrangement(ar_series({0.5}, 100, 1), 20, -1.0),
                    "reverse_arrangement: threshold -1, need a finite |u| > 0");
}

}  // namespace

TEST(TimeSeriesOptions, BadValuesAreNamed) {
  const Eigen::VectorXd y = ar_series({0.5}, 500, 3);
  fluxcal::ArOptions a;
  a.init_samples = -5;
  EXPECT_ERROR_SAYS(fluxcal::fit_ar(y, a), "ArOptions::init_samples: -5, need ≥ 0");
  a = {};
  a.forgetting = std::nan("");
  EXPECT_ERROR_SAYS(fluxcal::fit_ar(y, a), "ArOptions::forgetting: nan");
  a = {};
  a.whiteness_lags = -1;
  EXPECT_ERROR_SAYS(fluxcal::fit_ar(y, a), "ArOptions::whiteness_lags: -1");
  a = {};
  a.order = -3;  // was taken for "choose by AIC"
  EXPECT_ERROR_SAYS(fluxcal::fit_ar(y, a), "ArOptions::order: -3");
  a = {};
  a.max_order = -1;
  EXPECT_ERROR_SAYS(fluxcal::fit_ar(y, a), "ArOptions::max_order: -1");
  a = {};
  a.significance = 1.0;
  EXPECT_ERROR_SAYS(fluxcal::fit_ar(y, a), "ArOptions::significance: 1");

  fluxcal::PreprocessOptions p;
  p.threshold = std::nan("");  // every series "not stationary"
  EXPECT_ERROR_SAYS(fluxcal::preprocess(y, p), "PreprocessOptions::threshold: nan");
  p = {};
  p.subseries = 2;
  EXPECT_ERROR_SAYS(fluxcal::preprocess(y, p), "PreprocessOptions::subseries: 2, need ≥ 3");
  p = {};
  p.trend_degree = -1;
  EXPECT_ERROR_SAYS(fluxcal::preprocess(y, p), "PreprocessOptions::trend_degree: -1");
  p = {};
  p.significance = -0.1;
  EXPECT_ERROR_SAYS(fluxcal::preprocess(y, p), "PreprocessOptions::significance: -0.1");
}

TEST(TimeSeries, DistributionsRefuseBadArguments) {
  EXPECT_ERROR_SAYS(fluxcal::chi2_sf(3.0, -1.0), "chi2_sf: df: -1");
  EXPECT_ERROR_SAYS(fluxcal::chi2_sf(std::nan(""), 2.0), "chi2_sf: x: nan");
  EXPECT_ERROR_SAYS(fluxcal::f1_sf(1.0, std::nan("")), "f1_sf: df: nan");
  EXPECT_ERROR_SAYS(fluxcal::f1_sf(std::nan(""), 5.0), "f1_sf: x: nan");
  EXPECT_ERROR_SAYS(fluxcal::f_sf(1.0, 0.0, 5.0), "f_sf: d1: 0");
  EXPECT_ERROR_SAYS(fluxcal::f_sf(1.0, 2.0, -1.0), "f_sf: d2: -1");
  EXPECT_EQ(fluxcal::chi2_sf(std::numeric_limits<double>::infinity(), 2.0), 0.0);
  EXPECT_NEAR(fluxcal::chi2_sf(2.0, 2.0), std::exp(-1.0), 1e-14);
  EXPECT_ERROR_SAYS(fluxcal::ljung_box(ar_series({0.5}, 200, 1), 10, -1), "ljung_box: model_df: -1");
  EXPECT_ERROR_SAYS(fluxcal::normality(ar_series({0.5}, 200, 1), std::nan("")), "normality: significance: nan");
}

// Skewness, kurtosis and autocorrelations do not depend on the scale: a series of 1e80 … 1e300 (whose
// fourth powers overflow) gets the statistics of the same series in units, not NaN and "not normal".
TEST(TimeSeries, NormalityAndLjungBoxOfHugeValues) {
  const Eigen::VectorXd y = ar_series({0.5}, 500, 3);
  const auto plain = fluxcal::normality(y);
  const auto plain_lb = fluxcal::ljung_box(y, 10);
  for (double scale : {1e80, 1e300}) {
    const auto big = fluxcal::normality(y * scale);
    EXPECT_NEAR(big.skewness, plain.skewness, 1e-12);
    EXPECT_NEAR(big.kurtosis, plain.kurtosis, 1e-12);
    EXPECT_NEAR(big.p_value, plain.p_value, 1e-12);
    EXPECT_NEAR(fluxcal::ljung_box(y * scale, 10).statistic, plain_lb.statistic, 1e-9 * plain_lb.statistic);
  }
}

// A series whose squares overflow: AR(0) "converged" with σ² = inf, or a fixed order refused as
// "rank deficient".
TEST(TimeSeries, HugeSeriesIsNamed) {
  const Eigen::VectorXd y = ar_series({0.5}, 500, 3) * 1e300;
  EXPECT_ERROR_SAYS(fluxcal::fit_ar(y), "series: values up to");
  fluxcal::ArOptions o;
  o.order = 2;
  EXPECT_ERROR_SAYS(fluxcal::fit_ar(y, o), "overflow the AR fit");
}

// A series input given a matrix of two columns: read as its first column in Release and an Eigen assertion
// (abort) in Debug with a plain Eigen::Ref; now an Error. Rows, columns and strided views still work.
TEST(TimeSeries, SeriesRefRefusesAMatrixAndViewsVectors) {
  const Eigen::MatrixXd two = Eigen::MatrixXd::Random(50, 2);
  EXPECT_ERROR_SAYS(fluxcal::zero_mean(two), "a series (N values) was given a matrix of 50 rows × 2 columns");
  const Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> rows = Eigen::MatrixXd::Random(50, 3);
  const Eigen::VectorXd column = rows.col(1);  // strided in the row-major matrix: copied
  EXPECT_EQ(fluxcal::zero_mean(rows.col(1)), fluxcal::zero_mean(column));
  EXPECT_EQ(fluxcal::zero_mean(column.transpose()), fluxcal::zero_mean(column));  // a row vector
  const fluxcal::SeriesRef view(rows.col(2)), copy(view);
  EXPECT_EQ(Eigen::VectorXd(copy), Eigen::VectorXd(rows.col(2)));
}
