"""Labelled text logs (a serial monitor's capture: `Mag X: 1.2 Y: 3.4 Z: 5.6 uT`, `mx=1.2,my=3.4`) and a
comment line that names a header-less table's columns: read by content, values exact, units and time
from the text, garbled lines named by line, and `fluxcal calibrate` runs on them."""
import numpy as np
import pytest

from conftest import run_cli, simulated
from fluxcal.io import read_recording


def readings(n=600, seed=3):
    """Readings of a simulated sensor in µT, rounded as a device would print them (2 decimals)."""
    return np.round(simulated(seed, n=n, field_norm=50.0).readings, 2)


BANNER = "Adafruit LIS3MDL test!\nLIS3MDL Found!\nRange set to: +-4 gauss\nData rate set to: 155 Hz\n"


def test_one_reading_per_line_with_a_banner_and_a_unit_after_the_last_axis(tmp_path):
    m = readings()
    path = tmp_path / "monitor.txt"
    # a capture starts mid-line; the sketch's banner follows
    path.write_text("-13.5 Y: 27.1 Z: -17.0 uT\n" + BANNER
                    + "".join(f"Mag X: {x:.2f}  Y: {y:.2f}  Z: {z:.2f}  uT\n" for x, y, z in m))
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.samples(), m)
    assert rec.mag_names() == ("Mag X", "Mag Y", "Mag Z") and rec.field_units() == "uT"
    assert rec.line_numbers[0] == 6 and rec.metadata["preamble"].startswith("line 1: -13.5 Y: 27.1")
    assert "line 5: Data rate set to: 155 Hz" in rec.metadata["preamble"]


def test_one_line_per_sensor_with_the_ides_clock_across_midnight(tmp_path):
    m = readings()
    acc = np.round(np.random.default_rng(1).normal(size=m.shape), 3)
    lines = []
    for k, (r, a) in enumerate(zip(m, acc)):
        s = 23 * 3600 + 59 * 60 + 55 + k * 0.02  # 12 s of readings from 23:59:55
        clock = f"{int(s // 3600) % 24:02d}:{int(s % 3600 // 60):02d}:{s % 60:06.3f} -> "
        lines.append(f"{clock}Accel X: {a[0]:.3f} \tY: {a[1]:.3f} \tZ: {a[2]:.3f} m/s^2\n")
        lines.append(f"{clock}Mag X: {r[0]:.2f} \tY: {r[1]:.2f} \tZ: {r[2]:.2f} uTesla\n")
    path = tmp_path / "ide.txt"
    path.write_text("".join(lines))
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.samples(), m)
    np.testing.assert_array_equal(rec.acceleration(), acc)
    assert rec.field_units() == "uT" and rec.units["Accel X"] == "m/s^2"
    np.testing.assert_allclose(rec.time(), np.arange(len(m)) * 0.02, atol=1e-9)  # unwrapped past midnight
    assert rec.roles()["time"] == "time"


@pytest.mark.parametrize("layout", ["kv", "per_axis_line", "decimal_comma"])
def test_other_labelled_layouts(tmp_path, layout):
    m = readings(n=200)
    if layout == "kv":
        text = "".join(f"t={20 * k}, mx={x:.2f}, my={y:.2f}, mz={z:.2f}\n" for k, (x, y, z) in enumerate(m))
    elif layout == "per_axis_line":
        text = "".join(f"X: {x:.2f}\nY: {y:.2f}\nZ: {z:.2f}\n" for x, y, z in m)
    else:
        text = "".join(f"X: {x:.2f} Y: {y:.2f} Z: {z:.2f}\n".replace(".", ",") for x, y, z in m)
    path = tmp_path / "log.txt"
    path.write_text(text)
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.samples(), m)
    if layout == "kv":
        assert rec.mag_names() == ("mx", "my", "mz") and rec.time()[-1] == 20 * (len(m) - 1)


