"""Importer of ROS 1 and ROS 2 bags, through a mapping file (:mod:`graphpos.io.mapping`).

Bags are read with ``rosbags`` (pure Python, no ROS install): a ROS 1
``.bag`` file, or a ROS 2 bag (sqlite3 or MCAP storage) given as its folder
(the one with ``metadata.yaml``) or as the ``.db3``/``.mcap`` file in it.
Message types come from the definitions the bag carries (a ROS 2 bag
without them is read with the latest ROS 2 types).

Times: a row's measurement time is its message's ``header.stamp`` (or the
field the mapping's ``time`` names; ``time = "record"``, the default for a
message without a header such as ``std_msgs/Float64``, takes the record
time). The record time, when the recorder received the message, is the
``arrival_s`` of rfid and rsu readings (so a reading recorded before its
stamp is refused: stamps from another clock want ``time = "record"``).

Before any message is read, every mapped topic must be in the bag with one
message type (the mapping's ``type`` where it gives one), every field path
must lead to a field of that type of the right kind (a number; a number or
text for ids; a ``Quaternion`` for ``orientation``; an array of 9 for
``covariance``; a ``Time`` or a number for ``time``), and a type without
default fields (:data:`DEFAULT_FIELDS`) must have its fields named. Each
failure is one line naming the mapping section, the topic and the field.

Live rosbridge input (:mod:`graphpos.live.rosbridge`) reads the same
mappings with the same steps (:func:`topic_fields`, :func:`field_paths`,
:func:`get_field`, :func:`stamp_s`) from JSON messages.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import Nodetype
from rosbags.rosbag1 import ReaderError as Ros1ReaderError
from rosbags.rosbag2 import ReaderError as Ros2ReaderError
from rosbags.typesys import Stores, get_typestore

from graphpos.drive import Drive
from graphpos.errors import ConfigError, FileFormatError
from graphpos.io.files import open_input
from graphpos.io.mapping import INPUTS, ChannelMapping, RawChannel, build_drive, check_inputs, load_mapping

#: Fields read by default, by (channel, message type): input -> field path.
DEFAULT_FIELDS: dict[tuple[str, str], dict[str, str]] = {
    ("imu", "sensor_msgs/msg/Imu"): {"yaw_rate": "angular_velocity.z", "accel_x": "linear_acceleration.x",
                                     "accel_y": "linear_acceleration.y"},
    ("imu", "nav_msgs/msg/Odometry"): {"yaw_rate": "twist.twist.angular.z"},
    ("imu", "geometry_msgs/msg/TwistStamped"): {"yaw_rate": "twist.angular.z"},
    ("wheel", "nav_msgs/msg/Odometry"): {"speed": "twist.twist.linear.x"},
    ("wheel", "geometry_msgs/msg/TwistStamped"): {"speed": "twist.linear.x"},
    ("compass", "sensor_msgs/msg/Imu"): {"orientation": "orientation"},
    ("compass", "std_msgs/msg/Float64"): {"yaw": "data"},
    ("rfid", "sensor_msgs/msg/Range"): {"tag_id": "header.frame_id", "range": "range"},
    ("gnss", "sensor_msgs/msg/NavSatFix"): {"lat": "latitude", "lon": "longitude", "alt": "altitude",
                                            "covariance": "position_covariance", "status": "status.status"},
    ("truth", "nav_msgs/msg/Odometry"): {"east": "pose.pose.position.x", "north": "pose.pose.position.y",
                                         "orientation": "pose.pose.orientation", "v_forward": "twist.twist.linear.x",
                                         "v_left": "twist.twist.linear.y", "yaw_rate": "twist.twist.angular.z"},
    ("truth", "geometry_msgs/msg/PoseStamped"): {"east": "pose.position.x", "north": "pose.position.y",
                                                 "orientation": "pose.orientation"},
}

#: ``time`` meaning the bag's record time.
RECORD = "record"

_TIME_TYPE = "builtin_interfaces/msg/Time"
_QUATERNION_TYPE = "geometry_msgs/msg/Quaternion"
_NUMERIC = {"bool", "byte", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64",
            "float32", "float64"}
_STEP = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)(?:\[(\d+|\*)\])?")
_READ_ERRORS = (AnyReaderError, Ros1ReaderError, Ros2ReaderError, OSError)

Step = tuple[str, "int | str | None"]


def stamp_s(sec: int, nanosec: int) -> float:
    """Seconds of a ``builtin_interfaces/msg/Time`` (ROS 1 ``time``) given as its seconds and nanoseconds."""
    return sec + nanosec / 1e9


def _parse_path(path: str, where: str) -> list[Step]:
    """``a.b[2].c`` -> [("a", None), ("b", 2), ("c", None)]; ``[*]`` at most once."""
    steps = []
    for part in path.split("."):
        match = _STEP.fullmatch(part)
        if match is None:
            raise ConfigError(f"{where}: '{path}' is not a field path (names joined by dots, each with an optional "
                              "[index] or [*])")
        steps.append((match[1], None if match[2] is None else "*" if match[2] == "*" else int(match[2])))
    if sum(index == "*" for _, index in steps) > 1:
        raise ConfigError(f"{where}: '{path}' has more than one [*]")
    return steps


def _describe(node: tuple) -> str:
    kind, detail = node
    if kind == Nodetype.BASE:
        return detail[0]
    if kind == Nodetype.NAME:
        return detail
    return f"an array of {detail[1]}" if kind == Nodetype.ARRAY else "a sequence"


def _leaf(typestore: Any, msgtype: str, steps: list[Step], where: str) -> tuple:
    """The type node a field path ends at, walking the message definitions."""
    node: tuple = (Nodetype.NAME, msgtype)
    for name, index in steps:
        if node[0] != Nodetype.NAME:
            raise ConfigError(f"{where}: '{name}' is not a field ({_describe(node)} has none)")
        fields = dict(typestore.fielddefs[node[1]][1])
        if name not in fields:
            raise ConfigError(f"{where}: {node[1]} has no field '{name}' (its fields: {', '.join(fields)})")
        node = fields[name]
        if index is not None:
            if node[0] not in (Nodetype.ARRAY, Nodetype.SEQUENCE):
                raise ConfigError(f"{where}: '{name}' is {_describe(node)}, not an array")
            if node[0] == Nodetype.ARRAY and isinstance(index, int) and index >= node[1][1]:
                raise ConfigError(f"{where}: '{name}' has {node[1][1]} elements")
            node = node[1][0]
    return node


def _converter(name: str, kind: str, node: tuple, where: str) -> Callable[[Any], Any]:
    """How a field's value becomes an input's raw value, after checking that the field suits the input."""
    base = node[1][0] if node[0] == Nodetype.BASE else None
    if name == "time" and node == (Nodetype.NAME, _TIME_TYPE):
        return lambda stamp: stamp_s(stamp.sec, stamp.nanosec)
    if kind == "quaternion" and node == (Nodetype.NAME, _QUATERNION_TYPE):
        return lambda q: (q.x, q.y, q.z, q.w)
    if kind == "covariance" and node[0] == Nodetype.ARRAY and node[1][1] == 9 and node[1][0][0] == Nodetype.BASE:
        return lambda values: values
    if (kind in ("number", "id") and base in _NUMERIC) or (kind == "id" and base == "string"):
        return lambda value: value
    wanted = {"quaternion": _QUATERNION_TYPE, "covariance": "an array of 9 numbers",
              "id": "a number or a string"}.get(kind, f"a number{' or a ' + _TIME_TYPE if name == 'time' else ''}")
    raise ConfigError(f"{where}: the field is {_describe(node)}; {name} needs {wanted}")


def get_field(value: Any, steps: list[Step], convert: Callable[[Any], Any], field: Callable[[Any, str], Any] = getattr,
              array: Callable[[Any], Any] = lambda value: value) -> Any:
    """The converted value at a field path (a list of them, one per element, past a ``[*]``).

    Parameters
    ----------
    value : object
        The message.
    steps : list of Step
        The parsed path (:func:`field_paths`).
    convert : callable
        The value at the end of the path -> the input's raw value.
    field : callable
        (message, name) -> its field ``name``: ``getattr`` for a deserialized message, a lookup for JSON.
    array : callable
        A field indexed by the path -> the sequence to index (a check for JSON).

    Raises
    ------
    IndexError
        An array shorter than the path's index (and whatever ``field``, ``array`` and ``convert`` raise).
    """
    for i, (name, index) in enumerate(steps):
        value = field(value, name)
        if index == "*":
            return [get_field(element, steps[i + 1:], convert, field, array) for element in array(value)]
        if index is not None:
            value = array(value)[index]
    return convert(value)


@dataclass
class _Plan:
    """How to read one channel from its topic's messages, and what was read."""

    cm: ChannelMapping
    source: str
    fields: dict[str, str | float]
    paths: dict[str, tuple[list[Step], Callable[[Any], Any]]]
    starred: set[str]
    values: dict[str, list] = field(default_factory=dict)
    messages: list[int] = field(default_factory=list)
    record_ns: list[int] = field(default_factory=list)

    def read(self, msg: Any, index: int, record_ns: int) -> None:
        got = {}
        for name, (steps, convert) in self.paths.items():
            try:
                got[name] = get_field(msg, steps, convert)
            except IndexError:
                raise FileFormatError(f"{self.source}, message {index}: field '{self.fields[name]}' ({name}) "
                                      "has fewer elements than the path asks") from None
        rows = len(got[min(self.starred)]) if self.starred else 1  # the [*] fields walk one array
        for name, value in got.items():
            self.values.setdefault(name, []).extend(value if name in self.starred else [value] * rows)
        for name in ("time", "arrival"):
            if self.fields.get(name) == RECORD:
                self.values.setdefault(name, []).extend([record_ns / 1e9] * rows)
        self.messages.extend([index] * rows)
        self.record_ns.extend([record_ns] * rows)

    def row_name(self, row: int) -> str:
        ns = self.record_ns[row]
        return f"message {self.messages[row]} (recorded at {ns // 10**9}.{ns % 10**9:09d} s)"

    def raw(self) -> RawChannel:
        values = {name: self.values.get(name, []) for name in self.fields if isinstance(self.fields[name], str)}
        return RawChannel(self.cm, self.source, self.fields, values, self.row_name, "field")


