#include "fluxcal/positions.hpp"

#include "fluxcal/ellipsoid.hpp"
#include "checks.hpp"
#include "linalg.hpp"

#include <Eigen/Sparse>
#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

namespace fluxcal {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr const char* kAxis = "xyz";

std::string fmt(double v, int precision = 4) {
  std::ostringstream s;
  s.precision(precision);
  s << v;
  return s.str();
}

std::string vec_str(const Eigen::Vector3d& v, int precision = 3) {
  return "(" + fmt(v(0), precision) + ", " + fmt(v(1), precision) + ", " + fmt(v(2), precision) + ")";
}

// Field in the heading-corrected frame: Hrot(ψ)ᵀ f, Hrot the rotation by ψ about local up
// (ned: Rz(ψ); nue: Ry(−ψ)). Templated for Ceres autodiff.
template <typename T>
void unrotate_heading(const T& psi, const T* f, Frame frame, T* out) {
  using std::cos;
  using std::sin;
  const T c = cos(psi), s = sin(psi);
  if (frame == Frame::ned) {
    out[0] = c * f[0] + s * f[1];
    out[1] = -s * f[0] + c * f[1];
    out[2] = f[2];
  } else {
    out[0] = c * f[0] + s * f[2];
    out[1] = f[1];
    out[2] = -s * f[0] + c * f[2];
  }
}

// Local field with inclination I: F (cos I · ĥ + sin I · d̂), ĥ the given field's horizontal
// direction, d̂ local down.
template <typename T>
void field_with_inclination(const T& inc, double magnitude, const Eigen::Vector3d& horizontal_dir,
                            const Eigen::Vector3d& down, T* out) {
  using std::cos;
  using std::sin;
  for (int k = 0; k < 3; ++k) out[k] = magnitude * (cos(inc) * horizontal_dir(k) + sin(inc) * down(k));
}

// Residual of one position: U_i − U0 − K Lᵢᵀ R(−w_i) Hrot(ψ_i)ᵀ f(I), with w_i = t_n n̂ + t_e ê a small
// levelling correction about the local horizontal axes (held at 0 unless tilt_sigma_deg > 0).
struct PositionResidual {
  Eigen::Vector3d output;
  Eigen::Matrix3d level_t;  // Lᵢᵀ
  Eigen::Vector3d field, horizontal_dir, down, north, east;
  double magnitude;
  Frame frame;
  bool with_inclination;

