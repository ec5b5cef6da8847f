#include <fluxcal/cable.hpp>

#include <gtest/gtest.h>

#include "errors.hpp"

#include <cmath>
#include <limits>
#include <random>

using fluxcal::CableRing;
using fluxcal::ConductorPositions;

namespace {

CableRing paper_ring() {
  CableRing r;
  r.angles.resize(4);
  r.angles << 0.0, M_PI / 2, M_PI, 3 * M_PI / 2;
  r.radius = 0.010;
  return r;
}

Eigen::MatrixXd snapshot(const CableRing& ring, const ConductorPositions& p, const Eigen::VectorXd& I) {
  const auto b = fluxcal::cable_field(ring, p, I);
  Eigen::MatrixXd row(1, 2 * ring.sensors());
  for (Eigen::Index i = 0; i < ring.sensors(); ++i) row(0, 2 * i) = b(i, 0), row(0, 2 * i + 1) = b(i, 1);
  return row;
}

}  // namespace

TEST(Cable, CentredConductorIsPurelyTangential) {
  const CableRing ring = paper_ring();
  ConductorPositions p(1, 2);
  p << 0.0, 0.0;
  const auto b = fluxcal::cable_field(ring, p, Eigen::VectorXd::Constant(1, 3.0));
  for (int i = 0; i < 4; ++i) {
    EXPECT_NEAR(b(i, 0), 0.0, 1e-18);
    EXPECT_NEAR(b(i, 1), fluxcal::kMu0Over2Pi * 3.0 / 0.010, 1e-16);  // right-hand rule: +I gives +tangential
  }
}

TEST(Cable, AxisAnglesTurnTheReading) {
  CableRing ring = paper_ring();
  ConductorPositions p(2, 2);
  p << -1e-3, 0.5e-3, 2e-3, -1e-3;
  const Eigen::Vector2d I(4.0, -3.0);
  const auto b0 = fluxcal::cable_field(ring, p, I);
  ring.axis_angles = Eigen::VectorXd::Constant(4, 0.3);
  const auto b1 = fluxcal::cable_field(ring, p, I);
  for (int i = 0; i < 4; ++i) {
    EXPECT_NEAR(b1(i, 0), std::cos(0.3) * b0(i, 0) + std::sin(0.3) * b0(i, 1), 1e-18);
    EXPECT_NEAR(b1(i, 1), -std::sin(0.3) * b0(i, 0) + std::cos(0.3) * b0(i, 1), 1e-18);
  }
}

TEST(Cable, JacobianMatchesFiniteDifferences) {
  const CableRing ring = paper_ring();
  ConductorPositions p(2, 2);
  p << -1.2e-3, 0.7e-3, 2.1e-3, -0.4e-3;
  Eigen::VectorXd I(2);
  I << 5.0, -4.0;
  const Eigen::MatrixXd J = fluxcal::cable_field_jacobian(ring, p, I);
  for (int k = 0; k < 6; ++k) {
    ConductorPositions pp = p, pm = p;
    Eigen::VectorXd Ip = I, Im = I;
    const double h = k < 4 ? 1e-8 : 1e-4;
    if (k < 4) pp(k / 2, k % 2) += h, pm(k / 2, k % 2) -= h;
    else Ip(k - 4) += h, Im(k - 4) -= h;
    const auto bp = fluxcal::cable_field(ring, pp, Ip), bm = fluxcal::cable_field(ring, pm, Im);
    for (int i = 0; i < 4; ++i)
      for (int a = 0; a < 2; ++a) {
        const double fd = (bp(i, a) - bm(i, a)) / (2 * h);
        EXPECT_NEAR(J(2 * i + a, k), fd, 1e-6 * J.col(k).cwiseAbs().maxCoeff()) << "column " << k;
      }
  }
}

