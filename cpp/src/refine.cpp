#include "fluxcal/refine.hpp"

#include "fluxcal/coverage.hpp"
#include "fluxcal/timeseries.hpp"
#include "checks.hpp"
#include "clones.hpp"
#include "linalg.hpp"
#include "long_run.hpp"

#include <ceres/ceres.h>

#include <algorithm>
#include <vector>
#include <cmath>
#include <limits>
#include <memory>
#include <sstream>
#include <utility>

namespace fluxcal {
namespace {

constexpr const char* kMagnitudeNames[] = {"b0", "b1", "b2", "a00", "a01", "a02", "a11", "a12", "a22"};
constexpr const char* kVectorNames[] = {"b0",  "b1",  "b2",  "w00", "w01", "w02",
                                        "w10", "w11", "w12", "w20", "w21", "w22"};

// Sampson residual r = (|h| − H)|h| / |g|, h = A (m − b), g = A h (A symmetric): the first-order
// distance of m to the ellipsoid |A (m − b)| = H. With s = |h|, q = |g|:
//   dr = ((2s − H)/q) ds − (r/q) dq,   ds = ĥᵀ dh,   dq = ĝᵀ dg,
//   d/db: dh = −A db, dg = −A² db;   d/da_kl: dh = E_kl d, dg = E_kl h + A E_kl d,
// with uᵀ E_kl v = u_k v_l + u_l v_k (k ≠ l) or u_k v_k, for the symmetric basis E_kl.
//
// The residual (out[9 · stride]) and its derivatives over [b, a00 a01 a02 a11 a12 a22] (out[c · stride],
// c = 0 … 8) at d = m − b, for A's six entries `a`. Written once for the single reading (stride 1) and for
// sampson_rows' lanes (stride kLanes), where GCC vectorises it across readings once inlined.
FLUXCAL_ALWAYS_INLINE void sampson_at(double dx, double dy, double dz, const double* a, double H, double* out,
                                      int stride) {
  const double a00 = a[0], a01 = a[1], a02 = a[2], a11 = a[3], a12 = a[4], a22 = a[5];
  const double hx = a00 * dx + a01 * dy + a02 * dz, hy = a01 * dx + a11 * dy + a12 * dz,
               hz = a02 * dx + a12 * dy + a22 * dz;  // h = A d
  const double gx = a00 * hx + a01 * hy + a02 * hz, gy = a01 * hx + a11 * hy + a12 * hz,
               gz = a02 * hx + a12 * hy + a22 * hz;  // g = A h
  // two divisions, not six: a refine evaluates this ~10 times a reading
  const double sn = std::sqrt(hx * hx + hy * hy + hz * hz), inv_q = 1.0 / std::sqrt(gx * gx + gy * gy + gz * gz);
  const double res = (sn - H) * sn * inv_q, inv_sn = 1.0 / sn;
  const double uhx = hx * inv_sn, uhy = hy * inv_sn, uhz = hz * inv_sn;  // ĥ
  const double ugx = gx * inv_q, ugy = gy * inv_q, ugz = gz * inv_q;     // ĝ
  const double cs = (2.0 * sn - H) * inv_q, cq = res * inv_q;
  const double vx = a00 * ugx + a01 * ugy + a02 * ugz, vy = a01 * ugx + a11 * ugy + a12 * ugz,
               vz = a02 * ugx + a12 * ugy + a22 * ugz;  // A ĝ
  const double wx = a00 * vx + a01 * vy + a02 * vz, wy = a01 * vx + a11 * vy + a12 * vz,
               wz = a02 * vx + a12 * vy + a22 * vz;  // A² ĝ
  // d/db: ds = −(A ĥ)ᵀ db = −(g/|h|)ᵀ db, dq = −(A² ĝ)ᵀ db
  const double cb = cs * inv_sn;
  out[0] = -cb * gx + cq * wx, out[stride] = -cb * gy + cq * wy, out[2 * stride] = -cb * gz + cq * wz;
  // d/da_kl = cs ds − cq dq with ds = ĥᵀ E_kl d, dq = ĝᵀ E_kl h + (A ĝ)ᵀ E_kl d
  out[3 * stride] = cs * (uhx * dx) - cq * (ugx * hx + vx * dx);
  out[4 * stride] = cs * (uhx * dy + uhy * dx) - cq * (ugx * hy + ugy * hx + vx * dy + vy * dx);
  out[5 * stride] = cs * (uhx * dz + uhz * dx) - cq * (ugx * hz + ugz * hx + vx * dz + vz * dx);
  out[6 * stride] = cs * (uhy * dy) - cq * (ugy * hy + vy * dy);
  out[7 * stride] = cs * (uhy * dz + uhz * dy) - cq * (ugy * hz + ugz * hy + vy * dz + vz * dy);
  out[8 * stride] = cs * (uhz * dz) - cq * (ugz * hz + vz * dz);
  out[9 * stride] = res;
}

double sampson(const double* m, const double* th, double H, double* jac /* 9 or nullptr */) {
  double out[10];
  sampson_at(m[0] - th[0], m[1] - th[1], m[2] - th[2], th + 3, H, out, 1);
  if (jac) std::copy(out, out + 9, jac);
  return out[9];
}

// `sampson` for n readings (rows `stride` apart), the residuals into r and, when jac is not null, the
// Jacobian rows into jac (9 a reading, contiguous); each reading's |h| = H, or Hs[i] when Hs is not null (a
// field that changes while the sensor turns). A block of kLanes readings goes through small arrays so that
// the compiler vectorises across readings (clones.hpp): the scalar loop was a third of refine.
FLUXCAL_CLONES
void sampson_rows(const double* m, Eigen::Index stride, Eigen::Index n, const double* th, double H, double* r,
                  double* jac, const double* Hs = nullptr) {
  using detail::kLanes;
  double target[kLanes];
  std::fill(target, target + kLanes, H);
  Eigen::Index i = 0;
  for (; i + kLanes <= n; i += kLanes) {
    double x[kLanes], y[kLanes], z[kLanes], out[10][kLanes];
    for (int l = 0; l < kLanes; ++l) {
      const double* mi = m + stride * (i + l);
      x[l] = mi[0] - th[0], y[l] = mi[1] - th[1], z[l] = mi[2] - th[2];
    }
    if (Hs) std::copy(Hs + i, Hs + i + kLanes, target);
    for (int l = 0; l < kLanes; ++l) sampson_at(x[l], y[l], z[l], th + 3, target[l], &out[0][l], kLanes);
    for (int l = 0; l < kLanes; ++l) r[i + l] = out[9][l];
    if (jac)
      for (int l = 0; l < kLanes; ++l)
        for (int c = 0; c < 9; ++c) jac[9 * (i + l) + c] = out[c][l];
  }
  for (; i < n; ++i) r[i] = sampson(m + stride * i, th, Hs ? Hs[i] : H, jac ? jac + 9 * i : nullptr);
}

// Σ_k ∂J_k/∂n_k: each reading's Jacobian row (∂r_k/∂θ) differentiated along its normal n_k = A h/|A h| in the readings,
// by central differences (a step of 1e-4 of the readings' scale H/‖A‖), a chunk at a time.
Eigen::Matrix<double, 9, 1> normal_derivative_of_jacobian(const SamplesRef& samples, const Eigen::Matrix<double, 9, 1>& th,
                                                          double H, const double* Hs) {
  Eigen::Matrix3d A;
  A << th(3), th(4), th(5), th(4), th(6), th(7), th(5), th(7), th(8);
  const double step = 1e-4 * H * std::sqrt(3.0) / A.norm();
  constexpr Eigen::Index kChunk = 512;
  Samples plus(kChunk, 3), minus(kChunk, 3);
  Eigen::Matrix<double, 9, Eigen::Dynamic> jp(9, kChunk), jm(9, kChunk);
  Eigen::VectorXd r(kChunk);
  Eigen::Matrix<double, 9, 1> sum = Eigen::Matrix<double, 9, 1>::Zero();
  for (Eigen::Index i0 = 0; i0 < samples.rows(); i0 += kChunk) {
    const Eigen::Index len = std::min(kChunk, samples.rows() - i0);
    for (Eigen::Index j = 0; j < len; ++j) {
      const Eigen::Vector3d m = samples.row(i0 + j).transpose();
      Eigen::Vector3d n = A * (A * (m - th.head<3>()));
      n = n.norm() > 0.0 ? Eigen::Vector3d(n.normalized() * step) : Eigen::Vector3d::Zero();
      plus.row(j) = (m + n).transpose();
      minus.row(j) = (m - n).transpose();
    }
    sampson_rows(plus.data(), 3, len, th.data(), H, r.data(), jp.data(), Hs ? Hs + i0 : nullptr);
    sampson_rows(minus.data(), 3, len, th.data(), H, r.data(), jm.data(), Hs ? Hs + i0 : nullptr);
    sum += (jp.leftCols(len) - jm.leftCols(len)).rowwise().sum();
  }
  return sum / (2.0 * step);
}

// The readings' mean distance from `offset`: the scale of the offsets' standard errors.
double mean_radius(const SamplesRef& samples, const Eigen::Vector3d& offset) {
  double radius = 0.0;
  for (Eigen::Index i = 0; i < samples.rows(); ++i) radius += (samples.row(i).transpose() - offset).norm();
  return radius / static_cast<double>(samples.rows());
}

// One Sampson residual (a robust loss acts per residual block).
class MagnitudeOne : public ceres::SizedCostFunction<1, 9> {
 public:
  MagnitudeOne(const Eigen::Vector3d& m, double H) : m_(m), H_(H) {}
  bool Evaluate(double const* const* p, double* r, double** jac) const override {
    r[0] = sampson(m_.data(), p[0], H_, jac ? jac[0] : nullptr);
    return true;
  }

