#include <fluxcal/positions.hpp>

#include <gtest/gtest.h>

#include "errors.hpp"

#include <cmath>
#include <limits>
#include <random>

using fluxcal::Frame;
using fluxcal::Samples;

namespace {

constexpr double kDeg = 3.14159265358979323846 / 180.0;

// Seed 002's published sensor (mV, mV/nT) and its local field: H = 52200 nT, inclination 52°.
const Eigen::Vector3d kU0(-497.08827, 266.96974, -55.90444);
Eigen::Matrix3d paper_K() {
  Eigen::Matrix3d K;
  K << 0.08950715, -0.02225698, -0.00046962, 0.00018554, 0.08954021, -0.00008744, 0.00041184, 0.00018746,
      0.08925137;
  return K;
}
// (N, U, E): the field dips below the horizon, so its up component is −H sin I.
Eigen::Vector3d field_nue() { return {52200.0 * std::cos(52 * kDeg), -52200.0 * std::sin(52 * kDeg), 0.0}; }

struct Scene {
  Samples U, acc;
  std::vector<Eigen::Matrix3d> nominal, truth;
};

// The twelve positions with random tilt (≤ tilt°) and heading (≤ yaw°) errors, noise σ on U (mV);
// copies > 1 repeats them turned by 45° in heading each time.
Scene twelve(double tilt, double yaw, double noise, unsigned seed, int copies = 1) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::normal_distribution<double> g(0.0, 1.0);
  Scene s;
  for (int c = 0; c < copies; ++c)
    for (const auto& R : fluxcal::twelve_positions(Frame::nue))
      s.nominal.push_back(fluxcal::heading_rotation(45.0 * c * kDeg, Frame::nue) * R);
  const int n = 12 * copies;
  s.U.resize(n, 3);
  s.acc.resize(n, 3);
  const Eigen::Vector3d up = fluxcal::local_up(Frame::nue);
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d axis = Eigen::Vector3d(u(rng), 0.0, u(rng)).normalized();  // horizontal (N, E)
    const Eigen::Matrix3d R = fluxcal::heading_rotation(yaw * u(rng) * kDeg, Frame::nue) *
                              Eigen::AngleAxisd(tilt * u(rng) * kDeg, axis).toRotationMatrix() * s.nominal[i];
    s.truth.push_back(R);
    const Eigen::Vector3d H = R.transpose() * field_nue();
    s.U.row(i) = (kU0 + paper_K() * H + noise * Eigen::Vector3d(g(rng), g(rng), g(rng))).transpose();
    s.acc.row(i) = (9.80665 * R.transpose() * up).transpose();
  }
  return s;
}

TEST(Positions, PitchRollIsSeed002Eq4AndRotationIsEq6) {
  const double theta = 12.5 * kDeg, gamma = -33.0 * kDeg;
  const Eigen::Matrix3d R = fluxcal::body_to_local(theta, gamma, 0.0, Frame::nue);
  // Eq. 6 as printed, rows (N, U, E).
  Eigen::Matrix3d eq6;
  eq6 << std::cos(theta), -std::sin(theta) * std::cos(gamma), std::sin(theta) * std::sin(gamma), std::sin(theta),
      std::cos(theta) * std::cos(gamma), -std::cos(theta) * std::sin(gamma), 0.0, std::sin(gamma), std::cos(gamma);
  EXPECT_LT((R - eq6).norm(), 1e-14);
  const Eigen::Vector3d a = 9.8 * R.transpose() * fluxcal::local_up(Frame::nue);  // specific force, body
  const Eigen::Vector2d pr = fluxcal::pitch_roll(a, Frame::nue);
  EXPECT_NEAR(pr(0), std::asin(a(0) / a.norm()), 1e-14);
  EXPECT_NEAR(pr(1), std::atan(-a(2) / a(1)), 1e-14);
  EXPECT_NEAR(pr(0), theta, 1e-12);
  EXPECT_NEAR(pr(1), gamma, 1e-12);
  // ned: same physical attitude.
  const Eigen::Matrix3d Rn = fluxcal::body_to_local(theta, gamma, 40 * kDeg, Frame::ned);
  const Eigen::Vector2d prn = fluxcal::pitch_roll(9.8 * Rn.transpose() * fluxcal::local_up(Frame::ned), Frame::ned);
  EXPECT_NEAR(prn(0), theta, 1e-12);
  EXPECT_NEAR(prn(1), gamma, 1e-12);
}

