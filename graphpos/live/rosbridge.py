"""Live input in the rosbridge JSON protocol, read through an import mapping.

A ROS vehicle feeds ``graphpos live`` through ``rosbridge_suite`` (or
anything that sends the same JSON): each message is a rosbridge protocol
operation, ``{"op": "publish", "topic": "/imu/data", "msg": {...}}``, and
the topics are read into drive measurements by the mapping file of
``graphpos import rosbag`` (:mod:`graphpos.io.mapping`): the same sections,
default fields, units, conventions, ids, geodesy and checks, so that a bag
imported with :func:`graphpos.io.rosbag.import_rosbag` and the same
messages fed live give the same rows.

Operations
----------
- ``publish``: a message on a mapped topic gives the measurements of every
  channel mapped to that topic (an ``Imu`` may feed ``imu`` and
  ``compass``; a ``ranges[*].range`` path gives one row per element).
- ``advertise`` (``"type": "sensor_msgs/Imu"``, ROS 1, or
  ``"sensor_msgs/msg/Imu"``, ROS 2): records the topic's message type. An
  advertise of a topic the mapping does not name is ignored.

A topic's message type is the mapping's ``type`` where its section gives
one (an advertise must agree), else the advertised one, else the one type
among those with default fields for its channels
(:data:`graphpos.io.rosbag.DEFAULT_FIELDS`) whose fields the first message
has. Types that ``rosbags`` knows (the common ROS 2 packages) have their
field paths checked as the importer checks them; a driver's own type is
read as the paths say, and its messages are taken to have a header.

Times: the measurement time is ``header.stamp`` (``{"sec", "nanosec"}``,
ROS 2, or ``{"secs", "nsecs"}``, ROS 1), or the field the mapping's
``time`` names (a stamp or a number in ``units.time``); ``time = "record"``
(the default without a header) takes the receipt time. A reading's
``arrival_s`` is its own time: the receipt time is on this computer's
clock, the stamps on the vehicle's, and mixing them would make every
reading look early or late by the clocks' offset; live mode instead takes
each reading to arrive when it is received relative to the others
(:mod:`graphpos.live.session`), which a bag's record time gives the
importer.
GNSS fixes below ``min_status`` give no measurement. A mapping's truth
section is not read: truth is for scoring only, and live takes none (a
publish on its topic is an unmapped topic).

Every message that cannot be used raises
:class:`~graphpos.live.malformed.MalformedMessage` with one line naming the
topic and the field; its ``kind`` is ``json`` (not an object), ``op`` (an
operation other than publish and advertise), ``topic`` (not in the
mapping), ``type`` (a message type unknown, ambiguous or that the mapping
cannot read), ``field`` (a field missing, mistyped, not finite, out of
range) or ``id`` (a tag or RSU id not in ``ids`` or not in its map).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
from rosbags.typesys import Stores, get_typestore

from graphpos.drive import Measurement
from graphpos.errors import ConfigError, FileFormatError
from graphpos.io.mapping import (INPUTS, ChannelMapping, RawChannel, build_drive, input_values, load_mapping,
                                 ros_msgtype)
from graphpos.io.rosbag import (DEFAULT_FIELDS, RECORD, Step, field_paths, get_field, has_header, stamp_s,
                                topic_fields)
from graphpos.live.malformed import MalformedMessage

#: A stamp's seconds and nanoseconds as rosbridge spells them: ROS 2, then ROS 1.
_STAMP_KEYS = (("sec", "nanosec"), ("secs", "nsecs"))


class _Unfit(Exception):
    """A JSON value that is not what the field path or the input needs (the reason)."""


def _json_kind(value: Any) -> str:
    """What a JSON value is, in words."""
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, (int, float)):
        return "a number"
    return {dict: "an object", list: "an array", str: "a string"}.get(type(value), "null")


def _json_field(value: Any, name: str) -> Any:
    """Field ``name`` of a JSON object."""
    if not isinstance(value, dict):
        raise _Unfit(f"'{name}' is not a field ({_json_kind(value)} has none)")
    if name not in value:
        raise _Unfit(f"no field '{name}' (its fields: {', '.join(map(str, value)) or 'none'})")
    return value[name]


def _json_array(value: Any) -> list:
    """A JSON array indexed by a field path."""
    if not isinstance(value, list):
        raise _Unfit(f"{_json_kind(value)} is not an array")
    return value


def _float(value: int | float) -> float:
    """A JSON number as a float (a whole number too large for one is refused)."""
    try:
        return float(value)
    except OverflowError:
        raise _Unfit(f"{value} is too large for a number") from None


def _number(value: Any) -> float:
    """A JSON number (null: NaN, as rosbridge sends a NaN)."""
    if value is None:
        return math.nan
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _Unfit(f"{value!r} is {_json_kind(value)}, not a number")
    return _float(value)


def _id(value: Any) -> int | float | str:
    """A JSON id: a number, or a name for ``ids``."""
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise _Unfit(f"{value!r} is {_json_kind(value)}, not a number or a string")
    if not isinstance(value, str):
        _float(value)
    return value


def _quaternion(value: Any) -> tuple:
    """A JSON quaternion as (x, y, z, w)."""
    if not isinstance(value, dict) or not all(axis in value for axis in "xyzw"):
        raise _Unfit(f"{_json_kind(value)} is not a quaternion (an object with x, y, z, w)")
    return tuple(_number(value[axis]) for axis in "xyzw")


def _covariance(value: Any) -> list:
    """A JSON position covariance (9 numbers, row-major)."""
    if not isinstance(value, list) or len(value) != 9:
        raise _Unfit(f"{_json_kind(value)} is not an array of 9 numbers")
    return [_number(v) for v in value]


def _time_converter(cm: ChannelMapping) -> Callable[[Any], Any]:
    """A time field's value: a stamp (no unit), or a number in ``units.time``."""

    def convert(value: Any) -> Any:
        if not isinstance(value, dict):
            return _number(value)
        for sec, nanosec in _STAMP_KEYS:
            if sec in value and nanosec in value:
                parts = value[sec], value[nanosec]
                if not all(isinstance(p, int) and not isinstance(p, bool) for p in parts):
                    raise _Unfit(f"stamp {sec} {parts[0]!r}, {nanosec} {parts[1]!r} are not whole numbers")
                if "time" in cm.units:
                    raise _Unfit("a stamp (seconds and nanoseconds) takes no unit; drop units.time")
                return stamp_s(*(_float(part) for part in parts))
        raise _Unfit("an object without sec and nanosec (ROS 2) or secs and nsecs (ROS 1) is not a stamp")

    return convert


