"""Flight-controller logs: ArduPilot DataFlash (.bin and text .log) and PX4 ULog (.ulg), built here byte
by byte from the published formats around a simulated compass with a known hard and soft iron, read back
through fluxcal.read_recording (pymavlink / pyulog underneath). The readings, units, times, attitude
and instances come back as written; fluxcal.calibrate recovers the known offset; damaged logs and
wrong choices are ValueErrors naming the file, and a log cut off inside its last message keeps its
complete messages with a warning."""
import struct
import warnings

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import fluxcal
from conftest import run_cli
from fluxcal import attitude, sim
from fluxcal.io import read_recording, sniff

FIELD_NED_MG = np.array([200.0, 10.0, 450.0])  # a mid-latitude field, milligauss
BOOT_US = 5_000_000  # logging starts 5 s after boot


def simulate(seed, field, n_seconds=40.0, rate_hz=25.0, noise=0.004):
    """Readings of a random sensor (soft iron ±20 %, offset ≤ 50 % of |field|) turned smoothly through
    every orientation; the scene's rotations are body → NED, so they are the attitude of the vehicle."""
    rng = np.random.default_rng(seed)
    scene = sim.tumble(n_seconds, rate_hz=rate_hz, temperature=None, rng=rng)
    norm = float(np.linalg.norm(field))
    result = sim.simulate(scene, sim.random_sensor(norm, rng, noise=noise), field, rng)
    return scene, result


# -- ArduPilot DataFlash, written per the format: every message A3 95 <type> <fields>, FMT messages
#    (type 128, 89 bytes) describe the others; UNIT / MULT / FMTU give the units --------------------------

_PACK = {"b": "b", "B": "B", "h": "h", "H": "H", "i": "i", "I": "I", "f": "f", "d": "d", "n": "4s",
         "N": "16s", "Z": "64s", "c": "h", "C": "H", "e": "i", "E": "I", "L": "i", "M": "b", "q": "q", "Q": "Q"}
_SCALED = {"c": 100, "C": 100, "e": 100, "E": 100, "L": 1e7}  # stored as integer hundredths (1e-7 deg for L)


class DataFlash:
    """Collects messages, then writes them as a binary .bin or as a text .log."""

    def __init__(self):
        self.formats, self.messages = {}, []
        self.define(128, "FMT", "BBnNZ", "Type,Length,Name,Format,Columns")

    def define(self, mtype, name, fmt, columns):
        body = struct.Struct("<" + "".join(_PACK[c] for c in fmt))
        self.formats[name] = (mtype, fmt, body)
        self.add("FMT", mtype, 3 + body.size, name, fmt, columns)

    def add(self, name, *values):
        self.messages.append((name, values))

    def binary(self) -> bytes:
        out = []
        for name, values in self.messages:
            mtype, fmt, body = self.formats[name]
            packed = [v.encode() if isinstance(v, str) else round(v * _SCALED[c]) if c in _SCALED else v
                      for c, v in zip(fmt, values)]
            out.append(b"\xa3\x95" + bytes([mtype]) + body.pack(*packed))
        return b"".join(out)

    def text(self) -> str:
        lines = []
        for name, values in self.messages:
            fmt = self.formats[name][1]
            cells = [f"{v:.2f}" if c in "cCeE" else f"{v:.7f}" if c == "L" else str(v) for c, v in zip(fmt, values)]
            lines.append(", ".join([name, *cells]))
        return "\n".join(lines) + "\n"


def ardupilot_header(log: DataFlash, params: dict, mag_style="current", version=True):
    log.define(129, "UNIT", "QbZ", "TimeUS,Id,Label")
    log.define(130, "MULT", "Qbd", "TimeUS,Id,Mult")
    log.define(131, "FMTU", "QBNN", "TimeUS,FmtType,UnitIds,MultIds")
    log.define(132, "PARM", "QNf", "TimeUS,Name,Value")
    log.define(133, "VER", "QBHBBBBIZH", "TimeUS,BT,BST,Maj,Min,Pat,FWT,GH,FWS,APJ")
    log.define(134, "MSG", "QZ", "TimeUS,Message")
    log.define(135, "ATT", "QccccCCCCB", "TimeUS,DesRoll,Roll,DesPitch,Pitch,DesYaw,Yaw,ErrRP,ErrYaw,AEKF")
    log.define(139, "BAT", "QBfff", "TimeUS,Inst,Volt,Curr,CurrTot")
    if mag_style == "current":  # one MAG message, instance in I (ArduPilot 4.x)
        log.define(136, "MAG", "QBhhhhhhhhhBI", "TimeUS,I,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOX,MOY,MOZ,Health,S")
    else:  # one message per compass, no units (ArduPilot 3.x)
        for k, name in enumerate(("MAG", "MAG2")):
            log.define(136 + k, name, "Qhhhhhhhhh", "TimeUS,MagX,MagY,MagZ,OfsX,OfsY,OfsZ,MOfsX,MOfsY,MOfsZ")
    if mag_style == "current":
        for unit_id, label in (("s", "s"), ("G", "Gauss"), ("#", "instance"), ("-", ""), ("d", "deg")):
            log.add("UNIT", 0, ord(unit_id), label)
        for mult_id, mult in (("F", 1e-6), ("C", 1e-3), ("-", 0.0), ("B", 1e-2)):
            log.add("MULT", 0, ord(mult_id), mult)
        log.add("FMTU", 0, 136, "s#GGGGGGGGG-s", "F-CCCCCCCCC-F")
        log.add("FMTU", 0, 135, "sdddddd---", "F---------")
    if version:
        log.add("VER", 0, 3, 0, 4, 5, 7, 255, 0x2A3DC4B7, "ArduCopter V4.5.7 (2a3dc4b7)", 1063)
    log.add("MSG", 0, "ArduCopter V4.5.7 (2a3dc4b7)")
    log.add("MSG", 0, "ChibiOS: 6a85082c")
    for name, value in params.items():
        log.add("PARM", 0, name, value)


