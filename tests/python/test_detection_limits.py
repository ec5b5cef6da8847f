"""Detection limits (fluxcal.detection_limits): how large each candidate must be before a recording's own
diagnosis confirms it — measured by adding it to the recording, and checked here on shapes it was not measured
on and against a recording whose own slow disturbance hides more."""
import json

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter1d

from fluxcal.cli import main
from fluxcal.diagnose import detection_limits, diagnose
from fluxcal.io import write_csv
from fluxcal.sim.inject import inject
from fluxcal.sim.withheld import withheld_trial


@pytest.fixture(scope="module")
def clean():
    result, kw = withheld_trial([], 1)  # a minute of a hand-turned sensor, white noise only
    return result.readings, {"t": kw["t"], "temp": kw["temp"], "field_norm": 50.0}


def _confirmed_alone(m, kw, name, strength, seed, bonferroni):
    inj = inject(m, [name], seed, strength=strength, **kw)
    return name in diagnose(inj.readings, candidates=[name], alpha=0.01 / bonferroni, **inj.kwargs).accepted


def test_a_limit_holds_for_shapes_it_was_not_measured_on(clean):
    m, kw = clean
    limits = detection_limits(m, names=["offset_drift"], **kw)
    row = limits.row("offset_drift")
    assert row["status"] == "limit" and row["not_at"] is not None and row["found_at"] > row["not_at"]
    # the Bonferroni count is the full diagnosis' number of candidates (nothing made up here)
    assert row["bonferroni"] == limits.bonferroni == len(diagnose(m, **kw).ranking)
    # Twelve other shapes (seeds 10–21): most are confirmed at the limit, at most half at the size below it — a
    # limit reported twice too small or too large fails one of the two.
    at = sum(_confirmed_alone(m, kw, "offset_drift", row["strength"], s, row["bonferroni"]) for s in range(10, 22))
    below = sum(_confirmed_alone(m, kw, "offset_drift", row["strength"] / 2, s, row["bonferroni"]) for s in range(10, 22))
    assert at >= 8 and below <= 6, (at, below)


def test_a_recordings_own_slow_disturbance_raises_the_limit(clean):
    m, kw = clean
    rng = np.random.default_rng(5)
    slow = gaussian_filter1d(rng.standard_normal((len(m), 3)), 100, axis=0)  # a 2 s wander, 1 % of the field
    slow *= 0.01 * 50.0 / np.sqrt(np.mean(np.sum(slow ** 2, axis=1)))
    names = ["offset_step", "temp_offset"]
    quiet, disturbed = (detection_limits(x, names=names, **kw) for x in (m, m + slow))
    for name in names:
        assert disturbed.row(name)["found_at"] > 4 * quiet.row(name)["found_at"], name
    assert disturbed.row("temp_offset")["found_at"] > 0.5  # % of the field: far above the white noise's limit


def test_an_effect_the_recording_carries_gets_no_limit():
    result, kw = withheld_trial(["offset_step"], 2)
    limits = detection_limits(result.readings, names=["offset_step", "colored_noise"], t=kw["t"], temp=kw["temp"],
                              field_norm=50.0)
    assert limits.row("offset_step")["status"] == "in_recording"
    assert limits.row("colored_noise")["status"] == "not_tried"
    assert "confirmed in the untouched recording itself" in limits.text()


def test_a_missing_regressor_is_made_up_and_said(clean):
    m, kw = clean
    limits = detection_limits(m, t=kw["t"], field_norm=50.0, names=["temp_offset"], seeds=1)
    assert limits.row("temp_offset")["made_up"] == ["temp"]
    assert "no temperature column: made up" in limits.text()
    # a logged temperature with a gap too long to fill is not used, as by the diagnosis, and the text says why
    temp = np.array(kw["temp"], dtype=float)
    temp[100:120] = np.nan
    limits = detection_limits(m, t=kw["t"], temp=temp, field_norm=50.0, names=["temp_offset"], seeds=1)
    assert limits.row("temp_offset")["missing"] == {"temp": 20}
    assert "its temperature column has 20 missing values: made up" in limits.text()
    temp[101:120] = kw["temp"][101:120]  # one blank cell: filled from its neighbours, the logged temperature used
    limits = detection_limits(m, t=kw["t"], temp=temp, field_norm=50.0, names=["temp_offset"], seeds=1)
    assert limits.row("temp_offset")["made_up"] == [] and not limits.row("temp_offset")["missing"]


def test_bad_options_are_clear_errors(clean):
    m, kw = clean
    with pytest.raises(ValueError, match="names: unknown effect"):
        detection_limits(m, names=["magnet"], **kw)
    with pytest.raises(ValueError, match="seeds: need a whole number"):
        detection_limits(m, names=["offset_step"], seeds=0, **kw)


def test_the_command_line_prints_and_saves_the_limits(clean, tmp_path, capsys):
    m, kw = clean
    path = write_csv(tmp_path / "rec.csv", {"t": kw["t"], "mx": m[:, 0], "my": m[:, 1], "mz": m[:, 2]},
                     units={"t": "s", "mx": "uT", "my": "uT", "mz": "uT"})
    out = tmp_path / "d.json"
    assert main(["diagnose", str(path), "--candidates", "offset_step", "--detection-limits", "--seeds", "1",
                 "--quiet", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "DETECTION LIMITS" in text and "offset_step" in text.split("DETECTION LIMITS")[1]
    saved = json.loads(out.read_text())
    assert [r["effect"] for r in saved["detection_limits"]["rows"]] == ["offset_step"]
    assert saved["detection_limits"]["units"] == "uT"
    assert main(["diagnose", str(path), "--model", "cable", "--detection-limits"]) == 2
    assert "--detection-limits: measured for magnetometer recordings" in capsys.readouterr().err


def test_what_the_base_model_absorbs_gets_no_size():
    # Against reference vectors the full matrix takes a rotation of the axes whole: no misalignment shows.
    result, kw = withheld_trial([], 3, model="vector")
    limits = detection_limits(result.readings, names=["misalignment"], seeds=1,
                              **{k: kw[k] for k in ("t", "temp", "reference", "gravity")})
    assert limits.row("misalignment")["status"] == "absorbed"
    assert "absorbed by the base model's own parameters" in limits.text()
