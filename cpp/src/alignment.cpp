// Magnetometer-to-accelerometer alignment from the dip (alignment.hpp for the model).
#include "fluxcal/alignment.hpp"

#include "checks.hpp"
#include "linalg.hpp"
#include "long_run.hpp"

#include <Eigen/SVD>

#include <algorithm>
#include <cmath>
#include <limits>

namespace fluxcal {
namespace {

constexpr double kPi = 3.14159265358979323846, kDeg = 180.0 / kPi;

/// A start value of the dip kept off ±90° (a start from noisy cosines can reach ±1).
double start_dip(double dip) { return std::clamp(dip, -89.0 / kDeg, 89.0 / kDeg); }

Eigen::Matrix3d exp_rotation(const Eigen::Vector3d& theta) {
  const double angle = theta.norm();
  if (angle < 1e-300) return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(angle, theta / angle).toRotationMatrix();
}

/// The nearest rotation to M (Frobenius), through its SVD.
Eigen::Matrix3d nearest_rotation(const Eigen::Matrix3d& m) {
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(m, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
  d(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0 ? -1.0 : 1.0;
  return svd.matrixU() * d * svd.matrixV().transpose();
}

/// The dip each reading shows less δ: atan2(d_k·v_k, |d_k × v_k|) − δ, v_k = R ĥ_k (radians). Its noise is the
/// direction noise across the two vectors, the same for every reading at any dip — unlike the cosine d_k·v_k − sin δ,
/// whose first-order noise fades as cos δ towards the poles while its second-order noise does not, and whose
/// Jacobian's noise correlates with its own (least squares on it was biased by 1–2° on a hand turn's uneven
/// attitudes at 1 % noise, and by 3.7° at a dip of 85°). On the angle that correlation cancels to first order.
Eigen::VectorXd residuals(const Samples& down, const Samples& dir, const Eigen::Matrix3d& r, double dip) {
  Eigen::VectorXd out(down.rows());
  for (Eigen::Index k = 0; k < down.rows(); ++k) {
    const Eigen::Vector3d v = r * dir.row(k).transpose(), d = down.row(k).transpose();
    out(k) = std::atan2(d.dot(v), d.cross(v).norm()) - dip;
  }
  return out;
}

double cost(const Samples& down, const Samples& dir, const Eigen::Matrix3d& r, double dip) {
  return residuals(down, dir, r, dip).squaredNorm();
}

/// σ̂²: the cost over the degrees of freedom (four parameters).
double residual_variance(double cost, Eigen::Index rows) {
  return cost / static_cast<double>(std::max<Eigen::Index>(rows - 4, 1));
}

/// The residuals e and their Jacobian J at (R, δ) in one pass: J's rows are (the unit vector along R ĥ_k × d_k, −1)
/// over (a small rotation, δ).
void linearise(const Samples& down, const Samples& dir, const Eigen::Matrix3d& r, double dip,
               Eigen::Matrix<double, Eigen::Dynamic, 4>& j, Eigen::VectorXd& e) {
  j.resize(down.rows(), 4);
  e.resize(down.rows());
  for (Eigen::Index k = 0; k < down.rows(); ++k) {
    const Eigen::Vector3d v = r * dir.row(k).transpose(), d = down.row(k).transpose(), across = v.cross(d);
    const double norm = across.norm();  // 0 only for a field exactly along gravity: no rotation seen
    e(k) = std::atan2(d.dot(v), norm) - dip;
    j.row(k) << (norm > 0 ? (across / norm).eval() : Eigen::Vector3d::Zero()).transpose(), -1.0;
  }
}

/// JᵀJ and Jᵀe of the residuals at (R, δ).
void normal_equations(const Samples& down, const Samples& dir, const Eigen::Matrix3d& r, double dip,
                      Eigen::Matrix4d& jtj, Eigen::Vector4d& jte) {
  Eigen::Matrix<double, Eigen::Dynamic, 4> j;
  Eigen::VectorXd e;
  linearise(down, dir, r, dip, j, e);
  jtj = j.transpose() * j;
  jte = j.transpose() * e;
}

/// The step −(JᵀJ + μ λ_max)⁻¹ g taken only along the directions the data see (standard error along the eigen-
/// direction, at the residual variance sigma2, within 3 max_se_deg); the others keep their value. For level turns
/// that is the rotation about the vertical (its SE 5° and more), along which a free step wanders to an arbitrary
/// heading (every heading fits nearly as well). Not max_se_deg itself: an eigen-direction mixing two parameters
/// has a larger SE than either, and the iterates' variance is inflated far from the minimum; weakly determined
/// directions frozen so stopped hand-turn fits 5–10° off at 10–30 % more cost (a blind check).
Eigen::Vector4d determined_step(const detail::SymmetricEigen<4>& eig, const Eigen::Vector4d& g,
                                double sigma2, double mu, const AlignmentOptions& options) {
  const Eigen::Vector4d lambda = eig.values, in_eigen = eig.vectors.transpose() * g;
  const double se_limit2 = std::pow(3.0 * options.max_se_deg / kDeg, 2), scale = std::max(lambda(3), 1e-300);
  Eigen::Vector4d step = Eigen::Vector4d::Zero();
  for (int i = 0; i < 4; ++i)
    if (lambda(i) > 0 && sigma2 / lambda(i) <= se_limit2) step(i) = -in_eigen(i) / (lambda(i) + mu * scale);
  return eig.vectors * step;
}

struct Fit {
  Eigen::Matrix3d rotation;
  double dip = 0.0, cost = 0.0, sigma2 = 0.0;
  int iterations = 0;
  bool converged = false, identifiable = false, singular = false;  // singular: the inverted matrix's floor reached
  bool flat_cost = false;  // H not positive definite: the covariance is σ̂²(JᵀJ)⁻¹ and the fit not identifiable
  Eigen::Matrix4d inverse = Eigen::Matrix4d::Zero();     // H⁻¹, huge along an undetermined direction
  Eigen::Matrix4d covariance = Eigen::Matrix4d::Zero();  // σ̂² H⁻¹ JᵀJ H⁻¹
};

/// Levenberg's damped Gauss–Newton on R = exp([θ]×) R and δ. The damping (μ × the largest curvature) keeps steps
/// along a direction the data barely see (a rotation about the vertical, for level turns) from wandering.
Fit gauss_newton(const Samples& down, const Samples& dir, Eigen::Matrix3d r, double dip,
                 const AlignmentOptions& options) {
  Fit fit;
  double current = cost(down, dir, r, dip), mu = 1e-6;
  while (fit.iterations < options.max_iterations) {
    Eigen::Matrix4d jtj;
    Eigen::Vector4d jte;
    normal_equations(down, dir, r, dip, jtj, jte);
    ++fit.iterations;
    const detail::SymmetricEigen<4> eig = detail::symmetric_eigen(jtj);
    const double sigma2 = residual_variance(current, down.rows());
    bool accepted = false;
    for (; mu <= 1e6 && !accepted; ) {
      const Eigen::Vector4d step = determined_step(eig, jte, sigma2, mu, options);
      const Eigen::Matrix3d r_try = exp_rotation(step.head<3>()) * r;
      const double dip_try = dip + step(3), c = cost(down, dir, r_try, dip_try);
      if (c < current) {
        // a gain below 1e-10 of the cost moves the parameters by ~1e-5·√N of their standard errors: the minimum —
        // when the step was nearly undamped (a heavily damped one gains little anywhere)
        const bool done = mu <= 1e-3 && (current - c <= 1e-10 * current || step.norm() < options.tolerance);
        r = r_try, dip = dip_try, current = c, mu = std::max(mu / 10, 1e-12), accepted = true;
        if (done) fit.converged = true;
      } else {
        mu *= 10;
      }
    }
    if (!accepted) fit.converged = true;  // no step lowers the cost: the minimum
    if (fit.converged) break;
  }
  fit.rotation = r, fit.dip = dip, fit.cost = current;
  return fit;
}

/// The Hessian of ½Σe_k² at (R, δ): JᵀJ + Σ e_k ∇²e_k. Gauss–Newton's JᵀJ alone overstates what the data know along a
/// direction the attitudes barely see (a probe rolled about one body axis: the rotation about it trades with the dip):
/// the direction noise tilts each row of J at random, lending JᵀJ ~Nσ² of curvature there that the cost does not
/// have — the same noise across the plane of the two vectors both makes e_k and bends e_k along that direction, so
/// Σ e_k ∇²e_k takes that share back. (A blind check: rolled with no wobble, 5000 readings, σ 1 %: JᵀJ gave SEs of
/// 0.5° for errors of 31°, "identifiable".) With g = d·v = sin e, v = R ĥ, a small rotation θ: ∇g = v × d,
/// ∇²g = ½(d vᵀ + v dᵀ) − g I, and e = asin g, so ∇²e = ∇²g / cos e + g / cos³e ∇g ∇gᵀ; δ enters linearly.
Eigen::Matrix4d cost_hessian(const Samples& down, const Samples& dir, const Eigen::Matrix3d& r,
                             const Eigen::Matrix<double, Eigen::Dynamic, 4>& j, const Eigen::VectorXd& e) {
  Eigen::Matrix4d h = j.transpose() * j;
  for (Eigen::Index k = 0; k < down.rows(); ++k) {
    const Eigen::Vector3d v = r * dir.row(k).transpose(), d = down.row(k).transpose(), across = v.cross(d);
    const double c = across.norm(), g = d.dot(v);
    if (!(c > 0)) continue;  // a field exactly along gravity: no rotation seen (its row of J is 0 too)
    const Eigen::Matrix3d g2 = 0.5 * (d * v.transpose() + v * d.transpose()) - g * Eigen::Matrix3d::Identity();
    h.topLeftCorner<3, 3>() += e(k) * (g2 / c + (g / (c * c * c)) * across * across.transpose());
  }
  return h;
}

/// The covariance at the fit, σ̂² H⁻¹ JᵀJ H⁻¹ (H the cost's Hessian, cost_hessian: the sandwich of an M-estimator;
/// σ̂²(JᵀJ)⁻¹ where the attitudes are spread, as H = JᵀJ there), and whether every standard error is within
/// options.max_se_deg. A direction the data do not see (an eigenvalue of H near 0, or below: not a minimum along it)
/// gets a huge but finite variance.
void covariance(const Samples& down, const Samples& dir, Fit& fit, const AlignmentOptions& options) {
  Eigen::Matrix<double, Eigen::Dynamic, 4> j;
  Eigen::VectorXd e;
  linearise(down, dir, fit.rotation, fit.dip, j, e);
  fit.sigma2 = residual_variance(fit.cost, down.rows());
  const Eigen::Matrix4d jtj = j.transpose() * j;
  const detail::SymmetricEigen<4> eig = detail::symmetric_eigen(cost_hessian(down, dir, fit.rotation, j, e));
  const double floor = 1e-12 * std::max(eig.values(3), 1e-300);
  // H not positive definite: some direction is no minimum of the cost (its curvature there all noise: a level turn's
  // rotation about the vertical). Clamped and squared in the sandwich, that direction's tilt spread huge variances to
  // every parameter (a review: a level swing's dip read ±63913°); σ̂²(JᵀJ)⁻¹ names the undetermined axes as before,
  // and the fit is flagged (flat_cost).
  fit.flat_cost = !(eig.values(0) > floor);
  const detail::SymmetricEigen<4> used = fit.flat_cost ? detail::symmetric_eigen(jtj) : eig;
  const double used_floor = 1e-12 * std::max(used.values(3), 1e-300);
  fit.singular = !(used.values(0) > used_floor);
  const Eigen::Vector4d inverse = used.values.cwiseMax(used_floor).cwiseInverse();
  fit.inverse = used.vectors * inverse.asDiagonal() * used.vectors.transpose();
  fit.covariance = fit.flat_cost ? (fit.sigma2 * fit.inverse).eval() : (fit.sigma2 * fit.inverse * jtj * fit.inverse).eval();
  fit.covariance = 0.5 * (fit.covariance + fit.covariance.transpose()).eval();
  fit.identifiable = !fit.flat_cost &&
                     (fit.covariance.diagonal().cwiseMax(0.0).cwiseSqrt() * kDeg).maxCoeff() <= options.max_se_deg;
}

/// The fit from the two starts (the linear one and R = I), the one kept as described below.
Fit solve(const Samples& down, const Samples& dir, const AlignmentOptions& options) {
  const Eigen::Index n = down.rows();
  // Start: d_kᵀ M ĥ_k − s = 0 for all k, the unit vector (vec M, s) of least residual.
  Eigen::Matrix<double, Eigen::Dynamic, 10> a(n, 10);
  for (Eigen::Index k = 0; k < n; ++k) {
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) a(k, 3 * i + j) = down(k, i) * dir(k, j);
    a(k, 9) = -1.0;
  }
  const Eigen::Matrix<double, 10, 10> ata = a.transpose() * a;
  Eigen::Matrix<double, 10, 1> x = detail::symmetric_eigen(ata).vectors.col(0);
  Eigen::Matrix3d m;
  m << x(0), x(1), x(2), x(3), x(4), x(5), x(6), x(7), x(8);
  if (m.determinant() < 0) {
    m = -m;
    x = -x;
  }
  const double scale = Eigen::JacobiSVD<Eigen::Matrix3d>(m).singularValues().mean();
  const double dip = start_dip(std::asin(std::clamp(scale > 0 ? x(9) / scale : 0.0, -1.0, 1.0)));

  // Damped Gauss–Newton from there and from R = I (a mounting is usually nearly aligned). Neither moves along a
  // direction the data leave undetermined (turns about one axis), so the R = I fit keeps the mounted heading
  // there, while the linear start's place along it is arbitrary — even the mirror family (R flipped 180° about
  // a horizontal axis, the dip negated). The linear start wins when it ends at half the cost or less (R = I sat
  // in another basin: axes relabelled or turned far), or when it alone is identifiable, or both are and it is
  // lower; otherwise the R = I fit is kept.
  Eigen::VectorXd cosines = (down.cwiseProduct(dir)).rowwise().sum();
  std::sort(cosines.data(), cosines.data() + cosines.size());
  Fit linear = gauss_newton(down, dir, nearest_rotation(m), dip, options);
  Fit aligned = gauss_newton(down, dir, Eigen::Matrix3d::Identity(),
                             start_dip(std::asin(std::clamp(cosines(cosines.size() / 2), -1.0, 1.0))), options);
  for (Fit* f : {&linear, &aligned}) covariance(down, dir, *f, options);
  const bool clearly_lower = linear.cost < 0.5 * aligned.cost;  // half the cost: R = I sits in another basin
  // identifiable alone wins only where it fits about as well (within a 5σ likelihood ratio): a clustered hand turn's
  // linear start had stopped in a false minimum at 4× the cost, 25° off, "identifiable" beside an R = I fit whose
  // SEs were 1.2–1.3° (a review)
  const double tie = 25.0 * std::max(aligned.sigma2, 1e-300);
  return clearly_lower || (linear.identifiable && (aligned.identifiable ? linear.cost < 0.99 * aligned.cost
                                                                         : linear.cost < aligned.cost + tie))
             ? linear : aligned;
}

double median_of(Eigen::VectorXd v) {
  std::sort(v.data(), v.data() + v.size());
  const Eigen::Index h = v.size() / 2;
  return v.size() % 2 ? v(h) : 0.5 * (v(h - 1) + v(h));
}

}  // namespace

AlignmentResult align_to_gravity(const SamplesRef& field, const SamplesRef& specific_force,
                                 const AlignmentOptions& options) {
  field.require_width("field");
  specific_force.require_width("specific_force");
  if (!(options.max_iterations >= 1))
    throw Error("AlignmentOptions::max_iterations: " + std::to_string(options.max_iterations) + ", need ≥ 1");
  if (!(options.serial_correlation_alpha > 0.0 && options.serial_correlation_alpha < 1.0))
    throw Error("AlignmentOptions::serial_correlation_alpha: " + detail::num(options.serial_correlation_alpha) +
                ", need a significance level in (0, 1)");
  // +inf stays allowed (max_se_deg = inf: never flag an axis), as before
  detail::require(options.tolerance > 0.0, "AlignmentOptions::tolerance", options.tolerance, "a step > 0 (radians)");
  detail::require(options.max_se_deg > 0.0, "AlignmentOptions::max_se_deg", options.max_se_deg,
                  "a standard error in degrees > 0");
  detail::require(!std::isnan(options.max_dynamic), "AlignmentOptions::max_dynamic", options.max_dynamic,
                  "a fraction of the median |f| (≤ 0 keeps every reading)");
  check_samples(field, "field", 8, "a rotation and the dip");
  check_samples(specific_force, "specific_force", 8, "a rotation and the dip");
  if (field.rows() != specific_force.rows())
    throw Error("specific_force: " + std::to_string(specific_force.rows()) + " rows, field has " +
                std::to_string(field.rows()) + " (one accelerometer reading per field reading)");
  const Eigen::VectorXd field_norm = field.rowwise().norm(), force_norm = specific_force.rowwise().norm();
  for (Eigen::Index k = 0; k < field.rows(); ++k) {
    if (!(field_norm(k) > 0)) throw Error("field: row " + std::to_string(k) + " is zero (no direction)");
    if (!(force_norm(k) > 0)) throw Error("specific_force: row " + std::to_string(k) + " is zero (no direction)");
  }

  // Static readings only: |f| near its median (the device was not accelerating).
  Eigen::VectorXd sorted = force_norm;
  std::sort(sorted.data(), sorted.data() + sorted.size());
  const double median = sorted(sorted.size() / 2);
  std::vector<Eigen::Index> keep;
  for (Eigen::Index k = 0; k < field.rows(); ++k)
    if (options.max_dynamic <= 0 || std::abs(force_norm(k) - median) <= options.max_dynamic * median) keep.push_back(k);
  auto n = static_cast<Eigen::Index>(keep.size());
  if (n < 8)
    throw Error("specific_force: " + std::to_string(n) + " of " + std::to_string(field.rows()) +
                " readings have |f| within " + detail::percent(options.max_dynamic) +
                " of the median: the device was moving; need at least 8 at rest (or raise max_dynamic)");
  Samples down(n, 3), dir(n, 3);
  for (Eigen::Index i = 0; i < n; ++i) {
    down.row(i) = -specific_force.row(keep[i]) / force_norm(keep[i]);
    dir.row(i) = field.row(keep[i]) / field_norm(keep[i]);
  }

  AlignmentResult result;
  Summary& s = result.summary;
  if (n < field.rows())
    s.warnings.push_back(std::to_string(field.rows() - n) + " of " + std::to_string(field.rows()) +
                         " readings left out: |f| more than " + detail::percent(options.max_dynamic) +
                         " from its median (the device was accelerating)");

  Fit best = solve(down, dir, options);

  // Outliers (a spike, a knock): readings whose dip residual is more than 5 robust SDs (1.4826 MAD) off are left
  // out and the fit run again, until none is (at most 5 rounds: a first fit bent by many outliers hides some);
  // one such reading had turned R by 1.8° and 5 % of them had stopped the fit.
  Eigen::Index outliers = 0;
  for (int round = 0; round < 5; ++round) {
    const Eigen::VectorXd residual = residuals(down, dir, best.rotation, best.dip);
    const double centre = median_of(residual), spread = 1.4826 * median_of((residual.array() - centre).abs());
    std::vector<Eigen::Index> inliers;
    for (Eigen::Index i = 0; i < n; ++i)
      if (!(std::abs(residual(i) - centre) > 5.0 * spread)) inliers.push_back(i);
    if (!(spread > 0) || static_cast<Eigen::Index>(inliers.size()) == n || inliers.size() < 8) break;
    outliers += n - static_cast<Eigen::Index>(inliers.size());
    std::vector<Eigen::Index> kept;
    for (Eigen::Index i : inliers) kept.push_back(keep[i]);
    keep = kept;
    n = static_cast<Eigen::Index>(keep.size());
    down = down(inliers, Eigen::all).eval();
    dir = dir(inliers, Eigen::all).eval();
    best = solve(down, dir, options);
  }
  if (outliers > 0)
    s.warnings.push_back(std::to_string(outliers) +
                         " readings left out as outliers: their dip residual was more than 5 robust SDs off");
  result.readings_used = static_cast<std::size_t>(n);
  s.samples = result.readings_used;

  // Tilts all about one body axis n (the down directions in one plane) leave a second answer that fits as well:
  // R turned 180° about n with the dip negated (n's half turn reverses every down direction in the plane). Found
  // by fitting from there; when it is as good (within what noise alone makes, below), the one nearer the axes as
  // mounted is kept and the result is flagged: the data cannot tell them apart.
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> plane(down.transpose() * down);
  const Eigen::Matrix3d half_turn = Eigen::AngleAxisd(kPi, plane.eigenvectors().col(0)).toRotationMatrix();
  // The plane's thickness (mean square of the down directions across it) against the direction noise σ_h² + σ_f²
  // (the residual variance): within twice that, the tilts may have been about one axis, and noise alone moves the two
  // costs apart by tens of σ̂² (it picked the wrong answer at 34 σ̂² lower cost in a blind check).
  const double thickness = plane.eigenvalues()(0) / static_cast<double>(n);
  // The mirror start costs as much as the fit when the tilts were about one axis, and more by about N × thickness
  // otherwise; 1000 σ̂² above it the other branch is out of reach, and the fit from there (crawling through a cost
  // hundreds of times the best one's) would take most of the alignment's time: it is skipped.
  const Eigen::Matrix3d mirror_start = half_turn * best.rotation;
  Fit mirror = best;
  if (thickness <= 2.0 * best.sigma2 || cost(down, dir, mirror_start, -best.dip) < best.cost + 1000.0 * best.sigma2) {
    mirror = gauss_newton(down, dir, mirror_start, start_dip(-best.dip), options);
    covariance(down, dir, mirror, options);
  }
  const bool other_branch = Eigen::AngleAxisd(mirror.rotation * best.rotation.transpose()).angle() > kPi / 2;
  // How far apart the two branches' costs may lie on noise alone. Tilts exactly about n: the mirror's residuals are
  // −e_k + 2a_k, a_k the part of e_k that the down direction's noise across the plane makes, so the costs differ by
  // −4 Σ (e_k − a_k) a_k, of SD at most 2√N σ̂² (measured: 1.4–1.9 √N σ̂² with the noise split evenly, 0.2–0.4 when
  // the magnetometer's dominates; skewed: 0.1–0.3 % of exact planes go past +10√N σ̂² and are called decided, none
  // below −4√N). 5 of those SDs; a plane only as thick as the noise can still be tilted out of by a little at every
  // reading (a 0.6° wobble at 1 % noise and N 1000 made the mirror 500 σ̂² dearer: the data decide). Otherwise a 5σ
  // likelihood ratio, 25 σ̂².
  const double tie = (thickness <= 2.0 * best.sigma2 ? 10.0 * std::sqrt(static_cast<double>(n)) : 25.0) * best.sigma2;
  bool ambiguous = false;
  if (other_branch && mirror.cost < best.cost - tie) {
    best = mirror;  // the other branch fits clearly better
  } else if (other_branch && mirror.cost < best.cost + tie) {
    ambiguous = true;
    if (Eigen::AngleAxisd(mirror.rotation).angle() < Eigen::AngleAxisd(best.rotation).angle()) best = mirror;
    const Eigen::Vector3d axis = plane.eigenvectors().col(0);
    s.warnings.push_back("not identifiable: two answers fit equally — this one and the rotation turned 180° about (" +
                         detail::num(axis.x()) + ", " + detail::num(axis.y()) + ", " + detail::num(axis.z()) +
                         ") with the dip negated: every tilt was about that one axis; tilt the device about a second "
                         "axis (the one nearer the axes as mounted is returned)");
  }
  s.iterations = best.iterations;
  s.converged = best.converged;
  const Eigen::Matrix3d r = best.rotation;
  double dip = best.dip;
  const double current = best.cost, sigma2 = best.sigma2;
  // Readings correlated in time: the Newey–West sandwich over the scores J_kᵀe_k (rows in time order; those left
  // out are skipped over), taken as refine takes it — also when some direction is poorly determined (a level turn:
  // the dip's SE must still widen), not where H is singular.
  Eigen::MatrixXd cov = best.covariance;
  Eigen::Matrix<double, Eigen::Dynamic, 4> j;
  Eigen::VectorXd e;
  linearise(down, dir, best.rotation, best.dip, j, e);
  const Eigen::MatrixXd scores = j.array().colwise() * e.array();
  const std::string correlated = detail::correct_for_serial_correlation(
      cov, result.serial_correlation, e, scores, best.inverse, best.singular,
      options.serial_correlation, options.serial_correlation_alpha);
  // Residuals that drift with the attitude are also what a sensor error this model leaves out makes (a blind check:
  // a 0.02 g accelerometer offset on a slow turn gave mean errors of 3–7 SDs, this correlation its only sign). A test
  // of the residuals against attitude regressors had little power once the regressors' own noise, which correlates
  // with the residuals', was kept out of it (36 % at that size), so the cause is named here instead — whether or not
  // the covariance was widened (the bias is not in the standard errors).
  const std::string follows = "or the residuals follow the attitude: a sensor error this fit does not model (an "
                              "accelerometer offset or scale error — fluxcal.positions.calibrate_accelerometer —, the "
                              "magnetometer's calibration off) biases R and the dip beyond any standard error";
  const bool drifting = result.serial_correlation.ljung_box_p < options.serial_correlation_alpha;
  if (!correlated.empty())
    s.warnings.push_back(correlated + (drifting ? "; " + follows : ""));
  else if (drifting)
    s.warnings.push_back("the dip residuals are correlated in time (Ljung-Box p = " +
                         detail::num(result.serial_correlation.ljung_box_p) + "): slowly varying noise, " + follows);
  result.covariance = cov;
  result.standard_errors = result.covariance.diagonal().cwiseMax(0.0).cwiseSqrt();

  // Noise across the plane of the two directions only widens the angle between them (by ≈ s²/2 · cot α for an
  // offset s, α = 90° − δ their angle), so the dip comes out nearer 0 by ≈ (σ_h² + σ_f²)/2 · tan δ; σ_h² + σ_f² is
  // the residual variance. Adding it back removes the bias (the rotation has none to first order).
  if (options.noise_bias_correction && sigma2 < 0.5)
    dip = std::clamp(dip + 0.5 * sigma2 * std::tan(dip), -kPi / 2, kPi / 2);

  result.residuals = Eigen::VectorXd::Constant(field.rows(), std::numeric_limits<double>::quiet_NaN());
  for (Eigen::Index i = 0; i < n; ++i) result.residuals(keep[i]) = e(i);
  result.rotation = r;
  const Eigen::AngleAxisd aa(r);
  result.rotation_vector = aa.angle() * aa.axis();
  result.dip = dip;
  result.residual_rms = std::sqrt(current / static_cast<double>(n));
  // Not determined: by the attitudes (the independent-readings error), or only once widened for the correlation.
  static const char* const kNames[] = {"x", "y", "z", "dip"};
  std::string unmoved, widened;
  for (int i = 0; i < 4; ++i) {
    const std::string name = i < 3 ? std::string("the rotation about ") + kNames[i] : "the dip";
    std::string& list = !(result.serial_correlation.standard_errors_independent(i) * kDeg <= options.max_se_deg)
                            ? unmoved : widened;
    if (!(result.standard_errors(i) * kDeg <= options.max_se_deg)) list += (list.empty() ? "" : ", ") + name;
  }
  // Within 3 noise SDs of vertical the field's horizontal part, which fixes the rotation about the vertical, is near
  // the noise (at the magnetic pole a compass has no north), and the angle between the two directions is of the
  // order of the noise: on a poorly spread turn least squares slides towards the pole, where that angle's spread is
  // smaller (a blind check: a true 85° on a 3° hand turn read 88.7°, 3–4° off against SEs of 0.2°). With attitudes
  // spread well it is right (86° at 1.6° noise: 0.1° off), so this is said, not flagged.
  if (kPi / 2 - std::abs(dip) < 3.0 * std::sqrt(sigma2))
    s.warnings.push_back("the field is within 3 noise SDs (" + detail::num(3.0 * std::sqrt(sigma2) * kDeg) +
                         "°) of vertical: its horizontal part, which fixes the rotation about the vertical, is near "
                         "the noise, and the fit may lie beyond its standard errors: several degrees towards vertical "
                         "on a poorly spread turn, tenths of a degree either way on a widely spread one (quieter "
                         "readings, or averaging each attitude at rest, help)");
  result.identifiable = unmoved.empty() && widened.empty() && !ambiguous && !best.flat_cost;
  if (best.flat_cost && unmoved.empty())
    s.warnings.push_back("not identifiable: the cost does not curve up along every direction at the fit (its Hessian "
                         "is not positive definite): some combination of the rotation and the dip is not determined, "
                         "though σ²(JᵀJ)⁻¹ shows none (the noise lends JᵀJ information there); turn the device about "
                         "more axes");
  if (!unmoved.empty())
    s.warnings.push_back("not identifiable: " + unmoved + " not determined to " + detail::num(options.max_se_deg) +
                         "° (the attitudes did not move about every axis: tilt the device, not only turn it "
                         "level; a rotation about the vertical needs tilts about two horizontal axes)");
  if (!widened.empty())
    s.warnings.push_back("not identifiable: " + widened + " not determined to " + detail::num(options.max_se_deg) +
                         "° once the standard errors are widened for the correlation in time (more readings, or "
                         "turns about more axes)");
  if (dip < -2.0 * result.standard_errors(3))  // not on noise around a dip of 0
    s.warnings.push_back("the dip is negative (the field points up): right in the southern hemisphere; in the "
                         "northern one either the accelerometer reports gravity (down) rather than the specific force "
                         "(up) — say so (acc_measures gravity) and the dip turns positive with the same rotation — or "
                         "the magnetometer's axes are a mirror image of the accelerometer's (one axis reversed), which "
                         "a rotation cannot undo: fix that axis's sign");
  if (!s.converged)
    s.warnings.push_back("not converged after " + std::to_string(s.iterations) + " iterations");
  s.residual_rms = result.residual_rms;
  s.cost = current / static_cast<double>(n);
  s.message = "magnetometer to accelerometer: " + detail::num(aa.angle() * kDeg) + "° rotation, dip " +
              detail::num(dip * kDeg) + "° (±" + detail::num(result.standard_errors(3) * kDeg) + "°), " +
              std::to_string(n) + " static readings";
  return result;
}

}  // namespace fluxcal
