// Serial correlation in refine: white noise keeps the independent-readings covariance, noise
// correlated in time along a smooth path switches to Newey–West and says so. (Agreement with the
// statsmodels oracle is tested in tests/python/test_serial_correlation.py.)
#include <fluxcal/ellipsoid.hpp>
#include <fluxcal/refine.hpp>

#include <gtest/gtest.h>

#include "errors.hpp"

#include <cmath>
#include <random>

#include "simulate.hpp"

namespace {

// A spiral over the whole sphere, consecutive readings close together (a sensor turned slowly),
// with AR(1) noise of coefficient `phi` and stationary standard deviation `noise`·field per axis.
fluxcal::Samples spiral(const fluxcal_test::Truth& t, int n, double noise, double phi, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0.0, 1.0);
  fluxcal::Samples s(n, 3);
  Eigen::Vector3d e = Eigen::Vector3d::Zero();
  const double pi = std::acos(-1.0);
  for (int i = 0; i < n; ++i) {
    const double z = 1.0 - 2.0 * (i + 0.5) / n, phase = 2.0 * pi * 20.0 * i / n, rho = std::sqrt(1.0 - z * z);
    const Eigen::Vector3d dir(rho * std::cos(phase), rho * std::sin(phase), z);
    e = phi * e + std::sqrt(1.0 - phi * phi) * Eigen::Vector3d(g(rng), g(rng), g(rng));
    s.row(i) = (t.W * dir * t.field + t.b + noise * t.field * e).transpose();
  }
  return s;
}

fluxcal::RefineResult refined(const fluxcal::Samples& s, double field, const fluxcal::RefineOptions& o = {}) {
  fluxcal::Calibration start = fluxcal::fit_ellipsoid(s).calibration;
  start.field_norm = field;
  return fluxcal::refine(start, s, o);
}

bool warns(const fluxcal::RefineResult& r) {
  for (const auto& w : r.summary.warnings)
    if (w.find("correlated in time") != std::string::npos) return true;
  return false;
}

TEST(RefineSerialCorrelation, WhiteNoiseKeepsIndependentCovariance) {
  const auto t = fluxcal_test::make_truth(3, 50.0);
  const auto r = refined(spiral(t, 1500, 0.01, 0.0, 4), t.field);
  EXPECT_EQ(r.serial_correlation.lags, 0);
  EXPECT_GT(r.serial_correlation.ljung_box_p, 0.01);
  EXPECT_TRUE(r.standard_errors.isApprox(r.serial_correlation.standard_errors_independent));
  EXPECT_FALSE(warns(r));
}

TEST(RefineSerialCorrelation, CorrelatedNoiseWidensTheErrors) {
  const auto t = fluxcal_test::make_truth(5, 50.0);
  const auto s = spiral(t, 1500, 0.01, 0.95, 6);
  const auto r = refined(s, t.field);
  EXPECT_GT(r.serial_correlation.lag1, 0.5);
  EXPECT_LT(r.serial_correlation.ljung_box_p, 1e-6);
  EXPECT_GE(r.serial_correlation.lags, 1);  // of the prewhitened scores: AR(1) noise leaves them nearly white
  EXPECT_GT(r.serial_correlation.inflation, 2.0);
  EXPECT_TRUE(warns(r));
  for (Eigen::Index k = 0; k < 9; ++k)
    EXPECT_GT(r.standard_errors(k), r.serial_correlation.standard_errors_independent(k));

  fluxcal::RefineOptions off;
  off.serial_correlation = fluxcal::SerialCorrelation::independent;
  const auto plain = refined(s, t.field, off);
  EXPECT_EQ(plain.serial_correlation.lags, 0);
  EXPECT_TRUE(plain.standard_errors.isApprox(r.serial_correlation.standard_errors_independent));
  EXPECT_FALSE(warns(plain));
}

}  // namespace

