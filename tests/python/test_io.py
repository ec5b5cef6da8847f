import numpy as np
import pytest

from fluxcal.io import read_csv, write_csv


def test_round_trip_keeps_columns_units_and_metadata(tmp_path):
    t = np.arange(5) * 0.02
    cols = {"t": t, "mx": t + 1, "my": t - 2, "mz": 3 * t, "temp": 20 + t}
    path = write_csv(tmp_path / "r.csv", cols, units={"t": "s", "mx": "uT", "my": "uT", "mz": "uT", "temp": "degC"},
                     metadata={"sensor": "RM3100"})
    rec = read_csv(path)
    assert list(rec.columns) == ["t", "mx", "my", "mz", "temp"]
    np.testing.assert_allclose(rec.samples(), np.column_stack([t + 1, t - 2, 3 * t]))
    assert rec.field_units() == "uT" and rec.units["temp"] == "degC"
    assert rec.metadata["sensor"] == "RM3100"
    assert len(rec) == 5


def test_units_in_header_cells_and_other_column_names(tmp_path):
    p = tmp_path / "h.csv"
    p.write_text("x [G],y [G],z [G]\n0.1,0.2,0.3\n0.4,0.5,0.6\n")
    rec = read_csv(p)
    assert rec.field_units() == "G"
    np.testing.assert_allclose(rec.samples()[1], [0.4, 0.5, 0.6])
    p.write_text("a,b,c,d\n1,2,3,4\n")
    np.testing.assert_allclose(read_csv(p, columns="b,c,d", units="counts").samples(), [[2, 3, 4]])
    assert read_csv(p, columns="b,c,d", units="counts").field_units() == "counts"


@pytest.mark.parametrize("body, message", [
    ("mx,my,mz\n1,2,3\n4,abc,6\n", r"bad.csv, line 3, column 'my': 'abc' is not a number"),
    ("mx,my,mz\n1,2,3\n4,,6\n", r"bad.csv, line 3, column 'my': empty"),
    ("# units: mx=nT\nmx,my,mz\n1,2,3\n4,5\n", r"bad.csv, line 4: 2 fields, the header has 3"),
    ("1,2,3\n4,5,6\n", r"bad.csv, line 1: the first line holds numbers"),
    ("mx,my,mz\n", r"bad.csv: header but no data rows"),
    ("", r"bad.csv: no header line"),
    ("mx,mx,mz\n1,2,3\n", r"bad.csv, line 1: header .* repeated"),
    ("# units: nT\nmx,my,mz\n1,2,3\n", r"bad.csv, line 1: units entry 'nT' is not name=unit"),
])
def test_reader_errors_name_file_line_and_column(tmp_path, body, message):
    p = tmp_path / "bad.csv"
    p.write_text(body)
    with pytest.raises(ValueError, match=message):
        read_csv(p)


def test_missing_columns_and_missing_file(tmp_path):
    p = tmp_path / "r.csv"
    p.write_text("ax,ay,az\n1,2,3\n")
    with pytest.raises(ValueError, match=r"no magnetometer columns \(looked for mx,my,mz.*columns are: ax, ay, az\)"):
        read_csv(p).samples()
    with pytest.raises(ValueError, match=r"no column 'mz'; columns are: ax, ay, az"):
        read_csv(p, columns="ax,ay,mz")
    with pytest.raises(ValueError, match="cannot read"):
        read_csv(tmp_path / "absent.csv")


def test_nan_cell_is_reported_with_its_file_line(tmp_path):
    p = tmp_path / "n.csv"
    p.write_text("# note: x\nmx,my,mz\n1,2,3\n\n4,nan,6\n")
    rec = read_csv(p)
    with pytest.raises(ValueError, match=r"n.csv: line 5, column 'my' is nan"):
        rec.samples()
