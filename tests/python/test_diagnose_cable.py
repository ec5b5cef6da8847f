"""The cable-ring diagnosis (fluxcal.diagnose.cable), checked blind on withheld-effect simulations
(fluxcal.sim.cable_effects.cable_trial): the diagnosis sees the raw readings, the ring's calibration, the
reference currents, the rotations and the known conductor positions; candidates are fitted, never looked up.

The rig: the paper's ring (4 biaxial sensors on 10 mm, noise σ 1–2e-8 T, the paper's gain, hard-iron and
drift-wire errors), calibrated the paper's way (5 × 72°, ±5 A go and return) against the ring's model;
recorded at 8 rotations × 2, 5, 10 A × go-and-return and each core alone × both polarities × 2 repeats.
Withheld magnitudes (typical(), drawn per trial): helical lay L = 10–40 × the 4 mm pitch diameter;
finite length ℓ = 0.1–0.25 m either side of the ring, return wire 0.15–0.3 m away; sensor position
±0.3–0.7° along the ring, ±0.1–0.2 mm radius, ±0.5–1.5° axis; z leakage k_z ±1–2 % per axis with a
2–4° cable tilt.
"""
import importlib
import json

import re

import numpy as np
import pytest

from fluxcal.cable import Ring, read_ring_csv, write_ring_csv
from fluxcal.diagnose import diagnose_cable
from fluxcal.sim.cable_effects import (CABLE_CANDIDATES, FiniteLength, HelicalLay, SensorPositionError, cable_trial,
                                       helix_paths, helix_series_unit_fields, segment_field, sensor_points,
                                       straight_unit_fields, to_axes)
from fluxcal.sim.cable import PAPER_POSITIONS_M

TRIALS = 10
# (background_gradient and _curvature are a background field's change across the ring: found after the field
# itself, below)
EFFECTS = [c.name for c in CABLE_CANDIDATES if c.name not in ("background_gradient", "background_curvature")]
RING = Ring([0, 90, 180, 270], 0.010)
POSITIONS = np.asarray(PAPER_POSITIONS_M)
D = HelicalLay.pitch_diameter(POSITIONS)  # 4 mm


def _readings(unit_fields, points, axes, currents):
    """(points…, 2) readings of per-ampere complex fields (…, n) for the currents (n,)."""
    return to_axes(unit_fields @ np.asarray(currents, float), axes)


def _helix_by_segments(points, lay, **kw):
    pts = np.column_stack([points.real, points.imag, np.zeros(points.size)])
    b = np.stack([segment_field(pts, s, e, np.ones(len(s)))[:, :2] for s, e in helix_paths(POSITIONS, lay, **kw)], -1)
    return b[:, 0] + 1j * b[:, 1]


def test_segment_sum_converges_to_the_ring_model_and_the_helix_series():
    pts, axes = sensor_points(RING, 30.0)
    currents = [5.0, -5.0]
    ring_model = RING.rotated(30.0).field(POSITIONS, currents)
    scale = np.abs(ring_model).max()
    # straight segments 2 × 10 km long: the ring's infinite conductors (its C++ Biot–Savart)
    far = FiniteLength(1e4, 1e4).unit_fields(pts, POSITIONS)
    assert np.abs(_readings(far, pts, axes, currents) - ring_model).max() < 1e-9 * scale
    straight = _readings(straight_unit_fields(pts, POSITIONS), pts, axes, currents)
    assert np.abs(straight - ring_model).max() < 1e-12 * scale
    for ratio in (10.0, 25.0, 40.0):
        lay = ratio * D
        series = _readings(helix_series_unit_fields(pts, POSITIONS, lay), pts, axes, currents)
        coarse = _readings(_helix_by_segments(pts, lay), pts, axes, currents)               # 20 turns, 128/turn
        fine = _readings(_helix_by_segments(pts, lay, turns=40, per_turn=256), pts, axes, currents)
        assert np.abs(coarse - fine).max() < 1e-6 * scale, "segment sum not converged in turns and chords"
        assert np.abs(fine - series).max() < 1e-6 * scale, "segment sum and multipole series disagree"
        assert np.abs(series - ring_model).max() > 0.02 * scale  # a lay of ≤ 40 D is no small correction
    # a very long lay is straight: the change falls roughly as (D/L)^1.3 (2e-4 at 2000 D)
    change = [np.abs(_readings(helix_series_unit_fields(pts, POSITIONS, r * D), pts, axes, currents) - ring_model).max()
              for r in (2e3, 1e5)]
    assert 5e-5 * scale < change[0] < 5e-4 * scale and change[1] < 1e-6 * scale


def _context(currents_per_rotation):
    from types import SimpleNamespace

    rots = np.arange(0.0, 360.0, 45.0)
    geometry = [sensor_points(RING, r) for r in rots]
    pts = np.array([g[0] for g in geometry])
    axes = np.array([g[1] for g in geometry])
    cur = np.tile(np.asarray(currents_per_rotation, float), (len(rots), 1))
    index = np.repeat(np.arange(len(rots)), len(currents_per_rotation))
    lab = np.einsum("kmn,kn->km", straight_unit_fields(pts, POSITIONS)[index], cur)
    return SimpleNamespace(positions=POSITIONS, points=pts, axes=axes, rot_index=index, currents=cur, field_lab=lab,
                           extra=np.zeros_like(lab), net_current=bool(np.abs(cur.sum(axis=1)).max() > 0)), rots


def _exact_change(ctx, rots, unit_fields_of):
    """Readings (K, M, 2) of `unit_fields_of(points)` minus the ring model's."""
    delta = np.array([unit_fields_of(ctx.points[r]) - straight_unit_fields(ctx.points[r], POSITIONS)
                      for r in range(len(rots))])
    return np.einsum("kman,kn->kma", to_axes(delta, ctx.axes[..., None]).transpose(0, 1, 3, 2)[ctx.rot_index],
                     ctx.currents)


def _fit_share(features, exact):
    """Coefficients of the features' least-squares fit to the exact change, and the RMS left (fraction)."""
    F = features.reshape(-1, features.shape[-1])
    c, *_ = np.linalg.lstsq(F, exact.ravel(), rcond=None)
    return c, np.sqrt(np.mean((exact.ravel() - F @ c) ** 2) / np.mean(exact ** 2))


def test_first_order_candidates_against_the_exact_simulation():
    # finite length, go and return through the ring: one coefficient S = 1/ℓ1² + 1/ℓ2² (first order in (r/ℓ)²)
    ctx, rots = _context([[5.0, -5.0], [-5.0, 5.0]])
    for near, far in ((0.1, 0.1), (0.12, 0.25), (0.3, 0.3)):
        effect = FiniteLength(near, far, 0.2, 30.0)
        exact = _exact_change(ctx, rots, lambda p: effect.unit_fields(p, POSITIONS))  # noqa: B023
        c, left = _fit_share(FiniteLength.features(ctx), exact)
        assert c[0] == pytest.approx(1 / near ** 2 + 1 / far ** 2, rel=0.03)
        assert left < 0.02
    # each core alone, the return wire outside: uniform field and gradient per ampere of net current
    ctx, rots = _context([[5.0, 0.0], [0.0, 5.0]])
    effect = FiniteLength(0.15, 0.2, 0.25, 120.0)
    exact = _exact_change(ctx, rots, lambda p: effect.unit_fields(p, POSITIONS))
    _, left = _fit_share(FiniteLength.features(ctx), exact)
    assert left < 0.01
    # helical lay: the reference lay on a √2 grid leaves 4–20 % of the effect (why the diagnosis fits the
    # lay as a non-linear parameter); at the true lay the candidate is the exact effect
    ctx, rots = _context([[5.0, -5.0], [5.0, 0.0], [0.0, 5.0]])
    for ratio in (12.0, 30.0):
        exact = _exact_change(ctx, rots, lambda p: HelicalLay(ratio * D).unit_fields(p, POSITIONS))
        c, left = _fit_share(HelicalLay.features(ctx, ratio), exact)
        assert c[0] == pytest.approx(1.0, abs=1e-4) and left < 1e-4
        _, left_grid = _fit_share(HelicalLay.features(ctx, ratio * np.sqrt(2.0)), exact)
        assert 0.02 < left_grid < 0.25
    # sensor position error at assembly magnitudes: the derivatives leave only second-order terms; re-linearised at
    # the displacement, nothing (the angles and radii against their mean: a common part turns or scales the ring)
    rng = np.random.default_rng(5)
    for effect, first_left in ((SensorPositionError.typical(4, rng), 0.03),
                               (SensorPositionError(np.zeros(4), np.array([0.0, 0.0, 0.8e-3, 0.0]), np.zeros(4)), 0.1)):
        effect.angle_deg, effect.radius_m = (v - np.mean(v) for v in (effect.angle_deg, effect.radius_m))
        exact = []
        for r, rot in enumerate(rots):
            moved, axes = effect.sensors(RING, rot)
            exact.append(to_axes(straight_unit_fields(moved, POSITIONS), axes[:, None])
                         - to_axes(straight_unit_fields(ctx.points[r], POSITIONS), ctx.axes[r][:, None]))
        exact = np.einsum("kmna,kn->kma", np.array(exact)[ctx.rot_index], ctx.currents)
        params = np.column_stack([effect.angle_deg, effect.radius_m * 1e3, effect.axis_deg]).ravel()
        left = np.sqrt(np.mean((exact - SensorPositionError.features(ctx) @ params) ** 2) / np.mean(exact ** 2))
        assert 1e-4 < left < first_left
        at = SensorPositionError.relinearised_at(params)
        relinearised = SensorPositionError.features(ctx, at) @ np.append(params, 1.0)
        assert np.sqrt(np.mean((exact - relinearised) ** 2) / np.mean(exact ** 2)) < 1e-9


@pytest.mark.parametrize("name", EFFECTS)
def test_withheld_cable_effect_ranks_first_closes_the_gap_and_the_current_error(name):
    hits, shrinks, current_ratio, flagged = 0, [], [], 0
    for seed in range(TRIALS):
        kwargs, _ = cable_trial([name], seed)
        d = diagnose_cable(**kwargs)
        top, flagged = d.ranking[0], flagged + bool(d.confounded)
        if top["effect"] == name and top["significant"]:
            hits += 1
            shrinks.append(1 - top["heldout_gap_after"] / top["heldout_gap_before"])
            current_ratio.append(top["current_error_a_after"] / top["current_error_a_before"])
    assert hits >= 0.9 * TRIALS, f"{name} ranked first and significant in {hits}/{TRIALS}"
    assert flagged <= 1, f"{name}: 'cannot tell apart' in {flagged}/{TRIALS} single-effect trials"
    assert np.median(shrinks) >= 0.7, f"{name}: held-out gap shrinks {np.round(shrinks, 3)}"
    # downstream: the currents measured on the held-out snapshots are closer to the reference
    assert np.mean(np.array(current_ratio) < 1.0) >= 0.9 and np.median(current_ratio) < 0.5, np.round(current_ratio, 3)


