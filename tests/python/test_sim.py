import numpy as np
import pytest

from fluxcal import sim


def test_noise_free_truth_calibration_undoes_the_sensor():
    rng = np.random.default_rng(0)
    W = np.array([[1.1, 0.2, 0.0], [-0.1, 0.9, 0.05], [0.0, 0.1, 1.0]])  # not symmetric
    s = sim.simulate(sim.uniform(300, rng), [sim.SoftIron(W), sim.HardIron([1.0, -2.0, 0.5])], [0.0, 3.0, 4.0], rng)
    truth = s.true_calibration()
    h = truth.apply(s.readings)
    np.testing.assert_allclose(np.linalg.norm(h, axis=1), 5.0, rtol=1e-12)
    np.testing.assert_allclose(truth.matrix, truth.matrix.T, atol=1e-12)  # the identifiable, symmetric factor
    np.testing.assert_allclose(truth.offset, [1.0, -2.0, 0.5])


def test_effects_apply_in_order():
    rng = np.random.default_rng(1)
    scene = sim.uniform(10, rng)
    W, b = 2.0 * np.eye(3), np.array([1.0, 0.0, 0.0])
    a = sim.simulate(scene, [sim.SoftIron(W), sim.HardIron(b)], [1.0, 0, 0], rng)
    c = sim.simulate(scene, [sim.HardIron(b), sim.SoftIron(W)], [1.0, 0, 0], rng)
    np.testing.assert_allclose(a.readings, 2 * a.truth + b)
    np.testing.assert_allclose(c.readings, 2 * (c.truth + b))
    assert a.true_calibration().offset == pytest.approx(b)
    assert c.true_calibration().offset == pytest.approx(2 * b)


def test_sweeps_turn_about_each_axis():
    scene = sim.sweeps("yxz", per_turn=360)
    assert len(scene) == 1080
    h = scene.sensor_field([1.0, 0.0, 0.0])
    # a turn about y keeps the y component at zero, about x keeps x at 1
    np.testing.assert_allclose(h[:360, 1], 0.0, atol=1e-12)
    np.testing.assert_allclose(h[360:720, 0], 1.0, atol=1e-12)
    with pytest.raises(ValueError, match="axes: 'q'"):
        sim.sweeps("q")


def test_white_noise_has_the_stated_sigma():
    rng = np.random.default_rng(2)
    s = sim.simulate(sim.uniform(20000, rng), [sim.WhiteNoise(0.3)], [0, 0, 1.0], rng)
    assert np.std(s.readings - s.truth) == pytest.approx(0.3, rel=0.02)


def test_cross_axis_holds_only_where_its_exact_features_do():
    # easy-axis signals reach 2 (x's easy axis is y; y's and z's are x): 1 + c u ≥ 0.5 needs |c| ≤ 0.25
    from types import SimpleNamespace

    signal = np.array([[2.0, -1.0, 0.5], [-1.0, 2.0, 0.3], [0.5, 0.5, 1.0]])
    ctx = SimpleNamespace(signal=signal, scale=1.0, coefficients=None)
    assert sim.CrossAxis.holds(ctx, [0.25, -0.25, 0.1])
    assert not sim.CrossAxis.holds(ctx, [0.0, 0.0, 0.26])
    assert not sim.CrossAxis.holds(ctx, [np.nan, 0.0, 0.0])
    # beyond the range the features clip the coefficient: they no longer describe the fit's own model
    ctx.coefficients = np.array([0.0, 0.0, 0.26])
    clipped = sim.CrossAxis.features(ctx)
    ctx.coefficients = np.array([0.0, 0.0, 0.25])
    assert np.array_equal(clipped, sim.CrossAxis.features(ctx))
    assert sim.Effect.holds(ctx, [1e9])  # other candidates' features hold everywhere


def test_a_tumble_turns_by_its_body_rates_as_scipys_rotation_product():
    # tumble integrates the attitude on Python floats (fast); it must be SciPy's R_{i+1} = R_i · step_i, composed
    # on the body side (the other order turns by the same angles about the world's axes: O(1) apart)
    from scipy.spatial.transform import Rotation

    from fluxcal.sim.scene import _integrate

    rng = np.random.default_rng(3)
    steps = Rotation.from_rotvec(0.05 * rng.standard_normal((500, 3)))
    attitude = start = Rotation.random(random_state=rng)
    expected = []
    for i in range(len(steps)):
        expected.append(attitude.as_quat())
        attitude = attitude * steps[i]
    np.testing.assert_allclose(_integrate(start.as_quat(), steps.as_quat()), expected, rtol=0, atol=1e-14)
    scene = sim.tumble(duration_s=2.0, rng=0)
    np.testing.assert_allclose(np.linalg.norm(scene.rotations.as_quat(), axis=1), 1.0, atol=1e-15)
