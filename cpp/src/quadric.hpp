// Internal (not installed): the centre and shape of a fitted quadric uᵀMu + 2vᵀu + k = 0 that must
// be a real ellipsoid — shared by the ellipsoid fit and the TWOSTEP first step.
#pragma once

#include "fluxcal/types.hpp"
#include "checks.hpp"

#include <Eigen/Eigenvalues>

#include <iomanip>
#include <sstream>
#include <string>

namespace fluxcal::detail {

struct EllipsoidShape {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;  ///< of M
  Eigen::Vector3d centre;                              ///< c = −M⁻¹v
  double rho2;                                         ///< (u − c)ᵀ M (u − c) = ρ²
};

/// Throws Error when M is not positive definite or the ellipsoid has no real points. `which` names
/// the fit in the messages ("fitted", "first step's"). `coverage_ratio` (the readings' thinnest/widest
/// spread) below `thin` (the poor-coverage threshold) names the coverage as the cause.
// Below this many readings a quadric that is not an ellipsoid says more about their number than about them.
inline constexpr long kFewReadings = 30;

inline EllipsoidShape ellipsoid_shape(const Eigen::Matrix3d& M, const Eigen::Vector3d& v, double k,
                                      const std::string& which, double coverage_ratio = 1.0, double thin = 0.0,
                                      long samples = 0) {
  EllipsoidShape s{Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(M), Eigen::Vector3d::Zero(), 0.0};
  if (!(s.eig.eigenvalues()(0) > 0.0) && coverage_ratio < thin) {
    // Readings close to a plane (a sensor turned flat, with a little wobble) leave the thin direction's
    // curvature to the noise: the quadric comes out a hyperboloid, not because recordings were mixed.
    std::ostringstream msg;
    msg.precision(3);
    msg << "samples: the readings lie nearly in one plane (thinnest/widest spread " << 100.0 * coverage_ratio
        << " %) and the " << which << " quadric is not an ellipsoid (eigenvalues " << std::setprecision(6)
        << s.eig.eigenvalues().transpose()
        << "); " << kTurnAdvice << ", give reference vectors, or " << kTwoDAdvice;
    throw Error(msg.str());
  }
  if (!(s.eig.eigenvalues()(0) > 0.0)) {
    std::ostringstream msg;
    msg << "samples: the readings do not lie on an ellipsoid (the " << which << " quadric has eigenvalues "
        << s.eig.eigenvalues().transpose()
        << "); "
        << (samples > 0 && samples < kFewReadings
                ? "only " + std::to_string(samples) + " readings: with so few, the noise decides the quadric's shape "
                  "— record a few hundred while turning the sensor"
                : std::string("check for mixed recordings, saturation or a field that changes during the recording"));
    throw Error(msg.str());
  }
  s.centre = -s.eig.eigenvectors() * (s.eig.eigenvectors().transpose() * v).cwiseQuotient(s.eig.eigenvalues());
  s.rho2 = s.centre.dot(M * s.centre) - k;
  if (!(s.rho2 > 0.0))
    throw Error("samples: the " + which + " ellipsoid is imaginary (no real points); the readings are degenerate");
  return s;
}

}  // namespace fluxcal::detail
