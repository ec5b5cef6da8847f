#include <fluxcal/ellipsoid.hpp>

#include "simulate.hpp"

#include <gtest/gtest.h>

#include "errors.hpp"

#include <cmath>
#include <limits>
#include <random>

using fluxcal::Samples;
using fluxcal_test::make_truth;
using fluxcal_test::simulate;
using fluxcal_test::Truth;

TEST(Ellipsoid, RecoversNoiseFreeEllipsoidExactly) {
  const Truth t = make_truth(1, 48.0);
  const Samples s = simulate(t, 500, 0.0, 2);
  fluxcal::EllipsoidOptions opt;
  opt.field_norm = t.field;
  const auto r = fluxcal::fit_ellipsoid(s, opt);
  // Symmetric W ⇒ the symmetric correction is exactly W⁻¹.
  EXPECT_LT((r.calibration.offset - t.b).norm() / t.field, 1e-9);
  EXPECT_LT((r.calibration.matrix - t.W.inverse()).norm(), 1e-9);
  EXPECT_LT(r.summary.norm_std_over_mean, 1e-10);
  EXPECT_TRUE(r.summary.converged);
  EXPECT_EQ(r.summary.samples, 500u);
  EXPECT_EQ(r.calibration.model, "ellipsoid");
}

TEST(Ellipsoid, NoisyFitIsWithinOnePercent) {
  const Truth t = make_truth(3, 50000.0);
  const Samples s = simulate(t, 2000, 0.005, 4);
  fluxcal::EllipsoidOptions opt;
  opt.field_norm = t.field;
  const auto r = fluxcal::fit_ellipsoid(s, opt);
  EXPECT_LT((r.calibration.offset - t.b).norm() / t.field, 0.01);
  EXPECT_LT((r.calibration.matrix - t.W.inverse()).norm() / t.W.inverse().norm(), 0.01);
  // Residual of |h| is the projected noise, about σ·H.
  EXPECT_NEAR(r.summary.residual_rms / t.field, 0.005, 0.002);
}

TEST(Ellipsoid, WithoutFieldNormTheMatrixHasUnitDeterminant) {
  const Truth t = make_truth(5, 3.0);
  const auto r = fluxcal::fit_ellipsoid(simulate(t, 300, 0.0, 6));
  EXPECT_NEAR(r.calibration.matrix.determinant(), 1.0, 1e-10);
  EXPECT_NEAR(r.calibration.field_norm, t.field * std::cbrt(t.W.determinant()), 1e-9);
}

TEST(Ellipsoid, MomentStatisticsAgreeWithExactPass) {
  const Truth t = make_truth(7, 1.0);
  const Samples s = simulate(t, 5000, 0.01, 8);
  fluxcal::EllipsoidOptions exact, moments;
  moments.exact_statistics = false;
  const auto a = fluxcal::fit_ellipsoid(s, exact);
  const auto b = fluxcal::fit_ellipsoid(s, moments);
  EXPECT_TRUE(a.summary.exact_statistics);
  EXPECT_FALSE(b.summary.exact_statistics);
  EXPECT_NEAR(b.summary.norm_std_over_mean / a.summary.norm_std_over_mean, 1.0, 0.02);
  EXPECT_NEAR(b.summary.residual_rms / a.summary.residual_rms, 1.0, 0.02);
  EXPECT_NEAR(b.summary.norm_mean / a.summary.norm_mean, 1.0, 1e-4);
}

TEST(Ellipsoid, StreamingAndAnyNormalisationGiveTheSameFit) {
  const Truth t = make_truth(9, 2.0);
  const Samples s = simulate(t, 1000, 0.01, 10);
  const auto batch = fluxcal::fit_ellipsoid(s);
  // Another centre and scale, samples added one at a time and in two merged halves.
  fluxcal::EllipsoidMoments one(Eigen::Vector3d(0.3, -0.2, 0.1), 7.0), half(Eigen::Vector3d(0.3, -0.2, 0.1), 7.0);
  for (Eigen::Index i = 0; i < 500; ++i) one.add(Eigen::Vector3d(s.row(i).transpose()));
  half.add_rows(s.bottomRows(500));
  one.merge(half);
  const auto stream = fluxcal::fit_ellipsoid(one);
  EXPECT_LT((stream.calibration.offset - batch.calibration.offset).norm(), 1e-9);
  EXPECT_LT((stream.calibration.matrix - batch.calibration.matrix).norm(), 1e-9);
}

