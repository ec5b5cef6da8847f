// JacobiSVD, and the one rotation that instantiates it (linalg.hpp).
#include "linalg.hpp"

#include <Eigen/Geometry>
#include <Eigen/SVD>

namespace fluxcal::detail {

Eigen::VectorXd singular_values(const Eigen::MatrixXd& a) { return Eigen::JacobiSVD<Eigen::MatrixXd>(a).singularValues(); }

Eigen::MatrixXd right_singular_vectors(const Eigen::MatrixXd& a) {
  return Eigen::JacobiSVD<Eigen::MatrixXd>(a, Eigen::ComputeFullV).matrixV();
}

SvdLeastSquares svd_least_squares(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(a, Eigen::ComputeThinU | Eigen::ComputeThinV);
  return {svd.singularValues(), svd.matrixV(), svd.solve(b)};
}

Eigen::Matrix3d rotation_between(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return Eigen::Quaterniond::FromTwoVectors(a, b).toRotationMatrix();
}

}  // namespace fluxcal::detail
