#include "fluxcal/planar.hpp"

#include "checks.hpp"
#include "clones.hpp"
#include "linalg.hpp"
#include "long_run.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/LU>

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>
#include <sstream>
#include <tuple>
#include <utility>
#include <vector>

namespace fluxcal {
namespace {

using detail::num;
using detail::percent;

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kTiny = 1e-300;  // guards diagonals and costs against exact zeros
constexpr double kFloor2 = 1e-300;  // added to |h|², |A h|² of the normalised readings (O(1)): never 0
// The five parameters of an ellipse; twice as many readings, so that σ̂ and the standard errors rest on as many
// spare readings as parameters (fewer, and the determined check judges nothing).
constexpr int kEllipseParameters = 5;
constexpr Eigen::Index kMinReadings = 2 * kEllipseParameters;
// The direct fit's 3×3 scatter S3 of (x, y, 1) of the normalised readings (O(1) entries) below this reciprocal
// condition number: the readings lie on a line and determine no ellipse.
constexpr double kCollinear = 1e-12;

const char* shape_name(PlanarShape s) {
  switch (s) {
    case PlanarShape::circle: return "circle";
    case PlanarShape::diagonal: return "diag";
    case PlanarShape::symmetric: return "sym";
  }
  return "?";
}

int coefficient_count(PlanarShape s) { return s == PlanarShape::circle ? 1 : s == PlanarShape::diagonal ? 2 : 3; }

// A = Σ c_j B_j for the shape's basis: circle I; diag E00, E11; sym E00, E01 + E10, E11.
Eigen::Matrix2d matrix_of(PlanarShape s, const double* c) {
  Eigen::Matrix2d A;
  switch (s) {
    case PlanarShape::circle: A << c[0], 0.0, 0.0, c[0]; break;
    case PlanarShape::diagonal: A << c[0], 0.0, 0.0, c[1]; break;
    case PlanarShape::symmetric: A << c[0], c[1], c[1], c[2]; break;
  }
  return A;
}

// A start's matrix projected onto a shape's coefficients (circle: the geometric-mean gain).
Eigen::VectorXd coefficients_of(PlanarShape s, const Eigen::Matrix2d& A) {
  Eigen::VectorXd c(coefficient_count(s));
  switch (s) {
    case PlanarShape::circle: c << std::sqrt(std::abs(A.determinant())); break;
    case PlanarShape::diagonal: c << A(0, 0), A(1, 1); break;
    case PlanarShape::symmetric: c << A(0, 0), 0.5 * (A(0, 1) + A(1, 0)), A(1, 1); break;
  }
  return c;
}

// The 5 × (2 + k) map from a shape's parameters (b, c) to the full (b, a_xx, a_xy, a_yy) the kernel
// differentiates by: ∂r/∂c_j = Σ (B_j)_entries ∂r/∂a_entry.
Eigen::MatrixXd full_map(PlanarShape s) {
  const int k = 2 + coefficient_count(s);
  Eigen::MatrixXd P = Eigen::MatrixXd::Zero(5, k);
  P(0, 0) = P(1, 1) = 1.0;
  switch (s) {
    case PlanarShape::circle: P(2, 2) = P(4, 2) = 1.0; break;
    case PlanarShape::diagonal: P(2, 2) = P(4, 3) = 1.0; break;
    case PlanarShape::symmetric: P(2, 2) = P(3, 3) = P(4, 4) = 1.0; break;
  }
  return P;
}

bool positive_definite(const Eigen::Matrix2d& A) {
  return A(0, 0) > 0.0 && A(1, 1) > 0.0 && A(0, 0) * A(1, 1) - A(0, 1) * A(1, 0) > 0.0;
}

// ---- the Sampson residual and its sums ---------------------------------------------------------------------------

// r = (ρ − T)ρ/γ, h = A d, g = A h, ρ = |h|, γ = |g|, d = u − b (A = [[a, c], [c, e]]). With
//   ∂r = (2ρ − T)/γ · ∂ρ − (ρ² − Tρ)/γ² · ∂γ,  ∂ρ = h·∂h/ρ,  ∂γ = g·∂g/γ:
//   ∂/∂b: ∂h = −A e_i, ∂g = A ∂h;   ∂/∂a_entry (basis E): ∂h = E d, ∂g = E h + A E d.
// Writes r and its derivatives by (b_x, b_y, a, c, e) to out[5 · stride], out[0 … 4 · stride].
FLUXCAL_ALWAYS_INLINE void sampson_2d(double dx, double dy, double a, double c, double e, double T, double* out,
                                      int stride) {
  const double hx = a * dx + c * dy, hy = c * dx + e * dy;
  const double gx = a * hx + c * hy, gy = c * hx + e * hy;
  // |h| and |g| kept off 0 by adding kFloor² (below the rounding of the O(1) normalised values, so it changes no
  // result) rather than by a max or a select: GCC vectorises this loop across readings only without a branch.
  const double rho = std::sqrt(hx * hx + hy * hy + kFloor2), gam = std::sqrt(gx * gx + gy * gy + kFloor2);
  const double inv_g = 1.0 / gam;
  const double r = (rho - T) * rho * inv_g;
  // each column w1 (h·∂h) − w2 (g·∂g); w1 = (2ρ − T)/(γρ), w2 = r/γ²
  const double w1 = (2.0 * rho - T) * inv_g / rho, w2 = r * inv_g * inv_g;
  const double u1x = w1 * hx, u1y = w1 * hy, u2x = w2 * gx, u2y = w2 * gy;
  out[0] = -(u1x * a + u1y * c) + (u2x * (a * a + c * c) + u2y * (a * c + c * e));
  out[stride] = -(u1x * c + u1y * e) + (u2x * (a * c + c * e) + u2y * (c * c + e * e));
  out[2 * stride] = u1x * dx - (u2x * (hx + a * dx) + u2y * (c * dx));                               // E00
  out[3 * stride] = u1x * dy + u1y * dx - (u2x * (hy + a * dy + c * dx) + u2y * (hx + c * dy + e * dx));  // E01 + E10
  out[4 * stride] = u1y * dy - (u2x * (c * dy) + u2y * (hy + e * dy));                               // E11
  out[5 * stride] = r;
}

// Σ r², JᵀJ (5×5, by b_x, b_y, a, c, e) and Jᵀr over the readings (ux, uy; targets T), in one pass. Blocks of kLanes
// readings through small arrays, each lane its own partial sums, so that the compiler vectorises across readings
// (clones.hpp); a scalar loop with one running sum cannot be (floating-point addition does not reassociate).
constexpr int kSums = 21;  // cost, 15 distinct JᵀJ entries, 5 of Jᵀr

// Adds lanes 0 … lanes − 1 of one block (derivatives out[0 … 4], residual out[5]) to the lane sums.
FLUXCAL_ALWAYS_INLINE void accumulate(const double (&out)[6][detail::kLanes], double (&acc)[kSums][detail::kLanes],
                                      int lanes) {
  for (int l = 0; l < lanes; ++l) acc[0][l] += out[5][l] * out[5][l];
  int s = 1;
  for (int i = 0; i < 5; ++i)
    for (int j = i; j < 5; ++j, ++s)
      for (int l = 0; l < lanes; ++l) acc[s][l] += out[i][l] * out[j][l];
  for (int i = 0; i < 5; ++i, ++s)
    for (int l = 0; l < lanes; ++l) acc[s][l] += out[i][l] * out[5][l];
}
FLUXCAL_CLONES
void sampson_sums(const double* ux, const double* uy, const double* T, Eigen::Index n, const double* th,
                  double* sums) {
  using detail::kLanes;
  const double bx = th[0], by = th[1], a = th[2], c = th[3], e = th[4];
  double acc[kSums][kLanes] = {};
  double out[6][kLanes] = {};
  Eigen::Index k = 0;
  for (; k + kLanes <= n; k += kLanes) {
    for (int l = 0; l < kLanes; ++l) sampson_2d(ux[k + l] - bx, uy[k + l] - by, a, c, e, T[k + l], &out[0][l], kLanes);
    accumulate(out, acc, kLanes);
  }
  for (; k < n; ++k) {  // the last readings, one at a time through lane 0
    sampson_2d(ux[k] - bx, uy[k] - by, a, c, e, T[k], &out[0][0], kLanes);
    accumulate(out, acc, 1);
  }
  for (int s = 0; s < kSums; ++s) {
    double total = 0.0;
    for (int l = 0; l < kLanes; ++l) total += acc[s][l];
    sums[s] = total;
  }
}

// The normalised problem: U = (u − centre)/scale (O(1)), targets T = H_k/field_scale (mean 1).
struct Problem {
  Eigen::VectorXd ux, uy, T;
  PlanarShape shape;
  Eigen::MatrixXd P;  // full_map(shape)
};

struct Evaluation {
  double cost = kInf;  // Σ r² (normalised units)
  Eigen::MatrixXd F;   // JᵀJ by the shape's parameters
  Eigen::VectorXd g;   // Jᵀr
};

Evaluation evaluate(const Problem& pr, const Eigen::VectorXd& p, const Eigen::VectorXd& T) {
  const Eigen::Matrix2d A = matrix_of(pr.shape, p.data() + 2);
  const double th[5] = {p(0), p(1), A(0, 0), A(0, 1), A(1, 1)};
  double sums[kSums];
  sampson_sums(pr.ux.data(), pr.uy.data(), T.data(), pr.ux.size(), th, sums);
  Eigen::Matrix<double, 5, 5> F5;
  Eigen::Matrix<double, 5, 1> g5;
  int s = 1;
  for (int i = 0; i < 5; ++i)
    for (int j = i; j < 5; ++j) F5(i, j) = F5(j, i) = sums[s++];
  for (int i = 0; i < 5; ++i) g5(i) = sums[s++];
  Evaluation ev;
  ev.cost = sums[0];
  ev.F = pr.P.transpose() * F5 * pr.P;
  ev.g = pr.P.transpose() * g5;
  return ev;
}

// Each reading's Sampson residual (N×1) and score J_kᵀ r_k by the shape's parameters (N×k), normalised units, rows
// in the readings' order: what the test for correlation in time and the Newey–West sandwich take (long_run.hpp).
std::pair<Eigen::MatrixXd, Eigen::MatrixXd> residuals_and_scores(const Problem& pr, const Eigen::VectorXd& p,
                                                                 const Eigen::VectorXd& T) {
  const Eigen::Matrix2d A = matrix_of(pr.shape, p.data() + 2);
  const Eigen::Index n = pr.ux.size();
  Eigen::MatrixXd r(n, 1), J(n, 5);
  double out[6];
  for (Eigen::Index i = 0; i < n; ++i) {
    sampson_2d(pr.ux(i) - p(0), pr.uy(i) - p(1), A(0, 0), A(0, 1), A(1, 1), T(i), out, 1);
    for (int j = 0; j < 5; ++j) J(i, j) = out[j];
    r(i, 0) = out[5];
  }
  Eigen::MatrixXd scores = (J * pr.P).array().colwise() * r.col(0).array();
  return {std::move(r), std::move(scores)};
}

struct Solve {
  Eigen::VectorXd p;
  Evaluation at;  // cost, F, g at p
  int iterations = 0;
  bool converged = false;
};

// Levenberg–Marquardt (Marquardt's diagonal scaling) from p on Σ r² with targets T, A kept positive definite.
// Converged when a step changes no parameter by more than tolerance × max(1, |p|), when it lowers the cost by no
// more than its rounding (1e-15 of it), or when no step lowers it and the Gauss–Newton step's predicted decrease
// ½ gᵀF⁻¹g is below the rounding of the cost (a sum of N squares).
Solve levenberg_marquardt(const Problem& pr, Eigen::VectorXd p, const Eigen::VectorXd& T, int max_iterations,
                          double tolerance) {
  Solve out;
  Evaluation cur = evaluate(pr, p, T);
  const double n = static_cast<double>(pr.ux.size());
  double lambda = 1e-3;
  for (int it = 1; it <= max_iterations; ++it) {
    out.iterations = it;
    const Eigen::VectorXd D = cur.F.diagonal().cwiseMax(kTiny);
    std::optional<std::pair<Eigen::VectorXd, Evaluation>> accepted;
    while (lambda < 1e16) {
      Eigen::MatrixXd M = cur.F;
      M.diagonal() += lambda * D;
      bool factored = false;
      const Eigen::VectorXd delta = detail::ldlt_solve(M, -cur.g, &factored);
      if (!factored || !delta.allFinite()) {
        lambda *= 10.0;
        continue;
      }
      const Eigen::VectorXd trial = p + delta;
      if (positive_definite(matrix_of(pr.shape, trial.data() + 2))) {
        Evaluation next = evaluate(pr, trial, T);
        if (next.cost <= cur.cost) {
          accepted.emplace(delta, std::move(next));
          break;
        }
      }
      lambda *= 4.0;
    }
    if (!accepted) {
      const Eigen::VectorXd x = detail::least_squares_min_norm(cur.F, -cur.g);
      const double predicted = x.allFinite() ? 0.5 * (-cur.g).dot(x) : kInf;
      out.converged = predicted <= std::max(cur.cost, kTiny) * n * std::numeric_limits<double>::epsilon();
      break;
    }
    const Eigen::VectorXd& delta = accepted->first;
    const bool small = delta.cwiseAbs().maxCoeff() <= tolerance * std::max(1.0, p.cwiseAbs().maxCoeff());
    const bool settled = cur.cost - accepted->second.cost <= 1e-15 * cur.cost;
    p += delta;
    cur = std::move(accepted->second);
    lambda = std::max(lambda / 3.0, 1e-12);
    if (small || settled) {
      out.converged = true;
      break;
    }
  }
  out.p = std::move(p);
  out.at = std::move(cur);
  return out;
}

// ---- the starts ----------------------------------------------------------------------------------------------------

struct Start {
  std::string name;
  Eigen::Vector2d b;  // reading units
  Eigen::Matrix2d A;  // |A (u − b)| ≈ const (scaled to the targets later)
};

// Halir & Flusser's direct least-squares ellipse fit of the normalised readings (x, y): the centre c and E with
// (x − c)ᵀ E (x − c) = 1, or nothing when they determine no ellipse (a line, a point).
std::optional<std::pair<Eigen::Vector2d, Eigen::Matrix2d>> direct_ellipse(const Eigen::VectorXd& x,
                                                                          const Eigen::VectorXd& y) {
  // D1 = [x², xy, y²], D2 = [x, y, 1]: S1 = D1ᵀD1, S2 = D1ᵀD2, S3 = D2ᵀD2 from the monomial sums.
  double s40 = 0, s31 = 0, s22 = 0, s13 = 0, s04 = 0, s30 = 0, s21 = 0, s12 = 0, s03 = 0, s20 = 0, s11 = 0, s02 = 0,
         s10 = 0, s01 = 0;
  for (Eigen::Index k = 0; k < x.size(); ++k) {
    const double X = x(k), Y = y(k), xx = X * X, xy = X * Y, yy = Y * Y;
    s40 += xx * xx; s31 += xx * xy; s22 += xx * yy; s13 += xy * yy; s04 += yy * yy;
    s30 += xx * X; s21 += xx * Y; s12 += X * yy; s03 += yy * Y;
    s20 += xx; s11 += xy; s02 += yy; s10 += X; s01 += Y;
  }
  Eigen::Matrix3d S1, S2, S3;
  S1 << s40, s31, s22, s31, s22, s13, s22, s13, s04;
  S2 << s30, s21, s20, s21, s12, s11, s12, s03, s02;
  S3 << s20, s11, s10, s11, s02, s01, s10, s01, static_cast<double>(x.size());
  const Eigen::Vector3d s3 = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(S3, Eigen::EigenvaluesOnly).eigenvalues();
  if (!(s3(0) > kCollinear * s3(2))) return std::nullopt;
  const Eigen::Matrix3d T = -S3.inverse() * S2.transpose();
  const Eigen::Matrix3d M = S1 + S2 * T;
  Eigen::Matrix3d C;  // C1⁻¹ M, C1 = [[0, 0, 2], [0, −1, 0], [2, 0, 0]]
  C.row(0) = M.row(2) / 2.0;
  C.row(1) = -M.row(1);
  C.row(2) = M.row(0) / 2.0;
  const std::optional<Eigen::Matrix3d> vectors = detail::general_eigenvectors_real(C);
  if (!vectors) return std::nullopt;
  const Eigen::Matrix3d& V = *vectors;
  int chosen = -1;
  for (int j = 0; j < 3 && chosen < 0; ++j)
    if (4.0 * V(0, j) * V(2, j) - V(1, j) * V(1, j) > 0.0) chosen = j;  // the ellipse's constraint 4ac − b² > 0
  if (chosen < 0) return std::nullopt;
  const Eigen::Vector3d a1 = V.col(chosen), a2 = T * a1;
  Eigen::Matrix2d Q;
  Q << a1(0), a1(1) / 2.0, a1(1) / 2.0, a1(2);
  Eigen::Vector2d de(a2(0), a2(1));
  double f = a2(2);
  if (Q.trace() < 0.0) Q = -Q, de = -de, f = -f;
  if (!positive_definite(Q)) return std::nullopt;
  const Eigen::Vector2d centre = -0.5 * Q.inverse() * de;
  const double k = centre.dot(Q * centre) - f;
  if (!(k > 0.0) || !std::isfinite(k)) return std::nullopt;
  return std::make_pair(centre, Eigen::Matrix2d(Q / k));
}

// ---- the fit -------------------------------------------------------------------------------------------------------

void check(const PlanarOptions& o) {
  const std::string s = "PlanarOptions::";
  detail::require_enum(s + "shape", o.shape, 3, "circle, diagonal, symmetric");
  detail::require(std::isfinite(o.field_norm) && o.field_norm >= 0.0, s + "field_norm", o.field_norm,
                  "a finite value > 0 (the horizontal field), or 0 for a relative scale");
  detail::require_int(o.max_iterations >= 1, s + "max_iterations", o.max_iterations, "≥ 1");
  detail::require_positive(s + "tolerance", o.tolerance);
  detail::require_positive(s + "determined_tolerance", o.determined_tolerance);
  detail::require_nonnegative(s + "min_radius_over_noise", o.min_radius_over_noise, "a finite value ≥ 0 (0: never)");
  detail::require_enum(s + "serial_correlation", o.serial_correlation, 3, "automatic, independent, newey_west (0 … 2)");
  detail::require_open_unit(s + "serial_correlation_alpha", o.serial_correlation_alpha,
                            "a significance level in (0, 1)");
  if (o.start && !(o.start->offset.allFinite() && o.start->matrix.allFinite() &&
                   positive_definite(0.5 * (o.start->matrix + o.start->matrix.transpose()))))
    throw Error(s + "start: the offset and matrix must be finite and the matrix positive definite (a planar "
                "calibration's), got offset (" + std::to_string(o.start->offset(0)) + ", " +
                std::to_string(o.start->offset(1)) + ")");
}

void check_readings(const Readings2DRef& readings) {
  readings.require_width("readings");
  if (readings.rows() < kMinReadings)
    throw Error("readings: " + std::to_string(readings.rows()) + " rows; a planar calibration fits " +
                std::to_string(kEllipseParameters) + " parameters (offset and a 2×2 matrix) and needs at least " +
                std::to_string(kMinReadings) + " — log more readings while the vehicle turns a full circle");
  static const char* axis[] = {"x", "y"};
  for (Eigen::Index i = 0; i < readings.rows(); ++i)
    for (int j = 0; j < 2; ++j)
      if (!std::isfinite(readings(i, j)))
        throw Error("readings: row " + std::to_string(i) + ", column " + std::to_string(j) + " (" + axis[j] +
                    ") is " + (std::isnan(readings(i, j)) ? "NaN" : "infinite") +
                    "; remove or repair non-finite readings");
}

PlanarResult fit(const Readings2DRef& u, const Eigen::VectorXd* norms, const PlanarOptions& options) {
  const Eigen::Index n = u.rows();
  const double nd = static_cast<double>(n);
  PlanarResult out;
  out.shape = options.shape;
  out.units = options.units;
  out.relative_scale = norms == nullptr;
  Summary& sum = out.summary;
  sum.samples = static_cast<std::size_t>(n);

  // Normalisation: centre the mean, scale the RMS distance from it.
  const Eigen::Vector2d centre = u.colwise().mean().transpose();
  Problem pr;
  pr.shape = options.shape;
  pr.P = full_map(options.shape);
  pr.ux = u.col(0).array() - centre(0);
  pr.uy = u.col(1).array() - centre(1);
  const double scale = std::sqrt((pr.ux.squaredNorm() + pr.uy.squaredNorm()) / nd);
  detail::require_finite_fit(std::isfinite(scale), "readings", u, "the planar fit");
  if (!(scale > 0.0))
    throw Error("readings: every row is the same reading: the sensor did not turn — log while the vehicle turns a "
                "full circle");
  pr.ux /= scale;
  pr.uy /= scale;
  {
    Eigen::Matrix2d cov;
    cov << pr.ux.squaredNorm(), pr.ux.dot(pr.uy), pr.ux.dot(pr.uy), pr.uy.squaredNorm();
    const Eigen::Vector2d ev = detail::symmetric_eigenvalues(cov);
    sum.coverage_ratio = ev(1) > 0.0 ? std::sqrt(std::max(ev(0), 0.0) / ev(1)) : 0.0;
  }

  // Starts (reading units), and the reference radius R0 of a relative scale: the direct fit's geometric-mean radius
  // (any radius gives the same b and det-normalised A: the Sampson residual is unchanged by A → λA, T → λT), or a
  // given start's (its mean |A (u − b)| / √det A).
  std::vector<Start> starts;
  double radius = scale;
  std::optional<std::pair<Eigen::Vector2d, Eigen::Matrix2d>> direct;
  if (options.start) {
    const PlanarStart& given = *options.start;
    double mean_h = 0.0;
    for (Eigen::Index i = 0; i < n; ++i) mean_h += (given.matrix * (u.row(i).transpose() - given.offset)).norm();
    radius = mean_h / nd / std::sqrt(std::abs(given.matrix.determinant()));
    starts.push_back({"given", given.offset, given.matrix});
  } else if ((direct = direct_ellipse(pr.ux, pr.uy))) {
    radius = std::pow((direct->second / (scale * scale)).determinant(), -0.25);
  }
  const Eigen::VectorXd targets = norms ? *norms : Eigen::VectorXd::Constant(n, radius);
  // step 1's two starts (with a given start: only when the refinement from it does not converge)
  const auto step_one = [&]() {
    std::vector<Start> found;
    if (options.start) direct = direct_ellipse(pr.ux, pr.uy);
    if (direct) {
      const Eigen::Matrix2d E = direct->second / (scale * scale);  // (u − b)ᵀ E (u − b) = 1
      found.push_back({"direct ellipse fit", centre + scale * direct->first,
                       detail::symmetric_sqrt(E)});
    }
    try {
      const TwoStep2DResult ts = twostep_2d(u, targets);  // reading = γ ⊙ h + b
      found.push_back({"twostep_2d", ts.offset, Eigen::Vector2d(ts.gain.cwiseInverse()).asDiagonal()});
    } catch (const Error&) {
      // no start from it; the direct fit may still have one
    }
    return found;
  };
  if (!options.start) starts = step_one();
  if (starts.empty())
    throw Error("readings: the readings trace no ellipse (the direct ellipse fit and TWOSTEP 2-D both fail: points on "
                "a line, or at a few places) — turn the vehicle through a full circle");
  const double field_scale = targets.mean();
  pr.T = targets / field_scale;

  // Each start scaled to the targets (its mean |A (U − β)| to their mean 1), then refined from the one that fits best
  // to begin with; the other only when that refinement does not converge (each solve passes over all readings a few
  // dozen times: at 10⁵ readings the second start doubled the time for the same answer).
  const int k = 2 + coefficient_count(options.shape);
  std::optional<Solve> best;
  std::size_t best_start = 0;
  const auto refine_from = [&](std::size_t first) {
    std::vector<std::tuple<double, std::size_t, Eigen::VectorXd>> candidates;
    for (std::size_t s = first; s < starts.size(); ++s) {
      const Start& st = starts[s];
      const Eigen::Vector2d beta = (st.b - centre) / scale;
      double mean_h = 0.0;
      for (Eigen::Index i = 0; i < n; ++i)
        mean_h += (st.A * Eigen::Vector2d(pr.ux(i) - beta(0), pr.uy(i) - beta(1))).norm();
      mean_h /= nd;
      Eigen::VectorXd p0(k);
      p0.head<2>() = beta;
      p0.tail(k - 2) = coefficients_of(options.shape, st.A * (pr.T.mean() / mean_h));
      double cost0 = kInf;
      if (p0.allFinite() && positive_definite(matrix_of(options.shape, p0.data() + 2))) {
        cost0 = evaluate(pr, p0, pr.T).cost;
        if (!std::isfinite(cost0)) cost0 = kInf;
      }
      candidates.emplace_back(cost0, s, std::move(p0));
    }
    std::stable_sort(candidates.begin(), candidates.end(),
                     [](const auto& l, const auto& r) { return std::get<0>(l) < std::get<0>(r); });
    for (const auto& [cost0, s, p0] : candidates) {
      if (!p0.allFinite() || !positive_definite(matrix_of(options.shape, p0.data() + 2))) continue;
      Solve solved = levenberg_marquardt(pr, p0, pr.T, options.max_iterations, options.tolerance);
      if (solved.p.allFinite() && std::isfinite(solved.at.cost) && (!best || solved.at.cost < best->at.cost)) {
        best = std::move(solved);
        best_start = s;
      }
      if (best && best->converged) break;
    }
  };
  refine_from(0);
  if (options.start && !(best && best->converged)) {
    for (Start& st : step_one()) starts.push_back(std::move(st));
    refine_from(1);
  }
  if (!best)
    throw Error("readings: the planar fit (shape " + std::string(shape_name(options.shape)) +
                ") found no ellipse from any start — check the readings for outliers, and that the vehicle turned a "
                "full circle");
  out.start = starts[best_start].name;
  Solve result = std::move(*best);
  int iterations = result.iterations;
  const double dof = std::max(nd - k, 1.0);

  // Noise bias: raise each target by σ̂²‖A‖_F²/(4 T_k) and solve again (the header's step 3).
  Eigen::VectorXd fitted_targets = pr.T;
  if (options.noise_bias_correction) {
    const double sigma2 = result.at.cost / dof;
    const Eigen::Matrix2d A = matrix_of(options.shape, result.p.data() + 2);
    fitted_targets = pr.T.array() + sigma2 * A.squaredNorm() / (4.0 * pr.T.array());
    Solve again = levenberg_marquardt(pr, result.p, fitted_targets, options.max_iterations, options.tolerance);
    iterations += again.iterations;
    result = std::move(again);
  }
  sum.iterations = iterations;
  sum.converged = result.converged;

  // Covariance σ̂²(JᵀJ)⁻¹ through the eigen-decomposition of the column-scaled JᵀJ.
  const double sigma2 = result.at.cost / dof;
  const detail::ScaledInverse Finv = detail::scaled_inverse(result.at.F);
  out.fisher_condition = Finv.condition;
  Eigen::MatrixXd independent = sigma2 * Finv.inverse, cov = independent;
  // Readings correlated in time: the Newey–West sandwich (the header's step 4), rows in the readings' order.
  const auto [r_n, scores] = residuals_and_scores(pr, result.p, fitted_targets);
  const std::string correlated = detail::correct_for_serial_correlation(
      cov, out.serial_correlation, r_n, scores, Finv.inverse, Finv.singular, options.serial_correlation,
      options.serial_correlation_alpha);
  // Back to reading units: b = centre + scale·β, A = A_n·field_scale/scale.
  Eigen::VectorXd to(k), values(k);
  to.head<2>().setConstant(scale);
  to.tail(k - 2).setConstant(field_scale / scale);
  values.head<2>() = centre + scale * result.p.head<2>();
  values.tail(k - 2) = result.p.tail(k - 2) * (field_scale / scale);
  for (Eigen::MatrixXd* c : {&cov, &independent}) *c = to.asDiagonal() * *c * to.asDiagonal();
  Eigen::Matrix2d A = matrix_of(options.shape, values.data() + 2);
  Eigen::VectorXd H = targets;  // each reading's |h| target, reading units of h
  out.field_norm = field_scale;
  if (!norms) {
    // Relative scale: c → c/√det A(c) (det A = 1), its covariance carried by the Jacobian G (delta method);
    // field_norm = R0/√det A: the fitted ellipse's geometric-mean radius.
    const double det = A.determinant(), root = std::sqrt(det);
    const Eigen::VectorXd c = values.tail(k - 2);
    Eigen::VectorXd grad(k - 2);  // ∂det/∂c
    switch (options.shape) {
      case PlanarShape::circle: grad << 2.0 * c(0); break;
      case PlanarShape::diagonal: grad << c(1), c(0); break;
      case PlanarShape::symmetric: grad << c(2), -2.0 * c(1), c(0); break;
    }
    Eigen::MatrixXd G = Eigen::MatrixXd::Identity(k, k);
    G.bottomRightCorner(k - 2, k - 2) =
        Eigen::MatrixXd::Identity(k - 2, k - 2) / root - 0.5 * c * grad.transpose() / (det * root);
    for (Eigen::MatrixXd* m : {&cov, &independent}) *m = G * *m * G.transpose();
    values.tail(k - 2) = c / root;
    A /= root;
    out.field_norm = radius / root;
    H.setConstant(out.field_norm);
  }
  out.offset = values.head<2>();
  out.matrix = A;
  out.parameters = values;
  out.covariance = cov;
  out.standard_errors = cov.diagonal().cwiseMax(0.0).cwiseSqrt();
  out.serial_correlation.standard_errors_independent = independent.diagonal().cwiseMax(0.0).cwiseSqrt();
  if (out.serial_correlation.lags > 0) {  // the widening of the reported parameters (after the delta method)
    double widest = 0.0;
    for (int j = 0; j < k; ++j)
      if (out.serial_correlation.standard_errors_independent(j) > 0.0)
        widest = std::max(widest, out.standard_errors(j) / out.serial_correlation.standard_errors_independent(j));
    out.serial_correlation.inflation = widest;
  }
  out.sigma = std::sqrt(sigma2) * scale;
  out.rss = result.at.cost * scale * scale;
  out.parameter_names = {"b_x", "b_y"};
  switch (options.shape) {
    case PlanarShape::circle: out.parameter_names.push_back("a"); break;
    case PlanarShape::diagonal: out.parameter_names.insert(out.parameter_names.end(), {"a_xx", "a_yy"}); break;
    case PlanarShape::symmetric:
      out.parameter_names.insert(out.parameter_names.end(), {"a_xx", "a_xy", "a_yy"});
      break;
  }

  // A pass over the readings: each one's Sampson residual against its target, |h| statistics, the mean radius.
  out.residuals.resize(n);
  double radius_sum = 0.0, q_sum = 0.0, q2_sum = 0.0, d2_sum = 0.0, h_sum = 0.0;
  for (Eigen::Index i = 0; i < n; ++i) {
    const Eigen::Vector2d d(u(i, 0) - out.offset(0), u(i, 1) - out.offset(1));
    const Eigen::Vector2d h = A * d;
    const double rho = h.norm();
    out.residuals(i) = (rho - H(i)) * rho / std::max((A * h).norm(), kTiny);
    radius_sum += d.norm();
    const double q = rho / H(i);
    q_sum += q, q2_sum += q * q, h_sum += rho;
    d2_sum += (rho - H(i)) * (rho - H(i));
  }
  out.mean_radius = radius_sum / nd;
  const double q_mean = q_sum / nd;
  sum.norm_mean = h_sum / nd;
  sum.norm_std_over_mean = std::sqrt(std::max(0.0, q2_sum / nd - q_mean * q_mean)) / q_mean;
  sum.residual_rms = std::sqrt(d2_sum / nd);
  sum.exact_statistics = true;
  sum.cost = out.rss / nd;
  sum.condition_number = out.fisher_condition;
  detail::require_finite_fit(detail::finite_fit(sum) && out.matrix.allFinite() && out.offset.allFinite(), "readings", u,
                             "the planar fit");

  const double matrix_scale = A.norm() / std::sqrt(2.0);
  out.determined.resize(static_cast<std::size_t>(k));
  out.identifiable = true;
  std::string undetermined;
  for (int j = 0; j < k; ++j) {
    // a property of the coverage: judged on the independent-readings errors, as refine's
    const bool ok = out.serial_correlation.standard_errors_independent(j) <
                    options.determined_tolerance * (j < 2 ? out.mean_radius : matrix_scale);
    out.determined[static_cast<std::size_t>(j)] = ok;
    if (!ok) {
      out.identifiable = false;
      undetermined += (undetermined.empty() ? "" : ", ") + out.parameter_names[static_cast<std::size_t>(j)];
    }
  }

  if (options.min_radius_over_noise > 0.0 && !(out.mean_radius > options.min_radius_over_noise * out.sigma))
    throw Error("readings: the readings scatter about their fitted ellipse by " + num(out.sigma) + " RMS, " +
                percent(out.sigma / out.mean_radius) + " of its mean radius " + num(out.mean_radius) +
                ": they trace no ellipse — a vehicle that barely turned (turn a full circle), or readings disturbed "
                "far beyond a sensor's noise (a magnet or motor near the sensor, a tumbled or shaken sensor)");
  if (!sum.converged)
    sum.warnings.push_back("the planar fit did not converge in " + std::to_string(iterations) +
                           " iterations: the result is the last iterate — check the readings for outliers and that "
                           "the vehicle turned a full circle");
  if (!correlated.empty()) sum.warnings.push_back(correlated);
  if (!out.identifiable)
    sum.warnings.push_back("not identifiable: the data do not determine " + undetermined + " (standard error above " +
                           percent(options.determined_tolerance) + " of its scale) — turn through more of the circle, "
                           "more evenly, or log more readings");

  std::ostringstream msg;
  const std::string unit = out.units.empty() ? "" : " " + out.units;
  msg << "planar fit (" << shape_name(options.shape) << "): " << n << " readings, "
      << (sum.converged ? "converged" : "NOT converged") << " in " << iterations << " iterations, |h| std/mean "
      << percent(sum.norm_std_over_mean) << ", noise σ " << num(out.sigma) << unit << ", from the " << out.start;
  if (!sum.warnings.empty()) msg << " (" << sum.warnings.size() << " warning(s))";
  sum.message = msg.str();
  return out;
}

}  // namespace

Readings2D PlanarResult::apply_rows(const Readings2DRef& readings) const {
  readings.require_width("readings");
  return (readings.rowwise() - offset.transpose()) * matrix.transpose();
}

PlanarResult fit_planar(const Readings2DRef& readings, const PlanarOptions& options) {
  check(options);
  check_readings(readings);
  if (options.field_norm > 0.0) {
    const Eigen::VectorXd norms = Eigen::VectorXd::Constant(readings.rows(), options.field_norm);
    return fit(readings, &norms, options);
  }
  return fit(readings, nullptr, options);
}

PlanarResult fit_planar(const Readings2DRef& readings, const SeriesRef& field_norms, const PlanarOptions& options) {
  check(options);
  check_readings(readings);
  detail::check_field_norms(field_norms, readings.rows());
  const Eigen::VectorXd norms = field_norms;
  return fit(readings, &norms, options);
}

}  // namespace fluxcal
