#include "fluxcal/twostep.hpp"

#include "fluxcal/coverage.hpp"
#include "fluxcal/ellipsoid.hpp"
#include "checks.hpp"
#include "clones.hpp"
#include "linalg.hpp"
#include "long_run.hpp"
#include "quadric.hpp"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>
#include <utility>

namespace fluxcal {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
// Field magnitudes within this relative spread count as one magnitude (2-D known-radius first step).
constexpr double kConstantField = 1e-6;
// A column-scaled normal matrix above this condition number is rank deficient (the design matrix
// above ~1e6): the data leave a direction of the first-step state undetermined.
constexpr double kRankDeficient2D = 1e12;
constexpr double kRankDeficient3D = 1e14;  // the same threshold as the ellipsoid fit
// Step halvings before a Gauss–Newton step counts as failed.
constexpr int kLineSearchSteps = 40;
// Readings whose field is within this many noise σ (σ/h > 0.2) keep their magnitude as the target and are left out
// of the noise-bias correction's Jacobian term: the O(σ²) expansion does not hold there.
constexpr double kExpansionReach = 5.0;

using detail::num;  // "%.6g", as every message of the checks
using detail::percent;


// Solves N x = rhs for symmetric positive semi-definite N after scaling it to unit diagonal (so the
// condition number measures the geometry, not the units of the columns). Returns that condition number
// (∞ when singular); x is only meaningful when it is finite.
template <int K>
double solve_scaled(const Eigen::Matrix<double, K, K>& N, const Eigen::Matrix<double, K, 1>& rhs,
                    Eigen::Matrix<double, K, 1>& x) {
  Eigen::Matrix<double, K, 1> d;
  for (int i = 0; i < K; ++i) d(i) = N(i, i) > 0.0 ? 1.0 / std::sqrt(N(i, i)) : 1.0;
  // One dynamic-size solver for every K: each fixed-size one instantiated cost ~10 s of compile time.
  const Eigen::MatrixXd Ns = d.asDiagonal() * N * d.asDiagonal();
  const detail::SymmetricEigen<Eigen::Dynamic> eig = detail::symmetric_eigen(Ns);
  const auto& lam = eig.values;
  if (!(lam(0) > 0.0) || !lam.allFinite()) {
    x.setConstant(std::numeric_limits<double>::quiet_NaN());
    return kInf;
  }
  x = d.asDiagonal() *
      (eig.vectors * (eig.vectors.transpose() * d.cwiseProduct(rhs)).cwiseQuotient(lam));
  return lam(K - 1) / lam(0);
}

void check(const TwoStep2DOptions& o) {
  const std::string s = "TwoStep2DOptions::";
  detail::require_int(o.max_iterations >= 0, s + "max_iterations", o.max_iterations, "≥ 0");
  detail::require_positive(s + "tolerance", o.tolerance);
  detail::require_nonnegative(s + "misfit_spread", o.misfit_spread);
  detail::require_nonnegative(s + "poorly_determined", o.poorly_determined);
  detail::require(std::isfinite(o.runaway_factor) && o.runaway_factor > 1.0, s + "runaway_factor", o.runaway_factor,
                  "a finite value > 1");
}

void check(const TwoStepOptions& o) {
  const std::string s = "TwoStepOptions::";
  detail::require_int(o.max_iterations >= 0, s + "max_iterations", o.max_iterations, "≥ 0 (0: the first step only)");
  detail::require_positive(s + "tolerance", o.tolerance);
  detail::require_finite(s + "noise_sigma", o.noise_sigma, "a finite value (< 0: estimate it, 0: no correction)");
  detail::require_coverage_options(s, o);
  detail::require(o.runaway_misfit > 1.0, s + "runaway_misfit", o.runaway_misfit, "a value > 1 (inf: never)");
  detail::require_positive(s + "determined_tolerance", o.determined_tolerance);
  detail::require_enum(s + "serial_correlation", o.serial_correlation, 3, "automatic, independent, newey_west (0 … 2)");
  detail::require_open_unit(s + "serial_correlation_alpha", o.serial_correlation_alpha,
                            "a significance level in (0, 1)");
}

// ---- 2-D ---------------------------------------------------------------------------------------------

void check_2d(const Readings2DRef& readings, const Eigen::Ref<const Eigen::VectorXd>& h,
              const TwoStep2DOptions& opt) {
  check(opt);
  readings.require_width("readings");
  if (readings.rows() < 5) {
    std::ostringstream msg;
    msg << "readings: " << readings.rows()
        << " rows, need at least 5 for the 5-parameter first step of the 2-D two-step calibration";
    throw Error(msg.str());
  }
  static const char* axis[] = {"x", "y"};
  for (Eigen::Index i = 0; i < readings.rows(); ++i)
    for (int j = 0; j < 2; ++j)
      if (!std::isfinite(readings(i, j))) {
        std::ostringstream msg;
        msg << "readings: row " << i << ", column " << j << " (" << axis[j] << ") is "
            << (std::isnan(readings(i, j)) ? "NaN" : "infinite") << "; remove or repair non-finite readings first";
        throw Error(msg.str());
      }
  detail::check_field_norms(h, readings.rows());
}

// Normalised problem: u = (ĥ − centre)/scale, f = h/field_scale. The model keeps its form:
// b = centre + scale·β, γ = scale·κ/field_scale.
struct Normalised2D {
  Eigen::Vector2d centre;
  double scale;
  double field_scale;
};

// Sum of squared Sampson residuals Σ r_k², r = (ρ_k − f_k)/|∇ρ_k|, ρ = |(u − β) ⊘ κ|, θ = (βx, βy, κx, κy), and the
// Gauss–Newton normal matrix F = JᵀJ and gradient g = Jᵀr, all in one pass.
double magnitude_residuals(const Readings2DRef& readings, const Eigen::Ref<const Eigen::VectorXd>& h,
                           const Normalised2D& nz, const Eigen::Vector4d& th, Eigen::Matrix4d& F,
                           Eigen::Vector4d& g, Eigen::Vector4d* jacobian_sum = nullptr) {
  const double inv_s = 1.0 / nz.scale, inv_t = 1.0 / nz.field_scale;
  const double ikx = 1.0 / th(2), iky = 1.0 / th(3);
  // u − β = ĥ·inv_s − (centre·inv_s + β)
  const double ox = nz.centre(0) * inv_s + th(0), oy = nz.centre(1) * inv_s + th(1);
  // Scalar sums of the 10 distinct entries of JᵀJ and the 4 of Jᵀe (plain doubles keep the loop tight).
  double cost = 0.0, f00 = 0, f01 = 0, f02 = 0, f03 = 0, f11 = 0, f12 = 0, f13 = 0, f22 = 0, f23 = 0, f33 = 0;
  double g0 = 0, g1 = 0, g2 = 0, g3 = 0, s0 = 0, s1 = 0, s2 = 0, s3 = 0;
  for (Eigen::Index k = 0; k < readings.rows(); ++k) {
    const double a = (readings(k, 0) * inv_s - ox) * ikx;
    const double c = (readings(k, 1) * inv_s - oy) * iky;
    const double rho = std::sqrt(a * a + c * c);  // normalised: O(1), no overflow to guard against
    const double q2 = a * a * ikx * ikx + c * c * iky * iky, q = std::sqrt(q2);
    if (rho > 0.0 && q > 0.0) {  // at ρ = 0 the magnitude has no derivative; such a reading adds nothing
      // The Sampson residual r = e ρ/q = e/|∇ρ|, e = ρ − h_k, q = ρ |∇ρ| over the (normalised) reading: the
      // reading's distance from its field's ellipse. The magnitude's own residual e weighs an axis of small gain
      // more (its noise is larger in h) and shrinks it: a blind check's half turn at 2.5–3.8 % noise was 1.6–2.8×
      // the Cramér–Rao bound, at 1.06–1.09× so.
      const double e = rho - h(k) * inv_t, r = e * rho / q;
      cost += r * r;
      const double ir = 1.0 / rho;
      const double d0 = -a * ikx * ir, d1 = -c * iky * ir, d2 = a * d0, d3 = c * d1;  // ∂ρ/∂θ
      // ∂(q²)/∂θ: through a and c, and for the gains through 1/κ² too
      const double a3 = a * ikx * ikx * ikx, c3 = c * iky * iky * iky;
      const double q0 = -2.0 * a3, q1 = -2.0 * c3, q2k = -4.0 * a * a3, q3 = -4.0 * c * c3;
      const double u = (rho + e) / q, v = e * rho / (2.0 * q2 * q);  // ∂r = (ρ + e) ∂ρ/q − e ρ ∂(q²)/(2q³)
      const double j0 = u * d0 - v * q0, j1 = u * d1 - v * q1, j2 = u * d2 - v * q2k, j3 = u * d3 - v * q3;
      s0 += j0; s1 += j1; s2 += j2; s3 += j3;
      f00 += j0 * j0; f01 += j0 * j1; f02 += j0 * j2; f03 += j0 * j3;
      f11 += j1 * j1; f12 += j1 * j2; f13 += j1 * j3;
      f22 += j2 * j2; f23 += j2 * j3; f33 += j3 * j3;
      g0 += r * j0; g1 += r * j1; g2 += r * j2; g3 += r * j3;
    }
  }
  F << f00, f01, f02, f03, 0, f11, f12, f13, 0, 0, f22, f23, 0, 0, 0, f33;
  g << g0, g1, g2, g3;
  F.triangularView<Eigen::StrictlyLower>() = F.transpose();
  if (jacobian_sum) *jacobian_sum << s0, s1, s2, s3;
  return cost;
}

// Gauss–Newton on the Sampson residuals towards `targets` (field units), from th, which it updates.
struct Refined2D {
  bool converged = false;
  bool failed = false;  // no descent step found (rather than the iteration limit)
  int iterations = 0;
  double cost = 0.0;  // Σ r_k² at th
  Eigen::Matrix4d F = Eigen::Matrix4d::Zero();  // JᵀJ at th
};

Refined2D gauss_newton_2d(const Readings2DRef& readings, const Eigen::Ref<const Eigen::VectorXd>& targets,
                          const Normalised2D& nz, Eigen::Vector4d& th, const TwoStep2DOptions& options) {
  Refined2D out;
  Eigen::Matrix4d F, Fn;
  Eigen::Vector4d g, gn;
  double cost = magnitude_residuals(readings, targets, nz, th, F, g);
  const double nd = static_cast<double>(readings.rows());
  for (int it = 0; it < options.max_iterations; ++it) {
    Eigen::Vector4d delta;
    if (!(solve_scaled<4>(F, Eigen::Vector4d(-g), delta) < kInf)) {
      out.failed = true;
      break;
    }
    const double size = delta.cwiseAbs().maxCoeff();
    const double tol = options.tolerance * std::max(1.0, th.cwiseAbs().maxCoeff());
    // Below the tolerance, or with a predicted decrease ½δᵀFδ below the rounding of the cost (a sum of n
    // squares), the cost cannot tell the step apart from rounding: without the latter, 10^5 readings
    // spent up to 40 line-search passes over them on steps of 1e-11.
    if (size <= tol || 0.5 * delta.dot(F * delta) <= cost * nd * std::numeric_limits<double>::epsilon()) {
      th += delta;
      out.iterations = it + 1;
      out.converged = true;
      break;
    }
    // The trial pass also accumulates F and g, so an accepted step (the rule) costs one pass.
    double t = 1.0, trial = kInf;
    Eigen::Vector4d next;
    for (int ls = 0; ls < kLineSearchSteps; ++ls, t *= 0.5) {
      next = th + t * delta;
      trial = magnitude_residuals(readings, targets, nz, next, Fn, gn);
      if (trial < cost) break;
    }
    if (!(trial < cost)) {  // no decrease along a descent direction: at the minimum to rounding
      out.converged = size <= std::sqrt(options.tolerance) * std::max(1.0, th.cwiseAbs().maxCoeff());
      out.failed = !out.converged;
      break;
    }
    th = next;
    cost = trial;
    F = Fn;
    g = gn;
    out.iterations = it + 1;
  }
  out.cost = magnitude_residuals(readings, targets, nz, th, out.F, g);  // (at the final th: a converged step moved it)
  return out;
}

// The noise per axis in the field across a reading's direction (−c, a)/ρ, per unit of σ²: (c²/κx² + a²/κy²)/ρ²; a
// reading at the offset itself has no direction, so the mean of the two.
double noise_across(double a, double c, double rho2, double ikx, double iky) {
  return rho2 > 0.0 ? (c * c * ikx * ikx + a * a * iky * iky) / rho2 : 0.5 * (ikx * ikx + iky * iky);
}

// Σ_k ∂J_k/∂n_k in the normalised readings: each reading's Jacobian row differentiated along its normal ∇ρ/|∇ρ|,
// by central differences (a step of 1e-4 of the readings' scale).
Eigen::Vector4d normal_derivative_of_jacobian(const Readings2DRef& readings, const Eigen::Ref<const Eigen::VectorXd>& targets,
                                             const Normalised2D& nz, const Eigen::Vector4d& th, double sigma2) {
  const double step = 1e-4, inv_s = 1.0 / nz.scale, ikx = 1.0 / th(2), iky = 1.0 / th(3);
  const double ox = nz.centre(0) * inv_s + th(0), oy = nz.centre(1) * inv_s + th(1);
  Readings2D plus(readings.rows(), 2), minus(readings.rows(), 2);
  Eigen::VectorXd kept_targets(readings.rows());
  Eigen::Index kept = 0;
  for (Eigen::Index k = 0; k < readings.rows(); ++k) {
    const double a = (readings(k, 0) * inv_s - ox) * ikx, c = (readings(k, 1) * inv_s - oy) * iky;
    const double rho2 = a * a + c * c, f = targets(k) / nz.field_scale;
    // a field within kExpansionReach of the noise leaves the O(σ²) expansion: its term ∝ σ²/ρ² has no mean in 2-D,
    // and a few readings near the offset (a sweep through small currents) moved the offset by 100 standard errors
    const double across = noise_across(a, c, rho2, ikx, iky);
    if (!(f > kExpansionReach * std::sqrt(sigma2 * across)) || !(rho2 > 0.0)) continue;
    Eigen::Vector2d n(a * ikx, c * iky);  // ∇ρ's direction in the readings
    n = n.normalized() * (step * nz.scale);
    plus.row(kept) = readings.row(k) + n.transpose();
    minus.row(kept) = readings.row(k) - n.transpose();
    kept_targets(kept++) = targets(k);
  }
  Eigen::Matrix4d F;
  Eigen::Vector4d g, up, down;
  magnitude_residuals(plus.topRows(kept), kept_targets.head(kept), nz, th, F, g, &up);
  magnitude_residuals(minus.topRows(kept), kept_targets.head(kept), nz, th, F, g, &down);
  return (up - down) / (2.0 * step);
}

// The mean of a Rice distribution: E|v + ε| for |v| = nu and ε 2-D Gaussian of σ = s per axis,
// s√(π/2)·L½(−ν²/2s²), through the scaled Bessel functions; beyond ν/s ≈ 14 its series (error < 1e-12 ν).
double rice_mean(double nu, double s) {
  if (!(s > 0.0)) return nu;
  const double z = nu * nu / (4.0 * s * s);
  if (z > 50.0) {
    const double q = s * s / (nu * nu);
    return nu * (1.0 + q * (0.5 + q * (0.125 + q * 0.1875)));
  }
  const double e = std::exp(-z);
  constexpr double kHalfPi = 1.57079632679489661923;
  return s * std::sqrt(kHalfPi) *
         ((1.0 + 2.0 * z) * e * std::cyl_bessel_i(0.0, z) + 2.0 * z * e * std::cyl_bessel_i(1.0, z));
}

// Noise makes |(ĥ − b) ⊘ γ| longer than h_k on average — by σ_k²/(2h_k), σ_k the noise across the reading's
// direction in field units — and a fit to h_k shrinks the ellipse: gains σ²/(2h²) high, a blind check's
// 1.00057 ± 0.00016 at 3 % noise. The fit aims at E|…| instead (the planar fit's step 3, per reading: the
// Rice mean, which stays finite for h_k near the noise). σ² per axis, normalised reading units (the Sampson
// residuals' mean square); the targets in field units.
Eigen::VectorXd raised_targets(const Readings2DRef& readings, const Eigen::Ref<const Eigen::VectorXd>& h,
                               const Normalised2D& nz, const Eigen::Vector4d& th, double sigma2) {
  const double inv_s = 1.0 / nz.scale, ikx = 1.0 / th(2), iky = 1.0 / th(3);
  const double ox = nz.centre(0) * inv_s + th(0), oy = nz.centre(1) * inv_s + th(1);
  Eigen::VectorXd out(h.size());
  for (Eigen::Index k = 0; k < h.size(); ++k) {
    const double a = (readings(k, 0) * inv_s - ox) * ikx, c = (readings(k, 1) * inv_s - oy) * iky;
    const double rho2 = a * a + c * c;
    const double across = noise_across(a, c, rho2, ikx, iky);
    // the Sampson residual's normaliser g = |∇ρ| moves with the noise along ∇ρ too: −σ²(q₄/q − q)/h, q = ûᵀK⁻²û,
    // q₄ = ûᵀK⁻⁴û (refine.cpp's target; 0 for equal gains)
    double normaliser = 0.0;
    if (rho2 > 0.0) {
      const double x2 = ikx * ikx, y2 = iky * iky;
      const double q = (a * a * x2 + c * c * y2) / rho2, q4 = (a * a * x2 * x2 + c * c * y2 * y2) / rho2;
      normaliser = q4 / q - q;
    }
    const double f = h(k) / nz.field_scale, noise = std::sqrt(sigma2 * across);
    // only where the expansion holds (the Rice mean alone, near the noise, moved the fit more than it mended)
    out(k) = f > kExpansionReach * noise ? nz.field_scale * (rice_mean(f, noise) - sigma2 * normaliser / f) : h(k);
  }
  return out;
}

// Both gains known to options.poorly_determined or better at the first pass's σ̂²(JᵀJ)⁻¹: else (a field along x
// only) the noise-bias terms in 1/γ² along the undetermined gain are noise themselves (γy moved from 1 to 0.01), and
// the gain's error is far beyond an O(σ²) bias anyway — the summary says "poorly determined".
bool well_determined(const Refined2D& pass, const Eigen::Vector4d& th, double nd, const TwoStep2DOptions& options) {
  const std::optional<Eigen::Matrix4d> inverse = detail::ldlt_inverse_if_positive(pass.F);
  if (!inverse) return false;
  const Eigen::Vector2d se = (pass.cost / (nd - 4.0) * inverse->diagonal().tail<2>()).cwiseSqrt();
  return se.cwiseQuotient(th.tail<2>().cwiseAbs()).maxCoeff() <= options.poorly_determined;
}

// The noise's O(σ²) bias taken off a converged fit (pass, at th): solved again towards raised_targets, then moved by
// F⁻¹σ²Σ∂J_k/∂n, since E[J_k r_k] = σ² ∂J_k/∂n ≠ 0 even at E[r_k] = 0 (an M-estimator's first-order bias; refine.cpp
// takes off both the same way). Updates th, pass and targets; returns the iterations spent.
int without_noise_bias(const Readings2DRef& readings, const SeriesRef& field_norms, const Normalised2D& nz,
                       Eigen::Vector4d& th, Refined2D& pass, Eigen::VectorXd& targets, const TwoStep2DOptions& options) {
  const double sigma2 = pass.cost / (static_cast<double>(readings.rows()) - 4.0);
  targets = raised_targets(readings, field_norms, nz, th, sigma2);
  pass = gauss_newton_2d(readings, targets, nz, th, options);
  Eigen::Vector4d shift;
  if (pass.converged && solve_scaled<4>(pass.F, normal_derivative_of_jacobian(readings, targets, nz, th, sigma2), shift) < kInf)
    th += sigma2 * shift;
  return pass.iterations;
}

}  // namespace

