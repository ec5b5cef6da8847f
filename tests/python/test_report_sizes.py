"""Every effect the diagnosis can find is reported with its size, in the readings' unit (a newcomer's review: FOUND
temp_offset and eddy_current printed no size, their coefficients only in --json without a unit); and the
before/after plot's tick labels and legend are legible for readings in nT (-80000-60000-40000…, |h| = 5e+04)."""
import re
from types import SimpleNamespace
from dataclasses import replace

import numpy as np
import pytest

from fluxcal.calibration import Calibration
from fluxcal.diagnose import diagnose
from fluxcal.plots import before_after_figure
from fluxcal.sim.effects import CANDIDATES
from fluxcal.sim.withheld import withheld_trial

NUMBER = r"-?[0-9.]+(?:e[-+][0-9]+)?"
VECTOR = rf"\[{NUMBER}, {NUMBER}, {NUMBER}\]"
SHARE = rf"{NUMBER} uT, {NUMBER} % of the field"  # a size in the readings' unit and as a share of the field
# The size line of each candidate, once found in a trial simulated in µT (`withheld_trial`, seed 0).
SIZE_LINES = {
    "temp_offset": rf"temp_offset: {VECTOR} uT per °C \(x, y, z\); over the recording's {NUMBER} °C {SHARE}",
    "temp_scale": rf"temp_scale: the sensitivity changes by {VECTOR} % per °C \(x, y, z\); over the recording's "
                  rf"{NUMBER} °C by {VECTOR} %, at the field's magnitude {SHARE}",
    "motor_current": rf"motor_current: {VECTOR} uT per A \(x, y, z\); at the recording's peak {NUMBER} A "
                     rf"{NUMBER} uT, {NUMBER} % of the field",
    "offset_drift": rf"offset_drift: the offset drifts linearly, by {VECTOR} uT \(x, y, z; {NUMBER} % of the field\)",
    "scale_drift": rf"scale_drift: the sensitivity drifts linearly, by {VECTOR} % \(x, y, z\)",
    "nonlinearity_cubic": rf"nonlinearity_cubic: the readings depart from a straight line by {VECTOR} % "
                          rf"\(x, y, z\) at a reading of {NUMBER} uT .*; in this recording up to {SHARE}",
    "nonlinearity_quadratic": rf"nonlinearity_quadratic: the readings depart from a straight line by {VECTOR} % "
                              rf"\(x, y, z\) at a reading of \+{NUMBER} uT, the opposite at −{NUMBER} uT .*; in this "
                              rf"recording up to {SHARE}",
    "saturation": rf"saturation: .*: it compresses a reading of {NUMBER} uT by {NUMBER} %.*; in this recording the "
                  rf"readings by up to {SHARE}",
    "saturation_knee": rf"saturation_knee: straight up to a knee at {NUMBER} uT \({NUMBER} × the field\), then it bends: "
                       rf"the largest readings \({NUMBER} uT\) by {NUMBER} uT .*; in this recording the readings by up "
                       rf"to {SHARE}",
    "cross_axis": rf"cross_axis: anisotropy fields {VECTOR} uT \(x, y, z.*; in this recording up to {SHARE}",
    "non_orthogonality": rf"non_orthogonality: the axes x–y, x–z, y–z are {VECTOR}° apart \(90° − {VECTOR}°\); "
                         rf"in this recording up to {SHARE}",
    "misalignment": rf"misalignment: rotation vector {VECTOR}° \(\|θ\| {NUMBER}°: up to {SHARE}\)",
    "hysteresis": rf"hysteresis: a loop {NUMBER} uT wide .*the readings lag their input by up to {VECTOR} uT "
                  rf".*: {SHARE}",
    "moving_dipole": rf"moving_dipole: .*largest at t = {NUMBER} s: [-+]{NUMBER} uT along the field "
                     rf"\({NUMBER} % of the field",
    "offset_step": rf"offset_step: the offset jumped by {VECTOR} uT \(x, y, z; {NUMBER} % of the field\)",
    # (from a magnitude: above the smallest axis's, none negative)
    "eddy_current": rf"eddy_current: the readings lag the field by time constants \[(?:[0-9.]+(?:e[-+][0-9]+)?, ){{2}}"
                    rf"[0-9.]+(?:e[-+][0-9]+)?\] ms above the smallest axis's: a magnitude shows only .* \(x, y, z; "
                    rf"m = s − τ ds/dt, in field per field/s\); with the readings changing "
                    rf"by up to {NUMBER} uT/s in this recording, up to {SHARE}",
    "time_offset": rf"time_offset: the readings {NUMBER} ms (behind|ahead of) the reference vectors.*; with the "
                   rf"readings changing by up to {NUMBER} uT/s in this recording, up to {SHARE}",
    "colored_noise": rf"colored_noise: noise correlated in time beside the white σ, RMS {SHARE} .*correlated over "
                     rf"roughly {NUMBER} s",
    "quantization": rf"quantization: readings on a grid of {VECTOR} uT \(x, y, z; the ADC's step\).*: {SHARE}",
    "periodic_interference": rf"periodic_interference: a field at {NUMBER} Hz fixed in the sensor's axes \({NUMBER} ± "
                             rf"{NUMBER} Hz: the Cramér–Rao bound in the noise σ\), amplitude "
                             rf"{VECTOR} uT \(x, y, z\), up to {SHARE} \(a motor, fan or pump at a steady speed",
}


