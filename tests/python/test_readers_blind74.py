"""Defects a blind check (s74/readers) found in the table readers: two compasses interleaved row by row by an
instance column (mavlogdump's `I`, PX4's `device_id`) fitted as one sensor; the compass and the readings of a
flight log not said by the command line; a partial first line of numbers taken for the header; an unnamed spacer
column refusing the file; a blank temperature cell refusing it while `nan` passed; a quoted units row, or Campbell
TOA5's (TS, RN beside nT), taken for the header."""
from __future__ import annotations

import numpy as np
import pytest

from fluxcal import read_recording
from fluxcal.cli import _print_roles
from fluxcal.io.recording import Recording
from conftest import run_cli


def sphere(n, offset, radius=500.0, seed=0):
    v = np.random.default_rng(seed).normal(size=(n, 3))
    return radius * v / np.linalg.norm(v, axis=1, keepdims=True) + offset


def write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


# -- D2: compasses interleaved by an instance column ------------------------------------------------------------

def interleaved(tmp_path, column="I", ids=(0, 1)):
    a, b = sphere(300, (-270, 170, -345), seed=1), sphere(300, (185, -372, 346), seed=2)
    lines = [f"TimeUS,{column},MagX,MagY,MagZ"]
    for k in range(300):
        for m, v in zip(ids, (a[k], b[k])):
            lines.append(f"{1000000 + 20000 * k + m % 7},{m},{v[0]:.1f},{v[1]:.1f},{v[2]:.1f}")
    return write(tmp_path, "mag.csv", "\n".join(lines) + "\n"), a, b


def test_two_compasses_interleaved_by_I_read_the_first_and_say_so(tmp_path):
    path, a, _ = interleaved(tmp_path)
    rec = read_recording(path)
    assert len(rec) == 300 and np.allclose(rec.samples(), np.round(a, 1))
    assert rec.metadata["instance"] == "I = 0 (300 rows)"
    assert "2 compasses interleaved by column 'I'" in rec.metadata["instances"]
    assert "--columns I=1" in rec.metadata["instances"]
    assert rec.line_numbers[:2].tolist() == [2, 4]  # the file's lines of the rows kept


def test_the_other_compass_is_picked_with_columns_name_equals_value(tmp_path):
    path, _, b = interleaved(tmp_path, "device_id", (396297, 528137))
    rec = read_recording(path, columns="device_id=528137")
    assert np.allclose(rec.samples(), np.round(b, 1)) and rec.metadata["instance"].startswith("device_id = 528137")
    rec = read_recording(path, columns="MagX,MagY,MagZ,device_id=528137")
    assert rec.mag_names() == ("MagX", "MagY", "MagZ") and len(rec) == 300
    with pytest.raises(ValueError, match=r"column 'device_id' holds 396297, 528137, not 5"):
        read_recording(path, columns="device_id=5")


def test_calibrate_says_which_compass_of_an_interleaved_table(tmp_path):
    path, _, _ = interleaved(tmp_path)
    out = run_cli("calibrate", path).stdout
    assert "compass instance: I = 0 (300 rows)" in out and "choose with --columns I=1" in out


def test_a_single_compass_with_its_id_column_is_read_whole(tmp_path):
    path, a, _ = interleaved(tmp_path)
    rows = path.read_text().splitlines()
    path.write_text("\n".join(rows[:1] + rows[1::2]) + "\n")  # I = 0 only
    rec = read_recording(path)
    assert len(rec) == 300 and "instances" not in rec.metadata


# -- D1: what the command line says of a flight log's compass ---------------------------------------------------

def test_print_roles_says_the_compass_instance_and_what_was_applied(capsys):
    rec = Recording(columns={"mx": [1.0, 2], "my": [1.0, 2], "mz": [1.0, 2]},
                    metadata={"instance": "MAG[0]", "instances": "MAG[0] (2 readings), MAG[1] (2 readings)",
                              "readings": "MagX..Z as logged", "offsets_applied": "yes: OfsX..Z"})
    _print_roles(rec)
    out = capsys.readouterr().out
    assert "compass instance: MAG[0]\n" in out and "instances in the file: MAG[0] (2 readings)" in out
    assert "readings: MagX..Z as logged\n" in out and "offsets already applied: yes: OfsX..Z\n" in out
    _print_roles(Recording(columns={"mx": [1.0, 2], "my": [1.0, 2], "mz": [1.0, 2]}))
    assert "instance" not in capsys.readouterr().out


