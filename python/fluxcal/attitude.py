"""Attitude helpers: turn a local-frame field and an attitude into the field seen in the body frame.

A vector calibration fits m_k = W r_k + b to readings m_k whose true field r_k in the body frame is
known: r_k = R_kᵀ f, with f the local field (e.g. IGRF north/east/down) and R_k the body→local
rotation given by the attitude. The attitude convention must be right — a wrong one (transposed
rotation, a flipped sign, a swapped angle) leaves residuals of thousands of nT instead of ~100 nT.

Conventions (`convention=`). Each names a body frame, a local frame and the meaning of the angles;
rotations are active, body→local: v_local = R v_body (scipy `Rotation.apply`).

"aerospace" (default)
    Body x forward, y right, z down (FRD). Local north, east, down (NED). Intrinsic Z-Y'-X''
    (yaw, then pitch, then roll): R = Rz(yaw) · Ry(pitch) · Rx(roll) =
    `Rotation.from_euler("ZYX", [yaw, pitch, roll])`. yaw = heading, clockwise from north seen from
    above (90° = nose east); pitch positive nose up; roll positive right wing down. This is the
    usual convention of INS/AHRS outputs: the airborne recording
    airborne_flt1002_02 (INS pitch, roll, yaw) fits to ~130 nT with it.

"seed002"
    The frames of seed 002 (twelve-position method): body x forward, y up, z right (FUR); local
    north, up, east (NUE). Same physical angles as "aerospace" (heading clockwise from north, pitch
    nose up, roll right side down). R = Ry(−yaw) · Rz(pitch) · Rx(roll) =
    `Rotation.from_euler("YZX", [−yaw, pitch, roll])`; at yaw = 0 this is the paper's eq. 6,
    whose middle row is eq. 7: H_up = sinθ H_bx + cosθ cosγ H_by − cosθ sinγ H_bz.

"enu"
    ROS REP-103: body x forward, y left, z up (FLU); local east, north, up (ENU). Intrinsic Z-Y'-X''
    as for "aerospace" (`Rotation.from_euler("ZYX", [yaw, pitch, roll])`), but yaw is measured
    counterclockwise from EAST (yaw_enu = 90° − heading), pitch is positive NOSE DOWN
    (pitch_enu = −pitch_aerospace) and roll is positive right side down (= roll_aerospace).

All three describe the same physical attitude when given matching angles; they differ only in the
axes in which the body and local vectors are written. `reference_vectors` always takes the field in
NED (what IGRF/WMM and `field_from_inclination` give) and returns it in the convention's body axes.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

CONVENTIONS = ("aerospace", "seed002", "enu")

# Rows: local-frame axes of each convention written in NED, so v_local = _NED_TO_LOCAL[c] @ v_ned.
_NED_TO_LOCAL = {
    "aerospace": np.eye(3),
    "seed002": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]),  # (N, U, E) = (N, −D, E)
    "enu": np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]),  # (E, N, U) = (E, N, −D)
}


def _check(convention: str) -> str:
    if convention not in CONVENTIONS:
        raise ValueError(f"unknown attitude convention {convention!r}; use one of {CONVENTIONS}")
    return convention


def _finite(name: str, values: np.ndarray, direction: bool = False) -> np.ndarray:
    """`values`, or ValueError naming `name` when it holds NaN/Inf or, for a `direction` (…×3), a zero vector:
    the helpers otherwise returned NaN, or a made-up frame for a reading with no direction."""
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{name}: holds NaN or infinite values")
    if direction and np.any(~np.any(values != 0, axis=-1)):
        raise ValueError(f"{name}: a zero vector has no direction")
    return values


def rotation_from_euler(pitch, roll, yaw, degrees: bool = True, convention: str = "aerospace") -> Rotation:
    """Body→local rotation(s) from pitch, roll, yaw (scalars or arrays, broadcast together).

    Returns one scipy `Rotation` (stacked when the angles are arrays) with v_local = R.apply(v_body);
    see the module docstring for the frames and angle meanings of each convention. Angles in degrees
    unless degrees=False.
    """
    _check(convention)
    p, r, y = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (pitch, roll, yaw)))
    if convention == "seed002":
        angles, seq = np.stack([-y, p, r], axis=-1), "YZX"
    else:  # aerospace and enu share the formula; only the frames and angle meanings differ
        angles, seq = np.stack([y, p, r], axis=-1), "ZYX"
    if not np.all(np.isfinite(angles)):
        raise ValueError("attitude angles must be finite")
    return Rotation.from_euler(seq, angles, degrees=degrees)


def reference_vectors(field_ned, pitch, roll, yaw, degrees: bool = True, convention: str = "aerospace") -> np.ndarray:
    """The local field seen in the body frame: r = Rᵀ f for each attitude.

    field_ned: one (north, east, down) 3-vector, or N×3 (one per attitude), in any unit (r has it).
    pitch, roll, yaw: scalars or length-N arrays (see `rotation_from_euler`).
    Returns an N×3 array (N = the broadcast length, 1 when everything is scalar) in the body axes of
    `convention` (FRD for "aerospace", FUR for "seed002", FLU for "enu").
    """
    _check(convention)
    f = np.asarray(field_ned, dtype=float)
    if f.shape[-1:] != (3,) or f.ndim > 2:
        raise ValueError("field_ned must be a 3-vector or N×3")
    _finite("field_ned", f)
    f_local = np.atleast_2d(f) @ _NED_TO_LOCAL[convention].T
    R = rotation_from_euler(pitch, roll, yaw, degrees=degrees, convention=convention)
    if not R.single and len(R) == 1:
        R = R[0]
    n = len(f_local) if R.single else len(R)
    if len(f_local) not in (1, n):
        raise ValueError("field_ned and the angles must have the same length (or length 1)")
    return np.atleast_2d(R.inv().apply(np.array(np.broadcast_to(f_local, (n, 3)))))


def field_from_inclination(total, inclination, declination=0.0, degrees: bool = True) -> np.ndarray:
    """Local field (north, east, down) from total intensity F, inclination I and declination D.

    north = F cos I cos D, east = F cos I sin D, down = F sin I. Inclination is positive when the
    field points below the horizon (northern hemisphere); declination is positive east of true north
    (0 gives the field in a magnetic-north frame). Broadcasts; returns shape broadcast + (3,).
    Seed 002: F = 52200 nT, I = 52° → down = 41134 nT (its "up" component H_u, quoted unsigned).
    """
    F, inc, dec = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (total, inclination, declination)))
    for name, value in (("total", F), ("inclination", inc), ("declination", dec)):
        _finite(name, value)
    if degrees:
        inc, dec = np.radians(inc), np.radians(dec)
    horizontal = F * np.cos(inc)
    return np.stack([horizontal * np.cos(dec), horizontal * np.sin(dec), F * np.sin(inc)], axis=-1)


def pitch_roll_from_accelerometer(acc, convention: str = "aerospace", degrees: bool = True):
    """(pitch, roll) of a static accelerometer from its reading of specific force.

    acc: a 3-vector or N×3 in the convention's body axes, any unit. A static accelerometer measures
    specific force = −gravity, i.e. it points UP with magnitude g (a level sensor in FRD reads
    (0, 0, −g); in FUR (0, +g, 0); in FLU (0, 0, +g)). If your device reports gravity (pointing
    down) instead, negate it first. Yaw is not observable from gravity.

    "aerospace" (FRD):  a = g (sinθ, −sinφ cosθ, −cosφ cosθ) → θ = atan2(ax, √(ay² + az²)),
                        φ = atan2(−ay, −az).
    "seed002" (FUR):    a = g (sinθ, cosθ cosγ, −cosθ sinγ) → θ = arcsin(Ax/|A|) (eq. 4, written
                        as atan2(Ax, √(Ay² + Az²))), γ = atan2(−Az, Ay) (= arctan(−Az/Ay) for |γ| < 90°).
    "enu" (FLU):        a = g (−sinθ, sinφ cosθ, cosφ cosθ) with θ positive nose down →
                        θ = atan2(−ax, √(ay² + az²)), φ = atan2(ay, az).
    Pitch is in [−90°, 90°], roll in (−180°, 180°]. Returns two arrays (scalars for a 3-vector), in
    degrees unless degrees=False.
    """
    _check(convention)
    a = np.asarray(acc, dtype=float)
    if a.shape[-1:] != (3,):
        raise ValueError("acc must be a 3-vector or N×3")
    _finite("acc", a, direction=True)
    x, y, z = np.moveaxis(a, -1, 0)
    if convention == "aerospace":
        pitch, roll = np.arctan2(x, np.hypot(y, z)), np.arctan2(-y, -z)
    elif convention == "seed002":
        pitch, roll = np.arctan2(x, np.hypot(y, z)), np.arctan2(-z, y)
    else:
        pitch, roll = np.arctan2(-x, np.hypot(y, z)), np.arctan2(y, z)
    if degrees:
        pitch, roll = np.degrees(pitch), np.degrees(roll)
    return pitch, roll


__all__ = ["CONVENTIONS", "field_from_inclination", "pitch_roll_from_accelerometer", "reference_vectors",
           "rotation_from_euler"]


def magnetic_frame(field, down) -> np.ndarray:
    """The magnetic north, east and down axes seen in the sensor frame at each reading (N×3×3, one axis
    a row; sensor → world is `Rotation.from_matrix` of it), from the field and the down direction, both
    sensor frame and fixed in the world (TRIAD): north is the field's horizontal part, east = down × north.
    Down as `down` points: an accelerometer's reading at rest points up, which turns east and down round.
    Where the field is vertical, any horizontal axis serves as north."""
    f = np.atleast_2d(np.asarray(field, dtype=float))
    d = np.atleast_2d(np.asarray(down, dtype=float))
    for name, value in (("field", f), ("down", d)):
        if value.ndim != 2 or value.shape[1] != 3:
            raise ValueError(f"{name}: shape {value.shape}, need a 3-vector or N×3")
        _finite(name, value, direction=True)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    north = f - np.sum(f * d, axis=1, keepdims=True) * d
    size = np.linalg.norm(north, axis=1, keepdims=True)
    other = np.where(np.abs(d[:, 2:]) < 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
    north = np.where(size > 1e-9 * np.linalg.norm(f, axis=1, keepdims=True), north, np.cross(d, other))
    north /= np.linalg.norm(north, axis=1, keepdims=True)
    return np.stack([north, np.cross(d, north), d], axis=1)


def axis_remapping(matrix, tolerance: float = 0.25):
    """(P, text, mirror) when `matrix` is a relabelling of axes: within `tolerance` (of its mean scale, every
    entry) of a signed permutation P that is not the identity; else None. text names the mapping, row by row:
    "+y, +x, +z" says row x takes the other frame's +y; mirror: det P = −1 (the frames differ in handedness).
    The fits that determine the full matrix (vector fit, positions) find a mislabelled or differently mounted
    axis this way; the model absorbs it, but the user should know it is there."""
    m = np.asarray(matrix, dtype=float)
    if m.shape != (3, 3) or not np.all(np.isfinite(m)):
        return None
    cols = np.abs(m).argmax(axis=1)
    if len(set(cols.tolist())) != 3:
        return None
    P = np.zeros((3, 3))
    P[np.arange(3), cols] = np.sign(m[np.arange(3), cols])
    scale = float(np.mean(np.abs(m[np.arange(3), cols])))
    if np.array_equal(P, np.eye(3)) or not scale > 0 or np.abs(m / scale - P).max() > tolerance:
        return None
    text = ", ".join(f"{'+' if P[i, c] > 0 else '-'}{'xyz'[c]}" for i, c in enumerate(cols))
    return P, text, bool(np.linalg.det(P) < 0)
