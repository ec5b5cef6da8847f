"""The sim-to-real diagnosis, checked blind on simulations with withheld effects (fluxcal.sim.withheld):
the diagnosis sees only readings, time and temperature; candidates are fitted, never looked up."""
import importlib
import json
import re

import numpy as np
import pytest
from conftest import run_cli

import fluxcal
from fluxcal import sim
from fluxcal.diagnose import diagnose, estimate_noise
from fluxcal.diagnose.report import text as report_text
from fluxcal.oracle.refine import refine_terms as oracle_refine_terms
from fluxcal.sim.effects import CANDIDATES
from fluxcal.sim.withheld import NOISE, withheld_trial

TRIALS = 10
EFFECTS = [c.name for c in CANDIDATES]


def _run(names, seed):
    result, kwargs = withheld_trial(names, seed)
    return diagnose(result.readings, **kwargs)


@pytest.mark.parametrize("name", EFFECTS)
def test_withheld_effect_ranks_first_and_closes_the_gap(name):
    hits, alone, shrinks = 0, 0, []
    for seed in range(TRIALS):
        d = _run([name], seed)
        top = d.ranking[0]
        alone += d.accepted == [name]
        if top["effect"] == name and top["significant"] and not d.confounded:
            hits += 1
            shrinks.append(1 - top["heldout_gap_after"] / top["heldout_gap_before"])
    assert hits >= 0.9 * TRIALS, f"{name} ranked first and significant in {hits}/{TRIALS}"
    assert alone >= 0.8 * TRIALS, f"{name} found with no spurious extra effect in only {alone}/{TRIALS}"
    assert np.median(shrinks) >= 0.7, f"{name}: held-out gap shrinks {np.round(shrinks, 2)}"


def test_a_profiles_gain_is_what_least_squares_takes():
    # A profile's gain at each value (core._taken_by: the normal equations of the unit-norm columns) is the part of
    # the residuals numpy's SVD-based lstsq takes: on well-conditioned columns, nearly collinear ones, a zero column,
    # one column, and columns whose norms differ by 1e15 (lstsq drops the small one's direction there).
    from fluxcal.diagnose.core import _taken_by

    rng = np.random.default_rng(5)
    for trial in range(300):
        n, p = int(rng.integers(8, 600)), int(rng.integers(1, 7))
        R = rng.normal(size=(n, p)) * 10.0 ** rng.uniform(-2, 2, size=p)
        if trial % 5 == 1:
            R[:, 0] = 0.0
        if trial % 5 == 2 and p > 1:
            R[:, -1] = 3.0 * R[:, 0] + 1e-7 * rng.normal(size=n)
        if trial % 5 == 3:
            R[:, 0] *= 1e-15 / np.linalg.norm(R[:, 0]) * np.linalg.norm(R, axis=0).max()
        e = rng.normal(size=n) + R @ rng.normal(size=p)
        coef, *_ = np.linalg.lstsq(R, e, rcond=None)
        assert _taken_by(R, e) == pytest.approx(float(np.sum((R @ coef) ** 2)), rel=1e-6), trial
    # two columns 2.1e-5 … 2e-4 rad apart (Gram condition 1e10 … 1e8: θ²/4), the residuals along their difference:
    # the normal equations' weakest direction (a review found 3.5e-6 off at a 1e10 cut; the cut is 1e8 now)
    for trial, angle in enumerate(np.geomspace(2.1e-5, 2e-4, 60)):
        a, q = rng.normal(size=(2, 2000))
        a /= np.linalg.norm(a)
        q -= a * (a @ q)
        q /= np.linalg.norm(q)
        R = np.column_stack([a, np.cos(angle) * a + np.sin(angle) * q]) * rng.uniform(1, 1e4, size=2)
        e = q + 1e-3 * rng.normal(size=2000)
        coef, *_ = np.linalg.lstsq(R, e, rcond=None)
        assert _taken_by(R, e) == pytest.approx(float(np.sum((R @ coef) ** 2)), rel=1e-6), (trial, angle)
    assert _taken_by(np.zeros((10, 0)), np.ones(10)) == 0.0
    R[0, 1] = np.nan  # as lstsq: no finite answer from a column that is not finite
    with pytest.raises(np.linalg.LinAlgError):
        _taken_by(R, e)


def test_events_scored_at_once_score_as_each_on_its_own_readings(monkeypatch):
    # The event searches score their coarse scans at once (core._EventScores): ~530 boxes in time from running sums
    # over the readings, ~600 passes of a magnet in one padded stack. Each score must be the one the event's own
    # readings give (score_on), against magnitudes (a step: a constant per axis; a magnet along the field) and
    # against reference vectors (a magnet in the world frame).
    events, compared = importlib.import_module("fluxcal.diagnose.core")._EventScores, {"boxes": [], "passes": []}
    boxes, passes = events.boxes, events.passes

    def boxes_and_own(self, cls, ctx, edges):
        fast = boxes(self, cls, ctx, edges)
        compared["boxes"] += [(f, self.score_on(*cls._box_rows(ctx, *ab)), self.vector) for f, ab in zip(fast, edges)]
        return fast

    def passes_and_own(self, cls, ctx, closest, t_pass):
        fast = passes(self, cls, ctx, closest, t_pass)
        compared["passes"] += [(f, self.score_on(*cls._pass_rows(ctx, c, t_pass)), self.vector)
                               for f, c in zip(fast, closest)]
        return fast

    monkeypatch.setattr(events, "boxes", boxes_and_own)
    monkeypatch.setattr(events, "passes", passes_and_own)
    for names, model in ((["offset_step"], None), (["moving_dipole"], "vector")):
        result, kwargs = withheld_trial(names, 0, model=model)
        d = diagnose(result.readings, **kwargs)
        assert d.accepted == names
        truth = next(effect for effect in result.effects if effect.name == names[0])
        if names == ["offset_step"]:  # a step that stays (t_off = ∞) is told as on from its time, not as on from the
            # recording's start until then: the two boxes tie, and rounding had picked either
            assert np.isinf(truth.t_off) and d.ranking[0]["off_s"] is None, d.ranking[0]
            assert abs(d.ranking[0]["on_s"] - truth.t_on) < 0.2
    for kind, tolerance in (("boxes", 1e-6), ("passes", 1e-12)):  # (boxes: powers of time across the recording)
        fast, own, vector = np.array(compared[kind]).T
        assert len(own) > 1000 and vector.any() and not vector.all(), kind
        np.testing.assert_allclose(fast, own, rtol=tolerance, atol=1e-9 * own.max(), err_msg=kind)


@pytest.mark.parametrize("pair", [("temp_offset", "nonlinearity_cubic"), ("offset_drift", "cross_axis"),
                                  ("temp_scale", "hysteresis"), ("motor_current", "temp_offset"),
                                  ("moving_dipole", "offset_step"), ("moving_dipole", "temp_offset")])
def test_two_withheld_effects_are_both_found(pair):
    found = sum(set(pair) <= set(_run(list(pair), 100 + seed).accepted) for seed in range(5))
    assert found >= 4, f"{pair} both found in {found}/5"


def _warm_up(t):
    return 20.0 + 15.0 * t / t[-1]  # a linear warm-up: the temperature follows time exactly


@pytest.mark.parametrize("name", ["offset_drift", "temp_offset", "scale_drift", "temp_scale"])
def test_temperature_that_follows_time_is_reported_as_a_confound(name):
    # An offset (a sensitivity) drifting in time and one drifting with temperature leave the same signature
    # when the temperature rises linearly: the diagnosis must say it cannot tell them apart, not pick one
    # silently.
    pair = {"offset_drift", "temp_offset"} if "offset" in name else {"scale_drift", "temp_scale"}
    for seed in range(2):
        result, kwargs = withheld_trial([name], seed, temperature=_warm_up)
        d = diagnose(result.readings, **kwargs)
        assert len(d.accepted) == 1 and d.accepted[0] in pair, d.accepted
        rivals = d.confounded[d.accepted[0]]
        assert [r["effect"] for r in rivals] == list(pair - set(d.accepted))
        assert rivals[0]["temperature_time_correlation"] > 0.999
        assert abs(rivals[0]["delta_bic_difference"]) < 1.0
        assert "CANNOT TELL APART" in d.text() and "follows time" in d.text()
        assert json.loads(json.dumps(d.to_dict(), default=float))["confounded"] == d.confounded


def test_a_second_effect_is_not_taken_for_a_rival():
    # offset_drift and cross_axis both withheld under a linear warm-up: temp_offset is offset_drift's rival
    # (its evidence collapses once offset_drift is in), cross_axis is a second effect. With max_effects=1
    # the search stops after one: the other significant one is reported as not modelled, not hidden.
    result, kwargs = withheld_trial(["offset_drift", "cross_axis"], 1, temperature=_warm_up)
    d = diagnose(result.readings, **kwargs)
    assert set(d.accepted) >= {"cross_axis"} and len(set(d.accepted) & {"offset_drift", "temp_offset"}) == 1
    drift = (set(d.accepted) & {"offset_drift", "temp_offset"}).pop()
    assert [r["effect"] for r in d.confounded[drift]] == list({"offset_drift", "temp_offset"} - {drift})
    assert "cross_axis" not in d.confounded
    one = diagnose(result.readings, **kwargs, max_effects=1)
    extra = [r["effect"] for r in one.ranking if r["significant_not_modelled"]]
    assert len(one.accepted) == 1 and extra and one.accepted[0] not in extra
    assert "ALSO SIGNIFICANT, not modelled" in one.text()


def test_confound_report_words():
    from fluxcal.diagnose.report import confound_lines

    def fake(regime_a, regime_b, corr=None):
        rival = {"effect": "b", "regime": regime_b, "delta_bic_difference": 2.0, "signature_correlation": 0.97}
        if corr is not None:
            rival["temperature_time_correlation"] = corr
        rows = [{"effect": "a", "regime": regime_a, "confounded_with": [rival]}, {"effect": "b", "regime": regime_b}]
        return "\n".join(confound_lines(type("D", (), {"ranking": rows, "confounded": {"a": [rival]}})()))

    assert "follows time here (r = 0.995)" in fake("temperature", "time", 0.995)
    weak = fake("temperature", "time", 0.3)  # a weak correlation is not the explanation
    assert "follows time" not in weak and "the temperature and the elapsed time vary independently" in weak
    assert "Both were held out on the orientation" in fake("orientation", "orientation")


def test_a_curved_warm_up_lets_the_data_decide():
    # A warm-up whose temperature is not a straight line in time (an S-curve over a minute, r(T, t) ≈ 0.96):
    # temperature no longer follows time, the right effect wins by a wide ΔBIC margin and nothing is flagged.
    for name in ("offset_drift", "temp_offset"):
        result, kwargs = withheld_trial([name], 7, temperature=lambda t: 20.0 + 15.0 / (1 + np.exp(-(t - 30.0) / 6.0)))
        d = diagnose(result.readings, **kwargs)
        assert d.accepted == [name] and not d.confounded, (d.accepted, d.confounded)


def test_an_exponential_warm_up_is_an_offset_settling_in_time():
    # A temperature rising exponentially (τ = 30 s): an offset following it is an offset settling in time
    # with that time constant (offset_drift's profiled warm-up), one parameter dearer: found, and said to be
    # confounded with the settling, which only a temperature off that curve could tell apart.
    result, kwargs = withheld_trial(["temp_offset"], 7, temperature=lambda t: 20.0 + 15.0 * (1 - np.exp(-t / 30.0)))
    d = diagnose(result.readings, **kwargs)
    assert d.accepted == ["temp_offset"]
    assert [r["effect"] for r in d.confounded["temp_offset"]] == ["offset_drift"]


def test_a_warm_up_logged_with_a_noisy_or_coarse_thermometer_is_not_told_from_a_drift(monkeypatch):
    """An offset that follows a warm-up's temperature (10× the typical, 1.5–3 µT over 15 °C), logged with 0.02 °C of
    noise or to 0.25 °C: the drift's smooth law fits it better than the logged temperature by what that logging costs
    (ΔBIC 15–160), and a blind check's reports named offset_drift alone, with "or log its temperature" beside a
    temperature logged. The two are now said not to be told apart; the exact S-curve above still is."""
    from fluxcal.sim.effects import TemperatureOffset

    typical = TemperatureOffset.typical.__func__

    def larger(cls, field_norm, rng):
        effect = typical(cls, field_norm, rng)
        effect.beta = 10.0 * effect.beta
        return effect

    monkeypatch.setattr(TemperatureOffset, "typical", classmethod(larger))
    for seed, logged in ((8, lambda T: T + np.random.default_rng(8).normal(0.0, 0.02, T.size)),
                         (7, lambda T: 0.25 * np.round(T / 0.25))):
        result, kwargs = withheld_trial(["temp_offset"], seed,
                                        temperature=lambda t: 20.0 + 15.0 * (1 - np.exp(-t / 30.0)))
        kwargs["temp"] = logged(np.asarray(kwargs["temp"], dtype=float))
        d = diagnose(result.readings, **kwargs)
        assert d.accepted == ["offset_drift"], d.accepted
        assert [r["effect"] for r in d.confounded["offset_drift"]] == ["temp_offset"], d.confounded
        text = d.text()
        assert "CANNOT TELL APART: offset_drift and temp_offset take out the same departure" in text, text
        assert "or log its temperature" not in text, text


@pytest.mark.parametrize("name", ["temp_scale", "scale_drift", "nonlinearity_cubic"])
def test_an_electronic_offset_is_told_from_a_hard_iron(monkeypatch, name):
    # A sensor's own (electronic) offset is added after its transducer; a platform's hard iron is a field the
    # transducer's gain and non-linearity act on. Both forms are tried. Before, about an electronic offset of two
    # fields, a gain needed a companion offset term (temp_offset beside temp_scale) or with the same sign on every
    # axis was taken for a passing magnet, and a cubic was missed (coloured noise). The row says which form.
    from fluxcal.sim.effects import ScaleDrift, TemperatureScale

    if name != "nonlinearity_cubic":
        cls, field = (TemperatureScale, "alpha") if name == "temp_scale" else (ScaleDrift, "rate")
        typical = cls.typical.__func__

        def same_sign(c, *args):
            effect = typical(c, *args)
            setattr(effect, field, np.abs(getattr(effect, field)))
            return effect

        monkeypatch.setattr(cls, "typical", classmethod(same_sign))
    # (seed 1's same-sign gain drifting in time is taken for the field changing along itself, flagged CANNOT TELL
    # APART: a magnitude can hardly tell the two apart, bench/RESULTS.md)
    for electronic, kind in ((True, "electronic"), (False, "hard_iron")):
        for seed in (0, 2):
            result, kwargs = withheld_trial([name], seed, hard_iron=2.0, electronic_offset=electronic)
            d = diagnose(result.readings, **kwargs)
            assert d.accepted == [name], (electronic, seed, d.accepted)
            assert d.ranking[0]["offset_kind"] == kind, (electronic, seed, d.ranking[0].get("offset_kind"))
            words = "leaves the offset as it is" if electronic else "acts on the offset too"
            assert words in report_text(d), (electronic, seed)


def test_a_wide_hysteresis_loop_is_hysteresis(monkeypatch):
    # A loop 5–10 µT wide (a tenth to a fifth of the field) of which 4–5 % is irreversible: the play widths tried
    # stopped at 0.8 % of the field, and such a loop was taken for a cubic or saturation plus coloured noise.
    from fluxcal.sim.effects import Hysteresis

    monkeypatch.setattr(Hysteresis, "typical",
                        classmethod(lambda cls, field_norm, rng: cls(field_norm * rng.uniform(0.1, 0.2, 3),
                                                                     share=rng.uniform(0.04, 0.05))))
    found = [diagnose(r.readings, **kw).accepted for r, kw in (withheld_trial(["hysteresis"], seed) for seed in range(4))]
    assert all(a[:1] == ["hysteresis"] for a in found), found
    # one width for every axis (each has its own here): what it leaves may still look like something else
    assert sum(not {"nonlinearity_cubic", "saturation"} & set(a) for a in found) >= 3, found


def test_a_hysteresis_loop_width_is_measured(monkeypatch):
    # One play 2.5 µT wide (5 % of the field) moving 60 % of the output, about a hard iron of two fields: the width
    # is profiled, at the signal of the fit that models the loop (the base fit's matrix takes the loop's mean loss
    # of gain; profiled at its signal, a blind check's loop like this one left 3.1 σ to coloured noise).
    from fluxcal.sim.effects import Hysteresis

    monkeypatch.setattr(Hysteresis, "typical", classmethod(lambda cls, field_norm, rng: cls(np.full(3, 0.05 * field_norm),
                                                                                             share=0.6)))
    for seed in range(2):
        result, kwargs = withheld_trial(["hysteresis"], seed, hard_iron=2.0)
        d = diagnose(result.readings, **kwargs)
        assert d.accepted == ["hysteresis"], (seed, d.accepted)
        assert d.ranking[0]["width"] == pytest.approx(2.5, rel=0.05), (seed, d.ranking[0]["width"])
        assert np.allclose(d.ranking[0]["coefficients"], 0.6 * 2.5, rtol=0.1), (seed, d.ranking[0]["coefficients"])


def test_hysteresis_is_no_temperature_lookalike():
    # Held out in time like a drift, but it follows how the field moved: no warming sensor looks like it, and the
    # MAYBE TEMPERATURE caveat named it (a helper's blind check), beside colored_noise, which a warming can be.
    from types import SimpleNamespace

    from fluxcal.diagnose.report import temperature_caveat

    d = SimpleNamespace(remaining={"skipped_candidates": ["temp_scale", "temp_offset"]},
                        ranking=[{"effect": "hysteresis", "regime": "time"}, {"effect": "colored_noise", "regime": "time"}],
                        accepted=["hysteresis", "colored_noise"])
    (line,) = temperature_caveat(d)
    assert line.startswith("MAYBE TEMPERATURE: colored_noise follow(s) time"), line
    assert temperature_caveat(SimpleNamespace(**{**vars(d), "accepted": ["hysteresis"]})) == []


def test_nothing_withheld_reports_nothing():
    quiet = sum(not _run([], 200 + seed).significant for seed in range(20))
    assert quiet >= 19, f"no significant effect in only {quiet}/20"


def test_downstream_heading_error_with_an_accelerometer():
    # A misaligned sensor against reference vectors: modelling the misalignment must bring the held-out
    # heading error (horizontal projections of h and r, about the down direction) down with the field error.
    # Accepted, the rotation is modelled exactly (not to first order), so its second-order part is not
    # taken for non-orthogonal axes, and the angles come out as simulated.
    for seed in range(3):
        result, kwargs = withheld_trial(["misalignment"], seed)
        d = diagnose(result.readings, **kwargs)
        top = d.ranking[0]
        assert d.accepted == ["misalignment"], d.accepted
        truth = next(e.rotvec for e in result.effects if e.name == "misalignment")
        assert np.max(np.abs(np.asarray(top["rotation_deg"]) - np.degrees(truth))) < 0.05
        assert top["heading_error_deg_before"] > 1.0
        assert top["heading_error_deg_after"] < 0.25 * top["heading_error_deg_before"]
        assert top["direction_error_deg_after"] < 0.25 * top["direction_error_deg_before"]
        assert top["field_error_after"] < 0.25 * top["field_error_before"]


def test_rotation_refit_by_later_rounds_is_folded_in():
    # A second effect accepted after the misalignment: the later rounds refit the rotation's block, and
    # the reported angles include what they moved.
    result, kwargs = withheld_trial(["misalignment", "temp_offset"], 0)
    d = diagnose(result.readings, **kwargs)
    assert {"misalignment", "temp_offset"} <= set(d.accepted), d.accepted
    k = next(i for i, r in enumerate(d.ranking) if r["effect"] == "misalignment")
    truth = next(e.rotvec for e in result.effects if e.name == "misalignment")
    assert np.max(np.abs(np.asarray(d.ranking[k]["rotation_deg"]) - np.degrees(truth))) < 0.05
    saved = json.loads(json.dumps(d.to_dict(), default=float))
    assert saved["ranking"][k]["rotation_deg"] == d.ranking[k]["rotation_deg"]
    assert "misalignment: rotation vector" in d.text()


def test_a_time_offset_is_measured_as_a_delay():
    # Readings logged late (or early) against their reference vectors: found alone, modelled as an exact
    # delay of the reference (not to first order), so the delay comes out as simulated, either sign.
    for seed, word in ((0, "behind"), (1, "ahead of")):
        result, kwargs = withheld_trial(["time_offset"], seed)
        d = diagnose(result.readings, **kwargs)
        assert d.accepted == ["time_offset"], d.accepted
        truth = next(e.delta for e in result.effects if e.name == "time_offset")
        assert abs(d.ranking[0]["delay_ms"] - 1e3 * truth) < 0.1, (d.ranking[0]["delay_ms"], truth)
        assert d.ranking[0]["heldout_gap_after"] < 0.25 * d.ranking[0]["heldout_gap_before"]
        assert f"ms {word} the reference vectors" in d.text()


