"""Recording formats: round trips (CSV, .npz, .mat, Parquet, JSON) keep columns bit for bit, units and
metadata; foreign .mat/.npz/Parquet files are read by the stated rule; damaged files are a ValueError
naming the file; every text reader names file, line and column; the real recordings of others are read
as they are, and `fluxcal calibrate` runs on each of them."""
import json
import re

import numpy as np
import pytest
from scipy.io import savemat

from conftest import run_cli, simulated
from fluxcal import attitude
from fluxcal.io import Recording, read_recording, sniff, write_recording


def sample_recording(n=50, seed=0):
    rng = np.random.default_rng(seed)
    cols = {"t": np.arange(n) * 0.01, "mx": rng.normal(size=n) * 3e4, "my": rng.normal(size=n) * 3e4,
            "mz": rng.normal(size=n) * 3e4, "temp": 20 + rng.normal(size=n) / 3, "temp-outside": rng.normal(size=n)}
    units = {"t": "s", "mx": "nT", "my": "nT", "mz": "nT", "temp": "degC"}
    return Recording(columns=cols, units=units, metadata={"sensor": "RM3100", "operator": "a, b: c"})


@pytest.mark.parametrize("suffix", [".csv", ".npz", ".mat", ".parquet", ".json"])
def test_round_trip_keeps_columns_units_and_metadata(tmp_path, suffix):
    rec = sample_recording()
    if suffix != ".csv":  # CSV metadata are text; the other formats keep JSON values
        rec.metadata.update(gain=2.5, axes=["x", "y", "-z"])
    path = write_recording(tmp_path / f"rec{suffix}", rec)
    back = read_recording(path)
    assert list(back.columns) == list(rec.columns)
    for name in rec.columns:
        np.testing.assert_array_equal(back.columns[name], rec.columns[name])  # bit for bit
    assert back.units == rec.units and back.metadata == rec.metadata
    assert back.field_units() == "nT" and back.samples().shape == (50, 3)


def test_content_decides_not_the_extension(tmp_path):
    rec = sample_recording()
    for suffix, kind in [(".npz", "npz"), (".mat", "mat"), (".parquet", "parquet"), (".json", "json"), (".csv", "text")]:
        written = write_recording(tmp_path / f"r{suffix}", rec)
        renamed = written.rename(tmp_path / f"r{suffix}.dat")
        assert sniff(renamed) == kind
        np.testing.assert_array_equal(read_recording(renamed).samples(), rec.samples())
    with pytest.raises(ValueError, match=r"r.txt: unknown recording extension '.txt'"):
        write_recording(tmp_path / "r.txt", rec)


def test_foreign_mat_files(tmp_path):
    rng = np.random.default_rng(1)
    d, acc, t = rng.normal(size=(40, 3)), rng.normal(size=(40, 3)), np.arange(40.0).reshape(-1, 1)
    # a MATLAB magcal user's file: one N×3 matrix (plus a time vector and a scalar)
    savemat(tmp_path / "magcal.mat", {"D": d, "t": t, "fs": 50.0})
    rec = read_recording(tmp_path / "magcal.mat", units="uT")
    np.testing.assert_array_equal(rec.samples(), d)
    np.testing.assert_array_equal(rec.columns["t"], t.ravel())
    assert rec.metadata["magnetometer_variable"] == "D" and rec.metadata["fs"] == 50.0 and rec.field_units() == "uT"
    # two N×3 matrices: the reader asks which; --columns NAME picks it, the other keeps its columns
    savemat(tmp_path / "two.mat", {"mag": d, "acc": acc})
    with pytest.raises(ValueError, match=r"two.mat: several N×3 variables \(.*\); name the magnetometer one"):
        read_recording(tmp_path / "two.mat")
    rec = read_recording(tmp_path / "two.mat", columns="mag")
    np.testing.assert_array_equal(rec.samples(), d)
    np.testing.assert_array_equal(rec.columns["acc_y"], acc[:, 1])
    with pytest.raises(ValueError, match=r"two.mat: no N×3 variable 'gyro'"):
        read_recording(tmp_path / "two.mat", columns="gyro")
    # a struct of fields
    savemat(tmp_path / "struct.mat", {"log": {"mag": d, "t": t}})
    np.testing.assert_array_equal(read_recording(tmp_path / "struct.mat").samples(), d)
    # readings in columns (3×N) are refused with the hint
    savemat(tmp_path / "wide.mat", {"D": d.T})
    with pytest.raises(ValueError, match=r"wide.mat: no N×3 magnetometer matrix .* D \(3×40\).*transposed"):
        read_recording(tmp_path / "wide.mat")
    # a complex or text N×3 matrix: the listing says its type is the problem, not only its shape
    np.savez(tmp_path / "complex.npz", m=d.astype(complex))
    with pytest.raises(ValueError, match=r"complex.npz: no N×3 .* m \(40×3 complex128, not real numbers\)"):
        read_recording(tmp_path / "complex.npz")


def test_foreign_npz_npy_and_parquet(tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq

    rng = np.random.default_rng(2)
    d = rng.normal(size=(30, 3))
    np.savez(tmp_path / "plain.npz", mag=d, t=np.arange(30.0), other=np.arange(7.0))
    rec = read_recording(tmp_path / "plain.npz")
    np.testing.assert_array_equal(rec.samples(), d)
    assert "other (length 7, not 30)" in rec.metadata["ignored_variables"]  # nothing vanishes unmentioned
    np.save(tmp_path / "plain.npy", d)
    np.testing.assert_array_equal(read_recording(tmp_path / "plain.npy").samples(), d)
    table = pa.table({"time": pa.array(np.arange(30) * 1_000_000, pa.timestamp("us")),
                      "x": pa.array((d[:, 0] * 1000).astype(np.int16)), "y": d[:, 1], "z": d[:, 2],
                      "label": ["a"] * 30})
    pq.write_table(table, tmp_path / "foreign.parquet")
    rec = read_recording(tmp_path / "foreign.parquet")
    assert rec.mag_names() == ("x", "y", "z") and rec.units["time"] == "s"
    np.testing.assert_array_equal(rec.columns["time"], np.arange(30.0))
    assert rec.metadata["ignored_columns"] == "label (string)"
    nulls = pa.table({"mx": pa.array([1.0, None, 3.0]), "my": [1.0, 2.0, 3.0], "mz": [1.0, 2.0, 3.0]})
    pq.write_table(nulls, tmp_path / "nulls.parquet")
    with pytest.raises(ValueError, match=r"nulls.parquet: row 1, column 'mx' is nan"):
        read_recording(tmp_path / "nulls.parquet").samples()


def write_matlab_v73(path, variables):
    """A MATLAB v7.3 .mat as MATLAB writes it: HDF5 behind a 512-byte header, arrays column-major (a
    MATLAB N×3 stored 3×N), char arrays as uint16 with MATLAB_class 'char'."""
    import h5py

    with h5py.File(path, "w", userblock_size=512) as f:
        for name, value in variables.items():
            if isinstance(value, str):
                f.create_dataset(name, data=np.array([[ord(c) for c in value]], dtype=np.uint16).T)
                f[name].attrs["MATLAB_class"] = np.bytes_("char")
            else:
                f.create_dataset(name, data=np.atleast_2d(np.asarray(value, dtype=float)).T)
                f[name].attrs["MATLAB_class"] = np.bytes_("double")
        f.create_group("#refs#")
    with open(path, "r+b") as f:
        f.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Wed Nov 25 09:00:00 2026 HDF5 schema 1.00 .")


def test_matlab_v73_and_other_hdf5_files(tmp_path):
    import h5py

    m = simulated(6, n=200, field_norm=50.0).readings
    path = tmp_path / "magcal_v73.mat"
    write_matlab_v73(path, {"D": m, "t": np.arange(200) * 0.1, "sensor": "LIS3MDL"})
    assert sniff(path) == "hdf5"
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.samples(), m)  # N×3 as in MATLAB, not 3×N
    assert rec.metadata["format"] == "MATLAB v7.3 (HDF5)" and rec.metadata["sensor"] == "LIS3MDL"
    assert rec.metadata["magnetometer_variable"] == "D" and rec.time()[1] == 0.1
    r = run_cli("calibrate", path)
    assert r.returncode == 0 and "offset b" in r.stdout, r.stderr
    plain = tmp_path / "survey.h5"  # an instrument's own HDF5: row-major, units as attributes
    with h5py.File(plain, "w") as f:
        f.create_dataset("imu/mag", data=m).attrs["units"] = "nT"
        f.create_dataset("imu/acc", data=np.ones((200, 3)))
        f.create_dataset("imu/time", data=np.arange(200) * 0.1)
    with pytest.raises(ValueError, match=r"survey.h5: several N×3 variables \(imu/acc, imu/mag\); name the magnetometer"):
        read_recording(plain)
    rec = read_recording(plain, columns="imu/mag")
    np.testing.assert_array_equal(rec.samples(), m)
    assert rec.field_units() == "nT" and rec.metadata["format"] == "HDF5"
    plain.write_bytes(plain.read_bytes()[:3000])
    with pytest.raises(ValueError, match=r"survey.h5: not a readable HDF5 file"):
        read_recording(plain)


