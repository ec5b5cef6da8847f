"""Withheld effects added to real recordings (fluxcal.sim.inject): each lands where it acts in a sensor, and
the diagnosis finds it through a real sensor's own noise and disturbances."""
import numpy as np
import pytest

import fluxcal
from fluxcal.diagnose import diagnose
from fluxcal.sim.inject import inject, injectable


@pytest.fixture
def handheld(real_data):
    return fluxcal.read_csv(real_data / "handheld_set1.csv", columns="x,y,z").samples()


def test_an_offset_step_is_added_exactly_in_its_box(handheld):
    inj = inject(handheld, ["offset_step"], 3, field_norm=0.47)
    step = inj.effects[0]
    t = inj.kwargs["t"]
    on = (t >= step.t_on) & (t <= step.t_off)
    added = inj.readings - handheld
    assert np.allclose(added[on], step.delta) and np.allclose(added[~on], 0.0)
    assert on.any() and (~on).any()
    twice = inject(handheld, ["offset_step"], 3, field_norm=0.47, strength=2.0)
    assert np.allclose(twice.readings - handheld, 2 * added)


def test_nothing_added_leaves_the_readings_and_makes_up_a_temperature(handheld):
    inj = inject(handheld, [], 0)
    assert np.array_equal(inj.readings, handheld)
    temp = inj.kwargs["temp"]
    assert temp.shape == (len(handheld),) and np.ptp(temp) > 10  # rises and falls: not a copy of time
    assert abs(np.corrcoef(temp, inj.kwargs["t"])[0, 1]) < 0.5


def test_a_magnet_without_the_attitude_is_added_along_the_field(handheld):
    # Without the down direction only the disturbance's component along the field is known.
    inj = inject(handheld, ["moving_dipole"], 1, field_norm=0.47)
    cal = fluxcal.calibrate(handheld, field_norm=0.47)
    h = cal.apply(handheld)
    dh = (inj.readings - handheld) @ np.asarray(cal.matrix).T
    across = np.linalg.norm(np.cross(dh, h / np.linalg.norm(h, axis=1, keepdims=True)), axis=1)
    assert np.max(np.linalg.norm(dh, axis=1)) > 0.01 * 0.47
    assert np.max(across) < 0.05 * np.max(np.linalg.norm(dh, axis=1))


def test_what_cannot_be_added_is_a_clear_error(handheld):
    assert "misalignment" not in injectable(reference=False) and "non_orthogonality" not in injectable(True)
    with pytest.raises(ValueError, match="names: cannot inject time_offset here"):
        inject(handheld, ["time_offset"], 0)
    with pytest.raises(ValueError, match="t: need 3000 times"):
        inject(handheld, ["offset_step"], 0, t=np.arange(10.0))


def test_events_follow_the_recordings_own_clock(handheld):
    # An airborne log's time starts at 46 370 s: a box timed from 0 would fall before the data and add
    # nothing (a step that stays would add a constant, which the hard iron absorbs).
    t = 46370.0 + np.arange(len(handheld)) / 50.0
    for name in ("moving_dipole", "offset_step"):
        inj = inject(handheld, [name], 3, t=t, field_norm=0.47)
        effect = inj.effects[0]
        assert t[0] < effect.t_on < t[-1]
        added = np.linalg.norm(inj.readings - handheld, axis=1)
        assert np.ptp(added) > 0.005 * 0.47, name  # on for part of the recording only


def test_offsets_are_sized_in_the_readings_units(handheld):
    # Readings in mG with the field norm in G: an offset is added to readings, so in mG.
    in_mg = inject(handheld * 1000.0, ["offset_step"], 3, field_norm=0.47)
    in_g = inject(handheld, ["offset_step"], 3, field_norm=0.47)
    assert np.allclose(in_mg.effects[0].delta, 1000.0 * in_g.effects[0].delta, rtol=1e-6)
