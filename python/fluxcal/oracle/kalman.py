"""References for fluxcal.kalman: a textbook NumPy Kalman filter (full matrices, Joseph form) and the
bit-exact Python integer model of the fixed-point filter (cpp/include/fluxcal/fixed_kalman.hpp).

FixedModel.filter      pure Python integers, one sample at a time: the readable specification
FixedModel.filter_batch  the same arithmetic in NumPy int64, vectorised across independent series
                         (axis 0), with explicit overflow detection on every 64-bit add — fast enough
                         to check 10⁶ samples bit for bit in a test
golden_vectors         inputs, coefficients and outputs for firmware tests
"""
from __future__ import annotations

import numpy as np

INT32_MIN, INT32_MAX = -(2 ** 31), 2 ** 31 - 1
INT64_MIN, INT64_MAX = -(2 ** 63), 2 ** 63 - 1


def companion(a) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    n = a.size
    m = np.zeros((n, n))
    m[0] = a
    m[np.arange(1, n), np.arange(n - 1)] = 1.0
    return m


def kalman_filter(a, q, r, p0, y, steady_gain=None, breaks=()):
    """Filtered outputs C x̂_{k|k} with full-matrix predict and Joseph update (or a constant gain); with breaks
    (gaps in time) each stretch between them filtered on its own from x = 0, P = p0."""
    if len(breaks):
        return np.concatenate([kalman_filter(a, q, r, p0, s, steady_gain) for s in np.split(np.asarray(y), breaks)])
    A = companion(a)
    n = A.shape[0]
    H = np.eye(n)[:1]
    Q = np.zeros((n, n))
    Q[0, 0] = q
    x, P = np.zeros(n), np.array(p0, dtype=float)
    out = np.empty(len(y))
    for k, yk in enumerate(y):
        x = A @ x
        if steady_gain is None:
            P = A @ P @ A.T + Q
            S = (H @ P @ H.T)[0, 0] + r
            K = P @ H.T[:, 0] / S
            I_KH = np.eye(n) - np.outer(K, H[0])
            P = I_KH @ P @ I_KH.T + r * np.outer(K, K)
        else:
            K = np.asarray(steady_gain)
        x = x + K * (yk - x[0])
        out[k] = x[0]
    return out


def stationary_covariance(a, q):
    """Stationary covariance of the AR(p) state, exactly for the given float coefficients: the
    autocovariance equations γ_k = Σ a_i γ_|k−i| + q δ_k0 (k = 0 … p) solved in rational arithmetic,
    then the Toeplitz matrix of γ0 … γ_{p−1}. Exact where double-precision solvers lose digits (poles
    near 1)."""
    from fractions import Fraction

    a = [Fraction(float(v)) for v in np.atleast_1d(a)]
    p = len(a)
    n = p + 1
    m = [[Fraction(int(i == j)) for j in range(n)] for i in range(n)]
    b = [Fraction(float(q)) if k == 0 else Fraction(0) for k in range(n)]
    for k in range(n):
        for i in range(1, p + 1):
            m[k][abs(k - i)] -= a[i - 1]
    for c in range(n):  # Gauss–Jordan, exact
        piv = next(row for row in range(c, n) if m[row][c] != 0)
        m[c], m[piv], b[c], b[piv] = m[piv], m[c], b[piv], b[c]
        for row in range(n):
            if row != c and m[row][c] != 0:
                f = m[row][c] / m[c][c]
                m[row] = [x - f * y for x, y in zip(m[row], m[c])]
                b[row] -= f * b[c]
    g = [float(b[k] / m[k][k]) for k in range(n)]
    return np.array([[g[abs(i - j)] for j in range(p)] for i in range(p)])