@pytest.mark.parametrize("suffix", [".npz", ".mat", ".parquet", ".npy"])
def test_truncated_or_corrupt_binary_files_are_clear_errors(tmp_path, suffix):
    rec = sample_recording(n=400)
    path = tmp_path / f"rec{suffix}"
    if suffix == ".npy":
        np.save(path, rec.samples())
    else:
        write_recording(path, rec)
    data = path.read_bytes()
    for damaged in (data[: len(data) // 2], data[:40] + bytes(len(data) - 40)):
        path.write_bytes(damaged)
        with pytest.raises(ValueError, match=rf"rec{re.escape(suffix)}: (not a readable|no N×3|an HDF5)"):
            read_recording(path)
    r = run_cli("calibrate", path)
    assert r.returncode == 2 and f"rec{suffix}" in r.stderr and "Traceback" not in r.stderr


# -- text readers: file, line and column --------------------------------------------------------------------------

AIRBORNE_ROW = "46370.0\t-45289.2\t-16300.6\t-23482.6\t4.52\t16.79\t219.76\t17751.1\t-3975.9\t50750.9\n"


@pytest.mark.parametrize("name, body, message", [
    ("garbled.csv", "mx,my,mz\n1,2,3\n4,5\x00,6\n", r"garbled.csv, line 3, column 'my': '5\\x00' is not a number"),
    ("binary.csv", "mx,my,mz\n1,2,3\n1,\udcff2,3\n", r"binary.csv, line 3, column 'my': '\ufffd2' is not a number "
                                                      r"\(bytes that are not text: garbage from a serial line\?\)"),
    ("binary.bin", "mx,my,mz\n1,2,3\n\udcff\udcfe\x00\udc80\n", r"binary.bin, line 3, column 1 \(character\): byte 0xff "
                                                              r"is not text"),
    ("renamed.mat", "\udcb8\udc9f\x00\udc81\x00\udc90" * 20,  # not a .mat from its first byte: no line to name
     r"renamed.mat: named as a MATLAB .mat file, but it does not start as one \(nor is it text\)"),
    ("short.csv", "mx,my,mz\n1,2,3\n4,5\n", r"short.csv, line 3: 2 fields, the header has 3: column 'mz' \(field 3\) is missing"),
    ("long.csv", "mx,my,mz\n1,2,3\n4,5,6,7\n", r"long.csv, line 3: 4 fields, the header has 3: field 4 \('7'\) has no column"),
    ("qmc.csv", "Fs,50.00\nInitialization time,60\nmx,my,mz\n1,2,3\n4,5\n",
     r"qmc.csv, line 5: 2 fields, the header has 3: column 'mz' \(field 3\) is missing"),
    ("flight.tsv", AIRBORNE_ROW * 3 + AIRBORNE_ROW.replace("-23482.6", "-2348x.6") + AIRBORNE_ROW,
     r"flight.tsv, line 4, column 'mz': '-2348x.6' is not a number"),
    ("flight_cut.tsv", AIRBORNE_ROW * 3 + "46370.0\t-45289.2\t-16300.6\n",
     r"flight_cut.tsv, line 4: 3 fields, the airborne layout has 10: column 'mz' \(field 4\) is missing"),
    ("shots.json", '{"mag": [[1, 2, 3],\n  [4, 5]],\n "grav": [[0, 0, 9.8], [0, 0, 9.8]]}',
     r"shots.json, line 2, column 3 \(character; mag\[1\]\): mag\[1\] = \[4, 5\] is not a triple"),
    ("cut.json", '{"mag": [[1, 2, 3],\n  [4, 5, 6],\n  [7, 8',
     r"cut.json, line 3, column 8 \(character\): not valid JSON .*truncated"),
    ("own.json", '{"kind": "fluxcal recording",\n "columns": {"mx": [1, 2], "my": [1, "2"], "mz": [1, 2]}}',
     r"own.json, line 2, column 38 \(character; columns.my\[1\]\): my\[1\] = \"2\" is not a number"),
    ("numbers.txt", "1 2 3 4\n5 6 7 8\n", r"numbers.txt, line 1: 4 whitespace-separated numbers and no header; "
                                          r"name the columns with --columns"),
    ("ten.tsv", "1\t2\t3\t4\t5\t6\t7\t8\t9\t10\n" * 3, r"ten.tsv, line 1: 10 tab-separated numbers and no header"),
])
def test_every_text_reader_names_file_line_and_column(tmp_path, name, body, message):
    path = tmp_path / name
    path.write_bytes(body.encode("utf-8", "surrogateescape"))
    with pytest.raises(ValueError, match=message):
        read_recording(path)


def test_headerless_tables_named_by_columns(tmp_path):
    path = tmp_path / "numbers.txt"
    path.write_text("0.0 1 2 3\n0.1 4 5 6\n")
    rec = read_recording(path, columns="t,mx,my,mz", units="counts")
    np.testing.assert_array_equal(rec.samples(), [[1, 2, 3], [4, 5, 6]])
    assert rec.field_units() == "counts" and rec.line_numbers.tolist() == [1, 2]
    with pytest.raises(ValueError, match=r"--columns \(columns=\) gives 3 names, need one per column"):
        read_recording(path, columns="a,b,c")
    (tmp_path / "three.csv").write_text("1,2,3\n4,5,6\n")
    np.testing.assert_array_equal(read_recording(tmp_path / "three.csv", columns="bx,by,bz").samples()[1], [4, 5, 6])


def test_comment_lines_among_the_data_are_kept_as_notes(tmp_path):
    path = tmp_path / "r.csv"
    path.write_text("mx,my,mz\n1,2,3\n# reconnected after 2.0 s\n4,5,6\n")
    rec = read_recording(path)
    assert len(rec) == 2 and rec.line_numbers.tolist() == [2, 4]
    assert rec.metadata["notes"] == "line 3: reconnected after 2.0 s"


def test_decimal_commas_of_a_semicolon_or_tab_table_are_read(tmp_path):
    path = tmp_path / "excel.csv"  # a European spreadsheet export
    path.write_text("# logged 1,5 h after power-up\nBx [uT];By [uT];Bz [uT]\n-0,5;1,25;3\n# a note, kept\n4,5e1;-,5;6\n")
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.samples(), [[-0.5, 1.25, 3], [45, -0.5, 6]])
    assert rec.field_units() == "uT" and rec.metadata["decimal_separator"] == "comma"
    assert rec.metadata["notes"] == "line 4: a note, kept"
    tabbed = tmp_path / "tabbed.txt"
    tabbed.write_text("mx\tmy\tmz\n1,5\t2\t3\n")
    np.testing.assert_array_equal(read_recording(tabbed).samples(), [[1.5, 2, 3]])
    # a decimal point anywhere: commas are not decimal separators, and the error names the cell
    mixed = tmp_path / "mixed.csv"
    mixed.write_text("mx;my;mz\n1.5;2;3\n1,5;2;3\n")
    with pytest.raises(ValueError, match=r"line 3, column 'mx': '1,5' is not a number"):
        read_recording(mixed)


def test_a_german_export_with_a_dotted_date_column_keeps_its_decimal_commas(tmp_path):
    # Excel's German CSV: a Zeit column 14.03.2026 09:26:53 beside readings to three decimals (-3,342) had made
    # every reading column look like 1,234 beside a decimal point, and the file was refused
    path = tmp_path / "de.csv"
    path.write_text("Zeit;X (µT);Y (µT);Z (µT)\n14.03.2026 09:26:53,000;-3,342;-4,726;-45,408\n"
                    "14.03.2026 09:26:53,100;-36,114;-29,139;-4,171\n", encoding="utf-8")
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.samples(), [[-3.342, -4.726, -45.408], [-36.114, -29.139, -4.171]])
    np.testing.assert_allclose(rec.time(), [0.0, 0.1])
    assert rec.field_units() == "uT" and rec.metadata["decimal_separator"] == "comma"