 private:
  Eigen::Vector3d m_;
  double H_;
};

// A magnitude-model shape as a linear map θ = P φ from its free parameters φ to the nine
// θ = [b, a00 a01 a02 a11 a12 a22]: what the shape holds at zero (off-diagonals) or equal (a sphere's
// diagonal) never moves.
struct ShapeMap {
  Eigen::MatrixXd P;               // 9 × k, orthogonal columns
  Eigen::MatrixXd pinv;            // k × 9: φ = P⁺ θ
  std::vector<std::string> names;  // of φ
};

ShapeMap shape_map(Shape shape) {
  // each free parameter: its name and the θ entries it sets
  std::vector<std::pair<const char*, std::vector<int>>> free = {{"b0", {0}}, {"b1", {1}}, {"b2", {2}}};
  if (shape == Shape::sphere) {
    free.push_back({"a", {3, 6, 8}});
  } else if (shape == Shape::diagonal) {
    free.insert(free.end(), {{"a00", {3}}, {"a11", {6}}, {"a22", {8}}});
  } else {
    for (int c = 0; c < 6; ++c) free.push_back({kMagnitudeNames[3 + c], {3 + c}});
  }
  ShapeMap map;
  map.P = Eigen::MatrixXd::Zero(9, static_cast<Eigen::Index>(free.size()));
  for (std::size_t j = 0; j < free.size(); ++j) {
    map.names.emplace_back(free[j].first);
    for (int row : free[j].second) map.P(row, static_cast<Eigen::Index>(j)) = 1.0;
  }
  map.pinv = detail::lu_inverse(map.P.transpose() * map.P) * map.P.transpose();
  return map;
}

// Ceres moves θ only along the shape's columns: θ ⊞ δ = θ + P δ.
class ShapeManifold : public ceres::Manifold {
 public:
  explicit ShapeManifold(const ShapeMap& map) : P_(map.P), pinv_(map.pinv) {}
  int AmbientSize() const override { return static_cast<int>(P_.rows()); }
  int TangentSize() const override { return static_cast<int>(P_.cols()); }
  bool Plus(const double* x, const double* delta, double* x_plus_delta) const override {
    Eigen::Map<Eigen::VectorXd>(x_plus_delta, P_.rows()) =
        Eigen::Map<const Eigen::VectorXd>(x, P_.rows()) + P_ * Eigen::Map<const Eigen::VectorXd>(delta, P_.cols());
    return true;
  }
  bool PlusJacobian(const double*, double* jacobian) const override {
    RowMajor(jacobian, P_.rows(), P_.cols()) = P_;
    return true;
  }
  bool Minus(const double* y, const double* x, double* y_minus_x) const override {
    Eigen::Map<Eigen::VectorXd>(y_minus_x, P_.cols()) =
        pinv_ * (Eigen::Map<const Eigen::VectorXd>(y, P_.rows()) - Eigen::Map<const Eigen::VectorXd>(x, P_.rows()));
    return true;
  }
  bool MinusJacobian(const double*, double* jacobian) const override {
    RowMajor(jacobian, P_.cols(), P_.rows()) = pinv_;
    return true;
  }

 private:
  using RowMajor = Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>;
  Eigen::MatrixXd P_, pinv_;
};

// The vector model's residual r = m − W ref − b (θ = [b, W row-major]) and, when `jac` is given,
// its 3×12 Jacobian (row-major), which does not depend on θ: the model is linear.
void vector_residual(const double* m, const double* ref, const double* th, double* r, double* jac) {
  for (int a = 0; a < 3; ++a) {
    r[a] = m[a] - th[a] - th[3 + 3 * a] * ref[0] - th[4 + 3 * a] * ref[1] - th[5 + 3 * a] * ref[2];
    if (!jac) continue;
    double* row = jac + 12 * a;
    std::fill(row, row + 12, 0.0);
    row[a] = -1.0;
    for (int k = 0; k < 3; ++k) row[3 + 3 * a + k] = -ref[k];
  }
}

// One reading's vector residual (a robust loss acts per residual block).
class VectorOne : public ceres::SizedCostFunction<3, 12> {
 public:
  VectorOne(const Eigen::Vector3d& m, const Eigen::Vector3d& ref) : m_(m), ref_(ref) {}
  bool Evaluate(double const* const* p, double* r, double** jac) const override {
    vector_residual(m_.data(), ref_.data(), p[0], r, jac ? jac[0] : nullptr);
    return true;
  }

