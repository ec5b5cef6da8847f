#include "fluxcal/cable.hpp"

#include "checks.hpp"
#include "linalg.hpp"
#include "fluxcal/timeseries.hpp"

#include <ceres/ceres.h>

#include <Eigen/Dense>
#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <numeric>
#include <utility>
#include <sstream>

namespace fluxcal {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
// Column-scaled Fisher matrices above this condition number are singular to double precision.
constexpr double kSingularFisher = 1e14;

using detail::num;

// Sensor positions and axes of a ring in normalised units (radius 1).
struct RingFrame {
  Eigen::Index m = 0;
  Eigen::Matrix2Xd p, x, y;  // position, x axis, y axis of each sensor
  Eigen::VectorXd w;         // each sensor's residual weight in the fit: 1 / its relative σ
  explicit RingFrame(const CableRing& ring) : m(ring.sensors()), p(2, m), x(2, m), y(2, m), w(Eigen::VectorXd::Ones(m)) {
    for (Eigen::Index i = 0; i < m; ++i) {
      const double th = ring.angles(i), a = th + ring.axis_angle(i);
      p.col(i) << std::cos(th), std::sin(th);
      x.col(i) << std::cos(a), std::sin(a);
      y.col(i) << -std::sin(a), std::cos(a);
    }
  }
};

// Unit-current reading of sensor i from a conductor at c (normalised): g = (−dy, dx)/|d|², d = p − c,
// projected on the sensor axes; optionally its derivatives over c (∂/∂c = −∂/∂d).
inline void unit_reading(const RingFrame& f, Eigen::Index i, double cx, double cy, double out[2], double dcx[2],
                         double dcy[2]) {
  const double dx = f.p(0, i) - cx, dy = f.p(1, i) - cy;
  const double q = dx * dx + dy * dy, iq = 1.0 / q;
  const double gx = -dy * iq, gy = dx * iq;
  const double xx = f.x(0, i), xy = f.x(1, i), yx = f.y(0, i), yy = f.y(1, i);
  out[0] = gx * xx + gy * xy;
  out[1] = gx * yx + gy * yy;
  if (dcx) {
    // ∂g/∂dx = ((0,1) − 2dx g)/q, ∂g/∂dy = ((−1,0) − 2dy g)/q; ∂/∂c = −∂/∂d
    const double ax = (-2.0 * dx * gx) * iq, ay = (1.0 - 2.0 * dx * gy) * iq;
    const double bx = (-1.0 - 2.0 * dy * gx) * iq, by = (-2.0 * dy * gy) * iq;
    dcx[0] = -(ax * xx + ay * xy);
    dcx[1] = -(ax * yx + ay * yy);
    dcy[0] = -(bx * xx + by * xy);
    dcy[1] = -(bx * yx + by * yy);
  }
}

// Design matrix of the currents at given (normalised) positions: 2M × N, column j = unit-current readings.
void design(const RingFrame& f, const double* pos, int n, Eigen::MatrixXd& G) {
  G.resize(2 * f.m, n);
  for (int j = 0; j < n; ++j)
    for (Eigen::Index i = 0; i < f.m; ++i) {
      double r[2];
      unit_reading(f, i, pos[2 * j], pos[2 * j + 1], r, nullptr, nullptr);
      G(2 * i, j) = r[0];
      G(2 * i + 1, j) = r[1];
    }
}

// Currents columns for the reduced parametrisation: with ΣI = 0 the last current is −Σ others.
Eigen::MatrixXd reduce(const Eigen::MatrixXd& G, bool zero_sum) {
  if (!zero_sum) return G;
  const Eigen::Index n = G.cols();
  return G.leftCols(n - 1).colwise() - G.col(n - 1);
}

// Readings of a uniform field b (cable frame) in every sensor's axes: 2M × 2, rows x̂_iᵀ, ŷ_iᵀ.
Eigen::MatrixXd background_design(const RingFrame& f) {
  Eigen::MatrixXd U(2 * f.m, 2);
  for (Eigen::Index i = 0; i < f.m; ++i) {
    U.row(2 * i) = f.x.col(i).transpose();
    U.row(2 * i + 1) = f.y.col(i).transpose();
  }
  return U;
}

// One snapshot: residuals 2M (model − reading, normalised), parameter blocks: positions (2N), currents
// (N, or N − 1 with ΣI = 0) and, with a background, the uniform field (2, shared by every snapshot).
class SnapshotCost : public ceres::CostFunction {
 public:
  SnapshotCost(const RingFrame& f, const double* reading, int n, bool zero_sum, bool background)
      : f_(f), reading_(reading), n_(n), zero_sum_(zero_sum), background_(background) {
    set_num_residuals(static_cast<int>(2 * f.m));
    mutable_parameter_block_sizes()->push_back(2 * n);
    mutable_parameter_block_sizes()->push_back(zero_sum ? n - 1 : n);
    if (background) mutable_parameter_block_sizes()->push_back(2);
  }

  bool Evaluate(double const* const* params, double* residuals, double** jacobians) const override {
    const double* pos = params[0];
    const double* cur = params[1];
    const int nc = zero_sum_ ? n_ - 1 : n_;
    const int rows = static_cast<int>(2 * f_.m);
    double last = 0.0;
    if (zero_sum_)
      for (int j = 0; j < nc; ++j) last -= cur[j];
    for (int k = 0; k < rows; ++k) residuals[k] = -reading_[k];
    if (background_) {
      const double* b = params[2];
      double* jb = jacobians ? jacobians[2] : nullptr;
      for (Eigen::Index i = 0; i < f_.m; ++i) {
        const double* axes[2] = {&f_.x(0, i), &f_.y(0, i)};
        for (int a = 0; a < 2; ++a) {
          const int row = static_cast<int>(2 * i) + a;
          residuals[row] += axes[a][0] * b[0] + axes[a][1] * b[1];
          if (jb) jb[2 * row] = axes[a][0], jb[2 * row + 1] = axes[a][1];
        }
      }
    }
    double* jp = jacobians ? jacobians[0] : nullptr;
    double* jc = jacobians ? jacobians[1] : nullptr;
    if (jc)
      for (int k = 0; k < rows * nc; ++k) jc[k] = 0.0;
    for (int j = 0; j < n_; ++j) {
      const double I = (j < nc) ? cur[j] : last;
      for (Eigen::Index i = 0; i < f_.m; ++i) {
        double r[2], dx[2], dy[2];
        unit_reading(f_, i, pos[2 * j], pos[2 * j + 1], r, jp ? dx : nullptr, jp ? dy : nullptr);
        for (int a = 0; a < 2; ++a) {
          const int row = static_cast<int>(2 * i) + a;
          residuals[row] += I * r[a];
          if (jp) {
            jp[row * 2 * n_ + 2 * j] = I * dx[a];
            jp[row * 2 * n_ + 2 * j + 1] = I * dy[a];
          }
          if (jc) {
            if (j < nc) {
              jc[row * nc + j] += r[a];
            } else {
              for (int k = 0; k < nc; ++k) jc[row * nc + k] -= r[a];
            }
          }
        }
      }
    }
    // each sensor's rows weighted by 1 / its relative σ (all 1 unless CableSolveOptions::relative_sigma)
    const int widths[3] = {2 * n_, nc, 2};
    for (int row = 0; row < rows; ++row) {
      const double w = f_.w(row / 2);
      if (w == 1.0) continue;
      residuals[row] *= w;
      for (int b = 0; b < (background_ ? 3 : 2); ++b)
        if (jacobians && jacobians[b])
          for (int c = 0; c < widths[b]; ++c) jacobians[b][row * widths[b] + c] *= w;
    }
    return true;
  }