def _found(names, seed=0, **kwargs):
    result, kw = withheld_trial(names, seed, **kwargs)
    d = diagnose(result.readings, **kw, units="uT")
    return result, d, d.text()


def _line(text, name):
    lines = [line.strip() for line in text.splitlines() if line.startswith(f"  {name}: ")]
    assert lines, f"no size line for {name}:\n{text}"
    return lines[0]


def _vectors(line):
    return [np.array([float(x) for x in v.split(", ")]) for v in re.findall(r"\[([^\]]+)\]", line)]


def _truth(result, name):
    return next(e for e in result.effects if e.name == name)


def test_every_candidate_has_a_size_line():
    # a candidate added to sim.effects must come with its size line (and a case here)
    assert {c.name for c in CANDIDATES} == set(SIZE_LINES)


def _temp_offset(result, d, line):
    beta = _vectors(line)[0]
    assert np.allclose(beta, _truth(result, "temp_offset").beta, rtol=0.05)
    span = float(re.search(r"over the recording's ([0-9.]+) °C", line).group(1))
    assert span == pytest.approx(np.ptp(d.series["temp"]), rel=0.01)
    size = float(re.search(rf"°C ({NUMBER}) uT", line).group(1))
    assert size == pytest.approx(np.linalg.norm(beta) * span, rel=0.01)


def _periodic(result, d, line):
    truth = _truth(result, "periodic_interference")
    assert float(re.search(rf"at ({NUMBER}) Hz", line).group(1)) == pytest.approx(truth.frequency_hz, abs=0.01)
    np.testing.assert_allclose(_vectors(line)[0], np.abs(truth.amplitude), rtol=0.05)


def _cubic(result, d, line):
    at = float(re.search(r"at a reading of ([0-9.]+) uT", line).group(1))
    truth = _truth(result, "nonlinearity_cubic")
    assert np.allclose(_vectors(line)[0], 100 * truth.relative * (at / truth.scale) ** 2, rtol=0.1)
    # a compression on every axis is said as one (a saturation's first order)
    assert ("every axis compressed" in line) == bool(np.all(np.asarray(truth.relative) < 0)), line


def _quadratic(result, d, line):
    at = float(re.search(r"at a reading of \+([0-9.]+) uT", line).group(1))
    truth = _truth(result, "nonlinearity_quadratic")
    assert np.allclose(_vectors(line)[0], 100 * truth.relative * at / truth.scale, rtol=0.15)


def _saturation(result, d, line):
    limit = float(re.search(r"as a core saturating at ([0-9.]+) uT", line).group(1))
    assert limit == pytest.approx(_truth(result, "saturation").limit, rel=0.1)


def _knee(result, d, line):
    truth = _truth(result, "saturation_knee")
    knee, limit = (float(x) for x in re.search(rf"a knee at ({NUMBER}) uT.*bending towards ({NUMBER}) uT", line).groups())
    assert knee == pytest.approx(truth.knee, rel=0.03)
    assert limit == pytest.approx(truth.knee + truth.width, rel=0.1)


def _hysteresis(result, d, line):
    truth = _truth(result, "hysteresis")
    assert np.allclose(_vectors(line)[0], truth.share * truth.width, rtol=0.1)
    # the loop twice the play's half-width (a blind check read "0.297 uT wide" for a loop 0.6 wide)
    wide, half = (float(x) for x in re.search(rf"a loop ({NUMBER}) uT wide \(a play of half-width ({NUMBER}) uT",
                                                line).groups())
    assert wide == pytest.approx(2 * half, rel=0.01)
    assert 0.9 * np.min(truth.width) < half < 1.1 * np.max(truth.width), (half, truth.width)


