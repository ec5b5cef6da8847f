// Householder QR factorisations: plain, column-pivoting, complete orthogonal (linalg.hpp).
#include "linalg.hpp"

#include <Eigen/QR>

#include <algorithm>

namespace fluxcal::detail {

Eigen::VectorXd least_squares_min_norm(const Eigen::MatrixXd& a, const Eigen::VectorXd& b) {
  return a.completeOrthogonalDecomposition().solve(b);
}

Eigen::VectorXd least_squares_qr(const Eigen::MatrixXd& a, const Eigen::VectorXd& b, Eigen::Index* rank) {
  const Eigen::ColPivHouseholderQR<Eigen::MatrixXd> qr(a);
  if (rank) *rank = qr.rank();
  return qr.solve(b);
}

Eigen::MatrixXd least_squares_qr_columns(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
  return a.colPivHouseholderQr().solve(b);
}

namespace {

Eigen::MatrixXd r_of(const Eigen::HouseholderQR<Eigen::MatrixXd>& qr) {
  const Eigen::Index keep = std::min(qr.matrixQR().rows(), qr.matrixQR().cols());
  return qr.matrixQR().topRows(keep).triangularView<Eigen::Upper>();
}

}  // namespace

Eigen::MatrixXd householder_r(const Eigen::MatrixXd& a) { return r_of(Eigen::HouseholderQR<Eigen::MatrixXd>(a)); }

HouseholderLeastSquares householder_least_squares(const Eigen::MatrixXd& a, const Eigen::VectorXd& b) {
  const Eigen::HouseholderQR<Eigen::MatrixXd> qr(a);
  return {r_of(qr), qr.solve(b)};
}

HouseholderThinQ householder_thin_q(const Eigen::MatrixXd& a) {
  const Eigen::HouseholderQR<Eigen::MatrixXd> qr(a);
  return {qr.householderQ() * Eigen::MatrixXd::Identity(a.rows(), a.cols()), qr.matrixQR().diagonal()};
}

}  // namespace fluxcal::detail
