#include "fluxcal/kalman.hpp"

#include "checks.hpp"
#include "linalg.hpp"

#include <cmath>
#include <cstdlib>
#include <limits>
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

// s + e = a + b exactly (Knuth's TwoSum).
void two_sum(double a, double b, double& s, double& e) {
  s = a + b;
  const double bb = s - a;
  e = (a - (s - bb)) + (b - bb);
}

// Residual of the autocovariance equation k, q δ_k0 − γ_k + Σ_i a_i γ_|k−i|, in twice the working
// precision (TwoSum and fma products, Ogita–Rump–Oishi Dot2) and rounded once: it is computed from the
// coefficients themselves, so iterative refinement converges to the covariance of exactly these a.
double autocovariance_residual(const Eigen::VectorXd& a, double q, const Eigen::VectorXd& g, Eigen::Index k) {
  double s = k == 0 ? q : 0.0, c = 0.0, e = 0.0;
  two_sum(s, -g[k], s, e);
  c += e;
  for (Eigen::Index i = 1; i <= a.size(); ++i) {
    const double x = a[i - 1], y = g[std::abs(k - i)];
    const double prod = x * y, prod_err = std::fma(x, y, -prod);
    two_sum(s, prod, s, e);
    c += e + prod_err;
  }
  return s + c;
}

}  // namespace

Eigen::MatrixXd ar_stationary_covariance(const Eigen::VectorXd& a, double q) {
  if (a.size() < 1) throw Error("ar_coefficients: empty, the AR order must be ≥ 1");
  if (!a.allFinite()) throw Error("ar_coefficients: not finite");
  if (!(q >= 0.0) || !std::isfinite(q))
    throw Error("q: the innovation variance " + detail::num(q) + " must be finite and ≥ 0");
  const Eigen::MatrixXd A = companion(a);
  const double rho = detail::general_eigenvalues(A).cwiseAbs().maxCoeff();
  if (!(rho < 1.0)) {
    std::ostringstream msg;
    msg << "ar_coefficients: the AR model is not stationary (companion spectral radius " << rho
        << " ≥ 1), it has no stationary covariance";
    throw Error(msg.str());
  }
  // The state is (y_k … y_{k−p+1}), so P is the Toeplitz matrix of the autocovariances γ0 … γ_{p−1},
  // and those solve the autocovariance (Yule–Walker) equations γ_k = Σ_i a_i γ_|k−i| + q δ_k0,
  // k = 0 … p: a (p+1)² linear system instead of summing A^k Q A^kᵀ (doubling on the non-normal
  // companion matrix lost all digits with poles near 1). Poles near 1 make the system ill conditioned
  // (four at 0.99: a plain solve is 2 % off), so the LU solution is refined with residuals in twice the
  // working precision until the correction is at rounding level.
  const Eigen::Index p = a.size(), n = p + 1;
  Eigen::MatrixXd m = Eigen::MatrixXd::Identity(n, n);
  for (Eigen::Index k = 0; k < n; ++k)
    for (Eigen::Index i = 1; i <= p; ++i) m(k, std::abs(k - i)) -= a[i - 1];
  const detail::PartialPivLu lu(m);
  Eigen::VectorXd rhs = Eigen::VectorXd::Zero(n), r(n);
  rhs[0] = q;
  Eigen::VectorXd g = lu.solve(rhs);
  // Each step shrinks the error by about cond(m)·ε; stop at rounding level or when it stops shrinking
  // (cond(m)·ε ≳ 1: the covariance of these coefficients is beyond double precision).
  double change = std::numeric_limits<double>::infinity();
  for (int it = 0; it < 100 && g.allFinite(); ++it) {
    for (Eigen::Index k = 0; k < n; ++k) r[k] = autocovariance_residual(a, q, g, k);
    const Eigen::VectorXd d = lu.solve(r);
    g += d;
    const double previous = change;
    change = d.cwiseAbs().maxCoeff() / g.cwiseAbs().maxCoeff();
    if (change <= 4.0 * std::numeric_limits<double>::epsilon() || !(change < 0.9 * previous)) break;
  }
  const bool converged = change <= 1e-12;
  Eigen::MatrixXd cov(p, p);
  for (Eigen::Index i = 0; i < p; ++i)
    for (Eigen::Index j = 0; j < p; ++j) cov(i, j) = g[std::abs(i - j)];
  if (!converged || !g.allFinite() || !(g[0] > 0.0) || !detail::cholesky_succeeds(cov)) {
    std::ostringstream msg;
    msg << "ar_coefficients: the AR model is too close to non-stationary (companion spectral radius " << rho
        << "): its stationary covariance is not determined in double precision"
        << (g.allFinite() ? "" : " (it overflows)") << "; give initial_variance > 0";
    throw Error(msg.str());
  }
  return cov;
}

