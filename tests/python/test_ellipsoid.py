import json

import numpy as np
import pytest

import fluxcal
import fluxcal.oracle
from conftest import simulated


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("known_norm", [False, True])
def test_core_agrees_with_numpy_oracle(seed, known_norm):
    s = simulated(seed, n=500 + 300 * seed, noise=0.01)
    norm = s.field_norm if known_norm else None
    cal = fluxcal.fit_ellipsoid(s.readings, field_norm=norm)
    ref = fluxcal.oracle.fit_ellipsoid(s.readings, field_norm=norm)
    assert np.linalg.norm(cal.offset - ref["offset"]) <= 1e-8 * np.linalg.norm(ref["offset"])
    assert np.linalg.norm(cal.matrix - ref["matrix"]) <= 1e-8 * np.linalg.norm(ref["matrix"])
    assert cal.field_norm == pytest.approx(ref["field_norm"], rel=1e-10)


@pytest.mark.parametrize("seed", range(20))
def test_recovers_simulated_sensor_within_one_percent(seed):
    # N = 2000, noise 0.5 % of the field, soft iron within ±20 %, offset up to 50 % of the field.
    s = simulated(100 + seed)
    truth = s.true_calibration()
    cal = fluxcal.fit_ellipsoid(s.readings, field_norm=s.field_norm)
    assert np.linalg.norm(cal.offset - truth.offset) < 0.01 * s.field_norm
    assert np.linalg.norm(cal.matrix - truth.matrix) < 0.01 * np.linalg.norm(truth.matrix)
    # after correction the magnitude spread is the noise (0.5 %), before it is the distortion
    assert cal.summary["norm_std_over_mean"] < 0.007
    assert cal.summary["exact_statistics"] is True


def test_summary_statistics_are_those_of_the_corrected_readings():
    s = simulated(7, noise=0.01)
    cal = fluxcal.fit_ellipsoid(s.readings, field_norm=s.field_norm)
    norm = np.linalg.norm(cal.apply(s.readings), axis=1)
    assert cal.summary["samples"] == len(s.readings)
    assert cal.summary["norm_mean"] == pytest.approx(norm.mean(), rel=1e-12)
    assert cal.summary["norm_std_over_mean"] == pytest.approx(norm.std() / norm.mean(), rel=1e-9)
    assert cal.summary["residual_rms"] == pytest.approx(np.sqrt(np.mean((norm - s.field_norm) ** 2)), rel=1e-9)
    moments = fluxcal.fit_ellipsoid(s.readings, field_norm=s.field_norm, exact_statistics=False)
    assert moments.summary["norm_std_over_mean"] == pytest.approx(norm.std() / norm.mean(), rel=0.02)


def test_without_field_norm_scale_is_volume_radius():
    s = simulated(3, noise=0.0)
    cal = fluxcal.fit_ellipsoid(s.readings)
    assert np.linalg.det(cal.matrix) == pytest.approx(1.0, abs=1e-10)
    W = s.true_calibration().forward_matrix
    assert cal.field_norm == pytest.approx(s.field_norm * abs(np.linalg.det(W)) ** (1 / 3), rel=1e-9)


@pytest.mark.parametrize("scale", [1e-110, 1e110])
def test_the_fitted_radius_does_not_overflow_at_extreme_scales(scale):
    """The volume radius was the cube root of the semi-axes' product in reading units: inf (and a NaN
    matrix) at 1e110, 0 at 1e-110, silently."""
    m = simulated(9, n=500, field_norm=50.0).readings
    base, far = fluxcal.fit_ellipsoid(m), fluxcal.fit_ellipsoid(m * scale)
    np.testing.assert_allclose(far.field_norm / scale, base.field_norm, rtol=1e-10)
    np.testing.assert_allclose(far.matrix, base.matrix, rtol=1e-8)


def test_streaming_moments_match_batch_fit():
    s = simulated(4)
    acc = fluxcal.EllipsoidMoments.from_first(s.readings[:50])
    for block in np.array_split(s.readings, 7):
        acc.add(block)
    assert acc.count == len(s.readings)
    streamed, batch = acc.fit(field_norm=s.field_norm), fluxcal.fit_ellipsoid(s.readings, field_norm=s.field_norm)
    np.testing.assert_allclose(streamed.offset, batch.offset, rtol=1e-9, atol=1e-9 * s.field_norm)
    np.testing.assert_allclose(streamed.matrix, batch.matrix, rtol=1e-9, atol=1e-12)


def test_accepts_lists_fortran_order_and_float32():
    s = simulated(5)
    ref = fluxcal.fit_ellipsoid(s.readings)
    for variant in (s.readings.tolist(), np.asfortranarray(s.readings), s.readings[::1].copy()):
        np.testing.assert_allclose(fluxcal.fit_ellipsoid(variant).matrix, ref.matrix, rtol=1e-12)
    f32 = fluxcal.fit_ellipsoid(s.readings.astype(np.float32))
    np.testing.assert_allclose(f32.matrix, ref.matrix, rtol=1e-4)