def _json_converter(cm: ChannelMapping, name: str) -> Callable[[Any], Any]:
    """How the JSON value at an input's field path becomes its raw value (as the importer reads it)."""
    if name == "time":
        return _time_converter(cm)
    return {"number": _number, "id": _id, "quaternion": _quaternion,
            "covariance": _covariance}[INPUTS[cm.channel][name].kind]


@dataclass(frozen=True)
class _Reading:
    """How one channel is read from its topic's messages of one type."""

    cm: ChannelMapping
    fields: dict[str, str | float]
    paths: dict[str, tuple[list[Step], Callable[[Any], Any]]]
    starred: frozenset[str]

    def fits(self, msg: dict) -> bool:
        """Every field path leads to a field of ``msg``."""
        try:
            for steps, _ in self.paths.values():
                get_field(msg, steps, lambda value: value, _json_field, _json_array)
        except (_Unfit, IndexError):
            return False
        return True


class RosbridgeTranslator:
    """Rosbridge protocol messages -> drive measurements, through a rosbag import mapping.

    Parameters
    ----------
    mapping_path : path-like
        The mapping file (TOML; :mod:`graphpos.io.mapping`, as for ``graphpos import rosbag``).

    Attributes
    ----------
    topics : set of str
        The mapped topics.
    tags : TagMap
    rsus : RsuMap
        The mapping's tag and RSU maps (empty where it names none).
    origin : GeoOrigin or None
        The mapping's geodetic origin.

    Raises
    ------
    ConfigError
        The mapping is wrong (:func:`~graphpos.io.mapping.load_mapping`), or cannot be served live: the
        sections of a topic give different types, a section's ``type`` that its fields do not fit.
    FileFormatError, DriveError
        The mapping, tag or RSU file cannot be read, a map is invalid.
    """

    def __init__(self, mapping_path: str | os.PathLike):
        self._mapping = load_mapping(mapping_path, "rosbag")
        self.tags = self._mapping.tags
        self.rsus = self._mapping.rsus
        self.origin = self._mapping.origin
        self._typestore = get_typestore(Stores.LATEST)
        self._sections: dict[str, list[ChannelMapping]] = {}
        for cm in self._mapping.channels.values():
            if cm.channel != "truth":  # truth is for scoring only: live never reads it
                self._sections.setdefault(cm.source, []).append(cm)
        self.topics = set(self._sections)
        self._declared: dict[str, str] = {}
        self._readings: dict[str, list[_Reading]] = {}
        self._refused: dict[str, str] = {}
        for topic, sections in self._sections.items():
            declared = {cm.msgtype for cm in sections if cm.msgtype}
            if len(declared) > 1:
                raise ConfigError(f"{self._mapping.path}: topic '{topic}' is given the types "
                                  f"{', '.join(sorted(declared))}; a topic carries one")
            if declared:
                self._declared[topic] = declared.pop()
                self._readings[topic] = self._plan(topic, self._declared[topic])

    def _plan(self, topic: str, msgtype: str) -> list[_Reading]:
        """How each channel of ``topic`` reads messages of ``msgtype`` (ConfigError: it cannot)."""
        known = msgtype in self._typestore.fielddefs
        readings = []
        for cm in self._sections[topic]:
            fields = topic_fields(cm, msgtype, has_header(msgtype, self._typestore), self.origin)
            paths, starred = field_paths(cm, fields, msgtype, self._typestore if known else None)
            converters = {name: (steps, _json_converter(cm, name)) for name, (steps, _) in paths.items()}
            readings.append(_Reading(cm, fields, converters, frozenset(starred)))
        return readings

    def _advertise(self, topic: str, text: Any) -> None:
        """Record an advertised message type."""
        try:
            msgtype = ros_msgtype(text, f"advertise of topic '{topic}': type")
        except ConfigError as exc:
            raise MalformedMessage("type", str(exc)) from None
        declared = self._declared.get(topic)
        if declared is not None:
            if msgtype != declared:
                raise MalformedMessage("type", f"topic '{topic}' is advertised as {msgtype}; the mapping's type is {declared}")
            return
        self._readings.pop(topic, None)
        self._refused.pop(topic, None)
        try:
            readings = self._plan(topic, msgtype)
        except ConfigError as exc:
            self._refused[topic] = f"topic '{topic}' is advertised as {msgtype}, which the mapping cannot read: {exc}"
            raise MalformedMessage("type", self._refused[topic]) from None
        self._readings[topic] = readings

    def _infer(self, topic: str, msg: dict) -> list[_Reading]:
        """The readings of the one type with default fields whose fields ``msg`` has (recorded for the topic)."""
        sections = self._sections[topic]
        candidates = sorted({t for (channel, t) in DEFAULT_FIELDS if channel in {cm.channel for cm in sections}})
        fits = {}
        for msgtype in candidates:
            try:
                readings = self._plan(topic, msgtype)
            except ConfigError:
                continue
            if all(reading.fits(msg) for reading in readings):
                fits[msgtype] = readings
        where = ", ".join(f"[{cm.channel}]" for cm in sections)
        if len(fits) != 1:
            found = (f"fits {' and '.join(fits)}" if fits else f"fits none of {', '.join(candidates) or 'no type'}")
            raise MalformedMessage("type", f"topic '{topic}': message type unknown (the message {found}); advertise "
                                           f"the topic or set type = \"pkg/msg/Type\" in {where}")
        (msgtype, readings), = fits.items()
        self._readings[topic] = readings
        return readings

    def _read(self, reading: _Reading, topic: str, msg: dict, receipt_s: float) -> list[Measurement]:
        """The measurements of one channel in one message (as :meth:`graphpos.drive.Drive.measurements` yields them)."""
        values: dict[str, list] = {}
        received = f"message received at {receipt_s:.6f} s"
        raw = RawChannel(reading.cm, f"topic '{topic}'", reading.fields, values, lambda row: received, "field")
        got = {}
        for name, (steps, convert) in reading.paths.items():
            try:
                got[name] = get_field(msg, steps, convert, _json_field, _json_array)
            except _Unfit as exc:
                raise MalformedMessage("field", str(raw.error(0, name, str(exc)))) from None
            except IndexError:
                raise MalformedMessage("field", str(raw.error(0, name, "has fewer elements than the path asks"))) from None
        rows = len(got[min(reading.starred)]) if reading.starred else 1  # the [*] fields walk one array
        if rows == 0:
            return []
        values.update({name: value if name in reading.starred else [value] * rows for name, value in got.items()})
        if reading.fields.get("time") == RECORD:
            values["time"] = [receipt_s] * rows
        if reading.fields.get("arrival") == RECORD:
            values["arrival"] = list(values["time"])  # the reading's own time: live mode orders the arrivals (module docstring)
        for name, word, known in (("tag_id", "tag", self.tags.tag_id), ("rsu_id", "RSU", self.rsus.rsu_id)):
            if name in reading.fields:
                try:
                    ids = input_values(raw, np.arange(rows), name)
                except FileFormatError as exc:
                    raise MalformedMessage("id", str(exc)) from None
                unknown = ~np.isin(ids, known)
                if unknown.any():
                    row = int(np.argmax(unknown))
                    raise MalformedMessage("id", str(raw.error(row, name, f"{word} id {int(ids[row])} is not in the "
                                                                          f"{word} map")))
        try:
            drive = build_drive(self._mapping, [raw], name="live", params={}, missing_as_gaps=False)
        except FileFormatError as exc:
            raise MalformedMessage("field", str(exc)) from None
        return list(drive.measurements([reading.cm.channel]))

    def translate(self, message: dict, receipt_s: float) -> list[Measurement]:
        """The measurements in one rosbridge message.

        Parameters
        ----------
        message : dict
            One rosbridge protocol message, parsed from JSON.
        receipt_s : float
            When it was received: the measurement time under ``time = "record"``.

        Returns
        -------
        list of Measurement
            Every column of the channel in ``values`` (NaN where the mapping reads no optional column), in
            channel order, then time order; empty for an advertise or a fix below ``min_status``.

        Raises
        ------
        MalformedMessage
            The message cannot be used (module docstring); one line naming the topic and the field.
        """
        if not isinstance(message, dict):
            raise MalformedMessage("json", f"a rosbridge message is a JSON object, not {_json_kind(message)}")
        op = message.get("op")
        if op not in ("publish", "advertise"):
            raise MalformedMessage("op", f"op {op!r} is not read (publish, advertise)")
        topic = message.get("topic")
        if not isinstance(topic, str):
            raise MalformedMessage("field", f"{op}: 'topic' is {_json_kind(topic)}, not a topic name")
        if op == "advertise":
            if topic in self.topics:
                self._advertise(topic, message.get("type"))
            return []
        if topic not in self.topics:
            raise MalformedMessage("topic", f"topic '{topic}' is not in the mapping (its topics: "
                                            f"{', '.join(sorted(self.topics))})")
        msg = message.get("msg")
        if not isinstance(msg, dict):
            raise MalformedMessage("field", f"publish on topic '{topic}': 'msg' is {_json_kind(msg)}, not a message")
        if topic in self._refused:
            raise MalformedMessage("type", self._refused[topic])
        readings = self._readings.get(topic) or self._infer(topic, msg)
        return [m for reading in readings for m in self._read(reading, topic, msg, receipt_s)]