// Review of the C++ API: a matrix of the wrong width is an Error, not a heap overrun; Ceres is not
// reached with options or a start it would fail on; aliased terms are reported as not determined.
TEST(RefineInputs, WrongWidthNaNOptionsSingularStartAndAliasedTerms) {
  const auto truth = fluxcal_test::make_truth(3, 50.0);
  const fluxcal::Samples s = fluxcal_test::simulate(truth, 400, 0.01, 4);
  const Eigen::MatrixXd two = s.leftCols(2);
  EXPECT_THROW(fluxcal::fit_ellipsoid(two), fluxcal::Error);
  EXPECT_THROW(fluxcal::fit_ellipsoid(Eigen::MatrixXd()), fluxcal::Error);
  const fluxcal::Calibration start = fluxcal::fit_ellipsoid(s).calibration;
  fluxcal::RefineOptions nan_tolerance;
  nan_tolerance.function_tolerance = std::nan("");
  EXPECT_THROW(fluxcal::refine(start, s, nan_tolerance), fluxcal::Error);
  fluxcal::Calibration singular = start;
  singular.matrix.setZero();
  EXPECT_THROW(fluxcal::refine(singular, s), fluxcal::Error);
  // A term that is a constant shift along x repeats b0.
  Eigen::MatrixXd features = Eigen::MatrixXd::Zero(s.rows(), 3);
  features.col(0).setOnes();
  const auto r = fluxcal::refine_terms(start, s, features, Eigen::VectorXd::Zero(1));
  EXPECT_FALSE(r.identifiable);
  EXPECT_FALSE(r.determined[0]);  // b0
  EXPECT_FALSE(r.determined[9]);  // c0
  EXPECT_TRUE(r.determined[1]);
  const auto plain = fluxcal::refine_terms(start, s, Eigen::MatrixXd::Zero(s.rows(), 0), Eigen::VectorXd());
  EXPECT_TRUE(plain.identifiable);
}

// The vector model of refine_terms takes its reference vectors by reference as well as by pointer.
TEST(RefineInputs, VectorTermsTakeTheReferenceByReference) {
  const auto truth = fluxcal_test::make_truth(5, 50.0);
  const fluxcal::Samples s = fluxcal_test::simulate(truth, 300, 0.01, 6);
  // The field each reading saw, h = W⁻¹ (m − b): the readings fit the vector model exactly.
  const fluxcal::Samples reference = (s.rowwise() - truth.b.transpose()) * truth.W.inverse().transpose();
  fluxcal::Calibration start;
  start.field_norm = truth.field;
  const Eigen::MatrixXd none = Eigen::MatrixXd::Zero(s.rows(), 0);
  const auto by_reference = fluxcal::refine_terms(start, s, none, Eigen::VectorXd(), {}, {}, reference);
  const fluxcal::SamplesRef view(reference);
  const auto by_pointer = fluxcal::refine_terms(start, s, none, Eigen::VectorXd(), {}, {}, &view);
  EXPECT_EQ(by_reference.parameters, by_pointer.parameters);
  EXPECT_LT((by_reference.calibration.offset - truth.b).norm(), 1e-6 * truth.field);
  EXPECT_LT((by_reference.calibration.matrix - truth.W.inverse()).norm(), 1e-6);
}

// The shapes (magcal's 'eye' / 'diag' / 'sym'): a sensor without cross-axis coupling is fitted by the
// diagonal shape with the off-diagonal terms exactly zero and fewer, better determined parameters; a
// nested shape never fits better than the full one; the vector model refuses a shape.
TEST(RefineShape, DiagonalAndSphereAreNestedInSymmetric) {
  auto truth = fluxcal_test::make_truth(7, 50.0);
  truth.W = Eigen::Vector3d(1.1, 0.9, 1.05).asDiagonal();
  const fluxcal::Samples s = fluxcal_test::simulate(truth, 600, 0.01, 8);
  fluxcal::RefineOptions o;
  const auto sym = refined(s, truth.field, o);
  o.shape = fluxcal::Shape::diagonal;
  const auto diag = refined(s, truth.field, o);
  o.shape = fluxcal::Shape::sphere;
  const auto sphere = refined(s, truth.field, o);
  ASSERT_EQ(diag.parameters.size(), 6);
  ASSERT_EQ(sphere.parameters.size(), 4);
  EXPECT_EQ(diag.parameter_names[4], "a11");
  EXPECT_EQ(sphere.parameter_names[3], "a");
  const Eigen::Matrix3d A = diag.calibration.matrix;
  EXPECT_EQ(A(0, 1), 0.0);
  EXPECT_EQ(A(0, 2), 0.0);
  EXPECT_EQ(A(1, 2), 0.0);
  EXPECT_LT((A - truth.W.inverse()).norm(), 0.01);
  EXPECT_LT((diag.calibration.offset - truth.b).norm(), 0.01 * truth.field);
  // nested: the full shape's residuals are no larger; the sphere's much larger (its axes differ by 20 %)
  EXPECT_LE(sym.summary.cost, diag.summary.cost * (1 + 1e-9));
  EXPECT_GT(sphere.summary.cost, 10 * diag.summary.cost);
  EXPECT_DOUBLE_EQ(sphere.calibration.matrix(0, 0), sphere.calibration.matrix(2, 2));
  EXPECT_EQ(diag.covariance.rows(), 6);
  EXPECT_TRUE(diag.identifiable);
  // fewer parameters, smaller errors for the ones both fit
  for (int j = 0; j < 3; ++j) EXPECT_LT(diag.standard_errors(j), sym.standard_errors(j) * 1.001);
  EXPECT_THROW(fluxcal::refine_vector(diag.calibration, s, s, o), fluxcal::Error);
}

