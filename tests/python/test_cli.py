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
    rec, cal, out = tmp_path / "sim.csv", tmp_path / "cal.json", tmp_path / "out.csv"
    r = run_cli("simulate", "-o", rec, "--n", 1500, "--noise", 0.002, "--seed", 3)
    assert r.returncode == 0, r.stderr
    r = run_cli("calibrate", rec, "--field-norm", 50000, "-o", cal, "--plot", tmp_path / "p.png")
    assert r.returncode == 0, r.stderr
    assert "|h| std/mean after" in r.stdout and "offset b" in r.stdout and "samples used          1500" in r.stdout
    assert (tmp_path / "p.png").stat().st_size > 10_000
    meta = fluxcal.read_csv(rec).metadata
    true_offset = np.array(meta["true_offset"].split(), dtype=float)
    saved = fluxcal.Calibration.load(cal)
    assert saved.units == "nT" and saved.metadata["source"] == str(rec)
    assert np.linalg.norm(saved.offset - true_offset) < 0.005 * 50000
    r = run_cli("apply", cal, rec, "-o", out)
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
    r = run_cli("calibrate", bad)
    assert r.returncode == 2
    assert "bad.csv, line 3, column 'my': 'x' is not a number" in r.stderr
    assert "Traceback" not in r.stderr
    few = tmp_path / "few.csv"
    few.write_text("mx,my,mz\n" + "1,2,3\n" * 5)
    r = run_cli("calibrate", few)
    assert r.returncode == 2 and "5 rows, need at least 9" in r.stderr
    r = run_cli("calibrate", tmp_path / "absent.csv")
    assert r.returncode == 2 and "cannot read" in r.stderr
    # an output that cannot be written (here a folder): an error naming it, not a traceback
    r = run_cli("simulate", "-o", tmp_path, "--n", 20)
    assert r.returncode == 2 and f"{tmp_path}: Is a directory" in r.stderr and "Traceback" not in r.stderr


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
