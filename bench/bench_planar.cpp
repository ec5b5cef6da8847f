// bench_planar — Google Benchmark of the planar (2-D) calibration, fluxcal::fit_planar.
//
// What it measures, for N = 1e3, 1e5 simulated readings (seeded; generated once, outside the timed loops):
//   BM_PlanarSym           shape symmetric, one horizontal field: both starts (direct ellipse fit: one moment
//                          pass; twostep_2d: its passes), Levenberg–Marquardt (a pass per trial step), the noise-bias
//                          solve, the covariance and one statistics pass.
//   BM_PlanarDiagonal      the same with per-axis gains (what shape "auto" adds).
//   BM_PlanarCircle        the same with one gain.
//   BM_PlanarRelative      shape symmetric without a field magnitude (det A = 1).
//   BM_PlanarNoBias        shape symmetric without the noise-bias solve: what that solve costs.
// calibrate_planar(shape="auto") runs the three shapes. Items processed = readings, so the report shows readings/s.
//
// Readings: a vehicle turning 20 times at an uneven rate in a 20 µT horizontal field, offset (12, −7), a soft iron
// with gains 1.12/0.90 rotated 30° from the sensor axes, noise σ = 0.1 µT (0.5 %) per axis.
#include "fluxcal/planar.hpp"

#include <benchmark/benchmark.h>

#include <cmath>
#include <cstdint>
#include <map>
#include <random>
#include <utility>

namespace {

const fluxcal::Readings2D& readings(std::int64_t n) {
  static std::map<std::int64_t, fluxcal::Readings2D> cache;
  auto it = cache.find(n);
  if (it != cache.end()) return it->second;
  std::mt19937_64 rng(19980812u + static_cast<std::uint64_t>(n));
  std::normal_distribution<double> gauss(0.0, 1.0);
  std::uniform_real_distribution<double> speed(0.2, 1.8);
  const Eigen::Matrix2d R = Eigen::Rotation2Dd(M_PI / 6.0).toRotationMatrix();
  const Eigen::Matrix2d W = R * Eigen::Vector2d(1.12, 0.90).asDiagonal() * R.transpose();
  const Eigen::Vector2d b(12.0, -7.0);
  Eigen::VectorXd psi(n);
  double total = 0.0;
  for (std::int64_t k = 0; k < n; ++k) psi(k) = total += speed(rng);
  psi *= 2.0 * M_PI * 20.0 / total;
  fluxcal::Readings2D u(n, 2);
  for (std::int64_t k = 0; k < n; ++k)
    u.row(k) = (W * Eigen::Vector2d(20.0 * std::cos(psi(k)), 20.0 * std::sin(psi(k))) + b +
                0.1 * Eigen::Vector2d(gauss(rng), gauss(rng)))
                   .transpose();
  return cache.emplace(n, std::move(u)).first->second;
}

void run(benchmark::State& state, const fluxcal::PlanarOptions& opt) {
  const fluxcal::Readings2D& u = readings(state.range(0));
  for (auto _ : state) {
    fluxcal::PlanarResult r = fluxcal::fit_planar(u, opt);
    benchmark::DoNotOptimize(r.offset.data());
    benchmark::ClobberMemory();
  }
  state.SetItemsProcessed(state.iterations() * state.range(0));
}

fluxcal::PlanarOptions options(fluxcal::PlanarShape shape, double field_norm = 20.0, bool bias = true) {
  fluxcal::PlanarOptions opt;
  opt.shape = shape;
  opt.field_norm = field_norm;
  opt.noise_bias_correction = bias;
  return opt;
}

void BM_PlanarSym(benchmark::State& s) { run(s, options(fluxcal::PlanarShape::symmetric)); }
void BM_PlanarDiagonal(benchmark::State& s) { run(s, options(fluxcal::PlanarShape::diagonal)); }
void BM_PlanarCircle(benchmark::State& s) { run(s, options(fluxcal::PlanarShape::circle)); }
void BM_PlanarRelative(benchmark::State& s) { run(s, options(fluxcal::PlanarShape::symmetric, 0.0)); }
void BM_PlanarNoBias(benchmark::State& s) { run(s, options(fluxcal::PlanarShape::symmetric, 20.0, false)); }

#define FLUXCAL_SIZES ->Arg(1000)->Arg(100000)->Unit(benchmark::kMicrosecond)
BENCHMARK(BM_PlanarSym) FLUXCAL_SIZES;
BENCHMARK(BM_PlanarDiagonal) FLUXCAL_SIZES;
BENCHMARK(BM_PlanarCircle) FLUXCAL_SIZES;
BENCHMARK(BM_PlanarRelative) FLUXCAL_SIZES;
BENCHMARK(BM_PlanarNoBias) FLUXCAL_SIZES;
#undef FLUXCAL_SIZES

}  // namespace

BENCHMARK_MAIN();