 private:
  Eigen::Vector3d m_, ref_;
};

Eigen::Matrix3d symmetric_part(const Eigen::Matrix3d& A) {
  // Polar factor sqrt(AᵀA): the symmetric matrix with the same |A x| for every x.
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(A.transpose() * A);
  return eig.eigenvectors() * eig.eigenvalues().cwiseMax(0.0).cwiseSqrt().asDiagonal() *
         eig.eigenvectors().transpose();
}

using detail::percent;

double robust_sigma(std::vector<double> abs_residuals) {
  if (abs_residuals.empty()) return 0.0;
  auto mid = abs_residuals.begin() + static_cast<std::ptrdiff_t>(abs_residuals.size() / 2);
  std::nth_element(abs_residuals.begin(), mid, abs_residuals.end());
  return 1.4826 * *mid;
}

ceres::LossFunction* make_loss(const RefineOptions& opt, double sigma_start) {
  if (opt.loss == Loss::none) return nullptr;
  const double scale = opt.loss_scale > 0.0 ? opt.loss_scale : 3.0 * sigma_start;
  if (!(scale > 0.0)) throw Error("loss_scale: the robust loss needs a positive scale (the start fits exactly?)");
  if (opt.loss == Loss::huber) return new ceres::HuberLoss(scale);
  return new ceres::CauchyLoss(scale);
}

void check_inputs(const SamplesRef& samples, Eigen::Index min_rows, const std::string& purpose) {
  check_samples(samples, "samples", min_rows, purpose);
  detail::require_squares_representable(samples, "samples", purpose);  // "… overflow a 12-parameter vector calibration"
}

// Per reading, in time order: the plain residuals (N×1 magnitude, N×3 vector) and the scores
// g_i = Σ_a J_ia r_ia (N×p), what the Newey–West covariance needs.
struct Scores {
  Eigen::MatrixXd residuals;
  Eigen::MatrixXd scores;
};

// With a robust loss the least-squares variance Σr²/(n − p) counts the outliers that the loss set
// aside (on 10 % spikes the errors came out 3–5× the Monte-Carlo spread). Huber (1981, §7.6), as in
// statsmodels' RLM (cov "H1"): σ² = K² [Σψ²/(n − p)] / mean(ψ')², ψ = ρ'(s)·r, K = 1 + (p/n) var(ψ')/mean(ψ')².
// A reading's block of k residuals shares one loss of s = |r|²: its ψ' is the mean eigenvalue of
// ρ' I + 2ρ'' r rᵀ, i.e. ρ' + 2sρ''/k. The scores become ψ-weighted and are divided by mean(ψ'), so
// that the Newey–West sandwich is A⁻¹ S A⁻¹ with A = mean(ψ') F. Returns the variance, or the plain one
// (with a warning) when mean(ψ') is not positive (a redescending loss that rejects most readings).
double robust_variance(const ceres::LossFunction& loss, Scores& sc, int p, double plain_sigma2,
                       std::vector<std::string>& warnings) {
  const Eigen::Index n = sc.residuals.rows(), k = sc.residuals.cols();
  double psi_sq = 0.0, d_sum = 0.0, d_sq = 0.0;
  Eigen::VectorXd weight(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    const double s = sc.residuals.row(i).squaredNorm();
    double rho[3];
    loss.Evaluate(s, rho);
    const double d = rho[1] + 2.0 * s * rho[2] / static_cast<double>(k);
    psi_sq += rho[1] * rho[1] * s;
    d_sum += d;
    d_sq += d * d;
    weight(i) = rho[1];
  }
  const double nk = static_cast<double>(n * k), mean = d_sum / static_cast<double>(n);
  if (!(mean > 0.0) || !(nk > p)) {
    warnings.push_back("robust loss: the loss leaves no curvature on average (it rejects most readings); "
                       "standard errors are those of least squares");
    return plain_sigma2;
  }
  const double var = std::max(0.0, d_sq / static_cast<double>(n) - mean * mean);
  const double K = 1.0 + (static_cast<double>(p) / nk) * var / (mean * mean);
  sc.scores = (weight / mean).asDiagonal() * sc.scores;
  return K * K * psi_sq / (nk - p) / (mean * mean);
}

// The residuals' test for correlation in time and, as the options say, the Newey–West sandwich (long_run.hpp).
void serial_correlation(RefineResult& out, const Eigen::MatrixXd& Finv, bool singular, const Scores& sc,
                        const RefineOptions& opt) {
  const std::string warning =
      detail::correct_for_serial_correlation(out.covariance, out.serial_correlation, sc.residuals, sc.scores, Finv,
                                             singular, opt.serial_correlation, opt.serial_correlation_alpha);
  if (!warning.empty()) out.summary.warnings.push_back(warning);
}

// Covariance, standard errors and identifiability from the information matrix F = JᵀJ (and, with
// `scores`, corrected for correlation between readings). Whether the data determine a parameter is a
// property of F (the coverage): judged on the independent-readings errors, before any correction.
// `vector_model`: the misfit's advice names the reference vectors (a magnitude fit has none to check).
// `axis_noise`: the vector model's noise covariance between the three axes (the rows of its residuals), which
// replaces σ² I: each axis has its own σ and the axes may share noise (one ADC, one reference error).
void finish_statistics(RefineResult& out, const Eigen::MatrixXd& F, double sigma2, const Eigen::VectorXd& scales,
                       const RefineOptions& opt, bool vector_model, const Scores* scores = nullptr,
                       const Eigen::Matrix3d* axis_noise = nullptr) {
  const Eigen::Index p = F.rows();
  const detail::ScaledInverse Finv = detail::scaled_inverse(F);
  out.fisher_condition = Finv.condition;
  out.covariance = sigma2 * Finv.inverse;
  if (axis_noise) {
    // m = W r + b is one regression per axis on the same design X = [r 1]: cov = Σ ⊗ (XᵀX)⁻¹ (a multivariate
    // regression's). F⁻¹ holds (XᵀX)⁻¹ once per axis (vector_information's layout: b_j at j, W_jk at 3 + 3j + k);
    // with σ pooled over the axes, noise of σ 50, 50, 300 had the x and y errors 3.5× too wide and z's 0.6×.
    const auto at = [](int axis, int a) { return a == 0 ? axis : 3 + 3 * axis + (a - 1); };
    for (int j = 0; j < 3; ++j)
      for (int l = 0; l < 3; ++l)
        for (int a = 0; a < 4; ++a)
          for (int c = 0; c < 4; ++c)
            out.covariance(at(j, a), at(l, c)) = (*axis_noise)(j, l) * Finv.inverse(at(0, a), at(0, c));
  }
  const Eigen::VectorXd independent = out.covariance.diagonal().cwiseMax(0.0).cwiseSqrt();
  out.determined.assign(static_cast<std::size_t>(p), true);
  out.identifiable = true;  // until a parameter is not determined
  std::ostringstream undetermined;
  for (Eigen::Index k = 0; k < p; ++k) {
    const bool ok = std::isfinite(independent(k)) && independent(k) < opt.determined_tolerance * scales(k);
    out.determined[static_cast<std::size_t>(k)] = ok;
    if (!ok) undetermined << (out.identifiable ? "" : ", ") << out.parameter_names[static_cast<std::size_t>(k)];
    if (!ok) out.identifiable = false;
  }
  if (scores) serial_correlation(out, Finv.inverse, Finv.singular, *scores, opt);
  out.standard_errors = out.covariance.diagonal().cwiseMax(0.0).cwiseSqrt();
  // Residuals of several % of the field are no sensor's noise: then the standard errors are large because
  // the readings do not fit the model, and "rotate more" would send the user the wrong way.
  const double misfit = std::sqrt(sigma2) / scales(0);
  if (!out.identifiable && misfit > detail::kMisfitFraction)
    out.summary.warnings.push_back(
        "not identifiable: the data do not determine " + undetermined.str() + " (standard error above " +
        percent(opt.determined_tolerance) + " of its scale) because the residuals are " + percent(misfit) +
        " of the field, far above a sensor's noise: the readings do not fit the model — check " +
        (vector_model ? "the reference vectors' attitude convention and time alignment, outliers or a disturbance"
                      : detail::kMagnitudeMisfitCauses) +
        ", and that the start is in the readings' units");
  else if (misfit > detail::kMisfitFraction)  // determined, yet not by a model that fits: the answer may be biased
    out.summary.warnings.push_back(
        "the residuals are " + percent(misfit) + " of the field, far above a sensor's noise: the readings do not "
        "fit the model, and the calibration may be biased by what it misses beyond its standard errors — check " +
        (vector_model ? "the reference vectors' attitude convention and time alignment, outliers or a disturbance"
                      : "for outliers, a disturbance or an offset that moved within the log (a magnet, a motor or "
                        "a current near the sensor; two sessions in one file: fluxcal diagnose looks for the cause)"));
  else if (!out.identifiable)
    out.summary.warnings.push_back(
        "not identifiable: the data do not determine " + undetermined.str() +
        " (standard error above " + percent(opt.determined_tolerance) +
        " of its scale); rotate the sensor through more orientations, give a reference vector, "
        "or " + std::string(detail::kTwoDAdvice));
}

// Thinnest/widest standard deviation of a set of 3-vectors (Summary::coverage_ratio; 0 on a plane or a line).
double spread_ratio(const SamplesRef& v) {
  const Eigen::RowVector3d mean = v.colwise().mean();
  const Eigen::Matrix3d cov = (v.rowwise() - mean).transpose() * (v.rowwise() - mean) / static_cast<double>(v.rows());
  const Eigen::Vector3d ev = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(cov, Eigen::EigenvaluesOnly).eigenvalues();
  return ev(2) > 0.0 ? std::sqrt(std::max(ev(0), 0.0) / ev(2)) : 0.0;
}

// Fills the Summary's residual statistics from the final calibration.
void finish_summary(RefineResult& out, const SamplesRef& samples, const SamplesRef* reference,
                    const Eigen::VectorXd* norms = nullptr) {
  const Calibration& cal = out.calibration;
  double sd = 0.0, sd2 = 0.0, sv2 = 0.0;
  for (Eigen::Index i = 0; i < samples.rows(); ++i) {
    const Eigen::Vector3d h = cal.apply(samples.row(i).transpose());
    const double dev = h.norm() - (norms ? (*norms)(i) : cal.field_norm);  // each reading's own |h| when given
    sd += dev;
    sd2 += dev * dev;
    if (reference) sv2 += (h - reference->row(i).transpose()).squaredNorm();
  }
  const double n = static_cast<double>(samples.rows());
  Summary& s = out.summary;
  s.samples = static_cast<std::size_t>(samples.rows());
  s.norm_mean = cal.field_norm + sd / n;
  s.norm_std_over_mean = std::sqrt(std::max(0.0, sd2 / n - (sd / n) * (sd / n))) / s.norm_mean;
  s.residual_rms = reference ? std::sqrt(sv2 / n) : std::sqrt(sd2 / n);
  s.exact_statistics = true;
  if (reference) {
    // With reference vectors the field's directions are known without the fit: coverage is theirs, and
    // coverage_ratio the thinnest/widest spread of the reference vectors (it was left 0, "planar").
    describe_coverage(s, *reference, Calibration{}, 16384);
    s.coverage_ratio = spread_ratio(*reference);
  } else {
    describe_coverage(s, samples, cal, 16384);
    s.coverage_ratio = spread_ratio(samples);  // the readings', as the ellipsoid fit reports it (it was left 0)
  }
  s.condition_number = out.fisher_condition;
  const bool finite =
      detail::finite_fit(s) && std::isfinite(out.noise_sigma) && cal.matrix.allFinite() && cal.offset.allFinite();
  if (reference)
    detail::require_finite_fit(finite, "samples", samples, "reference", *reference, cal.model);
  else
    detail::require_finite_fit(finite, "samples", samples, cal.model);
  std::ostringstream msg;
  msg << cal.model << ": " << s.samples << " samples, " << (s.converged ? "converged" : "NOT converged")
      << " in " << s.iterations << " iterations, noise σ " << out.noise_sigma << ", |h| std/mean "
      << 100.0 * s.norm_std_over_mean << " %, " << (reference ? "vector residual RMS " : "residual RMS ")
      << s.residual_rms << (out.identifiable ? "" : " — NOT IDENTIFIABLE");
  s.message = msg.str();
}

// Solves; fills the solver report, iterations and convergence. Returns Ceres' final cost ½Σρ(r²).
double solve_problem(ceres::Problem& problem, RefineResult& out, const RefineOptions& opt) {
  ceres::Solver::Options so;
  so.linear_solver_type = ceres::DENSE_NORMAL_CHOLESKY;  // tall and thin: N residuals, ≤ 12 parameters
  so.max_num_iterations = opt.max_iterations;
  so.function_tolerance = opt.function_tolerance;
  so.gradient_tolerance = opt.gradient_tolerance;
  so.parameter_tolerance = opt.parameter_tolerance;
  so.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(so, &problem, &summary);
  out.solver_report = summary.BriefReport();
  out.summary.iterations = static_cast<int>(summary.iterations.size()) - 1;
  out.summary.converged = summary.termination_type == ceres::CONVERGENCE;
  if (!summary.IsSolutionUsable()) throw Error("refine: the solver failed: " + summary.message);
  if (!out.summary.converged)
    out.summary.warnings.push_back("refinement stopped before converging: " + summary.message);
  return summary.final_cost;
}

// The shape constrains the magnitude model's refine(); elsewhere it would be silently ignored.
void require_symmetric_shape(const RefineOptions& o, const char* function) {
  if (o.shape != Shape::symmetric)
    throw Error(std::string("RefineOptions::shape: ") + function +
                " fits a full matrix (the vector model's W, or refine_terms' base with `fixed` names); "
                "the shape applies to refine's magnitude model");
}

// Options and start are checked before Ceres, which would otherwise print a glog line to stderr and
// fail with a message that names none of the caller's inputs (a NaN tolerance, a NaN start term).
void check_options(const RefineOptions& o) {
  const std::string s = "RefineOptions::";
  // An enum cast from an out-of-range integer fell through every switch: Loss(7) fitted without a loss.
  detail::require_enum(s + "loss", o.loss, 3, "none, huber, cauchy (0 … 2)");
  detail::require_enum(s + "shape", o.shape, 3, "sphere, diagonal, symmetric (0 … 2)");
  detail::require_enum(s + "serial_correlation", o.serial_correlation, 3, "automatic, independent, newey_west (0 … 2)");
  detail::require_int(o.max_iterations >= 1, s + "max_iterations", o.max_iterations, "≥ 1");
  for (const auto& [name, v] : {std::pair<const char*, double>{"function_tolerance", o.function_tolerance},
                                {"gradient_tolerance", o.gradient_tolerance},
                                {"parameter_tolerance", o.parameter_tolerance},
                                {"determined_tolerance", o.determined_tolerance}})
    detail::require_positive(s + name, v);
  detail::require_nonnegative(s + "loss_scale", o.loss_scale,
                              "a finite value ≥ 0 (0 = 3 × a robust estimate of the noise)");
  detail::require_open_unit(s + "serial_correlation_alpha", o.serial_correlation_alpha,
                            "a significance level in (0, 1)");
}

// `matrix` is the start's A (magnitude model: its symmetric part) or W: a singular one leaves Ceres
// nothing to evaluate ("Residual and Jacobian evaluation failed").
void check_start(const Calibration& start, const Eigen::Matrix3d& matrix, bool need_norm) {
  if (!start.offset.allFinite() || !start.matrix.allFinite()) throw Error("start: offset or matrix is not finite");
  if (need_norm && !(std::isfinite(start.field_norm) && start.field_norm > 0.0))
    throw Error("start: field_norm must be finite and positive (the known |h|)");
  const Eigen::Vector3d sv = Eigen::JacobiSVD<Eigen::Matrix3d>(matrix).singularValues();
  if (!(sv(2) > 1e-12 * sv(0)))
    throw Error("start: the matrix is singular (singular values " + std::to_string(sv(0)) + ", " +
                std::to_string(sv(1)) + ", " + std::to_string(sv(2)) +
                "); start from a fit (fit_ellipsoid, fit_vector) or the identity");
}

// The vector model's inputs: finite readings and one finite reference vector per reading.
void check_vector_inputs(const SamplesRef& samples, const SamplesRef& reference) {
  samples.require_width("samples");
  reference.require_width("reference");
  check_inputs(samples, 5, "a 12-parameter vector calibration");
  if (reference.rows() != samples.rows())
    throw Error("reference: " + std::to_string(reference.rows()) + " rows, samples have " +
                std::to_string(samples.rows()));
  check_finite(reference, "reference");
  detail::require_squares_representable(reference, "reference", "the vector calibration");
}

// The vector model m = W r + b is linear in θ: with X = [r 1] (N×4), its information JᵀJ is XᵀX on each
// output axis's block, whatever θ.
Eigen::Matrix4d reference_gram(const SamplesRef& reference) {
  Eigen::Matrix4d G;
  const Eigen::Vector3d sum = reference.colwise().sum().transpose();
  G.topLeftCorner<3, 3>() = reference.transpose() * reference;
  G.topRightCorner<3, 1>() = sum;
  G.bottomLeftCorner<1, 3>() = sum.transpose();
  G(3, 3) = static_cast<double>(reference.rows());
  return G;
}

// The information F = JᵀJ in θ order [b, W row-major] from XᵀX (constant column last): for output axis j
// the block over (b_j, W_j·) is XᵀX with the constant column first.
Eigen::MatrixXd vector_information(const Eigen::Matrix4d& XtX) {
  Eigen::MatrixXd F = Eigen::MatrixXd::Zero(12, 12);
  const int order[4] = {3, 0, 1, 2};  // X columns: constant, r0, r1, r2
  for (int j = 0; j < 3; ++j) {
    const int idx[4] = {j, 3 + 3 * j, 4 + 3 * j, 5 + 3 * j};
    for (int a = 0; a < 4; ++a)
      for (int c = 0; c < 4; ++c) F(idx[a], idx[c]) = XtX(order[a], order[c]);
  }
  return F;
}

// The vector model's residuals e = m − W r − b at θ and their scores (∂/∂b_j = −1, ∂/∂W_jk = −r_k):
// fills `scores`, returns Σ|e|².
double vector_scores(const SamplesRef& samples, const SamplesRef& reference, const Eigen::VectorXd& theta,
                     Scores& scores) {
  scores.residuals.resize(samples.rows(), 3);
  scores.scores.resize(samples.rows(), 12);
  double ssr = 0.0;
  for (Eigen::Index i = 0; i < samples.rows(); ++i) {
    Eigen::Vector3d e;
    vector_residual(samples.row(i).data(), reference.row(i).data(), theta.data(), e.data(), nullptr);
    ssr += e.squaredNorm();
    scores.residuals.row(i) = e.transpose();
    scores.scores.row(i).head<3>() = -e.transpose();
    for (int j = 0; j < 3; ++j) scores.scores.row(i).segment<3>(3 + 3 * j) = -e(j) * reference.row(i);
  }
  return ssr;
}

// Calibration (A = W⁻¹), statistics and summary of a vector-model result whose θ = [b, W] is set: its
// residuals and scores at θ, σ̂² (Huber's robust form with `loss`) and the information from XᵀX.
void finish_vector(RefineResult& out, const SamplesRef& samples, const SamplesRef& reference,
                   const Eigen::Matrix4d& XtX, const ceres::LossFunction* loss, const std::string& units,
                   const char* model, const RefineOptions& opt) {
  Scores scores;
  const double ssr = vector_scores(samples, reference, out.parameters, scores);
  const double residuals = static_cast<double>(3 * samples.rows());
  out.summary.cost = ssr / residuals;
  const double plain_sigma2 = ssr / (residuals - 12.0);
  out.noise_sigma = std::sqrt(plain_sigma2);
  const double sigma2 = loss ? robust_variance(*loss, scores, 12, plain_sigma2, out.summary.warnings) : plain_sigma2;
  Calibration& cal = out.calibration;
  cal.offset = out.parameters.head<3>();
  const Eigen::Matrix<double, 3, 3, Eigen::RowMajor> W(out.parameters.tail<9>().data());
  const std::optional<Eigen::Matrix3d> inverse = detail::full_piv_inverse(W);
  if (!inverse) throw Error(std::string(model) + ": the fitted W is singular");
  cal.matrix = *inverse;
  cal.field_norm = reference.rowwise().norm().mean();
  cal.units = units;
  cal.model = model;
  Eigen::VectorXd scales(12);  // offsets: the reading-space radius; W entries: its gain ‖W‖/√3
  scales.head<3>().setConstant((samples.rowwise() - cal.offset.transpose()).rowwise().norm().mean());
  scales.tail<9>().setConstant(W.norm() / std::sqrt(3.0));
  // the axes' noise covariance EᵀE/(N − 4) (4 parameters per axis), scaled as the robust loss scales σ²
  const double robust = plain_sigma2 > 0.0 ? sigma2 / plain_sigma2 : 1.0;
  const Eigen::Matrix3d axis_noise =
      scores.residuals.transpose() * scores.residuals / static_cast<double>(samples.rows() - 4) * robust;
  finish_statistics(out, vector_information(XtX), sigma2, scales, opt, true, &scores, &axis_noise);
  finish_summary(out, samples, &reference);
}

// The diagnosis' augmented model as one block of residuals: readings corrected by the terms,
// m'_i = m_i − Σ_j c_j f_ij, then the magnitude (Sampson) or vector residual of m'_i. Without terms
// (p = 0) it is refine's and refine_vector's plain least squares: Ceres then works on one dense
// Jacobian instead of N small blocks.
// Parameter blocks: base θ (9 or 12), then the term coefficients c (p, when p > 0).
class TermsBatch : public ceres::CostFunction {
 public:
  TermsBatch(const SamplesRef& m, const Eigen::Ref<const Eigen::MatrixXd>& f, double H, const SamplesRef* ref,
             const double* Hs = nullptr)
      : m_(m), f_(f), H_(H), Hs_(Hs), vector_(ref != nullptr), p_(static_cast<int>(f.cols() / 3)) {
    if (ref) ref_ = *ref;
    set_num_residuals(static_cast<int>(m.rows()) * (vector_ ? 3 : 1));
    mutable_parameter_block_sizes()->push_back(vector_ ? 12 : 9);
    if (p_ > 0) mutable_parameter_block_sizes()->push_back(p_);
  }
  int terms() const { return p_; }
  int base() const { return vector_ ? 12 : 9; }

