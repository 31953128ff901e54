"""`graphpos import rosbag`: a simulated drive written as a ROS 1 bag and a
ROS 2 MCAP bag with rosbags' writers comes back through the example mapping
(channels equal, every estimator recovers the trajectory); other message
types, a UWB driver's own message; every bad mapping is one line, status 2
and no output file."""

from __future__ import annotations

import os
import re

import numpy as np
import pytest
from recordings import (assert_bad_mapping_refused, assert_channels_close, BagWriter, copy_example, expected_import,
                        make, position_rms_m, simulated_drive, write_bag, write_tags_csv)
from rosbags.typesys import get_types_from_msg
from test_cli_drives import assert_one_line_error, run

from graphpos.drive import Drive, TagMap
from graphpos.errors import FileFormatError
from graphpos.io import read_drive
from graphpos.io.rosbag import import_rosbag


@pytest.fixture(scope="module")
def sim() -> Drive:
    return simulated_drive()


@pytest.fixture(scope="module")
def bags(sim, tmp_path_factory):
    """The simulated drive as a ROS 1 bag and a ROS 2 MCAP bag, beside the example mapping."""
    folder = tmp_path_factory.mktemp("bags")
    mapping = copy_example("mapping_rosbag.toml", folder, sim)
    return {"ros1": write_bag(sim, folder / "drive.bag", "ros1"),
            "ros2": write_bag(sim, folder / "drive_ros2", "ros2")}, mapping


@pytest.mark.parametrize("version", ["ros1", "ros2"])
def test_bag_comes_back_and_every_estimator_recovers_the_trajectory(version, bags, sim, tmp_path, capsys):
    paths, mapping = bags
    bag = paths[version] if version == "ros1" else paths[version] / "drive_ros2.mcap"  # the storage file also opens the bag
    out = tmp_path / "drive.mcap"
    status, stdout, err = run(capsys, "import", "rosbag", bag, "--mapping", mapping, "-o", out)
    assert status == 0, err
    assert f"wrote {out}" in stdout
    assert f"topic '/fix': 1 of {len(sim.gnss) + 1} fixes have a status below min_status 0; dropped" in err
    drive = read_drive(out)
    assert_channels_close(drive, expected_import(sim))
    assert drive.name == ("drive" if version == "ros1" else "drive_ros2")
    assert drive.params["topics"] == {"imu": "/imu/data", "wheel": "/odom", "compass": "/heading", "rfid": "/uwb/range",
                                      "gnss": "/fix", "truth": "/ground_truth"}
    # the record time is the arrival time; readings that arrived out of order are sorted by stamp
    assert (drive.rfid.arrival_s > drive.rfid.t_s).all()
    rms = position_rms_m(drive)
    assert max(rms.values()) < 3.0, rms
    assert rms["graph-batch"] < 1.0, rms


def _ros2_types_bag(tmp_path):
    """A ROS 2 sqlite3 bag of other message types: TwistStamped, an IMU orientation, PoseStamped, named frames."""
    w = BagWriter("ros2-db3")
    ts = w.typestore
    t_s = np.arange(5) * 0.5
    yaw = 0.1 * t_s
    for t, y in zip(t_s.tolist(), yaw.tolist()):
        twist = make(ts, "geometry_msgs/msg/Twist", linear=w.vector(x=2.0), angular=w.vector(z=0.1))
        w.add("/cmd", "geometry_msgs/msg/TwistStamped", t, header=w.header(t), twist=twist)
        q = make(ts, "geometry_msgs/msg/Quaternion", z=np.sin(y / 2), w=np.cos(y / 2))
        w.add("/imu", "sensor_msgs/msg/Imu", t, header=w.header(t), orientation=q)
        pose = make(ts, "geometry_msgs/msg/Pose", position=make(ts, "geometry_msgs/msg/Point", x=2.0 * t, y=1.0), orientation=q)
        w.add("/pose", "geometry_msgs/msg/PoseStamped", t, header=w.header(t), pose=pose)
        w.add("/range", "sensor_msgs/msg/Range", t + 0.1, header=w.header(t, "anchor_b"), range=4.0)
        # a receiver that does not know its covariance; one without a fix
        w.add("/fix", "sensor_msgs/msg/NavSatFix", t, header=w.header(t), latitude=29.5631, longitude=106.5516)
        w.add("/no_fix", "sensor_msgs/msg/NavSatFix", t, header=w.header(t), latitude=np.nan, longitude=np.nan,
              altitude=np.nan, status=make(ts, "sensor_msgs/msg/NavSatStatus", status=-1))
    return w.write(tmp_path / "types"), t_s, yaw