TEST(RefineOptions, BadValuesAreNamed) {
  const auto truth = fluxcal_test::make_truth(3, 50.0);
  const fluxcal::Samples s = fluxcal_test::simulate(truth, 400, 0.01, 4);
  fluxcal::Calibration start = fluxcal::fit_ellipsoid(s).calibration;
  start.field_norm = truth.field;
  fluxcal::RefineOptions o;
  o.loss = static_cast<fluxcal::Loss>(7);  // fitted without a loss before
  EXPECT_ERROR_SAYS(fluxcal::refine(start, s, o), "RefineOptions::loss: 7, need one of none, huber, cauchy");
  o = {};
  o.shape = static_cast<fluxcal::Shape>(9);
  EXPECT_ERROR_SAYS(fluxcal::refine(start, s, o), "RefineOptions::shape: 9");
  o = {};
  o.serial_correlation = static_cast<fluxcal::SerialCorrelation>(-1);
  EXPECT_ERROR_SAYS(fluxcal::refine(start, s, o), "RefineOptions::serial_correlation: -1");
  o = {};
  o.serial_correlation_alpha = std::nan("");
  EXPECT_ERROR_SAYS(fluxcal::refine(start, s, o), "RefineOptions::serial_correlation_alpha: nan");
  o = {};
  o.max_iterations = 0;
  EXPECT_ERROR_SAYS(fluxcal::fit_vector(s, s, o), "RefineOptions::max_iterations: 0");
  o = {};
  o.loss_scale = -1.0;
  EXPECT_ERROR_SAYS(fluxcal::refine_vector(start, s, s, o), "RefineOptions::loss_scale: -1");
}

TEST(RefineInputs, WrongWidthNamesTheArgument) {
  const auto truth = fluxcal_test::make_truth(3, 50.0);
  const fluxcal::Samples s = fluxcal_test::simulate(truth, 400, 0.01, 4);
  const fluxcal::Calibration start = fluxcal::fit_ellipsoid(s).calibration;
  const Eigen::MatrixXd two = s.leftCols(2);
  EXPECT_ERROR_SAYS(fluxcal::fit_vector(s, two), "reference: a matrix of 400 rows × 2 columns, need 3 columns");
  EXPECT_ERROR_SAYS(fluxcal::refine_vector(start, s, two), "reference: a matrix of 400 rows × 2 columns");
  EXPECT_ERROR_SAYS(fluxcal::refine(start, two), "samples: a matrix of 400 rows × 2 columns");
  EXPECT_ERROR_SAYS(start.apply_rows(two), "readings: a matrix of 400 rows × 2 columns");
}

// Readings whose squares overflow: refine failed inside Ceres ("Residual and Jacobian evaluation
// failed", naming no input), fit_vector said converged with an infinite cost.
TEST(RefineInputs, HugeReadingsAreNamed) {
  const auto truth = fluxcal_test::make_truth(3, 50.0);
  const fluxcal::Samples s = fluxcal_test::simulate(truth, 400, 0.01, 4);
  const fluxcal::Samples big = s * 1e300;
  fluxcal::Calibration start;
  start.offset = truth.b * 1e300;
  start.matrix = truth.W.inverse();
  start.field_norm = truth.field * 1e300;
  EXPECT_ERROR_SAYS(fluxcal::refine(start, big), "samples: values up to");
  EXPECT_ERROR_SAYS(fluxcal::refine(start, big), "-parameter magnitude refinement");  // what overflowed
  const fluxcal::Samples reference = (s.rowwise() - truth.b.transpose()) * truth.W.inverse().transpose();
  EXPECT_ERROR_SAYS(fluxcal::fit_vector(big, reference), "samples: values up to");
  EXPECT_ERROR_SAYS(fluxcal::fit_vector(big, reference), "overflow a 12-parameter vector calibration");
  EXPECT_ERROR_SAYS(fluxcal::fit_vector(s, reference * 1e300), "reference: values up to");
  EXPECT_ERROR_SAYS(fluxcal::refine_vector(fluxcal::Calibration(), s, reference * 1e300), "reference: values up to");
}