  bool Evaluate(double const* const* par, double* r, double** jac) const override {
    const double* th = par[0];
    const Eigen::Map<const Eigen::VectorXd> c(p_ > 0 ? par[1] : nullptr, p_);
    const bool want_base = jac && jac[0], want_terms = jac && p_ > 0 && jac[1];
    if (!vector_) {
      magnitude(th, c, r, want_base ? jac[0] : nullptr, want_terms ? jac[1] : nullptr);
      return true;
    }
    for (Eigen::Index i = 0; i < m_.rows(); ++i) {
      Eigen::Vector3d mi = m_.row(i).transpose();
      for (int j = 0; j < p_; ++j) mi -= c(j) * f_.row(i).segment<3>(3 * j).transpose();
      vector_residual(mi.data(), ref_.row(i).data(), th, r + 3 * i, want_base ? jac[0] + 36 * i : nullptr);
      if (want_terms)
        for (int a = 0; a < 3; ++a)
          for (int j = 0; j < p_; ++j) jac[1][p_ * (3 * i + a) + j] = -f_(i, 3 * j + a);
    }
    return true;
  }

 private:
  // Sampson residuals (Jacobian rows into jb and jt when not null) of the corrected readings
  // m'_i = m_i − Σ_j c_j f_ij, a chunk at a time.
  void magnitude(const double* th, const Eigen::Ref<const Eigen::VectorXd>& c, double* r, double* jb, double* jt) const {
    if (p_ == 0) return sampson_rows(m_.data(), 3, m_.rows(), th, H_, r, jb, Hs_);
    constexpr Eigen::Index kChunk = 32;  // a chunk's terms stay in L1 between the correction and ∂r/∂c
    Samples corrected(kChunk, 3);
    std::vector<double> scratch(jt && !jb ? 9 * kChunk : 0);
    for (Eigen::Index i0 = 0; i0 < m_.rows(); i0 += kChunk) {
      const Eigen::Index len = std::min(kChunk, m_.rows() - i0);
      for (Eigen::Index i = 0; i < len; ++i) {  // a plain loop: a product with a 3-column matrix is slower
        const double* f = f_.data() + 3 * p_ * (i0 + i);
        double x = m_(i0 + i, 0), y = m_(i0 + i, 1), z = m_(i0 + i, 2);
        for (int j = 0; j < p_; ++j) x -= c(j) * f[3 * j], y -= c(j) * f[3 * j + 1], z -= c(j) * f[3 * j + 2];
        corrected(i, 0) = x, corrected(i, 1) = y, corrected(i, 2) = z;
      }
      double* jrows = jb ? jb + 9 * i0 : (jt ? scratch.data() : nullptr);
      sampson_rows(corrected.data(), 3, len, th, H_, r + i0, jrows, Hs_ ? Hs_ + i0 : nullptr);
      if (!jt) continue;
      // r depends on m' − b, so ∂r/∂c_j = (∂r/∂b) · f_ij.
      for (Eigen::Index i = 0; i < len; ++i)
        for (int j = 0; j < p_; ++j)
          jt[p_ * (i0 + i) + j] =
              Eigen::Map<const Eigen::Vector3d>(jrows + 9 * i).dot(f_.row(i0 + i).segment<3>(3 * j));
    }
  }

