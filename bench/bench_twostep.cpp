// bench_twostep — Google Benchmark of the TWOSTEP solvers (fluxcal::twostep_2d, fluxcal::twostep).
//
// What it measures, for N = 1e3, 1e5 simulated readings (seeded; generated once, outside the timed
// loops):
//   BM_TwoStep2D            twostep_2d with default options: one-pass first step + Gauss–Newton
//                           refinement (a pass over the data per iteration) + one statistics pass.
//   BM_TwoStep2DClosedForm  twostep_2d with refine = false: first step + statistics pass.
//   BM_TwoStep              twostep (3-D) with default options: moment pass + centred first step +
//                           Fisher scoring on the moments (O(1) per iteration) + statistics and
//                           direction-coverage pass.
//   BM_TwoStepFirstStep     twostep with max_iterations = 0 (first step only), same passes.
//   BM_TwoStepFieldNorms    twostep with each reading's field magnitude (changing by ±2 %): the same, plus the
//                           weighted scatter's pass and the first step's misfit pass.
// Items processed = readings, so the report shows readings/s.
//
// 2-D readings: biaxial sensor, offset (0.005, −0.0035), gains (1.0302, 0.9796), field directions
// uniform, magnitudes uniform in [0.05, 0.2] (varying currents), noise σ = 1.5e-4 per axis.
// 3-D readings: m = W h + b + noise, h uniform on the sphere of radius 50, W symmetric soft iron,
// noise σ = 0.5 (1 % of the field) per axis.
#include "fluxcal/twostep.hpp"

#include <benchmark/benchmark.h>

#include <cmath>
#include <cstdint>
#include <map>
#include <utility>
#include <random>