def has_header(msgtype: str, typestore: Any) -> bool:
    """Whether messages of ``msgtype`` have a ``header`` (True for a type ``typestore`` does not define)."""
    return msgtype not in typestore.fielddefs or "header" in dict(typestore.fielddefs[msgtype][1])


def topic_fields(cm: ChannelMapping, msgtype: str, header: bool, origin: Any) -> dict[str, str | float]:
    """The inputs a channel reads from its topic's messages, ``time`` (and ``arrival``) included.

    Parameters
    ----------
    cm : ChannelMapping
    msgtype : str
        The topic's message type (``pkg/msg/Type``); its :data:`DEFAULT_FIELDS` under the mapping's fields.
    header : bool
        The messages have a header (:func:`has_header`): the default time is ``header.stamp``, else the record time.
    origin : GeoOrigin or None
        The mapping's origin.

    Returns
    -------
    dict of str to str or float
        Input -> field path, a constant, or :data:`RECORD` (the record time: ``arrival`` of rfid and rsu).

    Raises
    ------
    ConfigError
        The inputs do not make sense together (:func:`~graphpos.io.mapping.check_inputs`), or the type has
        no default fields and the mapping does not name them.
    """
    defaults = DEFAULT_FIELDS.get((cm.channel, msgtype))
    fields = cm.read_fields(defaults)
    try:
        check_inputs(cm, fields, origin)
    except ConfigError:
        if defaults is not None:
            raise
        known = [t for (channel, t) in DEFAULT_FIELDS if channel == cm.channel]
        raise ConfigError(f"{cm.where}: topic '{cm.source}' carries {msgtype}, which [{cm.channel}] does not read "
                          f"by default ({'it reads ' + ', '.join(known) if known else 'it has no default type'}); "
                          "name its fields in fields = { ... }") from None
    fields["time"] = cm.time or ("header.stamp" if header else RECORD)
    if cm.channel in ("rfid", "rsu"):
        fields["arrival"] = RECORD
    return fields


