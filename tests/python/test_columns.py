"""Columns named the way loggers name them (MagX, mag_x_uT, TimeUS, Temperature (°F), AccX) are
recognised, converted, reported, and used by calibrate and diagnose; ambiguity is an error."""
import json

import numpy as np
import pytest
from conftest import run_cli, simulated

import fluxcal
from fluxcal.io.columns import find_accelerometer, find_current, find_magnetometer, find_temperature, find_time
from fluxcal.sim.withheld import withheld_trial


@pytest.mark.parametrize("names, expected", [
    (["t", "mag_x", "mag_y", "mag_z"], ("mag_x", "mag_y", "mag_z")),
    (["MagX", "MagY", "MagZ", "GyrX", "GyrY", "GyrZ"], ("MagX", "MagY", "MagZ")),
    (["Bx", "By", "Bz"], ("Bx", "By", "Bz")),
    (["x_mag", "y_mag", "z_mag"], ("x_mag", "y_mag", "z_mag")),
    (["magnetometer_ga[0]", "magnetometer_ga[1]", "magnetometer_ga[2]"],
     ("magnetometer_ga[0]", "magnetometer_ga[1]", "magnetometer_ga[2]")),
    (["MagneticFieldX", "MagneticFieldY", "MagneticFieldZ"], ("MagneticFieldX", "MagneticFieldY", "MagneticFieldZ")),
    (["X", "Y", "Z"], ("X", "Y", "Z")),
    # raw beside calibrated: the raw triple
    (["mag_x_uT", "mag_y_uT", "mag_z_uT", "mag_cal_x", "mag_cal_y", "mag_cal_z"], ("mag_x_uT", "mag_y_uT", "mag_z_uT")),
    (["mag_raw_x", "mag_raw_y", "mag_raw_z", "mag_x", "mag_y", "mag_z"], ("mag_raw_x", "mag_raw_y", "mag_raw_z")),
    # iOS SensorLog: the raw magnetometer beside Core Motion's calibrated field
    (["magnetometerX(µT)", "magnetometerY(µT)", "magnetometerZ(µT)", "motionMagneticFieldX(µT)",
      "motionMagneticFieldY(µT)", "motionMagneticFieldZ(µT)"],
     ("magnetometerX(µT)", "magnetometerY(µT)", "magnetometerZ(µT)")),
    # PX4 1.10's sensor_mag: x,y,z are the driver's calibrated field, x_raw.. the raw readings
    (["timestamp", "device_id", "x", "y", "z", "temperature", "x_raw", "y_raw", "z_raw"], ("x_raw", "y_raw", "z_raw")),
    # named only by an axis and a field unit: the unit says it is a field (no magnetometer found before)
    (["x_uT", "y_uT", "z_uT"], ("x_uT", "y_uT", "z_uT")),
    (["x", "y", "z", "X (uT)", "Y (uT)", "Z (uT)"], ("X (uT)", "Y (uT)", "Z (uT)")),
    # ... only when no triple names a magnetometer: a reference beside the sensor is not a second sensor
    (["mag_x_nT", "mag_y_nT", "mag_z_nT", "igrf_x_nT", "igrf_y_nT", "igrf_z_nT"], ("mag_x_nT", "mag_y_nT", "mag_z_nT")),
    (["mx", "my", "mz", "ref_x_uT", "ref_y_uT", "ref_z_uT"], ("mx", "my", "mz")),
    # a phone app's export in the app's language (phyphox: "Magnetfeld x (µT)"); an accent splits "magnético"
    (["Zeit", "Magnetfeld x", "Magnetfeld y", "Magnetfeld z"], ("Magnetfeld x", "Magnetfeld y", "Magnetfeld z")),
    (["Tempo", "Campo magnético x", "Campo magnético y", "Campo magnético z"],
     ("Campo magnético x", "Campo magnético y", "Campo magnético z")),
    (["Tijd", "Magnetisch veld x", "Magnetisch veld y", "Magnetisch veld z"],
     ("Magnetisch veld x", "Magnetisch veld y", "Magnetisch veld z")),
    (["Czas", "Pole magnetyczne x", "Pole magnetyczne y", "Pole magnetyczne z"],
     ("Pole magnetyczne x", "Pole magnetyczne y", "Pole magnetyczne z")),
    (["x_g", "y_g", "z_g"], None),  # g and mg are accelerations too: not guessed
    (["x_mg", "y_mg", "z_mg"], None),
    # not a magnetometer
    (["ax", "ay", "az", "gx", "gy", "gz"], None),
    (["gyro_x", "gyro_y", "gyro_z"], None),
    (["mag_x", "mag_y"], None),
])
def test_magnetometer_triples(names, expected):
    assert find_magnetometer(names) == expected