@pytest.mark.parametrize("bad, message", [
    ("Mag X: 1.00  Y: 2.00\n", r"line 11: no 'Mag Z' \(truncated line\?\)"),
    ("Mag X: 1.00  Y: 2.00  Z: 3.0Mag X: 1.00  Y: 2.00  Z: 3.00 uT\n", r"line 11: 'Mag X' appears twice"),
    ("Mag X: nan  Y: 2.00  Z: 3.00 uT\n", r"line 11: Mag X: 'nan' is not a finite number"),
    ("Mag X: 1.00  Y: 2x5  Z: 3.00 uT\n", r"line 11: Mag Y: '2x5' is not a number"),
    ("Mag X: 1.00  Q: 2.00  Z: 3.00 uT\n", r"line 11: 'Mag Q' is not one of the columns \(Mag X, Mag Y, Mag Z\)"),
    ("\x7fG@@\n", r"line 11: no 'label: number' values \(garbled line\?\)"),
])
def test_a_garbled_line_is_named_and_can_be_left_out(tmp_path, bad, message):
    m = readings(n=20)
    good = [f"Mag X: {x:.2f}  Y: {y:.2f}  Z: {z:.2f}  uT\n" for x, y, z in m]
    path = tmp_path / "serial.txt"
    path.write_text("".join(good[:10] + [bad] + good[10:]))
    with pytest.raises(ValueError, match=message + r".*--bad-lines skip"):
        read_recording(path)
    rec = read_recording(path, bad_lines="skip")
    np.testing.assert_array_equal(rec.samples(), m)  # every whole reading kept, the bad line only left out
    assert rec.metadata["skipped_lines"].startswith("1 of 21: 11 (")
    assert 11 not in rec.line_numbers


def test_garbage_bytes_from_the_serial_line_cost_their_lines_only(tmp_path):
    m = readings(n=400)
    lines = [f"Mag X: {x:.2f}  Y: {y:.2f}  Z: {z:.2f}  uT\n".encode() for x, y, z in m]
    for k, at, byte in ((37, 9, 0xC3), (200, 14, 0xFF), (311, 3, 0x92)):  # bytes lost or flipped in transit
        lines[k] = lines[k][:at] + bytes([byte]) + lines[k][at:]
    path = tmp_path / "capture.txt"
    path.write_bytes(b"".join(lines))
    with pytest.raises(ValueError, match=r"line 38: bytes that are not text \(garbage from a serial line\?\).*"
                                         r"--bad-lines skip"):
        read_recording(path)
    rec = read_recording(path, bad_lines="skip")
    np.testing.assert_array_equal(rec.samples(), np.delete(m, [37, 200, 311], axis=0))
    assert rec.metadata["skipped_lines"].startswith("3 of 400: 38 (bytes that are not text")


def test_a_comment_line_naming_the_columns_is_the_header(tmp_path):
    m = readings(n=50)
    rows = "".join(f"{0.02 * k:.2f} {x:.2f} {y:.2f} {z:.2f}\n" for k, (x, y, z) in enumerate(m))
    path = tmp_path / "scan.dat"
    path.write_text("# bench scan, sensor 4\n# time[s] Bx[uT] By[uT] Bz[uT]\n" + rows)
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.samples(), m)
    assert rec.mag_names() == ("Bx", "By", "Bz") and rec.field_units() == "uT"
    assert rec.metadata["header"] == "the comment on line 2" and rec.time()[1] == 0.02
    # a comment that does not name a magnetometer is not a header: the error still asks for --columns
    other = tmp_path / "other.dat"
    other.write_text("# run 4 of the day\n" + rows)
    with pytest.raises(ValueError, match="4 whitespace-separated numbers and no header"):
        read_recording(other)
    np.testing.assert_array_equal(read_recording(other, columns="t,mx,my,mz").samples(), m)
    described = tmp_path / "described.dat"  # the usual comments above it still count, a cut line is a bad line
    described.write_text("# units: Bx=nT, By=nT, Bz=nT\n# sensor: FGM-3\n# t Bx By Bz\n" + rows + "9.9 1.0 2.0\n")
    with pytest.raises(ValueError, match=r"line 54: 3 fields, the header has 4"):
        read_recording(described)
    rec = read_recording(described, bad_lines="skip")
    assert rec.field_units() == "nT" and rec.metadata["sensor"] == "FGM-3" and len(rec) == len(m)


