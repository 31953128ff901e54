"""Shared helpers of the importer tests: a simulated drive written as a ROS
bag (with rosbags' writers) or as CSV logs, laid out as the example
mappings in ``examples/`` expect, and what importing it must give back."""

from __future__ import annotations

import csv
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pymap3d
from rosbags.interfaces import Nodetype
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import StoragePlugin, Writer as Ros2Writer
from rosbags.typesys import Stores, get_typestore
from test_cli_drives import assert_one_line_error, run

from graphpos.drive import Channel, Drive, TagMap
from graphpos.registry import estimator_classes, make_estimator
from graphpos.sim import simulate

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
#: Unix time of the simulated drive's start (bags and loggers stamp Unix time).
BASE_S = 1_700_000_000.0
#: Delay from a header stamp to the record time of a message with a header.
RECORD_DELAY_NS = 1_000_000


def simulated_drive() -> Drive:
    """30 s with a lane change: every channel a bag holds, ranges from a ranging radio, late readings."""
    return simulate("paper-comprehensive", pattern="lane-change-straight", seed=3, duration_s=30,
                    overrides={"rfid": {"reports_range": True}}, rfid_latency_s=(0.05, 0.3))


def expected_import(drive: Drive, truth_yaw_rate: bool = True) -> Drive:
    """What importing ``drive``'s recording gives: Unix times, no RSS (a range message has none), no
    truth-derived columns, no windows, no layouts but ``dense``, truth accelerations (and, unless
    ``truth_yaw_rate``, yaw rate) unknown."""
    channels = {}
    for name, ch in drive.channels.items():
        cols = {k: v + BASE_S if k in ("t_s", "arrival_s") else v for k, v in ch.columns.items()}
        if name == "rfid":
            cols.update(rss=np.full(len(ch), np.nan), true_range_m=np.full(len(ch), np.nan))
        if name == "truth":
            unknown = ("accel_x_mps2", "accel_y_mps2") + (() if truth_yaw_rate else ("yaw_rate_radps",))
            cols.update({k: np.full(len(ch), np.nan) for k in unknown})
        channels[name] = Channel(name, cols)
    tags = drive.tags
    return drive.replace(channels=channels, windows=(), tags=type(tags)(tags.tag_id, tags.east_m, tags.north_m,
                                                                        tags.wall_side, tags.group))


def assert_channels_close(got: Drive, want: Drive) -> None:
    """Every channel's columns equal within float tolerance (compass yaw modulo 2 pi)."""
    assert list(got.channels) == list(want.channels)
    for name, ch in want.channels.items():
        assert len(got.channels[name]) == len(ch), name
        for column, values in ch.columns.items():
            value = got.channels[name][column]
            if name == "compass" and column == "yaw_rad":
                value = values + np.angle(np.exp(1j * (value - values)))
            np.testing.assert_allclose(value, values, rtol=1e-9, atol=2e-6, equal_nan=True, err_msg=f"{name}.{column}")
    assert got.tags == want.tags


def position_rms_m(drive: Drive) -> dict[str, float]:
    """Each registered estimator's position RMS against the drive's truth (run without it)."""
    hidden = drive.without_truth()
    rms = {}
    for name in estimator_classes():
        estimate = make_estimator(name).run(hidden)
        east = np.interp(estimate.t_s, drive.truth.t_s, drive.truth.east_m)
        north = np.interp(estimate.t_s, drive.truth.t_s, drive.truth.north_m)
        rms[name] = float(np.sqrt(np.nanmean((estimate.east_m - east) ** 2 + (estimate.north_m - north) ** 2)))
    return rms


def write_tags_csv(path: Path, tags: TagMap) -> None:
    with path.open("w", newline="") as stream:
        out = csv.writer(stream)
        out.writerow(["tag_id", "east_m", "north_m", "wall_side", "group"])
        out.writerows(zip(tags.tag_id.tolist(), tags.east_m.tolist(), tags.north_m.tolist(), tags.wall_side.tolist(),
                          tags.group.tolist()))


def copy_example(name: str, folder: Path, drive: Drive) -> Path:
    """An example mapping copied into ``folder``, beside the drive's tag map."""
    folder.mkdir(parents=True, exist_ok=True)
    target = folder / name
    shutil.copy(EXAMPLES / name, target)
    write_tags_csv(folder / "tags.csv", drive.tags)
    return target


def assert_bad_mapping_refused(capsys: Any, source_format: str, source: Path, folder: Path, drive: Drive, old: str,
                               new: str, fragments: list[str]) -> None:
    """`graphpos import FORMAT` through the example mapping with ``old`` replaced by ``new``: status 2, one
    error line holding every fragment, no output file."""
    mapping = copy_example(f"mapping_{source_format}.toml", folder, drive)
    text = mapping.read_text()
    assert old in text
    mapping.write_text(text.replace(old, new, 1))
    out = folder / "out.mcap"
    assert_one_line_error(*run(capsys, "import", source_format, source, "--mapping", mapping, "-o", out), *fragments)
    assert not out.exists()