def test_two_compasses_is_an_error_listing_both():
    with pytest.raises(ValueError, match=r"several magnetometer column triples \(mag1_x,mag1_y,mag1_z; "
                                         r"mag2_x,mag2_y,mag2_z\); choose one with --columns"):
        find_magnetometer(["mag1_x", "mag1_y", "mag1_z", "mag2_x", "mag2_y", "mag2_z"])


def test_time_temperature_and_accelerometer_names():
    assert find_time(["TimeUS", "MagX"], {}) == ("TimeUS", 1e-6)
    for word in ("Zeit", "Tiempo", "Tempo", "Tijd", "Czas"):  # phyphox's time column in five languages
        assert find_time([word, "Magnetfeld x"], {word: "s"}) == (word, 1.0)
    assert find_time(["time_ms"], {}) == ("time_ms", 1e-3)
    assert find_time(["timeus"], {}) == ("timeus", 1e-6)  # lower case, one word
    assert find_time(["timestamp"], {"timestamp": "us"}) == ("timestamp", 1e-6)
    assert find_time(["elapsed"], {"elapsed": "ms"}) == ("elapsed", 1e-3)  # the header unit wins
    assert find_time(["T", "mx"], {}) is None  # a lone T is not guessed
    assert find_time(["millis", "mx"], {}) == ("millis", 1e-3)  # Arduino's millis() / micros()
    assert find_time(["micros", "mx"], {}) == ("micros", 1e-6)
    assert find_time(["ms", "magX"], {}) == ("ms", 1e-3)  # named only by its unit
    assert find_time(["s", "mx"], {}) is None  # a lone s is not guessed either
    assert find_time(["ts", "mx"], {}) == ("ts", 1.0)  # a time stamp's usual short name
    assert find_time(["ts_ms", "mx"], {}) == ("ts_ms", 1e-3)
    epoch = {"time": np.array([1.7e18, 1.70000000002e18])}  # Unix time too large for seconds: its size says
    assert find_time(["time"], {}, epoch) == ("time", 1e-9)  # ns (Android's Sensor Logger)
    assert find_time(["time"], {}, {"time": epoch["time"] / 1e6}) == ("time", 1e-3)
    assert find_time(["time"], {}, {"time": np.array([1.7e9, 1.7e9 + 0.02])}) == ("time", 1.0)  # seconds
    # Sensor Logger writes epoch nanoseconds as "time" beside "seconds_elapsed": one clock, the first taken
    # (no time at all before). Two clocks that step differently are not guessed.
    steps = np.array([0.0, 0.01, 0.02, 0.0301])
    logger = {"time": 1.7e18 + 1e9 * steps, "seconds_elapsed": 3.5 + steps}
    assert find_time(["time", "seconds_elapsed"], {}, logger) == ("time", 1e-9)
    assert find_time(["seconds_elapsed", "time"], {}, logger) == ("seconds_elapsed", 1.0)
    assert find_time(["time", "seconds_elapsed"], {}, {**logger, "seconds_elapsed": 2 * steps}) is None
    assert find_time(["time", "seconds_elapsed"], {}) is None  # without the values nothing says they agree
    assert find_temperature(["die_temp_C"], {}) == ("die_temp_C", "C")
    assert find_temperature(["Temperature"], {"Temperature": "°F"}) == ("Temperature", "F")
    assert find_temperature(["temp", "temp_outside"], {}) == ("temp", "C")
    assert find_temperature(["temp_a", "temp_b"], {}) is None  # two candidates: none guessed
    # named by a sensor word and degrees only (SparkFun OpenLog Artemis's imu_degC): not found before
    assert find_temperature(["mX", "imu_degC"], {}) == ("imu_degC", "C")
    assert find_temperature(["imu_degF"], {}) == ("imu_degF", "F")
    assert find_temperature(["sensor_degC", "imu_degC"], {}) is None  # two: none guessed
    assert find_temperature(["heading_deg"], {}) is None  # degrees of an angle
    assert find_accelerometer(["AccX", "AccY", "AccZ", "MagX", "MagY", "MagZ"]) == ("AccX", "AccY", "AccZ")
    assert find_current(["current", "curr"], {}) == ("current", 1.0)
    assert find_current(["t", "motor_current_mA"], {}) == ("motor_current_mA", 1e-3)
    assert find_current(["Curr", "CurrTot", "Volt"], {}) == ("Curr", 1.0)  # CurrTot is mAh used, not a current
    assert find_current(["BatteryCurrent"], {"BatteryCurrent": "mA"}) == ("BatteryCurrent", 1e-3)
    assert find_current(["current"], {"current": "V"}) is None  # a stated unit that is not a current's
    assert find_current(["I", "phase_a", "phase_b"], {}) is None  # ArduPilot's instance I, a CT's phases
    assert find_current(["curr_a", "amps"], {}) is None  # two candidates: none guessed


