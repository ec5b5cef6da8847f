"""JSON records (JSON Lines, a list of records, a columns/data table): values exact, nested keys
flattened and recognised by name, time stamps and constant text handled, and a damaged record (a
truncated line, a list cut off, a null) named by line or left out with bad_lines="skip"."""
import json

import numpy as np
import pytest

from conftest import run_cli, simulated
from fluxcal.io import read_recording


def readings(n=300, seed=5):
    return simulated(seed, n=n, field_norm=50.0).readings


def test_json_lines_with_nested_objects_a_clock_and_a_device_name(tmp_path):
    m = readings()
    path = tmp_path / "mqtt.jsonl"
    path.write_text("".join(json.dumps({"device": "esp32-07", "time": f"2026-11-25T10:00:{k * 0.1:06.3f}Z",
                                        "mag": {"x": x, "y": y, "z": z}, "acc": [0.0, 0.1, 9.8]}) + "\n"
                            for k, (x, y, z) in enumerate(m)))
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.samples(), m)  # bit for bit: JSON keeps every digit
    assert rec.mag_names() == ("mag_x", "mag_y", "mag_z") and rec.acceleration().shape == (len(m), 3)
    np.testing.assert_allclose(rec.time(), np.arange(len(m)) * 0.1, atol=1e-6)
    assert rec.metadata["device"] == "esp32-07" and rec.metadata["time_start"].startswith("2026-11-25T10:00:00")


def test_a_truncated_last_line_and_a_null_are_named_and_can_be_left_out(tmp_path):
    m = readings(n=50)
    lines = [json.dumps({"mx": x, "my": y, "mz": z}) for x, y, z in m]
    lines[20] = lines[20].replace(repr(float(m[20, 1])), "null")
    path = tmp_path / "log.jsonl"
    path.write_text("\n".join(lines) + '\n{"mx": 1.5, "my": ')  # the logger stopped mid-line
    with pytest.raises(ValueError, match=r"log.jsonl, line 21: 'my' is null, not a number; pass bad_lines='skip'"):
        read_recording(path)
    rec = read_recording(path, bad_lines="skip")
    np.testing.assert_array_equal(rec.samples(), np.delete(m, 20, axis=0))
    assert rec.metadata["skipped_lines"].startswith("2 of 51: 21 ('my' is null")
    assert "51 (not valid JSON" in rec.metadata["skipped_lines"]


def test_a_list_of_records_cut_off_keeps_its_complete_records(tmp_path):
    m = readings(n=40)
    text = json.dumps([{"t": 0.02 * k, "Bx [uT]": x, "By [uT]": y, "Bz [uT]": z} for k, (x, y, z) in enumerate(m)],
                      indent=1)
    path = tmp_path / "cut.json"
    path.write_text(text[:text.rfind("{") + 12])  # the last record cut off: the file ends mid-record
    with pytest.raises(ValueError, match=r"cut.json, record at line \d+: not valid JSON .*cut off here"):
        read_recording(path)
    rec = read_recording(path, bad_lines="skip")
    np.testing.assert_array_equal(rec.samples(), m[:-1])
    assert rec.field_units() == "uT" and rec.time()[-1] == pytest.approx(0.02 * (len(m) - 2))


def test_a_columns_and_data_table(tmp_path):
    m = readings(n=30)
    path = tmp_path / "split.json"
    path.write_text(json.dumps({"columns": ["time", "Bx (nT)", "By (nT)", "Bz (nT)"],
                                "data": [[0.01 * k, *r] for k, r in enumerate(m.tolist())]}))
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.samples(), m)
    assert rec.field_units() == "nT" and rec.time()[2] == 0.02
    path.write_text(json.dumps({"columns": ["mx", "my", "mz"], "data": [[1, 2, 3], [4, 5]]}))
    with pytest.raises(ValueError, match=r"split.json, data row 2: 2 values, the table has 3 columns"):
        read_recording(path)


def test_calibrate_runs_on_json_lines(tmp_path):
    m = readings(n=800)
    path = tmp_path / "log.jsonl"
    path.write_text("".join(json.dumps({"mag": [x, y, z]}) + "\n" for x, y, z in m))
    out = run_cli("calibrate", path)
    assert out.returncode == 0, out.stderr
    assert "magnetometer mag[0],mag[1],mag[2]" in out.stdout and "offset b" in out.stdout


def test_records_of_several_sensors_keep_the_magnetometers(tmp_path):
    path = tmp_path / "mixed.jsonl"
    path.write_text("".join(json.dumps({"sensor": "accel", "x": 0.1, "y": 0.0, "z": 9.8}) + "\n"
                            + json.dumps({"sensor": "mag", "x": 10.0 + k, "y": -4.0, "z": 20.0}) + "\n"
                            for k in range(6)))
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.samples()[:, 0], 10.0 + np.arange(6))
    assert rec.metadata["records_left_out"].startswith("sensor = accel 6")


def test_appended_lists_nan_one_record_and_utf16(tmp_path):
    path = tmp_path / "two_sessions.json"
    path.write_text(json.dumps([{"mx": 1, "my": 2, "mz": 3}]) + "\n" + json.dumps([{"mx": 4, "my": 5, "mz": 6}]))
    np.testing.assert_array_equal(read_recording(path).samples(), [[1, 2, 3], [4, 5, 6]])
    path.write_text(json.dumps([{"mx": 1, "my": 2, "mz": 3}]) + " trailing")
    with pytest.raises(ValueError, match=r"two_sessions.json, line 1: text after the list's end: 'trailing'"):
        read_recording(path)
    # a list written on one line: its records are named by their place in it, not all as "line 1"
    records = [{"mx": 1.0 * k, "my": 2.0, "mz": 3.0} for k in range(8)]
    records[5]["mz"] = None
    path.write_text(json.dumps(records))
    with pytest.raises(ValueError, match=r"two_sessions.json, record 6 \(line 1\): 'mz' is null, not a number"):
        read_recording(path)
    assert read_recording(path, bad_lines="skip").metadata["skipped_lines"] == \
        "1 of 8: record 6 (line 1) ('mz' is null, not a number)"
    nan = tmp_path / "nan.jsonl"
    nan.write_text('{"mx": NaN, "my": 2, "mz": 3}\n{"mx": 1, "my": 2, "mz": 3}\n')
    with pytest.raises(ValueError, match=r"nan.jsonl, line 1: 'mx' is NaN, not a number"):
        read_recording(nan)
    one = tmp_path / "one.jsonl"
    one.write_text('{"mx": 1, "my": 2, "mz": 3}\n')
    np.testing.assert_array_equal(read_recording(one).samples(), [[1, 2, 3]])
    wide = tmp_path / "wide.jsonl"
    wide.write_bytes('{"mx": 1, "my": 2, "mz": 3}\n{"mx": 4, "my": 5, "mz": 6}\n'.encode("utf-16"))
    np.testing.assert_array_equal(read_recording(wide).samples(), [[1, 2, 3], [4, 5, 6]])