def steady_state_gain(a, q, r, iterations=20000):
    """Steady-state gain from the discrete algebraic Riccati equation (SciPy), for comparison."""
    from scipy.linalg import solve_discrete_are

    A = companion(a)
    n = A.shape[0]
    H = np.eye(n)[:1]
    Q = np.zeros((n, n))
    Q[0, 0] = q
    P = solve_discrete_are(A.T, H.T, Q, np.array([[r]]))  # a-priori covariance
    return P[:, 0] / (P[0, 0] + r)


# --- the integer model, scalar (Python ints) ---------------------------------------------------------


class _Flag:
    def __init__(self):
        self.overflow = False


def _sat32(v, f):
    if v > INT32_MAX:
        f.overflow = True
        return INT32_MAX
    if v < INT32_MIN:
        f.overflow = True
        return INT32_MIN
    return v


def _add64(a, b, f):
    s = a + b
    if s > INT64_MAX or s < INT64_MIN:
        f.overflow = True
        return INT64_MAX if a > 0 else INT64_MIN
    return s


def _shift(v, s, f):
    return v if s == 0 else _add64(v, 1 << (s - 1), f) >> s   # Python >> floors: an arithmetic shift


def _div_round(num, den):
    mag = (2 * abs(num) + den) // (2 * den)
    return -mag if num < 0 else mag


