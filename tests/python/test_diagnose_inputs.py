"""Bad inputs to fluxcal.diagnose: a clear error (or warning) naming the input, never a silent wrong answer."""
import json
import re
import warnings

import numpy as np
import pytest

from fluxcal.diagnose import diagnose
from fluxcal.sim.withheld import withheld_trial


@pytest.fixture(scope="module")
def short():
    result, kwargs = withheld_trial([], 0, duration_s=10)
    return result.readings, kwargs


@pytest.mark.parametrize("sigma", [-0.05, 0.0, float("nan"), float("inf"), "abc"])
def test_bad_noise_sigma_is_named(short, sigma):
    m, kw = short
    with pytest.raises(ValueError, match="^noise_sigma: need"):
        diagnose(m, noise_sigma=sigma, **kw)


@pytest.mark.parametrize("sigma, said", [([0.05, 0.05], "or three (x, y, z), got 2 values"),
                                         ([0.05, -0.05, 0.05], "positive finite"),
                                         ([0.05, np.nan, 0.05], "positive finite"),
                                         ([[0.05, 0.05, 0.05]], "got an array of shape (1, 3)")])
def test_a_noise_sigma_per_axis_must_be_three_positive_values(short, sigma, said):
    m, kw = short
    with pytest.raises(ValueError, match=re.escape(said)):
        diagnose(m, noise_sigma=sigma, **kw)


def test_the_command_line_takes_a_noise_sigma_per_axis(tmp_path):
    # --noise-sigma σx,σy,σz: each axis weighted by its own against reference vectors; two values, or three with the
    # cable model, are refused by name
    from conftest import run_cli

    path = tmp_path / "v.csv"
    assert run_cli("simulate", "-o", path, "--effects", "misalignment", "--seed", "2").returncode == 0
    out = run_cli("diagnose", path, "--model", "vector", "--reference", "rx,ry,rz", "--noise-sigma", "0.05,0.05,0.15",
                  "--json", tmp_path / "d.json", "--quiet")
    assert out.returncode == 0, out.stderr
    assert json.loads((tmp_path / "d.json").read_text())["axis_noise"] == pytest.approx([0.05, 0.05, 0.15])
    out = run_cli("diagnose", path, "--noise-sigma", "0.05,0.05", "--quiet")
    assert out.returncode == 2 and "need one σ, or three separated by commas" in out.stderr, out.stderr
    out = run_cli("diagnose", path, "--model", "cable", "--noise-sigma", "1e-8,1e-8,1e-8", "--quiet")
    assert out.returncode == 2 and "--model cable takes one σ (tesla) for all the ring's sensors" in out.stderr, \
        out.stderr


@pytest.mark.parametrize("option", [{"alpha": 5}, {"alpha": 0}, {"alpha": 1.0}, {"max_effects": -1},
                                    {"max_effects": 1.5}, {"candidates": 3}, {"candidates": [1, 2]}])
def test_out_of_range_options_are_named(short, option):
    m, kw = short
    with pytest.raises(ValueError, match=f"^{next(iter(option))}: need"):
        diagnose(m, **option, **kw)


def test_candidates_as_one_string(short):
    m, kw = short
    for given in ("offset_drift", "offset_drift, temp_offset"):
        d = diagnose(m, candidates=given, max_effects=0, **kw)
        assert {r["effect"] for r in d.ranking} == {c.strip() for c in given.split(",")}
    with pytest.raises(ValueError, match="unknown effect.*tmp_scale"):
        diagnose(m, candidates="tmp_scale", **kw)


def test_constant_times_are_refused(short):
    m, kw = short
    with pytest.raises(ValueError, match="t: all"):
        diagnose(m, **dict(kw, t=np.zeros(len(m))))


def test_a_stuck_sensor_and_a_time_that_is_not_finite_are_named(short):
    # From a bad-input audit: 300 equal readings said "0 readings, the diagnosis needs at least 50" (every axis
    # piled up at one value, taken for a clipping rail), and a NaN time "need 300 finite times, got shape (300,)".
    m, kw = short
    with pytest.raises(ValueError, match=f"all {len(m)} readings are the same"):
        diagnose(np.tile(m[:1], (len(m), 1)), **kw)
    t = kw["t"].copy()
    t[17] = np.nan
    with pytest.raises(ValueError, match=r"t: 1 of \d+ times are not finite \(row 17: nan\)"):
        diagnose(m, **dict(kw, t=t))


def test_gravity_without_reference_warns(short):
    m, kw = short
    with pytest.warns(UserWarning, match="gravity: not used"):
        diagnose(m, gravity=np.tile([0, 0, 1.0], (len(m), 1)), candidates=[], **kw)


