#include <fluxcal/coverage.hpp>

#include <gtest/gtest.h>

#include "errors.hpp"

#include <cmath>
#include <random>
#include <set>

TEST(Coverage, EveryBinIsReachedAndBinsAreInRange) {
  std::mt19937 rng(1);
  std::normal_distribution<double> g;
  std::set<int> bins;
  for (int i = 0; i < 20000; ++i) {
    const int b = fluxcal::direction_bin(Eigen::Vector3d(g(rng), g(rng), g(rng)));
    ASSERT_GE(b, 0);
    ASSERT_LT(b, fluxcal::kDirectionBins);
    bins.insert(b);
  }
  EXPECT_EQ(static_cast<int>(bins.size()), fluxcal::kDirectionBins);
}

TEST(Coverage, AxesLandOnTheirFacesAndDegenerateVectorsHaveNoBin) {
  EXPECT_EQ(fluxcal::direction_bin({1, 0, 0}) / 16, 0);
  EXPECT_EQ(fluxcal::direction_bin({-1, 0, 0}) / 16, 1);
  EXPECT_EQ(fluxcal::direction_bin({0, 0, -2}) / 16, 5);
  EXPECT_EQ(fluxcal::direction_bin({0, 0, 0}), -1);
  EXPECT_EQ(fluxcal::direction_bin({NAN, 0, 0}), -1);
  EXPECT_EQ(fluxcal::direction_bin({NAN, 1, 1}), -1);  // not the largest component: it had picked a face
  EXPECT_EQ(fluxcal::direction_bin({1, INFINITY, 0}), -1);
}

TEST(Coverage, AHorizontalTurnSeesFewDirections) {
  fluxcal::Samples ring(360, 3);
  for (int i = 0; i < 360; ++i) ring.row(i) << std::cos(i * M_PI / 180), std::sin(i * M_PI / 180), 0.0;
  const double c = fluxcal::direction_coverage(ring);
  EXPECT_GT(c, 0.05);
  EXPECT_LT(c, 0.2);
}

TEST(Coverage, WrongWidthNamesTheArgument) {
  EXPECT_ERROR_SAYS(fluxcal::direction_coverage(Eigen::MatrixXd::Ones(10, 2)),
                    "fields: a matrix of 10 rows × 2 columns, need 3 columns");
  EXPECT_ERROR_SAYS(fluxcal::direction_coverage(Eigen::MatrixXd::Ones(10, 4), fluxcal::Calibration()),
                    "readings: a matrix of 10 rows × 4 columns");
}

TEST(Coverage, NoRowsNaNRowsNegativeMaxRowsAndANaNCalibrationAreNamed) {
  // They had given 0.0, the other rows' fraction (a NaN row skipped), or looked at every row, without a word.
  Eigen::MatrixXd v = Eigen::MatrixXd::Random(50, 3);
  EXPECT_ERROR_SAYS(fluxcal::direction_coverage(Eigen::MatrixXd(0, 3)), "fields: no rows");
  EXPECT_ERROR_SAYS(fluxcal::direction_coverage(v, -1), "max_rows: -1, need a whole number ≥ 0");
  v(7, 2) = std::nan("");
  EXPECT_ERROR_SAYS(fluxcal::direction_coverage(v), "fields: row 7, column 2 (z) is NaN");
  EXPECT_ERROR_SAYS(fluxcal::direction_coverage(v, fluxcal::Calibration()), "readings: row 7");
  fluxcal::Calibration bad;
  bad.matrix(0, 0) = std::nan("");
  EXPECT_ERROR_SAYS(fluxcal::direction_coverage(Eigen::MatrixXd::Random(50, 3), bad), "calibration: offset or matrix is not finite");
}
