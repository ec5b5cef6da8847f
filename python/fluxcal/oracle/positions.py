"""NumPy/SciPy references for fluxcal.positions (tests and benchmarks only).

Written independently of the C++ core: Euler rotations from SciPy, least squares by numpy.linalg.lstsq,
the joint heading problem by scipy.optimize.least_squares, seed 002's sums spelled out position by
position as in the paper (with its typos corrected).
"""
from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

_UP = {"ned": np.array([0.0, 0, -1]), "nue": np.array([0.0, 1, 0])}


def pitch_roll(acc, frame="nue"):
    """Seed 002 eq. 4 (nue) or the FRD equivalent (ned), radians."""
    a = np.asarray(acc, dtype=float)
    if frame == "nue":
        return np.arcsin(a[0] / np.linalg.norm(a)), np.arctan2(-a[2], a[1])
    return np.arcsin(a[0] / np.linalg.norm(a)), np.arctan2(-a[1], -a[2])


def body_to_local(pitch, roll, yaw, frame="nue"):
    if frame == "nue":
        return Rotation.from_euler("YZX", [-yaw, pitch, roll]).as_matrix()
    return Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()


def eq6(theta, gamma):
    """Seed 002 eq. 6 as printed (body → N-U-E at zero heading)."""
    c, s, cg, sg = np.cos(theta), np.sin(theta), np.cos(gamma), np.sin(gamma)
    return np.array([[c, -s * cg, s * sg], [s, c * cg, -c * sg], [0.0, sg, cg]])


def fit_positions(U, H):
    """U = U0 + K H by numpy lstsq. Returns (U0, K)."""
    X = np.column_stack([np.ones(len(H)), H])
    beta, *_ = np.linalg.lstsq(X, U, rcond=None)
    return beta[0], beta[1:].T


def level(nominal, sf, frame):
    """Nominal rotation corrected by the smallest rotation taking the measured up onto local up."""
    up = _UP[frame]
    v = nominal @ (sf / np.linalg.norm(sf))
    axis = np.cross(v, up)
    s = np.linalg.norm(axis)
    angle = np.arctan2(s, v @ up)
    C = Rotation.from_rotvec(axis / s * angle).as_matrix() if s > 1e-15 else np.eye(3)
    return C @ nominal


def heading(angle, frame):
    up = _UP[frame]
    return Rotation.from_rotvec(-up * angle).as_matrix()  # clockwise from above


def calibrate_joint(U, sf, nominal, field_local, frame, yaw0=None, U00=None, K0=None):
    """Joint least squares over U0, K and one heading per position (scipy least_squares)."""
    n = len(U)
    L = [level(R, a, frame) for R, a in zip(nominal, sf)]
    if K0 is None:
        U00, K0 = fit_positions(U, np.array([Li.T @ field_local for Li in L]))
    yaw0 = np.zeros(n) if yaw0 is None else yaw0

    def resid(p):
        u0, K, psi = p[:3], p[3:12].reshape(3, 3), p[12:]
        H = np.array([(heading(psi[i], frame) @ L[i]).T @ field_local for i in range(n)])
        return (U - u0 - H @ K.T).ravel()

    sol = least_squares(resid, np.concatenate([U00, K0.ravel(), yaw0]), method="lm", xtol=1e-15, ftol=1e-15,
                        gtol=1e-15, max_nfev=20000)
    return sol.x[:3], sol.x[3:12].reshape(3, 3), sol.x[12:]


def closed_form_twelve(U, Hu):
    """Seed 002 eqs. 14–29, position by position (1-based names as in the paper), typos corrected:
    eq. 27 Kz with minus signs, eq. 29 Kyz from U_hy, eq. 14 'Uky0' = Uhy0, eq. 22 uses 5–8."""
    U = np.asarray(U, dtype=float)
    X = {i + 1: U[i, 0] for i in range(12)}
    Y = {i + 1: U[i, 1] for i in range(12)}
    Z = {i + 1: U[i, 2] for i in range(12)}
    Uhy0 = (Y[1] + Y[2] + Y[3] + Y[4]) / 4                     # (14)
    Ky = (Y[1] + Y[2] - Y[3] - Y[4]) / (4 * Hu)                # (15)
    Kxy = (X[1] + X[2] - X[3] - X[4]) / (4 * Hu)               # (20)
    Kzy = (Z[1] + Z[2] - Z[3] - Z[4]) / (4 * Hu)               # (21)
    Uhx0 = (X[5] + X[6] + X[7] + X[8]) / 4                     # (22)
    Kx = (X[5] + X[6] - X[7] - X[8]) / (4 * Hu)                # (23)
    Kyx = (Y[5] + Y[6] - Y[7] - Y[8]) / (4 * Hu)               # (24)
    Kzx = (Z[5] + Z[6] - Z[7] - Z[8]) / (4 * Hu)               # (25)
    Uhz0 = (Z[9] + Z[10] + Z[11] + Z[12]) / 4                  # (26)
    Kz = (Z[9] + Z[10] - Z[11] - Z[12]) / (4 * Hu)             # (27) corrected
    Kxz = (X[9] + X[10] - X[11] - X[12]) / (4 * Hu)            # (28)
    Kyz = (Y[9] + Y[10] - Y[11] - Y[12]) / (4 * Hu)            # (29) corrected
    return np.array([Uhx0, Uhy0, Uhz0]), np.array([[Kx, Kxy, Kxz], [Kyx, Ky, Kyz], [Kzx, Kzy, Kz]])


def calibrate_accelerometer(raw, g=9.80665):
    """a = T (raw − b), T upper triangular; scipy least_squares on |a| − g."""
    raw = np.asarray(raw, dtype=float)
    lo, hi = raw.min(axis=0), raw.max(axis=0)
    x0 = np.array([*(hi + lo) / 2, *(2 * g / (hi - lo))[:1], 0, 0, (2 * g / (hi - lo))[1], 0, (2 * g / (hi - lo))[2]])

    def T_of(p):
        t = p[3:]
        return np.array([[t[0], t[1], t[2]], [0, t[3], t[4]], [0, 0, t[5]]])

    def resid(p):
        return np.linalg.norm((raw - p[:3]) @ T_of(p).T, axis=1) - g

    sol = least_squares(resid, x0, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    return sol.x[:3], T_of(sol.x)