def test_an_eddy_current_is_not_taken_for_a_time_offset():
    # A delay is an eddy current with one τ on every axis; a real eddy current (different τ per axis,
    # always a lag) against reference vectors must stay an eddy current.
    for seed in range(3):
        result, kwargs = withheld_trial(["eddy_current"], seed, model="vector")
        d = diagnose(result.readings, **kwargs)
        assert d.accepted == ["eddy_current"], d.accepted
    # the report says what absorbed a candidate: the eddy term (a delay is its first order), or the base's matrix
    lines = {line.split()[0]: line for line in d.text().splitlines() if "(absorbed" in line}
    assert lines["time_offset"].endswith("(absorbed once eddy_current was modelled)")
    assert lines["misalignment"].endswith("(absorbed)")


def test_a_long_delay_in_a_real_flight_is_a_delay_not_eddy_currents(real_data):
    """A blind check delayed the airborne readings by 150 ms against their IGRF/attitude reference: eddy_current
    took it (τ 171–191 ms on all three axes) and time_offset was then absorbed. The same lag on every axis is a
    delay; measured against the untouched slice's own."""
    rec = fluxcal.read_recording(real_data / "airborne_flt1002_02.tsv")
    rows = slice(2000, 6000)
    m, ref, t = rec.samples()[rows], rec.reference_field()[rows], rec.time()[rows]
    late = np.column_stack([np.interp(t - 0.15, t, m[:, k]) for k in range(3)])[20:]
    candidates = ["time_offset", "eddy_current"]
    own = diagnose(m[20:], reference=ref[20:], t=t[20:], model="vector", candidates=["time_offset"])  # its own lag
    d = diagnose(late, reference=ref[20:], t=t[20:], model="vector", candidates=candidates)
    assert d.accepted[:1] == ["time_offset"], d.text()
    delay = {r["effect"]: r for r in d.ranking}["time_offset"]["delay_ms"]
    base = own.ranking[0]["delay_ms"]
    assert delay - base == pytest.approx(150.0, abs=5.0), (delay, base)
    from fluxcal.sim.effects import EddyCurrent
    assert "a delay between the readings" in EddyCurrent.unphysical([0.171, 0.178, 0.191], [1e-3] * 3, vector=True,
                                                                    period=0.1)
    assert EddyCurrent.unphysical([0.001, 0.0012, 0.004], [1e-4] * 3, vector=True, period=0.01) == ""  # a housing's
    assert EddyCurrent.unphysical([0.0264, 0.0266, 0.0379], [5e-4] * 3, vector=True, period=0.1) == ""  # the flight's
    assert EddyCurrent.unphysical([0.171, 0.178, 0.191], [1e-3] * 3, period=0.1) == ""  # magnitudes: no delay shows
    assert "delay" in EddyCurrent.unphysical([-0.15, -0.16, -0.17], [1e-3] * 3, vector=True, period=0.1)  # ahead
    assert "only ever make it lag" in EddyCurrent.unphysical([-0.002, -0.003, -0.004], [1e-4] * 3)


def test_an_offset_step_is_timed_and_sized():
    # A jump of the sensor-frame offset (perming, a device switched on, and off again): when and by how
    # much, either way the fitted box lies (after the jump, or before it with the opposite sign), against
    # magnitudes and against reference vectors.
    for seed, model in ((0, None), (1, None), (3, None), (2, "vector")):
        result, kwargs = withheld_trial(["offset_step"], seed, model=model)
        d = diagnose(result.readings, **kwargs, units="uT")
        assert d.accepted == ["offset_step"], d.accepted
        truth = next(e for e in result.effects if e.name == "offset_step")
        row = d.ranking[0]
        at, sign = (row["off_s"], -1) if row["on_s"] is None else (row["on_s"], 1)
        assert abs(at - truth.t_on) < 0.2, (row["on_s"], row["off_s"], truth.t_on)
        back = row["off_s"] if row["on_s"] is not None else None
        assert (back is None) == np.isinf(truth.t_off) and (back is None or abs(back - truth.t_off) < 0.2)
        z = (sign * np.asarray(row["coefficients"]) - truth.delta) / np.asarray(row["standard_errors"])
        assert np.all(np.abs(z) < 4), z
        line = next(x for x in d.text().splitlines() if "offset_step: the offset jumped by" in x)
        assert f"at t = {at:.4g} s" in line and "% of the field" in line
        assert ("came back" in line) == (back is not None)


def test_a_step_that_stays_is_not_said_to_come_back_in_the_last_seconds():
    # The box search moves an edge inside for BIC's price in the plain ratio, which correlated noise pays: seed 15's
    # step (34.67 s, stays) had "came back at t = 58.7 s" of 60. An edge in the first or last grid cell must pay under
    # the residuals' correlation; a real return there does (a 2 % step back 1 s before the end, white noise).
    result, kwargs = withheld_trial(["offset_step", "colored_noise"], 15)
    d = diagnose(result.readings, **kwargs, units="uT")
    row = next(r for r in d.ranking if r["effect"] == "offset_step")
    assert "offset_step" in d.accepted and row["off_s"] is None and abs(row["on_s"] - 34.67) < 1.5, row
    line = next(x for x in d.text().splitlines() if "offset_step: the offset jumped by" in x)
    assert "and stayed" in line, line
    clean, kwargs = withheld_trial([], 0)
    t = kwargs["t"]
    jump = np.outer((t >= 20.0) & (t <= t[-1] - 1.0), [0.6, -0.5, 0.62])  # 1 uT, 2 % of the field
    d = diagnose(clean.readings + jump, **kwargs, units="uT")
    row = next(r for r in d.ranking if r["effect"] == "offset_step")
    assert d.accepted == ["offset_step"] and abs(row["off_s"] - (t[-1] - 1.0)) < 0.1, (d.accepted, row)


def test_an_offset_step_without_timestamps_is_placed_by_row():
    result, kwargs = withheld_trial(["offset_step"], 0)
    d = diagnose(result.readings, temp=kwargs["temp"], field_norm=50.0)  # no t: the row number is the time
    assert d.accepted == ["offset_step"], d.accepted
    line = next(x for x in d.text().splitlines() if "offset_step: the offset jumped by" in x)
    assert "at row " in line and " s " not in line, line


def test_a_clock_coarser_than_the_readings_is_spread_not_a_crash():
    # Whole-second timestamps at 50 Hz: 49 of every 50 rows repeat t (a ZeroDivisionError before).
    result, kwargs = withheld_trial(["offset_step"], 0)
    kwargs["t"] = np.floor(kwargs["t"])
    d = diagnose(result.readings, **kwargs)
    assert d.accepted == ["offset_step"], d.accepted
    assert "a clock coarser than the readings" in d.noise_source
    truth = next(e for e in result.effects if e.name == "offset_step")
    row = d.ranking[0]
    assert abs((row["on_s"] if row["on_s"] is not None else row["off_s"]) - truth.t_on) < 1.0


def test_lines_logged_twice_are_copies_not_a_coarse_clock():
    """A blind check: every 7th row logged twice (same time, same readings) was said to be both a clock coarser than
    the readings and sample-and-hold copies; it is one statement, and the step is still found where it is."""
    result, kwargs = withheld_trial(["offset_step"], 0)
    rows = np.sort(np.concatenate([np.arange(len(result.readings)), np.arange(0, len(result.readings), 7)]))
    d = diagnose(result.readings[rows], **{**kwargs, "t": kwargs["t"][rows], "temp": kwargs["temp"][rows]})
    copies = len(np.arange(0, len(result.readings), 7))
    assert f"{copies} of {len(rows)} rows repeat the row before them exactly, time and readings" in d.noise_source
    assert "clock coarser" not in d.noise_source and "sample and hold" not in d.noise_source, d.noise_source
    assert d.accepted == ["offset_step"], d.accepted


def test_a_moving_dipole_gains_no_spurious_offset_step():
    # What the dipole's low-order shape leaves inside its own box must not come back as a second event
    # (seeds where an offset box with two free edges was accepted after the dipole).
    for seed in (1, 5, 7):
        assert _run(["moving_dipole"], seed).accepted == ["moving_dipole"]


def _dipole_field(effect, t):
    """The simulated dipole's field at times t, world frame (north, east, down)."""
    frac = np.clip((t - effect.t_on) / (effect.t_off - effect.t_on), 0, 1)[:, None]
    r = -(effect.start + frac * (effect.end - effect.start))
    d = np.linalg.norm(r, axis=1, keepdims=True)
    return (3 * r / d * ((r / d) @ effect.moment)[:, None] - effect.moment) / d ** 3


def test_a_moving_dipole_against_reference_vectors_is_found_in_the_world_frame():
    # A world-frame field has three components against reference vectors (a magnitude sees only the one
    # along the field): with only that one as its feature, the dipole came out as colored_noise in 5 of 8
    # seeds. Found with its box, and its largest field in north, east, down (north: magnetic).
    from fluxcal.sim.withheld import FIELD

    heading = np.arctan2(FIELD[1], FIELD[0])
    to_magnetic = np.array([[np.cos(heading), np.sin(heading), 0], [-np.sin(heading), np.cos(heading), 0], [0, 0, 1]])
    for seed in (0, 3, 4):
        result, kwargs = withheld_trial(["moving_dipole"], seed, model="vector")
        d = diagnose(result.readings, **kwargs, units="uT")
        assert d.accepted == ["moving_dipole"], d.accepted
        truth = next(e for e in result.effects if e.name == "moving_dipole")
        row = d.ranking[0]
        assert abs(row["on_s"] - truth.t_on) < 0.2 and abs(row["off_s"] - truth.t_off) < 0.2
        expected = to_magnetic @ _dipole_field(truth, np.array([row["peak_s"]]))[0]
        assert np.linalg.norm(np.asarray(row["peak_ned"]) - expected) < 0.05 * np.linalg.norm(expected), \
            (row["peak_ned"], expected)
        line = next(x for x in d.text().splitlines() if "moving_dipole: an extra field" in x)
        assert "(north, east, down" in line and f"largest at t = {row['peak_s']:.4g} s" in line


def test_a_moving_dipole_against_magnitudes_is_sized_along_the_field():
    from fluxcal.sim.withheld import FIELD

    result, kwargs = withheld_trial(["moving_dipole"], 0)
    d = diagnose(result.readings, **kwargs)
    row = d.ranking[0]
    truth = next(e for e in result.effects if e.name == "moving_dipole")
    change = np.linalg.norm(FIELD + _dipole_field(truth, np.array([row["peak_s"]]))[0]) - np.linalg.norm(FIELD)
    assert abs(row["peak_along_field"] - change) < 0.05 * abs(change), (row["peak_along_field"], change)
    assert "along the field" in next(x for x in d.text().splitlines() if "moving_dipole: an extra field" in x)


def _straight_pass(t, t_close, t_pass, peak, rng):
    """A dipole of random moment carried on a straight line at a steady speed past the sensor (closest distance 1,
    travelled in t_pass, closest at t_close), world frame, scaled to `peak` at its largest; Biot–Savart's dipole
    field, independent of the candidate's Anderson functions."""
    v = rng.standard_normal(3)
    v /= np.linalg.norm(v)
    p = rng.standard_normal(3)
    p -= (p @ v) * v
    p /= np.linalg.norm(p)
    pos = p[None, :] + ((t - t_close) / t_pass)[:, None] * v[None, :]
    moment = rng.standard_normal(3)
    r = np.linalg.norm(pos, axis=1, keepdims=True)
    field = (3 * pos / r * ((pos / r) @ moment)[:, None] - moment) / r ** 3
    return field * peak / np.max(np.linalg.norm(field, axis=1))


def _with_field_change(result, field):
    """The trial's readings with an extra world-frame `field` as a magnitude sees it: the field at the sensor,
    m − b = W h, scaled by |F + field| / |F|."""
    from fluxcal.sim.withheld import FIELD

    scale = np.linalg.norm(FIELD + field, axis=1) / np.linalg.norm(FIELD)
    return result.readings + (scale[:, None] - 1) * (result.clean - np.asarray(result.true_calibration().offset))


def test_anderson_functions_span_a_straight_pass():
    # Every component of a straight pass's field is a combination of the candidate's three profiles: the
    # component along the field (what a magnitude sees) fitted by them leaves only rounding within ±4 T, and
    # beyond only the tails the features cut at ±8 T. The pass's times are read back from its features.
    from types import SimpleNamespace

    from fluxcal.sim.effects import MovingDipole, scatter_rows

    rng = np.random.default_rng(3)
    t = np.arange(0.0, 60.0, 0.02)
    direction = np.tile(rng.standard_normal(3), (len(t), 1))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    ctx = SimpleNamespace(t=t, direction=direction, world=None)
    for t_close, t_pass in ((21.3, 0.7), (40.0, 3.1)):
        along = np.sum(_straight_pass(t, t_close, t_pass, 1.0, rng) * direction, axis=1)
        feats = scatter_rows(len(t), *MovingDipole._pass_rows(ctx, t_close, t_pass))
        columns = np.einsum("npk,nk->np", feats, direction)
        coefficients = np.linalg.lstsq(columns, along, rcond=None)[0]
        assert np.max(np.abs(columns @ coefficients - along)) < 2e-3 * np.max(np.abs(along))  # the reach's cut tails
        reached = np.any(feats != 0, axis=(1, 2))
        inside = np.abs(t - t_close) < 4 * t_pass
        np.testing.assert_allclose((columns @ coefficients)[inside], along[inside], atol=1e-9)
        assert MovingDipole.describe(ctx, feats)["closest_s"] == pytest.approx(t_close)
        assert MovingDipole.describe(ctx, feats)["passage_s"] == pytest.approx(t_pass)
        assert reached.sum() < len(t)


def test_a_magnet_carried_past_is_found_as_a_pass():
    # A magnet carried past a hand-turned sensor on a straight line, 1.5 % of the field at its largest: as a
    # quadratic in a box it was found in 2 of 8 seeds (its lobes change sign); as a pass in 8 of 8, its closest
    # approach within 0.2 s and its passage time within 2 %. The last seed's times are Unix seconds (a logger's
    # clock): found the same, and said with the UTC clock time (".4g" printed every time as 1.7e+09 s).
    from datetime import datetime, timezone

    from fluxcal.sim.withheld import FIELD

    for seed in range(6):
        result, kwargs = withheld_trial([], seed)
        kwargs["t"] = kwargs["t"] + (1.7e9 if seed == 5 else 0.0)
        t = kwargs["t"]
        rng = np.random.default_rng(100 + seed)
        t_close, t_pass = t[0] + rng.uniform(0.3, 0.7) * np.ptp(t), rng.uniform(0.5, 3.0)
        d = diagnose(_with_field_change(result, _straight_pass(t, t_close, t_pass, 0.015 * np.linalg.norm(FIELD), rng)),
                     **kwargs)
        assert d.accepted == ["moving_dipole"], (seed, d.accepted)
        row = d.ranking[0]
        assert abs(row["closest_s"] - t_close) < 0.25 * t_pass and abs(row["passage_s"] / t_pass - 1) < 0.1, \
            (seed, row["closest_s"], t_close, row["passage_s"], t_pass)
        if seed < 5:
            assert f"a magnet or a vehicle passing, closest at t = {row['closest_s']:.4g} s" in d.text()
        else:
            clock = datetime.fromtimestamp(round(row["closest_s"], 3), timezone.utc).strftime("%Y-%m-%d %H:%M:%S")
            assert (f"closest at t = {row['closest_s']:.3f} s ({clock}." in d.text()
                    and f"UTC, {row['closest_s'] - t[0]:.3f} s in)" in d.text()), d.text()
            assert "e+09" not in d.text()


def test_a_magnet_carried_past_in_a_long_recording_is_found():
    # A second-long pass at 3 % of the field in ten minutes (20 Hz): it lay inside one of the recording's 16
    # held-out blocks (38 s) — held out, the training readings held none of it; trained on, no held-out reading
    # saw it — and the passage times searched began at a 200th of the recording (3 s). Found in 1 of 10 seeds
    # (/work/scratch/s28/longpass.py); now a short event is held out in blocks of its own span, judged where it
    # acts, and passage times go down to half a second: 8 of 10, 3 of these 4, each closest approach within a
    # tenth of its passage time.
    from fluxcal.sim.effects import MovingDipole

    found = 0
    for seed in range(4):
        rng = np.random.default_rng(300 + seed)
        t_close = rng.uniform(0.3, 0.7) * 600.0
        dipole = MovingDipole.straight_pass(50.0, rng, t_close, 1.0, 0.03)
        result, kwargs = withheld_trial(["moving_dipole"], seed, duration_s=600.0, rate_hz=20.0, dipole=dipole)
        d = diagnose(result.readings, **kwargs)
        assert set(d.accepted) <= {"moving_dipole"}, (seed, d.accepted)
        if d.accepted:
            row = d.ranking[0]
            assert abs(row["closest_s"] - t_close) < 0.1 and abs(row["passage_s"] - 1.0) < 0.1, (seed, row)
            assert row["heldout_block"] is not None and row["heldout_n_judged"] < row["heldout_n"] / 10
            found += 1
    assert found >= 3


def test_a_magnet_carried_past_is_found_as_a_pass_against_reference_vectors():
    # fluxcal.sim's straight pass (`MovingDipole.straight_pass`), 1.5 % of the field, against reference vectors and
    # the down direction: each world component of its field is a combination of the three profiles. Over seeds
    # 0–11 11 found (seed 5, a 1.1 s passage inside one training block, fails its held-out test); as a box, 4.
    from fluxcal.sim.effects import MovingDipole
    from fluxcal.sim.withheld import DURATION, FIELD

    heading = np.arctan2(FIELD[1], FIELD[0])
    to_magnetic = np.array([[np.cos(heading), np.sin(heading), 0], [-np.sin(heading), np.cos(heading), 0], [0, 0, 1]])
    for seed in range(4):
        rng = np.random.default_rng(200 + seed)
        t_close, t_pass = rng.uniform(0.3, 0.7) * DURATION, rng.uniform(0.5, 3.0)
        dipole = MovingDipole.straight_pass(50.0, rng, t_close, t_pass, 0.015)
        result, kwargs = withheld_trial(["moving_dipole"], seed, model="vector", dipole=dipole)
        d = diagnose(result.readings, **kwargs, units="uT")
        assert d.accepted == ["moving_dipole"], (seed, d.accepted)
        row = d.ranking[0]
        assert abs(row["closest_s"] - t_close) < 0.1 * t_pass and abs(row["passage_s"] / t_pass - 1) < 0.1, \
            (seed, row["closest_s"], t_close, row["passage_s"], t_pass)
        frac = (row["peak_s"] - dipole.t_on) / (dipole.t_off - dipole.t_on)
        expected = to_magnetic @ dipole._field(np.array([frac]))[0]
        assert np.linalg.norm(np.asarray(row["peak_ned"]) - expected) < 0.1 * np.linalg.norm(expected), \
            (seed, row["peak_ned"], expected)


def test_withheld_trial_simulates_a_magnet_carried_past_twice():
    # `withheld_trial(dipole=[…])`: the second pass adds its field within its own reach only; the rest of the trial
    # (sensor, motion, noise) is the same as with the first alone
    from fluxcal.sim.effects import MovingDipole

    rng = np.random.default_rng(7)
    first, second = (MovingDipole.straight_pass(50.0, rng, t_close, 1.0, 0.03) for t_close in (15.0, 45.0))
    alone, kwargs = withheld_trial(["moving_dipole"], 0, dipole=first)
    both, _ = withheld_trial(["moving_dipole"], 0, dipole=[first, second])
    change, t = np.linalg.norm(both.readings - alone.readings, axis=1), kwargs["t"]
    outside = (t < second.t_on) | (t > second.t_off)
    assert np.all(change[outside] == 0)
    assert 0.85 < change.max() / (0.03 * 50.0) < 1.15, change.max()  # (the sensor's soft iron)


