// fit_planar (planar.hpp): the 2-D calibration of a yaw-only magnetometer. Its NumPy/SciPy reference is
// python/fluxcal/oracle/planar.py, compared in tests/python/test_planar.py.
#include <fluxcal/planar.hpp>

#include <gtest/gtest.h>

#include "errors.hpp"

#include <cmath>
#include <limits>
#include <random>

using fluxcal::PlanarOptions;
using fluxcal::PlanarShape;
using fluxcal::Readings2D;

namespace {

constexpr double kH = 20.0;     // horizontal field (µT)
constexpr double kSigma = 0.1;  // reading noise per axis (0.5 % of H)
// How many standard errors an estimate may lie from the truth: |z| > 4 has probability 6e-5 per parameter.
constexpr double kZ = 4.0;

// A symmetric 2×2 soft iron whose principal axes are rotated `angle_deg` from the sensor's.
Eigen::Matrix2d soft_iron(double angle_deg, double g1, double g2) {
  const Eigen::Matrix2d R = Eigen::Rotation2Dd(angle_deg * M_PI / 180.0).toRotationMatrix();
  return R * Eigen::Vector2d(g1, g2).asDiagonal() * R.transpose();
}

struct Yaw {
  Readings2D u;
  Eigen::VectorXd field;  // |h| of each reading
  Eigen::Vector2d b{12.0, -7.0};
  Eigen::Matrix2d A;  // the truth: h = A (u − b)
};

// Readings of a vehicle turning `turns` times at an uneven rate: u = W h + b + noise, |h| = field(k).
Yaw yaw_only(unsigned seed, int n, const Eigen::Matrix2d& W, double noise = kSigma, double turns = 2.0,
             double field_change = 0.0) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0.0, 1.0);
  std::uniform_real_distribution<double> speed(0.2, 1.8);
  Eigen::VectorXd psi(n);
  double total = 0.0;
  for (int k = 0; k < n; ++k) psi(k) = total += speed(rng);
  psi *= 2.0 * M_PI * turns / total;
  Yaw y;
  y.u.resize(n, 2);
  y.field.resize(n);
  y.A = W.inverse();
  for (int k = 0; k < n; ++k) {
    y.field(k) = kH * (1.0 + field_change * std::sin(3.0 * k / n));
    const Eigen::Vector2d h(y.field(k) * std::cos(psi(k)), y.field(k) * std::sin(psi(k)));
    y.u.row(k) = (W * h + y.b + noise * Eigen::Vector2d(g(rng), g(rng))).transpose();
  }
  return y;
}

// Each estimate within kZ of its standard errors of the truth (b_x, b_y, a_xx, a_xy, a_yy).
void expect_at_truth(const fluxcal::PlanarResult& r, const Eigen::Vector2d& b, const Eigen::Matrix2d& A) {
  ASSERT_EQ(r.parameters.size(), 5);
  const Eigen::Matrix<double, 5, 1> truth(b(0), b(1), A(0, 0), A(0, 1), A(1, 1));
  for (int j = 0; j < 5; ++j)
    EXPECT_LT(std::abs(r.parameters(j) - truth(j)), kZ * r.standard_errors(j))
        << r.parameter_names[static_cast<std::size_t>(j)] << " = " << r.parameters(j) << ", truth " << truth(j)
        << ", SE " << r.standard_errors(j);
}

}  // namespace

TEST(Planar, RecoversARotatedEllipseWithinItsStandardErrors) {
  const Yaw y = yaw_only(1, 2000, soft_iron(30.0, 1.12, 0.9));
  PlanarOptions opt;
  opt.field_norm = kH;
  const auto r = fluxcal::fit_planar(y.u, opt);
  EXPECT_TRUE(r.summary.converged);
  EXPECT_TRUE(r.identifiable);
  EXPECT_FALSE(r.relative_scale);
  EXPECT_EQ(r.parameter_names, (std::vector<std::string>{"b_x", "b_y", "a_xx", "a_xy", "a_yy"}));
  expect_at_truth(r, y.b, y.A);
  EXPECT_TRUE(r.matrix.isApprox(r.matrix.transpose()));
  // The standard errors are the derived σ√(2/N) for the offset (tests/python/test_planar.py's docstring)
  const double se_b = kSigma * std::sqrt(2.0 / 2000.0);
  EXPECT_NEAR(r.standard_errors(0) / se_b, 1.0, 0.3);
  EXPECT_NEAR(r.standard_errors(1) / se_b, 1.0, 0.3);
  // σ̂ is the reading noise, |h| scatters by it
  EXPECT_NEAR(r.sigma / kSigma, 1.0, 0.1);
  EXPECT_LT(r.summary.norm_std_over_mean, 2.0 * kSigma / kH);
  EXPECT_EQ(r.residuals.size(), 2000);
  EXPECT_NEAR(std::sqrt(r.residuals.squaredNorm() / 1995.0), r.sigma, 0.01 * r.sigma);
  // rss is the minimised cost, against targets raised by the noise's bias of |h| (≈ σ²/H² relative): the residuals'
  // against H differ from it by that order
  EXPECT_NEAR(r.rss, r.residuals.squaredNorm(), 1e-3 * r.rss);
  // the corrected field is the model's
  const Readings2D h = r.apply_rows(y.u);
  EXPECT_TRUE(h.row(7).transpose().isApprox(r.apply(y.u.row(7).transpose())));
  EXPECT_NEAR(h.rowwise().norm().mean(), kH, 3.0 * kSigma / std::sqrt(2000.0) + 1e-3);
}

