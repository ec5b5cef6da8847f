#include <fluxcal/alignment.hpp>

#include <gtest/gtest.h>

#include "errors.hpp"

#include <cmath>
#include <limits>
#include <random>

using fluxcal::Samples;

namespace {

constexpr double kDeg = 3.14159265358979323846 / 180.0;

struct Scene {
  Samples field, force;
  Eigen::Matrix3d truth;
};

enum class Turns { random, level, rolled };

// Random static attitudes (or yaw-only turns, or rolls about the body x axis held level at heading 30°), the field at a 62° dip, the magnetometer turned 4° about
// (1, 2, −1) from the accelerometer (h_acc = R h_mag), relative noise σ per axis on both.
Scene scene(int n, double sigma, unsigned seed, Turns turns = Turns::random) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0.0, 1.0);
  std::uniform_real_distribution<double> u(0.0, 2.0 * 3.14159265358979323846);
  Scene s{Samples(n, 3), Samples(n, 3), Eigen::AngleAxisd(4 * kDeg, Eigen::Vector3d(1, 2, -1).normalized()).toRotationMatrix()};
  const Eigen::Vector3d field_ned(50 * std::cos(62 * kDeg), 0, 50 * std::sin(62 * kDeg)), up(0, 0, -9.81);
  for (int k = 0; k < n; ++k) {
    Eigen::Matrix3d body_to_ned;
    if (turns == Turns::level) {
      body_to_ned = Eigen::AngleAxisd(u(rng), Eigen::Vector3d::UnitZ()).toRotationMatrix();
    } else if (turns == Turns::rolled) {
      body_to_ned = (Eigen::AngleAxisd(30 * kDeg, Eigen::Vector3d::UnitZ()) *
                     Eigen::AngleAxisd(u(rng), Eigen::Vector3d::UnitX())).toRotationMatrix();
    } else {
      body_to_ned = Eigen::Quaterniond(g(rng), g(rng), g(rng), g(rng)).normalized().toRotationMatrix();
    }
    const Eigen::Vector3d noise_h(g(rng), g(rng), g(rng)), noise_f(g(rng), g(rng), g(rng));
    s.field.row(k) = (s.truth.transpose() * body_to_ned.transpose() * field_ned + 50 * sigma * noise_h).transpose();
    s.force.row(k) = (body_to_ned.transpose() * up + 9.81 * sigma * noise_f).transpose();
  }
  return s;
}

double angle_between(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  return Eigen::AngleAxisd(a * b.transpose()).angle();
}

}  // namespace

TEST(Alignment, ExactDataGiveTheRotationAndTheDip) {
  const Scene s = scene(50, 0.0, 1);
  const auto r = fluxcal::align_to_gravity(s.field, s.force);
  EXPECT_LT(angle_between(r.rotation, s.truth), 1e-9);
  EXPECT_NEAR(r.dip, 62 * kDeg, 1e-9);
  EXPECT_TRUE(r.identifiable);
  EXPECT_TRUE(r.summary.converged);
}

TEST(Alignment, NoisyDataWithinTheirStandardErrors) {
  const Scene s = scene(400, 0.01, 2);
  const auto r = fluxcal::align_to_gravity(s.field, s.force);
  const Eigen::AngleAxisd error(r.rotation * s.truth.transpose());
  const Eigen::Vector3d e = error.angle() * error.axis();
  for (int i = 0; i < 3; ++i) EXPECT_LT(std::abs(e(i)), 4.5 * r.standard_errors(i)) << i;
  EXPECT_LT(std::abs(r.dip - 62 * kDeg), 4.5 * r.standard_errors(3));
  EXPECT_LT(r.standard_errors.head<3>().maxCoeff(), 0.2 * kDeg);  // 1 % noise, 400 readings: ≈ 0.05°
}

TEST(Alignment, LevelTurnsLeaveTheVerticalAxisUndetermined) {
  const Scene s = scene(200, 0.01, 3, Turns::level);
  const auto r = fluxcal::align_to_gravity(s.field, s.force);
  EXPECT_FALSE(r.identifiable);
  EXPECT_GT(r.standard_errors(2), 1.0 * kDeg);
  ASSERT_FALSE(r.summary.warnings.empty());
  bool named = false;
  for (const auto& w : r.summary.warnings) named |= w.find("not identifiable: the rotation about z") != std::string::npos;
  EXPECT_TRUE(named);
  EXPECT_GT(r.dip, 0.0);  // the answer nearest the axes as mounted, not its mirror (R flipped, the dip negated)
}

// Rolled about one body axis only, the rotation about it trades with the dip. The direction noise tilts J's rows at
// random and lent JᵀJ curvature along that trade (SE 0.3–0.7° for errors of 10–30°, flagged identifiable); the
// covariance through the cost's Hessian does not.
TEST(Alignment, RollsAboutOneAxisLeaveItsRotationUndetermined) {
  const Scene s = scene(5000, 0.01, 5, Turns::rolled);
  fluxcal::AlignmentOptions options;
  options.serial_correlation = fluxcal::SerialCorrelation::independent;
  const auto r = fluxcal::align_to_gravity(s.field, s.force, options);
  EXPECT_FALSE(r.identifiable);
  EXPECT_GT(r.standard_errors(0) / kDeg, 3.0);
  EXPECT_LT(r.standard_errors(1) / kDeg, 0.1);
  EXPECT_LT(r.standard_errors(2) / kDeg, 0.1);
}

TEST(Alignment, BadInputThrowsNamingIt) {
  Scene s = scene(30, 0.01, 4);
  Samples nan_field = s.field;
  nan_field(3, 1) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_ERROR_SAYS(fluxcal::align_to_gravity(nan_field, s.force), "field");
  EXPECT_ERROR_SAYS(fluxcal::align_to_gravity(s.field, s.force.topRows(29)), "specific_force: 29 rows");
  EXPECT_ERROR_SAYS(fluxcal::align_to_gravity(s.field.topRows(5), s.force.topRows(5)), "at least 8");
  const Eigen::MatrixXd two_columns = s.field.leftCols(2);
  EXPECT_ERROR_SAYS(fluxcal::align_to_gravity(two_columns, s.force), "field: a matrix of 30 rows × 2 columns");
  fluxcal::AlignmentOptions bad;
  bad.max_iterations = 0;
  EXPECT_ERROR_SAYS(fluxcal::align_to_gravity(s.field, s.force, bad), "AlignmentOptions::max_iterations");
  // Each option named alone (one message had named tolerance, max_se_deg and max_dynamic together).
  fluxcal::AlignmentOptions se;
  se.max_se_deg = -1.0;
  EXPECT_ERROR_SAYS(fluxcal::align_to_gravity(s.field, s.force, se), "AlignmentOptions::max_se_deg: -1, need");
  fluxcal::AlignmentOptions tol;
  tol.tolerance = 0.0;
  EXPECT_ERROR_SAYS(fluxcal::align_to_gravity(s.field, s.force, tol), "AlignmentOptions::tolerance: 0, need");
  fluxcal::AlignmentOptions dyn;
  dyn.max_dynamic = std::nan("");
  EXPECT_ERROR_SAYS(fluxcal::align_to_gravity(s.field, s.force, dyn), "AlignmentOptions::max_dynamic: nan, need");
}