def test_calibrate_reads_a_serial_monitor_capture_as_it_reads_the_table(tmp_path):
    m = readings(n=1000)
    table = tmp_path / "table.csv"
    table.write_text("mx,my,mz\n" + "".join(f"{x:.2f},{y:.2f},{z:.2f}\n" for x, y, z in m))
    capture = tmp_path / "capture.txt"
    capture.write_text(BANNER + "".join(f"Mag X: {x:.2f}  Y: {y:.2f}  Z: {z:.2f}  uT\n" for x, y, z in m))
    out = [run_cli("calibrate", p) for p in (table, capture)]
    assert [o.returncode for o in out] == [0, 0], out[1].stderr
    offset = [next(line for line in o.stdout.splitlines() if "offset b" in line) for o in out]
    assert offset[1] == offset[0] + " uT"
    assert "magnetometer Mag X,Mag Y,Mag Z" in out[1].stdout


def test_two_sensors_under_the_same_names_are_kept_apart_never_mixed(tmp_path):
    path = tmp_path / "alternating.txt"  # accelerometer and magnetometer lines without the sensor's name
    path.write_text("".join(f"X: 0.1{k} Y: 0.0 Z: 9.81 m/s^2\nX: 12.{k} Y: -40.1 Z: 20.5 uT\n" for k in range(10)))
    rec = read_recording(path)  # a column per unit; the field unit says which is the magnetometer
    assert list(rec.columns)[:3] == ["X (m/s^2)", "Y (m/s^2)", "Z (m/s^2)"]
    np.testing.assert_array_equal(rec.samples()[:, 0], [12.0 + k / 10 for k in range(10)])
    assert rec.field_units() == "uT"
    # Adafruit's LIS3MDL demo prints each reading in counts, then in uTesla: both were one column labelled
    # µT, and calibrate fitted the mix (offset 1486 µT, |h| 2494 µT) without a word.
    rng = np.random.default_rng(1)
    u = rng.normal(size=(300, 3))
    m = 45.0 * u / np.linalg.norm(u, axis=1, keepdims=True) + [10.0, -5.0, 3.0]
    path = tmp_path / "lis3mdl.txt"
    path.write_text("Adafruit LIS3MDL test!\nLIS3MDL Found!\nRange set to: +-4 gauss\n\n" + "".join(
        f"X:  {round(x * 68.42)}  \tY:  {round(y * 68.42)}  \tZ:  {round(z * 68.42)}\n"
        f"\tX: {x:.2f} \tY: {y:.2f} \tZ: {z:.2f} uTesla \n" for x, y, z in m))
    rec = read_recording(path)
    assert rec.mag_names() == ("X (uT)", "Y (uT)", "Z (uT)") and rec.field_units() == "uT"
    np.testing.assert_allclose(rec.samples(), m, atol=0.005)
    assert np.all(np.abs(rec.columns["X"] - np.round(m[:, 0] * 68.42)) == 0)  # the counts kept beside them
    # A lone line in another unit, or a range change half-way (one switch, not alternating lines), is an
    # error, not a second sensor.
    path.write_text("".join(f"Mag X: {k}.5 Y: 2 Z: 3 uT\n" for k in range(5)) + "Mag X: 150 Y: 20 Z: 30 mG\n")
    with pytest.raises(ValueError, match=r"'Mag X' is in uT on line 1 and in mG on line 6; a changed range"):
        read_recording(path)
    path.write_text("".join(f"Mag X: {k}00 Y: 2 Z: 3 mG\n" for k in range(20))
                    + "".join(f"Mag X: 0.{k} Y: 2 Z: 3 G\n" for k in range(20)))
    with pytest.raises(ValueError, match=r"'Mag X' is in mG on line 1 and in G on line 21; a changed range"):
        read_recording(path)
    # Two sensors under one name, alternating: both triples kept and listed, neither picked silently.
    path.write_text("".join(f"Mag X: {k}00 Y: 2 Z: 3 mG\nMag X: 0.{k} Y: 0.2 Z: 0.3 uT\n" for k in range(10)))
    with pytest.raises(ValueError, match=r"several magnetometer column triples \(Mag X \(mG\),.*Mag X \(uT\)"):
        read_recording(path).samples()
    # A bracket that is not a unit stays in the name.
    path.write_text("".join(f"X (raw): {k} Y (raw): 2 Z (raw): 3 X (cal): 4 Y (cal): 5 Z (cal): 6\n" for k in range(9)))
    assert read_recording(path).mag_names() == ("X (raw)", "Y (raw)", "Z (raw)")


