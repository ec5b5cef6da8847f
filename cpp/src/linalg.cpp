// The LU and Cholesky factorisations of linalg.hpp; the others are split over linalg_*.cpp so they compile in
// parallel and each file stays cheap (GCC's cost per instantiation grows with what the file already holds).
#include "linalg.hpp"

#include <Eigen/Cholesky>
#include <Eigen/LU>

namespace fluxcal::detail {

Eigen::VectorXd ldlt_solve(const Eigen::MatrixXd& m, const Eigen::VectorXd& b, bool* ok) {
  const Eigen::LDLT<Eigen::MatrixXd> ldlt(m);
  if (ok) *ok = ldlt.info() == Eigen::Success;
  return ldlt.solve(b);
}

Eigen::Matrix<double, 4, 3> ldlt_solve(const Eigen::Matrix4d& m, const Eigen::Matrix<double, 4, 3>& b) {
  return m.ldlt().solve(b);
}

std::optional<Eigen::Matrix4d> ldlt_inverse_if_positive(const Eigen::Matrix4d& m) {
  const Eigen::LDLT<Eigen::Matrix4d> ldlt(m);
  if (ldlt.info() != Eigen::Success || !ldlt.isPositive()) return std::nullopt;
  return Eigen::Matrix4d(ldlt.solve(Eigen::Matrix4d::Identity()));
}

Ldlt::Ldlt() : ldlt_(std::make_unique<Eigen::LDLT<Eigen::MatrixXd>>()) {}
Ldlt::~Ldlt() = default;
Ldlt::Ldlt(Ldlt&&) noexcept = default;
Ldlt& Ldlt::operator=(Ldlt&&) noexcept = default;
void Ldlt::compute(const Eigen::MatrixXd& m) { ldlt_->compute(m); }
Eigen::VectorXd Ldlt::solve(const Eigen::VectorXd& b) const { return ldlt_->solve(b); }
Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> Ldlt::solve_transposed(const Eigen::MatrixXd& b) const {
  return ldlt_->solve(b.transpose());
}

bool cholesky_succeeds(const Eigen::MatrixXd& m) { return m.llt().info() == Eigen::Success; }

std::optional<Eigen::Matrix3d> full_piv_inverse(const Eigen::Matrix3d& m) {
  const Eigen::FullPivLU<Eigen::Matrix3d> lu(m);
  if (!lu.isInvertible()) return std::nullopt;
  return Eigen::Matrix3d(lu.inverse());
}

std::optional<Eigen::Vector3d> full_piv_solve(const Eigen::Matrix3d& m, const Eigen::Vector3d& b) {
  const Eigen::FullPivLU<Eigen::Matrix3d> lu(m);
  if (!lu.isInvertible()) return std::nullopt;
  return Eigen::Vector3d(lu.solve(b));
}

Eigen::MatrixXd lu_inverse(const Eigen::MatrixXd& m) { return m.inverse(); }

PartialPivLu::PartialPivLu(const Eigen::MatrixXd& m) : lu_(std::make_unique<Eigen::PartialPivLU<Eigen::MatrixXd>>(m)) {}
PartialPivLu::~PartialPivLu() = default;
PartialPivLu::PartialPivLu(PartialPivLu&&) noexcept = default;
PartialPivLu& PartialPivLu::operator=(PartialPivLu&&) noexcept = default;
Eigen::VectorXd PartialPivLu::solve(const Eigen::VectorXd& b) const { return lu_->solve(b); }
Eigen::MatrixXd PartialPivLu::solve_columns(const Eigen::MatrixXd& b) const { return lu_->solve(b); }

}  // namespace fluxcal::detail