def test_a_magnet_carried_past_twice_is_found_as_two_episodes():
    # Two passes, 3 % of the field each: each one's held-out test fails on what the other leaves. Before an event
    # could have episodes, seeds 0–3 gave colored_noise alone, one pass, one pass, colored_noise alone. Now the
    # second pass is a second episode of the first's block, found beside it or both together (over seeds 0–13:
    # both in 7, one in 4, neither in 3). Seed 1 finds one; its other does not pass its held-out test.
    from fluxcal.sim.withheld import FIELD

    both = 0
    for seed in range(4):
        result, kwargs = withheld_trial([], seed)
        t = kwargs["t"]
        rng = np.random.default_rng(100 + seed)
        passes = [(t[0] + rng.uniform(0.15, 0.4) * np.ptp(t), rng.uniform(0.5, 3.0)),
                  (t[0] + rng.uniform(0.6, 0.85) * np.ptp(t), rng.uniform(0.5, 3.0))]
        field = sum(_straight_pass(t, t_close, t_pass, 0.03 * np.linalg.norm(FIELD), rng) for t_close, t_pass in passes)
        d = diagnose(_with_field_change(result, field), **kwargs)
        assert set(d.accepted) <= {"moving_dipole", "colored_noise"}, (seed, d.accepted)
        row = next(r for r in d.ranking if r["effect"] == "moving_dipole")
        found = sorted((e["closest_s"], e["passage_s"]) for e in row.get("episodes", []))
        if not found:
            continue
        both += 1
        for (closest, passage), (t_close, t_pass) in zip(found, sorted(passes)):
            assert abs(closest - t_close) < 0.25 * t_pass and abs(passage / t_pass - 1) < 0.1, (seed, found, passes)
        text = d.text()
        assert "FOUND: moving_dipole (2 episodes)" in text
        assert text.count("moving_dipole: a magnet or a vehicle passing") == 2
        # each episode's own size: at most its pass's (a magnitude sees the part along the field)
        assert all(0 < e["peak_field"] < 0.035 * np.linalg.norm(FIELD) for e in row["episodes"]), row["episodes"]
        if row.get("episodes_together"):  # (seeds 0 and 3) the line names the two
            a, b = (f"closest at t = {e['closest_s']:.4g} s" for e in row["episodes"])
            assert f"two of its episodes ({a} and {b}) were found together" in text, text
    assert both >= 3, both


def test_an_episode_joins_its_event_block_where_it_stands(monkeypatch):
    # Two passes at 5 % and a temperature offset (seed 4): the first pass is found, then the temperature offset,
    # then the second pass as an episode of the first block, which is then not the last. Its columns go in after
    # the block's validated ones and every later term moves along: the refitted model is the same model as the
    # episode's own fit (its columns appended at the end), to rounding.
    import sys

    from fluxcal.sim.effects import MovingDipole
    from fluxcal.sim.withheld import DURATION

    core = sys.modules["fluxcal.diagnose.core"]
    merges, merge = [], core._with_episode

    def checked(data, model, state, row, i, columns):
        out = merge(data, model, state, row, i, columns)
        merges.append((i, len(state["features"]), float(np.sum(np.square(row["_fit"]["residuals"]))),
                       float(np.sum(np.square(out["result"]["residuals"])))))
        return out

    monkeypatch.setattr(core, "_with_episode", checked)
    rng = np.random.default_rng(304)
    timing = sorted((rng.uniform(*span) * DURATION, rng.uniform(0.5, 3.0)) for span in ((0.15, 0.4), (0.6, 0.85)))
    dipoles = [MovingDipole.straight_pass(50.0, rng, t_close, t_pass, 0.05) for t_close, t_pass in timing]
    result, kwargs = withheld_trial(["moving_dipole", "temp_offset"], 4, dipole=dipoles)
    d = diagnose(result.readings, **kwargs)
    assert d.accepted == ["moving_dipole", "temp_offset"], d.accepted
    assert [(i, blocks) for i, blocks, _, _ in merges] == [(0, 2)], merges
    assert merges[0][3] == pytest.approx(merges[0][2], rel=1e-9)
    row = d.ranking[0]
    found = sorted(e["closest_s"] for e in row["episodes"])
    for closest, (t_close, t_pass) in zip(found, timing):
        assert abs(closest - t_close) < 0.25 * t_pass, (found, timing)
    for e in row["episodes"]:  # each episode's size from its own columns: largest near its own closest approach
        assert abs(e["peak_s"] - e["closest_s"]) < 2 * e["passage_s"], row["episodes"]


def test_two_concurrent_events_are_found_together():
    # A magnet passing while the offset jumps: with either unmodelled, the other's held-out test fails
    # (seed 104: colored_noise alone was reported). Added on trial, each passes with the other modelled.
    result, kwargs = withheld_trial(["moving_dipole", "offset_step"], 104)
    # without a settling offset among the candidates (it can carry the first of them, below)
    d = diagnose(result.readings, **kwargs, candidates=[n for n in EFFECTS if n != "offset_drift"])
    assert set(d.accepted) == {"moving_dipole", "offset_step"}, d.accepted
    rows = {r["effect"]: r for r in d.ranking}
    assert rows["moving_dipole"]["found_with"] == "offset_step" and rows["offset_step"]["found_with"] == "moving_dipole"
    assert "were found together" in d.text()
    # Every candidate: a settling offset had been accepted first for what the two then explain (then pruned), its
    # warm-up time chosen with the held-out quarter in view. Chosen without it, it is not accepted at all.
    d = diagnose(result.readings, **kwargs)
    assert set(d.accepted) == {"moving_dipole", "offset_step"}, d.accepted
    drift = next(r for r in d.ranking if r["effect"] == "offset_drift")
    assert not drift["significant"] and "offset_drift: accepted" not in d.text()


def test_an_effect_accepted_early_that_later_ones_explain_is_left_out_and_said():
    # seed 112: a linear offset drift is accepted in round 1 for what the step and the temperature scale then explain
    # (seed 111's offset step beside a magnet and a temperature offset, this test's case until the held-out test
    # weighed its blocks, is now not confirmed beside them at all)
    result, kwargs = withheld_trial(["offset_step", "temp_scale"], 112)
    d = diagnose(result.readings, **kwargs)
    assert set(d.accepted) == {"offset_step", "temp_scale"}, d.accepted
    drift = next(r for r in d.ranking if r["effect"] == "offset_drift")
    assert "no longer pays BIC's price" in drift["note"] and drift["pruned_delta_bic"] > 0
    assert drift["unmet"] == ["pruned"] and not drift["significant_not_modelled"]
    assert "offset_drift: accepted in round 1" in d.text() and "(left out: with the later effects modelled" in d.text()


def _drift_and_step(seed: int):
    """300 s at 20 Hz: a linear offset drift of 0.3–0.6 µT per axis and an offset step of as much that stays, at a
    random time (40–260 s). Returns the readings, their times, the step's time and jump, and the drift."""
    from fluxcal.sim.effects import HardIron, OffsetDrift, OffsetStep, SoftIron, WhiteNoise
    from fluxcal.sim.withheld import FIELD

    rng = np.random.default_rng(seed)
    at = rng.uniform(40, 260)
    scene = sim.tumble(300.0, rate_hz=20.0, rng=rng)
    drift = rng.choice([-1, 1], 3) * rng.uniform(0.3, 0.6, 3)
    jump = rng.choice([-1, 1], 3) * rng.uniform(0.3, 0.6, 3)
    effects = [SoftIron(np.diag([1.03, 0.97, 1.01])), HardIron([4.0, -3.0, 2.0]), OffsetDrift(drift / 300.0),
               OffsetStep(jump, at), WhiteNoise(0.05)]
    r = sim.simulate(scene, effects, FIELD, rng)
    return r.readings, r.t, at, jump, drift


@pytest.mark.parametrize("seed", [2, 3])
def test_a_step_and_a_drift_are_placed_again_with_each_other_modelled(seed):
    # The greedy search placed the first one found against residuals that held the other: seed 2's step came 3 s
    # late (the drift's slope taken for part of it), seed 3's drift came first and the step then as a box 9.65–58.8 s
    # beside colored_noise (RMS 1.30 σ left). Each is now searched again with the other modelled.
    m, t, at, jump, drift = _drift_and_step(seed)
    d = diagnose(m, t=t, field_norm=50.0)
    assert set(d.accepted) == {"offset_step", "offset_drift"}, d.accepted
    step = next(r for r in d.to_dict()["ranking"] if r["effect"] == "offset_step")
    assert abs(step["jump_s"] - at) < 0.5 and step["back_s"] is None, step
    assert np.allclose(step["jump"], jump, atol=0.05), (step["jump"], jump)
    moved = [r for r in d.ranking if r.get("replaced")]
    assert moved and all(f"{r['effect']}: placed again once" in d.text() for r in moved), d.text()
    assert d.remaining["overall"]["rms_z"] < 1.05, d.remaining["overall"]
    saved = json.loads(json.dumps(d.to_dict()))
    assert any(r.get("replaced", {}).get("delta_bic_gain", 0) > 0 for r in saved["ranking"])


@pytest.mark.parametrize("pair, seed", [(("saturation", "offset_drift"), 0), (("saturation", "offset_drift"), 3),
                                        (("saturation", "temp_scale"), 0)])
def test_a_saturation_found_as_its_kin_beside_another_effect_takes_its_place(pair, seed):
    # Found while the drift (or the temperature scale) was unmodelled, a tanh saturation came out as the per-axis
    # cubic with equal coefficients ([-2.37, -2.35, -2.38] %, seed 0) or as the knee: with the other modelled, the
    # family's members are weighed again and saturation's one coefficient wins.
    result, kwargs = withheld_trial(list(pair), seed)
    d = diagnose(result.readings, **kwargs)
    assert sorted(d.accepted) == sorted(pair), d.accepted
    assert "saturation: took the place of" in d.text() or d.accepted[0] == "saturation", d.text()


@pytest.mark.parametrize("seed", [4, 9])
def test_a_warm_up_beside_a_step_is_held_out_where_it_settles(seed):
    # A 20 s warm-up in a 300 s recording has settled long before the last quarter, its held-out regime: there it
    # showed nothing (seed 4: refused, the step alone and 1.93 σ left; seed 9: a magnet instead). Held out on
    # interleaved blocks of time, as an event is, it is found with its time constant.
    from fluxcal.sim.effects import HardIron, OffsetDrift, OffsetStep, SoftIron, WhiteNoise
    from fluxcal.sim.withheld import FIELD

    rng = np.random.default_rng(seed)
    at = rng.uniform(100, 250)
    scene = sim.tumble(300.0, rate_hz=20.0, rng=rng)
    settled = rng.choice([-1, 1], 3) * rng.uniform(0.45, 0.6, 3)
    jump = rng.choice([-1, 1], 3) * rng.uniform(0.4, 0.8, 3)
    effects = [SoftIron(np.diag([1.03, 0.97, 1.01])), HardIron([4.0, -3.0, 2.0]),
               OffsetDrift(settled / 20.0, warmup_s=20.0), OffsetStep(jump, at), WhiteNoise(0.05)]
    r = sim.simulate(scene, effects, FIELD, rng)
    d = diagnose(r.readings, t=r.t, field_norm=50.0)
    assert sorted(d.accepted) == ["offset_drift", "offset_step"], d.accepted
    drift = next(x for x in d.ranking if x["effect"] == "offset_drift")
    assert drift["warmup_s"] == pytest.approx(20.0, rel=0.1) and drift["heldout"] == "events", drift
    assert d.remaining["overall"]["rms_z"] < 1.05


@pytest.mark.parametrize("seed", [0, 2])
def test_a_drift_refused_beside_a_step_against_it_is_judged_with_the_step_placed_again(seed):
    # A drift [1, −0.8, 0.6] over 300 s and a step against it, [−0.8, 0.5, −0.4] at 212.73 s (a blind check's case):
    # the step came first as a box from ~90 s that "came back" at 212.7 s, having taken the drift's middle; the
    # drift, profiled against that box as a settling one, failed its held-out quarter and colored_noise was named
    # (residuals ~2 σ). Added on trial in its plain (linear) form, the step is placed again and both pass.
    from fluxcal.sim.effects import HardIron, OffsetDrift, OffsetStep, SoftIron, WhiteNoise
    from fluxcal.sim.withheld import FIELD

    rng = np.random.default_rng(seed)
    scene = sim.tumble(300.0, rate_hz=20.0, rng=rng)
    drift, jump = np.array([1.0, -0.8, 0.6]), np.array([-0.8, 0.5, -0.4])
    effects = [SoftIron(np.diag([1.03, 0.97, 1.01])), HardIron([4.0, -3.0, 2.0]), OffsetDrift(drift / 300.0),
               OffsetStep(jump, 212.73), WhiteNoise(0.05)]
    r = sim.simulate(scene, effects, FIELD, rng)
    d = diagnose(r.readings, t=r.t, field_norm=50.0)
    assert sorted(d.accepted) == ["offset_drift", "offset_step"], d.accepted
    rows = {x["effect"]: x for x in d.to_dict()["ranking"]}
    assert abs(rows["offset_step"]["jump_s"] - 212.73) < 0.5 and rows["offset_step"]["back_s"] is None
    assert np.allclose(rows["offset_drift"]["coefficients"], drift, atol=0.05), rows["offset_drift"]["coefficients"]
    assert "offset_step: placed again once offset_drift was modelled" in d.text()
    assert d.remaining["overall"]["rms_z"] < 1.05


@pytest.mark.parametrize("warm_up, seed", [(False, 2), (False, 4), (True, 0), (True, 4), (True, 11)])
def test_a_drift_and_a_step_are_found_in_another_order(warm_up, seed):
    # A drift ±[1, −0.8, 0.6] µT over 300 s and a step against it, or a warm-up [0.6, −0.5, 0.45] µT (τ 35–50 s) and
    # a step, at a random time. Taken first, the step was a box that "came back", having taken part of the drift
    # (seed 4: 75.9 → 186.85 s for a step at 186.87 s; seed 2: 150 → 226 s; the warm-up's seed 0: 11 → 118.7 s),
    # residuals 1.4–2.1 σ (the warm-up's seed 11: nothing found, 3.65 σ — each failed its held-out test while the
    # other was unmodelled); the warm-up's seed 4 was found exactly but refused on its last quarter, where it had
    # settled (now held out on blocks of time). The drift, taken first in a second search (as found, or in its
    # plain form), lets the step be placed as it is, and that search's model replaces the first one.
    from fluxcal.sim.effects import HardIron, OffsetDrift, OffsetStep, SoftIron, WhiteNoise
    from fluxcal.sim.withheld import FIELD

    rng = np.random.default_rng(seed)
    scene = sim.tumble(300.0, rate_hz=20.0, rng=rng)
    sign, at = rng.choice([-1, 1]), rng.uniform(60, 240)
    if warm_up:
        tau = rng.uniform(35, 50)
        drift, jump = np.array([0.6, -0.5, 0.45]), sign * np.array([0.8, -0.5, 0.4])
        course = OffsetDrift(drift / tau, warmup_s=tau)
    else:
        drift, jump = sign * np.array([1.0, -0.8, 0.6]), -sign * np.array([0.8, -0.5, 0.4])
        course = OffsetDrift(drift / 300.0)
    effects = [SoftIron(np.diag([1.03, 0.97, 1.01])), HardIron([4.0, -3.0, 2.0]), course, OffsetStep(jump, at),
               WhiteNoise(0.05)]
    r = sim.simulate(scene, effects, FIELD, rng)
    d = diagnose(r.readings, t=r.t, field_norm=50.0)
    assert sorted(d.accepted) == ["offset_drift", "offset_step"], d.accepted
    rows = {x["effect"]: x for x in d.to_dict()["ranking"]}
    assert abs(rows["offset_step"]["jump_s"] - at) < 0.5 and rows["offset_step"]["back_s"] is None, rows["offset_step"]
    assert np.allclose(rows["offset_step"]["jump"], jump, atol=0.05)
    assert np.allclose(rows["offset_drift"]["coefficients"], drift, atol=0.05), rows["offset_drift"]["coefficients"]
    if warm_up:
        assert rows["offset_drift"]["warmup_s"] == pytest.approx(tau, rel=0.1)
    if "another_order" in rows["offset_drift"]:
        other = rows["offset_drift"]["another_order"]
        assert other["first"] in ("offset_step", None) and other["rms_z"] > 1.3 and other["delta_bic"] < -100, other
        assert "offset_drift: taken first in a second search — the first " in d.text()
    else:  # (the warm-up's seed 4: found first time, held out where it had not settled)
        assert warm_up and rows["offset_drift"]["heldout"] == "events", rows["offset_drift"]
    assert d.remaining["overall"]["rms_z"] < 1.05


def test_a_step_inside_the_held_out_quarter_does_not_fail_a_drift_beside_it():
    # Seed 4's step at 247.5 s lies in the drift's held-out quarter (the last): the held-out fits cannot determine it
    # and kept it as the fit without the drift had it — with part of the drift in it — so the drift's extrapolation
    # added that part again (gap 0.119 → 0.222) and the drift was refused; the step came out [-0.10, -0.34, 0.60]
    # for [-0.37, -0.50, 0.34]. The held-out fit with the drift now starts from the fit with it on every reading.
    m, t, at, jump, drift = _drift_and_step(4)
    d = diagnose(m, t=t, field_norm=50.0)
    assert set(d.accepted) == {"offset_step", "offset_drift"}, d.accepted
    rows = {r["effect"]: r for r in d.to_dict()["ranking"]}
    assert np.allclose(rows["offset_step"]["jump"], jump, atol=0.05)
    assert np.allclose(rows["offset_drift"]["coefficients"], drift, atol=0.05)
    # the rest cannot determine the step: the drift's held-out test is said not to test it, not hidden
    assert "NOT CONFIRMED: offset_drift" in d.text()


def test_a_held_out_test_the_rest_cannot_determine_is_said_and_the_json_stays_strict(tmp_path):
    # seed 106: beside the magnet, the readings outside the hottest quarter cannot tell the magnet's terms from the
    # temperature offset's (JᵀJ conditioned 2e17): the leverage had come out −8e13 (a sqrt warning, "nan" printed)
    result, kwargs = withheld_trial(["moving_dipole", "temp_offset"], 106)
    d = diagnose(result.readings, **kwargs)
    assert set(d.accepted) == {"moving_dipole", "temp_offset"}, d.accepted
    assert any(c.startswith("temp_offset: its held-out test may not be trusted") and "does not test the effect" in c
               for c in d.caveats), d.caveats
    assert not re.search(r"\b(nan|inf)\b", d.text())

    def refuse(word):
        raise ValueError(f"not JSON: {word}")

    saved = json.loads(d.save_json(tmp_path / "d.json").read_text(), parse_constant=refuse)
    row = next(r for r in saved["ranking"] if r["effect"] == "temp_offset")
    assert row["heldout_leverage"] is None and row["heldout_leverage_undetermined"] is True


def test_unequal_noise_between_the_axes_is_the_noise_not_an_excess():
    # σ [0.02, 0.05, 0.12] µT per axis, turned fast at 10 Hz (σ from the base model's residuals, a magnitude's: the
    # noise along the field, whose σ changes with the direction). The MAD of that mixture falls short of its RMS:
    # σ 0.81 of the noise's RMS and the residuals read 1.15 σ, "explained to the noise" beside an excess.
    from fluxcal.sim.effects import HardIron, SoftIron, WhiteNoise
    from fluxcal.sim.withheld import FIELD

    per_axis = np.array([0.02, 0.05, 0.12])
    for seed in range(3):
        rng = np.random.default_rng(seed)
        scene = sim.tumble(120.0, rate_hz=10.0, turn_rate_deg=200.0, rng=rng)
        effects = [SoftIron(np.diag([1.03, 0.97, 1.01])), HardIron([4.0, -3.0, 2.0]), WhiteNoise(per_axis)]
        r = sim.simulate(scene, effects, FIELD, rng)
        d = diagnose(r.readings, t=r.t, field_norm=50.0)
        assert "base model's residuals" in d.noise_source, d.noise_source  # (the path this is about)
        assert d.noise_sigma == pytest.approx(np.sqrt(np.mean(per_axis ** 2)), rel=0.07), seed
        assert abs(d.where["overall"]["rms_z"] - 1.0) < 0.06, (seed, d.where["overall"]["rms_z"])
        assert d.accepted == [], (seed, d.accepted)


def _noisier_z(seed, k=3.0, model="vector"):
    """A trial (vector model, or a magnitude model) with nothing withheld and its z axis k times as noisy as x and y."""
    result, kwargs = withheld_trial([], seed, model=model)
    rng = np.random.default_rng(500 + seed)
    m = result.readings.copy()
    m[:, 2] += rng.normal(0, NOISE * np.sqrt(k * k - 1), len(m))
    return m, kwargs


