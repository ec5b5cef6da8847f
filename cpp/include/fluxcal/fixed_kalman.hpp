// fluxcal/fixed_kalman.hpp — the AR(p) Kalman filter of kalman.hpp in fixed point, for firmware.
//
// Header-only, no dynamic allocation, no floating point inside step(); the maximum order is the
// template parameter. Three Q-formats (frac bits f: value = integer · 2^−f), all int32:
//   signal     y, the state x, the innovation e                           (FixedFormat::signal_frac_bits)
//   coefficient  the AR coefficients a and the gain K                     (coef_frac_bits, 0 … 30)
//   covariance   Q, R, P, S                                               (cov_frac_bits)
// Only coef_frac_bits enters the arithmetic (every rescaling shifts by it). The signal and covariance
// formats are pure scales, so their fraction bits may be anything (above 31 for small signals,
// negative for large ones): they only say what the integers stand for.
// Arithmetic (the bit-exact Python model is fluxcal.oracle.kalman.FixedModel; keep them in step):
//   products     int32 × int32 exactly in int64; sums of products in int64 with saturating adds
//   rescaling    shift_round(v, s) = floor((v + 2^(s−1)) / 2^s)  (round half up), saturating
//   narrowing    int64 → int32 saturates
//   division     K_i = div_round(M_i0 · 2^cf, S): nearest, ties away from zero (one per gain entry)
// Any saturation (an input at the int32 rails, or S ≤ 0) sets a sticky overflow flag: the output is clamped, never wrapped, and
// overflowed() stays true until clear_overflow().
//
// One time-varying step (companion A, u = P a):
//   x0' = shift(Σ a_i x_i, cf); x shifts down; x0 = x0'
//   u_j = shift(Σ_i P_ji a_i, cf); M00 = shift(Σ a_i u_i, cf) + Q; M_0j = M_j0 = u_{j−1}; M_ij = P_{i−1,j−1}
//   S = M00 + R; K_i = div_round(M_i0 · 2^cf, S); e = y − x0; x_i += shift(K_i e, cf)
//   t_i = shift(S K_i, cf); P_ij = shift(M_ij 2^cf − K_i M_j0 − M_i0 K_j + t_i K_j, cf)  (j ≤ i, mirrored)
// The steady-state step keeps only the state lines with the constant gain K.
#pragma once

#include <cstddef>
#include <cstdint>
#include <limits>