// Readings whose squares underflow (|x| < 1.5e-154): refine failed inside Ceres with a NaN Jacobian,
// fit_vector called the fitted W singular or the reference planar.
TEST(RefineInputs, AStartFarFromItsOwnFieldNormIsScaledToItAndSaid) {
  // A Calibration filled with a file's offset and matrix alone keeps field_norm 1: refine had failed, blaming the
  // data ("not positive definite"). Now the start's matrix is scaled to field_norm and a warning names it.
  const auto truth = fluxcal_test::make_truth(3, 50000.0);
  const fluxcal::Samples s = fluxcal_test::simulate(truth, 600, 0.002, 4);
  const fluxcal::RefineResult right = fluxcal::refine(fluxcal::fit_ellipsoid(s, {}).calibration, s);
  fluxcal::Calibration start;
  start.offset = right.calibration.offset;
  start.matrix = right.calibration.matrix * 1.01;
  start.field_norm = 1.0;
  const fluxcal::RefineResult r = fluxcal::refine(start, s);
  EXPECT_NEAR(r.calibration.field_norm, 1.0, 0.0);
  EXPECT_LT((r.calibration.offset - right.calibration.offset).norm(), 1e-6 * truth.field);
  EXPECT_LT((r.calibration.matrix * right.calibration.field_norm - right.calibration.matrix).norm(),
            1e-6 * right.calibration.matrix.norm());
  ASSERT_FALSE(r.summary.warnings.empty());
  EXPECT_NE(r.summary.warnings.back().find("times start.field_norm 1; its matrix was scaled"), std::string::npos)
      << r.summary.warnings.back();
  for (const std::string& w : right.summary.warnings) EXPECT_EQ(w.find("start.field_norm"), std::string::npos) << w;
  // The same start with each reading's field magnitude: its matrix had been scaled by their mean over 1, 5e4× off.
  const Eigen::VectorXd norms = Eigen::VectorXd::Constant(s.rows(), right.calibration.field_norm);
  const fluxcal::RefineResult each = fluxcal::refine(start, s, norms);
  EXPECT_LT((each.calibration.offset - right.calibration.offset).norm(), 1e-6 * truth.field);
  EXPECT_NE(each.summary.warnings.front().find("times start.field_norm 1"), std::string::npos);
  EXPECT_GT(right.summary.coverage_ratio, 0.5);  // the readings' spread, as the ellipsoid fit reports (it was 0)
}

TEST(RefineInputs, TinyReadingsAreNamed) {
  const auto truth = fluxcal_test::make_truth(3, 50.0);
  const fluxcal::Samples s = fluxcal_test::simulate(truth, 400, 0.01, 4);
  const fluxcal::Samples tiny = s * 1e-200;
  fluxcal::Calibration start = fluxcal::fit_ellipsoid(tiny).calibration;  // normalised: fits at any scale
  EXPECT_NEAR((start.offset * 1e200 - truth.b).norm() / truth.field, 0.0, 0.01);
  // Its |h| statistics too (they had underflowed to a negative mean |h| and a zero residual): as at full scale.
  for (const bool exact : {false, true}) {
    fluxcal::EllipsoidOptions o;
    o.exact_statistics = exact;
    const fluxcal::Summary big = fluxcal::fit_ellipsoid(s, o).summary, small = fluxcal::fit_ellipsoid(tiny, o).summary;
    EXPECT_NEAR(small.norm_mean * 1e200 / big.norm_mean, 1.0, 1e-9) << exact;
    EXPECT_NEAR(small.residual_rms * 1e200 / big.residual_rms, 1.0, 1e-6) << exact;
    EXPECT_NEAR(small.norm_std_over_mean / big.norm_std_over_mean, 1.0, 1e-6) << exact;
  }
  EXPECT_ERROR_SAYS(fluxcal::refine(start, tiny), "samples: values no larger than");
  EXPECT_ERROR_SAYS(fluxcal::refine(start, tiny), "underflow a 9-parameter magnitude refinement");
  const fluxcal::Samples reference = (s.rowwise() - truth.b.transpose()) * truth.W.inverse().transpose();
  EXPECT_ERROR_SAYS(fluxcal::fit_vector(tiny, reference * 1e-200), "samples: values no larger than");
  EXPECT_ERROR_SAYS(fluxcal::fit_vector(s, reference * 1e-200), "reference: values no larger than");
  EXPECT_NO_THROW(fluxcal::fit_vector(s * 1e-150, reference));  // squares still normal doubles
}