  template <typename T>
  bool operator()(const T* const u0, const T* const k, const T* const psi, const T* const inc, const T* const tilt,
                  T* r) const {
    T f[3];
    if (with_inclination) {
      field_with_inclination(inc[0], magnitude, horizontal_dir, down, f);
    } else {
      for (int j = 0; j < 3; ++j) f[j] = T(field(j));
    }
    T g[3], w[3], gt[3], h[3];
    unrotate_heading(psi[0], f, frame, g);
    for (int j = 0; j < 3; ++j) w[j] = -(tilt[0] * north(j) + tilt[1] * east(j));
    ceres::AngleAxisRotatePoint(w, g, gt);
    for (int j = 0; j < 3; ++j) h[j] = level_t(j, 0) * gt[0] + level_t(j, 1) * gt[1] + level_t(j, 2) * gt[2];
    for (int j = 0; j < 3; ++j) {
      r[j] = T(output(j)) - u0[j] - (k[3 * j] * h[0] + k[3 * j + 1] * h[1] + k[3 * j + 2] * h[2]);
    }
    return true;
  }
};

// Prior on a levelling correction: (t_n, t_e) · weight, weight = σ_output / σ_tilt (shared, updated
// between passes as the output noise estimate improves).
struct TiltPrior {
  const double* weight;
  template <typename T>
  bool operator()(const T* const tilt, T* r) const {
    r[0] = tilt[0] * T(*weight);
    r[1] = tilt[1] * T(*weight);
    return true;
  }
};

// Pseudo-inverse of a symmetric positive semi-definite matrix by eigen-decomposition; marks the
// coordinates that take part in a near-null direction (relative eigenvalue < 1e-14).
Eigen::MatrixXd spd_pinv(const Eigen::MatrixXd& M, std::vector<bool>& null_coord, double* condition = nullptr) {
  const Eigen::Index n = M.rows();
  null_coord.assign(static_cast<std::size_t>(n), false);
  if (n == 0) return M;
  const detail::SymmetricEigen<Eigen::Dynamic> eig = detail::symmetric_eigen(M);
  const Eigen::VectorXd& ev = eig.values;
  const double evmax = std::max(ev.maxCoeff(), 0.0), floor = evmax * 1e-14;
  if (condition)
    *condition = ev.minCoeff() > 0 ? std::sqrt(evmax / ev.minCoeff()) : std::numeric_limits<double>::infinity();
  Eigen::VectorXd inv = Eigen::VectorXd::Zero(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    if (ev(i) > floor && ev(i) > 0) {
      inv(i) = 1.0 / ev(i);
    } else {
      for (Eigen::Index j = 0; j < n; ++j)
        if (std::abs(eig.vectors(j, i)) > 1e-3) null_coord[static_cast<std::size_t>(j)] = true;
    }
  }
  return eig.vectors * inv.asDiagonal() * eig.vectors.transpose();
}

// Statistics shared by the linear and the joint fit: σ̂ and the covariance σ̂²(JᵀJ)⁻¹ of the
// column-scaled Jacobian (near-null directions → +inf, undetermined). `local[j]` ≥ 0 marks parameter j
// as belonging to position local[j] only (heading, levelling correction): those are eliminated by the
// Schur complement, so the cost is O(N) in the number of positions instead of O(N³). J is sparse
// (row-major) so that nothing of size rows × parameters is ever formed.
using SparseRows = Eigen::SparseMatrix<double, Eigen::RowMajor>;
// `prior_ss`: the sum of squares of J's prior rows (the tilt prior, in output units), part of the SSR;
// `known_sigma` > 0: the output noise σ the caller knows, which then scales the standard errors — or, `floor`, the
// least σ they take: σ̂ when the residuals say more (a misfit the σ given does not allow).
void finish_statistics(PositionsResult& r, const SparseRows& J, const Eigen::VectorXd& scales, double tolerance,
                       const std::vector<int>& local = {}, double prior_ss = 0.0, double known_sigma = 0.0,
                       bool floor = false) {
  const Eigen::Index p = J.cols(), m = J.rows();
  const double ssr = r.residuals.squaredNorm() + prior_ss;
  // No spare equation: the fit is exact and says nothing about the noise (σ̂ = 0 made every standard
  // error 0 and every parameter "determined" while U0 was off by 0.5 mV).
  const bool exact = m <= p;
  r.noise_sigma = exact ? std::numeric_limits<double>::quiet_NaN() : std::sqrt(ssr / static_cast<double>(m - p));
  const bool known = known_sigma > 0.0 && !(floor && r.noise_sigma > known_sigma);
  const double se_sigma = known ? known_sigma : r.noise_sigma;
  r.noise_dof = known ? std::numeric_limits<double>::infinity() : exact ? 0.0 : static_cast<double>(m - p);
  if (exact)
    r.summary.warnings.push_back(
        "as many equations as unknowns (" + std::to_string(m) + " for " + std::to_string(p) +
        "): the fit is exact, so it cannot estimate the noise σ" +
        (known_sigma > 0.0 ? " (the standard errors take the σ given, and cannot show what the model misses: "
                             "levelling, headings, a disturbed position)"
                           : " or the standard errors (NaN)") + "; add positions");
  Eigen::VectorXd colnorm = Eigen::VectorXd::Zero(p);
  for (Eigen::Index i = 0; i < m; ++i)
    for (SparseRows::InnerIterator it(J, i); it; ++it) colnorm(it.col()) += it.value() * it.value();
  for (Eigen::Index j = 0; j < p; ++j) colnorm(j) = colnorm(j) > 0 ? std::sqrt(colnorm(j)) : 1.0;
  // Global parameters get a dense column index; local ones an index within their position's block.
  std::vector<Eigen::Index> global;
  std::vector<Eigen::Index> index_of(static_cast<std::size_t>(p), -1);
  int groups = 0;
  for (Eigen::Index j = 0; j < p; ++j) {
    const int g = local.empty() ? -1 : local[static_cast<std::size_t>(j)];
    if (g < 0) {
      index_of[static_cast<std::size_t>(j)] = static_cast<Eigen::Index>(global.size());
      global.push_back(j);
    }
    groups = std::max(groups, g + 1);
  }
  std::vector<std::vector<Eigen::Index>> cols(static_cast<std::size_t>(groups)), rows(static_cast<std::size_t>(groups));
  for (Eigen::Index j = 0; j < p; ++j)
    if (!local.empty() && local[static_cast<std::size_t>(j)] >= 0) {
      auto& c = cols[static_cast<std::size_t>(local[static_cast<std::size_t>(j)])];
      index_of[static_cast<std::size_t>(j)] = static_cast<Eigen::Index>(c.size());
      c.push_back(j);
    }
  // Each row (one position's residual, or its tilt prior) touches the local parameters of at most one
  // position.
  for (Eigen::Index i = 0; i < m; ++i)
    for (SparseRows::InnerIterator it(J, i); it; ++it) {
      const int g = local.empty() ? -1 : local[static_cast<std::size_t>(it.col())];
      if (g >= 0 && it.value() != 0.0) {
        rows[static_cast<std::size_t>(g)].push_back(i);
        break;
      }
    }
  const Eigen::Index ng = static_cast<Eigen::Index>(global.size());
  Eigen::MatrixXd JG = Eigen::MatrixXd::Zero(m, ng);  // scaled global columns (ng ≤ 13)
  for (Eigen::Index i = 0; i < m; ++i)
    for (SparseRows::InnerIterator it(J, i); it; ++it)
      if (local.empty() || local[static_cast<std::size_t>(it.col())] < 0)
        JG(i, index_of[static_cast<std::size_t>(it.col())]) = it.value() / colnorm(it.col());
  Eigen::MatrixXd S = JG.transpose() * JG;
  std::vector<Eigen::MatrixXd> Cinv(static_cast<std::size_t>(groups)), B(static_cast<std::size_t>(groups));
  std::vector<std::vector<bool>> null_local(static_cast<std::size_t>(groups));
  for (int g = 0; g < groups; ++g) {
    const auto& R = rows[static_cast<std::size_t>(g)];
    const auto& L = cols[static_cast<std::size_t>(g)];
    Eigen::MatrixXd JL = Eigen::MatrixXd::Zero(static_cast<Eigen::Index>(R.size()), static_cast<Eigen::Index>(L.size()));
    Eigen::MatrixXd JGr(static_cast<Eigen::Index>(R.size()), ng);
    for (std::size_t a = 0; a < R.size(); ++a) {
      for (SparseRows::InnerIterator it(J, R[a]); it; ++it)
        if (local[static_cast<std::size_t>(it.col())] == g)
          JL(static_cast<Eigen::Index>(a), index_of[static_cast<std::size_t>(it.col())]) = it.value() / colnorm(it.col());
      JGr.row(static_cast<Eigen::Index>(a)) = JG.row(R[a]);
    }
    Cinv[static_cast<std::size_t>(g)] = spd_pinv(JL.transpose() * JL, null_local[static_cast<std::size_t>(g)]);
    B[static_cast<std::size_t>(g)] = JGr.transpose() * JL;
    S -= B[static_cast<std::size_t>(g)] * Cinv[static_cast<std::size_t>(g)] * B[static_cast<std::size_t>(g)].transpose();
  }
  std::vector<bool> null_global;
  double condition = 0.0;
  const Eigen::MatrixXd Sinv = spd_pinv(0.5 * (S + S.transpose()), null_global, &condition);
  r.summary.condition_number = condition;
  Eigen::VectorXd var(p);
  std::vector<bool> null_dir(static_cast<std::size_t>(p), false);
  for (Eigen::Index c = 0; c < ng; ++c) {
    var(global[static_cast<std::size_t>(c)]) = Sinv(c, c);
    null_dir[static_cast<std::size_t>(global[static_cast<std::size_t>(c)])] = null_global[static_cast<std::size_t>(c)];
  }
  bool any_null_global = false;
  for (bool b : null_global) any_null_global = any_null_global || b;
  for (int g = 0; g < groups; ++g) {
    const Eigen::MatrixXd& Ci = Cinv[static_cast<std::size_t>(g)];
    const Eigen::MatrixXd V = Ci + Ci * B[static_cast<std::size_t>(g)].transpose() * Sinv * B[static_cast<std::size_t>(g)] * Ci;
    const auto& L = cols[static_cast<std::size_t>(g)];
    for (std::size_t c = 0; c < L.size(); ++c) {
      var(L[c]) = V(static_cast<Eigen::Index>(c), static_cast<Eigen::Index>(c));
      // A local parameter is undetermined if its own block is singular, or if it couples to an
      // undetermined global direction.
      bool null = null_local[static_cast<std::size_t>(g)][c];
      if (any_null_global) {
        const Eigen::VectorXd coupling = (Ci * B[static_cast<std::size_t>(g)].transpose()).row(static_cast<Eigen::Index>(c));
        for (Eigen::Index k = 0; k < ng; ++k)
          if (null_global[static_cast<std::size_t>(k)] && std::abs(coupling(k)) > 1e-6) null = true;
      }
      null_dir[static_cast<std::size_t>(L[c])] = null;
    }
  }
  r.standard_errors.resize(p);
  r.determined.assign(static_cast<std::size_t>(p), true);
  for (Eigen::Index j = 0; j < p; ++j) {
    const bool null = null_dir[static_cast<std::size_t>(j)];
    r.standard_errors(j) = null ? std::numeric_limits<double>::infinity()
                                : se_sigma * std::sqrt(std::max(var(j), 0.0)) / colnorm(j);
    r.determined[static_cast<std::size_t>(j)] =
        !null && (std::isnan(se_sigma) || r.standard_errors(j) <= tolerance * scales(j));  // exact: geometry only
  }
}

// The size of K's gains for "determined": its RMS gain per axis, ‖K‖_F/√3. The mean of |diag K| was ~0 for
// a K that relabels axes (SAP6: +y, +x, +z) and flagged parameters known to 0.5 % of the gain.
double gain_scale(const Eigen::Matrix3d& k) { return k.norm() / std::sqrt(3.0); }

std::vector<std::string> base_names() {
  std::vector<std::string> names;
  for (int j = 0; j < 3; ++j) names.push_back(std::string("U0_") + kAxis[j]);
  for (int j = 0; j < 3; ++j)
    for (int k = 0; k < 3; ++k) names.push_back(std::string("K_") + kAxis[j] + kAxis[k]);
  return names;
}

void check_field(const Eigen::Vector3d& field) {
  if (!field.allFinite() || field.norm() == 0.0) {
    throw Error("field: the local reference field is missing (zero or not finite); give it as (N, E, D), as "
                "(total, inclination, declination) or from a geomagnetic model (IGRF/WMM) for the place and date");
  }
}

void fill_summary(PositionsResult& r, const char* what) {
  const Eigen::Index n = r.residuals.rows();
  r.summary.samples = static_cast<std::size_t>(n);
  r.summary.residual_rms = n > 0 ? std::sqrt(r.residuals.squaredNorm() / static_cast<double>(3 * n)) : 0.0;
  r.summary.cost = n > 0 ? r.residuals.squaredNorm() / static_cast<double>(n) : 0.0;
  r.summary.converged = true;
  std::ostringstream msg;
  msg << what << ": " << n << " positions, residual RMS " << fmt(r.summary.residual_rms)
      << (r.units.empty() ? "" : " " + r.units) << ", condition number " << fmt(r.summary.condition_number, 3);
  // Named one by one, but for the per-position unknowns (headings, levelling tilts): a long log's hundreds of
  // yaw_i are counted (a stream of 885 rows taken as positions had listed 894 names in one 7 kB line).
  const auto kind = [](const std::string& name) -> int {  // 0: named; 1–3: per position
    if (name.rfind("yaw_", 0) == 0) return 1;
    if (name.rfind("tilt_", 0) != 0) return 0;
    return name.size() >= 6 && name.compare(name.size() - 6, 6, "_north") == 0 ? 2 : 3;
  };
  constexpr const char* kKinds[4] = {"", "headings", "north tilts", "east tilts"};
  std::vector<std::string> poor[4];
  std::size_t all[4] = {0, 0, 0, 0};
  for (std::size_t j = 0; j < r.determined.size(); ++j) {
    const int k = kind(r.parameter_names[j]);
    ++all[k];
    if (!r.determined[j]) poor[k].push_back(r.parameter_names[j]);
  }
  const std::size_t total = poor[0].size() + poor[1].size() + poor[2].size() + poor[3].size();
  if (total > 0) {
    std::ostringstream w;
    w << total << " parameter(s) poorly determined:";
    constexpr std::size_t kListed = 6;
    bool listed = false;  // (a count follows names or another count after a semicolon)
    for (int k = 0; k < 4; ++k) {
      if (k == 0 || poor[k].size() <= kListed)
        for (const std::string& name : poor[k]) w << " " << name;
      else
        w << (listed ? "; " : " ") << poor[k].size() << " of the " << all[k] << " " << kKinds[k] << " (first "
          << poor[k].front() << ", last " << poor[k].back() << ")";
      listed = listed || !poor[k].empty();
    }
    r.summary.warnings.push_back(w.str());
  }
  r.summary.message = msg.str();
}

Eigen::Vector3d unit_up_from(const Eigen::Vector3d& sf, Eigen::Index row) {
  const double n = sf.norm();
  if (!(n > 0.0) || !std::isfinite(n)) {
    throw Error("specific_force: row " + std::to_string(row) + " is zero or not finite");
  }
  return sf / n;
}

void check_gravity(const SamplesRef& sf, const PositionsOptions& options) {
  Eigen::VectorXd mags = sf.rowwise().norm();
  double g = options.gravity;
  if (g <= 0.0) {
    std::vector<double> v(mags.data(), mags.data() + mags.size());
    std::nth_element(v.begin(), v.begin() + static_cast<long>(v.size() / 2), v.end());
    g = v[v.size() / 2];
  }
  for (Eigen::Index i = 0; i < mags.size(); ++i) {
    const double dev = mags(i) / g - 1.0;
    if (std::abs(dev) > options.gravity_tolerance) {
      throw Error("specific_force: position " + std::to_string(i + 1) + " reads |a| = " + fmt(mags(i)) + ", " +
                  fmt(100.0 * dev, 3) + " % from g = " + fmt(g) + " (tolerance " +
                  fmt(100.0 * options.gravity_tolerance, 3) +
                  " %): the device was moving, or the accelerometer is not calibrated (calibrate it from the same "
                  "positions: calibrate_accelerometer, --calibrate-accelerometer)");
    }
  }
}

// One heading correction for fixed U0, K: minimise |y − K Lᵀ Hrot(ψ)ᵀ f|² over ψ. Coarse grid, then
// Newton steps on the exact 1-D objective (a cos ψ + b sin ψ + c form in the rotated field).
double best_heading(const Eigen::Vector3d& y, const Eigen::Matrix3d& KLt, const Eigen::Vector3d& f, Frame frame,
                    double start, bool grid) {
  auto cost = [&](double psi) {
    double g[3];
    unrotate_heading(psi, f.data(), frame, g);
    return (y - KLt * Eigen::Vector3d(g[0], g[1], g[2])).squaredNorm();
  };
  double best = start, best_cost = cost(start);
  if (grid) {
    for (int k = 0; k < 72; ++k) {
      const double psi = -kPi + 2.0 * kPi * k / 72.0;
      const double c = cost(psi);
      if (c < best_cost) best = psi, best_cost = c;
    }
  }
  // Golden-section refinement in ±5° (one-dimensional, smooth, cheap).
  double a = best - 5.0 * kPi / 180.0, b = best + 5.0 * kPi / 180.0;
  const double gr = 0.5 * (std::sqrt(5.0) - 1.0);
  double c1 = b - gr * (b - a), c2 = a + gr * (b - a), f1 = cost(c1), f2 = cost(c2);
  for (int it = 0; it < 60; ++it) {
    if (f1 < f2) {
      b = c2, c2 = c1, f2 = f1, c1 = b - gr * (b - a), f1 = cost(c1);
    } else {
      a = c1, c1 = c2, f1 = f2, c2 = a + gr * (b - a), f2 = cost(c2);
    }
  }
  return 0.5 * (a + b);
}

// Tight stopping rules: the problems are small, and the tests hold the answers closely to the oracle.
ceres::Solver::Options tight_solver_options(ceres::LinearSolverType linear_solver, int max_iterations) {
  ceres::Solver::Options so;
  so.linear_solver_type = linear_solver;
  so.max_num_iterations = max_iterations;
  so.function_tolerance = 1e-15;
  so.gradient_tolerance = 1e-15;
  so.parameter_tolerance = 1e-13;
  so.num_threads = 1;
  return so;
}

}  // namespace

