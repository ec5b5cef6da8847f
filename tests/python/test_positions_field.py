"""A misplaced reference field is said on every positions path, not only with nominal attitudes (session 32).

With the headings unknown (levelling from the accelerometer only) the headings absorb any turn or mirror of the
field's horizontal part, and K's sign a reversed down component: only mistakes that change the dip show in the
residual (N,U,E given for N,E,D), and a reversed down component shows only in K's handedness. A body-frame reference
(`positions.fit`) holds no north of its own: only the size of its misfit against K's reading of it can be judged.
A field or readings in another unit than labelled show only in K's gain.
"""
import numpy as np
import pytest

import fluxcal.positions as fp
from fluxcal import sim

from conftest import run_cli

G = 9.80665
FIELD = np.array([17000.0, 1000.0, 48000.0])  # (N, E, D) nT
NUE = fp.to_local(FIELD, "nue")  # the same field written N,U,E: (17000, -48000, 1000)
U0 = np.array([120.0, -80.0, 40.0])  # mV
K = 0.09 * np.array([[1.05, 0.02, -0.01], [0.0, 0.97, 0.03], [0.01, -0.02, 1.01]])  # mV/nT


def _shots(seed, frame, sensor=(U0, K), noise=0.45, n=24, acc_deg=0.005):
    """n random static attitudes, headings unknown; accelerometer good to `acc_deg`."""
    rng = np.random.default_rng(seed)
    scene = sim.random_scene(n, frame, rng)
    acc = sim.Accelerometer(np.zeros(3), np.eye(3), G * np.radians(acc_deg))
    return sim.simulate_positions(scene, FIELD, sensor=sensor, noise=noise, accelerometer=acc, rng=rng)


def _misfit(res):
    return [w for w in res.summary["warnings"] if w.startswith("the model does not fit")]


def _said(s, given, frame):
    """("warning" or "error", the misfit warning or the error) of calibrate with the headings unknown."""
    try:
        res = fp.calibrate(s.outputs, s.acc_raw, given, frame=frame, units="mV")
    except ValueError as exc:
        return "error", str(exc)
    said = _misfit(res)
    return "warning", said[0] if said else ""


# ---------------------------------------------------------------- headings unknown

@pytest.mark.parametrize("frame, cause", [("nue", "it was given in the frame's local axes (N,U,E for --frame nue)"),
                                          ("ned", "it was given as N,U,E (seed 002's local axes")])
def test_headings_unknown_a_field_given_north_up_east_is_named(frame, cause):
    # Before: no mistake was tried without nominal attitudes — a generic "check the reference field", or, when the
    # wrong field left the solver a flat K, "these parameters are not observable … tilt the sensor through more
    # attitudes", which blamed the positions.
    kinds = set()
    for seed in range(6):
        kind, text = _said(_shots(seed, frame), NUE, frame)
        assert cause in text and "With the field read" in text, (seed, text)
        assert "(17000, 1000, 48000)" in text, (seed, text)  # the field the data point to
        if kind == "warning":
            assert "× less" in text, text
        else:
            assert text.startswith("the positions cannot be fitted against the reference field N,E,D = (17000, "
                                   "-48000, 1000) (the fit failed: positions: these parameters are not observable")
            assert "the positions fit: residual RMS" in text, text
        kinds.add(kind)
    assert kinds == {"warning", "error"}  # both ways of failing occur among these seeds, and both name it


def test_headings_unknown_right_field_says_nothing():
    for frame in fp.FRAMES:
        for seed in range(4):
            # a fluxgate-like sensor, and a MEMS-like one (25 mV ≈ 0.5 % of its reading, accelerometer to 0.2°)
            for kw in ({}, {"noise": 25.0, "acc_deg": 0.2}):
                s = _shots(seed, frame, **kw)
                res = fp.calibrate(s.outputs, s.acc_raw, FIELD, frame=frame, units="mV")
                said = [w for w in res.summary["warnings"] if "does not fit" in w or "mirror" in w
                        or "down component" in w]
                assert not said, (frame, seed, kw, said)


@pytest.mark.parametrize("mistake", [[-1.0, 1.0, 1.0], [1.0, -1.0, 1.0], "swap"])
def test_headings_unknown_horizontal_mistakes_change_only_the_headings(mistake):
    # the headings absorb a north or east sign or N and E swapped: the same fit (U0, K), so nothing to say
    s = _shots(3, "ned")
    given = FIELD[[1, 0, 2]] if mistake == "swap" else FIELD * mistake
    right = fp.calibrate(s.outputs, s.acc_raw, FIELD, frame="ned", units="mV")
    wrong = fp.calibrate(s.outputs, s.acc_raw, given, frame="ned", units="mV")
    assert np.allclose(wrong.K, right.K, rtol=0, atol=1e-6 * 0.09) and np.allclose(wrong.offset, right.offset,
                                                                                   atol=1e-3)
    assert wrong.summary["warnings"] == right.summary["warnings"] == []
    assert fp._same_to_the_fit(given, FIELD, headings_free=True)  # so no refit is spent on it
    assert not fp._same_to_the_fit(given, FIELD)  # with nominal headings it is tried (and named)