TEST(Planar, NoiseFreeReadingsGiveTheTruthExactly) {
  const Yaw y = yaw_only(2, 200, soft_iron(-50.0, 0.8, 1.3), 0.0);
  PlanarOptions opt;
  opt.field_norm = kH;
  const auto r = fluxcal::fit_planar(y.u, opt);
  EXPECT_TRUE(r.summary.converged);
  EXPECT_LT((r.offset - y.b).norm(), 1e-9);
  EXPECT_LT((r.matrix - y.A).norm(), 1e-11);
}

TEST(Planar, WithoutAFieldTheScaleIsRelative) {
  const Eigen::Matrix2d W = soft_iron(30.0, 1.12, 0.9);
  const Yaw y = yaw_only(3, 2000, W);
  const auto r = fluxcal::fit_planar(y.u);
  EXPECT_TRUE(r.relative_scale);
  EXPECT_NEAR(r.matrix.determinant(), 1.0, 1e-12);
  // the field norm is the ellipse's geometric-mean radius, H √det W
  EXPECT_NEAR(r.field_norm, kH * std::sqrt(W.determinant()), kZ * kSigma * std::sqrt(2.0 / 2000.0));
  const Eigen::Matrix2d expected = y.A / std::sqrt(y.A.determinant());
  expect_at_truth(r, y.b, expected);
  // the same readings with H: the same shape, scaled
  PlanarOptions given;
  given.field_norm = kH;
  const auto s = fluxcal::fit_planar(y.u, given);
  EXPECT_LT((s.matrix * r.field_norm / kH - r.matrix).cwiseAbs().maxCoeff(), 1e-3);
  EXPECT_LT((s.offset - r.offset).norm(), 1e-9 + 0.01 * s.standard_errors(0));
}

TEST(Planar, EachReadingItsOwnField) {
  const Yaw y = yaw_only(4, 2000, soft_iron(30.0, 1.12, 0.9), kSigma, 2.0, 0.1);
  const auto r = fluxcal::fit_planar(y.u, y.field);
  EXPECT_TRUE(r.summary.converged);
  EXPECT_NEAR(r.field_norm, y.field.mean(), 1e-12);
  expect_at_truth(r, y.b, y.A);
  EXPECT_LT(r.summary.norm_std_over_mean, 2.0 * kSigma / kH);
  // one mean field instead leaves the change in |h|: worse
  PlanarOptions one;
  one.field_norm = y.field.mean();
  EXPECT_GT(fluxcal::fit_planar(y.u, one).summary.norm_std_over_mean, 3.0 * r.summary.norm_std_over_mean);
}