# -- D7: a partial first line of numbers ------------------------------------------------------------------------

def test_a_partial_first_line_of_numbers_is_data_not_the_header(tmp_path):
    rows = "\n".join(f"{x:.3f},{y:.3f},{z:.3f}" for x, y, z in sphere(40, (0, 0, 0), 50.0))
    path = write(tmp_path, "reset.csv", ",52.127,-18.240\n" + rows + "\n\nQMC5883L test\nmx,my,mz\n" + rows + "\n")
    with pytest.raises(ValueError, match=r"reset.csv, line 1: the first line holds numbers, not column names; "
                                         r"the header 'mx,my,mz' is on line 44"):
        read_recording(path)


# -- D5: an unnamed column in the middle ------------------------------------------------------------------------

def test_an_empty_unnamed_spacer_column_is_left_out_with_a_note(tmp_path):
    rows = "\n".join(f"{0.05 * k:.2f},{x:.3f},{y:.3f},{z:.3f},,23.5" for k, (x, y, z) in
                     enumerate(sphere(30, (0, 0, 0), 50.0)))
    rec = read_recording(write(tmp_path, "gap.csv", "Time (s),Bx (uT),By (uT),Bz (uT),,Temp (C)\n" + rows + "\n"))
    assert rec.mag_names() == ("Bx", "By", "Bz") and "column5" not in rec.columns and "Temp" in rec.columns
    assert rec.metadata["text_columns"] == "column5 (empty)"


def test_an_unnamed_column_with_values_gets_a_name(tmp_path):
    rec = read_recording(write(tmp_path, "named.csv", "mx,my,,mz\n1,2,7,3\n4,5,8,6\n"))
    assert rec.columns["column3"].tolist() == [7, 8] and rec.mag_names() == ("mx", "my", "mz")


# -- D6: a blank cell in a column the magnetometer does not need ------------------------------------------------

def test_a_blank_temperature_cell_is_nan_said_as_nan_written_is(tmp_path):
    rows = [f"{0.02 * k:.2f},{x:.3f},{y:.3f},{z:.3f},{25 + k / 1000:.3f}" for k, (x, y, z) in
            enumerate(sphere(30, (0, 0, 0), 50.0))]
    rows[10] = rows[10].rsplit(",", 1)[0] + ","
    rows[20] = rows[20].rsplit(",", 1)[0] + ","
    rec = read_recording(write(tmp_path, "blank.csv", "t,mx,my,mz,temp\n" + "\n".join(rows) + "\n"))
    assert len(rec) == 30 and np.isnan(rec.columns["temp"]).sum() == 2
    assert rec.metadata["blank_cells"] == "temp: 2 (first on line 12) read as NaN"
    rows[5] = "0.10,,1.0,2.0,25.0"  # the magnetometer's blank cell stays a bad line
    with pytest.raises(ValueError, match=r"blank.csv, line 7, column 'mx': empty"):
        read_recording(write(tmp_path, "blank.csv", "t,mx,my,mz,temp\n" + "\n".join(rows) + "\n"))


# -- D4: units rows quoted, or with cells that are no units -----------------------------------------------------

def test_a_quoted_units_row_is_units_not_the_header(tmp_path):
    rows = "\n".join(f"{0.1 * k:.1f},{x:.1f},{y:.1f},{z:.1f}" for k, (x, y, z) in
                     enumerate(sphere(30, (0, 0, 0), 48000.0)))
    rec = read_recording(write(tmp_path, "q.csv", '"t","Bx","By","Bz"\n"s","nT","nT","nT"\n' + rows + "\n"))
    assert rec.mag_names() == ("Bx", "By", "Bz") and rec.units["Bx"] == "nT" and len(rec) == 30


