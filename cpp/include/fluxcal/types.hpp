// fluxcal/types.hpp — the value types every fluxcal solver shares.
//
//   Samples      N×3 readings, one row per reading (row-major, double).
//   Calibration  the correction h = A (m − b) of a three-axis sensor: offset b, matrix A, field norm.
//   Summary      what every solver reports about its run.
//   Error        what every solver throws on bad input; the message names the input and the problem.
#pragma once

#include <Eigen/Dense>

#include <stdexcept>
#include <string>
#include <vector>

namespace fluxcal {

/// Version of the linked library, "MAJOR.MINOR.PATCH" (the headers' is FLUXCAL_VERSION_STRING in
/// fluxcal/version.hpp).
const char* version();

/// Thrown on bad input (NaN, too few samples, degenerate coverage, ...). Never an abort.
class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

namespace detail {
/// What a RowsRef holds besides its view; a base listed first, so it exists before the view binds to it.
template <int Cols>
struct RowsRefStorage {
  Eigen::Index given_rows = 0, given_cols = Cols;  ///< shape of the matrix the view was made from
  /// The rows, when the matrix could not be viewed in place (column-major, an expression).
  Eigen::Matrix<double, Eigen::Dynamic, Cols, Eigen::RowMajor> evaluated;
};
}  // namespace detail

/// Read-only view of an N×Cols block, one row a reading. A plain Eigen::Ref would copy a matrix with
/// another number of columns (a MatrixXd of the wrong width) unchecked: heap corruption in Release, an
/// assertion in Debug. This view binds such a matrix as empty and remembers its shape; every function
/// taking it calls require_width(name) first, so the Error names the argument ("reference: …").
template <int Cols>
class RowsRef : private detail::RowsRefStorage<Cols>,
                public Eigen::Ref<const Eigen::Matrix<double, Eigen::Dynamic, Cols, Eigen::RowMajor>> {
  using Storage = detail::RowsRefStorage<Cols>;

 public:
  using Matrix = Eigen::Matrix<double, Eigen::Dynamic, Cols, Eigen::RowMajor>;
  using Base = Eigen::Ref<const Matrix>;
  RowsRef(const Base& view) : Storage{view.rows(), Cols, {}}, Base(view) {}  // NOLINT: implicit, as Eigen::Ref is
  template <typename Derived>
  RowsRef(const Eigen::DenseBase<Derived>& m)  // NOLINT
      : Storage{m.rows(), m.cols(), {}}, Base(bind(m.derived(), *this)) {}
  // A copy views its own copy of evaluated rows (Eigen::Ref's copy would point into the original's).
  RowsRef(const RowsRef& other) : Storage(other), Base(rebind(other, *this)) {}
  RowsRef& operator=(const RowsRef&) = delete;

  /// False when the matrix this view was made from was not Cols wide (the view is then empty).
  bool width_ok() const { return Storage::given_cols == Cols; }
  /// Throws Error("NAME: a matrix of R rows × C columns, need Cols columns …") unless width_ok().
  void require_width(const std::string& name) const {
    if (!width_ok())
      throw Error(name + ": a matrix of " + std::to_string(Storage::given_rows) + " rows × " +
                  std::to_string(Storage::given_cols) + " columns, need " + std::to_string(Cols) +
                  " columns (one row a reading)");
  }

 private:
  using Rows = Eigen::Map<const Matrix, 0, Eigen::OuterStride<>>;
  // Static, given the storage base (already constructed): the view base is still being initialised.
  template <typename Derived>
  static Rows bind(const Derived& m, Storage& storage) {
    if (m.cols() != Cols) return Rows(nullptr, 0, Cols, Eigen::OuterStride<>(Cols));
    // A matrix whose width is fixed at compile time to another value never gets here, but the copy below
    // would still be instantiated and fail with Eigen's YOU_MIXED_MATRICES_OF_DIFFERENT_SIZES: keep it out
    // of the instantiation, so such a matrix reaches require_width() and its Error like a MatrixXd does.
    if constexpr (Derived::ColsAtCompileTime == Eigen::Dynamic || Derived::ColsAtCompileTime == Cols) {
      if constexpr (bool(Derived::Flags & Eigen::DirectAccessBit)) {
        if (m.colStride() == 1) return Rows(m.data(), m.rows(), Cols, Eigen::OuterStride<>(m.rowStride()));
      }
      storage.evaluated = m;  // what Eigen::Ref would have copied into itself
      return Rows(storage.evaluated.data(), m.rows(), Cols, Eigen::OuterStride<>(Cols));
    } else {
      return Rows(nullptr, 0, Cols, Eigen::OuterStride<>(Cols));
    }
  }
  static Rows rebind(const RowsRef& other, Storage& storage) {
    const Storage& theirs = other;
    if (theirs.evaluated.size() > 0 && other.data() == theirs.evaluated.data())
      return Rows(storage.evaluated.data(), storage.evaluated.rows(), Cols, Eigen::OuterStride<>(Cols));
    return Rows(other.data(), other.rows(), Cols, Eigen::OuterStride<>(other.outerStride()));
  }
};

namespace detail {
/// A SeriesRef's values when they could not be viewed in place (strided, an expression); a base listed first.
struct SeriesRefStorage {
  Eigen::VectorXd evaluated;
};
}  // namespace detail

/// Read-only view of a series (N values: an Eigen vector, a row or column of a matrix, a mapped NumPy array).
/// A plain Eigen::Ref<const VectorXd> made from an N×2 matrix reads its first column in Release and asserts
/// (aborts) in Debug; this view throws Error naming the shape instead, when it is made — before the function
/// it is passed to runs, so the message cannot name the argument.
class SeriesRef : private detail::SeriesRefStorage, public Eigen::Ref<const Eigen::VectorXd> {
 public:
  using Base = Eigen::Ref<const Eigen::VectorXd>;
  SeriesRef(const Base& view) : Base(view) {}  // NOLINT: implicit, as Eigen::Ref is
  template <typename Derived>
  SeriesRef(const Eigen::DenseBase<Derived>& m) : Base(bind(m.derived(), *this)) {}  // NOLINT
  // A copy views its own copy of evaluated values (Eigen::Ref's copy would point into the original's).
  SeriesRef(const SeriesRef& other) : detail::SeriesRefStorage(other), Base(rebind(other, *this)) {}
  SeriesRef& operator=(const SeriesRef&) = delete;