Readings2D TwoStep2DResult::apply_rows(const Readings2DRef& readings) const {
  readings.require_width("readings");
  return (readings.rowwise() - offset.transpose()) * gain.cwiseInverse().asDiagonal();
}

TwoStep2DResult twostep_2d(const Readings2DRef& readings, const SeriesRef& field_norms,
                           const TwoStep2DOptions& options) {
  check_2d(readings, field_norms, options);
  const Eigen::Index n = readings.rows();
  const double nd = static_cast<double>(n);

  Normalised2D nz;
  const Eigen::Vector2d lo = readings.colwise().minCoeff().transpose();
  const Eigen::Vector2d hi = readings.colwise().maxCoeff().transpose();
  nz.centre = 0.5 * (lo + hi);
  nz.scale = 0.5 * (hi - lo).maxCoeff();
  if (!(nz.scale > 0.0)) nz.scale = 1.0;
  const double hmax = field_norms.maxCoeff(), hmin = field_norms.minCoeff();
  nz.field_scale = hmax;

  TwoStep2DResult out;
  Summary& sum = out.summary;
  sum.samples = static_cast<std::size_t>(n);
  out.units = options.units;
  out.constant_field = (hmax - hmin) <= kConstantField * hmax;

  // First step, normal equations in one pass: z = ux², row d = [2ux, 2uy, −uy², −1, f²].
  using Mat5 = Eigen::Matrix<double, 5, 5>;
  using Vec5 = Eigen::Matrix<double, 5, 1>;
  Mat5 N = Mat5::Zero();
  Vec5 rhs = Vec5::Zero();
  double zz = 0.0, f2sum = 0.0;
  {
    // Plain scalar sums of the monomials that make up N, rhs and zᵀz: independent add chains, no 5×5 updates.
    const double inv_s = 1.0 / nz.scale, inv_t = 1.0 / nz.field_scale;
    const double cx = nz.centre(0) * inv_s, cy = nz.centre(1) * inv_s;
    double sx = 0, sy = 0, sg = 0, sxx = 0, sxy = 0, syy = 0, sxg = 0, syg = 0, sgg = 0, sxyy = 0, syyy = 0,
           syyg = 0, syyyy = 0, sxxx = 0, sxxy = 0, sxxyy = 0, sxxg = 0, sxxxx = 0;
    for (Eigen::Index k = 0; k < n; ++k) {
      const double x = readings(k, 0) * inv_s - cx, y = readings(k, 1) * inv_s - cy;
      const double f = field_norms(k) * inv_t, g = f * f;
      const double xx = x * x, yy = y * y;
      sx += x; sy += y; sg += g;
      sxx += xx; sxy += x * y; syy += yy;
      sxg += x * g; syg += y * g; sgg += g * g;
      sxyy += x * yy; syyy += y * yy; syyg += yy * g; syyyy += yy * yy;
      sxxx += xx * x; sxxy += xx * y; sxxyy += xx * yy; sxxg += xx * g; sxxxx += xx * xx;
    }
    // d = [2x, 2y, −y², −1, g], z = x²
    N << 4 * sxx, 4 * sxy, -2 * sxyy, -2 * sx, 2 * sxg,  //
        0, 4 * syy, -2 * syyy, -2 * sy, 2 * syg,           //
        0, 0, syyyy, syy, -syyg,                           //
        0, 0, 0, nd, -sg,                                  //
        0, 0, 0, 0, sgg;
    N.triangularView<Eigen::StrictlyLower>() = N.transpose();
    rhs << 2 * sxxx, 2 * sxxy, -sxxyy, -sxx, sxxg;
    zz = sxxxx;
    f2sum = sg;
  }
  {  // thinnest/widest spread of the readings, from the sums already in N (Σ2u, Σ4uuᵀ)
    const Eigen::Vector2d mean(-N(0, 3) / (2.0 * nd), -N(1, 3) / (2.0 * nd));
    Eigen::Matrix2d second;
    second << N(0, 0), N(0, 1), N(0, 1), N(1, 1);
    const Eigen::Matrix2d cov = second / (4.0 * nd) - mean * mean.transpose();
    const Eigen::Vector2d ev = detail::symmetric_eigenvalues(cov);
    sum.coverage_ratio = ev(1) > 0.0 ? std::sqrt(std::max(ev(0), 0.0) / ev(1)) : 0.0;
  }

  double r = 0.0, kx2 = 0.0;  // (γx/γy)² and κx² (normalised γx²)
  Eigen::Vector2d beta;
  if (!out.constant_field) {
    Vec5 x;
    sum.condition_number = solve_scaled<5>(N, rhs, x);
    if (!(sum.condition_number < kRankDeficient2D))
      throw Error("readings: the first step of the 2-D two-step calibration is rank deficient (condition number " +
                  num(sum.condition_number) +
                  "); the readings and field_norms do not determine offset and gains. The field must change "
                  "direction between readings (turn the sensor; the paper turns the ring 5 × 72°) and the "
                  "readings must not lie on a line; field magnitudes that differ by less than ~0.1 % should "
                  "be given as one common value");
    sum.cost = std::max(0.0, zz - 2.0 * x.dot(rhs) + x.dot(N * x)) / nd;
    r = x(2);
    kx2 = x(4);
    beta << x(0), x(1) / r;
  } else {
    // One magnitude: x4 and x5 are not separable; the known radius gives γx² = (x4 − x4′)/f² with
    // x4 = x1² + x2²/x3 and x4′ = x4 − γx² f² the fitted constant.
    const Eigen::Matrix4d N4 = N.topLeftCorner<4, 4>();
    const Eigen::Vector4d rhs4 = rhs.head<4>();
    Eigen::Vector4d x;
    sum.condition_number = solve_scaled<4>(N4, rhs4, x);
    if (!(sum.condition_number < kRankDeficient2D))
      throw Error("readings: the first step of the 2-D two-step calibration is rank deficient (condition number " +
                  num(sum.condition_number) +
                  "); with one field magnitude the readings must trace an ellipse — turn the sensor through "
                  "more directions in its plane (readings on a line or at a few points do not determine it)");
    sum.cost = std::max(0.0, zz - 2.0 * x.dot(rhs4) + x.dot(N4 * x)) / nd;
    r = x(2);
    kx2 = (x(0) * x(0) + x(1) * x(1) / r - x(3)) / (f2sum / nd);
    beta << x(0), x(1) / r;
  }
  if (!(r > 0.0))
    throw Error("readings: the first step gives (γx/γy)² = " + num(r) +
                " ≤ 0, i.e. γy² < 0: the readings are not consistent with h² = (ĥx − bx)²/γx² + "
                "(ĥy − by)²/γy² — check that field_norms belong to the readings (same order, same field "
                "units) and that no axis is saturated");
  if (!(kx2 > 0.0))
    throw Error("readings: the first step gives γx² = " + num(kx2 * nz.scale * nz.scale / (nz.field_scale * nz.field_scale)) +
                " ≤ 0: the readings are not consistent with h² = (ĥx − bx)²/γx² + (ĥy − by)²/γy² — check "
                "that field_norms belong to the readings (same order, same field units)");

  Eigen::Vector4d th(beta(0), beta(1), std::sqrt(kx2), std::sqrt(kx2 / r));
  const Eigen::Vector4d first = th;
  sum.converged = true;
  // The magnitudes the fit aims at: field_norms, raised by the noise's bias when asked (noise_bias_correction).
  Eigen::VectorXd targets = field_norms;
  if (options.refine && options.max_iterations > 0) {
    Refined2D pass = gauss_newton_2d(readings, targets, nz, th, options);
    const double growth = th.tail<2>().cwiseAbs().cwiseQuotient(first.tail<2>().cwiseAbs()).maxCoeff();
    if (!pass.converged && !(growth <= options.runaway_factor))
      throw Error("readings: the 2-D two-step refinement ran away (gains " + num(growth) +
                  " times the first step's, not converged): the readings do not determine offset and gains. "
                  "Turn the sensor through more of its plane (a full turn), or give readings at different field "
                  "magnitudes; on a full turn, check that field_norms belong to the readings (same order, same "
                  "field units)");
    int iterations = pass.iterations;
    if (options.noise_bias_correction && pass.converged && n > 4 && well_determined(pass, th, nd, options))
      iterations += without_noise_bias(readings, field_norms, nz, th, pass, targets, options);
    sum.converged = pass.converged;
    sum.iterations = iterations;
    if (!sum.converged)
      sum.warnings.push_back(std::string("refinement did not converge ") +
                             (pass.failed ? "(no descent step found" : "(iteration limit") + " after " +
                             std::to_string(sum.iterations) +
                             " iterations); the result is the last iterate — check the readings for outliers and "
                             "that they cover enough of the sensor's plane");
  }

  out.offset = nz.centre + nz.scale * th.head<2>();
  out.gain = (nz.scale / nz.field_scale) * th.tail<2>().cwiseAbs();
  {  // standard errors: σ̂²(JᵀJ)⁻¹ at the result, in the normalised parameters, then in b and γ
    Eigen::Matrix4d F;
    Eigen::Vector4d g;
    const double cost = magnitude_residuals(readings, targets, nz, th, F, g);
    Eigen::Matrix4d cov = Eigen::Matrix4d::Constant(kInf);
    const std::optional<Eigen::Matrix4d> inverse = detail::ldlt_inverse_if_positive(F);
    if (n > 4 && inverse && F.diagonal().minCoeff() > 0.0) {
      const Eigen::Matrix4d c = (cost / (nd - 4.0)) * *inverse;
      if (c.allFinite() && c.diagonal().minCoeff() >= 0.0) cov = c;
    }
    // back to b and γ: b = centre + scale·β, γ = (scale / field_scale)·|κ|
    const double k = nz.scale / nz.field_scale;
    const Eigen::Vector4d d(nz.scale, nz.scale, th(2) < 0.0 ? -k : k, th(3) < 0.0 ? -k : k);
    out.covariance = cov.allFinite() ? Eigen::Matrix4d(d.asDiagonal() * cov * d.asDiagonal()) : cov;
    out.offset_se = out.covariance.diagonal().head<2>().cwiseSqrt();
    out.gain_se = out.covariance.diagonal().tail<2>().cwiseSqrt();
  }

  // Statistics of the compensated magnitudes.
  double sd2 = 0.0, sq = 0.0, sq2 = 0.0;
  const double igx = 1.0 / out.gain(0), igy = 1.0 / out.gain(1);
  for (Eigen::Index k = 0; k < n; ++k) {
    const double hx = (readings(k, 0) - out.offset(0)) * igx, hy = (readings(k, 1) - out.offset(1)) * igy;
    const double mag = std::sqrt(hx * hx + hy * hy);
    const double d = mag - field_norms(k), q = mag / field_norms(k);
    sd2 += d * d;
    sq += q;
    sq2 += q * q;
  }
  sum.residual_rms = std::sqrt(sd2 / nd);
  sum.norm_mean = sq / nd;
  sum.norm_std_over_mean = std::sqrt(std::max(0.0, sq2 / nd - sum.norm_mean * sum.norm_mean)) / sum.norm_mean;
  sum.exact_statistics = true;
  if (options.refine && options.max_iterations > 0) sum.cost = sd2 / nd;
  detail::require_finite_fit(detail::finite_fit(sum) && out.offset.allFinite() && out.gain.allFinite(), "readings",
                             readings, "field_norms", field_norms, "the 2-D two-step calibration");
  const Eigen::Vector2d relative = out.gain_se.cwiseQuotient(out.gain);
  if (!(relative.maxCoeff() <= options.poorly_determined))
    sum.warnings.push_back("poorly determined: standard errors of the gains ±" + percent(relative(0)) + ", ±" +
                           percent(relative(1)) + " and of the offset ±" + num(out.offset_se(0)) + ", ±" +
                           num(out.offset_se(1)) + " (the readings' unit: " +  // (bare numbers beside offsets in µT)
                           percent(out.offset_se(0) / field_norms.mean()) + ", " +
                           percent(out.offset_se(1) / field_norms.mean()) + " of the mean |field|)" +
                           " — the field did not turn through enough of the sensor's "
                           "plane, or never had a component along one axis; turn it through a full circle");
  if (sum.norm_std_over_mean > options.misfit_spread)
    sum.warnings.push_back("the readings do not fit the model: |h|/h scatters by " + percent(sum.norm_std_over_mean) +
                           " after the fit (more than " + percent(options.misfit_spread) +
                           "); check that field_norms belong to the readings (same order, same field units) "
                           "and that no axis is saturated");

  std::ostringstream msg;
  const std::string u = out.units.empty() ? "" : " " + out.units;
  msg << "two-step 2-D: " << n << " readings, "
      << (out.constant_field ? "one field magnitude (known-radius first step), " : "")
      << (options.refine && options.max_iterations > 0
              ? (sum.converged ? "refined in " + std::to_string(sum.iterations) + " iterations"
                               : "refinement not converged")
              : std::string("closed form"))
      << ", offset (" << num(out.offset(0)) << ", " << num(out.offset(1)) << ")" << u << ", gain ("
      << num(out.gain(0)) << ", " << num(out.gain(1)) << "), |h|/h std " << percent(sum.norm_std_over_mean)
      << ", condition number " << num(sum.condition_number);
  if (!sum.warnings.empty()) msg << " (" << sum.warnings.size() << " warning(s))";
  sum.message = msg.str();
  return out;
}

