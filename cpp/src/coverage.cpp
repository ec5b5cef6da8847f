#include "fluxcal/coverage.hpp"

#include <algorithm>
#include <bitset>

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

}  // namespace

double direction_coverage(const SamplesRef& fields, Eigen::Index max_rows) {
  fields.require_width("fields");
  return coverage_of(fields.rows(), max_rows, [&](Eigen::Index i) { return Eigen::Vector3d(fields.row(i)); });
}

double direction_coverage(const SamplesRef& readings, const Calibration& cal, Eigen::Index max_rows) {
  readings.require_width("readings");
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