def test_a_vector_models_axes_of_unequal_noise_are_weighted():
    # σ_z = 3 σ_x against reference vectors, nothing withheld. One pooled σ judged a candidate acting on z against
    # a noise too small: an offset step was named at these two seeds (2 of 40; 0 of 40 once weighted).
    for seed in (11, 16):
        m, kwargs = _noisier_z(seed)
        d = diagnose(m, **kwargs)
        assert d.accepted == [], (seed, d.accepted)
        np.testing.assert_allclose(d.axis_noise, [NOISE, NOISE, 3 * NOISE], rtol=0.08)
        assert "axes' noise differs" in d.noise_source and d.to_dict()["axis_noise"] == d.axis_noise
        # the weighted residuals scatter by the one σ reported on every axis
        e = d.series["residual_before"].reshape(-1, 3)
        np.testing.assert_allclose(np.std(e, axis=0), d.noise_sigma, rtol=0.1)


def test_a_noise_given_per_axis_weights_each_axis_against_reference_vectors():
    # A datasheet's σ per axis (x, y, z) against reference vectors: each axis weighted by its own, as when estimated;
    # the σ reported is their RMS, and the weighted residuals scatter by it on every axis (unweighted, z's by 3×).
    m, kwargs = _noisier_z(11)
    given = [NOISE, NOISE, 3 * NOISE]
    d = diagnose(m, **kwargs, noise_sigma=given)
    assert d.accepted == [], d.accepted
    np.testing.assert_allclose(d.axis_noise, given)
    assert d.noise_sigma == pytest.approx(np.sqrt(np.mean(np.square(given))))
    assert d.noise_source.startswith("given per axis (σ x, y, z 0.05, 0.05, 0.15, σ their RMS)"), d.noise_source
    assert "weighted by σ/σ_axis" in d.noise_source
    e = d.series["residual_before"].reshape(-1, 3)
    np.testing.assert_allclose(np.std(e, axis=0), d.noise_sigma, rtol=0.1)
    # a magnitude model weights each axis alike: its residual is the distance to the ellipsoid in noise units
    m, kwargs = _noisier_z(11, model="ellipsoid")
    d = diagnose(m, **kwargs, noise_sigma=given)
    assert d.accepted == [], d.accepted
    np.testing.assert_allclose(d.axis_noise, given)
    assert d.noise_sigma == pytest.approx(np.sqrt(np.mean(np.square(given))))
    assert "given per axis" in d.noise_source and "distance to the ellipsoid" in d.noise_source
    assert abs(d.where["overall"]["rms_z"] - 1.0) < 0.05, d.where["overall"]["rms_z"]


def test_readings_on_a_grid_with_a_noise_given_per_axis_are_weighted_alike():
    # The same recording rounded to a 0.08 grid, σ given per axis: the quantization candidate adds each axis's rounding
    # variance in the units of its weighted residuals, σ̄² + (w_k q)²/12 with w_k = σ̄/σ_k (the unweighted q²/12 on
    # every axis had put x's and y's at half theirs: LR 56 against 115). Quantization is found; with the RMS σ given
    # on every axis, x's and y's rounding went unexplained.
    m, kwargs = _noisier_z(11)
    q, given = 0.08, np.array([NOISE, NOISE, 3 * NOISE])
    d = diagnose(np.round(m / q) * q, **kwargs, noise_sigma=given, candidates=["quantization", "offset_step"])
    assert d.accepted == ["quantization"], d.accepted
    row = next(r for r in d.ranking if r["effect"] == "quantization")
    e = d.series["residual_before"].reshape(-1, 3)
    sigma = d.noise_sigma
    var = sigma ** 2 + (sigma / given * np.asarray(row["steps"])) ** 2 / 12
    lr = np.sum(np.log(sigma ** 2 / var) + e ** 2 / sigma ** 2 - e ** 2 / var)
    assert row["lr"] == pytest.approx(lr, rel=1e-9)


def test_a_step_on_a_quiet_axis_is_judged_against_that_axis_noise():
    # The same recordings with a step of 0.7 σ_x on x at mid-recording. Against the pooled σ (1.9 σ_x) the step was
    # named in 2 of these 10 (3 more called a drift, 5 missed); against x's own noise in 9. (Found as a step or a
    # drift at 0.3, 0.5, 0.7 σ_x: pooled 0, 2, 5 of 10; weighted 3, 8, 9.)
    named = 0
    for seed in range(10):
        m, kwargs = _noisier_z(seed)
        t = kwargs["t"]
        m[t > 0.5 * (t[0] + t[-1]), 0] += 0.7 * NOISE
        named += diagnose(m, **kwargs).accepted == ["offset_step"]
    assert named >= 8, named


def test_the_weighted_vector_fit_matches_weighted_least_squares():
    # _fit maps weighted least squares onto plain least squares of weighted readings (offset D b, matrix D W):
    # parameters, covariance, residuals and their Jacobian as the linear oracle weighting each axis's equations
    # finds them, for the full matrix and for the scale-only one (its off-diagonal W held at the start's).
    from fluxcal.diagnose.core import MODELS, _Data, _fit, _noise_floor, _project, _residuals
    from fluxcal.oracle.refine import vector_terms

    m, kwargs = _noisier_z(3)
    ref, temp = kwargs["reference"], kwargs["temp"]
    feats = np.zeros((len(m), 3, 3))
    for k in range(3):
        feats[:, k, k] = temp - temp.mean()
    weights = np.array([1.3, 1.3, 0.45])
    data = _Data(m, kwargs["t"], temp, ref, None, 50.0, "", "weighted", [], axis_weights=weights)
    start = fluxcal.calibrate(m, reference=ref)
    W0 = np.linalg.inv(start.matrix)
    for model in ("vector", "vector_scale"):
        fixed = MODELS[model][1]
        held = {3 + 3 * int(n[1]) + int(n[2]): W0[int(n[1]), int(n[2])] for n in fixed}
        got = _fit(data, start, fixed, feats)
        theta, covariance, e, J = vector_terms(m, ref, feats, weights, held)
        scale = np.abs(theta).max()
        np.testing.assert_allclose(got["parameters"], theta, rtol=0, atol=1e-8 * scale)
        np.testing.assert_allclose(got["offset"], theta[:3], rtol=0, atol=1e-8 * scale)
        np.testing.assert_allclose(np.linalg.inv(got["matrix"]), theta[3:12].reshape(3, 3), rtol=1e-9)
        np.testing.assert_allclose(got["covariance"], covariance, rtol=1e-6, atol=1e-9 * np.abs(covariance).max())
        np.testing.assert_allclose(got["standard_errors"], np.sqrt(np.diag(covariance)), rtol=1e-6)
        np.testing.assert_allclose(got["residuals"], e, rtol=0, atol=1e-9)
        np.testing.assert_allclose(_residuals(got, data, feats, slice(None)), e, rtol=0, atol=1e-9)
        free = [i for i in range(J.shape[1]) if i not in held]  # (a held parameter's column is zero)
        np.testing.assert_allclose(np.asarray(got["jacobian"])[:, free], J[:, free], rtol=0, atol=1e-9)
        # the candidates' columns are the weighted residuals' own derivatives
        np.testing.assert_allclose(_project(got, feats, True), J[:, 12:], rtol=0, atol=1e-12)
    # the noise floor through A with each axis's own σ (σ̄ / its weight): E|A n|² = Σ_k σ_k² |A e_k|²
    A = np.asarray(got["matrix"])
    floor = _noise_floor(got, data, None, slice(None), 0.1)
    assert floor == pytest.approx(np.sqrt(np.sum((0.1 / weights) ** 2 * np.sum(A ** 2, axis=0))), rel=1e-12)
    # with equal weights: the unweighted fit
    plain = _fit(_Data(m, kwargs["t"], temp, ref, None, 50.0, "", "plain", []), start, (), feats)
    np.testing.assert_allclose(plain["parameters"], vector_terms(m, ref, feats)[0], rtol=0,
                               atol=1e-8 * np.abs(theta).max())


def test_a_magnitude_model_weights_the_axes_noise_given_per_axis():
    # σ_z = 3 σ_x, nothing withheld, a magnitude model, σ given per axis (a datasheet's): each residual the distance to
    # the ellipsoid with every axis in units of its own noise. Unweighted, a reading whose field lies along z scatters
    # 3× as much as one along x, and a candidate was judged against their mixture. Not estimated from the readings:
    # their differences per axis also hold the turn (a yaw turn read x and y 1.1–1.17× noisier than z: effects named
    # in 4 of 30 such recordings with nothing withheld, a review's blind check).
    m, kwargs = _noisier_z(2, model="ellipsoid")
    assert diagnose(m, **kwargs).axis_noise is None
    d = diagnose(m, **kwargs, noise_sigma=[NOISE, NOISE, 3 * NOISE])
    assert d.accepted == [], d.accepted
    assert "given per axis" in d.noise_source and "distance to the ellipsoid" in d.noise_source
    e = d.series["residual_before"]
    cal = fluxcal.calibrate(m, field_norm=kwargs.get("field_norm"))
    u = np.abs(cal.apply(m) / np.linalg.norm(cal.apply(m), axis=1, keepdims=True))
    along_z, along_xy = u[:, 2] > 0.9, u[:, 2] < 0.3
    assert along_z.sum() > 100 and along_xy.sum() > 100
    for part in (along_z, along_xy):  # the one σ reported, whatever the field's direction
        assert np.std(e[part]) == pytest.approx(d.noise_sigma, rel=0.12), (np.std(e[along_z]), np.std(e[along_xy]))


def test_a_step_on_a_magnitude_models_quiet_axis_is_judged_against_that_axis_noise():
    # The same recordings, σ given per axis, with a step of 1.5 σ_x on x at mid-recording: against their RMS it was
    # missed at these seeds; weighted, a step in each (seeds 0–9: 10 of 10, against 7; at 2 σ_x 10 against 9).
    for seed in (4, 6):
        m, kwargs = _noisier_z(seed, model="ellipsoid")
        t = kwargs["t"]
        m[t > 0.5 * (t[0] + t[-1]), 0] += 1.5 * NOISE
        assert diagnose(m, **kwargs, noise_sigma=[NOISE, NOISE, 3 * NOISE]).accepted == ["offset_step"], seed


def test_the_weighted_magnitude_fit_matches_the_oracle():
    # _fit scales the readings to D m and refits the symmetric A' = root(D⁻¹ A² D⁻¹): the parameters, residuals,
    # Jacobian and covariance mapped back are those of the oracle's Sampson residual with the gradient in noise units.
    from fluxcal.diagnose.core import MODELS, _Data, _fit, _noise_floor, _project, _residuals

    oracle = importlib.import_module("fluxcal.oracle.refine")
    m, kwargs = _noisier_z(3, model="ellipsoid")
    temp = kwargs["temp"]
    feats = np.zeros((len(m), 3, 3))
    for k in range(3):
        feats[:, k, k] = temp - temp.mean()
    weights = np.array([1.3, 1.3, 0.45])
    data = _Data(m, kwargs["t"], temp, None, None, 50.0, "", "weighted", [], axis_weights=weights)
    start = fluxcal.calibrate(m, field_norm=50.0, shape="sym")
    got = _fit(data, start, (), feats)
    theta = oracle_refine_terms(start, m, feats, axis_weights=weights)
    np.testing.assert_allclose(got["parameters"], theta, rtol=0, atol=1e-7)

    def residuals(th):
        return oracle.residuals(th[:9], m - np.einsum("p,npk->nk", th[9:], feats), 50.0, weights)

    e = residuals(theta)
    J = np.empty((len(e), len(theta)))
    for j in range(len(theta)):
        step = np.zeros(len(theta))
        step[j] = 1e-6
        J[:, j] = (residuals(theta + step) - residuals(theta - step)) / 2e-6
    covariance = e @ e / (len(e) - len(theta)) * np.linalg.inv(J.T @ J)
    np.testing.assert_allclose(got["residuals"], e, rtol=0, atol=1e-7)
    np.testing.assert_allclose(_residuals(got, data, feats, slice(None)), e, rtol=0, atol=1e-7)
    np.testing.assert_allclose(got["jacobian"], J, rtol=0, atol=1e-6 * np.abs(J).max())
    np.testing.assert_allclose(got["covariance"], covariance, rtol=0, atol=1e-6 * np.abs(covariance).max())
    np.testing.assert_allclose(_project(got, feats, False), J[:, 9:], rtol=0, atol=1e-6 * np.abs(J).max())
    # the noise floor with each axis's own σ (σ̄ / its weight) along the field: E (u'A n)² = Σ_k σ_k² (u'A)_k²
    h = fluxcal.Calibration(offset=got["offset"], matrix=got["matrix"], field_norm=50.0).apply(
        m - np.einsum("p,npk->nk", theta[9:], feats))
    uA = (h / np.linalg.norm(h, axis=1, keepdims=True)) @ np.asarray(got["matrix"])
    floor = _noise_floor(got, data, feats, slice(None), 0.1)
    assert floor == pytest.approx(np.sqrt(np.mean(np.sum((0.1 / weights * uA) ** 2, axis=1))), rel=1e-12)
    # the scale-only model: its held off-diagonals stay zero through the mapping
    W = np.linalg.inv(start.matrix)
    diagonal = fluxcal.Calibration(offset=start.offset, matrix=np.diag(1.0 / np.diag(W)), field_norm=50.0)
    scale = _fit(data, diagonal, MODELS["scale"][1], feats)
    assert np.all(np.asarray(scale["matrix"])[~np.eye(3, dtype=bool)] == 0.0)
    assert np.all(np.asarray(scale["jacobian"])[:, [4, 5, 7]] == 0.0)


def test_equally_noisy_axes_keep_one_sigma():
    # Equal variances are rejected at AXES_ALPHA: about that share of recordings with equal noise is weighted, by
    # weights close to one; a ratio of 1.3 over 3000 readings is seen.
    from fluxcal.diagnose.core import AXES_ALPHA, _axis_noise, _difference_noise

    rng = np.random.default_rng(4)
    taken = [_axis_noise(rng.normal(0, 1, (3000, 3)), _difference_noise) for _ in range(400)]
    weighted = [t for t in taken if t is not None]
    assert len(weighted) <= 2 * AXES_ALPHA * len(taken) + 2, len(weighted)
    assert all(np.all(np.abs(t[0] - 1) < 0.1) for t in weighted)
    e = rng.normal(0, 1, (3000, 3)) * [1.0, 1.0, 1.3]
    w, relative, p = _axis_noise(e, _difference_noise)
    assert p < 1e-6 and np.sqrt(np.mean(relative ** 2)) == pytest.approx(1.0)
    np.testing.assert_allclose(relative / relative[0], [1.0, 1.0, 1.3], rtol=0.06)
    # an axis whose readings stay on one step of a grid for several readings (a smooth slow course rounded to 3):
    # its third differences are next to zero, and its σ is its rounding's, step/√12, not the 0.1 of the RMS it
    # had been clipped to (weight 10)
    slow = 10 * np.sin(np.linspace(0, 6, 3000))
    e[:, 2] = np.round(slow / 3.0) * 3.0 - slow
    assert _difference_noise(e[:, [2]], 3) < 0.01
    w, relative, p = _axis_noise(e, _difference_noise, np.array([0.0, 0.0, 3.0 / np.sqrt(12)]))
    np.testing.assert_allclose(relative / relative[0], [1.0, 1.0, 3.0 / np.sqrt(12)], rtol=0.06)


def test_readings_rounded_to_a_coarse_grid_keep_one_sigma():
    # Readings on a grid 20× their noise (σ raised to the quantization floor), one axis turning slowly: their
    # "noise" is rounding, as large on every axis that moves. Weighted by its third differences (the slow axis
    # 0.1 of the RMS, weight 10) the base's residuals read 6 σ and a magnet was named (a review, helper-202).
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(1)
    t = np.arange(3000) / 50.0
    field = np.array([20.0, 1.0, 45.8]) * 50 / np.linalg.norm([20.0, 1.0, 45.8])
    angles = np.column_stack([np.radians(90) * t, np.radians(30) * np.sin(2 * np.pi * 0.05 * t),
                              np.radians(20) * np.sin(2 * np.pi * 0.031 * t + 1)])
    ref = Rotation.from_euler("zyx", angles).inv().apply(field)
    clean = np.array([3.0, -2.0, 5.0]) + ref @ np.diag([1.03, 0.97, 1.01]).T
    m = np.round((clean + rng.normal(0, 0.05, clean.shape)) / 1.0) * 1.0
    d = diagnose(m, t=t, reference=ref, units="uT")
    assert "quantization floor" in d.noise_source and d.axis_noise is None
    assert d.where["overall"]["rms_z"] < 1.2


def test_a_noise_the_effects_found_shrink_is_said_with_the_sigma_they_leave():
    # Turned at 300°/s and logged at 20 Hz, the readings' differences hold the motion (σ 0.16 for 0.05) and the
    # residuals' hold the 15 ms delay's error: once time_offset is modelled the residuals left scatter 0.3 σ.
    from fluxcal.sim.effects import HardIron, SoftIron, TimeOffset, WhiteNoise
    from fluxcal.sim.withheld import FIELD

    rng = np.random.default_rng(0)
    scene = sim.tumble(120.0, rate_hz=20.0, turn_rate_deg=300.0, rng=rng)
    effects = [TimeOffset(0.015), SoftIron(np.diag([1.03, 0.97, 1.01])), HardIron([4.0, -3.0, 2.0]), WhiteNoise(0.05)]
    r = sim.simulate(scene, effects, FIELD, rng)
    d = diagnose(r.readings, t=r.t, reference=r.truth)
    assert d.accepted == ["time_offset"] and d.noise_sigma > 0.1
    said = next(c for c in d.caveats if c.startswith("noise σ:"))
    suggested = float(re.search(r"--noise-sigma ([0-9.]+)", said).group(1))
    assert suggested == pytest.approx(0.05, rel=0.1), said
    # (a σ given or one the residuals bear out is not questioned)
    assert not any(c.startswith("noise σ:") for c in diagnose(r.readings, t=r.t, reference=r.truth,
                                                               noise_sigma=suggested).caveats)


def test_noise_estimate_from_third_differences():
    result, _ = withheld_trial([], 7)
    assert estimate_noise(result.readings) == pytest.approx(0.05, rel=0.05)


def test_refine_terms_matches_scipy_oracle():
    result, kwargs = withheld_trial(["temp_offset"], 3)
    m = result.readings[:800]
    temp = kwargs["temp"][:800]
    feats = np.zeros((len(m), 3, 3))
    for k in range(3):
        feats[:, k, k] = temp - temp.mean()
    start = fluxcal.calibrate(m, field_norm=50.0)
    got = fluxcal._core.refine_terms(start.offset, start.matrix, 50.0, "", np.ascontiguousarray(m),
                                     feats.reshape(len(m), 9), np.zeros(3), [], fluxcal._core.RefineOptions(), None)
    want = oracle_refine_terms(start, m, feats)
    np.testing.assert_allclose(got["parameters"], want, rtol=0, atol=1e-7 * np.abs(want).max())
    # a fixed parameter stays at its start value
    fixed = fluxcal._core.refine_terms(start.offset, start.matrix, 50.0, "", np.ascontiguousarray(m),
                                       feats.reshape(len(m), 9), np.zeros(3), ["a01"], fluxcal._core.RefineOptions(),
                                       None)
    assert fixed["parameters"][4] == pytest.approx(start.matrix[0, 1], abs=1e-12)


def test_cli_diagnose_writes_json_and_report(tmp_path):
    result, kwargs = withheld_trial(["temp_offset"], 11)
    m = result.readings
    path = fluxcal.write_csv(tmp_path / "rec.csv", {"t": result.t, "temp": kwargs["temp"], "mx": m[:, 0],
                                                   "my": m[:, 1], "mz": m[:, 2]}, units={"mx": "uT", "my": "uT", "mz": "uT"})
    out = run_cli("diagnose", str(path), "--json", str(tmp_path / "out.json"), "--report", str(tmp_path / "rep"),
                  "--quiet")
    assert out.returncode == 0, out.stderr
    d = json.loads((tmp_path / "out.json").read_text())
    assert d["significant"] is True
    top = d["ranking"][0]
    assert top["effect"] == "temp_offset"
    for key in ("delta_bic", "lr_pvalue", "heldout_gap_before", "heldout_gap_after"):
        assert isinstance(top[key], float)
    assert top["heldout_gap_after"] < 0.3 * top["heldout_gap_before"]
    assert (tmp_path / "rep" / "index.html").exists() and (tmp_path / "rep" / "orientation.png").exists()