// ---- 3-D ---------------------------------------------------------------------------------------------

namespace {

using Vec9 = Eigen::Matrix<double, 9, 1>;
using Vec10 = Eigen::Matrix<double, 10, 1>;
using Vec11 = Eigen::Matrix<double, 11, 1>;
using Mat9 = Eigen::Matrix<double, 9, 9>;
using Mat10 = Eigen::Matrix<double, 10, 10>;
using Mat11 = Eigen::Matrix<double, 11, 11>;

// Normalised coordinates u = (m − centre)/scale (EllipsoidMoments), unit field: the residual of
// reading k is R_k = (u_k − q)ᵀ N (u_k − q) − 1 − ε_k − μ′ = (|h_k|² − H_k² − μ)/H², with o = centre + scale·q,
// A² = (H/scale)² N, H the (mean) field magnitude and ε_k = (H_k/H)² − 1 (0 when every reading has H).
// R_k = pᵀd_k for the design row d = [u², v², w², 2uv, 2uw, 2vw, 2u, 2v, 2w, 1, ε_k] and the p below, so
// every sum over the readings comes from the 11×11 scatter of those rows. (ε, not (H_k/H)²: a column of
// nearly 1 beside the constant one cancels it, and the rounding left the scoring steps of 1e-8 forever.)
Vec11 quadric(const Eigen::Vector3d& q, const Eigen::Matrix3d& N, double mu) {
  const Eigen::Vector3d Nq = N * q;
  Vec11 p;
  p << N(0, 0), N(1, 1), N(2, 2), N(0, 1), N(0, 2), N(1, 2), -Nq, q.dot(Nq) - 1.0 - mu, -1.0;
  return p;
}

// The scatters of the design rows [d_k, ε_k]: `plain` Σ d dᵀ (the first step's), and `weighted` Σ w_k d dᵀ with
// w_k = (H/H_k)² (the second step's: R_k's variance grows as H_k², A&S weigh by its inverse). For one field
// magnitude both are the ellipsoid moments' 10×10 scatter with a zero ε column; with each reading's (`relative`:
// H_k/H) lane-blocked passes of weighted moments give the ε column and the weighted scatter (one 11×11 update per
// reading had taken 5× the one-H fit's time).
struct DesignScatter {
  Mat11 plain, weighted;
  bool changing = false;  // (H_k/H)² has a standard deviation above kConstantField: else weighted = plain
};

DesignScatter design_scatter(const Mat10& S, const SamplesRef& samples, const Eigen::Vector3d& centre, double scale,
                             const Eigen::VectorXd* relative) {
  DesignScatter out;
  out.plain.setZero();
  out.plain.topLeftCorner<10, 10>() = S;
  out.weighted = out.plain;
  if (!relative) return out;
  // The weights a chunk at a time: three arrays of N had cost more in page faults than the sums themselves.
  constexpr Eigen::Index kChunk = 4096;
  Eigen::VectorXd e(kChunk), w(kChunk), we(kChunk);
  Vec11 ed = Vec11::Zero(), wed = Vec11::Zero();  // Σ ε_k [d_k, ε_k], Σ w_k ε_k [d_k, ε_k]
  Mat10 Sw = Mat10::Zero();
  for (Eigen::Index start = 0; start < samples.rows(); start += kChunk) {
    const Eigen::Index len = std::min(kChunk, samples.rows() - start);
    const auto r2 = relative->segment(start, len).array().square();
    e.head(len) = r2 - 1.0;  // ε_k = (H_k/H)² − 1
    w.head(len) = r2.inverse();
    we.head(len) = e.head(len).cwiseProduct(w.head(len));
    const SamplesRef rows = samples.middleRows(start, len);
    ed.head<10>() += detail::weighted_design_sum(rows, e.head(len), centre, scale);
    ed(10) += e.head(len).squaredNorm();
    wed.head<10>() += detail::weighted_design_sum(rows, we.head(len), centre, scale);
    wed(10) += we.head(len).dot(e.head(len));
    Sw += detail::weighted_scatter(rows, w.head(len), centre, scale);
  }
  out.plain.col(10) = ed;
  out.plain.row(10) = ed.transpose();
  const double n = S(9, 9);
  out.changing = ed(10) / n - (ed(9) / n) * (ed(9) / n) > kConstantField * kConstantField;
  if (!out.changing) {
    out.weighted = out.plain;  // the same magnitude throughout: every weight is 1 to 1e-6, the one-H form exactly
    return out;
  }
  out.weighted.topLeftCorner<10, 10>() = Sw;
  out.weighted.col(10) = wed;
  out.weighted.row(10) = wed.transpose();
  return out;
}

// ∂R_k/∂θ = T d_k for θ = [q0 q1 q2 N00 N11 N22 N01 N02 N12] (the Jacobian is quadratic in u too; ε_k's
// column is zero).
Eigen::Matrix<double, 9, 11> jacobian_map(const Eigen::Vector3d& q, const Eigen::Matrix3d& N) {
  Eigen::Matrix<double, 9, 11> T = Eigen::Matrix<double, 9, 11>::Zero();
  const Eigen::Vector3d Nq = N * q;
  for (int j = 0; j < 3; ++j) {  // ∂R/∂q_j = −2 [N (u − q)]_j
    for (int i = 0; i < 3; ++i) T(j, 6 + i) = -N(j, i);
    T(j, 9) = 2.0 * Nq(j);
  }
  for (int i = 0; i < 3; ++i) {  // ∂R/∂N_ii = (u_i − q_i)²
    T(3 + i, i) = 1.0;
    T(3 + i, 6 + i) = -q(i);
    T(3 + i, 9) = q(i) * q(i);
  }
  constexpr int pairs[3][3] = {{0, 1, 3}, {0, 2, 4}, {1, 2, 5}};  // (i, j, design column of 2u_iu_j)
  for (int r = 0; r < 3; ++r) {  // ∂R/∂N_ij = 2 (u_i − q_i)(u_j − q_j), N_ij = N_ji
    const int i = pairs[r][0], j = pairs[r][1];
    T(6 + r, pairs[r][2]) = 1.0;
    T(6 + r, 6 + i) = -q(j);
    T(6 + r, 6 + j) = -q(i);
    T(6 + r, 9) = 2.0 * q(i) * q(j);
  }
  return T;
}

struct Model3D {
  Eigen::Vector3d q;
  Eigen::Matrix3d N;
};

// Noise mean μ′ = μ/H² at the current estimate (header: A&S's E[v_k]) from the weighted scatter `Sw` of n
// readings: var v_k ≈ (4/3) H_k² tr Σ_ε, so μ′ = ¾ Σ w_k (R_k − R̄)²/n with the weights w_k = (H/H_k)² and R̄ their
// weighted mean (for one field magnitude, every w_k = 1: ¾ of the residuals' variance).
double noise_mean(const Mat11& Sw, double n, const Model3D& m, double noise_sigma, double scale) {
  if (noise_sigma == 0.0) return 0.0;
  if (noise_sigma > 0.0) return noise_sigma * noise_sigma * m.N.trace() / (scale * scale);
  const Vec11 p = quadric(m.q, m.N, 0.0);
  const double total = p.dot(Sw.col(9));  // Σ w_k R_k
  return 0.75 * std::max(0.0, p.dot(Sw * p) - total * total / Sw(9, 9)) / n;
}

// The Sampson residuals r_k = R_k/|N x_k| of a block of readings (x_k = u_k − q, R_k = x_kᵀN x_k − 1 − ε_k − μ′) and,
// when asked, their Jacobian over θ = [q0 q1 q2 N00 N11 N22 N01 N02 N12]. R_k's variance is 4σ²|N x_k|² (the noise
// seen along the quadric's normal, A&S's σ_k²): r_k is the reading's distance from the ellipsoid in the readings' own
// units (×2/scale), the first-order maximum likelihood. The scoring on Σ w R_k² with its weights held at an iterate
// (or w = (H/H_k)² alone, A&S's form for one field) shrinks an axis the readings see little of — its noise shrinks
// with it —, and a blind check found the offset along it 7× the Cramér–Rao bound off on a ±20° band of tilts (z
// 2680 nT off at σ 50 nT, not falling with more readings); with |N x_k|'s own derivative in the Jacobian, at the bound.
// The noise means of readings start … start + len: each one's (each_mu), else the one μ for all.
Eigen::ArrayXd block_noise_means(const Eigen::VectorXd* each_mu, double mu, Eigen::Index start, Eigen::Index len) {
  return each_mu ? Eigen::ArrayXd(each_mu->segment(start, len).array()) : Eigen::ArrayXd::Constant(len, mu);
}

struct SampsonBlock {
  Eigen::ArrayXd R0, g2;  // x_kᵀN x_k − 1 − ε_k (μ′ not taken off) and |N x_k|²
  Eigen::MatrixXd J;      // ∂r_k/∂θ, rows (when asked)
};

SampsonBlock sampson_block(const SamplesRef& rows, const Eigen::Vector3d& centre, double scale,
                           const Eigen::VectorXd* relative, Eigen::Index start, const Model3D& m, double mu,
                           bool jacobian, const Eigen::VectorXd* each_mu = nullptr) {
  const Eigen::MatrixXd X = ((rows.rowwise() - centre.transpose()) / scale).rowwise() - m.q.transpose();
  const Eigen::MatrixXd NX = X * m.N;  // rows (N x_k)ᵀ: N is symmetric
  SampsonBlock b;
  b.R0 = (X.array() * NX.array()).rowwise().sum() - 1.0;
  if (relative) b.R0 -= relative->segment(start, rows.rows()).array().square() - 1.0;
  b.g2 = NX.rowwise().squaredNorm().array();
  if (!jacobian) return b;
  // ∂r/∂θ = ∂R/∂θ / g − R ∂(g²)/∂θ / (2 g³), g = |N x|; a reading at the centre (g = 0) takes no part
  const Eigen::ArrayXd ok = (b.g2 > 0.0).cast<double>();
  const Eigen::ArrayXd g = b.g2.max(1e-300).sqrt();
  const Eigen::ArrayXd mus = block_noise_means(each_mu, mu, start, rows.rows());
  const Eigen::ArrayXd a = ok / g, c = ok * (b.R0 - mus) / (2.0 * g * b.g2.max(1e-300));
  const Eigen::MatrixXd NNX = NX * m.N;
  b.J.resize(rows.rows(), 9);
  for (int j = 0; j < 3; ++j) {
    b.J.col(j) = (-2.0 * a * NX.col(j).array() + 2.0 * c * NNX.col(j).array()).matrix();
    b.J.col(3 + j) = (a * X.col(j).array().square() - 2.0 * c * NX.col(j).array() * X.col(j).array()).matrix();
  }
  constexpr int pairs[3][2] = {{0, 1}, {0, 2}, {1, 2}};
  for (int e = 0; e < 3; ++e) {
    const int i = pairs[e][0], j = pairs[e][1];
    const Eigen::ArrayXd xi = X.col(i).array(), xj = X.col(j).array();
    b.J.col(6 + e) = (2.0 * a * xi * xj - 2.0 * c * (NX.col(i).array() * xj + NX.col(j).array() * xi)).matrix();
  }
  return b;
}

// One pass of the Sampson residuals at `m` with the noise mean μ′: Σ r², and with `jacobian` the scoring's F = JᵀJ and
// gradient Jᵀr; and the sums of the noise mean at m (sampson_noise_mean).
struct SampsonPass {
  double cost = 0.0, rounding = 0.0;  // Σ r_k², and what rounding the terms of R_k makes of it
  Mat9 F = Mat9::Zero();
  Vec9 g = Vec9::Zero();
  double s0 = 0.0, s1 = 0.0, s2 = 0.0;  // Σ w_k, Σ w_k R0_k, Σ w_k R0_k², w_k = λ̄/|N x_k|² (λ̄ = tr N/3)
};

SampsonPass sampson_pass(const SamplesRef& samples, const Eigen::Vector3d& centre, double scale,
                         const Eigen::VectorXd* relative, const Model3D& m, double mu, bool jacobian,
                         const Eigen::VectorXd* each_mu = nullptr) {
  // (512 rows: a block's temporaries stay under malloc's mmap threshold; at 4096 their page faults took a fifth)
  constexpr Eigen::Index kChunk = 512;
  const double mean_eigen = m.N.trace() / 3.0;
  SampsonPass out;
  for (Eigen::Index start = 0; start < samples.rows(); start += kChunk) {
    const Eigen::Index len = std::min(kChunk, samples.rows() - start);
    const SampsonBlock b =
        sampson_block(samples.middleRows(start, len), centre, scale, relative, start, m, mu, jacobian, each_mu);
    const Eigen::ArrayXd ok = (b.g2 > 0.0).cast<double>(), g2 = b.g2.max(1e-300);
    const Eigen::ArrayXd mus = block_noise_means(each_mu, mu, start, len);
    const Eigen::ArrayXd r = ok * (b.R0 - mus) / g2.sqrt();
    out.cost += r.square().sum();
    out.rounding += (ok * (b.R0.abs() + 2.0 + mus.abs()).square() / g2).sum();
    const Eigen::ArrayXd w = ok * mean_eigen / g2;
    out.s0 += w.sum();
    out.s1 += (w * b.R0).sum();
    out.s2 += (w * b.R0.square()).sum();
    if (jacobian) {
      out.F.noalias() += b.J.transpose() * b.J;
      out.g.noalias() += b.J.transpose() * r.matrix();
    }
  }
  out.rounding *= std::numeric_limits<double>::epsilon();
  return out;
}

// The noise mean μ′ of the Sampson fit at a pass's model: E[R_k] = σ² tr N, but weighted by 1/|N x_k|², whose noise
// is correlated with R_k's (a reading pushed outwards weighs less), the mean comes to σ² tr N − (4/3) σ² tr N =
// −σ² tr N/3 (on a sphere; refine's noise_bias_correction agrees to 2e-5 of the scale at σ 1–5 %). With w_k =
// λ̄/|N x_k|², w_k var R_k = (4/3) σ² tr N, so μ′ = −¼ of R's variance weighted by w_k about its weighted mean (a
// known σ: −σ² tr N/3 in these units; 0: none).
double sampson_noise_mean(const SampsonPass& pass, double n, const Model3D& m, double noise_sigma, double scale) {
  if (noise_sigma == 0.0) return 0.0;
  if (noise_sigma > 0.0) return -noise_sigma * noise_sigma * m.N.trace() / (scale * scale) / 3.0;
  if (!(pass.s0 > 0.0)) return 0.0;
  return -0.25 * std::max(0.0, pass.s2 - pass.s1 * pass.s1 / pass.s0) / n;
}

using Within = Eigen::Array<bool, Eigen::Dynamic, 1>;

// Each reading's noise mean of R_k to O(σ²) (σ² per axis, u units), where its Sampson residual r_k = (R_k − μ_k)/g_k,
// g_k = |N x_k|, has mean 0: the noise ε lengthens R by εᵀNε (mean σ² tr N), and the normaliser g moves with R's own
// noise along the normal n̂ = N x_k/g_k: E[R/g] = σ²(tr N − 2 q_k)/g, q_k = n̂ᵀN n̂. (On a sphere σ² tr N/3 for every
// reading; the one μ′ = −σ² tr N/3 fitted first also holds the Jacobian's move, taken off on its own here:
// normal_derivative_3d.) `within`: whether the expansion holds at each reading — its surface's distance from the
// centre along its normal, x_kᵀN x_k/g_k (the field's length there, in u), beyond kExpansionReach σ. Nearer the
// centre (field norms near the noise) its terms are O(σ), not O(σ²), and noisy: as in 2-D, such a reading keeps no
// noise mean (0) and stays out of the Jacobian term (a review: an offset's spread 1.25× wider with field norms 0–0.3
// of the largest).
Eigen::VectorXd reading_noise_means(const SamplesRef& samples, const Eigen::Vector3d& centre, double scale,
                                    const Model3D& m, double sigma2, Within& within) {
  const Eigen::MatrixXd X = ((samples.rowwise() - centre.transpose()) / scale).rowwise() - m.q.transpose();
  const Eigen::MatrixXd NX = X * m.N;
  const Eigen::ArrayXd g2 = NX.rowwise().squaredNorm().array();
  const Eigen::ArrayXd q = ((NX * m.N).array() * NX.array()).rowwise().sum() / g2.max(1e-300);
  within = (X.array() * NX.array()).rowwise().sum() / g2.max(1e-300).sqrt() > kExpansionReach * std::sqrt(sigma2);
  return within.select(sigma2 * (m.N.trace() - 2.0 * q), 0.0).matrix();
}

// Σ_k ∂J_k/∂n̂_k over the readings `within` the expansion: each one's Jacobian row (∂r_k/∂θ, its μ_k held)
// differentiated along its normal n̂_k in u, by central differences (a step of 1e-4 of the ellipsoid's mean radius),
// a chunk at a time.
Vec9 normal_derivative_3d(const SamplesRef& samples, const Eigen::Vector3d& centre, double scale,
                          const Eigen::VectorXd* relative, const Model3D& m, const Eigen::VectorXd& each_mu,
                          const Within& within) {
  const double step = 1e-4 / std::sqrt(m.N.trace() / 3.0);
  constexpr Eigen::Index kChunk = 512;
  Vec9 sum = Vec9::Zero();
  for (Eigen::Index start = 0; start < samples.rows(); start += kChunk) {
    const Eigen::Index len = std::min(kChunk, samples.rows() - start);
    const Samples rows = samples.middleRows(start, len);
    const Eigen::MatrixXd NX = (((rows.rowwise() - centre.transpose()) / scale).rowwise() - m.q.transpose()) * m.N;
    Samples along(len, 3);  // step·n̂_k in the readings' units (0: the same row twice, no term)
    for (Eigen::Index i = 0; i < len; ++i) {
      const double g = NX.row(i).norm();
      along.row(i) = g > 0.0 && within(start + i) ? Eigen::RowVector3d(NX.row(i) * (step * scale / g))
                                                  : Eigen::RowVector3d::Zero();
    }
    const Samples plus = rows + along, minus = rows - along;
    sum += (sampson_block(plus, centre, scale, relative, start, m, 0.0, true, &each_mu).J -
            sampson_block(minus, centre, scale, relative, start, m, 0.0, true, &each_mu).J)
               .colwise()
               .sum()
               .transpose();
  }
  return sum / (2.0 * step);
}

// The noise-bias correction's Jacobian move is taken where every parameter's standard error is below this many
// determined_tolerance of its scale (0.1 at the default): looser than "determined", as it must act on partial
// coverage (a hemisphere: 1.7 %; a 60° cap of 1000 readings at σ 1 %: 5 %), yet off where the readings leave a
// parameter undetermined (a 30° cap: errors of 30–180 % of the scale, where the move widened a matrix entry's error
// 1.2×). Each reading's own noise mean is taken regardless, as refine takes its targets.
constexpr double kBiasMoveTolerance = 10.0;

// Whether σ_r² F⁻¹ (σ_r² the Sampson residuals' variance) gives every parameter a standard error below `tolerance` of
// its scale — the mean radius 1/√λ̄ for q, the mean eigenvalue λ̄ = tr N/3 for N's entries (refine's rule).
bool all_determined(const Mat9& F, double var_r, const Model3D& m, double tolerance) {
  const detail::ScaledInverse Finv = detail::scaled_inverse(F);
  if (Finv.singular) return false;
  const double mean_eigen = m.N.trace() / 3.0;
  for (int j = 0; j < 9; ++j)
    if (!(std::sqrt(var_r * Finv.inverse(j, j)) < tolerance * (j < 3 ? 1.0 / std::sqrt(mean_eigen) : mean_eigen)))
      return false;
  return true;
}

// The model moved by t·δ (δ over θ, sampson_block's order).
Model3D moved(const Model3D& m, const Vec9& delta, double t) {
  Model3D next = m;
  next.q += t * delta.head<3>();
  Eigen::Matrix3d dN;
  dN << delta(3), delta(6), delta(7), delta(6), delta(4), delta(8), delta(7), delta(8), delta(5);
  next.N += t * dN;
  return next;
}

// The calibration (offset, A) of a model: A = (H/scale) N^½ (N's negative eigenvalues, of a model run off, as 0).
Calibration calibration_of(const Model3D& model, const Eigen::Vector3d& centre, double scale, double H) {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(model.N);
  Calibration cal;
  cal.offset = centre + scale * model.q;
  cal.matrix = (H / scale) * eig.eigenvectors() * eig.eigenvalues().cwiseMax(0.0).cwiseSqrt().asDiagonal() *
               eig.eigenvectors().transpose();
  cal.field_norm = H;
  return cal;
}

// The errors are σ̂² F⁻¹ up to kPlainReadings readings, the HC2 sandwich's from kSandwichReadings, a blend between.
constexpr Eigen::Index kPlainReadings = 10, kSandwichReadings = 30;

// The second step's covariance (TwoStepResult), from one pass over the readings: with x = u − q, each reading's
// weighted residual r_k = √w_k R_k, R_k = xᵀN x − 1 − ε_k − μ′, and its score r_k √w_k ∂R_k/∂θ over
// θ = [q0 q1 q2 N00 N11 N22 N01 N02 N12] (jacobian_map's: −2 N x, x_i², 2 x_i x_j); F = Σ w ∂R ∂Rᵀ is the scoring's.
void parameter_covariance(TwoStepResult& out, const SamplesRef& samples, const Model3D& m, double mu, const Mat9& F,
                          const Eigen::Vector3d& centre, double scale, double H, const Eigen::VectorXd* relative,
                          const TwoStepOptions& options, const Eigen::VectorXd* each_mu) {
  constexpr Eigen::Index p = 9;
  const Eigen::Index n = samples.rows();
  const Calibration& cal = out.calibration;
  out.parameter_names = {"b0", "b1", "b2", "a00", "a01", "a02", "a11", "a12", "a22"};
  out.parameters.resize(9);
  out.parameters << cal.offset, cal.matrix(0, 0), cal.matrix(0, 1), cal.matrix(0, 2), cal.matrix(1, 1),
      cal.matrix(1, 2), cal.matrix(2, 2);
  if (n <= p) {  // an exact fit: no residual is left to measure the noise by (its σ̂² would be 0/0)
    out.determined.assign(9, false);
    out.identifiable = false;
    out.summary.warnings.push_back(
        "not identifiable: " + std::to_string(n) + " readings fit the 9 parameters exactly, leaving no residual to "
        "measure the noise by, so no standard errors; log at least 10 readings (hundreds, while turning the sensor, "
        "for errors worth having)");
    return;
  }
  const Eigen::MatrixXd X =
      ((samples.rowwise() - centre.transpose()) / scale).rowwise() - m.q.transpose();  // x_k, rows
  const SampsonBlock block = sampson_block(samples, centre, scale, relative, 0, m, mu, true, each_mu);
  const Eigen::ArrayXd mus = block_noise_means(each_mu, mu, 0, n);
  const Eigen::ArrayXd r = (block.g2 > 0.0).select((block.R0 - mus) / block.g2.max(1e-300).sqrt(), 0.0);
  const Eigen::MatrixXd& J = block.J;  // ∂r_k/∂θ, rows: F = JᵀJ, the scores r_k J_k
  const Eigen::MatrixXd scores = r.matrix().asDiagonal() * J;
  // μ′ is no free parameter (N's scale absorbs a constant in R): N − 9 degrees of freedom
  const double sigma2 = r.square().sum() / static_cast<double>(n - p);
  const detail::ScaledInverse Finv = detail::scaled_inverse(F);
  // R's variance follows |Aᵀĥ|² around the ellipsoid (4 H² ĥᵀA Aᵀĥ σ²): for a strongly anisotropic A the readings
  // are not equally noisy, and σ̂² F⁻¹ gave 0.72–1.38× the Monte-Carlo spread (gains 0.3/1/3, 45–89 readings).
  // The sandwich F⁻¹ Σ g gᵀ/(1 − h_kk) F⁻¹ (HC2: h_kk each reading's leverage J_k F⁻¹ J_kᵀ, which N/(N − 9) had only
  // averaged) stays within 0.94–1.10× from 30 readings. With fewer it scatters from fit to fit, so it is blended
  // linearly with σ̂² F⁻¹ from 10 readings (σ̂² F⁻¹ alone) to 30 (the sandwich alone): a reading added had changed an
  // error 1.4–1.6× (median) where a hard switch was. R is relative to H²: residuals at rounding (readings without
  // noise) have no structure worth a sandwich (exact readings' rounding had widened an error 2× under Newey–West).
  const bool rounding = std::sqrt(sigma2) < 1e3 * std::numeric_limits<double>::epsilon();
  Eigen::MatrixXd cov = sigma2 * Finv.inverse;
  const double sandwich_share =
      std::clamp(static_cast<double>(n - kPlainReadings) / static_cast<double>(kSandwichReadings - kPlainReadings),
                 0.0, 1.0);
  if (sandwich_share > 0.0 && !Finv.singular && !rounding) {
    // Σ r_k² J_kᵀJ_k / (1 − h_k), a block of rows at a time: no N×9 matrix beyond J and the scores
    constexpr Eigen::Index kBlock = 512;
    Mat9 meat = Mat9::Zero();
    for (Eigen::Index k0 = 0; k0 < n; k0 += kBlock) {
      const Eigen::Index rows = std::min(kBlock, n - k0);
      const auto Jb = J.middleRows(k0, rows);
      const Eigen::ArrayXd leverage = (Jb * Finv.inverse).cwiseProduct(Jb).rowwise().sum().array();
      const Eigen::ArrayXd weight = r.segment(k0, rows).square() / (1.0 - leverage.min(0.99));
      meat.noalias() += Jb.transpose() * (weight.matrix().asDiagonal() * Jb);
    }
    Eigen::MatrixXd hc = Finv.inverse * meat * Finv.inverse;
    hc = 0.5 * (hc + hc.transpose());
    if (hc.allFinite()) cov = sandwich_share * hc + (1.0 - sandwich_share) * cov;
  }
  const Eigen::MatrixXd independent_theta = cov;
  // The test for correlation in time takes each R_k over its modelled σ (r_k: 2 σ_m |N x_k| in these units): raw, the
  // σ that changes around an anisotropic ellipsoid looked like correlation to Ljung–Box (white noise, gains 0.3/1/3:
  // rejected at p < 0.01 in 33 of 400 smooth turns, and Newey–West taken in 26)
  const Eigen::VectorXd standardised = r.matrix();
  const std::string correlated = detail::correct_for_serial_correlation(
      cov, out.serial_correlation, standardised, scores, Finv.inverse, Finv.singular,
      rounding ? SerialCorrelation::independent : options.serial_correlation, options.serial_correlation_alpha);

  // The delta method to [o, a00 a01 a02 a11 a12 a22]: ∂o/∂q = scale·I; A = c N^½ (c = H/scale) moves by
  // dA = c V [(Vᵀ dN V)_ij / (s_i + s_j)] Vᵀ, N = V diag(s²) Vᵀ.
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(m.N);
  const Eigen::Matrix3d V = eig.eigenvectors();
  const Eigen::Vector3d sv = eig.eigenvalues().cwiseMax(0.0).cwiseSqrt();
  const double c = H / scale;
  Eigen::Matrix<double, 9, 9> G = Eigen::Matrix<double, 9, 9>::Zero();
  G.topLeftCorner<3, 3>() = scale * Eigen::Matrix3d::Identity();
  constexpr int entries[6][2] = {{0, 0}, {1, 1}, {2, 2}, {0, 1}, {0, 2}, {1, 2}};  // θ's N entries, in order
  constexpr int rows[3][3] = {{3, 4, 5}, {4, 6, 7}, {5, 7, 8}};  // row of A(i, j) among a00 a01 a02 a11 a12 a22
  for (int e = 0; e < 6; ++e) {
    Eigen::Matrix3d dN = Eigen::Matrix3d::Zero();
    dN(entries[e][0], entries[e][1]) = dN(entries[e][1], entries[e][0]) = 1.0;
    Eigen::Matrix3d inner = V.transpose() * dN * V;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) inner(i, j) /= std::max(sv(i) + sv(j), 1e-300);
    const Eigen::Matrix3d dA = c * V * inner * V.transpose();
    for (int i = 0; i < 3; ++i)
      for (int j = i; j < 3; ++j) G(rows[i][j], 3 + e) = dA(i, j);
  }
  out.covariance = G * cov * G.transpose();
  out.standard_errors = out.covariance.diagonal().cwiseMax(0.0).cwiseSqrt();
  const Eigen::VectorXd independent = (G * independent_theta * G.transpose()).diagonal().cwiseMax(0.0).cwiseSqrt();
  out.serial_correlation.standard_errors_independent = independent;
  if (out.serial_correlation.lags > 0) {  // the widening of the reported parameters (after the delta method)
    double widest = 0.0;
    for (int j = 0; j < 9; ++j)
      if (independent(j) > 0.0) widest = std::max(widest, out.standard_errors(j) / independent(j));
    out.serial_correlation.inflation = widest;
  }
  if (!correlated.empty()) out.summary.warnings.push_back(correlated);