TEST(Planar, FewerParametersForShapesWithoutCoupling) {
  const Yaw y = yaw_only(5, 2000, Eigen::Vector2d(1.1, 0.95).asDiagonal().toDenseMatrix());
  PlanarOptions opt;
  opt.field_norm = kH;
  opt.shape = PlanarShape::diagonal;
  const auto d = fluxcal::fit_planar(y.u, opt);
  EXPECT_EQ(d.parameter_names, (std::vector<std::string>{"b_x", "b_y", "a_xx", "a_yy"}));
  EXPECT_EQ(d.matrix(0, 1), 0.0);
  const Eigen::Vector4d truth(y.b(0), y.b(1), y.A(0, 0), y.A(1, 1));
  for (int j = 0; j < 4; ++j) EXPECT_LT(std::abs(d.parameters(j) - truth(j)), kZ * d.standard_errors(j));
  // a circle cannot fit this ellipse: its residuals carry the gains' difference
  opt.shape = PlanarShape::circle;
  const auto c = fluxcal::fit_planar(y.u, opt);
  EXPECT_EQ(c.parameters.size(), 3);
  EXPECT_EQ(c.matrix(0, 0), c.matrix(1, 1));
  EXPECT_GT(c.sigma, 10.0 * d.sigma);
  // the diagonal model misses a rotated ellipse by far more than its errors for independent readings; its misfit
  // follows twice the heading, slowly in time, so the Newey–West errors it reports are wider, the miss beyond 3
  const Yaw rotated = yaw_only(6, 2000, soft_iron(30.0, 1.12, 0.9));
  opt.shape = PlanarShape::diagonal;
  const auto miss = fluxcal::fit_planar(rotated.u, opt);
  EXPECT_GT(std::abs(rotated.A(0, 1)), 20.0 * miss.serial_correlation.standard_errors_independent.tail(2).maxCoeff());
  EXPECT_GT(std::abs(rotated.A(0, 1)), 3.0 * miss.standard_errors.tail(2).maxCoeff());
  EXPECT_GT(miss.serial_correlation.lags, 0);
}

TEST(Planar, NoiseBiasCorrectionRemovesTheShrinkOfTheMatrix) {
  // At σ = 5 % of H the tangential noise lengthens |h| by σ²‖A‖²/(4H) ≈ 0.13 %: without the correction the gains
  // come out that much too small, many standard errors at N = 20000; with it, within them.
  const Yaw y = yaw_only(7, 20000, soft_iron(30.0, 1.12, 0.9), 0.05 * kH);
  PlanarOptions opt;
  opt.field_norm = kH;
  const auto with = fluxcal::fit_planar(y.u, opt);
  opt.noise_bias_correction = false;
  const auto without = fluxcal::fit_planar(y.u, opt);
  const double gain = std::sqrt(y.A.determinant());
  const double with_err = std::sqrt(with.matrix.determinant()) / gain - 1.0;
  const double without_err = std::sqrt(without.matrix.determinant()) / gain - 1.0;
  EXPECT_LT(without_err, -0.0008);
  EXPECT_LT(std::abs(with_err), 0.4 * std::abs(without_err));
  EXPECT_GT(with.summary.iterations, without.summary.iterations);
}

TEST(Planar, AnIterationLimitIsReportedNotThrown) {
  const Yaw y = yaw_only(8, 500, soft_iron(30.0, 1.12, 0.9));
  PlanarOptions opt;
  opt.field_norm = kH;
  opt.max_iterations = 1;
  opt.noise_bias_correction = false;
  opt.tolerance = 1e-300;
  const auto r = fluxcal::fit_planar(y.u, opt);
  EXPECT_FALSE(r.summary.converged);
  ASSERT_FALSE(r.summary.warnings.empty());
  EXPECT_NE(r.summary.warnings[0].find("did not converge in 1 iterations"), std::string::npos);
}

TEST(Planar, AShortArcLeavesParametersUndetermined) {
  // A quarter turn: the offset and the gains trade off (their standard errors ~130× a full turn's); said, not hidden.
  const Yaw y = yaw_only(9, 400, soft_iron(30.0, 1.12, 0.9), kSigma, 0.25);
  PlanarOptions opt;
  opt.field_norm = kH;
  const auto r = fluxcal::fit_planar(y.u, opt);
  EXPECT_FALSE(r.identifiable);
  EXPECT_FALSE(r.determined[0] && r.determined[1]);
  // a full turn of as many readings determines every parameter
  EXPECT_TRUE(fluxcal::fit_planar(yaw_only(9, 400, soft_iron(30.0, 1.12, 0.9)).u, opt).identifiable);
  bool said = false;
  for (const auto& w : r.summary.warnings) said = said || w.find("not identifiable") != std::string::npos;
  EXPECT_TRUE(said);
}