def _write_logger_csv(path, t_us, m, temp_f):
    header = "TimeUS,MagX (mGauss),MagY (mGauss),MagZ (mGauss),Temperature (°F),AccX,AccY,AccZ"
    rows = [f"{t:.0f},{a!r},{b!r},{c!r},{f!r},0,0,9.81" for t, (a, b, c), f in zip(t_us, m.tolist(), temp_f.tolist())]
    path.write_text(header + "\n" + "\n".join(rows) + "\n")
    return path


def test_logger_names_read_converted_and_calibrated(tmp_path):
    rng = np.random.default_rng(5)
    truth_offset = np.array([120.0, -80.0, 40.0])
    dirs = rng.normal(size=(800, 3))
    h = 500.0 * dirs / np.linalg.norm(dirs, axis=1)[:, None]
    m = h * [1.05, 0.97, 1.0] + truth_offset + rng.normal(scale=1.0, size=h.shape)
    t_us = np.arange(800) * 20000.0
    temp_f = 68.0 + np.linspace(0, 18, 800)
    path = _write_logger_csv(tmp_path / "log.csv", t_us, m, temp_f)
    rec = fluxcal.read_recording(path)
    assert rec.mag_names() == ("MagX", "MagY", "MagZ") and rec.field_units() == "mG"  # one spelling per unit
    assert rec.time()[1] == pytest.approx(0.02)
    assert rec.temperature()[[0, -1]] == pytest.approx([20.0, 30.0])
    assert rec.acceleration().shape == (800, 3)
    out = run_cli("calibrate", str(path), "-o", str(tmp_path / "cal.json"))
    assert out.returncode == 0, out.stderr
    assert "columns: magnetometer MagX,MagY,MagZ; time TimeUS (×1e-06 → s); temperature Temperature (F → °C)" \
        in out.stdout
    cal = json.loads((tmp_path / "cal.json").read_text())
    assert np.allclose(cal["offset"], truth_offset, atol=1.0)