def test_apply_reading_and_magcal_conventions():
    s = simulated(6)
    cal = fluxcal.fit_ellipsoid(s.readings, field_norm=s.field_norm)
    h = cal.apply(s.readings)
    np.testing.assert_allclose(cal.apply(s.readings[0]), h[0])
    np.testing.assert_allclose(cal.reading(h), s.readings, rtol=1e-12, atol=1e-9 * s.field_norm)
    A, b, expmfs = cal.to_magcal()  # MATLAB: C = (D − b)·A
    np.testing.assert_allclose((s.readings - b) @ A, h)
    assert expmfs == cal.field_norm
    back = fluxcal.Calibration.from_magcal(A, b, expmfs)
    np.testing.assert_allclose(back.matrix, cal.matrix)


def test_save_and_load_round_trip(tmp_path):
    s = simulated(8)
    cal = fluxcal.fit_ellipsoid(s.readings, field_norm=s.field_norm, units="nT")
    path = cal.save(tmp_path / "cal.json")
    data = json.loads(path.read_text())
    assert data["fluxcal_version"] == fluxcal.__version__
    assert data["model"] == "ellipsoid" and data["units"] == "nT"
    assert data["summary"]["samples"] == 2000
    back = fluxcal.Calibration.load(path)
    np.testing.assert_array_equal(back.matrix, cal.matrix)
    np.testing.assert_array_equal(back.offset, cal.offset)
    assert back.summary == cal.summary and back.units == "nT"
    # another convention's offset and matrix would give a wrong field: refused; the same equation spaced
    # otherwise is the same convention
    for other in ("h = A m + b", "C = (D - b) A", None):
        path.write_text(json.dumps(dict(data, convention=other)))
        with pytest.raises(ValueError, match=rf"cal.json: convention .* is not fluxcal's 'h = A \(m - b\)'"):
            fluxcal.Calibration.load(path)
    path.write_text(json.dumps(dict(data, convention="H = A(m-b)")))
    np.testing.assert_array_equal(fluxcal.Calibration.load(path).matrix, cal.matrix)


def test_printed_offset_keeps_its_digits_in_tesla():
    s = simulated(8)
    cal = fluxcal.fit_ellipsoid(s.readings * 1e-9, units="T")   # nT readings written in tesla
    line = next(row for row in str(cal).splitlines() if "offset b" in row)
    printed = np.array(line.split("[")[1].split("]")[0].split(), float)
    np.testing.assert_allclose(printed, cal.offset, rtol=1e-6)


def test_load_errors_name_the_file(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ValueError, match="bad.json: not a fluxcal calibration"):
        fluxcal.Calibration.load(bad)
    bad.write_text('{"offset": [1, 2, 3]}')
    with pytest.raises(ValueError, match="bad.json: missing matrix, field_norm"):
        fluxcal.Calibration.load(bad)


def test_every_saved_file_loader_says_what_is_wrong_the_same_way(tmp_path):
    # Four loaders had four wordings, and a folder or a missing calibration raised IsADirectoryError or
    # FileNotFoundError. Each names the file, what it should be and the problem.
    import os

    from fluxcal.cable import RingCalibration
    from fluxcal.drift import DriftModel
    from fluxcal.export_c import load_kalman

    cases = {"binary.json": (b"\x82\xff\x00abc", r"\(byte 0x82 at offset 0 is not text\)"),
             "cut.json": (b'{"offset": [1,', r"\(not valid JSON at line 1, column 15: .*truncated file\?\)"),
             "list.json": (b"[1, 2]", r"\(a JSON list, expected an object\)")}
    for name, (content, _) in cases.items():
        (tmp_path / name).write_bytes(content)
    os.mkfifo(tmp_path / "pipe.json")  # reading it would block forever
    loaders = {fluxcal.Calibration.load: "a fluxcal calibration", RingCalibration.load: "a ring calibration",
               DriftModel.load: "a fluxcal drift model", load_kalman: "a saved FixedArKalman or drift model"}
    for load, what in loaders.items():
        for name, (_, problem) in cases.items():
            with pytest.raises(ValueError, match=rf"{name}: not {what} {problem}"):
                load(tmp_path / name)
        with pytest.raises(ValueError, match=rf"{tmp_path.name}: a folder, not {what}"):
            load(tmp_path)
        with pytest.raises(ValueError, match=rf"pipe.json: not a regular file .*, not {what}"):
            load(tmp_path / "pipe.json")
        with pytest.raises(ValueError, match=rf"absent.json: cannot read {what} \(No such file"):
            load(tmp_path / "absent.json")
    # a byte-order mark (a Windows editor's) before a valid calibration is read, not called invalid JSON
    cal = fluxcal.calibrate(simulated(3).readings)
    cal.save(tmp_path / "plain.json")
    (tmp_path / "bom.json").write_bytes(b"\xef\xbb\xbf" + (tmp_path / "plain.json").read_bytes())
    np.testing.assert_array_equal(fluxcal.Calibration.load(tmp_path / "bom.json").offset, cal.offset)


