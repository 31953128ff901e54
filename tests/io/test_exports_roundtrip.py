"""The exports of ``graphpos run`` read by the tools they are for (issue 15, items 4-6).

- evo reads ``NAME.tum`` and ``truth.tum`` as they stand, and its APE (translation part, nearest stamps,
  no alignment) equals ours (:func:`eval.metrics.evaluate_estimate`) to 1 mm;
- the ROS 2 bag reads back with rosbags' ``AnyReader`` (and evo's bag reader) to the written poses,
  covariances, velocities, stamps and frames;
- every Foxglove message of ``estimates.mcap`` is valid against Foxglove's own schema (derived from the
  official definitions of ``foxglove-schemas-protobuf``), and each estimate's ``LocationFix`` carries its
  estimator's colour, the one of the plots and the KML tracks.

One simulated drive with truth, two estimators: ``fusion-ekf`` (velocity, yaw, covariance) and ``rfid-ekf``
(covariance, no velocity or yaw).
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import jsonschema
import numpy as np
import pytest
import yaml
from evo.core import metrics, sync
from evo.tools import file_interface
from google.protobuf.descriptor import Descriptor, FieldDescriptor
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader as Ros2Reader

from eval.metrics import evaluate_estimate
from graphpos.cli import main
from graphpos.colors import ESTIMATOR_COLORS, kml_color_of, rgb_of
from graphpos.io import read_drive, read_estimates, write_drive
from graphpos.io.exports import truth_estimate
from graphpos.io.ros2_bag import BODY_FRAME, MAP_FRAME, ODOMETRY, odometry_topic
from graphpos.registry import estimator_classes
from graphpos.sim import simulate

ESTIMATORS = ("fusion-ekf", "rfid-ekf")


@pytest.fixture(scope="module")
def run_folder(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("exports")
    write_drive(folder / "drive.mcap", simulate("paper-straight", seed=3, duration_s=20.0))
    assert main(["run", str(folder / "drive.mcap"), *[a for n in ESTIMATORS for a in ("-e", n)], "-o", str(folder / "run")]) == 0
    return folder


@pytest.fixture(scope="module")
def drive(run_folder):
    return read_drive(run_folder / "drive.mcap")


@pytest.fixture(scope="module")
def estimates(run_folder):
    return {e.name: e for e in read_estimates(run_folder / "run" / "estimates.mcap")}


# -- evo ------------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ESTIMATORS)
def test_evo_ape_equals_ours(run_folder, drive, estimates, name):
    truth = file_interface.read_tum_trajectory_file(run_folder / "run" / "truth.tum")
    estimate = file_interface.read_tum_trajectory_file(run_folder / "run" / f"{name}.tum")
    assert truth.num_poses == len(drive.truth) and estimate.num_poses == len(estimates[name])
    truth, estimate = sync.associate_trajectories(truth, estimate)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((truth, estimate))
    ours = evaluate_estimate(drive, estimates[name])["windows"]["whole"]["position"]["rms_m"]
    assert ape.get_statistic(metrics.StatisticsType.rmse) == pytest.approx(ours, abs=1e-3)


def test_evo_reads_the_yaw_from_the_tum_quaternion(run_folder, estimates):
    est = estimates["fusion-ekf"]
    traj = file_interface.read_tum_trajectory_file(run_folder / "run" / "fusion-ekf.tum")
    yaw = np.array([np.arctan2(r[1, 0], r[0, 0]) for r in traj.poses_se3])
    np.testing.assert_allclose(np.angle(np.exp(1j * (yaw - est.yaw_rad))), 0.0, atol=1e-7)
    np.testing.assert_allclose(traj.timestamps, est.t_s, atol=1e-6)


# -- the ROS 2 bag --------------------------------------------------------------------------------------------------
def _bag_messages(bag: Path) -> dict[str, list]:
    with AnyReader([bag]) as reader:
        assert {c.msgtype for c in reader.connections} == {ODOMETRY}
        found: dict[str, list] = {c.topic: [] for c in reader.connections}
        for connection, record_ns, raw in reader.messages():
            found[connection.topic].append((record_ns, reader.deserialize(raw, connection.msgtype)))
    return found


def test_ros2_bag_reads_back_to_the_estimates(run_folder, drive, estimates):
    bag = run_folder / "run" / "estimates_ros2"
    found = _bag_messages(bag)
    written = {"truth": truth_estimate(drive), **estimates}
    assert set(found) == {odometry_topic(name) for name in written}
    custom = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]["custom_data"]
    assert json.loads(custom["graphpos.estimators"]) == {odometry_topic(name): name for name in written}
    for name, est in written.items():
        messages = found[odometry_topic(name)]
        assert len(messages) == len(est), name
        stamps = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for _, m in messages])
        np.testing.assert_allclose(stamps, est.t_s, rtol=0, atol=1e-9)
        assert [ns for ns, _ in messages] == [round(t * 1e9) for t in est.t_s]
        assert {(m.header.frame_id, m.child_frame_id) for _, m in messages} == {(MAP_FRAME, BODY_FRAME)}
        pose = np.array([[m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.position.z] for _, m in messages])
        np.testing.assert_array_equal(pose, np.column_stack([est.east_m, est.north_m, np.zeros(len(est))]))
        quat = np.array([[q.x, q.y, q.z, q.w] for q in (m.pose.pose.orientation for _, m in messages)])
        yaw = est.yaw_rad if est.yaw_rad is not None else np.zeros(len(est))
        np.testing.assert_allclose(quat, np.column_stack([0 * yaw, 0 * yaw, np.sin(yaw / 2), np.cos(yaw / 2)]), atol=1e-12)
        cov = np.array([m.pose.covariance for _, m in messages]).reshape(-1, 6, 6)
        want = np.zeros_like(cov)
        if est.cov_en_m2 is not None:
            want[:, :2, :2] = est.cov_en_m2
        np.testing.assert_array_equal(cov, want)
        linear = np.array([[v.x, v.y] for v in (m.twist.twist.linear for _, m in messages)])
        if est.has_velocity:  # in base_link: turned by the yaw
            c, s = np.cos(yaw), np.sin(yaw)
            np.testing.assert_allclose(linear, np.column_stack([c * est.v_east_mps + s * est.v_north_mps,
                                                                -s * est.v_east_mps + c * est.v_north_mps]), atol=1e-9)
        else:
            assert np.isnan(linear).all(), name
    assert estimates["rfid-ekf"].yaw_rad is None and not estimates["rfid-ekf"].has_velocity  # both cases were seen


def test_evo_reads_the_ros2_bag(run_folder, estimates):
    with Ros2Reader(run_folder / "run" / "estimates_ros2") as reader:
        for name, est in estimates.items():
            traj = file_interface.read_bag_trajectory(reader, odometry_topic(name))
            np.testing.assert_array_equal(traj.positions_xyz[:, :2], np.column_stack([est.east_m, est.north_m]))
            np.testing.assert_allclose(traj.timestamps, est.t_s, atol=1e-9)


def test_topic_names_are_ros_names():
    assert odometry_topic("graph-batch") == "/graphpos/graph_batch/odometry"
    assert odometry_topic("2d fix") == "/graphpos/_2d_fix/odometry"


# -- Foxglove ------------------------------------------------------------------------------------------------------
#: The Foxglove JSON time (``foxglove`` JSON encoding of ``google.protobuf.Timestamp``).
_TIME = {"type": "object", "properties": {"sec": {"type": "integer", "minimum": 0},
                                          "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}},
         "required": ["sec", "nsec"], "additionalProperties": False}
_INTEGERS = {FieldDescriptor.TYPE_INT32, FieldDescriptor.TYPE_INT64, FieldDescriptor.TYPE_SINT32, FieldDescriptor.TYPE_SINT64,
             FieldDescriptor.TYPE_SFIXED32, FieldDescriptor.TYPE_SFIXED64}
_UNSIGNED = {FieldDescriptor.TYPE_UINT32, FieldDescriptor.TYPE_UINT64, FieldDescriptor.TYPE_FIXED32, FieldDescriptor.TYPE_FIXED64}
_SCALARS = {FieldDescriptor.TYPE_DOUBLE: {"type": "number"}, FieldDescriptor.TYPE_FLOAT: {"type": "number"},
            FieldDescriptor.TYPE_BOOL: {"type": "boolean"}, FieldDescriptor.TYPE_STRING: {"type": "string"},
            FieldDescriptor.TYPE_BYTES: {"type": "string", "contentEncoding": "base64"},
            **{t: {"type": "integer"} for t in _INTEGERS}, **{t: {"type": "integer", "minimum": 0} for t in _UNSIGNED}}


def foxglove_json_schema(message: Descriptor) -> dict:
    """The JSON schema of a Foxglove message as Foxglove's JSON encoding writes it, from its official
    protobuf definition: field names as defined, times as ``{sec, nsec}``, enums as their numbers; every
    field that is neither repeated nor optional is required, and no other field is allowed."""
    properties, required = {}, []
    for field in message.fields:
        if field.type == FieldDescriptor.TYPE_MESSAGE:
            item = _TIME if field.message_type.full_name == "google.protobuf.Timestamp" else foxglove_json_schema(field.message_type)
        elif field.type == FieldDescriptor.TYPE_ENUM:
            item = {"enum": [value.number for value in field.enum_type.values]}
        else:
            item = _SCALARS[field.type]
        properties[field.name] = {"type": "array", "items": item} if field.is_repeated else item
        if not field.is_repeated and field.containing_oneof is None:
            required.append(field.name)
    return {"title": message.full_name, "type": "object", "properties": properties, "required": required,
            "additionalProperties": False}


def _official_validators() -> dict[str, jsonschema.Draft202012Validator]:
    from foxglove_schemas_protobuf.GeoJSON_pb2 import GeoJSON
    from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix
    from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame

    return {m.DESCRIPTOR.full_name: jsonschema.Draft202012Validator(foxglove_json_schema(m.DESCRIPTOR))
            for m in (GeoJSON, LocationFix, PoseInFrame)}


def _foxglove_messages(path: Path) -> dict[str, tuple[str, list[dict]]]:
    """topic -> (schema name, messages) of the ``foxglove.*`` topics of an MCAP file."""
    found: dict[str, tuple[str, list[dict]]] = {}
    with open(path, "rb") as stream:
        for schema, channel, message in make_reader(stream).iter_messages():
            if schema.name.startswith("foxglove."):
                found.setdefault(channel.topic, (schema.name, []))[1].append(json.loads(message.data))
    return found


def test_foxglove_messages_are_valid_against_the_official_schemas(run_folder):
    validators = _official_validators()
    found = _foxglove_messages(run_folder / "run" / "estimates.mcap")
    assert {"/truth/fix", "/gnss/fix", "/map", "/truth/pose", *(f"/estimates/{n}/{k}" for n in ESTIMATORS for k in ("fix", "pose"))} <= set(found)
    for topic, (schema, messages) in found.items():
        assert schema in validators, f"{topic}: no official schema {schema} checked"
        for i, message in enumerate(messages):
            error = jsonschema.exceptions.best_match(validators[schema].iter_errors(message))
            assert error is None, f"{topic}, message {i}: {error.message} at {list(error.absolute_path)}"


def test_the_schema_check_catches_a_misspelt_field():
    validator = _official_validators()["foxglove.LocationFix"]
    fix = {"timestamp": {"sec": 1, "nsec": 0}, "frame_id": "enu", "latitude": 1.0, "longitude": 2.0, "altitude": 0.0,
           "position_covariance": [0.0] * 9, "position_covariance_type": 0, "color": {"r": 1.0, "g": 0.0, "b": 0.0, "a": 1.0}}
    assert validator.is_valid(fix)
    assert not validator.is_valid({**fix, "colour": fix["color"]})
    assert not validator.is_valid({**fix, "color": {"r": 1.0, "g": 0.0, "b": 0.0}})
    assert not validator.is_valid({**fix, "position_covariance_type": 7})


def test_each_estimate_has_its_colour_everywhere(run_folder):
    found = _foxglove_messages(run_folder / "run" / "estimates.mcap")
    colours = {}
    for name in ("truth", *ESTIMATORS):
        topic = "/truth/fix" if name == "truth" else f"/estimates/{name}/fix"
        seen = {tuple(m["color"][k] for k in "rgba") for m in found[topic][1]}
        assert seen == {(*rgb_of(name), 1.0)}, name
        colours[name] = seen
    assert len({c for s in colours.values() for c in s}) == len(colours), "two tracks share a colour"
    assert all("color" not in m for m in found["/gnss/fix"][1])
    kml = ET.parse(run_folder / "run" / "all_estimates.kml").getroot()
    styles = {e.text for e in kml.iter() if e.tag.endswith("color")}
    assert {kml_color_of(name) for name in colours} <= styles
    geojson = json.loads((run_folder / "run" / "fusion-ekf.geojson").read_text())
    assert geojson["features"][0]["properties"]["stroke"] == ESTIMATOR_COLORS["fusion-ekf"]


def test_every_estimator_has_a_colour_of_its_own():
    table = {name: ESTIMATOR_COLORS.get(name) for name in ("truth", *estimator_classes())}
    assert None not in table.values(), [n for n, c in table.items() if c is None]
    assert len(set(table.values())) == len(table)