def test_a_bracketed_clock_and_the_devices_own_time(tmp_path):
    m = readings(n=20)
    path = tmp_path / "coolterm.txt"
    path.write_text("".join(f"[12:30:{k:02d}.500] Time: {1000 * k} ms Mag X: {x:.2f} Y: {y:.2f} Z: {z:.2f} uT\n"
                            for k, (x, y, z) in enumerate(m)))
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.samples(), m)
    assert rec.time().tolist() == [float(k) for k in range(20)]  # the device's Time (ms), not the host's clock
    assert rec.columns["clock"][1] == 1.0 and rec.metadata["clock_start"] == "12:30:00.500000"  # no date: none made up


def test_a_table_with_a_key_value_text_cell_stays_a_table(tmp_path):
    path = tmp_path / "status.csv"
    path.write_text("t,mx,my,mz,status\n" + "".join(f"{k},{k}.5,2,3,mode={k % 2}\n" for k in range(5)))
    rec = read_recording(path)
    assert rec.mag_names() == ("mx", "my", "mz") and rec.metadata["text_columns"].startswith("status (e.g. mode=0")


def test_a_unit_in_the_sensors_words(tmp_path):
    path = tmp_path / "unit_first.txt"
    path.write_text("".join(f"Magnetometer (uT) X: {k}.5 Y: 2 Z: 3\n" for k in range(4)))
    rec = read_recording(path)
    assert rec.mag_names() == ("Magnetometer X", "Magnetometer Y", "Magnetometer Z") and rec.field_units() == "uT"


def test_an_ambiguous_comma_is_settled_by_the_file_or_named_never_guessed(tmp_path):
    """`X: 1,234` was read as 1.234 (1000 times off if the device wrote a thousands separator) and `1,234,567`
    as 1.234 (its tail ignored). The file's own numbers decide: a decimal comma that cannot be a thousands
    separator (0,5) or thousands groups beside a decimal point (1,234.5); only ambiguous ones are an error
    naming the line, the value and both readings, settled by decimal=',' or thousands=','."""
    path = tmp_path / "log.txt"
    ambiguous = "".join(f"X: 1,{234 + k} Y: -2,{500 + k} Z: 40,{100 + k} uT\n" for k in range(20))
    path.write_text(ambiguous)
    with pytest.raises(ValueError, match=r"log.txt, line 1: X: '1,234' is 1.234 with a decimal comma or 1234 with "
                                         r"a thousands separator.*decimal=','.*thousands=','"):
        read_recording(path)
    assert read_recording(path, decimal=",").samples()[0].tolist() == [1.234, -2.5, 40.1]
    assert read_recording(path, thousands=",").samples()[0].tolist() == [1234, -2500, 40100]
    path.write_text(ambiguous + "X: 0,5 Y: 2,25 Z: 40,1 uT\n")  # a decimal comma, even on the last line
    rec = read_recording(path)
    assert rec.samples()[[0, -1]].tolist() == [[1.234, -2.5, 40.1], [0.5, 2.25, 40.1]]
    assert rec.metadata["decimal_separator"] == "comma"
    path.write_text(ambiguous + "X: 1,234.5 Y: 2 Z: 3 uT\n")  # a thousands separator beside a decimal point
    assert read_recording(path).samples()[[0, -1]].tolist() == [[1234, -2500, 40100], [1234.5, 2, 3]]
    path.write_text("X: 1,234,567 Y: 2 Z: 3\n" * 20)  # several commas: never a truncated 1.234
    with pytest.raises(ValueError, match=r"line 1: X: '1,234,567' is 1234567 with thousands separators"):
        read_recording(path, bad_lines="skip")
    assert read_recording(path, thousands=",").samples()[0].tolist() == [1234567, 2, 3]
    path.write_text("X: 0,5 Y: 2 Z: 3\n" * 20 + "X: 1,234,567 Y: 2 Z: 3\nX: 1,234.5 Y: 2 Z: 3\n")
    with pytest.raises(ValueError, match=r"'0,5' on line 1 has a decimal comma, X: '1,234.5' on line 22 a thousands"):
        read_recording(path)
    with pytest.raises(ValueError, match=r"line 21: X: '1,234,567' is not a decimal comma"):
        read_recording(path, decimal=",")
    path.write_text("mx,my,mz\n1,2,3\n")
    with pytest.raises(ValueError, match="apply to labelled text logs"):
        read_recording(path, decimal=",")