def heading_deg(yaw_rad: np.ndarray) -> np.ndarray:
    """Compass degrees from north, clockwise, in [0, 360)."""
    return np.remainder(90.0 - np.degrees(yaw_rad), 360.0)


def geodetic(drive: Drive, east_m: np.ndarray, north_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    o = drive.origin
    return pymap3d.enu2geodetic(east_m, north_m, 0.0, o.lat_deg, o.lon_deg, o.alt_m)


# -- ROS bags --------------------------------------------------------------------------------------------------
def make(typestore: Any, msgtype: str, **values: Any) -> Any:
    """A message of ``msgtype`` with the given fields, every other field zero, empty or a zero sub-message."""
    kwargs = {}
    for name, (kind, detail) in typestore.fielddefs[msgtype][1]:
        if name in values:
            kwargs[name] = values[name]
        elif kind == Nodetype.NAME:
            kwargs[name] = make(typestore, detail)
        elif kind == Nodetype.BASE:
            kwargs[name] = "" if detail[0] == "string" else 0.0 if detail[0].startswith("float") else 0
        elif kind == Nodetype.ARRAY:
            kwargs[name] = np.zeros(detail[1], dtype=np.float64)
        else:
            kwargs[name] = []
    return typestore.types[msgtype](**kwargs)


class BagWriter:
    """Messages collected per topic, then written in record-time order as a ROS 1 or ROS 2 bag."""

    def __init__(self, version: str):
        self.version = version
        self.typestore = get_typestore(Stores.ROS1_NOETIC if version == "ros1" else Stores.ROS2_HUMBLE)
        self.messages: list[tuple[int, str, str, Any]] = []

    def header(self, t_s: float, frame_id: str = "") -> Any:
        ns = int(round((BASE_S + t_s) * 1e9))
        stamp = make(self.typestore, "builtin_interfaces/msg/Time", sec=ns // 10**9, nanosec=ns % 10**9)
        return make(self.typestore, "std_msgs/msg/Header", stamp=stamp, frame_id=frame_id)

    def vector(self, **xyz: float) -> Any:
        return make(self.typestore, "geometry_msgs/msg/Vector3", **xyz)

    def add(self, topic: str, msgtype: str, record_s: float, **fields: Any) -> None:
        record_ns = int(round((BASE_S + record_s) * 1e9))
        self.messages.append((record_ns, topic, msgtype, make(self.typestore, msgtype, **fields)))

    def write(self, path: Path) -> Path:
        if self.version == "ros1":
            writer, serialize = Ros1Writer(path), self.typestore.serialize_ros1
        else:
            storage = StoragePlugin.SQLITE3 if self.version == "ros2-db3" else StoragePlugin.MCAP
            writer, serialize = Ros2Writer(path, version=9, storage_plugin=storage), self.typestore.serialize_cdr
        with writer:
            connections = {}
            for record_ns, topic, msgtype, msg in sorted(self.messages, key=lambda m: m[0]):
                if topic not in connections:
                    connections[topic] = writer.add_connection(topic, msgtype, typestore=self.typestore)
                writer.write(connections[topic], record_ns, serialize(msg, msgtype))
        return path


def write_bag(drive: Drive, path: Path, version: str) -> Path:
    """``drive`` as the topics of ``examples/mapping_rosbag.toml``, plus one GNSS message without a fix."""
    w = BagWriter(version)
    late = RECORD_DELAY_NS / 1e9
    imu, wheel, truth = drive.imu, drive.wheel, drive.truth
    for t, ax, ay, wz in zip(imu.t_s.tolist(), imu.accel_x_mps2.tolist(), imu.accel_y_mps2.tolist(), imu.yaw_rate_radps.tolist()):
        w.add("/imu/data", "sensor_msgs/msg/Imu", t + late, header=w.header(t), angular_velocity=w.vector(z=wz),
              linear_acceleration=w.vector(x=ax, y=ay, z=9.81))
    for t, speed in zip(wheel.t_s.tolist(), wheel.speed_mps.tolist()):
        twist = make(w.typestore, "geometry_msgs/msg/TwistWithCovariance",
                     twist=make(w.typestore, "geometry_msgs/msg/Twist", linear=w.vector(x=speed)))
        w.add("/odom", "nav_msgs/msg/Odometry", t + late, header=w.header(t), twist=twist)
    for t, heading in zip(drive.compass.t_s.tolist(), heading_deg(drive.compass.yaw_rad).tolist()):
        w.add("/heading", "std_msgs/msg/Float64", t, data=heading)
    rfid = drive.rfid
    for t, arrival, tag, rng in zip(rfid.t_s.tolist(), rfid.arrival_s.tolist(), rfid.tag_id.tolist(), rfid.range_m.tolist()):
        w.add("/uwb/range", "sensor_msgs/msg/Range", arrival, header=w.header(t, str(int(tag))), range=rng, max_range=30.0)
    gnss = drive.gnss
    lat, lon, alt = geodetic(drive, gnss.east_m, gnss.north_m)
    for t, la, lo, h, sigma in zip(gnss.t_s.tolist(), lat.tolist(), lon.tolist(), alt.tolist(), gnss.sigma_m.tolist()):
        cov = np.diag([sigma**2, sigma**2, (2 * sigma) ** 2]).reshape(9)
        w.add("/fix", "sensor_msgs/msg/NavSatFix", t + late, header=w.header(t), latitude=la, longitude=lo, altitude=h,
              position_covariance=cov, position_covariance_type=2)
    no_fix = make(w.typestore, "sensor_msgs/msg/NavSatStatus", status=-1)
    w.add("/fix", "sensor_msgs/msg/NavSatFix", 20.0, header=w.header(20.0), status=no_fix, latitude=np.nan,
          longitude=np.nan, altitude=np.nan)
    for t, e, n, ve, vn, yaw, wz in zip(*(truth[c].tolist() for c in ("t_s", "east_m", "north_m", "v_east_mps",
                                                                       "v_north_mps", "yaw_rad", "yaw_rate_radps"))):
        pose = make(w.typestore, "geometry_msgs/msg/Pose", position=make(w.typestore, "geometry_msgs/msg/Point", x=e, y=n),
                    orientation=make(w.typestore, "geometry_msgs/msg/Quaternion", z=np.sin(yaw / 2), w=np.cos(yaw / 2)))
        forward, left = ve * np.cos(yaw) + vn * np.sin(yaw), -ve * np.sin(yaw) + vn * np.cos(yaw)
        twist = make(w.typestore, "geometry_msgs/msg/Twist", linear=w.vector(x=forward, y=left), angular=w.vector(z=wz))
        w.add("/ground_truth", "nav_msgs/msg/Odometry", t + late, header=w.header(t),
              pose=make(w.typestore, "geometry_msgs/msg/PoseWithCovariance", pose=pose),
              twist=make(w.typestore, "geometry_msgs/msg/TwistWithCovariance", twist=twist))
    return w.write(path)


# -- CSV logs --------------------------------------------------------------------------------------------------
def _ms(t_s: np.ndarray) -> list[str]:
    return [repr(v) for v in ((BASE_S + t_s) * 1000.0).tolist()]


def _write_csv(path: Path, header: list[str], columns: list[list[Any]]) -> None:
    with path.open("w", newline="") as stream:
        out = csv.writer(stream)
        out.writerow(header)
        out.writerows(zip(*columns))


def write_csv_logs(drive: Drive, folder: Path) -> Path:
    """``drive`` as the files of ``examples/mapping_csv.toml`` (times in ms, gyro in deg/s, speed in km/h,
    compass degrees from north, clockwise, GNSS latitude/longitude)."""
    folder.mkdir(parents=True, exist_ok=True)
    imu = drive.imu
    _write_csv(folder / "imu.csv", ["time_ms", "gyro_z", "acc_x", "acc_y"],
               [_ms(imu.t_s), np.degrees(imu.yaw_rate_radps).tolist(), imu.accel_x_mps2.tolist(), imu.accel_y_mps2.tolist()])
    wheel, compass = drive.wheel, drive.compass
    rows = sorted([(t, str(t_ms), repr(v * 3.6), "") for t, t_ms, v in zip(wheel.t_s, _ms(wheel.t_s), wheel.speed_mps.tolist())]
                  + [(t, str(t_ms), "", repr(h)) for t, t_ms, h in zip(compass.t_s, _ms(compass.t_s), heading_deg(compass.yaw_rad).tolist())],
                  key=lambda row: row[0])
    _write_csv(folder / "vehicle.csv", ["time_ms", "speed", "heading"], [list(c) for c in list(zip(*rows))[1:]])
    rfid = drive.rfid
    _write_csv(folder / "ranges.csv", ["time_ms", "received_ms", "tag", "range"],
               [_ms(rfid.t_s), _ms(rfid.arrival_s), rfid.tag_id.astype(int).tolist(), rfid.range_m.tolist()])
    gnss = drive.gnss
    lat, lon, _ = geodetic(drive, gnss.east_m, gnss.north_m)
    _write_csv(folder / "gnss.csv", ["time_ms", "lat", "lon", "accuracy"], [_ms(gnss.t_s), lat.tolist(), lon.tolist(), gnss.sigma_m.tolist()])
    truth = drive.truth
    _write_csv(folder / "reference.csv", ["time_ms", "east", "north", "yaw", "v_east", "v_north"],
               [_ms(truth.t_s), *(truth[c].tolist() for c in ("east_m", "north_m", "yaw_rad", "v_east_mps", "v_north_mps"))])
    return folder
