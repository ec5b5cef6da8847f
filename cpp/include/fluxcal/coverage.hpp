// fluxcal/coverage.hpp — how well readings cover the sphere of field directions.
//
// A 3-D calibration from field magnitudes is only determined along directions the sensor has seen.
// Directions are binned on a cube sphere: 6 faces × 4 × 4 cells, equal angle per cell (96 bins whose
// solid angles differ by at most a factor 1.9), computed in O(1) per reading.
#pragma once

#include "fluxcal/types.hpp"

#include <cmath>
#include <limits>

namespace fluxcal {

constexpr int kDirectionBins = 96;

/// Bin of the direction (x, y, z) (0 … 95), or −1 for a zero or non-finite vector. Face 2a + (v_a < 0)
/// for the axis a of largest |v_a| (the first on ties); then 4 × 4 cells of equal angle over the
/// face.
inline int direction_bin(double x, double y, double z) {
  // Every component, not only the largest: a NaN compares false and would otherwise pick a face.
  if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) return -1;
  const double ax = std::abs(x), ay = std::abs(y), az = std::abs(z);
  const int a = (ax >= ay && ax >= az) ? 0 : (ay >= az ? 1 : 2);  // face axis, the first on ties
  const double v[3] = {x, y, z};
  const double big = v[a], u = v[(a + 1) % 3], w = v[(a + 2) % 3];
  const double mag = std::abs(big);
  if (!(mag > 0.0) || !(mag <= std::numeric_limits<double>::max())) return -1;
  // Equal-angle cells: atan(u/|big|) split at −π/8, 0, π/8, i.e. u/|big| at ±tan(π/8) = ±(√2 − 1).
  const double tm = 0.41421356237309503 * mag;
  const int cu = (u >= -tm) + (u >= 0.0) + (u >= tm);
  const int cw = (w >= -tm) + (w >= 0.0) + (w >= tm);
  return (2 * a + (big < 0.0)) * 16 + cu * 4 + cw;
}

inline int direction_bin(const Eigen::Vector3d& v) { return direction_bin(v(0), v(1), v(2)); }

/// Fraction of the 96 direction bins that hold at least one row of `fields` (corrected fields, not
/// raw readings: raw readings are off-centre). 1.0 = every direction seen; a yaw-only turn ≈ 0.1.
/// `max_rows` > 0 looks at an evenly strided subsample of at most that many rows (a bin holding
/// fewer than N/max_rows readings may then be missed — it carries almost no weight in a fit). Error for no rows,
/// a NaN or infinite row (named), or max_rows < 0.
double direction_coverage(const SamplesRef& fields, Eigen::Index max_rows = 0);

/// The same for the corrected fields A (m − b) of raw readings m, without forming them (Error also for a
/// calibration that is not finite).
double direction_coverage(const SamplesRef& readings, const Calibration& calibration, Eigen::Index max_rows = 0);

/// Sets summary.direction_coverage and summary.direction_eigenvalues for the corrected fields of
/// `readings`, from one strided pass over at most `max_rows` rows (0 = all).
void describe_coverage(Summary& summary, const SamplesRef& readings, const Calibration& calibration,
                       Eigen::Index max_rows);

}  // namespace fluxcal
