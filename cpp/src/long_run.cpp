// Standard errors when the readings are correlated in time (long_run.hpp).
#include "long_run.hpp"

#include "fluxcal/timeseries.hpp"
#include "linalg.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <vector>

namespace fluxcal::detail {
namespace {

double lag1_autocorrelation(const Eigen::VectorXd& x) {
  const Eigen::VectorXd c = x.array() - x.mean();
  const double denominator = c.squaredNorm();
  const Eigen::Index n = c.size();
  return denominator > 0.0 ? c.head(n - 1).dot(c.tail(n - 1)) / denominator : 0.0;
}

// Bartlett bandwidth of one score column: the Politis & White (2004) automatic block length of the
// circular bootstrap, with the correction of Patton, Politis & White (2009), computed as in arch's
// optimal_block_length. It has the form of Andrews' (1991) optimal Bartlett bandwidth,
// (1.5 (G/ĝ0)² N)^(1/3), but estimates G = Σ λ(k/M)|k|γ_k and the long-run variance ĝ0 = Σ λ(k/M)γ_k
// nonparametrically (flat-top window λ, M from the first run of insignificant autocorrelations):
// an AR(1) plug-in misses the long memory of real recordings and gave 0.6× the bootstrap spread.
double block_length(const Eigen::VectorXd& x) {
  const Eigen::Index n = x.size();
  const Eigen::VectorXd e = x.array() - x.mean();
  const double nd = static_cast<double>(n);
  const double b_max = std::ceil(std::min(3.0 * std::sqrt(nd), nd / 3.0));
  const int kn = std::max(5, static_cast<int>(std::log10(nd)));
  const int m_max = static_cast<int>(std::ceil(std::sqrt(nd))) + kn;
  const double critical = 2.0 * std::sqrt(std::log10(nd) / nd);
  std::vector<double> acv(static_cast<std::size_t>(m_max) + 1), abs_acorr(acv.size());
  // v1, v2 (sums of squares of the lagged pieces) from the total: O(1) per lag.
  const double total = e.squaredNorm();
  double head_sq = total, tail_sq = total;  // Σ e² without the last / the first i + 1 values
  int first_quiet = -1;
  for (int i = 0; i <= m_max && i < n - 1; ++i) {
    head_sq -= e(n - 1 - i) * e(n - 1 - i);
    tail_sq -= e(i) * e(i);
    const double cross = e.tail(n - i).dot(e.head(n - i));
    acv[static_cast<std::size_t>(i)] = cross / nd;
    abs_acorr[static_cast<std::size_t>(i)] =
        tail_sq > 0.0 && head_sq > 0.0 ? std::abs(cross) / std::sqrt(tail_sq * head_sq) : 0.0;
    if (i >= kn && first_quiet < 0 &&
        std::all_of(abs_acorr.begin() + (i - kn), abs_acorr.begin() + i, [&](double r) { return r < critical; }))
      first_quiet = i - kn;
    if (first_quiet >= 0 && i >= 2 * std::max(first_quiet, 1)) break;  // the window needs no more lags
  }
  const int m = std::min(first_quiet >= 0 ? 2 * std::max(first_quiet, 1) : m_max, std::min<int>(m_max, static_cast<int>(n) - 2));
  double g = 0.0, long_run = acv[0];
  for (int k = 1; k <= m; ++k) {
    const double lam = k <= 0.5 * m ? 1.0 : 2.0 * (1.0 - static_cast<double>(k) / m);
    g += 2.0 * lam * k * acv[static_cast<std::size_t>(k)];
    long_run += 2.0 * lam * acv[static_cast<std::size_t>(k)];
  }
  if (!(long_run > 0.0)) return b_max;  // no long-run variance left to estimate: take the widest window
  return std::min(std::cbrt(1.5 * g * g / (long_run * long_run)) * std::cbrt(nd), b_max);
}

// The Newey–West bandwidth over all score columns: the cube root of the mean cubed block length
// (Andrews' rule averages (G/ĝ0)², i.e. b³, over the columns).
int bandwidth(const Eigen::MatrixXd& g) {
  double cubes = 0.0;
  int columns = 0;
  for (Eigen::Index a = 0; a < g.cols(); ++a) {
    if (!((g.col(a).array() - g.col(a).mean()).matrix().squaredNorm() > 0.0)) continue;
    const double b = block_length(g.col(a));
    cubes += b * b * b;
    ++columns;
  }
  const double lags = columns ? std::ceil(std::cbrt(cubes / columns)) : 1.0;
  return static_cast<int>(std::clamp(lags, 1.0, static_cast<double>(g.rows() - 1)));
}

// Long-run covariance of the scores, Γ0 + Σ_{l=1..L} (1 − l/(L+1)) (Γ_l + Γ_lᵀ), Γ_l = Σ_i g_i g_{i−l}ᵀ,
// computed in O(N p²) rather than O(N L p²): with g zero outside 0…N−1, the moving sums
// s_t = g_{t−L} + … + g_t (t = 0 … N+L−1) satisfy Σ_t s_t s_tᵀ = Σ_{|l|≤L} (L + 1 − |l|) Γ_l exactly,
// and the result is positive semi-definite by construction.
Eigen::MatrixXd newey_west(const Eigen::MatrixXd& g, int lags) {
  const Eigen::Index n = g.rows(), p = g.cols();
  // The moving sums are collected a chunk at a time and added with one symmetric rank-k update each:
  // a rank-1 update per reading costs ~3× more for p = 12.
  constexpr Eigen::Index kChunk = 2048;
  Eigen::MatrixXd S = Eigen::MatrixXd::Zero(p, p);
  Eigen::MatrixXd chunk(p, kChunk);
  Eigen::VectorXd window = Eigen::VectorXd::Zero(p);
  Eigen::Index filled = 0;
  for (Eigen::Index t = 0; t < n + lags; ++t) {
    if (t < n) window += g.row(t).transpose();
    if (t - lags - 1 >= 0) window -= g.row(t - lags - 1).transpose();
    chunk.col(filled++) = window;
    if (filled == kChunk || t == n + lags - 1) {
      S.selfadjointView<Eigen::Lower>().rankUpdate(chunk.leftCols(filled));
      filled = 0;
    }
  }
  return Eigen::MatrixXd(S.selfadjointView<Eigen::Lower>()) / (lags + 1.0);
}

}  // namespace

ScaledInverse scaled_inverse(const Eigen::MatrixXd& F) {
  constexpr double kTiny = 1e-300;  // guards the diagonal against exact zeros; the eigenvalues' floor
  const Eigen::Index p = F.rows();
  const Eigen::VectorXd d = F.diagonal().cwiseMax(kTiny).cwiseSqrt().cwiseInverse();
  const Eigen::MatrixXd scaled = d.asDiagonal() * F * d.asDiagonal();
  const SymmetricEigen<Eigen::Dynamic> eig = symmetric_eigen(scaled);
  const Eigen::VectorXd& lam = eig.values;
  const double floor = lam(p - 1) * kTiny;
  const Eigen::VectorXd inv = lam.cwiseMax(floor).cwiseInverse();
  ScaledInverse out;
  out.inverse = d.asDiagonal() * eig.vectors * inv.asDiagonal() * eig.vectors.transpose() * d.asDiagonal();
  out.condition = lam(0) > 0.0 ? lam(p - 1) / lam(0) : std::numeric_limits<double>::infinity();
  out.singular = lam(0) <= floor;
  return out;
}

// Long-run covariance of the scores, prewhitened (Andrews & Monahan 1992) with a diagonal first-order
// autoregression: each column's lag-1 coefficient a_j = Σ g_t g_{t−1} / Σ g_{t−1}² (clipped to ±0.97, as
// they recommend), Newey–West over the whitened e_t = g_t − a ∘ g_{t−1} (t ≥ 1) with its own bandwidth,
// recoloured S = D S* D, D = diag(1/(1 − a_j)). The recolouring is exact at frequency zero for any a; the
// whitened scores are short-memory, so a few lags do. Without it the Bartlett sums on the fitted scores
// (which the fit projects onto Σ g = 0) lost the low frequencies over the long bandwidth that AR(1) noise
// with φ = 0.9–0.95 needs: the offsets' errors were 1.5× the reported SEs (|z| > 3 in 5.8 % of fits);
// prewhitened 1.0–1.1×. Real recordings' whitened scores keep their long memory: their bandwidth stays
// long and their SEs move by 0–6 % (offsets) and 0–21 % (matrix), see bench/RESULTS.md.
constexpr double kPrewhiteningClip = 0.97;
// Independent readings' worth per parameter below which the Newey–West errors are said to be uncertain (the
// switch's own rule: a sandwich from fewer than 10 readings per parameter is too noisy to overrule the test).
constexpr double kFewIndependentPerParameter = 10.0;

Eigen::MatrixXd prewhitened_long_run(const Eigen::MatrixXd& g, int& lags) {
  const Eigen::Index n = g.rows(), p = g.cols();
  Eigen::VectorXd a = Eigen::VectorXd::Zero(p);
  for (Eigen::Index j = 0; j < p; ++j) {
    const double den = g.col(j).head(n - 1).squaredNorm();
    if (den > 0.0)
      a(j) = std::clamp(g.col(j).head(n - 1).dot(g.col(j).tail(n - 1)) / den, -kPrewhiteningClip, kPrewhiteningClip);
  }
  const Eigen::MatrixXd e = g.bottomRows(n - 1) - g.topRows(n - 1) * a.asDiagonal();
  lags = bandwidth(e);
  const Eigen::VectorXd d = (1.0 - a.array()).inverse().matrix();
  return d.asDiagonal() * newey_west(e, lags) * d.asDiagonal();
}

// Tests the residuals for correlation in time and, when `mode` says so, replaces the covariance by the
// Newey–West sandwich F⁻¹ S F⁻¹ (F⁻¹ the pseudo-inverse the independent covariance was built from,
// S the prewhitened long-run covariance of the scores).
// `automatic` switches when the residuals fail the Ljung–Box test and the sandwich widens an error, or
// when it widens one by ≥ 1.5× whatever the test says: with orientations that change fast a residual (the noise
// projected on a direction that turns) loses the noise's correlation that the scores (the residual times that
// direction) keep. It does not
// switch to a sandwich that widens nothing (negative correlation is rare, and a small sample's
// sandwich is noisy); `newey_west` reports the sandwich whatever it gives.
std::string correct_for_serial_correlation(Eigen::MatrixXd& covariance, SerialCorrelationReport& rep,
                                           const Eigen::MatrixXd& residuals, const Eigen::MatrixXd& scores,
                                           const Eigen::MatrixXd& Finv, bool singular, SerialCorrelation mode,
                                           double alpha) {
  if (!(alpha > 0.0 && alpha < 1.0))
    throw Error("serial_correlation_alpha: " + std::to_string(alpha) + ", need a significance level in (0, 1)");
  rep.standard_errors_independent = covariance.diagonal().cwiseMax(0.0).cwiseSqrt();
  const Eigen::Index n = residuals.rows(), k = residuals.cols(), p = Finv.rows();
  const int test_lags = static_cast<int>(std::min<Eigen::Index>(20, n / 5));
  if (test_lags < 1 || n <= p) return "";
  double smallest_p = 1.0;
  int tested = 0;
  rep.lag1 = 0.0;
  for (Eigen::Index a = 0; a < k; ++a) {
    const Eigen::VectorXd x = residuals.col(a);
    if (!((x.array() - x.mean()).matrix().squaredNorm() > 0.0)) continue;  // an exact axis: nothing to test
    smallest_p = std::min(smallest_p, ljung_box(x, test_lags).p_value);
    rep.lag1 += lag1_autocorrelation(x);
    ++tested;
  }
  if (tested) rep.lag1 /= tested;
  rep.ljung_box_p = std::min(1.0, smallest_p * tested);  // Bonferroni over the axes
  // The sandwich of a singular F is not defined; the independent covariance already marks the
  // directions the data leave undetermined.
  if (mode == SerialCorrelation::independent || singular) return "";
  int lags = 0;
  const Eigen::MatrixXd S = prewhitened_long_run(scores, lags);
  Eigen::MatrixXd C = Finv * S * Finv * (static_cast<double>(n) / static_cast<double>(n - p));
  C = 0.5 * (C + C.transpose());
  if (!C.allFinite()) return "";
  const Eigen::VectorXd se = C.diagonal().cwiseMax(0.0).cwiseSqrt();
  double widest = 0.0, narrowest = std::numeric_limits<double>::infinity();
  for (Eigen::Index j = 0; j < se.size(); ++j) {
    if (!(rep.standard_errors_independent(j) > 0.0)) continue;
    widest = std::max(widest, se(j) / rep.standard_errors_independent(j));
    narrowest = std::min(narrowest, se(j) / rep.standard_errors_independent(j));
  }
  const bool rejected = rep.ljung_box_p < alpha;
  // a sandwich from fewer than 10 readings per parameter is too noisy to overrule the test on its own
  // (30 independent readings of a 12-parameter vector fit widened an error ≥ 1.5× in 28 of 40 fits)
  const bool steady = n >= 10 * p;
  if (mode == SerialCorrelation::automatic && !((rejected && widest > 1.0) || (steady && widest >= 1.5)))
    return "";
  rep.lags = lags;
  rep.inflation = widest;
  covariance = C;
  std::ostringstream msg;
  msg.precision(2);
  if (rejected)
    msg << "the residuals are correlated in time (lag-1 autocorrelation " << rep.lag1 << ", Ljung-Box p = "
        << rep.ljung_box_p << ": noise correlated in time, or something the model misses)";
  else
    msg << "the scores are correlated in time although the residuals pass the Ljung-Box test (p = " << rep.ljung_box_p
        << "; orientations that change fast hide the correlation from the residuals)";
  msg << ": standard errors are Newey-West (AR(1)-prewhitened) over " << rep.lags << " lags, " << narrowest
      << "-" << widest << "x those for independent readings (rows must be in time order: serial_correlation="
      << "\"independent\", --serial-correlation independent, when they are not)";
  // The widening squared is about how many readings make one independent one's worth. A sandwich from few of them
  // is itself uncertain and tends low: AR(1) noise of φ 0.9 (about 100 readings' worth in 1000 … 5 in 100) left
  // the errors 1.1-1.3x the reported ones in fits of 100-1000 readings.
  const double worth = static_cast<double>(n) / (widest * widest);
  if (worth < kFewIndependentPerParameter * static_cast<double>(p)) {
    msg.precision(2);
    msg << "; the readings hold about " << worth << " independent ones' worth for " << p << " parameters, and "
        << "Newey-West errors from so few tend low (by 10-30 % with AR(1) noise): record for longer";
  }
  return msg.str();
}

}  // namespace fluxcal::detail