def test_diagnose_finds_temperature_effect_under_a_logger_name(tmp_path):
    """A temperature offset the diagnosis can only find if it recognises `Temperature (K)` as temperature
    (column `temp` is absent) and converts K to °C; the same file with the column renamed to something
    unrecognisable leaves temp_offset untried."""
    result, kwargs = withheld_trial(["temp_offset"], 11)
    m = result.readings
    lines = [f"{t!r},{a!r},{b!r},{c!r},{k!r}" for t, (a, b, c), k in zip(result.t.tolist(), m.tolist(),
                                                                       (kwargs["temp"] + 273.15).tolist())]
    good = tmp_path / "named.csv"
    good.write_text("time_s,mag_x,mag_y,mag_z,Temperature (K)\n" + "\n".join(lines) + "\n")
    out = run_cli("diagnose", str(good), "--json", str(tmp_path / "d.json"), "--quiet")
    assert out.returncode == 0, out.stderr
    assert "temperature Temperature (K → °C)" in out.stdout
    top = json.loads((tmp_path / "d.json").read_text())["ranking"][0]
    assert top["effect"] == "temp_offset" and top["significant"]

    hidden = tmp_path / "unnamed.csv"
    hidden.write_text("time_s,mag_x,mag_y,mag_z,channel5\n" + "\n".join(lines) + "\n")
    out = run_cli("diagnose", str(hidden), "--json", str(tmp_path / "h.json"), "--quiet")
    assert out.returncode == 0, out.stderr
    tried = {r["effect"] for r in json.loads((tmp_path / "h.json").read_text())["ranking"]}
    assert "temp_offset" not in tried


def _stamped_log(tmp_path, garble: bool):
    """ISO timestamps, a status text column, the magnetometer in µT; optionally three garbled lines."""
    rng = np.random.default_rng(9)
    dirs = rng.normal(size=(600, 3))
    m = 48.0 * dirs / np.linalg.norm(dirs, axis=1)[:, None] + [3.0, -2.0, 1.0] + rng.normal(scale=0.05, size=(600, 3))
    lines = ["datetime,status,mag_x_uT,mag_y_uT,mag_z_uT"]
    for k, (a, b, c) in enumerate(m.tolist()):
        stamp = f"2026-11-23T10:{k // 3000:02d}:{(k * 0.02) % 60:06.3f}Z"
        lines.append(f"{stamp},{'OK' if k % 50 else 'WARN'},{a!r},{b!r},{c!r}")
    if garble:
        lines[101] = lines[101].replace(",", ";", 1)           # one field short
        lines[202] = lines[202][:-4] + "#?x"                   # garbage in mag_z
        lines[303] = "2026-11-2?" + lines[303][24:]             # a broken timestamp
    path = tmp_path / ("garbled.csv" if garble else "stamped.csv")
    path.write_text("\n".join(lines) + "\n")
    return path, m


def test_timestamp_and_text_columns(tmp_path):
    path, m = _stamped_log(tmp_path, garble=False)
    rec = fluxcal.read_recording(path)
    assert rec.units["datetime"] == "s" and rec.metadata["datetime_start"].startswith("2026-11-23T10:00:00")
    assert rec.time()[[1, 599]] == pytest.approx([0.02, 11.98])
    assert "status (e.g. OK, WARN)" in rec.metadata["text_columns"] and "status" not in rec.columns
    assert np.array_equal(rec.samples(), m) and rec.field_units() == "uT"