TEST(Positions, TwelvePresetsAreProperRotationsAndAgreeBetweenFrames) {
  const auto nue = fluxcal::twelve_positions(Frame::nue), ned = fluxcal::twelve_positions(Frame::ned);
  ASSERT_EQ(nue.size(), 12u);
  Eigen::Matrix3d nue_to_ned;  // (N, E, D) from (N, U, E)
  nue_to_ned << 1, 0, 0, 0, 0, 1, 0, -1, 0;
  Eigen::Matrix3d frd_from_fur;  // body FRD from FUR
  frd_from_fur << 1, 0, 0, 0, 0, 1, 0, -1, 0;
  for (int i = 0; i < 12; ++i) {
    EXPECT_NEAR(nue[i].determinant(), 1.0, 1e-15);
    EXPECT_LT((nue_to_ned * nue[i] * frd_from_fur.transpose() - ned[i]).norm(), 1e-15) << "position " << i + 1;
  }
  // Position 1 is N-U-E: identity in nue.
  EXPECT_LT((nue[0] - Eigen::Matrix3d::Identity()).norm(), 1e-15);
}

TEST(Positions, ClosedFormAndLeastSquaresAgreeNoiseFree) {
  const Scene s = twelve(0.0, 0.0, 0.0, 1);
  fluxcal::PositionsOptions o;
  o.frame = Frame::nue;
  const auto ls = fluxcal::calibrate_positions(s.U, s.acc, s.nominal, field_nue(), o);
  // The signed up component: the field dips down, so it is −41134 nT (the paper quotes the magnitude).
  const auto cf = fluxcal::twelve_position_closed_form(s.U, field_nue()(1));
  EXPECT_LT((ls.K - paper_K()).cwiseAbs().maxCoeff() / 0.0895, 1e-12);
  EXPECT_LT((ls.offset - kU0).cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_LT((cf.K - ls.K).cwiseAbs().maxCoeff() / 0.0895, 1e-9);
  EXPECT_LT((cf.offset - ls.offset).cwiseAbs().maxCoeff(), 1e-9);
}

TEST(Positions, HeadingErrorsAreEstimatedJointly) {
  // The twelve alone determine headings poorly (a symmetric set: K's standard error ~1 % at 5 nT), so
  // the twelve twice, the second set turned 45° in heading.
  const Scene s = twelve(1.0, 3.0, 0.45, 7, 2);  // 0.45 mV ≈ 5 nT
  fluxcal::PositionsOptions o;
  o.frame = Frame::nue;
  const auto fixed = fluxcal::calibrate_positions(s.U, s.acc, s.nominal, field_nue(), o);
  o.estimate_yaw = true;
  const auto joint = fluxcal::calibrate_positions(s.U, s.acc, s.nominal, field_nue(), o);
  const double err_fixed = (fixed.K - paper_K()).cwiseAbs().maxCoeff() / 0.0895;
  const double err_joint = (joint.K - paper_K()).cwiseAbs().maxCoeff() / 0.0895;
  EXPECT_LT(err_joint, 2e-3);
  EXPECT_GT(err_fixed, err_joint);  // 3° heading errors bias the fixed-heading fit
  ASSERT_EQ(joint.yaw.size(), 24);
  for (int i = 0; i < 24; ++i) {
    // True heading correction: R_true = Hrot(ψ) · level(nominal).
    const Eigen::Matrix3d L = fluxcal::level_rotation(s.nominal[i], s.acc.row(i).transpose(), Frame::nue);
    const Eigen::Matrix3d D = s.truth[i] * L.transpose();  // rotation about up
    const double psi = std::atan2(D(2, 0), D(0, 0));
    EXPECT_NEAR(joint.yaw(i), psi, 0.1 * kDeg) << "position " << i + 1;
  }
}

TEST(Positions, BadInputIsAClearError) {
  const Scene s = twelve(0.0, 0.0, 0.0, 3);
  fluxcal::PositionsOptions o;
  o.frame = Frame::nue;
  // Too few positions.
  EXPECT_THROW(fluxcal::fit_positions(s.U.topRows(3), s.U.topRows(3), o), fluxcal::Error);
  // Positions 1–4 only: y axis vertical, the field's body x and z cancel pairwise -> H in planes?
  // Positions 1 and 2 and their repeats: all H with the same y component (a plane).
  Samples U(4, 3), H(4, 3);
  for (int i = 0; i < 4; ++i) {
    H.row(i) << 30000.0 * std::cos(i), 41134.0, 30000.0 * std::sin(i);
    U.row(i) = (kU0 + paper_K() * H.row(i).transpose()).transpose();
  }
  try {
    fluxcal::fit_positions(U, H, o);
    FAIL() << "no error for a planar set";
  } catch (const fluxcal::Error& e) {
    EXPECT_NE(std::string(e.what()).find("cannot be separated"), std::string::npos) << e.what();
  }
  // A moving device.
  Samples acc = s.acc;
  acc.row(5) *= 1.2;
  EXPECT_THROW(fluxcal::calibrate_positions(s.U, acc, s.nominal, field_nue(), o), fluxcal::Error);
  // Missing field.
  EXPECT_THROW(fluxcal::calibrate_positions(s.U, s.acc, s.nominal, Eigen::Vector3d::Zero(), o), fluxcal::Error);
  // Accelerometer that reports gravity (down) instead of specific force.
  EXPECT_THROW(fluxcal::calibrate_positions(s.U, -s.acc, s.nominal, field_nue(), o), fluxcal::Error);
}

TEST(Positions, AccelerometerCalibration) {
  std::mt19937 rng(11);
  std::normal_distribution<double> g(0.0, 1.0);
  Eigen::Matrix3d W;  // raw = W a + b
  W << 1.02, 0.004, -0.003, 0.0, 0.985, 0.002, 0.0, 0.0, 1.01;
  const Eigen::Vector3d b(0.12, -0.08, 0.2);
  Samples raw(24, 3);
  for (int i = 0; i < 24; ++i) {
    const Eigen::Vector3d a = 9.80665 * Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
    raw.row(i) = (W * a + b).transpose();
  }
  const auto r = fluxcal::calibrate_accelerometer(raw);
  EXPECT_TRUE(r.misalignment_estimated);
  EXPECT_LT((r.offset - b).norm(), 1e-8);
  EXPECT_LT((r.matrix - W.inverse()).norm(), 1e-8);
  EXPECT_LT(r.tilt_error_deg, 1e-8);
  // Six faces: offset and scales only.
  Samples six(6, 3);
  const Eigen::Matrix3d D = Eigen::Vector3d(1.02, 0.985, 1.01).asDiagonal();
  for (int i = 0; i < 6; ++i) {
    Eigen::Vector3d a = Eigen::Vector3d::Zero();
    a(i / 2) = (i % 2 ? -1.0 : 1.0) * 9.80665;
    six.row(i) = (D * a + b).transpose();
  }
  const auto r6 = fluxcal::calibrate_accelerometer(six);
  EXPECT_FALSE(r6.misalignment_estimated);
  EXPECT_LT((r6.offset - b).norm(), 1e-8);
  EXPECT_LT((r6.matrix - Eigen::Matrix3d(D.inverse())).norm(), 1e-8);
  EXPECT_THROW(fluxcal::calibrate_accelerometer(six.topRows(5)), fluxcal::Error);
  // Each face twice (turned about the vertical): 12 rows, still 6 directions — no misalignment from them.
  Samples twelve(12, 3);
  twelve << six, six;
  twelve.bottomRows(6).array() += 1e-5;
  const auto r12 = fluxcal::calibrate_accelerometer(twelve);
  EXPECT_FALSE(r12.misalignment_estimated);
  EXPECT_LT((r12.offset - b).norm(), 1e-4);
  // Ten rows but only five directions: offset and scales are not determined.
  Samples five(10, 3);
  five << six.topRows(5), six.topRows(5);
  EXPECT_THROW(fluxcal::calibrate_accelerometer(five), fluxcal::Error);
}

}  // namespace