def test_a_given_sigma_below_the_noise_is_not_called_explained(short):
    # the trial's noise is 0.05: given 0.03, "explains the data to the noise" would be false
    m, kw = short
    low = diagnose(m, noise_sigma=0.03, **kw)
    assert low.remaining["noise_check"]["exceeds"] and low.remaining["noise_check"]["rms_over_sigma"] > 1.4
    assert "explains the data to the noise" not in low.text()
    assert "residuals exceed the given noise σ" in low.text()
    right = diagnose(m, noise_sigma=0.05, **kw)
    assert not right.accepted and not right.remaining["noise_check"]["exceeds"]
    assert "explains the data to the noise" in right.text()


def test_times_in_ms_taken_for_seconds_are_flagged(short):
    # 50 Hz logged in ms under a plain `t`: 20 "s" between readings that turn like a hand's 50 Hz log
    m, kw = short
    with pytest.warns(UserWarning, match="t: readings 20 s apart"):
        d = diagnose(m, candidates=[], **dict(kw, t=kw["t"] * 1000))
    assert any("in ms" in c and "t [ms]" in c for c in d.caveats)
    assert "CAVEAT: t:" in d.text() and d.to_dict()["caveats"] == d.caveats
    def time_caveats(d):  # (a short recording's coverage is a caveat of its own)
        return [c for c in d.caveats if c.startswith("t:")]

    assert not time_caveats(diagnose(m, candidates=[], **kw))
    slow = dict(kw, t=kw["t"] * 50)  # a slow turntable logged at 1 Hz: turns too slow for a hand even in ms
    assert not time_caveats(diagnose(m, candidates=[], **slow))


def test_a_log_appended_to_itself_is_left_out(short):
    m, kw = short
    twice = dict(kw, t=np.concatenate([kw["t"], kw["t"]]), temp=np.concatenate([kw["temp"], kw["temp"]]))
    d = diagnose(np.vstack([m, m]), candidates=[], **twice)
    assert d.where["overall"]["n"] == len(m)
    assert f"{len(m)} of {2 * len(m)} rows (from row {len(m)}) repeat earlier rows exactly" in d.noise_source
    assert "went backwards" not in d.noise_source


def test_a_still_quantised_sensor_is_no_copy():
    from fluxcal._arrays import repeated_blocks as _repeated_blocks

    rng = np.random.default_rng(0)  # three levels per axis: rows repeat all the time, but not as a block
    still = np.round(np.array([10.0, -3.0, 40.0]) + rng.normal(0, 0.5, (20000, 3)))
    assert not _repeated_blocks(still).any()
    m = rng.normal(size=(500, 3))
    copied = _repeated_blocks(np.vstack([m, m[100:300], m]))
    assert copied.sum() == 700 and not copied[:500].any()


def test_cli_prints_the_time_unit_caveat_once(short, tmp_path):
    from conftest import run_cli
    from fluxcal.io.csv import write_csv

    m, kw = short
    path = write_csv(tmp_path / "ms.csv", {"t": kw["t"] * 1000, "mx": m[:, 0], "my": m[:, 1], "mz": m[:, 2]})
    out = run_cli("diagnose", path, "--candidates", "offset_drift", "--quiet")
    assert out.returncode == 0, out.stderr
    assert "CAVEAT: t: readings 20 s apart" in out.stdout and "UserWarning" not in out.stderr


def test_a_recording_too_short_for_its_held_out_test_gets_a_caveat():
    # 5 s of a drifting offset: a passing magnet fits the stretch as well, and the held-out fits extrapolate
    result, kwargs = withheld_trial(["offset_drift"], 0, duration_s=5)
    d = diagnose(result.readings, **kwargs)
    flagged = [r for r in d.ranking if r.get("heldout_gain_unresolved")]
    assert d.accepted and flagged and all(r["effect"] in d.accepted for r in flagged)
    assert any("too short" in c for c in d.caveats) and "CAVEAT: " in d.text()
    # …and the FOUND line says they are not confirmed (a blind check's clean 100 rows read "FOUND: hysteresis")
    said = [line for line in d.text().splitlines() if line.startswith("  NOT CONFIRMED: ")]
    assert len(said) == 1 and all(r["effect"] in said[0] for r in flagged), d.text()
    result, kwargs = withheld_trial(["temp_scale"], 0)  # a minute: no caveat
    d = diagnose(result.readings, **kwargs)
    assert d.accepted == ["temp_scale"] and d.ranking[0]["heldout_gain_unresolved"] is False and not d.caveats
    assert "NOT CONFIRMED" not in d.text()


