// Samples per second of the AR(p) Kalman filters: double (time-varying and steady-state gain) and
// fixed point (int32 Q-format, both forms), and of fit_ar on 10⁶ samples.
//   build/cpp/bench/bench_kalman --benchmark_min_time=0.5
#include <fluxcal/fixed_kalman.hpp>
#include <fluxcal/kalman.hpp>
#include <fluxcal/timeseries.hpp>

#include <benchmark/benchmark.h>

#include <cmath>
#include <random>

namespace {

constexpr int kSamples = 1'000'000;

Eigen::VectorXd ar_coefficients(int order) {
  // A stable AR(p): 0.6, −0.3, 0.2, then small alternating terms.
  Eigen::VectorXd a = Eigen::VectorXd::Zero(order);
  const double base[] = {0.6, -0.3, 0.2};
  for (int i = 0; i < order; ++i) a[i] = i < 3 ? base[i] : (i % 2 ? -0.02 : 0.02);
  return a;
}

const Eigen::VectorXd& series() {
  static const Eigen::VectorXd y = [] {
    std::mt19937_64 rng(7);
    std::normal_distribution<double> normal;
    Eigen::VectorXd v(kSamples);
    double s1 = 0, s2 = 0, s3 = 0;
    for (int t = 0; t < kSamples; ++t) {
      const double s = 0.6 * s1 - 0.3 * s2 + 0.2 * s3 + std::sqrt(0.5) * normal(rng);
      s3 = s2;
      s2 = s1;
      s1 = s;
      v[t] = s + std::sqrt(0.3) * normal(rng);
    }
    return Eigen::VectorXd(0.9 * v / v.cwiseAbs().maxCoeff());
  }();
  return y;
}

void BM_KalmanDouble(benchmark::State& state) {
  fluxcal::KalmanOptions options;
  options.steady_state = state.range(1) != 0;
  const fluxcal::ArKalman k(ar_coefficients(static_cast<int>(state.range(0))), 0.5 / 4, 0.3 / 4, options);
  const Eigen::VectorXd& y = series();
  for (auto _ : state) benchmark::DoNotOptimize(k.filter(y).filtered.data());
  state.SetItemsProcessed(state.iterations() * kSamples);
}
BENCHMARK(BM_KalmanDouble)->ArgsProduct({{1, 3, 8}, {0, 1}})->ArgNames({"order", "steady"})->Unit(benchmark::kMillisecond);

void BM_KalmanFixed(benchmark::State& state) {
  const int order = static_cast<int>(state.range(0));
  const Eigen::VectorXd a = ar_coefficients(order);
  fluxcal::KalmanOptions options;
  const fluxcal::ArKalman k(a, 0.5 / 4, 0.3 / 4, options);
  const Eigen::VectorXd gain = k.steady_state_gain();
  const Eigen::MatrixXd& p0 = k.initial_covariance();
  fluxcal::FixedArKalmanCoefficients<8> c;
  c.order = order;
  c.format = {30, 30, 29 - static_cast<int>(std::ceil(std::log2(p0.cwiseAbs().maxCoeff())))};
  c.steady_state = state.range(1) != 0;
  c.q = static_cast<std::int32_t>(std::lround(0.5 / 4 * std::ldexp(1.0, c.format.cov_frac_bits)));
  c.r = static_cast<std::int32_t>(std::lround(0.3 / 4 * std::ldexp(1.0, c.format.cov_frac_bits)));
  for (int i = 0; i < order; ++i) {
    c.a[i] = static_cast<std::int32_t>(std::lround(std::ldexp(a[i], 30)));
    c.gain[i] = static_cast<std::int32_t>(std::lround(std::ldexp(gain[i], 30)));
    for (int j = 0; j < order; ++j)
      c.p0[i * order + j] = static_cast<std::int32_t>(std::lround(std::ldexp(p0(i, j), c.format.cov_frac_bits)));
  }
  std::vector<std::int32_t> in(kSamples), out(kSamples);
  const Eigen::VectorXd& y = series();
  for (int i = 0; i < kSamples; ++i) in[i] = static_cast<std::int32_t>(std::lround(std::ldexp(y[i], 30)));
  fluxcal::FixedArKalman<8> f;
  f.configure(c);
  for (auto _ : state) {
    f.reset();
    f.filter(in.data(), out.data(), kSamples);
    benchmark::DoNotOptimize(out.data());
  }
  if (f.overflowed()) state.SkipWithError("overflow");
  state.SetItemsProcessed(state.iterations() * kSamples);
}
BENCHMARK(BM_KalmanFixed)->ArgsProduct({{1, 3, 8}, {0, 1}})->ArgNames({"order", "steady"})->Unit(benchmark::kMillisecond);

void BM_FitAr(benchmark::State& state) {
  fluxcal::ArOptions options;
  options.max_order = static_cast<int>(state.range(0));
  const Eigen::VectorXd& y = series();
  for (auto _ : state) benchmark::DoNotOptimize(fluxcal::fit_ar(y, options).coefficients.data());
  state.SetItemsProcessed(state.iterations() * kSamples);
}
BENCHMARK(BM_FitAr)->Arg(10)->ArgName("max_order")->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
