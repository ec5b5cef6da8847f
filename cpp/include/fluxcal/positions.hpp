// fluxcal/positions.hpp — multi-position calibration with accelerometer levelling (seed 002).
//
// Model (seed 002 eqs. 1–3): a three-axis sensor at rest in a known field reads
//     U = U0 + K H                                   (U, U0 in output units, e.g. mV; H in field units)
// with U0 the zero offsets and K a full 3×3 matrix: scale factors on the diagonal, installation /
// non-orthogonality coefficients off it (output per field unit). H is the local field f seen in the
// body frame of position i: H_i = R_iᵀ f, R_i the body→local rotation.
//
// Frames (Frame):
//   ned  body x forward, y right, z down (FRD); local north, east, down. A level, static
//        accelerometer reads specific force (0, 0, −g). This is what INS/AHRS tools use.
//   nue  seed 002: body x forward, y up, z right (FUR); local north, up, east. A level, static
//        accelerometer reads (0, +g, 0); pitch θ = arcsin(Ax/|A|), roll γ = arctan(−Az/Ay) (eq. 4).
// Both have the same physical angles (heading clockwise from north, pitch nose up, roll right side
// down) and differ only in the axes vectors are written in. The field f is given in the frame's local
// axes ((N, E, D) for ned, (N, U, E) for nue).
//
// Levelling. Each position has a nominal body→local rotation (e.g. a preset such as the twelve
// positions, or pitch/roll/heading). The accelerometer gives the body's true "up" direction; the
// levelled rotation is the nominal one corrected by the smallest rotation that maps the measured up
// onto local up (level_rotation). Only the heading then still comes from the nominal attitude.
// It is gimbal-free: positions with a body axis vertical (pitch ±90°) are handled like any other.
//
// Heading. When headings are not known exactly, calibrate_positions(estimate_yaw = true) estimates a
// heading correction ψ_i per position jointly with U0 and K (Ceres): R_i = Rz_up(ψ_i)·L_i. What is
// then observable: U0 and all nine entries of K (gravity fixes the body vertical in every position,
// so no rotation of K can be absorbed by the headings), the magnetic heading of every position, and
// optionally the inclination (dip) of the field. Not observable: the field's magnitude separately
// from the scale of K (it must be given: IGRF/WMM or a measurement), and the declination (headings
// are relative to the horizontal direction of the given field). How well the headings are determined
// depends on the set of positions: the twelve positions alone are symmetric enough that headings and K
// trade off (K's largest standard error ≈ 0.15 % of K at 5 nT noise, the paper's sensor, 10 seeds; 0.01 % with
// known headings); the twelve
// plus the same twelve turned 45° in heading bring it back to ≈ 0.01 %. Check standard_errors.
// Levelling errors: with tilt_sigma_deg > 0 each position also gets a small levelling correction with a
// Gaussian prior (the accelerometer's own uncertainty), estimated jointly.
#pragma once

#include "fluxcal/types.hpp"

#include <string>
#include <vector>

