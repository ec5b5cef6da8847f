"""fluxcal.planar.heading and `fluxcal apply --heading`: a compass's heading from a planar calibration of a level
sensor's x, y (a newcomer expected it and found none). The truth: a vehicle turning clockwise from north by ψ in a
field of horizontal component H north; the FRD body frame (x forward, y right) reads H cos ψ, −H sin ψ."""
import numpy as np
import pytest

from fluxcal.cli import main
from fluxcal.planar import calibrate_planar, heading

H, Z = 20.0, 44.0


def vehicle(psi_deg, frame="frd", seed=0, sigma=0.05):
    rng = np.random.default_rng(seed)
    psi = np.radians(psi_deg)
    side = -np.sin(psi) if frame == "frd" else np.sin(psi)
    h = np.column_stack([H * np.cos(psi), H * side, np.full(len(psi), Z if frame == "frd" else -Z)])
    W = np.array([[1.05, 0.04, 0.0], [0.04, 0.95, 0.0], [0.0, 0.0, 1.0]])
    return h @ W.T + [7.0, -3.0, 2.0] + rng.normal(0, sigma, h.shape)


def circular_error(a, b):
    return np.degrees(np.angle(np.exp(1j * np.radians(a - b))))


@pytest.mark.parametrize("frame", ["frd", "flu"])
def test_the_heading_of_a_calibrated_turn_is_the_vehicles(frame):
    psi = np.linspace(0, 720, 1500, endpoint=False) % 360
    m = vehicle(psi, frame)
    cal = calibrate_planar(m, field_norm=H, axes="xy")
    error = circular_error(heading(cal.apply(m), frame), psi)
    # a magnitude fit cannot see a rotation of the plane: a constant alignment; about it, the noise (σ/H ≈ 0.14°)
    assert np.degrees(np.std(np.radians(error))) < 0.5
    assert abs(np.mean(error)) < 3.0  # the soft iron's small skew, no mirror or quarter-turn error
    assert np.allclose(heading(cal.apply(m), frame, declination=10.0), (heading(cal.apply(m), frame) + 10) % 360)


def test_heading_refuses_a_frame_it_does_not_know():
    with pytest.raises(ValueError, match="frame: 'ned'"):
        heading(np.ones((3, 2)), "ned")


def test_apply_writes_the_heading_of_a_planar_calibration(tmp_path, capsys):
    import fluxcal

    psi = np.linspace(0, 720, 1200, endpoint=False) % 360
    m = vehicle(psi, seed=1)
    log = tmp_path / "car.csv"
    log.write_text("mx [uT],my [uT],mz [uT]\n" + "".join(f"{x:.4f},{y:.4f},{z:.4f}\n" for x, y, z in m))
    assert main(["calibrate", str(log), "--planar", "xy", "--field-norm", str(H), "-o", str(tmp_path / "cal.json")]) == 0
    assert main(["apply", str(tmp_path / "cal.json"), str(log), "-o", str(tmp_path / "out.csv"), "--heading",
                 "--declination", "2.5"]) == 0
    out = fluxcal.read_recording(tmp_path / "out.csv")
    assert out.units["heading"] == "deg"
    error = circular_error(out.columns["heading"], psi + 2.5)
    assert np.degrees(np.std(np.radians(error))) < 0.5 and abs(np.mean(error)) < 3.0
    # a 3-D calibration has no heading without the attitude: said, nothing written
    sim = tmp_path / "sim.csv"
    main(["simulate", "-o", str(sim), "--n", "600"])
    main(["calibrate", str(sim), "-o", str(tmp_path / "cal3.json")])
    capsys.readouterr()
    assert main(["apply", str(tmp_path / "cal3.json"), str(sim), "-o", str(tmp_path / "o3.csv"), "--heading"]) == 2
    assert "a heading needs the sensor's attitude" in capsys.readouterr().err