# The numbers, not only the words: each against the simulation's truth.
TRUE_SIZES = {
    # from a magnitude, the time constants above the smallest axis's (ms)
    "eddy_current": lambda result, d, line: np.testing.assert_allclose(
        _vectors(line)[0], 1e3 * (_truth(result, "eddy_current").tau - np.min(_truth(result, "eddy_current").tau)),
        atol=0.3),
    "temp_offset": _temp_offset,
    "temp_scale": lambda result, d, line: np.testing.assert_allclose(
        _vectors(line)[0], 100 * _truth(result, "temp_scale").alpha, rtol=0.05),
    "nonlinearity_cubic": _cubic,
    "nonlinearity_quadratic": _quadratic,
    "saturation": _saturation,
    "saturation_knee": _knee,
    "cross_axis": lambda result, d, line: np.testing.assert_allclose(
        _vectors(line)[0], _truth(result, "cross_axis").hk, rtol=0.1),
    # (the angles lean as simulated: 90° less the angle)
    "non_orthogonality": lambda result, d, line: np.testing.assert_allclose(
        _vectors(line)[1], np.degrees(_truth(result, "non_orthogonality").angles), atol=0.1),
    "misalignment": lambda result, d, line: np.testing.assert_allclose(
        float(re.search(r"\|θ\| ([0-9.]+)°", line).group(1)),
        np.degrees(np.linalg.norm(_truth(result, "misalignment").rotvec)), rtol=0.02),
    "hysteresis": _hysteresis,
    "quantization": lambda result, d, line: np.testing.assert_allclose(
        _vectors(line)[0], _truth(result, "quantization").step, rtol=0.01),
    "periodic_interference": _periodic,
    # (measured on the held-out last quarter alone: a few correlation times of it)
    "colored_noise": lambda result, d, line: np.testing.assert_allclose(
        float(re.search(rf"RMS ({NUMBER}) uT", line).group(1)), _truth(result, "colored_noise").sigma, rtol=0.35),
}


@pytest.mark.parametrize("name", sorted(SIZE_LINES))
def test_an_effect_found_is_reported_with_its_size_and_unit(name):
    result, d, text = _found([name])
    assert name in d.accepted, (name, d.accepted)
    line = _line(text, name)
    assert re.search(SIZE_LINES[name], line), line
    if name in TRUE_SIZES:
        TRUE_SIZES[name](result, d, line)


def test_an_eddy_current_against_reference_vectors_is_timed_and_sized():
    result, d, text = _found(["eddy_current"], model="vector")
    line = _line(text, "eddy_current")
    tau = _vectors(line)[0]
    truth = _truth(result, "eddy_current").tau
    assert np.allclose(tau, 1e3 * truth, atol=0.1), (tau, truth)
    assert "a magnitude shows only" not in line  # against reference vectors every axis' τ shows
    # the size at the recording's changes: τ times the rate of the field the readings saw (uT/s), per axis
    rate = float(re.search(rf"changing by up to ({NUMBER}) uT/s", line).group(1))
    size = float(re.search(rf"s in this recording, up to ({NUMBER}) uT", line).group(1))
    assert 0.5 * np.min(truth) * rate < size <= 1.01 * np.max(truth) * rate
    # beside a delay found, a lag common to every axis is the delay's: said above the smallest (a blind check's 20 ms
    # beside [1, 2, 6] ms had read 23.6 ms and [-2.66, -1.71, 2.42] ms)
    from fluxcal.diagnose.report import eddy_current_line

    row = next(r for r in d.ranking if r["effect"] == "eddy_current")
    beside = eddy_current_line(replace(d, accepted=["time_offset", *d.accepted]), row)
    assert "above the smallest axis's: beside the delay found (time_offset)" in beside
    assert np.allclose(_vectors(beside)[0], 1e3 * (truth - truth.min()), atol=0.15), beside
    # nearly the same lag on every axis is, to first order, a delay (a blind check's 5 ms delay read [5.02, 5.08, 5.18]
    # ms of eddy currents in 1 seed of 9): the line says so; a housing's unequal lags do not
    assert "check the timestamps" not in line
    same = eddy_current_line(d, dict(row, coefficients=[5.02e-3, 5.08e-3, 5.18e-3]))
    assert "as a delay between the readings and the reference vectors of 5.09 ms (time_offset)" in same, same


def test_a_delay_found_beside_eddy_currents_says_it_holds_their_common_lag():
    # a blind check's 20 ms delay beside eddy currents of [1, 2, 6] ms read 23.6 ms, with nothing said of the split
    from fluxcal.diagnose.report import text as report_text

    _, d, text = _found(["time_offset"])
    line = _line(text, "time_offset")
    assert "ms behind the reference vectors" in line and "CANNOT TELL APART" not in line
    beside = _line(report_text(replace(d, accepted=[*d.accepted, "eddy_current"])), "time_offset")
    assert "the delay alone may be shorter (CANNOT TELL APART to first order)" in beside, beside
    # readings ahead: eddy currents' lag makes the lead look shorter (a review: 5.42 ms read 3.61 ms)
    ahead = [dict(r, delay_ms=-r["delay_ms"]) if r.get("delay_ms") else r for r in d.ranking]
    lead = _line(report_text(replace(d, accepted=[*d.accepted, "eddy_current"], ranking=ahead)), "time_offset")
    assert "ms ahead of the reference vectors" in lead and "the lead alone may be longer" in lead, lead