namespace fluxcal {

/// Body and local frames of a positions calibration (see the header comment).
enum class Frame {
  ned,  ///< body forward-right-down, local north-east-down
  nue,  ///< seed 002: body forward-up-right, local north-up-east
};

/// Local "up" unit vector in the frame's local axes: (0, 0, −1) for ned, (0, 1, 0) for nue.
Eigen::Vector3d local_up(Frame frame);

/// Pitch and roll (radians) of a static accelerometer from its specific-force reading (pointing up,
/// magnitude g) in the frame's body axes. nue: seed 002 eq. 4, θ = atan2(Ax, √(Ay²+Az²)) (= arcsin(Ax/|A|)),
/// γ = atan2(−Az, Ay). ned: θ = atan2(ax, √(ay²+az²)), φ = atan2(−ay, −az).
Eigen::Vector2d pitch_roll(const Eigen::Vector3d& specific_force, Frame frame);

/// Body→local rotation for pitch, roll, heading (radians). ned: Rz(yaw)·Ry(pitch)·Rx(roll). nue: the
/// same physical attitude in the seed 002 axes; at yaw = 0 this is seed 002 eq. 6, whose middle row is
/// eq. 7, H_up = sinθ H_bx + cosθ cosγ H_by − cosθ sinγ H_bz.
Eigen::Matrix3d body_to_local(double pitch, double roll, double yaw, Frame frame);

/// The nominal body→local rotation corrected by the smallest rotation (about a horizontal axis) that
/// makes it map `body_up` (any length > 0) onto local up.
Eigen::Matrix3d level_rotation(const Eigen::Matrix3d& nominal, const Eigen::Vector3d& body_up, Frame frame);

/// Rotation by `angle` (radians, clockwise seen from above = heading increases) about local up.
Eigen::Matrix3d heading_rotation(double angle, Frame frame);

/// The twelve positions of seed 002 as body→local rotations in `frame`, in the paper's order:
/// body (x, y, z) of the seed 002 frame pointing N-U-E, S-U-W, S-D-E, N-D-W, U-S-E, U-N-W, D-N-E,
/// D-S-W, N-W-U, S-E-U, N-E-D, S-W-D.
std::vector<Eigen::Matrix3d> twelve_positions(Frame frame);

struct PositionsOptions {
  Frame frame = Frame::ned;
  /// Estimate a heading correction per position jointly with U0 and K (Ceres). Needs ≥ 6 positions.
  bool estimate_yaw = false;
  /// Estimate the field's inclination (dip) jointly; its magnitude and declination stay as given.
  bool estimate_inclination = false;
  /// Levelling uncertainty (degrees, 1σ per horizontal axis). > 0: each position also gets a small
  /// levelling correction (north, east tilt) with this Gaussian prior, estimated jointly — the
  /// maximum-likelihood answer when the accelerometer is noisier than the sensor (then field
  /// magnitude, which needs no levelling, carries more weight). 0: the accelerometer is taken as exact.
  double tilt_sigma_deg = 0.0;
  /// Output noise σ (output units), when known: it weighs the tilt prior and scales the joint solve's standard
  /// errors; the linear fit's take it or σ̂, whichever is larger (an exact fit of 4 positions then has them).
  /// 0 = estimated from the fit (noise_sigma).
  double output_sigma = 0.0;
  /// Expected magnitude of the accelerometer readings (their units); 0 = the median of the readings.
  double gravity = 0.0;
  /// A reading whose magnitude differs from `gravity` by more than this fraction is refused (the
  /// device was moving, or the accelerometer is not calibrated).
  double gravity_tolerance = 0.05;
  int max_iterations = 200;
  /// A parameter counts as determined when its standard error is below this fraction of its scale
  /// (offsets: the RMS reading; K entries: the mean diagonal scale factor).
  double determined_tolerance = 0.01;
  std::string units;  ///< units of the outputs U (carried into the result)
};

struct PositionsResult {
  Eigen::Vector3d offset = Eigen::Vector3d::Zero();  ///< U0 (output units)
  Eigen::Matrix3d K = Eigen::Matrix3d::Zero();       ///< output per field unit
  Eigen::Vector3d field = Eigen::Vector3d::Zero();   ///< local field used (local axes; inclination estimated if asked)
  Eigen::VectorXd yaw;              ///< heading correction ψ_i per position (radians; zeros if not estimated)
  std::vector<Eigen::Matrix3d> rotations;  ///< body→local rotation of each position, as fitted
  Samples reference;                ///< body-frame field H_i of each position
  Samples residuals;                ///< U_i − U0 − K H_i (output units)
  std::vector<std::string> parameter_names;  ///< "U0_x".., "K_xx".. (row-major), "yaw_i", "inclination", "tilt_i_north/east"
  Eigen::VectorXd parameters;       ///< in the order of parameter_names
  Eigen::VectorXd standard_errors;  ///< σ̂ √diag((JᵀJ)⁻¹); +inf where undetermined
  std::vector<bool> determined;     ///< per parameter (PositionsOptions::determined_tolerance)
  double noise_sigma = 0.0;         ///< σ̂ = √(SSR/(3N − p)) (output units; SSR includes the tilt prior's
                                    ///< residuals); NaN when 3N = p (the fit is exact)
  /// Degrees of freedom behind the standard errors' σ: 3N − p for σ̂ (tilt prior rows counted), +inf when they
  /// take the σ given (output_sigma) or another fit's, 0 when the fit is exact and no σ was given.
  double noise_dof = 0.0;
  std::string units;
  Summary summary;

