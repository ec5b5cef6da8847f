// Internal (not installed): the option checks the Ceres solvers share. NaN compares false, so a plain
// `v > 0` lets a NaN tolerance through to Ceres, which then fails with a message naming none of the
// caller's inputs; these name the option and its value.
#pragma once

#include "fluxcal/types.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>

namespace fluxcal {
struct ArOptions;
struct PreprocessOptions;
struct KalmanOptions;
struct DriftOptions;
}  // namespace fluxcal

namespace fluxcal::detail {

/// Option checks, one per options struct, defined next to the solver that takes it; each throws Error
/// "StructName::field: VALUE, need …". Declared here for the entry points that take them nested (fit_foct).
void check(const ArOptions& options);
void check(const PreprocessOptions& options);
void check(const KalmanOptions& options);
void check(const DriftOptions& options);

/// A number for a message: six significant digits ("nan", "inf" as such).
inline std::string num(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.6g", v);
  return buf;
}

/// A known field norm whose calibration scales the readings by `gain` beyond 5× either way usually means another
/// unit than the readings' (nT magnitudes beside µT readings): "WHAT is GAIN times the RADIUS_NAME R of the readings
/// — check the units", else "". The ellipsoid fit, TWOSTEP and the refinement with per-reading norms say it alike.
inline std::string units_mismatch(const std::string& what, double gain, double radius,
                                  const std::string& radius_name = "radius") {
  if (!(gain > 5.0 || gain < 0.2)) return "";
  return what + " is " + num(gain) + " times the " + radius_name + " " + num(radius) +
         " of the readings — check the units";
}

/// The true field magnitude of each of `rows` readings (twostep_2d, refine's per-reading norms): one positive
/// finite value per reading, or Error "field_norms: …".
inline void check_field_norms(const Eigen::Ref<const Eigen::VectorXd>& h, Eigen::Index rows) {
  if (h.size() != rows)
    throw Error("field_norms: " + std::to_string(h.size()) + " values for " + std::to_string(rows) +
                " readings; give the true field magnitude of every reading");
  for (Eigen::Index i = 0; i < h.size(); ++i)
    if (!(h(i) > 0.0) || !std::isfinite(h(i)))
      throw Error("field_norms: value " + std::to_string(i) + " is " + num(h(i)) +
                  "; every reading needs a positive finite true field magnitude (drop zero-field readings)");
}

/// What every "the readings do not determine a 3-D ellipsoid" error asks for. Two flat turns are not enough:
/// the quadrics through two conics in different planes form a family (the ellipsoid plus any multiple of the
/// product of the two planes), so the fit is rank deficient along it.
inline constexpr const char* kTurnAdvice =
    "turn the sensor about all three axes or tumble it (two flat turns leave an ellipsoid undetermined)";
/// The remedy for a sensor that only ever turns about one axis.
inline constexpr const char* kTwoDAdvice =
    "for a sensor that only turns about one axis (a vehicle's heading), the 2-D calibration of the two axes in its "
    "plane (fluxcal calibrate --planar; in Python fluxcal.calibrate_planar, with the horizontal field as the known "
    "norm)";

/// Residuals above this fraction of the field are no sensor's noise: the readings do not fit the model, and a
/// parameter left undetermined by them wants the model checked, not more turning.
inline constexpr double kMisfitFraction = 0.05;
/// Where a magnitude fit's misfit comes from, for its warnings.
inline constexpr const char* kMagnitudeMisfitCauses =
    "for outliers or a disturbance (a magnet, a motor or a current near the sensor while it turned: fluxcal diagnose "
    "looks for the cause)";

/// A ratio as a percentage for a message: three significant digits ("12.3 %").
inline std::string percent(double ratio) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3g %%", 100.0 * ratio);
  return buf;
}

/// The readings looked at for direction coverage (an even stride of at most max_rows; 0 = all).
inline double coverage_readings(Eigen::Index rows, Eigen::Index max_rows) {
  const Eigen::Index step = max_rows > 0 ? std::max<Eigen::Index>(1, rows / max_rows) : 1;
  return static_cast<double>((rows + step - 1) / step);
}

/// The fraction of the 96 direction bins that many readings spread evenly would fill, 1 − (1 − 1/96)^n.
inline double reachable_coverage(Eigen::Index rows, Eigen::Index max_rows) {
  return 1.0 - std::pow(1.0 - 1.0 / 96.0, coverage_readings(rows, max_rows));
}