namespace {

struct Data2D {
  fluxcal::Readings2D readings;
  Eigen::VectorXd norms;
};

const Data2D& data_2d(std::int64_t n) {
  static std::map<std::int64_t, Data2D> cache;
  auto it = cache.find(n);
  if (it != cache.end()) return it->second;
  std::mt19937_64 rng(20170612u + static_cast<std::uint64_t>(n));
  std::normal_distribution<double> gauss(0.0, 1.0);
  std::uniform_real_distribution<double> angle(0.0, 2.0 * M_PI), magnitude(0.05, 0.2);
  const Eigen::Vector2d b(0.005, -0.0035), gamma(1.0302, 0.9796);
  Data2D d{fluxcal::Readings2D(n, 2), Eigen::VectorXd(n)};
  for (std::int64_t i = 0; i < n; ++i) {
    const double a = angle(rng), h = magnitude(rng);
    d.readings.row(i) =
        (gamma.cwiseProduct(Eigen::Vector2d(h * std::cos(a), h * std::sin(a))) + b +
         1.5e-4 * Eigen::Vector2d(gauss(rng), gauss(rng)))
            .transpose();
    d.norms(i) = h;
  }
  return cache.emplace(n, std::move(d)).first->second;
}

// The field's magnitude at reading i of n: 50, or changing by ±2 % (a slow sine over the log).
double field_3d(std::int64_t i, std::int64_t n, bool changing) {
  return changing ? 50.0 * (1.0 + 0.02 * std::sin(6.0 * M_PI * static_cast<double>(i) / static_cast<double>(n)))
                  : 50.0;
}

const fluxcal::Samples& data_3d(std::int64_t n, bool changing = false) {
  static std::map<std::pair<std::int64_t, bool>, fluxcal::Samples> cache;
  auto it = cache.find({n, changing});
  if (it != cache.end()) return it->second;
  std::mt19937_64 rng(20020401u + static_cast<std::uint64_t>(n));
  std::normal_distribution<double> gauss(0.0, 1.0);
  Eigen::Matrix3d W;
  W << 1.10, 0.05, -0.03,  //
      0.05, 0.92, 0.04,    //
      -0.03, 0.04, 1.03;
  const Eigen::Vector3d b(12.0, -7.5, 3.25);
  fluxcal::Samples m(n, 3);
  for (std::int64_t i = 0; i < n; ++i) {
    Eigen::Vector3d h(gauss(rng), gauss(rng), gauss(rng));
    h *= field_3d(i, n, changing) / h.norm();
    m.row(i) = (W * h + b + 0.5 * Eigen::Vector3d(gauss(rng), gauss(rng), gauss(rng))).transpose();
  }
  return cache.emplace(std::make_pair(n, changing), std::move(m)).first->second;
}

void BM_TwoStep2D(benchmark::State& state) {
  const Data2D& d = data_2d(state.range(0));
  for (auto _ : state) {
    fluxcal::TwoStep2DResult r = fluxcal::twostep_2d(d.readings, d.norms);
    benchmark::DoNotOptimize(r.offset.data());
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * state.range(0));
}

void BM_TwoStep2DClosedForm(benchmark::State& state) {
  const Data2D& d = data_2d(state.range(0));
  fluxcal::TwoStep2DOptions opt;
  opt.refine = false;
  for (auto _ : state) {
    fluxcal::TwoStep2DResult r = fluxcal::twostep_2d(d.readings, d.norms, opt);
    benchmark::DoNotOptimize(r.offset.data());
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * state.range(0));
}

// The estimate alone (standard_errors off: the moments' one pass); BM_TwoStepWithErrors adds the covariance's pass.
void BM_TwoStep(benchmark::State& state) {
  const fluxcal::Samples& m = data_3d(state.range(0));
  fluxcal::TwoStepOptions opt;
  opt.field_norm = 50.0;
  opt.standard_errors = false;
  for (auto _ : state) {
    fluxcal::TwoStepResult r = fluxcal::twostep(m, opt);
    benchmark::DoNotOptimize(r.calibration.offset.data());
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * state.range(0));
}

void BM_TwoStepWithErrors(benchmark::State& state) {
  const fluxcal::Samples& m = data_3d(state.range(0));
  fluxcal::TwoStepOptions opt;
  opt.field_norm = 50.0;
  for (auto _ : state) {
    fluxcal::TwoStepResult r = fluxcal::twostep(m, opt);
    benchmark::DoNotOptimize(r.standard_errors.data());
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * state.range(0));
}

void BM_TwoStepFirstStep(benchmark::State& state) {
  const fluxcal::Samples& m = data_3d(state.range(0));
  fluxcal::TwoStepOptions opt;
  opt.field_norm = 50.0;
  opt.max_iterations = 0;
  for (auto _ : state) {
    fluxcal::TwoStepResult r = fluxcal::twostep(m, opt);
    benchmark::DoNotOptimize(r.calibration.offset.data());
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * state.range(0));
}

void BM_TwoStepFieldNorms(benchmark::State& state) {
  const std::int64_t n = state.range(0);
  const fluxcal::Samples& m = data_3d(n, true);
  Eigen::VectorXd norms(n);
  for (std::int64_t i = 0; i < n; ++i) norms(i) = field_3d(i, n, true);
  fluxcal::TwoStepOptions opt;
  opt.standard_errors = false;
  for (auto _ : state) {
    fluxcal::TwoStepResult r = fluxcal::twostep(m, norms, opt);
    benchmark::DoNotOptimize(r.calibration.offset.data());
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * state.range(0));
}

#define FLUXCAL_SIZES ->Arg(1000)->Arg(100000)->Unit(benchmark::kMicrosecond)
BENCHMARK(BM_TwoStep2D) FLUXCAL_SIZES;
BENCHMARK(BM_TwoStep2DClosedForm) FLUXCAL_SIZES;
BENCHMARK(BM_TwoStep) FLUXCAL_SIZES;
BENCHMARK(BM_TwoStepWithErrors) FLUXCAL_SIZES;
BENCHMARK(BM_TwoStepFirstStep) FLUXCAL_SIZES;
BENCHMARK(BM_TwoStepFieldNorms) FLUXCAL_SIZES;
#undef FLUXCAL_SIZES

}  // namespace

BENCHMARK_MAIN();