TEST(Planar, ReadingsCorrelatedInTimeGetNeweyWestErrors) {
  // A sensor's own filter: AR(1) noise of φ 0.9 (stationary σ kSigma). σ̂²(JᵀJ)⁻¹ assumes independent readings and
  // is 4–5× too narrow; the sandwich is taken (the residuals fail Ljung–Box) and the offset's z-scores are ~1.
  const int n = 1000, seeds = 20;
  const double phi = 0.9;
  int far_independent = 0, far_reported = 0;
  double z2 = 0.0;
  for (int seed = 0; seed < seeds; ++seed) {
    Yaw y = yaw_only(100 + seed, n, soft_iron(30.0, 1.12, 0.9), 0.0);
    std::mt19937 rng(500 + seed);
    std::normal_distribution<double> g(0.0, kSigma * std::sqrt(1.0 - phi * phi));
    std::normal_distribution<double> start(0.0, kSigma);  // the stationary distribution
    Eigen::Vector2d e(start(rng), start(rng));
    for (int k = 0; k < n; ++k) {
      e = phi * e + Eigen::Vector2d(g(rng), g(rng));
      y.u.row(k) += e.transpose();
    }
    PlanarOptions opt;
    opt.field_norm = kH;
    const auto r = fluxcal::fit_planar(y.u, opt);
    const auto& sc = r.serial_correlation;
    EXPECT_GT(sc.lags, 0);
    EXPECT_GT(sc.inflation, 2.0);
    EXPECT_GT(sc.lag1, 0.5);
    EXPECT_TRUE(r.identifiable);  // judged on the independent errors: the coverage, not the noise's colour
    bool said = false;
    for (const auto& w : r.summary.warnings) said = said || w.find("correlated in time") != std::string::npos;
    EXPECT_TRUE(said);
    for (int j = 0; j < 2; ++j) {
      const double off = std::abs(r.offset(j) - y.b(j));
      far_independent += off > kZ * sc.standard_errors_independent(j);
      far_reported += off > kZ * r.standard_errors(j);
      z2 += off * off / (r.standard_errors(j) * r.standard_errors(j));
    }
  }
  EXPECT_GE(far_independent, 10);  // of 40 offsets (measured: 21)
  EXPECT_LE(far_reported, 1);
  EXPECT_LT(std::sqrt(z2 / (2.0 * seeds)), 1.5);
  // independent: never the sandwich; white noise: automatic keeps σ̂²(JᵀJ)⁻¹ exactly
  const Yaw white = yaw_only(99, n, soft_iron(30.0, 1.12, 0.9));
  PlanarOptions opt;
  opt.field_norm = kH;
  const auto r = fluxcal::fit_planar(white.u, opt);
  EXPECT_EQ(r.serial_correlation.lags, 0);
  EXPECT_EQ(r.standard_errors, r.serial_correlation.standard_errors_independent);
  opt.serial_correlation = fluxcal::SerialCorrelation::newey_west;
  const auto nw = fluxcal::fit_planar(white.u, opt);
  EXPECT_GT(nw.serial_correlation.lags, 0);
  EXPECT_NEAR(nw.standard_errors(0) / r.standard_errors(0), 1.0, 0.3);
}

TEST(Planar, BadInputNamesTheInput) {
  const Yaw y = yaw_only(10, 200, soft_iron(30.0, 1.12, 0.9));
  EXPECT_ERROR_SAYS(fluxcal::fit_planar(Readings2D(y.u.topRows(9))), "readings: 9 rows");
  EXPECT_ERROR_SAYS(fluxcal::fit_planar(Readings2D(y.u.topRows(9))), "at least 10");
  Readings2D nan = y.u;
  nan(17, 1) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_ERROR_SAYS(fluxcal::fit_planar(nan), "readings: row 17, column 1 (y) is NaN");
  nan(17, 1) = std::numeric_limits<double>::infinity();
  EXPECT_ERROR_SAYS(fluxcal::fit_planar(nan), "row 17, column 1 (y) is infinite");
  EXPECT_ERROR_SAYS(fluxcal::fit_planar(Eigen::MatrixXd::Ones(20, 3)), "readings: a matrix of 20 rows × 3 columns");
  EXPECT_ERROR_SAYS(fluxcal::fit_planar(Readings2D(Readings2D::Constant(20, 2, 3.0))), "every row is the same");
  // per-reading fields: one a reading, each positive
  EXPECT_ERROR_SAYS(fluxcal::fit_planar(y.u, Eigen::VectorXd::Ones(7)), "field_norms: 7 values for 200 readings");
  Eigen::VectorXd zero = Eigen::VectorXd::Ones(200);
  zero(3) = 0.0;
  EXPECT_ERROR_SAYS(fluxcal::fit_planar(y.u, zero), "field_norms: value 3 is 0");
  PlanarOptions bad;
  bad.tolerance = std::numeric_limits<double>::quiet_NaN();
  EXPECT_ERROR_SAYS(fluxcal::fit_planar(y.u, bad), "PlanarOptions::tolerance: nan");
  bad = {};
  bad.field_norm = -20.0;
  EXPECT_ERROR_SAYS(fluxcal::fit_planar(y.u, bad), "PlanarOptions::field_norm: -20");
  bad = {};
  bad.shape = static_cast<PlanarShape>(7);
  EXPECT_ERROR_SAYS(fluxcal::fit_planar(y.u, bad), "PlanarOptions::shape: 7");
  bad = {};
  bad.serial_correlation_alpha = 1.5;
  EXPECT_ERROR_SAYS(fluxcal::fit_planar(y.u, bad), "PlanarOptions::serial_correlation_alpha: 1.5");
  bad = {};
  bad.serial_correlation = static_cast<fluxcal::SerialCorrelation>(5);
  EXPECT_ERROR_SAYS(fluxcal::fit_planar(y.u, bad), "PlanarOptions::serial_correlation: 5");
  bad = {};
  bad.start = fluxcal::PlanarStart{Eigen::Vector2d(1.0, 2.0), -Eigen::Matrix2d::Identity()};
  EXPECT_ERROR_SAYS(fluxcal::fit_planar(y.u, bad), "PlanarOptions::start: the offset and matrix must be finite");
}

