"""What the command line says, from a newcomer's review (/work/scratch/s31/newcomer/report.md): C11 (apply with a
calibration that does not fit the readings said nothing), C9 (the stretch warning gave rows, not file lines), M2
("identifiable yes" beside widened standard errors), C8 (the vector fit's columns line left out the reference's),
the --noise-sigma and cable simulate --repeats help, and the cable offsets in tesla."""
import json
import re

import numpy as np
import pytest

import fluxcal
from fluxcal import read_recording, sim, write_csv
from fluxcal.cli import _with_file_lines, main

FIELD = np.array([19.6, 0.8, 45.2])  # µT
UNITS = {"t": "s", "mx": "uT", "my": "uT", "mz": "uT"}


def _sensor(seed: int, noise: float) -> list:
    """A random sensor (soft iron ±20 %, offset up to half the field) with white noise `noise` µT."""
    return sim.random_sensor(np.linalg.norm(FIELD), np.random.default_rng(seed),
                             noise=noise / np.linalg.norm(FIELD))


def _log(effects, seed: int, seconds: float = 40.0):
    """A hand-turned log at 50 Hz (smooth at the sample rate, as a hand is)."""
    rng = np.random.default_rng(seed)
    return sim.simulate(sim.tumble(seconds, temperature=None, rng=rng), effects, FIELD, rng)


def _write(path, t, m):
    return write_csv(path, {"t": t, "mx": m[:, 0], "my": m[:, 1], "mz": m[:, 2]}, units=UNITS)


def _apply(capsys, cal, data, tmp_path):
    assert main(["apply", str(cal), str(data), "-o", str(tmp_path / "out.csv")]) == 0
    return capsys.readouterr().out


# ------------------------------------------------------------------ C11: apply with a calibration that does not fit

def test_apply_says_a_calibration_of_another_sensor_does_not_fit_and_not_of_the_same_sensors_other_half(
        tmp_path, capsys):
    """C11: another sensor's calibration gave |h| std/mean 30.9 % silently. Fitted on the first half of a log and
    applied to the second (other directions), the same sensor's is quiet; another sensor's is named, with both
    files, the spreads and the likely causes."""
    log = _log(_sensor(1, 0.05), 11)
    half = len(log.readings) // 2
    cal = fluxcal.calibrate(log.readings[:half], units="uT").save(tmp_path / "cal.json")
    second = _write(tmp_path / "second.csv", log.t[half:], log.readings[half:])
    out = _apply(capsys, cal, second, tmp_path)
    assert "warning" not in out, out

    other = _log(_sensor(2, 0.05), 12)
    garbled = other.readings.copy()
    garbled[5] = 1e300  # (a reading past any range, left out of the spreads, its time too)
    other_file = _write(tmp_path / "other.csv", other.t, garbled)
    out = _apply(capsys, cal, other_file, tmp_path)
    warning = next(line for line in out.splitlines() if "does not fit" in line)
    own = json.loads(cal.read_text())["summary"]["norm_std_over_mean"]
    assert warning.startswith(f"warning: {cal} does not fit {other_file}: the corrected |h| spreads "), warning
    assert f"the {100 * own:.3g} % the calibration left on the readings it was fitted on" in warning
    assert "raw readings" in warning
    for cause in ("another sensor's calibration", "the mounting changed", "iron come near", "the wrong file"):
        assert cause in warning, warning
    spread = float(warning.split("spreads ")[1].split(" %")[0])
    assert spread > 20 * 100 * own  # many times the fit's own, not a shade above it


def test_apply_allows_for_noisier_readings_and_glitches_of_the_same_sensor(tmp_path, capsys):
    """A calibration fitted on quiet readings (0.05 µT) applied to the same sensor read 10× noisier: the spread is
    10× the fit's own, all of it the noise, which these readings' differences show: no warning. Nor for a few
    0,0,0 glitches (1 %), which the fit of the calibration had left out too."""
    quiet = _log(_sensor(3, 0.05), 21)
    cal = fluxcal.calibrate(quiet.readings, units="uT").save(tmp_path / "cal.json")
    noisy = _log(_sensor(3, 0.5), 22)
    out = _apply(capsys, cal, _write(tmp_path / "noisy.csv", noisy.t, noisy.readings), tmp_path)
    corrected = float(out.split("|h| std/mean ")[1].split(" %")[0])
    assert corrected > 5 * 100 * json.loads(cal.read_text())["summary"]["norm_std_over_mean"]  # the case at issue
    assert "warning" not in out, out

    glitchy = _log(_sensor(3, 0.05), 23).readings.copy()
    glitchy[::100] = 0.0
    out = _apply(capsys, cal, _write(tmp_path / "glitchy.csv", quiet.t, glitchy), tmp_path)
    assert "does not fit" not in out, out