def test_decimal_given_settles_the_commas_of_a_semicolon_table(tmp_path):
    # 1,234 beside a time's decimal point: either reading fits, so none is guessed; --decimal says which
    path = tmp_path / "either.csv"
    path.write_text("t;Bx;By;Bz\n0.1;1,234;2,345;3,456\n0.2;1,240;2,350;3,460\n")
    with pytest.raises(ValueError, match=r"no value says.*--decimal , \(decimal commas\) or --decimal \."):
        read_recording(path).samples()
    np.testing.assert_array_equal(read_recording(path, decimal=",").samples(), [[1.234, 2.345, 3.456],
                                                                               [1.24, 2.35, 3.46]])
    np.testing.assert_array_equal(read_recording(path, decimal=".").samples(), [[1234, 2345, 3456],
                                                                               [1240, 2350, 3460]])
    np.testing.assert_array_equal(read_recording(path, thousands=",").samples()[0], [1234, 2345, 3456])
    grouped = tmp_path / "grouped.csv"  # decimal=',' also drops points that group thousands before the comma
    grouped.write_text("t;Bx;By;Bz\n0,1;45.199,6;-1,5;2\n")
    np.testing.assert_array_equal(read_recording(grouped, decimal=",").samples(), [[45199.6, -1.5, 2]])
    comma = tmp_path / "comma.csv"  # a comma-delimited table's commas are its delimiters
    comma.write_text("mx,my,mz\n1,2,3\n")
    with pytest.raises(ValueError, match=r"comma.csv: decimal= and thousands= apply to .* tab"):
        read_recording(comma, decimal=",")
    rng = np.random.default_rng(7)  # a sphere of radius 30 about (50, 50, 50): every cell 20,000–80,000
    u = rng.normal(size=(300, 3))
    field = 50 + 30 * u / np.linalg.norm(u, axis=1, keepdims=True)
    sphere = tmp_path / "sphere.csv"
    sphere.write_text("t;Bx;By;Bz\n" + "".join(f"{0.1 * k:.1f};" + ";".join(f"{v:.3f}".replace(".", ",") for v in row)
                                               + "\n" for k, row in enumerate(field)))
    out = run_cli("calibrate", str(sphere), "--decimal", ",", "-o", tmp_path / "cal.json")
    assert out.returncode == 0, out.stderr
    np.testing.assert_allclose(json.loads((tmp_path / "cal.json").read_text())["offset"], [50, 50, 50], atol=0.01)


def test_a_banner_states_one_unit_for_the_magnetometer(tmp_path):
    body = "t_s,x,y,z\n0,1,2,3\n0.1,4,5,6\n"
    for banner in ("# Units: nT", "# units: nT", "# UNIT: nanotesla"):
        path = tmp_path / "banner.csv"
        path.write_text(f"# FluxLogger FL-300\n{banner}\n{body}")
        rec = read_recording(path)
        assert rec.field_units() == "nT" and rec.units.get("t_s") != "nT", banner
    assert read_recording(path, units="nT").field_units() == "nT"
    with pytest.raises(ValueError, match=r"units 'uT' given, but the file's comment says nT"):
        read_recording(path, units="uT")
    own = tmp_path / "own.csv"  # the header and the banner disagree: neither is guessed right
    own.write_text("# units: nT\nt_s,x (uT),y (uT),z (uT)\n0,1,2,3\n")
    with pytest.raises(ValueError, match=r"own.csv: column 'x' is in uT by the header but in nT by the file's"):
        read_recording(own).field_units()