def attitude_of(rotations):
    """ATT Roll, Pitch, Yaw (deg, yaw 0..360) of body → NED rotations."""
    yaw, pitch, roll = rotations.as_euler("ZYX", degrees=True).T
    return roll, pitch, np.mod(yaw, 360.0)


def int16(values):
    return [int(v) for v in np.round(values)]


@pytest.fixture(scope="module")
def ardupilot():
    """A two-compass ArduPilot log. Compass 0: uncalibrated (offsets 0, no motor compensation), so MagX..Z
    are its raw readings. Compass 1: ArduPilot had already applied offsets, a soft-iron matrix and motor
    compensation, MagX = M·(raw + Ofs) + MO. ATT is logged half a sample after each MAG."""
    scene, first = simulate(11, FIELD_NED_MG)
    _, second = simulate(12, FIELD_NED_MG)
    n = len(scene.t)
    time_us = BOOT_US + np.round(scene.t * 1e6).astype(np.int64)
    ofs1 = np.array([35.0, -60.0, 20.0])
    dia1, odi1 = np.array([1.04, 0.97, 1.01]), np.array([0.02, 0.0, -0.015])
    m1 = np.array([[dia1[0], odi1[0], odi1[1]], [odi1[0], dia1[1], odi1[2]], [odi1[1], odi1[2], dia1[2]]])
    throttle = 0.5 + 0.4 * np.sin(np.arange(n) / 30.0)
    mot1 = np.outer(throttle, [6.0, -4.0, 9.0])
    logged1 = (m1 @ (second.readings + ofs1).T).T + mot1
    params = {"COMPASS_OFS_X": 0.0, "COMPASS_OFS_Y": 0.0, "COMPASS_OFS_Z": 0.0, "COMPASS_DEV_ID": 97539.0,
              **{f"COMPASS_OFS2_{a}": v for a, v in zip("XYZ", ofs1)},
              **{f"COMPASS_DIA2_{a}": v for a, v in zip("XYZ", dia1)},
              **{f"COMPASS_ODI2_{a}": v for a, v in zip("XYZ", odi1)}, "COMPASS_SCALE2": 1.0}
    log = DataFlash()
    ardupilot_header(log, params)
    half_step = int(0.5e6 / 25.0)
    for i in range(n):
        log.add("MAG", int(time_us[i]), 0, *int16(first.readings[i]), 0, 0, 0, 0, 0, 0, 1, 0)
        log.add("MAG", int(time_us[i]), 1, *int16(logged1[i]), *int16(ofs1), *int16(mot1[i]), 1, 123400 + i)
        if i + 1 < n:  # the attitude half-way to the next reading (the midpoint rotation)
            mid = Rotation.concatenate([scene.rotations[i], scene.rotations[i + 1]]).mean()
            r, p, y = attitude_of(mid)
            log.add("ATT", int(time_us[i]) + half_step, 0.0, float(r), 0.0, float(p), 0.0, float(y), 0.0, 0.0, 0)
        if i % 5 == 1:  # two batteries at 5 Hz; the first feeds the motors
            log.add("BAT", int(time_us[i]), 0, 15.2, float(25.0 * throttle[i]), 100.0 + i)
            log.add("BAT", int(time_us[i]), 1, 5.0, 0.3, 2.0)
    return {"log": log, "scene": scene, "first": first, "second": second, "time_us": time_us, "ofs1": ofs1,
            "mot1": mot1, "current": 25.0 * throttle}


@pytest.fixture
def bin_path(ardupilot, tmp_path):
    path = tmp_path / "flight.bin"
    path.write_bytes(ardupilot["log"].binary())
    return path