def test_arduino_sketch_captures_with_a_banner(tmp_path):
    # Adafruit's HMC5883 Unified example: a sensor banner, then "X: … uT" and "Heading (degrees): …" lines;
    # the heading's bracketed unit kept it from reading as labelled, and the file was taken for a table.
    m = readings(n=80)
    text = ("HMC5883 Magnetometer Test\n\n------------------------------------\nSensor:       HMC5883\n"
            "Max Value:    800.00 uT\n------------------------------------\n\n"
            + "".join(f"X: {x:.2f}  Y: {y:.2f}  Z: {z:.2f}  uT\nHeading (degrees): {k % 360}.5\n"
                      for k, (x, y, z) in enumerate(m)))
    (tmp_path / "hmc.txt").write_text(text)
    rec = read_recording(tmp_path / "hmc.txt")
    assert rec.mag_names() == ("X", "Y", "Z") and rec.field_units() == "uT" and rec.units["Heading"] == "degrees"
    np.testing.assert_allclose(rec.samples(), m, atol=0.005)
    assert "line 4: Sensor:       HMC5883" in rec.metadata["preamble"]
    # Arduino's Nano 33 BLE SimpleMagnetometer: a title line above a tab-separated header ("line 5: 3 fields,
    # the header has 1" before)
    text = ("Started\nMagnetic field sample rate = 20.00 Hz\n\nMagnetic Field in uT\nX\tY\tZ\n"
            + "".join(f"{x:.2f}\t{y:.2f}\t{z:.2f}\n" for x, y, z in m))
    (tmp_path / "nano.txt").write_text(text)
    rec = read_recording(tmp_path / "nano.txt")
    np.testing.assert_allclose(rec.samples(), m, atol=0.005)
    assert rec.metadata["preamble"] == ("line 1: Started; line 2: Magnetic field sample rate = 20.00 Hz; "
                                        "line 4: Magnetic Field in uT")
    # a title line above a header with a units row under it ("line 2: 4 fields, the header has 2" before)
    for units_row in ("s,uT,uT,uT", "[s],[uT],[uT],[uT]"):
        text = "Bench log, sensor 3\nt,mx,my,mz\n" + units_row + "\n" + "".join(
            f"{k / 10:.1f},{x:.2f},{y:.2f},{z:.2f}\n" for k, (x, y, z) in enumerate(m))
        (tmp_path / "titled.csv").write_text(text)
        rec = read_recording(tmp_path / "titled.csv")
        np.testing.assert_allclose(rec.samples(), m, atol=0.005)
        assert rec.field_units() == "uT" and rec.units["t"] == "s" and len(rec) == len(m)
        assert rec.metadata["preamble"] == "line 1: Bench log, sensor 3"


