// fluxcal/kalman.hpp — Kalman filter on the AR(p) companion state space (seed 001, S4).
//
//   X_k = A X_{k−1} + B V_k,   Y_k = C X_k + W_k,   V ~ N(0, Q), W ~ N(0, R)
//   A = companion matrix of a1 … ap (first row a, ones below the diagonal), B = e1, C = e1ᵀ.
//
// Per sample: predict x = A x, P = A P Aᵀ + Q e1 e1ᵀ; innovation e = y − x0, S = P00 + R,
// K = P e1 / S; update x += K e and the Joseph form P = (I − K C) P (I − K C)ᵀ + R K Kᵀ. With C = e1ᵀ
// the Joseph form expands exactly to P − K pᵀ − p Kᵀ + S K Kᵀ (p = P e1), which is what is computed:
// O(p²) per sample, symmetric by construction. The companion structure also makes A P Aᵀ O(p²).
// The steady-state form solves the discrete algebraic Riccati equation once (structure-preserving
// doubling, quadratic convergence; the plain recursion when r = 0) and then filters with that constant
// gain (no covariance per sample). The stationary covariance solves the AR autocovariance equations.
#pragma once

#include "fluxcal/timeseries.hpp"

#include <Eigen/Dense>

namespace fluxcal {

struct KalmanOptions {
  /// Initial state covariance P0 = initial_variance · I; 0 = the stationary covariance of the AR
  /// process (discrete Lyapunov equation), or 10 (Q + R) · I when the AR model is not stationary or so
  /// close to it that its stationary covariance is not determined in double precision.
  double initial_variance = 0.0;
  bool steady_state = false;          ///< filter with the steady-state gain
  /// Doubling steps for the steady-state gain (step k covers 2^k Riccati steps; the plain recursion
  /// steps when r = 0).
  int riccati_max_iterations = 100000;
  /// Relative change of the covariance (the gain when r = 0) that ends the iteration.
  double riccati_tolerance = 1e-15;
};

struct KalmanResult {
  Eigen::VectorXd filtered;     ///< C x̂_{k|k}: the filtered output L of seed 001
  Eigen::VectorXd innovations;  ///< y_k − C x̂_{k|k−1}
  Eigen::VectorXd state;        ///< final x̂_{N|N}
  /// final P_{N|N}, the posterior covariance: the time-varying filter's last, or the steady-state filter's
  /// (I − K C) M (M, the steady-state prior, is what steady_state_gain gives)
  Eigen::MatrixXd covariance;
  Eigen::VectorXd gain;         ///< final (or steady-state) K
  Summary summary;
};

/// Filter on the AR(p) model a1 … ap (p ≥ 1) with process variance q > 0 and measurement variance r ≥ 0.
class ArKalman {
 public:
  ArKalman(const Eigen::VectorXd& ar_coefficients, double q, double r, const KalmanOptions& options = {});

  /// Q and R estimated from an AR fit: Q = the residual variance σ² (what drives the AR model);
  /// R = `r` when r ≥ 0, else σ² as well. An AR fit alone cannot separate measurement noise from the
  /// process (white noise on an AR signal only raises the fitted order), so R = σ² is a convention that
  /// lets the filter smooth; give r when the sensor's white-noise floor is known. Throws Error for an
  /// order-0 fit (a white series has no dynamics to filter).
  static ArKalman from_ar(const ArResult& fit, double r = -1.0, const KalmanOptions& options = {});

  /// Filter a whole series from the initial state x = 0, P = P0. At each break (a gap in time, see
  /// Breaks) the filter starts again from x = 0, P = P0: the state before a gap says nothing of the noise
  /// after it once the gap is long against the AR model's memory (P0 is the stationary covariance, the
  /// state's distribution after a long gap). A gap of a few samples loses the state's memory early.
  KalmanResult filter(const SeriesRef& y, const Breaks& breaks = {}) const;

  int order() const { return static_cast<int>(a_.size()); }
  const Eigen::VectorXd& coefficients() const { return a_; }
  double q() const { return q_; }
  double r() const { return r_; }
  /// P0 used by filter().
  const Eigen::MatrixXd& initial_covariance() const { return p0_; }
  /// Steady-state gain and its a-priori covariance (computed on each call; nothing is cached).
  Eigen::VectorXd steady_state_gain(Eigen::MatrixXd* prior_covariance = nullptr, int* iterations = nullptr) const;
  /// Largest |eigenvalue| of the companion matrix (< 1: stationary AR model).
  double spectral_radius() const;

 private:
  Eigen::VectorXd a_;
  double q_, r_;
  KalmanOptions options_;
  Eigen::MatrixXd p0_;
};

/// Stationary covariance of the AR(p) state (solution of P = A P Aᵀ + Q e1 e1ᵀ: the Toeplitz matrix of
/// the autocovariances γ0 … γ_{p−1}); throws Error when the model is not stationary, or so close to it
/// that the covariance is not determined in double precision.
Eigen::MatrixXd ar_stationary_covariance(const Eigen::VectorXd& ar_coefficients, double q);

}  // namespace fluxcal