def test_decimal_commas_are_read_per_column_beside_decimal_points(tmp_path):
    # ISO times with a decimal point beside decimal-comma readings: every reading column was left out as text
    iso = tmp_path / "iso.csv"
    iso.write_text("time;Bx;By;Bz\n2024-01-01T12:00:00.1;12,5;-3,25;40\n2024-01-01T12:00:00.2;13,5;-3,5;41,0\n")
    rec = read_recording(iso)
    np.testing.assert_array_equal(rec.samples(), [[12.5, -3.25, 40], [13.5, -3.5, 41]])
    np.testing.assert_allclose(rec.time(), [0.0, 0.1])
    assert rec.metadata["decimal_separator"] == "comma"
    mixed = tmp_path / "mixed.csv"  # one column written by another program, with a decimal point
    mixed.write_text("t;Bx;By;Bz\n0;12,5;-3.25;40,0\n1;13,5;-3.5;41,0\n")
    np.testing.assert_array_equal(read_recording(mixed).samples(), [[12.5, -3.25, 40], [13.5, -3.5, 41]])
    # 1,234 beside 0.5 may be a thousands separator: not guessed; the error says which column was text
    thousands = tmp_path / "thousands.csv"
    thousands.write_text("n;Bx;By;Bz\n1;1,234;0.5;3.0\n2;2,345;0.6;3.1\n")
    with pytest.raises(ValueError, match=r"columns are: n, By, Bz; left out as text: Bx \(e.g. 1,234, 2,345: thousands separators or decimal commas\? no value says"):
        read_recording(thousands).samples()


def test_a_row_of_units_under_the_header_and_a_headerless_decimal_comma_table(tmp_path):
    path = tmp_path / "logger.csv"  # a data logger's export: names, then units, then numbers
    path.write_text("Time;Bx;By;Bz;Status\n(s);(µT);[µT];µT;\n0,0;-0,5;1,25;3;1\n0,1;4,5e1;-,5;6;1\n")
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.samples(), [[-0.5, 1.25, 3], [45, -0.5, 6]])
    assert rec.units == {"Time": "s", "Bx": "µT", "By": "µT", "Bz": "µT"} and rec.line_numbers.tolist() == [3, 4]
    assert rec.time().tolist() == [0.0, 0.1] and rec.metadata["decimal_separator"] == "comma"
    # a placeholder under a column without a unit (a position number): still a row of units (a blind check: the
    # units row had been taken for the header, "empty or repeated column names")
    for placeholder in ("-", "n"):
        marked = tmp_path / "marked.csv"
        marked.write_text(f"position;ax;ay;az;mx;my;mz\n{placeholder};g;g;g;µT;µT;µT\n1;0;0;1;20;1;45\n2;0;1;0;21;2;44\n")
        rec = read_recording(marked)
        assert rec.units == {"ax": "g", "ay": "g", "az": "g", "mx": "µT", "my": "µT", "mz": "µT"}
        assert rec.columns["position"].tolist() == [1.0, 2.0] and rec.line_numbers.tolist() == [3, 4]
    # a first data row that merely lacks numbers is not a row of units: it stays an error
    garbled = tmp_path / "garbled.csv"
    garbled.write_text("mx,my,mz\nabc,de,f\n1,2,3\n")
    with pytest.raises(ValueError, match=r"garbled.csv, line 2, column 'mx': 'abc' is not a number"):
        read_recording(garbled)
    bare = tmp_path / "bare.csv"  # no header, ';' and decimal commas: read once the columns are named
    bare.write_text("0,00;-13,5;27,25;-17\n0,02;-13,25;27;-16,5\n")
    with pytest.raises(ValueError, match=r"4 ';'-separated numbers and no header"):
        read_recording(bare)
    rec = read_recording(bare, columns="t,mx,my,mz")
    np.testing.assert_array_equal(rec.samples(), [[-13.5, 27.25, -17], [-13.25, 27, -16.5]])
    assert rec.metadata["decimal_separator"] == "comma"


@pytest.mark.parametrize("encoding", ["cp1252", "utf-16"])
def test_a_windows_export_in_its_own_encoding_is_read(tmp_path, encoding):
    path = tmp_path / "export.csv"  # a legacy Windows program's export, or a PowerShell redirect (UTF-16)
    path.write_bytes("Zeit [s];Bx [µT];By [µT];Bz [µT];Temperatur [°C]\n0,0;-0,5;1,25;3;21,5\n0,1;45;-0,5;6;21,5\n"
                     .encode(encoding))
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.samples(), [[-0.5, 1.25, 3], [45, -0.5, 6]])
    assert rec.field_units() == "uT" and rec.units["Temperatur"] == "°C" and rec.time().tolist() == [0.0, 0.1]
    assert rec.temperature().tolist() == [21.5, 21.5]


def test_an_excel_workbook_is_read_from_its_first_sheet_of_numbers(tmp_path):
    import datetime as dt

    import openpyxl

    m = np.random.default_rng(4).normal(size=(30, 3)) * 20.0
    book = openpyxl.Workbook()
    info = book.active
    info.title = "Info"
    info.append(["Operator", "B. Smith"])
    data = book.create_sheet("Data")  # a title row, and the table starting in column C
    data.append([None, None, "Bench run 4"])
    data.append([None, None, "Timestamp", "Bx", "By", "Bz", "Temp"])
    data.append([None, None, None, "µT", "µT", "µT", "°C"])
    for k, row in enumerate(m):
        data.append([None, None, dt.datetime(2026, 11, 25, 9, 0, 0) + dt.timedelta(seconds=0.5 * k), *map(float, row),
                     21.5])
    data.cell(row=11, column=5, value="#N/A")  # spreadsheet errors in cells, one where a line's '#' would start
    data.cell(row=14, column=3, value="#VALUE!")
    path = tmp_path / "bench.xlsx"
    book.save(path)
    assert sniff(path) == "xlsx"
    with pytest.raises(ValueError, match=r"bench.xlsx, sheet 'Data', row 11: column 'By': 'Excel error #N/A' is not a "
                                         r"number"):
        read_recording(path)
    rec = read_recording(path, bad_lines="skip")
    assert rec.metadata["skipped_lines"].startswith("2 of 30: row 11 (column 'By'") and "row 14 (column 'Timestamp'" in \
        rec.metadata["skipped_lines"]
    assert rec.metadata["comments"] == "Bench run 4"  # the title row, kept
    # as stored: openpyxl writes 16 significant digits (Excel itself keeps 15)
    np.testing.assert_allclose(rec.samples(), np.delete(m, [7, 10], axis=0), rtol=1e-15, atol=0)
    assert rec.field_units() == "uT" and rec.temperature()[0] == 21.5 and rec.time()[1] == 0.5
    assert rec.metadata["sheet"] == "Data" and rec.metadata["other_sheets"] == "Info"
    (tmp_path / "old.xls").write_bytes(b"\xd0\xcf\x11\xe0\xa1\xb1\x1a\xe1" + bytes(500))
    with pytest.raises(ValueError, match=r"old.xls: a legacy binary Excel \(.xls\).*save the sheet as .xlsx or CSV"):
        read_recording(tmp_path / "old.xls")
    empty = openpyxl.Workbook()
    empty.active.append(["notes only"])
    empty.save(tmp_path / "notes.xlsx")
    with pytest.raises(ValueError, match=r"notes.xlsx: no sheet holds rows of numbers \(sheets: Sheet\)"):
        read_recording(tmp_path / "notes.xlsx")


