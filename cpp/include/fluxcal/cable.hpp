// fluxcal/cable.hpp — non-invasive current measurement of a multicore cable with a ring of biaxial
// field sensors (seed 000: Song, Zhang, Ning, Wang 2017, eqs. 2–4; after Erlewein's 4-sensor ring).
//
// Geometry. The cable runs along z through the centre of a ring of M biaxial sensors; sensor i sits at
// angle θ_i on radius R. Its radial and tangential unit vectors are r̂_i = (cos θ_i, sin θ_i) and
// t̂_i = (−sin θ_i, cos θ_i). Its x axis may be turned from r̂_i by axis_angle ψ_i (mounting); its
// reading is then (x, y) = (B·x̂_i, B·ŷ_i) with x̂_i = r̂_i cos ψ_i + t̂_i sin ψ_i, ŷ_i = ẑ × x̂_i. With
// ψ_i = 0 (the paper's ring) x is radial and y tangential.
//
// Forward model (eq. 2, eqs. 3–4 generalised to N conductors). Conductor j is an infinite straight
// wire at c_j = (x_j, y_j) along +z carrying I_j (positive along +z):
//   B(p) = Σ_j (μ0 I_j / 2π) ẑ × (p − c_j) / |p − c_j|²,   ẑ × (dx, dy) = (−dy, dx).
// The Jacobian is analytic (∂/∂c_j = −∂/∂d, linear in I_j).
//
// Inverse problem. S snapshots share the conductor positions; each has its own currents (DC: S = 1;
// AC: samples of the waveforms). Unknowns θ = [x_0, y_0, …, x_{N−1}, y_{N−1}, I(snapshot 0) (N), …]:
// 2N + N·S, or 2N + (N−1)·S with the constraint Σ_j I_j = 0 (the last current is minus the sum of the
// others). Readings 2M·S. Solved by Ceres (Levenberg–Marquardt, analytic Jacobian) in normalised units
// (lengths / R, fields / (μ0/2πR)) from a grid over the bore: the currents are linear given the
// positions, so every pair (N = 2) or a greedy sequence (N > 2) of grid points is scored by linear least
// squares on the currents, and the best `starts` distinct seeds are refined (multi-start); the lowest
// cost wins. A warm start (positions, optionally currents) skips the grid and, by default (options.refiner), is
// refined by a built-in dense Levenberg–Marquardt on the same residuals (no set-up cost).
//
// Background. A field that does not follow the currents (the Earth's, a neighbouring busbar's) misfits the
// model and pulls the positions. fit_background adds a uniform field b = (b_x, b_y) in the cable's frame,
// shared by every snapshot (the ring and the room keep still during a recording): each sensor reads
// (x̂_i·b, ŷ_i·b) on top of the conductors. In the sensors' frame its pattern is harmonic −1 round the ring,
// which no conductor's field has; on M equally spaced sensors it aliases with the conductors' (M−1)-th term, so
// the ring tells it from the conductors' lower terms, and fully once the snapshots' currents differ (a field
// that does not follow them). Each snapshot needs 2M ≥ its currents + 2 readings. A gradient across the ring is
// not modelled (subtracting a zero-current snapshot taken in the same pose removes it too).
//
// Conditioning. The covariance is σ² (JᵀJ)⁻¹ at the solution (JᵀJ has an arrow shape — the shared positions
// and background against each snapshot's own currents —: above 400 parameters it is inverted by blocks, its
// condition number then estimated by power iteration) with σ the reading noise
// (options.noise_sigma, or the residual estimate). Two conductors close together are only seen through
// their dipole moment, conductors near the centre of a symmetric ring through few independent
// components; then JᵀJ is nearly singular and the standard errors explode. well_conditioned is false
// when a standard error exceeds its tolerance (position, relative current) or the Fisher matrix is
// numerically singular — the answer is then not to be trusted, whatever its residual.
#pragma once

#include "fluxcal/types.hpp"

#include <Eigen/Core>

#include <limits>
#include <string>
#include <vector>