def test_campbell_toa5_head_is_read(tmp_path):
    rows = "\n".join(f'"2024-03-01 12:00:{k // 10:02d}.{k % 10}",{k},{x:.1f},{y:.1f},{z:.1f},21.3' for k, (x, y, z)
                     in enumerate(sphere(30, (0, 0, 0), 48000.0)))
    head = ('"TOA5","MagStation","CR1000","12345","CR1000.Std.32","CPU:mag.CR1","4321","Mag10Hz"\n'
            '"TIMESTAMP","RECORD","Bx","By","Bz","PTemp_C"\n"TS","RN","nT","nT","nT","Deg C"\n')
    for processing in ('"","","Smp","Smp","Smp","Smp"\n', ""):
        rec = read_recording(write(tmp_path, "toa5.dat", head + processing + rows + "\n"))
        assert rec.mag_names() == ("Bx", "By", "Bz") and rec.units["Bx"] == "nT" and len(rec) == 30


# -- D3: quoted decimal commas in a comma-delimited table -------------------------------------------------------

def test_quoted_decimal_commas_of_a_comma_delimited_table_are_read(tmp_path):
    m = sphere(30, (11.7, -18.8, 30.6), 48.0)
    rows = "\n".join(f'"{0.05 * k:.2f}","{x:.2f}","{y:.2f}","{z:.2f}"'.replace(".", ",") for k, (x, y, z) in
                     enumerate(m))
    rec = read_recording(write(tmp_path, "de.csv", "Zeit,Bx,By,Bz\n" + rows + "\n"))
    assert np.allclose(rec.samples(), np.round(m, 2)) and rec.metadata["decimal_separator"].startswith("comma")
    # 1,234 alone says nothing: left as text, as before
    rec = read_recording(write(tmp_path, "k.csv", 'mx,my,mz,n\n1,2,3,"1,234"\n4,5,6,"2,345"\n'))
    assert "n" not in rec.columns


def test_gauss_as_gs_or_before_an_axis_index_is_the_files_unit(tmp_path):
    """PX4's vehicle_magnetometer export names its axes magnetometer_ga[0..2] (gauss before the index), and some
    loggers write gauss as Gs: both had been left without a unit (or as "Gs", which nothing converts)."""
    px4 = tmp_path / "vehicle_magnetometer_0.csv"
    px4.write_text("timestamp,magnetometer_ga[0],magnetometer_ga[1],magnetometer_ga[2]\n"
                   "1000,0.21,-0.05,0.40\n2000,0.22,-0.04,0.41\n3000,0.20,-0.06,0.39\n")
    rec = read_recording(px4)
    assert [rec.units[n] for n in rec.mag_names()] == ["G"] * 3
    from fluxcal.io.columns import unit_name
    assert unit_name("Gs") == "G" and unit_name("[gs]") == "G"


def test_a_gzip_compressed_log_is_read_and_a_cut_one_named(tmp_path):
    """A rotated logger's log.csv.gz had been refused as "byte 0x8b is not text … a binary file"."""
    import gzip

    text = "t,mx,my,mz\n" + "".join(f"{k},{20 + k % 7}.5,-5.25,40.125\n" for k in range(30))
    packed = tmp_path / "log.csv.gz"
    packed.write_bytes(gzip.compress(text.encode()))
    plain = tmp_path / "log.csv"
    plain.write_text(text)
    a, b = read_recording(packed), read_recording(plain)
    assert list(a.columns) == list(b.columns) and all(np.array_equal(a.columns[k], b.columns[k]) for k in a.columns)
    cut = tmp_path / "cut.csv.gz"
    cut.write_bytes(gzip.compress(text.encode())[:-12])
    with pytest.raises(ValueError, match=r"cut\.csv\.gz: gzip-compressed, but cannot be decompressed"):
        read_recording(cut)


def test_read_csv_points_other_formats_to_read_recording_and_one_unit_to_units(tmp_path):
    from fluxcal import read_csv

    lines = tmp_path / "mag.jsonl"
    lines.write_text("".join(f'{{"ts": {k}, "mag": {{"x": 1.{k}, "y": 2, "z": 3}}}}\n' for k in range(5)))
    with pytest.raises(ValueError, match=r"looks like JSON records, not a table: read it with fluxcal.read_recording"):
        read_csv(lines)
    assert read_recording(lines).mag_names()  # (which does read it)
    one = tmp_path / "one.csv"
    one.write_text("t,mx [uT],my,mz\n0,1,2,3\n1,2,3,4\n")
    with pytest.raises(ValueError, match=r"\(mx: uT, my: none, mz: none\); if they share uT, state it for all "
                                         r"\(--units uT"):
        read_recording(one).field_units()
