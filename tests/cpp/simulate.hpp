// Test support shared by the GoogleTest files: a random sensor and its readings on a sphere.
#pragma once

#include <fluxcal/types.hpp>

#include <random>

namespace fluxcal_test {

using fluxcal::Samples;

/// A sensor m = W h + b with symmetric soft iron within ±20 % and an offset up to 50 % of `field`.
struct Truth {
  Eigen::Matrix3d W;  // forward distortion, m = W h + b
  Eigen::Vector3d b;
  double field;
};

inline Truth make_truth(unsigned seed, double field) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  for (int i = 0; i < 3; ++i)
    for (int j = i; j < 3; ++j) R(i, j) = R(j, i) = (i == j ? 1.0 : 0.0) + 0.2 * u(rng);
  return {R, Eigen::Vector3d(u(rng), u(rng), u(rng)) * 0.5 * field, field};
}

inline Samples simulate(const Truth& t, int n, double noise, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0.0, 1.0);
  Samples s(n, 3);
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d dir = Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
    const Eigen::Vector3d e(g(rng), g(rng), g(rng));
    s.row(i) = (t.W * dir * t.field + t.b + noise * t.field * e).transpose();
  }
  return s;
}

}  // namespace fluxcal_test