def test_comment_lines_marked_the_xsens_or_matlab_way(tmp_path):
    xsens = tmp_path / "MT_0001.txt"  # MT Manager's export: '//' lines, then a tab-delimited table
    xsens.write_text("// Start Time: 2026-11-25 09:00:00\n// Update Rate: 100.0Hz\n// Filter Profile: human (46.1)\n"
                     "PacketCounter\tAcc_X\tAcc_Y\tAcc_Z\tMag_X\tMag_Y\tMag_Z\n"
                     "0\t0.1\t0.2\t9.8\t0.51\t-0.2\t0.33\n1\t0.1\t0.2\t9.8\t0.52\t-0.21\t0.34\n")
    rec = read_recording(xsens)
    np.testing.assert_array_equal(rec.samples(), [[0.51, -0.2, 0.33], [0.52, -0.21, 0.34]])
    assert rec.metadata["Update Rate"] == "100.0Hz" and rec.time().tolist() == [0.0, 0.01]
    assert rec.metadata["Start Time"] == "2026-11-25 09:00:00" and rec.acceleration().shape == (2, 3)
    matlab = tmp_path / "bench.txt"  # '%' comments; 'key = value' is metadata too
    matlab.write_text("% exported from the bench rig\n% fs = 50 Hz\nmx my mz\n1 2 3\n% paused\n4 5 6\n")
    rec = read_recording(matlab)
    np.testing.assert_array_equal(rec.samples(), [[1, 2, 3], [4, 5, 6]])
    assert rec.metadata["fs"] == "50 Hz" and rec.time().tolist() == [0.0, 0.02]
    assert rec.metadata["notes"] == "line 5: paused"


def test_a_semicolon_inside_a_text_cell_keeps_the_comma_delimiter(tmp_path):
    path = tmp_path / "flags.csv"
    path.write_text("t,mx,my,mz,flags\n" + "".join(f"{k},1.5,2.5,3.5,ok;cal\n" for k in range(5)))
    rec = read_recording(path)
    assert rec.samples().shape == (5, 3) and rec.metadata["text_columns"] == "flags (e.g. ok;cal)"


def test_a_truncated_last_line_says_how_to_leave_it_out(tmp_path):
    path = tmp_path / "cut.csv"
    path.write_text("mx,my,mz\n1,2,3\n4,5,6\n7,8")
    with pytest.raises(ValueError, match=r"cut.csv, line 4: 2 fields.*--bad-lines skip"):
        read_recording(path)
    rec = read_recording(path, bad_lines="skip")
    assert len(rec) == 2 and rec.metadata["skipped_lines"].startswith("1 of 3: 4 (2 fields")


def _rows(fmt, n=150, seed=3):
    rng = np.random.default_rng(seed)
    return [fmt % tuple(v) for v in rng.normal(0, 30, (n, 3))]


@pytest.mark.parametrize("head, fmt, cut", [
    ("mx,my,mz\n", "%.3f,%.3f,%.3f", lambda last: last[:-2]),                 # 26.345 -> 26.3
    ("mx,my,mz\n", "%.3f,%.3f,%.3f", lambda last: last[:last.rfind(",") + 1] + "-"),  # a lone sign
    ("mx,my,mz\n", "%.4e,%.4e,%.4e", lambda last: last[:-2]),                 # 1.2345e+01 -> 1.2345e+
    ("mx my mz\n", "%9.2f %9.2f %9.2f", lambda last: last[:-1]),              # whitespace table
    ("", "X: %.2f Y: %.2f Z: %.2f", lambda last: last[:-1]),                  # a serial monitor's labelled lines
])
def test_a_file_ending_in_the_middle_of_a_number_is_named_not_read_short(tmp_path, head, fmt, cut):
    rows = _rows(fmt)
    path = tmp_path / "cut.txt"
    path.write_text(head + "\n".join(rows[:-1] + [cut(rows[-1])]))
    with pytest.raises(ValueError, match=r"cut.txt, line \d+.*the file ends in the middle of this line"):
        read_recording(path)
    rec = read_recording(path, bad_lines="skip")
    assert len(rec) == len(rows) - 1 and "the file ends in the middle" in rec.metadata["skipped_lines"]


@pytest.mark.parametrize("text", [
    "mx,my,mz\n" + "\n".join(_rows("%.3f,%.3f,%.3f")),          # whole, only the final newline missing
    "mx,my,mz\n" + "\n".join(_rows("%g,%g,%g")),                # digits vary from line to line
    "mx,my,mz\n" + "\n".join(_rows("%.0f,%.0f,%.0f")),          # integers: a cut cannot be seen
    "mx,my,mz\n" + "\n".join(_rows("%.3f,%.3f,%.3f") + ["1.5,2.5,3.5\n"]),  # fewer decimals, then a newline
])
def test_a_last_line_without_a_newline_is_read_when_nothing_shows_it_cut(tmp_path, text):
    path = tmp_path / "whole.csv"
    path.write_text(text)
    assert len(read_recording(path)) == 150 + text.count("1.5,2.5,3.5")


def test_a_general_format_last_value_without_trailing_zeros_is_not_taken_for_a_cut(tmp_path):
    """%g drops trailing zeros: -19.66 (of -19.6600) after lines that all had four decimals read as "cut short"
    in 2 % of files when 20 lines judged the format (a review); and an ellipsis in a line is text, not the mark."""
    path = tmp_path / "g.csv"
    values = np.r_[np.random.default_rng(0).uniform(10.5, 99.5, (25, 3)).round(4), [[-19.66, 20.1234, 30.5678]]]
    path.write_text("mx,my,mz\n" + "\n".join(",".join(f"{v:g}" for v in row) for row in values))
    assert len(read_recording(path)) == 26
    log = tmp_path / "log.txt"
    log.write_text("".join(f"X: {x:.3f} Y: 2.500 Z: 3.500\n" for x in np.linspace(1, 2, 30)).replace(
        "X: 1.034", "waiting\u2026 X: 1.034"))
    with pytest.raises(ValueError) as err:
        read_recording(log)
    assert "line 2" in str(err.value) and "ends in the middle" not in str(err.value)


@pytest.mark.parametrize("quote, delimiter", [('"', ","), ("", ";"), ("", "\t")])
def test_thousands_separators_of_a_spreadsheet_export_are_read(tmp_path, quote, delimiter):
    rng = np.random.default_rng(4)
    field = rng.normal(0, 30_000, (50, 3))
    def cell(x):
        return quote + format(x, ",.1f") + quote
    path = tmp_path / "export.csv"
    path.write_text(delimiter.join(["t", "mx", "my", "mz"]) + "\n"
                    + "".join(delimiter.join([str(k)] + [cell(x) for x in row]) + "\n" for k, row in enumerate(field)))
    rec = read_recording(path)
    np.testing.assert_allclose(rec.samples(), np.round(field, 1), atol=1e-9)
    assert rec.metadata["thousands_separator"] == "comma (mx, my, mz)"


def test_thousands_grouped_with_points_before_a_decimal_comma_are_read(tmp_path):
    # A European spreadsheet export: 45.199,6 nT (a blind check's file was refused, naming --columns)
    field = np.random.default_rng(6).normal(0, 60_000, (50, 3))

    def cell(x):
        return format(x, ",.1f").replace(",", "_").replace(".", ",").replace("_", ".")

    path = tmp_path / "export.csv"
    path.write_text("t;mx;my;mz\ns;nT;nT;nT\n" + "".join(";".join([f"{k / 50:.2f}".replace(".", ",")]
                                                                 + [cell(x) for x in row]) + "\n"
                                                        for k, row in enumerate(field)))
    rec = read_recording(path)
    np.testing.assert_allclose(rec.samples(), np.round(field, 1), atol=1e-9)
    assert rec.metadata["thousands_separator"] == "point (mx, my, mz)" and rec.field_units() == "nT"
    np.testing.assert_allclose(rec.columns["t"][:3], [0.0, 0.02, 0.04])