TEST(RefineFieldNorms, EachReadingsOwnFieldAndTheSameOneEverywhere) {
  // The same field everywhere given per reading is the scalar model; a field changing by ±2 % is recovered
  // with each reading's own |h|, and put into the offset without it.
  const auto t = fluxcal_test::make_truth(11, 50.0);
  const fluxcal::Samples base = fluxcal_test::simulate(t, 800, 0.002, 12);
  fluxcal::Calibration start = fluxcal::fit_ellipsoid(base).calibration;
  start.field_norm = t.field;
  const Eigen::VectorXd same = Eigen::VectorXd::Constant(base.rows(), t.field);
  const auto scalar = fluxcal::refine(start, base);
  const auto per = fluxcal::refine(start, base, same);
  EXPECT_LT((scalar.parameters - per.parameters).norm(), 1e-9 * t.field);

  Eigen::VectorXd k(base.rows());
  for (Eigen::Index i = 0; i < k.size(); ++i) k(i) = 1.0 + 0.02 * std::sin(5.0 * i / k.size());
  const fluxcal::Samples changed = (base.rowwise() - t.b.transpose()).array().colwise() * k.array();
  const fluxcal::Samples readings = changed.rowwise() + t.b.transpose();
  const auto own = fluxcal::refine(start, readings, Eigen::VectorXd(k * t.field));
  const auto one = fluxcal::refine(start, readings);
  EXPECT_NEAR(own.calibration.field_norm, k.mean() * t.field, 1e-9 * t.field);
  EXPECT_LT((own.calibration.offset - t.b).norm(), 0.2 * (one.calibration.offset - t.b).norm());
  EXPECT_LT(own.summary.norm_std_over_mean, 0.2 * one.summary.norm_std_over_mean);

  Eigen::VectorXd bad = same;
  bad(3) = std::nan("");
  EXPECT_ERROR_SAYS(fluxcal::refine(start, base, bad), "field_norms: value 3 is nan");
  EXPECT_ERROR_SAYS(fluxcal::refine(start, base, Eigen::VectorXd(same.head(10))), "field_norms: 10 values for 800 readings");
}

TEST(RefineFieldNorms, TermsTakeEachReadingsOwnField) {
  // refine_terms as refine: one field given per reading is the scalar model; a changing one is recovered by the base
  // model with each reading's |h|, and with one |h| for all it is left in the residuals.
  const auto t = fluxcal_test::make_truth(13, 50.0);
  const fluxcal::Samples base = fluxcal_test::simulate(t, 800, 0.002, 14);
  fluxcal::Calibration start = fluxcal::fit_ellipsoid(base).calibration;
  start.field_norm = t.field;
  const Eigen::MatrixXd none = Eigen::MatrixXd::Zero(base.rows(), 0);
  const Eigen::VectorXd same = Eigen::VectorXd::Constant(base.rows(), t.field);
  const auto scalar = fluxcal::refine_terms(start, base, none, Eigen::VectorXd());
  const auto per = fluxcal::refine_terms(start, base, same, none, Eigen::VectorXd());
  EXPECT_LT((scalar.parameters - per.parameters).norm(), 1e-9 * t.field);

  Eigen::VectorXd k(base.rows());
  for (Eigen::Index i = 0; i < k.size(); ++i) k(i) = 1.0 + 0.01 * std::sin(7.0 * i / k.size());
  const fluxcal::Samples readings =
      ((base.rowwise() - t.b.transpose()).array().colwise() * k.array()).matrix().rowwise() + t.b.transpose();
  const auto own = fluxcal::refine_terms(start, readings, Eigen::VectorXd(k * t.field), none, Eigen::VectorXd());
  const auto one = fluxcal::refine_terms(start, readings, none, Eigen::VectorXd());
  EXPECT_NEAR(own.calibration.field_norm, k.mean() * t.field, 1e-9 * t.field);
  EXPECT_LT(own.summary.residual_rms, 0.3 * one.summary.residual_rms);
  EXPECT_ERROR_SAYS(fluxcal::refine_terms(start, base, Eigen::VectorXd(same.head(5)), none, Eigen::VectorXd()),
                    "field_norms: 5 values for 800 readings");
}