namespace {
// A Frame cast from an out-of-range integer would be taken for nue (or ned) silently.
void check_frame(Frame frame, const std::string& name = "frame") {
  detail::require_enum(name, frame, 2, "ned, nue (0 … 1)");
}
}  // namespace

namespace detail {

void check(const PositionsOptions& o) {
  const std::string s = "PositionsOptions::";
  check_frame(o.frame, s + "frame");
  // NaN compares false: a NaN tolerance switched the |a| check off, a NaN σ the levelling prior
  require_nonnegative(s + "gravity", o.gravity, "a finite value ≥ 0 (0 = the median |acc|)");
  require_positive(s + "gravity_tolerance", o.gravity_tolerance, "a finite fraction > 0");
  require_nonnegative(s + "tilt_sigma_deg", o.tilt_sigma_deg, "a finite value ≥ 0 (0 = levelling taken as exact)");
  require_nonnegative(s + "output_sigma", o.output_sigma, "a finite value ≥ 0 (0 = estimated)");
  require_positive(s + "determined_tolerance", o.determined_tolerance);
  require_int(o.max_iterations >= 1, s + "max_iterations", o.max_iterations, "≥ 1");
}

void check(const AccelerometerOptions& o) {
  const std::string s = "AccelerometerOptions::";
  require_positive(s + "gravity", o.gravity);
  require_int(o.max_iterations >= 1, s + "max_iterations", o.max_iterations, "≥ 1");
}

}  // namespace detail

Eigen::Vector3d local_up(Frame frame) {
  check_frame(frame);
  return frame == Frame::ned ? Eigen::Vector3d(0, 0, -1) : Eigen::Vector3d(0, 1, 0);
}

Eigen::Vector2d pitch_roll(const Eigen::Vector3d& a, Frame frame) {
  check_frame(frame);
  if (!a.allFinite() || a.norm() == 0.0) throw Error("specific_force: zero or not finite");
  if (frame == Frame::nue) {
    // Seed 002 eq. 4: θ = arcsin(Ax/|A|), γ = arctan(−Az/Ay), written with atan2 so that it is exact
    // near ±90° and the roll keeps its quadrant.
    return {std::atan2(a(0), std::hypot(a(1), a(2))), std::atan2(-a(2), a(1))};
  }
  return {std::atan2(a(0), std::hypot(a(1), a(2))), std::atan2(-a(1), -a(2))};
}

