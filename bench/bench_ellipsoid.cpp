// bench_ellipsoid — Google Benchmark of the ellipsoid fit (fluxcal::fit_ellipsoid).
//
// What it measures, for N = 1e3, 1e5, 1e6 simulated readings (seeded; generated once, outside the
// timed loops):
//   BM_FitEllipsoid            fit_ellipsoid with default options (exact_statistics = true):
//                              normalisation + moment accumulation + solve + one statistics pass.
//   BM_FitEllipsoidMomentsOnly fit_ellipsoid with exact_statistics = false (moments only, one pass).
//   BM_MomentsAddRows          EllipsoidMoments::add_rows alone (the accumulation pass).
//   BM_DirectionCoverage       fluxcal::direction_coverage on the corrected fields (computed outside
//                              the loop): the direction binning the exact-statistics pass also does.
//   BM_SumOfSquares            baseline: one plain pass Σ x² over the same N×3 array (the C++
//                              counterpart of NumPy's einsum('ij,ij->', x, x)).
// Items processed = samples, so the report shows samples/s; ns per sample = 1e9 / items_per_second.
//
// Readings: m = W h + b + noise, h uniform on the sphere of radius 50 (µT-like), W a symmetric
// soft-iron matrix, b an offset, noise N(0, 0.05²) per axis.
#include "fluxcal/coverage.hpp"
#include "fluxcal/ellipsoid.hpp"

#include <benchmark/benchmark.h>

#include <cstdint>
#include <map>
#include <random>

namespace {

const fluxcal::Samples& readings(std::int64_t n) {
  static std::map<std::int64_t, fluxcal::Samples> cache;
  auto it = cache.find(n);
  if (it != cache.end()) return it->second;

  std::mt19937_64 rng(20240611u + static_cast<std::uint64_t>(n));
  std::normal_distribution<double> gauss(0.0, 1.0);
  Eigen::Matrix3d W;  // symmetric soft iron
  W << 1.10, 0.05, -0.03,  //
      0.05, 0.92, 0.04,    //
      -0.03, 0.04, 1.03;
  const Eigen::Vector3d b(12.0, -7.5, 3.25);
  const double field = 50.0, noise = 0.05;

  fluxcal::Samples m(n, 3);
  for (std::int64_t i = 0; i < n; ++i) {
    Eigen::Vector3d h(gauss(rng), gauss(rng), gauss(rng));
    h *= field / h.norm();
    const Eigen::Vector3d e(gauss(rng), gauss(rng), gauss(rng));
    m.row(i) = (W * h + b + noise * e).transpose();
  }
  return cache.emplace(n, std::move(m)).first->second;
}

void BM_FitEllipsoid(benchmark::State& state) {
  const fluxcal::Samples& m = readings(state.range(0));
  for (auto _ : state) {
    fluxcal::EllipsoidResult r = fluxcal::fit_ellipsoid(m);
    benchmark::DoNotOptimize(r.calibration.offset.data());
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * state.range(0));
}

void BM_FitEllipsoidMomentsOnly(benchmark::State& state) {
  const fluxcal::Samples& m = readings(state.range(0));
  fluxcal::EllipsoidOptions opt;
  opt.exact_statistics = false;
  for (auto _ : state) {
    fluxcal::EllipsoidResult r = fluxcal::fit_ellipsoid(m, opt);
    benchmark::DoNotOptimize(r.calibration.offset.data());
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * state.range(0));
}

void BM_MomentsAddRows(benchmark::State& state) {
  const fluxcal::Samples& m = readings(state.range(0));
  const auto [centre, scale] = fluxcal::normalisation(m);
  for (auto _ : state) {
    fluxcal::EllipsoidMoments mom(centre, scale);
    mom.add_rows(m);
    benchmark::DoNotOptimize(&mom);
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * state.range(0));
}

void BM_DirectionCoverage(benchmark::State& state) {
  const fluxcal::Samples& m = readings(state.range(0));
  const fluxcal::Samples fields = fluxcal::fit_ellipsoid(m).calibration.apply_rows(m);
  for (auto _ : state) {
    double c = fluxcal::direction_coverage(fields);
    benchmark::DoNotOptimize(c);
  }
  state.SetItemsProcessed(state.iterations() * state.range(0));
}

void BM_SumOfSquares(benchmark::State& state) {
  const fluxcal::Samples& m = readings(state.range(0));
  for (auto _ : state) {
    double s = m.squaredNorm();
    benchmark::DoNotOptimize(s);
  }
  state.SetItemsProcessed(state.iterations() * state.range(0));
}

#define FLUXCAL_SIZES ->Arg(1000)->Arg(100000)->Arg(1000000)->Unit(benchmark::kMicrosecond)
BENCHMARK(BM_FitEllipsoid) FLUXCAL_SIZES;
BENCHMARK(BM_FitEllipsoidMomentsOnly) FLUXCAL_SIZES;
BENCHMARK(BM_MomentsAddRows) FLUXCAL_SIZES;
BENCHMARK(BM_DirectionCoverage) FLUXCAL_SIZES;
BENCHMARK(BM_SumOfSquares) FLUXCAL_SIZES;
#undef FLUXCAL_SIZES

}  // namespace

BENCHMARK_MAIN();