namespace fluxcal {

struct FixedFormat {
  int signal_frac_bits = 30;
  int coef_frac_bits = 29;
  int cov_frac_bits = 30;
};

/// Everything the firmware filter needs (what fluxcal exports as a C header).
/// Every array holds `order` meaningful entries from its start, in the layout the exported header
/// (export-c --kalman, FixedArKalman.export_header) writes them, whatever MaxOrder is:
///   a[0 … order−1], gain[0 … order−1], and p0[i · order + j] for i, j < order
///   (row-major with stride `order`, NOT MaxOrder). So a header loads with plain copies:
///     std::memcpy(c.a, name_a, sizeof name_a); std::memcpy(c.p0, name_p0, sizeof name_p0); …
/// Entries past the first order (resp. order²) are ignored.
template <int MaxOrder>
struct FixedArKalmanCoefficients {
  static_assert(MaxOrder >= 1, "MaxOrder must be ≥ 1");
  static constexpr std::size_t kSize = static_cast<std::size_t>(MaxOrder);  // array bounds are unsigned
  int order = 1;
  FixedFormat format;
  bool steady_state = false;
  std::int32_t a[kSize] = {};                ///< AR coefficients, coefficient format
  std::int32_t gain[kSize] = {};             ///< steady-state K, coefficient format
  std::int32_t q = 0;                           ///< process variance, covariance format
  std::int32_t r = 0;                           ///< measurement variance, covariance format
  std::int32_t p0[kSize * kSize] = {};    ///< initial covariance, p0[i·order + j] (row-major, stride order), covariance format
};

namespace fixed {

constexpr std::int64_t kInt64Max = std::numeric_limits<std::int64_t>::max();
constexpr std::int64_t kInt64Min = std::numeric_limits<std::int64_t>::min();

inline std::int32_t saturate32(std::int64_t v, bool& overflow) {
  if (v > std::numeric_limits<std::int32_t>::max()) {
    overflow = true;
    return std::numeric_limits<std::int32_t>::max();
  }
  if (v < std::numeric_limits<std::int32_t>::min()) {
    overflow = true;
    return std::numeric_limits<std::int32_t>::min();
  }
  return static_cast<std::int32_t>(v);
}

inline std::int64_t add64(std::int64_t a, std::int64_t b, bool& overflow) {
  // Checked before adding (signed overflow is undefined); portable where no compiler builtin exists.
  if ((b > 0 && a > kInt64Max - b) || (b < 0 && a < kInt64Min - b)) {
    overflow = true;
    return b > 0 ? kInt64Max : kInt64Min;
  }
  return a + b;
}

inline std::int64_t mul(std::int32_t a, std::int32_t b) { return static_cast<std::int64_t>(a) * b; }

/// floor(v / 2^s). C++17 leaves a right shift of a negative value to the implementation; ~v ≥ 0 when v < 0,
/// so only non-negative values are shifted (the bits of an arithmetic shift on any compiler, as the C99 twin).
inline std::int64_t floor_shift(std::int64_t v, int s) { return v >= 0 ? v >> s : ~(~v >> s); }

/// floor((v + 2^(s−1)) / 2^s): round half up; saturates when the rounding add overflows.
inline std::int64_t shift_round(std::int64_t v, int s, bool& overflow) {
  if (s == 0) return v;
  return floor_shift(add64(v, std::int64_t{1} << (s - 1), overflow), s);
}

/// num / den rounded to nearest, ties away from zero; den > 0, |num| < 2^62.
inline std::int64_t div_round(std::int64_t num, std::int64_t den) {
  const std::int64_t mag = (2 * (num < 0 ? -num : num) + den) / (2 * den);
  return num < 0 ? -mag : mag;
}

}  // namespace fixed

template <int MaxOrder>
class FixedArKalman {
 public:
  using Coefficients = FixedArKalmanCoefficients<MaxOrder>;
  static constexpr std::size_t kSize = Coefficients::kSize;

  /// Returns false (and leaves the filter unusable) when the coefficients are out of range:
  /// order outside 1 … MaxOrder or coef_frac_bits outside 0 … 30. No exceptions (firmware).
  bool configure(const Coefficients& c) {
    valid_ = c.order >= 1 && c.order <= MaxOrder && c.format.coef_frac_bits >= 0 && c.format.coef_frac_bits <= 30;
    c_ = c;
    reset();
    return valid_;
  }
  bool valid() const { return valid_; }

  /// State to zero, covariance to P0; the overflow flag is kept (clear_overflow() clears it).
  void reset() {
    const int n = c_.order >= 1 && c_.order <= MaxOrder ? c_.order : 0;  // p0's stride is the order
    for (int i = 0; i < MaxOrder; ++i) {
      x_[i] = 0;
      k_[i] = c_.gain[i];
      for (int j = 0; j < MaxOrder; ++j) p_[i][j] = i < n && j < n ? c_.p0[i * n + j] : 0;
    }
  }

  bool overflowed() const { return overflow_; }
  void clear_overflow() { overflow_ = false; }
  const std::int32_t* state() const { return x_; }
  const std::int32_t* gain() const { return k_; }
  std::int32_t covariance(int i, int j) const { return p_[i][j]; }

