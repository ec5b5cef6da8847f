// Internal (not installed): the option checks the Ceres solvers share. NaN compares false, so a plain
// `v > 0` lets a NaN tolerance through to Ceres, which then fails with a message naming none of the
// caller's inputs; these name the option and its value.
#pragma once

#include "fluxcal/types.hpp"

#include <cmath>
#include <cstdio>
#include <string>

namespace fluxcal::detail {

/// A number for a message: six significant digits ("nan", "inf" as such).
inline std::string num(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.6g", v);
  return buf;
}

/// Throws Error("NAME: VALUE, need NEED") unless `ok`.
inline void require(bool ok, const std::string& name, double value, const std::string& need) {
  if (!ok) throw Error(name + ": " + num(value) + ", need " + need);
}

inline void require_positive(const std::string& name, double value,
                             const std::string& need = "a finite value > 0") {
  require(std::isfinite(value) && value > 0.0, name, value, need);
}

inline void require_nonnegative(const std::string& name, double value,
                                const std::string& need = "a finite value ≥ 0") {
  require(std::isfinite(value) && value >= 0.0, name, value, need);
}

}  // namespace fluxcal::detail