 private:
  const RingFrame& f_;
  const double* reading_;
  int n_;
  bool zero_sum_;
  bool background_;
};

// How a refinement went.
struct RunInfo {
  double cost = kInf;  // ½ Σ r² (normalised), as Ceres reports it
  int iterations = 0;
  bool converged = false;
  bool usable = false;
  std::string message;
};

// Up to this many parameters the Fisher information is inverted whole (an eigen-decomposition, O(p³)); above, by
// blocks (one snapshot's currents are 1–4 parameters; 800 snapshots of an AC waveform had taken 8 s whole).
constexpr Eigen::Index kDenseFisher = 400;

// The inverse of the column-scaled Fisher information of the cable problem, read back unscaled by blocks, and its
// condition number (inf when singular: no inverse then).
class FisherInverse {
 public:
  double condition = kInf;
  Eigen::MatrixXd shared() const { return dk_.asDiagonal() * at(-1, -1) * dk_.asDiagonal(); }
  Eigen::MatrixXd shared_currents(Eigen::Index s) const { return dk_.asDiagonal() * at(-1, s) * dc(s).asDiagonal(); }
  Eigen::MatrixXd currents(Eigen::Index s, Eigen::Index t) const {
    return dc(s).asDiagonal() * at(s, t) * dc(t).asDiagonal();
  }

 private:
  friend class FisherBlocks;
  Eigen::Index k_ = 0, nc_ = 0;
  Eigen::VectorXd dk_, dc_;  // column scaling: shared, then every snapshot's currents
  Eigen::MatrixXd dense_;    // the whole scaled inverse (shared first), or empty ...
  Eigen::MatrixXd cpp_;      // ... its blocks: the shared block, E_s = D_s⁻¹ B_sᵀ and D_s⁻¹
  std::vector<Eigen::MatrixXd> e_, dinv_;
  Eigen::VectorXd dc(Eigen::Index s) const { return dc_.segment(nc_ * s, nc_); }
  // scaled inverse block: rows of the shared parameters (−1) or of snapshot s's currents, columns likewise
  Eigen::MatrixXd at(Eigen::Index s, Eigen::Index t) const {
    if (dense_.size()) {
      const Eigen::Index r0 = s < 0 ? 0 : k_ + nc_ * s, c0 = t < 0 ? 0 : k_ + nc_ * t;
      return dense_.block(r0, c0, s < 0 ? k_ : nc_, t < 0 ? k_ : nc_);
    }
    if (s < 0 && t < 0) return cpp_;
    if (s < 0) return -cpp_ * e_[static_cast<std::size_t>(t)].transpose();
    if (t < 0) return -e_[static_cast<std::size_t>(s)] * cpp_;
    Eigen::MatrixXd out = e_[static_cast<std::size_t>(s)] * cpp_ * e_[static_cast<std::size_t>(t)].transpose();
    if (s == t) out += dinv_[static_cast<std::size_t>(s)];
    return out;
  }
};

// JᵀJ of the cable problem in its arrow shape: the shared parameters (positions, background: k) against each
// snapshot's own currents (nc), which only that snapshot's readings see.
class FisherBlocks {
 public:
  FisherBlocks(Eigen::Index k, Eigen::Index nc, Eigen::Index snapshots)
      : k_(k), nc_(nc), A_(Eigen::MatrixXd::Zero(k, k)), B_(static_cast<std::size_t>(snapshots)),
        D_(static_cast<std::size_t>(snapshots)) {}
  void clear() { A_.setZero(); }
  /// Snapshot s's Jacobian: its shared columns and its currents' columns.
  void add(Eigen::Index s, const Eigen::MatrixXd& Jk, const Eigen::MatrixXd& Jc) {
    A_.noalias() += Jk.transpose() * Jk;
    B_[static_cast<std::size_t>(s)] = Jk.transpose() * Jc;
    D_[static_cast<std::size_t>(s)] = Jc.transpose() * Jc;
  }

  const Eigen::MatrixXd& shared() const { return A_; }
  const Eigen::MatrixXd& shared_currents(Eigen::Index s) const { return B_[static_cast<std::size_t>(s)]; }
  const Eigen::MatrixXd& currents(Eigen::Index s) const { return D_[static_cast<std::size_t>(s)]; }

  FisherInverse invert() const {
    const Eigen::Index S = static_cast<Eigen::Index>(D_.size()), p = k_ + nc_ * S;
    FisherInverse out;
    out.k_ = k_, out.nc_ = nc_;
    auto scale = [](const Eigen::VectorXd& diag) {
      return diag.unaryExpr([](double v) { return v > 0.0 ? 1.0 / std::sqrt(v) : 1.0; }).eval();
    };
    out.dk_ = scale(A_.diagonal());
    out.dc_.resize(nc_ * S);
    for (Eigen::Index s = 0; s < S; ++s) out.dc_.segment(nc_ * s, nc_) = scale(D_[static_cast<std::size_t>(s)].diagonal());
    const auto& dk = out.dk_;
    auto dc = [&](Eigen::Index s) { return out.dc_.segment(nc_ * s, nc_); };
    const Eigen::MatrixXd As = dk.asDiagonal() * A_ * dk.asDiagonal();
    std::vector<Eigen::MatrixXd> Bs(static_cast<std::size_t>(S)), Ds(static_cast<std::size_t>(S));
    for (Eigen::Index s = 0; s < S; ++s) {
      const auto u = static_cast<std::size_t>(s);
      Bs[u] = dk.asDiagonal() * B_[u] * dc(s).asDiagonal();
      Ds[u] = dc(s).asDiagonal() * D_[u] * dc(s).asDiagonal();
    }
    if (p <= kDenseFisher) {  // whole: as small problems always were
      Eigen::MatrixXd F(p, p);
      F.topLeftCorner(k_, k_) = As;
      F.bottomRightCorner(p - k_, p - k_).setZero();
      for (Eigen::Index s = 0; s < S; ++s) {
        const auto u = static_cast<std::size_t>(s);
        F.block(0, k_ + nc_ * s, k_, nc_) = Bs[u];
        F.block(k_ + nc_ * s, 0, nc_, k_) = Bs[u].transpose();
        F.block(k_ + nc_ * s, k_ + nc_ * s, nc_, nc_) = Ds[u];
      }
      const detail::SymmetricEigen<Eigen::Dynamic> eig = detail::symmetric_eigen(F);
      const Eigen::VectorXd& lam = eig.values;
      out.condition = lam(0) > 0.0 ? lam(p - 1) / lam(0) : kInf;
      if (out.condition < kSingularFisher)
        out.dense_ = eig.vectors * lam.cwiseInverse().asDiagonal() * eig.vectors.transpose();
      return out;
    }
    // by blocks: each snapshot's currents eliminated into the shared block (Schur complement)
    Eigen::MatrixXd schur = As;
    out.dinv_.resize(static_cast<std::size_t>(S));
    out.e_.resize(static_cast<std::size_t>(S));
    for (Eigen::Index s = 0; s < S; ++s) {
      const auto u = static_cast<std::size_t>(s);
      const detail::SymmetricEigen<Eigen::Dynamic> eig = detail::symmetric_eigen(Ds[u]);
      if (!(eig.values(0) > 1e-14 * eig.values(nc_ - 1))) return out;  // singular
      out.dinv_[u] = eig.vectors * eig.values.cwiseInverse().asDiagonal() * eig.vectors.transpose();
      out.e_[u] = out.dinv_[u] * Bs[u].transpose();
      schur.noalias() -= Bs[u] * out.e_[u];
    }
    const detail::SymmetricEigen<Eigen::Dynamic> eig = detail::symmetric_eigen(schur);
    if (!(eig.values(0) > 1e-14 * eig.values(k_ - 1))) return out;
    out.cpp_ = eig.vectors * eig.values.cwiseInverse().asDiagonal() * eig.vectors.transpose();
    // the extreme eigenvalues by power iteration: on the matrix for the largest, on its inverse for the smallest
    auto times = [&](const Eigen::VectorXd& x) {
      Eigen::VectorXd y(p);
      y.head(k_) = As * x.head(k_);
      for (Eigen::Index s = 0; s < S; ++s) {
        const auto u = static_cast<std::size_t>(s);
        y.head(k_) += Bs[u] * x.segment(k_ + nc_ * s, nc_);
        y.segment(k_ + nc_ * s, nc_) = Bs[u].transpose() * x.head(k_) + Ds[u] * x.segment(k_ + nc_ * s, nc_);
      }
      return y;
    };
    auto solve = [&](const Eigen::VectorXd& x) {
      Eigen::VectorXd y(p), rhs = x.head(k_);
      for (Eigen::Index s = 0; s < S; ++s) rhs -= out.e_[static_cast<std::size_t>(s)].transpose() * x.segment(k_ + nc_ * s, nc_);
      y.head(k_) = out.cpp_ * rhs;
      for (Eigen::Index s = 0; s < S; ++s) {
        const auto u = static_cast<std::size_t>(s);
        y.segment(k_ + nc_ * s, nc_) = out.dinv_[u] * x.segment(k_ + nc_ * s, nc_) - out.e_[u] * y.head(k_);
      }
      return y;
    };
    auto largest = [&](auto&& apply) {
      Eigen::VectorXd x = Eigen::VectorXd::LinSpaced(p, 1.0, 2.0).normalized();
      double value = 0.0;
      for (int it = 0; it < 500; ++it) {
        const Eigen::VectorXd y = apply(x);
        const double next = x.dot(y);  // Rayleigh quotient
        x = y.normalized();
        if (it > 10 && std::abs(next - value) <= 1e-12 * std::abs(next)) return next;
        value = next;
      }
      return value;
    };
    out.condition = largest(times) * largest(solve);
    return out;
  }