def test_quoted_decimal_commas_are_read(tmp_path):
    path = tmp_path / "quoted.csv"
    rows = np.random.default_rng(7).normal(0, 30, (40, 3)).round(3)
    path.write_text("mx;my;mz\n" + "".join(";".join(f'"{v:.3f}"'.replace(".", ",") for v in row) + "\n" for row in rows))
    np.testing.assert_allclose(read_recording(path).samples(), rows, atol=1e-9)


def test_commas_no_value_settles_are_not_guessed(tmp_path):
    path = tmp_path / "export.csv"
    path.write_text("mx,my,mz\n" + "".join(f'"{a:,}","{b:,}","{c:,}"\n' for a, b, c in
                                          np.random.default_rng(5).integers(-40_000, 40_000, (20, 3))))
    with pytest.raises(ValueError, match="mx .*thousands separators or decimal commas\\? no value says, not guessed"):
        read_recording(path)


# -- the real recordings -----------------------------------------------------------------------------------------

def test_real_qmc5883l_preamble(real_data):
    rec = read_recording(real_data / "qmc5883l_filtered.csv")
    assert len(rec) == 22745 and rec.mag_names() == ("mx", "my", "mz")
    assert rec.metadata["sample_rate_hz"] == 50.0 and rec.metadata["initialization_time_s"] == 60.0
    assert rec.field_units() == "counts" and rec.units["t"] == "s"
    np.testing.assert_allclose(rec.columns["t"][:3], [0.0, 0.02, 0.04])
    assert rec.line_numbers[0] == 4  # after Fs, Initialization time and the header
    np.testing.assert_array_equal(rec.samples()[0], [6202, 682, 4812])
    # the report says t was made, not read (the file has no t column)
    assert rec.roles()["time"] == "t = row / Fs (Fs = 50 Hz from line 1)"


def test_real_airborne_layout_and_reference(real_data, tmp_path):
    rec = read_recording(real_data / "airborne_flt1002_02.tsv")
    assert list(rec.columns) == ["t", "mx", "my", "mz", "pitch", "roll", "yaw", "igrf_n", "igrf_e", "igrf_d"]
    assert rec.field_units() == "nT" and rec.units["yaw"] == "deg" and len(rec) == 12301
    assert "declared by airborne_flt1002_02_info.txt" in rec.metadata["layout"]
    assert rec.metadata["mag_earth_intensity"] == pytest.approx(54085.193196)
    d = np.loadtxt(real_data / "airborne_flt1002_02.tsv")  # the reference as tests/python/test_refine.py builds it
    np.testing.assert_allclose(rec.reference_field(), attitude.reference_vectors(d[:, 7:10], d[:, 4], d[:, 5], d[:, 6]))
    # without the info file beside it the numbers alone identify the layout
    lines = (real_data / "airborne_flt1002_02.tsv").read_text().splitlines(keepends=True)
    (tmp_path / "segment.tsv").write_text("".join(lines[:300]))
    rec = read_recording(tmp_path / "segment.tsv")
    assert "the numbers fit it" in rec.metadata["layout"] and len(rec) == 300


def test_real_sap6_shots(real_data):
    rec = read_recording(real_data / "sap6" / "BB.json")
    assert len(rec) == 24 and list(rec.columns) == ["mx", "my", "mz", "ax", "ay", "az"]
    assert rec.field_units() == "uT" and rec.units["az"] == "m/s^2"
    assert rec.metadata["maker_mag_field_avg"] == pytest.approx(43.3819)
    assert rec.metadata["maker_dip_avg_deg"] == pytest.approx(67.8188)
    assert rec.line_numbers.tolist() == [1] * 24  # the file is one line


def test_positions_reads_what_calibrate_reads(real_data, tmp_path):
    # `fluxcal positions` read CSV only: the SAP6 shots (JSON) failed with "header but no data rows".
    out = tmp_path / "pos.json"
    r = run_cli("positions", real_data / "sap6" / "BB.json", "--total", "43.38", "--inclination", "67.8", "-o", out)
    assert r.returncode == 0, r.stderr
    assert "24 positions" in r.stdout
    d = json.loads(out.read_text())
    assert d["units"] == "uT" and d["verification"]["magnitude_error_rms"] < 0.01 * 43.38
    r = run_cli("positions", real_data / "handheld_set1.csv", "--total", "0.47", "--inclination", "50")
    assert r.returncode == 2 and "handheld_set1.csv: no accelerometer columns" in r.stderr


def test_ros_topic_echo_csv(tmp_path):
    # `rostopic echo -p /imu/mag > mag.csv`: the header is a '%' comment and each row has a text frame_id,
    # so the first data row was taken for a header ("empty or repeated column names").
    rng = np.random.default_rng(3)
    u = rng.normal(size=(200, 3))
    m = 45e-6 * u / np.linalg.norm(u, axis=1, keepdims=True) + [1e-5, -5e-6, 3e-6]
    names = ["field.magnetic_field_covariance" + str(k) for k in range(9)]
    head = "%time,field.header.seq,field.header.stamp,field.header.frame_id,field.magnetic_field.x," \
           "field.magnetic_field.y,field.magnetic_field.z," + ",".join(names)
    t0 = 1609060336768429266
    rows = [f"{t0 + k * 10_000_000},{k},{t0 + k * 10_000_000 - 1234},imu_link,{x!r},{y!r},{z!r}," + ",".join(["0.0"] * 9)
            for k, (x, y, z) in enumerate(m.tolist())]
    path = tmp_path / "mag.csv"
    path.write_text(head + "\n" + "\n".join(rows) + "\n")
    rec = read_recording(path)
    assert rec.mag_names() == ("field.magnetic_field.x", "field.magnetic_field.y", "field.magnetic_field.z")
    np.testing.assert_array_equal(rec.samples(), m)
    np.testing.assert_allclose(np.diff(rec.time()), 0.01, rtol=1e-4)  # epoch ns (a double holds them to 256 ns)
    assert rec.metadata["header"] == "the comment on line 1"


def test_diagnose_max_effects_from_the_command_line(real_data):
    # The report said "the max_effects limit stopped the search" and the command line had no way to raise it.
    r = run_cli("diagnose", real_data / "handheld_set1.csv", "--max-effects", "1", "--quiet")
    assert r.returncode == 0, r.stderr
    assert "FOUND: moving_dipole (added in this order)" in r.stdout
    assert "ALSO SIGNIFICANT, not modelled (the max_effects limit stopped the search; --max-effects): " \
           "colored_noise" in r.stdout
    assert "(LR p: the likelihood ratio on residuals whitened" in r.stdout
    r = run_cli("diagnose", real_data / "handheld_set1.csv", "--max-effects", "0")
    assert r.returncode == 2 and "argument --max-effects: 0 is not a positive" in r.stderr