def test_readings_nearly_in_a_plane_are_named_as_such():
    # a sensor turned flat (z within ±5 % of the field) whose readings curve the wrong way across the thin
    # direction (x² + y² − z² = H²: a drift or the noise can do it): the fitted quadric is a hyperboloid; the
    # message must name the coverage, not "mixed recordings"
    rng = np.random.default_rng(0)
    phi, z = rng.uniform(0, 2 * np.pi, 3000), rng.uniform(-2.5, 2.5, 3000)
    r = np.sqrt(50.0 ** 2 + z ** 2)
    m = np.column_stack([r * np.cos(phi), r * np.sin(phi), z]) + rng.normal(0, 0.01, (3000, 3)) + [3.0, -2.0, 1.0]
    with pytest.raises(Exception, match="nearly in one plane.*not an ellipsoid.*turn the sensor about all three axes"):
        diagnose(m, field_norm=50.0)


def test_an_event_that_recurs_is_modelled_as_episodes(tmp_path):
    # a device switched on and off twice: the offset step has two episodes, each its own times and jump (it had
    # been accepted once and the second said in a caveat, not modelled)
    from fluxcal import sim
    from fluxcal.sim.scene import tumble
    from fluxcal.sim.withheld import FIELD

    rng = np.random.default_rng(1)  # a sensor as in withheld_trial
    E3 = np.triu(rng.uniform(-0.03, 0.03, (3, 3)), 1)
    W, b = np.diag(1 + rng.uniform(-0.05, 0.05, 3)) + E3 + E3.T, rng.uniform(-1, 1, 3) * 10.0 / np.sqrt(3)
    steps = [sim.effects.OffsetStep(0.75 * np.array([0.6, -0.5, 0.62]), 10.0, 20.0),
             sim.effects.OffsetStep(0.75 * np.array([-0.3, 0.8, 0.5]), 35.0, 48.0)]
    effects = [sim.SoftIron(W), sim.HardIron(b), *steps, sim.WhiteNoise(0.05)]
    res = sim.simulate(tumble(60.0, rate_hz=50.0, rng=rng), effects, FIELD, rng)
    d = diagnose(res.readings, t=res.t, temp=res.temperature, field_norm=50.0)
    assert d.accepted == ["offset_step"], d.accepted
    row = next(r for r in d.ranking if r["effect"] == "offset_step")
    episodes = sorted(row["episodes"], key=lambda e: e["on_s"])
    assert [(round(e["on_s"]), round(e["off_s"])) for e in episodes] == [(10, 20), (35, 48)], episodes
    for e, step in zip(episodes, steps):  # each its own jump, in the readings' axes
        assert np.linalg.norm(np.asarray(e["jump"]) - step.delta) < 0.05 * np.linalg.norm(step.delta), (e, step.delta)
        assert e["jump_s"] == e["on_s"] and e["back_s"] == e["off_s"]
    assert (row["on_s"], row["off_s"], row["jump"]) == (row["episodes"][0]["on_s"], row["episodes"][0]["off_s"],
                                                        row["episodes"][0]["jump"])
    text = d.text()
    assert "FOUND: offset_step (2 episodes)" in text and text.count("offset_step: the offset jumped by") == 2
    assert not any("episode" in c for c in d.caveats), d.caveats
    saved = json.loads(d.save_json(tmp_path / "d.json").read_text())  # the JSON keeps each episode
    row = next(r for r in saved["ranking"] if r["effect"] == "offset_step")
    assert [e["jump_s"] for e in row["episodes"]] == [e["on_s"] for e in d.ranking[0]["episodes"]]


def test_an_offset_step_reads_the_same_in_the_json_as_in_the_text():
    # a step that stays may be fitted as the stretch before it (a box from the start, coefficients reversed):
    # the JSON says the jump as the text does; the text's MAYBE TEMPERATURE is in the JSON too
    from fluxcal import sim
    from fluxcal.sim.scene import tumble
    from fluxcal.sim.withheld import FIELD

    rng = np.random.default_rng(3)
    delta = np.array([0.5, -0.4, 0.45])
    effects = [sim.HardIron([4.0, -3.0, 2.0]), sim.effects.OffsetStep(delta, 20.0), sim.WhiteNoise(0.05)]
    res = sim.simulate(tumble(60.0, rate_hz=50.0, rng=rng), effects, FIELD, rng)
    d = diagnose(res.readings, t=res.t, field_norm=50.0)
    assert d.accepted[0] == "offset_step"
    row = d.to_dict()["ranking"][0]
    assert np.allclose(row["jump"], delta, atol=0.05) and abs(row["jump_s"] - 20.0) < 0.1 and row["back_s"] is None
    assert f"jumped by {np.round(row['jump'], 4).tolist()}" in d.text()
    assert any(line.startswith("MAYBE TEMPERATURE") for line in d.to_dict()["explanations"])