def test_left_over_is_said_when_most_is_taken_but_the_residuals_still_depart():
    # a blind check's fast eddy currents left the time whiteness at p 5.5e-33 and the report said nothing; beside
    # colored_noise what is left is the correlated noise it names (a review: an exact temp_offset read "not quite")
    from fluxcal.diagnose.report import text as report_text

    _, d, text = _found(["temp_offset"])
    assert "LEFT OVER" not in text
    rem = dict(d.remaining, unexplained=dict(d.remaining["unexplained"], share=0.01),
               tests=[dict(t, pvalue=1e-9 if t["test"].startswith("whiteness") else t["pvalue"])
                      for t in d.remaining["tests"]])
    said = report_text(replace(d, remaining=rem))
    assert "LEFT OVER: the effects found take 99 % of the departure, but the residuals still depart (time " \
           "whiteness (Ljung-Box, 20 lags) p 1e-09" in said, said
    assert "LEFT OVER" not in report_text(replace(d, remaining=rem, accepted=[*d.accepted, "colored_noise"]))


def test_a_cross_axis_error_about_a_large_hard_iron_is_sized_in_the_form_it_was_fitted():
    # About a hard iron of six fields the transducer's signal b + W h is 4–5 times W h alone, and the data may not
    # decide which it saw (offset_kind None): the anisotropy field must come from the form the coefficients were
    # fitted in (b + W h's scale gave 8440 uT for a simulated 2041 uT)
    result, d, text = _found(["cross_axis"], 0, hard_iron=6.0, soft_iron=0.15)
    assert d.accepted == ["cross_axis"] and d.ranking[0]["offset_kind"] is None, d.accepted
    hk = _vectors(_line(text, "cross_axis"))[0]
    assert np.allclose(hk, _truth(result, "cross_axis").hk, rtol=0.15), hk


def test_a_cubic_that_compresses_every_axis_is_said_as_a_saturations_first_order():
    result, d, text = _found(["nonlinearity_cubic"], 29)  # seed 29: every axis compressed, by −1.0 to −2.0 %
    assert "nonlinearity_cubic" in d.accepted, d.accepted
    _cubic(result, d, _line(text, "nonlinearity_cubic"))


def test_a_non_linearity_mostly_absorbed_by_the_offset_and_matrix_says_how_much_is_left():
    # a cubic about a hard iron of six fields changes the readings by more than the field, nearly all of it a shift
    # and a gain that the calibration takes up: the line says what is beyond them
    result, d, text = _found(["nonlinearity_cubic"], 0, hard_iron=6.0, soft_iron=0.15)
    line = _line(text, "nonlinearity_cubic")
    largest = float(re.search(rf"up to ({NUMBER}) uT", line).group(1))
    beyond = float(re.search(rf"\(({NUMBER}) uT of it beyond what an offset and a matrix take up\)", line).group(1))
    assert beyond < 0.5 * largest


def test_sizes_in_the_readings_own_units_when_none_is_stated():
    result, kw = withheld_trial(["temp_offset"], 0)
    d = diagnose(result.readings, **kw)
    assert "no unit stated" in d.text()
    assert re.search(rf"temp_offset: {VECTOR} per °C \(x, y, z\); over the recording's {NUMBER} °C {NUMBER}, "
                     rf"{NUMBER} % of the field", d.text())


# ---------------------------------------------------------------- the before/after plot


def _sensor(field, offset, n=2000, seed=0):
    """Readings of a turned sensor (field magnitude `field`, hard iron `offset`) and its calibration."""
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    W = np.diag([1.03, 0.97, 1.01])
    raw = field * u @ W.T + offset + rng.normal(0, 1e-3 * field, (n, 3))
    return raw, W


def _labels(fig):
    """Per axis of the figure, the drawn tick labels' texts and window boxes (those within the view)."""
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    out = []
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            lo, hi = sorted(axis.get_view_interval())
            ticks = axis.get_major_ticks(len(axis.get_majorticklocs()))
            drawn = [t.label1 for t in ticks if lo - 1e-9 * (hi - lo) <= t.get_loc() <= hi + 1e-9 * (hi - lo)
                     and t.label1.get_visible() and t.label1.get_text()]
            out.append(([t.get_text() for t in drawn], [t.get_window_extent(renderer) for t in drawn]))
    return out