def _number(text, label):
    return float(re.search(re.escape(label) + r"\s+([-\d.e+]+)", text).group(1))


# the spread of |h| after calibration measured on each file (percent), and the airborne held-out RMS (nT)
REAL_FILES = [("handheld_set1.csv", 2.64), ("phone_acc_mag.csv", 1.26), ("qmc5883l_filtered.csv", 2.82),
              ("sap6/BB.json", 0.091), ("sap6/CF.json", 0.079), ("sap6/FG.json", 0.134), ("sap6/HC.json", 0.076),
              ("sap6/IB.json", 0.104), ("sap6/JG.json", 0.101)]


@pytest.mark.parametrize("name, spread", REAL_FILES)
def test_calibrate_runs_on_every_real_file(real_data, tmp_path, name, spread):
    r = run_cli("calibrate", real_data / name, "-o", tmp_path / "cal.json")
    assert r.returncode == 0, r.stderr
    after = _number(r.stdout, "|h| std/mean after")
    assert after == pytest.approx(spread, rel=0.05)
    assert after < 0.3 * _number(r.stdout, "|h| std/mean before")
    assert "method                als+refine" in r.stdout
    saved = json.loads((tmp_path / "cal.json").read_text())
    # every reading is used but the screen's outliers, which are single readings off their neighbours (the QMC5883L:
    # rows 2505 and 15529, 5.2 and 5.5 robust σ off the ellipsoid against a threshold of 5.05 at α = 1 %)
    total = {"handheld_set1.csv": 3000, "phone_acc_mag.csv": 12000, "qmc5883l_filtered.csv": 22745}.get(name, 24)
    outliers = saved["summary"]["outliers"]["count"]
    assert saved["summary"]["samples"] + outliers == total and outliers <= 1e-4 * total


def test_calibrate_airborne_uses_the_reference_vectors(real_data, tmp_path):
    r = run_cli("calibrate", real_data / "airborne_flt1002_02.tsv", "-o", tmp_path / "cal.json")
    assert r.returncode == 0, r.stderr
    assert "method                vector" in r.stdout and "identifiable          yes" in r.stdout
    held_out = _number(r.stdout, "held-out vector RMS")
    assert 100 < held_out < 150  # measured 131.7 nT, as tests/python/test_refine.py
    saved = json.loads((tmp_path / "cal.json").read_text())
    assert saved["units"] == "nT" and saved["summary"]["held_out_rms"] == pytest.approx(held_out, rel=1e-5)
    # a magnitude-only method still runs on request (and its poor coverage is flagged)
    r = run_cli("calibrate", real_data / "airborne_flt1002_02.tsv", "--method", "als")
    assert r.returncode == 0 and "poor coverage" in r.stdout


def test_apply_writes_the_format_of_its_extension(real_data, tmp_path):
    cal = tmp_path / "cal.json"
    assert run_cli("calibrate", real_data / "sap6" / "CF.json", "-o", cal).returncode == 0
    for suffix in (".parquet", ".mat"):
        r = run_cli("apply", cal, real_data / "sap6" / "CF.json", "-o", tmp_path / f"out{suffix}")
        assert r.returncode == 0, r.stderr
        out = read_recording(tmp_path / f"out{suffix}")
        assert out.units["hx"] == "uT" and out.metadata["maker_mag_field_avg"] == pytest.approx(43.3654)
        h = np.column_stack([out.columns[c] for c in ("hx", "hy", "hz")])
        assert np.std(np.linalg.norm(h, axis=1)) / np.mean(np.linalg.norm(h, axis=1)) < 0.002


def test_cli_reports_reader_errors_with_exit_2(tmp_path):
    bad = tmp_path / "shots.json"
    bad.write_text('{"mag": [[1, 2, 3], [4, 5]]}')
    r = run_cli("calibrate", bad)
    assert r.returncode == 2 and "shots.json, line 1, column 21" in r.stderr and "Traceback" not in r.stderr
    table = tmp_path / "table.txt"
    table.write_text("1 2 3 4\n" * 20)
    r = run_cli("calibrate", table)
    assert r.returncode == 2 and "--columns" in r.stderr


def test_a_json_recording_writes_nan_as_null_and_reads_it_back(tmp_path):
    """Standard JSON has no NaN: a bare NaN (as json.dumps writes by default) makes strict parsers refuse the file
    (a blind check). A NaN temperature is written null and read back as NaN."""
    rec = Recording(columns={"mx": np.array([1.0, 2.0]), "my": np.array([3.0, 4.0]), "mz": np.array([5.0, 6.0]),
                             "temp": np.array([21.5, np.nan])}, units={"mx": "uT", "my": "uT", "mz": "uT"})
    path = write_recording(tmp_path / "r.json", rec)
    text = path.read_text()
    assert "NaN" not in text and json.loads(text, parse_constant=lambda c: pytest.fail(f"non-standard {c}"))
    back = read_recording(path)
    assert back.columns["temp"][0] == 21.5 and np.isnan(back.columns["temp"][1])
    np.testing.assert_array_equal(back.samples(), rec.samples())


def test_a_column_a_binary_reader_left_out_is_named_where_the_magnetometer_is_missing(tmp_path):
    # From a bad-input audit: an .npz whose my held 200 readings and mx, mz 300 said "no column 'my'; columns are:
    # mx, mz", as if my were absent; the reader had left it out, and said so only in the metadata.
    m = simulated(2).readings[:300]
    np.savez(tmp_path / "short_my.npz", mx=m[:, 0], my=m[:200, 1], mz=m[:, 2])
    with pytest.raises(ValueError, match=r"columns are: mx, mz; left out: my \(length 200, not 300\)"):
        read_recording(tmp_path / "short_my.npz").mag_names()


def test_select_takes_the_columns_as_one_string_as_columns_does():
    # From a bad-input audit: select("foo,bar,baz") iterated the string's characters ("got f, o, o, ,, b, …").
    rec = Recording(columns={"a": np.zeros(3), "b": np.ones(3), "c": np.arange(3.0)}, source="r")
    assert rec.select("c, a,b").mag_names() == ("c", "a", "b")
    with pytest.raises(ValueError, match="no column 'foo', 'bar', 'baz'"):
        rec.select("foo,bar,baz")


@pytest.mark.parametrize("fmt, cut", [
    ("%.3f,%.3f,%.3f", lambda last: last[:last.rfind(",") + 2]),  # 32.969 -> 3: a whole number, 10x too small
    ("%d,%d,%d", lambda last: last[:-2]),                        # 1234 -> 12
])
def test_a_last_number_cut_in_its_whole_part_is_named_in_a_short_file(tmp_path, fmt, cut):
    """Under 100 lines the decimals cannot judge a cut (%g drops zeros), but a last number shorter than the column's
    and under half its smallest is one (a blind check's 32.969 read as 3 from a 40-line log)."""
    rng = np.random.default_rng(5)
    values = rng.uniform(20, 40, (40, 3)) * (50 if "d" in fmt else 1)
    rows = [fmt % tuple(v) for v in values]
    path = tmp_path / "cut5.csv"
    path.write_text("mx,my,mz\n" + "\n".join(rows[:-1] + [cut(rows[-1])]))
    with pytest.raises(ValueError, match=r"cut5.csv, line 41.*the file ends in the middle of this line"):
        read_recording(path)
    assert len(read_recording(path, bad_lines="skip")) == 39
    if "d" in fmt:
        return
    near_zero = rows[:-5] + ["25,25,0.512"] + rows[-4:-1] + ["20,21,2.5"]  # the column came near zero: 2.5 is read
    path.write_text("mx,my,mz\n" + "\n".join(near_zero))
    assert len(read_recording(path)) == 40
    path.write_text("mx,my,mz\n" + "\n".join(rows[:-1] + ["20,21,20"]))  # shorter, but not smaller: read
    assert len(read_recording(path)) == 40