def test_cli_finds_motor_current_in_a_current_column(tmp_path):
    # A bench log with the motors' current (mA) beside the readings: the CLI takes the column by its name
    # and unit, finds the compass-motor interference and gives it in field units per A.
    result, kwargs = withheld_trial(["motor_current"], 4)
    m = result.readings
    path = fluxcal.write_csv(tmp_path / "rec.csv", {"t": result.t, "motor_current_mA": 1e3 * kwargs["current"],
                                                   "mx": m[:, 0], "my": m[:, 1], "mz": m[:, 2]})
    out = run_cli("diagnose", str(path), "--json", str(tmp_path / "out.json"), "--quiet")
    assert out.returncode == 0, out.stderr
    d = json.loads((tmp_path / "out.json").read_text())
    assert d["accepted"] == ["motor_current"]
    truth = next(e.k for e in result.effects if e.name == "motor_current")
    top = d["ranking"][0]
    assert np.allclose(top["coefficients"], truth, atol=4 * np.max(top["standard_errors"]))
    percent = 100 * np.linalg.norm(truth) * np.max(kwargs["current"]) / 50.0  # the interference at peak current
    said = re.search(r"([0-9.]+) % of the field \(compassmot's 'interference'\)", out.stdout)
    assert said and abs(float(said.group(1)) - percent) < 0.05 * percent, (percent, out.stdout)


def test_a_current_jittering_from_reading_to_reading_is_no_noise():
    # Throttle or PWM jitter: the current (logged beside the readings) changes by amperes from one reading to the
    # next, and the readings follow it. Their third differences held it (σ 2–3× the sensor's, a blind check), and
    # the motor was then refused as "below the noise" while a step took its place. The σ is taken from the
    # readings less what follows the logged current's fast changes.
    for seed in range(3):
        current = sim.jittering(np.random.default_rng(100 + seed))
        result, kwargs = withheld_trial(["motor_current"], seed, current=current)
        d = diagnose(result.readings, **kwargs)
        assert abs(d.noise_sigma / NOISE - 1) < 0.1, (seed, d.noise_sigma, d.noise_source)
        assert "follows the logged current's fast changes" in d.noise_source, d.noise_source
        assert d.accepted == ["motor_current"], (seed, d.accepted)
        row = next(r for r in d.ranking if r["effect"] == "motor_current")
        truth = next(e.k for e in result.effects if e.name == "motor_current")
        assert np.all(np.abs(np.asarray(row["coefficients"]) - truth) < 4 * np.asarray(row["standard_errors"])), seed
    # a current that only changes slowly (the default scene's) leaves the σ as the readings' differences give it
    result, kwargs = withheld_trial(["motor_current"], 0)
    assert "logged current" not in diagnose(result.readings, **kwargs).noise_source


def test_a_current_that_follows_time_cannot_be_told_from_a_drift():
    # compassmot-style: the throttle only ramps up, so a field growing with the current and one drifting
    # in time are the same signature; the report says so and what would separate them.
    result, kwargs = withheld_trial(["motor_current"], 0, current=lambda t: 2 + 18 * t / t[-1])
    d = diagnose(result.readings, **kwargs)
    # the two tie to rounding (ΔBIC equal to 1e-11): which one leads depends on the machine's arithmetic,
    # so the test asks only that each is named as the other's rival
    pairs = {frozenset((winner, r["effect"])) for winner, rows in d.confounded.items() for r in rows}
    assert frozenset(("motor_current", "offset_drift")) in pairs, d.confounded
    assert any("vary independently would separate them" in line and "the current drawn near the sensor" in line
               and "the elapsed time" in line for line in d.text().splitlines()), d.text()
    # without the current column the candidate is named as not tried
    d = diagnose(result.readings, t=kwargs["t"], field_norm=50.0)
    assert "motor_current" in d.remaining["skipped_candidates"]


def test_accepted_coefficients_are_the_final_models():
    # motor_current is accepted first, temp_offset second: the round that accepted the current fitted it
    # without the temperature term (its k was up to 11 SE off); the reported k is the final joint fit's.
    for seed in range(3):
        result, kwargs = withheld_trial(["motor_current", "temp_offset"], seed)
        d = diagnose(result.readings, **kwargs)
        assert set(d.accepted) == {"motor_current", "temp_offset"}, d.accepted
        for e in result.effects:
            if e.name in d.accepted:
                r = next(r for r in d.ranking if r["effect"] == e.name)
                z = (np.asarray(r["coefficients"]) - (e.k if e.name == "motor_current" else e.beta)) \
                    / np.asarray(r["standard_errors"])
                assert np.all(np.abs(z) < 4), (seed, e.name, z)


def test_motors_mostly_off_still_leave_a_held_out_quarter():
    # 0 A for four fifths of the time (motors off), 18 A bursts. A threshold at the quantile (0 A) would hold
    # out every reading; the top quarter by rank would hold out every burst, leaving the fit no current to
    # learn from: interleaved blocks of time are held out instead.
    result, kwargs = withheld_trial(["motor_current"], 2, current=lambda t: np.where(t % 20.0 > 16.0, 18.0, 0.0))
    d = diagnose(result.readings, **kwargs)
    assert d.accepted == ["motor_current"], d.accepted
    top = d.ranking[0]
    assert top["heldout"] == "events" and top["heldout_n"] <= 0.26 * len(result.readings)
    assert top["heldout_gap_after"] < 0.25 * top["heldout_gap_before"]


def test_side_columns_with_gaps_and_missing_timestamps():
    # A blank cell in the current column costs that column, not the diagnosis; a delay needs timestamps,
    # not row numbers.
    result, kwargs = withheld_trial(["temp_offset"], 3)
    m, current = result.readings, np.linspace(1.0, 9.0, len(result.readings))
    current[10] = np.nan
    rec = fluxcal.Recording(columns={"t": result.t, "temp": kwargs["temp"], "current": current, "mx": m[:, 0],
                                     "my": m[:, 1], "mz": m[:, 2]})
    d = diagnose(rec)
    assert d.accepted == ["temp_offset"] and "motor_current" in d.remaining["skipped_candidates"]
    assert "its current column has 1 missing or non-finite values and was not used" in d.noise_source
    result, kwargs = withheld_trial(["time_offset"], 0)
    d = diagnose(result.readings, reference=kwargs["reference"], field_norm=50.0)
    assert "time_offset" in d.remaining["skipped_candidates"]


def test_bad_input_is_a_clear_error():
    with pytest.raises(ValueError, match="at least 50"):
        diagnose(np.random.default_rng(0).standard_normal((20, 3)))
    result, kwargs = withheld_trial([], 1)
    with pytest.raises(ValueError, match="unknown effect"):
        diagnose(result.readings, candidates=["gremlins"], **kwargs)
    with pytest.raises(ValueError, match="reference"):
        diagnose(np.random.default_rng(0).standard_normal((100, 3)), model="vector")
    current = np.full(len(result.readings), 5.0)
    current[7] = np.nan
    with pytest.raises(ValueError, match="current: 1 of the 3000 currents are not finite"):
        diagnose(result.readings, current=current, **kwargs)


@pytest.mark.parametrize("name", ["phone_acc_mag.csv", "handheld_set1.csv"])
def test_real_recordings_run(real_data, name):
    rec = fluxcal.read_csv(real_data / name, columns="x,y,z" if name.startswith("handheld") else None)
    d = diagnose(rec)
    assert d.ranking and all(np.isfinite(r["delta_bic"]) for r in d.ranking)


def test_sample_and_hold_repeats_are_left_out():
    """A logger at 3× the sensor's rate repeats each reading three times: the noise is still estimated right
    (third differences of the copies would shrink it) and nothing is reported (the copies would look like
    coloured noise); the report says what was left out."""
    quiet = 0
    for seed in range(5):
        result, kwargs = withheld_trial([], 300 + seed)
        held = np.repeat(result.readings, 3, axis=0)
        t = np.arange(len(held)) * (result.t[1] - result.t[0]) / 3.0
        temp = np.repeat(kwargs["temp"], 3)
        d = diagnose(held, t=t, temp=temp, field_norm=kwargs["field_norm"])
        assert d.noise_sigma == pytest.approx(0.05, rel=0.1)
        assert f"{2 * len(result.readings)} of {len(held)} readings (67 %) repeat the previous one" in d.noise_source
        quiet += not d.significant
    assert quiet >= 4, f"no significant effect in only {quiet}/5"
    # calibrate keeps every reading but says its standard errors would count the copies
    assert any("sample and hold" in w for w in fluxcal.calibrate(held).summary["warnings"])
    assert not any("sample and hold" in w for w in fluxcal.calibrate(result.readings).summary["warnings"])


def test_quantization_floor_on_the_noise_estimate():
    from fluxcal.diagnose.core import quantization_step

    rng = np.random.default_rng(4)
    assert quantization_step(rng.normal(size=(500, 3))) == 0.0  # continuous readings: no grid
    grid = np.round(rng.normal(scale=20.0, size=(500, 3)) / 0.25) * 0.25 + 3.0
    assert quantization_step(grid) == pytest.approx(0.25)
    # Slow turns with a 1-LSB ADC and noise of 0.1 LSB: most third differences are exactly zero, so the
    # MAD estimate collapses; the σ used is LSB/√12.
    scene = sim.sweeps("yxz", per_turn=3000)
    field = np.array([20.0, 5.0, 45.0])
    clean = scene.sensor_field(field) * [1.02, 0.98, 1.0] + [4.0, -3.0, 2.0]
    readings = np.round((clean + rng.normal(scale=0.1, size=clean.shape)) / 1.0) * 1.0
    assert estimate_noise(readings) < 0.1
    d = diagnose(readings, t=scene.t, field_norm=float(np.linalg.norm(field)), candidates=["offset_drift"])
    assert d.noise_sigma == pytest.approx(1.0 / np.sqrt(12.0))
    assert "quantization floor" in d.noise_source and "repeat" not in d.noise_source


def test_noise_estimate_when_the_turns_are_fast_for_the_sample_rate():
    # A hand turn logged at 10 Hz: third differences of the readings hold the motion (σ comes out ~1.9x),
    # so the noise is taken from the base model's residuals in time order.
    from fluxcal.sim.effects import HardIron, SoftIron, WhiteNoise
    from fluxcal.sim.simulate import simulate
    from fluxcal.sim.withheld import FIELD

    rng = np.random.default_rng(0)
    scene = sim.tumble(300.0, rate_hz=10.0, rng=rng)
    W = np.diag([1.03, 0.97, 1.01]) + 0.02 * (np.eye(3)[[1, 0, 2]] - np.diag([0, 0, 1]))
    result = simulate(scene, [SoftIron(W), HardIron([4.0, -3.0, 2.0]), WhiteNoise(0.05)], FIELD, rng)
    assert estimate_noise(result.readings) > 1.5 * 0.05
    d = diagnose(result.readings, t=result.t, field_norm=50.0, candidates=["offset_drift"])
    assert d.noise_sigma == pytest.approx(0.05, rel=0.1)
    assert "base model's residuals" in d.noise_source


@pytest.mark.parametrize("seed", range(2))
def test_rows_out_of_time_order(seed):
    # Rows shuffled (a log sorted by another column, positions in any order): third differences of the
    # readings hold the whole field (σ 580x too high: nothing was ever found). The noise now comes from the
    # base model's residuals, and the report says why and asks for the datasheet σ.
    for names in (["nonlinearity_cubic"], []):
        result, kwargs = withheld_trial(names, seed)
        rows = np.random.default_rng(seed).permutation(len(result.readings))
        d = diagnose(result.readings[rows], field_norm=50.0)
        assert "not a time series" in d.noise_source and "noise_sigma" in d.noise_source
        assert d.accepted == names
        if not names:
            assert d.noise_sigma == pytest.approx(0.05, rel=0.15)  # the simulated white noise


def test_a_static_sensor_is_still_a_time_series():
    # Readings that do not turn spread by their noise only: not to be taken for shuffled rows.
    rng = np.random.default_rng(2)
    m = np.array([20.0, 1.0, 45.0]) + 0.05 * rng.standard_normal((2000, 3))
    ref = np.tile([20.0, 1.0, 45.0], (2000, 1))
    from fluxcal.diagnose.core import _Data, _noise

    data = _Data(m, np.arange(2000.0), None, ref, None, 0.0, "", "static", [])
    sigma, source, bound, _ = _noise(data, {"residuals": m - m.mean(axis=0)})
    assert "not a time series" not in source and not bound and sigma == pytest.approx(0.05, rel=0.1)


@pytest.mark.parametrize("positions,held", [(12, 5), (24, 4)])
def test_noise_estimate_when_positions_are_held_a_few_readings_each(positions, held):
    # A multi-position log at 1 Hz: the steps between positions raise the 4th-order estimate above the
    # 3rd and held the 3rd-order σ at 72-125x the noise; the base model's residuals do not step.
    from scipy.spatial.transform import Rotation

    from fluxcal.sim.effects import HardIron, SoftIron, WhiteNoise
    from fluxcal.sim.scene import Scene
    from fluxcal.sim.simulate import simulate
    from fluxcal.sim.withheld import FIELD

    rng = np.random.default_rng(3)
    at = Rotation.random(positions, random_state=rng)[np.repeat(np.arange(positions), held)]
    scene = Scene(at, np.arange(positions * held, dtype=float))
    W = np.diag([1.03, 0.97, 1.01])
    result = simulate(scene, [SoftIron(W), HardIron([4.0, -3.0, 2.0]), WhiteNoise(0.05)], FIELD, rng)
    assert estimate_noise(result.readings) > 2 * 0.05
    d = diagnose(result.readings, t=result.t, field_norm=50.0, candidates=["offset_drift"])
    assert d.noise_sigma == pytest.approx(0.05, rel=0.3) and "steps between held positions" in d.noise_source


def test_rows_given_out_of_time_order_are_sorted():
    result, kwargs = withheld_trial(["nonlinearity_cubic"], 0)
    rows = np.random.default_rng(0).permutation(len(result.readings))
    m = result.readings[rows]
    m[[5, 8]] = 0.0  # two I²C glitches, named by their rows in the input
    d = diagnose(m, t=kwargs["t"][rows], temp=kwargs["temp"][rows], field_norm=50.0)
    assert d.accepted == ["nonlinearity_cubic"] and d.noise_sigma == pytest.approx(0.05, rel=0.1)
    assert "sorted by t" in d.noise_source and "(rows 5, 8;" in d.noise_source


def test_a_clock_that_wraps_keeps_the_row_order():
    # Arduino's micros() wraps every 71.6 min: t jumps back once in a log written in time order. Sorted by
    # t, the two halves swapped places and the drift was missed or called colored noise (0/3 seeds).
    result, kwargs = withheld_trial(["offset_drift"], 0)
    wrapped = ((np.round(kwargs["t"] * 1e6) + 2 ** 32 - 30e6) % 2 ** 32) * 1e-6  # wraps 30 s in
    d = diagnose(result.readings, **dict(kwargs, t=wrapped))
    assert d.accepted == ["offset_drift"]
    assert "t went backwards at row 1500 (a counter wrap" in d.noise_source


@pytest.mark.parametrize("tau", [3.0, 12.0, 40.0])
def test_an_offset_settling_after_power_on_is_a_warm_up_not_a_step(tau):
    # An offset settling exponentially (a sensor warming up) with no temperature logged: before, a 3–15 s
    # settling in a minute was called an offset step near the start, a 40 s one a linear drift plus a step
    # (the linear one overshot). The time constant is profiled; the settled offset is the coefficient.
    from fluxcal.diagnose.report import text
    from fluxcal.sim.effects import HardIron, OffsetDrift, SoftIron, WhiteNoise
    from fluxcal.sim.simulate import simulate
    from fluxcal.sim.withheld import FIELD

    for seed in range(2):
        rng = np.random.default_rng(seed)
        settled = rng.choice([-1, 1], 3) * rng.uniform(0.25, 0.4, 3)  # µT, 0.5–0.8 % of the field
        scene = sim.tumble(60.0, rate_hz=50.0, rng=rng)
        W = np.diag([1.03, 0.97, 1.01])
        effects = [SoftIron(W), HardIron([4.0, -3.0, 2.0]), OffsetDrift(settled / tau, warmup_s=tau), WhiteNoise(0.05)]
        result = simulate(scene, effects, FIELD, rng)
        d = diagnose(result.readings, t=result.t, field_norm=50.0)
        assert d.accepted == ["offset_drift"], (seed, d.accepted)
        row = d.ranking[0]
        assert row["warmup_s"] == pytest.approx(tau, rel=0.15)
        assert np.all(np.abs(np.subtract(row["coefficients"], settled)) < 4 * np.asarray(row["standard_errors"]))
        assert f"time constant of {row['warmup_s']:.3g} s" in text(d)


def test_a_sensitivity_warming_up_unlogged_is_a_scale_drift_with_its_time_constant():
    # A temperature scale error whose temperature rises exponentially (τ = 15 s) and is not logged: it was
    # taken for colored noise, a moving magnet or an offset drift. Now a sensitivity settling in time, the
    # settling α·ΔT per axis, and the report says the temperature may be the cause.
    for seed in range(2):
        result, kwargs = withheld_trial(["temp_scale"], seed, temperature=lambda t: 20.0 + 15.0 * (1 - np.exp(-t / 15.0)))
        alpha = next(e for e in result.effects if e.name == "temp_scale").alpha
        del kwargs["temp"]
        d = diagnose(result.readings, **kwargs)
        assert d.accepted == ["scale_drift"], d.accepted
        row = d.ranking[0]
        assert row["warmup_s"] == pytest.approx(15.0, rel=0.15)
        settled = alpha * 15.0  # the scale's whole change, 1 + α (T − T0) with T settling by 15 °C
        assert np.all(np.abs(np.subtract(row["coefficients"], settled)) < 0.1 * np.abs(settled))
        assert "the sensitivity settles exponentially" in d.text() and "MAYBE TEMPERATURE" in d.text()


def test_a_settling_longer_than_the_recording_is_said_to_be_extrapolated():
    # τ = 100 s in a minute: the fitted end value lies beyond the recording, and τ at the grid's end is a bound
    from fluxcal.sim.effects import HardIron, OffsetDrift, SoftIron, WhiteNoise
    from fluxcal.sim.simulate import simulate
    from fluxcal.sim.withheld import FIELD

    rng = np.random.default_rng(0)
    scene = sim.tumble(60.0, rate_hz=50.0, rng=rng)
    effects = [SoftIron(np.diag([1.03, 0.97, 1.01])), HardIron([4.0, -3.0, 2.0]),
               OffsetDrift(np.array([1.0, -0.8, 0.9]) / 100.0, warmup_s=100.0), WhiteNoise(0.05)]
    r = simulate(scene, effects, FIELD, rng)
    d = diagnose(r.readings, t=r.t, field_norm=50.0)
    line = next(x for x in d.text().splitlines() if "offset_drift: the offset settles" in x)
    share = -np.expm1(-np.ptp(r.t) / d.ranking[0]["warmup_s"])
    assert f"within the recording, {round(100 * share)} % of the way towards" in line, line
    assert "(that end value extrapolated)" in line
    # what changed inside the recording leads (a blind check's led with an end value 5× the step it had found)
    inside = [float(x) for x in re.search(r"by \[([^]]*)\]", line).group(1).split(",")]
    assert np.allclose(inside, np.round(share * np.asarray(d.ranking[0]["coefficients"]), 4), atol=1e-4), line
    assert ("at least" in line) == (d.ranking[0]["warmup_s"] >= 0.99 * 2 * np.ptp(r.t))


def test_a_linear_drift_has_no_time_constant():
    result, kwargs = withheld_trial(["offset_drift"], 0)
    d = diagnose(result.readings, **kwargs)
    assert d.accepted == ["offset_drift"] and "warmup_s" not in d.ranking[0]
    drift = next(e for e in result.effects if e.name == "offset_drift")
    # the coefficient is the drift across the recording (rate × span)
    assert np.allclose(d.ranking[0]["coefficients"], drift.rate * np.ptp(result.t), atol=0.03)


@pytest.mark.parametrize("name,model", [("offset_step", None), ("moving_dipole", None), ("moving_dipole", "vector")])
def test_a_box_is_scored_on_its_rows_as_on_all_readings(monkeypatch, name, model):
    # The box search (and moving_dipole's pass search) scores each box from the readings inside it (Gram
    # matrices over those rows); the score must be the one over all readings with zeros outside the box, for
    # the magnitude and the vector model, given the rows as a slice or as indices.
    from fluxcal.sim.effects import MovingDipole, OffsetStep, scatter_rows

    compared, calls = [], []
    cls_searched = {"offset_step": OffsetStep, "moving_dipole": MovingDipole}[name]
    search = cls_searched.search.__func__

    def checked(cls, ctx, score):
        def both(feats, rows):
            value = score(feats, rows)
            calls.append(value)
            if len(compared) < 60 and len(calls) % 10 == 0:  # boxes across the coarse scan and the refinement
                indices = np.arange(len(ctx.t))[rows]
                compared.append((value, score(scatter_rows(len(ctx.t), feats, rows)), score(feats, indices)))
            return value
        return search(cls, ctx, both)

    monkeypatch.setattr(cls_searched, "search", classmethod(checked))
    result, kwargs = withheld_trial([name], 3, model=model)
    diagnose(result.readings, **kwargs, candidates=[name])
    compared = np.array(compared)
    assert len(compared) == 60 and max(calls) > 100  # the effect's own box scores high
    np.testing.assert_allclose(compared[:, 0], compared[:, 1], rtol=1e-7, atol=1e-7)
    np.testing.assert_allclose(compared[:, 2], compared[:, 1], rtol=1e-7, atol=1e-7)


