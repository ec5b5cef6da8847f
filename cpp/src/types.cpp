#include "fluxcal/types.hpp"
#include "fluxcal/version.hpp"
#include "linalg.hpp"

#include <cmath>
#include <sstream>

namespace fluxcal {

const char* version() { return FLUXCAL_VERSION_STRING; }

Samples Calibration::apply_rows(const SamplesRef& readings) const {
  // Row form of h = A (m − b): H = (M − 1 bᵀ) Aᵀ.
  readings.require_width("readings");
  return (readings.rowwise() - offset.transpose()) * matrix.transpose();
}

Eigen::Vector3d Calibration::reading(const Eigen::Vector3d& field) const {
  const std::optional<Eigen::Vector3d> unshifted = detail::full_piv_solve(matrix, field);
  if (!unshifted) throw Error("calibration: matrix A is singular, the forward model m = A⁻¹h + b does not exist");
  return *unshifted + offset;
}

void check_finite(const SamplesRef& samples, const std::string& name) {
  samples.require_width(name);
  static const char* axis[] = {"x", "y", "z"};
  for (Eigen::Index i = 0; i < samples.rows(); ++i) {
    for (int j = 0; j < 3; ++j) {
      const double v = samples(i, j);
      if (!std::isfinite(v)) {
        std::ostringstream msg;
        msg << name << ": row " << i << ", column " << j << " (" << axis[j] << ") is "
            << (std::isnan(v) ? "NaN" : "infinite") << "; remove or repair non-finite readings first";
        throw Error(msg.str());
      }
    }
  }
}

void check_samples(const SamplesRef& samples, const std::string& name, Eigen::Index min_rows,
                   const std::string& purpose) {
  samples.require_width(name);
  if (samples.rows() < min_rows) {
    std::ostringstream msg;
    msg << name << ": " << samples.rows() << " rows, need at least " << min_rows << " for " << purpose;
    throw Error(msg.str());
  }
  check_finite(samples, name);
}

}  // namespace fluxcal