@pytest.mark.parametrize("pair", [("helical_lay", "z_leakage"), ("sensor_position_error", "finite_length")])
def test_two_withheld_cable_effects_are_both_found(pair):
    found = sum(set(pair) <= set(diagnose_cable(**cable_trial(list(pair), 300 + seed)[0]).accepted)
                for seed in range(5))
    assert found >= 4, f"{pair} both found in {found}/5"


def test_with_fitted_currents_a_lay_and_z_leakage_are_both_found():
    """Currents fitted per snapshot: their common scale is the calibration's (which folded part of the lay into its
    gains: the currents come out 6–49 % off here) and a lay's coefficient trades with it, so z leakage's coefficients
    move it by tenths of a percent either way. Judged on the absolute current error z leakage was refused in 4 of 5
    bench pairs (held-out gap to the noise, ΔBIC −3000); the error after the best common scale is what such a
    recording determines."""
    found = 0
    for seed in range(5):
        d = diagnose_cable(**cable_trial(["helical_lay", "z_leakage"], 300 + seed)[0], fit_currents=True)
        found += set(d.accepted) == {"helical_lay", "z_leakage"}
        z = next(r for r in d.ranking if r["effect"] == "z_leakage")
        if z["significant"]:
            assert z["current_error_scaled_a_after"] < z["current_error_scaled_a_before"]
            assert 0.5 < z["current_scale_after"] < 2.0
    assert found >= 4, f"helical_lay + z_leakage with fitted currents found in {found}/5"


def test_nothing_withheld_reports_nothing():
    quiet = sum(not diagnose_cable(**cable_trial([], 200 + seed)[0]).significant for seed in range(20))
    assert quiet >= 19, f"no significant effect in only {quiet}/20"


def test_finite_length_of_go_and_return_is_mostly_a_calibration_gain():
    # Cores carrying go and return through the ring: the closing circuit's field is a uniform field ∝ I
    # across the pair, whose radial and tangential parts follow the pair's own dipole field — a per-axis
    # gain, which the calibration absorbs. The diagnosis says so (≈ 90 % absorbed) and finds at most the
    # rest, a few nT; the trials therefore also drive each core alone, the return outside the ring.
    kwargs, _ = cable_trial(["finite_length"], 3, patterns=((1.0, -1.0),))
    d = diagnose_cable(**kwargs)
    row = next(r for r in d.ranking if r["effect"] == "finite_length")
    assert row["absorbed_fraction"] > 0.85
    assert d.where["overall"]["gap"] < 2e-8


def test_fitted_currents_and_no_known_positions():
    # No conductor positions given (the ring's solver starts the fit) and currents fitted per snapshot:
    # the reference currents then only judge the currents measured on the held-out snapshots.
    kwargs, rig = cable_trial(["z_leakage"], 4)
    kwargs.pop("positions")
    d = diagnose_cable(**kwargs, fit_currents=True)
    top = d.ranking[0]
    assert d.accepted == ["z_leakage"] and d.base["fit_currents"]
    assert top["heldout_gap_after"] < 0.3 * top["heldout_gap_before"]
    assert top["current_error_a_after"] < top["current_error_a_before"]
    assert np.allclose(np.sort(np.asarray(d.base["positions_m"])[:, 0]), np.sort(rig.positions_m[:, 0]), atol=1e-4)


def test_ring_csv_json_and_report(tmp_path):
    # what `fluxcal diagnose RING.csv --model cable` does: a ring recording and its calibration from files
    kwargs, rig = cable_trial(["sensor_position_error"], 7)
    path = write_ring_csv(tmp_path / "ring.csv", kwargs["ring"], kwargs["readings"], kwargs["rotations_deg"],
                          kwargs["currents"], kwargs["positions"])
    cal = tmp_path / "cal.json"
    cal.write_text(json.dumps(kwargs["calibration"].to_dict()))
    data = read_ring_csv(path)
    d = diagnose_cable(data["readings"], data["ring"], currents=data["currents_a"],
                       rotations_deg=data["rotations_deg"], positions=data["positions_m"], calibration=cal,
                       source=str(path))
    assert d.accepted == ["sensor_position_error"]
    out = json.loads(d.save_json(tmp_path / "out.json").read_text())
    assert out["significant"] is True
    top = out["ranking"][0]
    assert top["effect"] == "sensor_position_error"
    for key in ("delta_bic", "lr_pvalue", "heldout_gap_before", "heldout_gap_after", "current_error_a_before",
                "current_error_a_after", "current_error_pct_before", "current_error_pct_after"):
        assert isinstance(top[key], float), key
    text = d.text()
    assert "FOUND: sensor_position_error" in text and "current error" in text
    assert (d.report(tmp_path / "rep")).exists() and (tmp_path / "rep" / "rotation.png").exists()


def test_bad_input_is_a_clear_error():
    kwargs, _ = cable_trial([], 1)
    y = kwargs["readings"]
    with pytest.raises(ValueError, match="readings: shape"):
        diagnose_cable(y[:, :3], RING)
    bad = y.copy()
    bad[:, 2, 1] = np.nan
    bad[7, 2, 1] = 0.0  # a sensor axis that reads in 1 snapshot only: too many left to leave out
    with pytest.raises(ValueError, match="snapshot 0, sensor 2, axis y"):
        diagnose_cable(bad, RING)
    with pytest.raises(ValueError, match="unknown cable effect"):
        diagnose_cable(**kwargs, candidates=["gremlins"])
    with pytest.raises(ValueError, match="rotations_deg"):
        diagnose_cable(y, RING, rotations_deg=[0.0, 90.0])
    with pytest.raises(ValueError, match="currents"):
        diagnose_cable(y, RING, currents=np.ones((3, 2)))
    with pytest.raises(ValueError, match="noise_sigma"):
        diagnose_cable(**kwargs, noise_sigma=-1.0)
    with pytest.raises(ValueError, match="more snapshots"):
        diagnose_cable(y[:2], RING, currents=kwargs["currents"][:2])


def test_reference_inputs_that_cannot_be_right_are_named():
    # a blind check: a NaN in a current or a rotation was reported as a wrong shape, a noise_sigma of the wrong length
    # as NumPy's broadcast error, constant readings as SciPy's "residuals are not finite", and reference currents all
    # zero beside a loaded cable's readings as "explained to the noise"
    kwargs, _ = cable_trial([], 1)
    currents, rotations = kwargs["currents"].copy(), np.asarray(kwargs["rotations_deg"], dtype=float).copy()
    currents[3, 1] = np.nan
    with pytest.raises(ValueError, match=r"currents: snapshot 3, conductor 1 is not finite \(1 such value\)"):
        diagnose_cable(**dict(kwargs, currents=currents))
    rotations[4] = np.nan
    with pytest.raises(ValueError, match=r"rotations_deg: snapshot 4 is not finite"):
        diagnose_cable(**dict(kwargs, rotations_deg=rotations))
    with pytest.raises(ValueError, match=r"currents: every reference current is zero in all \d+ snapshots"):
        diagnose_cable(**dict(kwargs, currents=np.zeros_like(kwargs["currents"])))
    with pytest.raises(ValueError, match=r"noise_sigma: 3 values for a ring of 4 sensors"):
        diagnose_cable(**kwargs, noise_sigma=[1e-8, 1e-8, 1e-8])
    constant = dict(kwargs, readings=np.full_like(kwargs["readings"], 1e-5), calibration=None)
    with pytest.raises(ValueError, match=r"readings: every sensor reads the same in all \d+ snapshots"):
        diagnose_cable(**constant)
    times = np.arange(len(currents), dtype=float)
    times[6] = np.inf
    with pytest.raises(ValueError, match=r"t: snapshot 6 is not finite"):
        diagnose_cable(**kwargs, t=times)
    # the snapshot said is the recording's, also when snapshots with a NaN reading are left out before (a review)
    readings = kwargs["readings"].copy()
    readings[2, 0, 0] = np.nan
    with pytest.raises(ValueError, match=r"rotations_deg: snapshot 4 is not finite"):
        diagnose_cable(**dict(kwargs, readings=readings, rotations_deg=rotations))
    # noise_sigma's length is the recording's ring's, also when a dead sensor is left out
    readings = kwargs["readings"].copy()
    readings[:, 1] = np.nan
    with pytest.raises(ValueError, match=r"noise_sigma: 3 values for a ring of 4 sensors"):
        diagnose_cable(**dict(kwargs, readings=readings), noise_sigma=[1e-8, 1e-8, 1e-8])


def test_readings_in_another_unit_are_not_explained_to_the_noise():
    # readings in µT passed as tesla: the gains ×1e6 fit them, and the FOUND line had said "explains the readings to
    # the noise" under the caveat
    kwargs, _ = cable_trial([], 1)
    d = diagnose_cable(**dict(kwargs, readings=kwargs["readings"] * 1e6, calibration=None))
    found = [line for line in d.text().splitlines() if line.startswith("FOUND")]
    assert found and "gains had to be multiplied by up to" in found[0] and "to the noise" not in found[0], found
    assert d.base["gain_factor_range"][1] > 1e5
    # readings 1000× too small: the gains cut to a thousandth had been "explained to the noise" too (a review)
    d = diagnose_cable(**dict(kwargs, readings=kwargs["readings"] * 1e-3, calibration=None))
    found = [line for line in d.text().splitlines() if line.startswith("FOUND")]
    assert found and "gains had to be divided by up to" in found[0] and "to the noise" not in found[0], found


def test_a_model_with_a_conductor_outside_the_bore_is_not_solved_again():
    # a blind check: a return conductor outside the ring, at one rotation, moved the final fit's conductors outside
    # the bore, and the solve of the effects found (`cable solve --joint`) raised the ring's own error from inside
    cable = importlib.import_module("fluxcal.diagnose.cable")
    kwargs, _ = cable_trial([], 1)
    data = cable._prepare(kwargs["readings"], kwargs["ring"], kwargs["currents"], kwargs["rotations_deg"], None,
                          kwargs.get("calibration"), None, None, None, None, True, True, "readings")[0]
    outside = np.array([[1.2 * data.ring.bore_radius_m, 0.0], [-0.001, 0.0], [0.0, 0.001]])[:data.n]
    errors = cable._solve_errors(data, outside, np.zeros_like(data.y), fit_background=False)
    assert errors.size == 0
    inside = outside * [[0.5, 1.0]]
    assert cable._solve_errors(data, inside, np.zeros_like(data.y), fit_background=False).size > 0
    # the caveat's test sees the final model's conductors too, not only the base model's
    bore = data.ring.bore_radius_m
    assert cable._outside_bore({"positions_m": inside, "final_positions_m": outside, "bore_radius_m": bore}) > bore
    assert cable._outside_bore({"positions_m": inside, "final_positions_m": inside, "bore_radius_m": bore}) == 0.0