  // Determined: the independent-readings error against each parameter's scale (refine's rule).
  const double radius = scale * X.rowwise().norm().mean(), gain = cal.matrix.norm() / std::sqrt(3.0);
  out.determined.assign(9, true);
  out.identifiable = true;
  std::string undetermined;
  for (int k = 0; k < 9; ++k) {
    if (std::isfinite(independent(k)) && independent(k) < options.determined_tolerance * (k < 3 ? radius : gain))
      continue;
    out.determined[static_cast<std::size_t>(k)] = false;
    undetermined += (out.identifiable ? "" : ", ") + out.parameter_names[static_cast<std::size_t>(k)];
    out.identifiable = false;
  }
  // (as refine: residuals of several % of the field make the errors large, and "turn more" would mislead; determined,
  // the answer may still be biased by what the model misses)
  const double misfit = out.summary.residual_rms / H;
  const std::string causes =
      relative ? "that field_norms belong to the readings (same order, same time, same units), " +
                     std::string(detail::kMagnitudeMisfitCauses)
               : std::string(detail::kMagnitudeMisfitCauses);
  const std::string misfit_said = "the residuals are " + percent(misfit) + " of the field, far above a sensor's noise: "
                                  "the readings do not fit the model";
  if (!out.identifiable)
    out.summary.warnings.push_back(
        "not identifiable: the data do not determine " + undetermined + " (standard error above " +
        percent(options.determined_tolerance) + " of its scale)" +
        (misfit > detail::kMisfitFraction
             ? " because " + misfit_said + " — check " + causes
             : "; log more readings (the errors shrink as 1/√N), or " + std::string(detail::kTurnAdvice)));
  else if (misfit > detail::kMisfitFraction)
    out.summary.warnings.push_back(misfit_said + ", and the calibration may be biased by what it misses beyond its "
                                   "standard errors — check " + causes);
}

