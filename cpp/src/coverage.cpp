#include "fluxcal/coverage.hpp"

#include <algorithm>
#include <bitset>
#include <string>

namespace fluxcal {

namespace {

template <class Field>
double coverage_of(Eigen::Index rows, Eigen::Index max_rows, Field&& field) {
  const Eigen::Index step = max_rows > 0 ? std::max<Eigen::Index>(1, rows / max_rows) : 1;
  std::bitset<kDirectionBins> seen;
  for (Eigen::Index i = 0; i < rows; i += step) {
    const int bin = direction_bin(field(i));
    if (bin >= 0) seen.set(static_cast<std::size_t>(bin));
  }
  return static_cast<double>(seen.count()) / kDirectionBins;
}

// What both direction_coverage overloads refuse: a NaN row would be skipped and the other rows' fraction passed for
// the whole set's; no rows, or a negative max_rows (0 looks at every row).
void check_coverage_input(const SamplesRef& rows, const char* name, Eigen::Index max_rows) {
  rows.require_width(name);
  if (rows.rows() == 0) throw Error(std::string(name) + ": no rows, nothing to cover");
  if (max_rows < 0)
    throw Error("max_rows: " + std::to_string(max_rows) + ", need a whole number ≥ 0 (0 looks at every row)");
  check_finite(rows, name);
}

}  // namespace

double direction_coverage(const SamplesRef& fields, Eigen::Index max_rows) {
  check_coverage_input(fields, "fields", max_rows);
  return coverage_of(fields.rows(), max_rows, [&](Eigen::Index i) { return Eigen::Vector3d(fields.row(i)); });
}

double direction_coverage(const SamplesRef& readings, const Calibration& cal, Eigen::Index max_rows) {
  check_coverage_input(readings, "readings", max_rows);
  if (!cal.offset.allFinite() || !cal.matrix.allFinite())
    throw Error("calibration: offset or matrix is not finite, no corrected field to bin");
  return coverage_of(readings.rows(), max_rows,
                     [&](Eigen::Index i) { return cal.apply(readings.row(i).transpose()); });
}

void describe_coverage(Summary& summary, const SamplesRef& readings, const Calibration& cal, Eigen::Index max_rows) {
  readings.require_width("readings");
  const Eigen::Index step = max_rows > 0 ? std::max<Eigen::Index>(1, readings.rows() / max_rows) : 1;
  std::bitset<kDirectionBins> seen;
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  Eigen::Index used = 0;
  for (Eigen::Index i = 0; i < readings.rows(); i += step) {
    const Eigen::Vector3d h = cal.apply(readings.row(i).transpose());
    const int bin = direction_bin(h);
    if (bin < 0) continue;
    seen.set(static_cast<std::size_t>(bin));
    const Eigen::Vector3d u = h.normalized();
    scatter += u * u.transpose();
    ++used;
  }
  summary.direction_coverage = static_cast<double>(seen.count()) / kDirectionBins;
  summary.direction_eigenvalues =
      used > 0 ? Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(scatter / static_cast<double>(used)).eigenvalues()
               : Eigen::Vector3d::Zero();
}

}  // namespace fluxcal