// Review of the C++ API: checks the Python layer made are in the core, where C++ callers get them.
TEST(Positions, CoreRefusesNonRotationsAndNonFiniteOptions) {
  const Scene s = twelve(0.0, 0.0, 0.0, 1);
  fluxcal::PositionsOptions o;
  o.frame = Frame::nue;
  auto scaled = s.nominal;
  scaled[3] *= 2.0;  // scaled K silently before
  EXPECT_THROW(fluxcal::calibrate_positions(s.U, s.acc, scaled, field_nue(), o), fluxcal::Error);
  o.output_sigma = std::nan("");
  EXPECT_THROW(fluxcal::calibrate_positions(s.U, s.acc, s.nominal, field_nue(), o), fluxcal::Error);
  fluxcal::AccelerometerOptions a;
  a.gravity = std::numeric_limits<double>::infinity();
  EXPECT_THROW(fluxcal::calibrate_accelerometer(s.acc, a), fluxcal::Error);
  EXPECT_THROW(fluxcal::PositionsResult().field_of(Eigen::Vector3d::Ones()), fluxcal::Error);
  EXPECT_THROW(fluxcal::level_rotation(Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero(), Frame::nue),
               fluxcal::Error);
  EXPECT_ERROR_SAYS(fluxcal::body_to_local(0.1, std::nan(""), 0.0, Frame::ned), "roll: nan, need a finite angle");
}

