import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import fluxcal
from conftest import REPO, run_cli


def test_version():
    r = run_cli("--version")
    assert r.returncode == 0 and r.stdout.strip() == f"fluxcal {fluxcal.__version__}"


def test_simulate_calibrate_apply(tmp_path):
    # these two tests start `python -m fluxcal` itself (process=True); the rest run its main in this process
    rec, cal, out = tmp_path / "sim.csv", tmp_path / "cal.json", tmp_path / "out.csv"
    r = run_cli("simulate", "-o", rec, "--n", 1500, "--noise", 0.002, "--seed", 3, process=True)
    assert r.returncode == 0, r.stderr
    r = run_cli("calibrate", rec, "--field-norm", 50000, "-o", cal, "--plot", tmp_path / "p.png", process=True)
    assert r.returncode == 0, r.stderr
    assert "|h| std/mean after" in r.stdout and "offset b" in r.stdout and "samples used          1500" in r.stdout
    assert (tmp_path / "p.png").stat().st_size > 10_000
    meta = fluxcal.read_csv(rec).metadata
    true_offset = np.array(meta["true_offset"].split(), dtype=float)
    saved = fluxcal.Calibration.load(cal)
    assert saved.units == "nT" and saved.metadata["source"] == str(rec)
    assert np.linalg.norm(saved.offset - true_offset) < 0.005 * 50000
    r = run_cli("apply", cal, rec, "-o", out, process=True)
    assert r.returncode == 0, r.stderr
    corrected = fluxcal.read_csv(out)
    h = np.column_stack([corrected.columns[c] for c in ("hx", "hy", "hz")])
    assert corrected.units["hx"] == "nT"
    assert np.std(np.linalg.norm(h, axis=1)) / 50000 < 0.004


def test_phone_recording_is_calibrated(real_data, tmp_path):
    r = run_cli("calibrate", real_data / "phone_acc_mag.csv", "--columns", "mx,my,mz", "-o", tmp_path / "c.json")
    assert r.returncode == 0, r.stderr
    before = float(r.stdout.split("|h| std/mean before")[1].split("%")[0])
    after = float(r.stdout.split("|h| std/mean after")[1].split("%")[0])
    assert 25.0 < before < 40.0  # about 32 %
    assert after <= 1.5
    assert json.loads((tmp_path / "c.json").read_text())["summary"]["samples"] == 12000


def test_errors_are_reported_not_raised(tmp_path):
    bad = tmp_path / "bad.csv"
    bad.write_text("mx,my,mz\n1,2,3\n1,x,3\n")
    r = run_cli("calibrate", bad, process=True)
    assert r.returncode == 2
    assert "bad.csv, line 3, column 'my': 'x' is not a number" in r.stderr
    assert "Traceback" not in r.stderr
    few = tmp_path / "few.csv"
    few.write_text("mx,my,mz\n" + "1,2,3\n" * 5)
    r = run_cli("calibrate", few, process=True)
    assert r.returncode == 2 and "5 rows, need at least 9" in r.stderr
    r = run_cli("calibrate", tmp_path / "absent.csv", process=True)
    assert r.returncode == 2 and "cannot read" in r.stderr
    # an output that cannot be written (here a folder): an error naming it, not a traceback
    r = run_cli("simulate", "-o", tmp_path, "--n", 20, process=True)
    assert r.returncode == 2 and f"{tmp_path}: Is a directory" in r.stderr and "Traceback" not in r.stderr