@pytest.mark.parametrize("name,seed,edges", [("offset_step", 0, 1), ("offset_step", 1, 2), ("moving_dipole", 0, 2),
                                             ("pass", 0, 2)])
def test_the_times_an_events_search_placed_pay_in_bic(name, seed, edges):
    # A time the search placed is a parameter the data chose, as a drift's profiled time constant is: a box's edges
    # inside the recording (an edge at an end makes it a step), a pass's closest approach and passage time. Each
    # pays ln N in ΔBIC (2 in ΔAIC); the p-value pays for them through the alternatives tried, not its degrees.
    from fluxcal.sim.effects import MovingDipole, OffsetStep, ScaleDrift

    assert OffsetStep.searched_times({"on_s": 3.0, "off_s": None}) == 1
    assert OffsetStep.searched_times({"on_s": 3.0, "off_s": 9.0}) == 2
    assert MovingDipole.searched_times({"on_s": None, "off_s": 9.0}) == 1
    assert MovingDipole.searched_times({"on_s": 3.0, "off_s": 9.0, "closest_s": 6.0, "passage_s": 0.5}) == 2
    assert ScaleDrift.searched_times({"on_s": 3.0}) == 0
    pass_ = MovingDipole.straight_pass(50.0, np.random.default_rng(seed), 30.0, 1.0, 0.03) if name == "pass" else None
    result, kwargs = withheld_trial(["moving_dipole" if pass_ else name], seed, dipole=pass_)
    d = diagnose(result.readings, **kwargs)
    row = next(r for r in d.ranking if r["effect"] in (name, "moving_dipole"))
    # (the simulated step at seed 0 stays on to the end: one edge; a pass: its closest approach is read back)
    assert (row.get("closest_s") is not None) == (name == "pass") and row["searched_times"] == edges
    assert row["delta_aic"] == pytest.approx(-row["lr"] + 2 * (row["new_dimensions"] + edges), abs=1e-9)
    ln_n = (row["delta_bic"] + row["lr"]) / (row["new_dimensions"] + edges)
    assert ln_n == pytest.approx(np.log(len(result.readings)), abs=0.01)


def test_heldout_gain_confined_to_one_block_is_significant():
    # An event: the held-out gain sits in one block and is tiny elsewhere, but positive in every block.
    # The sign-flip test sees 30 positive blocks (p 2^-30); a t-test on such skewed means gives p ≈ 0.16.
    from fluxcal.diagnose.core import _improvement_pvalue

    after = np.random.default_rng(1).normal(size=3000)
    gain = np.full(3000, 1e-3)
    gain[:100] = 1.0
    assert _improvement_pvalue(np.sqrt(after ** 2 + gain), after) < 1e-6
    assert _improvement_pvalue(after, after) == 1.0


def test_effects_a_magnitude_model_cannot_see_are_named():
    result, kwargs = withheld_trial(["temp_offset"], 3)
    d = diagnose(result.readings, t=kwargs["t"], field_norm=50.0)  # no temperature, no reference vectors
    assert {"misalignment", "time_offset"} <= set(d.remaining["invisible_candidates"])
    assert "misalignment" not in [r["effect"] for r in d.ranking]
    words = d.text()
    assert "leaves |h| unchanged" in words
    # the temperature effect shows up as something that varies in time; the report says what to log
    assert d.accepted and "MAYBE TEMPERATURE" in words and "Log the sensor's temperature" in words


def test_noisy_readings_do_not_fake_a_non_linearity():
    # White noise at 1 % of the field and nothing else. Features non-linear in the raw readings carried
    # their noise, which correlates with the residual's: saturation came first in 29/30 such trials and
    # was accepted in 6. They are now computed from the fitted model's noise-free reading.
    from fluxcal.sim.effects import HardIron, SoftIron, WhiteNoise
    from fluxcal.sim.simulate import simulate
    from fluxcal.sim.withheld import FIELD

    small_p, accepted = 0, []
    for seed in range(10):
        rng = np.random.default_rng(seed)
        scene = sim.tumble(60.0, rng=rng)
        W = np.diag(1 + rng.uniform(-0.05, 0.05, 3))
        result = simulate(scene, [SoftIron(W), HardIron(rng.uniform(-5, 5, 3)), WhiteNoise(0.5)], FIELD, rng)
        d = diagnose(result.readings, t=result.t, temp=result.temperature, field_norm=50.0,
                     candidates=["saturation", "nonlinearity_cubic", "cross_axis", "hysteresis"])
        accepted += d.accepted
        small_p += sum(r["lr_pvalue"] < 0.01 for r in d.ranking)
    assert not accepted, accepted
    assert small_p <= 2, f"{small_p} of 40 in-sample p-values below 0.01"


def test_a_special_case_is_not_a_rival():
    # Saturation is nonlinearity_cubic with equal coefficients on every axis: when the per-axis terms add
    # nothing, the data chose the special case; that is not "cannot tell apart".
    result, kwargs = withheld_trial(["saturation"], 7)
    d = diagnose(result.readings, **kwargs)
    assert d.accepted == ["saturation"] and not d.confounded, d.confounded
    assert next(r for r in d.ranking if r["effect"] == "nonlinearity_cubic")["delta_bic"] > 0


@pytest.mark.parametrize("sign, expected", [(1.0, "nonlinearity_cubic"), (-1.0, "saturation")])
def test_an_expanding_cubic_is_not_saturation(monkeypatch, sign, expected):
    # A cubic with equal coefficients on every axis is saturation's first order, but only when it compresses:
    # an expanding one was reported as saturation (a negative size). Saturation's size must be positive; the
    # expansion is then the per-axis cubic, and the compression is still saturation.
    from fluxcal.sim.effects import CubicNonlinearity

    monkeypatch.setattr(CubicNonlinearity, "typical",
                        classmethod(lambda cls, field_norm, rng: cls(np.full(3, sign * 0.015), field_norm)))
    for seed in range(2):
        result, kwargs = withheld_trial(["nonlinearity_cubic"], seed)
        d = diagnose(result.readings, **kwargs)
        assert d.accepted == [expected], (seed, d.accepted)


def test_unphysical_signs_are_named():
    from fluxcal.sim.effects import CubicNonlinearity, Hysteresis, Saturation

    assert "axis y" in Hysteresis.unphysical([0.1, -0.05, 0.1], [0.01] * 3)
    assert Hysteresis.unphysical([0.1, -0.01, 0.1], [0.01] * 3) == ""  # within two standard errors of zero
    assert "expanding" in Saturation.unphysical([-0.02], [0.001]) and Saturation.unphysical([0.02], [0.001]) == ""
    assert CubicNonlinearity.unphysical([-0.02, 0.02, 0.0], [0.001] * 3) == ""  # either sign is a sensor's


def test_a_cubic_about_a_large_hard_iron_is_found_alone():
    # Real sensors carry hard iron of several fields (a QMC5883L board 6.6×, phones and drones 1–5×) and scale
    # errors of 10–20 %. The base fit, without the cubic, absorbs its constant and linear parts about the hard
    # iron (c b³ into the offset, 3c b² into the scale): features computed at that fit's signal left 0.47 and
    # 0.05 µT here (seeds 0, 1; hard iron 4.4 and 2.7 fields), taken for coloured noise. They are now
    # recomputed at the signal of the fit that models the cubic. Nothing withheld still reports nothing.
    for seed in range(3):
        result, kwargs = withheld_trial(["nonlinearity_cubic"], seed, hard_iron=6.0, soft_iron=0.15)
        d = diagnose(result.readings, **kwargs)
        assert d.accepted == ["nonlinearity_cubic"], (seed, d.accepted)
        assert d.remaining["overall"]["gap"] < 0.5 * 0.05, (seed, d.remaining["overall"]["gap"])
    for seed in range(200, 203):
        result, kwargs = withheld_trial([], seed, hard_iron=6.0, soft_iron=0.15)
        assert not diagnose(result.readings, **kwargs).accepted


def test_saturation_about_a_large_hard_iron_is_found_as_saturation():
    # About a hard iron of several fields the signal reaches the limit L (4× the field here): L tanh(s/L) is far
    # from its first-order cubic, and the per-axis cubic won (0/3 before the limit was profiled). Now the limit is
    # profiled from the readings' reach up (counted as a parameter): found alone, L within 5 % of the truth.
    from fluxcal.sim.effects import Saturation

    for seed in range(3):
        result, kwargs = withheld_trial(["saturation"], seed, hard_iron=6.0, soft_iron=0.15)
        d = diagnose(result.readings, **kwargs)
        assert d.accepted == ["saturation"], (seed, d.accepted)
        truth = next(e for e in result.effects if isinstance(e, Saturation)).limit
        assert d.ranking[0]["limit"] == pytest.approx(truth, rel=0.05), (seed, d.ranking[0]["limit"], truth)
        assert d.remaining["overall"]["gap"] < 0.5 * 0.05, (seed, d.remaining["overall"]["gap"])


def test_the_saturation_limit_said_is_the_one_that_gives_the_compression_said():
    # The fit scales the tanh's shape by a free size, so its profiled limit is a shape: seed 3's came out 110 for a
    # true 247 (its size then compressing as a 247 would), and the text read "limit 110 … compresses by x %". The
    # limit said is the tanh's that compresses as the fit does; in the cubic form, the same to first order.
    from fluxcal.sim.effects import Saturation

    for seed in range(5):
        result, kwargs = withheld_trial(["saturation"], seed)
        d = diagnose(result.readings, **kwargs)
        assert d.accepted == ["saturation"], (seed, d.accepted)
        truth = next(e for e in result.effects if isinstance(e, Saturation)).limit
        line = next(x for x in d.text().splitlines() if x.startswith("  saturation:"))
        said = float(re.search(r"(?:limit|saturating at) ([0-9.]+)", line).group(1))
        assert said == pytest.approx(truth, rel=0.05), (seed, line, truth)


def test_quantization_seen_in_a_short_fast_recording():
    # 600 readings at 10 Hz hit ~500 distinct levels of the ADC: most values do not repeat, yet every
    # one lies on the grid. Continuous readings, float32 ones included, are not taken for a grid.
    from fluxcal.diagnose.core import quantization_step

    rng = np.random.default_rng(2)
    x = rng.normal(scale=20.0, size=(600, 3))
    assert quantization_step(x) == 0.0 and quantization_step(x.astype(np.float32).astype(float)) == 0.0
    assert quantization_step(np.round(x / 0.1) * 0.1) == pytest.approx(0.1)
    # a coarse step in gauss printed with 6 decimals: the smallest gap is the step ± the last digit (a blind check's
    # log was taken off its grid, its σ came out 0 and the diagnosis stopped)
    printed = np.round(np.round(x / 50 / 0.0154778) * 0.0154778, 6)
    assert quantization_step(printed) == pytest.approx(0.0154778, rel=1e-4)
    result, kwargs = withheld_trial(["quantization"], 0, rate_hz=10.0)
    assert len(result.readings) == 600
    assert diagnose(result.readings, **kwargs).accepted == ["quantization"]


def test_a_candidate_whose_refit_fails_is_reported_not_fatal(monkeypatch):
    # A candidate nearly inside the model can leave Ceres no valid step; the diagnosis goes on without it.
    import importlib

    core = importlib.import_module("fluxcal.diagnose.core")
    validate = core._validate

    def failing(data, model, state, feats, regime, sigma, **kwargs):
        if regime == "orientation":
            raise fluxcal._core.Error("refine: the solver failed: (simulated)")
        return validate(data, model, state, feats, regime, sigma, **kwargs)

    monkeypatch.setattr(core, "_validate", failing)
    result, kwargs = withheld_trial(["temp_offset"], 1)
    d = diagnose(result.readings, **kwargs)
    assert d.accepted == ["temp_offset"]
    cubic = next(r for r in d.ranking if r["effect"] == "nonlinearity_cubic")
    assert not cubic["significant"] and cubic["note"].startswith("not judged") and "simulated" in cubic["note"]
    assert "not judged: its refit failed" in d.text()


@pytest.mark.parametrize("model", ["ellipsoid", "vector"])
def test_the_heldout_noise_floor_is_what_white_noise_leaves(model):
    # With white noise alone, a held-out fit's field error is the noise carried through the calibration:
    # the floor the degenerate-fit guard compares against (σ u'A for a magnitude, σ‖A‖ against a reference).
    ratios = []
    for seed in range(3):
        result, kwargs = withheld_trial([], 300 + seed, model=model)
        d = diagnose(result.readings, **kwargs, noise_sigma=0.05, candidates=["nonlinearity_cubic"])
        row = d.ranking[0]
        ratios.append(row["field_error_before"] / row["heldout_noise_floor"])
    assert np.all(np.abs(np.array(ratios) - 1) < 0.1), ratios


def test_a_candidate_that_rebuilds_the_readings_from_themselves_is_not_accepted(monkeypatch):
    # Features taken from each reading itself (here its departure from the fitted sphere, exactly) let a fit
    # predict held-out readings better than their noise: every test of evidence passes, yet it models nothing.
    # Three signal-dependent candidates did this on the QMC5883L recording, at coefficients of order one, once an
    # even-order candidate had been tried there.
    from fluxcal.diagnose import core
    from fluxcal.sim.effects import Effect, _per_axis

    class Echo(Effect):
        name = "echo"

        @classmethod
        def features(cls, ctx):
            return _per_axis(ctx.readings - ctx.signal)

    monkeypatch.setattr(core, "CANDIDATES", [*CANDIDATES, Echo])
    result, kwargs = withheld_trial(["offset_step"], 1)
    d = diagnose(result.readings, **kwargs, candidates=["echo", "offset_step"])
    echo = next(r for r in d.ranking if r["effect"] == "echo")
    assert echo["delta_bic"] < -1000 and echo["heldout_gap_after"] < 0.5 * echo["heldout_gap_before"]
    assert echo["field_error_after"] < core.NOISE_FLOOR_FRACTION * echo["heldout_noise_floor"]
    assert echo["degenerate"] == "below the noise held out" and not echo["significant"]
    assert "degenerate" in echo["note"]
    assert d.accepted == ["offset_step"]
    assert "(degenerate: below the noise held out)" in d.text()


def test_distortion_is_the_largest_signal_dependent_block():
    from fluxcal.diagnose.core import _distortion

    rng = np.random.default_rng(0)
    signal = rng.normal(size=(200, 3))
    blocks = [rng.normal(size=(200, 2, 3)), signal[:, None, :], signal[:, None, :]]
    parameters = np.array([9.0] * 9 + [5.0, 5.0, 0.3, 2.0])  # nine base parameters, then the blocks' terms
    assert _distortion(signal, blocks, [False, True, True], parameters, 9) == pytest.approx(2.0)
    assert _distortion(signal, blocks, [False, True, False], parameters, 9) == pytest.approx(0.3)
    assert _distortion(signal, blocks, [False, False, False], parameters, 9) == 0.0


def test_a_row_says_which_acceptance_tests_it_fails():
    from types import SimpleNamespace

    from fluxcal.diagnose.core import _unmet
    from fluxcal.diagnose.report import ranking_lines

    # 13 candidates at α 0.01: the whitened LR p must be below 0.01 / 13
    row = {"effect": "temp_scale", "lr_pvalue": 1e-5, "delta_bic": -300.0, "heldout_pvalue": 0.01,
           "heldout_gap_before": 0.01, "heldout_gap_after": 0.008, "new_dimensions": 3, "heldout": "temperature"}
    assert _unmet(row, 13, 0.01) == []
    assert _unmet(dict(row, lr_pvalue=1e-3), 13, 0.01) == ["in_sample"]
    assert _unmet(dict(row, delta_bic=2.0), 13, 0.01) == ["bic"]
    assert _unmet(dict(row, heldout_pvalue=0.074), 13, 0.01) == ["heldout_p"]
    assert _unmet(dict(row, heldout_gap_after=0.0095), 13, 0.01) == ["heldout_gain"]
    # the report names the case a real recording's slow disturbances most often leave, and only that one
    held = dict(row, heldout_pvalue=0.074, significant=False, unmet=["heldout_p"])
    weak = dict(row, lr_pvalue=1e-3, significant=False, unmet=["in_sample", "heldout_p"])
    lines = ranking_lines(SimpleNamespace(ranking=[dict(row, significant=True, unmet=[]), held, weak]))
    assert "not confirmed" not in lines[2] and "not confirmed" not in lines[4]
    assert "strong in sample, not confirmed held out: p 0.074, gap 0.01 → 0.008" in lines[3]
    # and NOT EXPLAINED says so (a blind check's magnet pass, ΔBIC −10 943, had been passed over for generic causes)
    from fluxcal.diagnose.report import _unconfirmed_words

    said = _unconfirmed_words(SimpleNamespace(ranking=[held, weak]))
    assert "not confirmed on its held-out readings: temp_scale (ΔBIC -300; held out p 0.074, gap 0.01 → 0.008)" in said
    assert _unconfirmed_words(SimpleNamespace(ranking=[weak])) == ""


def test_why_a_fit_cannot_be_an_effect():
    from fluxcal.diagnose.core import _implausible
    from fluxcal.sim.effects import Saturation, TemperatureScale

    row = {"heldout_noise_floor": 1.0, "field_error_before": 1.5, "field_error_after": 1.1, "distortion": 0.02,
           "hidden_change": 0.5, "coefficients": [0.01, 0.02, 0.03], "standard_errors": [0.001] * 3,
           "significant": True}
    assert _implausible(row, 0.05, False, TemperatureScale) is None
    flag, why, note = _implausible(dict(row, field_error_after=0.3), 0.05, False, TemperatureScale)  # below the noise held out
    assert (flag, why) == ("degenerate", "below the noise held out")
    assert "0.30 of what the readings' noise alone leaves" in note and "0.03" in note
    assert _implausible(dict(row, field_error_after=0.3), 0.05, True, TemperatureScale) is None  # σ an upper bound: no floor
    flag, why, note = _implausible(dict(row, distortion=1.4), 0.05, False, TemperatureScale)
    assert (flag, why) == ("degenerate", "changes the readings more than the signal")
    assert "1.4× the signal" in note
    flag, why, note = _implausible(dict(row, field_error_after=1.6), 0.05, False, TemperatureScale)
    assert flag == "field_error_rises" and why and "1.5 → 1.6" in note
    # a course the readings do not show, cancelled by the base: refused before its held-out error is read
    flag, why, note = _implausible(dict(row, hidden_change=7.2, field_error_after=0.3), 0.05, False, TemperatureScale)
    assert (flag, why) == ("degenerate", "changes the readings more than they vary") and "7.2× as much" in note
    assert _implausible(dict(row, field_error_after=1.6, significant=False), 0.05, False, TemperatureScale) is None
    # a sign the effect's physics forbids: a saturation that expands
    flag, why, note = _implausible(dict(row, coefficients=[-0.02], standard_errors=[0.001]), 0.05, False, Saturation)
    assert flag == "unphysical" and "expanding" in why and note.startswith("not accepted as saturation")
    # an even-order error far beyond any magnetometer's: a trade with another term (beside a clean cross-axis error
    # a blind check's fit took 34.5 % of it on x against anisotropy fields of −142 µT)
    from fluxcal.sim.effects import QuadraticNonlinearity

    assert _implausible(dict(row, coefficients=[0.008, -0.003, 0.004]), 0.05, False, QuadraticNonlinearity) is None
    flag, why, _ = _implausible(dict(row, coefficients=[0.345, 0.0003, 0.0008]), 0.05, False, QuadraticNonlinearity)
    assert flag == "unphysical" and "even-order error of 34.5 %" in why


@pytest.mark.parametrize("lag", [40.0, -20.0])
@pytest.mark.parametrize("cls, size", [(sim.effects.TemperatureOffset, np.array([0.015, -0.010, 0.020])),
                                       (sim.effects.TemperatureScale, np.array([0.0008, -0.0006, 0.0007]))])