def test_other_message_types_and_frame_names(tmp_path):
    bag, t_s, yaw = _ros2_types_bag(tmp_path)
    (tmp_path / "tags.yaml").write_text("- {tag_id: 7, east_m: 10.0, north_m: 2.0}\n")
    mapping = tmp_path / "m.toml"
    mapping.write_text('[drive]\ntags = "tags.yaml"\n[imu]\ntopic = "/cmd"\n[wheel]\ntopic = "/cmd"\n'
                       '[compass]\ntopic = "/imu"\n[truth]\ntopic = "/pose"\n'
                       '[rfid]\ntopic = "/range"\nids = { "anchor_b" = 7 }\n')
    drive = import_rosbag(bag, mapping)
    np.testing.assert_allclose(drive.wheel.t_s - t_s, 1_700_000_000.0, atol=1e-6)
    assert (drive.wheel.speed_mps == 2.0).all() and np.allclose(drive.imu.yaw_rate_radps, 0.1)
    assert np.isnan(drive.imu.accel_x_mps2).all()
    np.testing.assert_allclose(drive.compass.yaw_rad, yaw, atol=1e-12)
    np.testing.assert_allclose(drive.truth.v_east_mps, 2.0, atol=1e-6)  # differentiated poses
    np.testing.assert_allclose(drive.truth.yaw_rad, yaw, atol=1e-12)
    assert (drive.rfid.tag_id == 7).all() and np.allclose(drive.rfid.arrival_s - drive.rfid.t_s, 0.1, atol=1e-6)


def test_a_nan_in_a_message_is_a_gap_dropped_and_counted(tmp_path):
    """As in a CSV log (README: non-finite samples are gaps): a bag whose yaw rate is NaN in one message loses that
    message's row with a note, instead of refusing the whole import."""
    w = BagWriter("ros1")
    for i in range(6):
        t = 0.5 * i
        twist = make(w.typestore, "geometry_msgs/msg/Twist", linear=w.vector(x=2.0), angular=w.vector(z=np.nan if i == 3 else 0.1))
        w.add("/cmd", "geometry_msgs/msg/TwistStamped", t, header=w.header(t), twist=twist)
    bag = w.write(tmp_path / "nan.bag")
    (tmp_path / "tags.yaml").write_text("- {tag_id: 7, east_m: 10.0, north_m: 2.0}\n")
    mapping = tmp_path / "m.toml"
    mapping.write_text('[drive]\ntags = "tags.yaml"\n[imu]\ntopic = "/cmd"\n[wheel]\ntopic = "/cmd"\n')
    drive = import_rosbag(bag, mapping)
    assert len(drive.imu) == 5 and np.allclose(drive.imu.yaw_rate_radps, 0.1) and len(drive.wheel) == 6
    assert any("1 of 6 rows have no value" in note and "gaps in that sensor; dropped" in note
               for note in drive.params["import_notes"])


@pytest.mark.parametrize("fields, want", [
    ("", "field 'position_covariance' (covariance): east/north variances 0, 0 are not positive (unknown?); give fields.sigma"),
    ("fields = { sigma = 3.0 }", 3.0),
])
def test_gnss_covariance_unknown(tmp_path, fields, want):
    bag, _, _ = _ros2_types_bag(tmp_path)
    mapping = tmp_path / "m.toml"
    mapping.write_text(f'[drive]\norigin = {{ lat_deg = 29.563, lon_deg = 106.5516 }}\n[gnss]\ntopic = "/fix"\n{fields}\n')
    if isinstance(want, str):
        with pytest.raises(FileFormatError, match=re.escape("types/types.db3: topic '/fix', message 0") + ".*" + re.escape(want)):
            import_rosbag(bag / "types.db3", mapping)
    else:
        gnss = import_rosbag(bag, mapping).gnss
        assert (gnss.sigma_m == want).all() and np.allclose(gnss.north_m, 11.08, atol=0.01)