namespace detail {

void check(const KalmanOptions& o) {
  const std::string s = "KalmanOptions::";
  require_nonnegative(s + "initial_variance", o.initial_variance, "a finite value ≥ 0 (0: the stationary covariance)");
  require_int(o.riccati_max_iterations >= 1, s + "riccati_max_iterations", o.riccati_max_iterations, "≥ 1");
  require_nonnegative(s + "riccati_tolerance", o.riccati_tolerance);
}

}  // namespace detail

ArKalman::ArKalman(const Eigen::VectorXd& ar_coefficients, double q, double r, const KalmanOptions& options)
    : a_(ar_coefficients), q_(q), r_(r), options_(options) {
  if (a_.size() < 1) throw Error("ar_coefficients: empty, the Kalman filter needs an AR order p ≥ 1");
  if (!a_.allFinite()) throw Error("ar_coefficients: NaN/Inf");
  if (!(std::isfinite(q) && q > 0.0)) throw Error("q: process variance " + detail::num(q) + " must be > 0");
  if (!(std::isfinite(r) && r >= 0.0)) throw Error("r: measurement variance " + detail::num(r) + " must be ≥ 0");
  detail::check(options);
  const Eigen::Index n = a_.size();
  if (options.initial_variance > 0.0) {
    p0_ = options.initial_variance * Eigen::MatrixXd::Identity(n, n);
  } else {
    try {
      p0_ = ar_stationary_covariance(a_, q_);
    } catch (const Error&) {
      // Not stationary, or so close (a double unit root's eigenvalues round to either side of 1)
      // that no stationary covariance is determined: start diffuse.
      p0_ = 10.0 * (q_ + r_) * Eigen::MatrixXd::Identity(n, n);
    }
  }
}

ArKalman ArKalman::from_ar(const ArResult& fit, double r, const KalmanOptions& options) {
  if (fit.order < 1 || fit.coefficients.size() != fit.order)
    throw Error("ar fit: order " + std::to_string(fit.order) +
                ", the Kalman filter needs an AR order p ≥ 1 (a white series has no dynamics to filter)");
  if (!(fit.sigma2 > 0.0)) throw Error("ar fit: residual variance " + detail::num(fit.sigma2) + " is not > 0");
  return ArKalman(fit.coefficients, fit.sigma2, r >= 0.0 ? r : fit.sigma2, options);
}

double ArKalman::spectral_radius() const { return detail::general_eigenvalues(companion(a_)).cwiseAbs().maxCoeff(); }

Eigen::VectorXd ArKalman::steady_state_gain(Eigen::MatrixXd* prior_covariance, int* iterations) const {
  const Eigen::Index n = a_.size();
  Eigen::MatrixXd m(n, n);
  int it = 0;
  bool converged = false;
  if (r_ > 0.0) {
    // Structure-preserving doubling (Chu, Fan, Lin 2005) on the filter DARE
    // M = A M Aᵀ − A M Cᵀ (C M Cᵀ + R)⁻¹ C M Aᵀ + Q, written as X = Fᵀ X (I + G X)⁻¹ F + H with F = Aᵀ,
    // G = Cᵀ R⁻¹ C, H = Q: step k covers 2^k Riccati steps, so it converges quadratically where the
    // recursion converges at the closed-loop rate 1 − K (a random walk with q/r = 1e-8 needs ~10⁵
    // recursion steps, ~20 doubling steps). H increases monotonically to M.
    Eigen::MatrixXd f = companion(a_).transpose(), g = Eigen::MatrixXd::Zero(n, n), h = Eigen::MatrixXd::Zero(n, n);
    g(0, 0) = 1.0 / r_;
    h(0, 0) = q_;
    const Eigen::MatrixXd eye = Eigen::MatrixXd::Identity(n, n);
    for (; it < options_.riccati_max_iterations; ++it) {
      const detail::PartialPivLu w(eye + g * h);
      const Eigen::MatrixXd wf = w.solve_columns(f), wg = w.solve_columns(g);
      Eigen::MatrixXd h_next = h + f.transpose() * h * wf;
      g += f * wg * f.transpose();
      f = (f * wf).eval();
      // Symmetric in exact arithmetic; keep them so.
      h_next = (0.5 * (h_next + h_next.transpose())).eval();
      g = (0.5 * (g + g.transpose())).eval();
      if (!h_next.allFinite()) break;
      const double change = (h_next - h).cwiseAbs().maxCoeff();
      h = std::move(h_next);
      if (change <= options_.riccati_tolerance * h.cwiseAbs().maxCoeff()) {
        converged = true;
        break;
      }
    }
    m = h;
  } else {
    // r = 0: the state is measured exactly after p samples, so the recursion reaches its fixed point
    // M = Q e1 e1ᵀ in about p steps (and G = Cᵀ R⁻¹ C above does not exist).
    Eigen::MatrixXd p = p0_;
    Eigen::VectorXd pa(n), k = Eigen::VectorXd::Zero(n), k_prev;
    for (; it < options_.riccati_max_iterations; ++it) {
      predict_covariance(a_, q_, p, m, pa);
      const double s = m(0, 0) + r_;
      k_prev = k;
      k = m.col(0) / s;
      update_covariance(m, k, s, p);
      if (!k.allFinite()) break;
      if (it > 0 && (k - k_prev).norm() <= options_.riccati_tolerance * k.norm()) {
        converged = true;
        break;
      }
    }
  }
  const double s = m(0, 0) + r_;
  if (!converged || !m.allFinite() || !(s > 0.0)) {
    std::ostringstream msg;
    msg << "steady_state_gain: the Riccati equation did not converge in " << options_.riccati_max_iterations
        << (r_ > 0.0 ? " doubling steps" : " iterations") << " (q = " << q_ << ", r = " << r_
        << "; the AR model's unstable modes must be driven by q and seen in y)";
    throw Error(msg.str());
  }
  if (prior_covariance) *prior_covariance = m;
  if (iterations) *iterations = it + 1;
  return m.col(0) / s;
}