namespace fluxcal {

/// μ0/(2π) in T·m/A (CODATA 2022 μ0 = 1.25663706127e-6 N/A², as magpylib and recent SciPy).
constexpr double kMu0Over2Pi = 1.25663706127e-6 / (2.0 * 3.14159265358979323846);

/// A ring of biaxial sensors around a cable. Angles in radians, lengths in metres.
struct CableRing {
  Eigen::VectorXd angles;       ///< θ_i of each sensor (M ≥ 1)
  double radius = 0.0;          ///< R > 0, metres
  Eigen::VectorXd axis_angles;  ///< ψ_i, sensor x axis from radial (empty: all 0, x radial, y tangential)
  /// Conductors must lie within this radius of the centre (the cable's bore); 0: 0.4·R (the paper's
  /// 8 mm hole in a ring of sensors at ~10 mm). The field refuses a conductor beyond it; solve_cable bounds each
  /// coordinate to ±bore (a box about the circle) and flags, with its distance, a conductor that ends on the box's edge
  /// or beyond the circle.
  double bore_radius = 0.0;

  /// Throws Error unless the ring is valid (finite angles, R > 0, 0 < bore < R, matching axis_angles).
  void validate() const;
  Eigen::Index sensors() const { return angles.size(); }
  double bore() const { return bore_radius > 0.0 ? bore_radius : 0.4 * radius; }
  double axis_angle(Eigen::Index i) const { return axis_angles.size() ? axis_angles(i) : 0.0; }
  /// The same ring turned by `angle` (radians, counter-clockwise) about the cable: sensors and their
  /// axes move together.
  CableRing rotated(double angle) const;
};

/// Conductor positions, N×2 (x, y) in metres, one row a conductor.
using ConductorPositions = Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor>;
/// Read-only view of N×2 positions; another width throws Error (types.hpp).
using ConductorPositionsRef = RowsRef<2>;

/// Field at every sensor in its own axes: M×2 (x, y) in tesla (radial, tangential when ψ = 0).
/// Throws Error on a bad ring, non-finite inputs, a size mismatch or a conductor outside the bore.
Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor> cable_field(const CableRing& ring,
                                                                      const ConductorPositionsRef& positions,
                                                                      const SeriesRef& currents);

/// Jacobian of the 2M readings (sensor-major: x_0, y_0, x_1, …) over [x_0, y_0, …, I_0, …] (3N
/// columns), tesla per metre and tesla per ampere.
Eigen::MatrixXd cable_field_jacobian(const CableRing& ring, const ConductorPositionsRef& positions,
                                     const SeriesRef& currents);

struct CableSolveOptions {
  int n_conductors = 2;
  /// Constrain Σ I = 0 in every snapshot (a cable whose return conductor is inside it).
  bool zero_sum_currents = false;
  /// Initialisation grid: points per bore diameter (those inside the bore are used). Cost: with 1–2
  /// conductors every pair of grid points is scored, ≈ 0.3·grid_points⁴ pairs (9: 2 000; 30: 250 000,
  /// about a second; 100: 30 million, minutes); with more, ≈ starts·n·0.8·grid_points² greedy scores.
  int grid_points = 9;
  /// Seeds refined by Ceres (multi-start); the lowest final cost wins. With N > 2 conductors at least 8·N.
  int starts = 6;
  int max_iterations = 100;
  /// Ceres stopping rules (relative; parameters are normalised to the ring radius, so 1e-10 is ~1e-12 m).
  double function_tolerance = 1e-12;
  double gradient_tolerance = 1e-12;
  double parameter_tolerance = 1e-10;
  /// Trust-region strategy: dogleg (Gauss–Newton steps where they work: fewer iterations on these small
  /// well-posed problems) or Levenberg–Marquardt.
  bool dogleg = true;
  /// Which solver refines each start: Ceres, or fluxcal's own dense Levenberg–Marquardt on the same
  /// residuals and analytic Jacobian (bounds by projection; the two agree to 1e-10 m). Ceres' problem and
  /// program construction cost more than the few iterations of a warm-started 8 × 6 problem (≈ 70 µs
  /// against 20 µs), so `automatic` uses the dense solver for a warm start — the tracking step of a
  /// continuous measurement — and Ceres for the multi-start from the grid.
  enum class Refiner { automatic, ceres, dense };
  Refiner refiner = Refiner::automatic;
  /// Reading noise σ per axis (tesla) for the covariance; ≤ 0: estimate it from the residuals (needs
  /// more readings than unknowns). Default: 1e-8 T (10 nT, the paper's 1e-4 G).
  double noise_sigma = 1e-8;
  /// well_conditioned needs every position standard error below this (metres) ...
  double max_position_sigma = 1e-4;
  /// ... and every current standard error below this fraction of the largest |current| of the snapshots (a
  /// 2-core cable with 2 mm spacing on a 10 mm ring has ~1 % at 10 nT; 0.6 mm spacing ~50 %).
  double max_current_relative_sigma = 0.05;
  /// fits_model is false when the residual RMS per degree of freedom exceeds this multiple of noise_sigma
  /// (sensors' offsets or gains, a wrong number of conductors, a field that does not follow the currents) ...
  double misfit_ratio = 5.0;
  /// ... or, when noise_sigma's own precision is known, when the residual's sum of squares over σ² is improbable:
  /// P(F(dof, noise_sigma_dof) > mean square / σ²) < misfit_alpha. noise_sigma_dof is the degrees of freedom
  /// behind noise_sigma (a calibration's repeated readings: their count less the poses); 0: not known (a
  /// datasheet's σ: the ratio rule alone, which allows σ to be 5× off); +inf: σ known exactly (χ² test). A
  /// busbar's gradient 2–36× the noise left currents 5–50 standard errors off with the ratio rule alone.
  double noise_sigma_dof = 0.0;
  double misfit_alpha = 1e-3;
  /// Each sensor's noise σ relative to noise_sigma (M values; empty: all 1): its residuals are weighted by the
  /// inverse, in the fit, the covariance and the misfit test (one σ for a ring with one sensor 3× noisier than the
  /// rest had given 3 % false misfits by the F test, nominal 0.1 %).
  Eigen::VectorXd relative_sigma;
  /// Fit a uniform background field (cable frame, shared by every snapshot) beside the conductors; see Background.
  bool fit_background = false;
  /// Warm start: N×2 positions (metres; empty = grid initialisation) ...
  ConductorPositions initial_positions;
  /// ... and S×N currents (empty = linear least squares at the initial positions).
  Eigen::MatrixXd initial_currents;
};

/// Conductor positions and currents, their covariance, and whether the geometry determines them.
struct CableSolution {
  ConductorPositions positions;  ///< N×2, metres (sorted by x, then y)
  Eigen::MatrixXd currents;      ///< S×N, amperes
  Eigen::Vector2d background = Eigen::Vector2d::Zero();  ///< uniform field, cable frame, tesla (0 unless fitted)
  /// Covariance of [x_0, y_0, …, x_{N−1}, y_{N−1}, I(snapshot 0, conductors 0…N−1), …] (2N + N·S
  /// square, m² / m·A / A²), then with fit_background (b_x, b_y) (T²); with zero_sum_currents the last current
  /// of each snapshot is derived.
  Eigen::MatrixXd covariance;
  Eigen::VectorXd standard_errors;  ///< sqrt of its diagonal (+inf where undetermined)
  bool well_conditioned = false;
  /// The readings fit the model: within misfit_ratio × noise_sigma and, with noise_sigma_dof, the test at
  /// misfit_alpha (only judged with more readings than unknowns and a given noise_sigma; true otherwise).
  bool fits_model = true;
  /// The misfit test's p (see CableSolveOptions::noise_sigma_dof); NaN when not judged by it.
  double misfit_p = std::numeric_limits<double>::quiet_NaN();
  double noise_sigma = 0.0;       ///< σ used for the covariance (tesla)
  double fisher_condition = 0.0;  ///< condition number of the column-scaled JᵀJ
  Eigen::MatrixXd residuals;      ///< S × 2M, reading − model (tesla)
  int starts_tried = 0;           ///< seeds refined
  Summary summary;  ///< samples = readings, cost = mean squared residual (T²), residual_rms (T)
};

/// Positions and currents from S × 2M readings (row = snapshot; columns sensor-major: x_0, y_0, x_1, …,
/// tesla). Throws Error on a bad ring, NaN/Inf readings, a column count that is not 2M, fewer readings
/// than unknowns (too few sensors for the conductors: use more snapshots or zero_sum_currents), bad
/// options, or a warm start outside the bore.
CableSolution solve_cable(const CableRing& ring, const Eigen::Ref<const Eigen::MatrixXd>& readings,
                          const CableSolveOptions& options = {});

}  // namespace fluxcal
