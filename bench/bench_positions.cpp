// bench_positions — Google Benchmark of the multi-position calibration (fluxcal/positions.hpp).
//
// Scenes (seeded, generated once outside the timed loops): the paper's sensor (U0, K of seed 002, mV
// and mV/nT), field 52200 nT at 52° dip, noise 0.45 mV (≈ 5 nT), accelerometer exact.
//   N = 12:    the twelve positions, tilted by up to 1° (levelled by the accelerometer).
//   N = 1000:  uniformly random attitudes, nominal = true.
// Benchmarks:
//   BM_Linear        calibrate_positions, headings known: levelling + linear least squares + statistics.
//   BM_JointYaw      calibrate_positions with estimate_yaw (Ceres, 12 + N parameters) from nominal headings
//                    turned by up to 2°.
//   BM_ClosedForm    seed 002's sums (N = 12 only).
//   BM_Accelerometer calibrate_accelerometer on N static readings (Ceres, 9 parameters).
//   BM_AlignToGravity align_to_gravity (alignment.hpp) on the true field in the body axes with 5 nT noise and
//                    the accelerometer's readings (N = 1000, 100000: uniformly random attitudes).
// Items processed = positions.
#include "fluxcal/alignment.hpp"
#include "fluxcal/positions.hpp"

#include <benchmark/benchmark.h>

#include <cmath>
#include <cstdint>
#include <map>
#include <random>

namespace {

constexpr double kDeg = M_PI / 180.0;

struct Scene {
  fluxcal::Samples U, acc, body_field;
  std::vector<Eigen::Matrix3d> nominal;
  Eigen::Vector3d field;  // ned
};

const Scene& scene(std::int64_t n) {
  static std::map<std::int64_t, Scene> cache;
  auto it = cache.find(n);
  if (it != cache.end()) return it->second;
  std::mt19937_64 rng(2002u + static_cast<std::uint64_t>(n));
  std::normal_distribution<double> g(0.0, 1.0);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Eigen::Matrix3d K;
  K << 0.08950715, -0.02225698, -0.00046962, 0.00018554, 0.08954021, -0.00008744, 0.00041184, 0.00018746,
      0.08925137;
  const Eigen::Vector3d U0(-497.08827, 266.96974, -55.90444);
  Scene s;
  s.field = Eigen::Vector3d(52200.0 * std::cos(52 * kDeg), 0.0, 52200.0 * std::sin(52 * kDeg));
  s.U.resize(n, 3);
  s.acc.resize(n, 3);
  s.body_field.resize(n, 3);
  const auto twelve = fluxcal::twelve_positions(fluxcal::Frame::ned);
  for (std::int64_t i = 0; i < n; ++i) {
    Eigen::Matrix3d nominal, truth;
    if (n == 12) {
      nominal = twelve[static_cast<std::size_t>(i)];
      truth = Eigen::AngleAxisd(1.0 * kDeg * u(rng), Eigen::Vector3d(u(rng), u(rng), 0.0).normalized()) * nominal;
    } else {
      nominal = Eigen::Quaterniond(g(rng), g(rng), g(rng), g(rng)).normalized().toRotationMatrix();
      truth = nominal;
    }
    truth = fluxcal::heading_rotation(2.0 * kDeg * u(rng), fluxcal::Frame::ned) * truth;
    s.nominal.push_back(nominal);
    s.U.row(i) = (U0 + K * truth.transpose() * s.field + 0.45 * Eigen::Vector3d(g(rng), g(rng), g(rng))).transpose();
    s.acc.row(i) = (9.80665 * truth.transpose() * fluxcal::local_up(fluxcal::Frame::ned)).transpose();
    s.body_field.row(i) = (truth.transpose() * s.field + 5.0 * Eigen::Vector3d(g(rng), g(rng), g(rng))).transpose();
  }
  return cache.emplace(n, std::move(s)).first->second;
}

void BM_Linear(benchmark::State& state) {
  const Scene& s = scene(state.range(0));
  for (auto _ : state) benchmark::DoNotOptimize(fluxcal::calibrate_positions(s.U, s.acc, s.nominal, s.field));
  state.SetItemsProcessed(state.iterations() * state.range(0));
}

void BM_JointYaw(benchmark::State& state) {
  const Scene& s = scene(state.range(0));
  fluxcal::PositionsOptions o;
  o.estimate_yaw = true;
  for (auto _ : state) benchmark::DoNotOptimize(fluxcal::calibrate_positions(s.U, s.acc, s.nominal, s.field, o));
  state.SetItemsProcessed(state.iterations() * state.range(0));
}

void BM_ClosedForm(benchmark::State& state) {
  const Scene& s = scene(12);
  for (auto _ : state) benchmark::DoNotOptimize(fluxcal::twelve_position_closed_form(s.U, 41134.0));
  state.SetItemsProcessed(state.iterations() * 12);
}

void BM_Accelerometer(benchmark::State& state) {
  const Scene& s = scene(state.range(0));
  for (auto _ : state) benchmark::DoNotOptimize(fluxcal::calibrate_accelerometer(s.acc));
  state.SetItemsProcessed(state.iterations() * state.range(0));
}

void BM_AlignToGravity(benchmark::State& state) {
  const Scene& s = scene(state.range(0));
  for (auto _ : state) benchmark::DoNotOptimize(fluxcal::align_to_gravity(s.body_field, s.acc));
  state.SetItemsProcessed(state.iterations() * state.range(0));
}

BENCHMARK(BM_Linear)->Arg(12)->Arg(1000)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_JointYaw)->Arg(12)->Arg(1000)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_ClosedForm)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_Accelerometer)->Arg(12)->Arg(1000)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_AlignToGravity)->Arg(1000)->Arg(100000)->Unit(benchmark::kMicrosecond);

}  // namespace

BENCHMARK_MAIN();