 private:
  Eigen::Index k_, nc_;
  Eigen::MatrixXd A_;
  std::vector<Eigen::MatrixXd> B_, D_;
};

// Dense Levenberg–Marquardt (Marquardt's diagonal scaling, bounds by projection) on the same residual
// blocks: no set-up cost, for the warm-started path of a continuous measurement. Its normal equations have the
// arrow shape of the problem — the shared parameters (positions, background) against each snapshot's own
// currents — and are solved by blocks (the Schur complement on the shared ones): O(S), where the whole matrix
// was O(S³) (800 snapshots of an AC waveform: 20 s).
// `bg` is the background field (2, normalised) or null when none is fitted.
RunInfo dense_lm(const std::vector<std::unique_ptr<SnapshotCost>>& costs, std::vector<double>& pos, Eigen::MatrixXd& cur,
                 Eigen::Vector2d* bg, int n, double bore, const CableSolveOptions& opt) {
  const int nc = static_cast<int>(cur.rows());
  const Eigen::Index S = cur.cols(), rows = costs.empty() ? 0 : costs[0]->num_residuals();
  const Eigen::Index nb = bg ? 2 : 0, k = 2 * n + nb;  // shared parameters: positions, then the background
  using RowMat = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  Eigen::VectorXd r(rows * S), r_try(rows * S);
  RowMat Jp(rows, 2 * n), Jc(rows, nc), Jb(rows, 2);
  Eigen::MatrixXd Jk(rows, k);  // one snapshot's shared columns
  FisherBlocks fb(k, nc, S);    // JᵀJ by blocks
  Eigen::VectorXd gk(k);
  Eigen::MatrixXd gc(nc, S);
  Eigen::Vector2d b = bg ? *bg : Eigen::Vector2d::Zero(), b_try = b;
  auto evaluate = [&](const std::vector<double>& ps, const Eigen::MatrixXd& cs, const Eigen::Vector2d& bs,
                      Eigen::VectorXd& res, bool jac) {
    if (jac) fb.clear(), gk.setZero();
    for (Eigen::Index s = 0; s < S; ++s) {
      const double* params[3] = {ps.data(), cs.col(s).data(), bs.data()};
      double* jacs[3] = {Jp.data(), Jc.data(), Jb.data()};
      costs[static_cast<std::size_t>(s)]->Evaluate(params, res.data() + rows * s, jac ? jacs : nullptr);
      if (jac) {
        Jk.leftCols(2 * n) = Jp;
        if (bg) Jk.rightCols(2) = Jb;
        const auto rs = res.segment(rows * s, rows);
        fb.add(s, Jk, Jc);
        gk.noalias() += Jk.transpose() * rs;
        gc.col(s).noalias() = Jc.transpose() * rs;
      }
    }
    return 0.5 * res.squaredNorm();
  };
  RunInfo info;
  double cost = evaluate(pos, cur, b, r, true);
  double lambda = 1e-4;
  std::vector<double> pos_try(pos.size());
  Eigen::MatrixXd cur_try(cur.rows(), cur.cols()), step_c(nc, S);
  std::vector<detail::Ldlt> Dd(static_cast<std::size_t>(S));
  for (info.iterations = 0; info.iterations < opt.max_iterations;) {
    if (std::max(gk.cwiseAbs().maxCoeff(), gc.cwiseAbs().maxCoeff()) <= opt.gradient_tolerance) {
      info.converged = true;
      info.message = "gradient tolerance reached";
      break;
    }
    // (M + λ diag M) step = −g by blocks: each snapshot's currents eliminated into the shared block
    Eigen::MatrixXd schur = fb.shared();
    schur.diagonal() += lambda * fb.shared().diagonal().cwiseMax(1e-300);
    Eigen::VectorXd rhs = -gk;
    for (Eigen::Index s = 0; s < S; ++s) {
      const auto u = static_cast<std::size_t>(s);
      const Eigen::MatrixXd& B = fb.shared_currents(s);
      Eigen::MatrixXd Ds = fb.currents(s);
      Ds.diagonal() += lambda * fb.currents(s).diagonal().cwiseMax(1e-300);
      Dd[u].compute(Ds);
      schur.noalias() -= B * Dd[u].solve_transposed(B);
      rhs.noalias() += B * Dd[u].solve(gc.col(s));
    }
    const Eigen::VectorXd step_k = detail::ldlt_solve(schur, rhs);
    for (Eigen::Index s = 0; s < S; ++s)
      step_c.col(s) =
          Dd[static_cast<std::size_t>(s)].solve(-gc.col(s) - fb.shared_currents(s).transpose() * step_k);
    if (!step_k.allFinite() || !step_c.allFinite()) {
      info.message = "the normal equations are singular";
      break;
    }
    for (int j = 0; j < 2 * n; ++j) pos_try[static_cast<std::size_t>(j)] = std::clamp(pos[static_cast<std::size_t>(j)] + step_k(j), -bore, bore);
    cur_try = cur + step_c;
    if (bg) b_try = b + step_k.tail<2>();
    const double cost_try = evaluate(pos_try, cur_try, b_try, r_try, false);
    ++info.iterations;
    if (cost_try < cost) {
      double x_norm = 0.0;
      for (double v : pos) x_norm += v * v;
      x_norm = std::sqrt(x_norm + cur.squaredNorm() + (bg ? b.squaredNorm() : 0.0));
      const double step_norm = std::sqrt(step_k.squaredNorm() + step_c.squaredNorm());
      const bool small_step = step_norm <= opt.parameter_tolerance * (x_norm + opt.parameter_tolerance);
      const bool small_change = (cost - cost_try) <= opt.function_tolerance * cost;
      pos = pos_try;
      cur = cur_try;
      b = b_try;
      cost = evaluate(pos, cur, b, r, true);
      lambda = std::max(lambda / 3.0, 1e-12);
      if (small_step || small_change) {
        info.converged = true;
        info.message = small_step ? "parameter tolerance reached" : "function tolerance reached";
        break;
      }
    } else {
      lambda *= 4.0;
      if (lambda > 1e12) {  // no descent left: at a minimum to working precision
        info.converged = true;
        info.message = "no further decrease";
        break;
      }
    }
  }
  if (info.message.empty()) info.message = "maximum iterations reached";
  if (bg) *bg = b;
  info.cost = cost;
  info.usable = std::isfinite(cost);
  return info;
}

void check_positions(const CableRing& ring, const ConductorPositionsRef& positions,
                     const char* name) {
  const double bore = ring.bore();
  for (Eigen::Index j = 0; j < positions.rows(); ++j) {
    if (!std::isfinite(positions(j, 0)) || !std::isfinite(positions(j, 1)))
      throw Error(std::string(name) + ": conductor " + std::to_string(j) + " has a non-finite position");
    const double r = positions.row(j).norm();
    if (r > bore)
      throw Error(std::string(name) + ": conductor " + std::to_string(j) + " at (" + num(positions(j, 0)) + ", " +
                  num(positions(j, 1)) + ") m is " + num(r) + " m from the centre, outside the bore (radius " +
                  num(bore) + " m); conductors must pass through the ring's hole");
  }
}

// The background's part of the linear fit at fixed positions. It is shared by the snapshots while each has
// its own currents, so with the currents' columns Q projected out (W = U − QQᵀU) it fits the snapshots'
// mean: b = (WᵀW)⁻¹Wᵀr̄, lowering the sum of squares by S·r̄ᵀW b. False when W does not determine it.
bool background_beside_currents(const Eigen::MatrixXd& Q, const Eigen::MatrixXd& U, const Eigen::MatrixXd& R,
                                     Eigen::Vector2d& b, double& reduction) {
  const Eigen::MatrixXd W = U - Q * (Q.transpose() * U);
  const Eigen::Matrix2d WtW = W.transpose() * W;
  if (!(std::abs(WtW.determinant()) > 1e-12 * std::max(WtW.squaredNorm(), 1e-300))) return false;
  const Eigen::Vector2d wm = W.transpose() * R.rowwise().mean();
  b = WtW.ldlt().solve(wm);
  reduction = static_cast<double>(R.cols()) * wm.dot(b);
  return true;
}

// Orthonormal basis of the currents' columns at fixed positions; false when the design is (near) rank-deficient
// (two seeds at one point).
bool currents_basis(const RingFrame& f, const double* pos, int n, bool zero_sum, Eigen::MatrixXd& Q) {
  Eigen::MatrixXd G;
  design(f, pos, n, G);
  const Eigen::MatrixXd Gr = reduce(G, zero_sum);
  detail::HouseholderThinQ qr = detail::householder_thin_q(Gr);
  Q = std::move(qr.q);
  const Eigen::VectorXd diag = qr.r_diagonal.cwiseAbs();
  return diag.minCoeff() >= 1e-9 * std::max(diag.maxCoeff(), 1e-300);
}

// Score of a set of positions: residual sum of squares after the best currents (all snapshots) and, when U
// (the background's design) is given, the best background.
double seed_cost(const RingFrame& f, const std::vector<double>& pos, int n, bool zero_sum,
                 const Eigen::MatrixXd& R, double total, const Eigen::MatrixXd* U) {
  Eigen::MatrixXd Q;
  if (!currents_basis(f, pos.data(), n, zero_sum, Q)) return kInf;  // a degenerate seed scores as useless
  double cost = total - (Q.transpose() * R).squaredNorm();
  Eigen::Vector2d b;
  double reduction = 0.0;
  if (U && !background_beside_currents(Q, *U, R, b, reduction)) return kInf;
  return cost - reduction;
}

Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor> field_kernel(const CableRing& ring,
                                                                       const ConductorPositionsRef& positions,
                                                                       const Eigen::Ref<const Eigen::VectorXd>& currents);
Eigen::MatrixXd jacobian_kernel(const CableRing& ring, const ConductorPositionsRef& positions,
                                const Eigen::Ref<const Eigen::VectorXd>& currents);

}  // namespace

