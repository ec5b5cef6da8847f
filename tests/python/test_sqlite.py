"""SQLite databases (fluxcal.io.sqlite): the magnetometer's table found among others, a table named with
--columns, NULL and BLOB cells named by table and row (or skipped and listed), a damaged file, a ROS 2
storage file without its folder, and `fluxcal calibrate` on a database."""
import sqlite3

import numpy as np
import pytest

import fluxcal
from conftest import run_cli, simulated
from fluxcal.io import read_recording, sniff


def write_db(path, readings, mag_names=("mx", "my", "mz"), rows=None):
    db = sqlite3.connect(path)
    db.execute("CREATE TABLE meta (key TEXT, value TEXT)")
    db.execute("INSERT INTO meta VALUES ('device', 'bench unit 7')")
    db.execute("CREATE TABLE accel (t REAL, ax REAL, ay REAL, az REAL)")  # numbers, but not a magnetometer
    names = ", ".join(f'"{n}" REAL' for n in mag_names)
    db.execute(f"CREATE TABLE samples (t REAL, {names})")
    t = np.arange(len(readings)) / 50.0
    db.executemany("INSERT INTO accel VALUES (?, ?, ?, ?)", [(float(s), 0.0, 0.0, 9.81) for s in t])
    body = rows if rows is not None else [(float(s), *map(float, m)) for s, m in zip(t, readings)]
    db.executemany("INSERT INTO samples VALUES (?, ?, ?, ?)", body)
    db.commit()
    db.close()
    return path


def test_the_magnetometers_table_is_read_among_others(tmp_path):
    m = simulated(4, n=500, field_norm=50.0).readings
    path = write_db(tmp_path / "log.db", m)
    assert sniff(path) == "sqlite"
    rec = read_recording(path)
    assert rec.metadata["table"] == "samples" and rec.metadata["other_tables"] == "meta, accel"
    np.testing.assert_array_equal(rec.samples(), m)
    np.testing.assert_allclose(rec.columns["t"], np.arange(500) / 50.0)
    np.testing.assert_allclose(fluxcal.calibrate(rec.samples()).offset, fluxcal.calibrate(m).offset, rtol=1e-12)
    other = read_recording(path, columns="accel")  # a table by name
    assert other.metadata["table"] == "accel" and list(other.columns) == ["t", "ax", "ay", "az"]


def test_units_in_the_column_names_are_read(tmp_path):
    m = simulated(5, n=300, field_norm=50.0).readings
    rec = read_recording(write_db(tmp_path / "u.db", m * 1000, mag_names=("Bx [nT]", "By [nT]", "Bz [nT]")))
    assert rec.units["Bx"] == "nT"
    np.testing.assert_allclose(rec.samples(), m * 1000)


def test_null_and_blob_cells_are_named_by_table_and_row_or_skipped(tmp_path):
    m = simulated(6, n=100, field_norm=50.0).readings
    rows = [(k / 50.0, *map(float, r)) for k, r in enumerate(m)]
    rows[5] = (0.1, None, 1.0, 2.0)
    rows[7] = (0.14, b"\x00\x01", 1.0, 2.0)
    path = write_db(tmp_path / "bad.db", m, rows=rows)
    with pytest.raises(ValueError, match=r"bad\.db, table 'samples', row 6, column 'mx': empty"):
        read_recording(path)
    rec = read_recording(path, bad_lines="skip")
    assert len(rec.samples()) == 98
    assert rec.metadata["skipped_lines"] == ("2 of 100: row 6 (column 'mx': empty); "
                                             "row 8 (column 'mx': 'BLOB' is not a number)")


def test_damaged_text_only_and_ros_storage_files_are_clear_errors(tmp_path):
    path = write_db(tmp_path / "whole.db", simulated(7, n=2000, field_norm=50.0).readings)
    cut = tmp_path / "cut.db"
    cut.write_bytes(path.read_bytes()[:6000])  # a copy that stopped part-way
    with pytest.raises(ValueError, match=r"cut\.db: not a readable SQLite database"):
        read_recording(cut)
    text = tmp_path / "text.db"
    db = sqlite3.connect(text)
    db.execute("CREATE TABLE notes (who TEXT, what TEXT)")
    db.execute("INSERT INTO notes VALUES ('me', 'nothing')")
    db.commit()
    db.close()
    with pytest.raises(ValueError, match=r"text\.db: no table holds rows of numbers \(tables: notes\)"):
        read_recording(text)
    bag = tmp_path / "rosbag2_0.db3"  # a ROS 2 storage file copied out of its folder
    db = sqlite3.connect(bag)
    db.execute("CREATE TABLE topics (id INTEGER, name TEXT)")
    db.execute("CREATE TABLE messages (id INTEGER, topic_id INTEGER, timestamp INTEGER, data BLOB)")
    db.commit()
    db.close()
    with pytest.raises(ValueError, match="ROS 2 bag's storage file without its folder's metadata.yaml"):
        read_recording(bag)


def test_calibrate_runs_on_a_database(tmp_path):
    path = write_db(tmp_path / "log.db", simulated(8, n=600, field_norm=50.0).readings)
    out = run_cli("calibrate", path)
    assert out.returncode == 0, out.stderr
    assert "magnetometer mx,my,mz" in out.stdout and "|h| = " in out.stdout