def test_apply_on_real_recordings_judges_the_same_sensor_and_another(tmp_path, capsys, real_data):
    """The handheld magnetometer's calibration from the first half of its recording, applied to the second half:
    quiet (3.3 % against its own 1.6 %). The phone's calibration applied to the handheld's readings: said."""
    def halves(name, columns):
        rec = read_recording(real_data / name, columns=columns)
        m, half = rec.samples(), len(rec) // 2
        return m[:half], m[half:]

    first, second = halves("handheld_set1.csv", None)
    second_file = write_csv(tmp_path / "handheld_second.csv", dict(zip(("mx", "my", "mz"), second.T)))
    cal = fluxcal.calibrate(first).save(tmp_path / "handheld_cal.json")
    out = _apply(capsys, cal, second_file, tmp_path)
    assert "does not fit" not in out, out

    phone, _ = halves("phone_acc_mag.csv", "mx,my,mz")
    phone_cal = fluxcal.calibrate(phone).save(tmp_path / "phone_cal.json")
    out = _apply(capsys, phone_cal, second_file, tmp_path)
    assert f"warning: {phone_cal} does not fit {second_file}" in out, out


# ------------------------------------------------------------------ C9: every warning that names rows names file lines

def test_file_lines_are_added_to_every_list_of_rows():
    """One mechanism for every calibrate warning that names rows: the outliers' (inside parentheses) and the
    stretches' (with a note per range)."""
    lines = np.arange(3000) + 5
    outliers = "left out 3 of 3000 readings … (rows 600, 700, 900; 3 read exactly 0,0,0 (glitches)); kept with …"
    assert "(rows 600, 700, 900; file lines 605, 705, 905; 3 read exactly" in _with_file_lines(outliers, lines)
    stretch = ("rows 2953–2999 (up to 7 σ), 10–12 (up to 5 σ), … lie off the ellipsoid for a stretch of more than 3 "
               "readings")
    assert _with_file_lines(stretch, lines).startswith("rows 2953–2999 (up to 7 σ), 10–12 (up to 5 σ), … "
                                                       "(file lines 2958–3004, 15–17, …) lie off the ellipsoid")
    assert _with_file_lines("a change at row 12 of the log", lines) == "a change at row 12 (file line 17) of the log"
    assert _with_file_lines(stretch, None) == stretch  # (a format without lines: rows only)
    said = "rows must be in time order: serial_correlation='independent'"  # no row numbers: as it was
    assert _with_file_lines(said, lines) == said


def test_calibrate_names_the_file_lines_of_a_stretch_off_the_ellipsoid(tmp_path, capsys):
    """C9: `rows 2953–2999 … lie off the ellipsoid` (the handheld recording) gave no file lines, the outliers'
    warning did. A magnet passing the sensor for 40 readings, in a file whose header puts row r on another line."""
    log = _log(_sensor(4, 0.05), 31)
    m = log.readings.copy()
    m[1200:1240] += [3.0, -2.0, 1.5]  # µT: a disturbance, not a glitch
    path = _write(tmp_path / "magnet.csv", log.t, m)
    line_numbers = read_recording(path).line_numbers
    assert line_numbers[0] != 0  # (rows and file lines differ)
    assert main(["calibrate", str(path)]) == 0
    out = capsys.readouterr().out
    stretch = next(line for line in out.splitlines() if "lie off the ellipsoid" in line)
    ranges = [(int(a), int(b)) for a, b in re.findall(r"(\d+)–(\d+) \(up to", stretch)]
    assert ranges and all(1195 <= a <= b <= 1245 for a, b in ranges), stretch
    lines = ", ".join(f"{line_numbers[a]}–{line_numbers[b]}" for a, b in ranges)
    assert f"(file lines {lines}) lie off the ellipsoid" in stretch, stretch


# ------------------------------------------------------------------ M2 and C8 on the airborne recording

def test_airborne_vector_fit_names_its_reference_columns_and_what_identifiable_is_judged_on(capsys, real_data):
    """C8: the vector fit's columns line read `magnetometer mx,my,mz; time t`; it now names the attitude and field
    columns it took the reference from. M2: "identifiable yes" beside Newey–West-widened standard errors says
    what it is judged on."""
    assert main(["calibrate", str(real_data / "airborne_flt1002_02.tsv")]) == 0
    out = capsys.readouterr().out
    assert out.splitlines()[0] == ("columns: magnetometer mx,my,mz; time t; reference attitude pitch,roll,yaw (deg), "
                                   "aerospace convention, with local field igrf_n,igrf_e,igrf_d (nT)"), out
    assert ("identifiable          yes   (judged on the Fisher information of independent readings; the std errors "
            "above are widened for readings correlated in time)") in out, out
    assert main(["calibrate", str(real_data / "airborne_flt1002_02.tsv"), "--method", "als"]) == 0
    assert "reference" not in capsys.readouterr().out.splitlines()[0]  # a magnitude fit takes none