@pytest.mark.parametrize("field, offset, unit, legend", [
    (54000.0, [-48000.0, 1500.0, -800.0], "nT", "|h| = 54000 nT"),   # an airborne fluxgate's readings in nT
    (50.0, [8.7, -14.2, 5.3], "uT", "|h| = 50 uT"),
])
def test_plot_tick_labels_do_not_overlap_and_the_legend_has_the_unit(field, offset, unit, legend):
    import matplotlib.pyplot as plt

    raw, W = _sensor(field, np.asarray(offset))
    cal = Calibration(offset=np.asarray(offset), matrix=np.linalg.inv(W), field_norm=field, units=unit)
    fig = before_after_figure(raw, cal, title="test")
    try:
        for texts, boxes in _labels(fig):
            assert 3 <= len(texts) <= 8, texts
            assert not any("e+" in t or len(t) > 6 for t in texts), texts  # -50k, not -50000 or 5e+04
            for a, b in zip(boxes, boxes[1:]):  # neighbours apart by at least 2 px
                assert not a.padded(1).overlaps(b.padded(1)), texts
        legends = [t.get_text() for ax in fig.axes if ax.get_legend() for t in ax.get_legend().get_texts()]
        assert legend in legends, legends
    finally:
        plt.close(fig)


def test_mains_pickup_aliased_by_the_sampling_is_said_as_one_line_and_red_noise_is_not():
    # a blind check's 50 Hz pickup sampled at 40 Hz (a 10 Hz line) was said as colored_noise alone
    result, kw = withheld_trial([], 0, rate_hz=40.0)
    t = kw["t"]
    pickup = 0.3 * np.sin(2 * np.pi * 50.0 * t + 0.4)[:, None] * np.array([0.6, -0.3, 0.74])  # fixed in the sensor
    d = diagnose(result.readings + pickup, **kw, units="uT")
    # modelled as a field at one frequency in the sensor's axes (periodic_interference), and named
    assert d.accepted == ["periodic_interference"], d.accepted
    line = _line(d.text(), "periodic_interference")
    assert re.search(r"a field at (9\.99|10|10\.01) Hz", line) and "50 Hz mains aliased by the 40 Hz" in line, line
    np.testing.assert_allclose(_vectors(line)[0], 0.3 * np.array([0.6, 0.3, 0.74]), rtol=0.05)
    # left to colored_noise (a line in a spectrum without the candidate), it is said as one line there
    from fluxcal.diagnose import report

    row = {"coefficients": [], "heldout_gap_before": 0.1, "heldout_rms_before": None}
    said = report.colored_noise_line(replace(d, series=dict(d.series, residual_after=d.series["residual_before"])),
                                     row)
    assert re.search(r"one line near (9\.[89]|10|10\.[12]) Hz", said) and "50 Hz mains aliased by the 40 Hz" in said
    # a red spectrum (colored noise, slow) is no line
    red = _line(_found(["colored_noise"])[2], "colored_noise")
    assert "one line" not in red, red


def test_mains_sampled_at_twice_its_frequency_is_not_taken_for_noise():
    # 50 Hz pickup sampled at 100 Hz sits at the Nyquist frequency: consecutive readings alternate, and their third
    # differences, the noise σ's yardstick, weigh it 3.2× — a review's pickup hid inside a σ raised 1.6× (and at 4 %
    # of the field, 4×: every effect "below the noise")
    result, kw = withheld_trial([], 0, rate_hz=100.0)
    t = kw["t"]
    white = diagnose(result.readings, **kw, units="uT")
    pickup = 1.0 * np.sin(2 * np.pi * 50.05 * t + 0.4)[:, None] * np.array([0.6, -0.3, 0.74])  # 2 % of the field
    d = diagnose(result.readings + pickup, **kw, units="uT")
    assert "alternate" not in white.noise_source, white.noise_source
    assert "readings two apart" in d.noise_source, d.noise_source
    assert abs(d.noise_sigma / white.noise_sigma - 1) < 0.1, (d.noise_sigma, white.noise_sigma)
    assert d.accepted == ["periodic_interference"], d.accepted
    line = _line(d.text(), "periodic_interference")
    assert re.search(r"a field at (49\.95|49\.9[4-6]\d*) Hz", line) and "50 Hz mains aliased by the 100 Hz" in line, line