def test_a_sensor_moved_into_another_sensors_place_is_no_placement_error():
    # a blind check: a return conductor outside a ring of 8 at one rotation was named a sensor 46° along the ring
    # (its neighbours 45° away) and another 6.7 mm further in on a 15 mm ring
    cable = importlib.import_module("fluxcal.diagnose.cable")
    ring = Ring(np.arange(8) * 45.0, 0.015)
    row = {"position_angle": 46.0, "position_angle_sensor": 4, "position_radius": -0.2, "position_radius_sensor": 2}
    assert "another sensor's place" in cable._off_the_ring(row, ring)  # (its neighbours 45° away)
    row.update(position_angle=3.0, position_radius=-6.7)
    assert "more than half the way from the ring to its bore (4.5 mm)" in cable._off_the_ring(row, ring)
    row.update(position_radius=-1.0)  # a sensor 3° and 1 mm off: a placement error
    assert cable._off_the_ring(row, ring) == ""


def test_a_sigma_from_residuals_that_held_the_effect_is_estimated_again(monkeypatch):
    # no repeats, no calibration, no noise_sigma: σ from the base fit's residuals held a neighbouring conductor's
    # field (a blind check: 5× the noise), and its gradient, left at 0.21 σ once the uniform part was found, was never
    # tested; σ from the residuals of the model with the effects found is taken for another pass
    cable = importlib.import_module("fluxcal.diagnose.cable")
    kwargs, _ = cable_trial(["background_gradient"], 0, repeats=1)
    kwargs["calibration"] = None
    monkeypatch.setattr(cable, "REESTIMATES", 0)
    once = diagnose_cable(**kwargs)
    assert once.accepted == ["background_field"] and once.remaining["overall"]["rms_z"] < cable.OVERSTATED
    monkeypatch.setattr(cable, "REESTIMATES", 3)
    d = diagnose_cable(**kwargs)
    assert d.accepted[:2] == ["background_field", "background_gradient"], d.accepted
    assert d.noise_source.startswith("from the base fit's residuals, then from those of the model with "
                                     "background_field, background_gradient")
    assert d.noise_sigma < 0.01 * once.noise_sigma
    assert any("the residuals of the fit with background_field" in c for c in d.caveats), d.caveats


def test_a_candidate_held_out_below_a_sigma_that_held_it_gives_the_sigma_of_another_pass(monkeypatch):
    # two current levels, four rotations, no repeats, no calibration: σ from the base fit's residuals held an AMR bend,
    # strong in sample, and its held-out gap read 0 against that σ though its held-out current error fell (a blind
    # check: ΔBIC −2658, 0.105 → 0.016 %, "no significant effect"); its fit's residuals now give σ for another pass
    from fluxcal.sim.cable_effects import SensorNonlinearity

    cable = importlib.import_module("fluxcal.diagnose.cable")
    bend = SensorNonlinearity(-np.random.default_rng(0).uniform(0.001, 0.004, (4, 2)))
    layout = dict(repeats=1, levels_a=(3.0, 10.0), rotations_deg=(0.0, 90.0, 180.0, 270.0))
    kwargs = dict(cable_trial([], 0, effects=[bend], **layout)[0], calibration=None)
    monkeypatch.setattr(cable, "REESTIMATES", 0)
    once = diagnose_cable(**kwargs)
    assert once.accepted == []
    row = next(r for r in once.ranking if r["effect"] == "sensor_nonlinearity")
    assert row["current_error_a_after"] < cable.CURRENT_ERROR_FALL * row["current_error_a_before"]
    monkeypatch.setattr(cable, "REESTIMATES", 3)
    d = diagnose_cable(**kwargs)
    assert d.accepted == ["sensor_nonlinearity"], d.accepted
    assert "then from those of the model with sensor_nonlinearity" in d.noise_source
    assert d.noise_sigma < 0.1 * once.noise_sigma
    null = diagnose_cable(**dict(cable_trial([], 0, **layout)[0], calibration=None))  # the same layout, no bend
    assert null.accepted == [] and cable.THEN_FROM not in null.noise_source


def test_cable_rivals_are_reported():
    # The rival bookkeeping is core's (tested there on warm-ups); here: the cable text carries it.
    d = diagnose_cable(**cable_trial(["helical_lay"], 0)[0])
    assert d.accepted == ["helical_lay"] and not d.confounded
    d.ranking[0]["confounded_with"] = [{"effect": "z_leakage", "regime": d.ranking[0]["regime"],
                                        "delta_bic_difference": 4.0, "signature_correlation": 0.9}]
    assert d.confounded and "CANNOT TELL APART: helical_lay and z_leakage" in d.text()
    assert "the current drawn near the sensor" not in d.text()  # the magnetometer's words, not a ring's


def test_an_effect_that_raises_the_current_error_is_not_accepted(tmp_path):
    # The lab rig (`cable simulate --lab`: ferrous parts, z leakage, the Earth's field): sensor_position_error
    # lowered the held-out residuals while it doubled the measured currents' error (0.0014 → 0.0025 A) and
    # moved the conductor positions 0.5 mm off, and it was accepted; the report then said "the ring's model
    # explains the readings to the noise" beside a residual of 8 σ.
    from conftest import run_cli

    ring, cal = tmp_path / "lab.csv", tmp_path / "ringcal.json"
    assert run_cli("cable", "simulate", "-o", ring, "--calibration", "--lab").returncode == 0
    assert run_cli("cable", "calibrate", ring, "-o", cal).returncode == 0
    # The lab rig's ferrous parts act on each sensor's field through a 2×2 matrix: its off-diagonal part is
    # sensor_coupling, which is found (and lowers the current error); without that candidate the others stand in.
    r = run_cli("diagnose", ring, "--model", "cable", "--calibration", cal, "--json", tmp_path / "all.json")
    d = json.loads((tmp_path / "all.json").read_text())
    row = next(row for row in d["ranking"] if row["effect"] == "sensor_coupling")
    assert d["accepted"][:1] == ["sensor_coupling"] and row["current_error_a_after"] < row["current_error_a_before"]
    others = "--candidates=helical_lay,finite_length,sensor_position_error,cable_tilt,z_leakage"
    r = run_cli("diagnose", ring, "--model", "cable", "--calibration", cal, others, "--json", tmp_path / "d.json")
    assert r.returncode == 0, r.stderr
    d = json.loads((tmp_path / "d.json").read_text())
    # (since sensor_position_error's common angle and radius were taken out — a turn and a scale of the whole ring,
    # which had moved the cores 0.53 mm — it is no longer significant in sample here, and not judged held out)
    assert "sensor_position_error" not in d["accepted"]
    for row in d["ranking"]:
        if row.get("current_error_a_after") is not None:
            assert not (row["significant"] and row["current_error_a_after"] > row["current_error_a_before"])
    if not d["accepted"]:
        assert "explains the readings to the noise" not in r.stdout
        assert "the readings still depart from the ring's model" in r.stdout
    # Currents fitted per snapshot: the position errors' common radius is a common current scale, which such a
    # recording does not fix; the currents' error fell 0.027 → 0.014 A through that scale alone and the effect was
    # accepted. After the best common scale it doubles (0.0020 → 0.0040 A), as with the reference currents.
    r = run_cli("diagnose", ring, "--model", "cable", "--calibration", cal, "--fit-currents", others,
                "--json", tmp_path / "f.json")
    assert r.returncode == 0, r.stderr
    d = json.loads((tmp_path / "f.json").read_text())
    assert "sensor_position_error" not in d["accepted"]
    row = next(row for row in d["ranking"] if row["effect"] == "sensor_position_error")
    assert row["current_error_scaled_a_after"] > row["current_error_scaled_a_before"] and row["current_error_rises"]
    assert "not accepted: the current error rises held out" in r.stdout


def test_ring_files_in_other_units_and_formats_are_read_as_stated(tmp_path):
    """A blind check wrote µT readings, mA currents and a ';' table with decimal commas: the readings were
    taken as tesla and the currents as amperes, silently (the sensors' gains absorbed the factor)."""
    kwargs, _ = cable_trial([], 11)
    ring, y, cur, rot = kwargs["ring"], kwargs["readings"], kwargs["currents"], kwargs["rotations_deg"]
    path = write_ring_csv(tmp_path / "ring.csv", ring, y, rot, cur, kwargs["positions"])
    plain = read_ring_csv(path)
    head, body = path.read_text().split("rotation_deg,", 1)
    scaled = tmp_path / "scaled.csv"  # the same recording in µT, mA and radians, stated in the units line
    rows = [line.split(",") for line in ("rotation_deg," + body).splitlines()]
    names = rows[0]
    factor = {n: 1e6 if n.startswith("s") else 1e3 if n.startswith("i") else np.pi / 180 for n in names}
    units = ", ".join(f"{n}={'uT' if n.startswith('s') else 'mA' if n.startswith('i') else 'rad'}" for n in names)
    lines = [",".join(names)] + [",".join(repr(float(v) * factor[n]) for n, v in zip(names, r)) for r in rows[1:]]
    scaled.write_text(head.replace(head.splitlines()[1], f"# units: {units}") + "\n".join(lines) + "\n")
    got = read_ring_csv(scaled)
    np.testing.assert_allclose(got["readings"], plain["readings"], rtol=1e-12)
    np.testing.assert_allclose(got["currents_a"], plain["currents_a"], rtol=1e-12)
    np.testing.assert_allclose(got["rotations_deg"], plain["rotations_deg"], rtol=1e-12, atol=1e-9)
    semicolon = tmp_path / "semicolon.csv"  # a European spreadsheet's export of the same file
    text = path.read_text().splitlines()
    semicolon.write_text("\n".join(t if t.startswith("#") else t.replace(",", ";").replace(".", ",") for t in text))
    np.testing.assert_allclose(read_ring_csv(semicolon)["readings"], plain["readings"], rtol=1e-12)
    bad = tmp_path / "bad.csv"
    bad.write_text(path.read_text().replace("s0_x=T", "s0_x=furlong"))
    with pytest.raises(ValueError, match="column s0_x: unit 'furlong' is not a field unit"):
        read_ring_csv(bad)
    renamed = tmp_path / "renamed.csv"  # a current named after its phase: with its unit an error, else a note
    renamed.write_text(path.read_text().replace("i0=A", "IA=A").replace("rotation_deg,i0,", "rotation_deg,IA,"))
    with pytest.raises(ValueError, match=r"column\(s\) IA hold currents \(A\), but reference currents are read "
                                         "from columns named i0, i1"):
        read_ring_csv(renamed)
    renamed.write_text(path.read_text().replace("rotation_deg,i0,", "rotation_deg,IA,"))  # no unit: i0 is missing
    with pytest.raises(ValueError, match=r"the reference currents are i1: column i0 missing .*; columns not used: IA "
                                         r"— is one of them a current\?"):
        read_ring_csv(renamed)
    rows = path.read_text().splitlines()  # a column the ring does not read (a note beside i0): said, not an error
    renamed.write_text("\n".join(r if r.startswith("#") else ",".join(r.split(",")[:2] + [
        "IA_note" if r.startswith("rotation_deg") else "0"] + r.split(",")[2:]) for r in rows) + "\n")
    from fluxcal.cable import ring_columns_note
    assert "columns not used: IA_note (reference currents are read from i0" in ring_columns_note(read_ring_csv(renamed))
    timed = tmp_path / "timed.csv"  # t in ms, stated
    lines = path.read_text().splitlines()
    k = next(i for i, line in enumerate(lines) if line.startswith("rotation_deg,"))
    lines[k] = "t[ms]," + lines[k]
    lines[k + 1:] = [f"{1000 * j},{line}" for j, line in enumerate(lines[k + 1:])]
    timed.write_text("\n".join(lines) + "\n")
    np.testing.assert_allclose(read_ring_csv(timed)["t_s"][:3], [0.0, 1.0, 2.0])
    lost = tmp_path / "lost.csv"  # a rotation that is not a number: named, not a crash in --joint
    lines = path.read_text().splitlines()
    lines[k + 4] = "nan," + lines[k + 4].split(",", 1)[1]
    lost.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"rotation_deg of snapshot 3 \(file line \d+\) is not a number"):
        read_ring_csv(lost)
    shifted = tmp_path / "shifted.csv"
    body = path.read_text()
    for k in range(3, -1, -1):
        body = body.replace(f"s{k}_", f"s{k + 1}_")
    shifted.write_text(body)
    with pytest.raises(ValueError, match=r"sensors s4 beyond the ring's 4 \(ring_angles_deg\) \(sensors are numbered "
                                         r"from s0\)"):
        read_ring_csv(shifted)


