// Internal (not installed): Eigen's heavy decompositions behind plain functions, each instantiated once in
// linalg*.cpp, to save compile time. Each has the class, matrix type and options of the call sites it replaced,
// so the results are the same bits. Cheap fixed-size ones (3×3 eigen, 2×2 LDLT, closed-form inverses) stay inline.
#pragma once

#include <Eigen/Core>

#include <memory>
#include <optional>

namespace fluxcal::detail {

/// Eigenvalues (ascending) and eigenvectors (columns) of a symmetric matrix: SelfAdjointEigenSolver<M>(m), which
/// reads the lower triangle only.
template <int N>
struct SymmetricEigen {
  Eigen::Matrix<double, N, 1> values;
  Eigen::Matrix<double, N, N> vectors;
};
SymmetricEigen<Eigen::Dynamic> symmetric_eigen(const Eigen::MatrixXd& m);
SymmetricEigen<4> symmetric_eigen(const Eigen::Matrix4d& m);
SymmetricEigen<9> symmetric_eigen(const Eigen::Matrix<double, 9, 9>& m);
SymmetricEigen<10> symmetric_eigen(const Eigen::Matrix<double, 10, 10>& m);

/// The eigenvalues alone (ascending): SelfAdjointEigenSolver<M>(m, EigenvaluesOnly).eigenvalues().
Eigen::Vector2d symmetric_eigenvalues(const Eigen::Matrix2d& m);
Eigen::Matrix<double, 10, 1> symmetric_eigenvalues(const Eigen::Matrix<double, 10, 10>& m);

/// The symmetric square root of a positive semi-definite matrix: SelfAdjointEigenSolver<Matrix2d>(m).operatorSqrt().
Eigen::Matrix2d symmetric_sqrt(const Eigen::Matrix2d& m);

/// The (complex) eigenvalues of a general square matrix: m.eigenvalues(), i.e. EigenSolver<MatrixXd>.
Eigen::VectorXcd general_eigenvalues(const Eigen::MatrixXd& m);

/// The real parts of the eigenvectors of a general 3×3 matrix, EigenSolver<Matrix3d>(m).eigenvectors().real(); none
/// when the solver does not converge.
std::optional<Eigen::Matrix3d> general_eigenvectors_real(const Eigen::Matrix3d& m);

/// The least-squares solution of least norm, a.completeOrthogonalDecomposition().solve(b).
Eigen::VectorXd least_squares_min_norm(const Eigen::MatrixXd& a, const Eigen::VectorXd& b);

/// The least-squares solution by a column-pivoting QR, a.colPivHouseholderQr().solve(b); `rank`, when given, gets
/// the QR's rank().
Eigen::VectorXd least_squares_qr(const Eigen::MatrixXd& a, const Eigen::VectorXd& b, Eigen::Index* rank = nullptr);
/// The same for each column of b.
Eigen::MatrixXd least_squares_qr_columns(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b);

/// Unpivoted Householder QR (HouseholderQR<MatrixXd>) of a: R, the upper triangle of its first min(rows, cols) rows.
Eigen::MatrixXd householder_r(const Eigen::MatrixXd& a);
/// The same with the least-squares solution of a x = b (HouseholderQR's solve).
struct HouseholderLeastSquares {
  Eigen::MatrixXd r;
  Eigen::VectorXd solution;
};
HouseholderLeastSquares householder_least_squares(const Eigen::MatrixXd& a, const Eigen::VectorXd& b);
/// The same QR's thin Q (householderQ() × the rows × cols identity) and R's diagonal.
struct HouseholderThinQ {
  Eigen::MatrixXd q;
  Eigen::VectorXd r_diagonal;
};
HouseholderThinQ householder_thin_q(const Eigen::MatrixXd& a);

/// Singular values (descending) of a, JacobiSVD<MatrixXd>(a).singularValues().
Eigen::VectorXd singular_values(const Eigen::MatrixXd& a);
/// All right singular vectors (columns, by descending singular value), JacobiSVD<MatrixXd>(a, ComputeFullV).matrixV().
Eigen::MatrixXd right_singular_vectors(const Eigen::MatrixXd& a);
/// The least-squares solution of a x = b by JacobiSVD<MatrixXd>(a, ComputeThinU | ComputeThinV).solve(b), with the
/// singular values and the thin V it came from.
struct SvdLeastSquares {
  Eigen::VectorXd singular_values;
  Eigen::MatrixXd v;
  Eigen::MatrixXd solution;
};
SvdLeastSquares svd_least_squares(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b);

/// m x = b for symmetric m by an LDLT (m.ldlt().solve(b)); `ok`, when given, gets whether the factorisation
/// succeeded (info() == Success).
Eigen::VectorXd ldlt_solve(const Eigen::MatrixXd& m, const Eigen::VectorXd& b, bool* ok = nullptr);
Eigen::Matrix<double, 4, 3> ldlt_solve(const Eigen::Matrix4d& m, const Eigen::Matrix<double, 4, 3>& b);
/// m⁻¹ by LDLT<Matrix4d> (solve(Identity)), or none unless the factorisation succeeded and found m positive
/// semi-definite (info() == Success and isPositive()).
std::optional<Eigen::Matrix4d> ldlt_inverse_if_positive(const Eigen::Matrix4d& m);

/// LDLT<MatrixXd> of a symmetric matrix, kept for several solves m x = b.
class Ldlt {
 public:
  Ldlt();
  ~Ldlt();
  Ldlt(Ldlt&&) noexcept;
  Ldlt& operator=(Ldlt&&) noexcept;
  void compute(const Eigen::MatrixXd& m);
  Eigen::VectorXd solve(const Eigen::VectorXd& b) const;
  /// m⁻¹ bᵀ, ldlt.solve(b.transpose()): row-major, the type Eigen evaluates that solve into (its triangular
  /// solves run on the rows, so a column-major result would round differently).
  Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> solve_transposed(const Eigen::MatrixXd& b) const;