def test_bad_lines_error_names_the_line_or_are_skipped_and_listed(tmp_path):
    path, m = _stamped_log(tmp_path, garble=True)
    with pytest.raises(ValueError, match=r"garbled.csv, line 102: 4 fields, the header has 5.*--bad-lines skip"):
        fluxcal.read_recording(path)
    rec = fluxcal.read_recording(path, bad_lines="skip")
    assert rec.metadata["skipped_lines"].startswith("3 of 600: 102 (4 fields")
    assert "203 (column 'mag_z_uT': " in rec.metadata["skipped_lines"]
    assert "304 (column 'datetime': '2026-11-2?" in rec.metadata["skipped_lines"]
    keep = np.setdiff1d(np.arange(600), [100, 201, 302])
    assert np.array_equal(rec.samples(), m[keep]) and np.array_equal(rec.line_numbers, keep + 2)
    out = run_cli("calibrate", str(path), "--bad-lines", "skip")
    assert out.returncode == 0, out.stderr
    assert "skipped 3 of 600 lines: 102 (4 fields" in out.stdout
    out = run_cli("calibrate", str(path))
    assert out.returncode != 0 and "line 102: 4 fields" in out.stderr


def test_time_from_a_stated_sample_rate(tmp_path):
    path = tmp_path / "rate.csv"
    path.write_text("# sample rate: 25 Hz\nmag_x,mag_y,mag_z\n1,2,3\n4,5,6\n7,8,9\n")
    rec = fluxcal.read_recording(path)
    assert rec.time() == pytest.approx([0.0, 0.04, 0.08])
    assert rec.roles()["time"] == "row / 25 Hz (metadata sample rate)"
    path.write_text("# sensor: RM3100\nmag_x,mag_y,mag_z\n1,2,3\n")
    assert fluxcal.read_recording(path).time() is None


@pytest.mark.parametrize("names, expected", [
    # qualifiers after the axis (found by review): raw wins over calibrated
    (["MagX", "MagY", "MagZ", "MagXRaw", "MagYRaw", "MagZRaw"], ("MagXRaw", "MagYRaw", "MagZRaw")),
    (["mag_x_raw", "mag_y_raw", "mag_z_raw", "mag_x", "mag_y", "mag_z"], ("mag_x_raw", "mag_y_raw", "mag_z_raw")),
    (["mx_raw", "my_raw", "mz_raw"], ("mx_raw", "my_raw", "mz_raw")),
    # an accelerometer or gyro is never the magnetometer
    (["accelerometer_m_s2[0]", "accelerometer_m_s2[1]", "accelerometer_m_s2[2]", "gyro_rad[0]", "gyro_rad[1]",
      "gyro_rad[2]"], None),
    (["acc_b_x", "acc_b_y", "acc_b_z", "x", "y", "z"], ("x", "y", "z")),
    # the Greek mu typed for the micro sign; axes numbered from 1 (left open by the last review)
    (["mag_x_\u03bcT", "mag_y_\u03bcT", "mag_z_\u03bcT"], ("mag_x_\u03bcT", "mag_y_\u03bcT", "mag_z_\u03bcT")),
    (["t", "mag_1", "mag_2", "mag_3"], ("mag_1", "mag_2", "mag_3")),
    (["Mag1", "Mag2", "Mag3", "Acc1", "Acc2", "Acc3"], ("Mag1", "Mag2", "Mag3")),
    (["mag[0]", "mag[1]", "mag[2]", "mag[3]"], ("mag[0]", "mag[1]", "mag[2]")),  # 0-based wins
    (["mag_1", "mag_2"], None),
    # numbered channels rank below x/y/z names, and single letters numbered from 1 are not axes
    (["Mag1", "Mag2", "Mag3", "flux_x", "flux_y", "flux_z"], ("flux_x", "flux_y", "flux_z")),
    (["field_1", "field_2", "field_3", "mag_x", "mag_y", "mag_z"], ("mag_x", "mag_y", "mag_z")),
    (["h1", "h2", "h3"], None),
])
def test_review_cases_for_triples(names, expected):
    assert find_magnetometer(names) == expected