void CableRing::validate() const {
  if (angles.size() < 1) throw Error("ring: no sensors (angles is empty)");
  for (Eigen::Index i = 0; i < angles.size(); ++i)
    if (!std::isfinite(angles(i))) throw Error("ring: angle " + std::to_string(i) + " is not finite");
  if (!(radius > 0.0) || !std::isfinite(radius)) throw Error("ring: radius must be a positive finite length (metres)");
  if (axis_angles.size() != 0 && axis_angles.size() != angles.size())
    throw Error("ring: " + std::to_string(axis_angles.size()) + " axis angles for " + std::to_string(angles.size()) +
                " sensors");
  for (Eigen::Index i = 0; i < axis_angles.size(); ++i)
    if (!std::isfinite(axis_angles(i))) throw Error("ring: axis angle " + std::to_string(i) + " is not finite");
  if (bore_radius < 0.0 || !std::isfinite(bore_radius) || bore() >= radius)
    throw Error("ring: bore radius " + num(std::isfinite(bore_radius) ? bore() : bore_radius) +
                " m must be finite, positive and smaller than the ring radius " + num(radius) + " m");
  for (Eigen::Index i = 0; i < angles.size(); ++i)
    for (Eigen::Index k = 0; k < i; ++k)
      if (std::abs(std::remainder(angles(i) - angles(k), 2.0 * M_PI)) < 1e-9)
        throw Error("ring: sensors " + std::to_string(k) + " and " + std::to_string(i) + " are at the same angle");
}

CableRing CableRing::rotated(double angle) const {
  CableRing r = *this;
  r.angles.array() += angle;
  return r;
}

Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor> cable_field(const CableRing& ring,
                                                                      const ConductorPositionsRef& positions,
                                                                      const SeriesRef& currents) {
  ring.validate();
  positions.require_width("positions");
  if (positions.rows() < 1) throw Error("positions: no conductors");
  if (currents.size() != positions.rows())
    throw Error("currents: " + std::to_string(currents.size()) + " values for " + std::to_string(positions.rows()) +
                " conductors");
  for (Eigen::Index j = 0; j < currents.size(); ++j)
    if (!std::isfinite(currents(j))) throw Error("currents: value " + std::to_string(j) + " is not finite");
  check_positions(ring, positions, "positions");
  return field_kernel(ring, positions, currents);
}

Eigen::MatrixXd cable_field_jacobian(const CableRing& ring, const ConductorPositionsRef& positions,
                                     const SeriesRef& currents) {
  cable_field(ring, positions, currents);  // the same checks
  return jacobian_kernel(ring, positions, currents);
}

