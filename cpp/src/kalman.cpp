#include "fluxcal/kalman.hpp"

#include <Eigen/Eigenvalues>

#include <cmath>
#include <sstream>

namespace fluxcal {

namespace {

Eigen::MatrixXd companion(const Eigen::VectorXd& a) {
  const Eigen::Index p = a.size();
  Eigen::MatrixXd m = Eigen::MatrixXd::Zero(p, p);
  m.row(0) = a.transpose();
  for (Eigen::Index i = 1; i < p; ++i) m(i, i - 1) = 1.0;
  return m;
}

// A P Aᵀ + Q e1 e1ᵀ for the companion A in O(p²): row/column 0 from P a, the rest is P shifted.
void predict_covariance(const Eigen::VectorXd& a, double q, const Eigen::MatrixXd& p, Eigen::MatrixXd& m,
                        Eigen::VectorXd& pa) {
  const Eigen::Index n = a.size();
  pa.noalias() = p * a;
  m.bottomRightCorner(n - 1, n - 1) = p.topLeftCorner(n - 1, n - 1);
  m(0, 0) = a.dot(pa) + q;
  for (Eigen::Index j = 1; j < n; ++j) m(0, j) = m(j, 0) = pa[j - 1];
}

// Joseph-form update for C = e1ᵀ, expanded: P − K mᵀ − m Kᵀ + S K Kᵀ with m = M e1.
void update_covariance(const Eigen::MatrixXd& m, const Eigen::VectorXd& k, double s, Eigen::MatrixXd& p) {
  const Eigen::Index n = k.size();
  for (Eigen::Index j = 0; j < n; ++j)
    for (Eigen::Index i = j; i < n; ++i)
      p(i, j) = p(j, i) = m(i, j) - k[i] * m(j, 0) - m(i, 0) * k[j] + s * k[i] * k[j];
}

}  // namespace

Eigen::MatrixXd ar_stationary_covariance(const Eigen::VectorXd& a, double q) {
  const Eigen::MatrixXd A = companion(a);
  const double rho = A.eigenvalues().cwiseAbs().maxCoeff();
  if (!(rho < 1.0)) {
    std::ostringstream msg;
    msg << "ar_coefficients: the AR model is not stationary (companion spectral radius " << rho
        << " ≥ 1), it has no stationary covariance";
    throw Error(msg.str());
  }
  // Doubling: P = Σ A^k Q A^kᵀ summed in log2 steps.
  const Eigen::Index n = a.size();
  Eigen::MatrixXd p = Eigen::MatrixXd::Zero(n, n), ak = A;
  p(0, 0) = q;
  for (int it = 0; it < 200; ++it) {
    const Eigen::MatrixXd next = p + ak * p * ak.transpose();
    ak = (ak * ak).eval();
    const double change = (next - p).cwiseAbs().maxCoeff();
    p = next;
    if (change <= 1e-17 * p.cwiseAbs().maxCoeff() || ak.cwiseAbs().maxCoeff() < 1e-300) break;
  }
  return 0.5 * (p + p.transpose());
}

ArKalman::ArKalman(const Eigen::VectorXd& ar_coefficients, double q, double r, const KalmanOptions& options)
    : a_(ar_coefficients), q_(q), r_(r), options_(options) {
  if (a_.size() < 1) throw Error("ar_coefficients: empty, the Kalman filter needs an AR order p ≥ 1");
  if (!a_.allFinite()) throw Error("ar_coefficients: NaN/Inf");
  if (!(std::isfinite(q) && q > 0.0)) throw Error("q: process variance " + std::to_string(q) + " must be > 0");
  if (!(std::isfinite(r) && r >= 0.0)) throw Error("r: measurement variance " + std::to_string(r) + " must be ≥ 0");
  if (!(options.initial_variance >= 0.0 && std::isfinite(options.initial_variance)))
    throw Error("initial_variance: must be finite and ≥ 0");
  const Eigen::Index n = a_.size();
  if (options.initial_variance > 0.0) {
    p0_ = options.initial_variance * Eigen::MatrixXd::Identity(n, n);
  } else if (spectral_radius() < 1.0) {
    p0_ = ar_stationary_covariance(a_, q_);
  } else {
    p0_ = 10.0 * (q_ + r_) * Eigen::MatrixXd::Identity(n, n);
  }
}

ArKalman ArKalman::from_ar(const ArResult& fit, double r, const KalmanOptions& options) {
  if (fit.order < 1 || fit.coefficients.size() != fit.order)
    throw Error("ar fit: order " + std::to_string(fit.order) +
                ", the Kalman filter needs an AR order p ≥ 1 (a white series has no dynamics to filter)");
  if (!(fit.sigma2 > 0.0)) throw Error("ar fit: residual variance " + std::to_string(fit.sigma2) + " is not > 0");
  return ArKalman(fit.coefficients, fit.sigma2, r >= 0.0 ? r : fit.sigma2, options);
}

double ArKalman::spectral_radius() const { return companion(a_).eigenvalues().cwiseAbs().maxCoeff(); }

Eigen::VectorXd ArKalman::steady_state_gain(Eigen::MatrixXd* prior_covariance, int* iterations) const {
  const Eigen::Index n = a_.size();
  Eigen::MatrixXd p = p0_, m(n, n);
  Eigen::VectorXd pa(n), k = Eigen::VectorXd::Zero(n), k_prev;
  int it = 0;
  for (; it < options_.riccati_max_iterations; ++it) {
    predict_covariance(a_, q_, p, m, pa);
    const double s = m(0, 0) + r_;
    k_prev = k;
    k = m.col(0) / s;
    update_covariance(m, k, s, p);
    if (it > 0 && (k - k_prev).norm() <= options_.riccati_tolerance * k.norm()) break;
  }
  if (it == options_.riccati_max_iterations)
    throw Error("steady_state_gain: the Riccati recursion did not converge in " +
                std::to_string(options_.riccati_max_iterations) + " iterations");
  if (prior_covariance) *prior_covariance = m;
  if (iterations) *iterations = it + 1;
  return k;
}

KalmanResult ArKalman::filter(const SeriesRef& y) const {
  check_series(y, "y", 1, "to filter");
  const Eigen::Index n = a_.size(), len = y.size();
  KalmanResult res;
  res.filtered.resize(len);
  res.innovations.resize(len);
  Eigen::VectorXd x = Eigen::VectorXd::Zero(n);
  if (options_.steady_state) {
    Eigen::MatrixXd m;
    int iterations = 0;
    const Eigen::VectorXd k = steady_state_gain(&m, &iterations);
    for (Eigen::Index t = 0; t < len; ++t) {
      const double x0 = a_.dot(x);
      for (Eigen::Index i = n - 1; i > 0; --i) x[i] = x[i - 1];
      x[0] = x0;
      const double e = y[t] - x0;
      x += k * e;
      res.innovations[t] = e;
      res.filtered[t] = x[0];
    }
    res.gain = k;
    res.covariance = m;
    res.summary.iterations = iterations;
  } else {
    Eigen::MatrixXd p = p0_, m(n, n);
    Eigen::VectorXd pa(n), k(n);
    for (Eigen::Index t = 0; t < len; ++t) {
      const double x0 = a_.dot(x);
      for (Eigen::Index i = n - 1; i > 0; --i) x[i] = x[i - 1];
      x[0] = x0;
      predict_covariance(a_, q_, p, m, pa);
      const double s = m(0, 0) + r_;
      if (!(s > 0.0)) throw Error("kalman: innovation variance became " + std::to_string(s) + " at sample " +
                                  std::to_string(t) + " (set r > 0 or initial_variance > 0)");
      k = m.col(0) / s;
      const double e = y[t] - x0;
      x += k * e;
      update_covariance(m, k, s, p);
      res.innovations[t] = e;
      res.filtered[t] = x[0];
    }
    res.gain = k;
    res.covariance = p;
  }
  res.state = x;
  Summary& s = res.summary;
  s.samples = static_cast<std::size_t>(len);
  s.residual_rms = std::sqrt(res.innovations.squaredNorm() / static_cast<double>(len));
  s.converged = true;
  s.message = std::string(options_.steady_state ? "steady-state" : "time-varying") + " Kalman filter, AR(" +
              std::to_string(n) + ")";
  if (spectral_radius() >= 1.0) s.warnings.push_back("the AR model is not stationary (spectral radius ≥ 1)");
  return res;
}

}  // namespace fluxcal