def test_two_interference_lines_are_found_and_sized_each():
    # a second motor beside the first: the second line had been left to colored_noise ("one line near 7.3 Hz")
    result, kw = withheld_trial(["periodic_interference"], 0)
    t = kw["t"]
    second = 0.4 * np.sin(2 * np.pi * 7.3 * t + 1.0)[:, None] * np.array([0.2, 0.9, -0.4])
    d = diagnose(result.readings + second, **kw, units="uT")
    text = d.text()
    assert d.accepted == ["periodic_interference"] and "FOUND: periodic_interference (2 lines)" in text, text
    lines = [line.strip() for line in text.splitlines() if line.startswith("  periodic_interference: ")]
    assert len(lines) == 2, lines
    truth = _truth(result, "periodic_interference")
    _periodic(result, d, lines[0])
    assert float(re.search(rf"at ({NUMBER}) Hz", lines[1]).group(1)) == pytest.approx(7.3, abs=0.01)
    np.testing.assert_allclose(_vectors(lines[1])[0], 0.4 * np.array([0.2, 0.9, 0.4]), rtol=0.05)
    assert truth.frequency_hz != pytest.approx(7.3, abs=0.1)


def test_a_line_is_taken_out_of_the_noise_sigma_and_found():
    # a 1.8 Hz line sampled at 10 Hz passes into third differences 1.2×: it had raised an injected airborne recording's
    # σ 300× (0.42 → 139 nT), and the degenerate-fit guard then refused the line itself. The σ is now the readings'
    # less the line, said; the line is found and sized
    result, kw = withheld_trial([], 1, rate_hz=10.0)
    white = diagnose(result.readings, **kw, units="uT")
    t = kw["t"]
    line = 1.0 * np.sin(2 * np.pi * 1.8 * t + 0.3)[:, None] * np.array([0.6, -0.3, 0.74])  # 2 % of the field
    d = diagnose(result.readings + line, **kw, units="uT")
    assert "the readings less the line at 1.8 Hz in their spectrum" in d.noise_source, d.noise_source
    assert abs(d.noise_sigma / white.noise_sigma - 1) < 0.1, (d.noise_sigma, white.noise_sigma)
    assert d.accepted == ["periodic_interference"], d.accepted
    said = _line(d.text(), "periodic_interference")
    assert re.search(r"a field at 1\.8 Hz", said), said
    np.testing.assert_allclose(_vectors(said)[0], [0.6, 0.3, 0.74], rtol=0.05)
    assert "less the line" not in white.noise_source  # no line, nothing taken out


@pytest.mark.parametrize("start, end, rate_hz", [(8.0, 8.4, 50.0), (20.0, 21.0, 50.0), (3.0, 2.9, 25.0)])
def test_a_line_whose_frequency_drifts_is_found_and_its_course_said(start, end, rate_hz):
    # a motor whose speed changes by 1–5 % over the recording: its line, spread over many bins, had been left to
    # colored_noise ("one line near 8.3 Hz", NOT EXPLAINED). Its frequency is followed through the recording (the
    # first three quarters: the held-out quarter chooses nothing) and fitted with the drift; the held-out gap closes
    from fluxcal.sim.effects import PeriodicInterference

    result, kw = withheld_trial([], 2, rate_hz=rate_hz)
    t = kw["t"]
    span = float(np.ptp(t))
    truth = PeriodicInterference(np.array([0.3, -0.24, 0.32]), 0.5 * (start + end), np.array([0.2, 1.0, 2.0]),
                                 (end - start) / span)
    d = diagnose(truth.apply(result.readings, SimpleNamespace(t=t)), **kw, units="uT")
    assert d.accepted == ["periodic_interference"], d.accepted
    row = d.ranking[0]
    assert row["rate_hz_per_s"] == pytest.approx(truth.rate_hz_per_s, rel=0.03), row
    assert row["heldout_gap_after"] < 0.2 * row["heldout_gap_before"], row
    said = _line(d.text(), "periodic_interference")
    found = re.search(rf"a field at ({NUMBER}) Hz drifting to ({NUMBER}) Hz", said)
    assert found and float(found.group(1)) == pytest.approx(start, abs=0.02) \
        and float(found.group(2)) == pytest.approx(end, abs=0.02), said
    np.testing.assert_allclose(_vectors(said)[0], [0.3, 0.24, 0.32], rtol=0.05)
    assert "whose speed changed" in said, said