# -- bad input: a clear ValueError naming the input, never a crash or a silent answer --------------------

def test_nan_and_inf_rows_are_named():
    x = simulated(9).readings.copy()
    x[17, 2] = np.nan
    with pytest.raises(ValueError, match=r"samples: row 17, column 2 \(z\) is NaN"):
        fluxcal.fit_ellipsoid(x)
    x[17, 2] = 1.0
    x[3, 0] = -np.inf
    with pytest.raises(ValueError, match=r"row 3, column 0 \(x\) is infinite"):
        fluxcal.fit_ellipsoid(x)


def test_too_few_samples():
    with pytest.raises(ValueError, match="samples: 8 rows, need at least 9"):
        fluxcal.fit_ellipsoid(simulated(1).readings[:8])


def test_a_sensor_never_turned_is_told_so():
    """A static log is noise about one point: the fit's failure says the readings hardly change, whatever shape the
    noise gave the quadric."""
    rng = np.random.default_rng(4)
    static = np.array([120.0, -340.0, 410.0]) + rng.normal(0.0, 0.4, (500, 3))
    with pytest.raises(ValueError, match=r"hardly change \(their widest spread is 0\.0\d+ % of their mean magnitude\)"):
        fluxcal.calibrate(static)
    # the plain algebraic fit can put a quadric through the noise: its warnings say what it is
    fitted = fluxcal.fit_ellipsoid(static)
    assert any(w.startswith("not turned: the readings hardly change") and "the noise's shape" in w
               for w in fitted.summary["warnings"]), fitted.summary["warnings"]
    # a turned sensor's counts about an unsigned ADC's mid-scale (spread under 1 % of their magnitude) fit well:
    # no such warning
    s = simulated(5)
    counts = 32768.0 + (s.readings - s.readings.mean(axis=0)) * (200.0 / s.field_norm)
    assert not any("not turned" in w for w in fluxcal.fit_ellipsoid(counts).summary["warnings"])
    # a static log whose z never leaves one count is taken for readings in a plane: that error says it too
    flat = static.copy()
    flat[:, 2] = 410.0
    with pytest.raises(ValueError, match=r"nearly in one plane .*; the readings hardly change"):
        fluxcal.fit_ellipsoid(flat)
    with pytest.raises(ValueError, match=r"nearly in one plane .*; the readings hardly change"):
        fluxcal.twostep(flat, 540.0)  # TWOSTEP's own check says it too


def test_a_scalar_argument_that_is_not_a_number_is_named():
    s = simulated(1)
    with pytest.raises(ValueError, match="field_norm: 2000 values; the ellipsoid fit takes one"):
        fluxcal.fit_ellipsoid(s.readings, field_norm=np.full(2000, s.field_norm))
    with pytest.raises(ValueError, match="field_norm: 'abc' is not a number"):  # float() had named nothing
        fluxcal.fit_ellipsoid(s.readings, field_norm="abc")
    for solve in (fluxcal.calibrate, fluxcal.twostep):  # (these take a Recording's column by its name)
        with pytest.raises(ValueError, match="field_norm: 'abc' names a column, but the samples are an array"):
            solve(s.readings, field_norm="abc")
    with pytest.raises(ValueError, match=r"loss_scale: 2 values where one number is taken"):
        fluxcal.refine(fluxcal.fit_ellipsoid(s.readings), s.readings, loss="huber", loss_scale=[1, 2])


def test_planar_samples_are_rejected():
    a = np.linspace(0, 2 * np.pi, 400)
    planar = np.column_stack([np.cos(a), np.sin(a), 0.1 * np.cos(a)]) + [0.3, -0.2, 0.5]
    with pytest.raises(ValueError, match="lie nearly in one plane"):
        fluxcal.fit_ellipsoid(planar)