def test_a_temperature_that_lags_the_logged_one_is_found_with_its_lag(cls, size, lag):
    """The logged temperature is seldom the sensing element's: with a 40 s thermal lag between them, the
    effect is found with that lag, not split into itself and an offset step or a passing magnet; and the
    other way round (the thermometer 20 s behind the element: a false offset drift came with it), from a
    thermometer's 0.1 °C steps with a row lost (unsmoothed slopes over the uneven step wrecked it)."""
    rng = np.random.default_rng(11)
    scene = sim.tumble(480.0, temperature=(25.0, 10.0, 120.0), rng=rng)
    field = np.array([20.0, 1.0, 45.0])
    # µT per °C (15 nT/°C class) or per-axis scale per °C (0.08 %/°C class), after the hard iron: the transducer
    # scales every field it sees
    effects = [sim.effects.SoftIron(np.eye(3) + 0.02 * np.diag([1, -1, 0.5])), sim.effects.HardIron([8.0, -5.0, 3.0]),
               cls(size, lag_s=max(lag, 0.0)), sim.effects.WhiteNoise(0.05)]
    s = sim.simulate(scene, effects, field, rng)
    m, t, logged = s.readings, s.t, s.temperature
    if lag < 0:  # the thermometer |lag| behind the element, logged in 0.1 °C steps, one row lost
        logged = np.round(sim.effects.lagged(s.temperature, s.t, -lag), 1)
        m, t, logged = (np.delete(x, 5000, axis=0) for x in (m, t, logged))
    d = diagnose(m, t=t, temp=logged, field_norm=float(np.linalg.norm(field)), progress=False)
    assert d.accepted == [cls.name], d.accepted
    row = next(r for r in d.ranking if r["effect"] == cls.name)
    assert row["lag_s"] == pytest.approx(lag, rel=0.25)
    assert ("element's temperature lags the logged one by" if lag > 0 else
            "the logged temperature lags the sensing element's by") in d.text()


def test_a_cause_outside_the_candidates_is_said_to_be_unexplained():
    """A soft iron that changes halfway (a steel part moved: no candidate describes it) leaves most of the
    departure to colored_noise and a few guesses; the report says NOT EXPLAINED. A recording whose effect is
    a candidate, or that has none, does not say it."""
    result, kwargs = withheld_trial([], 11)
    m = result.readings.copy()
    half = len(m) // 2
    centre = m.mean(axis=0)
    change = np.array([[1.04, 0.03, 0.0], [0.03, 0.97, 0.02], [0.0, 0.02, 1.03]])  # ±4 % and couplings
    m[half:] = centre + (m[half:] - centre) @ change.T
    moved = diagnose(m, **kwargs)
    assert moved.remaining["unexplained"]["left"] and moved.remaining["unexplained"]["share"] > 0.25
    assert "NOT EXPLAINED" in moved.text()
    for names, seed in (([], 12), (["temp_scale"], 13)):
        result, kwargs = withheld_trial(names, seed)
        d = diagnose(result.readings, **kwargs)
        assert not d.remaining["unexplained"]["left"] and "NOT EXPLAINED" not in d.text()


def test_uneven_sample_times_do_not_inflate_the_noise():
    """Readings taken at jittered times (a logger's clock, ±35 % of the step): differences of the rows hold
    the motion times the uneven step, 1.5× the noise on a hand-turned sensor; the estimate falls back to the
    base model's residuals, which the timing does not touch."""
    result, kwargs = withheld_trial([], 14)
    noise = 0.05  # µT, withheld_trial's NOISE
    t = kwargs["t"]
    dt = float(np.median(np.diff(t)))
    jittered = t + np.random.default_rng(0).uniform(-0.35, 0.35, t.size) * dt
    # the same sensor read at the jittered instants: move each reading along its local slope
    slope = np.gradient(result.readings, t, axis=0)
    m = result.readings + slope * (jittered - t)[:, None]
    assert estimate_noise(m) > 1.2 * noise  # what the rows' differences say
    d = diagnose(m, **{**kwargs, "t": jittered})
    assert d.noise_sigma == pytest.approx(noise, rel=0.1)
    assert "uneven times" in d.noise_source and not d.significant


def test_poor_coverage_of_the_base_calibration_is_a_caveat():
    """A sensor turned about one axis with a little wobble: calibrate warns of poor coverage; the diagnosis,
    which builds on that calibration, says so too (an effect can stand in for what the data do not fix)."""
    rng = np.random.default_rng(8)
    rot = sim.sweeps("z", per_turn=1500, tilt_deg=6.0, rng=rng)
    result = sim.simulate(rot, [sim.SoftIron(np.diag([1.05, 0.97, 1.02])), sim.HardIron([8.0, -5.0, 20.0]),
                                sim.WhiteNoise(0.05)], np.array([19.6, 0.8, 45.2]), rng)
    d = diagnose(result.readings, t=result.t)
    assert any("the base calibration: poor coverage" in c for c in d.caveats), d.caveats
    assert "CAVEAT: the base calibration: poor coverage" in d.text()


def test_a_small_departure_nothing_explains_is_said_not_passed_over():
    """A slow wander of 0.7 σ: colored_noise describes it, none of the effects explains it, and the residuals are
    within 1.5 σ RMS — not NOT EXPLAINED, but said (an injected temperature offset on the QMC5883L was reported as
    colored_noise alone, with 100 % of the departure left unsaid)."""
    from scipy.ndimage import gaussian_filter1d

    result, kw = withheld_trial([], 4)
    slow = gaussian_filter1d(np.random.default_rng(9).standard_normal((len(result.readings), 3)), 50, axis=0)
    d = diagnose(result.readings + slow * 0.035 / slow.std(), **kw)
    left = d.remaining["unexplained"]
    assert not left["left"] and left["share"] > 0.9 and left["rms_over_sigma"] < 1.5
    text = d.text()
    assert "LEFT: 100 % of a small departure" in text and "explains the data to the noise" not in text
    # its held-out gap after is 0 by construction (the correlated noise joins the noise model): said so
    assert "colored_noise" in d.accepted and "(a noise model: its gap after counts the correlated noise" in text
    assert "no unit stated" in text.splitlines()[0]  # sizes printed bare are the readings' own


def test_a_dipole_over_most_of_the_recording_is_not_called_a_passing_magnet():
    from types import SimpleNamespace

    from fluxcal.diagnose.report import moving_dipole_line

    d = SimpleNamespace(units="uT", series={"t": np.arange(0.0, 300.0, 0.1), "timestamps": True},
                        base=SimpleNamespace(field_norm=50.0))
    row = {"on_s": None, "off_s": 192.3, "peak_s": 2.2, "peak_field": 2.0, "peak_along_field": -2.0}
    assert "more likely the surroundings, a soft iron or the field itself changing slowly" in moving_dipole_line(d, row)
    d.series["field_norms"] = np.full(3000, 50.0)  # each reading's |field| given: its change is not the field's
    assert "more likely the surroundings or a soft iron changing slowly than a magnet passing)" in \
        moving_dipole_line(d, row)
    row.update(on_s=100.0, off_s=130.0)
    assert "a magnet, a tool or a vehicle moving near the sensor?" in moving_dipole_line(d, row)


def test_a_gain_equal_on_every_axis_that_follows_the_temperature_is_named_so(real_data):
    """The phone recording with a gain change equal on all three axes that follows a logged temperature (rising
    15 °C and falling back, the element 20 s behind it; 7.6 % of the field at the peak). Magnitudes alone see the
    same as a field changing along itself, which a passing magnet's free course in time fits too — and the
    recording's own slow disturbances besides, so the course won on ΔBIC (a blind check: moving_dipole, with no
    rival said). Now the logged quantity's explanation is named beside it: the recording cannot tell them apart."""
    from scipy.signal import lfilter

    m = np.loadtxt(real_data / "phone_acc_mag.csv", delimiter=",", skiprows=1, usecols=(3, 4, 5))
    t = np.arange(len(m)) / 50.0
    span = t[-1]
    warm = np.clip((t - 0.25 * span) / (0.15 * span), 0, None)
    course = np.where(t < 0.65 * span, 1 - np.exp(-warm),
                      (1 - np.exp(-0.4 / 0.15)) * np.exp(-(t - 0.65 * span) / (0.15 * span)))
    temp = 22 + 15 * course / course.max() + np.random.default_rng(3).normal(0, 0.05, len(t))
    a = 0.02 / (20.0 + 0.02)  # the element: a first-order lag of 20 s behind the logged temperature
    element = lfilter([a], [1, -(1 - a)], temp - temp[0]) + temp[0]
    centre = fluxcal.fit_ellipsoid(m, method="als").offset
    gain = (element - element[:50].mean()) * 0.076 / (np.ptp(element) or 1.0)
    d = diagnose(m + gain[:, None] * (m - centre), t=t, temp=temp)
    named = d.accepted[:1] + [r["effect"] for r in d.confounded.get(d.accepted[0], [])] if d.accepted else []
    assert "temp_scale" in named and "CANNOT TELL APART" in d.text() or d.accepted[:1] == ["temp_scale"], \
        (d.accepted, d.confounded)


def test_a_gain_equal_on_every_axis_warming_up_is_named_beside_a_free_course(real_data):
    """The phone recording with a gain equal on all three axes settling after power-on (τ a quarter of the
    recording, 7.6 % of the field). As with the temperature above, a passing magnet's free course fits it, and the
    recording's own slow disturbances besides (a blind check: moving_dipole on the QMC5883L, no rival said). The
    drift is now named beside it: the recording cannot tell them apart."""
    m = np.loadtxt(real_data / "phone_acc_mag.csv", delimiter=",", skiprows=1, usecols=(3, 4, 5))
    t = np.arange(len(m)) / 50.0
    centre = fluxcal.fit_ellipsoid(m, method="als").offset
    gain = 0.076 * -np.expm1(-t / (0.25 * t[-1]))
    d = diagnose(m + gain[:, None] * (m - centre), t=t)
    named = d.accepted[:1] + [r["effect"] for r in d.confounded.get(d.accepted[0], [])] if d.accepted else []
    assert "scale_drift" in named, (d.accepted, d.confounded)
    if d.accepted[0] != "scale_drift":
        assert "a free course in time fits a drift" in d.text() and "a second recording from power-on" in d.text()


def test_a_brisk_random_tumble_is_not_taken_for_noise():
    """A tumble whose angular velocity wanders (1.3 rad/s RMS, 1 s correlation) at 50 Hz: third differences of the
    readings hold the motion (σ 0.0815 against 0.05, the 4th order only a few per cent under the 3rd), while an
    offset step keeps the base residuals' RMS above 0.8 σ (a blind check: a step with a temperature scale missed).
    The residuals' own third differences show the noise: σ comes from them when they show less than 0.8 σ."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(5)
    n, dt = 6000, 0.02
    w = np.zeros((n, 3))
    for k in range(1, n):  # Ornstein–Uhlenbeck angular velocity
        w[k] = w[k - 1] * (1 - dt) + 1.3 * np.sqrt(2 * dt) * rng.standard_normal(3)
    attitudes = Rotation.from_quat(np.array([q.as_quat() for q in
                                             np.cumprod([Rotation.identity()] + [Rotation.from_rotvec(v * dt)
                                                                                 for v in w[1:]])]))
    t = np.arange(n) * dt
    m = attitudes.inv().apply(50 * np.array([np.cos(1.05), 0, np.sin(1.05)])) + [12.0, -5.0, 8.0]
    m += 0.05 * rng.standard_normal((n, 3))
    m[(t >= 40) & (t < 80)] += 0.2 * np.array([0.7, 0.1, -0.7])
    d = diagnose(m, t=t)
    assert abs(d.noise_sigma / 0.05 - 1) < 0.1, d.noise_sigma
    assert "third differences of the base model's residuals" in d.noise_source and d.accepted == ["offset_step"]


def test_a_random_walk_of_the_attitude_is_not_taken_for_noise():
    """A tumble with a random walk on top (1.1° per reading about each axis) changes the readings by white steps,
    which differences of any order take for noise: σ came out 3.8× the truth, the base model left less than it,
    and an offset step of 6 σ was "below the noise", nothing found (a blind check: 2.8×). The base model's residuals
    showing less than σ now send the estimate to them (at 0.6° per reading too: σ 0.097, the step found)."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(8)
    n = 6000
    t = np.arange(n) / 50.0
    tumble = Rotation.from_euler("ZYX", np.c_[20 * t, 60 * np.sin(2 * np.pi * t / 37), 45 * np.sin(2 * np.pi * t / 23)],
                                 degrees=True)
    attitudes = tumble * Rotation.from_rotvec(np.cumsum(rng.normal(0, 0.02, (n, 3)), axis=0))
    m = attitudes.inv().apply(50 * np.array([np.cos(1.1), 0, np.sin(1.1)])) + np.array([12.0, -5.0, 8.0])
    m += 0.1 * rng.standard_normal((n, 3))
    m[(t >= 40) & (t < 80)] += 0.6 * np.array([0.7, 0.1, -0.7])
    d = diagnose(m, t=t)
    assert abs(d.noise_sigma / 0.1 - 1) < 0.1 and d.accepted == ["offset_step"], (d.noise_sigma, d.accepted)


def _with_flicker(readings: np.ndarray, sigma: float, seed: int) -> np.ndarray:
    """Readings with flicker (1/f) noise of standard deviation sigma added to each axis: a wandering offset."""
    n = len(readings)
    white = np.random.default_rng(seed).standard_normal((n, 3))
    f = np.fft.rfftfreq(n)
    shaping = np.where(f > 0, 1.0 / np.sqrt(np.maximum(f, 1.0 / n)), 0.0)
    noise = np.fft.irfft(np.fft.rfft(white, axis=0) * shaping[:, None], n, axis=0)
    return readings + sigma * noise / noise.std()


def test_a_wandering_offset_is_seldom_taken_for_a_step():
    """Flicker (1/f) noise as large as the white noise on each axis is an offset wandering in time. The AR model of
    the magnitude's series, in which the turning sensor mixes the axes, had left an offset step's whitened LR at 49
    for 3 terms: a step, magnet or temperature offset was named in 5 of these 12 seeds. Under the wandering-offset
    noise model (a random walk through 32 times) in 2."""
    named = 0
    for seed in range(12):
        result, kwargs = withheld_trial([], seed=seed)
        d = diagnose(_with_flicker(result.readings, 0.05, 1000 + seed), **kwargs)
        assert "colored_noise" in d.accepted, (seed, d.accepted)
        named += bool({"offset_step", "moving_dipole", "offset_drift", "temp_offset"} & set(d.accepted))
    assert named <= 3, named


@pytest.mark.parametrize("names", [["offset_step"], ["moving_dipole"], ["offset_drift"], ["temp_offset"]])
def test_an_effect_in_a_wandering_offset_is_still_found(names):
    """The same flicker noise with a typical effect added: the wandering-offset model costs them nothing."""
    result, kwargs = withheld_trial(names, seed=2)
    d = diagnose(_with_flicker(result.readings, 0.05, 1002), **kwargs)
    assert names[0] in d.accepted, d.accepted


def _short_colored(seed: int):
    """A short recording (30–60 s, 10–50 Hz) with nothing but AR(1) (φ 0.98) or flicker noise of 0.05–0.1 µT added
    to the white noise, and the diagnose arguments for it."""
    from scipy.signal import lfilter

    rng = np.random.default_rng(seed)
    duration, rate, sigma = rng.choice([30.0, 45.0, 60.0]), rng.choice([10.0, 20.0, 50.0]), 0.05 * rng.choice([1, 2])
    result, kwargs = withheld_trial([], seed=seed, duration_s=float(duration), rate_hz=float(rate))
    if seed % 2:
        return _with_flicker(result.readings, sigma, 5000 + seed), kwargs
    noise = lfilter([1.0], [1.0, -0.98], np.random.default_rng(5000 + seed).standard_normal(result.readings.shape), axis=0)
    return result.readings + sigma * noise / noise.std(), kwargs


@pytest.mark.parametrize("seed", [13, 33, 36, 43, 54])
def test_a_box_is_not_placed_by_its_held_out_readings(seed):
    """Short recordings of correlated noise alone: a box's edges searched on every reading, the held-out blocks' too,
    had followed their wander, and the held-out test confirmed the box (an offset step or magnet named in 10 of 60
    such recordings, seeds 0–59; these 5 among them). Refined again on the training blocks within a block's length,
    a held-out block an edge may lie in not judged: 5 of 60, none of these."""
    m, kwargs = _short_colored(seed)
    d = diagnose(m, **kwargs)
    assert not {"offset_step", "moving_dipole"} & set(d.accepted), d.accepted


def test_a_box_whose_edge_is_open_is_judged_on_the_readings_placed_alone():
    """A true step (0.8 µT, 27.5–37.9 s of a 60-s, 10-Hz recording with AR(1) noise) whose return lies in a held-out
    block (37.5–41.25 s): refined on the training blocks, the return is open across that block, and its readings are
    not judged. Its held-out calibrated field error was measured on them too: there the box placed the return 1.4 s
    late and the error rose (0.197 → 0.213), and the step was refused. On the readings judged it falls."""
    result, kwargs = withheld_trial(["colored_noise", "offset_step"], 8, duration_s=60.0, rate_hz=10.0)
    truth = next(e for e in result.effects if type(e).__name__ == "OffsetStep")
    d = diagnose(result.readings, **kwargs)
    assert "offset_step" in d.accepted, d.accepted
    row = next(r for r in d.ranking if r["effect"] == "offset_step")
    assert row["heldout_n_unplaced"] > 0, row
    assert row["field_error_after"] < row["field_error_before"], row
    assert abs(row["on_s"] - truth.t_on) < 1 and abs(row["off_s"] - truth.t_off) < 1, (row["on_s"], row["off_s"])


def test_a_large_step_on_a_real_recording_is_found_under_its_wander(real_data):
    """The phone recording's first two minutes with the offset stepping by 12 % of the field for 26 s: the recording's
    own wander is modelled in the LR's noise (a wandering offset), the step's sharp edges are not part of it."""
    m = np.loadtxt(real_data / "phone_acc_mag.csv", delimiter=",", skiprows=1, usecols=(3, 4, 5))[:6000]
    t = np.arange(len(m)) / 50.0
    H = float(np.mean(np.linalg.norm(fluxcal.calibrate(m).apply(m), axis=1)))
    step = np.outer((t >= 24.2) & (t < 50.5), 0.12 * H * np.array([0.6, -0.48, 0.64]))
    d = diagnose(m + step @ np.linalg.inv(np.asarray(fluxcal.calibrate(m).matrix)).T, t=t)
    assert d.accepted[:1] == ["offset_step"], d.accepted
    # Its edges refined again on the training blocks (7.5 s, every fourth held out from 15 s): the step at 24.2 s, in a
    # training block, just where every reading put it; the return at 50.5 s, in the held-out block 45–52.5 s, within
    # a block of it.
    row = d.ranking[0]
    assert abs(row["on_s_without_heldout"] - 24.2) < 0.1 and abs(row["off_s_without_heldout"] - 50.5) < 7.5, row
    assert abs(row["on_s"] - 24.2) < 4 and abs(row["off_s"] - 50.5) < 4, (row["on_s"], row["off_s"])


def test_heldout_block_test_takes_the_blocks_length_from_the_noise_in_sample():
    """The blocks' length comes from the noise in sample when given (`length`): the held-out misprediction of an
    imperfect shape had set it (a simulated magnet's 4 % pass: 101 readings against 28 in sample, 5 blocks, p
    0.0625 with signed ranks). And the sign flips are exact and not biased towards confirming."""
    from fluxcal.diagnose.core import _improvement_pvalue

    rng = np.random.default_rng(2)
    after = rng.normal(size=1200)
    before = after + 0.05 * rng.normal(size=1200)  # elsewhere the fits differ by their parameters' noise
    before[300:600] += 2.0  # the candidate's gain where it acts
    misfit = np.zeros(1200)
    misfit[300:600] = 1.5 * np.sin(np.linspace(0, 3 * np.pi, 300))  # its shape's slow misprediction there
    assert _improvement_pvalue(before + misfit, after + misfit, length=1) < 0.05 < \
        _improvement_pvalue(before + misfit, after + misfit)
    draws = np.array([_improvement_pvalue(rng.normal(size=600), rng.normal(size=600), length=1) for _ in range(200)])
    assert np.mean(draws < 0.05) <= 0.09 and np.mean(draws < 0.5) > 0.35