namespace {

Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor> field_kernel(const CableRing& ring,
                                                                       const ConductorPositionsRef& positions,
                                                                       const Eigen::Ref<const Eigen::VectorXd>& currents) {
  const RingFrame f(ring);
  const double R = ring.radius, k = kMu0Over2Pi / R;
  Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor> out =
      Eigen::Matrix<double, Eigen::Dynamic, 2, Eigen::RowMajor>::Zero(f.m, 2);
  for (Eigen::Index j = 0; j < positions.rows(); ++j)
    for (Eigen::Index i = 0; i < f.m; ++i) {
      double r[2];
      unit_reading(f, i, positions(j, 0) / R, positions(j, 1) / R, r, nullptr, nullptr);
      out(i, 0) += k * currents(j) * r[0];
      out(i, 1) += k * currents(j) * r[1];
    }
  return out;
}

Eigen::MatrixXd jacobian_kernel(const CableRing& ring, const ConductorPositionsRef& positions,
                                const Eigen::Ref<const Eigen::VectorXd>& currents) {
  const RingFrame f(ring);
  const Eigen::Index n = positions.rows();
  const double R = ring.radius, k = kMu0Over2Pi / R;
  Eigen::MatrixXd J = Eigen::MatrixXd::Zero(2 * f.m, 3 * n);
  for (Eigen::Index j = 0; j < n; ++j)
    for (Eigen::Index i = 0; i < f.m; ++i) {
      double r[2], dx[2], dy[2];
      unit_reading(f, i, positions(j, 0) / R, positions(j, 1) / R, r, dx, dy);
      for (int a = 0; a < 2; ++a) {
        J(2 * i + a, 2 * j) = k * currents(j) * dx[a] / R;
        J(2 * i + a, 2 * j + 1) = k * currents(j) * dy[a] / R;
        J(2 * i + a, 2 * n + j) = k * r[a];
      }
    }
  return J;
}

}  // namespace

namespace detail {

void check(const CableSolveOptions& o) {
  const std::string s = "CableSolveOptions::";
  require_int(o.n_conductors >= 1, s + "n_conductors", o.n_conductors, "≥ 1");
  if (o.zero_sum_currents && o.n_conductors < 2)
    throw Error(s + "zero_sum_currents: needs at least 2 conductors (one conductor would carry 0 A)");
  require_int(o.grid_points >= 2, s + "grid_points", o.grid_points, "≥ 2");
  require_int(o.starts >= 1, s + "starts", o.starts, "≥ 1");
  require_int(o.max_iterations >= 1, s + "max_iterations", o.max_iterations, "≥ 1");
  for (const auto& [name, v] : {std::pair<const char*, double>{"function_tolerance", o.function_tolerance},
                                {"gradient_tolerance", o.gradient_tolerance},
                                {"parameter_tolerance", o.parameter_tolerance},
                                {"max_position_sigma", o.max_position_sigma},
                                {"max_current_relative_sigma", o.max_current_relative_sigma},
                                {"misfit_ratio", o.misfit_ratio}})
    require_positive(s + name, v);
  require(o.noise_sigma_dof >= 0.0, s + "noise_sigma_dof", o.noise_sigma_dof, "≥ 0 (0: σ's precision not known; +inf: exact)");
  require(o.misfit_alpha > 0.0 && o.misfit_alpha < 1.0, s + "misfit_alpha", o.misfit_alpha, "in (0, 1)");
  // NaN compares false: it fell through `noise_sigma > 0` to the residual estimate silently.
  require_finite(s + "noise_sigma", o.noise_sigma, "a finite value (≤ 0: estimate it from the residuals)");
  require_enum(s + "refiner", o.refiner, 3, "automatic, ceres, dense (0 … 2)");
  if (o.initial_currents.size() > 0 && !o.initial_currents.allFinite())
    throw Error(s + "initial_currents: contains NaN or Inf");
  if (o.relative_sigma.size() > 0 && !(o.relative_sigma.allFinite() && o.relative_sigma.minCoeff() > 0.0))
    throw Error(s + "relative_sigma: need a finite σ > 0 per sensor (relative to noise_sigma)");
}

}  // namespace detail