def test_fixes_without_a_fix_leave_an_empty_channel(tmp_path):
    bag, _, _ = _ros2_types_bag(tmp_path)
    mapping = tmp_path / "m.toml"
    mapping.write_text('[drive]\norigin = { lat_deg = 29.563, lon_deg = 106.5516 }\n[gnss]\ntopic = "/no_fix"\n')
    drive = import_rosbag(bag, mapping)
    assert len(drive.gnss) == 0
    assert drive.params["import_notes"] == [f"{bag}: topic '/no_fix': 5 of 5 fixes have a status below min_status 0; dropped"]


_UWB_TYPES = {**get_types_from_msg("string anchor\nfloat64 distance_mm\n", "uwb_msgs/msg/AnchorRange"),
              **get_types_from_msg("std_msgs/Header header\nuwb_msgs/AnchorRange[] ranges\n", "uwb_msgs/msg/Ranges")}
_UWB_MAPPING = ('[drive]\ntags = "tags.csv"\n[rfid]\ntopic = "/uwb"\nunits = { range = "mm" }\nids = { "A" = 1, "B" = 2 }\n'
                'fields = { tag_id = "ranges[*].anchor", range = "ranges[*].distance_mm" }\n')


def _uwb_bag(tmp_path, anchors):
    w = BagWriter("ros1")
    w.typestore.register(_UWB_TYPES)
    for i, readings in enumerate(anchors):
        ranges = [make(w.typestore, "uwb_msgs/msg/AnchorRange", anchor=a, distance_mm=d) for a, d in readings]
        w.add("/uwb", "uwb_msgs/msg/Ranges", i + 0.05, header=w.header(float(i)), ranges=ranges)
    (tmp_path / "m.toml").write_text(_UWB_MAPPING)
    write_tags_csv(tmp_path / "tags.csv", TagMap([1, 2], [0.0, 5.0], [1.0, 1.0], [0, 0], [-1, -1]))
    return w.write(tmp_path / "uwb.bag"), tmp_path / "m.toml"


def test_uwb_driver_message_one_row_per_array_element(tmp_path):
    bag, mapping = _uwb_bag(tmp_path, [[("A", 1500.0), ("B", 2500.0)], [("B", 3000.0)]])
    rfid = import_rosbag(bag, mapping).rfid
    assert rfid.tag_id.tolist() == [1, 2, 2]
    np.testing.assert_allclose(rfid.range_m, [1.5, 2.5, 3.0])
    np.testing.assert_allclose(rfid.t_s - 1_700_000_000.0, [0, 0, 1], atol=1e-6)


def test_bad_value_in_a_message_names_topic_message_and_field(tmp_path, capsys):
    bag, mapping = _uwb_bag(tmp_path, [[("A", 1500.0)], [("C", 10.0)]])
    out = tmp_path / "out.mcap"
    assert_one_line_error(*run(capsys, "import", "rosbag", bag, "--mapping", mapping, "-o", out),
                          "topic '/uwb', message 1 (recorded at 1700000001.0", "s), field 'ranges[*].anchor' (tag_id)",
                          "'C' is not in ids (known: A, B)")
    assert not out.exists()