def test_positions_held_at_1_hz_are_no_times_in_ms():
    # a multi-position log at 1 Hz: between held readings the direction turns by the noise only
    from scipy.spatial.transform import Rotation

    from fluxcal import sim
    from fluxcal.sim.scene import Scene
    from fluxcal.sim.withheld import FIELD

    rng = np.random.default_rng(3)
    at = Rotation.random(12, random_state=rng)[np.repeat(np.arange(12), 5)]
    effects = [sim.SoftIron(np.diag([1.03, 0.97, 1.01])), sim.HardIron([4.0, -3.0, 2.0]), sim.WhiteNoise(0.05)]
    result = sim.simulate(Scene(at, np.arange(60, dtype=float)), effects, FIELD, rng)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        d = diagnose(result.readings, t=result.t, field_norm=50.0, candidates=[])
    assert not [c for c in d.caveats if c.startswith("t:")]  # 12 positions: their coverage is a caveat of its own


def test_hard_clipping_is_named_saturation_and_its_censored_edge_is_not_a_cubic():
    """A range too small for the field plus hard iron clips an axis at the ADC rail (8 % of the readings
    here). It is said as such, and the readings just inside the rail, biased inwards because the noise that
    would have taken them past it was cut, are left out with them: no compression is left for a cubic."""
    sim_, kw = withheld_trial([], seed=5, duration_s=180.0)
    m = sim_.readings.copy()
    rail = float(np.quantile(m[:, 2], 0.92))
    m[:, 2] = np.minimum(m[:, 2], rail)
    d = diagnose(m, t=kw["t"], temp=kw["temp"], field_norm=kw["field_norm"], progress=False)
    assert [c["axis"] for c in d.clipping] == ["z"] and d.clipping[0]["rail"] == rail
    assert 0.07 < d.clipping[0]["fraction"] < 0.09
    assert not d.accepted, d.accepted
    assert "SATURATES (hard clipping): the sensor's range cuts its readings at z = " in d.text()
    # an analog front end that saturates before a noisy converter: the rail blurred by the noise (a blind check's was
    # named a 16–24 % cubic non-linearity, 6–11 σ left); a reading on two rails counted once ("the -258 within 3 σ")
    m = sim_.readings.copy()
    blurred = m[:, 2] > rail
    m[blurred, 2] = rail + np.random.default_rng(1).normal(0.0, 0.05, blurred.sum())
    d = diagnose(m, t=kw["t"], temp=kw["temp"], field_norm=kw["field_norm"], progress=False)
    assert [(c["axis"], c["noisy"]) for c in d.clipping] == [("z", True)] and abs(d.clipping[0]["rail"] - rail) < 0.02
    assert not d.accepted, d.accepted
    assert re.search(r"blurred by the noise\)\): those and the [0-9]+ within 3 σ", d.text()), d.text()
    # a coarse ADC's extreme code is as full as its neighbours: not a rail
    coarse = np.round(sim_.readings / 0.6) * 0.6
    assert diagnose(coarse, t=kw["t"], temp=kw["temp"], field_norm=kw["field_norm"], progress=False,
                            candidates=["quantization"]).clipping == []


def test_a_short_clipping_episode_at_the_other_rail_is_found_beside_a_long_one():
    """A front end that saturates before a noisy converter, cut at both ends: 8 % of the readings at the top rail,
    one pass 66 readings past the bottom one (0.45 µT, 9 σ, at its deepest), its way in and out as many again. The
    short one was judged beside the top rail's uncut readings, and its band held too few more than the band inward
    of it: a blind check's such episodes were missed in 7 of 30 and named a moving dipole (here: two). Both rails
    are found now, and nothing is left for an effect."""
    sim_, kw = withheld_trial([], seed=7, duration_s=180.0)
    m, z = sim_.readings.copy(), sim_.readings[:, 2]
    deepest = int(np.argmin(z))
    bottom, top = float(min(z[deepest - 9], z[deepest + 8])), float(np.quantile(z, 0.92))
    noise = np.random.default_rng(1)
    for rail, side in ((top, 1.0), (bottom, -1.0)):
        past = side * (m[:, 2] - rail) > 0
        m[past, 2] = rail + noise.normal(0.0, 0.05, past.sum())
    d = diagnose(m, t=kw["t"], temp=kw["temp"], field_norm=kw["field_norm"], progress=False)
    assert [(c["axis"], c["noisy"]) for c in d.clipping] == [("z", True), ("z", True)], d.clipping
    assert abs(d.clipping[0]["rail"] - bottom) < 0.05 and abs(d.clipping[1]["rail"] - top) < 0.05
    assert 60 <= d.clipping[0]["readings"] <= 2 * np.sum(z < bottom), d.clipping
    assert not d.accepted, d.accepted