// How far the readings lie from a model's ellipsoid |h| = radius (times reading i's `relative` field magnitude, when
// given) in their own units, d = (|h| − radius)/|Aᵀĥ| (first order): the RMS of d — the misfit maximum likelihood
// minimises, which a shrinking A cannot lower — and the row farthest off.
struct Misfit {
  double rms = 0.0;
  Eigen::Index worst_row = 0;
  double worst = 0.0;
};

// d_k of kLanes readings (row k at p + k·stride) against their targets t_k: held in arrays, vectorised across them.
FLUXCAL_ALWAYS_INLINE void lane_misfits(const double* p, Eigen::Index stride, const double* A /* 3×3 row-major */,
                                        const double* o, const double* t, double* d) {
  double xs[detail::kLanes], ys[detail::kLanes], zs[detail::kLanes];
  for (int l = 0; l < detail::kLanes; ++l) {
    xs[l] = p[l * stride] - o[0];
    ys[l] = p[l * stride + 1] - o[1];
    zs[l] = p[l * stride + 2] - o[2];
  }
  for (int l = 0; l < detail::kLanes; ++l) {
    const double x = xs[l], y = ys[l], z = zs[l];
    const double hx = A[0] * x + A[1] * y + A[2] * z;
    const double hy = A[3] * x + A[4] * y + A[5] * z;
    const double hz = A[6] * x + A[7] * y + A[8] * z;
    const double gx = A[0] * hx + A[3] * hy + A[6] * hz;  // Aᵀh
    const double gy = A[1] * hx + A[4] * hy + A[7] * hz;
    const double gz = A[2] * hx + A[5] * hy + A[8] * hz;
    const double norm2 = hx * hx + hy * hy + hz * hz, slope2 = gx * gx + gy * gy + gz * gz;
    // (|h| − t)/(|Aᵀh|/|h|); a reading at the offset itself (|h| = 0) is infinitely far from any ellipsoid
    d[l] = slope2 > 0.0 ? (std::sqrt(norm2) - t[l]) * std::sqrt(norm2 / slope2) : kInf;
  }
}