 private:
  std::unique_ptr<Eigen::LDLT<Eigen::MatrixXd>> ldlt_;
};

/// Whether the Cholesky factorisation of m succeeds, m.llt().info() == Success (m numerically positive definite).
bool cholesky_succeeds(const Eigen::MatrixXd& m);

/// FullPivLU<Matrix3d> of m: m⁻¹ (its inverse()), or m⁻¹ b (its solve(b)); none when m is not invertible (its
/// isInvertible(), at Eigen's default threshold).
std::optional<Eigen::Matrix3d> full_piv_inverse(const Eigen::Matrix3d& m);
std::optional<Eigen::Vector3d> full_piv_solve(const Eigen::Matrix3d& m, const Eigen::Vector3d& b);

/// m⁻¹ by Eigen's PartialPivLU, as m.inverse() of a MatrixXd.
Eigen::MatrixXd lu_inverse(const Eigen::MatrixXd& m);

/// PartialPivLU<MatrixXd> of a square matrix, kept for several solves m x = b.
class PartialPivLu {
 public:
  explicit PartialPivLu(const Eigen::MatrixXd& m);
  ~PartialPivLu();
  PartialPivLu(PartialPivLu&&) noexcept;
  PartialPivLu& operator=(PartialPivLu&&) noexcept;
  Eigen::VectorXd solve(const Eigen::VectorXd& b) const;
  Eigen::MatrixXd solve_columns(const Eigen::MatrixXd& b) const;  ///< m x = b for each column of b

 private:
  std::unique_ptr<Eigen::PartialPivLU<Eigen::MatrixXd>> lu_;
};

/// The rotation matrix taking the direction of a to that of b by the smallest angle,
/// Quaterniond::FromTwoVectors(a, b).toRotationMatrix() (which instantiates a JacobiSVD for the antiparallel case).
Eigen::Matrix3d rotation_between(const Eigen::Vector3d& a, const Eigen::Vector3d& b);

}  // namespace fluxcal::detail