  /// Field in the body frame from an output: H = K⁻¹ (U − U0).
  /// Throws Error when K is singular (e.g. a default-constructed result).
  Eigen::Vector3d field_of(const Eigen::Vector3d& output) const;
};

/// Linear least squares of U_i = U0 + K H_i over N ≥ 4 positions whose body-frame fields H_i are
/// known (N×3 each). Throws Error when fewer than 4 positions are given or when the H_i lie in one
/// plane (then U0 and one combination of K's columns cannot be separated; the message names them).
PositionsResult fit_positions(const SamplesRef& outputs, const SamplesRef& reference,
                              const PositionsOptions& options = {});

/// Full calibration from raw positions: `outputs` (N×3 sensor outputs), `specific_force` (N×3
/// calibrated accelerometer readings, pointing up, frame body axes), `nominal` (N body→local
/// rotations, e.g. twelve_positions(); empty = headings unknown, which needs estimate_yaw and ≥ 10
/// positions to start from an ellipsoid fit), `field` (local field in the frame's local axes).
/// Each position is levelled by its accelerometer; with estimate_yaw the headings are corrected too.
PositionsResult calibrate_positions(const SamplesRef& outputs, const SamplesRef& specific_force,
                                    const std::vector<Eigen::Matrix3d>& nominal, const Eigen::Vector3d& field,
                                    const PositionsOptions& options = {});

/// Seed 002's closed-form sums (eqs. 14–29, typos corrected) for exactly the twelve positions in the
/// order of twelve_positions(), `field_up` the SIGNED up component H_u of the field (negative where it
/// dips downward: −41134 nT for seed 002's 52°; the paper quotes the magnitude, which flips the sign of
/// K unless the sensor's polarity is reversed too). Exact when the positions are exact;
/// an independent check of the least-squares solution (the horizontal field cancels out).
struct ClosedForm {
  Eigen::Vector3d offset = Eigen::Vector3d::Zero();
  Eigen::Matrix3d K = Eigen::Matrix3d::Zero();
};
ClosedForm twelve_position_closed_form(const SamplesRef& outputs_nue_order, double field_up);

/// Multi-position accelerometer calibration: a = T (raw − b), T upper triangular with a positive
/// diagonal (the accelerometer's x axis and xy plane define the body axes; a rotation is not
/// observable from gravity alone), |a| = g at every static position. ≥ 9 positions: offset, scales and
/// the three misalignments; 6–8 positions: offset and scales only (misalignment left 0, reported).
struct AccelerometerOptions {
  double gravity = 9.80665;  ///< reference magnitude, in the units the corrected readings should have
  int max_iterations = 100;
};
struct AccelerometerResult {
  Eigen::Vector3d offset = Eigen::Vector3d::Zero();       ///< b (raw units)
  Eigen::Matrix3d matrix = Eigen::Matrix3d::Identity();   ///< T, upper triangular
  double gravity = 0.0;
  bool misalignment_estimated = false;
  Eigen::VectorXd magnitude_errors;  ///< |T (raw_i − b)| − g per position
  double tilt_error_deg = 0.0;       ///< RMS magnitude error / g in degrees: the tilt error it implies
  Summary summary;
  Samples apply_rows(const SamplesRef& raw) const;
};
AccelerometerResult calibrate_accelerometer(const SamplesRef& readings, const AccelerometerOptions& options = {});

}  // namespace fluxcal