def test_outputs_are_written_in_the_format_their_name_says(tmp_path):
    # `simulate -o s.mat` wrote CSV text under a .mat name, which MATLAB cannot load.
    from scipy.io import loadmat

    assert run_cli("simulate", "-o", tmp_path / "s.mat", "--n", 60, "--seed", 1).returncode == 0
    assert loadmat(tmp_path / "s.mat")["mx"].size == 60
    rec = fluxcal.read_recording(tmp_path / "s.mat")
    assert rec.metadata["field_norm"] == "50000" and len(rec) == 60
    r = run_cli("apply", fluxcal.Calibration(np.zeros(3), np.eye(3), units="nT").save(tmp_path / "c.json"), tmp_path / "s.mat", "-o", tmp_path / "h.txt")
    assert r.returncode == 0, r.stderr  # any other name: CSV text, read back by its content
    np.testing.assert_array_equal(fluxcal.read_recording(tmp_path / "h.txt").columns["hx"], rec.columns["mx"])
    # A writer of CSV only refuses another format's name instead of writing text under it.
    r = run_cli("cable", "simulate", "-o", tmp_path / "ring.npz")
    assert r.returncode == 2 and "ring.npz: CSV text under a .npz name; name it .csv" in r.stderr
    assert not (tmp_path / "ring.npz").exists()
    with pytest.raises(ValueError, match=r"x.json: CSV text under a .json name; name it .csv, or write .json"):
        fluxcal.write_csv(tmp_path / "x.json", {"a": [1.0]})
    r = run_cli("simulate", "-o", tmp_path / "s.xlsx")  # a format fluxcal reads only: text would not open in Excel
    assert r.returncode == 2 and "s.xlsx: CSV text under a .xlsx name; name it .csv" in r.stderr
    # the warning's unit is the field's, not the readings'
    from fluxcal.cli import _scale_warning

    counts = fluxcal.Calibration(np.zeros(3), np.eye(3), field_norm=48.2, units="counts", field_units="uT")
    assert "is 150 uT (median), 3.11× the calibration's field norm 48.2 uT" in \
        _scale_warning(counts, np.full((4, 3), 150 / np.sqrt(3)), "counts")


def test_apply_warns_when_the_corrected_field_is_not_the_calibrations(tmp_path):
    # A calibration in nT applied to readings in gauss that state no unit: every row came out near −A·b,
    # "|h| std/mean 0.001 %", and looked perfectly calibrated.
    rec, cal = tmp_path / "sim.csv", tmp_path / "cal.json"
    assert run_cli("simulate", "-o", rec, "--n", 300, "--seed", 2).returncode == 0
    assert run_cli("calibrate", rec, "-o", cal).returncode == 0
    m = fluxcal.read_recording(rec).samples()
    gauss = fluxcal.write_csv(tmp_path / "gauss.csv", {"x": m[:, 0] / 1e5, "y": m[:, 1] / 1e5, "z": m[:, 2] / 1e5})
    r = run_cli("apply", cal, gauss, "-o", tmp_path / "h.csv")
    assert r.returncode == 0, r.stderr
    assert "warning: the corrected |h| is" in r.stdout and "the readings state no unit: are they in nT? (--units)" \
        in r.stdout
    r = run_cli("apply", cal, gauss, "-o", tmp_path / "h.csv", "--units", "G")  # the remedy it names
    assert r.returncode == 0 and "converted to the calibration's nT" in r.stdout and "warning" not in r.stdout
    h = fluxcal.read_recording(tmp_path / "h.csv")
    assert abs(np.median(np.linalg.norm(np.column_stack([h.columns[k] for k in ("hx", "hy", "hz")]), axis=1))
               / 50000 - 1) < 0.01
    r = run_cli("apply", cal, rec, "-o", tmp_path / "h.csv")  # its own readings: no warning
    assert r.returncode == 0 and "warning" not in r.stdout


def test_poor_coverage_is_warned(tmp_path):
    rng = np.random.default_rng(4)
    az, el = rng.uniform(0, 2 * np.pi, 800), np.deg2rad(rng.uniform(-8, 8, 800))
    x = np.column_stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    path = fluxcal.write_csv(tmp_path / "flat.csv", {"mx": x[:, 0], "my": x[:, 1], "mz": x[:, 2]})
    r = run_cli("calibrate", path)
    assert r.returncode == 0, r.stderr
    assert "warning: poor coverage" in r.stdout


def test_demo_prints_and_plots(tmp_path):
    r = run_cli("demo", "-o", tmp_path / "demo")
    assert r.returncode == 0, r.stderr
    assert "against the simulation's truth" in r.stdout
    err = float(r.stdout.split("matrix error")[1].split("%")[0])
    assert err < 0.5
    assert (tmp_path / "demo" / "demo_before_after.png").stat().st_size > 10_000


def test_cmake_dir_without_the_cpp_library_is_an_error_not_a_traceback(monkeypatch, tmp_path, capsys):
    # A source checkout on PYTHONPATH carries no C++ library: FileNotFoundError ended in a traceback.
    import importlib.resources

    from fluxcal import cli

    (tmp_path / "fluxcal").mkdir()
    monkeypatch.setattr(importlib.resources, "files", lambda package: tmp_path / "fluxcal")
    assert cli.main(["--cmake-dir"]) == 2
    err = capsys.readouterr().err
    assert f"fluxcal --cmake-dir: error: the fluxcal at {tmp_path / 'fluxcal'} carries no C++ library" in err
    assert "make install" in err


