#include "fluxcal/ellipsoid.hpp"

#include "fluxcal/coverage.hpp"
#include "checks.hpp"
#include "clones.hpp"
#include "linalg.hpp"
#include "quadric.hpp"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <limits>
#include <utility>
#include <sstream>
#include <string>
#include <vector>

namespace fluxcal {
namespace {

// ---- moment bookkeeping --------------------------------------------------------------------------
// Moments are stored in the order: 1; u v w; then for degree 2, 3, 4 the exponents (i, j, k) with
// i descending, then j descending (uu uv uw vv vw ww, uuu uuv ...). The hot kernel below writes them
// in exactly this order.
struct MomentIndex {
  int index[5][5][5];
  MomentIndex() {
    int n = 0;
    for (int d = 0; d <= 4; ++d)
      for (int i = d; i >= 0; --i)
        for (int j = d - i; j >= 0; --j) index[i][j][d - i - j] = n++;
  }
};
const MomentIndex kIndex;

// Exponents of the design row d = [u², v², w², 2uv, 2uw, 2vw, 2u, 2v, 2w, 1] and its factors.
constexpr int kDesignExp[10][3] = {{2, 0, 0}, {0, 2, 0}, {0, 0, 2}, {1, 1, 0}, {1, 0, 1},
                                   {0, 1, 1}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {0, 0, 0}};
constexpr double kDesignFactor[10] = {1, 1, 1, 2, 2, 2, 2, 2, 2, 1};

// The 34 non-constant monomials of (x, y, z) in the storage order, written to out[0..33].
#define FLUXCAL_MONOMIALS(x, y, z, OUT)                                                      \
  do {                                                                                       \
    const double xx = x * x, xy = x * y, xz = x * z, yy = y * y, yz = y * z, zz = z * z;     \
    OUT(0, x); OUT(1, y); OUT(2, z);                                                         \
    OUT(3, xx); OUT(4, xy); OUT(5, xz); OUT(6, yy); OUT(7, yz); OUT(8, zz);                  \
    OUT(9, xx * x); OUT(10, xx * y); OUT(11, xx * z); OUT(12, xy * y); OUT(13, xy * z);      \
    OUT(14, xz * z); OUT(15, yy * y); OUT(16, yy * z); OUT(17, yz * z); OUT(18, zz * z);     \
    OUT(19, xx * xx); OUT(20, xx * xy); OUT(21, xx * xz); OUT(22, xx * yy);                  \
    OUT(23, xx * yz); OUT(24, xx * zz); OUT(25, xy * yy); OUT(26, xy * yz);                  \
    OUT(27, xy * zz); OUT(28, xz * zz); OUT(29, yy * yy); OUT(30, yy * yz);                  \
    OUT(31, yy * zz); OUT(32, yz * zz); OUT(33, zz * zz);                                    \
  } while (0)

// Accumulation kernel: a block of kLanes readings is normalised into small arrays, then every lane
// keeps its own partial sums so the compiler can vectorise across readings without reassociating
// (with an x86-64-v3 clone, clones.hpp).
using detail::kLanes;

// kLanes packed readings from p normalised into xs, ys, zs (inlined into each kernel's clones).
FLUXCAL_ALWAYS_INLINE void normalise_lanes(const double* p, const double* centre, double inv_scale, double* xs,
                                           double* ys, double* zs) {
  for (int l = 0; l < kLanes; ++l) {
    xs[l] = (p[3 * l] - centre[0]) * inv_scale;
    ys[l] = (p[3 * l + 1] - centre[1]) * inv_scale;
    zs[l] = (p[3 * l + 2] - centre[2]) * inv_scale;
  }
}

FLUXCAL_CLONES
void accumulate_moments(const double* p, std::size_t n, const double* centre, double inv_scale,
                        double* sums /* 34 */) {
  alignas(64) double acc[34][kLanes] = {};
  std::size_t i = 0;
  for (; i + kLanes <= n; i += kLanes) {
    double xs[kLanes], ys[kLanes], zs[kLanes];
    normalise_lanes(p + 3 * i, centre, inv_scale, xs, ys, zs);
    for (int l = 0; l < kLanes; ++l) {
      const double x = xs[l], y = ys[l], z = zs[l];
#define FLUXCAL_ACC(m, value) acc[m][l] += (value)
      FLUXCAL_MONOMIALS(x, y, z, FLUXCAL_ACC);
#undef FLUXCAL_ACC
    }
  }
  for (int m = 0; m < 34; ++m)
    for (int l = 0; l < kLanes; ++l) sums[m] += acc[m][l];
  for (; i < n; ++i) {
    const double x = (p[3 * i] - centre[0]) * inv_scale;
    const double y = (p[3 * i + 1] - centre[1]) * inv_scale;
    const double z = (p[3 * i + 2] - centre[2]) * inv_scale;
#define FLUXCAL_ADD(m, value) sums[m] += (value)
    FLUXCAL_MONOMIALS(x, y, z, FLUXCAL_ADD);
#undef FLUXCAL_ADD
  }
}

// The same with a weight per reading: Σ w_k·monomial_k into sums[0] (Σ w) and sums[1..34]; `full` false stops at
// degree 2 (sums[1..9]), all a design row's weighted sum needs.
FLUXCAL_CLONES
void accumulate_weighted_moments(const double* p, const double* weights, std::size_t n, const double* centre,
                                 double inv_scale, bool full, double* sums /* 35 */) {
  alignas(64) double acc[35][kLanes] = {};
  const int count = full ? 35 : 10;
  std::size_t i = 0;
  for (; i + kLanes <= n; i += kLanes) {
    double xs[kLanes], ys[kLanes], zs[kLanes];
    normalise_lanes(p + 3 * i, centre, inv_scale, xs, ys, zs);
    if (full) {
      for (int l = 0; l < kLanes; ++l) {
        const double x = xs[l], y = ys[l], z = zs[l], w = weights[i + l];
        acc[0][l] += w;
#define FLUXCAL_ACC(m, value) acc[(m) + 1][l] += w * (value)
        FLUXCAL_MONOMIALS(x, y, z, FLUXCAL_ACC);
#undef FLUXCAL_ACC
      }
    } else {
      for (int l = 0; l < kLanes; ++l) {
        const double x = xs[l], y = ys[l], z = zs[l], w = weights[i + l];
        const double wx = w * x, wy = w * y, wz = w * z;
        acc[0][l] += w;
        acc[1][l] += wx;
        acc[2][l] += wy;
        acc[3][l] += wz;
        acc[4][l] += wx * x;
        acc[5][l] += wx * y;
        acc[6][l] += wx * z;
        acc[7][l] += wy * y;
        acc[8][l] += wy * z;
        acc[9][l] += wz * z;
      }
    }
  }
  for (int m = 0; m < count; ++m)
    for (int l = 0; l < kLanes; ++l) sums[m] += acc[m][l];
  for (; i < n; ++i) {  // the last few readings one by one, every monomial (the sums past `count` are not read)
    const double x = (p[3 * i] - centre[0]) * inv_scale;
    const double y = (p[3 * i + 1] - centre[1]) * inv_scale;
    const double z = (p[3 * i + 2] - centre[2]) * inv_scale;
    const double w = weights[i];
    sums[0] += w;
#define FLUXCAL_ADD(m, value) sums[(m) + 1] += w * (value)
    FLUXCAL_MONOMIALS(x, y, z, FLUXCAL_ADD);
#undef FLUXCAL_ADD
  }
}

// Statistics pass: Σ(|h| − H), Σ(|h| − H)² over h = A (m − b), lane-blocked like the moments.
FLUXCAL_CLONES
void accumulate_residuals(const double* p, std::size_t n, const double* A /* 3×3 row-major */,
                          const double* b, double H, double* sums /* 2 */) {
  double sd[kLanes] = {}, sd2[kLanes] = {};
  double hx[kLanes], hy[kLanes], hz[kLanes];
  auto correct = [&](const double* m, int l) {
    const double x = m[0] - b[0], y = m[1] - b[1], z = m[2] - b[2];
    hx[l] = A[0] * x + A[1] * y + A[2] * z;
    hy[l] = A[3] * x + A[4] * y + A[5] * z;
    hz[l] = A[6] * x + A[7] * y + A[8] * z;
  };
  std::size_t i = 0;
  for (; i + kLanes <= n; i += kLanes) {
    for (int l = 0; l < kLanes; ++l) correct(p + 3 * (i + l), l);
    for (int l = 0; l < kLanes; ++l) {
      const double d = std::sqrt(hx[l] * hx[l] + hy[l] * hy[l] + hz[l] * hz[l]) - H;
      sd[l] += d;
      sd2[l] += d * d;
    }
  }
  for (; i < n; ++i) {
    correct(p + 3 * i, 0);
    const double d = std::sqrt(hx[0] * hx[0] + hy[0] * hy[0] + hz[0] * hz[0]) - H;
    sd[0] += d;
    sd2[0] += d * d;
  }
  for (int l = 0; l < kLanes; ++l) {
    sums[0] += sd[l];
    sums[1] += sd2[l];
  }
}

// Calls f(rows, count) on the readings as packed N×3 doubles: the data itself when the rows are
// packed (a C-contiguous NumPy array), else copies of 512-row blocks.
template <class F>
void for_each_packed_block(const SamplesRef& readings, F&& f) {
  if (readings.rows() == 0) return;
  if (readings.outerStride() == 3) {
    f(readings.data(), static_cast<std::size_t>(readings.rows()));
    return;
  }
  constexpr Eigen::Index kBlock = 512;
  double packed[3 * kBlock];
  for (Eigen::Index start = 0; start < readings.rows(); start += kBlock) {
    const Eigen::Index len = std::min(kBlock, readings.rows() - start);
    for (Eigen::Index i = 0; i < len; ++i)
      for (int j = 0; j < 3; ++j) packed[3 * i + j] = readings(start + i, j);
    f(packed, static_cast<std::size_t>(len));
  }
}

using detail::percent;

// Σ d dᵀ of the design rows from the 35 moment sums (EllipsoidMoments' order); with `noise_variance` > 0 every
// moment replaced by its unbiased estimate for noise-free readings.
Eigen::Matrix<double, 10, 10> scatter_of_moments(const double* sums, double noise_variance) {
  // E[t_n(x + e)] = xⁿ for e ~ N(0, v) with t_0..t_4 = 1, x, x² − v, x³ − 3vx, x⁴ − 6vx² + 3v²
  // (Hermite); axes are independent, so Π t gives the unbiased moment of a monomial. herm[n][a] is
  // the coefficient of xᵃ in t_n.
  const double v = noise_variance;
  const double herm[5][5] = {{1, 0, 0, 0, 0},
                             {0, 1, 0, 0, 0},
                             {-v, 0, 1, 0, 0},
                             {0, -3 * v, 0, 1, 0},
                             {3 * v * v, 0, -6 * v, 0, 1}};
  auto moment = [&](int i, int j, int k) {
    if (v == 0.0) return sums[kIndex.index[i][j][k]];
    double total = 0.0;
    for (int a = 0; a <= i; ++a)
      for (int b = 0; b <= j; ++b)
        for (int c = 0; c <= k; ++c) {
          const double coef = herm[i][a] * herm[j][b] * herm[k][c];
          if (coef != 0.0) total += coef * sums[kIndex.index[a][b][c]];
        }
    return total;
  };
  Eigen::Matrix<double, 10, 10> s;
  for (int a = 0; a < 10; ++a)
    for (int b = 0; b <= a; ++b) {
      s(a, b) = s(b, a) = kDesignFactor[a] * kDesignFactor[b] *
                          moment(kDesignExp[a][0] + kDesignExp[b][0], kDesignExp[a][1] + kDesignExp[b][1],
                                 kDesignExp[a][2] + kDesignExp[b][2]);
    }
  return s;
}

}  // namespace

// ---- EllipsoidMoments ----------------------------------------------------------------------------

EllipsoidMoments::EllipsoidMoments(const Eigen::Vector3d& centre, double scale)
    : centre_(centre), scale_(scale), inv_scale_(1.0 / scale) {
  if (!(scale > 0.0) || !std::isfinite(scale) || !centre.allFinite())
    throw Error("ellipsoid moments: normalisation needs a finite centre and a positive scale");
}

void EllipsoidMoments::add(const Eigen::Vector3d& reading) {
  sums_[0] += 1.0;
  accumulate_moments(reading.data(), 1, centre_.data(), inv_scale_, sums_.data() + 1);
}

void EllipsoidMoments::add_rows(const SamplesRef& readings) {
  readings.require_width("readings");
  sums_[0] += static_cast<double>(readings.rows());
  for_each_packed_block(readings, [&](const double* rows, std::size_t len) {
    accumulate_moments(rows, len, centre_.data(), inv_scale_, sums_.data() + 1);
  });
}

void EllipsoidMoments::merge(const EllipsoidMoments& other) {
  if (other.centre_ != centre_ || other.scale_ != scale_)
    throw Error("ellipsoid moments: cannot merge sums taken with a different normalisation");
  for (int m = 0; m < kMoments; ++m) sums_[m] += other.sums_[m];
}

bool EllipsoidMoments::finite() const {
  return std::all_of(sums_.begin(), sums_.end(), [](double s) { return std::isfinite(s); });
}

Eigen::Matrix<double, 10, 10> EllipsoidMoments::scatter(double noise_variance) const {
  return scatter_of_moments(sums_.data(), noise_variance);
}

namespace detail {

namespace {
// Σ w_k·monomial_k of the readings normalised by (centre, scale): a lane-blocked pass (degree ≤ 2 unless `full`).
std::array<double, EllipsoidMoments::kMoments> weighted_moments(const SamplesRef& samples, const SeriesRef& weights,
                                                                const Eigen::Vector3d& centre, double scale, bool full) {
  std::array<double, EllipsoidMoments::kMoments> sums{};
  std::size_t done = 0;
  for_each_packed_block(samples, [&](const double* rows, std::size_t len) {
    accumulate_weighted_moments(rows, weights.data() + done, len, centre.data(), 1.0 / scale, full, sums.data());
    done += len;
  });
  return sums;
}
}  // namespace

Eigen::Matrix<double, 10, 10> weighted_scatter(const SamplesRef& samples, const SeriesRef& weights,
                                               const Eigen::Vector3d& centre, double scale) {
  return scatter_of_moments(weighted_moments(samples, weights, centre, scale, true).data(), 0.0);
}

Eigen::Matrix<double, 10, 1> weighted_design_sum(const SamplesRef& samples, const SeriesRef& weights,
                                                 const Eigen::Vector3d& centre, double scale) {
  const auto sums = weighted_moments(samples, weights, centre, scale, false);
  Eigen::Matrix<double, 10, 1> out;
  for (int a = 0; a < 10; ++a)
    out(a) = kDesignFactor[a] * sums[kIndex.index[kDesignExp[a][0]][kDesignExp[a][1]][kDesignExp[a][2]]];
  return out;
}

std::string dominated_spread(const SamplesRef& samples, double ratio, double thin, const std::string& failed) {
  const Eigen::Index n = samples.rows();
  if (n < kFewReadings) return "";
  std::vector<double> values(static_cast<std::size_t>(n));
  const auto median_of = [&values]() {
    const auto mid = values.begin() + static_cast<std::ptrdiff_t>(values.size() / 2);
    std::nth_element(values.begin(), mid, values.end());
    return *mid;
  };
  Eigen::Vector3d median;
  for (int a = 0; a < 3; ++a) {
    for (Eigen::Index i = 0; i < n; ++i) values[static_cast<std::size_t>(i)] = samples(i, a);
    median(a) = median_of();
  }
  std::vector<double> distance(static_cast<std::size_t>(n));
  for (Eigen::Index i = 0; i < n; ++i)
    distance[static_cast<std::size_t>(i)] = (samples.row(i).transpose() - median).norm();
  values = distance;
  const double typical = median_of();
  if (!(typical > 0.0) || !std::isfinite(typical)) return "";
  // the far readings, and the spread of the others (about the median: no digits lost to a large offset)
  std::vector<Eigen::Index> far;
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  Eigen::Matrix3d second = Eigen::Matrix3d::Zero();
  for (Eigen::Index i = 0; i < n; ++i) {
    if (distance[static_cast<std::size_t>(i)] > kDominating * typical) {
      far.push_back(i);
      continue;
    }
    const Eigen::Vector3d d = samples.row(i).transpose() - median;
    sum += d;
    second += d * d.transpose();
  }
  const auto few = std::max<std::size_t>(1, static_cast<std::size_t>(kDominatingShare * static_cast<double>(n)));
  if (far.empty() || far.size() > few) return "";
  const double kept = static_cast<double>(n - static_cast<Eigen::Index>(far.size()));
  const Eigen::Vector3d mean = sum / kept;
  const Eigen::Vector3d ev = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(
                                 second / kept - mean * mean.transpose(), Eigen::EigenvaluesOnly)
                                 .eigenvalues();
  const double widest = std::sqrt(std::max(ev(2), 0.0));
  const double without = ev(2) > 0.0 ? std::sqrt(std::max(ev(0), 0.0) / ev(2)) : 0.0;
  if (!(widest >= 0.01 * (median + mean).norm()) || without < thin) return "";  // flat or unturned without them too

  const Eigen::Index farthest = far[static_cast<std::size_t>(std::distance(
      far.begin(), std::max_element(far.begin(), far.end(), [&](Eigen::Index a, Eigen::Index b) {
        return distance[static_cast<std::size_t>(a)] < distance[static_cast<std::size_t>(b)];
      })))];
  char times[32];
  const double factor = distance[static_cast<std::size_t>(farthest)] / typical;
  if (factor < 100.0)
    std::snprintf(times, sizeof times, "%.3g", factor);
  else
    std::snprintf(times, sizeof times, "%.0f", factor);
  const bool one = far.size() == 1;
  std::string rows;
  for (std::size_t k = 0; k < far.size() && k < 5; ++k) rows += (k ? ", " : "") + std::to_string(far[k]);
  if (far.size() > 5) rows += ", …";
  return "samples: row " + std::to_string(farthest) + " lies " + times +
         "× farther from the readings' median than the median reading" +
         (one ? ": an outlier dominates their spread"
              : " (" + std::to_string(far.size()) + " readings lie beyond " + num(kDominating) + "×: rows " + rows +
                    "): outliers dominate their spread") +
         " (thinnest/widest " + percent(ratio) + " with " + (one ? "it" : "them") + ", " + percent(without) +
         " without)" + (ratio < thin ? ", not a flat turn," : "") + " and " + failed + "; remove " +
         (one ? "it" : "them") +
         ", or let calibrate leave outliers out (its default, outliers='drop'; not --outliers keep) or weigh them down "
         "(loss='cauchy')";
}

}  // namespace detail

std::pair<Eigen::Vector3d, double> normalisation(const SamplesRef& samples, Eigen::Index max_rows) {
  samples.require_width("samples");
  const Eigen::Index n = samples.rows();
  if (n == 0) throw Error("samples: no rows");
  const Eigen::Index step = max_rows > 0 ? std::max<Eigen::Index>(1, n / max_rows) : 1;  // 0: every row
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d hi = -lo;
  for (Eigen::Index i = 0; i < n; i += step) {
    const Eigen::Vector3d r = samples.row(i).transpose();
    if (!r.allFinite()) continue;  // reported precisely by the caller's finiteness check
    lo = lo.cwiseMin(r);
    hi = hi.cwiseMax(r);
  }
  if (!(lo.array() <= hi.array()).all()) return {Eigen::Vector3d::Zero(), 1.0};
  const double scale = 0.5 * (hi - lo).maxCoeff();
  const Eigen::Vector3d centre = 0.5 * (lo + hi);
  // readings that do not spread (a sensor lying still through a live fit's first block): the size of the
  // reading itself, not 1.0, which in tesla or nT left every later fit rank deficient
  const double size = centre.cwiseAbs().maxCoeff();
  return {centre, scale > 0.0 ? scale : (size > 0.0 ? size : 1.0)};
}

// ---- the fit ---------------------------------------------------------------------------------------

namespace {

double smallest_eigenvalue(const Eigen::Matrix<double, 10, 10>& m) {
  return detail::symmetric_eigenvalues(m)(0);
}

// ALS: the noise variance v (normalised units) at which the adjusted scatter ψ(v) turns singular,
// found by bracketing from v = 0 (ψ(0) is the ordinary scatter, positive semi-definite) and
// bisection; the quadric is the null vector of ψ(v), scaled to trace(M) = 1.
Eigen::Matrix<double, 10, 1> adjusted_quadric(const EllipsoidMoments& mom, double& noise_sigma) {
  const double n = static_cast<double>(mom.count());
  auto lambda_min = [&](double v) { return smallest_eigenvalue(mom.scatter(v) / n); };
  double lo = 0.0, hi = 1e-8;
  while (lambda_min(hi) > 0.0) {
    lo = hi;
    hi *= 4.0;
    if (hi > 1.0) throw Error("samples: adjusted least squares found no noise level that fits (noise above the data's spread?)");
  }
  for (int it = 0; it < 200 && hi - lo > 1e-15 * hi; ++it) {
    const double mid = 0.5 * (lo + hi);
    (lambda_min(mid) > 0.0 ? lo : hi) = mid;
  }
  const double v = 0.5 * (lo + hi);
  Eigen::Matrix<double, 10, 1> p =
      detail::symmetric_eigen(Eigen::Matrix<double, 10, 10>(mom.scatter(v) / n)).vectors.col(0);
  const double trace = p(0) + p(1) + p(2);
  if (!(std::abs(trace) > 1e-12 * p.norm()))
    throw Error("samples: adjusted least squares gave a degenerate quadric (trace 0); use the ordinary fit");
  noise_sigma = std::sqrt(v) * mom.scale();
  return p / trace;
}

// The unit of the |h| statistics: 1, or the field H when H⁴ (their largest power) underflows below the normal doubles
// (readings so large that it overflows stay an Error: the corrected fields' squares overflow too).
double statistics_unit(double H) { return H * H * H * H < std::numeric_limits<double>::min() ? H : 1.0; }

// `samples` (null when only their moments are known): the readings, for naming a few far ones that spoil the fit.
EllipsoidResult solve(const EllipsoidMoments& mom, const EllipsoidOptions& opt, const SamplesRef* samples = nullptr) {
  const double n = static_cast<double>(mom.count());
  if (mom.count() < 9) {
    std::ostringstream msg;
    msg << "samples: " << mom.count() << " rows, need at least 9 for a 9-parameter ellipsoid fit";
    throw Error(msg.str());
  }

  const Eigen::Matrix<double, 10, 10> S = mom.scatter();
  EllipsoidResult out;
  Summary& sum = out.summary;
  sum.samples = mom.count();
  sum.coverage_ratio = detail::coverage_ratio(S);
  const auto [ev, mean] = detail::spread(S);
  if (!(ev(2) > 1e-20 * (1.0 + mean.squaredNorm())))  // to rounding: every reading the same
    throw Error("samples: all " + std::to_string(mom.count()) + " readings are the same (a sensor that is stuck, "
                "not updating, or was never turned); " + std::string(detail::kTurnAdvice));
  const std::string hardly_turned = detail::hardly_turned(S, mom.centre(), mom.scale());  // (for the failures below)
  if (sum.coverage_ratio < opt.planar_ratio) {
    const std::string dominated =
        samples ? detail::dominated_spread(*samples, sum.coverage_ratio, opt.planar_ratio,
                                           "a 3-D ellipsoid is not identifiable from such a spread")
                : "";
    if (!dominated.empty()) throw Error(dominated);
    throw Error("samples: the readings lie nearly in one plane (thinnest/widest spread " +
                percent(sum.coverage_ratio) +
                "); a 3-D ellipsoid is not identifiable — " + std::string(detail::kTurnAdvice) +
                ", or " + std::string(detail::kTwoDAdvice) + hardly_turned);
  }

  // Eliminate M11 = 1 − M22 − M33 (trace constraint): p = e0 + E q, q the other 9 coefficients.
  Eigen::Matrix<double, 10, 9> E = Eigen::Matrix<double, 10, 9>::Zero();
  E.bottomRows<9>().setIdentity();
  E(0, 0) = E(0, 1) = -1.0;
  Eigen::Matrix<double, 10, 1> e0 = Eigen::Matrix<double, 10, 1>::Zero();
  e0(0) = 1.0;
  const Eigen::Matrix<double, 9, 9> normal = E.transpose() * S * E / n;
  const Eigen::Matrix<double, 9, 1> rhs = -E.transpose() * S * e0 / n;
  const detail::SymmetricEigen<9> eig = detail::symmetric_eigen(normal);
  const auto& lam = eig.values;
  sum.condition_number = lam(0) > 0.0 ? lam(8) / lam(0) : std::numeric_limits<double>::infinity();
  if (!(sum.condition_number < 1e14)) {
    throw Error("samples: the ellipsoid fit is rank deficient (condition number " + detail::num(sum.condition_number) +
                "); the readings do not determine a 3-D ellipsoid — " + std::string(detail::kTurnAdvice) +
                hardly_turned);
  }
  const Eigen::Matrix<double, 9, 1> q =
      eig.vectors * (eig.vectors.transpose() * rhs).cwiseQuotient(lam);
  Eigen::Matrix<double, 10, 1> p = e0 + E * q;
  if (opt.method == EllipsoidMethod::adjusted) p = adjusted_quadric(mom, out.noise_sigma);
  out.quadric = p;

  Eigen::Matrix3d M;
  M << p(0), p(3), p(4), p(3), p(1), p(5), p(4), p(5), p(2);
  const Eigen::Vector3d v = p.segment<3>(6);
  const detail::EllipsoidShape shape = [&] {
    try {
      return detail::ellipsoid_shape(M, v, p(9), "fitted", sum.coverage_ratio, opt.poor_coverage_ratio,
                                     static_cast<long>(mom.count()));
    } catch (const Error& e) {
      const double thin = sum.coverage_ratio < opt.poor_coverage_ratio ? opt.poor_coverage_ratio : 0.0;
      const std::string dominated =
          samples ? detail::dominated_spread(*samples, sum.coverage_ratio, thin, "the fitted quadric is not an ellipsoid")
                  : "";
      if (!dominated.empty()) throw Error(dominated);
      throw Error(e.what() + hardly_turned);
    }
  }();
  const auto& meig = shape.eig;
  const Eigen::Vector3d& c = shape.centre;
  const double rho2 = shape.rho2;

  const double s = mom.scale();
  const Eigen::Vector3d lamB = meig.eigenvalues() / rho2;        // B = M/ρ² ⇒ (u−c)ᵀB(u−c) = 1
  // the geometric mean in normalised units, then scaled: the product of semi-axes in reading units
  // overflows (or underflows to 0) for readings beyond ~1e100 (or below ~1e-100)
  const double fitted_radius = s * std::cbrt(lamB.cwiseSqrt().cwiseInverse().prod());
  const double H = opt.field_norm > 0.0 ? opt.field_norm : fitted_radius;

  Calibration& cal = out.calibration;
  cal.offset = mom.centre() + s * c;
  cal.matrix = (H / s) * meig.eigenvectors() * lamB.cwiseSqrt().asDiagonal() * meig.eigenvectors().transpose();
  cal.field_norm = H;
  cal.units = opt.units;
  cal.model = opt.method == EllipsoidMethod::adjusted ? "ellipsoid_als" : "ellipsoid";

  // Residual statistics from the moments: |h|² = H² (1 + pᵀd/ρ²), d the design row. In units of H when H⁴ is not a
  // normal double (readings below ~1e-77 had a negative mean |h| and a zero residual); else unit 1, the same bits.
  const double unit = statistics_unit(H);
  const double Hu = H / unit;
  const Eigen::Matrix<double, 10, 1> dmean = S.col(9) / n;
  const double alg = p.dot(S * p) / n;  // mean (pᵀd)²
  const double mean_pd = p.dot(dmean);
  const double mean_q = Hu * Hu * (1.0 + mean_pd / rho2);
  const double var_q = std::max(0.0, Hu * Hu * Hu * Hu / (rho2 * rho2) * (alg - mean_pd * mean_pd));
  sum.cost = alg;
  const double norm_mean = std::sqrt(mean_q) * (1.0 - var_q / (8.0 * mean_q * mean_q));
  sum.norm_mean = unit * norm_mean;
  sum.norm_std_over_mean = std::sqrt(var_q) / (2.0 * std::sqrt(mean_q)) / norm_mean;
  sum.residual_rms = unit * (Hu * std::sqrt(alg) / (2.0 * rho2));
  sum.exact_statistics = false;
  sum.converged = true;

  // An ellipsoid through noise about one point (|h| scattering by tens of %), not a turned sensor's readings about a
  // large constant (an unsigned ADC's mid-scale), which fit well
  if (!hardly_turned.empty() && sum.norm_std_over_mean > 0.1)
    sum.warnings.push_back("not turned:" + hardly_turned.substr(1) +
                           " An ellipsoid fitted to such readings is the noise's shape, not the sensor's");
  if (mom.count() == 9)  // 9 readings fix the 9 parameters: the quadric passes through them, whatever their noise
    sum.warnings.push_back("samples: 9 readings fix the 9 parameters exactly, so the residual is 0 whatever the "
                           "noise and says nothing of the fit's error; give many more readings (hundreds, turned "
                           "through all directions)");
  if (sum.coverage_ratio < opt.poor_coverage_ratio)
    sum.warnings.push_back("poor coverage: thinnest/widest spread of the readings is " +
                           percent(sum.coverage_ratio) +
                           "; the offset and matrix along the thin direction are poorly determined");
  if (opt.field_norm > 0.0) {
    // A known field norm far from the fitted volume radius usually means mismatched units.
    const std::string said = detail::units_mismatch("field_norm " + detail::num(H), H / fitted_radius, fitted_radius,
                                                    "fitted radius");
    if (!said.empty())
      sum.warnings.push_back(said + (sum.coverage_ratio < opt.poor_coverage_ratio
                                         ? ", or the coverage: readings on a small cap of directions fit a far "
                                           "smaller or larger ellipsoid"
                                         : ""));
  }
  return out;
}

void finish_message(EllipsoidResult& r) {
  std::ostringstream msg;
  msg << (r.calibration.model == "ellipsoid_als" ? "ellipsoid fit (adjusted LS)" : "ellipsoid fit") << ": " << r.summary.samples << " samples, |h| std/mean "
      << percent(r.summary.norm_std_over_mean) << ", residual RMS " << r.summary.residual_rms
      << (r.calibration.units.empty() ? "" : " " + r.calibration.units) << ", condition number "
      << r.summary.condition_number;
  if (r.noise_sigma > 0.0) msg << ", noise σ " << r.noise_sigma;
  if (!r.summary.warnings.empty()) msg << " (" << r.summary.warnings.size() << " warning(s))";
  r.summary.message = msg.str();
}

}  // namespace

namespace detail {

void check(const EllipsoidOptions& o) {
  const std::string s = "EllipsoidOptions::";
  require_enum(s + "method", o.method, 2, "ordinary, adjusted (0 … 1)");
  require_nonnegative(s + "field_norm", o.field_norm,
                      "a positive finite magnitude, or 0 to use the fitted radius");
  require_coverage_options(s, o);
}

}  // namespace detail

EllipsoidResult fit_ellipsoid(const EllipsoidMoments& moments, const EllipsoidOptions& options) {
  detail::check(options);
  if (!moments.finite()) throw Error("samples: the accumulated sums are not finite (a NaN or Inf reading was added)");
  EllipsoidResult r = solve(moments, options);
  // the readings' size, as far as the sums know it: their centre and spread
  const Eigen::Vector3d size = moments.centre().cwiseAbs().array() + moments.scale();
  detail::require_finite_fit(detail::finite_fit(r.summary), "samples", size, "the ellipsoid fit");
  finish_message(r);
  return r;
}

EllipsoidResult fit_ellipsoid(const SamplesRef& samples, const EllipsoidOptions& options) {
  detail::check(options);
  samples.require_width("samples");
  if (samples.rows() < 9) {
    std::ostringstream msg;
    msg << "samples: " << samples.rows() << " rows, need at least 9 for a 9-parameter ellipsoid fit";
    throw Error(msg.str());
  }
  const auto [centre, scale] = normalisation(samples);
  EllipsoidMoments mom(centre, scale);
  mom.add_rows(samples);
  if (!mom.finite()) {
    check_finite(samples, "samples");  // names the first bad row
    throw Error("samples: values too large, their fourth powers overflow");
  }
  EllipsoidResult r = solve(mom, options, &samples);

  if (options.exact_statistics) {  // one more pass: |h| of every corrected reading
    const Calibration& cal = r.calibration;
    const double unit = statistics_unit(cal.field_norm);  // (|h| − H)² underflowed for tiny readings
    const double H = cal.field_norm / unit;
    const Eigen::Matrix<double, 3, 3, Eigen::RowMajor> A = cal.matrix / unit;
    double sums[2] = {0.0, 0.0};  // Σ(|h| − H), Σ(|h| − H)², in units of `unit`
    for_each_packed_block(samples, [&](const double* rows, std::size_t len) {
      accumulate_residuals(rows, len, A.data(), cal.offset.data(), H, sums);
    });
    const double sd = sums[0], sd2 = sums[1];
    describe_coverage(r.summary, samples, cal, options.coverage_rows);
    const std::string poor = detail::direction_coverage_warning(r.summary.direction_coverage, samples.rows(),
                                                                options.coverage_rows, options.poor_direction_coverage);
    if (!poor.empty()) r.summary.warnings.push_back(poor);
    const double n = static_cast<double>(samples.rows());
    const double mean_d = sd / n;
    r.summary.norm_mean = unit * (H + mean_d);
    r.summary.norm_std_over_mean = std::sqrt(std::max(0.0, sd2 / n - mean_d * mean_d)) / (H + mean_d);
    r.summary.residual_rms = unit * std::sqrt(sd2 / n);
    r.summary.exact_statistics = true;
  }
  detail::require_finite_fit(detail::finite_fit(r.summary), "samples", samples, "the ellipsoid fit");
  finish_message(r);
  return r;
}

}  // namespace fluxcal