def test_a_short_event_is_also_judged_by_the_block_test_where_it_acts():
    """A blind check's magnet pass (its held-out gap 2.7 → 0.17 on 30 readings) got p 0.24 in 2 of 12 seeds: over every
    held-out reading its gain sat in one of 30 blocks. Where it acts, the same residuals give 15 blocks; the smaller
    p, doubled, is kept — and with no gain there, both stay large."""
    from fluxcal.diagnose.core import _event_pvalue, _improvement_pvalue

    rng = np.random.default_rng(5)
    after = rng.normal(size=1860)
    before = after + 0.05 * rng.normal(size=1860)
    acts = np.zeros(1860, bool)
    acts[900:930] = True
    before[acts] += 20.0  # 27 σ of gap before, none after
    assert _improvement_pvalue(before, after, 1) > 0.05  # (one block of 30 holds the gain)
    assert _event_pvalue(before, after, (before[acts], after[acts]), 1) < 1e-3
    assert _event_pvalue(before, after, None, 1) == _improvement_pvalue(before, after, 1)
    draws = [_event_pvalue(a, b, (a[acts], b[acts]), 1) for a, b in (rng.normal(size=(2, 1860)) for _ in range(100))]
    assert np.mean(np.array(draws) < 0.05) <= 0.1
    # too few readings where it acts for 6 blocks of two correlation lengths: judged over every held-out reading only
    # (a review: 5 forced blocks of AR(1) noise gave p ≤ 1/32 in 6–7 % of nulls)
    assert _event_pvalue(before, after, (before[acts], after[acts]), 3) == _improvement_pvalue(before, after, 3)


def test_two_effects_found_together_that_cancel_are_refused():
    """A blind check's warm-up that only rose made temp_offset and offset_drift "found together", each ~30 % of the
    field, their changes cancelling: the data determine their difference only."""
    from fluxcal.diagnose.core import _cancelling

    rng = np.random.default_rng(0)
    n = 500
    J = np.column_stack([rng.normal(size=(n, 3)), np.zeros((n, 6))])  # ∂r/∂b first (a magnitude model's)
    ramp = np.linspace(-1, 1, n)
    warm = ramp + 0.1 * (ramp ** 2 - 1 / 3)  # a warm-up, nearly the ramp
    first = (warm[:, None] * np.array([1.0, 0.5, 0.2]))[:, None, :]
    second = (ramp[:, None] * np.array([1.0, 0.5, 0.2]))[:, None, :]
    fit = {"jacobian": J, "parameters": np.concatenate([np.zeros(9), [-10.0, 10.0]])}  # [..., second, first]
    assert _cancelling(fit, [second, first], vector=False) is not None
    fit["parameters"] = np.concatenate([np.zeros(9), [0.3, 1.0]])  # the same blocks, adding up: both stand
    assert _cancelling(fit, [second, first], vector=False) is None


def test_an_effect_that_cancels_one_found_is_refused():
    """A blind check (its seed 177): a quadratic of [0.67, −0.78, 0.36] % found first grew to 31 % on x once a
    cross-axis error of 22 % of the field was fitted beside it (the two cancelling, the residuals at 0.99 σ, a cubic
    found together with the cross-axis). The cross-axis is refused: its fit cancels the quadratic's and makes it
    unphysical by the quadratic's own rule (over 5 % at the typical reading); the quadratic keeps its size."""
    from fluxcal.sim.effects import HardIron, SoftIron, WhiteNoise
    from fluxcal.sim.scene import tumble
    from fluxcal.sim.simulate import simulate
    from fluxcal.sim.withheld import FIELD, OFF_DIAGONAL, SOFT_IRON

    rng = np.random.default_rng(177)
    off = OFF_DIAGONAL * 0.1 / SOFT_IRON  # the check's soft iron of ±10 %, hard iron of half the field
    E = rng.uniform(-off, off, (3, 3))
    W = np.diag(1 + rng.uniform(-0.1, 0.1, 3)) + np.triu(E, 1) + np.triu(E, 1).T
    b = rng.uniform(-1, 1, 3) * 0.5 * 50.0 / np.sqrt(3)
    quadratic = {c.name: c for c in CANDIDATES}["nonlinearity_quadratic"].typical(50.0, rng)
    scene = tumble(60.0, rate_hz=50.0, rng=rng)
    result = simulate(scene, [SoftIron(W), HardIron(b), quadratic, WhiteNoise(0.05)], FIELD, rng)
    d = diagnose(result.readings, t=result.t, temp=scene.temperature, field_norm=50.0)
    assert d.accepted == ["nonlinearity_quadratic"], d.accepted
    row = next(r for r in d.ranking if r["effect"] == "nonlinearity_quadratic")
    assert np.allclose(row["coefficients"], quadratic.relative, atol=0.001), row["coefficients"]
    cross = next(r for r in d.ranking if r["effect"] == "cross_axis")
    assert cross["cancels"] == "nonlinearity_quadratic" and cross["makes_unphysical"]["effect"] == cross["cancels"]
    line = next(x for x in d.text().splitlines() if x.strip().startswith("cross_axis "))
    assert "(degenerate: makes nonlinearity_quadratic unphysical)" in line, line


def test_a_candidate_that_makes_an_effect_found_unphysical_is_named():
    """_made_unphysical: an effect found (a quadratic of 1 %) whose terms, refitted beside a candidate, pass its own
    rule's bound (5 % at the typical reading) is named with the rule's reason; not one that was already past it, nor
    one still within it."""
    from fluxcal.diagnose.core import _made_unphysical

    terms = lambda *c: {"parameters": np.r_[np.zeros(9), c], "standard_errors": np.full(9 + len(c), 0.001)}  # noqa
    state = {"effects": ["nonlinearity_quadratic"], "features": [np.zeros((10, 3, 3))], "period": 0.0,
             "result": terms(0.01, -0.005, 0.002)}
    name, reason = _made_unphysical(terms(0.31, -0.005, 0.002, 7.0, 7.0), state, vector=False)
    assert name == "nonlinearity_quadratic" and "an even-order error of 31 %" in reason
    assert _made_unphysical(terms(0.012, -0.005, 0.002, 7.0, 7.0), state, vector=False) is None
    state["result"] = terms(0.2, -0.005, 0.002)
    assert _made_unphysical(terms(0.31, -0.005, 0.002, 7.0, 7.0), state, vector=False) is None


def test_heldout_block_test_is_free_of_units_and_refuses_non_finite():
    """A review: an absolute tolerance had made every block mean alike for readings in tesla (p 0 or 1 from the first
    block's sign), and a non-finite residual had given p 0, a pass, to the sign flips: it gives 1."""
    from fluxcal.diagnose.core import _improvement_pvalue

    rng = np.random.default_rng(4)
    after = rng.normal(size=900)
    before = after + 0.3 * rng.normal(size=900)
    before[:200] += 1.0
    p = _improvement_pvalue(before, after, length=1)
    assert _improvement_pvalue(before * 1e-6, after * 1e-6, length=1) == pytest.approx(p, rel=1e-9)
    before[5] = np.nan
    assert _improvement_pvalue(before, after, length=1) == 1.0


def test_in_sample_length_counts_residuals_not_readings():
    """Against reference vectors each reading has three residuals: the blocks' length is in residuals (a review: in
    readings, the vector model's blocks were a third as long as its noise's correlation)."""
    from types import SimpleNamespace

    from fluxcal.diagnose.core import _correlation_length, _in_sample_length

    rng = np.random.default_rng(5)
    walk = np.zeros(600)
    for k in range(1, 600):
        walk[k] = 0.95 * walk[k - 1] + rng.normal()
    residuals = np.repeat(walk, 3) + 0.01 * rng.normal(size=1800)
    rows = np.ones(600, bool)
    length = _in_sample_length({"residuals": residuals}, SimpleNamespace(t=np.arange(600.0)), rows)
    assert length == 3 * _correlation_length(residuals.reshape(-1, 3).mean(axis=1)) and length > 30


def test_a_second_shape_of_one_compression_is_refused():
    # a review's knee about a hard iron of three fields came out as a knee, a 13 % tanh and a cubic
    from fluxcal.diagnose.core import _second_shape, refused
    from fluxcal.sim.effects import CubicNonlinearity, Saturation, SaturationKnee

    row = {"significant": True}
    _second_shape(row, SaturationKnee, [CubicNonlinearity])
    assert row == {"significant": True}  # beside another kind of effect: judged as it is
    _second_shape(row, SaturationKnee, [Saturation])
    assert refused(row) and not row["significant"] and "second shape of the compression saturation" in row["note"]


def test_a_departure_against_the_orientation_is_left_over_beside_colored_noise():
    """colored_noise describes what is correlated in time; beside it a blind check's 10 ms lag of one axis left
    2.5 σ and the orientation's bins at p 5e-289, and nothing was said. LEFT OVER now, as without it; what is left in
    time only, or within 1.5 σ, stays the correlated noise it names."""
    from fluxcal.diagnose.report import _shape_left

    rem = {"unexplained": {"share": 0.01, "rms_over_sigma": 2.5},
           "tests": [{"regime": "orientation", "pvalue": 4.6e-289}, {"regime": "time", "pvalue": 0.0}]}
    assert _shape_left(rem, beside_noise=True) and _shape_left(rem)
    assert not _shape_left({**rem, "unexplained": {"share": 0.01, "rms_over_sigma": 1.2}}, beside_noise=True)
    in_time = {**rem, "tests": [{"regime": "orientation", "pvalue": 0.3}, {"regime": "time", "pvalue": 0.0}]}
    assert not _shape_left(in_time, beside_noise=True) and _shape_left(in_time)


def test_a_recording_that_determines_no_base_model_clears_nothing():
    """100 readings (2 s of turning): the base model's parameters undetermined (a CAVEAT says so), yet the verdict had
    read "the base model explains the data to the noise" (a blind check)."""
    result, kwargs = withheld_trial([], 3, duration_s=2.0)
    d = diagnose(result.readings, **kwargs)
    text = d.text()
    assert any("not identifiable" in c for c in d.caveats), d.caveats
    assert "nothing is cleared" in text and "explains the data to the noise" not in text, text


def test_eddy_currents_differences_carry_their_own_standard_errors():
    """A magnitude determines the differences between the axes' time constants, not their common part: each axis's
    own error holds that part (a blind check: 0.2–0.8 ms quoted for lags found within 0.03 ms). The report's errors are
    the differences' (from the fit's correlation), and cover them."""
    import re

    for seed in range(3):
        result, kwargs = withheld_trial(["eddy_current"], seed)
        d = diagnose(result.readings, **kwargs)
        row = next(r for r in d.ranking if r["effect"] == "eddy_current")
        truth = next(e for e in result.effects if type(e).__name__ == "EddyCurrent").tau
        tau, k = np.asarray(row["coefficients"]), int(np.argmin(row["coefficients"]))
        line = next(line for line in d.text().splitlines() if "eddy_current: the readings lag" in line)
        se = np.array([float(v) for v in re.search(r"standard errors \[([^\]]*)\] ms", line).group(1).split(",")]) / 1e3
        others = np.arange(3) != k
        assert np.all(se[others] < 0.2 * np.asarray(row["standard_errors"])[others]), (se, row["standard_errors"])
        z = ((tau - tau[k]) - (truth - truth[k]))[others] / se[others]
        assert np.all(np.abs(z) < 4.0), z


@pytest.mark.parametrize("seed", [0, 3])
def test_a_line_hidden_from_the_readings_differences_by_a_slow_tumble_is_found(seed):
    # A hand turning at 60 °/s logged at 2 Hz: the turning fills the readings' differences, so the noise σ came from
    # the base model's residuals, which held the line itself (σ 11–12× the truth), and the line, fitted, was refused as
    # "below the noise" or as closing no gap. Its held-out error, a fit of time alone, sets the σ of a second pass.
    s, kw = withheld_trial(["periodic_interference"], seed, rate_hz=2.0, duration_s=900.0)
    d = diagnose(s.readings, **kw)
    assert d.accepted == ["periodic_interference"]
    assert d.noise_source.startswith("re-estimated from periodic_interference's held-out field error")
    assert abs(d.noise_sigma / NOISE - 1) < 0.2


def _level_drive(seed, n=1200, rate=1.0, noise=0.1):
    """A vehicle driving level at 1 Hz (µT): turns between straight stretches, pitch and roll wandering by a few
    degrees; soft iron ±15 %, hard iron 40 % of the field; white noise. (t, readings)."""
    from scipy.signal import lfilter
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    yaw_rate = np.repeat(rng.uniform(-25, 25, n) * (rng.random(n) < 0.5), 20)[:n]
    yaw = np.radians(np.cumsum(lfilter([0.3], [1, -0.7], yaw_rate)) / rate)

    def wander(tau):
        return lfilter([np.sqrt(1 - np.exp(-2 / tau))], [1, -np.exp(-1 / tau)], rng.standard_normal(n))

    turned = Rotation.from_euler("ZYX", np.c_[yaw, np.radians(8) * wander(20), np.radians(8) * wander(10)])
    E = rng.uniform(-0.15, 0.15, (3, 3))
    b = rng.standard_normal(3)
    field = turned.inv().apply([20.0, 1.5, 45.0]) @ (np.eye(3) + (E + E.T) / 2).T
    return t, field + 20 * b / np.linalg.norm(b) + rng.normal(0, noise, (n, 3))


@pytest.mark.parametrize("seed", [6, 7])
def test_a_level_drive_with_nothing_withheld_names_nothing(seed):
    # A level drive sees 10–20 % of the field's directions: the base calibration is undetermined across them, and a
    # cross-axis or a cubic term (features of the signal alone) took up the noise along the open direction — held
    # out, 0.74–0.92 of what the noise leaves, and named (ΔBIC to −716). Refused now, and said why.
    t, m = _level_drive(seed)
    d = diagnose(m, t=t)
    assert d.accepted == []
    assert any("the base calibration: poor coverage" in c for c in d.caveats)
    # its readings differ by the turning (σ 1.0–1.3 from them): along the ellipsoid, which the differences across it
    # do not hold (0.19) — σ is the residuals', unlike a one-axis turntable's (below)
    assert abs(d.noise_sigma / 0.1 - 1) < 0.2 and "across its ellipsoid" not in d.noise_source, d.noise_source


def _one_axis_turntable(seed, n=1500, rate=10.0, noise=0.7):
    """A sensor on a turntable in one mounting, turning 10°/s about an axis 25° from its z (µT, 10 Hz): its readings
    lie on one circle, which leaves the ellipsoid undetermined. Soft iron ±10 %, hard iron 40 % of the field; white
    noise `noise`. (t, readings, |field|)."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    tilt = np.radians(25)
    turned = (Rotation.from_rotvec(np.outer(np.radians(10) * t, [np.sin(tilt), 0, np.cos(tilt)]))
              * Rotation.random(random_state=rng))
    E = rng.uniform(-0.1, 0.1, (3, 3))
    b = rng.standard_normal(3)
    world = np.array([25.0, 2.0, -28.0])
    field = turned.inv().apply(world) @ (np.eye(3) + (E + E.T) / 2).T
    return t, field + 15 * b / np.linalg.norm(b) + rng.normal(0, noise, (n, 3)), float(np.linalg.norm(world))


@pytest.mark.parametrize("seed", [1, 3])
def test_a_one_axis_turntable_is_judged_against_its_own_noise(seed):
    # Readings on one circle: the base fit, undetermined, is a pancake whose rim wraps the circle, and its residuals
    # differed by half the noise. Taken for σ (0.33–0.38 for 0.7), it had every null named coloured noise (a blind
    # check's: a periodic interference as well). The readings' differences across the ellipsoid, where the turning
    # does not move them, hold the noise: σ stays theirs, and the verdict says that nothing is cleared.
    t, m, norm = _one_axis_turntable(seed)
    d = diagnose(m, t=t, field_norm=norm)
    assert abs(d.noise_sigma / 0.7 - 1) < 0.1, d.noise_sigma
    assert "the readings' differences across its ellipsoid" in d.noise_source
    assert d.accepted == []
    assert "nothing is cleared" in next(line for line in d.text().splitlines() if line.startswith("FOUND"))


def test_a_course_larger_than_the_readings_variation_is_no_effect():
    # A static sensor's readings vary by its drift alone: a fit of that drift changes them by as much as they vary
    # (1×), while one that changes them by several times as much must be cancelled by the base calibration (a blind
    # check's one-axis turntable: a sensor-fixed interference 7.2× the readings' variation named).
    core = importlib.import_module("fluxcal.diagnose.core")
    rng = np.random.default_rng(0)
    t = np.arange(600.0)
    drift = np.outer(1 - np.exp(-t / 100), [0.5, -0.3, 0.8])
    m = np.array([20.0, 5.0, 40.0]) + drift + 0.01 * rng.standard_normal((600, 3))
    feats = drift[:, None, :]  # one feature: the drift's course, coefficient 1 reproduces it
    base = np.zeros(9)
    assert abs(core._hidden_change(m, [feats], [False], np.r_[base, 1.0], 9) - 1) < 0.05
    assert core._hidden_change(m, [feats], [False], np.r_[base, 3.0], 9) > core.MAX_HIDDEN_CHANGE
    assert core._hidden_change(m, [feats], [True], np.r_[base, 3.0], 9) == 0  # (the signal's: _distortion's)
    # two such courses that cancel each other are no change the base takes back (_cancelling's)
    assert core._hidden_change(m, [feats, feats], [False, False], np.r_[base, 3.0, -2.0], 9) < 1.05


def test_correlated_noise_alone_is_said_to_may_be_all_there_is():
    # A blind check's AR(1) nulls read "NOT EXPLAINED … its cause is not among the candidates" as if a cause were
    # missing: with colored_noise alone found, the sensor's own correlated noise comes first
    s, kw = withheld_trial(["colored_noise"], 1)
    d = diagnose(s.readings, **kw)
    assert d.accepted == ["colored_noise"]
    said = next(line for line in d.text().splitlines() if line.startswith("NOT EXPLAINED"))
    assert "the sensor's own correlated noise (its filter, 1/f), which colored_noise describes as noise, may be all" in said


def _figure8(seed, rate=2.0, minutes=11.0, noise=0.15):
    """A sensor waved in figure-8s (a period of 2.8–3.4 s, six readings at 2 Hz) while its heading and roll wander
    slowly: the readings are periodic at the waving's frequency and its harmonics. Soft iron ±5 %, hard iron up to
    30 % of the field; white noise `noise` µT. (t, readings)."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    t = np.arange(int(minutes * 60 * rate)) / rate
    w = 2 * np.pi / rng.uniform(2.8, 3.4)
    yaw = np.radians(70) * np.sin(w * t) + 2 * np.pi * t / 90
    pitch = np.radians(50) * np.sin(2 * w * t)
    roll = np.radians(40) * np.sin(w * t + 1.0) + np.radians(60) * np.sin(2 * np.pi * t / 120)
    world = np.array([20.0, 2.0, 45.0])
    E = rng.uniform(-0.05, 0.05, (3, 3))
    h = Rotation.from_euler("ZYX", np.c_[yaw, pitch, roll]).inv().apply(world)
    b = rng.uniform(-0.3, 0.3, 3) * np.linalg.norm(world)
    return t, h @ (np.eye(3) + (E + E.T) / 2).T + b + rng.normal(0, noise, h.shape)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_periodic_motion_is_no_interference_line(seed):
    # A figure-8 waved at 2 Hz puts lines at the waving's frequency and its harmonics in the readings' spectrum: taken
    # out as an interference, the rest of the motion was taken for the noise (σ 8.4 for 0.15, 57×; a blind check's
    # 52× said "explains the data to the noise" of a 3 % saturation). The model fits the motion: the base model's
    # residuals of the readings less those lines gain them, and the lines are left in.
    t, m = _figure8(seed)
    d = diagnose(m, t=t)
    assert 0.85 * 0.15 < d.noise_sigma < 1.15 * 0.15, (d.noise_sigma, d.noise_source)
    assert "less the lines" not in d.noise_source
    assert d.accepted == []


def test_a_special_case_goes_first_unless_the_general_forms_extra_terms_are_significant():
    # ΔBIC (from the plain likelihood ratio) ranks the winners, and correlated noise pays a general form's extra terms:
    # a blind check's saturation under AR(1) noise was named a cubic (ΔBIC −308 against −289) though the cubic's extra
    # terms' whitened likelihood ratio was 3.9. The special case now goes first unless those terms are significant.
    from types import SimpleNamespace

    core = importlib.import_module("fluxcal.diagnose.core")
    rng = np.random.default_rng(0)
    n = 2000
    basis = np.linalg.qr(rng.standard_normal((n, 3)))[0]
    e_special = rng.standard_normal(n)
    data, result = SimpleNamespace(t=np.arange(n, dtype=float), reference=None), {}
    state = {"result": result, "_wander": (result, None), "alpha": 0.01}

    def winners(shrink):
        general = {"effect": "nonlinearity_cubic", "fitted_parameters": 3, "_signature": basis,
                   "_fit": {"residuals": e_special * shrink}}
        special = {"effect": "saturation", "fitted_parameters": 2, "_signature": basis[:, :1],
                   "_fit": {"residuals": e_special}}
        return [r["effect"] for r in core._special_case_first([general, special], data, state)]

    assert winners(1 - 1e-4) == ["saturation", "nonlinearity_cubic"]  # extra terms: LR ≈ 0.4 for 1
    assert winners(0.9) == ["nonlinearity_cubic", "saturation"]       # LR ≈ 420
