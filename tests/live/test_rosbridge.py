"""Live rosbridge input (graphpos.live.rosbridge): a simulated drive written as a
ROS 1 and a ROS 2 bag, its messages sent one by one as rosbridge JSON, gives
the rows the importer gives; advertised, mapping-declared and inferred
types; both stamp forms; every unusable message is a MalformedMessage whose
one line names the topic and the field."""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "io"))
from recordings import BASE_S, copy_example, write_bag, write_tags_csv  # noqa: E402

from graphpos.drive import CHANNEL_SPECS, RsuMap, TagMap  # noqa: E402
from graphpos.errors import ConfigError  # noqa: E402
from graphpos.io.rosbag import import_rosbag  # noqa: E402
from graphpos.live.malformed import MalformedMessage  # noqa: E402
from graphpos.live.rosbridge import RosbridgeTranslator  # noqa: E402
from graphpos.sim import simulate  # noqa: E402


def rosbridge_json(msg: Any, ros1: bool) -> Any:
    """A deserialized rosbags message as rosbridge sends it: objects, arrays, stamps as secs/nsecs under ROS 1."""
    if dataclasses.is_dataclass(msg):
        if msg.__msgtype__ == "builtin_interfaces/msg/Time" and ros1:
            return {"secs": msg.sec, "nsecs": msg.nanosec}
        return {f.name: rosbridge_json(getattr(msg, f.name), ros1) for f in dataclasses.fields(msg)
                if not f.name.startswith("__")}
    if isinstance(msg, np.ndarray):
        return msg.tolist()
    if isinstance(msg, list):
        return [rosbridge_json(value, ros1) for value in msg]
    return msg


def ros1_name(msgtype: str) -> str:
    """``pkg/msg/Type`` -> ``pkg/Type``."""
    return msgtype.replace("/msg/", "/")