class FixedModel:
    """Integer model of FixedArKalman. `coefficients`: the dict of fluxcal.kalman.FixedArKalman.coefficients()
    (a, gain, q, r, p0 row-major, signal/coef/cov frac bits, steady_state)."""

    def __init__(self, coefficients: dict):
        c = coefficients
        self.a = [int(v) for v in c["a"]]
        self.gain = [int(v) for v in c["gain"]]
        self.q, self.r = int(c["q"]), int(c["r"])
        n = len(self.a)
        self.p0 = [[int(c["p0"][i * n + j]) for j in range(n)] for i in range(n)]
        self.cf = int(c["coef_frac_bits"])
        self.steady_state = bool(c["steady_state"])

    def filter(self, y, breaks=()):
        """(outputs, overflowed) for the int32 inputs y, from the reset state; with breaks (gaps in time) each
        np.split piece from the reset state, the outputs joined."""
        if len(breaks):
            runs = [self.filter(piece) for piece in np.split(np.asarray(y), breaks)]
            return np.concatenate([out for out, _ in runs]), any(flag for _, flag in runs)
        a, cf, n, f = self.a, self.cf, len(self.a), _Flag()
        x = [0] * n
        k = list(self.gain)
        P = [row[:] for row in self.p0]
        out = []
        for yk in y:
            acc = 0
            for i in range(n):
                acc = _add64(acc, a[i] * x[i], f)
            x = [_sat32(_shift(acc, cf, f), f)] + x[:-1]
            if not self.steady_state:
                u = []
                for j in range(n):
                    s = 0
                    for i in range(n):
                        s = _add64(s, P[j][i] * a[i], f)
                    u.append(_sat32(_shift(s, cf, f), f))
                s00 = 0
                for i in range(n):
                    s00 = _add64(s00, a[i] * u[i], f)
                M = [[0] * n for _ in range(n)]
                for i in range(1, n):
                    for j in range(1, n):
                        M[i][j] = P[i - 1][j - 1]
                M[0][0] = _sat32(_add64(_shift(s00, cf, f), self.q, f), f)
                for j in range(1, n):
                    M[0][j] = M[j][0] = u[j - 1]
                S = _sat32(M[0][0] + self.r, f)
                if S <= 0:
                    f.overflow = True
                    k = [0] * n
                else:
                    k = [_sat32(_div_round(M[i][0] << cf, S), f) for i in range(n)]
                t = [_sat32(_shift(S * k[i], cf, f), f) for i in range(n)]
                for j in range(n):
                    for i in range(j, n):
                        v = M[i][j] << cf
                        v = _add64(v, -(k[i] * M[j][0]), f)
                        v = _add64(v, -(M[i][0] * k[j]), f)
                        v = _add64(v, t[i] * k[j], f)
                        P[i][j] = P[j][i] = _sat32(_shift(v, cf, f), f)
            e = _sat32(int(yk) - x[0], f)
            x = [_sat32(_add64(x[i], _shift(k[i] * e, cf, f), f), f) for i in range(n)]
            out.append(x[0])
        return np.array(out, dtype=np.int64), f.overflow

    # --- the same arithmetic vectorised across independent series (NumPy int64) --------------------

    def filter_batch(self, Y, start=None):
        """Y: (S, N) int32 inputs of S independent series. Returns (outputs (S, N) int64, overflowed (S,)).
        start: optional (x (S, n), gain (S, n), P (S, n·n) row-major) to start each series from instead of
        the reset state; self.last_state then holds the final (x, gain, P) in the same layout."""
        Y = np.asarray(Y, dtype=np.int64)
        S_, N = Y.shape
        n, cf = len(self.a), self.cf
        a = [np.int64(v) for v in self.a]
        of = np.zeros(S_, dtype=bool)

        def add64(p, q):
            s = p + q  # wraps on overflow; detected below
            bad = ((p ^ s) & (q ^ s)) < 0
            if bad.any():
                nonlocal of
                of = of | bad
                s = np.where(bad, np.where(p > 0, np.int64(INT64_MAX), np.int64(INT64_MIN)), s)
            return s

        def sat32(v):
            nonlocal of
            bad = (v > INT32_MAX) | (v < INT32_MIN)
            if bad.any():
                of = of | bad
                v = np.clip(v, INT32_MIN, INT32_MAX)
            return v

        half = np.int64(1 << (cf - 1)) if cf > 0 else np.int64(0)

        def shift(v):
            return v if cf == 0 else add64(v, half) >> cf

        if start is None:
            x = [np.zeros(S_, dtype=np.int64) for _ in range(n)]
            k = [np.full(S_, g, dtype=np.int64) for g in self.gain]
            P = [[np.full(S_, self.p0[i][j], dtype=np.int64) for j in range(n)] for i in range(n)]
        else:
            xs, ks, ps = (np.asarray(v, dtype=np.int64) for v in start)
            x = [xs[:, i].copy() for i in range(n)]
            k = [ks[:, i].copy() for i in range(n)]
            P = [[ps[:, i * n + j].copy() for j in range(n)] for i in range(n)]
        out = np.empty((S_, N), dtype=np.int64)
        scale = np.int64(1 << cf)
        with np.errstate(over="ignore"):
            for t in range(N):
                acc = np.zeros(S_, dtype=np.int64)
                for i in range(n):
                    acc = add64(acc, a[i] * x[i])
                x = [sat32(shift(acc))] + x[:-1]
                if not self.steady_state:
                    u = []
                    for j in range(n):
                        s = np.zeros(S_, dtype=np.int64)
                        for i in range(n):
                            s = add64(s, P[j][i] * a[i])
                        u.append(sat32(shift(s)))
                    s00 = np.zeros(S_, dtype=np.int64)
                    for i in range(n):
                        s00 = add64(s00, a[i] * u[i])
                    M = [[None] * n for _ in range(n)]
                    for i in range(1, n):
                        for j in range(1, n):
                            M[i][j] = P[i - 1][j - 1]
                    M[0][0] = sat32(add64(shift(s00), np.int64(self.q)))
                    for j in range(1, n):
                        M[0][j] = M[j][0] = u[j - 1]
                    S = sat32(M[0][0] + self.r)
                    bad = S <= 0
                    of = of | bad
                    den = np.where(bad, 1, S)
                    k = []
                    for i in range(n):
                        num = M[i][0] * scale
                        mag = (2 * np.abs(num) + den) // (2 * den)
                        k.append(np.where(bad, 0, sat32(np.where(num < 0, -mag, mag))))
                    tt = [sat32(shift(S * k[i])) for i in range(n)]
                    for j in range(n):
                        for i in range(j, n):
                            v = M[i][j] * scale
                            v = add64(v, -(k[i] * M[j][0]))
                            v = add64(v, -(M[i][0] * k[j]))
                            v = add64(v, tt[i] * k[j])
                            P[i][j] = P[j][i] = sat32(shift(v))
                e = sat32(Y[:, t] - x[0])
                x = [sat32(add64(x[i], shift(k[i] * e))) for i in range(n)]
                out[:, t] = x[0]
        self.last_state = (np.stack(x, axis=1), np.stack(k, axis=1),
                           np.stack([P[i][j] for i in range(n) for j in range(n)], axis=1))
        return out, of