def test_one_conductor_is_diagnosed_without_the_lay():
    """A single core (its own return far away): a lay twists cores about each other, so helical_lay is not
    tried (it divided by the zero pitch diameter, a traceback on every one-core ring)."""
    rng = np.random.default_rng(12)
    rotations = np.repeat(np.arange(0.0, 360.0, 45.0), 6)
    currents = np.tile(np.repeat([[2.0], [5.0], [10.0]], 2, axis=0), (8, 1))
    core = np.array([[0.5e-3, -0.8e-3]])
    y = np.stack([RING.rotated(a).field(core, c) for a, c in zip(rotations, currents)])
    y += rng.normal(0, 2e-8, y.shape)
    d = diagnose_cable(y, RING, currents=currents, rotations_deg=rotations, positions=core,
                       candidates=["helical_lay", "sensor_position_error"])
    row = next(r for r in d.ranking if r["effect"] == "helical_lay")
    assert row["not_applicable"].startswith("one conductor") and not row["significant"]
    assert d.ranking[-1] is row  # a candidate not tried ranks last, not first on its ΔBIC of 0
    assert "(not tried: one conductor" in d.text()


def test_a_scale_the_gains_absorb_and_an_overestimated_noise_are_caveats():
    """A ring radius in millimetres written as metres fitted with gains ×0.001 and was 'explained to the noise'
    (blind check); repeats that differ for a reason (a neighbour's current) inflated σ without a word."""
    kwargs, _ = cable_trial([], 13)
    ten_m = Ring(kwargs["ring"].angles_deg, 10.0)
    d = diagnose_cable(**{**kwargs, "ring": ten_m, "calibration": None,
                          "readings": kwargs["calibration"].apply(kwargs["readings"])})
    assert any("gains had to change by a factor" in c for c in d.caveats), d.caveats
    assert any("from the positions the recording gives" in c for c in d.caveats)
    assert "CAVEAT: the sensors' gains" in d.text()
    # a disturbance of ±15 σ that reverses between the two repeats (a harmonic caught at opposite phases):
    # the repeats' spread is σ's estimate, their mean does not see it
    rng = np.random.default_rng(0)
    k = len(kwargs["readings"])
    swing = np.repeat(rng.normal(0, 3e-7, (k // 2, 1, 2)), 2, axis=0) * np.tile([1.0, -1.0], k // 2)[:, None, None]
    d = diagnose_cable(**{**kwargs, "readings": kwargs["readings"] + swing})
    assert any("the repeated snapshots differ more than the model misses" in c for c in d.caveats), d.caveats
    assert not diagnose_cable(**kwargs).caveats


def test_the_worst_bin_is_the_worst_when_p_values_underflow():
    """One sensor's gain 3 % off: every bin's p is 0, and the first bin (sensor 0) was named the worst."""
    kwargs, _ = cable_trial([], 14)
    y = kwargs["readings"].copy()
    y[:, 2] *= 1.0 + np.linspace(0.0, 0.03, len(y))[:, None]  # its gain drifts 3 % over the recording
    d = diagnose_cable(**kwargs | {"readings": y}, candidates=["z_leakage"])
    test = next(t for t in d.where["tests"] if t["regime"] == "sensor")
    assert "sensor 2" in test["test"], test


def test_a_lay_whose_twist_is_reversed_is_not_a_lay():
    """A cable end or a tilt taken for a helix fitted a negative coefficient (−34, −504): no lay makes that."""
    assert HelicalLay.unphysical([-33.7]).startswith("the twist's field change reversed")
    assert HelicalLay.unphysical([0.99]) == ""
    d = diagnose_cable(**cable_trial(["helical_lay"], 0)[0])
    assert d.accepted == ["helical_lay"]
    assert "FOUND: helical_lay (lay " in d.text() and "pitch diameters, coefficient" in d.text()


def test_a_tilted_cable_exact_field_and_its_second_order_candidate():
    """A straight core tilted by τ: the exact in-plane field against a long straight segment sum along the tilted
    direction, and the candidate's two columns (c₁, c₂) = τ²/2 (cos 2ψ, sin 2ψ) against the exact change."""
    from fluxcal.sim.cable_effects import CableTilt
    tilt = CableTilt(np.radians(4.0), 30.0)
    pts, axes = sensor_points(RING, 20.0)
    t = np.tan(tilt.tilt_rad) * np.array([np.cos(np.radians(30.0)), np.sin(np.radians(30.0)), 0.0])
    exact = tilt.unit_fields(pts, POSITIONS)
    xyz = np.column_stack([pts.real, pts.imag, np.zeros(pts.size)])
    for j, p in enumerate(POSITIONS):  # a 20 km segment through the core's crossing point, along (t, 1)
        d = (t + [0.0, 0.0, 1.0]) / np.linalg.norm(t + [0.0, 0.0, 1.0])
        start, end = np.array([*p, 0.0]) - 1e4 * d, np.array([*p, 0.0]) + 1e4 * d
        b = segment_field(xyz, start[None], end[None], np.ones(1))
        np.testing.assert_allclose(b[:, 0] + 1j * b[:, 1], exact[:, j], rtol=1e-8)
    ctx, rots = _context([[5.0, -5.0]])
    change = np.stack([to_axes(tilt.unit_fields(sensor_points(RING, r)[0], POSITIONS) @ [5.0, -5.0],
                               sensor_points(RING, r)[1]) for r in rots])
    change -= np.stack([to_axes(straight_unit_fields(sensor_points(RING, r)[0], POSITIONS) @ [5.0, -5.0],
                                sensor_points(RING, r)[1]) for r in rots])
    c = np.tan(tilt.tilt_rad) ** 2 / 2.0 * np.array([np.cos(np.radians(60.0)), np.sin(np.radians(60.0))])
    first = CableTilt.features(ctx) @ c
    assert np.abs(first - change).max() < 0.02 * np.abs(change).max()
    assert CableTilt.interpret(c)["tilt_deg"] == pytest.approx(4.0, rel=1e-9)


def test_a_lay_mostly_absorbed_by_fitted_currents_is_still_found():
    """Currents fitted per snapshot, no calibration, a 100 mm lay on cores 4.3 mm apart (a blind check's B02): 99 %
    of the lay's change is a current scale, so it was 'absorbed' (< 5 % new) and finite_length took the 7 σ left.
    A small new part along which the residuals lie beyond 5 σ is new all the same."""
    pos = np.array([[-0.0020132, 0.000744], [0.0020132, -0.000744]])
    rng = np.random.default_rng(2)
    rots = np.repeat(np.arange(0.0, 360.0, 45.0), 18)
    pattern = [level * np.array(p) for level in (5.0, 10.0, 20.0) for p in ((1.0, 0.0), (0.0, 1.0), (1.0, -1.0))]
    curs = np.tile(np.repeat(pattern, 2, axis=0), (8, 1))
    lay = HelicalLay(0.100)
    y = np.stack([to_axes(lay.unit_fields(sensor_points(RING, r)[0], pos) @ c, sensor_points(RING, r)[1])
                  for r, c in zip(rots, curs)]) + rng.normal(0, 3e-8, (len(rots), 4, 2))
    d = diagnose_cable(y, RING, currents=curs, rotations_deg=rots, positions=pos, fit_currents=True)
    assert d.accepted == ["helical_lay"], d.accepted
    assert d.ranking[0]["lay_length_m"] == pytest.approx(0.100, rel=0.05)


def test_a_field_from_outside_the_ring_is_said_not_explained():
    """A uniform background field (the Earth's, not taken off) that the ring turns against: no candidate models it,
    and the report had said "the cause is outside the candidates, or the noise σ is underestimated" at 200 σ and
    pointed only at units and the ring's radius (a newcomer's walk-through). It now names what lies outside the
    candidates, a field from outside the ring first."""
    kwargs, _ = cable_trial([], 14)
    rotations = np.asarray(kwargs["rotations_deg"], float)
    axes = np.array([sensor_points(kwargs["ring"], rot)[1] for rot in rotations])  # (K, M)
    background = 2e-6 * np.exp(1j * np.radians(35.0))  # 2 µT, fixed in the cable's (the lab's) frame
    shifted = kwargs["readings"] + to_axes(np.full(axes.shape, background), axes)
    others = [c.name for c in CABLE_CANDIDATES if not c.name.startswith("background")]
    d = diagnose_cable(**{**kwargs, "readings": shifted}, candidates=others)
    text = d.text()
    assert "NOT EXPLAINED" in text and "a field from outside the ring" in text, text
    assert "noise σ is underestimated" not in text
    d = diagnose_cable(**{**kwargs, "readings": shifted})  # (background_field is a candidate now)
    assert d.accepted == ["background_field"] and "NOT EXPLAINED" not in d.text()
    assert d.ranking[0]["background_t"] == pytest.approx(2e-6, rel=0.05)  # (1.93 µT: the paper rig's sensor errors)
    # at one set of currents nothing tells such a field from one that follows them: said
    one = np.all(kwargs["currents"] == [10.0, -10.0], axis=1)
    d = diagnose_cable(**{**kwargs, "readings": shifted[one], "currents": kwargs["currents"][one],
                          "rotations_deg": rotations[one]}, candidates=others)
    assert any("the recording holds one current level" in c for c in d.caveats), d.caveats
    # both polarities at that level do tell it (it does not change sign with them): found, and no such caveat
    both = np.max(np.abs(kwargs["currents"]), axis=1) == 10.0
    d = diagnose_cable(**{**kwargs, "readings": shifted[both], "currents": kwargs["currents"][both],
                          "rotations_deg": rotations[both]})
    assert d.accepted[:1] == ["background_field"], d.accepted
    assert not any("one current level" in c for c in d.caveats), d.caveats


def test_a_dead_sensor_is_left_out_and_a_missing_reading_is_named():
    """A sensor reading NaN in every snapshot had refused the diagnosis (`cable solve` leaves it out): the ring of
    the others is diagnosed, the report naming the sensors by their numbers in the recording; a reading missing
    here and there is refused with the remedy."""
    kwargs, _ = cable_trial([], 15)
    dead = kwargs["readings"].copy()
    dead[:, 2] = np.nan
    d = diagnose_cable(**{**kwargs, "readings": dead})
    assert any("sensor(s) 2 read no finite value in any snapshot (dead?): left out, the ring of the other 3" in c
               for c in d.caveats), d.caveats
    assert [row["bin"] for row in d.where["tables"]["sensor"]] == ["sensor 0", "sensor 1", "sensor 3"]
    assert not d.significant
    dead[5, 1, 0] = np.nan  # one reading missing: its snapshot left out, said (it had stopped the diagnosis)
    d = diagnose_cable(**{**kwargs, "readings": dead})
    assert any("snapshot 5, sensor 1, axis x is not finite (1 such values in 1 snapshots): those snapshots left out "
               f"(5), the other {len(dead) - 1} diagnosed" in c for c in d.caveats), d.caveats
    dead[: len(dead) // 5, 0, 1] = np.nan  # a fifth of the snapshots: the recording to be cleaned first
    with pytest.raises(ValueError, match=r"snapshot 0, sensor 0, axis y is not finite .*: leave those snapshots out"):
        diagnose_cable(**{**kwargs, "readings": dead})


def test_readings_on_a_rail_are_left_out_of_the_diagnosis():
    """A sensor clipped at its range had been fitted as gains (NOT EXPLAINED) though `cable solve` names the rail:
    a sensor on it in more than a tenth of the snapshots is left out, else the snapshots that hold a clipped
    reading are; the rail is said either way."""
    kwargs, _ = cable_trial([], 15)
    readings = kwargs["readings"].copy()
    x = readings[:, 2, 0]
    rail = np.quantile(np.abs(x), 0.7)  # 30 % of its snapshots on the rail
    readings[:, 2, 0] = np.clip(x, -rail, rail)
    d = diagnose_cable(**{**kwargs, "readings": readings})
    assert any(c.startswith("readings on a rail: sensor 2 x") for c in d.caveats), d.caveats
    assert any("sensor(s) 2 on the rail in more than 10% of the snapshots: left out, the ring of the other 3" in c
               for c in d.caveats), d.caveats
    assert not d.significant and [row["bin"] for row in d.where["tables"]["sensor"]] == ["sensor 0", "sensor 1",
                                                                                        "sensor 3"]
    few = kwargs["readings"].copy()  # a few snapshots: those are left out, the sensor kept
    order = np.argsort(-np.abs(few[:, 1, 1]))[:6]
    few[order, 1, 1] = np.sign(few[order, 1, 1]) * np.abs(few[order[-1], 1, 1])
    d = diagnose_cable(**{**kwargs, "readings": few})
    assert any(c.startswith("readings on a rail: sensor 1 y") for c in d.caveats), d.caveats
    assert any(f"the 6 snapshot(s) with a reading on the rail left out ({', '.join(map(str, sorted(order)))}), "
               f"the other {len(few) - 6} diagnosed" in c for c in d.caveats), d.caveats
    assert not d.significant and len(d.where["tables"]["sensor"]) == 4


def test_the_coupled_sensor_is_named_by_its_number_in_the_recording():
    """With sensor 0 dead, the coupling found on sensor 3 had been named "sensor 2" (the diagnosed ring's own
    numbering)."""
    from fluxcal.sim.cable_effects import SensorCoupling

    coupling = np.full((4, 2), 0.002)
    coupling[3, 1] = 0.03
    kwargs, _ = cable_trial([], 7, effects=[SensorCoupling(coupling)])
    readings = kwargs["readings"].copy()
    readings[:, 0] = np.nan
    d = diagnose_cable(**{**kwargs, "readings": readings})
    row = next(row for row in d.ranking if row["effect"] == "sensor_coupling")
    assert d.accepted == ["sensor_coupling"]
    assert (row["coupling_sensor"], row["coupling_axis"]) == (3, "y")
    assert row["coupling"] == pytest.approx(0.03, rel=0.1)
    assert "off right angles and turned together by" in d.text(), d.text()  # one axis coupled: not a turn


def test_a_sensor_turned_as_a_whole_is_said_turned_not_skewed():
    """Both axes of sensor 2 turned together by 0.6° (x reads +sin θ of y, y reads −sin θ of x): a blind check's
    turned sensor had read "an axis 0.54° off right angles, or crosstalk"."""
    from fluxcal.sim.cable_effects import SensorCoupling

    theta = np.radians(0.6)
    coupling = np.zeros((4, 2))
    coupling[2] = np.sin(theta), -np.sin(theta)
    kwargs, _ = cable_trial([], 7, effects=[SensorCoupling(coupling)])
    d = diagnose_cable(**kwargs)
    assert "sensor_coupling" in d.accepted, d.accepted
    line = next(x for x in d.text().splitlines() if "sensor_coupling (largest" in x)
    turned = float(re.search(r"both axes turned together by ([0-9.]+)°", line).group(1))
    assert turned == pytest.approx(0.6, abs=0.06) and "off right angles" not in line, line


def test_least_squares_survives_an_eigensolver_that_does_not_converge(monkeypatch):
    """LAPACK's eigh failed to converge on one ill-conditioned candidate fit of a blind check and aborted the whole
    diagnosis: the SVD-based solve takes over."""
    from fluxcal.diagnose import cable as dc

    rng = np.random.default_rng(0)
    X, y = rng.normal(size=(50, 3)), rng.normal(size=50)
    want = dc._lstsq(X, y)

    def fails(_):
        raise np.linalg.LinAlgError("Eigenvalues did not converge")

    monkeypatch.setattr(dc.np.linalg, "eigh", fails)
    np.testing.assert_allclose(dc._lstsq(X, y), want, rtol=1e-9)
    np.testing.assert_allclose(dc._lstsq(X, np.column_stack([y, 2 * y])),
                               np.column_stack([want, 2 * want]), rtol=1e-9)


def test_a_rise_of_the_held_out_current_error_is_judged_against_its_scatter():
    """The "current error rises" rule refused a true 9° tilt that took 82 % of the held-out gap for a rise of
    0.123 → 0.159 % (a blind check's rig: paired p 0.3), and a 4.6° tilt for 0.061 → 0.064 %. A rise now counts
    when the held-out snapshots show it beyond their own scatter; with too few of them for that (a lab ring held
    out 2 snapshots), beyond what the readings' noise makes of the currents."""
    from fluxcal.diagnose.cable import CURRENT_RISE_ALPHA, _rise_pvalue

    rng = np.random.default_rng(5)
    sigma = np.full((20, 2), 0.006)
    flagged = 0
    for _ in range(100):  # two fits as good as each other: a rise by chance only
        common = rng.normal(0.0, 0.006, (20, 2))
        before, after = common + rng.normal(0.0, 0.003, (2, 20, 2))
        flagged += _rise_pvalue(before, after, sigma) < CURRENT_RISE_ALPHA
    assert flagged <= 12
    before = rng.normal(0.0, 0.006, (20, 2))
    assert _rise_pvalue(before, 2.0 * before, sigma) < CURRENT_RISE_ALPHA  # a stand-in that doubles it
    # 2 held-out snapshots: against the currents' noise (σ 0.4 mA), the lab ring's 1.4 → 2.5 mA is a rise
    small = np.array([[1.3e-3, -1.4e-3], [1.5e-3, -1.3e-3]])
    assert _rise_pvalue(small, 1.85 * small, sigma[:2] / 15) < 0.001
    # errors within the noise that move by less than it are no rise
    within = np.array([[2e-4, -1e-4], [-3e-4, 1e-4]])
    assert _rise_pvalue(within, within + [[1e-4, 1e-4], [-2e-4, 1e-4]], sigma[:2] / 15) > CURRENT_RISE_ALPHA
    # and a diagnosis judges its held-out currents with it (a row without it would fall back to "any rise")
    d = diagnose_cable(**cable_trial(["cable_tilt"], 0)[0])
    judged = [r for r in d.ranking if r.get("current_error_a_before") is not None]
    assert judged and all(0.0 <= r["current_error_rise_pvalue"] <= 1.0 for r in judged)


def test_a_field_that_does_not_follow_the_currents_is_found_and_taken_out_of_them():
    """A background field (the Earth's, unsubtracted) or a neighbouring conductor on another circuit: the ring's model
    has no place for it, and the diagnosis had said NOT EXPLAINED (several current levels) or named stand-ins (one
    level). It is a candidate now, held apart from the per-ampere terms: the currents measured on held-out
    rotations are corrected for it."""
    from fluxcal.diagnose.cable import _Model, _prepare
    from fluxcal.sim.cable_effects import BackgroundField, BackgroundGradient

    kwargs, _ = cable_trial([], 5, rotations_deg=np.arange(0.0, 360.0, 45.0),
                            effects=[BackgroundField(30e-6 * np.exp(0.7j))])
    d = diagnose_cable(**kwargs)
    row = next(r for r in d.ranking if r["effect"] == "background_field")
    assert d.accepted == ["background_field"] and "NOT EXPLAINED" not in d.text()
    assert row["background_t"] == pytest.approx(30e-6, rel=0.01)
    assert row["background_direction_deg"] == pytest.approx(np.degrees(0.7), abs=1.0)
    assert row["current_error_a_after"] < 0.1 * row["current_error_a_before"]
    # a 13.7 A conductor 45 mm from the cable (61 µT here) beside the Earth's 20 µT: its field and its change across
    # the ring are found
    rng = np.random.default_rng(3)
    near = BackgroundGradient.typical(4, rng)  # an exact line current
    (where, current), = near.conductors
    earth = 20e-6 * np.exp(1.2j)
    kwargs, _ = cable_trial([], 6, effects=[BackgroundField(earth, conductors=near.conductors)])
    d = diagnose_cable(**kwargs)
    assert set(d.accepted) >= {"background_field", "background_gradient", "background_curvature"}, d.accepted
    # told apart: the line (where the busbar is, and its current) and the uniform rest (the Earth's)
    source = d.remaining["background_source"]
    assert source["distance_m"] == pytest.approx(abs(where), rel=0.02)
    assert source["direction_deg"] == pytest.approx(np.degrees(np.angle(where)) % 360.0, abs=1.0)
    assert source["current_a"] == pytest.approx(current, rel=0.02)
    assert source["uniform_t"] == pytest.approx(20e-6, rel=0.02)
    assert source["uniform_direction_deg"] == pytest.approx(np.degrees(1.2), abs=1.0)
    assert "BACKGROUND: as one line current of" in d.text()
    # what is left is that close source's higher terms: NOT EXPLAINED says so first, in the JSON too
    assert d.remaining["unexplained"]["not_explained"] == ("NOT EXPLAINED" in d.text())
    at_radius = 2e-7 * abs(current) / abs(where) * (kwargs["ring"].radius_m / abs(where))  # μ0 I/2πd · R/d
    gradient = next(r for r in d.ranking if r["effect"] == "background_gradient")
    assert gradient["background_gradient_t"] == pytest.approx(at_radius, rel=0.2)
    # the candidates' features are affine in the currents: per ampere of each conductor, plus what does not follow
    kwargs, _ = cable_trial(["sensor_coupling"], 7)
    data = _prepare(kwargs["readings"], kwargs["ring"], kwargs["currents"], kwargs["rotations_deg"],
                    kwargs["positions"], kwargs["calibration"], None, None, None, None, True, True, "test")[0]
    terms = [(BackgroundField, None), (CABLE_CANDIDATES[5], None)]
    model = _Model(data, terms, data.reference, [np.array([2e-5, -1e-5])])
    pos = np.asarray(kwargs["positions"])
    whole = model.features(pos, terms)
    rebuilt = np.einsum("kmapn,kn->kmap", model.unit_features(pos, terms), data.reference)
    rebuilt += model.constant_features(pos, terms)
    np.testing.assert_allclose(rebuilt, whole, atol=1e-12 * np.abs(whole).max())
    assert _Model(data, terms[1:], data.reference).constant_features(pos, terms[1:]) is None


def test_three_cores_without_known_positions_start_in_the_reference_currents_order():
    """The ring's solver numbers the conductors its own way: a newcomer's 3-core cable without positions_m was
    started from a swapped pair, its conductors pushed 55–71 mm out of a 14 mm ring, the gains ×3, and the report
    said "the ring's model explains the readings to the noise"."""
    ring = Ring(np.arange(0.0, 360.0, 60.0), 0.014)
    truth = np.array([[-2.1e-3, -1.8e-3], [0.5e-3, 2.7e-3], [3.1e-3, -1.8e-3]])
    rng = np.random.default_rng(8)
    rots, curs = [], []
    for rot in np.arange(0.0, 360.0, 45.0):
        for level in (5.0, 10.0, 20.0):
            for pattern in ((1.0, -0.5, -0.5), (-0.5, 1.0, -0.5), (-0.5, -0.5, 1.0)):
                rots.append(rot)
                curs.append(level * np.array(pattern))
    y = np.array([ring.rotated(r).field(truth, c) for r, c in zip(rots, curs)]) + rng.normal(0, 2e-8, (len(rots), 6, 2))
    d = diagnose_cable(y, ring, currents=np.array(curs), rotations_deg=np.array(rots), noise_sigma=2e-8)
    fitted = np.asarray(d.base["positions_m"])
    np.testing.assert_allclose(fitted, truth, atol=5e-5)  # in the currents' order, not the solver's
    assert not d.caveats and not d.accepted
    # a start the currents do not match is said, never "explained to the noise" with conductors outside the bore
    from fluxcal.diagnose import cable as diagnosis

    swapped = diagnosis._start_positions
    diagnosis._start_positions = lambda data: truth[[1, 0, 2]]
    try:
        d = diagnose_cable(y, ring, currents=np.array(curs), rotations_deg=np.array(rots), noise_sigma=2e-8,
                           max_effects=0)
    finally:
        diagnosis._start_positions = swapped
    assert np.linalg.norm(np.asarray(d.base["positions_m"]), axis=1).max() > ring.bore_radius_m  # (the gains ×3)
    assert any("outside its bore" in c for c in d.caveats), d.caveats
    assert "explains the readings to the noise" not in d.text() and "its fit is not the cable's" in d.text()


def test_repeats_that_scatter_beyond_the_calibration_runs_are_said():
    """A neighbouring current that varies makes a recording's repeated snapshots differ 94× the calibration run's
    repeated readings (a newcomer's switch room): σ from them made every test that much too lenient, unsaid."""
    kwargs, _ = cable_trial([], 16)
    d = diagnose_cable(**kwargs)
    assert not any("repeated snapshots scatter" in c for c in d.caveats), d.caveats
    noisy = kwargs["readings"] + np.random.default_rng(0).normal(0.0, 1e-7, kwargs["readings"].shape)
    d = diagnose_cable(**{**kwargs, "readings": noisy})
    assert d.noise_source.startswith("from repeated snapshots")
    assert any("this recording's repeated snapshots scatter" in c and "--noise-sigma" in c for c in d.caveats), \
        d.caveats


def test_the_given_calibration_is_compared_with_the_refit(tmp_path):
    """A ring calibrated by TWOSTEP, then one sensor's x gain changes by 0.3 % (or not) before the recording: the
    diagnosis's refit of the gains and offsets is compared with the calibration in units of their combined standard
    error, and the CALIBRATION line names the sensor (or says consistent); the refit is in the JSON."""
    from fluxcal import cable
    from test_cable import _room_run

    ring = Ring(np.arange(0.0, 360.0, 60.0), 0.012)
    rng = np.random.default_rng(0)
    readings, truth, rot, gains, offsets = _room_run(ring, rng, lambda z: 0 * z, noise=2e-8)
    cal = cable.calibrate_ring(readings, truth)
    cur = np.array([[3.0, -3.0], [-6.0, 6.0]])
    positions = [[-2e-3, 0.5e-3], [2.5e-3, 0.0]]
    truth2 = np.repeat(cable.calibration_fields(ring, positions, cur, 72.0 * np.arange(5)), 10, axis=0)
    noise = rng.normal(0, 2e-8, truth2.shape)
    for change in (0.0, 0.003):
        changed = gains.copy()
        changed[2, 0] *= 1 + change
        d = diagnose_cable(changed * truth2 + offsets + noise, ring, currents=np.repeat(np.tile(cur, (5, 1)), 10, axis=0),
                           rotations_deg=np.repeat(72.0 * np.arange(5), 20), positions=positions, calibration=cal,
                           max_effects=0)
        check = d.remaining["calibration_check"]
        line = next(x for x in d.text().splitlines() if x.startswith("CALIBRATION:"))
        found = next(x for x in d.text().splitlines() if x.startswith("FOUND:"))
        # FOUND says the model fits only with the calibration refitted (it had said "to the noise" alone)
        assert found.endswith("the calibration given does not (see CALIBRATION)") == bool(change), found
        if change:
            assert not check["consistent"] and check["largest"]["sensor"] == "sensor 2", line
            assert check["largest"]["what"] == "gain" and check["largest"]["axis"] == "x" and check["largest"]["z"] > 4
            assert "does not describe these sensors" in line and "sensor 2 x gain" in line
            assert check["refit_gains"][2][0] == pytest.approx(gains[2, 0] * 1.003, abs=5e-4)
        else:
            assert check["consistent"] and "consistent with this recording" in line, line
    d.save_json(tmp_path / "d.json")
    saved = json.loads((tmp_path / "d.json").read_text())["remaining"]["calibration_check"]
    assert saved["changed"][0]["sensor"] == "sensor 2"


def test_repeats_with_currents_logged_per_reading():
    """Currents logged per reading (0.1 % jitter): consecutive readings at one rotation and currents within POSE_RTOL
    are repeats — σ from their scatter less what the jitter did (fitted per rotation), their averages the snapshots,
    the levels three, not one per snapshot."""
    from fluxcal import cable

    ring = Ring(np.arange(0.0, 360.0, 60.0), 0.012)
    rng = np.random.default_rng(3)
    pos = np.array([[-2e-3, 0.5e-3], [2.5e-3, 0.0]])
    gains, offsets = rng.uniform(0.97, 1.03, (6, 2)), rng.uniform(-5e-6, 5e-6, (6, 2))
    rot = np.repeat(90.0 * np.arange(4), 24)
    pattern = np.repeat(np.outer(np.tile([1.0, -1.0], 3), [1.0, -1.0]) * np.repeat([2.0, 5.0, 10.0], 2)[:, None], 4,
                        axis=0)
    cur = np.tile(pattern, (4, 1)) * (1 + 1e-3 * rng.standard_normal((len(rot), 2)))
    truth = np.stack([ring.rotated(a).field(pos, c) for a, c in zip(rot, cur)])
    y = gains * truth + offsets + rng.normal(0, 2e-8, truth.shape)
    d = diagnose_cable(y, ring, currents=cur, rotations_deg=rot, positions=pos,
                       calibration=cable.RingCalibration(offsets, gains), max_effects=0)
    assert d.noise_source.startswith("from repeated snapshots")
    np.testing.assert_allclose(d.where["noise_sigma_per_sensor"], 2e-8, rtol=0.25)
    assert d.where["overall"]["snapshots"] == 24 and len(np.unique(d.series["levels"])) == 3
    assert d.remaining["calibration_check"]["consistent"]
    assert "time: the rows' order, no time column given" in d.text()  # (no t given)


def test_a_reference_meter_that_scatters_is_named():
    """A steady current read by a meter that scatters by 0.3 % (logged per reading): the readings do not follow the
    logged jitter, and what is left is named as the reference's scatter (before: NOT EXPLAINED named busbars and
    iron, never the meter). When the cable's current does jitter and is logged so, the readings follow it."""
    from fluxcal import cable

    ring = Ring(np.arange(0.0, 360.0, 60.0), 0.012)
    rng = np.random.default_rng(5)
    pos = np.array([[-2e-3, 0.5e-3], [2.5e-3, 0.0]])
    gains, offsets = rng.uniform(0.97, 1.03, (6, 2)), rng.uniform(-5e-6, 5e-6, (6, 2))
    rot = np.repeat(90.0 * np.arange(4), 24)
    steady = np.tile(np.repeat(np.outer(np.tile([1.0, -1.0], 3), [1.0, -1.0]) * np.repeat([2.0, 5.0, 10.0], 2)[:, None],
                               4, axis=0), (4, 1))
    logged = steady * (1 + 3e-3 * rng.standard_normal((len(rot), 1)))  # one meter for the go and return conductors
    for cable_current, meter in ((steady, True), (logged, False)):
        truth = np.stack([ring.rotated(a).field(pos, c) for a, c in zip(rot, cable_current)])
        y = gains * truth + offsets + rng.normal(0, 2e-8, truth.shape)
        d = diagnose_cable(y, ring, currents=logged, rotations_deg=rot, positions=pos,
                           calibration=cable.RingCalibration(offsets, gains), max_effects=0)
        ref = d.remaining["reference_scatter"]
        assert ref["scatters"] == meter, ref
        lines = d.text().splitlines()
        if meter:
            assert abs(ref["followed"]) < 0.05 and 0.7 < ref["meter_sigma_a"][1] / 0.021 < 1.3, ref  # 0.3 % of 7 A RMS
            # a meter's scatter is every sensor's alike (channels sampled at other instants would differ)
            assert np.all(np.abs(np.array(ref["followed_per_sensor"]) - ref["followed"])
                          < 4 * np.array(ref["followed_per_sensor_se"])), ref
            assert 0.7 < ref["meter_share_of_reading"][0] / 0.003 < 1.3, ref  # a clamp meter's % of reading
            assert d.remaining["overall"]["rms_z"] > 3 and 0.7 < ref["predicted_rms_z"] / d.remaining["overall"]["rms_z"] < 1.6
            assert any(x.startswith("NOT EXPLAINED") and "the reference currents' scatter (REFERENCE below)" in x
                       for x in lines), lines
            assert any(x.startswith("REFERENCE: the readings follow") for x in lines), lines
        else:
            assert abs(ref["followed"] - 1) < 0.05 and not any(x.startswith("REFERENCE") for x in lines), ref


def test_a_calibration_whose_fit_missed_its_model_is_judged_by_its_noise():
    """TWOSTEP on a bench with a 1.5 µT field that does not follow the ±5 A currents: its residuals (and so its
    standard errors) hold that miss, ~50× its repeats' noise, and its lack-of-fit test says so. The check judges
    the sensors there by the repeats' noise and names the calibration; with its standard errors as they are (no
    lack-of-fit kept: a calibration saved before) the same calibration passes."""
    from fluxcal import cable
    from test_cable import _room_run

    ring = Ring(np.arange(0.0, 360.0, 60.0), 0.012)
    rng = np.random.default_rng(0)
    readings, truth, rot, gains, offsets = _room_run(ring, rng, lambda z: 1.5e-6 * np.exp(-0.6j) + 0 * z, noise=2e-8)
    cal = cable.calibrate_ring(readings, truth)
    assert np.all(cal.lack_of_fit_p < cable.LACK_OF_FIT_P)
    cur, positions = np.array([[3.0, -3.0], [-6.0, 6.0]]), [[-2e-3, 0.5e-3], [2.5e-3, 0.0]]
    truth2 = np.repeat(cable.calibration_fields(ring, positions, cur, 72.0 * np.arange(5)), 10, axis=0)
    y = gains * truth2 + offsets + rng.normal(0, 2e-8, truth2.shape)
    kw = dict(currents=np.repeat(np.tile(cur, (5, 1)), 10, axis=0), rotations_deg=np.repeat(72.0 * np.arange(5), 20),
              positions=positions, max_effects=0)
    d = diagnose_cable(y, ring, calibration=cal, **kw)
    check = d.remaining["calibration_check"]
    assert not check["consistent"] and len(check["calibration_missed_model"]) == 6
    assert "its lack-of-fit warning" in next(x for x in d.text().splitlines() if x.startswith("CALIBRATION:"))
    saved_before = cable.RingCalibration.from_dict({k: v for k, v in cal.to_dict().items() if k != "lack_of_fit_p"})
    assert diagnose_cable(y, ring, calibration=saved_before, **kw).remaining["calibration_check"]["consistent"]


def test_cannot_tell_apart_names_the_rotations_that_would():
    """Two effects the ring's turns tell apart (a sensor's position error, a room's field gradient), confounded in a
    recording of 2 rotations: the line names the rotations to record, not "a recording that varies [the current]
    more" (held out on the current for want of rotations, which does not separate them: a newcomer's switch room,
    10 recordings of 11)."""
    from fluxcal.sim.cable_effects import BackgroundField, cable_trial

    kwargs, _ = cable_trial([], 0, rotations_deg=(0.0, 90.0), levels_a=(10.0, 20.0, 40.0),
                            effects=[BackgroundField(-15e-6 + 35e-6j, gradient_t=0.5e-6j)])
    d = diagnose_cable(**kwargs, max_effects=2)
    winner = next(r for r in d.ranking if r["effect"] == "background_gradient")
    assert winner["significant"] and not d.confounded and "too few to tell" not in d.text()  # nothing to separate
    winner["confounded_with"] = [{"effect": "sensor_position_error", "regime": "current", "delta_bic_difference": 5.5,
                                  "signature_correlation": 0.995, "same_departure": False}]
    text = d.text()
    assert "CANNOT TELL APART: background_gradient and sensor_position_error" in text, text
    assert "This recording turned the ring to 2 rotation(s) (0°, 90°), too few to tell these two apart: record at " \
           "least 5 spread evenly over the turn, e.g. 0°, 72°, 144°, 216°, 288°" in text, text
    assert "a zero-current snapshot at each rotation and `cable solve --subtract-zero`" in text  # the currents' remedy
    assert "Both were held out on" not in text
    winner["confounded_with"][0]["effect"] = "finite_length"  # the current's range separates that one
    assert "Both were held out on the cable's current" in d.text() and "too few to tell" not in d.text()


def test_with_currents_fitted_an_untried_background_leaves_the_calibration_unjudged():
    """With --fit-currents a field that does not follow the currents is not tried, and the refit's offsets take it up:
    a newcomer's good calibration beside a busbar was told "Recalibrate" (offsets 28 µT "changed") and a cable-end
    effect FOUND. The CALIBRATION line now says it cannot judge, and the FOUND line that it is tentative."""
    from fluxcal.sim.cable_effects import BackgroundField, cable_trial

    kwargs, _ = cable_trial([], 4, effects=[BackgroundField(30e-6 * np.exp(0.4j))])
    d = diagnose_cable(**kwargs, fit_currents=True, candidates=["z_leakage", "background_field"], max_effects=1)
    text = d.text()
    calibration = next(x for x in text.splitlines() if x.startswith("CALIBRATION:"))
    assert calibration.startswith("CALIBRATION: not judged") and "Recalibrate" not in calibration, calibration
    assert d.accepted == ["z_leakage"]  # (what stood in for the field here)
    assert "tentative: with the currents fitted" in next(x for x in text.splitlines() if x.startswith("FOUND:"))


def test_what_the_gradient_does_to_the_solvers_currents():
    """A room field with a gradient: the diagnosis says how far `cable solve --fit-background --joint` (a uniform
    field only) reads the currents off — simulated from its fit — and the solve of the recording itself agrees (a
    newcomer had read 0.09 % in the held-out column and 0.6 % from the solve)."""
    from fluxcal.sim.cable_effects import BackgroundField, cable_trial

    kwargs, rig = cable_trial([], 5, effects=[BackgroundField(30e-6 * np.exp(0.4j), gradient_t=0.6e-6 * np.exp(2.0j))])
    d = diagnose_cable(**kwargs, candidates=["background_field", "background_gradient"], max_effects=2)
    assert d.accepted == ["background_field", "background_gradient"]
    said = d.remaining["room_in_solve"]
    assert said["terms"] == ["background_gradient"]
    assert any(x.startswith("SOLVE: the room field's gradient leaves") for x in d.text().splitlines())
    cal, rot, cur = kwargs["calibration"], kwargs["rotations_deg"], kwargs["currents"]
    worst = 0.0
    for angle in np.unique(rot):
        rows = rot == angle
        sol = kwargs["ring"].rotated(angle).solve(cal.apply(kwargs["readings"][rows]), 2, fit_background=True)
        order = [int(np.argmin(np.linalg.norm(sol.positions - p, axis=1))) for p in kwargs["positions"]]
        worst = max(worst, float(np.max(np.abs(sol.currents[:, order] - cur[rows]) / np.abs(cur[rows]).max(axis=1)[:, None])))
    assert worst > 1e-3 and 0.5 < worst / said["max_relative_error"] < 2.0, (worst, said)


def test_a_busbar_near_the_ring_is_found_term_by_term():
    """A 14 A busbar 4.7 ring radii from the cable (the library's own `typical` range): the room field's uniform part,
    alone, moved the held-out currents further off (5.97 → 7.08 %) and was refused for it, and nothing was found.
    A term of the series is now judged with the series' next terms (0.25 %); the BACKGROUND line then places the
    busbar, and the SOLVE line says what its gradient and curvature do to `cable solve --fit-background`, as a solve
    of the recording shows."""
    from fluxcal.sim.cable_effects import BackgroundField, cable_trial

    where, current = 0.04695 * np.exp(4.88j), 14.35
    earth = 38.4e-6 * np.exp(-0.52j)
    kwargs, _ = cable_trial([], 421117, effects=[BackgroundField(earth, conductors=((where, current),))])
    d = diagnose_cable(**kwargs, candidates=["background_field", "background_gradient", "background_curvature"])
    assert d.accepted == ["background_field", "background_gradient", "background_curvature"], d.accepted
    first = d.ranking[0]
    assert first["current_error_falls_with"] == ["background_gradient", "background_curvature"]
    assert first["current_error_series_after"] < first["current_error_a_before"] < first["current_error_a_after"]
    assert "(with its series' next terms: → " in d.text()
    source = d.remaining["background_source"]
    assert source["distance_m"] == pytest.approx(abs(where), rel=0.02)
    assert source["current_a"] == pytest.approx(current, rel=0.02)
    said = d.remaining["room_in_solve"]
    assert said["terms"] == ["background_gradient", "background_curvature"]
    assert "SOLVE: the room field's gradient and curvature leave" in d.text()
    cal, rot, cur = kwargs["calibration"], kwargs["rotations_deg"], kwargs["currents"]
    rows = rot == rot[0]
    sol = kwargs["ring"].rotated(rot[0]).solve(cal.apply(kwargs["readings"][rows]), 2, fit_background=True)
    order = [int(np.argmin(np.linalg.norm(sol.positions - p, axis=1))) for p in kwargs["positions"]]
    off = np.max(np.abs(sol.currents[:, order] - cur[rows]) / np.abs(cur[rows]).max(axis=1)[:, None])
    assert 0.5 < off / said["max_relative_error"] < 1.5, (off, said)


def test_iron_near_the_ring_is_named_so_on_a_go_and_return_recording():
    """A blind check's steel plate 3 ring radii away, a two-core cable carrying go and return only: z_leakage, a
    2.7° tilt and a sensor position error had been named, all confidently, and the conductors pushed 0.35 mm off.
    Its field follows the currents and stays put as the ring turns: nearby_iron."""
    for seed in (0, 1):
        kwargs, rig = cable_trial(["nearby_iron"], seed, patterns=((1.0, -1.0),))
        d = diagnose_cable(**kwargs)
        assert d.accepted == ["nearby_iron"], (seed, d.accepted)
        assert "iron near the ring" in d.text()
        top = d.ranking[0]  # held out, the measured currents come closer to the reference
        assert top["current_error_a_after"] < 0.5 * top["current_error_a_before"], top
    # a lay shorter than any cable's is not a lay (a displaced sensor's remainder had been fitted as 2 pitch diameters)
    assert "shorter than any cable's" in HelicalLay.unphysical([1.0], 2.0) and not HelicalLay.unphysical([1.0], 20.0)


def test_a_clean_recording_with_few_repeats_does_not_depart():
    """σ from 16 repeated pairs (a blind check's AC snapshots at random phases merged a few by chance) is itself
    ±12 % off: judged as known, a clean ring read "the readings still depart" in 4 of 6 recordings. Against σ's own
    degrees of freedom (F, not χ²) none does."""
    for seed in (0, 2):
        kwargs, rig = cable_trial([], seed)
        rng = np.random.default_rng(100 + seed)
        raw, rotations, currents = [], [], []
        for rotation in np.arange(0.0, 360.0, 45.0):
            for k in range(24):
                current = rng.uniform(-10, 10) * np.array([1.0, -1.0])
                repeats = 2 if k < 2 else 1
                raw.append(rig.read([rotation], current, rng, repeats=repeats))
                rotations += [rotation] * repeats
                currents += [current] * repeats
        kwargs.update(readings=np.concatenate(raw), rotations_deg=np.array(rotations), currents=np.array(currents))
        d = diagnose_cable(**kwargs)
        assert d.noise_source.startswith("from repeated snapshots") and d.accepted == []
        assert "explains the readings to the noise" in d.text(), [t for t in d.where["tests"] if t["pvalue"] < 0.01]
    # without repeats here or in the calibration σ is its residuals', taken as known (a review: 0 degrees of freedom had
    # made every bin's p NaN, "p 1", and z leakage's departures unsaid)
    d = diagnose_cable(**cable_trial(["z_leakage"], 0, repeats=1, calibration_repeats=1)[0])
    assert d.noise_source.startswith("from the calibration's scatter about its own fit")
    assert all(t["pvalue"] < 1e-20 for t in d.where["tests"] if "worst bin" in t["test"]), d.where["tests"]


def test_a_sensor_out_of_place_and_a_near_circuit_are_said_with_their_sizes():
    """A blind check: sensor_position_error named no sensor and no size (the JSON's raw radii read −0.29 mm on five
    sensors and +0.47 on the one 0.76 mm out), finite_length no length."""
    kwargs, rig = cable_trial(["sensor_position_error"], 0)
    row = diagnose_cable(**kwargs).ranking[0]
    truth = rig.effects[0]
    for key, value in (("position_radius", 1e3 * np.asarray(truth.radius_m)), ("position_angle", truth.angle_deg),
                       ("position_axis", truth.axis_deg)):
        off = np.asarray(value) - np.median(value)  # against the others
        i = int(np.argmax(np.abs(off)))
        assert row[f"{key}_sensor"] == i and abs(row[key] - off[i]) < 0.05 * abs(off[i]), (key, row[key], off[i])
    kwargs, rig = cable_trial(["finite_length"], 0)
    d = diagnose_cable(**kwargs)
    e = rig.effects[0]
    symmetric = np.sqrt(2.0 / (1.0 / e.near_m ** 2 + 1.0 / e.far_m ** 2))  # 197 mm
    assert abs(d.ranking[0]["closing_distance_m"] - symmetric) < 0.15 * symmetric
    assert "the circuit closes about 185 mm either side of the ring" in d.text()
    # the leads beyond finite_length's first order, taken by nearby_iron: its rest, said so in the JSON too
    assert d.accepted == ["finite_length", "nearby_iron"] and d.ranking[1]["rest_of"] == ["finite_length"]
    assert "nearby_iron (beside finite_length: the rest of a field" in d.text()


def test_a_sensor_far_out_of_place_is_named_alone():
    """A blind check: 0.8 mm on a 12 mm ring left the first-order candidate's remainder, which a lay, then a near
    circuit and a 0.58° tilt, took (here 1 mm on 10 mm: finite_length and a lay). Re-linearised where its fit moved
    the sensors, nothing is left."""
    radius = np.zeros(4)
    radius[1] = 1e-3
    kwargs, _ = cable_trial([], 1, effects=[SensorPositionError(np.zeros(4), radius, np.zeros(4))])
    d = diagnose_cable(**kwargs)
    assert d.accepted == ["sensor_position_error"], d.accepted
    row = d.ranking[0]
    assert row["position_radius_sensor"] == 1 and abs(row["position_radius"] - 1.0) < 0.05, row["position_radius"]
    assert "sensor 1 0.98 mm further out" in d.text()


def test_solve_line_says_what_cable_solve_reads_with_the_effects_found():
    """A blind check: a 4° tilt cost 0.02 % of the current in the diagnosis's own held-out solve (positions shared by
    every rotation) while `cable solve --joint` read 1.9–4.5 % low. SOLVE simulates the latter from the fit; here
    against the solver on the recording itself, go and return only."""
    kwargs, rig = cable_trial(["cable_tilt"], 1, patterns=((1.0, -1.0),))
    d = diagnose_cable(**kwargs)
    said = d.remaining["effects_in_solve"]
    assert d.accepted == ["cable_tilt"] and said["effects"] == ["cable_tilt"]
    compensated = kwargs["calibration"].apply(kwargs["readings"])
    errors = []
    for angle in np.unique(kwargs["rotations_deg"]):
        rows = kwargs["rotations_deg"] == angle
        wanted = kwargs["currents"][rows]
        sol = kwargs["ring"].rotated(angle).solve(compensated[rows], n_conductors=2,
                                                  initial_positions=kwargs["positions"])
        order = [int(np.argmin(np.linalg.norm(sol.positions - p, axis=1))) for p in kwargs["positions"]]
        got = np.atleast_2d(sol.currents)[:, order]
        errors.append(np.max(np.abs(got - wanted), axis=1) / np.abs(wanted).max(axis=1))
    measured = float(np.max(np.concatenate(errors)))
    assert 0.7 * measured < said["max_relative_error"] < 1.3 * measured, (said, measured)
    # 4.2 %, where the diagnosis's own held-out solve reads 0.088 % before the tilt is modelled
    assert said["max_relative_error"] > 10 * d.ranking[0]["current_error_pct_before"] / 100
    assert "`cable solve --joint`" in d.text()


def test_a_clean_ring_departs_only_when_a_regime_test_does_so_beside_the_others():
    """Eight regime tests at p < 0.01 each had made 10 of 150 clean simulated rings (4 rotations × 2 levels × 3
    patterns, 48 snapshots) read "the readings still depart" (a blind check: 2 of 9 clean 64-snapshot rings); over
    the number of tests (Bonferroni) none of the 150 does. Seed 146's smallest p is 0.0067 of 8 tests."""
    kwargs, _ = cable_trial([], 146, rotations_deg=np.arange(0.0, 360.0, 90.0), levels_a=(5.0, 10.0), repeats=1)
    d = diagnose_cable(**kwargs)
    tests = d.remaining["tests"]
    assert d.accepted == [] and 0.01 / len(tests) < min(t["pvalue"] for t in tests) < 0.01, tests
    assert "explains the readings to the noise" in d.text() and "<-- departs" not in d.text(), d.text()


def test_a_calibration_made_with_the_cables_own_effect_is_said_to_have_held_it():
    """A blind check: every lay, tilt and sensor effect had been in its calibration run too, whose gains took it up
    (up to 0.24 off, the refit's within 1e-3), and the CALIBRATION line offered only sensors that changed since."""
    kwargs, _ = cable_trial(["cable_tilt"], 0)
    d = diagnose_cable(**kwargs)
    line = next(x for x in d.text().splitlines() if x.startswith("CALIBRATION"))
    assert d.accepted == ["cable_tilt"] and "does not describe these sensors" in line, (d.accepted, line)
    assert "the calibration run had cable_tilt too" in line and "calibrate on a straight jig" in line, line


def test_a_sensor_stuck_at_zero_is_left_out_and_a_rail_is_said():
    """A sensor reading 0.0, 0.0 in every snapshot had been diagnosed as a reading ("no significant effect"); a
    sensor clipped at its range was not said at all (cable solve says it)."""
    kwargs, _ = cable_trial([], 15)
    stuck = kwargs["readings"].copy()
    stuck[:, 2] = 0.0
    d = diagnose_cable(**{**kwargs, "readings": stuck})
    assert any("sensor(s) 2 read exactly 0 on both axes in every snapshot (a sensor that does not answer: dead?): "
               "left out, the ring of the other 3" in c for c in d.caveats), d.caveats
    clipped = kwargs["readings"].copy()
    rail = 0.6 * np.max(np.abs(clipped[:, 1, 0]))
    clipped[:, 1, 0] = np.clip(clipped[:, 1, 0], -rail, rail)
    d = diagnose_cable(**{**kwargs, "readings": clipped})
    assert any(c.startswith("readings on a rail: sensor 1 x") for c in d.caveats), d.caveats


def test_one_rotation_of_the_ring_is_said():
    """A recording at one rotation cannot tell what is fixed to the sensors from what is fixed to the cable: a blind
    check's was diagnosed with nothing said."""
    kwargs, _ = cable_trial([], 15)
    rotations = np.asarray(kwargs["rotations_deg"])
    one = rotations == rotations[0]
    d = diagnose_cable(**{**kwargs, "readings": kwargs["readings"][one], "currents": kwargs["currents"][one],
                          "rotations_deg": rotations[one]})
    assert any(c.startswith(f"the recording holds one rotation of the ring ({rotations[0]:g}°)") for c in d.caveats)
    assert not any("one rotation" in c for c in diagnose_cable(**kwargs).caveats)


def test_found_sizes_carry_the_noise_standard_errors():
    """A found effect's sizes had been said without any ±: its coefficients' standard errors (the projected Jacobian)
    reach the report's numbers by draws, said to be the noise's alone (a candidate's approximation is not in them)."""
    kwargs, rig = cable_trial(["cable_tilt"], 0)
    d = diagnose_cable(**kwargs)
    top = d.ranking[0]
    assert top["effect"] == "cable_tilt" and top["tilt_deg_se"] > 0 and len(top["coefficient_standard_errors"]) == 2
    assert abs(top["tilt_deg"] - np.degrees(rig.effects[0].tilt_rad)) < 4 * top["tilt_deg_se"]
    found = next(line for line in d.text().splitlines() if line.startswith("FOUND: cable_tilt"))
    assert f"{top['tilt_deg']:.2g}° ± " in found and "± the noise's alone" in found, found


@pytest.mark.parametrize("matrix, kind, said", [
    ([[0, 1], [1, 0]], "mirrored", "its x and y exchanged"),
    ([[0, -1], [-1, 0]], "mirrored", "its x and y exchanged and both reversed"),
    ([[1, 0], [0, -1]], "mirrored", "its y axis reversed"),
    ([[-0.98, 0], [0, 1.01]], "mirrored", "its x axis reversed"),
    ([[np.cos(0.5), -np.sin(0.5)], [np.sin(0.5), np.cos(0.5)]], "turned", "turned by 28.6°"),
    ([[-1, 0], [0, -1]], "turned", "or upside down"),
    ([[1.05, 0], [0, 0.99]], "scaled", "the field scaled"),
    ([[1, 0], [0.9, 0.02]], "one_axis", "one direction of the field only"),
    ([[1e-3, 0], [0, 2e-3]], "unresponsive", "hardly follows the field"),
])
def test_a_lone_sensors_map_is_named(matrix, kind, said):
    from fluxcal.diagnose.cable import _mapping_words

    got, words = _mapping_words(np.asarray(matrix, float))
    assert got == kind and said in words, words