def test_identifiable_is_bare_when_the_errors_are_not_widened(tmp_path, capsys):
    """Independent orientations (`fluxcal simulate`): no widening, nothing to explain."""
    path = tmp_path / "sim.csv"
    assert main(["simulate", "-o", str(path), "--n", "400"]) == 0
    assert main(["calibrate", str(path)]) == 0
    out = capsys.readouterr().out
    assert "  identifiable          yes\n" in out, out


def test_the_columns_line_names_the_reference_columns_given(tmp_path, capsys):
    """--reference's three columns appear on the columns line, with their unit."""
    rng = np.random.default_rng(5)
    r = rng.standard_normal((300, 3))
    r = 48.0 * r / np.linalg.norm(r, axis=1, keepdims=True)
    m = r @ np.array([[1.05, 0.02, 0.0], [0.0, 0.97, 0.03], [0.01, 0.0, 1.01]]).T + [5.0, -3.0, 2.0]
    m += 0.05 * rng.standard_normal(m.shape)
    path = write_csv(tmp_path / "ref.csv", {"mx": m[:, 0], "my": m[:, 1], "mz": m[:, 2],
                                            "bx": r[:, 0], "by": r[:, 1], "bz": r[:, 2]},
                     units={c: "uT" for c in ("mx", "my", "mz", "bx", "by", "bz")})
    assert main(["calibrate", str(path), "--reference", "bx,by,bz"]) == 0
    assert capsys.readouterr().out.splitlines()[0] == \
        "columns: magnetometer mx,my,mz; reference bx,by,bz (uT) (--reference)"


# ------------------------------------------------------------------ help texts, cable offsets

def _help(capsys, *words) -> str:
    with pytest.raises(SystemExit):
        main([*words, "--help"])
    return " ".join(capsys.readouterr().out.split())


def test_noise_sigma_help_lists_the_sources_in_the_order_the_code_takes_them(capsys):
    text = _help(capsys, "diagnose").split("--noise-sigma NOISE_SIGMA white-noise")[1].split("--candidates")[0]
    cable = [text.index(s) for s in ("repeated snapshots", "--calibration's scatter", "base fit's residuals")]
    magnetometer = [text.index(s) for s in ("third differences of the readings in time order",
                                            "of the base model's residuals", "quantization floor")]
    assert cable == sorted(cable) and magnetometer == sorted(magnetometer) and cable[-1] < magnetometer[0], text


def test_cable_simulate_repeats_applies_with_calibration_only_as_its_help_says(tmp_path, capsys):
    """The help says so, and it is so: without --calibration, --repeats changes nothing in the recording."""
    assert "with --calibration only" in _help(capsys, "cable", "simulate")
    written = []
    for repeats in ("2", "7"):
        path = tmp_path / f"ring{repeats}.csv"
        assert main(["cable", "simulate", "-o", str(path), "--rotations", "0,90", "--repeats", repeats]) == 0
        written.append(path.read_text())
    assert written[0] == written[1]
    assert main(["cable", "simulate", "-o", str(tmp_path / "c2.csv"), "--calibration", "--repeats", "2"]) == 0
    assert "wrote" in capsys.readouterr().out and (tmp_path / "c2.csv").read_text() != written[0]


def test_cable_calibrate_prints_the_offsets_in_a_readable_unit(tmp_path, capsys):
    """The offsets printed as `5.183e-07 T`: now in nT (tenths of µT), as the calibration JSON holds them × 1e9."""
    ring, cal = tmp_path / "ring.csv", tmp_path / "ringcal.json"
    assert main(["cable", "simulate", "--calibration", "-o", str(ring)]) == 0
    assert main(["cable", "calibrate", str(ring), "-o", str(cal)]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("sensor ")]
    offsets = np.array(json.loads(cal.read_text())["offsets"])
    assert len(lines) == len(offsets) and all(" nT, gain " in line and "e-0" not in line for line in lines), lines
    printed = np.array([[float(v) for v in line.split("offset ")[1].split(" nT")[0].split()] for line in lines])
    np.testing.assert_allclose(printed, offsets * 1e9, rtol=1e-3)