CableSolution solve_cable(const CableRing& ring, const Eigen::Ref<const Eigen::MatrixXd>& readings,
                          const CableSolveOptions& opt) {
  ring.validate();
  const int n = opt.n_conductors;
  const bool zs = opt.zero_sum_currents;
  detail::check(opt);
  const Eigen::Index m = ring.sensors(), S = readings.rows();
  if (readings.cols() != 2 * m)
    throw Error("readings: " + std::to_string(readings.cols()) + " columns, the ring has " + std::to_string(m) +
                " biaxial sensors: give 2 × " + std::to_string(m) + " = " + std::to_string(2 * m) +
                " columns (x_0, y_0, x_1, …) per snapshot");
  if (S < 1) throw Error("readings: no snapshots");
  if (opt.relative_sigma.size() > 0 && opt.relative_sigma.size() != m)
    throw Error("CableSolveOptions::relative_sigma: " + std::to_string(opt.relative_sigma.size()) +
                " values, the ring has " + std::to_string(m) + " sensors");
  for (Eigen::Index s = 0; s < S; ++s)
    for (Eigen::Index c = 0; c < readings.cols(); ++c)
      if (!std::isfinite(readings(s, c)))
        throw Error("readings: snapshot " + std::to_string(s) + ", sensor " + std::to_string(c / 2) + ", axis " +
                    (c % 2 ? "y" : "x") + " is " + (std::isnan(readings(s, c)) ? "NaN" : "infinite") +
                    "; remove or repair non-finite readings first");
  const int nc = zs ? n - 1 : n;
  const bool bg = opt.fit_background;
  const Eigen::Index nb = bg ? 2 : 0;
  const Eigen::Index unknowns = 2 * n + static_cast<Eigen::Index>(nc) * S + nb, equations = 2 * m * S;
  if (2 * m < nc + nb)  // each snapshot's readings must tell its currents from the background: more snapshots cannot
    throw Error("readings: each snapshot's " + std::to_string(2 * m) + " readings (" + std::to_string(m) +
                " biaxial sensors) must cover its " + std::to_string(nc) +
                " current(s) + 2 for the background field, which is told from the currents within a snapshot: add "
                "sensors, set zero_sum_currents (--zero-sum-currents) when the currents sum to zero, or leave out "
                "fit_background (--fit-background)");
  if (equations < unknowns)
    throw Error("readings: " + std::to_string(m) + " biaxial sensors × " + std::to_string(S) + " snapshot(s) give " +
                std::to_string(equations) + " readings for " + std::to_string(unknowns) + " unknowns (" +
                std::to_string(n) + (n == 1 ? " conductor: 2 coordinates" : " conductors: 2 coordinates each") + " + " +
                std::to_string(nc) + (nc == 1 ? " current" : " currents") + " per snapshot" +
                (bg ? "; + 2 for the background field" : "") +
                "); too few sensors for the unknowns — add sensors, give more snapshots "
                "sharing the positions (AC waveforms), or set zero_sum_currents (--zero-sum-currents) when they sum to "
                "zero");

  const double R = ring.radius, field_unit = kMu0Over2Pi / R, bore = ring.bore() / R;
  RingFrame f(ring);
  if (opt.relative_sigma.size() > 0) f.w = opt.relative_sigma.cwiseInverse();
  const Eigen::MatrixXd U = background_design(f);
  const Eigen::MatrixXd* Ub = bg ? &U : nullptr;
  // Normalised readings, one column per snapshot (2M × S).
  const Eigen::MatrixXd Rn = readings.transpose() / field_unit;
  const double total = Rn.squaredNorm();
  detail::require_finite_fit(std::isfinite(total), "readings", readings, "the cable solver");

  // ---- seeds -------------------------------------------------------------------------------------
  std::vector<std::vector<double>> seeds;
  if (opt.initial_positions.rows() > 0) {
    if (opt.initial_positions.rows() != n)
      throw Error("CableSolveOptions::initial_positions: " + std::to_string(opt.initial_positions.rows()) + " rows for " +
                  std::to_string(n) + " conductors");
    check_positions(ring, opt.initial_positions, "CableSolveOptions::initial_positions");
    std::vector<double> s(2 * n);
    for (int j = 0; j < n; ++j) {
      s[2 * j] = opt.initial_positions(j, 0) / R;
      s[2 * j + 1] = opt.initial_positions(j, 1) / R;
    }
    seeds.push_back(s);
  } else {
    std::vector<Eigen::Vector2d> grid;
    // With at most 1 reading to spare the fit can hardly show a misfit, and other exact (or near-exact) roots are the
    // danger, which only a start that reaches them reveals: search a finer grid from 4× the starts (a blind check's
    // 4-sensor ring with a background, 8 readings for 8 unknowns, gave 17–59 % wrong currents, flagged nowhere, in
    // 1–3 rigs of 40 from the default starts, and 6 sensors, 3 conductors with 1 to spare 2 of 40: 0 of 40 from
    // these; with 2 to spare, the paper's ring without a background, the default starts had none). Three or more
    // conductors with 2 to spare too: 6 sensors, 3 zero-sum conductors and a background ended wrong in 6 of 200 rigs
    // (one silently, 14 % off at a residual of 0.6 σ), right in all 6 from these starts.
    const bool few_spare = equations - unknowns <= (n > 2 ? 2 : 1);
    const int g = few_spare ? std::max(opt.grid_points, 15) : opt.grid_points;
    for (int a = 0; a < g; ++a)
      for (int b = 0; b < g; ++b) {
        const Eigen::Vector2d c(-bore + (a + 0.5) * 2.0 * bore / g, -bore + (b + 0.5) * 2.0 * bore / g);
        if (c.norm() < bore) grid.push_back(c);
      }
    const int P = static_cast<int>(grid.size());
    // three or more conductors: the greedy seeds are cheap and their basins small, so take more of them
    const int starts = (n > 2 ? std::max(opt.starts, 8 * n) : opt.starts) * (few_spare ? 4 : 1);
    std::vector<std::pair<double, std::vector<double>>> scored;
    auto score = [&](const std::vector<double>& pos, int k) { return seed_cost(f, pos, k, zs && k == n, Rn, total, Ub); };
    if (n <= 2) {
      for (int a = 0; a < P; ++a)
        for (int b = (n == 1 ? a : a + 1); b < (n == 1 ? a + 1 : P); ++b) {
          std::vector<double> pos = {grid[a](0), grid[a](1)};
          if (n == 2) pos.insert(pos.end(), {grid[b](0), grid[b](1)});
          scored.emplace_back(score(pos, n), pos);
        }
    } else {
      // greedy: the best first conductors, each completed by adding the grid point that helps most
      std::vector<std::pair<double, int>> first;
      for (int a = 0; a < P; ++a) first.emplace_back(score({grid[a](0), grid[a](1)}, 1), a);
      std::sort(first.begin(), first.end());
      for (int t = 0; t < std::min<int>(starts, P); ++t) {
        std::vector<double> pos = {grid[first[t].second](0), grid[first[t].second](1)};
        double c = kInf;
        for (int k = 2; k <= n; ++k) {
          double best = kInf;
          int best_b = -1;
          for (int b = 0; b < P; ++b) {
            std::vector<double> trial = pos;
            trial.insert(trial.end(), {grid[b](0), grid[b](1)});
            const double sc = score(trial, k);
            if (sc < best) best = sc, best_b = b;
          }
          if (best_b < 0) break;
          pos.insert(pos.end(), {grid[best_b](0), grid[best_b](1)});
          c = best;
        }
        if (static_cast<int>(pos.size()) == 2 * n) scored.emplace_back(c, pos);
      }
    }
    std::sort(scored.begin(), scored.end(),
              [](const auto& l, const auto& r) { return l.first < r.first; });
    // diverse seeds: skip one whose every coordinate is within a grid step of a chosen seed (neighbouring
    // grid cells fall into the same basin; the best few are often neighbours)
    const double step = 2.0 * bore / g * 1.01;
    for (const auto& sc : scored) {
      if (static_cast<int>(seeds.size()) >= starts || !std::isfinite(sc.first)) break;
      bool near = false;
      for (const auto& chosen : seeds) {
        double d = 0.0;
        for (std::size_t k = 0; k < chosen.size(); ++k) d = std::max(d, std::abs(chosen[k] - sc.second[k]));
        if (d <= step) near = true;
      }
      if (!near) seeds.push_back(sc.second);
    }
    if (seeds.empty()) throw Error("readings: no usable starting point on the grid (every seed is degenerate)");
  }

  // ---- refine every seed -------------------------------------------------------------------------
  ceres::Solver::Options so;
  so.linear_solver_type = S == 1 ? ceres::DENSE_QR : ceres::DENSE_SCHUR;
  so.max_num_iterations = opt.max_iterations;
  so.function_tolerance = opt.function_tolerance;
  so.gradient_tolerance = opt.gradient_tolerance;
  so.parameter_tolerance = opt.parameter_tolerance;
  so.logging_type = ceres::SILENT;
  so.num_threads = 1;
  if (opt.dogleg) so.trust_region_strategy_type = ceres::DOGLEG;

  double best_cost = kInf;
  std::vector<double> best_pos;
  Eigen::MatrixXd best_cur;  // nc × S
  Eigen::Vector2d best_bg = Eigen::Vector2d::Zero();
  RunInfo best_run;
  int tried = 0;
  std::vector<std::pair<double, std::vector<double>>> found;  // every usable end point: (cost, positions)
  const bool warm = opt.initial_positions.rows() > 0;
  const bool dense = opt.refiner == CableSolveOptions::Refiner::dense ||
                     (opt.refiner == CableSolveOptions::Refiner::automatic && warm);
  std::vector<std::unique_ptr<SnapshotCost>> costs;  // for the dense solver
  if (dense) {
    costs.reserve(static_cast<std::size_t>(S));
    for (Eigen::Index s = 0; s < S; ++s) costs.push_back(std::make_unique<SnapshotCost>(f, Rn.col(s).data(), n, zs, bg));
  }
  for (std::size_t t = 0; t < seeds.size(); ++t) {
    std::vector<double> pos = seeds[t];
    Eigen::MatrixXd cur(nc, S);
    Eigen::Vector2d b = Eigen::Vector2d::Zero();
    if (bg) {  // the seed's best background, then its currents with it taken off
      Eigen::MatrixXd Q;
      double reduction = 0.0;
      if (currents_basis(f, pos.data(), n, zs, Q)) background_beside_currents(Q, U, Rn, b, reduction);
    }
    if (t == 0 && opt.initial_positions.rows() > 0 && opt.initial_currents.size() > 0) {
      if (opt.initial_currents.rows() != S || opt.initial_currents.cols() != n)
        throw Error("CableSolveOptions::initial_currents: shape " + std::to_string(opt.initial_currents.rows()) + "×" +
                    std::to_string(opt.initial_currents.cols()) + ", expected " + std::to_string(S) + "×" +
                    std::to_string(n) + " (snapshots × conductors)");
      cur = opt.initial_currents.leftCols(nc).transpose();
    } else {
      Eigen::MatrixXd G;
      design(f, pos.data(), n, G);
      cur = detail::least_squares_qr_columns(reduce(G, zs), Rn.colwise() - U * b);
    }
    RunInfo run;
    if (dense) {
      run = dense_lm(costs, pos, cur, bg ? &b : nullptr, n, bore, opt);
    } else {
      ceres::Problem::Options po;
      po.cost_function_ownership = ceres::TAKE_OWNERSHIP;
      po.disable_all_safety_checks = true;  // the blocks are built right here
      ceres::Problem problem(po);
      for (Eigen::Index s = 0; s < S; ++s) {
        std::vector<double*> blocks = {pos.data(), cur.col(s).data()};
        if (bg) blocks.push_back(b.data());
        problem.AddResidualBlock(new SnapshotCost(f, Rn.col(s).data(), n, zs, bg), nullptr, blocks);
      }
      for (int k = 0; k < 2 * n; ++k) {
        problem.SetParameterLowerBound(pos.data(), k, -bore);
        problem.SetParameterUpperBound(pos.data(), k, bore);
      }
      ceres::Solver::Summary summary;
      ceres::Solve(so, &problem, &summary);
      run.cost = summary.final_cost;
      run.iterations = static_cast<int>(summary.iterations.size()) - 1;
      run.converged = summary.termination_type == ceres::CONVERGENCE;
      run.usable = summary.IsSolutionUsable();
      run.message = summary.message;
    }
    ++tried;
    if (run.usable) found.emplace_back(run.cost, pos);
    if (run.usable && run.cost < best_cost) {
      best_cost = run.cost;
      best_pos = pos;
      best_cur = cur;
      best_bg = b;
      best_run = run;
    }
  }
  if (best_pos.empty()) throw Error("solve_cable: the solver failed from every starting point");

  // ---- canonical order (x, then y) and physical units ------------------------------------------------
  std::vector<int> order(n);
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(), [&](int a, int b) {
    return best_pos[2 * a] != best_pos[2 * b] ? best_pos[2 * a] < best_pos[2 * b] : best_pos[2 * a + 1] < best_pos[2 * b + 1];
  });
  Eigen::MatrixXd full_cur(S, n);  // every current, including a derived last one
  for (Eigen::Index s = 0; s < S; ++s) {
    double last = 0.0;
    for (int j = 0; j < nc; ++j) full_cur(s, j) = best_cur(j, s), last -= best_cur(j, s);
    if (zs) full_cur(s, n - 1) = last;
  }
  CableSolution out;
  out.positions.resize(n, 2);
  out.currents.resize(S, n);
  for (int j = 0; j < n; ++j) {
    out.positions(j, 0) = best_pos[2 * order[j]] * R;
    out.positions(j, 1) = best_pos[2 * order[j] + 1] * R;
    out.currents.col(j) = full_cur.col(order[j]);
  }
  out.starts_tried = tried;
  if (bg) out.background = best_bg * field_unit;

  // ---- residuals, Fisher information (physical units, by blocks), covariance -------------------------
  // Parameters: full [x_0, y_0, …, I(snapshot 0, conductors 0…N−1), …, b_x, b_y] (pf); reduced, with ΣI = 0 the
  // derived current left out (pr). A snapshot's currents: full = Tc · reduced; after sorting, the derived conductor
  // is order⁻¹(n − 1), its current −Σ of the others.
  const Eigen::Index pf = 2 * n + n * S + nb, pr = 2 * n + nc * S + nb, k = 2 * n + nb;
  Eigen::MatrixXd Tc = Eigen::MatrixXd::Zero(n, nc);
  {
    int derived = -1, col = 0;
    if (zs)
      for (int j = 0; j < n; ++j)
        if (order[j] == n - 1) derived = j;
    for (int j = 0; j < n; ++j) {
      if (j == derived) continue;
      Tc(j, col) = 1.0;
      if (zs) Tc(derived, col) = -1.0;
      ++col;
    }
  }
  // The Fisher information JᵀJ has the problem's arrow shape: the shared block A (positions, background), and for
  // each snapshot B_s (shared × its currents) and D_s (its currents), which no other snapshot's readings touch.
  FisherBlocks fb(k, nc, S);
  const Eigen::VectorXd background_readings = U * out.background;  // zero without a background
  out.residuals.resize(S, 2 * m);
  Eigen::MatrixXd Jk(2 * m, k);
  // each sensor's rows weighted by 1 / its relative σ (the noise σ is noise_sigma × relative_sigma)
  Eigen::VectorXd row_w(2 * m);
  for (Eigen::Index i = 0; i < m; ++i) row_w(2 * i) = row_w(2 * i + 1) = f.w(i);
  for (Eigen::Index s = 0; s < S; ++s) {
    const Eigen::MatrixXd Js = row_w.asDiagonal() * jacobian_kernel(ring, out.positions, out.currents.row(s).transpose());
    const auto model = field_kernel(ring, out.positions, out.currents.row(s).transpose());
    for (Eigen::Index i = 0; i < m; ++i)
      for (int a = 0; a < 2; ++a) out.residuals(s, 2 * i + a) = readings(s, 2 * i + a) - model(i, a) - background_readings(2 * i + a);
    Jk.leftCols(2 * n) = Js.leftCols(2 * n);
    if (bg) Jk.rightCols(2) = row_w.asDiagonal() * U;
    fb.add(s, Jk, Js.rightCols(n) * Tc);
  }
  const double ssr = (out.residuals * row_w.asDiagonal()).squaredNorm();  // weighted: in units of noise_sigma²
  const Eigen::Index dof = equations - pr;
  if (opt.noise_sigma > 0.0) {
    out.noise_sigma = opt.noise_sigma;
  } else if (dof > 0) {
    out.noise_sigma = std::sqrt(ssr / static_cast<double>(dof));
  } else {
    out.summary.warnings.push_back("as many readings as unknowns: the noise cannot be estimated from the residuals; "
                                   "set noise_sigma for a covariance");
  }
  if (dof == 0)
    out.summary.warnings.push_back("as many readings as unknowns: the fit is exact and cannot show a misfit (add "
                                   "sensors, or solve snapshots that share the positions together)");
  const FisherInverse inv = fb.invert();  // of the column-scaled information, and its condition number
  out.fisher_condition = inv.condition;
  const bool singular = !(out.fisher_condition < kSingularFisher);
  // no σ given and none to estimate (an exact fit): the standard errors are unknown, not 0
  const bool unknown_sigma = opt.noise_sigma <= 0.0 && dof <= 0;
  out.covariance = Eigen::MatrixXd::Zero(pf, pf);
  if (singular || unknown_sigma) {
    out.covariance.diagonal().setConstant(kInf);
  } else {
    // full index of shared parameter j (positions, then the background last) and of snapshot s's current block
    auto shared = [&](Eigen::Index j) { return j < 2 * n ? j : pf - (k - j); };
    const double v = out.noise_sigma * out.noise_sigma;
    const Eigen::MatrixXd Ckk = v * inv.shared();
    for (Eigen::Index a = 0; a < k; ++a)
      for (Eigen::Index b = 0; b < k; ++b) out.covariance(shared(a), shared(b)) = Ckk(a, b);
    for (Eigen::Index s = 0; s < S; ++s) {
      const Eigen::MatrixXd Cks = v * inv.shared_currents(s) * Tc.transpose();  // k × n
      for (Eigen::Index a = 0; a < k; ++a) {
        out.covariance.block(shared(a), 2 * n + n * s, 1, n) = Cks.row(a);
        out.covariance.block(2 * n + n * s, shared(a), n, 1) = Cks.row(a).transpose();
      }
      for (Eigen::Index t = s; t < S; ++t) {
        const Eigen::MatrixXd Cst = v * Tc * inv.currents(s, t) * Tc.transpose();
        out.covariance.block(2 * n + n * s, 2 * n + n * t, n, n) = Cst;
        out.covariance.block(2 * n + n * t, 2 * n + n * s, n, n) = Cst.transpose();
      }
    }
  }
  out.standard_errors = out.covariance.diagonal().cwiseMax(0.0).cwiseSqrt();

  bool ok = !singular && !unknown_sigma;
  std::string why;
  if (singular) why = "the Fisher matrix is singular (condition " + num(out.fisher_condition) + ")";
  else if (unknown_sigma) why = "no noise σ: the standard errors are unknown";
  for (Eigen::Index k = 0; k < 2 * n && ok; ++k)
    if (!(out.standard_errors(k) <= opt.max_position_sigma)) {
      ok = false;
      why = "position standard error " + num(out.standard_errors(k)) + " m of conductor " + std::to_string(k / 2) +
            " exceeds " + num(opt.max_position_sigma) + " m at noise σ = " + num(out.noise_sigma) + " T";
    }
  // a current's error against the largest current of the snapshots solved together: an idle snapshot (the one that
  // pins a background best) or an AC waveform's zero crossing is small, not undetermined
  const double scale = out.currents.cwiseAbs().maxCoeff();
  for (Eigen::Index s = 0; s < S && ok; ++s) {
    if (!(scale > 0.0)) continue;
    for (int j = 0; j < n && ok; ++j) {
      const double se = out.standard_errors(2 * n + n * s + j);
      if (!(se <= opt.max_current_relative_sigma * scale)) {
        ok = false;
        why = "current standard error " + num(se) + " A of conductor " + std::to_string(j) + " exceeds " +
              num(100 * opt.max_current_relative_sigma) + " % of " + num(scale) + " A";
      }
    }
  }
  for (int j = 0; j < n; ++j) {
    // The solver bounds each coordinate to ±bore (Ceres takes boxes), so a conductor may end on the box's edge or
    // between the bore's circle and its corners: said with its own distance (a blind check's 4.157 mm, found right,
    // was said to be "on the bore's edge (4 mm)", and a (4, 4) mm conductor, 5.66 mm out, was left unsaid as such).
    const double reach = out.positions.row(j).norm();
    const bool on_box = out.positions.row(j).cwiseAbs().maxCoeff() >= ring.bore() * (1.0 - 1e-9);
    if (reach > ring.bore() * (1.0 - 1e-9) || on_box) {
      // the bore is the solver's bound, which the user may not know was set (0.4 × the ring's radius by default)
      const bool beyond = reach > ring.bore() * (1.0 + 1e-9);
      out.summary.warnings.push_back("conductor " + std::to_string(j) + " ended " + num(1e3 * reach) +
                                     " mm from the ring's centre, " + (beyond ? "beyond" : "on the edge of") +
                                     " the bore (radius " + num(1e3 * ring.bore()) + " mm, the solver's bound: x and "
                                     "y each within ±" + num(1e3 * ring.bore()) + " mm): the readings fit no "
                                     "conductor inside the bore — a cable off-centre beyond it? give the bore's radius "
                                     "(ring_bore_radius_m in the ring file, Ring(bore_radius_m=…))");
      if (ok) why = std::string("a conductor ended ") + (beyond ? "beyond" : "on") + " the bore's edge";
      ok = false;
    }
  }
  // Another start that ended elsewhere and fits as well (within 3 σ of the best in the sum of squares): the
  // readings do not decide — a nonlinear system with as many readings as unknowns, or a symmetric ring, has
  // several exact solutions, and the local covariance cannot see the others.
  const double sigma_n = (opt.noise_sigma > 0.0 ? opt.noise_sigma : out.noise_sigma) / field_unit;
  const double tol_ssr = 9.0 * sigma_n * sigma_n + 1e-12 * total;
  double se_pos = 0.0;
  for (Eigen::Index k = 0; k < 2 * n; ++k) se_pos = std::max(se_pos, out.standard_errors(k) / R);
  const double apart = std::max(5.0 * (std::isfinite(se_pos) ? se_pos : 0.0), 0.01);  // ring radii
  for (const auto& [cost, pos] : found) {
    if (!(2.0 * (cost - best_cost) <= tol_ssr)) continue;
    double d = 0.0;  // the farthest conductor from its nearest counterpart (conductors are unlabelled)
    for (int j = 0; j < n; ++j) {
      double nearest = kInf;
      for (int k = 0; k < n; ++k)
        nearest = std::min(nearest, std::hypot(pos[2 * j] - best_pos[2 * k], pos[2 * j + 1] - best_pos[2 * k + 1]));
      d = std::max(d, nearest);
    }
    if (d > apart) {
      std::ostringstream alt;
      alt.precision(3);
      for (int j = 0; j < n; ++j)
        alt << (j ? ", " : "") << "(" << pos[2 * j] * R * 1e3 << ", " << pos[2 * j + 1] * R * 1e3 << ")";
      out.summary.warnings.push_back("ambiguous: another solution fits the readings as well, conductors at " +
                                     alt.str() + " mm; add sensors, or snapshots with other currents, to decide");
      if (ok) why = "another solution fits as well";
      ok = false;
      break;
    }
  }
  out.well_conditioned = ok;
  if (opt.noise_sigma > 0.0 && dof > 0) {
    const double per_dof = std::sqrt(ssr / static_cast<double>(dof));
    std::string judged = " T";
    if (opt.noise_sigma_dof > 0.0) {
      out.misfit_p = f_sf(per_dof * per_dof / (opt.noise_sigma * opt.noise_sigma), static_cast<double>(dof),
                          opt.noise_sigma_dof);
      judged += " (p " + num(out.misfit_p) + ", σ " +
                (std::isinf(opt.noise_sigma_dof) ? std::string("taken as exact")
                                                 : "from " + std::to_string(std::lround(opt.noise_sigma_dof)) + " dof") +
                ")";
    }
    if (per_dof > opt.misfit_ratio * opt.noise_sigma || out.misfit_p < opt.misfit_alpha) {
      out.fits_model = false;
      out.summary.warnings.push_back("the readings do not fit the model: residual " + num(per_dof) + " T per degree of "
                                     "freedom vs noise σ = " + num(opt.noise_sigma) + judged +
                                     " (" + (bg ? "a background that is not uniform: a conductor near the ring, whose gradient "
                                                  "`diagnose --model cable` names and zero-current snapshots taken "
                                                  "off (--subtract-zero) remove; "
                                               : "a field that does not follow the currents: fit_background / "
                                                 "--fit-background; ") +
                                     "sensors' offsets or gains, a wrong number of conductors?)");
    }
  }
  if (!ok) out.summary.warnings.push_back("ill-conditioned: " + why + "; do not trust these positions and currents");

  Summary& sum = out.summary;
  sum.samples = static_cast<std::size_t>(equations);
  sum.iterations = best_run.iterations;
  sum.cost = out.residuals.squaredNorm() / static_cast<double>(equations);
  sum.residual_rms = std::sqrt(sum.cost);
  sum.condition_number = out.fisher_condition;
  sum.converged = best_run.converged;
  detail::require_finite_fit(detail::finite_fit(sum) && out.positions.allFinite() && out.currents.allFinite(),
                             "readings", readings, "the cable solver");
  if (!sum.converged) sum.warnings.push_back("the best start stopped before converging: " + best_run.message);
  std::ostringstream msg;
  msg << n << " conductor(s) from " << m << " sensors × " << S << " snapshot(s); residual RMS "
      << num(sum.residual_rms) << " T; " << (ok ? "well conditioned" : "ILL-CONDITIONED") << (out.fits_model ? "" : ", MISFIT") << "; " << tried
      << " start(s)";
  if (bg) msg << "; background " << num(out.background.norm()) << " T";
  sum.message = msg.str();
  return out;
}

}  // namespace fluxcal
