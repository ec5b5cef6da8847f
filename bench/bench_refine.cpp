// bench_refine — Google Benchmark of the iterative and consistent solvers, N = 1e3 and 1e5:
//   BM_FitEllipsoidALS   adjusted least squares (moments pass + bisection on the adjusted scatter)
//   BM_Refine            Ceres maximum-likelihood refinement (magnitude model) from the ALS fit,
//                        including the covariance (and the Ljung–Box test of the residuals)
//   BM_RefineIndependent / BM_RefineNeweyWest   the same with the covariance forced to assume
//                        independent readings / forced to Newey–West: the cost of the correlation check
//   BM_FitVector         closed-form vector calibration (one pass)
//   BM_RefineVector      Ceres vector-model refinement with a Huber loss
//   BM_RefineTerms       the diagnosis' refit: magnitude model with 12 extra terms (36 feature columns,
//                        slow sinusoids in time times the reading), from the ALS fit and zero terms
// Readings: m = W h + b + noise, |h| = 50, symmetric W, σ = 0.5 (1 % of the field).
#include "fluxcal/ellipsoid.hpp"
#include "fluxcal/refine.hpp"

#include <benchmark/benchmark.h>

#include <cmath>
#include <cstdint>
#include <map>
#include <random>

namespace {

struct Data {
  fluxcal::Samples readings, reference;
};

const Data& data(std::int64_t n) {
  static std::map<std::int64_t, Data> cache;
  auto it = cache.find(n);
  if (it != cache.end()) return it->second;
  std::mt19937_64 rng(17u + static_cast<std::uint64_t>(n));
  std::normal_distribution<double> g(0.0, 1.0);
  Eigen::Matrix3d W;
  W << 1.06, 0.04, -0.03, 0.04, 0.95, 0.02, -0.03, 0.02, 1.01;
  const Eigen::Vector3d b(12.0, -7.5, 3.25);
  Data d{fluxcal::Samples(n, 3), fluxcal::Samples(n, 3)};
  for (std::int64_t i = 0; i < n; ++i) {
    Eigen::Vector3d h(g(rng), g(rng), g(rng));
    h *= 50.0 / h.norm();
    d.reference.row(i) = h.transpose();
    d.readings.row(i) = (W * h + b + 0.5 * Eigen::Vector3d(g(rng), g(rng), g(rng))).transpose();
  }
  return cache.emplace(n, std::move(d)).first->second;
}

fluxcal::EllipsoidOptions als_options() {
  fluxcal::EllipsoidOptions o;
  o.method = fluxcal::EllipsoidMethod::adjusted;
  o.field_norm = 50.0;
  return o;
}

void BM_FitEllipsoidALS(benchmark::State& state) {
  const Data& d = data(state.range(0));
  for (auto _ : state) benchmark::DoNotOptimize(fluxcal::fit_ellipsoid(d.readings, als_options()).calibration.offset);
  state.SetItemsProcessed(state.iterations() * state.range(0));
}

void BM_Refine(benchmark::State& state) {
  const Data& d = data(state.range(0));
  const fluxcal::Calibration start = fluxcal::fit_ellipsoid(d.readings, als_options()).calibration;
  for (auto _ : state) benchmark::DoNotOptimize(fluxcal::refine(start, d.readings).calibration.offset);
  state.SetItemsProcessed(state.iterations() * state.range(0));
}

void refine_with(benchmark::State& state, fluxcal::SerialCorrelation mode) {
  const Data& d = data(state.range(0));
  const fluxcal::Calibration start = fluxcal::fit_ellipsoid(d.readings, als_options()).calibration;
  fluxcal::RefineOptions o;
  o.serial_correlation = mode;
  for (auto _ : state) benchmark::DoNotOptimize(fluxcal::refine(start, d.readings, o).calibration.offset);
  state.SetItemsProcessed(state.iterations() * state.range(0));
}
void BM_RefineIndependent(benchmark::State& state) { refine_with(state, fluxcal::SerialCorrelation::independent); }
void BM_RefineNeweyWest(benchmark::State& state) { refine_with(state, fluxcal::SerialCorrelation::newey_west); }

void BM_FitVector(benchmark::State& state) {
  const Data& d = data(state.range(0));
  for (auto _ : state) benchmark::DoNotOptimize(fluxcal::fit_vector(d.readings, d.reference).calibration.offset);
  state.SetItemsProcessed(state.iterations() * state.range(0));
}

void BM_RefineVector(benchmark::State& state) {
  const Data& d = data(state.range(0));
  const fluxcal::Calibration start = fluxcal::fit_vector(d.readings, d.reference).calibration;
  fluxcal::RefineOptions o;
  o.loss = fluxcal::Loss::huber;
  for (auto _ : state) benchmark::DoNotOptimize(fluxcal::refine_vector(start, d.readings, d.reference, o).calibration.offset);
  state.SetItemsProcessed(state.iterations() * state.range(0));
}

void BM_RefineTerms(benchmark::State& state) {
  const Data& d = data(state.range(0));
  const fluxcal::Calibration start = fluxcal::fit_ellipsoid(d.readings, als_options()).calibration;
  constexpr int kTerms = 12;
  Eigen::MatrixXd features(d.readings.rows(), 3 * kTerms);
  for (Eigen::Index i = 0; i < d.readings.rows(); ++i)
    for (int j = 0; j < kTerms; ++j)
      features.row(i).segment<3>(3 * j) = std::cos(1e-3 * (j + 1) * static_cast<double>(i)) * d.readings.row(i);
  const Eigen::VectorXd zero = Eigen::VectorXd::Zero(kTerms);
  for (auto _ : state)
    benchmark::DoNotOptimize(fluxcal::refine_terms(start, d.readings, features, zero).calibration.offset);
  state.SetItemsProcessed(state.iterations() * state.range(0));
}

#define FLUXCAL_SIZES ->Arg(1000)->Arg(100000)->Unit(benchmark::kMillisecond)
BENCHMARK(BM_FitEllipsoidALS) FLUXCAL_SIZES;
BENCHMARK(BM_Refine) FLUXCAL_SIZES;
BENCHMARK(BM_RefineIndependent) FLUXCAL_SIZES;
BENCHMARK(BM_RefineNeweyWest) FLUXCAL_SIZES;
BENCHMARK(BM_FitVector) FLUXCAL_SIZES;
BENCHMARK(BM_RefineVector) FLUXCAL_SIZES;
BENCHMARK(BM_RefineTerms) FLUXCAL_SIZES;
#undef FLUXCAL_SIZES

}  // namespace

BENCHMARK_MAIN();