FLUXCAL_CLONES
void accumulate_misfit(const double* p, Eigen::Index stride, Eigen::Index n, const double* A, const double* o,
                       double radius, const double* relative, double* sum2, double* worst, Eigen::Index* worst_row) {
  constexpr int L = detail::kLanes;
  double t[L], d[L];
  auto take = [&](Eigen::Index first, int count) {
    for (int l = 0; l < count; ++l) {
      *sum2 += d[l] * d[l];
      if (!(std::abs(d[l]) <= *worst)) {
        *worst = std::abs(d[l]);
        *worst_row = first + l;
      }
    }
  };
  Eigen::Index i = 0;
  for (; i + L <= n; i += L) {
    for (int l = 0; l < L; ++l) t[l] = relative ? radius * relative[i + l] : radius;
    lane_misfits(p + i * stride, stride, A, o, t, d);
    take(i, L);
  }
  if (i < n) {  // the last few: copied into a full block of lanes
    double rest[3 * L] = {};
    const int count = static_cast<int>(n - i);
    for (int l = 0; l < L; ++l) {
      for (int j = 0; j < 3; ++j) rest[3 * l + j] = l < count ? p[(i + l) * stride + j] : o[j] + 1.0;
      t[l] = l < count && relative ? radius * relative[i + l] : radius;
    }
    lane_misfits(rest, 3, A, o, t, d);
    take(i, count);
  }
}

Misfit reading_misfit(const SamplesRef& samples, const Calibration& cal, double radius,
                      const Eigen::VectorXd* relative) {
  const Eigen::Matrix<double, 3, 3, Eigen::RowMajor> A = cal.matrix;
  Misfit out;
  double sum2 = 0.0;
  accumulate_misfit(samples.data(), samples.outerStride(), samples.rows(), A.data(), cal.offset.data(), radius,
                    relative ? relative->data() : nullptr, &sum2, &out.worst, &out.worst_row);
  out.rms = std::sqrt(sum2 / static_cast<double>(samples.rows()));
  return out;
}

