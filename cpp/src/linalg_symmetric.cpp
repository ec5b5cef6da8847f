// SelfAdjointEigenSolver, once per matrix type (linalg.hpp).
#include "linalg.hpp"

#include <Eigen/Eigenvalues>

namespace fluxcal::detail {
namespace {

template <typename Matrix>
SymmetricEigen<Matrix::RowsAtCompileTime> eigen_of(const Matrix& m) {
  const Eigen::SelfAdjointEigenSolver<Matrix> eig(m);
  return {eig.eigenvalues(), eig.eigenvectors()};
}

}  // namespace

SymmetricEigen<Eigen::Dynamic> symmetric_eigen(const Eigen::MatrixXd& m) { return eigen_of(m); }
SymmetricEigen<4> symmetric_eigen(const Eigen::Matrix4d& m) { return eigen_of(m); }
SymmetricEigen<9> symmetric_eigen(const Eigen::Matrix<double, 9, 9>& m) { return eigen_of(m); }
SymmetricEigen<10> symmetric_eigen(const Eigen::Matrix<double, 10, 10>& m) { return eigen_of(m); }

Eigen::Vector2d symmetric_eigenvalues(const Eigen::Matrix2d& m) {
  return Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d>(m, Eigen::EigenvaluesOnly).eigenvalues();
}

Eigen::Matrix<double, 10, 1> symmetric_eigenvalues(const Eigen::Matrix<double, 10, 10>& m) {
  return Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 10, 10>>(m, Eigen::EigenvaluesOnly).eigenvalues();
}

Eigen::Matrix2d symmetric_sqrt(const Eigen::Matrix2d& m) {
  return Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d>(m).operatorSqrt();
}

}  // namespace fluxcal::detail