def test_review_cases_for_units_and_headers(tmp_path):
    from fluxcal.io.columns import field_unit_of

    assert field_unit_of("mag_x_\u03bcT") == "uT"
    assert find_time(["time_\u03bcs"], {}) == ("time_\u03bcs", 1e-6)
    assert find_time(["Time"], {"Time": "min"}) == ("Time", 60.0)
    assert find_time(["time"], {"time": "ticks"}) is None          # an unknown unit is not guessed
    assert find_temperature(["Temp"], {"Temp": "mdegC"}) is None
    px4 = {"timestamp": np.arange(5) * 20000.0}                      # PX4 CSV: µs without a unit
    assert find_time(["timestamp"], {}, px4) == ("timestamp", 1e-6)
    cases = {"ulog2csv": "magnetometer_ga[0],magnetometer_ga[1],magnetometer_ga[2]\n1,2,3\n4,5,6\n",
             "trailing_comma": "mx,my,mz,\n1,2,3,\n4,5,6,\n",
             "quoted": '"mx","my","mz"\n"1","2","3"\n"4","5","6"\n',
             "status_with_numbers": "status,mx,my,mz\nOK,1,2,3\n1,4,5,6\nOK,7,8,9\nOK,1,1,1\n"}
    for name, text in cases.items():
        path = tmp_path / f"{name}.csv"
        path.write_text(text)
        assert fluxcal.read_recording(path).samples()[:2].tolist() == [[1, 2, 3], [4, 5, 6]], name
    path = tmp_path / "garbled_first.csv"
    path.write_text("mx,my,mz\ngarbage\n1,2,3\n4,5,6\n")
    with pytest.raises(ValueError, match="line 2: 1 fields, the header has 3"):
        fluxcal.read_recording(path)
    assert fluxcal.read_recording(path, bad_lines="skip").samples().shape == (2, 3)


def test_review_cases_for_timestamps(tmp_path):
    from fluxcal.io.csv import _timestamps

    day_first, _ = _timestamps(["12/11/2026 23:59:59", "13/11/2026 00:00:00", "13/11/2026 00:00:01"])
    assert day_first.tolist() == [0.0, 1.0, 2.0]
    past_midnight, start = _timestamps(["23:59:59.5", "00:00:00.0", "00:00:00.5"])
    assert past_midnight.tolist() == [0.0, 0.5, 1.0] and start == "23:59:59.500000"  # no date: none made up
    offsets, first = _timestamps(["2026-11-23T10:00:00+01:00", "2026-11-23T09:00:01Z"])
    assert offsets.tolist() == [0.0, 1.0] and first.startswith("2026-11-23T09:00:00")
    for labels in (["T1", "T2", "T3"], ["3-1", "3-2", "4-1"], ["Jan", "Feb", "Mar"]):
        assert _timestamps(labels) == (None, None)


def test_sample_and_hold_below_twice_the_rate():
    from fluxcal._arrays import held_copies

    rng = np.random.default_rng(0)
    readings = rng.normal(size=(2300, 3))
    logged = readings[np.floor(np.arange(3000) * 75 / 100).astype(int)]   # 75 Hz sensor, 100 Hz logger
    assert held_copies(logged).mean() == pytest.approx(0.25)
    assert held_copies(np.repeat(readings[:24], 100, axis=0)) is None      # a static device's long runs


def test_unit_name_normalises_unit_words():
    """One place names a unit word the recording's way (the serial recorder's stated and printed units)."""
    from fluxcal.io.columns import unit_name

    assert [unit_name(w) for w in ("uTesla", "µT", "\u03bcT", " [uT] ", "(nT)", "Gauss", "Ga", "tesla", "mgauss")] \
        == ["uT", "uT", "uT", "uT", "nT", "G", "G", "T", "mG"]
    assert unit_name(" counts ") == "counts" and unit_name("m/s^2") == "m/s^2"  # others as given