/// The poor-coverage warning on field directions, or "" when coverage is fine. Judged against what the rows
/// looked at (`rows`, strided to at most `max_rows`) would fill if spread evenly over the sphere, 1 − (1 − 1/96)^n,
/// times `poor`: 30 readings of a full tumble fill about 27 % of the bins, and were told to turn more.
inline std::string direction_coverage_warning(double coverage, Eigen::Index rows, Eigen::Index max_rows, double poor) {
  const double n = coverage_readings(rows, max_rows), reachable = reachable_coverage(rows, max_rows);
  if (coverage >= poor * reachable) return "";
  std::string text = "poor coverage: only " + percent(coverage) + " of field directions seen";
  if (reachable < 0.9) text += " (" + num(n) + " readings spread evenly would fill about " + percent(reachable) + ")";
  return text + "; turn the sensor through more orientations";
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

/// Whole-number options: Throws Error("NAME: VALUE, need NEED") unless `ok`.
inline void require_int(bool ok, const std::string& name, long long value, const std::string& need) {
  if (!ok) throw Error(name + ": " + std::to_string(value) + ", need " + need);
}

/// A finite value (any sign; e.g. ≤ 0 meaning "estimate it").
inline void require_finite(const std::string& name, double value, const std::string& need = "a finite value") {
  require(std::isfinite(value), name, value, need);
}

/// A probability strictly between 0 and 1 (a significance level, a fraction).
inline void require_open_unit(const std::string& name, double value,
                              const std::string& need = "a value in (0, 1)") {
  require(value > 0.0 && value < 1.0, name, value, need);
}

/// A ratio of spreads or a fraction of bins: finite, within [0, 1].
inline void require_unit(const std::string& name, double value,
                         const std::string& need = "a value in [0, 1]") {
  require(value >= 0.0 && value <= 1.0, name, value, need);
}

/// True when a solver's final figures are numbers. Readings so large that their squares overflow
/// (|x| ≳ 1e154) otherwise came back "converged" with an infinite or NaN cost or residual.
inline bool finite_fit(const Summary& s) {
  return std::isfinite(s.cost) && std::isfinite(s.residual_rms) && std::isfinite(s.norm_mean);
}

/// Throws Error naming the input `name` and its largest |value| unless `finite`: the one message for
/// input too large for a solver, whether found before it (a sum of squares of the input) or after.
template <typename Values>
void require_finite_fit(bool finite, const std::string& name, const Values& values, const std::string& solver) {
  if (finite) return;
  const double largest = values.size() > 0 ? values.cwiseAbs().maxCoeff() : 0.0;
  throw Error(name + ": values up to " + num(largest) + " overflow " + solver +
              " (a sum of their squares is not finite); rescale them, e.g. to other units");
}

/// As above for a solver of two inputs: names the one with the larger |value| (the one to rescale).
template <typename First, typename Second>
void require_finite_fit(bool finite, const std::string& first_name, const First& first, const std::string& second_name,
                        const Second& second, const std::string& solver) {
  if (finite) return;
  const auto largest = [](const auto& v) { return v.size() > 0 ? v.cwiseAbs().maxCoeff() : 0.0; };
  if (largest(second) > largest(first)) require_finite_fit(false, second_name, second, solver);
  require_finite_fit(false, first_name, first, solver);
}

/// Before a solver whose cost is a sum of squares of `values` (Ceres would fail on the first
/// evaluation with a message naming none of the inputs, and log the NaN Jacobian to stderr).
/// Also values so small that their squares are subnormal or 0 (|x| < 1.5e-154): the solvers that do
/// not normalise their input then found a singular matrix or a NaN Jacobian, and said so instead.
template <typename Values>
void require_squares_representable(const Values& values, const std::string& name, const std::string& solver) {
  require_finite_fit(std::isfinite(values.squaredNorm()), name, values, solver);
  const double largest = values.size() > 0 ? values.cwiseAbs().maxCoeff() : 0.0;
  if (largest > 0.0 && largest * largest < std::numeric_limits<double>::min())
    throw Error(name + ": values no larger than " + num(largest) + " underflow " + solver +
                " (their squares are below the smallest normal double); rescale them, e.g. to other units");
}

/// The coverage thresholds EllipsoidOptions and TwoStepOptions share; `s` is the struct's "Name::".
template <typename Options>
void require_coverage_options(const std::string& s, const Options& o) {
  require_unit(s + "planar_ratio", o.planar_ratio);
  require_unit(s + "poor_coverage_ratio", o.poor_coverage_ratio);
  require_unit(s + "poor_direction_coverage", o.poor_direction_coverage);
  require_int(o.coverage_rows >= 0, s + "coverage_rows", o.coverage_rows, "≥ 0 (0: all rows)");
}

/// An enum holds one of its `count` enumerators 0 … count − 1: a static_cast from an out-of-range
/// integer (a bad config value, a Python int) otherwise falls through every switch silently.
template <typename Enum>
void require_enum(const std::string& name, Enum value, int count, const std::string& names) {
  const auto v = static_cast<long long>(value);
  require_int(v >= 0 && v < count, name, v, "one of " + names);
}

}  // namespace fluxcal::detail