#: (replace this, by that) in the example mapping, and what the one error line says.
BAD_MAPPINGS = {
    "unknown topic": ('"/uwb/range"', '"/uwb/ranges"', ["[rfid]: topic '/uwb/ranges' is not in", "its topics: /fix"]),
    "wrong type": ('topic = "/fix"', 'topic = "/imu/data"',
                   ["[gnss]: topic '/imu/data' carries sensor_msgs/msg/Imu, which [gnss] does not read by default",
                    "it reads sensor_msgs/msg/NavSatFix"]),
    "bad field path": ('topic = "/imu/data"', 'topic = "/imu/data"\nfields = { yaw_rate = "angular_velocity.w" }',
                       ["[imu] fields.yaw_rate = 'angular_velocity.w' (topic '/imu/data', sensor_msgs/msg/Imu)",
                        "geometry_msgs/msg/Vector3 has no field 'w' (its fields: x, y, z)"]),
    "path syntax": ('topic = "/imu/data"', 'topic = "/imu/data"\nfields = { yaw_rate = "angular velocity" }',
                    ["'angular velocity' is not a field path"]),
    "field of the wrong kind": ('topic = "/uwb/range"', 'topic = "/uwb/range"\nfields = { tag_id = "header" }',
                                ["the field is std_msgs/msg/Header; tag_id needs a number or a string"]),
    "bad unit": ('units = { yaw = "deg" }', 'units = { yaw = "grad" }',
                 ["[compass] units.yaw: unknown angle unit 'grad' (known: rad, deg)"]),
    "unit of a time stamp": ('topic = "/imu/data"', 'topic = "/imu/data"\nunits = { time = "ms" }',
                             ["[imu] units.time: the time field 'header.stamp' is a builtin_interfaces/msg/Time"]),
    "no header": ('units = { yaw = "deg" }', 'units = { yaw = "deg" }\ntime = "header.stamp"',
                  ["[compass] time = 'header.stamp'", "std_msgs/msg/Float64 has no field 'header'"]),
    "missing tag map": ('tags = "tags.csv"', 'tags = "missing.csv"', ["[drive] tags: ", "missing.csv: no such file"]),
    "no origin for lat/lon": ("origin = {", "# origin = {", ["[gnss]: latitude/longitude need [drive] origin"]),
    "unknown key": ('min_status = 0', 'min_stat = 0', ["[gnss]: unknown key 'min_stat'", "min_status"]),
    "unknown section": ("[truth]", "[truthh]", ["unknown section [truthh]"]),
    "unknown input": ('topic = "/odom"', 'topic = "/odom"\nfields = { velocity = "twist" }',
                      ["[wheel] fields: unknown input 'velocity' (known: speed"]),
    "not TOML": ("[imu]", "[imu", ["not valid TOML"]),
}


@pytest.mark.parametrize("case", BAD_MAPPINGS)
def test_bad_mapping_is_one_line_and_writes_nothing(case, bags, sim, tmp_path, capsys):
    assert_bad_mapping_refused(capsys, "rosbag", bags[0]["ros1"], tmp_path, sim, *BAD_MAPPINGS[case])


@pytest.mark.parametrize("what", ["bag", "mapping"])
def test_missing_bag_or_mapping(what, bags, tmp_path, capsys):
    paths, mapping = bags
    bag = tmp_path / "nope.bag" if what == "bag" else paths["ros1"]
    mapping = tmp_path / "nope.toml" if what == "mapping" else mapping
    out = tmp_path / "out.mcap"
    assert_one_line_error(*run(capsys, "import", "rosbag", bag, "--mapping", mapping, "-o", out),
                          f"nope.{'bag: no such file or folder' if what == 'bag' else 'toml: no such file'}")
    assert not out.exists()


def test_not_a_bag(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    mapping = tmp_path / "m.toml"
    mapping.write_text('[wheel]\ntopic = "/odom"\n')
    assert_one_line_error(*run(capsys, "import", "rosbag", tmp_path / "empty", "--mapping", mapping, "-o", tmp_path / "o.mcap"),
                          "empty: not a readable ROS bag")


def test_a_fifo_is_refused_before_it_is_opened(bags, tmp_path, capsys):
    _, mapping = bags
    os.mkfifo(tmp_path / "pipe.bag")
    assert_one_line_error(*run(capsys, "import", "rosbag", tmp_path / "pipe.bag", "--mapping", mapping, "-o", tmp_path / "o.mcap"),
                          "pipe.bag: not a regular file: it is a named pipe (FIFO)")