def test_hyphenated_labels_and_an_is_sentence_with_mg_beside_mG(tmp_path):
    """kriswiner's MPU9250BasicAHRS sketch (SparkFun's MPU-9250 library example): a banner, then four lines
    per cycle. Its `X-mag field: … mG` is milligauss, its `X-acceleration: … mg` milli-g, and
    `Temperature is 24.0 degrees C` the die temperature."""
    m = np.round(readings(n=300) * 10.0, 1)  # µT → mG, printed with 2 decimals
    acc = np.round(np.random.default_rng(2).normal(scale=500.0, size=m.shape), 2)
    lines = ["MPU9250 I AM 71 I should be 71", "MPU9250 is online...", "AK8963 I AM 48 I should be 48",
             "AK8963 initialized for active data mode...."]
    for k, (r, a) in enumerate(zip(m, acc)):
        lines.append(f"X-acceleration: {a[0]:.2f} mg Y-acceleration: {a[1]:.2f} mg Z-acceleration: {a[2]:.2f} mg ")
        lines.append("X-gyro rate: 0.123 degrees/sec Y-gyro rate: -0.456 degrees/sec Z-gyro rate: 0.789 degrees/sec ")
        lines.append(f"X-mag field: {r[0]:.2f} mG Y-mag field: {r[1]:.2f} mG Z-mag field: {r[2]:.2f} mG")
        lines.append(f"Temperature is {24 + k / 1000:.3f} degrees C")
    path = tmp_path / "mpu9250.txt"
    path.write_text("\n".join(lines) + "\n")
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.samples(), m)
    assert rec.mag_names() == ("X-mag field", "Y-mag field", "Z-mag field") and rec.field_units() == "mG"
    assert rec.acc_names() == ("X-acceleration", "Y-acceleration", "Z-acceleration")
    assert {rec.units[n] for n in rec.acc_names()} == {"mg"}  # milli-g, not milligauss
    np.testing.assert_allclose(rec.temperature(), 24 + np.arange(300) / 1000)
    assert rec.metadata["preamble"].startswith("line 1: MPU9250 I AM 71")
    out = run_cli("calibrate", str(path), "-o", str(tmp_path / "cal.json"))
    assert out.returncode == 0, out.stderr
    assert "magnetometer X-mag field,Y-mag field,Z-mag field; temperature Temperature" in out.stdout


@pytest.mark.parametrize("style", ["space", "comma", "comma_tight", "tab", "counts", "two_sensors", "clock"])
def test_a_label_then_the_vector(tmp_path, style):
    """Arduino sketches print `Mag: x y z` (Serial.print(x); Serial.print(" ") …): one label, then the vector,
    after a start-up banner. Its components are the label's X, Y, Z."""
    m = readings(n=200)
    row = {"space": "Mag: {:.2f} {:.2f} {:.2f}", "comma": "Mag: {:.2f}, {:.2f}, {:.2f}",
           "comma_tight": "Mag: {:.2f},{:.2f},{:.2f}", "tab": "Mag:\t{:.2f}\t{:.2f}\t{:.2f}",
           "counts": "Mag: {:.0f},{:.0f},{:.0f}", "two_sensors": "Acc: 0.1, -0.2, 9.8 Mag: {:.2f}, {:.2f}, {:.2f} uT",
           "clock": "12:30:01.123 -> Mag: {:.2f} {:.2f} {:.2f}"}[style]
    scale = 100.0 if style == "counts" else 1.0
    path = tmp_path / "log.txt"
    path.write_text("QMC5883L init OK\nStarting mag log...\n" + "".join(row.format(*(r * scale)) + "\n" for r in m))
    rec = read_recording(path)
    assert rec.mag_names() == ("Mag X", "Mag Y", "Mag Z")
    decimals = 0 if style == "counts" else 2
    np.testing.assert_allclose(rec.samples(), np.round(m * scale, decimals), atol=1e-9)
    assert "init OK" in rec.metadata["preamble"]
    if style == "two_sensors":
        assert rec.units["Mag X"] == "uT" and "Acc Z" in rec.columns



def test_a_trailing_number_or_a_decimal_comma_vector_is_no_vector(tmp_path):
    """Lines with pairs and a trailing unlabelled number (a counter) keep the pairs' names; a vector written
    with decimal commas is not split at them."""
    m = readings(n=200)
    path = tmp_path / "log.txt"
    path.write_text("".join(f"Mag X: {x:.2f} Y: {y:.2f} Z: {z:.2f} {k}\n" for k, (x, y, z) in enumerate(m)))
    assert read_recording(path).mag_names() == ("Mag X", "Mag Y", "Mag Z")
    from fluxcal.io.labelled import _vectors
    assert _vectors("Mag: 12,34 56,78 -9,10") is None