def test_thermometer_error_codes_are_interpolated_and_a_constant_column_is_said():
    """15 of the temperatures replaced by a DS18B20's error codes (85 °C, −127 °C) made a 3 s thermal lag and a
    colored_noise the clean recording has not, unsaid; a stuck thermometer (constant) read "without a temperature
    column" (a blind check). The codes are interpolated, said; the diagnosis is the clean one's."""
    result, kw = withheld_trial(["temp_offset"], 3)
    clean = diagnose(result.readings, **kw)
    temp = np.array(kw["temp"], dtype=float)
    rows = np.linspace(300, len(temp) - 300, 15).astype(int)
    temp[rows[::2]], temp[rows[1::2]] = 85.0, -127.0
    d = diagnose(result.readings, **{**kw, "temp": temp})
    assert d.accepted == clean.accepted == ["temp_offset"], (d.accepted, clean.accepted)
    assert "15 temperature reading(s) leave its course" in d.noise_source and "interpolated" in d.noise_source
    row, clean_row = d.ranking[0], clean.ranking[0]
    np.testing.assert_allclose(row["coefficients"], clean_row["coefficients"], rtol=0.02, atol=1e-6)
    stuck = diagnose(result.readings, **{**kw, "temp": np.full(len(temp), 25.0)})
    assert "its temperature column is constant (25)" in stuck.noise_source


def test_temperature_and_current_columns_under_other_names_are_taken_when_named(tmp_path):
    """`T` and `motor_I` were ignored by name and nothing could point diagnose at them (a blind check):
    --temp-column and --current-column name them, converted by their unit."""
    from conftest import run_cli
    from fluxcal.io.csv import write_csv

    result, kw = withheld_trial(["temp_offset"], 3)
    m = result.readings
    path = write_csv(tmp_path / "T.csv", {"t": kw["t"], "mx": m[:, 0], "my": m[:, 1], "mz": m[:, 2],
                                          "T": np.asarray(kw["temp"]) * 1.8 + 32.0}, units={"T": "degF"})
    out = run_cli("diagnose", path, "--quiet", "--temp-column", "T", "--candidates", "temp_offset,offset_drift")
    assert out.returncode == 0 and "temperature: column T (--temp-column)" in out.stdout, out.stdout + out.stderr
    assert "FOUND: temp_offset" in out.stdout, out.stdout
    out = run_cli("diagnose", path, "--quiet", "--current-column", "I")
    assert out.returncode == 2 and "no column 'I' (--current-column" in out.stderr, out.stderr


def test_readings_in_another_unit_than_stated_are_warned_of(tmp_path):
    """nT readings stated as µT: calibrate warned, diagnose printed every size 1000× in µT unsaid (a blind check)."""
    from conftest import run_cli
    from fluxcal.io.csv import write_csv

    result, kw = withheld_trial([], 4)
    m = result.readings * 1000.0  # the simulation's µT in nT
    path = write_csv(tmp_path / "nT.csv", {"t": kw["t"], "mx": m[:, 0], "my": m[:, 1], "mz": m[:, 2]})
    for units, warned in (("uT", True), ("nT", False)):
        out = run_cli("diagnose", path, "--quiet", "--units", units, "--candidates", "offset_drift")
        assert out.returncode == 0, out.stderr
        assert ("far from the Earth's field" in out.stdout) == warned, out.stdout


def test_no_readings_and_a_missing_temperature_are_named():
    # From a blind check: an empty array raised an IndexError from the clipping screen, and a temperature's NaN was
    # counted without its row
    import fluxcal

    with pytest.raises(ValueError, match="samples: 0 readings, the diagnosis needs at least 50"):
        fluxcal.diagnose(np.zeros((0, 3)))
    t = np.arange(600.0)
    m = np.random.default_rng(0).normal(0, 0.1, (600, 3)) + [30.0, 0.0, 40.0]
    temp = 20 + t / 100
    temp[7] = np.nan
    with pytest.raises(ValueError, match=r"temp: 1 of the 600 temperatures are not finite \(row 7: nan\)"):
        fluxcal.diagnose(m, t=t, temp=temp)
