// Internal (not installed): run-time dispatch of the hot per-reading kernels.
// On x86-64 GCC also builds an x86-64-v3 (AVX2/FMA) clone of a function marked FLUXCAL_CLONES, chosen at
// run time by CPU features (not by CPU model, which "arch=haswell" would test); the rest of the library,
// and the Eigen ABI it shares with Ceres, stays at the baseline instruction set. The kernels work on
// blocks of kLanes readings held in small arrays, so that the compiler vectorises across readings.
#pragma once

#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__)
#define FLUXCAL_CLONES __attribute__((target_clones("arch=x86-64-v3", "default")))
#else
#define FLUXCAL_CLONES
#endif

// A kernel's per-reading body, inlined into each clone so that it is vectorised there.
#if defined(__GNUC__)
#define FLUXCAL_ALWAYS_INLINE __attribute__((always_inline)) inline
#else
#define FLUXCAL_ALWAYS_INLINE inline
#endif

namespace fluxcal::detail {
constexpr int kLanes = 8;
}  // namespace fluxcal::detail
