// bench_cable — Google Benchmark of the cable inverse solver (fluxcal::solve_cable).
//
//   BM_CableSolveWarm   one snapshot of a 2-core cable (4 sensors at 90° on 10 mm, conductors at
//                       (−1.7, 0.4) and (2.3, 0.1) mm, ±5 A, noise 1e-8 T), warm-started from positions
//                       0.2 mm off (what a continuous measurement has from its previous snapshot):
//                       one dense Levenberg–Marquardt solve (the default for a warm start) + residuals
//                       + covariance.
//   BM_CableSolveWarmCeres  the same refined by Ceres (options.refiner = ceres).
//   BM_CableSolveCold   the same snapshot from the grid initialisation (9 points per diameter, 6 starts).
//   BM_CableField       the forward model alone (4 sensors, 2 conductors).
//   BM_CableSolveSnapshots/0|1  three snapshots of that cable (currents ×1, −0.6, 0.3) in the Earth's
//                       (25, −30) µT, from the grid: /1 fits the uniform background (options.fit_background),
//                       /0 does not (and misfits) — the background's cost.
//   BM_CableSolveWaveform/S  S snapshots of 50 Hz currents sampled at 1 kHz (10 A, 8 A, 0.3 rad apart), solved
//                       jointly, warm-started (the dense refiner): the Fisher information by blocks above 400
//                       parameters.
#include "fluxcal/cable.hpp"

#include <benchmark/benchmark.h>

#include <cmath>
#include <random>

namespace {

struct Problem {
  fluxcal::CableRing ring;
  fluxcal::ConductorPositions truth{2, 2};
  Eigen::Vector2d currents{5.0, -5.0};
  Eigen::MatrixXd readings{1, 8};
  Problem() {
    ring.angles.resize(4);
    ring.angles << 0.0, M_PI / 2, M_PI, 3 * M_PI / 2;
    ring.radius = 0.010;
    truth << -1.7e-3, 0.4e-3, 2.3e-3, 0.1e-3;
    const auto b = fluxcal::cable_field(ring, truth, currents);
    std::mt19937_64 rng(2017);
    std::normal_distribution<double> g(0.0, 1e-8);
    for (int i = 0; i < 4; ++i) readings(0, 2 * i) = b(i, 0) + g(rng), readings(0, 2 * i + 1) = b(i, 1) + g(rng);
  }
};

// Three snapshots in a uniform field (x radial, y tangential).
struct Snapshots : Problem {
  Eigen::MatrixXd rows{3, 8};
  Snapshots() {
    const double scale[3] = {1.0, -0.6, 0.3};
    const Eigen::Vector2d earth(25e-6, -30e-6);
    for (int s = 0; s < 3; ++s) {
      const auto b = fluxcal::cable_field(ring, truth, currents * scale[s]);
      for (int i = 0; i < 4; ++i) {
        const Eigen::Vector2d r(std::cos(ring.angles(i)), std::sin(ring.angles(i))), t(-r(1), r(0));
        rows(s, 2 * i) = b(i, 0) + r.dot(earth), rows(s, 2 * i + 1) = b(i, 1) + t.dot(earth);
      }
    }
  }
};

const Problem& problem() {
  static const Problem p;
  return p;
}

void BM_CableSolveWarm(benchmark::State& state) {
  const Problem& p = problem();
  fluxcal::CableSolveOptions o;
  o.initial_positions = p.truth;
  o.initial_positions.array() += 0.2e-3;
  for (auto _ : state) benchmark::DoNotOptimize(fluxcal::solve_cable(p.ring, p.readings, o));
}
BENCHMARK(BM_CableSolveWarm)->Unit(benchmark::kMicrosecond);

void BM_CableSolveWarmCeres(benchmark::State& state) {
  const Problem& p = problem();
  fluxcal::CableSolveOptions o;
  o.initial_positions = p.truth;
  o.initial_positions.array() += 0.2e-3;
  o.refiner = fluxcal::CableSolveOptions::Refiner::ceres;
  for (auto _ : state) benchmark::DoNotOptimize(fluxcal::solve_cable(p.ring, p.readings, o));
}
BENCHMARK(BM_CableSolveWarmCeres)->Unit(benchmark::kMicrosecond);

void BM_CableSolveCold(benchmark::State& state) {
  const Problem& p = problem();
  for (auto _ : state) benchmark::DoNotOptimize(fluxcal::solve_cable(p.ring, p.readings));
}
BENCHMARK(BM_CableSolveCold)->Unit(benchmark::kMicrosecond);

void BM_CableField(benchmark::State& state) {
  const Problem& p = problem();
  for (auto _ : state) benchmark::DoNotOptimize(fluxcal::cable_field(p.ring, p.truth, p.currents));
}
BENCHMARK(BM_CableField)->Unit(benchmark::kNanosecond);

void BM_CableSolveSnapshots(benchmark::State& state) {
  static const Snapshots p;
  fluxcal::CableSolveOptions o;
  o.fit_background = state.range(0) != 0;
  for (auto _ : state) benchmark::DoNotOptimize(fluxcal::solve_cable(p.ring, p.rows, o));
}
BENCHMARK(BM_CableSolveSnapshots)->Arg(0)->Arg(1)->Unit(benchmark::kMicrosecond);

void BM_CableSolveWaveform(benchmark::State& state) {
  const Problem& p = problem();
  const Eigen::Index S = state.range(0);
  Eigen::MatrixXd rows(S, 8);
  for (Eigen::Index s = 0; s < S; ++s) {
    const double w = 2 * M_PI * 50 * static_cast<double>(s) / 1000.0;
    const auto b = fluxcal::cable_field(p.ring, p.truth, Eigen::Vector2d(10 * std::sin(w), -8 * std::sin(w + 0.3)));
    for (int i = 0; i < 4; ++i) rows(s, 2 * i) = b(i, 0), rows(s, 2 * i + 1) = b(i, 1);
  }
  fluxcal::CableSolveOptions o;
  o.initial_positions = p.truth;
  o.initial_positions.array() += 0.2e-3;
  for (auto _ : state) benchmark::DoNotOptimize(fluxcal::solve_cable(p.ring, rows, o));
}
BENCHMARK(BM_CableSolveWaveform)->Arg(100)->Arg(800)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