def field_paths(cm: ChannelMapping, fields: dict[str, str | float], msgtype: str,
                typestore: Any | None) -> tuple[dict[str, tuple[list[Step], Callable[[Any], Any] | None]], set[str]]:
    """The parsed field paths of a channel's inputs, checked against the message definition.

    Parameters
    ----------
    cm : ChannelMapping
    fields : dict
        The inputs read (:func:`topic_fields`).
    msgtype : str
        The topic's message type.
    typestore : rosbags typestore or None
        Where ``msgtype`` is defined; None when it is not known (the paths are then only parsed).

    Returns
    -------
    paths : dict of str to (list of Step, callable or None)
        Input -> its path and the converter of a deserialized message's value at it (None without a
        typestore), for every input read from a field.
    starred : set of str
        The inputs whose path has a ``[*]`` (one row per element).

    Raises
    ------
    ConfigError
        A path that is not one, that leads to no field of ``msgtype`` or to a field of the wrong kind, a unit
        for a ``Time``, ``[*]`` over different arrays.
    """
    paths = {}
    for name, path in fields.items():
        if not isinstance(path, str) or path == RECORD:
            continue
        where = f"{cm.where} {'time' if name == 'time' else 'fields.' + name} = '{path}' (topic '{cm.source}', {msgtype})"
        steps = _parse_path(path, where)
        if typestore is None:
            paths[name] = (steps, None)
            continue
        node = _leaf(typestore, msgtype, steps, where)
        kind = "number" if name == "time" else INPUTS[cm.channel][name].kind
        paths[name] = (steps, _converter(name, kind, node, where))
        if name == "time" and node[0] == Nodetype.NAME and "time" in cm.units:
            raise ConfigError(f"{cm.where} units.time: the time field '{path}' is a {_TIME_TYPE} (seconds and "
                              "nanoseconds); it takes no unit")
    starred = {name for name, (steps, _) in paths.items() if any(index == "*" for _, index in steps)}
    arrays = {tuple(steps[:next(i for i, (_, index) in enumerate(steps) if index == "*") + 1])
              for name, (steps, _) in paths.items() if name in starred}
    if len(arrays) > 1:
        raise ConfigError(f"{cm.where}: the fields with [*] walk different arrays; one row per element needs one array")
    return paths, starred