Eigen::Matrix3d body_to_local(double pitch, double roll, double yaw, Frame frame) {
  check_frame(frame);
  for (const auto& [name, angle] : {std::pair<const char*, double>{"pitch", pitch}, {"roll", roll}, {"yaw", yaw}})
    if (!std::isfinite(angle))
      throw Error(std::string(name) + ": " + detail::num(angle) + ", need a finite angle (radians)");
  using Eigen::AngleAxisd;
  using Eigen::Vector3d;
  if (frame == Frame::ned) {
    return (AngleAxisd(yaw, Vector3d::UnitZ()) * AngleAxisd(pitch, Vector3d::UnitY()) *
            AngleAxisd(roll, Vector3d::UnitX()))
        .toRotationMatrix();
  }
  // nue: heading about up (y) clockwise from above = Ry(−yaw); pitch about right (z); roll about x.
  return (AngleAxisd(-yaw, Vector3d::UnitY()) * AngleAxisd(pitch, Vector3d::UnitZ()) *
          AngleAxisd(roll, Vector3d::UnitX()))
      .toRotationMatrix();
}

Eigen::Matrix3d heading_rotation(double angle, Frame frame) {
  check_frame(frame);
  return frame == Frame::ned ? Eigen::AngleAxisd(angle, Eigen::Vector3d::UnitZ()).toRotationMatrix()
                             : Eigen::AngleAxisd(-angle, Eigen::Vector3d::UnitY()).toRotationMatrix();
}