TEST(PositionsOptions, BadValuesAreNamed) {
  const Scene s = twelve(0.0, 0.0, 0.0, 1);
  fluxcal::PositionsOptions o;
  o.frame = static_cast<Frame>(4);  // was taken for nue
  EXPECT_ERROR_SAYS(fluxcal::calibrate_positions(s.U, s.acc, s.nominal, field_nue(), o), "PositionsOptions::frame: 4");
  o = {};
  o.frame = Frame::nue;
  o.gravity_tolerance = std::nan("");
  EXPECT_ERROR_SAYS(fluxcal::calibrate_positions(s.U, s.acc, s.nominal, field_nue(), o),
                    "PositionsOptions::gravity_tolerance: nan");
  o.gravity_tolerance = 0.05;
  o.tilt_sigma_deg = -1.0;
  EXPECT_ERROR_SAYS(fluxcal::calibrate_positions(s.U, s.acc, s.nominal, field_nue(), o),
                    "PositionsOptions::tilt_sigma_deg: -1");
  o.tilt_sigma_deg = 0.0;
  o.determined_tolerance = std::nan("");
  EXPECT_ERROR_SAYS(fluxcal::fit_positions(s.U, s.U, o), "PositionsOptions::determined_tolerance: nan");
  o.determined_tolerance = 0.01;
  o.max_iterations = 0;
  EXPECT_ERROR_SAYS(fluxcal::calibrate_positions(s.U, s.acc, s.nominal, field_nue(), o),
                    "PositionsOptions::max_iterations: 0, need ≥ 1");
  fluxcal::AccelerometerOptions a;
  a.gravity = -9.8;
  EXPECT_ERROR_SAYS(fluxcal::calibrate_accelerometer(s.acc, a), "AccelerometerOptions::gravity: -9.8");
  a = {};
  a.max_iterations = -1;
  EXPECT_ERROR_SAYS(fluxcal::calibrate_accelerometer(s.acc, a), "AccelerometerOptions::max_iterations: -1");
  EXPECT_ERROR_SAYS(fluxcal::local_up(static_cast<Frame>(3)), "frame: 3");
  EXPECT_ERROR_SAYS(fluxcal::twelve_positions(static_cast<Frame>(-1)), "frame: -1");
}

TEST(Positions, WrongWidthNamesTheArgument) {
  const Scene s = twelve(0.0, 0.0, 0.0, 1);
  const Eigen::MatrixXd two = Eigen::MatrixXd::Ones(12, 2), four = Eigen::MatrixXd::Ones(12, 4);
  EXPECT_ERROR_SAYS(fluxcal::fit_positions(s.U, two), "reference: a matrix of 12 rows × 2 columns, need 3 columns");
  EXPECT_ERROR_SAYS(fluxcal::fit_positions(four, s.U), "outputs: a matrix of 12 rows × 4 columns");
  fluxcal::PositionsOptions o;
  o.frame = Frame::nue;
  EXPECT_ERROR_SAYS(fluxcal::calibrate_positions(s.U, four, s.nominal, field_nue(), o),
                    "specific_force: a matrix of 12 rows × 4 columns");
  EXPECT_ERROR_SAYS(fluxcal::calibrate_accelerometer(two), "readings: a matrix of 12 rows × 2 columns");
  EXPECT_ERROR_SAYS(fluxcal::twelve_position_closed_form(two, 1.0), "outputs: a matrix of 12 rows × 2 columns");
}

// Outputs whose squares overflow used to give a converged fit with an infinite residual.
TEST(Positions, HugeOutputsAreNamed) {
  const Scene s = twelve(0.0, 0.0, 0.0, 1);
  fluxcal::PositionsOptions o;
  o.frame = Frame::nue;
  const Samples big = s.U * 1e300;
  EXPECT_ERROR_SAYS(fluxcal::calibrate_positions(big, s.acc, s.nominal, field_nue(), o), "outputs: values up to");
  o.estimate_yaw = true;  // named "not observable" parameters before
  EXPECT_ERROR_SAYS(fluxcal::calibrate_positions(big, s.acc, s.nominal, field_nue(), o), "outputs: values up to");
  EXPECT_ERROR_SAYS(fluxcal::calibrate_accelerometer(s.acc * 1e300), "readings: values up to");
}