def golden_vectors(coefficients: dict, y_int) -> dict:
    """Golden test vectors for firmware: the coefficient set, the int32 inputs and the model's outputs."""
    out, overflowed = FixedModel(coefficients).filter(list(map(int, y_int)))
    return {"coefficients": dict(coefficients), "input": [int(v) for v in y_int], "output": [int(v) for v in out],
            "overflowed": bool(overflowed)}


def write_golden_cpp(path, n: int = 1500) -> None:
    """Write the golden vectors of tests/cpp/test_kalman.cpp (C++ include file): three seeded cases —
    time-varying AR(3), steady-state AR(3), and a full-scale step that saturates (overflow flagged).
    Regenerate with: python -c "from fluxcal.oracle.kalman import write_golden_cpp as w; w('tests/cpp/fixed_kalman_golden.inc')"
    """
    from scipy.signal import lfilter

    from ..kalman import FixedArKalman

    rng = np.random.default_rng(2016)
    a, q, r = (0.6, -0.3, 0.2), 0.5, 0.3
    s = lfilter([1.0], [1.0, -0.6, 0.3, -0.2], np.sqrt(q) * rng.standard_normal(n + 500))[500:]
    y = s + np.sqrt(r) * rng.standard_normal(n)
    y = 0.9 * y / np.max(np.abs(y))
    step = np.where(np.arange(n) < n // 2, 1.9, -1.9)
    cases = [("time_varying", FixedArKalman(a, q, r), y), ("steady_state", FixedArKalman(a, q, r, steady_state=True), y),
             ("saturating", FixedArKalman((0.99,), 1.0, 0.1, frac_bits=30), step)]
    lines = ["// Golden vectors of the fixed-point AR Kalman filter, written by fluxcal.oracle.kalman.write_golden_cpp",
             "// from the bit-exact Python integer model. Do not edit by hand.", "#include <cstdint>", "#include <vector>",
             "struct GoldenCase { const char* name; int order; int signal_frac_bits; int coef_frac_bits; int cov_frac_bits;",
             "  bool steady_state; std::vector<std::int32_t> a, gain, p0; std::int32_t q, r;",
             "  std::vector<std::int32_t> input, output; bool overflowed; };",
             "static const std::vector<GoldenCase> kGoldenCases = {"]

    def arr(v):
        return "{" + ",".join(str(int(x)) for x in v) + "}"

    for name, f, series in cases:
        if f.frac_bits is None:
            f.frac_bits = 30
        y_int = f.to_fixed(series)[0]
        g = golden_vectors(f.coefficients(), y_int)
        c = g["coefficients"]
        lines.append(f'  {{"{name}", {len(c["a"])}, {c["signal_frac_bits"]}, {c["coef_frac_bits"]}, {c["cov_frac_bits"]}, '
                     f'{"true" if c["steady_state"] else "false"}, {arr(c["a"])}, {arr(c["gain"])}, {arr(c["p0"])}, '
                     f'{c["q"]}, {c["r"]},\n   {arr(g["input"])},\n   {arr(g["output"])}, '
                     f'{"true" if g["overflowed"] else "false"}}},')
    lines.append("};")
    with open(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")