def stamp(t_s: float, ros1: bool = False) -> dict[str, int]:
    ns = int(round((BASE_S + t_s) * 1e9))
    return {"secs": ns // 10**9, "nsecs": ns % 10**9} if ros1 else {"sec": ns // 10**9, "nanosec": ns % 10**9}


def imu_msg(t_s: float = 1.0, yaw_rate_radps: Any = 0.2, **extra: Any) -> dict:
    vector = {"x": 0.0, "y": 0.0, "z": 0.0}
    return {"header": {"stamp": stamp(t_s), "frame_id": "imu"}, "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
            "angular_velocity": {**vector, "z": yaw_rate_radps}, "linear_acceleration": {**vector, "x": 0.5, "y": -0.1},
            **extra}


def range_msg(t_s: float = 1.0, frame_id: str = "3", range_m: float = 4.0) -> dict:
    return {"header": {"stamp": stamp(t_s), "frame_id": frame_id}, "radiation_type": 2, "field_of_view": 0.0,
            "min_range": 0.0, "max_range": 30.0, "range": range_m}


def publish(topic: str, msg: Any) -> dict:
    return {"op": "publish", "topic": topic, "msg": msg}


@pytest.fixture(scope="module")
def sim():
    """10 s with a lane change: every channel a bag holds, ranges from a ranging radio, late readings."""
    return simulate("paper-comprehensive", pattern="lane-change-straight", seed=3, duration_s=10,
                    overrides={"rfid": {"reports_range": True}}, rfid_latency_s=(0.05, 0.3))


@pytest.fixture(scope="module")
def example(sim, tmp_path_factory) -> Path:
    """The example mapping beside the simulated drive's tag map."""
    return copy_example("mapping_rosbag.toml", tmp_path_factory.mktemp("example"), sim)


@pytest.fixture(scope="module")
def bags(sim, example) -> dict[str, Path]:
    """The simulated drive as a ROS 1 bag and a ROS 2 MCAP bag, beside the example mapping."""
    return {"ros1": write_bag(sim, example.parent / "drive.bag", "ros1"),
            "ros2": write_bag(sim, example.parent / "drive_ros2", "ros2")}


def write_mapping(folder: Path, text: str) -> Path:
    """A mapping file beside a tag map (ids 1-3) and an RSU map (id 7)."""
    write_tags_csv(folder / "tags.csv", TagMap([1, 2, 3], [0.0, 5.0, 10.0], [1.0, 1.0, 1.0], [0, 0, 0], [-1, -1, -1]))
    (folder / "rsus.csv").write_text("rsu_id,east_m,north_m\n7,20.0,0.0\n")
    path = folder / "m.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("version", ["ros1", "ros2"])
def test_messages_sent_live_give_the_rows_of_the_imported_bag(version, bags, example):
    """ROS 1: every topic advertised with its ROS 1 type name, stamps as secs/nsecs; ROS 2: types inferred."""
    bag = bags[version]
    drive = import_rosbag(bag, example)
    translator = RosbridgeTranslator(example)
    assert translator.topics == {"/imu/data", "/odom", "/heading", "/uwb/range", "/fix"}  # not the truth's: scoring only
    assert translator.tags == drive.tags and translator.origin == drive.origin
    got: dict[str, list] = {}
    with AnyReader([bag]) as reader:
        if version == "ros1":
            for connection in reader.connections:
                advertise = {"op": "advertise", "topic": connection.topic, "type": ros1_name(connection.msgtype)}
                assert translator.translate(advertise, 0.0) == []
        for connection, record_ns, data in reader.messages():
            if connection.topic not in translator.topics:
                continue  # the truth's topic: a live vehicle has no truth to send
            msg = rosbridge_json(reader.deserialize(data, connection.msgtype), version == "ros1")
            message = json.loads(json.dumps(publish(connection.topic, msg)))  # NaN as rosbridge writes it
            for m in translator.translate(message, record_ns / 1e9):
                got.setdefault(m.channel, []).append(m)
    assert set(got) == set(drive.channels) - {"truth"}
    for name, channel in drive.without_truth().channels.items():
        rows = sorted(got[name], key=lambda m: m.t_s)  # the importer sorts by stamp, stably
        assert len(rows) == len(channel), name
        assert all(list(m.values) == [spec.name for spec in CHANNEL_SPECS[name]] for m in rows)
        assert all(m.t_s == m.values["t_s"] and m.arrival_s == m.values.get("arrival_s", m.t_s) for m in rows)
        for column, values in channel.columns.items():
            if column == "arrival_s":  # live: a reading's own time (the session orders arrivals), not a record time
                values = channel.t_s
            np.testing.assert_allclose([m.values[column] for m in rows], values, rtol=0, atol=1e-12, equal_nan=True,
                                       err_msg=f"{name}.{column}")


@pytest.mark.parametrize("msgtype", ["sensor_msgs/Imu", "sensor_msgs/msg/Imu", "nav_msgs/msg/Odometry"])
def test_the_importer_checks_the_mapping_type_against_the_bag(msgtype, bags, example, tmp_path):
    mapping = tmp_path / "m.toml"
    mapping.write_text(example.read_text().replace('topic = "/imu/data"', f'topic = "/imu/data"\ntype = "{msgtype}"', 1))
    (tmp_path / "tags.csv").write_bytes((example.parent / "tags.csv").read_bytes())
    if msgtype.endswith("Imu"):
        assert len(import_rosbag(bags["ros1"], mapping).imu) == len(import_rosbag(bags["ros1"], example).imu)
        return
    with pytest.raises(ConfigError, match=r"\[imu\] type: topic '/imu/data' carries sensor_msgs/msg/Imu in .*drive.bag, "
                                          "not nav_msgs/msg/Odometry"):
        import_rosbag(bags["ros1"], mapping)


def test_imu_feeds_imu_and_compass_under_the_mapping_type(tmp_path):
    mapping = write_mapping(tmp_path, '[imu]\ntopic = "/imu"\ntype = "sensor_msgs/msg/Imu"\n'
                                      '[compass]\ntopic = "/imu"\nconvention = "north_cw"\n')
    translator = RosbridgeTranslator(mapping)
    q = {"x": 0.0, "y": 0.0, "z": math.sin(0.3 / 2), "w": math.cos(0.3 / 2)}
    imu, compass = translator.translate(publish("/imu", imu_msg(2.0, orientation=q)), BASE_S + 2.5)
    assert imu.channel == "imu" and compass.channel == "compass"
    assert imu.t_s == compass.t_s == pytest.approx(BASE_S + 2.0, abs=1e-6)
    assert imu.values == {"t_s": imu.t_s, "accel_x_mps2": 0.5, "accel_y_mps2": -0.1, "yaw_rate_radps": 0.2}
    assert compass.values["yaw_rad"] == pytest.approx(math.pi / 2 - 0.3)
    assert translator.translate({"op": "advertise", "topic": "/imu", "type": "sensor_msgs/Imu"}, 0.0) == []


def test_a_driver_type_is_read_once_advertised_one_row_per_array_element(tmp_path):
    mapping = write_mapping(tmp_path, '[drive]\ntags = "tags.csv"\n[rfid]\ntopic = "/uwb"\nunits = { range = "mm" }\n'
                                      'ids = { "A" = 1, "B" = 2 }\n'
                                      'fields = { tag_id = "ranges[*].anchor", range = "ranges[*].distance_mm" }\n')
    translator = RosbridgeTranslator(mapping)
    msg = {"header": {"stamp": stamp(1.0)}, "ranges": [{"anchor": "A", "distance_mm": 1500.0},
                                                        {"anchor": "B", "distance_mm": 2500}]}
    with pytest.raises(MalformedMessage, match="topic '/uwb': message type unknown .*advertise the topic or set type") as bad:
        translator.translate(publish("/uwb", msg), BASE_S + 1.2)
    assert bad.value.kind == "type"
    assert translator.translate({"op": "advertise", "topic": "/uwb", "type": "uwb_msgs/Ranges"}, 0.0) == []
    rows = translator.translate(publish("/uwb", msg), BASE_S + 1.2)
    assert [(m.values["tag_id"], m.values["range_m"], m.arrival_s) for m in rows] == [(1.0, 1.5, rows[0].t_s),
                                                                                      (2.0, 2.5, rows[0].t_s)]
    assert rows[0].t_s == pytest.approx(BASE_S + 1.0, abs=1e-6)  # the stamp, not the receipt
    assert all(m.values["arrival_s"] == m.arrival_s and math.isnan(m.values["rss"]) for m in rows)
    assert translator.translate(publish("/uwb", {**msg, "ranges": []}), BASE_S + 1.2) == []


def test_ros1_and_ros2_stamps_give_the_same_time(tmp_path):
    translator = RosbridgeTranslator(write_mapping(tmp_path, '[imu]\ntopic = "/imu"\n'))
    ros2, = translator.translate(publish("/imu", imu_msg(3.25)), 0.0)
    ros1_msg = imu_msg(3.25)
    ros1_msg["header"] = {"seq": 4, "stamp": stamp(3.25, ros1=True), "frame_id": "imu"}
    ros1, = translator.translate(publish("/imu", ros1_msg), 0.0)
    assert ros1 == ros2
    assert ros2.t_s == pytest.approx(BASE_S + 3.25, abs=1e-6)


def test_record_time_numeric_time_fields_and_fixes_without_a_fix(tmp_path):
    mapping = write_mapping(tmp_path, '[drive]\norigin = { lat_deg = 29.563, lon_deg = 106.5516 }\n'
                                      '[wheel]\ntopic = "/speed"\ntype = "std_msgs/Float64"\nfields = { speed = "data" }\n'
                                      'units = { speed = "km/h" }\n'
                                      '[imu]\ntopic = "/gyro"\ntype = "my_msgs/Gyro"\ntime = "t_ms"\n'
                                      'units = { time = "ms", yaw_rate = "deg/s" }\nfields = { yaw_rate = "wz" }\n'
                                      '[gnss]\ntopic = "/fix"\n')
    translator = RosbridgeTranslator(mapping)
    speed, = translator.translate(publish("/speed", {"data": 36.0}), 12.5)
    assert (speed.t_s, speed.values["speed_mps"]) == (12.5, pytest.approx(10.0))
    gyro, = translator.translate(publish("/gyro", {"t_ms": 1500, "wz": 90.0}), 99.0)
    assert (gyro.t_s, gyro.values["yaw_rate_radps"]) == (1.5, pytest.approx(math.pi / 2))
    assert math.isnan(gyro.values["accel_x_mps2"])
    fix = {"header": {"stamp": stamp(1.0)}, "status": {"status": 0, "service": 1}, "latitude": 29.563,
           "longitude": 106.5516, "altitude": 0.0, "position_covariance": [4.0, 0, 0, 0, 4.0, 0, 0, 0, 9.0],
           "position_covariance_type": 2}
    gnss, = translator.translate(publish("/fix", fix), BASE_S + 1.1)
    assert gnss.values == {"t_s": gnss.t_s, "east_m": pytest.approx(0.0, abs=1e-6),
                           "north_m": pytest.approx(0.0, abs=1e-6), "sigma_m": 2.0}
    no_fix = {**fix, "status": {"status": -1, "service": 1}, "latitude": None, "longitude": None}
    assert translator.translate(publish("/fix", no_fix), BASE_S + 1.1) == []


def test_a_mappings_truth_is_never_read_live(tmp_path):
    translator = RosbridgeTranslator(write_mapping(tmp_path, '[imu]\ntopic = "/imu"\n[truth]\ntopic = "/gt"\n'))
    assert translator.topics == {"/imu"}
    with pytest.raises(MalformedMessage) as refused:
        translator.translate(publish("/gt", {}), BASE_S)
    assert refused.value.kind == "topic"


@pytest.mark.parametrize("text, fragments", [
    ('[gnss]\ntopic = "/fix"\ntype = "sensor_msgs/msg/Imu"\n',
     ["[gnss]: topic '/fix' carries sensor_msgs/msg/Imu, which [gnss] does not read by default"]),
    ('[imu]\ntopic = "/imu"\ntype = "sensor_msgs/msg/Imu"\n[compass]\ntopic = "/imu"\ntype = "nav_msgs/msg/Odometry"\n',
     ["topic '/imu' is given the types nav_msgs/msg/Odometry, sensor_msgs/msg/Imu"]),
    ('[imu]\ntopic = "/imu"\ntype = "Imu"\n', ["[imu] type: expected a message type such as sensor_msgs/msg/Imu"]),
    ('[imu]\ntopic = "/imu"\ntype = "sensor_msgs/Imu"\nfields = { yaw_rate = "angular_velocity.w" }\n',
     ["geometry_msgs/msg/Vector3 has no field 'w'"]),
])
def test_a_mapping_live_input_cannot_serve_is_refused(text, fragments, tmp_path):
    with pytest.raises(ConfigError) as refused:
        RosbridgeTranslator(write_mapping(tmp_path, text))
    assert "\n" not in str(refused.value)
    for fragment in fragments:
        assert fragment in str(refused.value)


_MAPPING = ('[drive]\ntags = "tags.csv"\nrsus = "rsus.csv"\n[imu]\ntopic = "/imu"\ntype = "sensor_msgs/Imu"\n[rfid]\ntopic = "/range"\n'
            '[truth]\ntopic = "/pose"\n'
            '[rsu]\ntopic = "/rsu"\ntype = "sensor_msgs/Range"\nids = { "rsu_a" = 7, "rsu_b" = 8 }\n'
            'fields = { rsu_id = "header.frame_id", range = "range", sigma = 0.5 }\n')
_BAD_STAMP = {"header": {"stamp": {"secs": 1.5, "nsecs": 0}}}
_POSE = {"header": {"stamp": stamp(1.0)}, "pose": {"position": {"x": 0.0, "y": 0.0, "z": 0.0},
                                                    "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}}

#: A message, its kind, and what its one line says.
MALFORMED = {
    "not an object": (["publish"], "json", ["a rosbridge message is a JSON object, not an array"]),
    "other op": ({"op": "subscribe", "topic": "/imu"}, "op", ["op 'subscribe' is not read (publish, advertise)"]),
    "no op": ({"topic": "/imu", "msg": {}}, "op", ["op None is not read"]),
    "no topic": ({"op": "publish", "msg": {}}, "field", ["publish: 'topic' is null, not a topic name"]),
    "unmapped topic": (publish("/cmd_vel", {}), "topic", ["topic '/cmd_vel' is not in the mapping (its topics: /imu"]),
    "no msg": ({"op": "publish", "topic": "/imu"}, "field", ["publish on topic '/imu': 'msg' is null, not a message"]),
    "unknown type": (publish("/range", {"distance": 1.0}), "type",
                     ["topic '/range': message type unknown (the message fits none of sensor_msgs/msg/Range)",
                      "advertise the topic or set type = \"pkg/msg/Type\" in [rfid]"]),
    "bad advertised type": ({"op": "advertise", "topic": "/range", "type": "Range"}, "type",
                            ["advertise of topic '/range': type: expected a message type", "got 'Range'"]),
    "advertised type the mapping cannot read": ({"op": "advertise", "topic": "/range", "type": "std_msgs/Float64"}, "type",
                                                ["topic '/range' is advertised as std_msgs/msg/Float64, which the mapping "
                                                 "cannot read", "[rfid]: topic '/range' carries std_msgs/msg/Float64"]),
    "advertised type not the mapping's": ({"op": "advertise", "topic": "/imu", "type": "nav_msgs/msg/Odometry"}, "type",
                                          ["topic '/imu' is advertised as nav_msgs/msg/Odometry; the mapping's type is "
                                           "sensor_msgs/msg/Imu"]),
    "missing field": (publish("/imu", {k: v for k, v in imu_msg().items() if k != "angular_velocity"}), "field",
                      ["topic '/imu', message received at 1700000001.500000 s, field 'angular_velocity.z' (yaw_rate): "
                       "no field 'angular_velocity' (its fields: header, orientation, linear_acceleration)"]),
    "not an object on the path": (publish("/imu", imu_msg(angular_velocity=[1.0])), "field",
                                  ["field 'angular_velocity.z' (yaw_rate): 'z' is not a field (an array has none)"]),
    "mistyped number": (publish("/imu", imu_msg(yaw_rate_radps="0.2")), "field",
                        ["field 'angular_velocity.z' (yaw_rate): '0.2' is a string, not a number"]),
    "boolean number": (publish("/imu", imu_msg(yaw_rate_radps=True)), "field", ["True is a boolean, not a number"]),
    "non-finite value": (publish("/imu", imu_msg(yaw_rate_radps=float("nan"))), "field",
                         ["field 'angular_velocity.z' (yaw_rate): nan is not a finite number"]),
    "null value": (publish("/imu", imu_msg(yaw_rate_radps=None)), "field",  # rosbridge's NaN
                   ["field 'angular_velocity.z' (yaw_rate): nan is not a finite number"]),
    "number too large": (publish("/imu", imu_msg(yaw_rate_radps=10**400)), "field", ["is too large for a number"]),
    "id too large": (publish("/range", range_msg(frame_id=10**400)), "field", ["(tag_id): 1000", "is too large"]),
    "out of range": (publish("/imu", imu_msg(yaw_rate_radps=100.0)), "field",
                     ["topic '/imu', message received at 1700000001.500000 s: yaw_rate_radps = 100 is outside the "
                      "plausible range"]),
    "non-finite time": (publish("/imu", imu_msg(header={"stamp": float("inf")})), "field",
                        ["field 'header.stamp' (time): inf is not a finite number"]),
    "stamp of fractions": (publish("/imu", imu_msg(**_BAD_STAMP)), "field",
                           ["field 'header.stamp' (time): stamp secs 1.5, nsecs 0 are not whole numbers"]),
    "stamp without seconds": (publish("/imu", imu_msg(header={"stamp": {"nanosec": 5}})), "field",
                              ["without sec and nanosec (ROS 2) or secs and nsecs (ROS 1) is not a stamp"]),
    "tag id not a number": (publish("/range", range_msg(frame_id="anchor")), "id",
                            ["topic '/range', message received at 1700000001.500000 s, field 'header.frame_id' (tag_id): "
                             "'anchor' is not a number; map names to ids with ids"]),
    "tag not in the map": (publish("/range", range_msg(frame_id="9")), "id",
                           ["field 'header.frame_id' (tag_id): tag id 9 is not in the tag map"]),
    "RSU name not in ids": (publish("/rsu", range_msg(frame_id="rsu_c")), "id",
                            ["topic '/rsu'", "field 'header.frame_id' (rsu_id): 'rsu_c' is not in ids (known: rsu_a, rsu_b)"]),
    "RSU not in the map": (publish("/rsu", range_msg(frame_id="rsu_b")), "id", ["RSU id 8 is not in the RSU map"]),
}


@pytest.mark.parametrize("case", MALFORMED)
def test_an_unusable_message_is_malformed_with_one_line_naming_topic_and_field(case, tmp_path):
    message, kind, fragments = MALFORMED[case]
    translator = RosbridgeTranslator(write_mapping(tmp_path, _MAPPING))
    with pytest.raises(MalformedMessage) as bad:
        translator.translate(message, BASE_S + 1.5)
    assert bad.value.kind == kind
    reason = str(bad.value)
    assert "\n" not in reason
    for fragment in fragments:
        assert fragment in reason, reason


def test_after_a_malformed_message_the_next_good_one_is_read(tmp_path):
    translator = RosbridgeTranslator(write_mapping(tmp_path, _MAPPING))
    with pytest.raises(MalformedMessage):
        translator.translate(publish("/range", range_msg(frame_id="9")), BASE_S + 1.5)
    reading, = translator.translate(publish("/range", range_msg(frame_id="3")), BASE_S + 1.5)
    assert (reading.values["tag_id"], reading.values["range_m"]) == (3.0, 4.0)
    rsu, = translator.translate(publish("/rsu", range_msg(frame_id="rsu_a", range_m=12.0)), BASE_S + 1.5)
    assert (rsu.values["rsu_id"], rsu.values["range_m"], rsu.values["sigma_m"]) == (7.0, 12.0, 0.5)
    assert math.isnan(rsu.values["east_m"])
    assert isinstance(translator.rsus, RsuMap) and translator.rsus.rsu_id.tolist() == [7]


_FIX = {"header": {"stamp": stamp(1.0)}, "status": {"status": 0, "service": 1}, "latitude": 29.563, "longitude": 106.5516,
        "altitude": 0.0, "position_covariance": [4.0, 0, 0, 0, 4.0, 0, 0, 0, 9.0], "position_covariance_type": 2}
_JUNK = [None, True, -1, float("inf"), 10**400, "x", [], {"a": 1}, {"secs": -5, "nsecs": 10**12},
         {"x": 0, "y": 0, "z": 0, "w": 0}]


def _leaf_paths(value: Any, path: tuple = ()) -> list[tuple]:
    """Every path to a value inside a JSON message (the message's own path () excluded)."""
    children = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else []
    return [p for key, child in children for p in [path + (key,), *_leaf_paths(child, path + (key,))]]


@pytest.mark.filterwarnings("ignore:Gimbal lock")  # an orientation pitched 90 degrees still has a yaw
@pytest.mark.parametrize("topic, msg", [("/imu", imu_msg()), ("/range", range_msg()), ("/fix", _FIX)])
def test_any_value_anywhere_gives_rows_or_a_malformed_message(topic, msg, tmp_path):
    mapping = write_mapping(tmp_path, _MAPPING + '[compass]\ntopic = "/imu"\n[gnss]\ntopic = "/fix"\n')
    mapping.write_text(mapping.read_text().replace("[drive]\n", "[drive]\norigin = { lat_deg = 29.563, lon_deg = 106.5516 }\n"))
    translator = RosbridgeTranslator(mapping)
    for path in _leaf_paths(msg):
        for junk in [*_JUNK, "drop"]:
            damaged = json.loads(json.dumps(msg))
            parent = damaged
            for key in path[:-1]:
                parent = parent[key]
            if junk == "drop":
                del parent[path[-1]]
            else:
                parent[path[-1]] = junk
            try:
                translator.translate(publish(topic, damaged), BASE_S + 1.5)
            except MalformedMessage as bad:
                assert "\n" not in str(bad) and bad.kind in ("field", "id", "type")


def test_a_ros_vehicle_feeds_graphpos_live_through_rosbridge(bags, example, sim, tmp_path):
    """``graphpos live --mapping``: the bag's topics sent as rosbridge JSON over UDP (its truth kept back),
    estimates for the whole drive, nothing malformed."""
    import socket
    import time

    from live_helpers import LiveProcess

    from graphpos.io import read_estimates, write_drive

    site = tmp_path / "site.mcap"
    write_drive(site, import_rosbag(bags["ros2"], example))
    rec = tmp_path / "rec.mcap"
    live = LiveProcess("--site", str(site), "--mapping", str(example), "-e", "fusion-ekf", "-e", "graph-isam2",
                       "--listen", "udp://127.0.0.1:0", "--no-foxglove", "--quiet", "-o", str(rec), cwd=tmp_path)
    host, port = live.listen.removeprefix("udp://").rsplit(":", 1)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        with AnyReader([bags["ros2"]]) as reader:
            for connection, _, data in reader.messages():
                if connection.topic == "/ground_truth":
                    continue
                msg = rosbridge_json(reader.deserialize(data, connection.msgtype), False)
                sock.sendto(json.dumps(publish(connection.topic, msg)).encode(), (host, int(port)))
                time.sleep(0.0003)
        for _ in range(3):
            sock.sendto(b'{"op": "graphpos_end"}', (host, int(port)))
        status, final = live.result()
    finally:
        sock.close()
        live.kill()
    assert status == 0 and final["ended"] and final["malformed_total"] == 0, "\n".join(live.stderr)
    truth = import_rosbag(bags["ros2"], example).truth
    for est in read_estimates(rec):
        assert est.t_s[-1] > truth.t_s[-1] - 1.0
        err = np.hypot(est.east_m - np.interp(est.t_s, truth.t_s, truth.east_m), est.north_m - np.interp(est.t_s, truth.t_s, truth.north_m))
        assert np.sqrt(np.mean(err**2)) < 1.5, f"{est.name}: {np.sqrt(np.mean(err ** 2)):.2f} m"