def test_a_header_written_again_is_left_out_and_one_in_another_order_is_refused(tmp_path):
    m = np.round(np.random.default_rng(6).normal(0, 30, (60, 3)), 3)
    rows = [f"{k},{x},{y},{z}" for k, (x, y, z) in enumerate(m)]
    path = tmp_path / "joined.csv"
    path.write_text("t,mx [uT],my [uT],mz [uT]\n" + "\n".join(rows[:30] + ["t,mx [uT],my [uT],mz [uT]"] + rows[30:])
                    + "\n")
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.samples(), m)
    assert rec.metadata["repeated_header"] == "line 32 (the same columns and units)"
    swapped = [f"{k},{y},{x},{z}" for k, (x, y, z) in enumerate(m)]
    path.write_text("t,mx,my,mz\n" + "\n".join(rows[:30] + ["t,my,mx,mz"] + swapped[30:]) + "\n")
    for bad_lines in ("error", "skip"):
        with pytest.raises(ValueError, match=r"joined.csv, line 32: the header again, with the columns in another "
                                             r"order: t,my,mx,mz.*Split the file at line 32"):
            read_recording(path, bad_lines=bad_lines)
    path.write_text("t,mx [uT],my [uT],mz [uT]\n" + "\n".join(rows[:30] + ["t,mx [nT],my [nT],mz [nT]"] + rows[30:]))
    with pytest.raises(ValueError, match=r"line 32: the header again, with mx in nT, not uT; my in nT"):
        read_recording(path, bad_lines="skip")


def test_magnetometer_vectors_under_their_own_names_in_mat_and_npz(tmp_path):
    """Bx, By, Bz vectors (a LabVIEW or MATLAB log's) had been refused as "no N×3 magnetometer matrix", even with
    --columns Bx,By,Bz; they are the magnetometer by name, and named columns pick among several triples."""
    from scipy.io import savemat

    rng = np.random.default_rng(8)
    d = rng.normal(0, 30, (40, 3))
    savemat(tmp_path / "vectors.mat", {"Bx": d[:, :1], "By": d[:, 1:2], "Bz": d[:, 2:], "T": rng.normal(20, 1, (40, 1))})
    rec = read_recording(tmp_path / "vectors.mat", units="uT")
    np.testing.assert_array_equal(rec.samples(), d)
    np.savez(tmp_path / "two.npz", Bx=d[:, 0], By=d[:, 1], Bz=d[:, 2], Hx=-d[:, 0], Hy=-d[:, 1], Hz=-d[:, 2])
    np.testing.assert_array_equal(read_recording(tmp_path / "two.npz", columns="Hx,Hy,Hz").samples(), -d)
    out = run_cli("calibrate", tmp_path / "two.npz", "--columns", "Bx,By,Bz")
    assert "no N×3" not in out.stderr, out.stderr


def test_picotesla_and_gamma_are_field_units(tmp_path):
    """pT (a SQUID's, an optically pumped magnetometer's) and gamma (the geophysicists' nT) had been left unread."""
    path = tmp_path / "pt.csv"
    path.write_text("t,mx [pT],my [pT],mz [pT]\n0,1000,2000,3000\n1,1100,2100,3100\n")
    assert read_recording(path).field_units() == "pT"
    path.write_text("t,mx [gamma],my [gamma],mz [gamma]\n0,1000,2000,3000\n1,1100,2100,3100\n")
    assert read_recording(path).field_units() == "nT"
    from fluxcal.calibration import TESLA_PER_UNIT
    assert TESLA_PER_UNIT["pT"] == 1e-12


@pytest.mark.parametrize("orient", ["columns", "index"])
def test_pandas_to_json_default_and_index_layouts_are_read(tmp_path, orient):
    """DataFrame.to_json()'s default ({column: {index: value}}) had been read as one record (mx_0, mx_1, …)."""
    import pandas as pd

    d = np.random.default_rng(0).normal(0, 30, (50, 3))
    path = tmp_path / "frame.json"
    pd.DataFrame({"t": np.arange(50) * 0.02, "mx": d[:, 0], "my": d[:, 1], "mz": d[:, 2]}).to_json(path, orient=orient)
    rec = read_recording(path)
    np.testing.assert_allclose(rec.samples(), d, atol=1e-9)  # (to_json writes 10 decimals)
    np.testing.assert_allclose(rec.time(), np.arange(50) * 0.02, atol=1e-9)


def test_a_mat_v4_file_is_read(tmp_path):
    """MAT v4 (save -v4, older instrument software) has no text header: it had been refused as "does not start as
    a MATLAB .mat file"."""
    from scipy.io import savemat

    d = np.random.default_rng(0).normal(0, 30, (40, 3))
    savemat(tmp_path / "v4.mat", {"mag": d}, format="4")
    np.testing.assert_array_equal(read_recording(tmp_path / "v4.mat").samples(), d)
    savemat(tmp_path / "v4vec.mat", {"Bx": d[:, :1], "By": d[:, 1:2], "Bz": d[:, 2:]}, format="4")
    np.testing.assert_array_equal(read_recording(tmp_path / "v4vec.mat").samples(), d)
    (tmp_path / "cut.mat").write_bytes((tmp_path / "v4.mat").read_bytes()[:100])
    with pytest.raises(ValueError, match=r"cut.mat: not a readable MATLAB .mat file \(truncated or corrupt"):
        read_recording(tmp_path / "cut.mat")


def test_a_banner_above_a_table_without_a_header_is_named_as_such(tmp_path):
    """The banner had been taken for the header: "line 2: 3 fields, the header has 1 … (garbled line?)"."""
    d = np.random.default_rng(0).normal(0, 30, (40, 3))
    path = tmp_path / "banner.csv"
    path.write_text("HMC5883L logger v1.2\n" + "".join(f"{x:.3f},{y:.3f},{z:.3f}\n" for x, y, z in d))
    with pytest.raises(ValueError, match=r"banner.csv, line 2: 3 comma-separated numbers and no header \(line 1 above "
                                         r"them, 'HMC5883L logger v1.2', is text: a banner\); name the columns"):
        read_recording(path)
    rec = read_recording(path, columns="mx,my,mz")
    np.testing.assert_allclose(rec.samples(), d, atol=1e-3)
    assert rec.metadata["preamble"].endswith("line 1: HMC5883L logger v1.2")
