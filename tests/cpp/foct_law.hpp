// The FOCT zero-bias drift law of fluxcal.sim.foct (amperes), shared by test_drift.cpp and
// test_foct.cpp: orders 2 / 1 / 3 over −20…0 / 0…30 / 30…50 °C, meeting at 0 and 30 °C; the cubic
// is in u = T − 30.
#pragma once

inline double foct_drift_law(double t) {
  if (t < 0.0) return 0.8 + 0.05 * t + 0.004 * t * t;
  if (t < 30.0) return 0.8 - 0.03 * t;
  const double u = t - 30.0;
  return -0.1 - 0.02 * u + 0.004 * u * u - 0.0004 * u * u * u;
}