def truth(result, units="mG"):
    return result.true_calibration(units=units)


def test_dataflash_binary_readings_units_times_and_calibration(ardupilot, bin_path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an intact log reports no damage
        rec = read_recording(bin_path)
    first = ardupilot["first"]
    assert sniff(bin_path) == "dataflash"
    assert rec.mag_names() == ("mx", "my", "mz") and rec.units["mx"] == "mG" and rec.field_units() == "mG"
    assert rec.units["t"] == "s" and len(rec) == len(first.readings)
    np.testing.assert_allclose(rec.columns["t"], ardupilot["time_us"] * 1e-6, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(rec.samples(), np.round(first.readings))  # int16 mG as logged
    meta = rec.metadata
    assert meta["source_format"] == "ArduPilot DataFlash binary log" and meta["instance"] == "MAG[0]"
    assert meta["instances"] == f"MAG[0] ({len(rec)} readings), MAG[1] ({len(rec)} readings)"
    assert meta["units_from"] == "the log's FMTU/UNIT messages"
    assert "not raw" in meta["readings"] and meta["offsets_applied"].startswith("yes")
    assert meta["firmware"] == "ArduCopter V4.5.7 (2a3dc4b7)" and meta["firmware_version"] == "4.5.7"
    assert meta["firmware_git_hash"] == "2a3dc4b7" and meta["firmware_os"] == "ChibiOS: 6a85082c"
    assert "COMPASS_DEV_ID=97539" in meta["compass_parameters"]
    assert "damage" not in meta
    # compass 0 had no calibration applied: calibrating its readings finds its hard and soft iron
    cal = fluxcal.calibrate(rec.samples(), units=rec.field_units())
    expected = truth(first)
    assert np.linalg.norm(cal.offset - expected.offset) < 0.01 * np.linalg.norm(FIELD_NED_MG)
    assert np.linalg.norm(expected.offset) > 0.05 * np.linalg.norm(FIELD_NED_MG)  # a real offset was found
    assert cal.units == "mG"


def test_dataflash_attitude_is_interpolated_to_the_mag_times(ardupilot, bin_path):
    rec = read_recording(bin_path)
    assert rec.units["roll"] == rec.units["pitch"] == rec.units["yaw"] == "deg"
    assert rec.metadata["attitude_convention"] == "aerospace"
    # ATT lies between the readings: the first and last readings are outside its span (no attitude)
    roll, pitch, yaw = (rec.columns[a][1:-1] for a in ("roll", "pitch", "yaw"))
    assert np.isnan(rec.columns["roll"][[0, -1]]).all() and np.isfinite(np.c_[roll, pitch, yaw]).all()
    assert ((yaw >= 0) & (yaw < 360)).all() and ((roll >= -180) & (roll < 180)).all()
    body = attitude.reference_vectors(FIELD_NED_MG, pitch, roll, yaw, degrees=True, convention="aerospace")
    error = np.linalg.norm(body - ardupilot["first"].truth[1:-1], axis=1)
    # interpolating between midpoints of a smooth turn: well under a degree (8.6 mG) almost everywhere
    assert np.median(error) < 2.0 and np.quantile(error, 0.95) < 8.6


def test_dataflash_battery_current_is_interpolated_to_the_mag_times(ardupilot, bin_path):
    # BAT Curr of the first battery (not the second, not CurrTot): the regressor of motor_current
    rec = read_recording(bin_path)
    assert rec.units["current"] == "A" and "BAT Curr" in rec.metadata["current"]
    current = rec.current()
    inside = slice(1, len(current) - 4)  # BAT every fifth reading from the second: held at the ends
    assert np.max(np.abs(current[inside] - ardupilot["current"][inside])) < 0.05  # a smooth 25 A swing
    assert current[0] == current[1] and rec.roles()["current"] == "current"


def test_dataflash_second_compass_offsets_were_already_applied(ardupilot, bin_path):
    rec = read_recording(bin_path, columns="MAG[1]")
    second, ofs1 = ardupilot["second"], ardupilot["ofs1"]
    assert rec.metadata["instance"] == "MAG[1]"
    np.testing.assert_array_equal(rec.columns["ofs_x"], np.full(len(rec), ofs1[0]))
    np.testing.assert_array_equal(rec.columns["mot_z"], np.round(ardupilot["mot1"][:, 2]))
    assert rec.units["ofs_x"] == rec.units["mot_x"] == rec.units["raw_x"] == "mG"
    raw = np.column_stack([rec.columns[f"raw_{a}"] for a in "xyz"])
    assert np.max(np.abs(raw - second.readings)) < 2.0  # int16 rounding of MagX and MOX only
    assert "COMPASS_DIA2_X..Z, COMPASS_ODI2_X..Z, COMPASS_SCALE2" in rec.metadata["raw_reconstruction"]
    # the raw readings give the sensor's own offset; the logged ones only what ArduPilot left uncorrected
    raw_rec = read_recording(bin_path, columns="MAG[1],raw_x,raw_y,raw_z")
    assert raw_rec.mag_names() == ("raw_x", "raw_y", "raw_z")
    cal_raw = fluxcal.calibrate(raw_rec.samples(), units=raw_rec.field_units())
    assert np.linalg.norm(cal_raw.offset - truth(second).offset) < 0.01 * np.linalg.norm(FIELD_NED_MG)
    logged_offset = fluxcal.calibrate(rec.samples()).offset
    assert np.linalg.norm(logged_offset - truth(second).offset) > 30.0
    # the same compass by its instance number through the Python API
    np.testing.assert_array_equal(fluxcal.io.drone.read_dataflash(bin_path, instance=1).samples(), rec.samples())


def test_dataflash_text_log_reads_as_the_binary_one(ardupilot, bin_path, tmp_path):
    text_path = tmp_path / "flight.log"
    text_path.write_text(ardupilot["log"].text())
    assert text_path.read_text().startswith("FMT, 128, 89, FMT, BBnNZ, Type,Length,Name,Format,Columns\n")
    assert sniff(text_path) == "dataflash_text"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        text, binary = read_recording(text_path, columns="MAG[1]"), read_recording(bin_path, columns="MAG[1]")
    assert text.metadata["source_format"] == "ArduPilot DataFlash text log"
    assert list(text.columns) == list(binary.columns) and text.units == binary.units
    for name in binary.columns:
        # angles go through text with two decimals, as the binary's centidegrees
        # (raw_x..z: the soft-iron parameters are float32 in the .bin, decimal in the .log)
        np.testing.assert_allclose(text.columns[name], binary.columns[name], rtol=1e-5, atol=1e-6, err_msg=name)
    assert text.metadata["firmware"] == binary.metadata["firmware"]


def test_older_logs_with_one_message_per_compass(tmp_path):
    scene, result = simulate(5, FIELD_NED_MG, n_seconds=20)
    log = DataFlash()
    ardupilot_header(log, {}, mag_style="MAG2", version=False)
    for i, t in enumerate(scene.t):
        us = BOOT_US + round(t * 1e6)
        log.add("MAG", us, *int16(result.readings[i]), 0, 0, 0, 0, 0, 0)
        log.add("MAG2", us, *int16(result.readings[i] * 2), 0, 0, 0, 1, 2, 3)
    path = tmp_path / "old.bin"
    path.write_bytes(log.binary())
    rec = read_recording(path, columns="MAG2")
    np.testing.assert_array_equal(rec.samples(), np.round(result.readings * 2))
    np.testing.assert_array_equal(rec.columns["mot_z"], np.full(len(rec), 3.0))  # MOfsZ of older logs
    assert rec.metadata["instance"] == "MAG[1] (message MAG2)" and rec.units["mx"] == "mG"
    assert "convention" in rec.metadata["units_from"]  # no FMTU/UNIT: milligauss by ArduPilot's convention
    assert "M = I, s = 1" in rec.metadata["raw_reconstruction"]
    assert rec.metadata["firmware"] == "ArduCopter V4.5.7 (2a3dc4b7)" and "firmware_version" not in rec.metadata
    np.testing.assert_array_equal(read_recording(path, columns="MAG[1]").samples(), rec.samples())
    np.testing.assert_array_equal(read_recording(path).samples(), np.round(result.readings))


def test_yaw_is_interpolated_across_north(tmp_path):
    log = DataFlash()
    ardupilot_header(log, {})
    log.add("ATT", BOOT_US, 0.0, 10.0, 0.0, -20.0, 0.0, 359.0, 0.0, 0.0, 0)
    log.add("MAG", BOOT_US + 5000, 0, 100, 200, 300, 0, 0, 0, 0, 0, 0, 1, 0)
    log.add("MAG", BOOT_US + 7500, 0, 100, 200, 300, 0, 0, 0, 0, 0, 0, 1, 0)
    log.add("ATT", BOOT_US + 10000, 0.0, 20.0, 0.0, -10.0, 0.0, 3.0, 0.0, 0.0, 0)
    path = tmp_path / "north.bin"
    path.write_bytes(log.binary())
    rec = read_recording(path)
    np.testing.assert_allclose(rec.columns["yaw"], [1.0, 2.0], atol=1e-9)  # not 181°: the short way round
    np.testing.assert_allclose(rec.columns["roll"], [15.0, 17.5], atol=1e-9)
    np.testing.assert_allclose(rec.columns["pitch"], [-15.0, -12.5], atol=1e-9)


def test_dataflash_cut_off_inside_its_last_message(ardupilot, bin_path, tmp_path):
    data = bin_path.read_bytes()
    cut = tmp_path / "cut.bin"
    cut.write_bytes(data[:-7])  # the log ends with a MAG of compass 1: that reading is lost, no other
    with pytest.warns(UserWarning, match=r"cut\.bin: the log is cut off inside its last message \(MAG, 7 bytes"):
        rec = read_recording(cut, columns="MAG[1]")
    assert "cut off" in rec.metadata["damage"]
    np.testing.assert_array_equal(rec.samples(), read_recording(bin_path, columns="MAG[1]").samples()[:-1])
    with pytest.warns(UserWarning):
        np.testing.assert_array_equal(read_recording(cut).samples(), read_recording(bin_path).samples())
    # cut before the first reading: nothing to calibrate
    cut.write_bytes(data[:data.find(b"\xa3\x95\x88") + 20])  # mid-way through the first MAG message
    with pytest.raises(ValueError, match=r"cut\.bin: no magnetometer messages \(MAG\).*no complete MAG message "
                                         r"was logged.*cut off"):
        read_recording(cut)


def test_dataflash_text_cut_off_mid_line(ardupilot, tmp_path):
    text = ardupilot["log"].text()
    path = tmp_path / "cut.log"
    last_mag = text.rfind("\nMAG, ") + 1
    path.write_text(text[:last_mag] + text[last_mag:].split("\n")[0][:-2])  # its last field (S) cut short
    whole = tmp_path / "whole.log"
    whole.write_text(text)
    with pytest.warns(UserWarning, match="no line end"):
        rec = read_recording(path, columns="MAG[1]")
    np.testing.assert_array_equal(rec.samples(), read_recording(whole, columns="MAG[1]").samples()[:-1])


def test_dataflash_damage_and_wrong_choices_are_value_errors(ardupilot, bin_path, tmp_path):
    bad = tmp_path / "garbled.bin"
    rng = np.random.default_rng(0)
    bad.write_bytes(b"\xa3\x95" + rng.integers(0, 256, 4000, dtype=np.uint8).tobytes())
    with pytest.raises(ValueError, match=r"garbled\.bin: not a readable DataFlash log: no message format \(FMT\)"):
        read_recording(bad)
    bad.write_bytes(ardupilot["log"].text().encode()[:3000] + b"\xff\xfe" + b"MAG, 1, 2\n")
    with pytest.raises(ValueError, match=r"garbled\.bin: not a readable DataFlash text log: line \d+ \(byte 3000\) "
                                         r"is not text"):
        read_recording(bad)
    no_mag = DataFlash()  # as ArduPilot writes it without a compass: MAG defined, never logged
    ardupilot_header(no_mag, {"COMPASS_USE": 0.0})
    no_mag.add("ATT", BOOT_US, 0.0, 1.0, 0.0, 2.0, 0.0, 3.0, 0.0, 0.0, 0)
    (tmp_path / "nomag.bin").write_bytes(no_mag.binary())
    with pytest.raises(ValueError, match=r"nomag\.bin: no magnetometer messages \(MAG\).*logged: ATT, MSG, PARM, "
                                         r"VER\)$"):
        read_recording(tmp_path / "nomag.bin")
    (tmp_path / "nomag.log").write_text(no_mag.text())
    with pytest.raises(ValueError, match=r"nomag\.log: no magnetometer messages"):
        read_recording(tmp_path / "nomag.log")
    with pytest.raises(ValueError, match=r"flight\.bin: no compass instance 2 \(MAG\[2\]\); the log has MAG\[0\], "
                                         r"MAG\[1\]"):
        read_recording(bin_path, columns="MAG[2]")
    with pytest.raises(ValueError, match=r"flight\.bin: .*compass instance.*three column names"):
        read_recording(bin_path, columns="sensor_mag[1]")
    with pytest.raises(ValueError, match=r"flight\.bin: no column 'MagX'"):
        read_recording(bin_path, columns="MagX,MagY,MagZ")
    text = ardupilot["log"].text().replace("MAG, 5000000, 0, ", "MAG, 5000000, 0, x", 1)
    (tmp_path / "badvalue.log").write_text(text)
    with pytest.raises(ValueError, match=r"badvalue\.log: a MAG message \(line \d+\) has a value that is not a number"):
        read_recording(tmp_path / "badvalue.log")


def test_missing_parsers_say_what_to_install(bin_path, tmp_path, monkeypatch):
    ulg = tmp_path / "x.ulg"
    ulg.write_bytes(ulog_file(topics={}, data=[]))
    monkeypatch.setitem(__import__("sys").modules, "pymavlink", None)
    monkeypatch.setitem(__import__("sys").modules, "pyulog", None)
    with pytest.raises(ValueError, match=r"flight\.bin: .*pip install 'fluxcal\[drone\]'"):
        read_recording(bin_path)
    with pytest.raises(ValueError, match=r"x\.ulg: .*pip install 'fluxcal\[drone\]'"):
        read_recording(ulg)


def test_cli_calibrates_a_dataflash_log(ardupilot, bin_path, tmp_path):
    out = tmp_path / "cal.json"
    r = run_cli("calibrate", bin_path, "-o", out)
    assert r.returncode == 0, r.stderr
    assert "offset b" in r.stdout and f"samples used          {len(ardupilot['scene'].t)}" in r.stdout
    saved = fluxcal.Calibration.load(out)
    assert saved.units == "mG" and saved.metadata["columns"] == "mx,my,mz"
    assert np.linalg.norm(saved.offset - truth(ardupilot["first"]).offset) < 0.01 * np.linalg.norm(FIELD_NED_MG)
    r = run_cli("calibrate", bin_path, "--columns", "MAG[1],raw_x,raw_y,raw_z", "-o", out)
    assert r.returncode == 0, r.stderr
    assert np.linalg.norm(fluxcal.Calibration.load(out).offset - truth(ardupilot["second"]).offset) < 5.0
    r = run_cli("calibrate", bin_path, "--columns", "MAG[7]")
    assert r.returncode == 2 and "no compass instance 7" in r.stderr and "Traceback" not in r.stderr


# -- PX4 ULog, written per the spec: 16-byte header (magic, version, start time), a flag-bits message,
#    definitions (info, format, parameter messages), then the data section (add_logged, data) -----------

# (name, format message, struct of a data message: the padding at the end of a topic is not logged)
SENSOR_MAG = ("sensor_mag", "uint64_t timestamp;uint64_t timestamp_sample;uint32_t device_id;float x;float y;"
              "float z;float temperature;uint32_t error_count;", "<QQIffffI")
VEHICLE_MAG = ("vehicle_magnetometer", "uint64_t timestamp;uint64_t timestamp_sample;uint32_t device_id;"
               "float[3] magnetometer_ga;uint8_t calibration_count;uint8_t[3] _padding0;", "<QQIfffB")
VEHICLE_ATTITUDE = ("vehicle_attitude", "uint64_t timestamp;uint64_t timestamp_sample;float[4] q;"
                    "float[4] delta_q_reset;uint8_t quat_reset_counter;uint8_t[7] _padding0;", "<QQffffffffB")
BATTERY_STATUS = ("battery_status", "uint64_t timestamp;float voltage_v;float current_a;float discharged_mah;",
                  "<Qfff")


def _ulog_message(kind: str, payload: bytes) -> bytes:
    return struct.pack("<HB", len(payload), ord(kind)) + payload


def _ulog_keyed(type_name: str, key: str, value: bytes) -> bytes:
    name = f"{type_name} {key}".encode()
    return bytes([len(name)]) + name + value


def ulog_file(topics: dict, data: list, info=None, params=None,
              formats=(SENSOR_MAG, VEHICLE_MAG, VEHICLE_ATTITUDE, BATTERY_STATUS)):
    """topics: {(topic, multi_id): msg_id}; data: [(msg_id, packed bytes)] in log order."""
    out = [b"ULog\x01\x12\x35\x01" + struct.pack("<Q", BOOT_US - 1000)]
    out.append(_ulog_message("B", bytes(16) + struct.pack("<3Q", 0, 0, 0)))
    for key, value in (info or {}).items():
        if isinstance(value, str):
            out.append(_ulog_message("I", _ulog_keyed(f"char[{len(value)}]", key, value.encode())))
        else:
            out.append(_ulog_message("I", _ulog_keyed("uint32_t", key, struct.pack("<I", value))))
    for name, fields, _ in formats:
        out.append(_ulog_message("F", f"{name}:{fields}".encode()))
    for key, value in (params or {}).items():
        packed = _ulog_keyed("int32_t", key, struct.pack("<i", value)) if isinstance(value, int) else \
            _ulog_keyed("float", key, struct.pack("<f", value))
        out.append(_ulog_message("P", packed))
    for (topic, multi_id), msg_id in topics.items():
        out.append(_ulog_message("A", struct.pack("<BH", multi_id, msg_id) + topic.encode()))
    out += [_ulog_message("D", struct.pack("<H", msg_id) + packed) for msg_id, packed in data]
    return b"".join(out)


@pytest.fixture(scope="module")
def px4(tmp_path_factory):
    """A PX4 log with two raw compasses (sensor_mag 0 and 1), PX4's calibrated vehicle_magnetometer and
    the attitude, in gauss."""
    field = FIELD_NED_MG / 1000.0
    scene, first = simulate(21, field)
    _, second = simulate(22, field)
    stamps = BOOT_US + np.round(scene.t * 1e6).astype(np.int64)
    quats = scene.rotations.as_quat()  # x, y, z, w; PX4 writes w, x, y, z
    temps = 30.0 + 0.01 * np.arange(len(stamps))
    topics = {("sensor_mag", 0): 0, ("sensor_mag", 1): 1, ("vehicle_magnetometer", 0): 2, ("vehicle_attitude", 0): 3,
              ("battery_status", 0): 4}
    amps = 12.0 + 8.0 * np.sin(np.arange(len(stamps)) / 40.0)
    data = []
    for i, stamp in enumerate(stamps):
        s = int(stamp)
        data.append((0, struct.pack(SENSOR_MAG[2], s + 300, s, 396825, *first.readings[i], temps[i], 0)))
        data.append((1, struct.pack(SENSOR_MAG[2], s + 300, s, 466441, *second.readings[i], temps[i], 0)))
        data.append((2, struct.pack(VEHICLE_MAG[2], s + 400, s, 396825, *first.truth[i], 1)))
        data.append((3, struct.pack(VEHICLE_ATTITUDE[2], s + 100, s, quats[i, 3], *quats[i, :3], 0, 0, 0, 0, 0)))
        if i % 4 == 0:  # the battery at a quarter of the rate; −1 (unknown) at first
            data.append((4, struct.pack(BATTERY_STATUS[2], s, 15.8, -1.0 if i == 0 else amps[i], 0.0)))
    info = {"sys_name": "PX4", "ver_hw": "PX4_FMU_V6C", "ver_sw": "0f1d3a4b9c2e7f60", "ver_sw_release": 0x010E03FF}
    params = {"CAL_MAG0_ID": 396825, "CAL_MAG0_XOFF": 0.05, "CAL_MAG0_YOFF": -0.02, "CAL_MAG0_ZOFF": 0.1,
              "CAL_MAG1_ID": 466441, "CAL_MAG1_XOFF": 0.0}
    path = tmp_path_factory.mktemp("px4") / "flight.ulg"
    path.write_bytes(ulog_file(topics, data, info, params))
    return {"path": path, "scene": scene, "first": first, "second": second, "stamps": stamps, "temps": temps,
            "topics": topics, "data": data, "info": info, "amps": amps}


def test_ulog_raw_compass_units_times_attitude_and_calibration(px4):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rec = read_recording(px4["path"])
    first = px4["first"]
    assert sniff(px4["path"]) == "ulog"
    assert rec.mag_names() == ("mx", "my", "mz") and rec.field_units() == "G" and rec.units["t"] == "s"
    np.testing.assert_array_equal(rec.samples(), first.readings.astype(np.float32))
    np.testing.assert_allclose(rec.columns["t"], px4["stamps"] * 1e-6, rtol=0, atol=1e-9)  # timestamp_sample
    np.testing.assert_allclose(rec.columns["temp"], px4["temps"], atol=1e-4)
    assert rec.units["temp"] == "C"
    meta = rec.metadata
    assert meta["source_format"] == "PX4 ULog" and meta["instance"] == "sensor_mag[0]"
    assert meta["readings"].startswith("raw") and meta["offsets_applied"].startswith("no")
    n = len(rec)
    assert meta["instances"] == (f"sensor_mag[0] ({n} readings, device_id 396825), sensor_mag[1] ({n} readings, "
                                 f"device_id 466441), vehicle_magnetometer[0] ({n} readings, device_id 396825)")
    assert meta["device_id"] == 396825 and "CAL_MAG0_XOFF=0.05" in meta["px4_calibration"]
    # battery_status current_a (the −1 of "unknown" left out) at the magnetometer times: motor_current's regressor
    assert rec.units["current"] == "A" and "battery_status[0] current_a" in meta["current"]
    inside = slice(4, len(rec) - 4)
    np.testing.assert_allclose(rec.current()[inside], px4["amps"][inside], atol=0.05)
    assert rec.current()[0] == rec.current()[4]
    assert "CAL_MAG1" not in meta["px4_calibration"]
    assert meta["firmware_version"] == "v1.14.3" and meta["firmware"] == "PX4" and meta["board"] == "PX4_FMU_V6C"
    assert meta["firmware_git_hash"] == "0f1d3a4b9c2e7f60"
    cal = fluxcal.calibrate(rec.samples(), units=rec.field_units())
    assert cal.units == "G"
    assert np.linalg.norm(cal.offset - truth(first, "G").offset) < 0.01 * np.linalg.norm(FIELD_NED_MG / 1000)
    body = attitude.reference_vectors(FIELD_NED_MG / 1000, rec.columns["pitch"], rec.columns["roll"],
                                      rec.columns["yaw"], degrees=True, convention=meta["attitude_convention"])
    np.testing.assert_allclose(body, first.truth, atol=1e-5)


def test_ulog_other_instances_and_the_calibrated_topic(px4):
    second = read_recording(px4["path"], columns="sensor_mag[1]")
    np.testing.assert_array_equal(second.samples(), px4["second"].readings.astype(np.float32))
    assert second.metadata["device_id"] == 466441
    assert np.linalg.norm(fluxcal.calibrate(second.samples()).offset - truth(px4["second"], "G").offset) < 0.005
    calibrated = read_recording(px4["path"], columns="vehicle_magnetometer[0]")
    np.testing.assert_allclose(calibrated.samples(), px4["first"].truth, atol=1e-6)
    assert calibrated.metadata["readings"].startswith("calibrated") and calibrated.field_units() == "G"
    assert calibrated.metadata["offsets_applied"].startswith("yes")
    # only vehicle_magnetometer logged: that is what there is
    only = px4["path"].with_name("calibrated_only.ulg")
    only.write_bytes(ulog_file({("vehicle_magnetometer", 0): 2}, [d for d in px4["data"] if d[0] == 2]))
    rec = read_recording(only)
    assert rec.metadata["instance"] == "vehicle_magnetometer[0]" and "roll" not in rec.columns
    with pytest.raises(ValueError, match=r"flight\.ulg: no compass instance sensor_mag\[2\]; the log has "
                                         r"sensor_mag\[0\], sensor_mag\[1\], vehicle_magnetometer\[0\]"):
        read_recording(px4["path"], columns="sensor_mag[2]")
    with pytest.raises(ValueError, match=r"flight\.ulg: .*compass instance.*three column names"):
        read_recording(px4["path"], columns="MAG[1]")


def test_ulog_damage_is_reported(px4, tmp_path):
    data = px4["path"].read_bytes()
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(data[:-5])  # inside the last message (an attitude)
    with pytest.warns(UserWarning, match=r"cut\.ulg: the log is cut off inside its last message"):
        rec = read_recording(cut)
    np.testing.assert_array_equal(rec.samples(), read_recording(px4["path"]).samples())
    assert "cut off" in rec.metadata["damage"]
    cut.write_bytes(data[:10])  # inside the file header
    with pytest.raises(ValueError, match=r"cut\.ulg: not a readable ULog"):
        read_recording(cut)
    no_mag = tmp_path / "nomag.ulg"
    no_mag.write_bytes(ulog_file({("vehicle_attitude", 0): 3}, [d for d in px4["data"] if d[0] == 3]))
    with pytest.raises(ValueError, match=r"nomag\.ulg: no magnetometer data \(sensor_mag or vehicle_magnetometer\) in "
                                         r"this ULog: no message of it was logged .*the log has: vehicle_attitude\[0\]\)$"):
        read_recording(no_mag)
    garbled = tmp_path / "garbled.ulg"
    garbled.write_bytes(data[:16] + np.random.default_rng(1).integers(0, 256, 3000, dtype=np.uint8).tobytes())
    with pytest.raises(ValueError, match=r"garbled\.ulg: (no magnetometer data|not a readable ULog)"):
        read_recording(garbled)


def test_ulog_of_px4_1_10_says_its_sensor_mag_is_calibrated(px4, tmp_path):
    old_sensor_mag = ("sensor_mag", "uint64_t timestamp;uint64_t error_count;float x;float y;float z;float range_ga;"
                      "float scaling;float temperature;int16_t x_raw;int16_t y_raw;int16_t z_raw;uint32_t device_id;"
                      "bool is_external;", "<QQffffffhhhI?")
    readings = px4["first"].readings
    data = [(0, struct.pack(old_sensor_mag[2], int(s), 0, *readings[i], 1.3, 1 / 1090, 25.0, 1, 2, 3, 7, True))
            for i, s in enumerate(px4["stamps"])]
    path = tmp_path / "px4_1_10.ulg"
    path.write_bytes(ulog_file({("sensor_mag", 0): 0}, data, formats=(old_sensor_mag,)))
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.samples(), readings.astype(np.float32))
    np.testing.assert_allclose(rec.columns["t"], px4["stamps"] * 1e-6, rtol=0, atol=1e-9)  # from timestamp
    assert rec.metadata["offsets_applied"].startswith("yes") and rec.metadata["readings"].startswith("calibrated")


def test_cli_calibrates_a_ulog(px4, tmp_path):
    out = tmp_path / "cal.json"
    r = run_cli("calibrate", px4["path"], "--columns", "sensor_mag[1]", "-o", out)
    assert r.returncode == 0, r.stderr
    saved = fluxcal.Calibration.load(out)
    assert saved.units == "G" and np.linalg.norm(saved.offset - truth(px4["second"], "G").offset) < 0.005
