#include "fluxcal/timeseries.hpp"

#include "checks.hpp"
#include "linalg.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>

namespace fluxcal {

namespace {

// Regularised lower incomplete gamma P(a, x) by its series (x < a + 1) and the upper Q(a, x) by
// Lentz's continued fraction otherwise (Numerical Recipes §6.2, written from the formulas).
double gamma_q(double a, double x) {
  if (x <= 0.0) return 1.0;
  const double log_prefactor = -x + a * std::log(x) - std::lgamma(a);
  if (x < a + 1.0) {
    double term = 1.0 / a, sum = term;
    for (int n = 1; n < 10000; ++n) {
      term *= x / (a + n);
      sum += term;
      if (std::abs(term) < std::abs(sum) * 1e-16) break;
    }
    return std::max(0.0, 1.0 - sum * std::exp(log_prefactor));
  }
  const double tiny = 1e-300;
  double b = x + 1.0 - a, c = 1.0 / tiny, d = 1.0 / b, h = d;
  for (int i = 1; i < 10000; ++i) {
    const double an = -i * (i - a);
    b += 2.0;
    d = an * d + b;
    if (std::abs(d) < tiny) d = tiny;
    c = b + an / c;
    if (std::abs(c) < tiny) c = tiny;
    d = 1.0 / d;
    const double delta = d * c;
    h *= delta;
    if (std::abs(delta - 1.0) < 1e-16) break;
  }
  return std::exp(log_prefactor) * h;
}

// Continued fraction of the incomplete beta function (modified Lentz).
double beta_cf(double a, double b, double x) {
  const double tiny = 1e-300;
  double c = 1.0, d = 1.0 - (a + b) * x / (a + 1.0);
  if (std::abs(d) < tiny) d = tiny;
  d = 1.0 / d;
  double h = d;
  for (int m = 1; m < 10000; ++m) {
    const int m2 = 2 * m;
    double aa = m * (b - m) * x / ((a + m2 - 1.0) * (a + m2));
    d = 1.0 + aa * d;
    if (std::abs(d) < tiny) d = tiny;
    c = 1.0 + aa / c;
    if (std::abs(c) < tiny) c = tiny;
    d = 1.0 / d;
    h *= d * c;
    aa = -(a + m) * (a + b + m) * x / ((a + m2) * (a + m2 + 1.0));
    d = 1.0 + aa * d;
    if (std::abs(d) < tiny) d = tiny;
    c = 1.0 + aa / c;
    if (std::abs(c) < tiny) c = tiny;
    d = 1.0 / d;
    const double delta = d * c;
    h *= delta;
    if (std::abs(delta - 1.0) < 1e-16) break;
  }
  return h;
}

// Regularised incomplete beta I_x(a, b).
double beta_i(double a, double b, double x) {
  if (x <= 0.0) return 0.0;
  if (x >= 1.0) return 1.0;
  const double front =
      std::exp(std::lgamma(a + b) - std::lgamma(a) - std::lgamma(b) + a * std::log(x) + b * std::log1p(-x));
  if (x < (a + 1.0) / (a + b + 2.0)) return front * beta_cf(a, b, x) / a;
  return 1.0 - front * beta_cf(b, a, 1.0 - x) / b;
}

// Calls row(t) for every t ≥ `lags` whose lags t − 1 … t − lags lie in t's own stretch (see Breaks), in
// ascending order: each stretch [s, e) gives t = s + lags … e − 1.
template <class Row>
void for_each_regressed(Eigen::Index n, const Breaks& breaks, int lags, Row&& row) {
  Eigen::Index start = 0;
  for (std::size_t b = 0; b <= breaks.size(); ++b) {
    const Eigen::Index end = b < breaks.size() ? breaks[b] : n;
    for (Eigen::Index t = start + lags; t < end; ++t) row(t);
    start = end;
  }
}

// Upper-triangular R of the QR factorisation of the lagged matrix [y_{t−1} … y_{t−k}, y_t] over the rows
// for_each_regressed gives with k lags, accumulated block by block (TSQR) so memory stays O(k²) for any N.
Eigen::MatrixXd lagged_r(const SeriesRef& y, int k, const Breaks& breaks) {
  const Eigen::Index block = 4096, cols = k + 1;
  Eigen::MatrixXd r = Eigen::MatrixXd::Zero(0, cols);
  Eigen::MatrixXd stack(block + cols, cols);
  Eigen::Index filled = 0;
  const auto fold = [&] {
    stack.topRows(r.rows()) = r;
    r = detail::householder_r(stack.topRows(r.rows() + filled));
    filled = 0;
  };
  for_each_regressed(y.size(), breaks, k, [&](Eigen::Index t) {
    const Eigen::Index i = r.rows() + filled;
    for (int j = 0; j < k; ++j) stack(i, j) = y[t - 1 - j];
    stack(i, k) = y[t];
    if (++filled == block) fold();
  });
  if (filled > 0) fold();
  return r;
}

}  // namespace

// NaN and a negative df otherwise came back as a number (NaN, or 1 for df < 0) with no sign of the misuse.
double chi2_sf(double x, double df) {
  detail::require(!std::isnan(x), "chi2_sf: x", x, "a number (not NaN)");
  detail::require_positive("chi2_sf: df", df);
  if (std::isinf(x)) return x > 0.0 ? 0.0 : 1.0;
  return gamma_q(0.5 * df, 0.5 * x);
}

double f1_sf(double x, double df) {
  detail::require(!std::isnan(x), "f1_sf: x", x, "a number (not NaN)");
  detail::require_positive("f1_sf: df", df);
  if (x <= 0.0) return 1.0;
  return beta_i(0.5 * df, 0.5, df / (df + x));
}

double f_sf(double x, double d1, double d2) {
  detail::require(!std::isnan(x), "f_sf: x", x, "a number (not NaN)");
  detail::require_positive("f_sf: d1", d1);
  detail::require(d2 > 0.0, "f_sf: d2", d2, "> 0 (+inf: σ known exactly)");
  if (x <= 0.0) return 1.0;
  if (std::isinf(x)) return 0.0;
  if (std::isinf(d2)) return chi2_sf(d1 * x, d1);
  return beta_i(0.5 * d2, 0.5 * d1, d2 / (d2 + d1 * x));
}

namespace detail {

void check(const ArOptions& o) {
  const std::string s = "ArOptions::";
  require_int(o.max_order >= 0, s + "max_order", o.max_order, "≥ 0");
  require_int(o.order >= -1, s + "order", o.order, "≥ 0, or −1 to choose by AIC");
  require_int(o.init_samples >= 0, s + "init_samples", o.init_samples, "≥ 0 (raised to 2 p when smaller)");
  require(o.forgetting > 0.0 && o.forgetting <= 1.0, s + "forgetting", o.forgetting, "a value in (0, 1]");
  require_int(o.whiteness_lags >= 0, s + "whiteness_lags", o.whiteness_lags, "≥ 0 (0: max(10, 2 p))");
  require_open_unit(s + "significance", o.significance);
}

void check(const PreprocessOptions& o) {
  const std::string s = "PreprocessOptions::";
  require_int(o.subseries >= 3, s + "subseries", o.subseries, "≥ 3");
  require_positive(s + "threshold", o.threshold);
  require_int(o.trend_degree >= 0, s + "trend_degree", o.trend_degree, "≥ 0");
  require_open_unit(s + "significance", o.significance);
}

}  // namespace detail

void check_series(const SeriesRef& series, const std::string& name, Eigen::Index min_length,
                  const std::string& purpose) {
  if (series.size() < min_length) {
    std::ostringstream msg;
    msg << name << ": " << series.size() << " samples, need at least " << min_length << " " << purpose;
    throw Error(msg.str());
  }
  for (Eigen::Index i = 0; i < series.size(); ++i) {
    if (!std::isfinite(series[i])) {
      std::ostringstream msg;
      msg << name << ": sample " << i << " is " << series[i] << " (NaN/Inf not allowed)";
      throw Error(msg.str());
    }
  }
}

void check_breaks(const Breaks& breaks, Eigen::Index n, const std::string& name) {
  for (std::size_t i = 0; i < breaks.size(); ++i) {
    if (breaks[i] < 1 || breaks[i] >= n || (i > 0 && breaks[i] <= breaks[i - 1])) {
      std::ostringstream msg;
      msg << name << ": break " << i << " at sample " << breaks[i] << " is not a sample index in 1 … " << n - 1
          << " after the previous break (gaps are the ascending indices of the first sample after each)";
      throw Error(msg.str());
    }
  }
}

Eigen::Index regressed_rows(Eigen::Index n, const Breaks& breaks, int lags) {
  Eigen::Index count = 0;
  for_each_regressed(n, breaks, lags, [&](Eigen::Index) { ++count; });
  return count;
}

Eigen::Index stretch_start(const Breaks& breaks, Eigen::Index t) {
  const auto after = std::upper_bound(breaks.begin(), breaks.end(), t);
  return after == breaks.begin() ? 0 : *(after - 1);
}

Eigen::VectorXd difference_within(const SeriesRef& x, const Breaks& breaks, Breaks* shifted) {
  check_breaks(breaks, x.size(), "breaks");
  Eigen::VectorXd d(std::max<Eigen::Index>(0, x.size() - static_cast<Eigen::Index>(breaks.size()) - 1));
  if (shifted) shifted->clear();
  Eigen::Index out = 0, start = 0;
  for (std::size_t b = 0; b <= breaks.size(); ++b) {
    const Eigen::Index end = b < breaks.size() ? breaks[b] : x.size();
    if (shifted && out > 0 && end - start > 1 && (shifted->empty() || shifted->back() < out)) shifted->push_back(out);
    for (Eigen::Index t = start + 1; t < end; ++t) d[out++] = x[t] - x[t - 1];
    start = end;
  }
  return d;
}

Eigen::VectorXd zero_mean(const SeriesRef& x, double* mean) {
  check_series(x, "series", 1, "to remove the mean");
  const double m = x.mean();
  if (mean) *mean = m;
  return x.array() - m;
}

Eigen::VectorXd difference(const SeriesRef& x, int order) {
  if (order < 0) throw Error("difference: order " + std::to_string(order) + " is negative");
  check_series(x, "series", order + 1, "to difference " + std::to_string(order) + " times");
  Eigen::VectorXd d = x;
  for (int k = 0; k < order; ++k) d = (d.tail(d.size() - 1) - d.head(d.size() - 1)).eval();
  return d;
}

Eigen::VectorXd remove_trend(const SeriesRef& x, int degree) {
  if (degree < 0) throw Error("remove_trend: degree " + std::to_string(degree) + " is negative");
  check_series(x, "series", degree + 2, "to remove a degree-" + std::to_string(degree) + " trend");
  const Eigen::Index n = x.size();
  // Index scaled to [−1, 1] keeps the Vandermonde matrix well conditioned.
  Eigen::MatrixXd v(n, degree + 1);
  for (Eigen::Index i = 0; i < n; ++i) {
    const double s = n > 1 ? 2.0 * i / (n - 1) - 1.0 : 0.0;
    double p = 1.0;
    for (int j = 0; j <= degree; ++j, p *= s) v(i, j) = p;
  }
  const Eigen::VectorXd coef = detail::least_squares_qr(v, x);
  return x - v * coef;
}

ReverseArrangementResult reverse_arrangement(const SeriesRef& x, int subseries, double threshold) {
  if (subseries < 3) throw Error("reverse_arrangement: subseries = " + std::to_string(subseries) + ", need ≥ 3");
  if (!(std::isfinite(threshold) && threshold > 0.0))
    throw Error("reverse_arrangement: threshold " + detail::num(threshold) + ", need a finite |u| > 0 (1.96: 5 %)");
  check_series(x, "series", 2 * static_cast<Eigen::Index>(subseries),
               "for " + std::to_string(subseries) + " sub-series of ≥ 2 samples");
  ReverseArrangementResult r;
  const Eigen::Index n = x.size(), l = subseries;
  r.subseries = subseries;
  r.means.resize(l);
  for (Eigen::Index k = 0; k < l; ++k) {
    const Eigen::Index a = k * n / l, b = (k + 1) * n / l;
    r.means[k] = x.segment(a, b - a).mean();
  }
  for (Eigen::Index i = 0; i < l; ++i)
    for (Eigen::Index j = i + 1; j < l; ++j) r.arrangements += r.means[i] > r.means[j];
  const double dl = static_cast<double>(l);
  r.expected = dl * (dl - 1.0) / 4.0;
  r.variance = dl * (2.0 * dl + 5.0) * (dl - 1.0) / 72.0;
  r.u = (static_cast<double>(r.arrangements) - r.expected) / std::sqrt(r.variance);
  r.stationary = std::abs(r.u) < threshold;
  return r;
}

namespace {

// The series less its mean, in units of its largest |value|: skewness, kurtosis and autocorrelations do
// not depend on the scale, and fourth powers of values ≤ 1 cannot overflow (readings of 1e80 gave NaN
// statistics and "not normal" without a word).
Eigen::VectorXd centred_unit(const SeriesRef& x) {
  const double top = x.cwiseAbs().maxCoeff();
  if (!(top > 0.0)) return Eigen::VectorXd::Zero(x.size());
  const Eigen::VectorXd y = x / top;
  return y.array() - y.mean();
}

}  // namespace

NormalityResult normality(const SeriesRef& x, double significance) {
  detail::require_open_unit("normality: significance", significance);
  check_series(x, "series", 3, "for skewness and kurtosis");
  const Eigen::VectorXd centred = centred_unit(x);
  double m2 = 0.0, m3 = 0.0, m4 = 0.0;
  for (Eigen::Index i = 0; i < x.size(); ++i) {
    const double d = centred[i], d2 = d * d;
    m2 += d2;
    m3 += d2 * d;
    m4 += d2 * d2;
  }
  const double n = static_cast<double>(x.size());
  m2 /= n;
  m3 /= n;
  m4 /= n;
  if (!(m2 > 0.0)) throw Error("series: constant (zero variance), skewness and kurtosis are undefined");
  NormalityResult r;
  r.skewness = m3 / std::pow(m2, 1.5);
  r.kurtosis = m4 / (m2 * m2);
  r.jarque_bera = n / 6.0 * (r.skewness * r.skewness + 0.25 * (r.kurtosis - 3.0) * (r.kurtosis - 3.0));
  r.p_value = std::exp(-0.5 * r.jarque_bera);
  r.normal = r.p_value > significance;
  return r;
}

LjungBoxResult ljung_box(const SeriesRef& x, int lags, int model_df, double significance, const Breaks& breaks) {
  if (lags < 1) throw Error("ljung_box: lags = " + std::to_string(lags) + ", need ≥ 1");
  detail::require_int(model_df >= 0, "ljung_box: model_df", model_df, "≥ 0");
  detail::require_open_unit("ljung_box: significance", significance);
  check_series(x, "series", static_cast<Eigen::Index>(lags) + 1, "for " + std::to_string(lags) + " lags");
  check_breaks(breaks, x.size(), "ljung_box: breaks");
  const Eigen::VectorXd d = centred_unit(x);
  const double c0 = d.squaredNorm();
  if (!(c0 > 0.0)) throw Error("series: constant (zero variance), autocorrelations are undefined");
  const Eigen::Index n = d.size();
  LjungBoxResult r;
  r.lags = 0;
  r.model_df = model_df;
  double q = 0.0;
  for (int k = 1; k <= lags; ++k) {
    double product = 0.0;
    Eigen::Index pairs = 0, start = 0;
    for (std::size_t b = 0; b <= breaks.size(); ++b) {  // lag-k pairs within each stretch [start, end)
      const Eigen::Index end = b < breaks.size() ? breaks[b] : n;
      if (end - start > k) {
        product += d.segment(start + k, end - start - k).dot(d.segment(start, end - start - k));
        pairs += end - start - k;
      }
      start = end;
    }
    if (pairs == 0) continue;
    const double rho = product / c0;
    q += rho * rho / static_cast<double>(pairs);
    ++r.lags;
  }
  r.statistic = static_cast<double>(n) * (n + 2.0) * q;
  const int df = r.lags - model_df;
  r.p_value = df > 0 ? chi2_sf(r.statistic, df) : std::numeric_limits<double>::quiet_NaN();
  r.white = df > 0 && r.p_value > significance;
  return r;
}

ArResult fit_ar(const SeriesRef& y, const ArOptions& options) {
  detail::check(options);
  const bool fixed = options.order >= 0;
  const int k = fixed ? options.order : options.max_order;
  check_series(y, "series", 2 * static_cast<Eigen::Index>(k) + 3,
               "for an AR model of order " + std::to_string(k) + (fixed ? "" : " (max_order)"));
  check_breaks(options.breaks, y.size(), "ArOptions::breaks");
  if (!((y.array() != y[0]).any())) throw Error("series: constant (every sample equals " + detail::num(y[0]) +
                                                "), an AR model needs a varying series");
  // Every step is a sum of squares: values whose squares overflow gave σ² = inf, "converged" at order 0.
  detail::require_finite_fit(std::isfinite(y.squaredNorm()), "series", y, "the AR fit");
  ArResult result;
  const Eigen::Index n_total = y.size();
  const Breaks& breaks = options.breaks;
  const Eigen::Index common = regressed_rows(n_total, breaks, k);
  if (common < k + 3)
    throw Error("series: " + std::to_string(common) + " samples lie " + std::to_string(k) +
                " or more samples after the start of their stretch between the " + std::to_string(breaks.size()) +
                " gaps in time, need at least " + std::to_string(k + 3) + " for an AR model of order " +
                std::to_string(k) + (fixed ? "" : " (max_order)") + ": the stretches are too short");

  // Order: AIC on the common sample (t = k … N−1; with breaks, each stretch's rows from its k-th on). SSR
  // of order p is the squared tail of the last column of R of [lags | y] (nested least squares, one QR).
  int p = k;
  if (!fixed) {
    const Eigen::MatrixXd r = lagged_r(y, k, breaks);
    const double n = static_cast<double>(common);
    result.aic.resize(k + 1);
    for (int q = 0; q <= k; ++q) {
      const double ssr = r.col(k).segment(q, r.rows() - q).squaredNorm();
      result.aic[q] = n * std::log(ssr / n) + 2.0 * q;
    }
    result.aic.minCoeff(&p);
    result.order_at_maximum = k > 0 && p == k;
  }
  result.order = p;

  // Coefficients: batch least squares on the first rows, then recursive least squares on the rest.
  const Eigen::Index rows = regressed_rows(n_total, breaks, p);
  Eigen::VectorXd theta = Eigen::VectorXd::Zero(p);
  Eigen::MatrixXd P, spread;  // the RLS's P = (Σ w xxᵀ)⁻¹ and Σ w² xxᵀ (for λ < 1): the covariance's parts
  if (p > 0) {
    // The batch start grows (doubling) until its rows have full rank: a recording that starts with a held or
    // zero stretch longer than init_samples made the whole fit fail although the full regression is well posed.
    Eigen::Index n0 = std::min<Eigen::Index>(rows, std::max(options.init_samples, 2 * p));
    Eigen::MatrixXd x0;
    Eigen::VectorXd y0;
    detail::HouseholderLeastSquares qr;
    for (;;) {
      x0.resize(n0, p);
      y0.resize(n0);
      Eigen::Index i = 0;
      for_each_regressed(n_total, breaks, p, [&](Eigen::Index t) {
        if (i >= n0) return;
        for (int j = 0; j < p; ++j) x0(i, j) = y[t - 1 - j];
        y0[i++] = y[t];
      });
      qr = detail::householder_least_squares(x0, y0);
      const Eigen::MatrixXd& r0 = qr.r;
      const double diag_min = r0.diagonal().cwiseAbs().minCoeff(), diag_max = r0.diagonal().cwiseAbs().maxCoeff();
      if (diag_min > 1e-12 * diag_max) break;
      if (n0 >= rows)
        throw Error("series: the " + std::to_string(rows) + " regression rows of an AR(" + std::to_string(p) +
                    ") model are rank deficient (the series repeats itself exactly), no least-squares fit");
      n0 = std::min<Eigen::Index>(rows, 2 * n0);
    }
    theta = qr.solution;
    const Eigen::MatrixXd r_inv = qr.r.triangularView<Eigen::Upper>().solve(Eigen::MatrixXd::Identity(p, p));
    Eigen::MatrixXd cov = r_inv * r_inv.transpose();  // (X0ᵀX0)⁻¹
    cov = (0.5 * (cov + cov.transpose())).eval();     // exactly symmetric from the start (see below)
    const double lambda = options.forgetting;
    if (lambda < 1.0) spread = qr.r.transpose() * qr.r;  // X0ᵀX0: the start's rows, weighed as one
    Eigen::VectorXd phi(p), g(p);
    Eigen::Index seen = 0;
    for_each_regressed(n_total, breaks, p, [&](Eigen::Index t) {
      if (seen++ < n0) return;  // the batch start's rows
      for (int j = 0; j < p; ++j) phi[j] = y[t - 1 - j];
      g.noalias() = cov * phi;
      const double denom = lambda + phi.dot(g);
      const double err = y[t] - phi.dot(theta);
      theta += g * (err / denom);
      // Rank-one downdate computed on one triangle and mirrored, so cov stays exactly symmetric:
      // g_i (g_j / denom) and g_j (g_i / denom) round differently, the downdate never shrinks the
      // antisymmetric part, and dividing by λ < 1 every step then grows it as λ^−t until it swamps cov.
      for (int j = 0; j < p; ++j)
        for (int i2 = j; i2 < p; ++i2) cov(i2, j) = cov(j, i2) = (cov(i2, j) - g[i2] * g[j] / denom) / lambda;
      if (lambda < 1.0) spread = lambda * lambda * spread + phi * phi.transpose();
    });
    P = cov;
  }
  if (!theta.allFinite())  // 1/λ^t overflowed: a memory of 1/(1 − λ) readings is far too short
    throw Error("fit_ar: forgetting factor " + detail::num(options.forgetting) +
                " forgets too fast (a memory of about " + detail::num(1.0 / (1.0 - options.forgetting)) +
                " readings): the recursive least squares overflowed; use a λ closer to 1");
  result.coefficients = theta;
  result.residuals.resize(rows);
  Breaks residual_breaks;  // where the residuals start a new stretch: the whiteness test must not pair across a gap
  Eigen::Index i = 0, stretch = -1;
  for_each_regressed(n_total, breaks, p, [&](Eigen::Index t) {
    const Eigen::Index start = stretch_start(breaks, t);
    if (i > 0 && start != stretch) residual_breaks.push_back(i);
    stretch = start;
    double pred = 0.0;
    for (int j = 0; j < p; ++j) pred += theta[j] * y[t - 1 - j];
    result.residuals[i++] = y[t] - pred;
  });
  result.sigma2 = result.residuals.squaredNorm() / static_cast<double>(rows);
  detail::require_finite_fit(std::isfinite(result.sigma2), "series", y, "the AR fit");
  result.covariance = p == 0 ? Eigen::MatrixXd(0, 0)
                      : options.forgetting < 1.0 ? Eigen::MatrixXd(result.sigma2 * P * spread * P)
                                                 : Eigen::MatrixXd(result.sigma2 * P);
  result.standard_errors = result.covariance.diagonal().cwiseSqrt();

  const int wanted_lags = options.whiteness_lags > 0 ? options.whiteness_lags : std::max(10, 2 * p);
  const int lags = static_cast<int>(std::min<Eigen::Index>(wanted_lags, std::max<Eigen::Index>(1, rows / 2)));
  if (result.sigma2 > 0.0)
    result.whiteness = ljung_box(result.residuals, lags, p, options.significance, residual_breaks);

  Summary& s = result.summary;
  s.samples = static_cast<std::size_t>(n_total);
  s.iterations = static_cast<int>(rows);
  s.cost = result.sigma2;
  s.residual_rms = std::sqrt(result.sigma2);
  s.converged = true;
  std::ostringstream msg;
  // Ljung–Box needs more lags than the model's p degrees of freedom; the cap of (N − p)/2 lags can leave
  // fewer, and then whiteness is untested (p-value NaN), not rejected.
  const bool tested = result.sigma2 > 0.0 && result.whiteness.lags > p;
  msg << "AR(" << p << ")" << (fixed ? " (fixed order)" : " by AIC") << ", sigma2 " << result.sigma2;
  if (tested)
    msg << ", Ljung-Box p " << result.whiteness.p_value;
  else if (result.sigma2 > 0.0)
    msg << ", whiteness not tested";
  s.message = msg.str();
  if (result.order_at_maximum)
    s.warnings.push_back("AIC chose the maximum order " + std::to_string(k) +
                         ": the noise may have longer memory than max_order allows");
  const int tested_lags = result.whiteness.lags;  // with breaks, lags no stretch is long enough for are left out
  if (result.sigma2 > 0.0 && !tested)
    s.warnings.push_back(
        "residual whiteness could not be tested: " +
        (tested_lags < lags ? "the stretches between gaps in time allow only " + std::to_string(tested_lags) +
                                  " Ljung-Box lags"
         : lags < wanted_lags ? std::to_string(rows) + " residuals allow only " + std::to_string(lags) + " Ljung-Box lags"
                              : "whiteness_lags = " + std::to_string(lags)) +
        ", the test needs more than the AR order " + std::to_string(p) +
        (tested_lags < wanted_lags ? " (more samples or a lower order)" : ""));
  else if (tested && !result.whiteness.white)
    s.warnings.push_back("residuals are not white (Ljung-Box p = " + detail::num(result.whiteness.p_value) +
                         "): the AR model is rejected by seed 001's S3.3 check");
  return result;
}

PreprocessResult preprocess(const SeriesRef& x, const PreprocessOptions& options) {
  detail::check(options);
  // Enough for the test on the twice-differenced series: N − 2 ≥ 2 l.
  check_series(x, "series", 2 * static_cast<Eigen::Index>(options.subseries) + 2,
               "for the stationarity test on " + std::to_string(options.subseries) + " sub-series");
  check_breaks(options.breaks, x.size(), "PreprocessOptions::breaks");
  Breaks once;
  if (difference_within(difference_within(x, options.breaks, &once), once).size() < 2 * options.subseries)
    throw Error("series: " + std::to_string(x.size()) + " samples in " + std::to_string(options.breaks.size() + 1) +
                " stretches between gaps in time leave fewer than " + std::to_string(2 * options.subseries) +
                " second differences for the stationarity test on " + std::to_string(options.subseries) +
                " sub-series");
  if (!((x.array() != x[0]).any()))
    throw Error("series: constant (every sample equals " + detail::num(x[0]) + "), nothing to model");
  PreprocessResult r;
  const Eigen::VectorXd z = zero_mean(x, &r.mean);
  Breaks breaks1;
  Eigen::VectorXd d1 = difference_within(z, options.breaks, &breaks1);
  r.stationarity = reverse_arrangement(d1, options.subseries, options.threshold);
  Summary& s = r.summary;
  if (r.stationarity.stationary) {
    r.series = std::move(d1);
    r.differences = 1;
    r.stationarity_after = r.stationarity;
  } else {
    r.series = remove_trend(difference_within(d1, breaks1), options.trend_degree);
    r.differences = 2;
    r.stationarity_after = reverse_arrangement(r.series, options.subseries, options.threshold);
  }
  if (!((r.series.array() != r.series[0]).any()))
    throw Error("series: its differences are constant (a pure polynomial trend), the noise model needs variation");
  r.normality = normality(r.series, options.significance);
  s.samples = static_cast<std::size_t>(x.size());
  s.converged = r.stationarity_after.stationary;
  std::ostringstream msg;
  msg << "differenced " << r.differences << "x, reverse arrangement u = " << r.stationarity.u;
  if (r.differences == 2) msg << " (after: " << r.stationarity_after.u << ")";
  msg << ", skewness " << r.normality.skewness << ", kurtosis " << r.normality.kurtosis;
  s.message = msg.str();
  if (!r.stationarity_after.stationary)
    s.warnings.push_back("the series is not stationary even after differencing twice and removing a trend (u = " +
                         detail::num(r.stationarity_after.u) + ")");
  if (!r.normality.normal)
    s.warnings.push_back("the stationary series is not normal (Jarque-Bera p = " +
                         detail::num(r.normality.p_value) + ", skewness " + detail::num(r.normality.skewness) +
                         ", kurtosis " + detail::num(r.normality.kurtosis) + ")");
  return r;
}

}  // namespace fluxcal