def _plan(cm: ChannelMapping, reader: AnyReader, bag: Path, origin: Any) -> _Plan:
    """Check a channel's topic, type and field paths against the bag; the plan to read it."""
    types = sorted({c.msgtype for c in reader.connections if c.topic == cm.source})
    if not types:
        topics = sorted({c.topic for c in reader.connections})
        raise ConfigError(f"{cm.where}: topic '{cm.source}' is not in {bag} (its topics: {', '.join(topics) or 'none'})")
    if len(types) > 1:
        raise ConfigError(f"{cm.where}: topic '{cm.source}' carries several message types ({', '.join(types)})")
    msgtype = types[0]
    if cm.msgtype not in (None, msgtype):
        raise ConfigError(f"{cm.where} type: topic '{cm.source}' carries {msgtype} in {bag}, not {cm.msgtype}")
    fields = topic_fields(cm, msgtype, has_header(msgtype, reader.typestore), origin)
    paths, starred = field_paths(cm, fields, msgtype, reader.typestore)
    return _Plan(cm, f"{bag}: topic '{cm.source}'", fields, paths, starred)


def _bag_path(path: Path) -> Path:
    """What ``rosbags`` opens: a ROS 1 ``.bag`` file or a ROS 2 bag folder (also from the storage file in it).

    Its files must be regular files (:func:`graphpos.io.files.open_input`), so that a FIFO or a device
    is refused before ``rosbags`` blocks on it.
    """
    if not path.exists():
        raise FileFormatError(f"{path}: no such file or folder")
    if path.suffix == ".bag" and not path.is_dir():
        files, bag = [path], path
    elif path.is_dir() or path.suffix in (".db3", ".mcap"):
        bag = path if path.is_dir() else path.parent
        if not (bag / "metadata.yaml").exists():
            raise FileFormatError(f"{path}: not a readable ROS bag (a ROS 2 bag is a folder with a metadata.yaml, "
                                  f"and {bag} has none)")
        files = [f for f in sorted(bag.iterdir()) if f.name == "metadata.yaml" or f.suffix in (".db3", ".mcap")]
    else:
        raise FileFormatError(f"{path}: not a ROS bag (a ROS 1 .bag file, or a ROS 2 bag folder or its .db3/.mcap file)")
    for file in files:
        with open_input(file):
            pass
    return bag


def import_rosbag(bag: str | os.PathLike, mapping: str | os.PathLike) -> Drive:
    """Read a ROS bag as a drive, through a mapping file.

    Parameters
    ----------
    bag : path-like
        A ROS 1 ``.bag`` file, or a ROS 2 bag folder (or the ``.db3``/``.mcap`` file in it).
    mapping : path-like
        The mapping file (TOML; format: :mod:`graphpos.io.mapping`).

    Returns
    -------
    Drive
        Named after the bag; ``params`` records the source, the mapping,
        each channel's topic and ``import_notes`` (rows dropped or sorted).

    Raises
    ------
    FileFormatError
        The bag or a map file cannot be read; a value read is not valid
        (naming the topic, the message and the field).
    ConfigError
        The mapping is wrong, or does not fit the bag: a topic not in it,
        a message type it cannot read, a bad field path.
    """
    loaded = load_mapping(mapping, "rosbag")
    path = _bag_path(Path(bag))
    try:
        with AnyReader([path], default_typestore=get_typestore(Stores.LATEST)) as reader:
            plans = [_plan(cm, reader, Path(bag), loaded.origin) for cm in loaded.channels.values()]
            by_topic: dict[str, list[_Plan]] = {}
            for plan in plans:
                by_topic.setdefault(plan.cm.source, []).append(plan)
            counts = dict.fromkeys(by_topic, 0)
            connections = [c for c in reader.connections if c.topic in by_topic]
            for connection, record_ns, data in reader.messages(connections=connections):
                msg = reader.deserialize(data, connection.msgtype)
                for plan in by_topic[connection.topic]:
                    plan.read(msg, counts[connection.topic], record_ns)
                counts[connection.topic] += 1
    except _READ_ERRORS as exc:
        raise FileFormatError(f"{bag}: not a readable ROS bag ({' '.join(str(exc).split())})") from None
    params = {"source": "rosbag", "file": Path(bag).name, "mapping": loaded.path.name,
              "topics": {plan.cm.channel: plan.cm.source for plan in plans}}
    return build_drive(loaded, [plan.raw() for plan in plans], name=path.stem or path.name, params=params)
