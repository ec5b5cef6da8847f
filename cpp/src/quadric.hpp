// Internal (not installed): the centre and shape of a fitted quadric uᵀMu + 2vᵀu + k = 0 that must
// be a real ellipsoid, and the spread of the readings it is fitted to — shared by the ellipsoid fit and TWOSTEP.
#pragma once

#include "fluxcal/types.hpp"
#include "checks.hpp"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <sstream>
#include <string>
#include <utility>

namespace fluxcal::detail {

/// The spread of the normalised readings u from the moments' 10×10 scatter of the design rows
/// [u², v², w², 2uv, 2uw, 2vw, 2u, 2v, 2w, 1]: the eigenvalues (ascending) of their covariance, and their mean.
inline std::pair<Eigen::Vector3d, Eigen::Vector3d> spread(const Eigen::Matrix<double, 10, 10>& scatter) {
  const double n = scatter(9, 9);
  const Eigen::Vector3d mean = scatter.block<1, 3>(9, 6).transpose() / (2.0 * n);
  Eigen::Matrix3d second;
  second << scatter(0, 9), scatter(3, 9) / 2, scatter(4, 9) / 2,  //
      scatter(3, 9) / 2, scatter(1, 9), scatter(5, 9) / 2,        //
      scatter(4, 9) / 2, scatter(5, 9) / 2, scatter(2, 9);
  const Eigen::Matrix3d cov = second / n - mean * mean.transpose();
  return {Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(cov, Eigen::EigenvaluesOnly).eigenvalues(), mean};
}

/// Thinnest/widest standard deviation of the normalised readings (0: on a plane or a line).
inline double coverage_ratio(const Eigen::Matrix<double, 10, 10>& scatter) {
  const Eigen::Vector3d ev = spread(scatter).first;
  if (!(ev(2) > 0.0)) return 0.0;
  return std::sqrt(std::max(ev(0), 0.0) / ev(2));
}

/// A sensor that was hardly turned (a static log) leaves noise about one point, which a fit's failures would blame
/// on the quadric's shape or on a plane: "; the readings hardly change (…)" for their messages when the widest
/// spread is under 1 % of the readings' mean magnitude, else "". Turned through the field's directions, readings
/// spread over a sphere of the field's radius, more than that unless the offset is fifty fields. `centre` and
/// `scale`: the normalisation u = (m − centre)/scale.
inline std::string hardly_turned(const Eigen::Matrix<double, 10, 10>& scatter, const Eigen::Vector3d& centre,
                                 double scale) {
  const auto [ev, mean] = spread(scatter);
  const double widest = scale * std::sqrt(std::max(ev(2), 0.0));
  const double level = (centre + scale * mean).norm();
  if (!(widest < 0.01 * level)) return "";
  return "; the readings hardly change (their widest spread is " + percent(widest / level) +
         " of their mean magnitude): was the sensor turned at all? (or are they counts about a large constant, an "
         "unsigned ADC's mid-scale?)";
}

/// A reading this many times farther from the readings' median (per axis) than the median reading is out of any
/// sensor's ellipsoid: turned through the field, readings lie on one whose longest axis is at most a few times its
/// shortest, around the median (a cap's readings: within about twice the median distance of it).
inline constexpr double kDominating = 10.0;
/// At most this share of the readings (and at least one) may lie that far for them to be called a few outliers;
/// more is a second group of readings (mixed recordings, a sensor at rest that was turned briefly).
inline constexpr double kDominatingShare = 0.01;

/// When a few readings far out (kDominating, kDominatingShare) alone make the readings' spread look flat or
/// their quadric no ellipsoid (a spike at 170× the field: its share of the scatter made a full-sphere log
/// "nearly in one plane"): the message that names the farthest and the remedy, else "". Without them the others
/// must be turned (their widest spread at least 1 % of their mean magnitude, as hardly_turned) and, when `thin`
/// > 0 (the coverage ratio below which the caller called the readings flat; `ratio` is theirs), no flatter than
/// `thin`. `failed` says what went wrong with them ("the fitted quadric is not an ellipsoid"). On the error
/// paths only: a median of N values, two passes.
std::string dominated_spread(const SamplesRef& samples, double ratio, double thin, const std::string& failed);

/// Σ w_k d_k d_kᵀ over the design rows d = [u², v², w², 2uv, 2uw, 2vw, 2u, 2v, 2w, 1] of the readings normalised
/// by u = (m − centre)/scale, with a weight w_k per reading: the ellipsoid moments' scatter, weighted, from one
/// lane-blocked pass (ellipsoid.cpp). `weights` has one entry per row of `samples`.
Eigen::Matrix<double, 10, 10> weighted_scatter(const SamplesRef& samples, const SeriesRef& weights,
                                               const Eigen::Vector3d& centre, double scale);
/// Σ w_k d_k, the design rows' weighted sum (one pass over degree ≤ 2).
Eigen::Matrix<double, 10, 1> weighted_design_sum(const SamplesRef& samples, const SeriesRef& weights,
                                                 const Eigen::Vector3d& centre, double scale);

struct EllipsoidShape {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;  ///< of M
  Eigen::Vector3d centre;                              ///< c = −M⁻¹v
  double rho2;                                         ///< (u − c)ᵀ M (u − c) = ρ²
};

/// Throws Error when M is not positive definite or the ellipsoid has no real points. `which` names
/// the fit in the messages ("fitted", "first step's"). `coverage_ratio` (the readings' thinnest/widest
/// spread) below `thin` (the poor-coverage threshold) names the coverage as the cause.
// Below this many readings a quadric that is not an ellipsoid says more about their number than about them.
inline constexpr long kFewReadings = 30;

inline EllipsoidShape ellipsoid_shape(const Eigen::Matrix3d& M, const Eigen::Vector3d& v, double k,
                                      const std::string& which, double coverage_ratio = 1.0, double thin = 0.0,
                                      long samples = 0) {
  EllipsoidShape s{Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(M), Eigen::Vector3d::Zero(), 0.0};
  if (!(s.eig.eigenvalues()(0) > 0.0) && coverage_ratio < thin) {
    // Readings close to a plane (a sensor turned flat, with a little wobble) leave the thin direction's
    // curvature to the noise: the quadric comes out a hyperboloid, not because recordings were mixed.
    std::ostringstream msg;
    msg.precision(3);
    msg << "samples: the readings lie nearly in one plane (thinnest/widest spread " << 100.0 * coverage_ratio
        << " %) and the " << which << " quadric is not an ellipsoid (eigenvalues " << std::setprecision(6)
        << s.eig.eigenvalues().transpose()
        << "); " << kTurnAdvice << ", give reference vectors, or " << kTwoDAdvice;
    throw Error(msg.str());
  }
  if (!(s.eig.eigenvalues()(0) > 0.0)) {
    std::ostringstream msg;
    msg << "samples: the readings do not lie on an ellipsoid (the " << which << " quadric has eigenvalues "
        << s.eig.eigenvalues().transpose()
        << "); "
        << (samples > 0 && samples < kFewReadings
                ? "only " + std::to_string(samples) + " readings: with so few, the noise decides the quadric's shape "
                  "— record a few hundred while turning the sensor"
                : std::string("check that the columns are one magnetometer's x, y, z (from a file: the reader's columns=, "
                              "fluxcal's --columns), and for mixed "
                              "recordings, saturation or a field that changes during the recording"));
    throw Error(msg.str());
  }
  s.centre = -s.eig.eigenvectors() * (s.eig.eigenvectors().transpose() * v).cwiseQuotient(s.eig.eigenvalues());
  s.rho2 = s.centre.dot(M * s.centre) - k;
  if (!(s.rho2 > 0.0))
    throw Error("samples: the " + which + " ellipsoid is imaginary (no real points); the readings are degenerate");
  return s;
}

}  // namespace fluxcal::detail