  /// One sample y (signal format) in, the filtered output C x̂ (signal format) out.
  std::int32_t step(std::int32_t y) {
    if (!valid_) {
      overflow_ = true;
      return 0;
    }
    const int n = c_.order, cf = c_.format.coef_frac_bits;
    bool& of = overflow_;
    // Predict the state.
    std::int64_t acc = 0;
    for (int i = 0; i < n; ++i) acc = fixed::add64(acc, fixed::mul(c_.a[i], x_[i]), of);
    const std::int32_t x0 = fixed::saturate32(fixed::shift_round(acc, cf, of), of);
    for (int i = n - 1; i > 0; --i) x_[i] = x_[i - 1];
    x_[0] = x0;

    if (!c_.steady_state) {
      // Predict the covariance: M = A P Aᵀ + Q e1 e1ᵀ (companion structure).
      std::int32_t u[kSize] = {};  // zeroed: GCC cannot see that order ≥ 1 fills what is read
      for (int j = 0; j < n; ++j) {
        std::int64_t s = 0;
        for (int i = 0; i < n; ++i) s = fixed::add64(s, fixed::mul(p_[j][i], c_.a[i]), of);
        u[j] = fixed::saturate32(fixed::shift_round(s, cf, of), of);
      }
      std::int64_t s00 = 0;
      for (int i = 0; i < n; ++i) s00 = fixed::add64(s00, fixed::mul(c_.a[i], u[i]), of);
      for (int i = n - 1; i > 0; --i)
        for (int j = n - 1; j > 0; --j) m_[i][j] = p_[i - 1][j - 1];
      m_[0][0] = fixed::saturate32(fixed::add64(fixed::shift_round(s00, cf, of), c_.q, of), of);
      for (int j = 1; j < n; ++j) m_[0][j] = m_[j][0] = u[j - 1];
      // Gain: one division per entry, no inverse.
      const std::int32_t s = fixed::saturate32(std::int64_t{m_[0][0]} + c_.r, of);
      if (s <= 0) {
        of = true;
        for (int i = 0; i < n; ++i) k_[i] = 0;
      } else {
        for (int i = 0; i < n; ++i)
          k_[i] = fixed::saturate32(fixed::div_round(std::int64_t{m_[i][0]} * (std::int64_t{1} << cf), s), of);
      }
      // Joseph form for C = e1ᵀ, expanded: P = M − K m0ᵀ − m0 Kᵀ + S K Kᵀ.
      std::int32_t t[kSize] = {};
      for (int i = 0; i < n; ++i) t[i] = fixed::saturate32(fixed::shift_round(fixed::mul(s, k_[i]), cf, of), of);
      for (int j = 0; j < n; ++j) {
        for (int i = j; i < n; ++i) {
          std::int64_t v = std::int64_t{m_[i][j]} * (std::int64_t{1} << cf);
          v = fixed::add64(v, -fixed::mul(k_[i], m_[j][0]), of);
          v = fixed::add64(v, -fixed::mul(m_[i][0], k_[j]), of);
          v = fixed::add64(v, fixed::mul(t[i], k_[j]), of);
          p_[i][j] = p_[j][i] = fixed::saturate32(fixed::shift_round(v, cf, of), of);
        }
      }
    }
    // Update the state with the innovation.
    // A sample at the int32 rails is what a saturated conversion to the signal format leaves: flagged.
    if (y == std::numeric_limits<std::int32_t>::max() || y == std::numeric_limits<std::int32_t>::min()) of = true;
    const std::int32_t e = fixed::saturate32(std::int64_t{y} - x_[0], of);
    for (int i = 0; i < n; ++i)
      x_[i] = fixed::saturate32(fixed::add64(x_[i], fixed::shift_round(fixed::mul(k_[i], e), cf, of), of), of);
    return x_[0];
  }

  /// Filter `length` samples (y and out may be the same buffer).
  void filter(const std::int32_t* y, std::int32_t* out, long length) {
    for (long i = 0; i < length; ++i) out[i] = step(y[i]);
  }

 private:
  Coefficients c_{};
  bool valid_ = false;
  bool overflow_ = false;
  std::int32_t x_[kSize] = {};
  std::int32_t k_[kSize] = {};
  std::int32_t p_[kSize][kSize] = {};
  std::int32_t m_[kSize][kSize] = {};
};

}  // namespace fluxcal