namespace {
// A scaled matrix would scale K and a reflection flip an axis without a word; 1e-4 lets matrices
// written with 5–6 decimals pass.
void check_rotation(const Eigen::Matrix3d& r, const std::string& name) {
  if (!r.allFinite()) throw Error(name + ": not finite");
  const double off = (r.transpose() * r - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  if (off > 1e-4 || r.determinant() < 0.0)
    throw Error(name + ": not a rotation (RᵀR − I up to " + fmt(off) + ", det " + fmt(r.determinant()) +
                "); give proper orthonormal matrices");
}
}  // namespace

Eigen::Vector3d PositionsResult::field_of(const Eigen::Vector3d& output) const {
  const std::optional<Eigen::Vector3d> field =
      K.allFinite() ? detail::full_piv_solve(K, output - offset) : std::nullopt;
  if (!field) throw Error("field_of: K is singular or not finite (no calibration?)");
  return *field;
}

Eigen::Matrix3d level_rotation(const Eigen::Matrix3d& nominal, const Eigen::Vector3d& body_up, Frame frame) {
  check_frame(frame);
  check_rotation(nominal, "nominal");
  if (!body_up.allFinite() || !(body_up.norm() > 0.0))
    throw Error("body_up: need a finite vector of length > 0 (the accelerometer's up in the body frame)");
  const Eigen::Vector3d v = nominal * body_up.normalized();
  const Eigen::Matrix3d correction = detail::rotation_between(v, local_up(frame));
  return correction * nominal;
}

std::vector<Eigen::Matrix3d> twelve_positions(Frame frame) {
  check_frame(frame);
  // Pointing directions of the seed 002 body axes (x forward, y up, z right) in N-U-E letters.
  static const char* kPositions[12] = {"NUE", "SUW", "SDE", "NDW", "USE", "UNW",
                                       "DNE", "DSW", "NWU", "SEU", "NED", "SWD"};
  auto dir = [frame](char c) {
    Eigen::Vector3d nue = Eigen::Vector3d::Zero();
    switch (c) {
      case 'N': nue << 1, 0, 0; break;
      case 'S': nue << -1, 0, 0; break;
      case 'U': nue << 0, 1, 0; break;
      case 'D': nue << 0, -1, 0; break;
      case 'E': nue << 0, 0, 1; break;
      default: nue << 0, 0, -1; break;  // W
    }
    if (frame == Frame::nue) return nue;
    return Eigen::Vector3d(nue(0), nue(2), -nue(1));  // (N, E, D)
  };
  std::vector<Eigen::Matrix3d> out;
  for (const char* p : kPositions) {
    Eigen::Matrix3d R;  // columns: local coordinates of the body axes
    if (frame == Frame::nue) {
      R << dir(p[0]), dir(p[1]), dir(p[2]);
    } else {  // FRD body: forward = seed x, right = seed z, down = −seed y
      R << dir(p[0]), dir(p[2]), -dir(p[1]);
    }
    out.push_back(R);
  }
  return out;
}

PositionsResult fit_positions(const SamplesRef& outputs, const SamplesRef& reference, const PositionsOptions& options) {
  outputs.require_width("outputs");
  reference.require_width("reference");
  detail::check(options);
  const Eigen::Index n = outputs.rows();
  if (n < 4) {
    throw Error("outputs: " + std::to_string(n) +
                " positions, need at least 4 (12 unknowns: 3 offsets and 9 entries of K, 3 equations per position)");
  }
  if (reference.rows() != n) {
    throw Error("reference: " + std::to_string(reference.rows()) + " rows for " + std::to_string(n) + " outputs");
  }
  check_finite(outputs, "outputs");
  check_finite(reference, "reference");
  detail::require_squares_representable(outputs, "outputs", "the positions calibration");
  detail::require_squares_representable(reference, "reference", "the positions calibration");
  // Design [1, H] (N×4), column-scaled; one solve for the three output axes.
  Eigen::MatrixXd X(n, 4);
  X.col(0).setOnes();
  X.rightCols(3) = reference;
  Eigen::Vector4d scale = X.colwise().norm().transpose();
  for (int j = 0; j < 4; ++j) scale(j) = scale(j) > 0 ? scale(j) : 1.0;
  const Eigen::MatrixXd Xs = X * scale.cwiseInverse().asDiagonal();
  const detail::SvdLeastSquares svd = detail::svd_least_squares(Xs, Eigen::MatrixXd(outputs));
  const Eigen::Vector4d sv = svd.singular_values;
  if (sv(3) < 1e-9 * sv(0)) {
    const Eigen::Vector4d v = scale.cwiseInverse().asDiagonal() * svd.v.col(3);
    const Eigen::Vector3d normal = v.tail<3>();
    const double nn = normal.norm();
    const Eigen::Vector3d nhat = normal / nn;
    const double c = -v(0) / nn;  // n̂·H = c for every position
    std::string what = std::abs(c) < 1e-6 * reference.rowwise().norm().maxCoeff()
                           ? "the response K·n to a field along n = " + vec_str(nhat) + " is not observable"
                           : "the offset U0 and the response K·n to a field along n = " + vec_str(nhat) +
                                 " cannot be separated";
    throw Error("reference: the body-frame fields of the " + std::to_string(n) +
                " positions lie in one plane (n·H = " + fmt(c) + "): " + what +
                "; add positions that put the field on both sides of that plane (turn the sensor over)");
  }
  const Eigen::MatrixXd beta = scale.cwiseInverse().asDiagonal() * svd.solution;  // 4×3

  PositionsResult r;
  r.units = options.units;
  r.offset = beta.row(0).transpose();
  r.K = beta.bottomRows(3).transpose();
  r.reference = reference;
  r.residuals = outputs - (X * beta);
  r.yaw = Eigen::VectorXd::Zero(n);
  r.parameter_names = base_names();
  r.parameters.resize(12);
  r.parameters << r.offset, Eigen::Map<const Eigen::Matrix<double, 9, 1>>(Eigen::Matrix<double, 3, 3, Eigen::RowMajor>(r.K).data());
  // Jacobian of the stacked residuals (3N × 12, four non-zeros a row): dr/dU0 = −I, dr_j/dK_jk = −H_k.
  SparseRows J(3 * n, 12);
  J.reserve(Eigen::VectorXi::Constant(3 * n, 4));
  for (Eigen::Index i = 0; i < n; ++i)
    for (int j = 0; j < 3; ++j) {
      J.insert(3 * i + j, j) = -1.0;
      for (int k = 0; k < 3; ++k) J.insert(3 * i + j, 3 + 3 * j + k) = -reference(i, k);
    }
  Eigen::VectorXd scales(12);
  const double out_scale = std::sqrt(Eigen::MatrixXd(outputs).squaredNorm() / static_cast<double>(n));
  scales << Eigen::Vector3d::Constant(out_scale), Eigen::VectorXd::Constant(9, gain_scale(r.K));
  // a σ given is the least the standard errors take (a blind check's exact fit of 4 positions had none with it);
  // σ̂ when the residuals say more: a wrong reference field is no smaller an error for a σ given
  finish_statistics(r, J, scales, options.determined_tolerance, {}, 0.0, options.output_sigma, true);
  r.summary.condition_number = sv(0) / sv(3);
  fill_summary(r, "positions (linear least squares)");
  detail::require_finite_fit(detail::finite_fit(r.summary) && r.K.allFinite() && r.offset.allFinite(), "outputs",
                             outputs, "reference", reference, "the positions calibration");
  return r;
}

PositionsResult calibrate_positions(const SamplesRef& outputs, const SamplesRef& specific_force,
                                    const std::vector<Eigen::Matrix3d>& nominal, const Eigen::Vector3d& field,
                                    const PositionsOptions& options) {
  outputs.require_width("outputs");
  specific_force.require_width("specific_force");
  const Eigen::Index n = outputs.rows();
  check_field(field);
  detail::check(options);
  if (specific_force.rows() != n) {
    throw Error("specific_force: " + std::to_string(specific_force.rows()) + " rows for " + std::to_string(n) +
                " positions of outputs");
  }
  if (!nominal.empty() && static_cast<Eigen::Index>(nominal.size()) != n) {
    throw Error("nominal: " + std::to_string(nominal.size()) + " attitudes for " + std::to_string(n) + " positions");
  }
  for (std::size_t i = 0; i < nominal.size(); ++i) check_rotation(nominal[i], "nominal[" + std::to_string(i) + "]");
  const Eigen::Index min_n = options.estimate_yaw ? (options.estimate_inclination ? 7 : 6) : 4;
  if (n < min_n) {
    throw Error("outputs: " + std::to_string(n) + " positions, need at least " + std::to_string(min_n) +
                (options.estimate_yaw ? " when the headings are estimated (12 + N unknowns, 3N equations)"
                                      : " (12 unknowns, 3 equations per position)"));
  }
  check_finite(outputs, "outputs");
  check_finite(specific_force, "specific_force");
  detail::require_squares_representable(outputs, "outputs", "the positions calibration");
  check_gravity(specific_force, options);
  if (nominal.empty() && !options.estimate_yaw) {
    throw Error("nominal: no attitudes given and estimate_yaw is off: give each position's nominal attitude (a "
                "preset such as the twelve positions, or pitch/roll/heading), or estimate the headings");
  }
  if (nominal.empty() && n < 10) {
    throw Error("nominal: headings unknown and only " + std::to_string(n) +
                " positions: the starting point comes from an ellipsoid fit, which needs at least 10; give "
                "nominal attitudes instead");
  }

  // Levelling: each nominal attitude corrected so that the accelerometer's up maps onto local up.
  const Eigen::Vector3d up = local_up(options.frame);
  std::vector<Eigen::Matrix3d> level(static_cast<std::size_t>(n));
  for (Eigen::Index i = 0; i < n; ++i) {
    const Eigen::Vector3d u = unit_up_from(specific_force.row(i).transpose(), i);
    const Eigen::Matrix3d R0 = nominal.empty() ? Eigen::Matrix3d::Identity() : nominal[static_cast<std::size_t>(i)];
    if (!nominal.empty()) {
      const double angle = std::acos(std::clamp((R0 * u).dot(up), -1.0, 1.0)) * 180.0 / kPi;
      if (angle > 30.0) {
        throw Error("specific_force: position " + std::to_string(i + 1) + ": the accelerometer's up is " + fmt(angle, 3) +
                    "° from the nominal attitude's (more than 30°): wrong order of positions, wrong frame, or an "
                    "accelerometer that reports gravity (down) instead of specific force (up)?");
      }
    }
    level[static_cast<std::size_t>(i)] = level_rotation(R0, u, options.frame);
  }

  Samples reference(n, 3);
  for (Eigen::Index i = 0; i < n; ++i) reference.row(i) = (level[static_cast<std::size_t>(i)].transpose() * field).transpose();

  if (!options.estimate_yaw && !options.estimate_inclination && options.tilt_sigma_deg <= 0.0) {
    PositionsResult r = fit_positions(outputs, reference, options);
    r.field = field;
    r.rotations = level;
    return r;
  }

  // Starting point for U0, K and the headings.
  Eigen::VectorXd yaw = Eigen::VectorXd::Zero(n);
  Eigen::Vector3d u0;
  Eigen::Matrix3d K;
  if (!nominal.empty()) {
    const PositionsResult start = fit_positions(outputs, reference, options);
    u0 = start.offset;
    K = start.K;
  } else {
    EllipsoidOptions eo;
    eo.field_norm = field.norm();
    const EllipsoidResult e = fit_ellipsoid(outputs, eo);
    u0 = e.calibration.offset;
    K = e.calibration.matrix.inverse();
  }
  // Alternate: headings for fixed (U0, K), then (U0, K) by linear least squares (a few rounds), so
  // that the joint solve starts near the right basin even from an ellipsoid fit's symmetric K.
  // Only when the headings are unknowns: a heading fitted here but held fixed later would be a hidden
  // parameter, outside the standard errors and the degrees of freedom.
  for (int round = 0; options.estimate_yaw && round < 8; ++round) {
    for (Eigen::Index i = 0; i < n; ++i) {
      const Eigen::Matrix3d KLt = K * level[static_cast<std::size_t>(i)].transpose();
      yaw(i) = best_heading(outputs.row(i).transpose() - u0, KLt, field, options.frame, yaw(i),
                            nominal.empty() && round == 0);
    }
    for (Eigen::Index i = 0; i < n; ++i) {
      double g[3];
      unrotate_heading(yaw(i), field.data(), options.frame, g);
      reference.row(i) = (level[static_cast<std::size_t>(i)].transpose() * Eigen::Vector3d(g[0], g[1], g[2])).transpose();
    }
    try {
      const PositionsResult step = fit_positions(outputs, reference, options);
      u0 = step.offset;
      K = step.K;
    } catch (const Error&) {
      break;  // the joint solve below reports unobservable parameters precisely
    }
  }

  // Joint solve (Ceres): U0, K (row-major), ψ_i, and the inclination if asked.
  const Eigen::Vector3d down = -up;
  Eigen::Vector3d horizontal = field - field.dot(up) * up;
  const Eigen::Vector3d north = Eigen::Vector3d::UnitX();
  const Eigen::Vector3d horizontal_dir = horizontal.norm() > 1e-12 * field.norm() ? Eigen::Vector3d(horizontal.normalized()) : north;
  double inclination = std::atan2(field.dot(down), horizontal.norm());
  double u0p[3] = {u0(0), u0(1), u0(2)};
  double kp[9];
  for (int j = 0; j < 3; ++j)
    for (int k = 0; k < 3; ++k) kp[3 * j + k] = K(j, k);
  std::vector<double> yp(yaw.data(), yaw.data() + n);
  std::vector<double> tp(static_cast<std::size_t>(2 * n), 0.0);
  const bool with_tilt = options.tilt_sigma_deg > 0.0;
  bool sigma_undetermined = false;  // see the tilt-prior weighting below
  bool dip_mirrored = false;
  double sigma_fallback = 0.0;
  double sigma_estimated = 0.0;  // σ̂ solved from the positions themselves (tilt prior, no output_sigma given)
  const Eigen::Vector3d east = options.frame == Frame::ned ? Eigen::Vector3d::UnitY() : Eigen::Vector3d::UnitZ();
  double prior_weight = 0.0;
  ceres::Problem problem;
  for (Eigen::Index i = 0; i < n; ++i) {
    auto* cost = new ceres::AutoDiffCostFunction<PositionResidual, 3, 3, 9, 1, 1, 2>(new PositionResidual{
        outputs.row(i).transpose(), level[static_cast<std::size_t>(i)].transpose(), field, horizontal_dir, down,
        north, east, field.norm(), options.frame, options.estimate_inclination});
    double* tilt = &tp[static_cast<std::size_t>(2 * i)];
    problem.AddResidualBlock(cost, nullptr, u0p, kp, &yp[static_cast<std::size_t>(i)], &inclination, tilt);
    if (with_tilt) {
      problem.AddResidualBlock(new ceres::AutoDiffCostFunction<TiltPrior, 2, 2>(new TiltPrior{&prior_weight}),
                               nullptr, tilt);
    } else {
      problem.SetParameterBlockConstant(tilt);
    }
  }
  if (!options.estimate_yaw)
    for (auto& y : yp) problem.SetParameterBlockConstant(&y);
  if (!options.estimate_inclination) problem.SetParameterBlockConstant(&inclination);
  // Per-position parameters (heading, levelling correction) are eliminated first (Schur complement,
  // as for points in bundle adjustment): the reduced system has only U0, K and the dip.
  ceres::Solver::Options so = tight_solver_options(ceres::DENSE_SCHUR, options.max_iterations);
  ceres::Solver::Summary summary;
  // A fresh ordering for every solve: Ceres drops constant blocks from the ordering it is given.
  auto solve = [&]() {
    auto ordering = std::make_shared<ceres::ParameterBlockOrdering>();
    // The eliminated group must be an independent set (no two of its blocks in one residual): the
    // headings, or with levelling corrections the tilts (then the headings join the reduced system).
    for (Eigen::Index i = 0; i < n; ++i) {
      ordering->AddElementToGroup(&yp[static_cast<std::size_t>(i)], with_tilt ? 1 : 0);
      ordering->AddElementToGroup(&tp[static_cast<std::size_t>(2 * i)], with_tilt ? 0 : 1);
    }
    ordering->AddElementToGroup(u0p, 1);
    ordering->AddElementToGroup(kp, 1);
    ordering->AddElementToGroup(&inclination, 1);
    so.linear_solver_ordering = ordering;
    ceres::Solve(so, &problem, &summary);
  };
  const Eigen::Index free_params = 12 + (options.estimate_yaw ? n : 0) + (options.estimate_inclination ? 1 : 0);
  const double dof = static_cast<double>(std::max<Eigen::Index>(3 * n - free_params, 1));
  auto output_residual_ss = [&]() {
    double ss = 0.0;
    for (Eigen::Index i = 0; i < n; ++i) {
      double res[3];
      const double* params[5] = {u0p, kp, &yp[static_cast<std::size_t>(i)], &inclination,
                                 &tp[static_cast<std::size_t>(2 * i)]};
      PositionResidual{outputs.row(i).transpose(), level[static_cast<std::size_t>(i)].transpose(), field,
                       horizontal_dir, down, north, east, field.norm(), options.frame,
                       options.estimate_inclination}(params[0], params[1], params[2], params[3], params[4], res);
      ss += res[0] * res[0] + res[1] * res[1] + res[2] * res[2];
    }
    return ss;
  };
  auto prior_ss = [&]() {  // the tilt prior's residuals, in output units
    double ss = 0.0;
    for (double t : tp) ss += (t * prior_weight) * (t * prior_weight);
    return ss;
  };
  if (with_tilt) {
    // Levelling errors as unknowns with a prior σ_tilt: the weight σ/σ_tilt needs the output noise σ.
    // Unknown σ is estimated from the fit itself: first with the accelerometer taken as exact (σ_exact),
    // then σ̂ with σ̂² = (output SSR + prior SSR)/(3N − p) at prior weight σ̂/σ_tilt. With the prior rows
    // included this is r'V⁻¹r/(3N − p) for the marginal covariance V = σ²I + σ_t²ZZᵀ, whose expectation
    // is σ² at the right weight (the output SSR alone shrinks as the tilts soak up noise: σ̂ about half
    // the truth). Solved as a root, not by fixed-point passes, which crawl when the map's slope is near 1.
    //
    // With few positions the headings and tilts (3 local unknowns per position against 3 outputs) can
    // absorb the output noise: then there is no root above 0 and σ is not determined by the data. The
    // fit falls back to σ_exact (which also holds the levelling scatter, so the SEs err on the large
    // side) and says so.
    const double sigma_tilt = options.tilt_sigma_deg * kPi / 180.0;
    double sigma_out = options.output_sigma;
    double sigma_exact = 0.0;
    if (sigma_out <= 0.0) {
      for (auto& t : tp) t = 0.0;
      for (Eigen::Index i = 0; i < n; ++i) problem.SetParameterBlockConstant(&tp[static_cast<std::size_t>(2 * i)]);
      solve();
      for (Eigen::Index i = 0; i < n; ++i) problem.SetParameterBlockVariable(&tp[static_cast<std::size_t>(2 * i)]);
      sigma_out = sigma_exact = std::sqrt(output_residual_ss() / dof);
    }
    if (options.output_sigma > 0.0) {
      prior_weight = std::max(sigma_out, 1e-12 * field.norm()) / sigma_tilt;
      solve();
    } else {
      // σ̂ solves σ² = S(σ)/(3N − p), S the penalised SSR at prior weight σ/σ_tilt. f(u) = log(S/dof) − 2u
      // in u = log σ is ≤ 0 at σ_exact (S there is at most the accelerometer-exact SSR); step down until
      // f > 0 to bracket the largest root, then Illinois regula falsi. No sign change down to 1e-3 σ_exact:
      // the corrections absorb the noise (collapse).
      auto f = [&](double u) {
        prior_weight = std::max(std::exp(u), 1e-12 * field.norm()) / sigma_tilt;
        solve();
        return std::log(std::max(output_residual_ss() + prior_ss(), 1e-300) / dof) - 2.0 * u;
      };
      const double floor_u = std::log(1e-3 * sigma_exact);
      double hi = std::log(sigma_exact), f_hi = f(hi), lo = hi, f_lo = f_hi;
      while (f_lo <= 0.0 && lo > floor_u) {
        hi = lo;
        f_hi = f_lo;
        lo -= std::log(4.0);
        f_lo = f(lo);
      }
      if (f_lo <= 0.0) {
        sigma_undetermined = true;
        sigma_out = sigma_fallback = sigma_exact;
      } else {
        int side = 0;
        double u = hi;
        for (int it = 0; it < 60 && hi - lo > 1e-4; ++it) {
          u = (lo * f_hi - hi * f_lo) / (f_hi - f_lo);
          const double fu = f(u);
          if (fu > 0.0) {
            lo = u, f_lo = fu;
            if (side == 1) f_hi *= 0.5;
            side = 1;
          } else {
            hi = u, f_hi = fu;
            if (side == -1) f_lo *= 0.5;
            side = -1;
          }
        }
        sigma_out = sigma_estimated = std::exp(u);
      }
      prior_weight = std::max(sigma_out, 1e-12 * field.norm()) / sigma_tilt;
      solve();
    }
  } else {
    solve();
  }

  if (options.estimate_inclination && std::cos(inclination) < 0.0) {
    // The dip left (−90°, 90°): F(cos I ĥ + sin I d̂) with cos I < 0 is the field reversed, and K came out
    // negated (K' = −K with the field reversed fits the outputs equally). Return the physical branch and say why.
    inclination = std::remainder(inclination + kPi, 2.0 * kPi);
    for (double& k : kp) k = -k;
    dip_mirrored = true;
  }
  PositionsResult r;
  r.units = options.units;
  r.offset = Eigen::Vector3d(u0p[0], u0p[1], u0p[2]);
  for (int j = 0; j < 3; ++j)
    for (int k = 0; k < 3; ++k) r.K(j, k) = kp[3 * j + k];
  r.yaw = Eigen::Map<const Eigen::VectorXd>(yp.data(), n);
  for (auto& y : r.yaw) y = std::remainder(y, 2.0 * kPi);
  if (options.estimate_inclination) {
    double f[3];
    field_with_inclination(inclination, field.norm(), horizontal_dir, down, f);
    r.field = Eigen::Vector3d(f[0], f[1], f[2]);
  } else {
    r.field = field;
  }
  r.reference.resize(n, 3);
  r.rotations.resize(static_cast<std::size_t>(n));
  for (Eigen::Index i = 0; i < n; ++i) {
    const Eigen::Vector3d w = tp[static_cast<std::size_t>(2 * i)] * north + tp[static_cast<std::size_t>(2 * i + 1)] * east;
    const Eigen::Matrix3d tilt = w.norm() > 0 ? Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix()
                                              : Eigen::Matrix3d::Identity();
    r.rotations[static_cast<std::size_t>(i)] = heading_rotation(r.yaw(i), options.frame) * tilt * level[static_cast<std::size_t>(i)];
    r.reference.row(i) = (r.rotations[static_cast<std::size_t>(i)].transpose() * r.field).transpose();
  }
  r.residuals = outputs - ((r.K * r.reference.transpose()).colwise() + r.offset).transpose();

  // Parameters and the Jacobian of the free ones, for the standard errors and observability.
  r.parameter_names = base_names();
  std::vector<double*> blocks = {u0p, kp};
  if (options.estimate_yaw)
    for (Eigen::Index i = 0; i < n; ++i) {
      r.parameter_names.push_back("yaw_" + std::to_string(i));
      blocks.push_back(&yp[static_cast<std::size_t>(i)]);
    }
  if (options.estimate_inclination) {
    r.parameter_names.push_back("inclination");
    blocks.push_back(&inclination);
  }
  if (with_tilt)
    for (Eigen::Index i = 0; i < n; ++i) {
      r.parameter_names.push_back("tilt_" + std::to_string(i) + "_north");  // levelling correction (rad)
      r.parameter_names.push_back("tilt_" + std::to_string(i) + "_east");
      blocks.push_back(&tp[static_cast<std::size_t>(2 * i)]);
    }
  const Eigen::Index p = static_cast<Eigen::Index>(r.parameter_names.size());
  r.parameters.resize(p);
  for (int j = 0; j < 3; ++j) r.parameters(j) = u0p[j];
  for (int j = 0; j < 9; ++j) r.parameters(3 + j) = kp[j];
  {
    Eigen::Index j = 12;
    for (std::size_t b = 2; b < blocks.size(); ++b)
      for (int c = 0; c < problem.ParameterBlockSize(blocks[b]); ++c) r.parameters(j++) = blocks[b][c];
  }
  ceres::Problem::EvaluateOptions eo;
  eo.parameter_blocks = blocks;
  ceres::CRSMatrix crs;
  problem.Evaluate(eo, nullptr, nullptr, nullptr, &crs);
  const SparseRows J = Eigen::Map<const SparseRows>(crs.num_rows, crs.num_cols, static_cast<Eigen::Index>(crs.values.size()),
                                                     crs.rows.data(), crs.cols.data(), crs.values.data());
  Eigen::VectorXd scales(p);
  const double out_scale = std::sqrt(Eigen::MatrixXd(outputs).squaredNorm() / static_cast<double>(n));
  scales << Eigen::Vector3d::Constant(out_scale), Eigen::VectorXd::Constant(9, gain_scale(r.K)),
      Eigen::VectorXd::Constant(p - 12, kPi);
  std::vector<int> local(static_cast<std::size_t>(p), -1);
  for (Eigen::Index j = 12; j < p; ++j) {
    const std::string& name = r.parameter_names[static_cast<std::size_t>(j)];
    if (name.rfind("yaw_", 0) == 0 || name.rfind("tilt_", 0) == 0)
      local[static_cast<std::size_t>(j)] = std::stoi(name.substr(name.find('_') + 1));
  }
  finish_statistics(r, J, scales, options.determined_tolerance, local, prior_ss(),
                    sigma_undetermined ? sigma_fallback : options.output_sigma);
  std::vector<std::string> unobservable;
  for (Eigen::Index j = 0; j < p; ++j)
    if (std::isinf(r.standard_errors(j))) unobservable.push_back(r.parameter_names[static_cast<std::size_t>(j)]);
  if (!unobservable.empty()) {
    std::string names;
    for (std::size_t j = 0; j < unobservable.size() && j < 8; ++j) names += (j ? ", " : "") + unobservable[j];
    if (unobservable.size() > 8) names += ", ...";
    throw Error("positions: these parameters are not observable from the " + std::to_string(n) +
                " positions: " + names +
                " — tilt the sensor through more attitudes (each body axis up and down, several headings)");
  }
  r.summary.iterations = static_cast<int>(summary.iterations.size());
  fill_summary(r, options.estimate_yaw ? "positions (joint, headings estimated)" : "positions (joint)");
  detail::require_finite_fit(detail::finite_fit(r.summary) && r.K.allFinite() && r.offset.allFinite(), "outputs",
                             outputs, "the positions calibration");
  r.summary.converged = summary.IsSolutionUsable();
  if (!r.summary.converged) r.summary.warnings.push_back("Ceres: " + summary.message);
  if (dip_mirrored)
    r.summary.warnings.push_back(
        "the dip estimate went past ±90° (the field reversed, K negated); returned the physical branch, dip " +
        fmt(inclination * 180.0 / kPi) + "°: the given inclination's sign (or the field's north) is probably wrong");
  if (sigma_undetermined)
    r.summary.warnings.push_back(
        "output noise σ is not determined by these positions (headings and levelling corrections absorb it): "
        "it used σ = " + fmt(sigma_fallback) + " from the fit with the accelerometer taken as exact, so the "
        "standard errors err on the large side; give output_sigma (the sensor's noise) or more positions");
  if (sigma_estimated > 0.0 && static_cast<double>(3 * n) < 10.0 * static_cast<double>(r.parameters.size()))
    // A blind check: σ̂ from twelve positions with 24 levelling corrections beside it ranged 0.2–4.9× the truth,
    // and the standard errors with it (|z| up to 9).
    r.summary.warnings.push_back(
        "output noise σ̂ = " + fmt(sigma_estimated) + " was estimated from the " + std::to_string(n) +
        " positions themselves, beside their levelling corrections: loosely determined, and the standard errors "
        "scale with it; give output_sigma (the sensor's noise per position, e.g. from repeated readings)");
  return r;
}

ClosedForm twelve_position_closed_form(const SamplesRef& U, double field_up) {
  U.require_width("outputs");
  if (U.rows() != 12) {
    throw Error("outputs: " + std::to_string(U.rows()) + " rows, the closed form needs exactly the twelve positions");
  }
  check_finite(U, "outputs");
  if (!(std::abs(field_up) > 0.0) || !std::isfinite(field_up)) throw Error("field_up: zero or not finite");
  // Groups of four positions with one body axis vertical (seed 002 body axes x fwd, y up, z right):
  // positions 1–4 y vertical, 5–8 x vertical, 9–12 z vertical; in each group the first two have that
  // axis up, the last two down, and the horizontal field cancels in both the sum and the
  // difference. So for vertical axis j: U0_j = (U_a + U_b + U_c + U_d)_j / 4 and column j of K is
  // (U_a + U_b − U_c − U_d) / (4 H_u) (all three outputs).
  // Corrections to the printed formulas: eq. 14 names the offset "Uky0" (it is Uhy0); eq. 22 is
  // introduced with positions "5, 6, 7, 8, 9" (only 5–8 enter); eq. 27 prints Kz with all plus signs
  // (it is (U9 + U10 − U11 − U12)/4H_u — the all-plus sum is 4·Uhz0, eq. 26); eq. 29 uses U_hx where
  // K_yz needs U_hy (as printed it equals K_xz, eq. 28); the printed K matrix labels its third row
  // Kxz Kxy Kz (it is Kzx Kzy Kz); the text before eq. 3's use writes "Uhx = Uhz0 + ..." for Uhz.
  ClosedForm c;
  const int vertical[3] = {1, 0, 2};  // group g (rows 4g..4g+3) has body axis vertical[g] vertical
  for (int g = 0; g < 3; ++g) {
    const int j = vertical[g];
    const Eigen::Vector3d a = U.row(4 * g).transpose(), b = U.row(4 * g + 1).transpose();
    const Eigen::Vector3d cc = U.row(4 * g + 2).transpose(), d = U.row(4 * g + 3).transpose();
    c.offset(j) = 0.25 * (a(j) + b(j) + cc(j) + d(j));
    c.K.col(j) = (a + b - cc - d) / (4.0 * field_up);
  }
  return c;
}

// --- accelerometer ---------------------------------------------------------------------------------

namespace {
struct GravityResidual {
  Eigen::Vector3d raw;
  double g;
  template <typename T>
  bool operator()(const T* const b, const T* const t, T* r) const {
    // T = [[t0 t1 t2], [0 t3 t4], [0 0 t5]]
    const T d0 = T(raw(0)) - b[0], d1 = T(raw(1)) - b[1], d2 = T(raw(2)) - b[2];
    const T a0 = t[0] * d0 + t[1] * d1 + t[2] * d2, a1 = t[3] * d1 + t[4] * d2, a2 = t[5] * d2;
    using std::sqrt;
    r[0] = sqrt(a0 * a0 + a1 * a1 + a2 * a2) - T(g);
    return true;
  }
};
}  // namespace

Samples AccelerometerResult::apply_rows(const SamplesRef& raw) const {
  raw.require_width("raw");
  return ((matrix * (raw.transpose().colwise() - offset))).transpose();
}

namespace {
constexpr double kSameDirectionDeg = 5.0;  // a static position's gravity reading repeats to well within this

// Readings whose directions lie within `tolerance_deg` of a representative count once (greedy clustering).
int distinct_directions(const SamplesRef& readings, double tolerance_deg) {
  const double cos_tol = std::cos(tolerance_deg * kPi / 180.0);
  std::vector<Eigen::Vector3d> seen;
  for (Eigen::Index i = 0; i < readings.rows(); ++i) {
    const Eigen::Vector3d u = readings.row(i).transpose().normalized();
    bool known = false;
    for (const auto& v : seen) known = known || u.dot(v) >= cos_tol;
    if (!known) seen.push_back(u);
  }
  return static_cast<int>(seen.size());
}
}  // namespace

AccelerometerResult calibrate_accelerometer(const SamplesRef& readings, const AccelerometerOptions& options) {
  const Eigen::Index n = readings.rows();
  check_samples(readings, "readings", 6,
                "static positions for an accelerometer calibration (offset and scale: 6 unknowns; with "
                "misalignment 9)");
  detail::check(options);
  detail::require_squares_representable(readings, "readings", "the accelerometer calibration");
  const Eigen::Vector3d lo = readings.colwise().minCoeff(), hi = readings.colwise().maxCoeff();
  const Eigen::Vector3d mean_abs = readings.cwiseAbs().colwise().mean();
  for (int k = 0; k < 3; ++k) {
    // Every axis must see gravity from both sides, or its offset and scale trade off.
    if (hi(k) - lo(k) < 0.5 * readings.rowwise().norm().mean()) {
      throw Error(std::string("readings: axis ") + kAxis[k] +
                  " never points (nearly) up and down (range " + fmt(lo(k)) + " … " + fmt(hi(k)) +
                  "): its offset and scale cannot be separated; add positions with that axis up and down");
    }
  }
  (void)mean_abs;
  double b[3], t[6] = {0, 0, 0, 0, 0, 0};
  for (int k = 0; k < 3; ++k) b[k] = 0.5 * (hi(k) + lo(k));
  t[0] = 2.0 * options.gravity / (hi(0) - lo(0));
  t[3] = 2.0 * options.gravity / (hi(1) - lo(1));
  t[5] = 2.0 * options.gravity / (hi(2) - lo(2));
  // What determines the unknowns is the number of distinct gravity directions, not of rows: the twelve
  // positions turn the sensor about the vertical, which repeats each of 6 gravity readings (6 equations
  // for 9 unknowns — the misalignment came out 5× too large, with no warning).
  const int distinct = distinct_directions(readings, kSameDirectionDeg);
  if (distinct < 6)
    throw Error("readings: only " + std::to_string(distinct) + " distinct gravity directions (readings within " +
                fmt(kSameDirectionDeg) + "° are one position); offset and scale need 6: add positions with " +
                "other faces up");
  const bool misalignment = distinct >= 9;
  ceres::Problem problem;
  for (Eigen::Index i = 0; i < n; ++i) {
    problem.AddResidualBlock(new ceres::AutoDiffCostFunction<GravityResidual, 1, 3, 6>(
                                 new GravityResidual{readings.row(i).transpose(), options.gravity}),
                             nullptr, b, t);
  }
  if (!misalignment) problem.SetManifold(t, new ceres::SubsetManifold(6, {1, 2, 4}));
  ceres::Solver::Options so = tight_solver_options(ceres::DENSE_QR, options.max_iterations);
  ceres::Solver::Summary summary;
  ceres::Solve(so, &problem, &summary);

  AccelerometerResult r;
  r.offset = Eigen::Vector3d(b[0], b[1], b[2]);
  r.matrix << t[0], t[1], t[2], 0, t[3], t[4], 0, 0, t[5];
  if (r.matrix.diagonal().minCoeff() <= 0.0) {
    throw Error("readings: the fit gave a non-positive scale factor; the positions do not determine the "
                "accelerometer (spread them over all faces)");
  }
  r.gravity = options.gravity;
  r.misalignment_estimated = misalignment;
  const Samples corrected = r.apply_rows(readings);
  r.magnitude_errors = corrected.rowwise().norm().array() - options.gravity;
  const double rms = std::sqrt(r.magnitude_errors.squaredNorm() / static_cast<double>(n));
  r.tilt_error_deg = rms / options.gravity * 180.0 / kPi;
  r.summary.samples = static_cast<std::size_t>(n);
  r.summary.iterations = static_cast<int>(summary.iterations.size());
  r.summary.cost = 2.0 * summary.final_cost / static_cast<double>(n);
  r.summary.residual_rms = rms;
  r.summary.converged = summary.IsSolutionUsable();
  r.summary.norm_mean = corrected.rowwise().norm().mean();
  detail::require_finite_fit(detail::finite_fit(r.summary) && r.matrix.allFinite() && r.offset.allFinite(),
                             "readings", readings, "the accelerometer calibration");
  r.summary.message = "accelerometer: " + std::to_string(n) + " positions, |a| − g RMS " + fmt(rms) + " (" +
                      fmt(r.tilt_error_deg, 3) + "° equivalent)" +
                      (misalignment ? "" : "; fewer than 9 gravity directions: misalignment not estimated");
  if (!misalignment)
    r.summary.warnings.push_back("only " + std::to_string(distinct) + " distinct gravity directions (turns about the " +
                                 "vertical repeat one): misalignment not estimated (left 0); it needs 9, e.g. " +
                                 "positions tilted between the faces");
  return r;
}

}  // namespace fluxcal