@pytest.mark.parametrize("given", [FIELD * [1.0, 1.0, -1.0], np.array([FIELD[1], FIELD[0], -FIELD[2]])],
                         ids=["inclination sign", "E,N,U"])
def test_headings_unknown_a_reversed_down_component_is_said_by_Ks_handedness(given):
    # the same residual with K negated: only K's handedness (det K < 0) tells, and two sensors of opposite
    # handedness leave the same trace — both are said
    s = _shots(2, "ned")
    right = fp.calibrate(s.outputs, s.acc_raw, FIELD, frame="ned", units="mV")
    wrong = fp.calibrate(s.outputs, s.acc_raw, given, frame="ned", units="mV")
    assert np.allclose(wrong.K, -right.K, rtol=0, atol=1e-6 * 0.09)
    assert not any("down component" in w for w in right.summary["warnings"]), right.summary["warnings"]
    said = [w for w in wrong.summary["warnings"] if "wrong sign of its down component" in w]
    assert len(said) == 1 and "cannot tell these apart" in said[0], wrong.summary["warnings"]
    assert fp._vector(given * [1.0, 1.0, -1.0]) in said[0] and "give nominal attitudes" in said[0], said[0]
    # K ≈ −gain·I is a relabelling with a mirror: the one warning says both, every axis reversed as a sign's trace
    assert said[0].startswith("K is an axis relabelling") and ". Or the reference field" in said[0], said[0]
    assert "Every axis reversed is seldom a mounting" in said[0], said[0]
    # an accelerometer that reports gravity where specific force is taken leaves the same trace (a blind check:
    # K negated, the accelerometer unnamed): it is among the causes
    gravity = fp.calibrate(s.outputs, -s.acc_raw, FIELD, frame="ned", units="mV")
    assert np.allclose(gravity.K, -right.K, rtol=0, atol=1e-6 * 0.09)
    assert any("the accelerometer reports gravity (down)" in w and "--acc-measures gravity" in w
               for w in gravity.summary["warnings"]), gravity.summary["warnings"]


def test_headings_unknown_mirror_said_alone_for_a_sheared_K_and_for_sensors_of_opposite_handedness():
    sheared = 0.09 * np.array([[1.0, 0.35, 0.0], [0.0, 1.0, 0.3], [0.0, 0.0, 1.0]])  # not a relabelling
    s = _shots(5, "nue", sensor=(U0, sheared))
    res = fp.calibrate(s.outputs, s.acc_raw, FIELD * [1.0, 1.0, -1.0], frame="nue", units="mV")
    said = [w for w in res.summary["warnings"] if "mirror" in w]
    assert len(said) == 1 and said[0].startswith("K is a mirror (det K < 0): the magnetometer's and "
                                                 "accelerometer's axes differ in handedness, or the reference"), said
    # the right field, but the magnetometer's z wired the other way: the data cannot tell it from the field's
    # down component reversed, so the same words
    t = _shots(5, "nue", sensor=(U0, sheared @ np.diag([1.0, 1.0, -1.0])))
    mirrored = fp.calibrate(t.outputs, t.acc_raw, FIELD, frame="nue", units="mV")
    assert any(w.startswith("K is a mirror (det K < 0)") for w in mirrored.summary["warnings"]), \
        mirrored.summary["warnings"]


def test_a_field_that_cannot_be_fitted_and_no_mistake_that_fits_keeps_the_solvers_error():
    # a field no mistake of the list explains (its dip 10°, the truth 70°): whatever the fit says stands; when
    # it fits, the misfit is said with the generic causes
    s = _shots(3, "ned")
    wrong = fp.field_from_inclination(np.linalg.norm(FIELD), 10.0)
    try:
        res = fp.calibrate(s.outputs, s.acc_raw, wrong, frame="ned", units="mV")
    except ValueError as exc:
        assert "With the" not in str(exc), str(exc)
    else:
        said = _misfit(res)
        assert said and "Check the reference field (inclination sign" in said[0], res.summary["warnings"]


# ---------------------------------------------------------------- nominal attitudes, --frame ned