def test_a_rate_scan_turned_step_by_step_is_the_power_of_each_course():
    """_demodulated_power turns the last course's phasors by an even step's (one product, not an exponential): each
    power must be the plain |Σ series e^(−i phase)|² of its own course — for the scan _line_rate asks for, runs of
    different steps, negative, zero and three-rate runs, and a lone rate — over a long recording (where a step's
    rounding would add up) and a short one."""
    from fluxcal.sim.effects import _demodulated_power, _line_phase

    rng = np.random.default_rng(4)
    for n, dt in ((300, 0.05), (60000, 0.01)):
        t = np.arange(n) * dt
        series = rng.normal(size=(n, 3)) + np.sin(2 * np.pi * (3.0 * t + 0.004 * t ** 2))[:, None] * [1.0, 0.5, -0.3]
        span = float(t[-1])
        even = -0.2 + np.linspace(-4.0, 4.0, 33) / (2.0 * span ** 2)
        mixed = np.array([0, 0.01, 0.02, 0.05, 0.08, 0.11, 0.10, 0.09, 0.09, 0.09]) / span
        for rates in (np.r_[0.0, even], np.r_[even[:5], 0.3, even[5:9], even[20:]], mixed,
                      np.array([0, 0.01, 0.02, 0.04]) / span, [0.3, 0.3, 0.3], [0.01]):
            plain = [np.sum(np.abs(np.exp(-1j * _line_phase(t, 3.0, r, (t[0], t[-1]))) @ series) ** 2) for r in rates]
            np.testing.assert_allclose(_demodulated_power(t, series, 3.0, rates, (t[0], t[-1])), plain,
                                       rtol=1e-9, atol=1e-9 * max(plain))


def _ridge_afresh(t, series, f):
    """_line_ridge as it was before the stretches' spectra were kept: each stretch's spectrum computed for f."""
    from fluxcal.sim.effects import LINE_DRIFT_MOST, LINE_SEGMENTS

    used = int(0.75 * len(t))
    step, seg = float(t[1] - t[0]), used // LINE_SEGMENTS
    freqs = np.fft.rfftfreq(8 * seg, step)
    band = np.abs(freqs - f) <= max(LINE_DRIFT_MOST * f, 3.0 / (seg * step))
    centres, peaks, weights = [], [], []
    for k in range(LINE_SEGMENTS):
        chunk = series[k * seg:(k + 1) * seg] * np.hanning(seg)[:, None]
        power = np.sum(np.abs(np.fft.rfft(chunk, n=8 * seg, axis=0)) ** 2, axis=1)
        j = np.flatnonzero(band)[np.argmax(power[band])]
        a, b, c = np.log(power[j - 1:j + 2] + 1e-300)
        j = j + 0.5 * (a - c) / (a - 2 * b + c) if a - 2 * b + c < 0 else j
        centres.append(float(np.mean(t[k * seg:(k + 1) * seg])) - 0.5 * float(t[0] + t[-1]))
        peaks.append(float(j) * float(freqs[1]))
        weights.append(float(np.max(power[band])))
    rate, at_middle = np.polyfit(centres, peaks, 1, w=np.sqrt(weights))
    return float(rate), float(at_middle)


def test_a_lines_ridge_from_spectra_kept_is_the_one_computed_afresh():
    """_line_ridge from the stretches' spectra a context keeps (_segment_spectra) is the one each frequency's own
    spectra give, bit for bit — also where a padded bin lies exactly on the edge of the narrowest band and holds a
    line (20 000 readings at 12.3 ms, asked at 0.195 Hz, a line at 0.065 Hz: 3/(seg·step) and 24 bins' width
    differ in the last bit there, and had taken that bin out of the band)."""
    from fluxcal.sim.effects import _line_ridge, _segment_spectra

    for n, dt, freqs, line in ((4000, 0.02, (4.0, 5.5, 7.0, 12.0), 5.0),
                               (20000, 0.0123, (48 / (20000 * 0.0123), 0.5), 12 / (15000 * 0.0123))):
        t = np.arange(n) * dt
        series = np.sin(2 * np.pi * (line * t + 0.01 * t ** 2 * (line > 1)))[:, None] * [1.0, -0.4, 0.2]
        series = series + np.random.default_rng(1).normal(0, 0.3, series.shape)
        kept = _segment_spectra(t, series)
        for f in freqs:
            assert _line_ridge(t, series, f, kept) == _line_ridge(t, series, f) == _ridge_afresh(t, series, f), f
    t = np.arange(4000) * 0.02
    series = np.sin(2 * np.pi * (5.0 * t + 0.01 * t ** 2))[:, None] * [1.0, -0.4, 0.2]
    rate, middle = _line_ridge(t, series, 5.8)
    assert rate == pytest.approx(0.02, rel=0.1) and middle == pytest.approx(5.0 + 0.02 * 0.5 * t[-1], abs=0.05)
    assert _segment_spectra(t[:40], series[:40]) is None and _line_ridge(t[:40], series[:40], 5.0) is None