def test_two_flat_turns_are_named_not_enough():
    # The planar error said "rotate the sensor about at least two axes"; a user who did (a turn about z, then
    # one about x) met "rank deficient": the quadrics through two conics in different planes are a family.
    a = np.linspace(0, 2 * np.pi, 300, endpoint=False)
    z_turn = np.column_stack([np.cos(a), np.sin(a), np.zeros_like(a)])
    x_turn = np.column_stack([np.zeros_like(a), np.cos(a), np.sin(a)])
    m = 50.0 * np.vstack([z_turn, x_turn]) @ np.diag([1.05, 0.97, 1.0]) + [10.0, -5.0, 3.0]
    for method in ("ls", "als"):
        with pytest.raises(ValueError, match="rank deficient .* turn the sensor about all three axes or tumble it "
                                             r"\(two flat turns leave an ellipsoid undetermined\)"):
            fluxcal.fit_ellipsoid(m, method=method)
    with pytest.raises(ValueError, match="turn the sensor about all three axes"):
        fluxcal.twostep(m, 50.0)
    y_turn = np.column_stack([np.cos(a), np.zeros_like(a), np.sin(a)])  # a third turn settles it
    m3 = 50.0 * np.vstack([z_turn, x_turn, y_turn]) @ np.diag([1.05, 0.97, 1.0]) + [10.0, -5.0, 3.0]
    np.testing.assert_allclose(fluxcal.fit_ellipsoid(m3, method="ls").offset, [10.0, -5.0, 3.0], atol=1e-6)


def test_wrong_shapes_and_types():
    x = simulated(2).readings
    with pytest.raises(ValueError, match=r"shape \(3, 2000\).*transposed"):
        fluxcal.fit_ellipsoid(x.T)
    with pytest.raises(ValueError, match="samples: not numeric"):
        fluxcal.fit_ellipsoid([["a", "b", "c"]] * 10)
    with pytest.raises(ValueError, match="field_norm"):
        fluxcal.fit_ellipsoid(x, field_norm=-1.0)


def test_a_small_cap_is_not_blamed_on_the_units():
    """Readings within 20° of one direction, in the right units: the fit's radius is far from field_norm
    because of the coverage, and the warning says so beside 'check the units'."""
    rng = np.random.default_rng(1)
    v = rng.normal(size=(20000, 3))
    v /= np.linalg.norm(v, axis=1)[:, None]
    v = v[v[:, 2] > np.cos(np.deg2rad(20))][:1000]
    m = 50 * v @ np.diag([1.1, 0.92, 1.02]).T + [12.0, -7.0, 20.0] + 0.2 * rng.standard_normal(v.shape)
    warnings = fluxcal.fit_ellipsoid(m, field_norm=50.0).summary["warnings"]
    units = next(w for w in warnings if "times the fitted radius" in w)
    assert "check the units, or the coverage" in units


def test_poor_coverage_warns():
    # half the azimuths, elevation within ±25°: about a fifth of the directions
    rng = np.random.default_rng(0)
    az, el = rng.uniform(0, np.pi, 2000), np.deg2rad(rng.uniform(-25, 25, 2000))
    x = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    x = x + 0.001 * rng.standard_normal(x.shape)
    cal = fluxcal.fit_ellipsoid(x)
    assert cal.summary["direction_coverage"] < 0.5
    assert any("poor coverage" in w for w in cal.summary["warnings"])
    # direction scatter: the thin (z) direction holds mean(ĥz²) ≈ 0.07 instead of 1/3
    h = cal.apply(x)
    u = h / np.linalg.norm(h, axis=1, keepdims=True)
    np.testing.assert_allclose(cal.summary["direction_eigenvalues"], np.linalg.eigvalsh(u.T @ u / len(u)), atol=1e-12)
    assert cal.summary["direction_eigenvalues"][0] < 0.1
    full = fluxcal.fit_ellipsoid(simulated(1).readings)
    assert full.summary["direction_coverage"] > 0.95 and not full.summary["warnings"]
    np.testing.assert_allclose(full.summary["direction_eigenvalues"], 1 / 3, atol=0.03)


@pytest.mark.parametrize("seed", range(3))
def test_direction_coverage_agrees_with_oracle(seed):
    rng = np.random.default_rng(seed)
    v = rng.standard_normal((50 + 100 * seed, 3)) * [1, 1, 0.3 * seed + 0.1]
    assert fluxcal.direction_coverage(v) == fluxcal.oracle.direction_coverage(v)
    from fluxcal import _core
    assert [_core.direction_bin(r) for r in v[:20]] == list(fluxcal.oracle.direction_bins(v[:20]))
    assert fluxcal.direction_coverage(rng.standard_normal((20000, 3))) == 1.0


def test_summary_coverage_is_that_of_the_corrected_fields():
    s = simulated(12, n=3000)
    s.readings[:2000] = np.tile(s.readings[2000:], (2, 1))  # a third repeated: fewer directions
    cal = fluxcal.fit_ellipsoid(s.readings)
    assert cal.summary["direction_coverage"] == fluxcal.oracle.direction_coverage(cal.apply(s.readings))
    sub = fluxcal.fit_ellipsoid(s.readings, coverage_rows=300)  # strided subsample: never more bins
    assert sub.summary["direction_coverage"] <= cal.summary["direction_coverage"]