  Samples m_, ref_;
  Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> f_;  // a reading's terms side by side
  double H_;
  const double* Hs_;  // each reading's H, when not null (the caller keeps them)
  bool vector_;
  int p_;
};

}  // namespace

namespace {

// `start` with field_norm the mean of `norms` and its matrix scaled to it: a start fitted to another |h|, or to
// the readings' own radius, had left the solver far from it.
Calibration at_mean_norm(const Calibration& start, const Eigen::VectorXd& norms) {
  Calibration out = start;
  out.field_norm = norms.mean();
  if (std::isfinite(start.field_norm) && start.field_norm > 0.0) out.matrix *= norms.mean() / start.field_norm;
  return out;
}

// The calibration of the magnitude model's θ = [offset (3), A's upper triangle row by row (6)] at field norm H.
Calibration magnitude_calibration(const Eigen::Matrix<double, 9, 1>& t, double H) {
  Calibration cal;
  cal.offset = t.head<3>();
  cal.matrix << t(3), t(4), t(5), t(4), t(6), t(7), t(5), t(7), t(8);
  cal.field_norm = H;
  return cal;
}

// The median over the readings of | |h_i| − field | (cal.field_norm, or (*norms)(i)).
double median_misfit(const SamplesRef& samples, const Calibration& cal, const Eigen::VectorXd* norms) {
  std::vector<double> d(static_cast<std::size_t>(samples.rows()));
  for (Eigen::Index i = 0; i < samples.rows(); ++i)
    d[static_cast<std::size_t>(i)] = std::abs((cal.matrix * (samples.row(i).transpose() - cal.offset)).norm() -
                                              (norms ? (*norms)(i) : cal.field_norm));
  const auto mid = d.begin() + static_cast<std::ptrdiff_t>(d.size() / 2);
  std::nth_element(d.begin(), mid, d.end());
  return *mid;
}

// refine's magnitude model; each reading's |h| is start.field_norm, or (*norms)(i) when norms is not null.
RefineResult refine_magnitude(const Calibration& start, const SamplesRef& samples, const Eigen::VectorXd* norms,
                              const RefineOptions& opt) {
  check_options(opt);
  const ShapeMap shape = shape_map(opt.shape);
  const Eigen::Index k = shape.P.cols();
  check_inputs(samples, k + 1, "a " + std::to_string(k) + "-parameter magnitude refinement");
  if (!start.matrix.allFinite()) throw Error("start: offset or matrix is not finite");
  const Eigen::Matrix3d A = symmetric_part(start.matrix);
  check_start(start, A, true);
  RefineResult out;
  out.parameter_names = shape.names;
  Eigen::Matrix<double, 9, 1> th;  // all nine; the shape's projection of the start, then the solution
  th << start.offset, A(0, 0), A(0, 1), A(0, 2), A(1, 1), A(1, 2), A(2, 2);
  th = shape.P * (shape.pinv * th);
  double* theta = th.data();

  std::unique_ptr<ceres::LossFunction> loss;
  if (opt.loss != Loss::none) {
    std::vector<double> start_abs;
    for (Eigen::Index i = 0; i < samples.rows(); ++i) {
      const Eigen::Vector3d m = samples.row(i).transpose();
      start_abs.push_back(std::abs(sampson(m.data(), theta, norms ? (*norms)(i) : start.field_norm, nullptr)));
    }
    loss.reset(make_loss(opt, robust_sigma(start_abs)));
  }
  Eigen::MatrixXd F;
  double ssr;
  // fits |h| to H, or reading i's to Hs[i]; returns Ceres' final cost ½Σρ(r²)
  auto solve_for = [&](double H, const double* Hs) {
    ceres::Problem::Options po;
    po.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
    ceres::Problem problem(po);
    if (!loss) {
      problem.AddResidualBlock(new TermsBatch(samples, Eigen::MatrixXd(samples.rows(), 0), H, nullptr, Hs), nullptr,
                               theta);
    } else {
      for (Eigen::Index i = 0; i < samples.rows(); ++i)
        problem.AddResidualBlock(new MagnitudeOne(samples.row(i).transpose(), Hs ? Hs[i] : H), loss.get(), theta);
    }
    if (k < 9) problem.SetManifold(theta, new ShapeManifold(shape));
    return solve_problem(problem, out, opt);
  };
  Eigen::VectorXd gradient;  // of the shape's parameters
  Scores scores{Eigen::MatrixXd(samples.rows(), 1), Eigen::MatrixXd(samples.rows(), k)};
  // Σr², JᵀJ and Jᵀr at θ (shape's φ), |h| fitted to H or Hs[i]
  auto plain_fit = [&](double H, const double* Hs, Eigen::MatrixXd& info, double& sum_sq) {
    // The Jacobian's rows a chunk at a time: one rank-k update of JᵀJ and one product onto the shape's
    // parameters per chunk (a rank-1 update and a dynamic-size product per reading cost 3× more).
    constexpr Eigen::Index kChunk = 512;
    Eigen::Matrix<double, 9, Eigen::Dynamic> jac(9, kChunk);
    Eigen::Matrix<double, 9, 9> f = Eigen::Matrix<double, 9, 9>::Zero();
    Eigen::Matrix<double, 9, 1> g = Eigen::Matrix<double, 9, 1>::Zero();
    sum_sq = 0.0;
    for (Eigen::Index i0 = 0; i0 < samples.rows(); i0 += kChunk) {
      const Eigen::Index len = std::min(kChunk, samples.rows() - i0);
      sampson_rows(samples.data() + samples.outerStride() * i0, samples.outerStride(), len, theta, H,
                   scores.residuals.data() + i0, jac.data(), Hs ? Hs + i0 : nullptr);
      const auto J = jac.leftCols(len);
      const auto r = scores.residuals.col(0).segment(i0, len);
      sum_sq += r.squaredNorm();
      f.selfadjointView<Eigen::Lower>().rankUpdate(J);
      g.noalias() += J * r;
      scores.scores.middleRows(i0, len).noalias() = r.asDiagonal() * (J.transpose() * shape.P);
    }
    gradient = shape.P.transpose() * g;
    const Eigen::Matrix<double, 9, 9> full = f.selfadjointView<Eigen::Lower>();
    info = shape.P.transpose() * full * shape.P;
    out.summary.cost = sum_sq / static_cast<double>(samples.rows());
  };
  const double spare = static_cast<double>(samples.rows() - k);
  const double H = start.field_norm;
  Eigen::VectorXd fit_norms;  // each reading's target: when the field changes, or with the noise's bias
  if (norms) fit_norms = *norms;
  const double* Hs = norms ? fit_norms.data() : nullptr;
  const double solved_cost = solve_for(H, Hs);
  bool current = false;  // F, ssr and the scores are those of θ as it stands
  if (opt.noise_bias_correction && out.summary.converged) {  // (a run-away iterate has no noise to correct for)
    // σ̂² from the plain Σr² (Ceres' final cost) without a loss; with one, from the median residual: the plain Σr²
    // holds the outliers the loss ignores (one spike at 170× the field made the target 31× the field, and A with it).
    const Eigen::Matrix<double, 9, 1>& t = th;
    double s2 = 2.0 * solved_cost / spare;
    if (loss) s2 = std::pow(1.4826 * median_misfit(samples, magnitude_calibration(th, H), norms), 2);
    // Each reading's target: where its Sampson residual r = (|h| − H)/g, g = |∇|h|| = |Aû|, has mean 0. To O(σ²),
    // E[|h|] − H = σ²(tr A² − q)/(2H), the noise across û lengthening h, and the noise along ∇|h| also moves g: −σ²∇|h|·∇g/g
    // = −σ²(q₄/q − q)/H, with q = ûᵀA²û, q₄ = ûᵀA⁴û (0 for A ∝ I). One target tr A²/(3H) for all, the mean of the
    // first term over directions, left a blind check's A (gains 0.5/1/1.5) 0.8–1.3 standard errors off at 5000 readings.
    // With a robust loss (no Jacobian term below) the one mean target of before: the per-reading targets alone moved
    // a Huber fit's A the other way (a review: a00's t −13.2 → +7.2 over 1000 fits).
    const Eigen::Matrix3d A = magnitude_calibration(t, H).matrix, A2 = A * A;
    const double a2 = A2.trace();
    fit_norms.resize(samples.rows());
    for (Eigen::Index i = 0; i < samples.rows() && loss; ++i)
      fit_norms(i) = (norms ? (*norms)(i) : H) + s2 * a2 / (3.0 * (norms ? (*norms)(i) : H));
    for (Eigen::Index i = 0; i < samples.rows() && !loss; ++i) {
      const Eigen::Vector3d h = A * (samples.row(i).transpose() - t.head<3>()), a2h = A2 * h;
      const double hn2 = h.squaredNorm(), Hi = norms ? (*norms)(i) : H;
      double raise = 2.0 * a2 / 3.0;  // (a reading at the offset itself has no direction: the mean)
      if (hn2 > 0.0) {
        const double q = h.dot(a2h) / hn2, q4 = a2h.squaredNorm() / hn2;
        raise = (a2 - q) - 2.0 * (q4 / q - q);
      }
      fit_norms(i) = Hi + s2 * raise / (2.0 * Hi);
    }
    Hs = fit_norms.data();  // (H itself is then not used: every reading has its target)
    // The targets move by O(σ²/H): Gauss–Newton steps from the solution converge at once (plain
    // least squares; with a robust loss the full solve again).
    if (loss) {
      const int first_iterations = out.summary.iterations;
      out.summary.warnings.clear();
      solve_for(H, Hs);
      out.summary.iterations += first_iterations;
    } else {
      // A step below 1e-5 of a standard error (δᵀFδ ≤ 1e-10 σ̂²) is not taken: θ has converged, and the
      // pass that found the step has the statistics at θ.
      for (int step = 0; step < 4; ++step) {
        plain_fit(H, Hs, F, ssr);
        const Eigen::VectorXd delta = -detail::ldlt_solve(F, gradient);
        current = delta.dot(F * delta) <= 1e-10 * ssr / spare;
        if (current) break;
        th += shape.P * delta;
        ++out.summary.iterations;
      }
      // With E[r_k] = 0 the fit is still biased at O(σ²): the Jacobian moves with the noise along the reading's
      // normal n = ∇|h|/g, so E[J_k r_k] = σ² ∂J_k/∂n and θ̂ is off by −F⁻¹σ² Σ ∂J_k/∂n (an M-estimator's
      // first-order bias), taken off here — ∂J/∂n by central differences of the analytic Jacobian. (The gains
      // 0.5/1/1.5 above: A still 4–8 standard errors of a 200-fit mean off without it.)
      // Not where the readings leave a parameter undetermined (finish_statistics' rule): F⁻¹ along it would turn
      // noise into the shift, and that parameter's error is far beyond an O(σ²) bias anyway.
      const detail::ScaledInverse Finv = detail::scaled_inverse(F);
      const Calibration now = magnitude_calibration(th, H);
      const double radius = mean_radius(samples, now.offset);
      bool determined = !Finv.singular;
      for (Eigen::Index j = 0; j < k && determined; ++j)
        determined = std::sqrt(s2 * Finv.inverse(j, j)) <
                     opt.determined_tolerance * (j < 3 ? radius : now.matrix.norm() / std::sqrt(3.0));
      if (determined) {
        th += shape.P * (Finv.inverse * (shape.P.transpose() * normal_derivative_of_jacobian(samples, th, H, Hs))) * s2;
        current = false;
      }
    }
  }
  if (!current) plain_fit(H, Hs, F, ssr);
  const double plain_sigma2 = ssr / spare;
  out.noise_sigma = std::sqrt(plain_sigma2);
  const double sigma2 =
      loss ? robust_variance(*loss, scores, static_cast<int>(k), plain_sigma2, out.summary.warnings) : plain_sigma2;

  Calibration& cal = out.calibration;
  cal = magnitude_calibration(th, start.field_norm);
  cal.units = opt.units.empty() ? start.units : opt.units;
  cal.model = "refine";
  out.parameters = shape.pinv * th;
  if (!(Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(cal.matrix).eigenvalues()(0) > 0.0))
    throw Error("refine: the refined matrix is not positive definite; the start was too far off, the data "
                "do not lie on an ellipsoid, or they cover too few directions (a small cap of the sphere: turn "
                "the sensor through more orientations)");

  const double radius = mean_radius(samples, cal.offset);  // reading-space radius: the scale of the offsets
  const double gain = cal.matrix.norm() / std::sqrt(3.0);
  Eigen::VectorXd scales(k);  // offsets: the radius; matrix entries: the gain ‖A‖_F/√3
  for (Eigen::Index j = 0; j < k; ++j) scales(j) = j < 3 ? radius : gain;
  finish_statistics(out, F, sigma2, scales, opt, false, &scores);
  finish_summary(out, samples, nullptr, norms);
  // A fit that left the readings: |h| as far from the field as the field is large (on a cap, the offset and A ran to
  // 1e75 and 1e69 in 100 iterations, its cost underflowed to 0 and won a comparison of shapes by BIC). Judged on the
  // median reading: one spike left far off by a robust loss is no runaway.
  const double typical = median_misfit(samples, cal, norms);
  if (!(typical < cal.field_norm))
    throw Error("refine: the refinement ran away from the readings (" +
                std::string(out.summary.converged ? "converged" : "not converged") + " after " +
                std::to_string(out.summary.iterations) + " iterations, the median | |h| − field | " +
                detail::num(typical) + " against a field of " + detail::num(cal.field_norm) +
                "); the start was too far off, or the readings cover too few directions (a small cap of the sphere: "
                "turn the sensor through more orientations)");
  return out;
}

}  // namespace

namespace {

// A start whose correction maps the readings far from its own field_norm (beyond 5× either way, as a units mismatch
// is judged) had left the solver far off, and it failed blaming the data ("not positive definite"): a Calibration
// filled with a cal.json's offset and matrix alone keeps the default field_norm 1. Its matrix is scaled to
// field_norm, and `said` says so; nothing changes for a start that is roughly right. (A far offset, the identity on
// raw readings with a large hard iron, moves the median too: the scaling still helps, hence the advice's "if".)
Calibration at_stated_norm(const Calibration& start, const SamplesRef& samples, std::string& said) {
  if (!(start.offset.allFinite() && start.matrix.allFinite() && std::isfinite(start.field_norm) &&
        start.field_norm > 0.0))
    return start;  // check_start says what is wrong
  std::vector<double> h;
  h.reserve(static_cast<std::size_t>(samples.rows()));
  for (Eigen::Index i = 0; i < samples.rows(); ++i) {
    const Eigen::Vector3d m = samples.row(i).transpose();
    if (m.allFinite()) h.push_back((start.matrix * (m - start.offset)).norm());
  }
  if (h.empty()) return start;
  const auto mid = h.begin() + static_cast<std::ptrdiff_t>(h.size() / 2);
  std::nth_element(h.begin(), mid, h.end());
  const double median = *mid, gain = median / start.field_norm;
  if (!(std::isfinite(gain) && gain > 0.0) || !(gain > 5.0 || gain < 0.2)) return start;
  said = "start: its correction maps the readings to a median |h| of " + detail::num(median) + ", " +
         detail::num(gain) + " times start.field_norm " + detail::num(start.field_norm) +
         "; its matrix was scaled to field_norm before refining (if the start's offset is right and its field is "
         "about " + detail::num(median) + ", set start.field_norm to it: a calibration read from a file has it as "
         "field_norm)";
  Calibration out = start;
  out.matrix /= gain;
  return out;
}

}  // namespace

RefineResult refine(const Calibration& start, const SamplesRef& samples, const RefineOptions& opt) {
  std::string said;
  RefineResult out = refine_magnitude(at_stated_norm(start, samples, said), samples, nullptr, opt);
  if (!said.empty()) out.summary.warnings.push_back(said);
  return out;
}

RefineResult refine(const Calibration& start, const SamplesRef& samples, const SeriesRef& field_norms,
                    const RefineOptions& opt) {
  detail::check_field_norms(field_norms, samples.rows());
  const Eigen::VectorXd norms = field_norms;
  std::string stated;
  RefineResult out = refine_magnitude(at_mean_norm(at_stated_norm(start, samples, stated), norms), samples, &norms, opt);
  if (!stated.empty()) out.summary.warnings.push_back(stated);
  // Norms far from the readings' own radius usually mean another unit (nT magnitudes for µT readings), as the
  // ellipsoid fit and TWOSTEP say of a field_norm; the start's matrix, rescaled to them, hid it here.
  const double gain = std::cbrt(out.calibration.matrix.determinant());
  const std::string said = detail::units_mismatch("field_norms: their mean " + detail::num(norms.mean()), gain,
                                                  norms.mean() / gain);
  if (!said.empty()) out.summary.warnings.push_back(said);
  return out;
}

RefineResult refine_vector(const Calibration& start, const SamplesRef& samples, const SamplesRef& reference,
                           const RefineOptions& opt) {
  check_vector_inputs(samples, reference);
  check_options(opt);
  require_symmetric_shape(opt, "refine_vector");
  check_start(start, start.matrix, false);
  const Eigen::Matrix<double, 3, 3, Eigen::RowMajor> W = start.matrix.inverse();
  RefineResult out;
  out.parameter_names.assign(std::begin(kVectorNames), std::end(kVectorNames));
  out.parameters.resize(12);
  out.parameters.head<3>() = start.offset;
  out.parameters.tail<9>() = Eigen::Map<const Eigen::Matrix<double, 9, 1>>(W.data());
  double* theta = out.parameters.data();

  std::vector<double> start_abs;  // the robust loss's default scale
  if (opt.loss != Loss::none) {
    for (Eigen::Index i = 0; i < samples.rows(); ++i) {
      double r[3];
      vector_residual(samples.row(i).data(), reference.row(i).data(), theta, r, nullptr);
      for (double v : r) start_abs.push_back(std::abs(v));
    }
  }
  ceres::Problem::Options po;
  po.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(po);
  std::unique_ptr<ceres::LossFunction> loss(make_loss(opt, robust_sigma(start_abs)));
  if (!loss) {  // plain least squares: all residuals in one block, one dense Jacobian
    problem.AddResidualBlock(new TermsBatch(samples, Eigen::MatrixXd(samples.rows(), 0), 0.0, &reference), nullptr,
                             theta);
  } else {
    for (Eigen::Index i = 0; i < samples.rows(); ++i)
      problem.AddResidualBlock(new VectorOne(samples.row(i).transpose(), reference.row(i).transpose()), loss.get(),
                               theta);
  }
  solve_problem(problem, out, opt);
  finish_vector(out, samples, reference, reference_gram(reference), loss.get(),
                opt.units.empty() ? start.units : opt.units, "refine_vector", opt);
  return out;
}

RefineResult fit_vector(const SamplesRef& samples, const SamplesRef& reference, const RefineOptions& opt) {
  check_vector_inputs(samples, reference);
  check_options(opt);
  require_symmetric_shape(opt, "fit_vector");
  // XᵀX and XᵀM for X = [r 1] (N×4), M the readings (N×3).
  const Eigen::Matrix4d XtX = reference_gram(reference);
  Eigen::Matrix<double, 4, 3> XtM;
  XtM.topRows<3>() = reference.transpose() * samples;
  XtM.row(3) = samples.colwise().sum();
  const Eigen::Vector4d d = XtX.diagonal().cwiseSqrt().cwiseInverse();
  const Eigen::Vector4d lam = detail::symmetric_eigen(Eigen::Matrix4d(d.asDiagonal() * XtX * d.asDiagonal())).values;
  if (!(lam(0) > 1e-12 * lam(3)))
    throw Error("reference: the reference vectors do not span 3-D (all in one plane or one direction); "
                "the full 3×3 matrix is not identifiable — turn the sensor about more axes");
  const Eigen::Matrix<double, 4, 3> beta = detail::ldlt_solve(XtX, XtM);  // rows: W columns 0..2, then b

  RefineResult out;
  out.parameter_names.assign(std::begin(kVectorNames), std::end(kVectorNames));
  out.parameters.resize(12);
  out.parameters.head<3>() = beta.row(3).transpose();
  for (int j = 0; j < 3; ++j)
    for (int k = 0; k < 3; ++k) out.parameters(3 + 3 * j + k) = beta(k, j);  // W(j, k)
  out.summary.converged = true;
  finish_vector(out, samples, reference, XtX, nullptr, opt.units, "vector", opt);
  return out;
}

namespace {

// refine_terms; each reading's |h| is start.field_norm, or (*norms)(i) when norms is not null (magnitude model).
RefineResult terms_fit(const Calibration& start, const SamplesRef& samples, const Eigen::Ref<const Eigen::MatrixXd>& features,
                       const Eigen::VectorXd& start_terms, const std::vector<std::string>& fixed,
                       const RefineOptions& opt, const SamplesRef* reference, const Eigen::VectorXd* norms) {
  const bool vector = reference != nullptr;
  if (vector) check_vector_inputs(samples, *reference);
  else check_inputs(samples, 10, "a magnitude model with extra terms");
  if (features.rows() != samples.rows() || features.cols() % 3 != 0)
    throw Error("features: " + std::to_string(features.rows()) + "×" + std::to_string(features.cols()) +
                ", need " + std::to_string(samples.rows()) + " rows (one per reading) and 3 columns per term");
  if (!features.allFinite()) throw Error("features: contains NaN or Inf");
  const int p = static_cast<int>(features.cols() / 3);
  if (start_terms.size() != p)
    throw Error("start_terms: " + std::to_string(start_terms.size()) + " values for " + std::to_string(p) + " terms");
  if (!start_terms.allFinite()) throw Error("start_terms: contains NaN or Inf");
  check_options(opt);
  require_symmetric_shape(opt, "refine_terms");
  if (!start.matrix.allFinite()) throw Error("start: offset or matrix is not finite");
  check_start(start, vector ? start.matrix : symmetric_part(start.matrix), !vector);
  if (opt.loss != Loss::none) throw Error("refine_terms: only plain least squares (loss none)");

  RefineResult out;
  const int nb = vector ? 12 : 9;
  if (vector) {
    const Eigen::Matrix<double, 3, 3, Eigen::RowMajor> W = start.matrix.inverse();
    out.parameter_names.assign(std::begin(kVectorNames), std::end(kVectorNames));
    out.parameters.resize(nb + p);
    out.parameters.head<3>() = start.offset;
    out.parameters.segment<9>(3) = Eigen::Map<const Eigen::Matrix<double, 9, 1>>(W.data());
  } else {
    const Eigen::Matrix3d A = symmetric_part(start.matrix);
    out.parameter_names.assign(std::begin(kMagnitudeNames), std::end(kMagnitudeNames));
    out.parameters.resize(nb + p);
    out.parameters.head<9>() << start.offset, A(0, 0), A(0, 1), A(0, 2), A(1, 1), A(1, 2), A(2, 2);
  }
  out.parameters.tail(p) = start_terms;
  for (int j = 0; j < p; ++j) out.parameter_names.push_back("c" + std::to_string(j));
  std::vector<int> held;
  for (const std::string& name : fixed) {
    const auto it = std::find(out.parameter_names.begin(), out.parameter_names.begin() + nb, name);
    if (it == out.parameter_names.begin() + nb) throw Error("fixed: no base parameter named '" + name + "'");
    held.push_back(static_cast<int>(it - out.parameter_names.begin()));
  }
  std::sort(held.begin(), held.end());
  held.erase(std::unique(held.begin(), held.end()), held.end());

  // Ceres works on separate arrays for the two blocks.
  Eigen::VectorXd base = out.parameters.head(nb), terms = out.parameters.tail(p);
  auto* cost = new TermsBatch(samples, features, start.field_norm, reference, norms ? norms->data() : nullptr);
  ceres::Problem problem;
  std::vector<double*> blocks{base.data()};
  if (p > 0) blocks.push_back(terms.data());
  problem.AddResidualBlock(cost, nullptr, blocks);
  if (!held.empty()) problem.SetManifold(base.data(), new ceres::SubsetManifold(nb, held));
  solve_problem(problem, out, opt);
  out.parameters << base, terms;

  // Residuals and the full Jacobian at the solution (fixed columns zeroed: they are not estimated).
  const Eigen::Index nr = cost->num_residuals();
  out.residuals.resize(nr);
  Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> jb(nr, nb), jt(nr, std::max(p, 1));
  double* jacs[2] = {jb.data(), jt.data()};
  const double* pars[2] = {base.data(), terms.data()};
  cost->Evaluate(pars, out.residuals.data(), jacs);
  out.jacobian.resize(nr, nb + p);
  out.jacobian << jb, jt.leftCols(p);
  for (int k : held) out.jacobian.col(k).setZero();

  const Eigen::Index free = nb + p - static_cast<Eigen::Index>(held.size());
  const double ssr = out.residuals.squaredNorm();
  const double sigma2 = ssr / static_cast<double>(std::max<Eigen::Index>(nr - free, 1));
  out.noise_sigma = std::sqrt(sigma2);
  out.summary.cost = ssr / static_cast<double>(nr);
  out.summary.residual_rms = std::sqrt(out.summary.cost);
  out.summary.samples = static_cast<std::size_t>(samples.rows());

  // Covariance σ̂² (JᵀJ)⁺ over the free parameters, through the column-scaled eigen-decomposition.
  const Eigen::MatrixXd info = out.jacobian.transpose() * out.jacobian;
  const Eigen::VectorXd d = info.diagonal().unaryExpr([](double v) { return v > 0.0 ? 1.0 / std::sqrt(v) : 0.0; });
  const detail::SymmetricEigen<Eigen::Dynamic> eig = detail::symmetric_eigen(Eigen::MatrixXd(d.asDiagonal() * info * d.asDiagonal()));
  const Eigen::VectorXd& lam = eig.values;
  const double top = lam.maxCoeff();
  const Eigen::VectorXd inv = lam.unaryExpr([top](double v) { return v > 1e-14 * top ? 1.0 / v : 0.0; });
  out.covariance = sigma2 * d.asDiagonal() * eig.vectors * inv.asDiagonal() * eig.vectors.transpose() *
                   d.asDiagonal();
  out.standard_errors = out.covariance.diagonal().cwiseMax(0.0).cwiseSqrt();
  // A direction of (near) zero information moves the parameters on it without changing the residuals
  // (a term that copies the offset, a reference with no z component): those are not determined, and
  // the pseudo-inverse's finite errors for them mean nothing. Held parameters' zero columns are skipped.
  out.determined.assign(static_cast<std::size_t>(nb + p), true);
  out.identifiable = true;  // until a direction without information names a parameter
  double smallest = std::numeric_limits<double>::infinity();
  std::ostringstream undetermined;
  for (Eigen::Index j = 0; j < lam.size(); ++j) {
    const Eigen::VectorXd v = eig.vectors.col(j);
    double on_free = 0.0;
    for (Eigen::Index k = 0; k < v.size(); ++k) on_free += d(k) > 0.0 ? v(k) * v(k) : 0.0;
    if (on_free < 0.5) continue;  // the zero column of a held parameter
    smallest = std::min(smallest, std::max(lam(j), 0.0));
    if (lam(j) > 1e-10 * top) continue;
    for (Eigen::Index k = 0; k < v.size(); ++k) {
      const auto kk = static_cast<std::size_t>(k);
      if (d(k) == 0.0 || std::abs(v(k)) < 0.1 || !out.determined[kk]) continue;
      undetermined << (out.identifiable ? "" : ", ") << out.parameter_names[kk];
      out.determined[kk] = false;
      out.identifiable = false;
    }
  }
  out.fisher_condition = smallest > 0.0 ? top / smallest : std::numeric_limits<double>::infinity();
  if (!out.identifiable)
    out.summary.warnings.push_back("not identifiable: the data do not determine " + undetermined.str() +
                                   " (they move together without changing the residuals: a term that "
                                   "repeats a base parameter, or readings that do not span it)");

  Calibration& cal = out.calibration;
  cal.offset = base.head<3>();
  if (vector) {
    const Eigen::Matrix<double, 3, 3, Eigen::RowMajor> W(base.tail<9>().data());
    cal.matrix = W.inverse();
    cal.field_norm = reference->rowwise().norm().mean();
  } else {
    cal.matrix << base(3), base(4), base(5), base(4), base(6), base(7), base(5), base(7), base(8);
    cal.field_norm = start.field_norm;
  }
  cal.units = opt.units.empty() ? start.units : opt.units;
  cal.model = vector ? "vector+terms" : "magnitude+terms";
  detail::require_finite_fit(detail::finite_fit(out.summary) && cal.matrix.allFinite() && cal.offset.allFinite(),
                             "samples", samples, cal.model);
  std::ostringstream msg;
  msg << cal.model << ": " << samples.rows() << " samples, " << p << " extra terms, "
      << (out.summary.converged ? "converged" : "NOT converged") << " in " << out.summary.iterations
      << " iterations, residual RMS " << out.summary.residual_rms;
  out.summary.message = msg.str();
  return out;
}

}  // namespace

RefineResult refine_terms(const Calibration& start, const SamplesRef& samples, const Eigen::Ref<const Eigen::MatrixXd>& features,
                          const Eigen::VectorXd& start_terms, const std::vector<std::string>& fixed,
                          const RefineOptions& opt, const SamplesRef* reference) {
  return terms_fit(start, samples, features, start_terms, fixed, opt, reference, nullptr);
}

RefineResult refine_terms(const Calibration& start, const SamplesRef& samples, const SeriesRef& field_norms,
                          const Eigen::Ref<const Eigen::MatrixXd>& features, const Eigen::VectorXd& start_terms,
                          const std::vector<std::string>& fixed, const RefineOptions& opt) {
  detail::check_field_norms(field_norms, samples.rows());
  const Eigen::VectorXd norms = field_norms;
  Calibration mean_start = start;  // its matrix as given: `fixed` holds base parameters at their start values
  mean_start.field_norm = norms.mean();
  return terms_fit(mean_start, samples, features, start_terms, fixed, opt, nullptr, &norms);
}

}  // namespace fluxcal
