// Built by tests/cpp/abi_consumer with flags that change Eigen's defaults (-march=native,
// -fsanitize=address): results allocated inside libfluxcal are destroyed here, in the consumer's code.
#include <fluxcal/ellipsoid.hpp>
#include <fluxcal/refine.hpp>
#include <fluxcal/version.hpp>

#include <cstdio>
#include <cstring>
#include <random>
#include <vector>

int main() {
  // The installed headers are those of the installed library.
  static_assert(FLUXCAL_VERSION_NUMBER >= 100, "fluxcal/version.hpp: expected at least 0.1.0");
  if (std::strcmp(fluxcal::version(), FLUXCAL_VERSION_STRING) != 0) {
    std::fprintf(stderr, "FAIL: headers say %s, the library %s\n", FLUXCAL_VERSION_STRING, fluxcal::version());
    return 1;
  }
  std::printf("consumer: EIGEN_MAX_ALIGN_BYTES=%d EIGEN_DEFAULT_ALIGN_BYTES=%d EIGEN_MALLOC_ALREADY_ALIGNED=%d\n",
              EIGEN_MAX_ALIGN_BYTES, EIGEN_DEFAULT_ALIGN_BYTES, EIGEN_MALLOC_ALREADY_ALIGNED);
  std::mt19937 rng(1);
  std::normal_distribution<double> g;
  fluxcal::Samples s(500, 3);
  for (int i = 0; i < 500; ++i) {
    const Eigen::Vector3d d(g(rng), g(rng), g(rng));
    s.row(i) = (50.0 * d.normalized()).transpose() + 0.05 * Eigen::RowVector3d(g(rng), g(rng), g(rng));
  }
  std::vector<fluxcal::RefineResult> kept;
  for (int k = 0; k < 3; ++k) {
    fluxcal::EllipsoidResult e = fluxcal::fit_ellipsoid(s);
    fluxcal::RefineResult r = fluxcal::refine(e.calibration, s);  // members allocated in the library
    if (!(r.noise_sigma > 0.0 && r.noise_sigma < 1.0)) {
      std::fprintf(stderr, "FAIL: noise sigma %g\n", r.noise_sigma);
      return 1;
    }
    r.parameters.resize(r.parameters.size() + 7);  // reallocated here, freed by whoever destroys it
    kept.push_back(std::move(r));
  }  // e and r destroyed here, in the consumer's code
  kept.clear();
  std::printf("OK: fit, refined and destroyed the results\n");
  return 0;
}