 private:
  using Values = Eigen::Map<const Eigen::VectorXd>;
  template <typename Derived>
  static Values bind(const Derived& m, detail::SeriesRefStorage& storage) {
    if (m.rows() != 1 && m.cols() != 1)
      throw Error("a series (N values) was given a matrix of " + std::to_string(m.rows()) + " rows × " +
                  std::to_string(m.cols()) + " columns: pass one column (or one row)");
    if constexpr (Derived::ColsAtCompileTime == 1 && bool(Derived::Flags & Eigen::DirectAccessBit)) {
      if (m.innerStride() == 1) return Values(m.data(), m.rows());
    }
    storage.evaluated.resize(m.size());  // element by element: compiles for any shape, runs for vectors only
    for (Eigen::Index i = 0; i < m.size(); ++i) storage.evaluated(i) = m.cols() == 1 ? m(i, 0) : m(0, i);
    return Values(storage.evaluated.data(), storage.evaluated.size());
  }
  static Values rebind(const SeriesRef& other, detail::SeriesRefStorage& storage) {
    const detail::SeriesRefStorage& theirs = other;
    if (theirs.evaluated.size() > 0 && other.data() == theirs.evaluated.data())
      return Values(storage.evaluated.data(), storage.evaluated.size());
    return Values(other.data(), other.size());
  }
};

/// N×3 readings, one row a reading. Row-major so a C-contiguous NumPy array maps without a copy.
using Samples = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;
/// Read-only view of any N×3 block (an Eigen matrix, a mapped NumPy array, ...); another width throws.
using SamplesRef = RowsRef<3>;
/// The plain Eigen view underneath (what the Python bindings map a NumPy array to).
using SamplesView = SamplesRef::Base;

/// How the covariance treats correlation between readings (rows taken in time order).
enum class SerialCorrelation {
  automatic,    ///< Newey–West when the residuals fail the Ljung–Box test and it widens an error, or when
                ///< it widens one ≥ 1.5×; never to a sandwich that widens nothing
  independent,  ///< σ̂² (JᵀJ)⁻¹ whatever the residuals (rows not in time order, or for comparison)
  newey_west,   ///< always the Newey–West sandwich
};

/// What the residuals say about correlation between readings, and what the covariance did about it.
struct SerialCorrelationReport {
  double lag1 = 0.0;                 ///< lag-1 autocorrelation of the residuals (mean over axes for vectors)
  double ljung_box_p = 1.0;          ///< Ljung–Box p-value (smallest axis × 3 for vectors)
  int lags = 0;                      ///< Newey–West bandwidth; 0 = independent readings assumed
  double inflation = 1.0;            ///< largest ratio of the reported to the independent-readings standard error
  /// sqrt diag of the independent-readings covariance (σ̂² (JᵀJ)⁻¹; TWOSTEP's from 30 readings its HC2 sandwich)
  Eigen::VectorXd standard_errors_independent;
};

/// What a solver reports. Fields that do not apply to a solver keep their defaults.
struct Summary {
  std::size_t samples = 0;         ///< readings used by the fit
  int iterations = 0;              ///< solver iterations (0 for a closed-form solution)
  double cost = 0.0;               ///< final cost of the solver's own objective (per sample)
  double residual_rms = 0.0;       ///< RMS of |h| − field_norm after correction (data units of h)
  double norm_mean = 0.0;          ///< mean of |h| after correction
  double norm_std_over_mean = 0.0; ///< std/mean of |h| after correction (0.01 = 1 %)
  double condition_number = 0.0;   ///< of the solver's (normalised) linear system
  /// Thinnest/widest spread of the readings (0 planar, 1 sphere-like): the ellipsoid fit, TWOSTEP, the planar fit and
  /// refine (the reference vectors' with a vector model) set it; the other solvers leave the default 0.
  double coverage_ratio = 0.0;
  double direction_coverage = -1;  ///< fraction of direction bins seen after correction (−1: not computed)
  /// Eigenvalues (ascending) of the direction scatter mean(ĥĥᵀ) of the corrected fields: 1/3 each on a
  /// full sphere, one near 0 for a planar (yaw-only) turn, two near 0 for a single direction.
  Eigen::Vector3d direction_eigenvalues = Eigen::Vector3d::Zero();
  bool exact_statistics = false;   ///< residual statistics from a pass over the samples, not moments
  bool converged = false;          ///< the solver reached a valid solution
  std::string message;             ///< one human-readable line
  std::vector<std::string> warnings;  ///< conditions the caller should know about (poor coverage, ...)
};

/// Correction of a three-axis sensor that reads m = W h + b + noise: h = A (m − b), A = W⁻¹.
struct Calibration {
  Eigen::Vector3d offset = Eigen::Vector3d::Zero();      ///< b, in reading units
  Eigen::Matrix3d matrix = Eigen::Matrix3d::Identity();  ///< A, field units per reading unit
  double field_norm = 1.0;  ///< |h| the correction maps the readings to
  std::string units;        ///< units of the readings, as the recording states them ("" = not stated)
  std::string model;        ///< which solver produced it ("ellipsoid", ...)

  /// Corrected field of one reading.
  Eigen::Vector3d apply(const Eigen::Vector3d& reading) const { return matrix * (reading - offset); }
  /// Corrected field of every row.
  Samples apply_rows(const SamplesRef& readings) const;
  /// The reading a true field h would produce (the forward model, without noise).
  Eigen::Vector3d reading(const Eigen::Vector3d& field) const;
};

/// Throws Error unless `samples` has at least `min_rows` rows and only finite values.
/// `name` is the input's name in the message, `purpose` says why so many rows are needed.
void check_samples(const SamplesRef& samples, const std::string& name, Eigen::Index min_rows,
                   const std::string& purpose);

/// Throws Error naming the first non-finite value of `samples` (row and axis), if there is one.
void check_finite(const SamplesRef& samples, const std::string& name);

}  // namespace fluxcal
