"""ROS bags written with rosbags (ROS 1 .bag, ROS 2 .db3 and .mcap folders): the magnetometer topic in
µT from tesla, header stamps as time, the IMU's acceleration interpolated to the magnetometer's times,
topic choice and its errors, and `fluxcal calibrate` on a bag folder."""
import numpy as np
import pytest

from rosbags.rosbag1 import Writer as Writer1  # in the test extra; the reader's own extra is fluxcal[ros]
from rosbags.rosbag2 import StoragePlugin, Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from conftest import run_cli, simulated
from fluxcal.io import read_recording, sniff

T0 = 1_700_000_000_000_000_000  # ns


def write_bag(path, kind, field_t, mag_topics=("/imu/mag",), rate_hz=50.0):
    """A bag with MagneticField messages (field_t: N×3 tesla) on each topic and an Imu topic whose
    acceleration's x is the reading index."""
    ros1 = kind == "ros1"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    types = ts.types
    Time, Vec = types["builtin_interfaces/msg/Time"], types["geometry_msgs/msg/Vector3"]
    serialize = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    writer = Writer1(path) if ros1 else Writer2(path, version=9, storage_plugin=(
        StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3))
    with writer as w:
        mags = [w.add_connection(t, "sensor_msgs/msg/MagneticField", typestore=ts) for t in mag_topics]
        imu = w.add_connection("/imu/data", "sensor_msgs/msg/Imu", typestore=ts)
        for k, b in enumerate(field_t):
            ns = T0 + int(round(k * 1e9 / rate_hz))
            stamp = Time(sec=ns // 10 ** 9, nanosec=ns % 10 ** 9)
            header = types["std_msgs/msg/Header"](**({"seq": k} if ros1 else {}), stamp=stamp, frame_id="imu")
            msg = types["sensor_msgs/msg/MagneticField"](header=header, magnetic_field=Vec(x=b[0], y=b[1], z=b[2]),
                                                         magnetic_field_covariance=np.eye(3).ravel() * 1e-16)
            for c in mags:
                w.write(c, ns + 1000, serialize(msg, "sensor_msgs/msg/MagneticField"))
            zeros = np.zeros(9)
            acc = types["sensor_msgs/msg/Imu"](
                header=header, orientation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=zeros, angular_velocity=Vec(x=0.0, y=0.0, z=0.0),
                angular_velocity_covariance=zeros, linear_acceleration=Vec(x=float(k), y=0.0, z=9.81),
                linear_acceleration_covariance=zeros)
            w.write(imu, ns + 2000, serialize(acc, "sensor_msgs/msg/Imu"))
    return path


@pytest.mark.parametrize("kind", ["ros1", "db3", "mcap"])
def test_a_bags_magnetometer_in_microtesla_with_time_and_acceleration(tmp_path, kind):
    m_ut = simulated(2, n=100, field_norm=50.0).readings
    path = write_bag(tmp_path / ("mag.bag" if kind == "ros1" else "bag"), kind, m_ut * 1e-6)
    assert sniff(path) == "rosbag"
    rec = read_recording(path)
    np.testing.assert_allclose(rec.samples(), m_ut, rtol=1e-12)
    assert rec.field_units() == "uT" and rec.metadata["topic"] == "/imu/mag"
    np.testing.assert_allclose(rec.time(), np.arange(100) * 0.02, atol=1e-9)  # header stamps, not receive times
    np.testing.assert_allclose(rec.acceleration()[:, 0], np.arange(100), atol=1e-9)
    assert rec.metadata["magnetic_field_covariance_uT2"] == pytest.approx([1e-4] * 3)
    if kind != "ros1":  # a file inside the bag folder reads as the bag
        part = next(p for p in path.iterdir() if p.suffix in (".db3", ".mcap"))
        np.testing.assert_array_equal(read_recording(part).samples(), rec.samples())


def test_several_magnetometer_topics_are_chosen_by_name(tmp_path):
    field = np.tile([[2e-5, -1e-5, 4e-5]], (5, 1))
    path = write_bag(tmp_path / "two.bag", "ros1", field, mag_topics=("/imu/mag", "/compass/mag"))
    with pytest.raises(ValueError, match=r"several magnetometer topics \(/compass/mag, /imu/mag\); name one with "
                                         r"--columns /compass/mag"):
        read_recording(path)
    assert read_recording(path, columns="/compass/mag").metadata["topic"] == "/compass/mag"
    with pytest.raises(ValueError, match=r"no sensor_msgs/msg/MagneticField topic '/nope'; topics: .*/imu/data"):
        read_recording(path, columns="/nope")
    (tmp_path / "cut.bag").write_bytes(path.read_bytes()[:600])
    with pytest.raises(ValueError, match=r"cut.bag: not a readable ROS bag"):
        read_recording(tmp_path / "cut.bag")


def test_calibrate_runs_on_a_ros2_bag_folder(tmp_path):
    m_ut = simulated(3, n=600, field_norm=50.0).readings
    path = write_bag(tmp_path / "bag", "db3", m_ut * 1e-6)
    out = run_cli("calibrate", path)
    assert out.returncode == 0, out.stderr
    assert "magnetometer mx,my,mz; time t" in out.stdout and "|h| = " in out.stdout and " uT" in out.stdout