KalmanResult ArKalman::filter(const SeriesRef& y, const Breaks& breaks) const {
  check_series(y, "y", 1, "to filter");
  check_breaks(breaks, y.size(), "breaks");
  const Eigen::Index n = a_.size(), len = y.size();
  KalmanResult res;
  res.filtered.resize(len);
  res.innovations.resize(len);
  Eigen::VectorXd x = Eigen::VectorXd::Zero(n);
  if (options_.steady_state) {
    Eigen::MatrixXd m;
    int iterations = 0;
    const Eigen::VectorXd k = steady_state_gain(&m, &iterations);
    std::size_t next = 0;
    for (Eigen::Index t = 0; t < len; ++t) {
      if (next < breaks.size() && breaks[next] == t) {
        x.setZero();
        ++next;
      }
      const double x0 = a_.dot(x);
      for (Eigen::Index i = n - 1; i > 0; --i) x[i] = x[i - 1];
      x[0] = x0;
      const double e = y[t] - x0;
      x += k * e;
      res.innovations[t] = e;
      res.filtered[t] = x[0];
    }
    res.gain = k;
    // P = (I − K C) M, C = e1ᵀ: the posterior, as the time-varying form reports (symmetrised: rounding)
    const Eigen::MatrixXd p = m - k * m.row(0);
    res.covariance = 0.5 * (p + p.transpose());
    res.summary.iterations = iterations;
  } else {
    Eigen::MatrixXd p = p0_, m(n, n);
    Eigen::VectorXd pa(n), k(n);
    std::size_t next = 0;
    for (Eigen::Index t = 0; t < len; ++t) {
      if (next < breaks.size() && breaks[next] == t) {
        x.setZero();
        p = p0_;
        ++next;
      }
      const double x0 = a_.dot(x);
      for (Eigen::Index i = n - 1; i > 0; --i) x[i] = x[i - 1];
      x[0] = x0;
      predict_covariance(a_, q_, p, m, pa);
      const double s = m(0, 0) + r_;
      if (!(s > 0.0)) throw Error("kalman: innovation variance became " + detail::num(s) + " at sample " +
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
  // The filter is linear and right for any finite y; the plain sum of squares of innovations ≳ 1e154 is not
  // (the RMS came back inf), so only then the overflow-safe norm.
  const double squares = res.innovations.squaredNorm();
  s.residual_rms = std::isfinite(squares) ? std::sqrt(squares / static_cast<double>(len))
                                          : res.innovations.stableNorm() / std::sqrt(static_cast<double>(len));
  s.converged = true;
  s.message = std::string(options_.steady_state ? "steady-state" : "time-varying") + " Kalman filter, AR(" +
              std::to_string(n) + ")" +
              (breaks.empty() ? "" : ", restarted after " + std::to_string(breaks.size()) +
                                         (breaks.size() == 1 ? " gap" : " gaps") + " in time");
  if (spectral_radius() >= 1.0) s.warnings.push_back("the AR model is not stationary (spectral radius ≥ 1)");
  return res;
}

}  // namespace fluxcal
