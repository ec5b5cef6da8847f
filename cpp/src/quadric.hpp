// Internal (not installed): the centre and shape of a fitted quadric uᵀMu + 2vᵀu + k = 0 that must
// be a real ellipsoid — shared by the ellipsoid fit and the TWOSTEP first step.
#pragma once

#include "fluxcal/types.hpp"

#include <Eigen/Eigenvalues>

#include <sstream>
#include <string>

namespace fluxcal::detail {

struct EllipsoidShape {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;  ///< of M
  Eigen::Vector3d centre;                              ///< c = −M⁻¹v
  double rho2;                                         ///< (u − c)ᵀ M (u − c) = ρ²
};

/// Throws Error when M is not positive definite or the ellipsoid has no real points. `which` names
/// the fit in the messages ("fitted", "first step's").
inline EllipsoidShape ellipsoid_shape(const Eigen::Matrix3d& M, const Eigen::Vector3d& v, double k,
                                      const std::string& which) {
  EllipsoidShape s{Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(M), Eigen::Vector3d::Zero(), 0.0};
  if (!(s.eig.eigenvalues()(0) > 0.0)) {
    std::ostringstream msg;
    msg << "samples: the readings do not lie on an ellipsoid (the " << which << " quadric has eigenvalues "
        << s.eig.eigenvalues().transpose()
        << "); check for mixed recordings, saturation or a field that changes during the recording";
    throw Error(msg.str());
  }
  s.centre = -s.eig.eigenvectors() * (s.eig.eigenvectors().transpose() * v).cwiseQuotient(s.eig.eigenvalues());
  s.rho2 = s.centre.dot(M * s.centre) - k;
  if (!(s.rho2 > 0.0))
    throw Error("samples: the " + which + " ellipsoid is imaginary (no real points); the readings are degenerate");
  return s;
}

}  // namespace fluxcal::detail