TEST(Ellipsoid, ApplyAndReadingAreInverse) {
  const Truth t = make_truth(11, 1.0);
  const auto r = fluxcal::fit_ellipsoid(simulate(t, 200, 0.0, 12));
  const Eigen::Vector3d h(0.3, -0.5, 0.8);
  EXPECT_LT((r.calibration.apply(r.calibration.reading(h)) - h).norm(), 1e-12);
  const Samples s = simulate(t, 10, 0.0, 13);
  const Samples hs = r.calibration.apply_rows(s);
  for (Eigen::Index i = 0; i < s.rows(); ++i)
    EXPECT_LT((hs.row(i).transpose() - r.calibration.apply(Eigen::Vector3d(s.row(i).transpose()))).norm(), 1e-12);
}

TEST(EllipsoidErrors, NaNRowIsNamed) {
  Samples s = simulate(make_truth(1, 1.0), 100, 0.0, 1);
  s(42, 1) = std::numeric_limits<double>::quiet_NaN();
  try {
    fluxcal::fit_ellipsoid(s);
    FAIL() << "no error";
  } catch (const fluxcal::Error& e) {
    EXPECT_NE(std::string(e.what()).find("row 42, column 1 (y) is NaN"), std::string::npos) << e.what();
  }
}

TEST(EllipsoidErrors, TooFewRows) {
  const Samples s = simulate(make_truth(1, 1.0), 8, 0.0, 1);
  try {
    fluxcal::fit_ellipsoid(s);
    FAIL() << "no error";
  } catch (const fluxcal::Error& e) {
    EXPECT_NE(std::string(e.what()).find("8 rows, need at least 9"), std::string::npos) << e.what();
  }
  // Nine fix the nine parameters: a residual of 0 whatever the noise, said (it had read as a perfect fit).
  const Truth t = make_truth(1, 50000.0);
  for (int seed = 1; seed <= 5; ++seed) {
    try {
      const fluxcal::Summary nine = fluxcal::fit_ellipsoid(simulate(t, 9, 0.002, seed)).summary;
      ASSERT_FALSE(nine.warnings.empty());
      EXPECT_NE(nine.warnings.front().find("9 readings fix the 9 parameters exactly"), std::string::npos);
    } catch (const fluxcal::Error&) {  // nine noisy points need not lie on an ellipsoid
    }
  }
  for (const std::string& w : fluxcal::fit_ellipsoid(simulate(t, 10, 0.0, 1)).summary.warnings)
    EXPECT_EQ(w.find("fix the 9 parameters"), std::string::npos) << w;
}

TEST(EllipsoidErrors, PlanarReadingsAreRejected) {
  Samples s(200, 3);
  for (int i = 0; i < 200; ++i) {  // a yaw-only turn, tilted plane
    const double a = 0.0314 * i;
    s.row(i) = Eigen::RowVector3d(std::cos(a), std::sin(a), 0.3 * std::cos(a) + 0.2);
  }
  try {
    fluxcal::fit_ellipsoid(s);
    FAIL() << "no error";
  } catch (const fluxcal::Error& e) {
    EXPECT_NE(std::string(e.what()).find("one plane"), std::string::npos) << e.what();
  }
}

TEST(EllipsoidErrors, HyperboloidIsRejected) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-2.0, 2.0);
  Samples s(300, 3);
  for (int i = 0; i < 300; ++i) {  // x² + y² − z² = 1
    const double a = u(rng) * 3.14159, z = u(rng);
    const double r = std::sqrt(1.0 + z * z);
    s.row(i) = Eigen::RowVector3d(r * std::cos(a), r * std::sin(a), z);
  }
  EXPECT_THROW(fluxcal::fit_ellipsoid(s), fluxcal::Error);
}

TEST(EllipsoidErrors, BadFieldNorm) {
  fluxcal::EllipsoidOptions opt;
  opt.field_norm = -1.0;
  EXPECT_THROW(fluxcal::fit_ellipsoid(simulate(make_truth(1, 1.0), 50, 0.0, 1), opt), fluxcal::Error);
}

