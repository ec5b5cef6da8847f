"""Attitude conventions (fluxcal.attitude) and the NumPy vector-calibration oracle, on simulated
attitudes and on the real airborne recording (IGRF vector + INS attitude per row)."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import fluxcal
from fluxcal.attitude import (CONVENTIONS, field_from_inclination, pitch_roll_from_accelerometer,
                              reference_vectors, rotation_from_euler)
from fluxcal.oracle.vector import crlb_vector, fit_vector

F_NED = np.array([17750.0, -3976.0, 50750.0])  # roughly the airborne segment's IGRF field, nT
# Axis changes from the aerospace frames: v_conv = P v_aero.
FRD_TO_FUR = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])   # (fwd, up, right) = (x, −z, y)
NED_TO_NUE = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])   # (N, U, E) = (N, −D, E)
FRD_TO_FLU = np.diag([1.0, -1, -1])                           # (fwd, left, up) = (x, −y, −z)
NED_TO_ENU = np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]])   # (E, N, U) = (E, N, −D)


def random_attitudes(rng, n):
    return rng.uniform(-80, 80, n), rng.uniform(-179, 179, n), rng.uniform(0, 360, n)


# ---------------------------------------------------------------- conventions, hand-computed cases
def test_aerospace_is_scipy_intrinsic_zyx():
    p, r, y = random_attitudes(np.random.default_rng(0), 50)
    R = rotation_from_euler(p, r, y)
    ref = Rotation.from_euler("ZYX", np.column_stack([y, p, r]), degrees=True)
    assert np.allclose(R.as_matrix(), ref.as_matrix(), atol=1e-14)
    # … = Rz(yaw) Ry(pitch) Rx(roll), written out
    c, s = np.cos, np.sin
    P, Rl, Y = np.radians([p[0], r[0], y[0]])
    Rz = np.array([[c(Y), -s(Y), 0], [s(Y), c(Y), 0], [0, 0, 1]])
    Ry = np.array([[c(P), 0, s(P)], [0, 1, 0], [-s(P), 0, c(P)]])
    Rx = np.array([[1, 0, 0], [0, c(Rl), -s(Rl)], [0, s(Rl), c(Rl)]])
    assert np.allclose(R[0].as_matrix(), Rz @ Ry @ Rx, atol=1e-14)
    # radians give the same rotation
    assert np.allclose(rotation_from_euler(*np.radians([p, r, y]), degrees=False).as_matrix(), R.as_matrix())


def test_level_attitude_sees_the_ned_field():
    # zero angles: the body axes coincide with the convention's local axes
    for conv, B in [("aerospace", np.eye(3)), ("seed002", NED_TO_NUE), ("enu", NED_TO_ENU)]:
        assert np.allclose(reference_vectors(F_NED, 0, 0, 0, convention=conv), B @ F_NED, atol=1e-9)
    # ENU yaw 90° = nose north: FLU body sees (north, west, up)
    N, E, D = F_NED
    assert np.allclose(reference_vectors(F_NED, 0, 0, 90, convention="enu"), [[N, -E, -D]], atol=1e-9)
    assert reference_vectors(F_NED, 0, 0, 0).shape == (1, 3)


def test_hand_computed_aerospace_cases():
    north, east, down = np.eye(3)
    # heading east: the nose points east, the right wing south → north lies along body −y
    assert np.allclose(reference_vectors(north, 0, 0, 90), [[0, -1, 0]], atol=1e-12)
    assert np.allclose(reference_vectors(east, 0, 0, 90), [[1, 0, 0]], atol=1e-12)
    # 90° nose up: the nose points up, the belly (z) north → down is body −x, north is body +z
    assert np.allclose(reference_vectors(down, 90, 0, 0), [[-1, 0, 0]], atol=1e-12)
    assert np.allclose(reference_vectors(north, 90, 0, 0), [[0, 0, 1]], atol=1e-12)
    # 90° right wing down: body y points down
    assert np.allclose(reference_vectors(down, 0, 90, 0), [[0, 1, 0]], atol=1e-12)
    # small nose-up pitch: the down field gains a backward component −sinθ on x
    assert np.allclose(reference_vectors(down, 10, 0, 0), [[-np.sin(np.radians(10)), 0, np.cos(np.radians(10))]])


def test_round_trip_and_broadcasting():
    rng = np.random.default_rng(1)
    p, r, y = random_attitudes(rng, 200)
    f = rng.normal(0, 3e4, (200, 3))
    for conv in CONVENTIONS:
        R = rotation_from_euler(p, r, y, convention=conv)
        body = reference_vectors(f, p, r, y, convention=conv)
        f_local = reference_vectors(f, 0, 0, 0, convention=conv)  # zero angles: body axes = local axes
        assert np.allclose(R.apply(body), f_local, atol=1e-8)
        assert np.allclose(np.linalg.norm(body, axis=1), np.linalg.norm(f, axis=1))
    # one field, many attitudes == the field repeated
    assert np.allclose(reference_vectors(F_NED, p, r, y), reference_vectors(np.tile(F_NED, (200, 1)), p, r, y))
    # one attitude, many fields
    assert np.allclose(reference_vectors(f, p[0], r[0], y[0]), rotation_from_euler(p[0], r[0], y[0]).inv().apply(f))
    with pytest.raises(ValueError):
        reference_vectors(f[:3], p[:5], r[:5], y[:5])
    with pytest.raises(ValueError):
        rotation_from_euler(0, 0, 0, convention="ned-xyz")


def test_alternative_conventions_describe_the_same_physical_attitude():
    p, r, hdg = random_attitudes(np.random.default_rng(2), 100)
    aero = reference_vectors(F_NED, p, r, hdg)
    # seed 002: same angles, body (fwd, up, right), local (north, up, east)
    seed = reference_vectors(F_NED, p, r, hdg, convention="seed002")
    assert np.allclose(seed, aero @ FRD_TO_FUR.T, atol=1e-8)
    R_seed = rotation_from_euler(p, r, hdg, convention="seed002").as_matrix()
    R_aero = rotation_from_euler(p, r, hdg).as_matrix()
    assert np.allclose(R_seed, NED_TO_NUE @ R_aero @ FRD_TO_FUR.T, atol=1e-12)
    # ROS REP-103: yaw ccw from east = 90° − heading, pitch nose down = −pitch, roll unchanged
    enu = reference_vectors(F_NED, -p, r, 90 - hdg, convention="enu")
    assert np.allclose(enu, aero @ FRD_TO_FLU.T, atol=1e-8)


def test_seed002_rotation_is_its_eq6_and_eq7():
    theta, gamma = np.radians([7.0, -23.0])
    c, s = np.cos, np.sin
    eq6 = np.array([[c(theta), -s(theta) * c(gamma), s(theta) * s(gamma)],
                    [s(theta), c(theta) * c(gamma), -c(theta) * s(gamma)],
                    [0.0, s(gamma), c(gamma)]])
    assert np.allclose(rotation_from_euler(7.0, -23.0, 0.0, convention="seed002").as_matrix(), eq6, atol=1e-14)
    Hb = np.array([30000.0, 20000.0, -5000.0])
    H_up = s(theta) * Hb[0] + c(theta) * c(gamma) * Hb[1] - c(theta) * s(gamma) * Hb[2]   # eq. 7
    assert rotation_from_euler(7.0, -23.0, 0.0, convention="seed002").apply(Hb)[1] == pytest.approx(H_up)


def test_field_from_inclination_seed002_number():
    N, E, D = field_from_inclination(52200.0, 52.0)
    assert abs(D - 41134.0) < 1.0          # seed 002: H_u = 52200 sin 52° = 41134 nT
    assert E == 0.0 and N == pytest.approx(52200 * np.cos(np.radians(52)))
    f = field_from_inclination([52200.0, 54085.0], [52.0, 70.0], [0.0, -12.75])
    assert f.shape == (2, 3)
    assert np.allclose(np.linalg.norm(f, axis=1), [52200.0, 54085.0])
    assert np.degrees(np.arctan2(f[1, 1], f[1, 0])) == pytest.approx(-12.75)
    assert np.allclose(field_from_inclination(1.0, np.pi / 2, degrees=False), [0, 0, 1], atol=1e-15)


@pytest.mark.parametrize("convention", CONVENTIONS)
def test_accelerometer_levelling_on_static_readings(convention):
    rng = np.random.default_rng(3)
    n = 300
    p = rng.uniform(-85, 85, n)
    r = rng.uniform(-175, 175, n)
    y = rng.uniform(0, 360, n)
    g = 9.80665
    up = {"aerospace": [0, 0, -g], "seed002": [0, g, 0], "enu": [0, 0, g]}[convention]  # specific force, local
    acc = rotation_from_euler(p, r, y, convention=convention).inv().apply(up)
    pe, re = pitch_roll_from_accelerometer(acc, convention=convention)
    assert np.allclose(pe, p, atol=1e-9) and np.allclose(re, r, atol=1e-9)
    # noisy static readings (1 mg): levelling within a few hundredths of a degree
    noisy = acc + rng.normal(0, 1e-3 * g, acc.shape)
    pe, re = pitch_roll_from_accelerometer(noisy, convention=convention)
    ok = np.abs(p) < 70  # roll is ill-defined near ±90° pitch
    assert np.max(np.abs(pe - p)) < 0.5 and np.max(np.abs((re - r + 180)[ok] % 360 - 180)) < 0.5
    assert np.sqrt(np.mean((pe - p) ** 2)) < 0.15


def test_accelerometer_seed002_formula_and_level():
    A = np.array([0.2, 0.9, -0.3])
    theta, gamma = pitch_roll_from_accelerometer(A, convention="seed002", degrees=False)
    assert theta == pytest.approx(np.arcsin(A[0] / np.linalg.norm(A)))
    assert gamma == pytest.approx(np.arctan(-A[2] / A[1]))
    assert np.allclose(pitch_roll_from_accelerometer([0.0, 0.0, -1.0]), (0.0, 0.0))  # level FRD reads −g on z
    assert np.allclose(pitch_roll_from_accelerometer([0.5, 0.0, -np.sqrt(0.75)]), (30.0, 0.0))  # nose up 30°


# ---------------------------------------------------------------- oracle vector calibration
def simulated_vector(rng, n=400, sigma=20.0, field=54000.0):
    d = rng.standard_normal((n, 3))
    ref = field * d / np.linalg.norm(d, axis=1, keepdims=True)
    W = np.eye(3) + rng.uniform(-0.1, 0.1, (3, 3))
    b = rng.uniform(-3000, 3000, 3)
    return ref, W, b, ref @ W.T + b + rng.normal(0, sigma, (n, 3)) * (sigma > 0)


def test_oracle_vector_fit_is_exact_without_noise():
    rng = np.random.default_rng(4)
    ref, W, b, m = simulated_vector(rng, n=50, sigma=0.0)
    fit = fit_vector(m, ref)
    assert np.allclose(fit["forward"], W, atol=1e-12) and np.allclose(fit["offset"], b, atol=1e-7)
    assert np.allclose(fit["matrix"] @ W, np.eye(3), atol=1e-12)
    assert fit["residual_rms"] < 1e-7
    # fluxcal's correction convention: h = A (m − b) gives back the reference
    assert np.allclose((m - fit["offset"]) @ fit["matrix"].T, ref, atol=1e-6)


def test_crlb_layout():
    rng = np.random.default_rng(5)
    ref, *_ = simulated_vector(rng)
    C = crlb_vector(ref, 2.0)
    X = np.column_stack([ref, np.ones(len(ref))])
    block = 4.0 * np.linalg.inv(X.T @ X)
    assert C.shape == (12, 12) and np.allclose(C, C.T)
    for i in range(3):
        idx = [3 * i, 3 * i + 1, 3 * i + 2, 9 + i]
        assert np.allclose(C[np.ix_(idx, idx)], block)
    assert np.count_nonzero(C) == 3 * 16  # axes uncorrelated


def test_oracle_vector_fit_attains_the_crlb_monte_carlo():
    rng = np.random.default_rng(6)
    sigma = 20.0
    ref, W, b, _ = simulated_vector(rng, n=300, sigma=sigma)
    C = crlb_vector(ref, sigma)
    truth = np.concatenate([W.ravel(), b])
    errors = []
    for run in range(300):
        noise = np.random.default_rng(1000 + run).normal(0, sigma, (len(ref), 3))
        fit = fit_vector(ref @ W.T + b + noise, ref)
        errors.append(np.concatenate([fit["forward"].ravel(), fit["offset"]]) - truth)
    errors = np.array(errors)
    sd = np.sqrt(np.diag(C))
    # a single run: every parameter within 5 standard errors
    assert np.all(np.abs(errors[0]) < 5 * sd)
    # RMS error of b (and of W) matches √trace of its CRLB block within 15 %
    rms_b = np.sqrt(np.mean(np.sum(errors[:, 9:] ** 2, axis=1)))
    assert rms_b == pytest.approx(np.sqrt(np.trace(C[9:, 9:])), rel=0.15)
    rms_W = np.sqrt(np.mean(np.sum(errors[:, :9] ** 2, axis=1)))
    assert rms_W == pytest.approx(np.sqrt(np.trace(C[:9, :9])), rel=0.15)
    # the empirical covariance has the predicted structure (per-parameter variance within 35 %; measured 0.77 … 1.16)
    assert np.allclose(errors.var(axis=0) / sd ** 2, 1.0, atol=0.35)


# ---------------------------------------------------------------- real airborne recording
@pytest.fixture
def airborne(real_data):
    d = np.loadtxt(real_data / "airborne_flt1002_02.tsv")
    assert d.shape == (12301, 10)
    return d


def test_airborne_vector_fit_predicts_held_out_half(airborne):
    # columns: time, flux x y z (nT), INS pitch roll yaw (deg), IGRF north east down (nT)
    m, (pitch, roll, yaw), f = airborne[:, 1:4], airborne[:, 4:7].T, airborne[:, 7:10]
    h = len(m) // 2
    ref = reference_vectors(f, pitch, roll, yaw)  # aerospace convention
    fit = fit_vector(m[:h], ref[:h])
    res = m[h:] - (ref[h:] @ fit["forward"].T + fit["offset"])
    rms = np.sqrt(np.mean(np.sum(res ** 2, axis=1)))
    assert rms < 150.0                                           # measured 131.9 nT
    assert np.all(np.sqrt(np.mean(res ** 2, axis=0)) < 130.0)     # measured 68 / 40 / 106 nT
    # the sensor is a near-orthonormal fluxgate mounted x up, y forward, z left (W ≈ signed permutation)
    sv = np.linalg.svd(fit["forward"], compute_uv=False)
    assert np.all(np.abs(sv - 1) < 0.05)                         # measured 0.991 … 1.017
    assert np.allclose(np.round(fit["forward"]), [[0, 0, -1], [1, 0, 0], [0, -1, 0]])
    # the transposed rotation (r = R f instead of Rᵀ f) is thousands of nT off
    wrong = rotation_from_euler(pitch, roll, yaw).apply(f)
    wfit = fit_vector(m[:h], wrong[:h])
    wres = m[h:] - (wrong[h:] @ wfit["forward"].T + wfit["offset"])
    assert np.sqrt(np.mean(np.sum(wres ** 2, axis=1))) > 2000.0  # measured 7021 nT


def test_airborne_magnitude_only_ellipsoid_is_nonsense(airborne):
    m, (pitch, roll, yaw), f = airborne[:, 1:4], airborne[:, 4:7].T, airborne[:, 7:10]
    h = len(m) // 2
    ref = reference_vectors(f, pitch, roll, yaw)
    vec = fit_vector(m[:h], ref[:h])
    igrf = np.linalg.norm(f[:h], axis=1).mean()
    cal = fluxcal.fit_ellipsoid(m[:h], field_norm=igrf)
    # the magnitude fits beautifully (|h| residual ≈ 53 nT in-sample, 66 nT held-out) …
    assert cal.summary["residual_rms"] < 100.0
    held = np.linalg.norm(cal.apply(m[h:]), axis=1) - np.linalg.norm(f[h:], axis=1)
    assert np.sqrt(np.mean(held ** 2)) < 100.0
    # … but the offset is far from the vector fit's (measured 4479 nT; vector offset
    # (−1833, −977, 4525), ellipsoid (−5994, −454, 2954)), and fluxcal warns about coverage
    assert np.linalg.norm(cal.offset - vec["offset"]) > 3000.0
    assert any("coverage" in w for w in cal.summary["warnings"])
    # the corrected vectors are wrong even after the best fixed rotation (measured 830 nT held-out)
    hh = cal.apply(m)
    U, _, Vt = np.linalg.svd(hh[:h].T @ ref[:h])
    Q = U @ Vt
    err = hh[h:] - ref[h:] @ Q.T
    assert np.sqrt(np.mean(np.sum(err ** 2, axis=1))) > 500.0
    # while the vector calibration's h = A (m − b) is within ~130 nT of the true vector
    hv = (m[h:] - vec["offset"]) @ vec["matrix"].T
    assert np.sqrt(np.mean(np.sum((hv - ref[h:]) ** 2, axis=1))) < 150.0  # measured 131.7 nT


def test_magnetic_frame_recovers_the_attitude_about_magnetic_north():
    # Field and down seen by a sensor at random attitudes; the frame's rows are the world's magnetic
    # north, east, down in the sensor frame, so Rotation.from_matrix(frame) is sensor → magnetic NED.
    from fluxcal import attitude

    rot = Rotation.random(50, random_state=4)  # sensor → NED
    field_ned = attitude.field_from_inclination(50.0, 60.0, declination=0.0)
    frame = attitude.magnetic_frame(rot.inv().apply(field_ned), rot.inv().apply([0.0, 0.0, 1.0]))
    assert np.allclose(frame, rot.as_matrix(), atol=1e-12)
    assert np.allclose(np.linalg.det(frame), 1.0)
    vertical = attitude.magnetic_frame([[0.0, 0.0, 1.0]], [[0.0, 0.0, 1.0]])  # at a magnetic pole
    assert np.allclose(vertical[0] @ vertical[0].T, np.eye(3))


def test_bad_vectors_and_angles_are_named():
    from fluxcal import attitude, positions

    # these returned NaN, or a made-up frame for a vector with no direction
    cases = [(lambda: attitude.magnetic_frame([np.nan, 0, 1], [0, 0, 1]), "field: holds NaN"),
             (lambda: attitude.magnetic_frame([0, 0, 0], [0, 0, 1]), "field: a zero vector"),
             (lambda: attitude.magnetic_frame([1, 0, 0], [0, 0, 0]), "down: a zero vector"),
             (lambda: attitude.pitch_roll_from_accelerometer([0, 0, 0]), "acc: a zero vector"),
             (lambda: attitude.pitch_roll_from_accelerometer([np.inf, 0, -9.8]), "acc: holds NaN or infinite"),
             (lambda: attitude.reference_vectors([np.nan, 0, 1], 0, 0, 0), "field_ned: holds NaN"),
             (lambda: attitude.field_from_inclination(5e4, np.inf), "inclination: holds NaN or infinite"),
             (lambda: positions.reference_field(total=50000, inclination=np.nan), "inclination: holds NaN")]
    for call, message in cases:
        with pytest.raises(ValueError, match=message):
            call()
    np.testing.assert_allclose(positions.field_from_inclination(52200, 52), [32137.529012, 0, 41134.161338])


def test_an_axis_relabelling_is_named_and_soft_iron_or_a_small_rotation_is_not():
    from fluxcal.attitude import axis_remapping

    swap = np.array([[0.0, 1.02, 0.03], [0.98, -0.02, 0.0], [0.01, 0.0, -1.01]])
    P, text, mirror = axis_remapping(swap)
    assert text == "+y, +x, -z" and not mirror and np.array_equal(P, [[0, 1, 0], [1, 0, 0], [0, 0, -1]])
    assert axis_remapping(np.diag([1.0, 1.0, -1.0]))[1:] == ("+x, +y, -z", True)
    soft = np.eye(3) + 0.1 * np.random.default_rng(0).uniform(-1, 1, (3, 3))
    assert axis_remapping(soft) is None
    assert axis_remapping(Rotation.from_euler("z", 30, degrees=True).as_matrix()) is None
    assert axis_remapping(Rotation.from_euler("z", 90, degrees=True).as_matrix())[1] == "-y, +x, +z"
    assert axis_remapping(np.full((3, 3), np.nan)) is None


def test_the_vector_fit_says_when_the_sensor_axes_are_the_references_relabelled():
    rng = np.random.default_rng(4)
    r = rng.standard_normal((400, 3))
    r *= 50.0 / np.linalg.norm(r, axis=1, keepdims=True)
    W = np.eye(3) + 0.03 * rng.uniform(-1, 1, (3, 3))
    m = r @ W.T + [5.0, -3.0, 2.0] + 0.05 * rng.standard_normal(r.shape)
    plain = fluxcal.fit_vector(m, r, units="uT")
    assert not any("relabelling" in w for w in plain.summary["warnings"])
    mounted = fluxcal.fit_vector(m[:, [1, 0, 2]] * [1, -1, 1], r, units="uT")  # x and −y swapped
    assert any("the reference's x, y, z are the sensor's -y, +x, +z" in w for w in mounted.summary["warnings"])
    np.testing.assert_allclose(mounted.apply(m[:, [1, 0, 2]] * [1, -1, 1]), plain.apply(m), atol=1e-9)