@pytest.mark.skipif(shutil.which("cmake") is None, reason="cmake is installed by `make test`")
def test_cpp_example_builds_against_the_installed_wheel(tmp_path):
    # The wheel carries the static library, headers and fluxcalConfig.cmake (fluxcal --cmake-dir).
    cmake_dir = run_cli("--cmake-dir").stdout.strip()
    assert (Path(cmake_dir) / "fluxcalConfig.cmake").is_file()
    build = tmp_path / "build"
    for cmd in (["cmake", "-S", REPO / "cpp" / "examples", "-B", build, f"-Dfluxcal_DIR={cmake_dir}",
                 "-DCMAKE_BUILD_TYPE=Release"],
                ["cmake", "--build", build]):
        r = subprocess.run([str(c) for c in cmd], capture_output=True, text=True)
        assert r.returncode == 0, r.stdout + r.stderr
    r = subprocess.run([str(build / "calibrate_example")], capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "OK" in r.stdout
    # the wheel's generated fluxcal/version.hpp is that of its library
    assert f"fluxcal {fluxcal.__version__} (headers {fluxcal.__version__})" in r.stdout


def _scaled_copy(src: Path, dst: Path, unit: str, factor: float) -> Path:
    """The recording `src` with its magnetometer columns × factor, stated in `unit`."""
    rec = fluxcal.read_csv(src)
    cols = {**rec.columns, **{c: rec.columns[c] * factor for c in ("mx", "my", "mz")}}
    return fluxcal.write_csv(dst, cols, units={"t": "s", **{c: unit for c in ("mx", "my", "mz")}})


def test_units_are_converted_or_refused_never_mixed(tmp_path):
    """apply converts readings in another field unit to the calibration's, refuses counts against nT, and
    --units never overrides the unit a file states; a calibration to a given norm from counts says h's unit."""
    rec, cal = tmp_path / "sim.csv", tmp_path / "cal.json"
    assert run_cli("simulate", "-o", rec, "--n", 1500, "--seed", 5).returncode == 0
    r = run_cli("calibrate", rec, "-o", cal)
    assert r.returncode == 0 and "field norm 50000 nT from the simulation's metadata" in r.stdout, r.stderr
    assert fluxcal.Calibration.load(cal).field_norm == 50000.0
    assert run_cli("apply", cal, rec, "-o", tmp_path / "a.csv").returncode == 0
    ut = _scaled_copy(rec, tmp_path / "ut.csv", "uT", 1e-3)
    r = run_cli("apply", cal, ut, "-o", tmp_path / "b.csv")
    assert r.returncode == 0 and "converted to the calibration's nT (× 1000)" in r.stdout, r.stderr
    h = [np.column_stack([fluxcal.read_csv(tmp_path / f).columns[c] for c in ("hx", "hy", "hz")]) for f in ("a.csv", "b.csv")]
    np.testing.assert_allclose(h[1], h[0], rtol=1e-9, atol=1e-6)
    counts = _scaled_copy(rec, tmp_path / "counts.csv", "counts", 1.5)
    r = run_cli("apply", cal, counts, "-o", tmp_path / "c.csv")
    assert r.returncode == 2 and "counts.csv: readings in counts, the calibration was fitted to readings in nT" in r.stderr
    assert not (tmp_path / "c.csv").exists()
    r = run_cli("calibrate", rec, "--units", "uT")
    assert r.returncode == 2 and "units 'uT' given, but the file states the magnetometer in nT" in r.stderr
    # counts to a norm in µT: h is in µT, and says so; without --field-units it is not called counts
    r = run_cli("calibrate", counts, "--field-norm", 50, "--field-units", "µT", "-o", tmp_path / "q.json")
    assert r.returncode == 0 and "|h| = 50 uT" in r.stdout, r.stderr
    q = fluxcal.Calibration.load(tmp_path / "q.json")
    assert (q.units, q.h_units) == ("counts", "uT")
    assert run_cli("apply", tmp_path / "q.json", counts, "-o", tmp_path / "d.csv").returncode == 0
    assert fluxcal.read_csv(tmp_path / "d.csv").units["hx"] == "uT"
    r = run_cli("calibrate", counts, "--field-norm", 50)
    assert r.returncode == 0 and "|h| = 50 (no unit stated)" in r.stdout and "|h| = 50 counts" not in r.stdout
    # a norm in another unit than the readings' is compared in tesla (it was compared number to number: nT
    # readings with --field-norm 50 --field-units uT were "0.001 times the fitted radius — check the units")
    for unit, warned in (("uT", False), ("G", True)):
        norm = 50 if unit == "uT" else 5
        r = run_cli("calibrate", rec, "--field-norm", norm, "--field-units", unit)
        assert r.returncode == 0, r.stderr
        assert ("times the fitted radius" in r.stdout) is False
        assert (f"field_norm {norm} G is 11.1 times the readings' field" in r.stdout) is warned, r.stdout
    assert "times the fitted radius" not in run_cli("calibrate", counts, "--field-norm", 50, "--field-units",
                                                    "uT").stdout


def test_field_far_from_the_earths_is_warned(tmp_path):
    """Readings in µT labelled nT give |h| ≈ 50 nT: a warning naming the likely unit mix-up."""
    rec = tmp_path / "sim.csv"
    assert run_cli("simulate", "-o", rec, "--n", 800, "--seed", 2).returncode == 0
    wrong = _scaled_copy(rec, tmp_path / "wrong.csv", "nT", 1e-3)
    r = run_cli("calibrate", wrong)
    assert r.returncode == 0, r.stderr
    assert "far from the Earth's field (22–67 µT): are the readings really in nT?" in r.stdout
    assert "far from the Earth's field" not in run_cli("calibrate", rec).stdout


def test_old_calibration_files_keep_their_field_unit(tmp_path):
    """A calibration saved before field_units existed: h is in the readings' unit, as it was."""
    data = fluxcal.Calibration(offset=[1, 2, 3], matrix=np.eye(3), field_norm=48.0, units="uT").to_dict()
    del data["field_units"]
    assert fluxcal.Calibration.from_dict(data).h_units == "uT"


def test_solver_errors_name_the_file(tmp_path):
    rng = np.random.default_rng(1)
    az = rng.uniform(0, 2 * np.pi, 400)
    path = fluxcal.write_csv(tmp_path / "yaw_only.csv", {"mx": 30 * np.cos(az), "my": 30 * np.sin(az),
                                                         "mz": 20 + 0.01 * rng.standard_normal(400)})
    r = run_cli("calibrate", path)
    assert r.returncode == 2 and r.stderr.startswith(f"fluxcal calibrate: error: {path}: "), r.stderr


def test_ambiguous_commas_are_settled_on_the_command_line(tmp_path):
    """A labelled log whose only commas are ambiguous (X: 1,234) is an error pointing at --decimal, which
    settles it either way."""
    rng = np.random.default_rng(3)
    u = rng.standard_normal((300, 3))
    m = 1500 * u / np.linalg.norm(u, axis=1, keepdims=True) + [2100, -300, 800]
    text = "".join("Mag X: {} Y: {} Z: {} counts\n".format(*(f"{int(round(v)):,}" for v in row)) for row in m)
    path = tmp_path / "log.txt"
    path.write_text(text)
    assert "," in text
    r = run_cli("calibrate", path)
    assert r.returncode == 2 and "--decimal" in r.stderr, r.stderr
    r = run_cli("calibrate", path, "--decimal", ".", "-o", tmp_path / "c.json")
    assert r.returncode == 0, r.stderr
    cal = fluxcal.Calibration.load(tmp_path / "c.json")
    np.testing.assert_allclose(cal.offset, [2100, -300, 800], atol=5)  # thousands separators: counts as printed


def test_cli_names_bad_magnitudes_and_a_calibration_that_overflows(tmp_path):
    rec, out = tmp_path / "sim.csv", tmp_path / "out.csv"
    assert run_cli("simulate", "-o", rec, "--n", 200, "--seed", 4).returncode == 0
    for value in ("inf", "nan", "0", "-5"):  # named EllipsoidOptions::field_norm and blamed the file
        r = run_cli("calibrate", rec, "--field-norm", value)
        assert r.returncode == 2 and f"argument --field-norm: {value} is not a positive finite number" in r.stderr
    huge = tmp_path / "huge.json"
    huge.write_text(json.dumps({"offset": [1e308, 0, 0], "matrix": (1e300 * np.eye(3)).tolist(), "field_norm": 1e308}))
    r = run_cli("apply", huge, rec, "-o", out)  # wrote inf fields and exited 0
    assert r.returncode == 2 and "huge.json: correcting" in r.stderr and "overflows from row 0" in r.stderr
    assert "RuntimeWarning" not in r.stderr and not out.exists()
    zero = tmp_path / "zero.json"
    zero.write_text(json.dumps({"offset": [0, 0, 0], "matrix": np.zeros((3, 3)).tolist(), "field_norm": 1}))
    r = run_cli("apply", zero, rec, "-o", out)  # wrote all-zero fields
    assert r.returncode == 2 and "zero.json: matrix is singular or nearly so" in r.stderr
    r = run_cli("simulate", "-o", tmp_path / "nan.csv", "--noise", "nan")  # wrote a recording of NaN
    assert r.returncode == 2 and "argument --noise: nan is not a non-negative finite number" in r.stderr
    for option in ("--current", "--repeats"):  # wrote a recording with no field to calibrate on
        r = run_cli("cable", "simulate", "-o", tmp_path / "ring.csv", "--calibration", option, 0)
        assert r.returncode == 2 and f"argument {option}: 0 is not a positive" in r.stderr
    binary = tmp_path / "binary.json"
    binary.write_bytes(b"\x82\xff\x00abc")
    r = run_cli("export-c", binary, "-o", tmp_path / "o.h")  # named the codec, not the file
    assert r.returncode == 2 and "binary.json: not a fluxcal calibration (byte 0x82 at offset 0 is not text)" in r.stderr


def test_simulate_effects_writes_a_trial_the_diagnosis_reads(tmp_path):
    """`simulate --effects` gives a CLI user a recording with a known unmodelled effect to try diagnose on."""
    path = tmp_path / "w.csv"
    r = run_cli("simulate", "-o", path, "--effects", "temp_offset", "--seed", "3")
    assert r.returncode == 0 and "effects: temp_offset; try: fluxcal diagnose" in r.stdout, r.stderr
    rec = fluxcal.read_recording(path)
    assert rec.roles()["time"] == "t" and rec.roles()["temperature"] == "temp" and len(rec) == 3000
    assert rec.metadata["effects"] == "temp_offset" and rec.field_units() == "uT"
    d = run_cli("diagnose", path, "--quiet")
    assert d.returncode == 0 and "FOUND: temp_offset" in d.stdout, d.stdout
    vector = tmp_path / "v.csv"
    r = run_cli("simulate", "-o", vector, "--effects", "misalignment", "--seed", "2")
    assert "--model vector_scale --reference rx,ry,rz" in r.stdout
    assert {"rx", "ry", "rz", "ax", "ay", "az"} <= set(fluxcal.read_recording(vector).columns)
    bad = run_cli("simulate", "-o", tmp_path / "x.csv", "--effects", "temp_ofset")
    assert bad.returncode == 2 and "--effects: unknown effect(s) temp_ofset (the candidates: temp_scale" in bad.stderr
    assert not (tmp_path / "x.csv").exists()


def test_first_day_mistakes_get_their_own_words(tmp_path):
    """A stuck sensor, a unit nobody knows, a .tsv output: each said as it is."""
    stuck = fluxcal.write_csv(tmp_path / "stuck.csv", {k: np.full(200, v) for k, v in (("mx", 1.0), ("my", 2.0),
                                                                                        ("mz", 3.0))})
    r = run_cli("calibrate", stuck)
    assert r.returncode == 2 and "all 200 readings are the same" in r.stderr, r.stderr
    rec = tmp_path / "sim.csv"
    assert run_cli("simulate", "-o", rec, "--n", 800, "--seed", 4).returncode == 0
    few = fluxcal.read_csv(rec)
    r = run_cli("calibrate", rec, "--units", "bananas")
    assert r.returncode == 2 and "'bananas' is not a field unit" in r.stderr
    assert run_cli("calibrate", rec, "-o", tmp_path / "c.json").returncode == 0
    r = run_cli("apply", tmp_path / "c.json", rec, "-o", tmp_path / "out.tsv")
    assert r.returncode == 0, r.stderr
    assert "\t" in (tmp_path / "out.tsv").read_text().splitlines()[-1]
    np.testing.assert_array_equal(fluxcal.read_recording(tmp_path / "out.tsv").columns["mx"], few.columns["mx"])


def test_no_command_writes_over_a_file_it_reads(tmp_path):
    """From a bad-input audit: calibrate, diagnose --json, drift fit and export-c with -o onto their own input
    replaced it (apply alone refused); --plot into a missing folder failed after -o was written, exit status 2."""
    rec, cal = tmp_path / "sim.csv", tmp_path / "cal.json"
    assert run_cli("simulate", "-o", rec, "--n", 600, "--seed", 4).returncode == 0
    assert run_cli("calibrate", rec, "-o", cal).returncode == 0
    before = {path: path.read_bytes() for path in (rec, cal)}
    for args, what in ((("calibrate", rec, "-o", rec), "-o"), (("diagnose", rec, "--json", rec), "--json"),
                       (("drift", "fit", rec, "-o", rec), "-o"), (("export-c", cal, "-o", cal), "-o"),
                       (("calibrate", rec, "-o", tmp_path / "c2.json", "--plot", rec), "--plot")):
        r = run_cli(*args)
        assert r.returncode == 2 and f"{what} {args[-1]} is the " in r.stderr and "it reads" in r.stderr, (args, r.stderr)
    assert all(path.read_bytes() == data for path, data in before.items())
    new = tmp_path / "new.json"
    r = run_cli("calibrate", rec, "-o", new, "--plot", tmp_path / "missing" / "p.png")
    assert r.returncode == 2 and "the folder" in r.stderr and "does not exist" in r.stderr and not new.exists()


def test_apply_names_a_reading_past_any_range_and_keeps_its_statistics_finite(tmp_path):
    """From a bad-input audit: one reading of 1e300 printed NumPy's overflow warnings and "|h| std/mean nan %"."""
    rec, cal = tmp_path / "sim.csv", tmp_path / "cal.json"
    assert run_cli("simulate", "-o", rec, "--n", 600, "--seed", 4).returncode == 0
    assert run_cli("calibrate", rec, "-o", cal).returncode == 0
    lines = rec.read_text().splitlines()
    row = next(i for i, line in enumerate(lines) if line and not line.startswith("#") and line[0].isdigit()) + 10
    cells = lines[row].split(",")
    cells[1] = "1e300"
    lines[row] = ",".join(cells)
    huge = tmp_path / "huge.csv"
    huge.write_text("\n".join(lines) + "\n")
    r = run_cli("apply", cal, huge, "-o", tmp_path / "h.csv")
    assert r.returncode == 0, r.stderr
    assert f"1 reading(s) past any sensor's range (file line {row + 1}" in r.stdout, r.stdout
    assert "nan %" not in r.stdout and "RuntimeWarning" not in r.stdout + r.stderr
    assert len(fluxcal.read_recording(tmp_path / "h.csv")) == 600  # written as read


def test_apply_keeps_what_it_reads_and_says_what_it_cannot(tmp_path):
    """From a blind check: -o onto the calibration or the recording replaced it; input columns hx,hy,hz were
    overwritten; a calibration that did not converge was applied without a word; µT and uT were two units."""
    rec, cal = tmp_path / "sim.csv", tmp_path / "cal.json"
    assert run_cli("simulate", "-o", rec, "--n", 600, "--seed", 4).returncode == 0
    assert run_cli("calibrate", rec, "-o", cal).returncode == 0
    before = cal.read_bytes()
    for target, what in ((cal, "the calibration"), (rec, "the recording")):
        r = run_cli("apply", cal, rec, "-o", target)
        assert r.returncode == 2 and f"is {what} it reads" in r.stderr
    assert cal.read_bytes() == before
    r = run_cli("apply", cal, rec, "-o", tmp_path / "h.csv")
    assert r.returncode == 0, r.stderr
    r = run_cli("apply", cal, tmp_path / "h.csv", "-o", tmp_path / "hh.csv")
    assert r.returncode == 2 and "already has column(s) hx, hy, hz" in r.stderr
    data = json.loads(before)
    data["summary"]["converged"] = False
    (tmp_path / "nc.json").write_text(json.dumps(data))
    r = run_cli("apply", tmp_path / "nc.json", rec, "-o", tmp_path / "nc.csv")
    assert r.returncode == 0 and "did not converge" in r.stdout
    data["summary"] = None
    (tmp_path / "bad.json").write_text(json.dumps(data))
    r = run_cli("apply", tmp_path / "bad.json", rec, "-o", tmp_path / "bad.csv")
    assert r.returncode == 2 and "summary None must be a JSON object" in r.stderr and "Traceback" not in r.stderr
    # the same unit spelled µT and uT: read as one
    m = fluxcal.read_csv(rec)
    micro = tmp_path / "micro.csv"
    micro.write_text("mx [µT],my [µT],mz [µT]\n" + "\n".join(
        f"{x / 1000},{y / 1000},{z / 1000}" for x, y, z in m.samples()[:50]) + "\n")
    r = run_cli("apply", cal, micro, "-o", tmp_path / "micro_h.csv")
    assert r.returncode == 0 and "converted to the calibration's nT" in r.stdout, r.stdout + r.stderr
