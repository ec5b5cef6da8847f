// bench_twostep — placeholder until the TWOSTEP solvers land.
#include <benchmark/benchmark.h>
BENCHMARK_MAIN();
