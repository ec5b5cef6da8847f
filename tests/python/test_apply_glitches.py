"""`fluxcal apply` says which readings are glitches (0 in every axis, or |h| off the calibration's field by more than
half of it), with their file lines: they are corrected and written like the rest, and a newcomer found a 0,0 row
written as a field 55° off in heading, and a burst of garbage (|h| spread 549 %), with nothing said. calibrate
leaves such readings out; apply cannot (a row per reading), so it names them."""
import numpy as np

from conftest import simulated
from fluxcal.cli import main


def _csv(path, m):
    path.write_text("mx [nT],my [nT],mz [nT]\n" + "".join(f"{x:.3f},{y:.3f},{z:.3f}\n" for x, y, z in m))
    return str(path)


def test_glitches_in_the_applied_file_are_named_with_their_lines(tmp_path, capsys):
    m = simulated(2).readings
    assert main(["calibrate", _csv(tmp_path / "fit.csv", m[:1500]), "-o", str(tmp_path / "cal.json")]) in (0, 3)
    other = m[1500:].copy()  # the same sensor's other readings
    other[[40, 41]] = 0.0
    other[300] *= 3.0
    assert main(["apply", str(tmp_path / "cal.json"), _csv(tmp_path / "other.csv", other),
                 "-o", str(tmp_path / "out.csv")]) == 0
    said = [line for line in capsys.readouterr().out.splitlines() if "reading(s) read 0 in every axis" in line]
    assert len(said) == 1 and "3 reading(s)" in said[0] and "rows 40, 41, 300; file lines 42, 43, 302" in said[0]


def test_clean_readings_are_not_named(tmp_path, capsys):
    m = simulated(3).readings
    main(["calibrate", _csv(tmp_path / "fit.csv", m[:1500]), "-o", str(tmp_path / "cal.json")])
    main(["apply", str(tmp_path / "cal.json"), _csv(tmp_path / "other.csv", m[1500:]),
          "-o", str(tmp_path / "out.csv")])
    assert "read 0 in every axis" not in capsys.readouterr().out


def test_a_calibration_used_in_another_field_names_no_glitches(tmp_path, capsys):
    """The same sensor in a field 1.55× the calibration's (another site): every reading is off the calibration's
    field by over 50 %, and each had been called a glitch (review); readings are judged against their own median
    |h|, the field's size is _scale_warning's."""
    m = simulated(4).readings
    b = np.median(m, axis=0)
    main(["calibrate", _csv(tmp_path / "fit.csv", m[:1500]), "-o", str(tmp_path / "cal.json")])
    stronger = b + 1.55 * (m[1500:] - b)  # roughly: the offset kept, the field 1.55×
    main(["apply", str(tmp_path / "cal.json"), _csv(tmp_path / "site2.csv", stronger), "-o", str(tmp_path / "o.csv")])
    assert "read 0 in every axis" not in capsys.readouterr().out