def test_axes_named_only_as_axes_are_a_magnetometer_when_their_unit_is_a_fields(tmp_path):
    """MbientLab's MetaBase export names the axes `x-axis (T)`; its accelerometer file says `x-axis (g)`."""
    m = simulated(1, n=400, field_norm=50.0).readings * 1e-6  # µT → T
    t = np.arange(len(m)) * 0.04
    header = "epoch (ms),time (-05:00),elapsed (s),x-axis ({u}),y-axis ({u}),z-axis ({u})\n"
    rows = "".join(f"{1709305200000 + int(round(s * 1000))},2024-03-01T10.00.{s:06.3f},{s:.3f},"
                   f"{x:.9g},{y:.9g},{z:.9g}\n" for s, (x, y, z) in zip(t, m))
    (tmp_path / "mag.csv").write_text(header.format(u="T") + rows)
    rec = fluxcal.read_recording(tmp_path / "mag.csv")
    assert rec.mag_names() == ("x-axis", "y-axis", "z-axis") and rec.field_units() == "T"
    np.testing.assert_allclose(rec.time(), t, atol=1e-9)
    (tmp_path / "acc.csv").write_text(header.format(u="g") + rows)
    with pytest.raises(ValueError, match="no magnetometer columns"):
        fluxcal.read_recording(tmp_path / "acc.csv").samples()


def test_the_magnetometers_own_clock_and_an_rtc_time_of_day(tmp_path):
    """iOS SensorLog writes a clock per sensor (…Timestamp_sinceReboot(s)) beside its logging time: the
    magnetometer's own is the time. SparkFun's OpenLog Artemis writes rtcDate,rtcTime: the time of day."""
    t = np.arange(50) * 0.01
    m = np.random.default_rng(0).normal(size=(50, 3)) * 40
    head = ("loggingTime(txt),accelerometerTimestamp_sinceReboot(s),accelerometerAccelerationX(G),"
            "accelerometerAccelerationY(G),accelerometerAccelerationZ(G),magnetometerTimestamp_sinceReboot(s),"
            "magnetometerX(µT),magnetometerY(µT),magnetometerZ(µT)\n")
    rows = "".join(f"2025-12-29T13:13:{6 + s:06.3f}-06:00,{5000.1 + s:.4f},0.1,0.2,0.9,{5000.1037 + 1.001 * s:.4f},"
                   f"{x:.4f},{y:.4f},{z:.4f}\n" for s, (x, y, z) in zip(t, m))
    (tmp_path / "sensorlog.csv").write_text(head + rows, encoding="utf-8")
    rec = fluxcal.read_recording(tmp_path / "sensorlog.csv")
    assert rec.roles()["time"] == "magnetometerTimestamp_sinceReboot"
    np.testing.assert_allclose(rec.time(), 5000.1037 + 1.001 * t, atol=1e-9)
    rows = "".join(f"07/01/2000,12:34:{56 + s:05.2f},{x:.2f},{y:.2f},{z:.2f},24.00,25.000,\n"
                   for s, (x, y, z) in zip(t, m))
    (tmp_path / "openlog.txt").write_text("rtcDate,rtcTime,mX,mY,mZ,imu_degC,output_Hz,\n" + rows)
    rec = fluxcal.read_recording(tmp_path / "openlog.txt")
    assert rec.roles()["time"] == "rtcTime" and rec.roles()["temperature"] == "imu_degC"
    np.testing.assert_allclose(rec.time(), t, atol=1e-9)


def test_a_reference_field_spelled_like_the_magnetometer_is_one_unit():
    """µT on both: once the magnetometer's unit is named uT, the IGRF columns' µT must be read as the same unit
    (a review found "the field columns are in µT, the magnetometer in uT")."""
    n = 5
    columns = {**{c: np.ones(n) for c in ("mx", "my", "mz", "igrf_n", "igrf_e", "igrf_d")},
               **{c: np.zeros(n) for c in ("pitch", "roll", "yaw")}}
    rec = fluxcal.Recording(columns=columns, units={c: "µT" for c in ("mx", "my", "mz", "igrf_n", "igrf_e", "igrf_d")})
    assert rec.field_units() == rec.reference_units() == "uT"