def test_twelve_positions_frame_ned_a_field_given_north_up_east_is_named():
    # before: the frame's-local-axes mistake applied to --frame nue only; N,U,E (seed 002's order) given with
    # --frame ned got only the generic causes
    rng = np.random.default_rng(6)
    scene = sim.twelve_scene("ned", tilt_deg=1.0, rng=rng)
    acc = sim.Accelerometer(np.zeros(3), np.eye(3), G * np.radians(0.01))
    s = sim.simulate_positions(scene, FIELD, sensor=(U0, K), noise=0.45, accelerometer=acc, rng=rng)
    res = fp.calibrate(s.outputs, s.acc_raw, NUE, frame="ned", preset="twelve", units="mV")
    said = _misfit(res)
    assert len(said) == 1 and "it was given as N,U,E" in said[0] and "(17000, 1000, 48000)" in said[0], said
    assert not _misfit(fp.calibrate(s.outputs, s.acc_raw, FIELD, frame="ned", preset="twelve", units="mV"))


# ---------------------------------------------------------------- a body-frame reference: fit()

def _twelve_body(seed, frame="nue"):
    rng = np.random.default_rng(seed)
    scene = sim.twelve_scene(frame, tilt_deg=1.0, rng=rng)  # set to a degree, as on a bench
    s = sim.simulate_positions(scene, FIELD, sensor=(U0, K), noise=0.45, rng=rng)

    def body(field, transposed=False):  # H = Rᵀ f from the nominal attitudes (or R f: the transpose mistaken)
        return np.einsum("nij,j->ni" if transposed else "nji,j->ni", scene.nominal, fp.to_local(field, frame))
    return s, body


@pytest.mark.parametrize("frame", fp.FRAMES)
def test_body_frame_reference_that_does_not_fit_is_said_with_why_its_mistake_cannot_be_named(frame):
    # before: fit() said nothing (1650 mV residual against 0.45 mV noise: "12 parameters poorly determined")
    for seed in range(3):
        s, body = _twelve_body(seed, frame)
        right = fp.fit(s.outputs, body(FIELD), units="mV")
        assert not _misfit(right), right.summary["warnings"]
        for H in (body(FIELD * [-1.0, 1.0, 1.0]), body(FIELD * [1.0, 1.0, -1.0]), body(NUE),
                  body(FIELD, transposed=True)):
            res = fp.fit(s.outputs, H, units="mV")
            first = res.summary["warnings"][0]
            assert first.startswith("the model does not fit the body-frame reference: residual RMS"), first
            assert "no noise σ is needed to see it" in first and "cannot be told from it" in first, first
            assert "calibrate(), which names a field's mistake" in first, first
            assert res.summary["field_misfit"]["gross"], res.summary["field_misfit"]


def test_body_frame_reference_in_another_unit_than_the_readings_is_said_by_Ks_gain():
    s, body = _twelve_body(4)
    nT = sim.simulate_positions(s.scene, FIELD, sensor=(U0, np.eye(3)), noise=0.45, rng=np.random.default_rng(4))
    H = body(FIELD)
    for call in (lambda u: fp.fit(nT.outputs, H, units=u),  # and calibrate with the headings unknown
                 lambda u: fp.calibrate(nT.outputs, nT.acc_raw, FIELD, frame="nue", units=u)):
        assert not call("nT").summary["warnings"]
        said = [w for w in call("uT").summary["warnings"] if w.startswith("K's gain is")]
        assert len(said) == 1 and "not in uT (or the field not in nT)" in said[0], said


# ---------------------------------------------------------------- the command line, headings unknown

def test_cli_positions_without_a_preset_names_the_field_given_north_up_east_and_says_a_unit_once(tmp_path):
    for seed in (0, 1):  # one that fails against the field given, one that fits it badly
        s = _shots(seed, "nue")
        path = tmp_path / f"shots{seed}.csv"
        path.write_text("# units: mx=mV, my=mV, mz=mV\nax,ay,az,mx,my,mz\n" + "\n".join(
            ",".join(f"{v:.10g}" for v in [*a, *m]) for a, m in zip(s.acc_raw, s.outputs)) + "\n")
        r = run_cli("positions", path, "--frame", "nue", "--field", ",".join(f"{v:g}" for v in NUE))
        text = r.stdout + r.stderr
        # (refused: 2; fitted badly: 3, U0 and K poorly determined)
        assert r.returncode in (2, 3) and "it was given in the frame's local axes" in text, text
        assert ("warning: the model does not fit" in r.stdout) == (r.returncode == 3), text
    # readings in nT labelled uT: K's gain says it, once (calibrate's own and the command line's were one text)
    s = _shots(1, "nue", sensor=(U0, np.eye(3)))
    path = tmp_path / "nT.csv"
    path.write_text("# units: mx=uT, my=uT, mz=uT\nax,ay,az,mx,my,mz\n" + "\n".join(
        ",".join(f"{v:.10g}" for v in [*a, *m]) for a, m in zip(s.acc_raw, s.outputs)) + "\n")
    r = run_cli("positions", path, "--frame", "nue", "--field", ",".join(f"{v:g}" for v in FIELD))
    assert r.returncode == 0, r.stderr
    assert r.stdout.count("warning: K's gain is") == 1, r.stdout