TEST(EllipsoidOptions, BadValuesAreNamed) {
  const Samples s = simulate(make_truth(1, 1.0), 200, 0.0, 1);
  fluxcal::EllipsoidOptions o;
  o.planar_ratio = std::nan("");  // switched the planar check off silently
  EXPECT_ERROR_SAYS(fluxcal::fit_ellipsoid(s, o), "EllipsoidOptions::planar_ratio: nan, need a value in [0, 1]");
  o = {};
  o.coverage_rows = -1;
  EXPECT_ERROR_SAYS(fluxcal::fit_ellipsoid(s, o), "EllipsoidOptions::coverage_rows: -1");
  o = {};
  o.method = static_cast<fluxcal::EllipsoidMethod>(5);
  EXPECT_ERROR_SAYS(fluxcal::fit_ellipsoid(s, o), "EllipsoidOptions::method: 5");
  o = {};
  o.field_norm = -1.0;
  EXPECT_ERROR_SAYS(fluxcal::fit_ellipsoid(s, o), "EllipsoidOptions::field_norm: -1");
  o = {};
  o.poor_direction_coverage = 2.0;
  EXPECT_ERROR_SAYS(fluxcal::fit_ellipsoid(s, o), "EllipsoidOptions::poor_direction_coverage: 2");
  // The streaming overload checks the same options.
  const auto [centre, scale] = fluxcal::normalisation(s);
  fluxcal::EllipsoidMoments m(centre, scale);
  m.add_rows(s);
  o = {};
  o.poor_coverage_ratio = -0.5;
  EXPECT_ERROR_SAYS(fluxcal::fit_ellipsoid(m, o), "EllipsoidOptions::poor_coverage_ratio: -0.5");
}

// A matrix of the wrong width is named by its argument.
TEST(EllipsoidErrors, WrongWidthNamesTheArgument) {
  const Samples s = simulate(make_truth(1, 1.0), 200, 0.0, 1);
  const Eigen::MatrixXd two = s.leftCols(2), four = Eigen::MatrixXd::Ones(200, 4);
  EXPECT_ERROR_SAYS(fluxcal::fit_ellipsoid(two), "samples: a matrix of 200 rows × 2 columns, need 3 columns");
  EXPECT_ERROR_SAYS(fluxcal::fit_ellipsoid(four), "samples: a matrix of 200 rows × 4 columns");
  // a width fixed at compile time to another value is the same Error, not a compile failure
  const Eigen::Matrix<double, Eigen::Dynamic, 2> fixed_two = s.leftCols(2);
  EXPECT_ERROR_SAYS(fluxcal::fit_ellipsoid(fixed_two), "samples: a matrix of 200 rows × 2 columns");
  fluxcal::EllipsoidMoments m(Eigen::Vector3d::Zero(), 1.0);
  EXPECT_ERROR_SAYS(m.add_rows(two), "readings: a matrix of 200 rows × 2 columns");
  // Column-major input of the right width is still read correctly (copied, as Eigen::Ref did).
  const Eigen::MatrixXd col_major = s;
  const auto a = fluxcal::fit_ellipsoid(col_major), b = fluxcal::fit_ellipsoid(s);
  EXPECT_TRUE(a.calibration.offset.isApprox(b.calibration.offset, 1e-12));
  EXPECT_TRUE(a.calibration.matrix.isApprox(b.calibration.matrix, 1e-12));
  // A copied view of converted rows still reads its own rows.
  const fluxcal::SamplesRef view(col_major);
  const fluxcal::SamplesRef copy(view);
  EXPECT_EQ(Samples(copy), s);
}

// Readings whose squares overflow: the fit itself is normalised, but |h| of the residual statistics
// was inf and the result said converged; now the Error names the input and its size.
TEST(EllipsoidErrors, HugeReadingsAreNamedNotConverged) {
  const Samples s = simulate(make_truth(1, 1.0), 200, 0.01, 1) * 1e300;
  EXPECT_ERROR_SAYS(fluxcal::fit_ellipsoid(s), "samples: values up to 1.");
  EXPECT_ERROR_SAYS(fluxcal::fit_ellipsoid(s), "e+300 overflow the ellipsoid fit");
  const auto [centre, scale] = fluxcal::normalisation(s);
  fluxcal::EllipsoidMoments m(centre, scale);
  m.add_rows(s);
  EXPECT_ERROR_SAYS(fluxcal::fit_ellipsoid(m), "samples: values up to");
}
