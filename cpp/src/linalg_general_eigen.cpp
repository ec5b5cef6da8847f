// EigenSolver: eigenproblems of general (non-symmetric) matrices (linalg.hpp).
#include "linalg.hpp"

#include <Eigen/Eigenvalues>

namespace fluxcal::detail {

Eigen::VectorXcd general_eigenvalues(const Eigen::MatrixXd& m) { return m.eigenvalues(); }

std::optional<Eigen::Matrix3d> general_eigenvectors_real(const Eigen::Matrix3d& m) {
  const Eigen::EigenSolver<Eigen::Matrix3d> eig(m);
  if (eig.info() != Eigen::Success) return std::nullopt;
  return Eigen::Matrix3d(eig.eigenvectors().real());
}

}  // namespace fluxcal::detail