TEST(Cable, SolvesATwoCoreCableFromOneSnapshot) {
  const CableRing ring = paper_ring();
  ConductorPositions p(2, 2);
  p << -1.7e-3, 0.4e-3, 2.3e-3, 0.1e-3;
  const Eigen::Vector2d I(5.0, -5.0);
  const auto sol = fluxcal::solve_cable(ring, snapshot(ring, p, I));
  EXPECT_TRUE(sol.well_conditioned) << sol.summary.message;
  EXPECT_LT((sol.positions - p).cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_LT((sol.currents.row(0).transpose() - I).cwiseAbs().maxCoeff(), 1e-7);
  EXPECT_EQ(sol.covariance.rows(), 6);
}

TEST(Cable, FitsAUniformBackgroundBesideTheConductors) {
  const CableRing ring = paper_ring();
  ConductorPositions p(2, 2);
  p << -1.7e-3, 0.4e-3, 2.3e-3, 0.1e-3;
  const Eigen::Vector2d earth(25e-6, -30e-6);
  Eigen::MatrixXd R(3, 8);
  const double scale[3] = {1.0, -0.6, 0.3};
  for (int s = 0; s < 3; ++s) {
    R.row(s) = snapshot(ring, p, Eigen::Vector2d(5.0, -5.0) * scale[s]);
    for (Eigen::Index i = 0; i < 4; ++i) {  // x radial, y tangential
      const Eigen::Vector2d r(std::cos(ring.angles(i)), std::sin(ring.angles(i))), t(-r(1), r(0));
      R(s, 2 * i) += r.dot(earth);
      R(s, 2 * i + 1) += t.dot(earth);
    }
  }
  fluxcal::CableSolveOptions o;
  const auto plain = fluxcal::solve_cable(ring, R, o);
  EXPECT_FALSE(plain.fits_model);
  bool hinted = false;  // the misfit's warning names the remedy
  for (const auto& w : plain.summary.warnings) hinted = hinted || w.find("fit_background") != std::string::npos;
  EXPECT_TRUE(hinted);
  o.fit_background = true;
  for (auto refiner : {fluxcal::CableSolveOptions::Refiner::ceres, fluxcal::CableSolveOptions::Refiner::dense}) {
    o.refiner = refiner;
    const auto sol = fluxcal::solve_cable(ring, R, o);
    EXPECT_TRUE(sol.fits_model && sol.well_conditioned) << sol.summary.message;
    EXPECT_LT((sol.positions - p).cwiseAbs().maxCoeff(), 1e-9);
    EXPECT_LT((sol.background - earth).cwiseAbs().maxCoeff(), 1e-12);
    EXPECT_EQ(sol.covariance.rows(), 4 + 2 * 3 + 2);
  }
}

TEST(Cable, MisfitTestWithSigmaOfKnownPrecision) {
  // a uniform field of 4 σ that the model leaves out, under 10 nT noise: within the ratio rule's 5 σ, but
  // improbable for a σ known from its degrees of freedom
  const CableRing ring = paper_ring();
  ConductorPositions p(2, 2);
  p << -1.7e-3, 0.4e-3, 2.3e-3, 0.1e-3;
  std::mt19937 rng(11);
  std::normal_distribution<double> g(0.0, 1e-8);
  Eigen::MatrixXd clean(6, 8), shifted(6, 8);
  for (int s = 0; s < 6; ++s) {
    clean.row(s) = snapshot(ring, p, Eigen::Vector2d(5.0, -5.0) * (1.0 - 0.3 * s));
    for (int k = 0; k < 8; ++k) clean(s, k) += g(rng);
    shifted.row(s) = clean.row(s);
    for (Eigen::Index i = 0; i < 4; ++i)  // 40 nT along x of the cable frame
      shifted(s, 2 * i) += 4e-8 * std::cos(ring.angles(i)), shifted(s, 2 * i + 1) -= 4e-8 * std::sin(ring.angles(i));
  }
  fluxcal::CableSolveOptions o;
  const auto ratio_only = fluxcal::solve_cable(ring, shifted, o);
  EXPECT_TRUE(ratio_only.fits_model) << ratio_only.summary.message;
  EXPECT_TRUE(std::isnan(ratio_only.misfit_p));
  for (double dof : {200.0, std::numeric_limits<double>::infinity()}) {
    o.noise_sigma_dof = dof;
    const auto flagged = fluxcal::solve_cable(ring, shifted, o);
    EXPECT_FALSE(flagged.fits_model) << flagged.summary.message;
    EXPECT_LT(flagged.misfit_p, 1e-3);
    const auto fine = fluxcal::solve_cable(ring, clean, o);
    EXPECT_TRUE(fine.fits_model) << fine.summary.message;
    EXPECT_GT(fine.misfit_p, 1e-3);
  }
  o.noise_sigma_dof = 3.0;  // σ from 3 degrees of freedom could be far too small: no verdict from the test
  EXPECT_TRUE(fluxcal::solve_cable(ring, shifted, o).fits_model);
  // every sensor's σ twice noise_sigma: the same fit, the covariance 4×
  fluxcal::CableSolveOptions w;
  const auto plain = fluxcal::solve_cable(ring, clean, w);
  w.relative_sigma = Eigen::VectorXd::Constant(4, 2.0);
  const auto weighted = fluxcal::solve_cable(ring, clean, w);
  EXPECT_LT((weighted.positions - plain.positions).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_NEAR(weighted.covariance(0, 0) / plain.covariance(0, 0), 4.0, 1e-6);
  w.relative_sigma = Eigen::VectorXd::Constant(3, 1.0);
  EXPECT_ERROR_SAYS(fluxcal::solve_cable(ring, clean, w), "relative_sigma: 3 values, the ring has 4 sensors");
  w.relative_sigma = Eigen::VectorXd::Constant(4, 0.0);
  EXPECT_ERROR_SAYS(fluxcal::solve_cable(ring, clean, w), "relative_sigma: need a finite σ > 0");
}

TEST(Cable, ThreeConductorsNeedSnapshotsAndShareTheirPositions) {
  const CableRing ring = paper_ring();
  ConductorPositions p(3, 2);
  p << -2.0e-3, -1.0e-3, 0.5e-3, 2.0e-3, 2.2e-3, -0.8e-3;
  // one snapshot: 9 unknowns, 8 readings
  EXPECT_THROW(fluxcal::solve_cable(ring, snapshot(ring, p, Eigen::Vector3d(1, 2, -3)),
                                    [] { fluxcal::CableSolveOptions o; o.n_conductors = 3; return o; }()),
               fluxcal::Error);
  // three-phase currents at 6 instants, ΣI = 0
  Eigen::MatrixXd R(6, 8), I(6, 3);
  for (int s = 0; s < 6; ++s) {
    for (int j = 0; j < 3; ++j) I(s, j) = 10.0 * std::cos(2 * M_PI * s / 12.0 - 2 * M_PI * j / 3.0);
    R.row(s) = snapshot(ring, p, I.row(s).transpose());
  }
  fluxcal::CableSolveOptions o;
  o.n_conductors = 3;
  o.zero_sum_currents = true;
  const auto sol = fluxcal::solve_cable(ring, R, o);
  EXPECT_LT((sol.positions - p).cwiseAbs().maxCoeff(), 1e-8) << sol.summary.message;
  EXPECT_LT((sol.currents - I).cwiseAbs().maxCoeff(), 1e-6);
  EXPECT_LT(std::abs(sol.currents.row(2).sum()), 1e-9);
}

TEST(Cable, CloseConductorsAreFlaggedIllConditioned) {
  const CableRing ring = paper_ring();
  ConductorPositions p(2, 2);
  p << -0.05e-3, 0.0, 0.05e-3, 0.0;  // 0.1 mm apart at the centre: only the dipole moment is seen
  const auto sol = fluxcal::solve_cable(ring, snapshot(ring, p, Eigen::Vector2d(5.0, -5.0)));
  EXPECT_FALSE(sol.well_conditioned);
  EXPECT_FALSE(sol.summary.warnings.empty());
}

TEST(Cable, WarmStartConverges) {
  const CableRing ring = paper_ring();
  ConductorPositions p(2, 2), start(2, 2);
  p << -1.7e-3, 0.4e-3, 2.3e-3, 0.1e-3;
  start << -1.5e-3, 0.5e-3, 2.0e-3, 0.0;
  fluxcal::CableSolveOptions o;
  o.initial_positions = start;
  const auto sol = fluxcal::solve_cable(ring, snapshot(ring, p, Eigen::Vector2d(5.0, -5.0)), o);
  EXPECT_EQ(sol.starts_tried, 1);
  EXPECT_LT((sol.positions - p).cwiseAbs().maxCoeff(), 1e-9);
}

TEST(Cable, DenseSolverAgreesWithCeres) {
  const CableRing ring = paper_ring();
  ConductorPositions p(2, 2);
  p << -1.7e-3, 0.4e-3, 2.3e-3, 0.1e-3;
  Eigen::MatrixXd R = snapshot(ring, p, Eigen::Vector2d(5.0, -5.0));
  std::mt19937 rng(3);
  std::normal_distribution<double> g(0.0, 1e-8);
  for (int k = 0; k < 8; ++k) R(0, k) += g(rng);
  fluxcal::CableSolveOptions o;
  const auto ceres_cold = fluxcal::solve_cable(ring, R, o);  // automatic: Ceres from the grid
  o.refiner = fluxcal::CableSolveOptions::Refiner::dense;
  const auto dense_cold = fluxcal::solve_cable(ring, R, o);
  o.initial_positions = p;
  o.initial_positions.array() += 0.2e-3;
  o.refiner = fluxcal::CableSolveOptions::Refiner::automatic;  // a warm start: the dense solver
  const auto dense_warm = fluxcal::solve_cable(ring, R, o);
  o.refiner = fluxcal::CableSolveOptions::Refiner::ceres;
  const auto ceres_warm = fluxcal::solve_cable(ring, R, o);
  EXPECT_LT((dense_cold.positions - ceres_cold.positions).cwiseAbs().maxCoeff(), 1e-10);
  EXPECT_LT((dense_warm.positions - ceres_cold.positions).cwiseAbs().maxCoeff(), 1e-10);
  EXPECT_LT((ceres_warm.positions - ceres_cold.positions).cwiseAbs().maxCoeff(), 1e-10);
  EXPECT_LT((dense_warm.currents - ceres_cold.currents).cwiseAbs().maxCoeff(), 1e-7);
  EXPECT_TRUE(dense_warm.summary.converged) << dense_warm.summary.message;
}

TEST(Cable, BadInputIsAClearError) {
  const CableRing ring = paper_ring();
  ConductorPositions p(2, 2);
  p << -1.7e-3, 0.4e-3, 2.3e-3, 0.1e-3;
  Eigen::MatrixXd R = snapshot(ring, p, Eigen::Vector2d(5.0, -5.0));
  R(0, 3) = std::numeric_limits<double>::quiet_NaN();
  try {
    fluxcal::solve_cable(ring, R);
    FAIL() << "NaN accepted";
  } catch (const fluxcal::Error& e) {
    EXPECT_NE(std::string(e.what()).find("NaN"), std::string::npos) << e.what();
  }
  // two sensors: 4 readings for 6 unknowns
  CableRing two = ring;
  two.angles = Eigen::Vector2d(0.0, M_PI / 2);
  try {
    fluxcal::solve_cable(two, Eigen::MatrixXd::Ones(1, 4) * 1e-5);
    FAIL() << "too few sensors accepted";
  } catch (const fluxcal::Error& e) {
    EXPECT_NE(std::string(e.what()).find("too few sensors"), std::string::npos) << e.what();
  }
  // a conductor outside the bore (4 mm for a 10 mm ring)
  ConductorPositions out(1, 2);
  out << 5e-3, 0.0;
  try {
    fluxcal::cable_field(ring, out, Eigen::VectorXd::Ones(1));
    FAIL() << "conductor outside the bore accepted";
  } catch (const fluxcal::Error& e) {
    EXPECT_NE(std::string(e.what()).find("outside the bore"), std::string::npos) << e.what();
  }
  CableRing bad = ring;
  bad.radius = -1.0;
  EXPECT_THROW(fluxcal::cable_field(bad, p, Eigen::Vector2d(1, 1)), fluxcal::Error);
}

TEST(Cable, WrongWidthPositionsAndNaNOptionsAreErrors) {
  const CableRing ring = paper_ring();
  const Eigen::MatrixXd three = Eigen::MatrixXd::Zero(2, 3);  // heap overrun in Release before
  EXPECT_THROW(fluxcal::cable_field(ring, three, Eigen::VectorXd::Ones(2)), fluxcal::Error);
  ConductorPositions p(2, 2);
  p << 0.001, 0.0, -0.001, 0.0;
  fluxcal::CableSolveOptions o;
  o.function_tolerance = std::nan("");
  EXPECT_THROW(fluxcal::solve_cable(ring, snapshot(ring, p, Eigen::Vector2d(1.0, -1.0)), o), fluxcal::Error);
  o = {};
  o.initial_positions = p;
  o.initial_currents = Eigen::MatrixXd::Constant(1, 2, std::nan(""));
  EXPECT_THROW(fluxcal::solve_cable(ring, snapshot(ring, p, Eigen::Vector2d(1.0, -1.0)), o), fluxcal::Error);
}

// Every option is checked on entry and the message names it: a NaN noise_sigma fell through
// `noise_sigma > 0` to the residual estimate, an out-of-range refiner to the dense solver.
TEST(CableOptions, BadValuesAreNamed) {
  const CableRing ring = paper_ring();
  ConductorPositions p(2, 2);
  p << 0.001, 0.0, -0.001, 0.0;
  const Eigen::MatrixXd y = snapshot(ring, p, Eigen::Vector2d(1.0, -1.0));
  fluxcal::CableSolveOptions o;
  o.noise_sigma = std::nan("");
  EXPECT_ERROR_SAYS(fluxcal::solve_cable(ring, y, o), "CableSolveOptions::noise_sigma: nan");
  o = {};
  o.max_position_sigma = -1.0;
  EXPECT_ERROR_SAYS(fluxcal::solve_cable(ring, y, o), "CableSolveOptions::max_position_sigma: -1");
  o = {};
  o.misfit_ratio = std::numeric_limits<double>::infinity();
  EXPECT_ERROR_SAYS(fluxcal::solve_cable(ring, y, o), "CableSolveOptions::misfit_ratio: inf");
  o = {};
  o.noise_sigma_dof = -2.0;
  EXPECT_ERROR_SAYS(fluxcal::solve_cable(ring, y, o), "CableSolveOptions::noise_sigma_dof: -2");
  o = {};
  o.misfit_alpha = 1.0;
  EXPECT_ERROR_SAYS(fluxcal::solve_cable(ring, y, o), "CableSolveOptions::misfit_alpha: 1");
  o = {};
  o.max_current_relative_sigma = std::nan("");
  EXPECT_ERROR_SAYS(fluxcal::solve_cable(ring, y, o), "CableSolveOptions::max_current_relative_sigma: nan");
  o = {};
  o.refiner = static_cast<fluxcal::CableSolveOptions::Refiner>(7);
  EXPECT_ERROR_SAYS(fluxcal::solve_cable(ring, y, o), "CableSolveOptions::refiner: 7");
  o = {};
  o.grid_points = -3;
  EXPECT_ERROR_SAYS(fluxcal::solve_cable(ring, y, o), "CableSolveOptions::grid_points: -3, need ≥ 2");
  // A wrong width names the argument, not "readings".
  EXPECT_ERROR_SAYS(fluxcal::cable_field(ring, Eigen::MatrixXd::Zero(2, 3), Eigen::VectorXd::Ones(2)),
                    "positions: a matrix of 2 rows × 3 columns, need 2 columns");
  // Valid values still solve.
  o = {};
  o.noise_sigma = 0.0;  // ≤ 0: estimate it
  EXPECT_NO_THROW(fluxcal::solve_cable(ring, y, o));
}

// Readings whose squares overflow: "no usable starting point on the grid" before.
TEST(Cable, HugeReadingsAreNamed) {
  const CableRing ring = paper_ring();
  ConductorPositions p(2, 2);
  p << 0.001, 0.0, -0.001, 0.0;
  const Eigen::MatrixXd y = snapshot(ring, p, Eigen::Vector2d(1.0, -1.0)) * 1e304;
  EXPECT_ERROR_SAYS(fluxcal::solve_cable(ring, y), "readings: values up to");
}