TEST(Planar, AGivenStartGivesTheSameAnswer) {
  // a part of a log refined from the whole log's fit (what calibrate_planar's moved-offset check does): the same
  // offset, matrix, field norm and errors as from the two starts of its own, with or without a field given
  const Yaw y = yaw_only(12, 3000, soft_iron(30.0, 1.12, 0.9), kSigma, 4.0);
  for (const double field : {kH, 0.0}) {
    PlanarOptions opt;
    opt.field_norm = field;
    const auto whole = fluxcal::fit_planar(y.u, opt);
    const Readings2D part = y.u.topRows(1000);
    const auto cold = fluxcal::fit_planar(part, opt);
    opt.start = fluxcal::PlanarStart{whole.offset, 3.0 * whole.matrix};  // (any scale of A)
    const auto warm = fluxcal::fit_planar(part, opt);
    EXPECT_EQ(warm.start, "given");
    EXPECT_TRUE(warm.summary.converged);
    EXPECT_LT((warm.offset - cold.offset).norm(), 1e-6 * cold.standard_errors(0));
    EXPECT_LT((warm.matrix - cold.matrix).norm(), 1e-8);
    EXPECT_NEAR(warm.field_norm, cold.field_norm, 1e-8 * cold.field_norm);
    EXPECT_LT((warm.standard_errors - cold.standard_errors).norm(), 1e-6 * cold.standard_errors.norm());
    // a start far off, refined with one iteration: not converged from it, so the two starts of step 1 are tried
    opt.start = fluxcal::PlanarStart{Eigen::Vector2d(500.0, -300.0), Eigen::Matrix2d::Identity()};
    opt.max_iterations = 1;
    const auto far = fluxcal::fit_planar(part, opt);
    EXPECT_NE(far.start, "given");
  }
}

TEST(Planar, ReadingsThatTraceNoEllipseAreRefused) {
  // on a line: neither start exists
  Readings2D line(100, 2);
  for (int k = 0; k < 100; ++k) line.row(k) << 3.0 + 0.5 * k, -1.0 + 0.25 * k;
  EXPECT_ERROR_SAYS(fluxcal::fit_planar(line), "trace no ellipse");
  // at two places (a sensor flipped between two headings): no ellipse either
  Readings2D two(100, 2);
  for (int k = 0; k < 100; ++k) two.row(k) << (k % 2 ? 20.0 : -20.0), 5.0;
  EXPECT_ERROR_SAYS(fluxcal::fit_planar(two), "trace no ellipse");
  // scattered about one point (a vehicle that did not turn): some ellipse fits, far below the noise
  std::mt19937 rng(11);
  std::normal_distribution<double> g(0.0, 1.0);
  Readings2D blob(500, 2);
  for (int k = 0; k < 500; ++k) blob.row(k) << 25.0 + g(rng), -3.0 + g(rng);
  EXPECT_ERROR_SAYS(fluxcal::fit_planar(blob), "trace no ellipse");
  PlanarOptions never;
  never.min_radius_over_noise = 0.0;  // the caller judges (the Python layer, after choosing a shape)
  EXPECT_NO_THROW(fluxcal::fit_planar(blob, never));
}