// Σd and Σd² of d_i = |h_i| − target(i) over the calibrated readings. A template, one loop per form of target: a
// test per reading had cost 9 % of the fit at 1e5 readings.
template <class Target>
std::pair<double, double> deviations(const SamplesRef& samples, const Calibration& cal, Target target) {
  const Eigen::Matrix3d& A = cal.matrix;
  const Eigen::Vector3d& o = cal.offset;
  double sd = 0.0, sd2 = 0.0;
  for (Eigen::Index i = 0; i < samples.rows(); ++i) {
    const double x = samples(i, 0) - o(0), y = samples(i, 1) - o(1), z = samples(i, 2) - o(2);
    const double hx = A(0, 0) * x + A(0, 1) * y + A(0, 2) * z;
    const double hy = A(1, 0) * x + A(1, 1) * y + A(1, 2) * z;
    const double hz = A(2, 0) * x + A(2, 1) * y + A(2, 2) * z;
    const double d = std::sqrt(hx * hx + hy * hy + hz * hz) - target(i);
    sd += d;
    sd2 += d * d;
  }
  return {sd, sd2};
}

// twostep with one field magnitude H for every reading, or reading i's H·(*relative)(i) when relative is not null
// (H then their mean).
TwoStepResult twostep_fit(const SamplesRef& samples, const TwoStepOptions& options, double H,
                          const Eigen::VectorXd* relative) {

  // One pass: the 35 moments of the normalised readings (shared with the ellipsoid fit). A NaN or Inf
  // poisons them; only then is the data searched for the row to name.
  const auto [centre, scale] = normalisation(samples);
  EllipsoidMoments mom(centre, scale);
  mom.add_rows(samples);
  if (!mom.finite()) {
    check_finite(samples, "samples");
    throw Error("samples: values too large, their fourth powers overflow");
  }
  const Mat10 S10 = mom.scatter();
  const DesignScatter scatters = design_scatter(S10, samples, centre, scale, relative);
  const Mat11& S = scatters.plain;
  const Mat11& Sw = scatters.weighted;
  const double n = S(9, 9);

  TwoStepResult out;
  Summary& sum = out.summary;
  sum.samples = mom.count();
  sum.coverage_ratio = detail::coverage_ratio(S10);
  if (sum.coverage_ratio < options.planar_ratio) {
    const std::string dominated = detail::dominated_spread(
        samples, sum.coverage_ratio, options.planar_ratio, "the first step of the two-step calibration is rank deficient");
    if (!dominated.empty()) throw Error(dominated);  // (a spike far out, not a flat turn: quadric.hpp)
    throw Error("samples: the readings lie nearly in one plane (thinnest/widest spread " + percent(sum.coverage_ratio) +
                "), so the first step of the two-step calibration is rank deficient — " + std::string(detail::kTurnAdvice) +
                ", or " + std::string(detail::kTwoDAdvice) + detail::hardly_turned(S10, centre, scale));
  }

  // First step (centred, tr E = 0): minimise Σ (aᵀ(d_k − d̄) − λ(ε_k − ε̄))² over the 9 non-constant quadric
  // coefficients a with a0 + a1 + a2 = 3 (tr N′ = tr(I + E) = 3) and, when the field's magnitude changes, its
  // coefficient λ (A&S's z_k = |B_k|² − |H_k|²: the change is not the quadric's shape); the constant absorbs
  // |b|², H² and μ. Its scale is then that of the mean (H_k/H)² = 1 + ε̄: N = N′ (1 + ε̄)/ρ², ρ² the quadric's
  // radius there.
  const Vec9 s9 = S.block<9, 1>(0, 9);
  const double mean_ratio2 = 1.0 + S(9, 10) / n;  // the mean (H_k/H)²
  const bool changing = scatters.changing;
  Eigen::Matrix<double, 10, 1> sums;
  sums << s9, S(10, 9);
  Eigen::Matrix<double, 10, 10> second;  // the scatter of [d_0 … d_8, ε]
  second.topLeftCorner<9, 9>() = S.topLeftCorner<9, 9>();
  second.topRightCorner<9, 1>() = S.block<9, 1>(0, 10);
  second.bottomLeftCorner<1, 9>() = S.block<1, 9>(10, 0);
  second(9, 9) = S(10, 10);
  const Eigen::Matrix<double, 10, 10> C = second - sums * sums.transpose() / n;
  Eigen::Matrix<double, 10, 9> G = Eigen::Matrix<double, 10, 9>::Zero();  // [a; −λ] = g0 + G [free (8), λ]
  G.block<8, 8>(1, 0).setIdentity();
  G(0, 0) = G(0, 1) = -1.0;
  G(9, 8) = -1.0;
  Eigen::Matrix<double, 10, 1> g0 = Eigen::Matrix<double, 10, 1>::Zero();
  g0(0) = 3.0;
  Vec9 free = Vec9::Zero();
  double first_condition = kInf;
  if (changing) {
    first_condition = solve_scaled<9>(Mat9(G.transpose() * C * G), Vec9(-G.transpose() * C * g0), free);
  } else {
    const Eigen::Matrix<double, 10, 8> Gs = G.leftCols<8>();
    Eigen::Matrix<double, 8, 1> shape_only;
    first_condition = solve_scaled<8>(Eigen::Matrix<double, 8, 8>(Gs.transpose() * C * Gs),
                                      Eigen::Matrix<double, 8, 1>(-Gs.transpose() * C * g0), shape_only);
    free.head<8>() = shape_only;
  }
  if (!(first_condition < kRankDeficient3D))
    throw Error("samples: the first step of the two-step calibration is rank deficient (condition number " +
                num(first_condition) +
                "); the readings do not determine offset and soft iron — " + std::string(detail::kTurnAdvice) +
                (changing ? "; or the field magnitudes follow the readings' directions (check that field_norms "
                            "belong to the readings: same order, same field units)"
                          : ""));
  const Vec9 a = (g0 + G * free).head<9>();
  const double k = -a.dot(s9) / n;
  Eigen::Matrix3d Np;
  Np << a(0), a(3), a(4), a(3), a(1), a(5), a(4), a(5), a(2);
  const detail::EllipsoidShape shape = [&] {
    try {
      return detail::ellipsoid_shape(Np, a.segment<3>(6), k, "first step's", sum.coverage_ratio,
                                     options.poor_coverage_ratio);
    } catch (const Error&) {  // a spike far out makes the quadric no ellipsoid too: name it (quadric.hpp)
      const std::string dominated = detail::dominated_spread(
          samples, sum.coverage_ratio,
          sum.coverage_ratio < options.poor_coverage_ratio ? options.poor_coverage_ratio : 0.0,
          "the first step's quadric is not an ellipsoid");
      if (!dominated.empty()) throw Error(dominated);
      throw;
    }
  }();
  Model3D m;
  m.q = shape.centre;
  const double rho2 = shape.rho2;
  m.N = Np * (mean_ratio2 / rho2);  // the scale from H: (u − q)ᵀ N (u − q) = 1 + ε_k ⇔ |h| = H_k
  const Model3D first = m;

  // Second step: Fisher scoring (Gauss–Newton) on Σ w_k R_k², all sums from the weighted scatter.
  double mu = 0.0;
  Eigen::VectorXd each_mu;  // each reading's noise mean, once the noise's bias is taken off (else μ for all)
  Mat9 F = Mat9::Zero();  // its Fisher matrix at the result
  sum.condition_number = first_condition;
  sum.converged = true;
  if (options.max_iterations > 0) {
    sum.converged = false;
    bool failed = false;
    double last_step = kInf;
    for (int it = 0; it < options.max_iterations; ++it) {
      mu = noise_mean(Sw, n, m, options.noise_sigma, scale);  // held fixed within the iteration
      const Vec11 p = quadric(m.q, m.N, mu);
      const Eigen::Matrix<double, 9, 11> T = jacobian_map(m.q, m.N);
      const Mat9 F = T * Sw * T.transpose();
      const Vec9 g = T * (Sw * p);
      Vec9 delta;
      if (!(solve_scaled<9>(F, Vec9(-g), delta) < kInf)) {
        failed = true;
        break;
      }
      last_step = delta.cwiseAbs().maxCoeff();
      // Below the tolerance, or with a predicted decrease δᵀFδ (of the cost pᵀS p, a sum of squares without ½)
      // below the rounding of that cost (the size of the terms it cancels), the cost cannot tell the step from
      // rounding: without the latter, the same readings in another memory layout (sums rounded otherwise) ran 19
      // iterations instead of 5 on steps of 1e-10.
      const double cost_rounding =
          p.cwiseAbs().dot(Sw.cwiseAbs() * p.cwiseAbs()) * std::numeric_limits<double>::epsilon();
      if (last_step <= options.tolerance || delta.dot(F * delta) <= cost_rounding) {
        m = moved(m, delta, 1.0);
        sum.iterations = it + 1;
        sum.converged = true;
        break;
      }
      const double cost = p.dot(Sw * p);
      double t = 1.0, trial = kInf;
      Model3D next;
      for (int ls = 0; ls < kLineSearchSteps; ++ls, t *= 0.5) {
        next = moved(m, delta, t);
        const Vec11 pn = quadric(next.q, next.N, mu);
        trial = pn.dot(Sw * pn);
        if (trial < cost) break;
      }
      if (!(trial < cost)) {  // no decrease along a descent direction: at the minimum to rounding
        sum.converged = last_step <= std::sqrt(options.tolerance);
        failed = !sum.converged;
        break;
      }
      m = next;
      sum.iterations = it + 1;
    }
    mu = noise_mean(Sw, n, m, options.noise_sigma, scale);
    F = [&] {
      const Eigen::Matrix<double, 9, 11> T = jacobian_map(m.q, m.N);
      return Mat9(T * Sw * T.transpose());
    }();
    {
      const Vec11 p = quadric(m.q, m.N, mu);
      sum.cost = p.dot(Sw * p) / n;
    }
    {
      // From the scoring's answer, the same scoring on the Sampson residuals (sampson_block): their weights' own
      // derivative in the Jacobian, two passes over the readings an iteration (a Jacobian's, a line search's). When
      // the first part ran off (on a narrow band of tilts at σ 100–200 nT a blind check's did, and the readings were
      // refused), from the first step.
      if (!sum.converged) m = first;
      sum.converged = failed = false;
      // μ starts as the scoring's, ¾ of the weighted variance, carried to this fit's −¼ of it (no pass for it)
      mu = options.noise_sigma < 0.0 ? -mu / 3.0 : sampson_noise_mean(SampsonPass{}, n, m, options.noise_sigma, scale);
      SampsonPass pass = sampson_pass(samples, centre, scale, relative, m, mu, true);
      for (int it = 0; it < options.max_iterations; ++it) {
        Vec9 delta;
        if (!(solve_scaled<9>(pass.F, Vec9(-pass.g), delta) < kInf)) {
          failed = true;
          break;
        }
        last_step = delta.cwiseAbs().maxCoeff();
        ++sum.iterations;
        if (last_step <= options.tolerance || delta.dot(pass.F * delta) <= pass.rounding) {
          m = moved(m, delta, 1.0);  // (F and the cost of the pass before it: the step is below the tolerance)
          sum.converged = true;
          break;
        }
        double t = 1.0;
        SampsonPass trial;
        Model3D next;
        for (int ls = 0; ls < kLineSearchSteps; ++ls, t *= 0.5) {
          next = moved(m, delta, t);
          trial = sampson_pass(samples, centre, scale, relative, next, mu, false);
          if (trial.cost < pass.cost) break;
        }
        if (!(trial.cost < pass.cost)) {  // no decrease along a descent direction: at the minimum to rounding
          sum.converged = last_step <= std::sqrt(options.tolerance);
          failed = !sum.converged;
          break;
        }
        m = next;
        mu = sampson_noise_mean(trial, n, m, options.noise_sigma, scale);  // (the trial's sums are m's)
        pass = sampson_pass(samples, centre, scale, relative, m, mu, true);
      }
      // The noise's O(σ²) bias, as refine's noise_bias_correction takes it off: the one noise mean μ′ left the
      // matrix of an anisotropic sensor biased (gains 0.7–1.3 at σ 5 %, 2000 readings: its entries 0.4–1.2 standard
      // errors off, over 400 fits). On every converged fit, each reading's own μ_k (reading_noise_means) and the fit
      // solved again, as refine takes its per-reading targets whatever the coverage; then the Jacobian's move
      // F⁻¹ 2σ² Σ ∂J_k/∂n̂ (E[J_k r_k] = 2σ² ∂J_k/∂n̂: r_k ≈ 2 n̂·ε), only where every parameter's standard error is
      // below kBiasMoveTolerance × determined_tolerance of its scale (all_determined at the re-solved fit): F⁻¹ along
      // an undetermined parameter turns noise into the shift. Both had been gated at determined_tolerance itself, so
      // partial coverage kept μ′ (a review: a hemisphere of directions at σ 3 %, 1000 readings, z's offset known to
      // 1.7 % of the field — its matrix entries up to 0.71 of their spread off over 300 fits, t 12.3; μ_k alone left
      // 0.45, both 0.07, t 1.3). A correction that leaves the model non-finite or not positive definite is not taken.
      const double spare = n - 9.0;
      if (sum.converged && options.noise_sigma != 0.0 && spare > 0.0) {
        const double var_r = options.noise_sigma > 0.0
                                 ? 4.0 * (options.noise_sigma / scale) * (options.noise_sigma / scale)
                                 : pass.cost / spare;
        const Model3D uncorrected = m;
        const SampsonPass uncorrected_pass = pass;
        Within within;
        each_mu = reading_noise_means(samples, centre, scale, m, var_r / 4.0, within);
        // the targets move by O(σ²): Gauss–Newton from the solution, with the scoring's line search, converges at once
        // where the readings determine the fit, in more steps along a poorly determined direction (a 60° cap of 300
        // readings: 4 steps had left it 2e-4 short); a step below 1e-5 of a standard error (δᵀFδ ≤ 1e-10 σ_r²) is not
        // taken
        pass = sampson_pass(samples, centre, scale, relative, m, 0.0, true, &each_mu);
        for (int step = 0; step < std::max(options.max_iterations, 4); ++step) {
          Vec9 delta;
          if (!(solve_scaled<9>(pass.F, Vec9(-pass.g), delta) < kInf) ||
              delta.dot(pass.F * delta) <= 1e-10 * pass.cost / spare)
            break;
          double t = 1.0;
          bool lower = false;
          Model3D next;
          for (int ls = 0; ls < kLineSearchSteps && !lower; ++ls, t *= 0.5) {
            next = moved(m, delta, t);
            lower = sampson_pass(samples, centre, scale, relative, next, 0.0, false, &each_mu).cost < pass.cost;
          }
          if (!lower) break;  // (at the minimum to rounding)
          m = next;
          ++sum.iterations;
          pass = sampson_pass(samples, centre, scale, relative, m, 0.0, true, &each_mu);
        }
        if (all_determined(pass.F, var_r, m, kBiasMoveTolerance * options.determined_tolerance)) {
          Vec9 shift;
          if (solve_scaled<9>(pass.F, normal_derivative_3d(samples, centre, scale, relative, m, each_mu, within),
                              shift) < kInf) {
            m = moved(m, shift, 0.5 * var_r);  // 2σ² = σ_r²/2
            pass = sampson_pass(samples, centre, scale, relative, m, 0.0, true, &each_mu);
          }
        }
        if (!(m.q.allFinite() && m.N.allFinite() && std::isfinite(pass.cost) &&
              Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(m.N, Eigen::EigenvaluesOnly).eigenvalues()(0) > 0.0)) {
          m = uncorrected;
          pass = uncorrected_pass;
          each_mu.resize(0);
        }
      }
      F = pass.F;
      sum.cost = pass.cost * scale * scale / (4.0 * n);  // r_k = 2 × the distance in u = (m − centre)/scale
    }
    Vec9 unused;
    sum.condition_number = solve_scaled<9>(F, Vec9::Zero(), unused);
    if (!sum.converged)
      sum.warnings.push_back(std::string("second step did not converge ") +
                             (failed ? "(no descent step found" : "(iteration limit") + " after " +
                             std::to_string(sum.iterations) + " iterations, last step " + num(last_step) +
                             "); the result is the last iterate — check the readings for outliers");
  } else {
    const Vec11 p = quadric(m.q, m.N, mu);
    sum.cost = p.dot(Sw * p) / n;
  }

  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(m.N);
  if (!(eig.eigenvalues()(0) > 0.0)) {
    std::ostringstream msg;
    msg << "samples: the two-step solution is not positive definite (eigenvalues of A² ∝ "
        << eig.eigenvalues().transpose()
        << "); the readings do not determine a calibration — check for mixed recordings or saturation";
    throw Error(msg.str());
  }
  Calibration& cal = out.calibration;
  cal = calibration_of(m, centre, scale, H);
  cal.units = options.units;
  cal.model = "twostep";

  // Statistics of |h| from a pass over the samples, and direction coverage.
  const auto [sd, sd2] = relative ? deviations(samples, cal, [&](Eigen::Index i) { return H * (*relative)(i); })
                                  : deviations(samples, cal, [H](Eigen::Index) { return H; });
  const double mean_d = sd / n;
  sum.norm_mean = H + mean_d;
  sum.norm_std_over_mean = std::sqrt(std::max(0.0, sd2 / n - mean_d * mean_d)) / sum.norm_mean;
  sum.residual_rms = std::sqrt(sd2 / n);
  sum.exact_statistics = true;
  detail::require_finite_fit(detail::finite_fit(sum) && cal.matrix.allFinite() && cal.offset.allFinite(), "samples",
                             samples, "the two-step calibration");
  describe_coverage(sum, samples, cal, options.coverage_rows);
  if (options.max_iterations > 0 && options.standard_errors)
    parameter_covariance(out, samples, m, mu, F, centre, scale, H, relative, options,
                         each_mu.size() ? &each_mu : nullptr);
  // The readings' misfit to the first step's (unweighted) ellipsoid: where a reading lies that pulls the weighted
  // fit its way, and the yardstick of a second step that ran away.
  const Calibration start = calibration_of(first, centre, scale, H);
  const Misfit before = relative || !sum.converged ? reading_misfit(samples, start, H, relative) : Misfit{};
  if (relative && before.worst > 10.0 * before.rms)  // weighted by 1/H_k², one far off a low H_k weighs heavily
    sum.warnings.push_back("reading " + std::to_string(before.worst_row) + " lies " + num(before.worst) +
                           " off its field magnitude's ellipsoid (" + num(before.worst / before.rms) +
                           " times the RMS, in the readings' units): a glitch in field_norms or an outlier, which "
                           "the weights 1/H_k² let weigh on the fit; fluxcal.calibrate leaves such readings out");
  if (!sum.converged) {
    // On a cap the squared-magnitude objective keeps falling towards an infinite offset and a vanishing A (the
    // noise shrinks with A), so the iterate leaves the readings: their misfit to its ellipsoid grows. So it does
    // when a few readings lie far off (an outlier at twice the field's distance ran a full sphere away).
    // (the iterate's own radius: the noise mean μ it fitted puts |h|² at H² + μ, which is no runaway)
    const Misfit after = reading_misfit(samples, cal, H * std::sqrt(1.0 + mu), relative);
    if (!(after.rms <= options.runaway_misfit * before.rms)) {
      throw Error("samples: the second step of the two-step calibration ran away from the readings (not converged "
                  "after " + std::to_string(sum.iterations) + " iterations; their misfit to its ellipsoid, in the "
                  "readings' units, grew from " + num(before.rms) + " to " + num(after.rms) + "). Either the "
                  "readings cover too little of the sphere — the first step sees " +
                  percent(direction_coverage(samples, start, options.coverage_rows)) + " of the field directions, "
                  "where " + num(static_cast<double>(samples.rows())) + " readings spread evenly would fill " +
                  percent(detail::reachable_coverage(samples.rows(), options.coverage_rows)) +
                  "; on a cap the objective falls towards an infinite offset: turn the sensor through more "
                  "orientations (tumble it) — or a few readings lie far off the ellipsoid (row " +
                  std::to_string(before.worst_row) + " is " + num(before.worst) + " from the first step's, " +
                  num(before.worst / before.rms) + " times the misfit): drop such outliers. Calibrate's maximum "
                  "likelihood says what the readings determine; max_iterations = 0 gives the first step alone");
    }
  }
  if (sum.coverage_ratio < options.poor_coverage_ratio)
    sum.warnings.push_back("poor coverage: thinnest/widest spread of the readings is " + percent(sum.coverage_ratio) +
                           "; the offset and matrix along the thin direction are poorly determined");
  const std::string poor = detail::direction_coverage_warning(sum.direction_coverage, samples.rows(),
                                                              options.coverage_rows, options.poor_direction_coverage);
  if (!poor.empty()) sum.warnings.push_back(poor);
  {  // a field_norm far from the readings' own radius usually means mismatched units
    const double gain = std::cbrt(cal.matrix.determinant());
    const std::string said = detail::units_mismatch("field_norm " + num(H), gain, H / gain);
    if (!said.empty()) sum.warnings.push_back(said);
  }


  std::ostringstream msg;
  const std::string u = cal.units.empty() ? "" : " " + cal.units;
  msg << "two-step fit: " << sum.samples << " samples, "
      << (options.max_iterations == 0
              ? std::string("first step only")
              : (sum.converged ? "second step converged in " + std::to_string(sum.iterations) + " iterations"
                               : std::string("second step not converged")))
      << ", |h| std/mean " << percent(sum.norm_std_over_mean) << ", residual RMS " << num(sum.residual_rms) << u
      << ", condition number " << num(sum.condition_number);
  if (!sum.warnings.empty()) msg << " (" << sum.warnings.size() << " warning(s))";
  sum.message = msg.str();
  return out;
}

}  // namespace

TwoStepResult twostep(const SamplesRef& samples, const TwoStepOptions& options) {
  samples.require_width("samples");
  const double H = options.field_norm;
  if (!(H > 0.0) || !std::isfinite(H))
    throw Error("field_norm: must be a positive finite magnitude (the known |H|, e.g. from IGRF), got " + num(H));
  check(options);
  if (samples.rows() < 9) check_samples(samples, "samples", 9, "the 9-parameter two-step calibration");
  return twostep_fit(samples, options, H, nullptr);
}

TwoStepResult twostep(const SamplesRef& samples, const SeriesRef& field_norms, const TwoStepOptions& options) {
  samples.require_width("samples");
  check(options);
  if (samples.rows() < 9) check_samples(samples, "samples", 9, "the 9-parameter two-step calibration");
  detail::check_field_norms(field_norms, samples.rows());
  const double H = field_norms.mean();
  const Eigen::VectorXd relative = field_norms / H;
  return twostep_fit(samples, options, H, &relative);
}

}  // namespace fluxcal
