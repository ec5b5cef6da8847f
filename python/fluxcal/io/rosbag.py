"""ROS bags (rosbags, `pip install fluxcal[ros]`): a ROS 1 `.bag` file, or a ROS 2 bag folder (its
metadata.yaml with .db3 or .mcap storage). No ROS installation is needed.

The magnetometer is the `sensor_msgs/MagneticField` topic (when a bag holds several, `columns` names one:
"/imu/mag"). Its field is in tesla by the message's definition; fluxcal records it in µT (×1e6, metadata
says so) so that the numbers are of the size calibration tolerances expect. Time is the message header's
stamp (the bag's receive time where a driver leaves the stamp at zero), in seconds since the first
reading (the first stamp in metadata "t_start_ns"). From a `sensor_msgs/Imu` topic the linear acceleration
(m/s², for levelling and diagnose's down direction) and from a `sensor_msgs/Temperature` topic the
temperature (°C) are interpolated to the magnetometer's times. The driver's stated field covariance, when
it gives one, goes to the metadata.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .recording import Recording

MAGNETIC_FIELD = "sensor_msgs/msg/MagneticField"
IMU = "sensor_msgs/msg/Imu"
TEMPERATURE = "sensor_msgs/msg/Temperature"
TESLA_TO_UT = 1e6


def bag_path(path: Path):
    """The path rosbags opens for `path`, or None when it is not a bag: a ROS 1 bag file, a ROS 2 bag
    folder, or a file inside one (metadata.yaml, a .db3 or .mcap part)."""
    if path.is_dir():
        return path if (path / "metadata.yaml").is_file() else None
    if path.is_file():
        with path.open("rb") as f:
            if f.read(13) == b"#ROSBAG V2.0\n":
                return path
        if (path.parent / "metadata.yaml").is_file() and (path.suffix in (".db3", ".mcap") or path.name == "metadata.yaml"):
            return path.parent
    return None


def _stamps(reader, connections):
    """(times in ns, messages) of the topics, in time order: the header stamp, else the bag's time."""
    times, msgs = [], []
    for conn, bag_ns, raw in reader.messages(connections=connections):
        msg = reader.deserialize(raw, conn.msgtype)
        stamp = msg.header.stamp
        ns = int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
        times.append(ns if ns > 0 else bag_ns)
        msgs.append(msg)
    order = np.argsort(np.array(times, dtype=np.int64), kind="stable")
    return np.array(times, dtype=np.int64)[order], [msgs[k] for k in order]


def read_rosbag(path, columns=None, units: str | None = None) -> Recording:
    path = Path(path)
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise ValueError(f"{path}: a ROS bag; reading it needs rosbags (pip install 'fluxcal[ros]')") from None
    where = bag_path(path) or path
    topic = columns if isinstance(columns, str) and columns.startswith("/") else None
    try:
        with AnyReader([where], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
            mags = [c for c in reader.connections if c.msgtype == MAGNETIC_FIELD]
            listing = ", ".join(f"{c.topic} ({c.msgtype})" for c in reader.connections) or "none"
            if topic is not None:
                mags = [c for c in mags if c.topic == topic]
            names = sorted({c.topic for c in mags})
            if not names:
                raise ValueError(f"{path}: no {MAGNETIC_FIELD} topic" + (f" {topic!r}" if topic else "")
                                 + f"; topics: {listing}")
            if len(names) > 1:
                raise ValueError(f"{path}: several magnetometer topics ({', '.join(names)}); name one with "
                                 f"--columns {names[0]}")
            t_ns, msgs = _stamps(reader, mags)
            if not msgs:
                raise ValueError(f"{path}: the topic {names[0]} has no messages")
            field = np.array([[m.magnetic_field.x, m.magnetic_field.y, m.magnetic_field.z] for m in msgs])
            cols = {"t": (t_ns - t_ns[0]) * 1e-9, **dict(zip(("mx", "my", "mz"), (field * TESLA_TO_UT).T))}
            unit_map = {"t": "s", "mx": "uT", "my": "uT", "mz": "uT"}
            metadata = {"topic": names[0], "t_start_ns": int(t_ns[0]),
                        "field_units": "tesla in the bag (sensor_msgs/MagneticField), ×1e6 → µT"}
            cov = np.asarray(msgs[0].magnetic_field_covariance, dtype=float).reshape(3, 3)
            if np.any(cov != 0):
                metadata["magnetic_field_covariance_uT2"] = (np.diag(cov) * TESLA_TO_UT ** 2).tolist()
            for msgtype, build in ((IMU, _acceleration), (TEMPERATURE, _temperature)):
                found = [c for c in reader.connections if c.msgtype == msgtype]
                if found:
                    t_src, side = _stamps(reader, found[:1])
                    if len(t_src) >= 2:
                        new, new_units = build(side, (t_src - t_ns[0]) * 1e-9, cols["t"])
                        cols.update(new)
                        unit_map.update(new_units)
                        metadata[f"{msgtype.split('/')[-1].lower()}_topic"] = found[0].topic
    except ValueError:
        raise
    except Exception as exc:  # rosbags raises its own errors for damaged bags
        raise ValueError(f"{path}: not a readable ROS bag ({type(exc).__name__}: {exc})") from None
    rec = Recording(columns=cols, units=unit_map, metadata=metadata, source=str(path))
    return rec.choose(None if topic else columns, units)


def _acceleration(msgs, t_src, t_dst):
    acc = np.array([[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z] for m in msgs])
    return ({k: np.interp(t_dst, t_src, acc[:, j]) for j, k in enumerate(("ax", "ay", "az"))},
            dict.fromkeys(("ax", "ay", "az"), "m/s^2"))


def _temperature(msgs, t_src, t_dst):
    return {"temp": np.interp(t_dst, t_src, [m.temperature for m in msgs])}, {"temp": "C"}