def test_a_step_in_a_short_recording_is_no_line_drifting_through_zero_hertz():
    """100 readings over 5 s with an offset step: the ridge through a step's spectrum fitted "a field at −0.151 Hz
    drifting to 2.163 Hz" (a blind check). A line drifts within LINE_DRIFT_MOST of its frequency either way; on
    steps the course is never taken (it had been, 35–70 % of the frequency, at 14 of 50 trial frequencies)."""
    from fluxcal.sim.effects import LINE_DRIFT_MOST, _line_rate

    t = np.arange(100) * 0.05
    for seed in range(10):
        rng = np.random.default_rng(seed)
        steps = np.where(t[:, None] > 2.5, 1.0, 0.0) * np.array([0.8, -0.5, 0.4]) + rng.normal(0, 0.05, (100, 3))
        for f in (0.5, 0.8, 1.0, 1.5, 2.0):
            rate = _line_rate(t, steps - steps.mean(axis=0), f)
            assert abs(rate) * 0.5 * np.ptp(t) <= LINE_DRIFT_MOST * f, (seed, f, rate)


@pytest.mark.parametrize("model", [None, "vector"])
def test_a_line_on_for_part_of_the_recording_is_said_so(model):
    # a motor switched on halfway: its line had been sized as one averaged over the whole (0.18 for 0.5, its
    # direction skewed), or — on before the held-out quarter only — not confirmed, with no word of why
    result, kw = withheld_trial([], 5, model=model)
    t = kw["t"]
    half = 0.5 * (t[0] + t[-1])
    wave = 0.5 * np.sin(2 * np.pi * 7.0 * t)[:, None] * np.array([0.6, -0.48, 0.64])
    for on, said in ((t >= half, "on only from about 30 s on"), (t < half, "on only until about 30 s")):
        d = diagnose(result.readings + wave * on[:, None], **kw, units="uT")
        text = d.text()
        assert said in text and "its amplitude is not steady" in text, text
        stretches = _vectors(text[text.index("stretches: "):])[0]
        np.testing.assert_allclose(stretches[on[::len(t) // 8][:8]], 0.5, rtol=0.1)
        assert np.all(stretches[~on[::len(t) // 8][:8]] < 0.05), stretches
    steady = diagnose(result.readings + wave, **kw, units="uT")
    assert "not steady" not in steady.text() and steady.accepted == ["periodic_interference"]


def test_a_lines_frequency_comes_with_its_cramer_rao_bound():
    # the fitted frequency's spread over seeds against the bound the line states (white noise, magnitudes): 1.01×
    # over 12 seeds when measured; here 10 seeds, whose standard deviation is itself known to ±25 %
    found, bounds = [], []
    for seed in range(10):
        result, kw = withheld_trial([], seed)
        t = kw["t"]
        line = np.sin(2 * np.pi * 5.3 * t + 0.7)[:, None] * np.array([0.3, -0.24, 0.32])
        d = diagnose(result.readings + line, **kw, units="uT", max_effects=1)
        said = _line(d.text(), "periodic_interference")
        at, bound = re.search(rf"fixed in the sensor's axes \(({NUMBER}) ± ({NUMBER}) Hz: the Cramér–Rao bound", said
                              ).groups()
        found.append(float(at))
        bounds.append(float(bound))
        row = next(r for r in d.ranking if r["effect"] == "periodic_interference")  # the JSON's too
        assert row["frequency_se_hz"] == pytest.approx(float(bound), rel=0.05) and row["rate_se_hz_per_s"] is None
    ratio = np.std(found, ddof=1) / np.mean(bounds)
    assert 0.6 < ratio < 1.6, (found, bounds)
    assert abs(np.mean(found) - 5.3) < 3 * np.mean(bounds) / np.sqrt(10), found


def test_a_step_at_the_first_reading_after_a_hole_is_dated_to_the_hole():
    """A step inside 60 s without readings was dated to the first reading after them (a blind check): said as
    between the readings on either side."""
    from fluxcal.diagnose.report import offset_step_line

    t = np.concatenate([np.arange(0, 150, 0.05), np.arange(210, 300, 0.05)])
    d = SimpleNamespace(units="uT", base=Calibration(offset=np.zeros(3), matrix=np.eye(3), field_norm=50.0),
                        series={"t": t, "timestamps": True})
    said = offset_step_line(d, {"jump": [0.8, -0.5, 0.4], "jump_s": 210.0, "back_s": None})
    assert "between t = 150 s and t = 210 s (no readings in between)" in said, said  # (149.95 s)
    said = offset_step_line(d, {"jump": [0.8, -0.5, 0.4], "jump_s": 250.0, "back_s": None})
    assert "at t = 250 s and stayed" in said, said
