#include "fluxcal/drift.hpp"

#include "checks.hpp"
#include "linalg.hpp"
#include "long_run.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

namespace fluxcal {

namespace {

constexpr double kUnitRoot = 0.98;  // whitening AR coefficients summing above this: a near random walk
// The AR model the drift's errors rest on summing above this: they are said to be lower bounds. Least squares
// understates a long memory, and the errors with it: on AR(1) 0.97 noise the whitened fits' f(T) errors were
// 0.8–0.9 of the spread (95 % intervals covering 85–92 %), on 0.99 0.7–0.8 (a review, and its check).
constexpr double kLowerBound = 0.95;

// Vandermonde matrix [1 x … x^m] and the column scales s_i = max_j |x_j^i| that balance it.
Eigen::MatrixXd vandermonde(const Eigen::VectorXd& x, int order) {
  Eigen::MatrixXd v(x.size(), order + 1);
  v.col(0).setOnes();
  for (int i = 1; i <= order; ++i) v.col(i) = v.col(i - 1).cwiseProduct(x);
  return v;
}

Eigen::VectorXd column_scales(const Eigen::MatrixXd& v) {
  Eigen::VectorXd s = v.cwiseAbs().colwise().maxCoeff().transpose();
  for (Eigen::Index i = 0; i < s.size(); ++i)
    if (!(s[i] > 0.0)) s[i] = 1.0;
  return s;
}

std::string range_name(double lo, double hi) {
  std::ostringstream o;
  o << "[" << lo << ", " << hi << "]";
  return o.str();
}

int segment_of(const std::vector<double>& edges, double t) {
  const int k = static_cast<int>(edges.size()) - 1;
  for (int s = 0; s < k; ++s)
    if (t >= edges[s] && (t < edges[s + 1] || (s == k - 1 && t <= edges[s + 1]))) return s;
  return -1;
}

std::string edges_name(const std::vector<double>& edges) {
  std::ostringstream o;
  o << "[";
  for (std::size_t i = 0; i < edges.size(); ++i) o << (i ? ", " : "") << edges[i];
  o << "]";
  return o.str();
}

// How many separate levels the regressor takes in a range `width` wide, for the highest order the range can
// determine: values within 5 % of the width of each other are one level (a chamber's hold, its ±0.3 °C wander),
// a stretch wider than that counts one level per 5 % it spans (a ramp across the range: 21). Two holds
// determine a line, not the quadratic their wander let the F-test pick. (The width, not the data's own spread:
// holds 10 °C apart in a 30 °C range, each wandering 0.6 °C, counted 4 levels against their 10.6 °C spread.)
int separate_levels(const std::vector<double>& v, double width) {  // v sorted
  const double resolution = 0.05 * width;
  if (!(resolution > 0.0) || !(v.back() > v.front())) return 1;
  int levels = 0;
  std::size_t first = 0;
  for (std::size_t i = 1; i <= v.size(); ++i) {
    if (i < v.size() && v[i] - v[i - 1] <= resolution) continue;
    levels += 1 + static_cast<int>(std::floor((v[i - 1] - v[first]) / resolution));
    first = i;
  }
  return levels;
}

// The range edges made to cover the temperatures: the outer edges at the coldest and hottest sample (the
// polynomials hold where they were fitted and no further), the inner edges that fall inside the data kept,
// and a range with fewer than min_samples samples joined to its thinner neighbour. The default edges
// (−20, 0, 30, 50 °C: seed 001's chamber) then serve any chamber cycle or outdoor record.
std::vector<double> covering_edges(const SeriesRef& select, const std::vector<double>& given, int min_samples) {
  const double lo = select.minCoeff(), hi = select.maxCoeff();
  if (!(hi > lo)) return given;  // one temperature: no range to cover (the fit says what is wrong)
  std::vector<double> edges{lo};
  for (std::size_t i = 1; i + 1 < given.size(); ++i)
    if (given[i] > lo && given[i] < hi) edges.push_back(given[i]);
  edges.push_back(hi);
  while (edges.size() > 2) {
    std::vector<int> counts(edges.size() - 1, 0);
    for (Eigen::Index i = 0; i < select.size(); ++i) ++counts[static_cast<std::size_t>(segment_of(edges, select[i]))];
    const auto thinnest = std::min_element(counts.begin(), counts.end());
    if (*thinnest >= min_samples) break;
    const std::size_t k = static_cast<std::size_t>(thinnest - counts.begin()), last = counts.size() - 1;
    const std::size_t drop = k == 0 ? 1 : k == last ? last : (counts[k - 1] <= counts[k + 1] ? k : k + 1);
    edges.erase(edges.begin() + static_cast<std::ptrdiff_t>(drop));
  }
  return edges;
}

// Rows of a range usable after AR(p) whitening: those whose p predecessors in time are in the range too,
// and in the same stretch between gaps in time.
bool whitenable(const std::vector<Eigen::Index>& idx, std::size_t j, Eigen::Index p, const Breaks& breaks) {
  if (static_cast<Eigen::Index>(j) < p) return false;
  // indices ascend, so p steps back = consecutive
  return idx[j - static_cast<std::size_t>(p)] == idx[j] - p && stretch_start(breaks, idx[j]) <= idx[j] - p;
}

Eigen::Index whitened_rows(const std::vector<Eigen::Index>& idx, Eigen::Index p, const Breaks& breaks) {
  if (p == 0) return static_cast<Eigen::Index>(idx.size());
  Eigen::Index n = 0;
  for (std::size_t j = 0; j < idx.size(); ++j) n += whitenable(idx, j, p, breaks);
  return n;
}

// The covariance of the coefficients S⁻¹z of a least-squares fit B z ≈ w on the balanced columns B = V S⁻¹ (full
// column rank) with residuals r: σ̂²(BᵀB)⁻¹, σ̂² = Σr²/(rows − cols), or with `correlated` noise the prewhitened
// Newey–West sandwich (BᵀB)⁻¹ S (BᵀB)⁻¹ · rows/(rows − cols) of the scores B_k r_k (rows in time order) — now only
// the fallback for rows no AR model whitened when no AR model of their residuals can be fitted either (ar_sandwich
// is used otherwise: a range's rows come from separate visits of a temperature cycle, and the per-column AR(1)
// prewhitening of their scores made these errors 2–20× too wide, a review). Then to the data units by S⁻¹.
// (BᵀB)⁻¹ = R⁻¹R⁻ᵀ from B's R, without forming BᵀB (a quartic's balanced columns are collinear.)
Eigen::MatrixXd gram_inverse(const Eigen::MatrixXd& b) {
  const Eigen::MatrixXd r = detail::householder_r(b);
  const Eigen::MatrixXd r_inv = r.triangularView<Eigen::Upper>().solve(Eigen::MatrixXd::Identity(b.cols(), b.cols()));
  return r_inv * r_inv.transpose();
}

Eigen::MatrixXd coefficient_covariance(const Eigen::MatrixXd& balanced, const Eigen::VectorXd& scales,
                                       const Eigen::VectorXd& residuals, bool correlated) {
  const Eigen::Index rows = balanced.rows(), cols = balanced.cols();
  Eigen::MatrixXd inverse = gram_inverse(balanced);
  const double spare = static_cast<double>(rows - cols);
  if (correlated) {
    int lags = 0;
    const Eigen::MatrixXd S = detail::prewhitened_long_run(residuals.asDiagonal() * balanced, lags);
    inverse = inverse * S * inverse * (static_cast<double>(rows) / spare);
  } else {
    inverse *= residuals.squaredNorm() / spare;
  }
  return scales.cwiseInverse().asDiagonal() * inverse * scales.cwiseInverse().asDiagonal();
}

// The stretches of a series of samples `at` (ascending time indices), as ArOptions::breaks (positions in the series):
// a new one where a sample was left out (outside every range) or time has a gap.
Breaks series_breaks(const std::vector<Eigen::Index>& at, const Breaks& breaks) {
  Breaks out;
  for (std::size_t i = 1; i < at.size(); ++i)
    if (at[i] != at[i - 1] + 1 || stretch_start(breaks, at[i]) == at[i]) out.push_back(static_cast<Eigen::Index>(i));
  return out;
}

// The highest AR order a series of n samples in these stretches can show: ≤ max_order and (n − 3)/2, and short
// stretches between gaps no longer memory than they hold (max_order + 3 regressed rows).
int series_max_order(Eigen::Index n, const Breaks& stretches, int max_order) {
  int m = std::max(0, std::min<int>(max_order, (static_cast<int>(n) - 3) / 2));
  while (m > 0 && regressed_rows(n, stretches, m) < m + 3) --m;
  return m;
}

// Least squares' covariance of z in B z ≈ w (rows in time order, at samples `at`, residuals r) when the noise is the
// AR model `ar` (empty: white): Σ = σ_e² L⁻¹L⁻ᵀ, L the whitening filter (e_t = n_t − Σ a_q n_{t−q} within a stretch
// of consecutive samples), so (BᵀB)⁻¹ BᵀΣB (BᵀB)⁻¹ with BᵀΣB = σ_e² YᵀY, LᵀY = B: Y_t = B_t + Σ a_q Y_{t+q},
// backwards in time; σ_e² = Σ e_t² / (rows − cols) from the whitened residuals. Taken as σ_e² XᵀX, X = Y_Q R⁻ᵀ with
// Y_Q the recursion run on B's orthonormal factor Q = B R⁻¹: (BᵀB)⁻¹ BᵀΣB (BᵀB)⁻¹ as written lost cond(B)²·ε to
// cancellation (1e-9 of a cubic's covariance on 30–50 °C against an SVD reference), this only cond(B)·ε.
Eigen::MatrixXd ar_sandwich(const Eigen::MatrixXd& b, const Eigen::VectorXd& r, const std::vector<Eigen::Index>& at,
                            const Eigen::VectorXd& ar, const Breaks& breaks) {
  const Eigen::Index rows = b.rows(), p = ar.size();
  std::vector<Eigen::Index> stretch(static_cast<std::size_t>(rows));
  for (Eigen::Index i = 0; i < rows; ++i)
    stretch[i] = i > 0 && at[i] == at[i - 1] + 1 && stretch_start(breaks, at[i]) != at[i] ? stretch[i - 1] : i;
  const Eigen::MatrixXd rb = detail::householder_r(b);
  Eigen::MatrixXd y = rb.triangularView<Eigen::Upper>().solve<Eigen::OnTheRight>(b);  // Q
  for (Eigen::Index i = rows - 1; i >= 0; --i)
    for (Eigen::Index q = 1; q <= p && i + q < rows && stretch[i + q] == stretch[i]; ++q)
      y.row(i) += ar[q - 1] * y.row(i + q);
  double sum_sq = 0.0;
  for (Eigen::Index i = 0; i < rows; ++i) {
    double e = r[i];
    for (Eigen::Index q = 1; q <= p && i - q >= 0 && stretch[i - q] == stretch[i]; ++q) e -= ar[q - 1] * r[i - q];
    sum_sq += e * e;
  }
  const Eigen::MatrixXd x = rb.transpose().triangularView<Eigen::Lower>().solve<Eigen::OnTheRight>(y);  // Y_Q R⁻ᵀ
  return (x.transpose() * x) * (sum_sq / static_cast<double>(rows - b.cols()));
}

// For the errors of a fit no AR model whitened (whiten off, a noise near a random walk, an AR order starved to 0):
// an AR model by AIC of its residuals r, in time order over the whole series (rows at samples `at`), fitted for the
// errors alone. Empty: AIC found them white; false: none can be fitted (a constant residual, too short a series),
// and the errors stay Newey–West's. Coefficients summing above 1 (an explosive fit to a random walk) are scaled to
// sum to 1: the Y recursion of ar_sandwich would grow them as (Σa)^rows.
bool error_noise_model(const Eigen::VectorXd& r, const std::vector<Eigen::Index>& at, const Breaks& breaks,
                       int max_order, Eigen::VectorXd& ar) {
  ArOptions o;
  o.breaks = series_breaks(at, breaks);
  o.max_order = series_max_order(r.size(), o.breaks, max_order);
  if (o.max_order == 0 || !(r.array() != r[0]).any()) return false;
  try {
    ar = fit_ar(r, o).coefficients;
  } catch (const Error&) {
    return false;
  }
  if (ar.size() > 0 && ar.sum() > 1.0) ar /= ar.sum();
  return true;
}

// Balanced least squares on the (optionally AR-whitened) Vandermonde rows; SSE in the fitted space; `covariance`:
// the coefficients' (coefficient_covariance; `correlated`: the noise is not white and no AR model whitened it).
Eigen::VectorXd fit_rows(const Eigen::VectorXd& x, const Eigen::VectorXd& w, const std::vector<Eigen::Index>& idx,
                         const Eigen::VectorXd& ar, int order, double* sse, double* condition,
                         const Breaks& breaks = {}, Eigen::MatrixXd* covariance = nullptr, bool correlated = false) {
  const Eigen::MatrixXd v = vandermonde(x, order);
  const Eigen::Index p = ar.size();
  Eigen::MatrixXd vw;
  Eigen::VectorXd ww;
  if (p == 0) {
    vw = v;
    ww = w;
  } else {
    const Eigen::Index rows = whitened_rows(idx, p, breaks);
    vw.resize(rows, order + 1);
    ww.resize(rows);
    Eigen::Index r = 0;
    for (std::size_t j = 0; j < idx.size(); ++j) {
      if (!whitenable(idx, j, p, breaks)) continue;
      const Eigen::Index jj = static_cast<Eigen::Index>(j);
      vw.row(r) = v.row(jj);
      ww[r] = w[jj];
      for (Eigen::Index q = 1; q <= p; ++q) {
        vw.row(r) -= ar[q - 1] * v.row(jj - q);
        ww[r] -= ar[q - 1] * w[jj - q];
      }
      ++r;
    }
  }
  if (vw.rows() < order + 2)
    throw Error("drift: too few consecutive samples in a range for order " + std::to_string(order));
  const Eigen::VectorXd s = column_scales(vw);
  const Eigen::MatrixXd vb = vw * s.cwiseInverse().asDiagonal();
  Eigen::Index rank = 0;
  const Eigen::VectorXd solution = detail::least_squares_qr(vb, ww, &rank);
  if (rank < order + 1)
    throw Error("drift: the temperatures take too few distinct values for a polynomial of order " +
                std::to_string(order));
  const Eigen::VectorXd coef = solution.cwiseQuotient(s);
  const Eigen::VectorXd residuals = ww - vw * coef;
  if (sse) *sse = residuals.squaredNorm();
  if (covariance) *covariance = coefficient_covariance(vb, s, residuals, correlated);
  if (condition) {
    const Eigen::VectorXd sv = detail::singular_values(vb);
    *condition = sv[0] / sv[sv.size() - 1];
  }
  return coef;
}

}  // namespace

Eigen::VectorXd fit_polynomial(const SeriesRef& x, const SeriesRef& w, int order, double* sse, double* condition) {
  if (order < 0) throw Error("order: " + std::to_string(order) + ", a polynomial order must be ≥ 0");
  check_series(x, "regressor", order + 2, "for a polynomial of order " + std::to_string(order));
  check_series(w, "zero_bias", x.size(), "(one per regressor value)");
  if (w.size() != x.size())
    throw Error("zero_bias: " + std::to_string(w.size()) + " values for " + std::to_string(x.size()) +
                " regressor values, need one each");
  std::vector<Eigen::Index> idx(static_cast<std::size_t>(x.size()));
  for (std::size_t i = 0; i < idx.size(); ++i) idx[i] = static_cast<Eigen::Index>(i);
  return fit_rows(x, w, idx, Eigen::VectorXd(), order, sse, condition);
}

namespace detail {

void check(const DriftOptions& o) {
  const std::string s = "DriftOptions::";
  const auto& edges = o.breakpoints;
  if (edges.size() < 2) throw Error(s + "breakpoints: need at least two edges (one range)");
  for (std::size_t i = 1; i < edges.size(); ++i)
    if (!(edges[i] > edges[i - 1])) throw Error(s + "breakpoints: not strictly ascending");
  require_int(o.max_order >= 0 && o.max_order <= 12, s + "max_order", o.max_order, "0 … 12");
  require_int(o.order >= -1 && o.order <= 12, s + "order", o.order, "0 … 12, or −1 to choose by F-test");
  require_open_unit(s + "significance", o.significance);
  require_int(o.min_samples >= 0, s + "min_samples", o.min_samples, "≥ 0");
  require_int(o.whiten_max_order >= 0, s + "whiten_max_order", o.whiten_max_order, "≥ 0 (0: no whitening)");
}

}  // namespace detail

DriftModel fit_drift(const SeriesRef& select, const SeriesRef& x, const SeriesRef& w, const DriftOptions& options) {
  check_series(select, "temperature", 1, "to fit a drift model");
  check_series(x, "regressor", 1, "to fit a drift model");
  check_series(w, "zero_bias", 1, "to fit a drift model");
  if (select.size() != w.size() || x.size() != w.size())
    throw Error("drift: temperature, regressor and zero_bias lengths differ (" + std::to_string(select.size()) +
                ", " + std::to_string(x.size()) + ", " + std::to_string(w.size()) + ")");
  detail::check(options);
  check_breaks(options.breaks, w.size(), "DriftOptions::breaks");
  // Every fit is a sum of squares of w: values whose squares overflow gave inf SSEs and a "converged" order 0.
  detail::require_finite_fit(std::isfinite(w.squaredNorm()), "zero_bias", w, "the drift fit");
  const std::vector<double> edges = covering_edges(select, options.breakpoints, options.min_samples);
  std::vector<std::string> notes;
  bool moved = edges.size() != options.breakpoints.size();  // an edge dropped, or one moved by > 0.1 % of the span
  for (std::size_t i = 0; !moved && i < edges.size(); ++i)
    moved = std::abs(edges[i] - options.breakpoints[i]) > 1e-3 * (edges.back() - edges.front());
  std::string range_note;
  if (moved)
    notes.push_back(range_note = "temperature ranges " + edges_name(options.breakpoints) + " adjusted to the data: " +
                    edges_name(edges) + " (outer edges at the coldest and hottest sample; a range with fewer than " +
                    std::to_string(options.min_samples) + " samples joined its neighbour); set them with --breakpoints");
  const int k = static_cast<int>(edges.size()) - 1;
  std::vector<std::vector<Eigen::Index>> members(k);
  std::size_t outside = 0;
  for (Eigen::Index i = 0; i < select.size(); ++i) {
    const int s = segment_of(edges, select[i]);
    if (s < 0)
      ++outside;
    else
      members[s].push_back(i);
  }

  DriftModel model;
  const bool x_is_select = (x.array() == select.array()).all();  // the device temperature is the regressor
  std::vector<Eigen::VectorXd> xs(k), ws(k);
  std::vector<int> top(k);
  for (int s = 0; s < k; ++s) {
    const Eigen::Index n = static_cast<Eigen::Index>(members[s].size());
    const int need = std::max(options.min_samples, (options.order >= 0 ? options.order : 0) + 2);
    if (n < need)
      throw Error("temperature range " + range_name(edges[s], edges[s + 1]) + ": " + std::to_string(n) +
                  " samples, need at least " + std::to_string(need));
    xs[s].resize(n);
    ws[s].resize(n);
    for (Eigen::Index j = 0; j < n; ++j) {
      xs[s][j] = x[members[s][j]];
      ws[s][j] = w[members[s][j]];
    }
    double coldest = select[members[s].front()], hottest = coldest;
    for (const Eigen::Index i : members[s]) {
      coldest = std::min(coldest, select[i]);
      hottest = std::max(hottest, select[i]);
    }
    if (hottest - coldest < 0.5 * (edges[s + 1] - edges[s]))  // holds at one end of a range: the rest is a guess
      notes.push_back("temperature range " + range_name(edges[s], edges[s + 1]) + ": its samples span only " +
                      range_name(coldest, hottest) + ", so the polynomial is extrapolated over the rest of the "
                      "range; record across it, or move the breakpoint (--breakpoints)");
    std::vector<double> v(xs[s].data(), xs[s].data() + n);
    std::sort(v.begin(), v.end());
    // (the regressor's own span when it is not the selecting temperature: the inside–outside difference)
    const double width = x_is_select ? edges[s + 1] - edges[s] : v.back() - v.front();
    const int levels = separate_levels(v, width);
    const int distinct = static_cast<int>(std::unique(v.begin(), v.end()) - v.begin());
    top[s] = options.order >= 0 ? options.order
                                : std::min<int>(options.max_order, std::min<Eigen::Index>(levels - 1, n - 3));
    if (options.order < 0 && levels <= 2 && levels - 1 < options.max_order && levels < distinct)
      notes.push_back("temperature range " + range_name(edges[s], edges[s + 1]) + ": the regressor sits at " +
                      std::to_string(levels) + " separate level(s) (holds), so orders above " +
                      std::to_string(std::max(levels - 1, 0)) + " were not tried: a polynomial needs one level "
                      "more than its order; record between the holds (a ramp) for a higher order");
    if (options.order >= 0 && distinct <= options.order)
      throw Error("temperature range " + range_name(edges[s], edges[s + 1]) + ": the regressor takes " +
                  std::to_string(distinct) + " distinct values, too few for order " + std::to_string(options.order));
  }

  // Noise model for generalised least squares: AR fit to the residual of the highest-order fits,
  // taken in time order over every sample inside a range.
  Eigen::VectorXd ar;
  bool white = false;  // an AR model was fitted and AIC found the noise white
  bool near_unit_root = false;  // the whitening model was dropped as a near random walk
  if (options.whiten) {
    Eigen::VectorXd residual = Eigen::VectorXd::Constant(w.size(), std::numeric_limits<double>::quiet_NaN());
    for (int s = 0; s < k; ++s) {
      const Eigen::VectorXd c = fit_polynomial(xs[s], ws[s], top[s]);
      const Eigen::VectorXd r = ws[s] - vandermonde(xs[s], top[s]) * c;
      for (std::size_t j = 0; j < members[s].size(); ++j) residual[members[s][j]] = r[static_cast<Eigen::Index>(j)];
    }
    // The samples inside a range, in time order; a stretch breaks where a sample was left out or time has a gap.
    std::vector<double> kept;
    std::vector<Eigen::Index> at;
    for (Eigen::Index i = 0; i < residual.size(); ++i) {
      if (std::isnan(residual[i])) continue;
      kept.push_back(residual[i]);
      at.push_back(i);
    }
    const Eigen::Map<const Eigen::VectorXd> series(kept.data(), static_cast<Eigen::Index>(kept.size()));
    ArOptions ar_options;
    ar_options.breaks = series_breaks(at, options.breaks);
    ar_options.max_order = series_max_order(series.size(), ar_options.breaks, options.whiten_max_order);
    // Whitening by AR(p) drops each range's samples without p in-range predecessors: a sparse log (48 samples,
    // ranges crossed in runs of 7) had AR(8) chosen and no row left in a range. Each range keeps enough to test
    // every order it may take (top + 3 rows).
    const int series_order = ar_options.max_order;
    auto starved = [&](int p) {
      for (int s = 0; s < k; ++s)
        if (whitened_rows(members[s], p, options.breaks) < top[s] + 3) return true;
      return false;
    };
    while (ar_options.max_order > 0 && starved(ar_options.max_order)) --ar_options.max_order;
    if (ar_options.max_order < series_order)
      notes.push_back("the noise model's AR order was kept at most " + std::to_string(ar_options.max_order) +
                      " (not " + std::to_string(series_order) + "): whitened by more, a temperature range would keep "
                      "too few consecutive samples to fit its drift (a range crossed in short runs; log faster, or "
                      "set wider ranges with --breakpoints)");
    if (ar_options.max_order > 0 && (series.array() != series[0]).any()) {
      ar = fit_ar(series, ar_options).coefficients;
      white = ar.size() == 0;
    }
    // Whitening multiplies a range's constant by 1 − Σa: near a random walk each range's level would rest on
    // the few rows at its edges, and the fitted levels landed further from the data than no model at all.
    if (ar.size() > 0 && ar.sum() > kUnitRoot) {
      std::ostringstream note;
      note << "the noise about the drift is close to a random walk (its AR coefficients sum to " << ar.sum()
           << "): weighted by it, each range's level is nearly undetermined, so the drift was fitted unweighted "
              "(its F-tests then assume white noise and may keep too many orders)";
      notes.push_back(note.str());
      ar.resize(0);
      near_unit_root = true;
    }
  }
  model.noise_ar = ar;

  for (int s = 0; s < k; ++s) {
    DriftSegment seg;
    seg.lo = edges[s];
    seg.hi = edges[s + 1];
    const Eigen::Index n = xs[s].size();
    if (n > 0) {
      seg.x_lo = xs[s].minCoeff();
      seg.x_hi = xs[s].maxCoeff();
    }
    int m = options.order >= 0 ? options.order : 0;
    double sse = 0.0, cond = 0.0;
    Eigen::VectorXd coef = fit_rows(xs[s], ws[s], members[s], ar, m, &sse, &cond, options.breaks);
    const Eigen::Index rows = whitened_rows(members[s], ar.size(), options.breaks);
    if (options.order < 0) {
      while (m < top[s] && rows - m - 2 > 0) {
        double sse_next = 0.0, cond_next = 0.0;
        const Eigen::VectorXd next =
            fit_rows(xs[s], ws[s], members[s], ar, m + 1, &sse_next, &cond_next, options.breaks);
        const double dof = static_cast<double>(rows - m - 2);
        const double f = sse_next > 0.0 ? (sse - sse_next) / (sse_next / dof)
                                        : std::numeric_limits<double>::infinity();
        seg.f_statistics.push_back(f);
        if (!(f1_sf(f, dof) < options.significance)) {
          // A drift even about the range's middle (a bowl) has no linear term to find: the step to m+1 fails and
          // m+2 was never tried (a blind check: (T − 15)² on 0…30 °C fitted as a constant in 19 of 20 seeds). So
          // before stopping, m → m+2 is tested on its own 2 degrees of freedom: F(2, ν) survives as (1 + 2F/ν)^(−ν/2).
          if (m + 2 > top[s] || rows - m - 3 <= 0) break;
          double sse_two = 0.0, cond_two = 0.0;
          const Eigen::VectorXd two = fit_rows(xs[s], ws[s], members[s], ar, m + 2, &sse_two, &cond_two, options.breaks);
          const double dof2 = static_cast<double>(rows - m - 3);
          const double f2 = sse_two > 0.0 ? 0.5 * (sse - sse_two) / (sse_two / dof2)
                                          : std::numeric_limits<double>::infinity();
          seg.f_statistics.push_back(f2);
          // (at the significance squared, a second chance at each stop: a blind check's line-shaped range got its
          // order right in 58 of 60 fits without it, 55 at half the significance, 56 at a fifth, 58 at its square —
          // the simulator's phase B took a cubic at 0.01 / 5 on F 6.4 — and its bowls, F ~ 50–140, 18 of 20 each)
          if (!(std::pow(1.0 + 2.0 * f2 / dof2, -0.5 * dof2) < options.significance * options.significance)) break;
          m += 2;
          coef = two;
          sse = sse_two;
          cond = cond_two;
          continue;
        }
        ++m;
        coef = next;
        sse = sse_next;
        cond = cond_next;
      }
    }
    seg.order = m;
    seg.coefficients = coef;
    // the errors: generalised least squares' under the AR model, or σ̂²(VᵀV)⁻¹ for noise AIC found white; where no
    // model whitened the rows, replaced below by the sandwich under an AR model of the residuals (this range's own
    // Newey–West sandwich stays only when none can be fitted)
    fit_rows(xs[s], ws[s], members[s], ar, m, nullptr, nullptr, options.breaks, &seg.covariance,
             ar.size() == 0 && !white);
    seg.samples = static_cast<std::size_t>(n);
    seg.sse = (ws[s] - vandermonde(xs[s], m) * coef).squaredNorm();
    seg.residual_rms = std::sqrt(seg.sse / static_cast<double>(n));
    seg.condition_number = cond;
    model.segments.push_back(seg);
  }

  // Every range's rows in time order, its balanced Vandermonde row in its own columns: the continuous refit's
  // design, and (block-diagonal) the ranges fitted alone, whose errors need the noise's correlation across ranges
  // when no AR model whitened their rows — a range's rows come from separate visits of a temperature cycle, and
  // the Newey–West sandwich of each range's scores, AR(1)-prewhitened column by column over the joins between
  // visits, was 2–20× too wide on AR(1) 0.9 noise with the temperature cycling every 50–200 samples (a review).
  const bool joint = options.continuous && k > 1;
  const bool unmodelled = ar.size() == 0 && !white;  // no AR model whitened the rows, none found the noise white
  double memory = ar.size() > 0 ? ar.sum() : 0.0;    // Σa of the AR model the errors rest on
  bool newey_west = unmodelled;                      // the errors are Newey–West's (no AR model could be fitted)
  if (joint || unmodelled) {
    std::vector<Eigen::Index> offset(k + 1, 0);
    for (int s = 0; s < k; ++s) offset[s + 1] = offset[s] + model.segments[s].order + 1;
    const Eigen::Index cols = offset[k];
    Eigen::Index rows = 0;
    for (int s = 0; s < k; ++s) rows += xs[s].size();
    Eigen::MatrixXd big = Eigen::MatrixXd::Zero(rows, cols);
    Eigen::VectorXd rhs(rows), scale(cols);
    Eigen::Index r0 = 0;
    for (int s = 0; s < k; ++s) {
      const Eigen::MatrixXd v = vandermonde(xs[s], model.segments[s].order);
      const Eigen::VectorXd sc = column_scales(v);
      big.block(r0, offset[s], v.rows(), v.cols()) = v * sc.cwiseInverse().asDiagonal();
      scale.segment(offset[s], sc.size()) = sc;
      rhs.segment(r0, v.rows()) = ws[s];
      r0 += v.rows();
    }
    Eigen::MatrixXd design = big, map = scale.cwiseInverse().asDiagonal();  // z ↦ the coefficients in data units
    if (joint) {
      // Joint least squares of all segments (balanced columns) under f_s(b) = f_{s+1}(b) at the inner
      // breakpoints, solved in the null space of the constraints.
      Eigen::MatrixXd con = Eigen::MatrixXd::Zero(k - 1, cols);
      for (int s = 0; s + 1 < k; ++s) {
        const double b = edges[s + 1];
        for (int side = 0; side < 2; ++side) {
          const int seg = s + side;
          double p = 1.0;
          for (int i = 0; i <= model.segments[seg].order; ++i, p *= b)
            con(s, offset[seg] + i) = (side == 0 ? 1.0 : -1.0) * p / scale[offset[seg] + i];
        }
      }
      const Eigen::MatrixXd null = detail::right_singular_vectors(con).rightCols(cols - (k - 1));
      design = big * null;
      const Eigen::VectorXd z = detail::least_squares_qr(design, rhs);
      const Eigen::VectorXd theta = (null * z).cwiseQuotient(scale);
      map = scale.cwiseInverse().asDiagonal() * null;
      for (int s = 0; s < k; ++s) model.segments[s].coefficients = theta.segment(offset[s], model.segments[s].order + 1);
    }
    std::vector<std::pair<Eigen::Index, Eigen::Index>> when;  // (sample, row of `design`)
    Eigen::VectorXd residuals(rows);
    r0 = 0;
    for (int s = 0; s < k; ++s) {
      DriftSegment& seg = model.segments[s];
      const Eigen::VectorXd r = ws[s] - vandermonde(xs[s], seg.order) * seg.coefficients;
      seg.sse = r.squaredNorm();
      seg.residual_rms = std::sqrt(seg.sse / static_cast<double>(xs[s].size()));
      residuals.segment(r0, r.size()) = r;
      for (std::size_t j = 0; j < members[s].size(); ++j) when.emplace_back(members[s][j], r0 + static_cast<Eigen::Index>(j));
      r0 += r.size();
    }
    std::sort(when.begin(), when.end());
    Eigen::MatrixXd in_time(rows, design.cols());
    Eigen::VectorXd residuals_in_time(rows);
    std::vector<Eigen::Index> at(static_cast<std::size_t>(rows));
    for (Eigen::Index i = 0; i < rows; ++i) {
      in_time.row(i) = design.row(when[i].second);
      residuals_in_time[i] = residuals[when[i].second];
      at[i] = when[i].first;
    }
    // The noise model of the errors: the whitening one (the continuous refit is unweighted, so its errors are least
    // squares' sandwich under that model), none for noise AIC found white, else one fitted to these residuals in
    // time order, across the ranges, for the errors alone (whiten off: the fit stays unweighted, as asked).
    Eigen::VectorXd noise = ar;
    const bool modelled = !unmodelled || error_noise_model(residuals_in_time, at, options.breaks,
                                                           options.whiten_max_order, noise);
    Eigen::MatrixXd zcov;
    if (modelled) {
      zcov = ar_sandwich(in_time, residuals_in_time, at, noise, options.breaks);
      // Near a unit root that sandwich is a lower bound: the fitted AR model understates the memory (least squares
      // is biased towards less of it) and the noise's level at the start is taken as known. With AR(1) 0.99 the
      // f(T) errors were ~0.5 of the spread as Newey–West's (its prewhitening is clipped at 0.97), with a random
      // walk 0.1–0.3; they are better under the AR model but still too small — said, not hidden (a review).
      if (unmodelled && noise.size() > 0) memory = noise.sum();
    } else if (joint) {
      zcov = coefficient_covariance(in_time, Eigen::VectorXd::Ones(in_time.cols()), residuals_in_time, true);
    }
    if (modelled || joint) {
      const Eigen::MatrixXd cov = map * zcov * map.transpose();
      for (int s = 0; s < k; ++s)
        model.segments[s].covariance = cov.block(offset[s], offset[s], model.segments[s].order + 1,
                                                 model.segments[s].order + 1);
    }
    newey_west = !modelled;
  }
  if (near_unit_root || memory > kLowerBound) {
    std::ostringstream note;
    note.precision(3);
    note << "the drift's standard errors are lower bounds, not reliable: the noise about the drift is close to a "
            "random walk";
    if (memory > kLowerBound) note << " (the AR model they rest on sums to " << memory << ")";
    note << ", whose memory is longer than the record can show: the errors ("
         << (newey_west ? "Newey–West's" : "least squares' under that AR model") << ") come out too small (in "
         << (newey_west ? "simulations about 0.5× the true spread for AR(1) 0.99 noise, 0.1–0.3× for a random walk"
                        : "simulations 0.8–0.9× the true spread for AR(1) 0.97 noise, 0.7–0.8× for 0.99, 0.4–0.5× "
                          "for a random walk")
         << "); record for longer, or look for what wanders (ageing, a slow thermal effect the model misses)";
    notes.push_back(note.str());
  }
  for (DriftSegment& seg : model.segments) seg.standard_errors = seg.covariance.diagonal().cwiseSqrt();

  Summary& sum = model.summary;
  double sse_total = 0.0;
  std::size_t used = 0;
  std::ostringstream msg;
  msg << "drift model, orders";
  for (const auto& seg : model.segments) {
    sse_total += seg.sse;
    used += seg.samples;
    msg << " " << seg.order;
    sum.condition_number = std::max(sum.condition_number, seg.condition_number);
  }
  if (model.noise_ar.size() > 0) msg << "; fits and F-tests whitened by an AR(" << model.noise_ar.size() << ") noise model";
  sum.samples = used;
  sum.residual_rms = std::sqrt(sse_total / static_cast<double>(used));
  sum.cost = sse_total / static_cast<double>(used);
  bool finite = detail::finite_fit(sum);
  for (const auto& seg : model.segments) finite = finite && seg.coefficients.allFinite();
  detail::require_finite_fit(finite, "regressor", x, "the drift polynomials (powers of the regressor)");
  sum.converged = true;
  sum.message = msg.str();
  sum.warnings.insert(sum.warnings.begin(), notes.begin(), notes.end());
  if (outside > 0)
    sum.warnings.push_back(std::to_string(outside) + " samples outside every temperature range were not used");
  model.range_note = range_note;
  return model;
}

namespace {

// The edges lo_0 < lo_1 < … < hi_last the segments are found by: a gap or an unsorted list (a hand-edited
// or merged model) would silently pick the wrong polynomial, so the ranges must tile one interval.
std::vector<double> tiling_edges(const std::vector<DriftSegment>& segments) {
  if (segments.empty()) throw Error("drift: the model has no segments");
  std::vector<double> edges;
  for (std::size_t k = 0; k < segments.size(); ++k) {
    const DriftSegment& seg = segments[k];
    std::ostringstream msg;
    if (!(std::isfinite(seg.lo) && std::isfinite(seg.hi) && seg.lo < seg.hi))
      msg << "drift model: segment " << k << " has the range [" << seg.lo << ", " << seg.hi
          << "], not a finite range with lo < hi";
    else if (k > 0 && seg.lo != segments[k - 1].hi)
      msg << "drift model: segment " << k << " starts at " << seg.lo << " but segment " << k - 1 << " ends at "
          << segments[k - 1].hi << "; the ranges must be ascending and contiguous (no gaps, no overlaps)";
    if (!msg.str().empty()) throw Error(msg.str());
    edges.push_back(seg.lo);
  }
  edges.push_back(segments.back().hi);
  return edges;
}

void check_lengths(const SeriesRef& select, const SeriesRef& x) {
  check_series(select, "temperature", 0, "");
  check_series(x, "regressor", 0, "");
  if (select.size() != x.size()) throw Error("drift: temperature and regressor lengths differ");
}

}  // namespace

namespace {

// The segment of sample i (by its selecting temperature); Error when it is outside every range.
int segment_at(const std::vector<double>& edges, const SeriesRef& select, Eigen::Index i) {
  const int s = segment_of(edges, select[i]);
  if (s < 0) {
    std::ostringstream msg;
    msg << "temperature: sample " << i << " is " << select[i] << ", outside every range of the drift model ("
        << edges.front() << " … " << edges.back() << ")";
    throw Error(msg.str());
  }
  return s;
}

}  // namespace

Eigen::VectorXd DriftModel::evaluate(const SeriesRef& select, const SeriesRef& x) const {
  check_lengths(select, x);
  const std::vector<double> edges = tiling_edges(segments);
  Eigen::VectorXd f(x.size());
  for (Eigen::Index i = 0; i < x.size(); ++i) {
    const Eigen::VectorXd& c = segments[segment_at(edges, select, i)].coefficients;
    double v = 0.0;
    for (Eigen::Index j = c.size() - 1; j >= 0; --j) v = v * x[i] + c[j];
    f[i] = v;
  }
  return f;
}

Eigen::VectorXd DriftModel::standard_error(const SeriesRef& select, const SeriesRef& x) const {
  check_lengths(select, x);
  const std::vector<double> edges = tiling_edges(segments);
  Eigen::VectorXd se(x.size());
  for (Eigen::Index i = 0; i < x.size(); ++i) {
    const DriftSegment& seg = segments[segment_at(edges, select, i)];
    const Eigen::Index m = seg.coefficients.size();
    if (seg.covariance.rows() != m || seg.covariance.cols() != m)
      throw Error("drift: the segment [" + detail::num(seg.lo) + ", " + detail::num(seg.hi) + "] has no " +
                  std::to_string(m) + "×" + std::to_string(m) + " covariance of its coefficients (a model built "
                  "by hand, or saved before fluxcal kept them): fit it again for standard errors");
    Eigen::VectorXd v(m);
    for (Eigen::Index j = 0; j < m; ++j) v[j] = j == 0 ? 1.0 : v[j - 1] * x[i];
    se[i] = std::sqrt(std::max(0.0, v.dot(seg.covariance * v)));
  }
  return se;
}

void DriftModel::require_fitted_x(const SeriesRef& select, const SeriesRef& x, double margin) const {
  check_lengths(select, x);
  const std::vector<double> edges = tiling_edges(segments);
  for (Eigen::Index i = 0; i < x.size(); ++i) {
    const int s = segment_of(edges, select[i]);
    if (s < 0) continue;  // evaluate says it
    const DriftSegment& seg = segments[static_cast<std::size_t>(s)];
    const double slack = margin * (seg.x_hi - seg.x_lo);
    if (x[i] < seg.x_lo - slack || x[i] > seg.x_hi + slack) {  // false for NaN x_lo/x_hi: not recorded
      std::ostringstream msg;
      msg << "regressor: sample " << i << " is " << x[i] << " at temperature " << select[i]
          << ", outside what the drift model's range " << range_name(seg.lo, seg.hi) << " was fitted over ("
          << seg.x_lo << " … " << seg.x_hi << "): the polynomials are not extrapolated";
      throw Error(msg.str());
    }
  }
}

Eigen::VectorXd DriftModel::compensate(const SeriesRef& w, const SeriesRef& select, const SeriesRef& x) const {
  check_series(w, "zero_bias", 0, "");
  if (w.size() != x.size()) throw Error("drift: zero_bias and temperature lengths differ");
  return w - evaluate(select, x);
}

}  // namespace fluxcal
